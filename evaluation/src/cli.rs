//! `taxel evaluate`: the paper's Table I on the simulator (`table1`), the generalisation check
//! on every simulator family, world B and the real recordings (`worlds`), and the dynamic
//! calibration on the same worlds (`dynamics`).

use std::path::PathBuf;
use std::process::ExitCode;

use taxel_runtime::process::{exit_code, init_tracing, Failure, ResultExt};

/// The shipped curvature model (trained on the dataset whose first sensor is build 1001).
const CURVATURE_MODEL: &[u8] = include_bytes!("../../models/curvature-default.taxcrv");

#[derive(Debug, clap::Subcommand)]
pub enum Evaluate {
    /// The paper's Table I on simulated everyday objects: data, flat and curvature-aware
    /// calibrations, the table (Markdown) next to the paper's numbers, and plots.
    Table1 {
        /// Output directory (default: a fresh directory under the system temp dir; the files
        /// written are listed at the end).
        #[arg(long)]
        out: Option<PathBuf>,
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
    /// The generalisation check: the whole offline pipeline (curvature model trained,
    /// calibrations fitted, objects evaluated) on every simulator family with hold-out seeds,
    /// on world B and on the real recordings; every number per family (worlds.md, worlds.json).
    Worlds {
        /// Output directory (default: a fresh directory under the system temp dir, printed).
        #[arg(long)]
        out: Option<PathBuf>,
        #[command(flatten)]
        worlds: WorldSet,
        /// Training epochs of the curvature MLP (the paper: 500).
        #[arg(long, default_value_t = 500)]
        epochs: usize,
        /// Print exactly one JSON object on stdout instead of the Markdown table.
        #[arg(long)]
        json: bool,
    },
    /// Dynamic calibration (creep, hysteresis) on every simulator family with hold-out seeds and
    /// on world B: the paper's objects held 15 s at 2-8 N in a warming hand, calibrated with and
    /// without the dynamic terms fitted on one characterisation recording (dynamics.md).
    Dynamics {
        /// Output directory (default: a fresh directory under the system temp dir, printed).
        #[arg(long)]
        out: Option<PathBuf>,
        #[command(flatten)]
        worlds: WorldSet,
    },
}

/// Which worlds `worlds` and `dynamics` run on.
#[derive(Debug, clap::Args)]
pub struct WorldSet {
    /// Simulator families (taxel-sim presets), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = crate::worlds::FAMILIES.map(String::from))]
    families: Vec<String>,
    /// Seeds of each family (default: the hold-out seeds, never tuned on), comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = crate::worlds::HOLDOUT_SEEDS)]
    seeds: Vec<u64>,
    /// Folder holding worldb/ and real/ (skipped with a note when absent).
    #[arg(long, default_value = "../shared/data")]
    shared: PathBuf,
}

impl WorldSet {
    fn options(self, out: PathBuf, epochs: usize) -> crate::worlds::Options {
        crate::worlds::Options {
            out,
            families: self.families,
            seeds: self.seeds,
            shared: Some(self.shared),
            epochs,
        }
    }
}

pub fn main(e: Evaluate) -> ExitCode {
    init_tracing("info");
    exit_code("taxel evaluate", run(e))
}

/// The output directory: the one named, else a fresh `taxel-<what>-<pid>` under the system temp
/// dir (said on stderr).
fn out_dir(named: Option<PathBuf>, what: &str) -> PathBuf {
    named.unwrap_or_else(|| {
        let d = std::env::temp_dir().join(format!("taxel-{what}-{}", std::process::id()));
        eprintln!(
            "taxel evaluate {what}: writing to {} (--out DIR to choose)",
            d.display()
        );
        d
    })
}

fn run(e: Evaluate) -> Result<(), Failure> {
    match e {
        Evaluate::Table1 {
            out,
            seed,
            curvature_model,
            build_seed,
        } => table1(out_dir(out, "table1"), seed, curvature_model, build_seed),
        Evaluate::Worlds {
            out,
            worlds: w,
            epochs,
            json,
        } => worlds(w.options(out_dir(out, "worlds"), epochs), json),
        Evaluate::Dynamics { out, worlds: w } => dynamics(w.options(out_dir(out, "dynamics"), 1)),
    }
}

fn dynamics(o: crate::worlds::Options) -> Result<(), Failure> {
    use crate::worlds;
    let mut bar = taxel_runtime::progress::Progress::new("dynamics", 1);
    let t0 = std::time::Instant::now();
    let s = worlds::run_dynamics(&o, |done, total, what| {
        bar.set_total(total as u64);
        bar.set(done as u64);
        tracing::info!("dynamics: {what} ({:.0} s)", t0.elapsed().as_secs_f64());
    })
    // As for worlds: bad input and failure alike exit 2, as before.
    .config_err()?;
    bar.finish();
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    let md = worlds::dynamics_markdown(&s, &command);
    let js = worlds::dynamics_json(&s);
    for (name, text) in [("dynamics.md", &md), ("dynamics.json", &js)] {
        let p = o.out.join(name);
        std::fs::write(&p, format!("{text}\n"))
            .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
            .runtime_err()?;
    }
    println!("{md}");
    println!(
        "done in {:.0} s; report: {}",
        t0.elapsed().as_secs_f64(),
        o.out.join("dynamics.md").display()
    );
    Ok(())
}

fn worlds(o: crate::worlds::Options, json: bool) -> Result<(), Failure> {
    use crate::worlds;
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    let mut bar = taxel_runtime::progress::Progress::new("worlds", 1);
    let t0 = std::time::Instant::now();
    let s = worlds::run(&o, |done, total, what| {
        bar.set_total(total as u64);
        bar.set(done as u64);
        tracing::info!("worlds: {what} ({:.0} s)", t0.elapsed().as_secs_f64());
    })
    // The offline evaluation does not tell bad input from failure yet: exit 2 for both, as
    // before.
    .config_err()?;
    bar.finish();
    let md = worlds::markdown(&s, &command);
    let js = worlds::json(&s);
    for (name, text) in [("worlds.md", &md), ("worlds.json", &js)] {
        let p = o.out.join(name);
        std::fs::write(&p, format!("{text}\n"))
            .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
            .runtime_err()?;
    }
    if json {
        println!("{js}");
    } else {
        println!("{md}");
        println!(
            "done in {:.0} s; report: {}",
            t0.elapsed().as_secs_f64(),
            o.out.join("worlds.md").display()
        );
    }
    Ok(())
}

fn table1(
    out: PathBuf,
    seed: u64,
    curvature_model: Option<PathBuf>,
    build_seed: u64,
) -> Result<(), Failure> {
    let model = match &curvature_model {
        Some(p) => taxel_estimator::model::CurvatureModel::load(p).config_err()?,
        None => {
            taxel_estimator::model::CurvatureModel::from_bytes("shipped model", CURVATURE_MODEL)
                .runtime_err()?
        }
    };
    let mut sensor = taxel_sim::presets::preset("paper-dataset")
        .ok_or_else(|| anyhow::anyhow!("missing preset"))
        .runtime_err()?;
    sensor.spread.build_seed = Some(build_seed);
    let t0 = std::time::Instant::now();
    let t = crate::table1::run(&out, &model, &sensor, seed, |step| {
        eprintln!("table1: {step} ...");
    })
    // As for worlds: bad input and failure alike exit 2, as before.
    .config_err()?;
    println!("{}", t.markdown);
    println!("done in {:.1} s; files:", t0.elapsed().as_secs_f64());
    for f in &t.files {
        println!("  {}", f.display());
    }
    Ok(())
}
