//! The diagnosis's forward model: the simulator's physics, written so that every per-node
//! parameter is fitted by weighted linear least squares inside each evaluation and only a few
//! global parameters (force-law exponent, resistance floor, and each effect's own) are searched.
//!
//! Per node `k` and sample `i`: load `L = F` (shifted in time by scan skew, passed through the
//! hysteresis, play operators or a Bouc-Wen state, and the creep low-pass), `p = L^n`;
//! conductance `G = m_i (b_k + [c_k kappa_i] + a_k s_i p)` with the thermal factor `m`, the
//! curvature sensitivity `s` and the curvature baseline term; then the resistance floor
//! `G / (1 + r G)`, the row crosstalk `G (1 - Rs sum_row G)`, and the readout.

use crate::context::Context;
use crate::data::ReadoutMap;
use crate::effects::{Config, Thermal};
use crate::forms::{bouc_wen_load, load_series, max_scan_skew, Knee};
use crate::law::{Basis, Law, RowMap};
pub use crate::numeric::{centre_by_level, play_gap, solve_spd};
use crate::numeric::{hat, lowpass, nnls, PowTable};
use crate::preisach::Preisach;

/// Result of one evaluation.
pub struct Eval {
    /// Predicted reading in the residual domain, sample-major.
    pub pred: Vec<f64>,
    /// Per-node linear parameters: intercept(s), [curvature slope], gain.
    pub theta: Vec<Vec<f64>>,
    /// Thermal factor per sample (1 without thermal drift).
    pub m: Vec<f64>,
    /// The latent thermal values at the knots after fitting (if latent).
    pub latent: Option<Vec<f64>>,
    /// The per-trial sensitivities after fitting (if the sensitivity is per trial).
    pub trial_gains: Option<Vec<f64>>,
    /// Training SSE (only when predictions were not requested).
    pub train_sse: f64,
}

/// Evaluates `cfg`: fits the per-node linear parameters on the samples where `train(i)` is
/// true and predicts every sample.
pub fn evaluate(ctx: &Context, cfg: &Config, train: &dyn Fn(usize) -> bool) -> Eval {
    evaluate_with(ctx, cfg, train, 1, true)
}

/// As [`evaluate`], predicting only the samples it does not train on (the others are 0): what
/// a cross-validation fold needs.
pub fn evaluate_held_out(ctx: &Context, cfg: &Config, train: &dyn Fn(usize) -> bool) -> Eval {
    evaluate_inner(ctx, cfg, train, 1, true, true)
}

/// As [`evaluate`], fitting on every `stride`-th training sample; with `want_pred` false only
/// the training SSE over those samples is computed (`Eval::train_sse`; `pred` stays empty).
pub fn evaluate_with(
    ctx: &Context,
    cfg: &Config,
    train: &dyn Fn(usize) -> bool,
    stride: usize,
    want_pred: bool,
) -> Eval {
    evaluate_inner(ctx, cfg, train, stride, want_pred, false)
}

