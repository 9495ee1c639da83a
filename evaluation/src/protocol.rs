//! The paper's evaluation protocol on one recording: every frame goes through the live
//! estimator's code (no-load baseline detection, and the curvature from the model) and the live
//! calibrator's code, and for each force level the windows where the reference force stays
//! within +-0.2 N of it for at least 1 s give the mean absolute error and its SD, for the flat
//! and the curvature-aware calibration.
//!
//! Two ways to get the curvature:
//! - predicted (the paper's protocol): from the first no-load window, by a curvature model;
//!   frames before that estimate are not scored; later windows re-zero the calibration as they
//!   do live, with the first window's curvature held;
//! - given (`Curvature::Known`, a single-node sensor or a known mounting): the stream's
//!   baseline still comes from the estimator's no-load detection, and until the first window
//!   from the calibration's `no_load_reading` (when it has one); every frame with a force is
//!   scored. `Curvature::Continuing` is for a recording that continues the calibration's own
//!   session: its no-load detection starts from that `no_load_reading`.
//!
//! Both the whole array and the central 2 x 2 block (the paper's indenter) are scored. The
//! reference force is the load on the whole sensor, and a hand loads more than the central
//! block, so the headline is the whole array unless asked otherwise. `overall` is the error over
//! every scored frame whose reference force is at least 0.5 N, absolute and relative.

use taxel_estimator::baseline::DetectorConfig;
use taxel_estimator::estimate::Estimator;
use taxel_estimator::model::CurvatureModel;
use taxel_formats::{Geometry, Recording};
use taxel_msgs::{sensor_id_bytes, source, CurvatureEstimate, ForceSample, RawFrame, MAX_NODES};

use crate::holds::Hold;
use taxel_calibrator::calibration::Calibration;
use taxel_calibrator::run::Calibrator;

/// Tolerance around a level (N) and least window length (s), as in the paper.
pub const LEVEL_TOLERANCE_N: f64 = 0.2;
pub const LEVEL_MIN_S: f64 = 1.0;
/// Least reference force of the frames in `overall` (N).
pub const OVERALL_MIN_N: f64 = 0.5;

/// Where the curvature comes from.
#[derive(Debug, Clone, Copy)]
pub enum Curvature<'m> {
    /// Predicted from the first no-load window by this model.
    Model(&'m CurvatureModel),
    /// Given (1/m); the recording's own no-load windows give its baseline.
    Known(f64),
    /// Given (1/m), and the recording continues the calibration's own session (its held-out
    /// tail, say, which may start in the middle of a press): the calibration's `no_load_reading`
    /// is where unloaded windows are expected, so a steady loaded or saturated start, as on a
    /// rig that never unloads, is not taken for one.
    Continuing(f64),
}

/// Which block's force the headline compares with the reference.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Headline {
    /// The whole array (the load on the whole sensor).
    Array,
    /// The central 2 x 2 block (the calibration's first block; the paper's indenter).
    Center,
}

impl Headline {
    pub fn name(self) -> &'static str {
        match self {
            Headline::Array => "array",
            Headline::Center => "center",
        }
    }
}

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
    /// The curvature-aware calibration without its dynamic terms (NaN when it has none).
    pub static_curve_mae_n: f64,
}

/// Error over every scored frame with a reference of at least `OVERALL_MIN_N`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Overall {
    pub mae_n: f64,
    /// Mean of |error| / reference.
    pub rel_mae: f64,
    pub frames: usize,
}

/// The scores of one block.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockScores {
    pub block: Headline,
    pub levels: Vec<LevelResult>,
    /// Curvature-aware (or the only) calibration.
    pub overall: Overall,
    /// The flat calibration, when there is one.
    pub overall_flat: Option<Overall>,
    /// Calibrated force per frame (curvature-aware, flat); NaN where not scored.
    pub forces: Vec<(f32, f32)>,
    /// Every hold of the reference and the drift through it of the curvature-aware, the flat
    /// and the static estimate (`holds`).
    pub holds: Vec<Hold>,
    /// The curvature-aware calibration without its dynamic terms, per frame (NaN when it has
    /// none).
    pub static_forces: Vec<f32>,
}

