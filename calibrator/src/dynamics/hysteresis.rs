//! Rate-independent hysteresis of a block's force: the reading depends on the loading history,
//! not only on the level, and not on how fast the load moved.
//!
//! Model (Prandtl-Ishlinskii): the force the static model reports for the block is
//! `F_s = F + sum_j w_j (p_j - F)`, with each `p_j` a play operator of half-width `r_j` (N)
//! driven by the true force: `p_j <- clamp(p_j, F - r_j, F + r_j)`. While the load rises every
//! moving play trails it by `r_j`, so with `w_j > 0` the sensor reads low on the way up, high on
//! the way down, and keeps a remanent reading after unloading (Velostat's usual loop: the
//! crossing stays more conductive while unloading); `w_j < 0` gives the opposite loop. The loop
//! closes where it started (return-point memory), whatever the rate.
//!
//! Inversion: for given states, `g(F) = F + sum_j w_j (clamp(p_j, F - r_j, F + r_j) - F)` is
//! continuous and piecewise linear with slope `1 - sum_{j stuck} w_j`. A file is refused unless
//! `sum_j max(w_j, 0) <= 0.9`, so the slope is at least 0.1 and `g` has exactly one inverse,
//! found by Newton steps kept inside the bracket `[y - R, y + R]` (`R = sum_j |w_j| r_j`; exact
//! on a linear piece, bisection when a step leaves the bracket). No allocation.

use serde::{Deserialize, Serialize};

/// Most play operators per block.
pub const MAX_PLAYS: usize = 8;
/// Largest sum of the positive weights: the inverse's slope is at least `1 -` this.
pub const MAX_POSITIVE_WEIGHT: f64 = 0.9;
/// Largest sum of the weights' magnitudes.
pub const MAX_ABS_WEIGHT: f64 = 2.0;

/// Hysteresis of a block, as written in a calibration file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HysteresisSpec {
    /// Half-widths of the play operators (N of the block's force), strictly increasing.
    pub threshold_n: Vec<f64>,
    /// Weight of each play (no unit; the positive ones sum to at most 0.9, the magnitudes to at
    /// most 2).
    pub weight: Vec<f64>,
}

/// Validated hysteresis of a block.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hysteresis {
    n: usize,
    r: [f64; MAX_PLAYS],
    w: [f64; MAX_PLAYS],
    /// `sum_j |w_j| r_j`.
    bound: f64,
}

/// Per-block play states (N).
pub type PlayState = [f64; MAX_PLAYS];

impl Hysteresis {
    /// Validates a spec; the error names the block and the rule broken.
    pub fn from_spec(block: &str, spec: &HysteresisSpec) -> Result<Hysteresis, String> {
        let n = spec.threshold_n.len();
        if n == 0 || n > MAX_PLAYS || spec.weight.len() != n {
            return Err(format!(
                "block {block:?}: hysteresis needs 1 to {MAX_PLAYS} threshold_n and as many weight values, got {} and {}",
                n,
                spec.weight.len()
            ));
        }
        let mut prev = 0.0;
        for &r in &spec.threshold_n {
            if !(r.is_finite() && r > prev && r <= 1e6) {
                return Err(format!(
                    "block {block:?}: hysteresis threshold_n must be finite, positive, strictly increasing and at most 1e6 N, got {:?}",
                    spec.threshold_n
                ));
            }
            prev = r;
        }
        if spec.weight.iter().any(|w| !w.is_finite()) {
            return Err(format!(
                "block {block:?}: hysteresis weight must be finite, got {:?}",
                spec.weight
            ));
        }
        let positive: f64 = spec.weight.iter().map(|w| w.max(0.0)).sum();
        if positive > MAX_POSITIVE_WEIGHT {
            return Err(format!(
                "block {block:?}: hysteresis positive weights sum to {positive:.3}; at most {MAX_POSITIVE_WEIGHT} keeps the force a function of the reading"
            ));
        }
        let total: f64 = spec.weight.iter().map(|w| w.abs()).sum();
        if total > MAX_ABS_WEIGHT {
            return Err(format!(
                "block {block:?}: hysteresis weights sum to {total:.3} in magnitude; at most {MAX_ABS_WEIGHT}"
            ));
        }
        let mut h = Hysteresis {
            n,
            r: [0.0; MAX_PLAYS],
            w: [0.0; MAX_PLAYS],
            bound: 0.0,
        };
        h.r[..n].copy_from_slice(&spec.threshold_n);
        h.w[..n].copy_from_slice(&spec.weight);
        h.bound = spec
            .threshold_n
            .iter()
            .zip(&spec.weight)
            .map(|(r, w)| r * w.abs())
            .sum();
        Ok(h)
    }

