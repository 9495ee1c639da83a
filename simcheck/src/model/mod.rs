//! The diagnosis's forward model: the simulator's physics, written so that every per-node
//! parameter is fitted by weighted linear least squares inside each evaluation and only a few
//! global parameters (force-law exponent, resistance floor, and each effect's own) are searched.
//!
//! Per node `k` and sample `i`: load `L = F` (shifted in time by scan skew, passed through the
//! hysteresis, play operators or a Bouc-Wen state, and the creep low-pass), `p = L^n`;
//! conductance `G = m_i (b_k + [c_k kappa_i] + a_k s_i p)` with the thermal factor `m`, the
//! curvature sensitivity `s` and the curvature baseline term; then the resistance floor
//! `G / (1 + r G)`, the row crosstalk `G (1 - Rs sum_row G)`, and the readout.

mod alternate;
mod factors;
mod fit;
mod latent;
mod loads;
mod terms;

pub use fit::{Observed, ObservedKey};
pub use loads::preisach_acting;

use crate::context::Context;
use crate::effects::{Config, Thermal};
pub use crate::numeric::{centre_by_level, play_gap, solve_spd};
use crate::numeric::{hat, lowpass};
use alternate::fit_rounds;
use fit::Locals;
use terms::Terms;

/// A latent drift's knot values and the per-trial sensitivities (trial `j`, node `k` at
/// `j n + k`) after the first round of an alternation that runs two (see
/// [`evaluate_held_out_rereading`]).
pub type FirstRound = (Option<Vec<f64>>, Option<Vec<f64>>);

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
    /// With [`evaluate_held_out_rereading`], when there are factors to fit: the latent values
    /// and the per-trial sensitivities as the first round left them (the re-read).
    pub first_round: Option<FirstRound>,
    /// Training SSE (only when predictions were not requested).
    pub train_sse: f64,
}

/// Evaluates `cfg`: fits the per-node linear parameters on the samples where `train(i)` is
/// true and predicts every sample.
pub fn evaluate(ctx: &Context, cfg: &Config, train: &dyn Fn(usize) -> bool) -> Eval {
    evaluate_with(ctx, cfg, train, 1, true)
}

/// As [`evaluate`], predicting only the samples it does not train on (the others are 0): what
/// a cross-validation fold needs. The per-node fit looks at every [`Context::held_out_stride`]-th
/// training sample (every one up to [`crate::context::FIT_SAMPLES`] samples).
pub fn evaluate_held_out(ctx: &Context, cfg: &Config, train: &dyn Fn(usize) -> bool) -> Eval {
    evaluate_inner(ctx, cfg, train, ctx.held_out_stride(), true, true, 1)
}

/// As [`evaluate_held_out`] for a configuration straight out of a search, whose fitted factors
/// (a latent drift's knot values, per-trial sensitivities) are still its start's: the factors
/// are first re-read from a fit on the same samples (what [`crate::search::fit`] does at a
/// search's end) and the held-out fit refits them from there. Both in one evaluation, the
/// alternation in two rounds (see `alternate::fit_rounds`), the factors the first round left
/// in [`Eval::first_round`]. The same numbers as the two evaluations to rounding (about 1e-12:
/// a power law's table spans the load at every sample here, at the fit's samples in a fit
/// without predictions).
pub fn evaluate_held_out_rereading(
    ctx: &Context,
    cfg: &Config,
    train: &dyn Fn(usize) -> bool,
) -> Eval {
    evaluate_inner(ctx, cfg, train, ctx.held_out_stride(), true, true, 2)
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
    evaluate_inner(ctx, cfg, train, stride, want_pred, false, 1)
}

