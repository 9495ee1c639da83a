//! Driven-mode and readout tests of the simulator.

use super::*;
use crate::model::{Hysteresis, NodeFactors};

#[test]
fn driven_mode_follows_the_given_inputs_and_node_factors() {
    let mut m = SensorModel::default();
    m.readout.noise_counts = 0.0;
    m.nodes = Some(NodeFactors {
        g0: vec![1.0; 16],
        gain: (0..16).map(|k| if k == 5 { 1.0 } else { 0.0 }).collect(),
        load_share: None,
    });
    let mut sim = Simulator::new(&m, &Scenario::default()).expect("valid");
    let mut out = vec![0.0f32; 16];
    sim.step_driven(0.0, 0.0, 0.0, 25.0, 0, &mut out);
    let rest = out.clone();
    sim.step_driven(0.01, 5.0, 0.0, 25.0, 0, &mut out);
    assert!(out[5] > rest[5] + 50.0, "{} vs {}", out[5], rest[5]);
    assert_eq!(out[0], rest[0], "a node with zero gain does not respond");
    // A node carrying half the load reads what the full node reads at half the force.
    let mut half = m.clone();
    if let Some(nf) = &mut half.nodes {
        nf.load_share = Some((0..16).map(|k| if k == 5 { 0.5 } else { 1.0 }).collect());
    }
    let mut sim_half = Simulator::new(&half, &Scenario::default()).expect("valid");
    let mut sim_full = Simulator::new(&m, &Scenario::default()).expect("valid");
    let mut out_full = vec![0.0f32; 16];
    sim_half.step_driven(0.0, 8.0, 0.0, 25.0, 0, &mut out);
    sim_full.step_driven(0.0, 4.0, 0.0, 25.0, 0, &mut out_full);
    assert_eq!(out[5], out_full[5]);
    // Curvature lowers the sensitivity in driven mode too.
    let mut bent = Simulator::new(&m, &Scenario::default()).expect("valid");
    bent.step_driven(0.0, 5.0, 80.0, 25.0, 0, &mut out);
    let mut flat = Simulator::new(&m, &Scenario::default()).expect("valid");
    let mut out2 = vec![0.0f32; 16];
    flat.step_driven(0.0, 5.0, 0.0, 25.0, 0, &mut out2);
    assert!(out[5] < out2[5]);
}

#[test]
fn resistance_and_divider_readouts_fall_with_force() {
    for kind in [ReadoutKind::Resistance, ReadoutKind::Divider] {
        let mut m = SensorModel {
            rows: 1,
            cols: 1,
            ..SensorModel::default()
        };
        m.readout.kind = kind;
        m.readout.noise_counts = 0.0;
        let mut sim = Simulator::new(&m, &Scenario::default()).expect("valid");
        let mut out = vec![0.0f32; 1];
        let mut prev = f32::INFINITY;
        for (i, f) in [0.0, 1.0, 5.0, 20.0].iter().enumerate() {
            sim.step_driven(i as f64 * 0.01, *f, 0.0, 25.0, 0, &mut out);
            assert!(out[0] < prev, "{kind:?}: {} at {f} N", out[0]);
            prev = out[0];
        }
    }
}

/// A one-node sensor with Bouc-Wen hysteresis (saturation 0.5 N, weight 0.3) with the given
/// input deadband and exponent, driven through `forces` at 100 Hz; returns the codes and
/// the states.
fn bouc_wen_run(deadband: f64, exponent: f64, forces: &[f64]) -> (Vec<f32>, Vec<f64>) {
    let mut m = SensorModel {
        rows: 1,
        cols: 1,
        ..SensorModel::default()
    };
    m.readout.noise_counts = 0.0;
    m.hysteresis = Some(Hysteresis {
        weight: 0.3,
        thresholds_n: Vec::new(),
        bouc_wen_saturation_n: Some(0.5),
        bouc_wen_exponent: exponent,
        input_deadband_n: deadband,
    });
    m.validate().expect("a valid Bouc-Wen model");
    let mut sim = Simulator::new(&m, &Scenario::default()).expect("valid");
    let mut out = vec![0.0f32; 1];
    let (mut codes, mut states) = (Vec::new(), Vec::new());
    for (i, f) in forces.iter().enumerate() {
        sim.step_driven(i as f64 * 0.01, *f, 0.0, 25.0, 0, &mut out);
        codes.push(out[0]);
        states.push(sim.hyst[0]);
    }
    (codes, states)
}

