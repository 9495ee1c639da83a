//! Dynamic terms of a calibration block: what a static calibration cannot know because it
//! depends on the sensor's history, corrected frame by frame with state kept in the calibrator.
//!
//! - `creep`: creep under a held load and its recovery after unloading, of the reading or of
//!   the force (several time constants; `creep.rs`);
//! - `hysteresis`: rate-independent hysteresis of the force, play operators (`hysteresis.rs`);
//! - the **zero credit**: every no-load window the estimator publishes re-zeroes the block
//!   (slow drift of the unloaded reading: warming, a remount, wear). With dynamic terms, part of
//!   what a no-load window reads is the terms' own doing (a remanent reading after a press,
//!   creep still recovering), which the terms go on correcting; the credit is that part, the
//!   reading the model predicts at zero load when the window is taken, so a re-zero takes out
//!   only the drift the model does not explain (`State::rezero`).
//!
//! The chain for a block, each part optional: reading S plus the credit -> reading-domain creep
//! inverted -> the static model -> force-domain creep inverted -> hysteresis inverted -> force.
//! Every part is stable for any frame interval and bounded by validation, so no file can make
//! the force run away.

mod creep;
mod hysteresis;

pub use creep::{lag_step, Creep, CreepSpec, CreepState, Domain, MAX_TERMS, MAX_TOTAL_SHARE};
pub use hysteresis::{
    Hysteresis, HysteresisSpec, PlayState, MAX_ABS_WEIGHT, MAX_PLAYS, MAX_POSITIVE_WEIGHT,
};

use crate::calibration::{Block, Evaluated};

/// The dynamic terms of a block (none: static).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Dynamics {
    pub creep: Option<Creep>,
    pub hysteresis: Option<Hysteresis>,
}

impl Dynamics {
    /// No term at all.
    pub fn is_static(&self) -> bool {
        self.creep.is_none() && self.hysteresis.is_none()
    }

    /// The longest creep time constant (s), 0 without creep.
    pub fn longest_tau_s(&self) -> f64 {
        self.creep.map_or(0.0, |c| c.longest_tau_s())
    }

    fn creep_in(&self, d: Domain) -> Option<&Creep> {
        self.creep.as_ref().filter(|c| c.domain == d)
    }
}

/// The state of one block's dynamic terms, kept by the calibrator between frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct State {
    pub creep: CreepState,
    pub plays: PlayState,
    /// Reading (S units) added to the block's reading since the last re-zero.
    pub credit: f64,
    /// The force of the last frame (N), as corrected.
    pub last_force_n: f64,
    /// What the hysteresis added to it at the last frame (N).
    last_excess_n: f64,
    /// The creep's instantaneous value at the last frame (its domain's units).
    last_creep_value: f64,
    /// Lowest and highest force since the states started (N): a play is known once the force
    /// has swept twice its half-width in one direction.
    sweep: [f64; 2],
}

impl Default for State {
    fn default() -> Self {
        State::REST
    }
}

impl State {
    /// A sensor at rest: no creep under way, every play at zero.
    pub const REST: State = State {
        creep: [0.0; MAX_TERMS],
        plays: [0.0; MAX_PLAYS],
        credit: 0.0,
        last_force_n: 0.0,
        last_excess_n: 0.0,
        last_creep_value: 0.0,
        sweep: [f64::INFINITY, f64::NEG_INFINITY],
    };

    /// The force of block `b` for reading `s` (counted from the block's zero) at curvature `c`,
    /// `dt_s` after the previous frame, advancing the states. Without terms it is the static
    /// model's force.
    #[inline]
    pub fn step(&mut self, b: &Block, s: f64, c: f64, dt_s: f64) -> Evaluated {
        let d = &b.dynamics;
        let s = s + self.credit;
        let se = match d.creep_in(Domain::Reading) {
            Some(cr) => {
                let v = cr.step(&mut self.creep, s, dt_s);
                self.last_creep_value = v;
                v
            }
            None => s,
        };
        let mut e = b.evaluate(se, c);
        if let Some(cr) = d.creep_in(Domain::Force) {
            e.force_n = cr.step(&mut self.creep, e.force_n, dt_s);
            self.last_creep_value = e.force_n;
        }
        if let Some(h) = &d.hysteresis {
            let reported = e.force_n;
            e.force_n = h.invert(&mut self.plays, reported, self.last_excess_n);
            if e.force_n.is_finite() {
                self.last_excess_n = reported - e.force_n;
            }
        }
        if e.force_n.is_finite() {
            self.last_force_n = e.force_n;
            self.sweep = [self.sweep[0].min(e.force_n), self.sweep[1].max(e.force_n)];
        }
        e
    }

