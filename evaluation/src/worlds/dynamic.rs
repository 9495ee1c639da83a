//! The dynamic-calibration check behind `taxel evaluate dynamics`: the paper's five objects
//! held 15 s at 2/3/4/5/6/8 N in a warming hand, on a sensor that creeps and has hysteresis,
//! calibrated the way a user would (`fit` on fixture presses, `--dynamics` on one
//! characterisation recording with long holds and triangle sweeps), scored with the known
//! curvature so the dynamic terms are judged, not the curvature model:
//!
//! - every simulator family ([`super::FAMILIES`]) with the hold-out seeds, each with its own
//!   creep (two time constants), hysteresis form (play operators or Bouc-Wen) and thermal drift
//!   ([`effects`]), none of them the calibrator's own forms;
//! - world B's `dynamic_object_*` recordings (an external world), each object's terms fitted on
//!   the other four objects' recordings (it has no characterisation recording).
//!
//! Every number is the curvature-aware calibration with and without its dynamic terms.

use std::path::Path;

use taxel_formats::Recording;
use taxel_sim::{Mounting, Scenario, SensorModel, Step, Tremor};

use crate::protocol::{evaluate_with, Curvature, Headline, Report};
use crate::table1::{fixture_scenario, simulate, OBJECTS};
use taxel_calibrator::calibration::Calibration;
use taxel_calibrator::fit::{fit_calibration, with_dynamics, FitOptions};

/// The force levels of the dynamic protocol (N).
pub const DYNAMIC_LEVELS: [f64; 6] = [2.0, 3.0, 4.0, 5.0, 6.0, 8.0];
/// How long each level is held (s).
pub const HOLD_S: f64 = 15.0;
/// Curvature of the characterisation recording (1/m): between two fixtures, not one of them.
pub const CHARACTERISATION_CURVATURE_M1: f64 = 20.0;

/// One world's dynamic result.
#[derive(Debug, Clone)]
pub struct DynamicRow {
    pub world: String,
    pub seed: Option<u64>,
    /// The sensor's effects, in words.
    pub effects: String,
    /// The terms written for the whole array (its fit's report line), or why none.
    pub terms: String,
    /// Mean absolute error over the object x level cells (N): with the terms, without.
    pub dynamic_n: f64,
    pub static_n: f64,
    /// Worst cell with the terms (N).
    pub worst_n: f64,
    /// Mean absolute hold drift (N): with the terms, without.
    pub drift_n: f64,
    pub static_drift_n: f64,
}

/// The effects each family's sensor gets: two creep time constants, a hysteresis form and a
/// thermal drift, varied across families so no form matches another's (or the calibrator's).
pub fn effects(sensor: &mut SensorModel, family: usize) -> String {
    let creeps = [
        ([0.05, 0.07], [3.0, 40.0]),
        ([0.04, 0.05], [1.5, 20.0]),
        ([0.06, 0.04], [5.0, 60.0]),
        ([0.03, 0.08], [2.0, 30.0]),
        ([0.05, 0.05], [4.0, 25.0]),
    ];
    let (amplitudes, tau) = creeps[family % creeps.len()];
    sensor.creep = Some(taxel_sim::model::Creep {
        amplitudes: amplitudes.to_vec(),
        tau_s: tau.to_vec(),
    });
    let plays = family.is_multiple_of(2);
    sensor.hysteresis = Some(if plays {
        taxel_sim::model::Hysteresis {
            weight: 0.15,
            thresholds_n: vec![0.1, 0.3, 0.6, 1.0],
            bouc_wen_saturation_n: None,
            bouc_wen_exponent: 1.0,
            input_deadband_n: 0.0,
        }
    } else {
        taxel_sim::model::Hysteresis {
            weight: 0.3,
            thresholds_n: Vec::new(),
            bouc_wen_saturation_n: Some(0.6),
            bouc_wen_exponent: 1.5,
            input_deadband_n: 0.05,
        }
    });
    sensor.thermal_drift = Some(taxel_sim::model::ThermalDrift {
        alpha_per_k: -0.004,
        tau_s: 60.0,
        t0_c: 25.0,
    });
    format!(
        "creep {:?} at {:?} s; hysteresis {}; thermal -0.004/K",
        amplitudes,
        tau,
        if plays {
            "plays 0.1-1 N, weight 0.15"
        } else {
            "Bouc-Wen n 1.5, saturation 0.6 N, weight 0.3"
        }
    )
}

