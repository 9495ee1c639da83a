//! The generalisation check behind `taxel evaluate worlds`: the whole offline pipeline run the
//! way a new user runs it on a sensor taxel has never seen (a curvature model trained on the
//! world's no-load baselines, flat and curvature-aware calibrations fitted on its fixture
//! presses, the paper's five objects evaluated with `taxel calibrator eval`'s protocol), on
//!
//! - every family of the simulator's zoo ([`FAMILIES`]: different static laws, curvature
//!   sensitivity and baseline forms, contact footprints, noise colours, readouts and ADC
//!   widths), each with hold-out seeds ([`HOLDOUT_SEEDS`]) that no constant was tuned on;
//! - world B (`../shared/data/worldb`, an external world taxel did not write), when present;
//! - the real recordings (`../shared/data/real`), when present: each file's first 60 % fits
//!   a flat calibration, its last 40 % is predicted.
//!
//! Every number is reported per family, world and file; nothing is averaged across worlds.

pub mod dynamic;
pub mod dynamic_real;
mod dynamic_report;
mod external;
mod report;
mod zoo;

use std::path::{Path, PathBuf};

pub use dynamic_report::{dynamics_json, dynamics_markdown};
pub use report::{json, markdown};

/// The simulator families run by default (taxel-sim presets).
pub const FAMILIES: [&str; 5] = ["paper-dataset", "alt", "zoo-log", "zoo-sat", "zoo-pow"];
/// Hold-out seeds: never used while choosing a method or a constant.
pub const HOLDOUT_SEEDS: [u64; 2] = [101, 102];
/// Share of each real recording (by time) that fits the calibration; the rest is predicted.
pub const REAL_TRAIN_SHARE: f64 = 0.6;

/// What to run.
#[derive(Debug, Clone)]
pub struct Options {
    /// Output directory (one folder per family and seed, per world, per real file).
    pub out: PathBuf,
    /// Simulator families (preset names; empty names are ignored, so none runs only the
    /// external worlds).
    pub families: Vec<String>,
    pub seeds: Vec<u64>,
    /// The folder holding `worldb/` and `real/` (skipped with a note when absent).
    pub shared: Option<PathBuf>,
    /// Training epochs of the curvature MLP (the paper: 500).
    pub epochs: usize,
}

/// One world's objects: the paper's Table I averages and the curvature model's accuracy.
#[derive(Debug, Clone)]
pub struct ObjectsRow {
    pub world: String,
    pub seed: Option<u64>,
    /// Curvature model on held-out baselines (0-80 1/m): R^2 and MAE (1/m).
    pub curvature_r2: f64,
    pub curvature_mae_m1: f64,
    /// Mean absolute force error over the scored object x level cells (N).
    pub flat_n: f64,
    pub curve_n: f64,
    pub worst_n: f64,
    /// The same for the central 2 x 2 block (the paper's indenter): flat, curvature-aware,
    /// worst cell (N).
    pub center: (f64, f64, f64),
    /// What the fit decided: readout and the array's form.
    pub readout: String,
    pub form: String,
}

impl ObjectsRow {
    /// The row of one world: its curvature model's metrics, the object reports and the
    /// curvature-aware calibration the fit wrote.
    pub fn of(
        world: &str,
        seed: Option<u64>,
        curvature: &taxel_estimator::model::Metrics,
        reports: &[(String, f64, crate::protocol::Report)],
        cal: &taxel_calibrator::calibration::Calibration,
    ) -> ObjectsRow {
        let (flat_n, curve_n, worst_n) = crate::table1::averages(reports);
        ObjectsRow {
            world: world.to_string(),
            seed,
            curvature_r2: curvature.r2,
            curvature_mae_m1: curvature.mae_m1,
            flat_n,
            curve_n,
            worst_n,
            center: crate::table1::block_averages(reports, crate::protocol::Headline::Center),
            readout: cal.readout.to_string(),
            form: cal.array.model.name().to_string(),
        }
    }
}

/// One real recording: a flat calibration on the first 60 %, the last 40 % predicted.
#[derive(Debug, Clone)]
pub struct RealRow {
    pub file: String,
    /// The readout and form decided, or the fit's refusal.
    pub outcome: Result<(String, String), String>,
    /// Mean of |error| / reference and mean absolute error over test frames with F >= 0.5 N.
    pub rel_mae: f64,
    pub mae_n: f64,
    pub frames: usize,
}

