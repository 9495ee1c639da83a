//! Dynamic terms from a simulator model (`--dynamics-from SIM.toml`): the creep and hysteresis
//! that `taxel-simcheck diagnose` fitted to a recording (or any taxel-sim model file) become
//! the calibration's terms, so the mismatch tool's findings flow into the live calibration.
//!
//! The simulator applies its effects to each crossing's local load (`docs/sim.md`): hysteresis
//! first, then creep of the hysteretic load. The calibration's terms act on a block's force in
//! the same order, so the forms map one to one where they are the same, with the local load of
//! the most loaded crossing (which carries the recorded force, `nodes.load_share` = 1) read as
//! the block's force:
//! - creep `F_eff = F + sum c_k lowpass_tau_k(F)` is force-domain creep with shares `c_k`;
//! - play hysteresis `F_eff = (1 - w) F + w mean_r play_r(F)` is hysteresis with half-widths
//!   `r` and weights `w / m`;
//! - a Bouc-Wen state has no play form: its loop is traced on triangle sweeps up to the
//!   largest force of the calibration and the plays that reproduce it best are fitted (least
//!   squares on the calibration's play grid, one sign).
//!
//! Thermal drift, crosstalk and everything static are not dynamic terms and are left out (the
//! report says which).

use taxel_sim::model::{Creep as SimCreep, Hysteresis as SimHysteresis};
use taxel_sim::SensorModel;

use crate::dynamics::{CreepSpec, Domain, HysteresisSpec, MAX_PLAYS};

use super::nnls::Normal;
use super::PLAY_GRID;