fn evaluate_inner(
    ctx: &Context,
    cfg: &Config,
    train: &dyn Fn(usize) -> bool,
    stride: usize,
    want_pred: bool,
    held_out_only: bool,
) -> Eval {
    let stride = stride.max(1);
    let ds = ctx.ds;
    let (len, n) = (ds.len(), ds.n);
    let mut dt: Vec<f64> = Vec::with_capacity(len);
    dt.push(ds.dt());
    dt.extend(ds.t.windows(2).map(|w| (w[1] - w[0]).max(1e-9)));
    // The samples the per-node fit looks at.
    let fit_idx: Vec<usize> = (0..len).step_by(stride).filter(|&i| train(i)).collect();
    // The effects' states run on every sample, or, in the search on a long recording, on every
    // `state_stride`-th (the fit's samples lie on that grid).
    let step = ctx.state_stride();
    let step = if !want_pred && stride.is_multiple_of(step) {
        step
    } else {
        1
    };
    let mut terms = Terms::new(ctx, cfg, &fit_idx, want_pred, step);
    let (mut m, mut latent) = thermal_factor(ctx, cfg, &dt);
    if cfg.thermal_gain_only && latent.is_none() {
        // The drift scales the force term only: it joins the sensitivity.
        for (s, mi) in terms.sens.iter_mut().zip(m.iter_mut()) {
            *s *= *mi;
            *mi = 1.0;
        }
    }
    let obs = Observed::cached(ctx, cfg, &fit_idx);
    let mut gains = cfg.curv_trials.clone();
    let mut theta = vec![vec![0.0; terms.lay.dim()]; n];
    // A latent drift or per-trial sensitivities are fitted with the nodes, alternately.
    let iterations = if latent.is_some() || gains.is_some() {
        3
    } else {
        1
    };
    for it in 0..iterations {
        if let Some((knots, values)) = &latent {
            apply_latent(ctx, knots, values, &mut m);
        }
        if let Some(g) = &gains {
            terms.sens = ds.trial.iter().map(|&j| g[j]).collect();
        }
        let fit = NodeFit {
            ctx,
            terms: &terms,
            obs: &obs,
            fit_idx: &fit_idx,
            r: cfg.floor(),
        };
        theta = crate::parallel::map(n, |k| fit.node(k, &m));
        if it + 1 == iterations {
            break;
        }
        // Latent thermal: refit the common-mode factor on the knots.
        if let Some((knots, values)) = &mut latent {
            *values = fit.latent(knots, &theta);
        }
        if let Some(g) = &mut gains {
            *g = fit.trial_gains(&theta, &m, g.len());
        }
    }
    let looked: &[usize] = if want_pred { &[] } else { &fit_idx };
    let skip: Vec<bool> = if held_out_only {
        (0..len).map(train).collect()
    } else {
        Vec::new()
    };
    let (pred, train_sse) = predict(ctx, cfg, &terms, &theta, &m, looked, want_pred, &skip);
    Eval {
        pred,
        theta,
        m,
        latent: latent.map(|l| l.1),
        trial_gains: gains,
        train_sse,
    }
}

/// The load each node's force law sees, per node (one series for all nodes unless hysteresis
/// acts in the load path), and its time slopes when scan skew is on: node `k` reads the force
/// `k * dt_node` later in the frame, to first order `p_k(t) = p(t) + k dt_node dp/dt`, and the
/// first node of each row also settles after the row switch, a lag of `scan_settle`.
/// The effects' states run on every `step`-th sample (1 unless a long recording is searched,
/// see [`Context::state_stride`]); the series hold every sample of that grid, or, in the
/// search (`compact`), only the samples the fit looks at, in order.
struct Loads {
    loads: Vec<Vec<f64>>,
    slopes: Vec<Vec<f64>>,
    skew: f64,
    settle: f64,
    cols: usize,
    step: usize,
    compact: bool,
}

/// The grid the effects' states run on: every `step`-th sample's time, interval, force and
/// whether the fit needs its load (all when `None`).
struct Grid<'a> {
    /// The force above which creep that stays with the load counts the load as on.
    on_n: f64,
    t: Vec<f64>,
    dt: Vec<f64>,
    force: std::borrow::Cow<'a, [f64]>,
    need: Option<Vec<bool>>,
}

