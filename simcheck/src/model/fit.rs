//! The per-node weighted least squares of one evaluation: the observations undone through
//! the crosstalk and the floor (kept between evaluations), the normal equations per node, and
//! the common factors fitted with the nodes (a latent drift, per-trial sensitivities).

use std::sync::Arc;

use super::terms::Terms;
use crate::context::Context;
use crate::data::ReadoutMap;
use crate::effects::Config;
use crate::law::{Basis, RowMap};
use crate::numeric::{hat, nnls, solve_spd};

/// A readout's fit stops its Gauss-Newton passes early once a pass moved the node's fitted
/// values by less than this share of their size (see [`step_is_small`]): the passes converge
/// fast (on zoo-hys's 10-minute creep + loop recording the second pass moved the parameters
/// by a median 2e-4 of their size, the third by 8e-7), so the pass left out would move them
/// by a small fraction of that again. There, 1e-3 left every verdict, parameter and held-out
/// RMSE as it was to the digits reported and took a fifth off the diagnosis (paired ratio
/// 0.81).
const GN_STEP_TOL: f64 = 1e-3;

/// The observed conductance undone through the crosstalk and the floor (`g2`), with the weight
/// of each observation in the residual domain (0: unusable), at the fit's samples only, node
/// by node (`k * m + j` for the `j`-th of `m` samples: each node's fit reads its own run).
pub struct Observed {
    pub(super) g2: Vec<f64>,
    pub(super) wgt: Vec<f64>,
    /// The readings at the same samples in the same order.
    readings: std::sync::Arc<Readings>,
}

/// The reading in the residual domain, the observed conductance, and whether it is usable, at
/// the fit's samples node by node (the training SSE reads them, and [`Observed::new`] for every
/// floor a search tries; the full sample-major arrays are read at a stride that misses the
/// cache). They depend on the samples only, so every [`Observed`] of the same samples shares
/// them.
struct Readings {
    dom: Vec<f64>,
    g: Vec<f64>,
    usable: Vec<bool>,
}

impl Readings {
    fn new(ctx: &Context, fit_idx: &[usize]) -> Readings {
        let (n, m) = (ctx.ds.n, fit_idx.len());
        let mut dom = vec![0.0; m * n];
        let mut g = vec![0.0; m * n];
        let mut usable = vec![false; m * n];
        // Node by node (nodes side by side): each node's samples are one stretch of each array.
        crate::parallel::chunks_mut2(&mut dom, &mut g, m, |k, dom, g| {
            for (j, &i) in fit_idx.iter().enumerate() {
                dom[j] = ctx.dom_obs[i * n + k];
                g[j] = ctx.g_obs[i * n + k];
            }
        });
        crate::parallel::chunks_mut(&mut usable, m, |k, usable| {
            for (j, &i) in fit_idx.iter().enumerate() {
                usable[j] = ctx.usable[i * n + k];
            }
        });
        Readings { dom, g, usable }
    }
}

/// How many [`Observed`]s the context keeps; the least recently used goes (the whole
/// recording's sample sets, read by the joins and the final fits, stay while the candidates'
/// tests come and go).
const OBSERVED_KEPT: usize = 8;

/// What [`Observed`] depends on: the samples (their count, first and sum) and the floor and
/// switch resistance it was undone through.
pub type ObservedKey = (usize, usize, usize, u64, u64);

