//! Hold drift: how far a calibrated force wanders while the true load holds still. Velostat
//! creeps under a held load (its resistance keeps falling), so a static calibration reports a
//! force that climbs through every hold; this is the number the dynamic terms of a calibration
//! must bring down.
//!
//! A *hold* is a stretch of at least [`HOLD_MIN_S`] where the reference force stays within a
//! band (the larger of [`HOLD_BAND_N`] and [`HOLD_BAND_SHARE`] of the level) of the level it
//! has over every centred second, at [`HOLD_MIN_N`] or more. Its *drift* is the change of the
//! estimated force from its first second to its last, minus the change of the reference over
//! the same seconds.

/// Shortest hold (s): a first and a last second that do not overlap.
pub const HOLD_MIN_S: f64 = 2.0;
/// Smallest held force (N).
pub const HOLD_MIN_N: f64 = 0.5;
/// Half-width of the band the reference must stay in over each centred second (N, and share
/// of the level).
pub const HOLD_BAND_N: f64 = 0.1;
pub const HOLD_BAND_SHARE: f64 = 0.03;

/// One hold and the drift of each estimate through it.
#[derive(Debug, Clone, PartialEq)]
pub struct Hold {
    pub t_start_s: f64,
    pub seconds: f64,
    /// Mean reference force (N).
    pub force_n: f64,
    /// Drift of each estimate given (N), in the order given; NaN when it has no value there.
    pub drift_n: Vec<f64>,
}

/// Frames whose reference stays within the band over the centred second around them.
fn held(t_s: &[f64], reference: &[f64]) -> Vec<bool> {
    let n = t_s.len().min(reference.len());
    let mut out = vec![false; n];
    let (mut lo, mut hi) = (0usize, 0usize);
    for i in 0..n {
        while t_s[i] - t_s[lo] > 0.5 {
            lo += 1;
        }
        while hi + 1 < n && t_s[hi + 1] - t_s[i] <= 0.5 {
            hi += 1;
        }
        let w = &reference[lo..=hi];
        let (min, max) = w.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, &v| {
            (a.0.min(v), a.1.max(v))
        });
        let level = reference[i];
        let band = HOLD_BAND_N.max(HOLD_BAND_SHARE * level.abs());
        out[i] = level >= HOLD_MIN_N && max - min <= 2.0 * band;
    }
    out
}

/// Mean of `v[i]` over the frames of `range` whose time lies in `[t0, t1]`.
fn mean_in(t_s: &[f64], v: &[f64], range: std::ops::Range<usize>, t0: f64, t1: f64) -> f64 {
    let (s, k) = range
        .filter(|&i| t_s[i] >= t0 && t_s[i] <= t1 && v[i].is_finite())
        .fold((0.0, 0usize), |a, i| (a.0 + v[i], a.1 + 1));
    if k == 0 {
        f64::NAN
    } else {
        s / k as f64
    }
}

/// Every hold of `reference` and the drift of each of `estimates` (per frame, NaN where there
/// is none) through it.
pub fn holds(t_s: &[f64], reference: &[f64], estimates: &[&[f64]]) -> Vec<Hold> {
    let flags = held(t_s, reference);
    let mut out = Vec::new();
    let mut i = 0;
    while i < flags.len() {
        if !flags[i] {
            i += 1;
            continue;
        }
        let start = i;
        while i < flags.len() && flags[i] {
            i += 1;
        }
        let (t0, t1) = (t_s[start], t_s[i - 1]);
        if t1 - t0 < HOLD_MIN_S {
            continue;
        }
        let change = |v: &[f64]| {
            mean_in(t_s, v, start..i, t1 - 1.0, t1) - mean_in(t_s, v, start..i, t0, t0 + 1.0)
        };
        let ref_change = change(reference);
        out.push(Hold {
            t_start_s: t0,
            seconds: t1 - t0,
            force_n: reference[start..i].iter().sum::<f64>() / (i - start) as f64,
            drift_n: estimates.iter().map(|e| change(e) - ref_change).collect(),
        });
    }
    out
}

/// Mean absolute drift of estimate `k` over the holds where it has one (NaN without any).
pub fn mean_abs_drift(holds: &[Hold], k: usize) -> f64 {
    let (s, n) = holds
        .iter()
        .filter_map(|h| h.drift_n.get(k).copied().filter(|d| d.is_finite()))
        .fold((0.0, 0usize), |a, d| (a.0 + d.abs(), a.1 + 1));
    if n == 0 {
        f64::NAN
    } else {
        s / n as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_creeping_estimate_drifts_and_a_true_one_does_not() {
        // 0.5 s rest, a ramp to 5 N, a 10 s hold, a ramp down, rest; 100 Hz.
        let t: Vec<f64> = (0..1500).map(|i| i as f64 * 0.01).collect();
        let reference: Vec<f64> = t
            .iter()
            .map(|&t| match t {
                t if t < 0.5 => 0.0,
                t if t < 1.0 => 10.0 * (t - 0.5),
                t if t < 11.0 => 5.0,
                t if t < 11.5 => 5.0 - 10.0 * (t - 11.0),
                _ => 0.0,
            })
            .collect();
        let exact = reference.clone();
        // Creeps up 20 % over the hold.
        let creeping: Vec<f64> = t
            .iter()
            .zip(&reference)
            .map(|(&t, &f)| {
                if (1.0..11.0).contains(&t) {
                    f * (1.0 + 0.02 * (t - 1.0))
                } else {
                    f
                }
            })
            .collect();
        let none = vec![f64::NAN; t.len()];
        let h = holds(&t, &reference, &[&exact, &creeping, &none]);
        assert_eq!(h.len(), 1, "{h:?}");
        assert!((h[0].force_n - 5.0).abs() < 0.01);
        assert!(h[0].seconds > 8.5 && h[0].seconds <= 10.0, "{h:?}");
        assert!(h[0].drift_n[0].abs() < 1e-9);
        // 5 N x 2 %/s between the centres of the first and the last second.
        let expected = 0.1 * (h[0].seconds - 1.0);
        assert!((h[0].drift_n[1] - expected).abs() < 0.02, "{h:?}");
        assert!(h[0].drift_n[2].is_nan());
        assert!((mean_abs_drift(&h, 1) - h[0].drift_n[1]).abs() < 1e-12);
        assert!(mean_abs_drift(&h, 2).is_nan());
    }

    #[test]
    fn tremor_within_the_band_is_a_hold_and_a_slow_ramp_or_a_light_touch_is_not() {
        let t: Vec<f64> = (0..1000).map(|i| i as f64 * 0.01).collect();
        let tremor: Vec<f64> = t.iter().map(|&t| 4.0 + 0.08 * (t * 50.0).sin()).collect();
        assert_eq!(holds(&t, &tremor, &[]).len(), 1);
        let ramp: Vec<f64> = t.iter().map(|&t| 1.0 + 0.5 * t).collect();
        assert!(holds(&t, &ramp, &[]).is_empty());
        let light = vec![0.3; t.len()];
        assert!(holds(&t, &light, &[]).is_empty());
    }
}
