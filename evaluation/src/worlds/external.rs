//! Worlds taxel did not write: world B (the Table I protocol on its files) and the real
//! recordings (a flat calibration from each file's first 60 %, its last 40 % predicted).

use std::path::{Path, PathBuf};

use taxel_formats::Recording;

use super::zoo::{curvature_metrics, train_curvature};
use super::{ObjectsRow, RealRow, REAL_TRAIN_SHARE};
use crate::protocol::{evaluate, evaluate_with, Curvature, Headline};
use crate::table1::{LEVELS, OBJECTS};
use taxel_calibrator::fit::{fit_calibration, FitOptions};

/// World B with its README's protocol: the curvature model from `baselines_train`, tested on
/// `baselines_test`; both calibrations from `calibration`; the five `object_*` recordings.
pub fn world_b(dir: &Path, out: &Path, epochs: usize) -> anyhow::Result<ObjectsRow> {
    std::fs::create_dir_all(out).map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
    let model = train_curvature(&[dir.join("baselines_train.csv.gz")], 1, epochs)?;
    model.save(&out.join("curvature.taxcrv"))?;
    let m = curvature_metrics(&model, &[dir.join("baselines_test.csv.gz")])?;
    let fixtures = Recording::read(&dir.join("calibration.csv.gz"))?;
    let mut cals = Vec::new();
    for (name, flat) in [("curvature", false), ("flat", true)] {
        let opts = FitOptions::new(&format!("worldb-{name}"), flat);
        let (text, cal, _) = fit_calibration(std::slice::from_ref(&fixtures), &opts)?;
        let p = out.join(format!("{name}.toml"));
        std::fs::write(&p, text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
        cals.push(cal);
    }
    let mut reports = Vec::new();
    for (name, c) in OBJECTS {
        let p = dir.join(format!("object_{}.csv.gz", name.replace([' ', '-'], "_")));
        let rec = Recording::read(&p)?;
        let g = rec.geometry(None, None)?;
        let r = evaluate(&rec, g, &model, &cals[0], &cals[1], &LEVELS)?;
        reports.push((name.to_string(), c, r));
    }
    Ok(ObjectsRow::of("world B", None, &m, &reports, &cals[0]))
}

/// Every `*.csv.gz` with a force column in `dir`, in name order.
pub fn real(dir: &Path, out: &Path) -> anyhow::Result<Vec<RealRow>> {
    std::fs::create_dir_all(out).map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.to_string_lossy().ends_with(".csv.gz"))
        .collect();
    files.sort();
    let mut rows = Vec::new();
    for p in files {
        let rec = Recording::read(&p)?;
        if rec.force_n.is_none() {
            continue;
        }
        rows.push(one_real(&rec, out));
    }
    Ok(rows)
}

fn one_real(rec: &Recording, out: &Path) -> RealRow {
    let name = rec
        .path
        .file_name()
        .map(|n| n.to_string_lossy().trim_end_matches(".csv.gz").to_string())
        .unwrap_or_default();
    let mut row = RealRow {
        file: name.clone(),
        outcome: Err(String::new()),
        rel_mae: f64::NAN,
        mae_n: f64::NAN,
        frames: 0,
    };
    let run = || -> anyhow::Result<(String, String, crate::protocol::Overall)> {
        let k = (rec.len() as f64 * REAL_TRAIN_SHARE) as usize;
        let (train, test) = (rec.slice(0..k), rec.slice(k..rec.len()));
        let g = rec
            .geometry(None, None)
            .or_else(|_| rec.geometry(Some(1), Some(rec.n_nodes)))?;
        let opts = FitOptions {
            rows: Some(g.rows),
            cols: Some(g.cols),
            ..FitOptions::new(&name, true)
        };
        let (text, cal, _) = fit_calibration(std::slice::from_ref(&train), &opts)?;
        let p = out.join(format!("{name}.toml"));
        std::fs::write(&p, text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
        let r = evaluate_with(
            &test,
            g,
            Curvature::Continuing(0.0),
            &cal,
            None,
            &LEVELS,
            Headline::Array,
        )?;
        Ok((
            cal.readout.to_string(),
            cal.array.model.name().to_string(),
            r.overall,
        ))
    };
    match run() {
        Ok((readout, form, o)) => {
            row.outcome = Ok((readout, form));
            row.rel_mae = o.rel_mae;
            row.mae_n = o.mae_n;
            row.frames = o.frames;
        }
        Err(e) => row.outcome = Err(format!("{e:#}").replace('\n', " ")),
    }
    row
}