/// The result for one recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Report {
    pub curvature_pred_m1: f64,
    pub curvature_sd_m1: f64,
    /// The curvature was given, not predicted.
    pub curvature_given: bool,
    /// Frame index from which frames are scored (the curvature estimate, or the first force).
    pub estimate_at: usize,
    /// Frames that completed a no-load window, in order: each re-zeroed the calibration from
    /// that frame on (live, the same windows end at the same `seq`).
    pub zeros: Vec<usize>,
    pub headline: Headline,
    /// The headline block's levels and forces (copies of `blocks`' entry).
    pub levels: Vec<LevelResult>,
    pub overall: Overall,
    pub forces: Vec<(f32, f32)>,
    /// Every block scored: the whole array, then the central block.
    pub blocks: Vec<BlockScores>,
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

fn force_of(s: &ForceSample, block: Headline) -> f32 {
    match block {
        Headline::Center if s.n_blocks > 0 => s.block_force_n[0],
        _ => s.total_force_n,
    }
}

fn overall(force: &[f32], reference: &[f64]) -> Overall {
    let (mut sum, mut rel, mut n) = (0.0, 0.0, 0usize);
    for (f, r) in force.iter().zip(reference) {
        if f.is_finite() && *r >= OVERALL_MIN_N {
            let e = (*f as f64 - r).abs();
            sum += e;
            rel += e / r;
            n += 1;
        }
    }
    let d = n.max(1) as f64;
    Overall {
        mae_n: sum / d,
        rel_mae: rel / d,
        frames: n,
    }
}

fn score(
    rec: &Recording,
    reference: &[f64],
    block: Headline,
    (forces, statics): (Vec<(f32, f32)>, Vec<f32>),
    levels: &[f64],
    has: Has,
) -> BlockScores {
    let mut results = Vec::new();
    for &target in levels {
        let (mut ef, mut ec, mut es) = (Vec::new(), Vec::new(), Vec::new());
        for w in level_windows(&rec.t_s, reference, target, LEVEL_TOLERANCE_N, LEVEL_MIN_S) {
            for i in w {
                let (c, f) = forces[i];
                if c.is_finite() {
                    ec.push((c as f64 - reference[i]).abs());
                    ef.push((f as f64 - reference[i]).abs());
                    es.push((statics[i] as f64 - reference[i]).abs());
                }
            }
        }
        let (fm, fs) = if has.flat {
            mae_sd(&ef)
        } else {
            (f64::NAN, f64::NAN)
        };
        let (cm, cs) = mae_sd(&ec);
        results.push(LevelResult {
            target_n: target,
            n: ec.len(),
            flat_mae_n: fm,
            flat_sd_n: fs,
            curve_mae_n: cm,
            curve_sd_n: cs,
            static_curve_mae_n: if has.statik { mae_sd(&es).0 } else { f64::NAN },
        });
    }
    let curve: Vec<f32> = forces.iter().map(|f| f.0).collect();
    let flat: Vec<f32> = forces.iter().map(|f| f.1).collect();
    let wide = |v: &[f32]| -> Vec<f64> { v.iter().map(|&x| x as f64).collect() };
    let holds = crate::holds::holds(
        &rec.t_s,
        reference,
        &[&wide(&curve), &wide(&flat), &wide(&statics)],
    );
    BlockScores {
        block,
        levels: results,
        overall: overall(&curve, reference),
        overall_flat: has.flat.then(|| overall(&flat, reference)),
        forces,
        holds,
        static_forces: statics,
    }
}

