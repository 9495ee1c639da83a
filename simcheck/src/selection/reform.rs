//! A sensitivity loss's form chosen again once the baseline's shift has joined. Without a
//! curvature column, the loss is fitted in one of three forms (the trial's baseline shift's
//! form, one factor per trial, one per trial and node; see `crate::candidates`), and the form
//! is chosen in the round the loss joins. When that round comes before the baseline's shift
//! joins, the choice is made under the shift's misfit, tens of counts, and the form that wins
//! is the one that leans least on the misfit, not the one the mountings need. What the form
//! then leaves is slow within each mounting and another effect takes it up (zoo-hys's
//! unlabelled curvature, seeds 260 and 261: creep removed 29 % of what the shift's form left
//! although it made the holds worse by 22 %). So once both are in the model, the per-trial
//! forms are held out against it once, in place of the shift's form, each charged only the
//! parameters it adds; one stands in when the rule accepts it.

use std::time::Instant;

use super::{Selection, Tested};
use crate::candidates::{added_params, candidates};
use crate::diagnose::Trial;
use crate::effects::EffectKind;

impl Selection<'_> {
    /// The per-trial forms of a sensitivity loss held out in place of the baseline shift's form
    /// (see the module's description), once, when the model holds that form and the baseline's
    /// shift; the better accepted one joins. True when one joined.
    pub(crate) fn reform_sensitivity(&mut self, round: usize) -> bool {
        let e = EffectKind::CurvatureSensitivity;
        let cur = &self.cur;
        if self.reformed
            || self.ctx.ds.kappa.is_some()
            || !cur.curv_base
            || cur.curv_sens.is_none()
            || cur.curv_trials.is_some()
        {
            return false;
        }
        self.reformed = true;
        let tc = Instant::now();
        let mut best: Option<Tested> = None;
        for (starts, params) in candidates(self.ctx, &self.cur, e) {
            let Some(first) = starts.first().filter(|c| c.curv_trials.is_some()) else {
                continue;
            };
            let k = added_params(&self.cur, first, e);
            let (cv, v, screened) = self.held_out(&starts, &params, k);
            let better = best
                .as_ref()
                .is_none_or(|b| match (v.accepted, b.1.accepted) {
                    (true, false) => true,
                    (false, true) => false,
                    _ => v.ic_gain > b.1.ic_gain,
                });
            if better {
                best = Some((cv, v, screened));
            }
        }
        let Some((cv, v, screened)) = best else {
            return false;
        };
        let per_node = cv.fits[0].curv_per_node.is_some();
        self.trials.push(Trial {
            round,
            effect: format!(
                "curvature_sensitivity (one factor per trial{}, in place of the shift's form)",
                if per_node { " and node" } else { "" }
            ),
            verdict: v,
            seconds: tc.elapsed().as_secs_f64(),
            screened,
        });
        if !v.accepted {
            return false;
        }
        self.join(&cv.fits);
        // The model before the last effect joined held the other form.
        self.last = None;
        true
    }
}