impl<'a> Grid<'a> {
    fn new(ctx: &'a Context, need: Option<&[bool]>, step: usize) -> Grid<'a> {
        let ds = ctx.ds;
        let t: Vec<f64> = ds.t.iter().step_by(step).copied().collect();
        let mut dt: Vec<f64> = Vec::with_capacity(t.len());
        dt.push(step as f64 * ds.dt());
        dt.extend(t.windows(2).map(|w| (w[1] - w[0]).max(1e-9)));
        let f = &ctx.force_model;
        let force = if step == 1 {
            std::borrow::Cow::Borrowed(&f[..])
        } else {
            std::borrow::Cow::Owned(f.iter().step_by(step).copied().collect())
        };
        let need = need.map(|m| m.iter().step_by(step).copied().collect());
        Grid {
            on_n: 0.05 * ds.max_force(),
            t,
            dt,
            force,
            need,
        }
    }

    /// The load series of the load `f` (see [`load_series`]) and its largest value.
    fn series(&self, f: impl Iterator<Item = f64>, cfg: &Config, tau_max: f64) -> Vec<f64> {
        let mut p = Vec::with_capacity(self.t.len());
        load_series(
            f,
            &self.dt,
            cfg,
            tau_max,
            self.on_n,
            self.need.as_deref(),
            &mut p,
        );
        p
    }
}

impl Loads {
    fn new(ctx: &Context, cfg: &Config, skew: f64, need: Option<&[bool]>, step: usize) -> Loads {
        let ds = ctx.ds;
        let len = ds.len();
        let grid = Grid::new(ctx, need, step);
        let tau_max = ctx.creep_tau_max;
        let knee = cfg.hyst_bouc_wen.then(|| Knee::new(cfg.hyst_bw_n));
        let relays = (cfg.hyst_preisach && cfg.hysteresis.is_some()).then(|| {
            let (h0, mu, sigma) = preisach_acting(ctx, cfg);
            Preisach::new(ds.max_force(), h0, mu, sigma)
        });
        let r_max = ctx.hyst_r_max;
        let mut loads: Vec<Vec<f64>> = match (cfg.hysteresis.map(|r| r.min(r_max)), cfg.hyst_share)
        {
            (Some(r), Some(share)) => crate::parallel::map(ctx.load_scale.len(), |k| {
                let sc = ctx.load_scale[k];
                if let Some(relays) = &relays {
                    return grid.series(relays.load(&grid.force, share, sc), cfg, tau_max);
                }
                if let Some(knee) = &knee {
                    let f = bouc_wen_load(&grid.force, r, knee, share, sc, ctx.force_deadband);
                    return grid.series(f, cfg, tau_max);
                }
                // The two play operators of `play_gap`, run inline (no temporary series).
                let (r1, r4) = (r * sc, 4.0 * r * sc);
                let mut z: Option<(f64, f64)> = None;
                let f = grid.force.iter().map(|&fi| {
                    let l = fi.max(0.0);
                    let (a, b) = z.map_or((l + r1, l + r4), |(a, b)| {
                        (a.clamp(l - r1, l + r1), b.clamp(l - r4, l + r4))
                    });
                    z = Some((a, b));
                    fi + share * ((a - l) + cfg.hyst_mix * (b - l))
                });
                grid.series(f, cfg, tau_max)
            }),
            _ => vec![grid.series(grid.force.iter().copied(), cfg, tau_max)],
        };
        // The power law, p = L^n (a spline reads the load itself).
        if cfg.law == Law::Power {
            let l_max = loads
                .iter()
                .map(|p| p.iter().fold(0.0f64, |a, &b| a.max(b)))
                .fold(0.0f64, f64::max);
            let law = PowTable::new(l_max, cfg.exponent);
            for p in loads.iter_mut() {
                p.iter_mut().for_each(|v| *v = law.at(*v));
            }
        }
        let t = &grid.t;
        let slopes: Vec<Vec<f64>> = if skew != 0.0 {
            let m = t.len();
            loads
                .iter()
                .map(|p| {
                    (0..m)
                        .map(|j| {
                            let (a, b) = (j.saturating_sub(1), (j + 1).min(m - 1));
                            let span = t[b] - t[a];
                            if span > 0.0 {
                                (p[b] - p[a]) / span
                            } else {
                                0.0
                            }
                        })
                        .collect()
                })
                .collect()
        } else {
            Vec::new()
        };
        let compact = grid.need.is_some();
        debug_assert!(compact || loads.iter().all(|p| p.len() == len.div_ceil(step)));
        Loads {
            loads,
            slopes,
            skew,
            settle: cfg.scan_settle,
            cols: ds.cols.max(1),
            step,
            compact,
        }
    }