#[test]
fn bouc_wen_hysteresis_makes_a_loop_and_saturates() {
    // 0 -> 10 N -> 0 in steps of 0.1 N.
    let up: Vec<f64> = (0..=100).map(|i| i as f64 * 0.1).collect();
    let forces: Vec<f64> = up.iter().chain(up.iter().rev()).copied().collect();
    let (codes, states) = bouc_wen_run(0.0, 1.0, &forces);
    // At the top the state sits at its saturation; on the way down it has swung negative.
    assert!((states[100] - 0.5).abs() < 1e-3, "{}", states[100]);
    assert!(
        states[forces.len() - 1] < -0.4,
        "{}",
        states[forces.len() - 1]
    );
    // At 5 N the loading branch (state +0.5) reads above the unloading one (state -0.5).
    let (load, unload) = (codes[50], codes[forces.len() - 1 - 50]);
    assert!(load > unload + 2.0, "loading {load} vs unloading {unload}");
}

#[test]
fn a_larger_bouc_wen_exponent_sharpens_the_knee() {
    // From the virgin state, 0.5 N of load (one saturation): z = 0.5 (1 - e^-1) = 0.316
    // with n = 1; with n = 4 the state runs nearly linearly until close to saturation.
    let forces: Vec<f64> = (0..=50).map(|i| i as f64 * 0.01).collect();
    let (_, soft) = bouc_wen_run(0.0, 1.0, &forces);
    let (_, sharp) = bouc_wen_run(0.0, 4.0, &forces);
    assert!((soft[50] - 0.316).abs() < 0.01, "{}", soft[50]);
    assert!(sharp[50] > 0.4 && sharp[50] <= 0.5, "{}", sharp[50]);
}

#[test]
fn an_input_deadband_keeps_force_noise_from_ratcheting_the_bouc_wen_state() {
    // Load to 5 N, then hold with +-0.02 N of alternating load-cell noise.
    let mut forces: Vec<f64> = (0..=50).map(|i| i as f64 * 0.1).collect();
    forces.extend((0..2000).map(|i| 5.0 + if i % 2 == 0 { 0.02 } else { -0.02 }));
    let (_, raw) = bouc_wen_run(0.0, 1.0, &forces);
    let (_, clean) = bouc_wen_run(0.06, 1.0, &forces);
    let last = forces.len() - 1;
    assert!(
        raw[last] < 0.25,
        "without a deadband the noise walks it down: {}",
        raw[last]
    );
    assert!(
        (clean[last] - 0.5).abs() < 0.01,
        "with one it stays saturated: {}",
        clean[last]
    );
}

#[test]
fn plays_and_bouc_wen_exclude_each_other() {
    let mut m = SensorModel {
        hysteresis: Some(Hysteresis {
            bouc_wen_saturation_n: Some(0.5),
            ..Hysteresis::default()
        }),
        ..SensorModel::default()
    };
    let err = m.validate().expect_err("both forms at once").to_string();
    assert!(err.contains("exclude each other"), "{err}");
    m.hysteresis = Some(Hysteresis {
        thresholds_n: Vec::new(),
        bouc_wen_saturation_n: Some(0.0),
        ..Hysteresis::default()
    });
    let err = m.validate().expect_err("zero saturation").to_string();
    assert!(err.contains("bouc_wen_saturation_n"), "{err}");
}