impl Observed {
    /// [`Observed::new`], kept in the context for the next evaluation with the same samples,
    /// floor and crosstalk (most evaluations of a search change neither).
    pub(super) fn cached(
        ctx: &Context,
        cfg: &Config,
        fit_idx: &[usize],
    ) -> std::sync::Arc<Observed> {
        let key: ObservedKey = (
            fit_idx.len(),
            fit_idx.first().copied().unwrap_or(0),
            fit_idx.iter().sum(),
            cfg.floor().to_bits(),
            cfg.crosstalk.unwrap_or(0.0).to_bits(),
        );
        let mut readings = None;
        if let Ok(mut cache) = ctx.observed.lock() {
            // Least recently used first: a hit moves to the back.
            if let Some(at) = cache.iter().position(|(k, _)| *k == key) {
                let hit = cache.remove(at);
                let o = hit.1.clone();
                cache.push(hit);
                return o;
            }
            let same_samples = |k: &ObservedKey| k.0 == key.0 && k.1 == key.1 && k.2 == key.2;
            readings = cache
                .iter()
                .find(|(k, _)| same_samples(k))
                .map(|(_, o)| o.readings.clone());
        }
        let readings = readings.unwrap_or_else(|| std::sync::Arc::new(Readings::new(ctx, fit_idx)));
        let o = std::sync::Arc::new(Observed::new(ctx, cfg, fit_idx, readings));
        if let Ok(mut cache) = ctx.observed.lock() {
            if cache.len() >= OBSERVED_KEPT {
                cache.remove(0);
            }
            cache.push((key, o.clone()));
        }
        o
    }

    fn new(
        ctx: &Context,
        cfg: &Config,
        fit_idx: &[usize],
        readings: std::sync::Arc<Readings>,
    ) -> Observed {
        let ds = ctx.ds;
        let (n, m) = (ds.n, fit_idx.len());
        let r = cfg.floor();
        let rs = cfg.crosstalk.unwrap_or(0.0);
        let cols = ds.cols;
        let mut g2 = vec![0.0; m * n];
        let mut wgt = vec![0.0; m * n];
        let g = &readings.g;
        // Row by row (rows side by side): each row's nodes are one stretch of each array.
        crate::parallel::chunks_mut2(&mut g2, &mut wgt, cols * m, |row, g2, wgt| {
            // The row's crosstalk factor per sample (all 1 without crosstalk).
            let xf: Vec<f64> = if rs > 0.0 {
                (0..m)
                    .map(|j| {
                        let srow: f64 = (0..cols).map(|c| g[(row * cols + c) * m + j]).sum();
                        (1.0 - rs * srow).max(0.05)
                    })
                    .collect()
            } else {
                Vec::new()
            };
            for c in 0..cols {
                let k = row * cols + c;
                for j in 0..m {
                    let at = k * m + j;
                    let xf = xf.get(j).copied().unwrap_or(1.0);
                    // (Without crosstalk `xf` is 1: no division, the same number.)
                    let g1 = if rs > 0.0 { g[at] / xf } else { g[at] };
                    let rg = r * g1;
                    if !readings.usable[at] || rg >= 0.9 {
                        continue;
                    }
                    g2[c * m + j] = g1 / (1.0 - rg);
                    let d = ds.map.ddom_dg(g[at]) * xf * (1.0 - rg).powi(2);
                    wgt[c * m + j] = d * d;
                }
            }
        });
        Observed { g2, wgt, readings }
    }

    /// Node `k`'s reading in the residual domain at the `j`-th of the `m` samples, when usable.
    pub(super) fn dom(&self, k: usize, j: usize, m: usize) -> Option<f64> {
        let at = k * m + j;
        self.readings.usable[at].then(|| self.readings.dom[at])
    }
}

/// One node's local regressors (see [`Terms::local`]) at each sample the fit looks at, computed
/// once per evaluation: the fit's passes and the training SSE read them (the law's basis and the
/// loads are most of an evaluation's time).
pub(super) struct Locals {
    seg: Vec<usize>,
    v: Vec<f64>,
    vdim: usize,
}

impl Locals {
    pub(super) fn new(terms: &Terms, k: usize, fit_idx: &[usize]) -> Locals {
        let vdim = terms.vdim();
        let mut seg = Vec::with_capacity(fit_idx.len());
        let mut v = vec![0.0; fit_idx.len() * vdim];
        for (j, (&i, out)) in fit_idx.iter().zip(v.chunks_exact_mut(vdim)).enumerate() {
            seg.push(terms.local(k, i, j, out));
        }
        Locals { seg, v, vdim }
    }

    /// The segment and local values at the `j`-th sample the fit looks at.
    pub(super) fn at(&self, j: usize) -> (usize, &[f64]) {
        (self.seg[j], &self.v[j * self.vdim..(j + 1) * self.vdim])
    }
}