    /// The force-law term `p` (the power law) or the load (a spline) of node `k` at sample `i`
    /// (a multiple of `step`), the `jj`-th the fit looks at.
    fn at(&self, k: usize, i: usize, jj: usize) -> f64 {
        let j = k.min(self.loads.len() - 1);
        let i = if self.compact { jj } else { i / self.step };
        if self.slopes.is_empty() {
            self.loads[j][i]
        } else {
            let lag = if k.is_multiple_of(self.cols) {
                self.settle
            } else {
                0.0
            };
            (self.loads[j][i] + (self.skew * k as f64 - lag) * self.slopes[j][i]).max(0.0)
        }
    }
}

/// The Preisach parameters that act: the median half-width between 3 % of the peak force and
/// the hysteresis bound (`Context::hyst_r_max`), the centres' mean within -10 %..=100 % of the
/// peak and their spread within 5 %..=100 % of it (narrower relays make a staircase in the load,
/// a static law's share; a flat spread of centres makes the plays).
pub fn preisach_acting(ctx: &Context, cfg: &Config) -> (f64, f64, f64) {
    let fmax = ctx.ds.max_force().max(1e-9);
    let h0 = cfg
        .hysteresis
        .unwrap_or(1.0)
        .clamp(0.03 * fmax, ctx.hyst_r_max.max(0.03 * fmax));
    (
        h0,
        cfg.preis_mu.clamp(-0.1 * fmax, fmax),
        cfg.preis_sigma.clamp(0.05 * fmax, fmax),
    )
}

/// The regressors of the per-node linear fit: the loads, the curvature sensitivity per sample,
/// the additive hysteresis term and the curvature-baseline regressor, the spline's basis (with
/// a spline law), and where each sits in `theta`.
struct Terms {
    lay: Layout,
    loads: Loads,
    basis: Option<Basis>,
    sens: Vec<f64>,
    hyst: Vec<f64>,
    curv_x: Vec<f64>,
}

impl Terms {
    fn new(ctx: &Context, cfg: &Config, fit_idx: &[usize], want_pred: bool, step: usize) -> Terms {
        let ds = ctx.ds;
        let skew = cfg.scan_skew.map_or(0.0, |v| v.min(max_scan_skew(ds)));
        // The slopes scan skew needs read the neighbours of each sample.
        let need: Option<Vec<bool>> = (!want_pred && skew == 0.0).then(|| {
            let mut need = vec![false; ds.len()];
            fit_idx.iter().for_each(|&i| need[i] = true);
            need
        });
        let loads = Loads::new(ctx, cfg, skew, need.as_deref(), step);
        let sens = sensitivity(ctx, cfg);
        let curv_x = curvature_regressor(ctx, cfg);
        let hyst = additive_hysteresis(ctx, cfg);
        let basis = match cfg.law {
            Law::Power => None,
            Law::Spline(m) => Some(Basis::new(m, ds.max_force())),
        };
        let lay = Layout {
            n_int: 1,
            curv_k: cfg.curv_base,
            hyst: !hyst.is_empty(),
            law: cfg.law.per_node(),
        };
        Terms {
            lay,
            loads,
            basis,
            sens,
            hyst,
            curv_x,
        }
    }

    /// The number of local values (see [`Terms::local`]).
    fn vdim(&self) -> usize {
        self.lay.law_start() + if self.basis.is_some() { 3 } else { 1 }
    }

    /// Node `k`'s local regressors at sample `i`, the `j`-th the fit looks at (written into
    /// `v`, [`Terms::vdim`] long: 1, the curvature-baseline and hysteresis regressors, and the
    /// law's value (power) or the sensitivity and the two values that vary within the load's
    /// knot segment (spline), see [`crate::law::RowMap`]); returns the segment.
    fn local(&self, k: usize, i: usize, j: usize, v: &mut [f64]) -> usize {
        v[0] = 1.0;
        if self.lay.curv_k {
            v[self.lay.n_int] = self.curv_x[i];
        }
        if self.lay.hyst {
            v[self.lay.hyst_index()] = self.sens[i] * self.hyst[i];
        }
        let o = self.lay.law_start();
        let l = self.loads.at(k, i, j);
        match &self.basis {
            None => {
                v[o] = self.sens[i] * l;
                0
            }
            Some(b) => {
                let (s, a, c) = b.local(l);
                v[o] = self.sens[i];
                v[o + 1] = self.sens[i] * a;
                v[o + 2] = self.sens[i] * c;
                s
            }
        }
    }

    /// The prediction `theta . x` from local values `v` in segment `s`.
    fn z_local(&self, th: &[f64], s: usize, v: &[f64]) -> f64 {
        let o = self.lay.law_start();
        let z: f64 = th[..o].iter().zip(&v[..o]).map(|(t, x)| t * x).sum();
        match &self.basis {
            None => z + th[o] * v[o],
            Some(b) => {
                let c = &th[o..];
                let below: f64 = c[..s].iter().zip(b.full()).map(|(c, f)| c * f).sum();
                z + v[o] * below + c[s] * v[o + 1] + c.get(s + 1).map_or(0.0, |cn| cn * v[o + 2])
            }
        }
    }

    /// Node `k`'s static law at sample `i` (the `j`-th the fit looks at), before the
    /// sensitivity factor.
    fn law(&self, th: &[f64], k: usize, i: usize, j: usize) -> f64 {
        let l = self.loads.at(k, i, j);
        match &self.basis {
            None => th[self.lay.law_start()] * l,
            Some(b) => b.value(&th[self.lay.law_start()..], l),
        }
    }

