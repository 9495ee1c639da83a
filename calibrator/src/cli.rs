//! Command line of the calibrator (also embedded as `taxel calibrator`).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};
use taxel_formats::readout::ReadoutChoice;
use taxel_formats::Recording;
use taxel_runtime::ipc::Ipc;
use taxel_runtime::priority::RealtimeArg;
use taxel_runtime::process::{exit_code, init_tracing, CommonArgs, Failure, ResultExt};
use taxel_runtime::sensors::{process_name, sensor_list, PerSensor, WakeGroupArg};
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
    /// Run the calibrator process for one sensor or several.
    Run(RunArgs),
    /// Fit a calibration file from recording CSVs with force_n (and curvature_m1).
    Fit(FitArgs),
}

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Sensor id, or several (`a,b,c`): one process serves them all, each on its own services.
    #[arg(long, default_value = "s0")]
    pub sensor: String,
    /// Calibration file (TOML); reloaded when it changes. One for every sensor, or one per
    /// sensor (`a.toml,b.toml,c.toml`); each distinct file is loaded and watched once.
    #[arg(long)]
    pub calibration: PerSensor<PathBuf>,
    /// Flag forces whose curvature estimate (baseline) is older than this (s).
    #[arg(long, default_value_t = 60.0)]
    pub curvature_stale_s: f64,
    /// Array rows the sensor streams (checked against the calibration).
    #[arg(long)]
    pub rows: Option<usize>,
    /// Array columns.
    #[arg(long)]
    pub cols: Option<usize>,
    /// How to wait for raw frames: event (default), busy, or adaptive (one sensor; several wait
    /// event-driven).
    #[arg(long, value_enum, default_value_t = WakeMode::Event)]
    pub wake: WakeMode,
    #[command(flatten)]
    pub group: WakeGroupArg,
    #[command(flatten)]
    pub realtime: RealtimeArg,
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
    /// Model form: the paper's polynomial, the physics-derived form, the shape-free monotone
    /// form, or whichever has the lowest error on held-out trials.
    #[arg(long, value_enum, default_value_t = Form::Auto)]
    pub form: Form,
    /// What the readings are: amplifier, divider, resistance, inverted, or auto (decided from
    /// the data; one printed line says what and why).
    #[arg(long, default_value_t = ReadoutChoice::default())]
    pub readout: ReadoutChoice,
    /// The ADC's full scale (default: the smallest 2^b - 1 at or above the largest reading).
    #[arg(long)]
    pub full_scale: Option<f64>,
    /// Keep fixtures whose reading stops rising with force (left out by default).
    #[arg(long)]
    pub keep_non_monotone: bool,
    /// Write a fit even when its held-out R^2 is below 0.5 or its forces span less than a
    /// tenth of the reference range.
    #[arg(long)]
    pub accept_poor_fit: bool,
    /// Characterisation recordings with a reference force (long holds, triangle sweeps; a
    /// curvature_m1 column or the calibration's default curvature): fit dynamic terms (creep,
    /// hysteresis) for every block on them, written where they lower the held-out error.
    #[arg(long, num_args = 1.., conflicts_with = "dynamics_from")]
    pub dynamics: Vec<PathBuf>,
    /// Take the dynamic terms from a simulator model instead (SIM.toml from `taxel-simcheck
    /// diagnose`, or any taxel-sim model file): its creep and hysteresis.
    #[arg(long)]
    pub dynamics_from: Option<PathBuf>,
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
    };
    exit_code("taxel-calibrator", r)
}

fn run(common: &CommonArgs, a: RunArgs) -> Result<(), Failure> {
    let bad = |e: String| Failure::config(anyhow::anyhow!(e));
    let names = sensor_list("--sensor", &a.sensor).map_err(bad)?;
    let paths = a
        .calibration
        .resolve_all("--calibration", names.len())
        .map_err(bad)?;
    if !(a.curvature_stale_s.is_finite() && a.curvature_stale_s > 0.0) {
        return Err(Failure::config(anyhow::anyhow!(
            "--curvature-stale-s must be a positive number"
        )));
    }
    if names.len() > 1 && a.wake != WakeMode::Event {
        let mode = if a.wake == WakeMode::Busy {
            "busy"
        } else {
            "adaptive"
        };
        return Err(bad(format!(
            "--wake {mode}: several sensors wait event-driven only (drop --wake or serve one sensor)"
        )));
    }
    let group = a.group.checked().map_err(bad)?;
    a.realtime.apply(a.wake == WakeMode::Busy).map_err(bad)?;
    // Each distinct file is loaded once; a bad one names the sensor(s) it was given for.
    let mut files: Vec<PathBuf> = Vec::new();
    let mut initial = Vec::new();
    let mut sensors = Vec::with_capacity(names.len());
    for (name, p) in names.iter().zip(&paths) {
        let at = if names.len() == 1 {
            String::new()
        } else {
            format!("sensor {name:?}: ")
        };
        let file = match files.iter().position(|f| f == p) {
            Some(i) => i,
            None => {
                let cal = Calibration::load(p)
                    .map_err(|e| anyhow::anyhow!("{at}{e}"))
                    .config_err()?;
                if let (Some(r), Some(c)) = (a.rows, a.cols) {
                    load_for(p, r, c)
                        .map_err(|e| anyhow::anyhow!("{at}{e}"))
                        .config_err()?;
                }
                files.push(p.clone());
                initial.push(cal);
                files.len() - 1
            }
        };
        sensors.push(crate::run::SensorConfig {
            sensor: name.clone(),
            file,
        });
    }
    let cfg = crate::run::Config {
        sensors,
        files,
        curvature_stale_s: a.curvature_stale_s,
        wake: a.wake,
        group: group.map(str::to_string),
    };
    let shutdown = Shutdown::install().runtime_err()?;
    let ipc = Ipc::open(&common.prefix, &process_name("calibrator", &names)).runtime_err()?;
    let s = crate::run::run(&ipc, &cfg, initial, &shutdown).runtime_err()?;
    info!(
        sensor = %a.sensor,
        frames = s.frames,
        dropped = s.dropped,
        reloads = s.reloads,
        skipped_geometry = s.geometry_mismatches,
        skipped_readout = s.readout_mismatches,
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
    if let Some(fs) = a.full_scale {
        if !(fs.is_finite() && (1.0..=1e9).contains(&fs)) {
            return Err(Failure::config(anyhow::anyhow!(
                "--full-scale must be 1..=1e9, got {fs}"
            )));
        }
    }
    let opts = FitOptions {
        form: a.form,
        version: a.version,
        rows: a.rows,
        cols: a.cols,
        max_curvature_m1: a.max_curvature_m1,
        readout: a.readout.0,
        full_scale: a.full_scale,
        keep_non_monotone: a.keep_non_monotone,
        accept_poor_fit: a.accept_poor_fit,
        ..FitOptions::new(&a.id, a.flat)
    };
    let (mut text, mut cal, mut report) = fit_calibration(&recs, &opts).config_err()?;
    if !a.dynamics.is_empty() {
        let mut chars = Vec::new();
        for p in &a.dynamics {
            chars.push(Recording::read(p).config_err()?);
        }
        (text, cal) = crate::fit::with_dynamics(&text, &cal, &chars, &mut report).config_err()?;
    }
    if let Some(p) = &a.dynamics_from {
        let model = crate::fit::from_sim::load(p).config_err()?;
        (text, cal) =
            crate::fit::with_sim_dynamics(&text, &cal, &model, &mut report).config_err()?;
    }
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
