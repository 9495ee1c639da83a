//! Tests of the functional-form families (the zoo) through the whole simulator: each option
//! moves the output the expected way, and bad values are refused by name.

use super::*;
use crate::footprint::Footprint;
use crate::forms::{BaselineForm, Law, SensitivityForm};
use crate::noise::{Wander, WanderMode};
use crate::scenario::Step;

fn quiet() -> SensorModel {
    let mut m = SensorModel::default();
    m.readout.noise_counts = 0.0;
    m
}

fn frames(model: &SensorModel, scenario: &Scenario, n: usize) -> Vec<Vec<f32>> {
    let mut sim = Simulator::new(model, scenario).expect("valid");
    let mut out = vec![0.0f32; model.rows * model.cols];
    (0..n)
        .map(|_| {
            sim.step(&mut out);
            out.clone()
        })
        .collect()
}

/// 0 -> 20 N over 10 s at 100 Hz on the flat mounting.
fn ramp() -> Scenario {
    Scenario {
        rate_hz: 100.0,
        steps: vec![Step::Ramp {
            force_n: 20.0,
            duration_s: 10.0,
        }],
        ..Scenario::default()
    }
}

fn block(frame: &[f32]) -> f64 {
    [5, 6, 9, 10].iter().map(|&k| frame[k] as f64).sum()
}

/// Block-sum response (loaded minus unloaded) at each force in turn, on a mounting of
/// curvature `kappa`: a ramp to each force at 100 Hz, read after it settles.
fn responses(model: &SensorModel, kappa: f64, forces: &[f64]) -> Vec<f64> {
    let mut steps = Vec::new();
    for &f in forces {
        steps.push(Step::Ramp {
            force_n: f,
            duration_s: 0.1,
        });
        steps.push(Step::Rest { duration_s: 0.1 });
    }
    let s = Scenario {
        rate_hz: 100.0,
        mounting: Mounting {
            curvature_m1: kappa,
            ..Mounting::default()
        },
        steps,
        ..Scenario::default()
    };
    let fr = frames(model, &s, 20 * forces.len() + 1);
    let rest = block(&fr[0]);
    (0..forces.len())
        .map(|i| block(&fr[20 * i + 19]) - rest)
        .collect()
}

fn invalid(m: &SensorModel, field: &str) {
    let e = m.validate().expect_err(field).to_string();
    assert!(e.contains(field), "{field}: {e}");
}

#[test]
fn log_and_hyperbolic_laws_flatten_where_the_power_law_stays_straight() {
    let mut m = quiet();
    m.material.r_floor_ohm = 0.0; // no saturation from the floor: only the law's shape
    m.material.gain_us_per_n = 50.0;
    let straight = responses(&m, 0.0, &[5.0, 10.0, 20.0]);
    // Power with n = 1: doubling the force doubles the response (to rounding).
    assert!(
        (straight[2] / straight[1] - 2.0).abs() < 0.05,
        "{straight:?}"
    );
    m.material.law = Law::Log;
    m.material.log_gain_us = 200.0;
    let log = responses(&m, 0.0, &[5.0, 10.0, 20.0]);
    m.material.law = Law::Hyperbolic;
    m.material.hyperbolic_gmax_us = 800.0;
    let hyp = responses(&m, 0.0, &[5.0, 10.0, 20.0]);
    for r in [&log, &hyp] {
        assert!(r[0] > 0.0 && r[1] > r[0] && r[2] > r[1], "rises: {r:?}");
        assert!(r[2] / r[1] < 1.7, "concave: {r:?}");
    }
}

#[test]
fn node_exponent_spread_gives_each_node_its_own_curve() {
    let mut m = quiet();
    m.spread.node_gain_log_sd = 0.0;
    m.spread.node_g0_log_sd = 0.0;
    m.material.r_floor_ohm = 0.0;
    m.material.gain_us_per_n = 40.0;
    let s = Scenario {
        rate_hz: 100.0,
        steps: vec![
            Step::Ramp {
                force_n: 2.0,
                duration_s: 0.1,
            },
            Step::Rest { duration_s: 0.1 },
            Step::Ramp {
                force_n: 20.0,
                duration_s: 0.1,
            },
            Step::Rest { duration_s: 0.1 },
        ],
        ..Scenario::default()
    };
    // Ratio of the 20 N to the 2 N response of each block node.
    let ratios = |m: &SensorModel| -> Vec<f64> {
        let fr = frames(m, &s, 41);
        [5, 6, 9, 10]
            .iter()
            .map(|&k| (fr[39][k] - fr[0][k]) as f64 / (fr[19][k] - fr[0][k]) as f64)
            .collect()
    };
    let same = ratios(&m);
    assert!(same.iter().all(|r| (r - same[0]).abs() < 0.05), "{same:?}");
    m.spread.node_exponent_log_sd = 0.15;
    let spread = ratios(&m);
    let (lo, hi) = spread
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), r| (a.min(*r), b.max(*r)));
    assert!(hi - lo > 1.0, "exponents differ per node: {spread:?}");
    m.spread.node_exponent_log_sd = 3.0;
    invalid(&m, "spread.node_exponent_log_sd");
}

