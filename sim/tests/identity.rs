//! The existing models must produce bit-identical frames whatever optional families are added:
//! checksums of the first 2000 frames of each, recorded on the commit before the functional-form
//! families (the zoo) were added.

use taxel_sim::model::{Crosstalk, ScanSkew, ThermalDrift};
use taxel_sim::{presets, ReadoutKind, Scenario, SensorModel, Simulator, Step, Tremor};

/// A scenario that touches every path: presses with tremor, ramps, remounts at other
/// curvatures, rotations and flips, a contact move and a temperature change; it repeats.
fn scenario() -> Scenario {
    let press = |f: f64| Step::Press {
        force_n: f,
        ramp_s: 0.5,
        hold_s: 1.0,
        release_s: 0.3,
        rest_s: 0.5,
    };
    Scenario {
        name: "identity".into(),
        rate_hz: 100.0,
        seed: 11,
        repeat: true,
        mounting: taxel_sim::Mounting {
            curvature_m1: 30.0,
            ..Default::default()
        },
        tremor: Some(Tremor::default()),
        steps: vec![
            Step::Rest { duration_s: 0.5 },
            press(5.0),
            press(15.0),
            Step::Mount {
                curvature_m1: 70.0,
                rotation_deg: 90,
                flipped: true,
                rest_s: 0.5,
            },
            Step::Contact {
                row: 1.5,
                col: 2.5,
                size_rows: 2.0,
                size_cols: 2.0,
            },
            press(10.0),
            Step::Temperature {
                temp_c: 35.0,
                duration_s: 3.0,
            },
            Step::Ramp {
                force_n: 8.0,
                duration_s: 1.0,
            },
            Step::Ramp {
                force_n: 0.0,
                duration_s: 0.5,
            },
            Step::Mount {
                curvature_m1: 0.0,
                rotation_deg: 270,
                flipped: false,
                rest_s: 0.3,
            },
            Step::Contact {
                row: 2.0,
                col: 2.0,
                size_rows: 2.0,
                size_cols: 2.0,
            },
            press(20.0),
        ],
        ..Scenario::default()
    }
}

/// FNV-1a over the bits of every reading and every truth field of the first `frames` frames.
fn checksum(model: &SensorModel, frames: usize) -> u64 {
    let mut sim = Simulator::new(model, &scenario()).expect("valid");
    let mut out = vec![0.0f32; model.rows * model.cols];
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |v: u64| {
        for b in v.to_le_bytes() {
            h ^= b as u64;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    };
    for _ in 0..frames {
        let t = sim.step(&mut out);
        for v in &out {
            eat(v.to_bits() as u64);
        }
        for v in [t.t_s, t.force_n, t.curvature_m1, t.temp_c] {
            eat(v.to_bits());
        }
        eat(t.trial as u64);
    }
    h
}

fn every_layer() -> SensorModel {
    SensorModel {
        creep: Some(Default::default()),
        hysteresis: Some(Default::default()),
        thermal_drift: Some(ThermalDrift::default()),
        crosstalk: Some(Crosstalk::default()),
        scan_skew: Some(ScanSkew::default()),
        ..SensorModel::default()
    }
}

fn with_kind(kind: ReadoutKind) -> SensorModel {
    let mut m = SensorModel::default();
    m.readout.kind = kind;
    m
}

fn models() -> Vec<(&'static str, SensorModel)> {
    vec![
        ("default", presets::preset("default").expect("known")),
        (
            "paper-dataset",
            presets::preset("paper-dataset").expect("known"),
        ),
        ("alt", presets::preset("alt").expect("known")),
        ("every-layer", every_layer()),
        ("resistance", with_kind(ReadoutKind::Resistance)),
        ("divider", with_kind(ReadoutKind::Divider)),
    ]
}

/// FNV-1a of a text.
fn text_hash(text: &str) -> u64 {
    text.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Recorded on the base commit (5f79655): (model, frames, TOML text). A failure prints the
/// line that would record the new value, for a change that is meant.
const RECORDED: [(&str, u64, u64); 6] = [
    ("default", 0x02241460f383dc78, 0x581793dec7311213),
    ("paper-dataset", 0x3047d0dd2b1092d7, 0x5bc2b666b84db6a3),
    ("alt", 0x7aca82bed651736d, 0x3763333b3e2e6e5f),
    ("every-layer", 0xc058cb4654a82b42, 0x7765eb1a9d6c4107),
    ("resistance", 0xc6b04bf9ec7881b6, 0x7a417c48420cbd2d),
    ("divider", 0xe3905d989b3ed23e, 0xb8249e34402042c1),
];

#[test]
fn existing_models_give_bit_identical_frames_and_toml() {
    for ((name, m), (rec_name, frames, toml)) in models().into_iter().zip(RECORDED) {
        assert_eq!(name, rec_name);
        let (f, t) = (checksum(&m, 2000), text_hash(&m.to_toml_string()));
        let line = format!("(\"{name}\", {f:#018x}, {t:#018x}),");
        assert_eq!(f, frames, "{name}: frames changed; if meant, record {line}");
        assert_eq!(t, toml, "{name}: TOML changed; if meant, record {line}");
    }
}