/// One characterisation recording: long holds at three levels and two triangle sweeps, at
/// [`CHARACTERISATION_CURVATURE_M1`].
pub fn characterisation_scenario(seed: u64) -> Scenario {
    let hold = |force_n: f64| Step::Press {
        force_n,
        ramp_s: 0.8,
        hold_s: 40.0,
        release_s: 0.5,
        rest_s: 20.0,
    };
    let triangle = |top: f64, half_s: f64| {
        [
            Step::Ramp {
                force_n: top,
                duration_s: half_s,
            },
            Step::Ramp {
                force_n: 0.0,
                duration_s: half_s,
            },
            Step::Rest { duration_s: 10.0 },
        ]
    };
    let mut steps = vec![Step::Rest { duration_s: 5.0 }, hold(3.0), hold(10.0)];
    steps.extend(triangle(12.0, 6.0));
    steps.push(hold(6.0));
    steps.extend(triangle(6.0, 4.0));
    steps.push(hold(15.0));
    Scenario {
        name: "characterisation".into(),
        rate_hz: 100.0,
        seed,
        mounting: Mounting {
            curvature_m1: CHARACTERISATION_CURVATURE_M1,
            ..Mounting::default()
        },
        steps,
        ..Scenario::default()
    }
}

/// A warming hand holds the object at each level for [`HOLD_S`] (tremor; the sensor warms by
/// 1.5 degC during each hold), with a no-load lead and rests.
pub fn warming_hand_scenario(curvature_m1: f64, seed: u64) -> Scenario {
    let mut steps = vec![Step::Rest { duration_s: 5.0 }];
    let mut temp = 25.0;
    for f in DYNAMIC_LEVELS {
        temp += 1.5;
        steps.extend([
            Step::Ramp {
                force_n: f,
                duration_s: 0.8,
            },
            Step::Temperature {
                temp_c: temp,
                duration_s: HOLD_S,
            },
            Step::Ramp {
                force_n: 0.0,
                duration_s: 0.5,
            },
            Step::Rest { duration_s: 6.0 },
        ]);
    }
    Scenario {
        name: "warming-hand".into(),
        rate_hz: 100.0,
        seed,
        mounting: Mounting {
            curvature_m1,
            rotation_deg: 90 * (seed % 4) as u32,
            flipped: seed % 2 == 1,
        },
        temp_c: 25.0,
        tremor: Some(Tremor {
            amplitude_n: 0.05,
            freq_hz: 9.0,
        }),
        steps,
        ..Scenario::default()
    }
}

/// Scores of a set of object reports: cell mean with and without the terms, worst cell with
/// them, hold drift with and without.
fn row_scores(reports: &[Report]) -> (f64, f64, f64, f64, f64) {
    let cells: Vec<(f64, f64)> = reports
        .iter()
        .flat_map(|r| r.levels.iter().filter(|l| l.n > 0))
        .map(|l| {
            let st = if l.static_curve_mae_n.is_finite() {
                l.static_curve_mae_n
            } else {
                l.curve_mae_n
            };
            (l.curve_mae_n, st)
        })
        .collect();
    let mean = |v: &mut dyn Iterator<Item = f64>| {
        let (s, n) = v.fold((0.0, 0usize), |a, x| (a.0 + x, a.1 + 1));
        if n == 0 {
            f64::NAN
        } else {
            s / n as f64
        }
    };
    let holds: Vec<&crate::holds::Hold> = reports
        .iter()
        .flat_map(|r| r.blocks.iter().filter(|b| b.block == r.headline))
        .flat_map(|b| b.holds.iter())
        .collect();
    let drift = |k: usize| {
        mean(&mut holds.iter().filter_map(|h| {
            let d = h.drift_n.get(k).copied()?;
            d.is_finite().then_some(d.abs())
        }))
    };
    let static_drift = if holds
        .iter()
        .all(|h| h.drift_n.get(2).is_none_or(|d| d.is_nan()))
    {
        drift(0)
    } else {
        drift(2)
    };
    (
        mean(&mut cells.iter().map(|c| c.0)),
        mean(&mut cells.iter().map(|c| c.1)),
        cells.iter().map(|c| c.0).fold(0.0, f64::max),
        drift(0),
        static_drift,
    )
}