    /// Node `k`'s conductance before the thermal factor at sample `i` (the `j`-th the fit looks
    /// at), with parameters `th`.
    fn z(&self, th: &[f64], k: usize, i: usize, j: usize) -> f64 {
        let hv = if self.lay.hyst {
            self.sens[i] * self.hyst[i]
        } else {
            0.0
        };
        let cx = if self.lay.curv_k { self.curv_x[i] } else { 0.0 };
        let l = self.loads.at(k, i, j);
        let mut z = th[0];
        if self.lay.curv_k {
            z += th[self.lay.n_int] * cx;
        }
        if self.lay.hyst {
            z += th[self.lay.hyst_index()] * hv;
        }
        match &self.basis {
            None => z + th[self.lay.law_start()] * (self.sens[i] * l),
            Some(b) => z + self.sens[i] * b.value(&th[self.lay.law_start()..], l),
        }
    }
}

/// Curvature sensitivity per sample: `1 / (1 + kappa / kappa_s)` or `1 - kappa / kappa_0`,
/// with the trial's no-load shift in place of the curvature when there is no curvature column.
fn sensitivity(ctx: &Context, cfg: &Config) -> Vec<f64> {
    let ds = ctx.ds;
    let form = |x: f64| -> f64 {
        if cfg.curv_linear {
            (1.0 - x).max(0.05)
        } else {
            1.0 / (1.0 + x).max(0.05)
        }
    };
    if let Some(g) = &cfg.curv_trials {
        return ds.trial.iter().map(|&j| g[j]).collect();
    }
    match (cfg.curv_sens, &ds.kappa) {
        (Some(ks), Some(kappa)) => kappa
            .iter()
            .map(|&k| form(k.max(0.0) / ks.max(1e-6)))
            .collect(),
        (Some(beta), None) => ds
            .trial
            .iter()
            .map(|&j| form(beta * ctx.trial_shift[j]))
            .collect(),
        _ => vec![1.0; ds.len()],
    }
}

/// The thermal factor per sample from the recorded temperature, or all ones and the latent
/// knots (fitted with the nodes) when the drift is latent.
#[allow(clippy::type_complexity)]
fn thermal_factor(
    ctx: &Context,
    cfg: &Config,
    dt: &[f64],
) -> (Vec<f64>, Option<(Vec<f64>, Vec<f64>)>) {
    let ds = ctx.ds;
    let len = ds.len();
    let mut m = vec![1.0; len];
    let mut latent: Option<(Vec<f64>, Vec<f64>)> = None;
    match &cfg.thermal {
        Some(Thermal::Recorded { alpha_per_k, tau_s }) => {
            if let Some(temp) = &ds.temp {
                let t0 = temp.iter().sum::<f64>() / len as f64;
                let ts = lowpass(temp, dt, *tau_s);
                for (mi, t) in m.iter_mut().zip(&ts) {
                    *mi = (1.0 + alpha_per_k * (t - t0)).max(0.05);
                }
            }
        }
        Some(Thermal::Latent { knots_s, values }) => {
            latent = Some((knots_s.clone(), values.clone()));
        }
        None => {}
    }
    (m, latent)
}

/// The latent thermal factor at every sample, piecewise linear through `values` at `knots`.
fn apply_latent(ctx: &Context, knots: &[f64], values: &[f64], m: &mut [f64]) {
    for (i, mi) in m.iter_mut().enumerate() {
        let (j, w) = hat(knots, ctx.ds.t[i]);
        let v = if knots.len() < 2 {
            values[0]
        } else {
            values[j] * (1.0 - w) + values[j + 1] * w
        };
        *mi = v.max(0.05);
    }
}

/// Curvature baseline: a per-node slope on the curvature, or, without a curvature column, on
/// the trial's common no-load shift (the curvature's footprint: rank one in trial x node).
fn curvature_regressor(ctx: &Context, cfg: &Config) -> Vec<f64> {
    let ds = ctx.ds;
    if cfg.curv_base {
        match &ds.kappa {
            Some(k) => k.clone(),
            None => ds.trial.iter().map(|&j| ctx.trial_shift[j]).collect(),
        }
    } else {
        Vec::new()
    }
}

/// Hysteresis: two play operators (half-widths r and 4 r) mixed by one global weight, so the
/// loop's shape (sharp or rounded corners) is fitted, not assumed; one amplitude per node. The
/// gap is centred on its mean at the same force level, so the term only carries the difference
/// between branches (a loop), never a level-dependent offset the static law should carry.
fn additive_hysteresis(ctx: &Context, cfg: &Config) -> Vec<f64> {
    match cfg.hysteresis.map(|r| r.min(ctx.hyst_r_max)) {
        Some(r) if cfg.hyst_share.is_none() => {
            let narrow = play_gap(&ctx.force_model, r);
            let wide = play_gap(&ctx.force_model, 4.0 * r);
            let mixed = narrow
                .iter()
                .zip(&wide)
                .map(|(a, b)| a + cfg.hyst_mix * b)
                .collect();
            centre_by_level(&ctx.force_model, mixed)
        }
        _ => Vec::new(),
    }
}

/// The observed conductance undone through the crosstalk and the floor (`g2`), with the weight
/// of each observation in the residual domain (0: unusable), at the fit's samples only, node
/// by node (`k * m + j` for the `j`-th of `m` samples: each node's fit reads its own run).
pub struct Observed {
    g2: Vec<f64>,
    wgt: Vec<f64>,
}

/// What [`Observed`] depends on: the samples (their count, first and sum) and the floor and
/// switch resistance it was undone through.
pub type ObservedKey = (usize, usize, usize, u64, u64);

impl Observed {
    /// [`Observed::new`], kept in the context for the next evaluation with the same samples,
    /// floor and crosstalk (most evaluations of a search change neither).
    fn cached(ctx: &Context, cfg: &Config, fit_idx: &[usize]) -> std::sync::Arc<Observed> {
        let key: ObservedKey = (
            fit_idx.len(),
            fit_idx.first().copied().unwrap_or(0),
            fit_idx.iter().sum(),
            cfg.floor().to_bits(),
            cfg.crosstalk.unwrap_or(0.0).to_bits(),
        );
        if let Ok(cache) = ctx.observed.lock() {
            if let Some((_, o)) = cache.iter().find(|(k, _)| *k == key) {
                return o.clone();
            }
        }
        let o = std::sync::Arc::new(Observed::new(ctx, cfg, fit_idx));
        if let Ok(mut cache) = ctx.observed.lock() {
            if cache.len() >= 8 {
                cache.remove(0);
            }
            cache.push((key, o.clone()));
        }
        o
    }

