//! Creep of a block under a held load, and its recovery after unloading.
//!
//! Model: the measured quantity is the instantaneous one plus creep parts, each a first-order
//! lag of the instantaneous quantity,
//! `y = y_e + sum_i a_i x_i`, `dx_i/dt = (y_e - x_i) / tau_i`.
//! The quantity is the block's reading S (`domain = "reading"`, the default) or the force the
//! static model reports for it (`domain = "force"`: the load itself creeps, as when the
//! material's strain does; under a saturating static law the two differ at high loads).
//! Under a load held from t = 0 the quantity climbs as `y_e (1 + sum_i a_i (1 - exp(-t/tau_i)))`
//! (several time constants cover a log-time law over their span); after unloading each part
//! decays with its own time constant (recovery: the unloaded reading is elevated and relaxes).
//! The calibrator inverts it causally, frame by frame: `y_e = y - sum_i a_i x_i` with the
//! states of the previous frame, then each state takes the step `x += dt / (tau + dt) (y_e -
//! x)`. With `a_i >= 0` and `sum a_i < 1` this is stable for every frame interval, and a
//! constant input settles at `y_e = y / (1 + sum a_i)`: no file can make the force run away.

use serde::{Deserialize, Serialize};

/// Most creep parts per block.
pub const MAX_TERMS: usize = 6;
/// Largest total share: above it the inversion amplifies noise more than it removes creep.
pub const MAX_TOTAL_SHARE: f64 = 0.9;

/// One step of a first-order lag: `x` moves toward `target` over `dt_s` with time constant
/// `tau_s` (stable for any step: it never overshoots).
#[inline]
pub fn lag_step(x: &mut f64, target: f64, dt_s: f64, tau_s: f64) {
    let dt = dt_s.max(0.0);
    *x += dt / (tau_s + dt) * (target - *x);
}

/// What creeps: the block's reading or the force the static model reports for it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Domain {
    /// The reading S (counts of the block's signal), before the static model.
    #[default]
    Reading,
    /// The force (N) the static model reports, after it.
    Force,
}

impl Domain {
    pub fn name(self) -> &'static str {
        match self {
            Domain::Reading => "reading",
            Domain::Force => "force",
        }
    }
}

fn is_reading(d: &Domain) -> bool {
    *d == Domain::Reading
}

/// Creep of a block, as written in a calibration file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CreepSpec {
    /// Time constants (s), strictly increasing.
    pub tau_s: Vec<f64>,
    /// Share of the instantaneous quantity each part adds once settled (no unit; each >= 0,
    /// their sum below 0.9).
    pub share: Vec<f64>,
    /// What creeps (default: the reading).
    #[serde(default, skip_serializing_if = "is_reading")]
    pub domain: Domain,
    /// Force domain only: each part adds at most its share of the present force, so what crept
    /// goes when the load goes (`min(x_i, F)`: no slow recovery at rest, as when the creep is
    /// in conduction paths that open with the load). Default false: the parts recover with
    /// their time constants.
    #[serde(default, skip_serializing_if = "is_false")]
    pub bounded: bool,
}

fn is_false(v: &bool) -> bool {
    !*v
}

/// Validated creep of a block.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Creep {
    pub domain: Domain,
    pub bounded: bool,
    n: usize,
    tau_s: [f64; MAX_TERMS],
    share: [f64; MAX_TERMS],
}

/// Per-block creep states.
pub type CreepState = [f64; MAX_TERMS];

impl Creep {
    /// Validates a spec; the error names the block and the rule broken.
    pub fn from_spec(block: &str, spec: &CreepSpec) -> Result<Creep, String> {
        let n = spec.tau_s.len();
        if n == 0 || n > MAX_TERMS || spec.share.len() != n {
            return Err(format!(
                "block {block:?}: creep needs 1 to {MAX_TERMS} tau_s and as many share values, got {} and {}",
                n,
                spec.share.len()
            ));
        }
        let mut prev = 0.0;
        for &t in &spec.tau_s {
            if !(t.is_finite() && t > prev && t <= 1e6) {
                return Err(format!(
                    "block {block:?}: creep tau_s must be finite, positive, strictly increasing and at most 1e6 s, got {:?}",
                    spec.tau_s
                ));
            }
            prev = t;
        }
        if spec.share.iter().any(|a| !(a.is_finite() && *a >= 0.0)) {
            return Err(format!(
                "block {block:?}: creep share must be finite and >= 0, got {:?}",
                spec.share
            ));
        }
        let total: f64 = spec.share.iter().sum();
        if total >= MAX_TOTAL_SHARE {
            return Err(format!(
                "block {block:?}: creep shares sum to {total:.3}; at most {MAX_TOTAL_SHARE} keeps the correction stable"
            ));
        }
        if spec.bounded && spec.domain != Domain::Force {
            return Err(format!(
                "block {block:?}: creep bounded = true needs domain = \"force\""
            ));
        }
        let mut c = Creep {
            domain: spec.domain,
            bounded: spec.bounded,
            n,
            tau_s: [0.0; MAX_TERMS],
            share: [0.0; MAX_TERMS],
        };
        c.tau_s[..n].copy_from_slice(&spec.tau_s);
        c.share[..n].copy_from_slice(&spec.share);
        Ok(c)
    }