fn write(p: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(p, text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
}

/// The array's line of a dynamic fit's report.
fn array_line(report: &[String]) -> String {
    report
        .iter()
        .find(|l| l.starts_with("block  array: held-out"))
        .map_or_else(String::new, |l| {
            l.trim_start_matches("block  array: ").to_string()
        })
}

/// One simulator family with one seed.
pub fn family(out: &Path, preset: &str, index: usize, seed: u64) -> anyhow::Result<DynamicRow> {
    let mut sensor = taxel_sim::presets::preset(preset).ok_or_else(|| {
        anyhow::anyhow!(
            "unknown family {preset:?} (one of {})",
            taxel_sim::presets::NAMES.join(", ")
        )
    })?;
    sensor.spread.build_seed = Some(taxel_estimator::synth::build_seed(seed, 0));
    let effects = effects(&mut sensor, index);
    let dir = out.join(format!("{preset}-seed{seed}"));
    std::fs::create_dir_all(&dir).map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?;
    let fixtures = simulate(
        &sensor,
        &fixture_scenario(seed),
        &dir.join("fixtures.csv.gz"),
    )?;
    let chars = simulate(
        &sensor,
        &characterisation_scenario(seed * 100 + 1),
        &dir.join("characterisation.csv.gz"),
    )?;
    let opts = FitOptions {
        rows: Some(sensor.rows),
        cols: Some(sensor.cols),
        ..FitOptions::new("dynamic", false)
    };
    let (text, cal, _) = fit_calibration(std::slice::from_ref(&fixtures), &opts)?;
    let mut report = Vec::new();
    let (text, cal) = with_dynamics(&text, &cal, std::slice::from_ref(&chars), &mut report)?;
    write(&dir.join("calibration.toml"), &text)?;
    let mut reports = Vec::new();
    for (i, (name, c)) in OBJECTS.iter().enumerate() {
        let p = dir.join(format!("object-{}.csv.gz", name.replace(' ', "-")));
        let rec = simulate(
            &sensor,
            &warming_hand_scenario(*c, seed * 100 + 10 + i as u64),
            &p,
        )?;
        reports.push(score(&rec, &cal, *c)?);
    }
    let (dynamic_n, static_n, worst_n, drift_n, static_drift_n) = row_scores(&reports);
    Ok(DynamicRow {
        world: preset.to_string(),
        seed: Some(seed),
        effects,
        terms: array_line(&report),
        dynamic_n,
        static_n,
        worst_n,
        drift_n,
        static_drift_n,
    })
}

/// `eval --curvature-m1 C --levels 2,3,4,5,6,8` on one recording.
fn score(rec: &Recording, cal: &Calibration, c: f64) -> anyhow::Result<Report> {
    let g = rec.geometry(Some(cal.rows), Some(cal.cols))?;
    evaluate_with(
        rec,
        g,
        Curvature::Known(c),
        cal,
        None,
        &DYNAMIC_LEVELS,
        Headline::Array,
    )
}

/// World B's dynamic objects, each scored with terms fitted on the other four (their
/// curvatures from `expected.json`'s objects, the same as the README's table).
pub fn world_b(dir: &Path, out: &Path) -> anyhow::Result<DynamicRow> {
    std::fs::create_dir_all(out).map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
    let fixtures = Recording::read(&dir.join("calibration.csv.gz"))?;
    let (text, cal, _) = fit_calibration(
        std::slice::from_ref(&fixtures),
        &FitOptions::new("worldb-dynamic", false),
    )?;
    let mut recs = Vec::new();
    for (name, c) in OBJECTS {
        let p = dir.join(format!(
            "dynamic_object_{}.csv.gz",
            name.replace([' ', '-'], "_")
        ));
        let mut rec = Recording::read(&p)?;
        rec.curvature_m1 = Some(vec![c; rec.len()]);
        recs.push((rec, c));
    }
    let mut reports = Vec::new();
    let mut lines = Vec::new();
    for (i, (rec, c)) in recs.iter().enumerate() {
        let others: Vec<Recording> = recs
            .iter()
            .enumerate()
            .filter(|(j, _)| *j != i)
            .map(|(_, r)| r.0.clone())
            .collect();
        let mut report = Vec::new();
        let (t, dyn_cal) = with_dynamics(&text, &cal, &others, &mut report)?;
        write(&out.join(format!("calibration-without-{i}.toml")), &t)?;
        lines.push(format!("{}: {}", OBJECTS[i].0, array_line(&report)));
        reports.push(score(rec, &dyn_cal, *c)?);
    }
    let (dynamic_n, static_n, worst_n, drift_n, static_drift_n) = row_scores(&reports);
    Ok(DynamicRow {
        world: "world B".into(),
        seed: None,
        effects: "creep, hysteresis, a warming hand (not disclosed)".into(),
        terms: lines.join(" / "),
        dynamic_n,
        static_n,
        worst_n,
        drift_n,
        static_drift_n,
    })
}
