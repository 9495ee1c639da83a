//! Paper-like curvature datasets from the simulator: `sensors` builds (one seed each) x ten
//! fixtures from 0 to 80 1/m x ten baseline measurements, each measurement a fresh mounting with
//! a random rotation and flip and realistic mounting scatter, recorded as 100 no-load frames.
//! One recording CSV per sensor, with `curvature_m1` and `trial`.

use std::path::{Path, PathBuf};

use taxel_formats::csv::{Columns, Row};
use taxel_formats::RecordingWriter;
use taxel_sim::rng::Rng;
use taxel_sim::{Mounting, Scenario, Simulator, Step};

/// Which simulated world to draw from (a sensor-model preset of taxel-sim).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum World {
    /// The `paper-dataset` preset: build-to-build spread and mounting scatter.
    Paper,
    /// The `alt` preset, for checking that a training method generalizes; never for tuning.
    Alt,
}

impl World {
    pub fn preset(self) -> &'static str {
        match self {
            World::Paper => "paper-dataset",
            World::Alt => "alt",
        }
    }
}

/// Build seed of sensor `index` (0-based) of a dataset drawn with `seed`: the identity of
/// that simulated sensor, for the publisher's `--build-seed`.
pub fn build_seed(seed: u64, index: usize) -> u64 {
    seed.wrapping_mul(1000).wrapping_add(index as u64 + 1)
}

/// Dataset shape.
#[derive(Debug, Clone)]
pub struct Spec {
    /// The taxel-sim preset drawn from (see [`World::preset`]; any name of
    /// `taxel_sim::presets::NAMES`).
    pub preset: String,
    pub sensors: usize,
    pub curvatures_m1: Vec<f64>,
    pub baselines: usize,
    pub frames: usize,
    pub rate_hz: f64,
    /// Seed of the sensors (builds).
    pub seed: u64,
    /// Measurement session: another session measures the same sensors again with new
    /// mountings and noise (held-out data of the same sensors).
    pub session: u64,
}

impl Spec {
    /// The paper's shape: 3 sensors x 10 fixtures (0-80 1/m) x 10 baselines of 100 frames.
    pub fn paper(world: World, seed: u64) -> Spec {
        Spec {
            preset: world.preset().to_string(),
            sensors: 3,
            curvatures_m1: (0..10).map(|i| 80.0 * i as f64 / 9.0).collect(),
            baselines: 10,
            frames: 100,
            rate_hz: 100.0,
            seed,
            session: 0,
        }
    }
}

/// Writes one CSV per sensor into `dir`; returns their paths.
pub fn generate(
    spec: &Spec,
    dir: &Path,
    mut progress: impl FnMut(usize, usize),
) -> anyhow::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir)?;
    let mut model = taxel_sim::presets::preset(&spec.preset)
        .ok_or_else(|| anyhow::anyhow!("unknown sensor-model preset {:?}", spec.preset))?;
    let n = model.rows * model.cols;
    let mut paths = Vec::new();
    let per_sensor = spec.curvatures_m1.len() * spec.baselines;
    for s in 0..spec.sensors {
        let build = build_seed(spec.seed, s);
        model.spread.build_seed = Some(build);
        let seed = build.wrapping_add(spec.session.wrapping_mul(7919));
        let mut rng = Rng::new(seed, 501);
        let mut mounts: Vec<Mounting> = Vec::with_capacity(per_sensor);
        for &c in &spec.curvatures_m1 {
            for _ in 0..spec.baselines {
                mounts.push(Mounting {
                    curvature_m1: c,
                    rotation_deg: 90 * (rng.next_u64() % 4) as u32,
                    flipped: rng.next_u64() % 2 == 1,
                });
            }
        }
        for i in (1..mounts.len()).rev() {
            let j = (rng.next_u64() % (i as u64 + 1)) as usize;
            mounts.swap(i, j);
        }
        let rest = spec.frames as f64 / spec.rate_hz;
        let steps: Vec<Step> = mounts[1..]
            .iter()
            .map(|m| Step::Mount {
                curvature_m1: m.curvature_m1,
                rotation_deg: m.rotation_deg,
                flipped: m.flipped,
                rest_s: rest,
            })
            .collect();
        let scenario = Scenario {
            name: format!("curvature-dataset-{s}"),
            rate_hz: spec.rate_hz,
            seed,
            mounting: mounts[0],
            steps: std::iter::once(Step::Rest { duration_s: rest })
                .chain(steps)
                .collect(),
            ..Scenario::default()
        };
        let mut sim = Simulator::new(&model, &scenario)?;
        let path = dir.join(format!("sensor{s}.csv.gz"));
        let cols = Columns {
            curvature_m1: true,
            trial: true,
            ..Columns::default()
        };
        let mut w = RecordingWriter::create(&path, n, cols)?;
        let mut out = vec![0f32; n];
        let mut nodes = vec![0f64; n];
        for _ in 0..per_sensor * spec.frames {
            let t = sim.step(&mut out);
            for (d, v) in nodes.iter_mut().zip(&out) {
                *d = *v as f64;
            }
            w.write_row(&Row {
                t_s: t.t_s,
                nodes: &nodes,
                curvature_m1: t.curvature_m1,
                trial: t.trial as i64,
                ..Row::default()
            })?;
        }
        w.finish()?;
        paths.push(path);
        progress(s + 1, spec.sensors);
    }
    Ok(paths)
}
