//! Command line of the estimator (also embedded as `taxel estimator`).

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;

use clap::{Parser, Subcommand};
use taxel_runtime::ipc::Ipc;
use taxel_runtime::priority::RealtimeArg;
use taxel_runtime::process::{exit_code, init_tracing, CommonArgs, Failure, ResultExt};
use taxel_runtime::sensors::{process_name, resolve_opt, sensor_list, PerSensor, WakeGroupArg};
use taxel_runtime::Shutdown;
use tracing::info;

use crate::baseline::DetectorConfig;
use crate::model::{CurvatureModel, Kind, Metrics, TrainOptions};
use crate::synth::{Spec, World};
use taxel_formats::readout::ReadoutChoice;
use taxel_runtime::progress::Progress;

/// No-load baselines and the mounting curvature of a sensor.
#[derive(Debug, Parser)]
#[command(name = "taxel-estimator", version)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    #[command(subcommand)]
    pub cmd: Cmd,
}

#[derive(Debug, Subcommand)]
pub enum Cmd {
    /// Run the estimator process for one sensor or several.
    Run(RunArgs),
    /// Train a curvature model from recordings with a curvature_m1 column.
    Train(TrainArgs),
    /// Evaluate a curvature model on recordings (curvatures 0-80 1/m).
    Eval(EvalArgs),
    /// Generate a paper-like curvature dataset from the simulator.
    Dataset(DatasetArgs),
}

#[derive(Debug, clap::Args)]
pub struct TrainArgs {
    /// Recording CSVs (.csv or .csv.gz) with curvature_m1; each trial becomes one sample.
    #[arg(long, num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// Output model file.
    #[arg(long)]
    pub out: PathBuf,
    /// Which model: the paper's residual MLP, ridge regression, or whichever validates better.
    #[arg(long, value_enum, default_value_t = Kind::Auto)]
    pub model: Kind,
    /// Seed of the split, the initialization and every random draw of training.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// MLP epochs (the paper: 500).
    #[arg(long, default_value_t = 500)]
    pub epochs: usize,
    /// Write the figures (predicted vs true curvature and error vs curvature of the kept model
    /// on the training data, SVG and PNG) and train.md (this report) into this directory.
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// What the readings are: amplifier, divider, resistance, inverted, or auto (from the
    /// data: one printed line says what and why; baselines without force_n are used as
    /// recorded).
    #[arg(long, default_value_t = ReadoutChoice::default())]
    pub readout: ReadoutChoice,
    /// The ADC's full scale (default: the smallest 2^b - 1 at or above the largest reading).
    #[arg(long)]
    pub full_scale: Option<f64>,
}

#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Model file from `train`.
    #[arg(long)]
    pub model: PathBuf,
    /// Recording CSVs with curvature_m1.
    #[arg(long, num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// Print exactly one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
    /// Draw predicted vs true curvature to this file (.svg or .png).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Write the figures (predicted vs true curvature, error vs curvature; SVG and PNG) and
    /// eval.json (the metrics) into this directory.
    #[arg(long)]
    pub plots: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