/// The calibrators an evaluation runs side by side on every frame: the curvature-aware one,
/// the flat one (at curvature 0), and the curvature-aware one without its dynamic terms (when
/// it has any, to show what they change).
struct Side {
    curve: Calibrator,
    flat: Option<Calibrator>,
    statik: Option<Calibrator>,
    out: [ForceSample; 3],
}

impl Side {
    fn new(curve: &Calibration, flat: Option<&Calibration>) -> Side {
        let wrap = |c: &Calibration| Calibrator::for_calibration(c.clone(), f64::INFINITY);
        let dynamic = curve.all_blocks().any(|b| !b.dynamics.is_static());
        Side {
            curve: wrap(curve),
            flat: flat.map(wrap),
            statik: dynamic.then(|| {
                let mut c = wrap(curve);
                c.set_dynamics(false);
                c
            }),
            out: [ForceSample::ZERO; 3],
        }
    }

    fn set_known(&mut self, c: f64) {
        self.curve.set_known_curvature(c);
        if let Some(s) = self.statik.as_mut() {
            s.set_known_curvature(c);
        }
        if let Some(f) = self.flat.as_mut() {
            f.set_known_curvature(0.0);
        }
    }

    fn set_curvature(&mut self, e: &CurvatureEstimate) {
        self.curve.set_curvature(e);
        if let Some(s) = self.statik.as_mut() {
            s.set_curvature(e);
        }
        if let Some(f) = self.flat.as_mut() {
            let mut flat_est = *e;
            flat_est.curvature_m1 = 0.0;
            f.set_curvature(&flat_est);
        }
    }

    /// (curvature-aware, flat, static) force of the whole array and of the central block; NaN
    /// for a calibrator that is not there.
    fn apply(&mut self, frame: &RawFrame) -> [(f32, f32, f32); 2] {
        let t = frame.t_capture_ns;
        let [oc, of, os] = &mut self.out;
        self.curve.apply(frame, t, oc);
        if let Some(f) = self.flat.as_mut() {
            f.apply(frame, t, of);
        }
        if let Some(s) = self.statik.as_mut() {
            s.apply(frame, t, os);
        }
        [Headline::Array, Headline::Center].map(|b| {
            let pick = |o: &ForceSample, on: bool| if on { force_of(o, b) } else { f32::NAN };
            (
                force_of(&self.out[0], b),
                pick(&self.out[1], self.flat.is_some()),
                pick(&self.out[2], self.statik.is_some()),
            )
        })
    }
}

/// Which of the side calibrators were there.
#[derive(Debug, Clone, Copy)]
struct Has {
    flat: bool,
    statik: bool,
}