/// The per-node weighted least squares of one evaluation.
pub(super) struct NodeFit<'a> {
    pub(super) ctx: &'a Context<'a>,
    pub(super) terms: &'a Terms,
    pub(super) obs: &'a Observed,
    /// The samples fitted on.
    pub(super) fit_idx: &'a [usize],
    pub(super) r: f64,
    /// Each group's local regressors, when nodes share them (see [`Terms::group`]; all nodes
    /// one group when [`Terms::node_independent`]): computed once per group, not once per
    /// node. Empty: each node computes its own.
    pub(super) groups: Vec<Arc<Locals>>,
    /// The thermal factor at every sample (1 without a drift).
    pub(super) m: &'a [f64],
    /// Whether `m` is 1 at every sample: the linearisation at the observations then skips
    /// dividing by it (exactly the same sums).
    unit_m: bool,
}

impl<'a> NodeFit<'a> {
    /// The fit of one evaluation's nodes on the samples `fit_idx` (observed as `obs`), with
    /// `cfg`'s resistance floor, the groups' shared local regressors and the thermal factor
    /// `m`.
    pub(super) fn new(
        ctx: &'a Context<'a>,
        cfg: &Config,
        terms: &'a Terms,
        (obs, fit_idx): (&'a Observed, &'a [usize]),
        groups: Vec<Arc<Locals>>,
        m: &'a [f64],
    ) -> NodeFit<'a> {
        NodeFit {
            ctx,
            terms,
            obs,
            fit_idx,
            r: cfg.floor(),
            groups,
            m,
            unit_m: m.iter().all(|&x| x == 1.0),
        }
    }

    /// Node `k`'s linear parameters given the thermal factor. For readouts that are not
    /// linear in conductance (resistance, divider) a few Gauss-Newton passes linearise the
    /// residual domain around the current prediction instead of the observation (whose 1/G^2
    /// weights would favour the highest-resistance samples); the last is left out when the one
    /// before barely moved the fit (see [`GN_STEP_TOL`]). The normal equations are those of
    /// [`NodeFit::block_equations`]. `warm`: the node's parameters from an earlier fit of the
    /// same evaluation (a latent drift or per-trial sensitivities are fitted with the nodes,
    /// alternately); such a readout's fit then starts from them and takes one Gauss-Newton
    /// pass, not the linearisation at the observations and two passes. `linear_only`: the
    /// linearisation at the observations alone, no pass (the alternation's fits before the
    /// last: the factors are fitted at that linearisation too). `reuse`: the node's local
    /// regressors from an earlier fit, when nothing they depend on has changed since. `own`:
    /// the node's per-trial factors, when not those in [`Terms`].
    pub(super) fn node(
        &self,
        k: usize,
        warm: Option<&[f64]>,
        linear_only: bool,
        reuse: Option<&Arc<Locals>>,
        own: Option<&[f64]>,
    ) -> (Vec<f64>, Arc<Locals>) {
        let ds = self.ctx.ds;
        let pdim = self.terms.lay.dim();
        let gn_passes = if linear_only || matches!(ds.map, ReadoutMap::Amplifier { .. }) {
            0
        } else {
            2
        };
        let (mut th, first) = match warm {
            Some(w) if gn_passes > 0 && w.len() == pdim => (w.to_vec(), gn_passes),
            _ => (vec![0.0; pdim], 0),
        };
        let locals = self.locals(k, reuse);
        let own = match own {
            Some(o) => o.to_vec(),
            None => self.own_factors(k),
        };
        for pass in first..=gn_passes {
            let eqs = self.block_equations(k, &locals, (pass > 0).then_some(&th), &own);
            let (mut a, mut b) = self.combine(eqs, &own);
            // The normal equations as summed (the solver ridges them in place), to measure a
            // Gauss-Newton step by.
            let gram = (pass > 0 && pass < gn_passes).then(|| a.clone());
            let new = self.solve(&mut a, &mut b);
            let converged = gram.is_some_and(|g| step_is_small(&g, &th, &new));
            th = new;
            if converged {
                break;
            }
        }
        (th, locals)
    }

    /// Node `k`'s local regressors: `reuse`d, its group's, or computed.
    pub(super) fn locals(&self, k: usize, reuse: Option<&Arc<Locals>>) -> Arc<Locals> {
        let shared = self.terms.group(k).and_then(|(g, _)| self.groups.get(g));
        match (reuse, shared) {
            (Some(l), _) | (None, Some(l)) => l.clone(),
            (None, None) => Arc::new(Locals::new(self.terms, k, self.fit_idx)),
        }
    }

    /// Node `k`'s own factor in each block (see [`Terms::factor_blocks`]).
    pub(super) fn own_factors(&self, k: usize) -> Vec<f64> {
        (0..self.terms.factor_blocks())
            .map(|t| self.terms.factor_at_block(k, t))
            .collect()
    }

    /// Node `k`'s normal equations per block (see [`Terms::factor_blocks`]; the lower
    /// triangle of the full row's, and the right side), summed per knot segment over the
    /// local values without the node's own factor and then mapped to the full row (one
    /// segment for the power law; see [`crate::law::RowMap`]). At the linearisation at the
    /// observations (`th` none), or a Gauss-Newton pass's at the prediction of `th` with the
    /// node's factor `own` in each block.
    pub(super) fn block_equations(
        &self,
        k: usize,
        locals: &Locals,
        th: Option<&[f64]>,
        own: &[f64],
    ) -> Vec<(Vec<f64>, Vec<f64>)> {
        let ds = self.ctx.ds;
        let lay = &self.terms.lay;
        let pdim = lay.dim();
        let vdim = self.terms.vdim();
        let segments = self.terms.basis.as_ref().map_or(1, Basis::dim);
        let blocks = own.len().max(1);
        let sections = segments * blocks;
        let base = k * self.fit_idx.len();
        let mut s_loc = vec![0.0; sections * vdim * vdim];
        let mut r_loc = vec![0.0; sections * vdim];
        let co = th.map(|th| self.terms.coefs(th));
        for (j, &i) in self.fit_idx.iter().enumerate() {
            let w = self.obs.wgt[base + j];
            if w == 0.0 {
                continue;
            }
            let mi = self.m[i];
            let (seg, v) = locals.at(j);
            let t = if blocks > 1 { self.terms.trials[i] } else { 0 };
            let (z, w) = match &co {
                None if self.unit_m => (self.obs.g2[base + j], w),
                None => (self.obs.g2[base + j] / mi, w * mi * mi),
                Some(co) => {
                    let f = own.get(t).copied().unwrap_or(1.0);
                    let zh = self.terms.z_local_factor(co, seg, v, f).1.max(1e-15);
                    let g = (mi * zh).max(1e-15);
                    let (f0, change) = ds.map.dom_step_g(g, self.r, 1e-4);
                    let d = change / (zh * 1e-4);
                    if !d.is_finite() || d == 0.0 {
                        continue;
                    }
                    (zh + (self.obs.readings.dom[base + j] - f0) / d, d * d)
                }
            };
            let sec = seg * blocks + t;
            let (sa, rb) = (
                &mut s_loc[sec * vdim * vdim..(sec + 1) * vdim * vdim],
                &mut r_loc[sec * vdim..(sec + 1) * vdim],
            );
            accumulate(sa, rb, v, w, z);
        }
        let mut eqs = vec![(vec![0.0; pdim * pdim], vec![0.0; pdim]); blocks];
        for seg in 0..segments {
            let map = RowMap::new(self.terms.basis.as_ref(), seg, lay.law_start() - 1);
            for (t, (a, b)) in eqs.iter_mut().enumerate() {
                let sec = seg * blocks + t;
                map.add(
                    &s_loc[sec * vdim * vdim..(sec + 1) * vdim * vdim],
                    &r_loc[sec * vdim..(sec + 1) * vdim],
                    vdim,
                    a,
                    b,
                );
            }
        }
        eqs
    }

    /// The node's normal equations (full, symmetric) from its blocks' (see
    /// [`NodeFit::block_equations`]), each block's scaled by the node's own factor there on
    /// the regressors it multiplies (the hysteresis terms and the law).
    pub(super) fn combine(
        &self,
        eqs: Vec<(Vec<f64>, Vec<f64>)>,
        own: &[f64],
    ) -> (Vec<f64>, Vec<f64>) {
        let pdim = self.terms.lay.dim();
        let h = self.terms.lay.hyst_index();
        let mut it = eqs.into_iter();
        let (mut a, mut b) = it
            .next()
            .unwrap_or_else(|| (vec![0.0; pdim * pdim], vec![0.0; pdim]));
        if own.len() > 1 {
            let d = |t: usize, u: usize| if u >= h { own[t] } else { 1.0 };
            for u in 0..pdim {
                b[u] *= d(0, u);
                for w in 0..=u {
                    a[u * pdim + w] *= d(0, u) * d(0, w);
                }
            }
            for (t, (at, bt)) in it.enumerate().map(|(t, e)| (t + 1, e)) {
                for u in 0..pdim {
                    b[u] += d(t, u) * bt[u];
                    for w in 0..=u {
                        a[u * pdim + w] += d(t, u) * d(t, w) * at[u * pdim + w];
                    }
                }
            }
        }
        for u in 0..pdim {
            for w in u + 1..pdim {
                a[u * pdim + w] = a[w * pdim + u];
            }
        }
        (a, b)
    }

    /// The per-node normal equations solved: the power law as before (least squares, and a
    /// baseline that came out negative refitted at zero); a spline with its coefficients
    /// non-negative (a monotone law), the same rule for the baseline.
    pub(super) fn solve(&self, a: &mut [f64], b: &mut [f64]) -> Vec<f64> {
        let lay = &self.terms.lay;
        let pdim = lay.dim();
        let constrained: Vec<bool> = (0..pdim).map(|u| u >= lay.law_start()).collect();
        let solve = |a: &[f64], b: &[f64]| {
            if self.terms.basis.is_some() {
                nnls(a, b, pdim, &constrained)
            } else {
                solve_spd(a, b, pdim)
            }
        };
        ridge(a, pdim, lay.ridged_range());
        let th = solve(a, b);
        if th[0] >= 0.0 {
            return th;
        }
        // A conductance baseline cannot be negative (a constant force, for one, cannot
        // separate it from the gain): refit with the baseline at zero.
        for u in 0..pdim {
            a[u * pdim] = 0.0;
            a[u] = 0.0;
        }
        a[0] = 1.0;
        b[0] = 0.0;
        solve(a, b)
    }

    /// Each trial's sensitivity factor given the nodes' parameters (the force term's share of
    /// the conductance, fitted per trial in closed form on the linearisation of the first
    /// pass), normalised to a mean of 1 over trials.
    pub(super) fn trial_gains(&self, theta: &[Vec<f64>], trials: usize) -> Vec<f64> {
        let ds = self.ctx.ds;
        let n = ds.n;
        let mut num = vec![0.0; trials];
        let mut den = vec![0.0; trials];
        let coefs: Vec<_> = theta.iter().map(|th| self.terms.coefs(th)).collect();
        // Each node's law and the rest of its conductance at each sample, node by node side by
        // side; then the sums in sample order, as one loop would take them.
        let (len, nodes) = (self.fit_idx.len(), n.min(theta.len()));
        let mut parts = vec![(0.0, 0.0); nodes * len];
        crate::parallel::chunks_mut(&mut parts, len, |k, out| {
            for (jj, (&i, p)) in self.fit_idx.iter().zip(out.iter_mut()).enumerate() {
                if self.obs.wgt[k * len + jj] * self.m[i] * self.m[i] != 0.0 {
                    let q = self.terms.law(&theta[k], k, i, jj);
                    let rest = self.terms.z_coefs(&coefs[k], k, i, jj) - self.terms.s(k, i) * q;
                    *p = (q, rest);
                }
            }
        });
        for (jj, &i) in self.fit_idx.iter().enumerate() {
            let j = ds.trial[i];
            let mi = self.m[i];
            for k in 0..nodes {
                let idx = k * len + jj;
                let w = self.obs.wgt[idx] * mi * mi;
                if w == 0.0 {
                    continue;
                }
                let (q, rest) = parts[idx];
                num[j] += w * q * (self.obs.g2[idx] / mi - rest);
                den[j] += w * q * q;
            }
        }
        let mut g: Vec<f64> = num
            .iter()
            .zip(&den)
            .map(|(a, b)| {
                if *b > 0.0 {
                    (a / b).clamp(0.05, 20.0)
                } else {
                    1.0
                }
            })
            .collect();
        let mean = g.iter().sum::<f64>() / trials.max(1) as f64;
        if mean > 0.0 {
            g.iter_mut().for_each(|v| *v /= mean);
        }
        g
    }

    /// The latent common-mode factor at `knots` given the nodes' parameters, normalised to a
    /// mean of 1.
    pub(super) fn latent(&self, knots: &[f64], theta: &[Vec<f64>]) -> Vec<f64> {
        let ds = self.ctx.ds;
        let n = ds.n;
        let kk = knots.len();
        let mut a = vec![0.0; kk * kk];
        let mut b = vec![0.0; kk];
        let coefs: Vec<_> = theta.iter().map(|th| self.terms.coefs(th)).collect();
        // Each node's conductance before the factor at each sample, node by node side by side;
        // then the sums in sample order, as one loop would take them.
        let (len, nodes) = (self.fit_idx.len(), n.min(coefs.len()));
        let mut qs = vec![0.0; nodes * len];
        crate::parallel::chunks_mut(&mut qs, len, |k, out| {
            for (jj, (&i, q)) in self.fit_idx.iter().zip(out.iter_mut()).enumerate() {
                if self.obs.wgt[k * len + jj] != 0.0 {
                    *q = self.terms.z_coefs(&coefs[k], k, i, jj);
                }
            }
        });
        for (jj, &i) in self.fit_idx.iter().enumerate() {
            let (j, w) = hat(knots, ds.t[i]);
            for k in 0..nodes {
                let idx = k * len + jj;
                let wt = self.obs.wgt[idx];
                if wt == 0.0 {
                    continue;
                }
                let q = qs[idx];
                let phi = [(j, (1.0 - w) * q), (j + 1, w * q)];
                for &(u, xu) in &phi {
                    if u >= kk {
                        continue;
                    }
                    b[u] += wt * xu * self.obs.g2[idx];
                    for &(v, xv) in &phi {
                        if v < kk {
                            a[u * kk + v] += wt * xu * xv;
                        }
                    }
                }
            }
        }
        super::latent::latent_values(a, b, kk)
    }
}