/// Reads a simulator model file; the error names the file.
pub fn load(path: &std::path::Path) -> anyhow::Result<SensorModel> {
    let text =
        std::fs::read_to_string(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    SensorModel::from_toml_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// The creep of `c` as force-domain creep (parts sorted by time constant).
pub fn creep(c: &SimCreep) -> anyhow::Result<CreepSpec> {
    let mut parts: Vec<(f64, f64)> = c
        .tau_s
        .iter()
        .copied()
        .zip(c.amplitudes.iter().copied())
        .collect();
    parts.sort_by(|a, b| a.0.total_cmp(&b.0));
    anyhow::ensure!(
        parts.iter().all(|p| p.1 >= 0.0),
        "creep amplitudes {:?}: a negative amplitude has no calibration form",
        c.amplitudes
    );
    Ok(CreepSpec {
        tau_s: parts.iter().map(|p| p.0).collect(),
        share: parts.iter().map(|p| p.1).collect(),
        domain: Domain::Force,
        bounded: false,
    })
}

/// The hysteresis of `h` as play operators; `f_max` is the largest force the calibration
/// covers (N), the span a Bouc-Wen loop is traced over.
pub fn hysteresis(h: &SimHysteresis, f_max: f64) -> anyhow::Result<HysteresisSpec> {
    if h.bouc_wen_saturation_n.is_none() {
        anyhow::ensure!(
            !h.thresholds_n.is_empty() && h.thresholds_n.len() <= MAX_PLAYS,
            "hysteresis with {} play thresholds: 1 to {MAX_PLAYS} have a calibration form",
            h.thresholds_n.len()
        );
        // Equal half-widths add up; the calibration's must increase strictly.
        let mut plays: Vec<(f64, f64)> = Vec::new();
        let m = h.thresholds_n.len() as f64;
        let mut sorted = h.thresholds_n.clone();
        sorted.sort_by(f64::total_cmp);
        for r in sorted {
            match plays.last_mut() {
                Some(last) if last.0 == r => last.1 += h.weight / m,
                _ => plays.push((r, h.weight / m)),
            }
        }
        return Ok(HysteresisSpec {
            threshold_n: plays.iter().map(|p| p.0).collect(),
            weight: plays.iter().map(|p| p.1).collect(),
        });
    }
    bouc_wen_as_plays(h, f_max)
}

/// The loop of a Bouc-Wen state (the simulator's equations, `docs/sim.md`) on triangle sweeps
/// up to `f_max`, as the plays on the calibration's grid that reproduce it best.
fn bouc_wen_as_plays(h: &SimHysteresis, f_max: f64) -> anyhow::Result<HysteresisSpec> {
    anyhow::ensure!(
        f_max.is_finite() && f_max > 0.0,
        "no force range to trace the Bouc-Wen loop over"
    );
    let zs = h.bouc_wen_saturation_n.unwrap_or(1.0);
    let n = h.bouc_wen_exponent;
    // Triangles of several heights, each up and down in 400 steps.
    let mut f = Vec::new();
    for top in [1.0, 0.3, 0.7, 0.15, 0.5, 1.0] {
        f.extend((0..=400).map(|k| f_max * top * k as f64 / 400.0));
        f.extend((0..400).rev().map(|k| f_max * top * k as f64 / 400.0));
    }
    let (mut z, mut u_prev, mut dead) = (0.0f64, 0.0f64, 0.0f64);
    let excess: Vec<f64> = f
        .iter()
        .map(|&v| {
            dead = dead.clamp(v - h.input_deadband_n, v + h.input_deadband_n);
            let u = dead.max(0.0);
            let du = u - u_prev;
            u_prev = u;
            let knee = (z.abs() / zs).powf(n - 1.0);
            z = (z + du - (du.abs() * z + du * z.abs()) * knee / (2.0 * zs)).clamp(-zs, zs);
            h.weight * z
        })
        .collect();
    let r: Vec<f64> = PLAY_GRID.iter().map(|g| g * f_max).collect();
    let cols: Vec<Vec<f64>> = r
        .iter()
        .map(|&r| {
            let mut p = 0.0f64;
            f.iter()
                .map(|&v| {
                    p = p.clamp(v - r, v + r);
                    p - v
                })
                .collect()
        })
        .collect();
    let mut best: Option<(f64, Vec<f64>)> = None;
    for sign in [1.0, -1.0] {
        let mut ne = Normal::new(cols.len());
        let mut x = vec![0.0; cols.len()];
        for (k, y) in excess.iter().enumerate() {
            for (xi, c) in x.iter_mut().zip(&cols) {
                *xi = sign * c[k];
            }
            ne.add(&x, *y);
        }
        let a = ne.solve_nonneg();
        let sse = ne.sse(&a);
        if best.as_ref().is_none_or(|b| sse < b.0) {
            best = Some((sse, a.iter().map(|v| sign * v).collect()));
        }
    }
    let w = best.map(|b| b.1).unwrap_or_default();
    let keep: Vec<usize> = (0..w.len()).filter(|&i| w[i].abs() >= 1e-3).collect();
    anyhow::ensure!(
        !keep.is_empty(),
        "the Bouc-Wen loop (weight {}, saturation {zs} N) is too small for any play over 0-{f_max:.1} N",
        h.weight
    );
    Ok(HysteresisSpec {
        threshold_n: keep.iter().map(|&i| r[i]).collect(),
        weight: keep.iter().map(|&i| w[i]).collect(),
    })
}

/// What a simulator model holds beyond the dynamic terms, named for the report.
pub fn left_out(m: &SensorModel) -> Vec<&'static str> {
    let mut out = Vec::new();
    if m.thermal_drift.is_some() {
        out.push("thermal drift (no temperature reaches the calibrator)");
    }
    if m.crosstalk.is_some() {
        out.push("crosstalk");
    }
    if m.scan_skew.is_some() {
        out.push("scan skew");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::{Hysteresis, MAX_PLAYS};

    #[test]
    fn plays_and_creep_map_one_to_one() {
        let c = creep(&SimCreep {
            amplitudes: vec![0.05, 0.03],
            tau_s: vec![40.0, 3.0],
        })
        .expect("maps");
        assert_eq!((c.tau_s, c.share), (vec![3.0, 40.0], vec![0.03, 0.05]));
        let h = hysteresis(
            &SimHysteresis {
                weight: 0.2,
                thresholds_n: vec![0.5, 0.1, 0.5, 1.0],
                bouc_wen_saturation_n: None,
                bouc_wen_exponent: 1.0,
                input_deadband_n: 0.0,
            },
            10.0,
        )
        .expect("maps");
        assert_eq!(h.threshold_n, vec![0.1, 0.5, 1.0]);
        let w: Vec<f64> = h.weight.iter().map(|w| (w * 1e9).round() / 1e9).collect();
        assert_eq!(w, vec![0.05, 0.1, 0.05]);
    }

    #[test]
    fn a_bouc_wen_loop_becomes_plays_that_trace_it() {
        let sim = SimHysteresis {
            weight: 0.3,
            thresholds_n: Vec::new(),
            bouc_wen_saturation_n: Some(0.8),
            bouc_wen_exponent: 1.5,
            input_deadband_n: 0.0,
        };
        let spec = hysteresis(&sim, 10.0).expect("fits");
        let h = Hysteresis::from_spec("b", &spec).expect("valid");
        // Up to 8 N and back: the plays' excess follows the Bouc-Wen state's, within a
        // quarter of the loop's height (0.3 x 0.8 N; six plays on a grid only approximate a
        // smooth knee).
        let mut p = [0.0; MAX_PLAYS];
        let (mut z, mut prev) = (0.0f64, 0.0f64);
        let mut worst: f64 = 0.0;
        let path: Vec<f64> = (0..=400)
            .map(|k| 8.0 * k as f64 / 400.0)
            .chain((0..400).rev().map(|k| 8.0 * k as f64 / 400.0))
            .collect();
        for v in path {
            let du = v - prev;
            prev = v;
            let knee = (z.abs() / 0.8).powf(0.5);
            z = (z + du - (du.abs() * z + du * z.abs()) * knee / 1.6).clamp(-0.8, 0.8);
            let want = 0.3 * z;
            let got = h.forward(&mut p, v) - v;
            worst = worst.max((got - want).abs());
        }
        assert!(worst < 0.25 * 0.24, "worst {worst}");
    }
}
