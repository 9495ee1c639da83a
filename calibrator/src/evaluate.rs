//! The paper's evaluation protocol on one recording of an object whose curvature is not given:
//! the curvature is predicted from the no-load period at the start (the live estimator's code),
//! every later frame is calibrated with the flat and the curvature-aware calibration (the live
//! calibrator's code), and for each force level the windows where the reference force stays
//! within +-0.2 N of it for at least 1 s give the mean absolute error and its SD.

use std::sync::Arc;

use taxel_estimator::baseline::DetectorConfig;
use taxel_estimator::estimate::Estimator;
use taxel_estimator::model::CurvatureModel;
use taxel_formats::{Geometry, Recording};
use taxel_msgs::{sensor_id_bytes, source, ForceSample, RawFrame, MAX_NODES};

use crate::calibration::Calibration;
use crate::reload::Loaded;
use crate::run::Calibrator;

/// Tolerance around a level (N) and least window length (s), as in the paper.
pub const LEVEL_TOLERANCE_N: f64 = 0.2;
pub const LEVEL_MIN_S: f64 = 1.0;

/// Errors at one level.
#[derive(Debug, Clone, PartialEq)]
pub struct LevelResult {
    pub target_n: f64,
    /// Frames in the level's windows.
    pub n: usize,
    pub flat_mae_n: f64,
    pub flat_sd_n: f64,
    pub curve_mae_n: f64,
    pub curve_sd_n: f64,
}

/// The result for one recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Report {
    pub curvature_pred_m1: f64,
    pub curvature_sd_m1: f64,
    /// Frame index at which the curvature estimate became available.
    pub estimate_at: usize,
    pub levels: Vec<LevelResult>,
    /// Calibrated force per frame (curvature-aware, flat); NaN before the estimate.
    pub forces: Vec<(f32, f32)>,
}

/// Frames of `rec` as the publisher's replay source would send them.
pub fn frames(rec: &Recording, g: Geometry) -> impl Iterator<Item = RawFrame> + '_ {
    let mut f = RawFrame::ZERO;
    f.sensor = sensor_id_bytes("eval").unwrap_or([0; taxel_msgs::SENSOR_ID_LEN]);
    f.rows = g.rows as u16;
    f.cols = g.cols as u16;
    f.source = source::REPLAY;
    let t0 = rec.t_s.first().copied().unwrap_or(0.0);
    let n = rec.n_nodes.min(MAX_NODES);
    (0..rec.len()).map(move |i| {
        f.seq = i as u64;
        f.t_capture_ns = ((rec.t_s[i] - t0).max(0.0) * 1e9) as u64;
        for (d, s) in f.counts[..n].iter_mut().zip(rec.sample(i)) {
            *d = *s as f32;
        }
        f
    })
}

/// Contiguous runs of frames whose reference force stays within `tol` of `target` for at least
/// `min_s` seconds.
pub fn level_windows(
    t_s: &[f64],
    force: &[f64],
    target: f64,
    tol: f64,
    min_s: f64,
) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut start: Option<usize> = None;
    for i in 0..=force.len() {
        let inside = i < force.len() && (force[i] - target).abs() <= tol;
        match (inside, start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                if t_s[i - 1] - t_s[s] >= min_s {
                    out.push(s..i);
                }
                start = None;
            }
            _ => {}
        }
    }
    out
}

fn mae_sd(errors: &[f64]) -> (f64, f64) {
    let n = errors.len().max(1) as f64;
    let mae = errors.iter().sum::<f64>() / n;
    let var = errors.iter().map(|e| (e - mae).powi(2)).sum::<f64>() / n;
    (mae, var.sqrt())
}

fn force_of(s: &ForceSample) -> f32 {
    if s.n_blocks > 0 {
        s.block_force_n[0]
    } else {
        s.total_force_n
    }
}