#[test]
fn every_sensitivity_form_lowers_the_response_with_curvature() {
    for form in [
        SensitivityForm::Current,
        SensitivityForm::Hyperbolic,
        SensitivityForm::Linear,
        SensitivityForm::Exponential,
    ] {
        let mut m = quiet();
        m.curvature.sensitivity_form = form;
        let r: Vec<f64> = [0.0, 40.0, 80.0]
            .iter()
            .map(|&k| responses(&m, k, &[10.0])[0])
            .collect();
        assert!(r[0] > r[1] && r[1] > r[2], "{form:?}: {r:?}");
    }
    // A form with its own scale: a smaller scale loses more.
    let mut m = quiet();
    m.curvature.sensitivity_form = SensitivityForm::Exponential;
    let wide = responses(&m, 80.0, &[10.0])[0];
    m.curvature.sensitivity_ce_m1 = 60.0;
    let narrow = responses(&m, 80.0, &[10.0])[0];
    assert!(narrow < wide, "{narrow} vs {wide}");
    for (field, set) in [
        (
            "curvature.sensitivity_c0_m1",
            (|c: &mut crate::model::Curvature| c.sensitivity_c0_m1 = 0.0) as fn(&mut _),
        ),
        ("curvature.sensitivity_cmax_m1", |c| {
            c.sensitivity_cmax_m1 = -5.0
        }),
        ("curvature.sensitivity_ce_m1", |c| {
            c.sensitivity_ce_m1 = f64::NAN
        }),
        ("curvature.sensitivity_exponent", |c| {
            c.sensitivity_exponent = 10.0
        }),
        ("curvature.baseline_cb_m1", |c| c.baseline_cb_m1 = 0.0),
    ] {
        let mut m = quiet();
        set(&mut m.curvature);
        invalid(&m, field);
    }
}

#[test]
fn the_exponential_baseline_levels_off() {
    let mut m = quiet();
    m.material.g0_us = 200.0;
    let poly = Simulator::new(&m, &Scenario::default()).expect("valid");
    m.curvature.baseline_form = BaselineForm::Exponential;
    let expo = Simulator::new(&m, &Scenario::default()).expect("valid");
    let at = |sim: &Simulator, k| {
        sim.baseline_factors(&Mounting {
            curvature_m1: k,
            ..Mounting::default()
        })
    };
    // The same slope when nearly flat, less rise at high curvature, the same pattern's sign.
    for (p, e) in at(&poly, 1.0).iter().zip(at(&expo, 1.0)) {
        assert!((p - e).abs() < 1e-4, "{p} vs {e}");
    }
    for (p, e) in at(&poly, 100.0).iter().zip(at(&expo, 100.0)) {
        assert!((e - 1.0).abs() < (p - 1.0).abs(), "{p} vs {e}");
        assert!((e - 1.0) * (p - 1.0) > 0.0, "{p} vs {e}");
    }
}

#[test]
fn any_angle_mountings_turn_the_pattern_continuously() {
    let mut m = quiet();
    let at = |m: &SensorModel, deg| {
        let s = Scenario {
            mounting: Mounting {
                curvature_m1: 60.0,
                rotation_deg: deg,
                flipped: false,
            },
            ..Scenario::default()
        };
        Simulator::new(m, &s).map(|sim| sim.baseline_factors(&s.mounting))
    };
    let e = at(&m, 45)
        .expect_err("45 degrees without any_angle")
        .to_string();
    assert!(e.contains("rotation_deg") && e.contains("any_angle"), "{e}");
    m.curvature.any_angle = true;
    let (b0, b45, b89, b90) = (
        at(&m, 0).expect("0"),
        at(&m, 45).expect("45"),
        at(&m, 89).expect("89"),
        at(&m, 90).expect("90"),
    );
    assert_ne!(b45, b0);
    assert_ne!(b45, b90);
    let gap = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max)
    };
    assert!(gap(&b89, &b90) < 0.1 * gap(&b0, &b90), "89 is near 90");
    assert!(at(&m, 360).is_err(), "0..360 only");
}