    fn new(ctx: &Context, cfg: &Config, fit_idx: &[usize]) -> Observed {
        let ds = ctx.ds;
        let n = ds.n;
        let r = cfg.floor();
        let rs = cfg.crosstalk.unwrap_or(0.0);
        let (rows, cols) = (ds.rows, ds.cols);
        let mut g2 = vec![0.0; fit_idx.len() * n];
        let mut wgt = vec![0.0; fit_idx.len() * n];
        for (j, &i) in fit_idx.iter().enumerate() {
            for row in 0..rows {
                let base = i * n + row * cols;
                let srow: f64 = if rs > 0.0 {
                    ctx.g_obs[base..base + cols].iter().sum()
                } else {
                    0.0
                };
                let xf = (1.0 - rs * srow).max(0.05);
                for c in 0..cols {
                    let idx = base + c;
                    let g1 = ctx.g_obs[idx] / xf;
                    let rg = r * g1;
                    if !ctx.usable[idx] || rg >= 0.9 {
                        continue;
                    }
                    let out = (row * cols + c) * fit_idx.len() + j;
                    g2[out] = g1 / (1.0 - rg);
                    let d = ds.map.ddom_dg(ctx.g_obs[idx]) * xf * (1.0 - rg).powi(2);
                    wgt[out] = d * d;
                }
            }
        }
        Observed { g2, wgt }
    }
}

/// The per-node weighted least squares of one evaluation.
struct NodeFit<'a> {
    ctx: &'a Context<'a>,
    terms: &'a Terms,
    obs: &'a Observed,
    /// The samples fitted on.
    fit_idx: &'a [usize],
    r: f64,
}

