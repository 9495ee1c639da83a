//! A loop against creep with a strength of each node's own. The tool's creep has one strength
//! for all nodes (each node's law scales it); a sensor whose nodes creep by different amounts
//! (zoo-hys: log sd 0.3) leaves, once creep is in the model, each node's share of its creep's
//! misfit: it grows under each press and falls after it, so at the same force the reading
//! differs on loading and unloading, and a loop with an amplitude per node takes part of it
//! (zoo-hys's creep, fresh seeds 264 and 265: a loop named beside creep, 4.8 % and 2.3 % of the
//! held-out SSE at block t 4.4 and 3.9). So a loop tested while creep is in the model must
//! also beat that model with its creep's contribution scaled node by node, by the acceptance
//! rule, charged what the loop adds beyond one number per node (as crosstalk must beat the same
//! droop along the columns: `crate::placebo`).
//!
//! The scaled model is held out without a new search: each fold's creep contribution is the
//! change its fit's prediction makes when creep is taken out (the node laws refitted in closed
//! form on its training half), and each node's scale on a fold's held-out blocks is fitted by
//! least squares on the other fold's held-out blocks (its training half), so no scale is
//! fitted on the samples it predicts. (Creep with a strength per node as a model form, beside
//! the shared one, was tried on 2026-11-28 and not kept: what it left was named as a narrow
//! loop instead.)

use std::time::Instant;

use super::{Selection, Tested};
use crate::candidates::{added_params, ParamCount};
use crate::context::Context;
use crate::cv::{compare, cv_of, Cv};
use crate::diagnose::Trial;
use crate::effects::EffectKind;
use crate::model::evaluate_held_out;

impl Selection<'_> {
    /// A hysteresis `tested` against the current model, accepted while creep is in it: held
    /// against the current model with its creep scaled node by node (see the module's
    /// description); refused when it does not beat that. The comparison's trial, when made.
    pub(super) fn loop_beats_node_creep(&self, round: usize, tested: &mut Tested) -> Option<Trial> {
        let (cv, v, screened) = tested;
        if *screened || !v.accepted || !self.cur.has(EffectKind::Creep) {
            return None;
        }
        let tc = Instant::now();
        let placebo = creep_per_node(self.ctx, &self.cur_cv)?;
        let form = cv.fits.first()?;
        let k = added_params(&self.cur, form, EffectKind::Hysteresis);
        let k = ParamCount {
            global: k.global,
            per_node: k.per_node.saturating_sub(1),
        };
        let against = compare(self.ctx, &placebo, cv, k, &self.noise);
        if !against.accepted {
            v.accepted = false;
        }
        Some(Trial {
            round,
            effect: "hysteresis (against creep with a strength per node)".into(),
            verdict: against,
            seconds: tc.elapsed().as_secs_f64(),
            screened: false,
        })
    }
}

/// The held-out result `cur` (a model with creep) with each fold's creep contribution scaled
/// node by node (see the module's description); None without creep.
fn creep_per_node(ctx: &Context, cur: &Cv) -> Option<Cv> {
    let ds = ctx.ds;
    let (len, n) = (ds.len(), ds.n);
    if !cur.fits.iter().all(|c| c.has(EffectKind::Creep)) {
        return None;
    }
    let without = |f: usize| {
        let train = |i: usize| ctx.fold(i) != f;
        evaluate_held_out(ctx, &cur.fits[f].without(EffectKind::Creep), &train)
    };
    let evs = crate::parallel::join(|| without(0), || without(1));
    let evs = [evs.0, evs.1];
    // Creep's contribution to each held-out prediction, and per node and fold the sums that
    // fit its scale there.
    let mut c = vec![0.0; len * n];
    let (mut num, mut den) = (vec![[0.0f64; 2]; n], vec![[0.0f64; 2]; n]);
    for i in 0..len {
        let f = ctx.fold(i);
        for k in 0..n {
            let idx = i * n + k;
            if !ctx.usable[idx] {
                continue;
            }
            c[idx] = cur.resid[idx] - (evs[f].pred[idx] - ctx.dom_obs[idx]);
            num[k][f] += cur.resid[idx] * c[idx];
            den[k][f] += c[idx] * c[idx];
        }
    }
    let mut resid = cur.resid.clone();
    for i in 0..len {
        let other = 1 - ctx.fold(i);
        for k in 0..n {
            let idx = i * n + k;
            if ctx.usable[idx] && den[k][other] > 0.0 {
                resid[idx] -= num[k][other] / den[k][other] * c[idx];
            }
        }
    }
    Some(cv_of(ctx, resid, cur.fits.clone()))
}