#[test]
fn a_gaussian_footprint_spreads_the_press_onto_neighbours() {
    let mut m = quiet();
    let fr = |m: &SensorModel| {
        let f = frames(m, &ramp(), 1001);
        (f[0].clone(), f[1000].clone())
    };
    let (rest, loaded) = fr(&m);
    assert_eq!(
        loaded[1], rest[1],
        "rectangle: a neighbour of the block carries nothing"
    );
    m.contact.footprint = Footprint::Gaussian;
    let (rest, loaded) = fr(&m);
    assert!(loaded[1] > rest[1] + 5.0, "{} vs {}", loaded[1], rest[1]);
    assert!(loaded[5] > loaded[1], "the centre carries most");
}

#[test]
fn contact_jitter_moves_every_press() {
    let press = Step::Press {
        force_n: 10.0,
        ramp_s: 0.1,
        hold_s: 0.5,
        release_s: 0.1,
        rest_s: 0.3,
    };
    let s = Scenario {
        rate_hz: 100.0,
        steps: vec![press.clone(), press],
        ..Scenario::default()
    };
    let mut m = quiet();
    m.contact.footprint = Footprint::Gaussian;
    let held = |m: &SensorModel| {
        let f = frames(m, &s, 200);
        (f[50].clone(), f[150].clone())
    };
    let (a, b) = held(&m);
    assert_eq!(a, b, "without jitter every press lands alike");
    m.contact.jitter_nodes = 0.3;
    let (a, b) = held(&m);
    assert_ne!(a, b, "with jitter each press lands elsewhere");
    // Roughly the same total, though: the force moves, it is not lost.
    let (ta, tb): (f32, f32) = (a.iter().sum(), b.iter().sum());
    assert!((ta - tb).abs() < 0.1 * ta, "{ta} vs {tb}");
}

#[test]
fn wander_and_spikes_disturb_the_unloaded_reading() {
    let s = Scenario {
        rate_hz: 100.0,
        steps: vec![Step::Rest { duration_s: 60.0 }],
        ..Scenario::default()
    };
    let mut m = quiet();
    let still = frames(&m, &s, 3000);
    assert!(still.iter().all(|f| *f == still[0]), "no noise: constant");
    m.noise.wander = Some(Wander {
        sd_counts: 3.0,
        tau_s: 2.0,
        mode: WanderMode::Common,
    });
    let common = frames(&m, &s, 3000);
    let node0: Vec<f32> = common.iter().map(|f| f[0] - still[0][0]).collect();
    let spread = node0.iter().fold(0.0f32, |a, v| a.max(v.abs()));
    assert!(spread > 2.0, "it wanders: {spread}");
    // Common mode: every node moves together (to rounding).
    for f in &common {
        let d0 = f[0] - still[0][0];
        assert!(f
            .iter()
            .zip(&still[0])
            .all(|(v, s)| (v - s - d0).abs() <= 1.0));
    }
    // Slow: successive frames differ by far less than the wander.
    let step = node0.windows(2).map(|w| (w[1] - w[0]).abs()).sum::<f32>() / 2999.0;
    assert!(step < 0.6, "{step}");
    if let Some(w) = &mut m.noise.wander {
        w.mode = WanderMode::PerNode;
    }
    let per_node = frames(&m, &s, 3000);
    assert!(per_node
        .iter()
        .any(|f| ((f[0] - still[0][0]) - (f[1] - still[0][1])).abs() > 2.0));
    let mut m = quiet();
    m.noise.spike_rate_hz = 0.5;
    m.noise.spike_counts = 40.0;
    let spiky = frames(&m, &s, 3000);
    let hits = spiky
        .iter()
        .flat_map(|f| f.iter().zip(&still[0]).map(|(v, s)| (v - s).abs()))
        .filter(|d| *d >= 39.0)
        .count();
    // 16 nodes x 30 s x 0.5 Hz = 240 expected.
    assert!((180..300).contains(&hits), "{hits}");
    m.noise.spike_counts = -1.0;
    invalid(&m, "noise.spike_counts");
    m.noise.spike_counts = 1.0;
    m.noise.wander = Some(Wander {
        sd_counts: -1.0,
        ..Wander::default()
    });
    invalid(&m, "noise.wander.sd_counts");
}

