//! The zoo presets by simulation: (a) no-load readings well inside the ADC range at 0-100 1/m,
//! (b) a 20 N press on the central 2 x 2 block does not saturate, (c) 1-20 N give clearly
//! distinguishable readings, (d) 0 -> 80 1/m loses 20-50 % of the response at 10 N.

use taxel_sim::{presets, Mounting, Scenario, SensorModel, Simulator, Step};

const FORCES: [f64; 5] = [1.0, 2.0, 5.0, 10.0, 20.0];
const RATE: f64 = 100.0;
const REST_S: f64 = 1.5;
const HOLD_S: f64 = 2.0;

/// What one mounting gave.
#[derive(Debug)]
struct Mount {
    /// Mean no-load reading of every node over the first rest.
    no_load: Vec<f64>,
    /// Per force: mean of the central block over the last second of the hold, and over the
    /// second before the press (the local no-load level).
    block: Vec<(f64, f64)>,
    /// Mean reading of every node over the last second of the 20 N hold.
    at_20n: Vec<f64>,
}

impl Mount {
    /// Size of the response (the readout may fall with force) at each force.
    fn response(&self) -> Vec<f64> {
        self.block.iter().map(|(l, b)| (l - b).abs()).collect()
    }
}

fn mount(
    model: &SensorModel,
    curvature_m1: f64,
    rotation_deg: u32,
    flipped: bool,
    seed: u64,
) -> Mount {
    let mut steps = vec![Step::Rest { duration_s: REST_S }];
    for f in FORCES {
        steps.push(Step::Press {
            force_n: f,
            ramp_s: 0.5,
            hold_s: HOLD_S,
            release_s: 0.3,
            rest_s: REST_S,
        });
    }
    let s = Scenario {
        rate_hz: RATE,
        seed,
        mounting: Mounting {
            curvature_m1,
            rotation_deg,
            flipped,
        },
        steps,
        ..Scenario::default()
    };
    let mut sim = Simulator::new(model, &s).expect("valid");
    let n = model.rows * model.cols;
    let mut out = vec![0.0f32; n];
    let total = sim.frames_in_scenario().expect("finite");
    let frames: Vec<Vec<f64>> = (0..total)
        .map(|_| {
            sim.step(&mut out);
            out.iter().map(|v| *v as f64).collect()
        })
        .collect();
    let at = |t: f64| (t * RATE).round() as usize;
    let mean = |from: f64, to: f64, k: usize| {
        let (a, b) = (at(from), at(to));
        frames[a..b].iter().map(|f| f[k]).sum::<f64>() / (b - a) as f64
    };
    let block = |from: f64, to: f64| {
        [5, 6, 9, 10]
            .iter()
            .map(|&k| mean(from, to, k))
            .sum::<f64>()
            / 4.0
    };
    let no_load = (0..n).map(|k| mean(0.2, REST_S, k)).collect();
    let press_s = 0.5 + HOLD_S + 0.3 + REST_S;
    let mut blocks = Vec::new();
    let mut at_20n = Vec::new();
    for (i, _) in FORCES.iter().enumerate() {
        let start = REST_S + i as f64 * press_s;
        let hold_end = start + 0.5 + HOLD_S;
        blocks.push((block(hold_end - 1.0, hold_end), block(start - 1.0, start)));
        if i == FORCES.len() - 1 {
            at_20n = (0..n).map(|k| mean(hold_end - 1.0, hold_end, k)).collect();
        }
    }
    Mount {
        no_load,
        block: blocks,
        at_20n,
    }
}

/// One reading's noise (counts): white plus wander.
fn frame_noise(m: &SensorModel) -> f64 {
    let w = m.noise.wander.as_ref().map_or(0.0, |w| w.sd_counts);
    let w2 = m.noise.second_wander.as_ref().map_or(0.0, |w| w.sd_counts);
    (m.readout.noise_counts.powi(2) + w * w + w2 * w2).sqrt()
}