/// Everything the run measured.
#[derive(Debug, Clone, Default)]
pub struct Summary {
    pub objects: Vec<ObjectsRow>,
    pub real: Vec<RealRow>,
    /// Worlds not run, and why.
    pub skipped: Vec<String>,
}

/// Runs every world; `progress(done, total, what)` after each step.
pub fn run(o: &Options, mut progress: impl FnMut(usize, usize, &str)) -> anyhow::Result<Summary> {
    anyhow::ensure!(
        (1..=100_000).contains(&o.epochs),
        "--epochs must be 1..=100000, got {}",
        o.epochs
    );
    std::fs::create_dir_all(&o.out).map_err(|e| anyhow::anyhow!("{}: {e}", o.out.display()))?;
    let worldb = o.shared.as_ref().map(|s| s.join("worldb"));
    let real = o.shared.as_ref().map(|s| s.join("real"));
    let families: Vec<&String> = o.families.iter().filter(|f| !f.trim().is_empty()).collect();
    let total = families.len() * o.seeds.len() + 2;
    let mut done = 0;
    let mut s = Summary::default();
    for f in families {
        for &seed in &o.seeds {
            progress(done, total, &format!("{f} seed {seed}"));
            s.objects.push(zoo::family(&o.out, f, seed, o.epochs)?);
            done += 1;
        }
    }
    progress(done, total, "world B");
    match worldb.as_deref().filter(|d| d.is_dir()) {
        Some(d) => s
            .objects
            .push(external::world_b(d, &o.out.join("worldb"), o.epochs)?),
        None => s.skipped.push(absent("world B", worldb.as_deref())),
    }
    done += 1;
    progress(done, total, "real recordings");
    match real.as_deref().filter(|d| d.is_dir()) {
        Some(d) => s.real = external::real(d, &o.out.join("real"))?,
        None => s.skipped.push(absent("real recordings", real.as_deref())),
    }
    progress(total, total, "done");
    Ok(s)
}

fn absent(what: &str, d: Option<&Path>) -> String {
    match d {
        Some(d) => format!("{what}: skipped, {} not found", d.display()),
        None => format!("{what}: skipped, no --shared folder"),
    }
}

/// What `taxel evaluate dynamics` measured.
#[derive(Debug, Clone, Default)]
pub struct DynamicSummary {
    pub rows: Vec<dynamic::DynamicRow>,
    pub real: Vec<dynamic_real::RealDynamicRow>,
    /// Worlds not run, and why.
    pub skipped: Vec<String>,
}

/// Runs the dynamic protocol on every family and seed and on world B; `progress(done, total,
/// what)` after each step.
pub fn run_dynamics(
    o: &Options,
    mut progress: impl FnMut(usize, usize, &str),
) -> anyhow::Result<DynamicSummary> {
    std::fs::create_dir_all(&o.out).map_err(|e| anyhow::anyhow!("{}: {e}", o.out.display()))?;
    let families: Vec<&String> = o.families.iter().filter(|f| !f.trim().is_empty()).collect();
    let total = families.len() * o.seeds.len() + 2;
    let mut done = 0;
    let mut s = DynamicSummary::default();
    for f in families {
        let index = FAMILIES.iter().position(|x| x == f).unwrap_or(0);
        for &seed in &o.seeds {
            progress(done, total, &format!("{f} seed {seed}"));
            s.rows.push(dynamic::family(&o.out, f, index, seed)?);
            done += 1;
        }
    }
    progress(done, total, "world B");
    let worldb = o.shared.as_ref().map(|s| s.join("worldb"));
    match worldb.as_deref().filter(|d| d.is_dir()) {
        Some(d) => s.rows.push(dynamic::world_b(d, &o.out.join("worldb"))?),
        None => s.skipped.push(absent("world B", worldb.as_deref())),
    }
    progress(done + 1, total, "real recordings");
    let real = o.shared.as_ref().map(|s| s.join("real"));
    match real.as_deref().filter(|d| d.is_dir()) {
        Some(d) => {
            s.real = dynamic_real::tams(d)?;
            s.real.extend(dynamic_real::lupasic(d)?);
        }
        None => s.skipped.push(absent("real recordings", real.as_deref())),
    }
    progress(total, total, "done");
    Ok(s)
}
