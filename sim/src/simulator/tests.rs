//! Scenario-mode tests of the simulator.

use super::*;
use crate::scenario::Step;

fn quiet_model() -> SensorModel {
    let mut m = SensorModel::default();
    m.readout.noise_counts = 0.0;
    m
}

fn run(model: &SensorModel, scenario: &Scenario, frames: usize) -> Vec<(FrameTruth, Vec<f32>)> {
    let mut sim = Simulator::new(model, scenario).expect("valid");
    let mut out = vec![0.0f32; model.rows * model.cols];
    (0..frames)
        .map(|_| {
            let t = sim.step(&mut out);
            (t, out.clone())
        })
        .collect()
}

fn ramp(curvature: f64) -> Scenario {
    Scenario {
        rate_hz: 100.0,
        mounting: Mounting {
            curvature_m1: curvature,
            ..Mounting::default()
        },
        steps: vec![Step::Ramp {
            force_n: 20.0,
            duration_s: 10.0,
        }],
        ..Scenario::default()
    }
}

fn block_sum(frame: &[f32]) -> f64 {
    [5, 6, 9, 10].iter().map(|&k| frame[k] as f64).sum()
}

#[test]
fn response_is_monotone_in_force() {
    let frames = run(&quiet_model(), &ramp(0.0), 1000);
    let mut prev = 0.0;
    for (truth, f) in &frames {
        let s = block_sum(f);
        assert!(s >= prev, "block sum fell at {} N", truth.force_n);
        prev = s;
    }
    let first = block_sum(&frames[0].1);
    assert!(
        prev - first > 600.0,
        "20 N should move the block by hundreds of counts"
    );
}

#[test]
fn sensitivity_falls_with_curvature() {
    let mut deltas = Vec::new();
    for k in [0.0, 40.0, 80.0] {
        let frames = run(&quiet_model(), &ramp(k), 501);
        deltas.push(block_sum(&frames[500].1) - block_sum(&frames[0].1));
    }
    assert!(deltas[0] > deltas[1] && deltas[1] > deltas[2], "{deltas:?}");
    assert!(
        deltas[2] < 0.8 * deltas[0],
        "loss at 80 1/m too small: {deltas:?}"
    );
}

#[test]
fn baseline_pattern_depends_on_curvature_and_orientation() {
    let mut m = quiet_model();
    m.material.g0_us = 200.0; // a high-baseline build makes the pattern easy to read
    let sim = Simulator::new(&m, &Scenario::default()).expect("valid");
    let flat = sim.baseline_factors(&Mounting::default());
    assert!(flat.iter().all(|f| (f - 1.0).abs() < 1e-12));
    let bent = Mounting {
        curvature_m1: 60.0,
        ..Mounting::default()
    };
    let a = sim.baseline_factors(&bent);
    let b = sim.baseline_factors(&Mounting {
        rotation_deg: 90,
        ..bent
    });
    let c = sim.baseline_factors(&Mounting {
        flipped: true,
        ..bent
    });
    assert!(
        a.iter().any(|f| (f - 1.0).abs() > 0.1),
        "curvature moves the baseline"
    );
    assert_ne!(a, b, "rotation changes the pattern");
    assert_ne!(a, c, "flipping changes the pattern");
    // Along the bend the pattern varies across columns for rotation 0, rows for 90.
    assert!((a[0] - a[4]).abs() < 1e-12 && (a[0] - a[1]).abs() > 1e-3);
    assert!((b[0] - b[1]).abs() < 1e-12 && (b[0] - b[4]).abs() > 1e-3);
    // And it reaches the ADC codes.
    let mut s = ramp(0.0);
    s.steps.clear();
    let flat_codes = run(&m, &s, 1)[0].1.clone();
    s.mounting.curvature_m1 = 60.0;
    let bent_codes = run(&m, &s, 1)[0].1.clone();
    assert_ne!(flat_codes, bent_codes);
}

#[test]
fn same_seed_same_frames_other_seed_other_frames() {
    let m = SensorModel {
        creep: Some(Default::default()),
        hysteresis: Some(Default::default()),
        thermal_drift: Some(Default::default()),
        crosstalk: Some(Default::default()),
        scan_skew: Some(Default::default()),
        ..SensorModel::default()
    };
    let s = Scenario::demo(30.0, 5);
    let a = run(&m, &s, 800);
    let b = run(&m, &s, 800);
    assert_eq!(a, b);
    let s2 = Scenario::demo(30.0, 6);
    let c = run(&m, &s2, 800);
    assert_ne!(a, c);
}

#[test]
fn every_geometry_from_1x1_to_32x32_runs() {
    for (rows, cols) in [(1, 1), (1, 8), (3, 5), (32, 32)] {
        let m = SensorModel {
            rows,
            cols,
            ..quiet_model()
        };
        let frames = run(&m, &ramp(20.0), 300);
        let (truth, last) = &frames[299];
        assert_eq!(last.len(), rows * cols);
        let first = &frames[0].1;
        let moved: f32 = last.iter().zip(first).map(|(a, b)| a - b).sum();
        assert!(
            moved > 10.0,
            "{rows}x{cols}: {moved} counts at {} N",
            truth.force_n
        );
    }
}

#[test]
fn rail_clipping_pins_the_top_code() {
    let mut m = quiet_model();
    m.material.r_floor_ohm = 0.0;
    m.material.gain_us_per_n = 3000.0;
    let frames = run(&m, &ramp(0.0), 1000);
    let last = &frames[999].1;
    assert_eq!(last[5], 1023.0);
    assert!(last[0] < 200.0, "unloaded nodes stay low");
}

#[test]
fn crosstalk_row_part_lowers_pressed_nodes() {
    let mut plain = quiet_model();
    plain.material.r_floor_ohm = 0.0;
    let mut xt = plain.clone();
    xt.crosstalk = Some(crate::model::Crosstalk {
        rs_ohm: 120.0,
        vos_max_v: 0.0,
    });
    let a = run(&plain, &ramp(0.0), 1000);
    let b = run(&xt, &ramp(0.0), 1000);
    assert!(
        b[999].1[5] < a[999].1[5],
        "{} vs {}",
        b[999].1[5],
        a[999].1[5]
    );
}

#[test]
fn creep_grows_under_constant_load() {
    let mut m = quiet_model();
    m.creep = Some(crate::model::Creep {
        amplitudes: vec![0.2],
        tau_s: vec![2.0],
    });
    let s = Scenario {
        rate_hz: 100.0,
        steps: vec![
            Step::Ramp {
                force_n: 8.0,
                duration_s: 0.1,
            },
            Step::Rest { duration_s: 10.0 },
        ],
        ..Scenario::default()
    };
    let frames = run(&m, &s, 1000);
    assert!(block_sum(&frames[999].1) > block_sum(&frames[20].1) + 20.0);
}
