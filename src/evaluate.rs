//! `taxel evaluate`: reproductions of the paper's results on the simulator.

use std::path::PathBuf;
use std::process::ExitCode;

use taxel_runtime::process::init_tracing;

/// The shipped curvature model (trained on the dataset whose first sensor is build 1001).
const CURVATURE_MODEL: &[u8] = include_bytes!("../models/curvature-default.taxcrv");

#[derive(Debug, clap::Subcommand)]
pub enum Evaluate {
    /// The paper's Table I on simulated everyday objects: data, flat and curvature-aware
    /// calibrations, the table (Markdown) next to the paper's numbers, and plots.
    Table1 {
        /// Output directory.
        #[arg(long, default_value = "table1")]
        out: PathBuf,
        /// Seed of the calibration session and the object sessions.
        #[arg(long, default_value_t = 7)]
        seed: u64,
        /// Curvature model (default: the shipped one).
        #[arg(long)]
        curvature_model: Option<PathBuf>,
        /// Build seed of the simulated sensor (must be a sensor the curvature model knows).
        #[arg(long, default_value_t = 1001)]
        build_seed: u64,
    },
}

pub fn main(e: Evaluate) -> ExitCode {
    init_tracing("info");
    match run(e) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!(
                "taxel evaluate: error: {}",
                format!("{e:#}").replace('\n', " ")
            );
            ExitCode::from(2)
        }
    }
}

fn run(e: Evaluate) -> anyhow::Result<()> {
    let Evaluate::Table1 {
        out,
        seed,
        curvature_model,
        build_seed,
    } = e;
    let model = match &curvature_model {
        Some(p) => taxel_estimator::model::CurvatureModel::load(p)?,
        None => {
            taxel_estimator::model::CurvatureModel::from_bytes("shipped model", CURVATURE_MODEL)?
        }
    };
    let mut sensor = taxel_sim::presets::preset("paper-dataset")
        .ok_or_else(|| anyhow::anyhow!("missing preset"))?;
    sensor.spread.build_seed = Some(build_seed);
    let t0 = std::time::Instant::now();
    let t = taxel_calibrator::table1::run(&out, &model, &sensor, seed, |step| {
        eprintln!("table1: {step} ...");
    })?;
    println!("{}", t.markdown);
    println!("done in {:.1} s; files:", t0.elapsed().as_secs_f64());
    for f in &t.files {
        println!("  {}", f.display());
    }
    Ok(())
}