    /// The reading (S units, from the true zero) the block's terms predict at zero load now:
    /// what a no-load window read now holds beyond the true zero.
    pub fn excess_at_zero(&self, b: &Block, c: f64) -> f64 {
        let d = &b.dynamics;
        let mut f = d.hysteresis.map_or(0.0, |h| h.excess_at(&self.plays, 0.0));
        if let Some(cr) = d.creep_in(Domain::Force) {
            f += cr.excess_at(&self.creep, f);
        }
        let mut s = b.reading_for(f, c) - b.reading_for(0.0, c);
        if let Some(cr) = d.creep_in(Domain::Reading) {
            s += cr.excess_at(&self.creep, 0.0);
        }
        if s.is_finite() {
            s
        } else {
            0.0
        }
    }

    /// A new no-load window became the block's zero: the credit is what the terms predict that
    /// window holds, so the zero moves only by the drift they do not explain.
    pub fn rezero(&mut self, b: &Block, c: f64) {
        self.credit = if b.dynamics.is_static() {
            0.0
        } else {
            self.excess_at_zero(b, c)
        };
    }

    /// A reloaded calibration serves block `new` from the next frame on (it was `old`): the new
    /// terms start from states that add what the old ones added at the last frame, so the force
    /// does not jump (creep of the same domain: the old excess spread evenly over the new parts;
    /// hysteresis: the old plays' excess at the last force, as one common share of each new
    /// play's half-width). A creep that changes domain starts from rest. The credit is kept.
    pub fn carry_over(&mut self, old: &Block, new: &Block) {
        let (o, n) = (&old.dynamics, &new.dynamics);
        match (o.creep, n.creep) {
            (Some(a), Some(b)) if a.domain == b.domain => {
                let excess = a.excess_at(&self.creep, self.last_creep_value);
                b.set_excess(&mut self.creep, excess);
            }
            _ => self.creep = [0.0; MAX_TERMS],
        }
        let f = self.last_force_n;
        let excess = o.hysteresis.map_or(0.0, |h| h.excess_at(&self.plays, f));
        match n.hysteresis {
            Some(h) => h.set_excess(&mut self.plays, f, excess),
            None => self.plays = [0.0; MAX_PLAYS],
        }
    }

