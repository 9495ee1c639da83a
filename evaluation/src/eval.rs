//! `taxel calibrator eval`: the paper's protocol on an object recording (flat vs
//! curvature-aware error per level, hold drift, figures). It runs the live estimator's and
//! calibrator's code offline, so it lives here rather than in either process crate; the
//! launcher adds it to the calibrator's subcommands.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use taxel_calibrator::calibration::Calibration;
use taxel_formats::Recording;
use taxel_runtime::process::{exit_code, init_tracing, Failure, ResultExt};

use crate::protocol::{Curvature, Headline, OVERALL_MIN_N};

#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    /// Curvature model (from `taxel estimator train`): the curvature is predicted from the
    /// recording's no-load start, as in the paper.
    #[arg(
        long,
        conflicts_with = "curvature_m1",
        required_unless_present = "curvature_m1"
    )]
    pub curvature_model: Option<PathBuf>,
    /// The mounting's curvature (1/m), for a sensor without a curvature model or a known
    /// mounting.
    #[arg(long)]
    pub curvature_m1: Option<f64>,
    /// With --curvature-m1: the recording continues the calibration's own session (its
    /// held-out tail, say, which may start in the middle of a press), so its no-load level is
    /// expected at the calibration's no_load_reading rather than taken from its first steady
    /// window.
    #[arg(long, requires = "curvature_m1")]
    pub continues_calibration: bool,
    /// Curvature-aware calibration (or the only one, with --curvature-m1).
    #[arg(long)]
    pub calibration: PathBuf,
    /// Flat calibration (fitted with --flat), scored beside it.
    #[arg(long)]
    pub flat: Option<PathBuf>,
    /// Recording of the object (.csv or .csv.gz) with force_n; with a curvature model it must
    /// start unloaded.
    #[arg(long)]
    pub recording: PathBuf,
    /// Force levels (N).
    #[arg(long, value_delimiter = ',', default_value = "2,4,6,8")]
    pub levels: Vec<f64>,
    /// Which force the headline (`levels`, `overall`) compares with the reference: the whole
    /// array (the load on the whole sensor) or the central 2 x 2 block. Both are always in
    /// `blocks`.
    #[arg(long, value_enum, default_value_t = Headline::Array)]
    pub headline: Headline,
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

/// Runs `taxel calibrator eval` with the calibrator's log filter; the exit code follows the
/// process conventions.
pub fn main(log: &str, a: EvalArgs) -> ExitCode {
    init_tracing(log);
    exit_code("taxel calibrator eval", eval(a))
}

fn eval(a: EvalArgs) -> Result<(), Failure> {
    for l in &a.levels {
        if !(l.is_finite() && *l > 0.0) {
            return Err(Failure::config(anyhow::anyhow!(
                "--levels must be positive forces in N, got {l}"
            )));
        }
    }
    if let Some(c) = a.curvature_m1 {
        if !(c.is_finite() && (0.0..=1000.0).contains(&c)) {
            return Err(Failure::config(anyhow::anyhow!(
                "--curvature-m1 must be 0..=1000 1/m, got {c}"
            )));
        }
    }
    let model = match &a.curvature_model {
        Some(p) => Some(taxel_estimator::model::CurvatureModel::load(p).config_err()?),
        None => None,
    };
    let curve = Calibration::load(&a.calibration).config_err()?;
    let flat = match &a.flat {
        Some(p) => Some(Calibration::load(p).config_err()?),
        None => None,
    };
    let rec = Recording::read(&a.recording).config_err()?;
    let g = rec.geometry(a.rows, a.cols).config_err()?;
    let curvature = match (&model, a.curvature_m1) {
        (Some(m), _) => {
            let p = a
                .curvature_model
                .as_ref()
                .map_or(String::new(), |p| p.display().to_string());
            m.check_nodes(&p, rec.n_nodes).config_err()?;
            Curvature::Model(m)
        }
        (None, Some(c)) if a.continues_calibration => Curvature::Continuing(c),
        (None, Some(c)) => Curvature::Known(c),
        (None, None) => {
            return Err(Failure::config(anyhow::anyhow!(
                "give --curvature-model (predict the curvature) or --curvature-m1 (a known one)"
            )))
        }
    };
    let r = crate::protocol::evaluate_with(
        &rec,
        g,
        curvature,
        &curve,
        flat.as_ref(),
        &a.levels,
        a.headline,
    )
    .config_err()?;
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
        std::fs::write(&p, format!("{}\n", crate::protocol::json(&r)))
            .with_context(|| format!("{}", p.display()))
            .runtime_err()?;
        if !a.json {
            println!("figures and eval.json: {}", dir.display());
        }
    }
    if a.json {
        println!("{}", crate::protocol::json(&r));
        return Ok(());
    }
    print_eval(&a, &r);
    Ok(())
}

/// The human-readable report of `eval`.
fn print_eval(a: &EvalArgs, r: &crate::protocol::Report) {
    if r.curvature_given {
        println!(
            "{}: curvature given, {:.1} 1/m; scored from frame {}",
            a.recording.display(),
            r.curvature_pred_m1,
            r.estimate_at + 1
        );
    } else {
        println!(
            "{}: curvature predicted {:.1} +- {:.1} 1/m from the first {} frames",
            a.recording.display(),
            r.curvature_pred_m1,
            r.curvature_sd_m1,
            r.estimate_at + 1
        );
    }
    for b in &r.blocks {
        let head = if b.block == r.headline {
            " (headline)"
        } else {
            ""
        };
        println!(
            "\n{}{head}:",
            if b.block == Headline::Array {
                "whole array"
            } else {
                "central 2 x 2 block"
            }
        );
        println!("| level (N) | frames | flat MAE +- SD (N) | curvature-aware MAE +- SD (N) |");
        println!("|---:|---:|---:|---:|");
        for l in &b.levels {
            if l.n == 0 {
                println!("| {} | 0 | no window | no window |", l.target_n);
            } else if l.flat_mae_n.is_finite() {
                println!(
                    "| {} | {} | {:.2} +- {:.2} | {:.2} +- {:.2} |",
                    l.target_n, l.n, l.flat_mae_n, l.flat_sd_n, l.curve_mae_n, l.curve_sd_n
                );
            } else {
                println!(
                    "| {} | {} | - | {:.2} +- {:.2} |",
                    l.target_n, l.n, l.curve_mae_n, l.curve_sd_n
                );
            }
        }
        println!(
            "every frame from {OVERALL_MIN_N} N: MAE {:.3} N, relative {:.1} % over {} frames",
            b.overall.mae_n,
            100.0 * b.overall.rel_mae,
            b.overall.frames
        );
    }
}