/// Runs the protocol. `flat` is optional when the curvature is given.
pub fn evaluate_with(
    rec: &Recording,
    g: Geometry,
    curvature: Curvature,
    curve: &Calibration,
    flat: Option<&Calibration>,
    levels: &[f64],
    headline: Headline,
) -> anyhow::Result<Report> {
    let reference = rec
        .force_n
        .as_ref()
        .ok_or_else(|| anyhow::anyhow!("{}: needs a force_n column", rec.path.display()))?;
    for (c, name) in [(Some(curve), "calibration"), (flat, "flat calibration")] {
        let Some(c) = c else { continue };
        anyhow::ensure!(
            (c.rows, c.cols) == (g.rows, g.cols),
            "the {name} is for {} x {}, the recording is {} x {}",
            c.rows,
            c.cols,
            g.rows,
            g.cols
        );
    }
    let detector = DetectorConfig {
        log_domain: curve.readout.log_domain(),
        rises: Some(curve.readout.rises),
        ..DetectorConfig::default()
    };
    let (model, given) = match curvature {
        Curvature::Model(m) => (Some(m), None),
        Curvature::Known(c) | Curvature::Continuing(c) => (None, Some(c)),
    };
    let mut estimator = Estimator::new(detector, model, given.unwrap_or(0.0));
    if matches!(curvature, Curvature::Continuing(_))
        && curve.no_load_reading.len() == g.rows * g.cols
    {
        estimator.seed_baseline(&curve.no_load_reading);
    }
    let mut side = Side::new(curve, flat);
    if let Some(c) = given {
        // Until the first no-load window, the given curvature with the file's no-load reading.
        side.set_known(c);
    }
    let mut estimate: Option<(f64, f64, usize)> = given.map(|c| (c, 0.0, 0));
    let mut zeros = Vec::new();
    let n = rec.len();
    let mut forces = [Vec::with_capacity(n), Vec::with_capacity(n)];
    let mut statics = [Vec::with_capacity(n), Vec::with_capacity(n)];
    for (i, frame) in frames(rec, g).enumerate() {
        if let Some(e) = estimator.push(&frame)? {
            zeros.push(i);
            // An estimate serves from the frame that completed its window on (live, that frame
            // gets it or not depending on which process handles it first). Every no-load
            // window re-zeroes, as live; with a predicted curvature the first window's
            // curvature is held, as in the protocol.
            match estimate {
                Some((c, _, _)) if given.is_none() => {
                    let mut held = *e;
                    held.curvature_m1 = c as f32;
                    side.set_curvature(&held);
                }
                _ => {
                    side.set_curvature(e);
                    if given.is_none() {
                        estimate = Some((e.curvature_m1 as f64, e.curvature_sd_m1 as f64, i));
                    }
                }
            }
        }
        let per_block = if estimate.is_none() {
            [(f32::NAN, f32::NAN, f32::NAN); 2]
        } else {
            side.apply(&frame)
        };
        for (k, (c, f, st)) in per_block.into_iter().enumerate() {
            forces[k].push((c, f));
            statics[k].push(st);
        }
    }
    let Some((c_pred, c_sd, mut at)) = estimate else {
        anyhow::bail!(
            "{}: no steady no-load period of {} frames before the first press: cannot predict the curvature",
            rec.path.display(),
            DetectorConfig::default().window_frames
        );
    };
    if given.is_some() {
        at = forces[0].iter().position(|f| f.0.is_finite()).ok_or_else(|| {
            anyhow::anyhow!(
                "{}: no steady no-load period was found and the calibration has no no_load_reading: no baseline to count the reading from",
                rec.path.display()
            )
        })?;
    }
    let [array, center] = forces;
    let [array_static, center_static] = statics;
    let has = Has {
        flat: flat.is_some(),
        statik: side.statik.is_some(),
    };
    let blocks = vec![
        score(
            rec,
            reference,
            Headline::Array,
            (array, array_static),
            levels,
            has,
        ),
        score(
            rec,
            reference,
            Headline::Center,
            (center, center_static),
            levels,
            has,
        ),
    ];
    let head = blocks
        .iter()
        .find(|b| b.block == headline)
        .unwrap_or(&blocks[0])
        .clone();
    Ok(Report {
        curvature_pred_m1: c_pred,
        curvature_sd_m1: c_sd,
        curvature_given: given.is_some(),
        estimate_at: at,
        zeros,
        headline,
        levels: head.levels,
        overall: head.overall,
        forces: head.forces,
        blocks,
    })
}

/// The paper's protocol with a curvature model and a flat calibration, the whole array as the
/// headline.
pub fn evaluate(
    rec: &Recording,
    g: Geometry,
    model: &CurvatureModel,
    curve: &Calibration,
    flat: &Calibration,
    levels: &[f64],
) -> anyhow::Result<Report> {
    evaluate_with(
        rec,
        g,
        Curvature::Model(model),
        curve,
        Some(flat),
        levels,
        Headline::Array,
    )
}

fn num(v: f64, n: usize) -> String {
    if n == 0 || !v.is_finite() {
        "null".to_string()
    } else {
        format!("{v:.4}")
    }
}

