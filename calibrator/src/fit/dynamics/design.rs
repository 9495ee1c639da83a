//! The design of the dynamic fits: the characterisation frames in time order, the regressors
//! (first-order lags at a grid of time constants, play operators at a grid of half-widths),
//! a sign-constrained least-squares fit, and the terms the coefficients make.

use super::super::nnls::Normal;
use super::super::observe::Observation;
use crate::dynamics::{
    lag_step, Creep, CreepSpec, Domain, Hysteresis, HysteresisSpec, MAX_ABS_WEIGHT,
};

/// Candidate time constants (s): log-spaced from a tap to a long hold.
pub const TAU_GRID_S: [f64; 5] = [0.5, 2.0, 8.0, 32.0, 128.0];
/// Candidate play half-widths, as shares of the characterisation data's largest force.
pub const PLAY_GRID: [f64; 6] = [0.01, 0.03, 0.08, 0.15, 0.25, 0.4];
/// Fitted creep shares and positive play weights are scaled down to at most this total (the
/// stability limits' margin).
const FIT_MAX_TOTAL: f64 = 0.85;
/// Shares and weights below this are dropped.
const MIN_COEF: f64 = 1e-3;

/// Frames of one block, in time order.
#[derive(Debug, Clone)]
pub struct Series {
    pub t: Vec<f64>,
    /// Which recording each frame is from: states start from rest at each new one.
    pub seg: Vec<usize>,
    pub o: Vec<Observation>,
}

impl Series {
    pub fn new_seg(&self, k: usize) -> bool {
        k == 0 || self.seg[k] != self.seg[k - 1]
    }

    /// Time to the previous frame of the same recording (0 at a start).
    pub fn dt(&self, k: usize) -> f64 {
        if self.new_seg(k) {
            0.0
        } else {
            self.t[k] - self.t[k - 1]
        }
    }

    /// Largest reference force.
    pub fn f_max(&self) -> f64 {
        self.o.iter().map(|o| o.f).fold(0.0, f64::max)
    }
}

/// First-order lag of `x` at `tau`, per frame the state the frames before it left.
pub fn lag(ser: &Series, x: &[f64], tau: f64) -> Vec<f64> {
    let mut out = Vec::with_capacity(x.len());
    let mut s = 0.0;
    for k in 0..x.len() {
        if ser.new_seg(k) {
            s = 0.0;
        } else {
            // The state a frame sees was advanced by the frames before it, over their interval.
            lag_step(&mut s, x[k - 1], ser.dt(k), tau);
        }
        out.push(s);
    }
    out
}

/// The creep part at `tau` for instantaneous values `x`: the lag (bounded: at most `x`).
pub fn creep_part(ser: &Series, x: &[f64], tau: f64, bounded: bool) -> Vec<f64> {
    let mut l = lag(ser, x, tau);
    if bounded {
        l.iter_mut().zip(x).for_each(|(v, x)| *v = v.min(*x));
    }
    l
}

/// `play_r(x) - x` from rest at the start of each recording.
pub fn play_excess(ser: &Series, x: &[f64], r: f64) -> Vec<f64> {
    let mut p = 0.0f64;
    (0..x.len())
        .map(|k| {
            if ser.new_seg(k) {
                p = 0.0;
            }
            p = p.clamp(x[k] - r, x[k] + r);
            p - x[k]
        })
        .collect()
}

/// What a design column is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A creep part: share >= 0.
    Lag,
    /// A play: the plays' weights share one sign.
    Play,
}