/// A Gauss-Newton step from `old` to `new` is small when it moves the node's fitted values by
/// less than [`GN_STEP_TOL`] of their size, both measured in the weighted norm of the normal
/// equations `gram` (`pdim` x `pdim`, full): `|new - old|_A <= tol |new|_A`.
fn step_is_small(gram: &[f64], old: &[f64], new: &[f64]) -> bool {
    let quad = |x: &dyn Fn(usize) -> f64| -> f64 {
        let p = new.len();
        (0..p)
            .map(|u| x(u) * (0..p).map(|v| gram[u * p + v] * x(v)).sum::<f64>())
            .sum()
    };
    let step = quad(&|u| new[u] - old[u]);
    let size = quad(&|u| new[u]);
    step.is_finite() && size.is_finite() && step <= GN_STEP_TOL * GN_STEP_TOL * size
}

/// Adds the ridge of [`super::SET_RIDGE`] (a share of the intercept's weight, `a[0]`) to
/// the diagonal of the normal equations `a` (`pdim` x `pdim`) at the amplitudes `range`.
fn ridge(a: &mut [f64], pdim: usize, range: std::ops::Range<usize>) {
    let lam = super::SET_RIDGE * a[0];
    for u in range {
        a[u * pdim + u] += lam;
    }
}