pub struct DatasetArgs {
    /// Output directory (one sensorN.csv.gz per simulated sensor).
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of the sensors, mountings and noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Number of simulated sensors (the paper: 3).
    #[arg(long, default_value_t = 3)]
    pub sensors: usize,
    /// Simulated world.
    #[arg(long, value_enum, default_value_t = World::Paper)]
    pub world: World,
    /// Measurement session: the same sensors measured again (new mountings and noise).
    #[arg(long, default_value_t = 0)]
    pub session: u64,
}

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Sensor id, or several (`a,b,c`): one process serves them all, each on its own services.
    #[arg(long, default_value = "s0")]
    pub sensor: String,
    /// Curvature of the mounting surface to publish (1/m): one for every sensor, or one per
    /// sensor (`40,55,`; an empty entry is 0).
    #[arg(long)]
    pub curvature_m1: Option<PerSensor<f64>>,
    #[command(flatten)]
    pub group: WakeGroupArg,
    #[command(flatten)]
    pub realtime: RealtimeArg,
    /// Frames per no-load window.
    #[arg(long, default_value_t = DetectorConfig::default().window_frames)]
    pub window_frames: usize,
    /// A window is steady when each node's spread is at most this many times its own
    /// frame-to-frame noise.
    #[arg(long, default_value_t = DetectorConfig::default().steady_ratio)]
    pub steady_ratio: f64,
    /// A no-load window's level is within this many noise levels (measured from the stream) of
    /// the baseline.
    #[arg(long, default_value_t = DetectorConfig::default().contact_sigmas)]
    pub contact_sigmas: f64,
    /// Fixed override: largest per-node standard deviation of a steady window (reading units;
    /// default: adaptive, from the stream's noise).
    #[arg(long)]
    pub max_node_sd: Option<f64>,
    /// Fixed override: largest per-node move from the baseline still counted as no load
    /// (reading units; default: adaptive).
    #[arg(long)]
    pub contact_threshold: Option<f64>,
    /// Least time between published baselines (s).
    #[arg(long, default_value_t = DetectorConfig::default().min_interval_s)]
    pub min_interval_s: f64,
    /// A steady no-load level that differs from the current baseline for this long is taken as
    /// a new baseline (the sensor was remounted) (s).
    #[arg(long, default_value_t = DetectorConfig::default().rebaseline_s)]
    pub rebaseline_s: f64,
    /// The same for a level on the loaded side of the baseline, when the model's readout says
    /// which side that is (s): longer than a light press is held still.
    #[arg(long, default_value_t = DetectorConfig::default().rebaseline_load_s)]
    pub rebaseline_load_s: f64,
    /// Curvature model file (from `train`); without it the configured --curvature-m1 is used.
    /// The file is watched: a valid replacement is used from the next no-load window on. One
    /// for every sensor, or one per sensor (`a.taxcrv,,b.taxcrv`; an empty entry: none).
    #[arg(long)]
    pub model: Option<PerSensor<PathBuf>>,
}

pub fn main(args: Args) -> ExitCode {
    init_tracing(&args.common.log);
    let r = match args.cmd {
        Cmd::Run(a) => run(&args.common, a),
        Cmd::Train(a) => train(a),
        Cmd::Eval(a) => eval(a),
        Cmd::Dataset(a) => dataset(a),
    };
    exit_code("taxel-estimator", r)
}

fn run(common: &CommonArgs, a: RunArgs) -> Result<(), Failure> {
    let bad = |e: String| Failure::config(anyhow::anyhow!(e));
    let names = sensor_list("--sensor", &a.sensor).map_err(bad)?;
    let n = names.len();
    let group = a.group.checked().map_err(bad)?;
    a.realtime.apply(false).map_err(bad)?;
    let curvatures = resolve_opt(&a.curvature_m1, "--curvature-m1", n).map_err(bad)?;
    let model_paths = resolve_opt(&a.model, "--model", n).map_err(bad)?;
    let detector = DetectorConfig {
        window_frames: a.window_frames,
        steady_ratio: a.steady_ratio,
        contact_sigmas: a.contact_sigmas,
        max_node_sd: a.max_node_sd,
        contact_threshold: a.contact_threshold,
        min_interval_s: a.min_interval_s,
        rebaseline_s: a.rebaseline_s,
        rebaseline_load_s: a.rebaseline_load_s,
        ..DetectorConfig::default()
    };
    detector
        .validate()
        .map_err(|e| anyhow::anyhow!(e))
        .config_err()?;
    // Each distinct model file is loaded once and shared by the sensors that name it.
    let mut loaded: Vec<(PathBuf, Arc<CurvatureModel>)> = Vec::new();
    let mut sensors = Vec::with_capacity(n);
    for (i, name) in names.iter().enumerate() {
        let at = if n == 1 {
            String::new()
        } else {
            format!("sensor {name:?}: ")
        };
        let c = curvatures[i].unwrap_or(0.0);
        if !(c.is_finite() && c >= 0.0) {
            return Err(bad(format!(
                "{at}--curvature-m1 must be a finite number >= 0, got {c}"
            )));
        }
        let model = match &model_paths[i] {
            Some(p) => match loaded.iter().find(|(q, _)| q == p) {
                Some((_, m)) => Some(m.clone()),
                None => {
                    let m = Arc::new(
                        CurvatureModel::load(p)
                            .map_err(|e| anyhow::anyhow!("{at}{e}"))
                            .config_err()?,
                    );
                    loaded.push((p.clone(), m.clone()));
                    Some(m)
                }
            },
            None => None,
        };
        sensors.push(crate::run::SensorConfig {
            sensor: name.clone(),
            curvature_m1: c,
            model,
            model_path: model_paths[i].clone(),
        });
    }
    let cfg = crate::run::Config {
        sensors,
        detector,
        group: group.map(str::to_string),
    };
    let shutdown = Shutdown::install().runtime_err()?;
    let ipc = Ipc::open(&common.prefix, &process_name("estimator", &names)).runtime_err()?;
    let s = crate::run::run(&ipc, &cfg, &shutdown).runtime_err()?;
    info!(
        sensor = %a.sensor,
        frames = s.frames,
        estimates = s.estimates,
        reloads = s.reloads,
        "estimator stopped"
    );
    Ok(())
}

