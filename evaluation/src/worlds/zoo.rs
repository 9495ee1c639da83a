//! One simulator family with one seed: baselines of three sensor builds (session 0 trains the
//! curvature model, session 1 tests it), then the Table I reproduction on build 0.

use std::path::{Path, PathBuf};

use taxel_estimator::model::{CurvatureModel, Kind, Metrics, TrainOptions};
use taxel_estimator::synth::{self, Spec, World};

use super::ObjectsRow;
use crate::table1;
use taxel_calibrator::calibration::Calibration;

pub fn family(out: &Path, preset: &str, seed: u64, epochs: usize) -> anyhow::Result<ObjectsRow> {
    let mut sensor = taxel_sim::presets::preset(preset).ok_or_else(|| {
        anyhow::anyhow!(
            "unknown family {preset:?} (one of {})",
            taxel_sim::presets::NAMES.join(", ")
        )
    })?;
    let dir = out.join(format!("{preset}-seed{seed}"));
    let spec = Spec {
        preset: preset.to_string(),
        ..Spec::paper(World::Paper, seed)
    };
    let train = synth::generate(&spec, &dir.join("baselines-train"), |_, _| {})?;
    let test_spec = Spec {
        session: 1,
        ..spec.clone()
    };
    let test = synth::generate(&test_spec, &dir.join("baselines-test"), |_, _| {})?;
    let model = train_curvature(&train, seed, epochs)?;
    model.save(&dir.join("curvature.taxcrv"))?;
    let m = curvature_metrics(&model, &test)?;
    sensor.spread.build_seed = Some(synth::build_seed(seed, 0));
    let t1 = dir.join("table1");
    let t = table1::run(&t1, &model, &sensor, seed, |_| {})?;
    let cal = Calibration::load(&t1.join("curvature.toml"))?;
    Ok(ObjectsRow::of(preset, Some(seed), &m, &t.reports, &cal))
}

/// `taxel estimator train` with its defaults (readout auto, model auto).
pub fn train_curvature(
    files: &[PathBuf],
    seed: u64,
    epochs: usize,
) -> anyhow::Result<CurvatureModel> {
    let (readout, _why, samples) = taxel_estimator::dataset::prepare(files, None, None)?;
    let names: Vec<String> = files.iter().map(|p| p.display().to_string()).collect();
    let opts = TrainOptions {
        readout,
        kind: Kind::Auto,
        seed,
        mlp: taxel_estimator::model::mlp::MlpConfig {
            epochs,
            ..Default::default()
        },
        ..TrainOptions::default()
    };
    Ok(taxel_estimator::model::train(
        &samples,
        &names,
        &opts,
        |_, _| {},
    )?)
}

/// `taxel estimator eval`: the model on held-out baselines, 0-80 1/m.
pub fn curvature_metrics(model: &CurvatureModel, files: &[PathBuf]) -> anyhow::Result<Metrics> {
    Ok(taxel_estimator::model::evaluate_files(model, files)?.0)
}