/// Least squares of `y` on `cols` over the frames where `rows` is true: the creep shares are
/// non-negative; the plays' weights share one sign, whichever fits the training frames better
/// (weights of both signs on neighbouring half-widths cancel into a badly conditioned loop).
/// Returns one coefficient per column.
pub fn regress(cols: &[(Vec<f64>, Kind)], y: &[f64], rows: &dyn Fn(usize) -> bool) -> Vec<f64> {
    let mut best: Option<(f64, Vec<f64>)> = None;
    let signs: &[f64] = if cols.iter().any(|c| c.1 == Kind::Play) {
        &[1.0, -1.0]
    } else {
        &[1.0]
    };
    let sign_of = |kind: Kind, sign: f64| if kind == Kind::Play { sign } else { 1.0 };
    for &sign in signs {
        let mut n = Normal::new(cols.len());
        let mut x = vec![0.0; cols.len()];
        for (k, yk) in y.iter().enumerate() {
            if !rows(k) || !yk.is_finite() {
                continue;
            }
            for (xi, (c, kind)) in x.iter_mut().zip(cols) {
                *xi = sign_of(*kind, sign) * c[k];
            }
            n.add(&x, *yk);
        }
        let a = n.solve_nonneg();
        let sse = n.sse(&a);
        let out: Vec<f64> = a
            .iter()
            .zip(cols)
            .map(|(a, (_, kind))| sign_of(*kind, sign) * a)
            .collect();
        if best.as_ref().is_none_or(|b| sse < b.0) {
            best = Some((sse, out));
        }
    }
    best.map(|b| b.1).unwrap_or_default()
}

/// Creep from grid shares (scaled into the stability limit, small ones dropped).
pub fn creep_of(block: &str, shares: &[f64], domain: Domain, bounded: bool) -> Option<Creep> {
    let total: f64 = shares.iter().sum();
    let scale = if total > FIT_MAX_TOTAL {
        FIT_MAX_TOTAL / total
    } else {
        1.0
    };
    let keep: Vec<usize> = (0..shares.len())
        .filter(|&i| shares[i] * scale >= MIN_COEF)
        .collect();
    let spec = CreepSpec {
        tau_s: keep.iter().map(|&i| TAU_GRID_S[i]).collect(),
        share: keep.iter().map(|&i| shares[i] * scale).collect(),
        domain,
        bounded,
    };
    (!keep.is_empty())
        .then(|| Creep::from_spec(block, &spec).ok())
        .flatten()
}

/// Hysteresis from grid weights (scaled into the limits, small ones dropped).
pub fn hysteresis_of(block: &str, weights: &[f64], r: &[f64]) -> Option<Hysteresis> {
    let positive: f64 = weights.iter().map(|w| w.max(0.0)).sum();
    let magnitude: f64 = weights.iter().map(|w| w.abs()).sum();
    let scale = (FIT_MAX_TOTAL / positive.max(1e-300))
        .min(0.95 * MAX_ABS_WEIGHT / magnitude.max(1e-300))
        .min(1.0);
    let w: Vec<f64> = weights.iter().map(|&w| w * scale).collect();
    let keep: Vec<usize> = (0..w.len()).filter(|&i| w[i].abs() >= MIN_COEF).collect();
    let spec = HysteresisSpec {
        threshold_n: keep.iter().map(|&i| r[i]).collect(),
        weight: keep.iter().map(|&i| w[i]).collect(),
    };
    (!keep.is_empty())
        .then(|| Hysteresis::from_spec(block, &spec).ok())
        .flatten()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lags_and_plays_restart_with_each_recording() {
        let ser = Series {
            t: vec![0.0, 1.0, 2.0, 0.0, 1.0],
            seg: vec![0, 0, 0, 1, 1],
            o: Vec::new(),
        };
        let x = [5.0, 5.0, 5.0, 5.0, 5.0];
        let l = lag(&ser, &x, 1.0);
        assert_eq!((l[0], l[3]), (0.0, 0.0));
        assert!(l[1] > 0.0 && l[2] > l[1] && l[4] == l[1], "{l:?}");
        let p = play_excess(&ser, &x, 2.0);
        assert_eq!(p, vec![-2.0; 5]);
        let b = creep_part(&ser, &[5.0, 5.0, 1.0, 0.0, 0.0], 1.0, true);
        assert!(b[2] <= 1.0 && b[3] == 0.0, "{b:?}");
    }
}