/// Adds one weighted observation `z` with regressors `xrow` to the lower triangle of the
/// normal equations `a` and to `b`.
fn accumulate(a: &mut [f64], b: &mut [f64], xrow: &[f64], w: f64, z: f64) {
    // The usual sizes unrolled at compile time (the same sums in the same order).
    match xrow.len() {
        2 => accumulate_n::<2>(a, b, xrow, w, z),
        3 => accumulate_n::<3>(a, b, xrow, w, z),
        4 => accumulate_n::<4>(a, b, xrow, w, z),
        5 => accumulate_n::<5>(a, b, xrow, w, z),
        6 => accumulate_n::<6>(a, b, xrow, w, z),
        _ => accumulate_any(a, b, xrow, w, z),
    }
}

/// [`accumulate`] for `P` regressors.
#[inline(always)]
fn accumulate_n<const P: usize>(a: &mut [f64], b: &mut [f64], xrow: &[f64], w: f64, z: f64) {
    let (Some(a), Some(b), Some(x)) = (a.get_mut(..P * P), b.get_mut(..P), xrow.get(..P)) else {
        return accumulate_any(a, b, xrow, w, z);
    };
    for u in 0..P {
        let xu = x[u];
        if xu == 0.0 {
            continue;
        }
        let wx = w * xu;
        b[u] += wx * z;
        for v in 0..=u {
            a[u * P + v] += wx * x[v];
        }
    }
}

