//! Command line of the calibrator (also embedded as `taxel calibrator`).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};
use taxel_formats::Recording;
use taxel_runtime::ipc::Ipc;
use taxel_runtime::process::{exit_code, init_tracing, CommonArgs, Failure, ResultExt};
use taxel_runtime::wake::WakeMode;
use taxel_runtime::Shutdown;
use tracing::info;

use crate::calibration::Calibration;
use crate::fit::{fit_calibration, FitOptions, Form};
use crate::reload::load_for;

/// Calibrated forces from raw frames, and the tools to make calibration files.
#[derive(Debug, Parser)]
#[command(name = "taxel-calibrator", version)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    #[command(subcommand)]
    pub cmd: Cmd,
}

#[derive(Debug, Subcommand)]
pub enum Cmd {
    /// Run the calibrator process for one sensor.
    Run(RunArgs),
    /// Fit a calibration file from recording CSVs with force_n (and curvature_m1).
    Fit(FitArgs),
    /// The paper's protocol on an object recording: flat vs curvature-aware error per level.
    Eval(EvalArgs),
}

#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Curvature model (from `taxel estimator train`).
    #[arg(long)]
    pub curvature_model: PathBuf,
    /// Curvature-aware calibration.
    #[arg(long)]
    pub calibration: PathBuf,
    /// Flat calibration (fitted with --flat).
    #[arg(long)]
    pub flat: PathBuf,
    /// Recording of the object (.csv or .csv.gz) with force_n; it must start unloaded.
    #[arg(long)]
    pub recording: PathBuf,
    /// Force levels (N).
    #[arg(long, value_delimiter = ',', default_value = "2,4,6,8")]
    pub levels: Vec<f64>,
    /// Print exactly one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
    /// Rows of the array (inferred for a square node count).
    #[arg(long)]
    pub rows: Option<usize>,
    /// Columns of the array.
    #[arg(long)]
    pub cols: Option<usize>,
    /// Write the figures (force over time: reference, curvature-aware and flat; error per
    /// level; SVG and PNG) and eval.json (the report) into this directory.
    #[arg(long)]
    pub plots: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Sensor id.
    #[arg(long, default_value = "s0")]
    pub sensor: String,
    /// Calibration file (TOML); reloaded when it changes.
    #[arg(long)]
    pub calibration: PathBuf,
    /// Flag forces whose curvature estimate (baseline) is older than this (s).
    #[arg(long, default_value_t = 60.0)]
    pub curvature_stale_s: f64,
    /// Array rows the sensor streams (checked against the calibration).
    #[arg(long)]
    pub rows: Option<usize>,
    /// Array columns.
    #[arg(long)]
    pub cols: Option<usize>,
    /// How to wait for raw frames: event (default), busy, or adaptive.
    #[arg(long, value_enum, default_value_t = WakeMode::Event)]
    pub wake: WakeMode,
}

#[derive(Debug, clap::Args)]
pub struct FitArgs {
    /// Recording CSVs (.csv or .csv.gz) with force_n and, for curvature-aware fits, curvature_m1.
    #[arg(long, num_args = 1.., required = true)]
    pub data: Vec<PathBuf>,
    /// Output calibration file.
    #[arg(long)]
    pub out: PathBuf,
    /// Fit a flat calibration from the curvature-0 data only.
    #[arg(long)]
    pub flat: bool,
    /// Model form: the paper's polynomial, the physics-derived monotone form, or whichever has
    /// the lower error on held-out trials.
    #[arg(long, value_enum, default_value_t = Form::Auto)]
    pub form: Form,
    /// Calibration id written into the file.
    #[arg(long, default_value = "fitted")]
    pub id: String,
    /// Calibration version written into the file.
    #[arg(long, default_value_t = 1)]
    pub version: u32,
    /// Rows of the array (inferred for a square node count).
    #[arg(long)]
    pub rows: Option<usize>,
    /// Columns of the array.
    #[arg(long)]
    pub cols: Option<usize>,
    /// Largest curvature used for the fit (1/m).
    #[arg(long, default_value_t = 100.0)]
    pub max_curvature_m1: f64,
    /// Draw the calibration surface (force vs reading at several curvatures) to .svg or .png.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Write the calibration surface of every block (SVG and PNG) and fit.md (this report)
    /// into this directory.
    #[arg(long)]
    pub plots: Option<PathBuf>,
}

/// Runs the calibrator CLI; the exit code follows the process conventions.
pub fn main(args: Args) -> ExitCode {
    init_tracing(&args.common.log);
    let r = match args.cmd {
        Cmd::Run(a) => run(&args.common, a),
        Cmd::Fit(a) => fit(a),
        Cmd::Eval(a) => eval(a),
    };
    exit_code("taxel-calibrator", r)
}

