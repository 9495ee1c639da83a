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

use crate::calibration::{BlockSpec, Calibration, CalibrationFile, ModelSpec};
use crate::fit::{fit_poly, fitted_range, observations, paper_terms, stats, to_toml, Observation};
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
    /// Model form (the paper's polynomial of total degree <= 3 in S and C).
    #[arg(long, default_value = "paper", value_parser = ["paper"])]
    pub form: String,
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
    #[arg(long, default_value_t = 80.0)]
    pub max_curvature_m1: f64,
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
    for (name, nodes) in &specs {
        let mut obs: Vec<Observation> = Vec::new();
        for r in &recs {
            obs.extend(observations(r, nodes, 0.0).runtime_err()?);
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
        let powers = paper_terms(3, a.flat);
        let (terms, st) = fit_poly(&obs, &powers).runtime_err()?;
        let range = fitted_range(&obs, &terms).runtime_err()?;
        let smax = range.s[1];
        let inside: Vec<Observation> = obs.iter().copied().filter(|o| o.s <= smax).collect();
        let model = |s: f64, c: f64| -> f64 {
            terms
                .iter()
                .map(|t| t.coef * s.powi(t.s as i32) * c.powi(t.c as i32))
                .sum()
        };
        let st_in = stats(&inside, model);
        println!(
            "block {name:>6}: n = {}, R^2 = {:.4}, RMSE = {:.3} N; within the declared range S <= {smax}: R^2 = {:.4}, RMSE = {:.3} N",
            st.n, st.r2, st.rmse_n, st_in.r2, st_in.rmse_n
        );
        blocks.push(BlockSpec {
            name: name.clone(),
            nodes: (!nodes.is_empty()).then(|| nodes.clone()),
            model: ModelSpec::Poly { terms },
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
            a.form,
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
    Calibration::from_toml_str(&a.out.display().to_string(), &text).runtime_err()?;
    std::fs::write(&a.out, text)
        .with_context(|| format!("{}", a.out.display()))
        .runtime_err()?;
    println!("wrote {}", a.out.display());
    Ok(())
}