impl NodeFit<'_> {
    /// Node `k`'s linear parameters given the thermal factor `m`. For readouts that are not
    /// linear in conductance (resistance, divider) a few Gauss-Newton passes linearise the
    /// residual domain around the current prediction instead of the observation (whose 1/G^2
    /// weights would favour the highest-resistance samples). The normal equations are summed
    /// per knot segment over the local regressors and then mapped to the full row (one
    /// segment for the power law; see [`crate::law::RowMap`]).
    fn node(&self, k: usize, m: &[f64]) -> Vec<f64> {
        let ds = self.ctx.ds;
        let n = ds.n;
        let lay = &self.terms.lay;
        let pdim = lay.dim();
        let vdim = self.terms.vdim();
        let segments = self.terms.basis.as_ref().map_or(1, Basis::dim);
        let gn_passes = if matches!(ds.map, ReadoutMap::Amplifier { .. }) {
            0
        } else {
            2
        };
        let mut th = vec![0.0; pdim];
        let mut v = vec![0.0; vdim];
        let base = k * self.fit_idx.len();
        for pass in 0..=gn_passes {
            let mut s_loc = vec![0.0; segments * vdim * vdim];
            let mut r_loc = vec![0.0; segments * vdim];
            for (j, &i) in self.fit_idx.iter().enumerate() {
                let w = self.obs.wgt[base + j];
                if w == 0.0 {
                    continue;
                }
                let mi = m[i];
                let seg = self.terms.local(k, i, j, &mut v);
                let (z, w) = if pass == 0 {
                    (self.obs.g2[base + j] / mi, w * mi * mi)
                } else {
                    let zh = self.terms.z_local(&th, seg, &v).max(1e-15);
                    let dom_of = |z: f64| {
                        let g = (mi * z).max(1e-15);
                        ds.map.dom(ds.map.from_g(g / (1.0 + self.r * g)))
                    };
                    let f0 = dom_of(zh);
                    let d = (dom_of(zh * (1.0 + 1e-4)) - f0) / (zh * 1e-4);
                    if !d.is_finite() || d == 0.0 {
                        continue;
                    }
                    (zh + (self.ctx.dom_obs[i * n + k] - f0) / d, d * d)
                };
                let (sa, rb) = (
                    &mut s_loc[seg * vdim * vdim..(seg + 1) * vdim * vdim],
                    &mut r_loc[seg * vdim..(seg + 1) * vdim],
                );
                accumulate(sa, rb, &v, w, z);
            }
            let mut a = vec![0.0; pdim * pdim];
            let mut b = vec![0.0; pdim];
            for seg in 0..segments {
                let map = RowMap::new(self.terms.basis.as_ref(), seg, lay.law_start() - 1);
                map.add(
                    &s_loc[seg * vdim * vdim..(seg + 1) * vdim * vdim],
                    &r_loc[seg * vdim..(seg + 1) * vdim],
                    vdim,
                    &mut a,
                    &mut b,
                );
            }
            for u in 0..pdim {
                for w in u + 1..pdim {
                    a[u * pdim + w] = a[w * pdim + u];
                }
            }
            th = self.solve(&mut a, &mut b);
        }
        th
    }

    /// The per-node normal equations solved: the power law as before (least squares, and a
    /// baseline that came out negative refitted at zero); a spline with its coefficients
    /// non-negative (a monotone law), the same rule for the baseline.
    fn solve(&self, a: &mut [f64], b: &mut [f64]) -> Vec<f64> {
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
    fn trial_gains(&self, theta: &[Vec<f64>], m: &[f64], trials: usize) -> Vec<f64> {
        let ds = self.ctx.ds;
        let n = ds.n;
        let mut num = vec![0.0; trials];
        let mut den = vec![0.0; trials];
        for (jj, &i) in self.fit_idx.iter().enumerate() {
            let j = ds.trial[i];
            let mi = m[i];
            for (k, th) in theta.iter().enumerate().take(n) {
                let idx = k * self.fit_idx.len() + jj;
                let w = self.obs.wgt[idx] * mi * mi;
                if w == 0.0 {
                    continue;
                }
                let q = self.terms.law(th, k, i, jj);
                let rest = self.terms.z(th, k, i, jj) - self.terms.sens[i] * q;
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
    fn latent(&self, knots: &[f64], theta: &[Vec<f64>]) -> Vec<f64> {
        let ds = self.ctx.ds;
        let n = ds.n;
        let kk = knots.len();
        let mut a = vec![0.0; kk * kk];
        let mut b = vec![0.0; kk];
        for (jj, &i) in self.fit_idx.iter().enumerate() {
            let (j, w) = hat(knots, ds.t[i]);
            for (k, th) in theta.iter().enumerate().take(n) {
                let idx = k * self.fit_idx.len() + jj;
                let wt = self.obs.wgt[idx];
                if wt == 0.0 {
                    continue;
                }
                let q = self.terms.z(th, k, i, jj);
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
        // A light pull towards 1 keeps knots without training data at 1.
        let diag = (0..kk).map(|u| a[u * kk + u]).fold(0.0, f64::max) * 1e-4 + 1e-300;
        for u in 0..kk {
            a[u * kk + u] += diag;
            b[u] += diag;
        }
        let mut v = solve_spd(&a, &b, kk);
        let mean = v.iter().sum::<f64>() / kk as f64;
        if mean > 0.0 {
            v.iter_mut().for_each(|x| *x /= mean);
        }
        v
    }
}

/// Adds one weighted observation `z` with regressors `xrow` to the lower triangle of the
/// normal equations `a` and to `b`.
fn accumulate(a: &mut [f64], b: &mut [f64], xrow: &[f64], w: f64, z: f64) {
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

/// The forward prediction of every sample (with `want_pred`; 0 where `skip` holds), or only the
/// SSE over the samples in `looked`. Rows are independent (crosstalk couples the nodes of a row): each
/// row's SSE is summed over samples in order and the rows' sums in row order.
#[allow(clippy::too_many_arguments)]
fn predict(
    ctx: &Context,
    cfg: &Config,
    terms: &Terms,
    theta: &[Vec<f64>],
    m: &[f64],
    looked: &[usize],
    want_pred: bool,
    skip: &[bool],
) -> (Vec<f64>, f64) {
    let ds = ctx.ds;
    let (len, n) = (ds.len(), ds.n);
    let r = cfg.floor();
    let rs = cfg.crosstalk.unwrap_or(0.0);
    let (rows, cols) = (ds.rows, ds.cols);
    let row_of = |row: usize| -> (Vec<f64>, f64) {
        let mut out = if want_pred {
            Vec::with_capacity(len * cols)
        } else {
            Vec::new()
        };
        let mut sse = 0.0;
        let mut gs = vec![0.0; cols];
        let mut one = |i: usize, j: usize| {
            if skip.get(i).copied().unwrap_or(false) {
                out.extend(std::iter::repeat_n(0.0, cols));
                return;
            }
            let mut srow = 0.0;
            for (c, gc) in gs.iter_mut().enumerate() {
                let k = row * cols + c;
                let z = terms.z(&theta[k], k, i, j);
                let g = (m[i] * z).max(1e-12);
                *gc = g / (1.0 + r * g);
                srow += *gc;
            }
            let xf = (1.0 - rs * srow).max(0.05);
            for (c, gc) in gs.iter().enumerate() {
                let idx = i * n + row * cols + c;
                let v = ds.map.dom(ds.map.from_g(gc * xf));
                if want_pred {
                    out.push(v);
                } else if ctx.usable[idx] {
                    sse += (v - ctx.dom_obs[idx]).powi(2);
                }
            }
        };
        if want_pred {
            (0..len).for_each(|i| one(i, i));
        } else {
            looked.iter().enumerate().for_each(|(j, &i)| one(i, j));
        }
        (out, sse)
    };
    let per_row = crate::parallel::map(rows, row_of);
    let train_sse = per_row.iter().map(|r| r.1).sum();
    let mut pred = if want_pred {
        vec![0.0; len * n]
    } else {
        Vec::new()
    };
    if want_pred {
        for (row, (vals, _)) in per_row.iter().enumerate() {
            for i in 0..len {
                let dst = i * n + row * cols;
                pred[dst..dst + cols].copy_from_slice(&vals[i * cols..(i + 1) * cols]);
            }
        }
    }
    (pred, train_sse)
}

/// Where each per-node linear parameter sits in `theta`: the intercept, the curvature-baseline
/// slope (on the curvature, or on the trial's no-load shift), the hysteresis amplitude, and
/// last the static law's parameters (the power law's gain, or a spline's coefficients).
#[derive(Debug, Clone, Copy)]
pub struct Layout {
    pub n_int: usize,
    pub curv_k: bool,
    pub hyst: bool,
    /// The static law's parameters per node.
    pub law: usize,
}

impl Layout {
    pub fn dim(&self) -> usize {
        self.law_start() + self.law
    }

    /// Index of the additive hysteresis amplitude.
    pub fn hyst_index(&self) -> usize {
        self.n_int + usize::from(self.curv_k)
    }

    /// Index of the static law's first parameter.
    pub fn law_start(&self) -> usize {
        self.n_int + usize::from(self.curv_k) + usize::from(self.hyst)
    }
}