    /// Whether every play of `b` is determined by the forces seen since the states started
    /// (the force swept twice the play's half-width in one direction), or `b` has none.
    pub fn plays_known(&self, b: &Block) -> bool {
        let swept = self.sweep[1] - self.sweep[0];
        b.dynamics
            .hysteresis
            .is_none_or(|h| h.thresholds().iter().all(|r| swept >= 2.0 * r))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::Calibration;

    /// A one-node calibration, F = 0.01 S, with the given dynamic terms.
    fn block(terms: &str) -> Block {
        let text = format!(
            "id = \"c\"\nversion = 1\nrows = 1\ncols = 1\n[array]\nname = \"array\"\nmodel = {{ form = \"poly\", terms = [{{ s = 1, c = 0, coef = 0.01 }}] }}\nrange = {{ s = [0, 2000], curvature_m1 = [0, 80] }}\n{terms}\n"
        );
        Calibration::from_toml_str("c.toml", &text)
            .expect("valid")
            .array
    }

    /// The reading a sensor with `b`'s terms gives for true forces `f` (100 Hz), through the
    /// forward models: hysteresis, then force-domain creep, then the static law (S = 100 F),
    /// then reading-domain creep.
    fn measured(b: &Block, f: &[f64]) -> Vec<f64> {
        let d = &b.dynamics;
        let mut plays = [0.0; MAX_PLAYS];
        let fh: Vec<f64> = f
            .iter()
            .map(|&v| d.hysteresis.map_or(v, |h| h.forward(&mut plays, v)))
            .collect();
        let t: Vec<f64> = (0..f.len()).map(|k| k as f64 * 0.01).collect();
        let fs = match d.creep_in(Domain::Force) {
            Some(c) => c.forward(&t, &fh),
            None => fh,
        };
        let se: Vec<f64> = fs.iter().map(|v| 100.0 * v).collect();
        match d.creep_in(Domain::Reading) {
            Some(c) => c.forward(&t, &se),
            None => se,
        }
    }

    fn session() -> Vec<f64> {
        // Rest, a 20 s hold at 6 N, rest 5 s, a slow triangle to 4 N and back, rest.
        let mut f = vec![0.0; 100];
        f.extend(std::iter::repeat_n(6.0, 2000));
        f.extend(std::iter::repeat_n(0.0, 500));
        f.extend((0..=300).map(|k| 4.0 * k as f64 / 300.0));
        f.extend((0..300).rev().map(|k| 4.0 * k as f64 / 300.0));
        f.extend(std::iter::repeat_n(0.0, 300));
        f
    }

    #[test]
    fn every_chain_of_terms_gives_the_load_back() {
        for terms in [
            "creep = { tau_s = [2, 30], share = [0.1, 0.2] }",
            "creep = { tau_s = [2, 30], share = [0.1, 0.2], domain = \"force\" }",
            "hysteresis = { threshold_n = [0.2, 1.0], weight = [0.2, 0.3] }",
            "creep = { tau_s = [3], share = [0.15], domain = \"force\" }\nhysteresis = { threshold_n = [0.3, 1.5], weight = [0.2, 0.2] }",
        ] {
            let b = block(terms);
            let f = session();
            let s = measured(&b, &f);
            let mut st = State::REST;
            for (k, (&s, &want)) in s.iter().zip(&f).enumerate() {
                let got = st.step(&b, s, 0.0, 0.01).force_n;
                assert!((got - want).abs() < 1e-6, "{terms}: frame {k}: {got} vs {want}");
            }
        }
    }

    #[test]
    fn a_rezero_keeps_what_the_terms_explain_and_takes_out_the_drift() {
        let b = block("creep = { tau_s = [3], share = [0.1], domain = \"force\" }\nhysteresis = { threshold_n = [0.5, 1.5], weight = [0.2, 0.3] }");
        let mut f = vec![0.0; 100];
        f.extend(std::iter::repeat_n(6.0, 1000));
        f.extend(std::iter::repeat_n(0.0, 300));
        f.extend(std::iter::repeat_n(3.0, 500));
        let s = measured(&b, &f);
        // The board's zero drifts up by 40 counts (warming) while the sensor rests; at frame
        // 1300 a no-load window is taken. Largest error after it, with and without the credit.
        let drift = |k: usize| if k >= 1200 { 40.0 } else { 0.0 };
        let worst = |credit: bool| {
            let mut st = State::REST;
            let mut zero = 0.0;
            let mut worst: f64 = 0.0;
            for (k, (&s, &want)) in s.iter().zip(&f).enumerate() {
                if k == 1300 {
                    // The window's level, counted from the old zero, becomes the new zero.
                    zero = s + drift(k);
                    st.rezero(&b, 0.0);
                    if !credit {
                        st.credit = 0.0;
                    }
                }
                let got = st.step(&b, s + drift(k) - zero, 0.0, 0.01).force_n;
                if k > 1300 {
                    worst = worst.max((got - want).abs());
                }
            }
            worst
        };
        assert!(worst(true) < 0.02, "{}", worst(true));
        // Without it, the remanence and the creep still recovering were taken for the zero.
        assert!(worst(false) > 0.3, "{}", worst(false));
    }

    #[test]
    fn a_reload_does_not_make_the_force_jump() {
        let old = block("creep = { tau_s = [2, 30], share = [0.1, 0.2], domain = \"force\" }\nhysteresis = { threshold_n = [0.5], weight = [0.3] }");
        let new = block("creep = { tau_s = [5], share = [0.25], domain = \"force\" }\nhysteresis = { threshold_n = [0.3, 1.0], weight = [0.1, 0.3] }");
        let f = session();
        let s = measured(&old, &f);
        let mut st = State::REST;
        let k = 1500; // in the 6 N hold
        let mut before = 0.0;
        for &s in &s[..k] {
            before = st.step(&old, s, 0.0, 0.01).force_n;
        }
        st.carry_over(&old, &new);
        let after = st.step(&new, s[k], 0.0, 0.01).force_n;
        assert!((after - before).abs() < 0.01, "{before} -> {after}");
    }

    #[test]
    fn plays_are_known_once_the_force_swept_them() {
        let b = block("hysteresis = { threshold_n = [0.5, 2.0], weight = [0.2, 0.3] }");
        let mut st = State::REST;
        for s in [0.0, 100.0, 300.0] {
            st.step(&b, s, 0.0, 0.01);
        }
        assert!(!st.plays_known(&b), "swept 3 N < 4 N");
        st.step(&b, 500.0, 0.0, 0.01);
        assert!(st.plays_known(&b));
        assert!(State::REST.plays_known(&block("")));
    }
}
