//! Per-node, per-trial sensitivity factors fitted with the node's parameters, alternately, on
//! the node's normal equations per trial: the alternation's linear steps never return to the
//! samples.

use std::sync::Arc;

use super::fit::{Locals, NodeFit};
use crate::data::ReadoutMap;

impl NodeFit<'_> {
    /// Node `k`'s parameters, local regressors and per-trial factors, fitted alternately
    /// `updates` times from the factors `own` at the linearisation at the observations, then
    /// the node's fit given the last factors (a readout that is not linear in conductance
    /// takes one Gauss-Newton pass there), and the factors after the first `mark` updates.
    /// Each linear step is solved from the node's normal equations per trial, summed once
    /// over the samples (see [`NodeFit::block_equations`]): the factors only scale them.
    pub(super) fn node_with_factors(
        &self,
        k: usize,
        mut own: Vec<f64>,
        updates: usize,
        mark: Option<usize>,
    ) -> (Vec<f64>, Arc<Locals>, Vec<f64>, Option<Vec<f64>>) {
        let locals = self.locals(k, None);
        let eqs = self.block_equations(k, &locals, None, &own);
        let solve = |own: &[f64]| {
            let (mut a, mut b) = self.combine(eqs.clone(), own);
            self.solve(&mut a, &mut b)
        };
        let mut th = solve(&own);
        let mut marked = None;
        for u in 0..updates {
            own = self.factors_from(&th, &eqs, &own);
            if mark == Some(u + 1) {
                marked = Some(own.clone());
            }
            if u + 1 < updates {
                th = solve(&own);
            }
        }
        if matches!(self.ctx.ds.map, ReadoutMap::Amplifier { .. }) {
            th = solve(&own);
        } else {
            th = self.node(k, Some(&th), false, Some(&locals), Some(&own)).0;
        }
        (th, locals, own, marked)
    }

    /// The node's per-trial factors given its parameters `th` (fitted with factors `own`), in
    /// closed form from its normal equations per trial `eqs` (lower triangles; the
    /// linearisation at the observations): each trial's least-squares factor on the law's
    /// term, with the other regressors' part held (the hysteresis terms with the factor they
    /// were fitted with), clamped to [0.05, 20] and normalised to a mean of 1 over the trials
    /// the node is loaded in (its gain carries its scale).
    pub(super) fn factors_from(
        &self,
        th: &[f64],
        eqs: &[(Vec<f64>, Vec<f64>)],
        own: &[f64],
    ) -> Vec<f64> {
        let lay = &self.terms.lay;
        let p = lay.dim();
        let (h, o) = (lay.hyst_index(), lay.law_start());
        let s = |a: &[f64], u: usize, w: usize| a[u.max(w) * p + u.min(w)];
        let mut g = vec![1.0; own.len()];
        let mut seen = Vec::new();
        for (t, (a, b)) in eqs.iter().enumerate() {
            let (mut num, mut den) = (0.0, 0.0);
            for u in o..p {
                let fixed: f64 = (0..h).map(|w| s(a, u, w) * th[w]).sum();
                let hyst: f64 = (h..o).map(|w| s(a, u, w) * th[w]).sum();
                let law: f64 = (o..p).map(|w| s(a, u, w) * th[w]).sum();
                num += th[u] * (b[u] - fixed - own[t] * hyst);
                den += th[u] * law;
            }
            if den > 0.0 {
                g[t] = (num / den).clamp(0.05, 20.0);
                seen.push(t);
            }
        }
        let mean = seen.iter().map(|&t| g[t]).sum::<f64>() / seen.len().max(1) as f64;
        if mean > 0.0 {
            seen.iter().for_each(|&t| g[t] /= mean);
        }
        g
    }

    /// Each node's sensitivity factor per trial (trial `j`, node `k` at `j n + k`) given the
    /// nodes' parameters, in closed form as [`NodeFit::trial_gains`] but node by node, each
    /// node's factors normalised to a mean of 1 over the trials it is loaded in (its gain
    /// carries its scale). Read from `locals`, each node's local regressors of the fit that
    /// gave its parameters (they carry its factor of that fit).
    pub(super) fn node_trial_gains(
        &self,
        theta: &[Vec<f64>],
        locals: &[Arc<Locals>],
        trials: usize,
    ) -> Vec<f64> {
        let ds = self.ctx.ds;
        let n = ds.n;
        // Node by node (each node's factors read its own fit only).
        let per_node = crate::parallel::map(n.min(theta.len()), |k| {
            let (co, loc) = (self.terms.coefs(&theta[k]), &locals[k]);
            let mut num = vec![0.0f64; trials];
            let mut den = vec![0.0f64; trials];
            let base = k * self.fit_idx.len();
            for (jj, &i) in self.fit_idx.iter().enumerate() {
                let mi = self.m[i];
                let w = self.obs.wgt[base + jj] * mi * mi;
                if w == 0.0 {
                    continue;
                }
                let j = ds.trial[i];
                let own = self.terms.node_sens[j * n + k];
                // What the regressors before the law contribute, and the force term before
                // the node's own factor (its local values carry that factor once applied).
                let (seg, v) = loc.at(jj);
                let (rest, z) = self.terms.z_local_factor(&co, seg, v, own);
                let q = (z - rest) / own;
                num[j] += w * q * (self.obs.g2[base + jj] / mi - rest);
                den[j] += w * q * q;
            }
            let seen: Vec<usize> = (0..trials).filter(|&j| den[j] > 0.0).collect();
            let mut g = vec![1.0; trials];
            for &j in &seen {
                g[j] = (num[j] / den[j]).clamp(0.05, 20.0);
            }
            let mean = seen.iter().map(|&j| g[j]).sum::<f64>() / seen.len().max(1) as f64;
            if mean > 0.0 {
                seen.iter().for_each(|&j| g[j] /= mean);
            }
            g
        });
        let mut g = vec![1.0; trials * n];
        for (k, own) in per_node.iter().enumerate() {
            for (j, v) in own.iter().enumerate() {
                g[j * n + k] = *v;
            }
        }
        g
    }
}