fn paths(v: &[PathBuf]) -> Vec<String> {
    v.iter().map(|p| p.display().to_string()).collect()
}

fn train(a: TrainArgs) -> Result<(), Failure> {
    if a.epochs == 0 || a.epochs > 100_000 {
        return Err(Failure::config(anyhow::anyhow!(
            "--epochs must be 1..=100000, got {}",
            a.epochs
        )));
    }
    if let Some(fs) = a.full_scale {
        if !(fs.is_finite() && (1.0..=1e9).contains(&fs)) {
            return Err(Failure::config(anyhow::anyhow!(
                "--full-scale must be 1..=1e9, got {fs}"
            )));
        }
    }
    let (readout, why, samples) =
        crate::dataset::prepare(&a.data, a.readout.0, a.full_scale).config_err()?;
    println!("{why}");
    let opts = TrainOptions {
        readout,
        kind: a.model,
        seed: a.seed,
        mlp: crate::model::mlp::MlpConfig {
            epochs: a.epochs,
            ..Default::default()
        },
        ..TrainOptions::default()
    };
    println!(
        "training on {} samples from {} file(s), curvature {:.1}..{:.1} 1/m",
        samples.len(),
        a.data.len(),
        samples
            .iter()
            .map(|s| s.curvature_m1)
            .fold(f64::INFINITY, f64::min),
        samples
            .iter()
            .map(|s| s.curvature_m1)
            .fold(f64::NEG_INFINITY, f64::max)
    );
    let t0 = std::time::Instant::now();
    let mut bar = Progress::new("training", 1);
    let model = crate::model::train(&samples, &paths(&a.data), &opts, |done, total| {
        bar.set_total(total as u64);
        bar.set(done as u64);
    })
    .config_err()?;
    bar.finish();
    let mut report = Vec::new();
    for (name, m) in &model.training.candidates {
        report.push(format!(
            "validation {name:>5}: R^2 {:.3}, MAE {:.2} 1/m, RMSE {:.2} 1/m (n = {})",
            m.r2, m.mae_m1, m.rmse_m1, m.n
        ));
    }
    model.save(&a.out).runtime_err()?;
    report.push(format!(
        "kept {} (version {:08x}), refitted on all {} samples in {:.1} s -> {}",
        model.kind,
        model.model_version,
        samples.len(),
        t0.elapsed().as_secs_f64(),
        a.out.display()
    ));
    for l in &report {
        println!("{l}");
    }
    if let Some(dir) = &a.plots {
        let pred = model.predict_samples(&samples);
        let truth: Vec<f64> = samples.iter().map(|s| s.curvature_m1).collect();
        let pairs: Vec<(f64, f64)> = truth.iter().copied().zip(pred.iter().copied()).collect();
        let m = Metrics::of(&pred, &truth);
        let what = format!("{} on its training data (in-sample)", model.kind);
        let files = write_figures(dir, &pairs, &m, &what).runtime_err()?;
        let md = dir.join("train.md");
        let text = format!(
            "# Curvature model training\n\n{}\n\nIn-sample on all {} samples: R^2 {:.3}, MAE {:.2} 1/m, RMSE {:.2} 1/m.\n\nFigures: {}\n",
            report.join("\n\n"),
            m.n,
            m.r2,
            m.mae_m1,
            m.rmse_m1,
            names(&files)
        );
        std::fs::write(&md, text)
            .map_err(|e| anyhow::anyhow!("{}: {e}", md.display()))
            .runtime_err()?;
        println!("report and figures: {}", dir.display());
    }
    Ok(())
}