    /// The largest time constant (s): how long a state takes to forget where it started.
    pub fn longest_tau_s(&self) -> f64 {
        self.tau_s[..self.n].iter().copied().fold(0.0, f64::max)
    }

    /// The file's form.
    pub fn spec(&self) -> CreepSpec {
        CreepSpec {
            tau_s: self.tau_s[..self.n].to_vec(),
            share: self.share[..self.n].to_vec(),
            domain: self.domain,
            bounded: self.bounded,
        }
    }

    /// What the creep parts add to an instantaneous value `v` read now: `sum_i a_i x_i`, or
    /// `sum_i a_i min(x_i, v)` when bounded by the load.
    #[inline]
    pub fn excess_at(&self, state: &CreepState, v: f64) -> f64 {
        let n = self.n;
        let parts = self.share[..n].iter().zip(&state[..n]);
        if self.bounded {
            parts.map(|(a, x)| a * x.min(v)).sum()
        } else {
            parts.map(|(a, x)| a * x).sum()
        }
    }

    /// The instantaneous value whose measured value is `y` (states as they stand). Bounded,
    /// `g(v) = v + sum_i a_i min(x_i, v)` is piecewise linear with slope >= 1, so the root lies
    /// between `y` and `y - (g(y) - y)`; Newton steps, exact on a linear piece, bisection when a
    /// step leaves that bracket.
    #[inline]
    fn instantaneous(&self, state: &CreepState, y: f64) -> f64 {
        if !self.bounded {
            return y - self.excess_at(state, f64::INFINITY);
        }
        let e = self.excess_at(state, y);
        let (mut lo, mut hi) = if e >= 0.0 { (y - e, y) } else { (y, y - e) };
        let tol = 1e-12 * (1.0 + y.abs() + e.abs());
        // Exact while every part lags below the load (a rising or held load).
        let mut v = y - e;
        for _ in 0..64 {
            let err = v + self.excess_at(state, v) - y;
            if err.abs() <= tol {
                break;
            }
            if err > 0.0 {
                hi = v;
            } else {
                lo = v;
            }
            let slope = 1.0
                + self.share[..self.n]
                    .iter()
                    .zip(&state[..self.n])
                    .map(|(a, x)| a * f64::from(u8::from(*x > v)))
                    .sum::<f64>();
            // A Newton step kept in the bracket; bisection when that makes no progress.
            let next = (v - err / slope).clamp(lo, hi);
            v = if next != v { next } else { 0.5 * (lo + hi) };
        }
        v
    }

    /// Sets the states so that they add `excess` now, spread evenly over the parts (a reload:
    /// the new terms continue from the old terms' excess, so the force does not jump).
    pub fn set_excess(&self, state: &mut CreepState, excess: f64) {
        let total: f64 = self.share[..self.n].iter().sum();
        let x = if total > 0.0 && excess.is_finite() {
            excess / total
        } else {
            0.0
        };
        state.fill(0.0);
        state[..self.n].fill(x);
    }

    /// The instantaneous reading of measured reading `s` (from the states as they stand), then
    /// the states advanced by `dt_s`, the time to the next frame as far as it is known (the
    /// calibrator uses the interval since the previous frame, which a steady stream repeats).
    /// A value that is not finite (no baseline yet) passes through and leaves the states alone.
    #[inline]
    pub fn step(&self, state: &mut CreepState, s: f64, dt_s: f64) -> f64 {
        if !s.is_finite() {
            return s;
        }
        let n = self.n;
        let se = self.instantaneous(state, s);
        for (x, tau) in state[..n].iter_mut().zip(&self.tau_s[..n]) {
            lag_step(x, se, dt_s, *tau);
        }
        se
    }