fn evaluate_inner(
    ctx: &Context,
    cfg: &Config,
    train: &dyn Fn(usize) -> bool,
    stride: usize,
    want_pred: bool,
    held_out_only: bool,
    rounds: usize,
) -> Eval {
    crate::timing::count_eval();
    let stride = stride.max(1);
    let ds = ctx.ds;
    let len = ds.len();
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
    // The regressors, the thermal factor and the observations side by side (independent).
    let (mut terms, ((mut m, mut latent), obs)) = crate::parallel::join(
        || Terms::new(ctx, cfg, &fit_idx, want_pred, step),
        || {
            crate::parallel::join(
                || thermal_factor(ctx, cfg),
                || Observed::cached(ctx, cfg, &fit_idx),
            )
        },
    );
    if cfg.thermal_gain_only && latent.is_none() {
        // The drift scales the force term only: it joins the sensitivity.
        for (s, mi) in terms.sens.iter_mut().zip(m.iter_mut()) {
            *s *= *mi;
            *mi = 1.0;
        }
    }
    let mut gains = cfg.curv_trials.clone();
    // A latent drift or per-trial sensitivities are fitted with the nodes, alternately: per-node
    // factors alone node by node (see `factors.rs`), the others across the nodes.
    let iterations = if latent.is_some() || gains.is_some() {
        3
    } else {
        1
    };
    let fit_data = (&*obs, &fit_idx[..]);
    let factors = (&mut m, &mut latent, &mut gains);
    let ((theta, locals), first_round) = fit_rounds(
        ctx,
        cfg,
        &mut terms,
        fit_data,
        factors,
        (iterations, rounds),
    );
    let looked: &[usize] = if want_pred { &[] } else { &fit_idx };
    let skip: Vec<bool> = if held_out_only {
        (0..len).map(train).collect()
    } else {
        Vec::new()
    };
    let at = Evaluated {
        obs: &obs,
        terms: &terms,
        m: &m,
        locals: &locals,
        coefs: theta.iter().map(|th| terms.coefs(th)).collect(),
    };
    let (pred, train_sse) = predict(ctx, cfg, &at, looked, want_pred, &skip);
    Eval {
        pred,
        theta,
        m,
        latent: latent.map(|l| l.1),
        trial_gains: gains,
        first_round,
        train_sse,
    }
}