fn accumulate_any(a: &mut [f64], b: &mut [f64], xrow: &[f64], w: f64, z: f64) {
    let pdim = xrow.len();
    for u in 0..pdim {
        if xrow[u] == 0.0 {
            continue;
        }
        b[u] += w * xrow[u] * z;
        for v in 0..=u {
            a[u * pdim + v] += w * xrow[u] * xrow[v];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gauss_newton_step_is_measured_in_fitted_values_not_parameters() {
        // A large intercept and a small gain on a regressor a thousand times larger: a step
        // of 10 % in the gain is 1e-4 of the parameters' size but moves the fitted values by
        // about 7 % of theirs.
        let gram = [1.0, 0.0, 0.0, 1e6];
        let (old, new) = ([1.0, 0.001], [1.0, 0.0011]);
        assert!(!step_is_small(&gram, &old, &new));
        // A step of 1e-5 of the gain moves them by less than 1e-3.
        assert!(step_is_small(&gram, &old, &[1.0, 0.001 * (1.0 + 1e-5)]));
        // Nothing that did not evaluate counts as converged.
        assert!(!step_is_small(&gram, &old, &[f64::NAN, 0.001]));
    }

    #[test]
    fn the_ridge_keeps_an_unseen_ramp_from_an_arbitrary_amplitude() {
        // Training samples where a set's first ramp is 0.75 + 0.25 x the second (the
        // first press reached three quarters of the first ramp; the rest before it is unseen),
        // and the reading steps by 10 where the second ramp is on.
        let rows: Vec<([f64; 3], f64)> = (0..200)
            .map(|i| {
                let r1 = if i < 50 { 0.0 } else { 1.0 };
                ([1.0, 0.75 + 0.25 * r1, r1], 100.0 + 10.0 * r1)
            })
            .collect();
        let (mut a, mut b) = (vec![0.0; 9], vec![0.0; 3]);
        for (x, y) in &rows {
            accumulate(&mut a, &mut b, x, 1.0, *y);
        }
        for u in 0..3 {
            for w in u + 1..3 {
                a[u * 3 + w] = a[w * 3 + u];
            }
        }
        // The unseen rest (both ramps 0): without the ridge the solver puts an arbitrary split
        // of the step on the two ramps and predicts far from any level seen; with it, about
        // the level before the step (the smallest amplitudes that fit).
        let plain = solve_spd(&a, &b, 3);
        ridge(&mut a, 3, 1..3);
        let ridged = solve_spd(&a, &b, 3);
        assert!((plain[0] - 100.0).abs() > 20.0, "{plain:?}");
        assert!((ridged[0] - 100.0).abs() < 3.0, "{ridged:?}");
        // Both fit the training samples.
        for th in [&plain, &ridged] {
            let fit = |x: &[f64; 3]| th.iter().zip(x).map(|(t, v)| t * v).sum::<f64>();
            assert!(rows.iter().all(|(x, y)| (fit(x) - y).abs() < 0.1), "{th:?}");
        }
    }
}