fn run(common: &CommonArgs, a: RunArgs) -> Result<(), Failure> {
    taxel_msgs::sensor_id_bytes(&a.sensor).config_err()?;
    if !(a.curvature_stale_s.is_finite() && a.curvature_stale_s > 0.0) {
        return Err(Failure::config(anyhow::anyhow!(
            "--curvature-stale-s must be a positive number"
        )));
    }
    let initial = Calibration::load(&a.calibration).config_err()?;
    if let (Some(r), Some(c)) = (a.rows, a.cols) {
        load_for(&a.calibration, r, c)
            .map_err(|e| anyhow::anyhow!(e))
            .config_err()?;
    }
    let cfg = crate::run::Config {
        sensor: a.sensor.clone(),
        calibration: a.calibration.clone(),
        curvature_stale_s: a.curvature_stale_s,
        wake: a.wake,
    };
    let shutdown = Shutdown::install().runtime_err()?;
    let ipc = Ipc::open(&common.prefix, &format!("calibrator-{}", a.sensor)).runtime_err()?;
    let s = crate::run::run(&ipc, &cfg, initial, &shutdown).runtime_err()?;
    info!(
        sensor = %a.sensor,
        frames = s.frames,
        dropped = s.dropped,
        reloads = s.reloads,
        adaptive_caught = s.wake.caught,
        adaptive_waiting = s.wake.waiting,
        adaptive_fallbacks = s.wake.fallbacks,
        adaptive_spin_ms = s.wake.spin_ns / 1_000_000,
        adaptive_learned = ?s.wake.learned,
        cpu_s = format!("{:.2}", taxel_runtime::process::cpu_seconds()),
        "calibrator stopped"
    );
    Ok(())
}

fn fit(a: FitArgs) -> Result<(), Failure> {
    let mut recs = Vec::new();
    for p in &a.data {
        recs.push(Recording::read(p).config_err()?);
    }
    let opts = FitOptions {
        form: a.form,
        flat: a.flat,
        id: a.id.clone(),
        version: a.version,
        rows: a.rows,
        cols: a.cols,
        max_curvature_m1: a.max_curvature_m1,
    };
    let (text, cal, report) = fit_calibration(&recs, &opts).config_err()?;
    for line in &report {
        println!("{line}");
    }
    if let Some(p) = &a.plot {
        crate::plots::surface(p, &cal).runtime_err()?;
        println!("plot: {}", p.display());
    }
    std::fs::write(&a.out, text)
        .with_context(|| format!("{}", a.out.display()))
        .runtime_err()?;
    println!("wrote {}", a.out.display());
    if let Some(dir) = &a.plots {
        let mut files = Vec::new();
        for (i, b) in cal.blocks.iter().enumerate() {
            files.extend(
                taxel_plot::svg_and_png(dir, &format!("calibration-surface-b{i}"), |p| {
                    crate::plots::block_surface(p, &cal, b)
                })
                .runtime_err()?,
            );
        }
        files.extend(
            taxel_plot::svg_and_png(dir, "calibration-surface-array", |p| {
                crate::plots::block_surface(p, &cal, &cal.array)
            })
            .runtime_err()?,
        );
        let md = dir.join("fit.md");
        let names: Vec<String> = files
            .iter()
            .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .collect();
        std::fs::write(
            &md,
            format!(
                "# Calibration fit -> {}\n\n{}\n\nFigures (force against reading at curvatures across the declared range, per block and for the whole array): {}\n",
                a.out.display(),
                report.join("\n\n"),
                names.join(", ")
            ),
        )
        .with_context(|| format!("{}", md.display()))
        .runtime_err()?;
        println!("report and figures: {}", dir.display());
    }
    Ok(())
}

fn eval(a: EvalArgs) -> Result<(), Failure> {
    for l in &a.levels {
        if !(l.is_finite() && *l > 0.0) {
            return Err(Failure::config(anyhow::anyhow!(
                "--levels must be positive forces in N, got {l}"
            )));
        }
    }
    let model = taxel_estimator::model::CurvatureModel::load(&a.curvature_model).config_err()?;
    let curve = Calibration::load(&a.calibration).config_err()?;
    let flat = Calibration::load(&a.flat).config_err()?;
    let rec = Recording::read(&a.recording).config_err()?;
    let g = rec.geometry(a.rows, a.cols).config_err()?;
    model
        .check_nodes(&a.curvature_model.display().to_string(), rec.n_nodes)
        .config_err()?;
    let r = crate::evaluate::evaluate(&rec, g, &model, &curve, &flat, &a.levels).config_err()?;
    if let Some(dir) = &a.plots {
        let name = a
            .recording
            .file_name()
            .map_or(String::new(), |n| n.to_string_lossy().into_owned());
        taxel_plot::svg_and_png(dir, "force-vs-time", |p| {
            crate::plots::force_vs_time(p, &rec, &r, &name)
        })
        .runtime_err()?;
        taxel_plot::svg_and_png(dir, "error-per-level", |p| {
            crate::plots::error_per_level(p, &r, &name)
        })
        .runtime_err()?;
        let p = dir.join("eval.json");
        std::fs::write(&p, format!("{}\n", crate::evaluate::json(&r)))
            .with_context(|| format!("{}", p.display()))
            .runtime_err()?;
        if !a.json {
            println!("figures and eval.json: {}", dir.display());
        }
    }
    if a.json {
        println!("{}", crate::evaluate::json(&r));
        return Ok(());
    }
    println!(
        "{}: curvature predicted {:.1} +- {:.1} 1/m from the first {} frames",
        a.recording.display(),
        r.curvature_pred_m1,
        r.curvature_sd_m1,
        r.estimate_at + 1
    );
    println!("| level (N) | frames | flat MAE +- SD (N) | curvature-aware MAE +- SD (N) |");
    println!("|---:|---:|---:|---:|");
    for l in &r.levels {
        if l.n == 0 {
            println!("| {} | 0 | no window | no window |", l.target_n);
        } else {
            println!(
                "| {} | {} | {:.2} +- {:.2} | {:.2} +- {:.2} |",
                l.target_n, l.n, l.flat_mae_n, l.flat_sd_n, l.curve_mae_n, l.curve_sd_n
            );
        }
    }
    Ok(())
}
