//! Command line of the calibrator (also embedded as `taxel calibrator`).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};
use taxel_formats::Recording;
use taxel_runtime::ipc::Ipc;
use taxel_runtime::process::{exit_code, init_tracing, CommonArgs, Failure, ResultExt};
use taxel_runtime::Shutdown;
use tracing::info;

use crate::calibration::validate_model;
use crate::calibration::{BlockSpec, Calibration, CalibrationFile};
use crate::fit::{
    fit_form, fitted_range, held_out_rmse, observations, stats, to_toml, Form, Observation,
};
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
    };
    let shutdown = Shutdown::install().runtime_err()?;
    let ipc = Ipc::open(&common.prefix, &format!("calibrator-{}", a.sensor)).runtime_err()?;
    let s = crate::run::run(&ipc, &cfg, initial, &shutdown).runtime_err()?;
    info!(
        sensor = %a.sensor,
        frames = s.frames,
        dropped = s.dropped,
        reloads = s.reloads,
        "calibrator stopped"
    );
    Ok(())
}

fn fit(a: FitArgs) -> Result<(), Failure> {
    let mut recs = Vec::new();
    for p in &a.data {
        recs.push(Recording::read(p).config_err()?);
    }
    let n = recs[0].n_nodes;
    for r in &recs {
        if r.n_nodes != n {
            return Err(Failure::config(anyhow::anyhow!(
                "{} has {} nodes but {} has {n}",
                r.path.display(),
                r.n_nodes,
                recs[0].path.display()
            )));
        }
        if r.force_n.is_none() {
            return Err(Failure::config(anyhow::anyhow!(
                "{}: needs a force_n column",
                r.path.display()
            )));
        }
    }
    let g = recs[0].geometry(a.rows, a.cols).config_err()?;
    let center = crate::central_block(g.rows, g.cols);
    let specs: Vec<(String, Vec<usize>)> =
        vec![("array".into(), Vec::new()), ("center".into(), center)];
    let mut blocks = Vec::new();
    let mut forms_used = Vec::new();
    for (name, nodes) in &specs {
        let mut obs: Vec<Observation> = Vec::new();
        for (i, r) in recs.iter().enumerate() {
            obs.extend(observations(r, i, nodes, 0.0).runtime_err()?);
        }
        obs.retain(|o| {
            if a.flat {
                o.c.abs() < 1e-9
            } else {
                o.c <= a.max_curvature_m1 + 1e-9
            }
        });
        if obs.is_empty() {
            return Err(Failure::config(anyhow::anyhow!(
                "no usable samples (a flat fit needs curvature_m1 = 0 rows)"
            )));
        }
        let form = match a.form {
            Form::Auto => {
                let (paper, trials) = held_out_rmse(&obs, Form::Paper, a.flat).runtime_err()?;
                let (physics, _) = held_out_rmse(&obs, Form::Physics, a.flat).runtime_err()?;
                let pick = if physics <= paper {
                    Form::Physics
                } else {
                    Form::Paper
                };
                println!(
                    "block {name:>6}: auto picks {} (held-out RMSE over {trials} trials: physics {physics:.3} N, paper {paper:.3} N)",
                    if pick == Form::Physics { "physics" } else { "paper" }
                );
                pick
            }
            f => f,
        };
        let spec = fit_form(&obs, form, a.flat).runtime_err()?;
        let model = validate_model(name, &spec)
            .map_err(|e| anyhow::anyhow!(e))
            .runtime_err()?;
        let range = fitted_range(&obs, &model).runtime_err()?;
        let smax = range.s[1];
        let within: Vec<Observation> = obs
            .iter()
            .copied()
            .filter(|o| o.s <= smax && o.c <= 80.0 + 1e-9)
            .collect();
        let st = stats(&within, |s, c| model.value(s.max(0.0), c));
        println!(
            "block {name:>6}: {} form, n = {}, on 0-80 1/m: R^2 = {:.4}, RMSE = {:.3} N; declared S <= {smax}, C {:?} 1/m",
            if form == Form::Physics { "physics" } else { "paper" },
            obs.len(),
            st.r2,
            st.rmse_n,
            range.curvature_m1
        );
        forms_used.push(if form == Form::Physics {
            "physics"
        } else {
            "paper"
        });
        blocks.push(BlockSpec {
            name: name.clone(),
            nodes: (!nodes.is_empty()).then(|| nodes.clone()),
            model: spec,
            range,
        });
    }
    let array = blocks.remove(0);
    let file = CalibrationFile {
        id: a.id.clone(),
        version: a.version,
        description: format!(
            "{} fit ({}) of {}",
            if a.flat { "flat" } else { "curvature-aware" },
            forms_used.join("/"),
            a.data
                .iter()
                .map(|p| p
                    .file_name()
                    .map_or_else(String::new, |f| f.to_string_lossy().into_owned()))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        rows: g.rows,
        cols: g.cols,
        default_curvature_m1: 0.0,
        array,
        blocks,
    };
    let comment = "Fitted by `taxel-calibrator fit`. S = block sum of (raw - no-load baseline) in counts;\nC = curvature in 1/m; F in N. Edit freely: the calibrator validates and hot-reloads it.";
    let text = to_toml(&file, comment);
    let cal = Calibration::from_toml_str(&a.out.display().to_string(), &text).runtime_err()?;
    if let Some(p) = &a.plot {
        crate::plots::surface(p, &cal).runtime_err()?;
        println!("plot: {}", p.display());
    }
    std::fs::write(&a.out, text)
        .with_context(|| format!("{}", a.out.display()))
        .runtime_err()?;
    println!("wrote {}", a.out.display());
    Ok(())
}
