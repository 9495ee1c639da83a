//! Dynamic terms of a calibration block: creep under a held load and its recovery after
//! unloading, applied to the block's reading S before the static model.
//!
//! Model: the measured reading is the instantaneous one plus creep parts, each a first-order
//! lag of the instantaneous reading,
//! `S = S_e + sum_i a_i x_i`, `dx_i/dt = (S_e - x_i) / tau_i`.
//! Under a load held from t = 0 the reading climbs as `S_e (1 + sum_i a_i (1 - exp(-t/tau_i)))`
//! (several time constants cover a log-time law over their span); after unloading each part
//! decays with its own time constant (recovery: the unloaded reading is elevated and relaxes).
//! The calibrator inverts it causally, frame by frame: `S_e = S - sum_i a_i x_i` with the
//! states of the previous frame, then each state takes the step `x += dt / (tau + dt) (S_e -
//! x)`. With `a_i >= 0` and `sum a_i < 1` this is stable for every frame interval, and a
//! constant reading settles at `S_e = S / (1 + sum a_i)`: no file can make the force run away.
//!
//! The states live in the calibrator process (one set per block, no allocation per frame); they
//! start at zero (a sensor that has rested), so a calibrator started under load reports the
//! creep it cannot know about until the states have settled (about the largest time constant).

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

/// Creep of a block, as written in a calibration file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CreepSpec {
    /// Time constants (s), strictly increasing.
    pub tau_s: Vec<f64>,
    /// Share of the instantaneous reading each part adds once settled (no unit; each >= 0,
    /// their sum below 0.9).
    pub share: Vec<f64>,
}

/// Validated creep of a block.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Creep {
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
        let mut c = Creep {
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
        }
    }

    /// The instantaneous reading of measured reading `s` (from the states as they stand), then
    /// the states advanced by `dt_s`, the time to the next frame as far as it is known (the
    /// calibrator uses the interval since the previous frame, which a steady stream repeats).
    #[inline]
    pub fn step(&self, state: &mut CreepState, s: f64, dt_s: f64) -> f64 {
        let n = self.n;
        let se = s - self.share[..n]
            .iter()
            .zip(&state[..n])
            .map(|(a, x)| a * x)
            .sum::<f64>();
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
            let n = self.n;
            let creep: f64 = self.share[..n]
                .iter()
                .zip(&state[..n])
                .map(|(a, x)| a * x)
                .sum();
            out.push(e + creep);
            for (x, tau) in state[..n].iter_mut().zip(&self.tau_s[..n]) {
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
        assert_eq!(ok.array.creep.map(|c| c.spec().share), Some(vec![0.1, 0.2]));
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