/// The thermal factor per sample from the recorded temperature, or all ones and the latent
/// knots (fitted with the nodes) when the drift is latent.
#[allow(clippy::type_complexity)]
fn thermal_factor(ctx: &Context, cfg: &Config) -> (Vec<f64>, Option<(Vec<f64>, Vec<f64>)>) {
    let ds = ctx.ds;
    let len = ds.len();
    let mut m = vec![1.0; len];
    let mut latent: Option<(Vec<f64>, Vec<f64>)> = None;
    match &cfg.thermal {
        Some(Thermal::Recorded { alpha_per_k, tau_s }) => {
            if let Some(temp) = &ds.temp {
                let t0 = temp.iter().sum::<f64>() / len as f64;
                // Every sample's interval, the first one step: the states' grid at step 1.
                let ts = lowpass(temp, &ctx.state_grid(1).dt, *tau_s);
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

/// What an evaluation's per-node fit left for the prediction: the regressors, each node's
/// parameters, the thermal factor and each node's local regressors at the fit's samples.
struct Evaluated<'a> {
    obs: &'a Observed,
    terms: &'a Terms,
    m: &'a [f64],
    locals: &'a [std::sync::Arc<Locals>],
    /// Each node's parameters as [`terms::Coefs`].
    coefs: Vec<terms::Coefs<'a>>,
}

impl Evaluated<'_> {
    /// Node `k`'s conductance before the thermal factor at sample `i`, the `j`-th the fit looked
    /// at when `fitted` (read from its local regressors).
    fn z(&self, k: usize, i: usize, j: usize, fitted: bool) -> f64 {
        match self.locals.get(k) {
            Some(l) if fitted => {
                let (seg, v) = l.at(j);
                let f = self.terms.factor_at(k, i).1;
                self.terms.z_local_factor(&self.coefs[k], seg, v, f).1
            }
            _ => self.terms.z_coefs(&self.coefs[k], k, i, j),
        }
    }
}

/// The forward prediction of every sample (with `want_pred`; 0 where `skip` holds), or only the
/// SSE over the samples in `looked` (the fit's samples). Rows are independent (crosstalk couples
/// the nodes of a row): each row's SSE is summed over samples in order and the rows' sums in row
/// order.
fn predict(
    ctx: &Context,
    cfg: &Config,
    at: &Evaluated,
    looked: &[usize],
    want_pred: bool,
    skip: &[bool],
) -> (Vec<f64>, f64) {
    let m = at.m;
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
                let z = at.z(k, i, j, !want_pred);
                let g = (m[i] * z).max(1e-12);
                *gc = g / (1.0 + r * g);
                srow += *gc;
            }
            let xf = (1.0 - rs * srow).max(0.05);
            for (c, gc) in gs.iter().enumerate() {
                let v = ds.map.dom(ds.map.from_g(gc * xf));
                if want_pred {
                    out.push(v);
                } else if let Some(y) = at.obs.dom(row * cols + c, j, looked.len()) {
                    sse += (v - y).powi(2);
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

/// The ridge on a hysteresis set's ramp amplitudes ([`Config::hyst_set`]), as a share of the
/// intercept's weight (the training samples' total weight). A set is a function of the
/// largest force so far, and the levels that takes are contiguous spans of time: a fold that
/// never saw a span (the rest before the first press, a first rise to a new peak) cannot tell
/// some ramps from the intercept or from each other, and an unpenalised solve then puts an
/// arbitrary amplitude on them that the held-out span pays for in full (hundreds of counts on
/// world B's mm_creep_hysteresis, with the remnant's ramps). The ridge makes such a direction
/// take the smallest amplitudes that fit (no set where none was seen); it shrinks a ramp the
/// data support by about `SET_RIDGE` over the share of the samples that support it, so a
/// resolution only. The remnant's own ramps ([`Config::hyst_remnant`]) are not ridged: that
/// moved zoo-hys's loop on training seed 2 enough for creep to be named beside it.
pub const SET_RIDGE: f64 = 1e-3;

/// Where each per-node linear parameter sits in `theta`: the intercept, the curvature-baseline
/// slope (on the curvature, or on the trial's no-load shift), the hysteresis amplitude, and
/// last the static law's parameters (the power law's gain, or a spline's coefficients).
#[derive(Debug, Clone, Copy)]
pub struct Layout {
    pub n_int: usize,
    pub curv_k: bool,
    /// The additive hysteresis regressors (0, 1, or 2 for the additive Bouc-Wen; with a
    /// remnant, its ramps too).
    pub hyst: usize,
    /// How many of the last `hyst` regressors are a set's ramps (ridged, see
    /// [`SET_RIDGE`]).
    pub ridged: usize,
    /// The static law's parameters per node.
    pub law: usize,
}

impl Layout {
    pub fn dim(&self) -> usize {
        self.law_start() + self.law
    }

    /// Index of the (first) additive hysteresis amplitude.
    pub fn hyst_index(&self) -> usize {
        self.n_int + usize::from(self.curv_k)
    }

    /// The indices of the ridged amplitudes (a set's ramps).
    pub fn ridged_range(&self) -> std::ops::Range<usize> {
        self.law_start() - self.ridged..self.law_start()
    }

    /// Index of the static law's first parameter.
    pub fn law_start(&self) -> usize {
        self.n_int + usize::from(self.curv_k) + self.hyst
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_node_gets_its_own_sensitivity_in_each_trial() {
        // Through the amplifier (linear in conductance: no Gauss-Newton passes) and through a
        // falling divider (whose alternation's first fit takes none, the next two one each).
        let amplifier =
            crate::data::ReadoutMap::from_readout(&taxel_sim::SensorModel::default().readout);
        let divider = crate::data::ReadoutMap::Divider {
            max: 4095.0,
            r_ref: 10_000.0,
            rises: false,
        };
        // The fit's RMS bound: on the divider the fit leaves about 2 counts (0.05 % of its
        // range; the same, to six digits, before the alternation's first fit took no pass).
        // Not the alternation's: twelve fits instead of three leave the same 2.047 counts and
        // the same factors to five digits.
        for (map, max_rms) in [(amplifier, 0.1), (divider, 4.0)] {
            per_trial_sensitivities_are_recovered(map, max_rms);
        }
    }

    fn per_trial_sensitivities_are_recovered(map: crate::data::ReadoutMap, max_rms: f64) {
        // Two nodes, three mountings: node 0's sensitivity falls 0.8x in trial 1 and node
        // 1's rises 1.25x in trial 2 (a contact spot that moved).
        let mut ds = crate::testdata::presses_on(1, 2);
        let len = ds.len();
        ds.trial = (0..len).map(|i| i * 3 / len).collect();
        ds.n_trials = 3;
        ds.trial_recorded = true;
        ds.map = map;
        let factor = |j: usize, k: usize| match (j, k) {
            (1, 0) => 0.8,
            (2, 1) => 1.25,
            _ => 1.0,
        };
        ds.y = (0..len * 2)
            .map(|idx| {
                let (i, k) = (idx / 2, idx % 2);
                let g = 20e-6 + 40e-6 * (1.0 + k as f64) * factor(ds.trial[i], k) * ds.force[i];
                ds.map.from_g(g)
            })
            .collect();
        let ctx = Context::new(&ds);
        let cfg = Config {
            curv_trials: Some(vec![1.0; 6]),
            curv_per_node: Some(2),
            ..Config::base(1.0, 0.0)
        };
        let ev = evaluate(&ctx, &cfg, &|_| true);
        let g = ev.trial_gains.expect("per-trial gains");
        // Each node's factors relative to its first trial.
        let rel = |j: usize, k: usize| g[j * 2 + k] / g[k];
        for (j, k) in [(1, 0), (2, 0), (1, 1), (2, 1)] {
            assert!(
                (rel(j, k) - factor(j, k)).abs() < 0.02,
                "{map:?} trial {j} node {k}: {} {g:?}",
                rel(j, k)
            );
        }
        let fit: f64 = ev
            .pred
            .iter()
            .zip(&ds.y)
            .map(|(p, y)| (p - ds.map.dom(*y)).powi(2))
            .sum::<f64>()
            / (2 * len) as f64;
        assert!(fit.sqrt() < max_rms, "{map:?} rms {}", fit.sqrt());
    }

    #[test]
    fn a_shape_every_node_shares_fits_a_saturating_law_the_power_law_cannot() {
        // Two nodes, the same soft saturation `1 - exp(-F / 3)` at different gains.
        let mut ds = crate::testdata::presses_on(1, 2);
        let len = ds.len();
        ds.map = crate::data::ReadoutMap::from_readout(&taxel_sim::SensorModel::default().readout);
        ds.y = (0..len * 2)
            .map(|idx| {
                let (i, k) = (idx / 2, idx % 2);
                let s = 1.0 - (-ds.force[i] / 3.0).exp();
                ds.map.from_g(20e-6 + 200e-6 * (1.0 + k as f64) * s)
            })
            .collect();
        let ctx = Context::new(&ds);
        let all = |_: usize| true;
        let power = crate::search::fit_all(
            &ctx,
            &[Config::base(1.0, 0.0)],
            &[crate::search::Param::LnExponent],
            400,
        );
        let shape = Config {
            law_shape: Some(vec![0.0; 6]),
            ..Config::base(1.0, 0.0)
        };
        let params = crate::search::law_params(&shape);
        assert_eq!(params.len(), 5);
        let shape = crate::search::fit_all(&ctx, &[shape], &params, 1500);
        let (sse_power, sse_shape) = (
            evaluate_with(&ctx, &power, &all, 1, false).train_sse,
            evaluate_with(&ctx, &shape, &all, 1, false).train_sse,
        );
        assert!(
            sse_shape < 0.05 * sse_power,
            "shape {sse_shape} power {sse_power}"
        );
    }

    #[test]
    fn an_additive_loop_is_fitted_as_it_is_not_centred_by_level() {
        // Two nodes, a linear law and an additive Bouc-Wen loop of each node's own strength,
        // read through the amplifier. Every press holds its level for a second, so the loop's
        // mean at each level held has a bump a smooth law cannot carry: the model must fit the
        // loop as the state it is, not the state less its mean by level.
        let mut ds = crate::testdata::presses_on(1, 2);
        let len = ds.len();
        ds.map = crate::data::ReadoutMap::from_readout(&taxel_sim::SensorModel::default().readout);
        let cfg = Config {
            hysteresis: Some(1.5),
            hyst_bouc_wen: true,
            hyst_bw_n: 1.5,
            hyst_bw_asym: -0.6,
            hyst_bw_z0: -1.0,
            ..Config::base(1.0, 0.0)
        };
        let ctx = Context::new(&ds);
        let r = ctx.hyst_r(1.5);
        let z = &crate::forms::bouc_wen_gap(
            &ctx.force_model,
            r,
            &crate::forms::Knee::new(1.5),
            ctx.force_deadband,
            -0.6,
            -1.0,
            1,
        )[0];
        let loop_g = |i: usize, k: usize| 8e-6 * (1.0 + 2.0 * k as f64) * z[i];
        // The baseline keeps the conductance positive at rest in the loop's lowest state.
        ds.y = (0..len * 2)
            .map(|idx| {
                let (i, k) = (idx / 2, idx % 2);
                let g = 60e-6 + 40e-6 * (1.0 + k as f64) * ds.force[i] + loop_g(i, k);
                ds.map.from_g(g)
            })
            .collect();
        let ctx = Context::new(&ds);
        let ev = evaluate(&ctx, &cfg, &|_| true);
        let rms = |v: &mut dyn Iterator<Item = f64>| {
            let (s, c) = v.fold((0.0, 0usize), |(s, c), x| (s + x * x, c + 1));
            (s / c.max(1) as f64).sqrt()
        };
        let misfit = rms(&mut (0..len * 2).map(|idx| ev.pred[idx] - ds.map.dom(ds.y[idx])));
        // The loop's own size in the same units: the reading with and without it.
        let size = rms(&mut (0..len * 2).map(|idx| {
            let (i, k) = (idx / 2, idx % 2);
            let g = 60e-6 + 40e-6 * (1.0 + k as f64) * ds.force[i];
            ds.map.dom(ds.map.from_g(g + loop_g(i, k))) - ds.map.dom(ds.map.from_g(g))
        }));
        assert!(misfit < 0.02 * size, "misfit {misfit} loop {size}");
    }
}