#[test]
fn a_silent_wander_leaves_every_other_draw_alone() {
    // The zoo's draws have streams of their own: switching a (zero) wander on changes nothing.
    let m = SensorModel::default();
    let mut w = m.clone();
    w.noise.wander = Some(Wander {
        sd_counts: 0.0,
        ..Wander::default()
    });
    let s = Scenario::demo(30.0, 4);
    assert_eq!(frames(&m, &s, 600), frames(&w, &s, 600));
}

#[test]
fn a_rising_divider_and_an_inverted_amplifier() {
    let mut m = quiet();
    m.readout.kind = ReadoutKind::Divider;
    m.readout.divider_rises = true;
    let r = responses(&m, 0.0, &[1.0, 5.0, 20.0]);
    assert!(r[0] > 0.0 && r[1] > r[0] && r[2] > r[1], "rises: {r:?}");
    let mut m = quiet();
    let plain = frames(&m, &ramp(), 1001);
    m.readout.inverted = true;
    let inv = frames(&m, &ramp(), 1001);
    for (p, i) in plain.iter().zip(&inv) {
        assert!(p.iter().zip(i).all(|(p, i)| *i == 1023.0 - *p));
    }
    assert!(
        block(&inv[1000]) < block(&inv[0]) - 600.0,
        "falls with force"
    );
    m.readout.kind = ReadoutKind::Divider;
    invalid(&m, "readout.inverted");
    let mut m = quiet();
    m.readout.divider_rises = true;
    invalid(&m, "readout.divider_rises");
}

#[test]
fn bad_law_parameters_are_refused_by_name() {
    let mut m = quiet();
    m.material.log_f0_n = 0.0;
    invalid(&m, "material.log_f0_n");
    let mut m = quiet();
    m.material.log_gain_us = -1.0;
    invalid(&m, "material.log_gain_us");
    let mut m = quiet();
    m.material.hyperbolic_half_n = -1.0;
    invalid(&m, "material.hyperbolic_half_n");
    let mut m = quiet();
    m.material.hyperbolic_gmax_us = f64::INFINITY;
    invalid(&m, "material.hyperbolic_gmax_us");
    let mut m = quiet();
    m.contact.width_nodes = 0.0;
    invalid(&m, "contact.width_nodes");
}

#[test]
fn zoo_fields_read_from_toml_and_round_trip() {
    let text = r#"
[material]
law = "hyperbolic"
hyperbolic_gmax_us = 1200
hyperbolic_half_n = 3

[spread]
node_exponent_log_sd = 0.1

[curvature]
sensitivity_form = "linear"
sensitivity_cmax_m1 = 230
baseline_form = "exponential"
baseline_cb_m1 = 50
any_angle = true

[readout]
inverted = true

[contact]
footprint = "gaussian"
width_nodes = 0.6
jitter_nodes = 0.2

[noise]
spike_rate_hz = 0.02
spike_counts = 30

[noise.wander]
sd_counts = 1.5
tau_s = 10
mode = "per_node"
"#;
    let m = SensorModel::from_toml_str(text).expect("parses");
    assert_eq!(m.material.law, Law::Hyperbolic);
    assert_eq!(m.curvature.sensitivity_form, SensitivityForm::Linear);
    assert_eq!(m.contact.footprint, Footprint::Gaussian);
    assert_eq!(
        m.noise.wander.as_ref().map(|w| w.mode),
        Some(WanderMode::PerNode)
    );
    let back = SensorModel::from_toml_str(&m.to_toml_string()).expect("round trip");
    assert_eq!(m, back);
    let e = SensorModel::from_toml_str("[material]\nlaw = \"cubic\"\n").expect_err("unknown law");
    assert!(e.to_string().contains("cubic"), "{e}");
    // A model without the zoo writes none of its fields.
    let plain = SensorModel::default().to_toml_string();
    for field in [
        "law",
        "sensitivity_form",
        "baseline_form",
        "any_angle",
        "footprint",
        "wander",
    ] {
        assert!(!plain.contains(field), "{field} in\n{plain}");
    }
}

#[test]
fn the_documented_zoo_example_is_a_valid_model() {
    let doc = include_str!("../../../docs/sim.md");
    let start = doc
        .find("```toml\n[material]\nlaw = \"log\"")
        .expect("zoo example in docs/sim.md")
        + 8;
    let end = start + doc[start..].find("```").expect("end of example");
    let m = SensorModel::from_toml_str(&doc[start..end]).expect("documented example is valid");
    assert_eq!(m.material.law, Law::Log);
    assert_eq!(
        m.noise.wander.as_ref().map(|w| w.mode),
        Some(WanderMode::PerNode)
    );
    assert!(!frames(&m, &ramp(), 10).is_empty());
}