/// Checks (a)-(d) on a preset; returns the 10 N block readings and responses at 0 and 80 1/m.
fn check(name: &str) -> [(f64, f64); 2] {
    let m = presets::preset(name).expect("known");
    let full = m.readout.max_code();
    let noise = frame_noise(&m);
    let mut d = [(0.0, 0.0); 2];
    for seed in [1, 2] {
        // (a) no load, at any curvature and orientation.
        for (c, rot, flip) in [
            (0.0, 0, false),
            (25.0, 90, true),
            (50.0, 180, false),
            (75.0, 270, true),
            (100.0, 0, false),
            (100.0, 90, true),
        ] {
            let r = mount(&m, c, rot, flip, seed);
            for v in &r.no_load {
                assert!(
                    *v > 0.05 * full && *v < 0.95 * full,
                    "{name} (a): no-load {v} of {full} at {c} 1/m"
                );
            }
            // (b) 20 N on the central block saturates nothing.
            for v in &r.at_20n {
                assert!(
                    *v > 0.02 * full && *v < 0.98 * full,
                    "{name} (b): {v} of {full} at 20 N, {c} 1/m"
                );
            }
        }
        let flat = mount(&m, 0.0, 0, false, seed);
        let bent = mount(&m, 80.0, 0, false, seed);
        // (c) distinguishable: each force step moves the block well beyond one reading's noise.
        for r in [&flat, &bent] {
            let resp = r.response();
            for w in resp.windows(2) {
                assert!(
                    w[1] - w[0] > 4.0 * noise,
                    "{name} (c): responses {resp:?}, noise {noise}"
                );
            }
            assert!(resp[0] > 4.0 * noise, "{name} (c): 1 N {resp:?}");
        }
        // (d) the curvature loss at 10 N.
        let (r0, r80) = (flat.response()[3], bent.response()[3]);
        let loss = 1.0 - r80 / r0;
        assert!(
            (0.2..=0.5).contains(&loss),
            "{name} (d): loss {loss} ({r0} -> {r80})"
        );
        if seed == 1 {
            d = [(flat.block[3].0, r0), (bent.block[3].0, r80)];
        }
    }
    d
}

#[test]
fn zoo_log_stays_in_range_and_loses_a_fifth_to_a_half_when_bent() {
    check_and_print("zoo-log");
}

#[test]
fn zoo_sat_stays_in_range_and_loses_a_fifth_to_a_half_when_bent() {
    check_and_print("zoo-sat");
}

#[test]
fn zoo_pow_stays_in_range_and_loses_a_fifth_to_a_half_when_bent() {
    check_and_print("zoo-pow");
}

#[test]
fn zoo_amp_stays_in_range_and_loses_a_fifth_to_a_half_when_bent() {
    check_and_print("zoo-amp");
}

/// Checks a preset and prints what it reads (seen with `--nocapture`).
fn check_and_print(name: &str) {
    let [(b0, r0), (b80, r80)] = check(name);
    println!(
        "{name} (d): 10 N block {b0:.1} -> {b80:.1}, response {r0:.1} -> {r80:.1}, loss {:.1} %",
        100.0 * (1.0 - r80 / r0)
    );
    let m = presets::preset(name).expect("known");
    for c in [0.0, 80.0, 100.0] {
        let r = mount(&m, c, 0, false, 1);
        let nl: Vec<String> = r.no_load.iter().map(|v| format!("{v:.0}")).collect();
        let resp: Vec<String> = r.response().iter().map(|v| format!("{v:.1}")).collect();
        let hi = r.at_20n.iter().fold(f64::MIN, |a, v| a.max(*v));
        let lo = r.at_20n.iter().fold(f64::MAX, |a, v| a.min(*v));
        println!(
                "{name} C={c}: no-load [{}], 10 N block {:.1}, responses [{}], 20 N nodes {lo:.0}..{hi:.0}",
                nl.join(" "),
                r.block[3].0,
                resp.join(" ")
            );
    }
}