/// Runs the protocol. The force compared is the calibration's first block (the paper's
/// central block), or the whole array when the calibration has no block.
pub fn evaluate(
    rec: &Recording,
    g: Geometry,
    model: &CurvatureModel,
    curve: &Calibration,
    flat: &Calibration,
    levels: &[f64],
) -> anyhow::Result<Report> {
    let force_ref = rec
        .force_n
        .as_ref()
        .ok_or_else(|| anyhow::anyhow!("{}: needs a force_n column", rec.path.display()))?;
    for (c, name) in [(curve, "calibration"), (flat, "flat calibration")] {
        anyhow::ensure!(
            (c.rows, c.cols) == (g.rows, g.cols),
            "the {name} is for {} x {}, the recording is {} x {}",
            c.rows,
            c.cols,
            g.rows,
            g.cols
        );
    }
    let mut estimator = Estimator::new(DetectorConfig::default(), Some(model), 0.0);
    let wrap = |c: &Calibration| {
        Calibrator::new(
            Arc::new(Loaded {
                calibration: c.clone(),
                generation: 1,
            }),
            f64::INFINITY,
        )
    };
    let (mut cal_curve, mut cal_flat) = (wrap(curve), wrap(flat));
    let mut estimate = None;
    let mut forces = Vec::with_capacity(rec.len());
    let (mut out_c, mut out_f) = (ForceSample::ZERO, ForceSample::ZERO);
    for (i, frame) in frames(rec, g).enumerate() {
        if estimate.is_none() {
            if let Some(e) = estimator.push(&frame)? {
                cal_curve.set_curvature(e);
                let mut flat_est = *e;
                flat_est.curvature_m1 = 0.0;
                cal_flat.set_curvature(&flat_est);
                // The estimate serves from the frame that completed its window on (live, that
                // frame gets it or not depending on which process handles it first).
                estimate = Some((e.curvature_m1 as f64, e.curvature_sd_m1 as f64, i));
            }
        }
        if estimate.is_none() {
            forces.push((f32::NAN, f32::NAN));
            continue;
        }
        cal_curve.apply(&frame, frame.t_capture_ns, &mut out_c);
        cal_flat.apply(&frame, frame.t_capture_ns, &mut out_f);
        forces.push((force_of(&out_c), force_of(&out_f)));
    }
    let Some((c_pred, c_sd, at)) = estimate else {
        anyhow::bail!(
            "{}: no steady no-load period of {} frames before the first press: cannot predict the curvature",
            rec.path.display(),
            DetectorConfig::default().window_frames
        );
    };
    let mut results = Vec::new();
    for &target in levels {
        let (mut ef, mut ec) = (Vec::new(), Vec::new());
        for w in level_windows(&rec.t_s, force_ref, target, LEVEL_TOLERANCE_N, LEVEL_MIN_S) {
            for i in w {
                let (c, f) = forces[i];
                if c.is_finite() && f.is_finite() {
                    ec.push((c as f64 - force_ref[i]).abs());
                    ef.push((f as f64 - force_ref[i]).abs());
                }
            }
        }
        let (fm, fs) = mae_sd(&ef);
        let (cm, cs) = mae_sd(&ec);
        results.push(LevelResult {
            target_n: target,
            n: ec.len(),
            flat_mae_n: fm,
            flat_sd_n: fs,
            curve_mae_n: cm,
            curve_sd_n: cs,
        });
    }
    Ok(Report {
        curvature_pred_m1: c_pred,
        curvature_sd_m1: c_sd,
        estimate_at: at,
        levels: results,
        forces,
    })
}

/// The JSON object of `taxel calibrator eval --json`.
pub fn json(r: &Report) -> String {
    let num = |v: f64, n: usize| {
        if n == 0 || !v.is_finite() {
            "null".to_string()
        } else {
            format!("{v:.4}")
        }
    };
    let levels: Vec<String> = r
        .levels
        .iter()
        .map(|l| {
            format!(
                "{{\"target_n\": {}, \"flat_mae_n\": {}, \"flat_sd_n\": {}, \"curve_mae_n\": {}, \"curve_sd_n\": {}, \"frames\": {}}}",
                l.target_n,
                num(l.flat_mae_n, l.n),
                num(l.flat_sd_n, l.n),
                num(l.curve_mae_n, l.n),
                num(l.curve_sd_n, l.n),
                l.n
            )
        })
        .collect();
    format!(
        "{{\"curvature_pred_m1\": {:.3}, \"levels\": [{}]}}",
        r.curvature_pred_m1,
        levels.join(", ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_need_a_second_inside_the_band() {
        let t: Vec<f64> = (0..500).map(|i| i as f64 * 0.01).collect();
        let f: Vec<f64> = t
            .iter()
            .map(|&t| {
                if (1.0..2.5).contains(&t) {
                    4.1
                } else if (3.0..3.5).contains(&t) {
                    4.0
                } else {
                    0.0
                }
            })
            .collect();
        let w = level_windows(&t, &f, 4.0, 0.2, 1.0);
        assert_eq!(w.len(), 1, "the 0.5 s window is too short");
        assert_eq!((w[0].start, w[0].end), (100, 250));
    }
}