    /// The file's form.
    pub fn spec(&self) -> HysteresisSpec {
        HysteresisSpec {
            threshold_n: self.r[..self.n].to_vec(),
            weight: self.w[..self.n].to_vec(),
        }
    }

    /// Half-widths (N).
    pub fn thresholds(&self) -> &[f64] {
        &self.r[..self.n]
    }

    /// Largest change of the reported force the plays can make, `sum_j |w_j| r_j` (N).
    pub fn bound_n(&self) -> f64 {
        self.bound
    }

    /// `g(f)` for the states as they stand, and its slope there (branch-free: the clamp is a
    /// min and a max, a play is stuck when the clamp leaves it where it is).
    #[inline]
    fn g(&self, p: &PlayState, f: f64) -> (f64, f64) {
        let (mut v, mut slope) = (f, 1.0);
        for ((&r, &w), &q) in self.r[..self.n]
            .iter()
            .zip(&self.w[..self.n])
            .zip(&p[..self.n])
        {
            let c = q.max(f - r).min(f + r);
            v += w * (c - f);
            slope -= w * f64::from(u8::from(c == q));
        }
        (v, slope)
    }

    #[inline]
    fn advance(&self, p: &mut PlayState, f: f64) {
        for (q, r) in p[..self.n].iter_mut().zip(&self.r[..self.n]) {
            *q = q.clamp(f - r, f + r);
        }
    }

    /// The reported force for true force `f`, advancing the states (the forward model).
    #[inline]
    pub fn forward(&self, p: &mut PlayState, f: f64) -> f64 {
        if !f.is_finite() {
            return f;
        }
        let v = self.g(p, f).0;
        self.advance(p, f);
        v
    }

    /// What the plays add to a true force `f` read now, without advancing the states.
    pub fn excess_at(&self, p: &PlayState, f: f64) -> f64 {
        self.g(p, f).0 - f
    }

    /// The true force whose reported force is `y`, advancing the states; `excess` is what the
    /// plays added at the previous frame, the first guess of what they add now (exact while
    /// every play keeps moving or every play stays put). A value that is not finite passes
    /// through and leaves the states alone.
    #[inline]
    pub fn invert(&self, p: &mut PlayState, y: f64, excess: f64) -> f64 {
        if !y.is_finite() {
            return y;
        }
        let bound = self.bound_n();
        let (mut lo, mut hi) = (y - bound, y + bound);
        let tol = 1e-12 * (1.0 + y.abs() + bound);
        let guess = y - excess;
        let mut f = if guess.is_finite() {
            guess.clamp(lo, hi)
        } else {
            y
        };
        for _ in 0..64 {
            let (v, slope) = self.g(p, f);
            let e = v - y;
            if e.abs() <= tol {
                break;
            }
            if e > 0.0 {
                hi = f;
            } else {
                lo = f;
            }
            // A Newton step, kept in the bracket (its ends are candidates: with every play
            // moving the root is one, and rounding may step a hair past it); bisection when
            // that makes no progress.
            let next = (f - e / slope).clamp(lo, hi);
            f = if next != f { next } else { 0.5 * (lo + hi) };
        }
        self.advance(p, f);
        f
    }