    /// The measured reading the model predicts for instantaneous readings `se` at times `t_s`
    /// (the forward model, for fitting and tests): each frame's creep parts are the states left
    /// by the frames before it.
    pub fn forward(&self, t_s: &[f64], se: &[f64]) -> Vec<f64> {
        let mut state = [0.0; MAX_TERMS];
        let mut out = Vec::with_capacity(se.len());
        for (k, &e) in se.iter().enumerate() {
            let dt = if k + 1 < t_s.len() {
                t_s[k + 1] - t_s[k]
            } else {
                0.0
            };
            out.push(e + self.excess_at(&state, e));
            for (x, tau) in state[..self.n].iter_mut().zip(&self.tau_s[..self.n]) {
                lag_step(x, e, dt, *tau);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn creep(tau: &[f64], share: &[f64]) -> Result<Creep, String> {
        Creep::from_spec(
            "b",
            &CreepSpec {
                tau_s: tau.to_vec(),
                share: share.to_vec(),
                domain: Domain::Reading,
                bounded: false,
            },
        )
    }

    #[test]
    fn a_creeping_hold_is_brought_back_to_its_instantaneous_reading() {
        let c = creep(&[2.0, 20.0], &[0.1, 0.2]).expect("valid");
        let t: Vec<f64> = (0..6000).map(|i| i as f64 * 0.01).collect();
        // Rest 1 s, a 40 s hold at 500, then unloaded.
        let se: Vec<f64> = t
            .iter()
            .map(|&t| if (1.0..41.0).contains(&t) { 500.0 } else { 0.0 })
            .collect();
        let measured = c.forward(&t, &se);
        // The measured reading creeps up by more than 20 % through the hold...
        assert!(measured[4000] > 600.0, "{}", measured[4000]);
        // ...and stays elevated after unloading (recovery).
        assert!(measured[4200] > 20.0, "{}", measured[4200]);
        let mut state = [0.0; MAX_TERMS];
        for (k, &m) in measured.iter().enumerate() {
            let e = c.step(&mut state, m, 0.01);
            assert!(
                (e - se[k]).abs() < 1e-6 * 500.0,
                "frame {k}: {e} vs {}",
                se[k]
            );
        }
    }

    #[test]
    fn bounded_creep_goes_with_the_load_and_is_inverted_exactly() {
        let c = Creep::from_spec(
            "b",
            &CreepSpec {
                tau_s: vec![2.0, 20.0],
                share: vec![0.1, 0.2],
                domain: Domain::Force,
                bounded: true,
            },
        )
        .expect("valid");
        let t: Vec<f64> = (0..6000).map(|i| i as f64 * 0.01).collect();
        // A 30 s hold at 5 N, a partial unload to 2 N, then unloaded.
        let f: Vec<f64> = t
            .iter()
            .map(|&t| match t {
                t if (1.0..31.0).contains(&t) => 5.0,
                t if (31.0..40.0).contains(&t) => 2.0,
                _ => 0.0,
            })
            .collect();
        let measured = c.forward(&t, &f);
        assert!(measured[3000] > 5.0 * 1.2, "{}", measured[3000]);
        // Partly unloaded, the excess is at most its share of the present load...
        assert!(measured[3200] <= 2.0 * 1.3 + 1e-12, "{}", measured[3200]);
        // ...and unloaded there is none left (no slow recovery at rest).
        assert_eq!(measured[4200], 0.0);
        let mut state = [0.0; MAX_TERMS];
        for (k, &m) in measured.iter().enumerate() {
            let e = c.step(&mut state, m, 0.01);
            assert!((e - f[k]).abs() < 1e-9, "frame {k}: {e} vs {}", f[k]);
        }
        let reading = CreepSpec {
            domain: Domain::Reading,
            ..c.spec()
        };
        let e = Creep::from_spec("b", &reading).expect_err("bounded needs the force");
        assert!(e.contains("domain = \"force\""), "{e}");
    }

    #[test]
    fn a_constant_reading_settles_and_no_file_can_run_away() {
        let c = creep(&[0.5, 5.0, 50.0], &[0.3, 0.3, 0.29]).expect("valid");
        let mut state = [0.0; MAX_TERMS];
        let mut e = 0.0;
        for dt in [0.001, 0.5, 3.0, 100.0, 0.01] {
            for _ in 0..20_000 {
                e = c.step(&mut state, 100.0, dt);
                assert!(e.is_finite() && (0.0..=100.0).contains(&e), "{e}");
            }
        }
        assert!((e - 100.0 / 1.89).abs() < 1e-3, "{e}");
        for (tau, share, what) in [
            (vec![1.0, 2.0], vec![0.5, 0.5], "sum"),
            (vec![2.0, 1.0], vec![0.1, 0.1], "increasing"),
            (vec![0.0], vec![0.1], "positive"),
            (vec![1.0], vec![-0.1], ">= 0"),
            (vec![1.0], vec![0.1, 0.1], "as many"),
            (vec![f64::NAN], vec![0.1], "finite"),
        ] {
            let e = creep(&tau, &share).expect_err(what);
            assert!(e.contains("block \"b\"") && e.contains(what), "{what}: {e}");
        }
    }

    #[test]
    fn a_calibration_file_with_runaway_creep_is_refused_on_load() {
        let file = |creep: &str| {
            format!(
                "id = \"c\"\nversion = 1\nrows = 1\ncols = 1\n[array]\nname = \"array\"\nmodel = {{ form = \"poly\", terms = [{{ s = 1, c = 0, coef = 0.01 }}] }}\nrange = {{ s = [0, 1000], curvature_m1 = [0, 80] }}\n{creep}\n"
            )
        };
        let ok = crate::calibration::Calibration::from_toml_str(
            "c.toml",
            &file("creep = { tau_s = [2, 30], share = [0.1, 0.2] }"),
        )
        .expect("valid");
        assert_eq!(
            ok.array.dynamics.creep.map(|c| c.spec().share),
            Some(vec![0.1, 0.2])
        );
        let e = crate::calibration::Calibration::from_toml_str(
            "c.toml",
            &file("creep = { tau_s = [2, 30], share = [0.5, 0.45] }"),
        )
        .expect_err("runaway");
        let msg = e.to_string();
        assert!(
            msg.contains("c.toml") && msg.contains("\"array\"") && msg.contains("sum"),
            "{msg}"
        );
        assert!(!msg.contains('\n'), "{msg}");
    }
}