fn levels_json(levels: &[LevelResult]) -> String {
    let v: Vec<String> = levels
        .iter()
        .map(|l| {
            format!(
                "{{\"target_n\": {}, \"flat_mae_n\": {}, \"flat_sd_n\": {}, \"curve_mae_n\": {}, \"curve_sd_n\": {}, \"static_curve_mae_n\": {}, \"frames\": {}}}",
                l.target_n,
                num(l.flat_mae_n, l.n),
                num(l.flat_sd_n, l.n),
                num(l.curve_mae_n, l.n),
                num(l.curve_sd_n, l.n),
                num(l.static_curve_mae_n, l.n),
                l.n
            )
        })
        .collect();
    format!("[{}]", v.join(", "))
}

fn overall_json(o: &Overall) -> String {
    format!(
        "{{\"mae_n\": {}, \"rel_mae\": {}, \"frames\": {}}}",
        num(o.mae_n, o.frames),
        num(o.rel_mae, o.frames),
        o.frames
    )
}

/// `{"holds": n, "mean_abs_n": …, "flat_mean_abs_n": …, "static_mean_abs_n": …, "per_hold":
/// [{"t_start_s": …, "seconds": …, "force_n": …, "drift_n": …, "flat_drift_n": …,
/// "static_drift_n": …}, …]}` (null for a missing value).
fn holds_json(holds: &[Hold]) -> String {
    let drift = |h: &Hold, k: usize| num(h.drift_n.get(k).copied().unwrap_or(f64::NAN), 1);
    let per: Vec<String> = holds
        .iter()
        .map(|h| {
            format!(
                "{{\"t_start_s\": {:.3}, \"seconds\": {:.3}, \"force_n\": {:.4}, \"drift_n\": {}, \"flat_drift_n\": {}, \"static_drift_n\": {}}}",
                h.t_start_s,
                h.seconds,
                h.force_n,
                drift(h, 0),
                drift(h, 1),
                drift(h, 2)
            )
        })
        .collect();
    format!(
        "{{\"holds\": {}, \"mean_abs_n\": {}, \"flat_mean_abs_n\": {}, \"static_mean_abs_n\": {}, \"per_hold\": [{}]}}",
        holds.len(),
        num(crate::holds::mean_abs_drift(holds, 0), holds.len()),
        num(crate::holds::mean_abs_drift(holds, 1), holds.len()),
        num(crate::holds::mean_abs_drift(holds, 2), holds.len()),
        per.join(", ")
    )
}

/// The JSON object of `taxel calibrator eval --json`.
pub fn json(r: &Report) -> String {
    let blocks: Vec<String> = r
        .blocks
        .iter()
        .map(|b| {
            format!(
                "\"{}\": {{\"levels\": {}, \"overall\": {}, \"overall_flat\": {}, \"hold_drift\": {}}}",
                b.block.name(),
                levels_json(&b.levels),
                overall_json(&b.overall),
                b.overall_flat
                    .as_ref()
                    .map_or("null".to_string(), overall_json),
                holds_json(&b.holds)
            )
        })
        .collect();
    let head = r.blocks.iter().find(|b| b.block == r.headline);
    format!(
        "{{\"curvature_pred_m1\": {:.3}, \"levels\": {}, \"overall\": {}, \"hold_drift\": {}, \"headline\": \"{}\", \"curvature_source\": \"{}\", \"blocks\": {{{}}}}}",
        r.curvature_pred_m1,
        levels_json(&r.levels),
        overall_json(&r.overall),
        head.map_or("null".to_string(), |b| holds_json(&b.holds)),
        r.headline.name(),
        if r.curvature_given { "given" } else { "predicted" },
        blocks.join(", ")
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

    #[test]
    fn overall_counts_frames_from_half_a_newton() {
        let o = overall(&[1.0, 2.2, f32::NAN, 0.3], &[1.0, 2.0, 5.0, 0.4]);
        assert_eq!(o.frames, 2);
        assert!(
            (o.mae_n - 0.1).abs() < 1e-6 && (o.rel_mae - 0.05).abs() < 1e-6,
            "{o:?}"
        );
    }
}