    /// States that add `excess` to the force `f` (spread as one common share of each play's
    /// half-width, clamped to what the plays can add): a reload continues from the old terms'
    /// excess, so the force does not jump.
    pub fn set_excess(&self, p: &mut PlayState, f: f64, excess: f64) {
        let reach: f64 = self.r[..self.n]
            .iter()
            .zip(&self.w[..self.n])
            .map(|(r, w)| r * w)
            .sum();
        let u = if reach != 0.0 && excess.is_finite() {
            (excess / reach).clamp(-1.0, 1.0)
        } else {
            0.0
        };
        p.fill(0.0);
        for (q, r) in p[..self.n].iter_mut().zip(&self.r[..self.n]) {
            *q = if f.is_finite() { f + u * r } else { 0.0 };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hyst(r: &[f64], w: &[f64]) -> Result<Hysteresis, String> {
        Hysteresis::from_spec(
            "b",
            &HysteresisSpec {
                threshold_n: r.to_vec(),
                weight: w.to_vec(),
            },
        )
    }

    /// A triangle 0 -> top -> 0, repeated with another top, as a force sequence.
    fn triangles(tops: &[f64]) -> Vec<f64> {
        let mut f = Vec::new();
        for &top in tops {
            for k in 0..=200 {
                f.push(top * k as f64 / 200.0);
            }
            for k in (0..200).rev() {
                f.push(top * k as f64 / 200.0);
            }
        }
        f
    }

    #[test]
    fn the_loop_reads_low_going_up_high_coming_down_and_keeps_a_remanence() {
        let h = hyst(&[0.2, 0.5, 1.5], &[0.1, 0.2, 0.3]).expect("valid");
        let mut p = [0.0; MAX_PLAYS];
        let f = triangles(&[6.0]);
        let y: Vec<f64> = f.iter().map(|&v| h.forward(&mut p, v)).collect();
        // At 3 N: below the load on the way up, above it on the way down.
        let up = y[100];
        let down = y[300];
        assert!((f[100] - 3.0).abs() < 1e-9 && (f[300] - 3.0).abs() < 1e-9);
        assert!(up < 3.0 - 0.5 && down > 3.0 + 0.5, "{up} {down}");
        // Unloaded again, the plays hold a remanent reading: sum w r.
        let rem = *y.last().expect("frames");
        assert!((rem - (0.02 + 0.1 + 0.45)).abs() < 1e-9, "{rem}");
    }

    #[test]
    fn the_inverse_recovers_the_load_through_any_history() {
        for (r, w) in [
            (vec![0.2, 0.5, 1.5], vec![0.1, 0.2, 0.3]),
            (vec![0.3, 1.0, 2.0, 4.0], vec![0.4, -0.5, 0.3, 0.2]),
            (vec![0.05], vec![0.9]),
        ] {
            let h = hyst(&r, &w).expect("valid");
            let (mut pf, mut pi) = ([0.0; MAX_PLAYS], [0.0; MAX_PLAYS]);
            let mut f = triangles(&[6.0, 2.0, 8.0, 0.5, 5.0]);
            // Steps and a few repeated values as well as ramps.
            f.extend([3.0, 3.0, 7.5, 0.0, 0.0, 4.2]);
            for (k, &v) in f.iter().enumerate() {
                let y = h.forward(&mut pf, v);
                let back = h.invert(&mut pi, y, 0.0);
                assert!((back - v).abs() < 1e-9, "{r:?} frame {k}: {back} vs {v}");
                let apart = pf
                    .iter()
                    .zip(&pi)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                assert!(apart < 1e-9, "states follow the same path: {pf:?} {pi:?}");
            }
        }
    }

    #[test]
    fn a_value_that_is_not_finite_leaves_the_states_alone() {
        let h = hyst(&[0.5], &[0.3]).expect("valid");
        let mut p = [0.0; MAX_PLAYS];
        h.invert(&mut p, 4.0, 0.0);
        let before = p;
        assert!(h.invert(&mut p, f64::NAN, 0.0).is_nan());
        assert_eq!(p, before);
    }

    #[test]
    fn a_reload_can_start_new_plays_from_the_old_excess() {
        let old = hyst(&[0.5, 1.0], &[0.2, 0.3]).expect("valid");
        let new = hyst(&[0.4, 0.8, 2.0], &[0.1, 0.2, 0.2]).expect("valid");
        let mut p = [0.0; MAX_PLAYS];
        for v in [0.0, 5.0, 2.0] {
            old.forward(&mut p, v);
        }
        let excess = old.excess_at(&p, 2.0);
        let mut q = [0.0; MAX_PLAYS];
        new.set_excess(&mut q, 2.0, excess);
        assert!((new.excess_at(&q, 2.0) - excess).abs() < 1e-12, "{excess}");
    }

    #[test]
    fn files_that_could_make_the_force_run_away_are_refused() {
        for (r, w, what) in [
            (vec![0.5, 1.0], vec![0.5, 0.5], "positive weights"),
            (vec![0.5, 1.0], vec![-1.5, -0.6], "magnitude"),
            (vec![1.0, 0.5], vec![0.1, 0.1], "increasing"),
            (vec![0.0], vec![0.1], "positive"),
            (vec![0.5], vec![0.1, 0.1], "as many"),
            (vec![0.5], vec![f64::NAN], "finite"),
            (vec![], vec![], "1 to"),
        ] {
            let e = hyst(&r, &w).expect_err(what);
            assert!(e.contains("block \"b\"") && e.contains(what), "{what}: {e}");
        }
    }
}