/// File names, comma separated (for the reports that list their figures).
fn names(files: &[PathBuf]) -> String {
    files
        .iter()
        .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Predicted-vs-true and error-vs-curvature figures, SVG and PNG, into `dir`.
fn write_figures(
    dir: &std::path::Path,
    pairs: &[(f64, f64)],
    m: &Metrics,
    what: &str,
) -> anyhow::Result<Vec<PathBuf>> {
    let mut files = taxel_plot::svg_and_png(dir, "predicted-vs-true", |p| {
        crate::plot::predicted_vs_true(p, pairs, m, what)
    })?;
    files.extend(taxel_plot::svg_and_png(dir, "error-vs-curvature", |p| {
        crate::plot::error_vs_curvature(p, pairs, what)
    })?);
    Ok(files)
}

/// Metrics of a model on recordings, restricted to 0-80 1/m.
pub fn evaluate(
    model: &CurvatureModel,
    data: &[PathBuf],
) -> Result<(Metrics, Vec<(f64, f64)>), Failure> {
    crate::model::evaluate_files(model, data).config_err()
}

fn eval(a: EvalArgs) -> Result<(), Failure> {
    let model = CurvatureModel::load(&a.model).config_err()?;
    let (m, pairs) = evaluate(&model, &a.data)?;
    if let Some(p) = &a.plot {
        crate::plot::predicted_vs_true(p, &pairs, &m, &model.kind).runtime_err()?;
    }
    let json = format!(
        "{{\"r2\": {:.6}, \"mae_m1\": {:.6}, \"rmse_m1\": {:.6}, \"n\": {}}}",
        m.r2, m.mae_m1, m.rmse_m1, m.n
    );
    if let Some(dir) = &a.plots {
        write_figures(dir, &pairs, &m, &model.kind).runtime_err()?;
        let p = dir.join("eval.json");
        std::fs::write(&p, format!("{json}\n"))
            .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
            .runtime_err()?;
    }
    if a.json {
        println!("{json}");
    } else {
        println!(
            "{} model {:08x} on {} sample(s), 0-80 1/m: R^2 {:.3}, MAE {:.2} 1/m, RMSE {:.2} 1/m",
            model.kind, model.model_version, m.n, m.r2, m.mae_m1, m.rmse_m1
        );
        if let Some(p) = &a.plot {
            println!("plot: {}", p.display());
        }
        if let Some(d) = &a.plots {
            println!("figures and eval.json: {}", d.display());
        }
    }
    Ok(())
}

fn dataset(a: DatasetArgs) -> Result<(), Failure> {
    if !(1..=100).contains(&a.sensors) {
        return Err(Failure::config(anyhow::anyhow!(
            "--sensors must be 1..=100, got {}",
            a.sensors
        )));
    }
    let spec = Spec {
        sensors: a.sensors,
        session: a.session,
        ..Spec::paper(a.world, a.seed)
    };
    let mut bar = Progress::new("simulating sensors", a.sensors as u64);
    let files = crate::synth::generate(&spec, &a.out, |d, _| bar.set(d as u64)).runtime_err()?;
    bar.finish();
    for f in &files {
        println!("{}", f.display());
    }
    Ok(())
}
