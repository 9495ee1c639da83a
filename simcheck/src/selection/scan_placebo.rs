//! Scan skew against the same time shift for every node. Scan skew's physics is a shift that
//! grows with each node's place in the scan (node `k` reads the force `k dt` later in the
//! frame), so its change is proportional to `k dF/dt`. What a loop or creep leaves on the
//! ramps also changes sign with `dF/dt`, at every node alike, and a shift takes part of it: on
//! loop recordings scan skew removed 1-25 % of the held-out SSE in round 1 (block t 4-14), and
//! on zoo-log's and zoo-hys's loops (fresh seed 300) it was named beside the loop in round 2
//! (2.2 % and 5.6 %). So scan skew must also beat its placebo, the same shift for every node
//! (the middle node's, no row settling: [`crate::effects::Config::scan_uniform`]), by the
//! acceptance rule, charged its one parameter more (the settling). The placebo is held out
//! from the skew's fits on each training half, its one shift searched again, and only when
//! the skew would join (it has the round's largest gain).

use std::time::Instant;

use super::{Best, Selection};
use crate::candidates::ParamCount;
use crate::cv::{compare, cross_validate_from, Cv};
use crate::diagnose::Trial;
use crate::effects::{Config, EffectKind};
use crate::search::Param;

impl Selection<'_> {
    /// Of a round's `accepted` candidates, the one with the largest held-out gain that also
    /// beats its placebo (the first tested among equal gains). Scan skew is held against the
    /// same shift for every node only when it would join: where a larger effect wins the round
    /// the comparison is not needed (a loop's round 1, on every loop recording).
    pub(super) fn best_standing(&mut self, round: usize, mut accepted: Vec<Best>) -> Option<Best> {
        accepted.sort_by(|a, b| b.2.rel_gain.total_cmp(&a.2.rel_gain));
        for (effects, cv, v) in accepted {
            if effects != [EffectKind::ScanSkew] {
                return Some((effects, cv, v));
            }
            let (trial, beats) = self.skew_against_uniform_shift(round, &cv);
            self.trials.push(trial);
            if beats {
                return Some((effects, cv, v));
            }
            // The skew's own row reads refused too.
            let own = EffectKind::ScanSkew.name();
            if let Some(tr) = self
                .trials
                .iter_mut()
                .rev()
                .find(|tr| tr.round == round && tr.effect == own)
            {
                tr.verdict.accepted = false;
            }
        }
        None
    }

    /// An accepted scan skew (held out as `cv`) against its placebo (see the module's
    /// description): the comparison's trial, and whether the skew beats the placebo.
    fn skew_against_uniform_shift(&self, round: usize, cv: &Cv) -> (Trial, bool) {
        let tc = Instant::now();
        let uniform = |f: usize| -> Vec<Config> {
            vec![Config {
                scan_uniform: true,
                scan_settle: 0.0,
                ..cv.fits[f].clone()
            }]
        };
        let (a, b) = (uniform(0), uniform(1));
        let placebo = cross_validate_from(self.ctx, [&a, &b], &[Param::LnSkew], self.ev_n);
        let k = ParamCount {
            global: 1,
            per_node: 0,
        };
        let against = compare(self.ctx, &placebo, cv, k, &self.noise);
        let trial = Trial {
            round,
            effect: "scan_skew (against the same shift for every node)".into(),
            verdict: against,
            seconds: tc.elapsed().as_secs_f64(),
            screened: false,
        };
        (trial, against.accepted)
    }
}
