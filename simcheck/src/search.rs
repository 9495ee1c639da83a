//! Fitting: Nelder-Mead over a few global parameters (per-node parameters are solved inside
//! each evaluation, see [`crate::model`]), and which parameters each model searches.

use crate::context::Context;
use crate::effects::{Config, Thermal};
use crate::law::Law;
use crate::model::evaluate_with;

/// A global parameter the search moves, in an unconstrained coordinate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Param {
    LnExponent,
    LawShape(usize),
    LnFloor,
    CreepC(usize),
    CreepLnTau(usize),
    CreepLnRecovery,
    HystLnR,
    HystMix,
    HystShare,
    HystLnN,
    HystAsym,
    HystZ0,
    PreisMu,
    PreisLnSigma,
    ThermAlpha,
    ThermLnTau,
    CurvLnK,
    CurvBeta,
    LnRs,
    LnSkew,
    LnSettle,
}

impl Param {
    pub fn get(self, c: &Config) -> f64 {
        match self {
            Param::LnExponent => c.exponent.ln(),
            Param::LawShape(j) => c
                .law_shape
                .as_ref()
                .and_then(|w| w.get(j))
                .map_or(0.0, |w| *w),
            Param::LnFloor => c.r_floor_ohm.max(1e-9).ln(),
            Param::CreepC(j) => c.creep.as_ref().and_then(|v| v.get(j)).map_or(0.0, |t| t.0),
            Param::CreepLnTau(j) => c
                .creep
                .as_ref()
                .and_then(|v| v.get(j))
                .map_or(0.0, |t| t.1.ln()),
            Param::CreepLnRecovery => c.creep_recovery.ln(),
            Param::HystLnR => c.hysteresis.map_or(0.0, |r| r.max(1e-9).ln()),
            Param::HystMix => c.hyst_mix,
            Param::HystShare => c.hyst_share.unwrap_or(0.0),
            Param::HystLnN => c.hyst_bw_n.ln(),
            Param::HystAsym => c.hyst_bw_asym,
            Param::HystZ0 => c.hyst_bw_z0,
            Param::PreisMu => c.preis_mu,
            Param::PreisLnSigma => c.preis_sigma.max(1e-9).ln(),
            Param::ThermAlpha => match &c.thermal {
                Some(Thermal::Recorded { alpha_per_k, .. }) => alpha_per_k * 100.0,
                _ => 0.0,
            },
            Param::ThermLnTau => match &c.thermal {
                Some(Thermal::Recorded { tau_s, .. }) => tau_s.ln(),
                _ => 0.0,
            },
            Param::CurvLnK => c.curv_sens.unwrap_or(1.0).max(1e-6).ln(),
            Param::CurvBeta => c.curv_sens.unwrap_or(0.0),
            Param::LnRs => c.crosstalk.map_or(0.0, |v| v.max(1e-9).ln()),
            Param::LnSkew => c.scan_skew.map_or(0.0, |v| v.max(1e-9).ln()),
            Param::LnSettle => c.scan_settle.max(1e-9).ln(),
        }
    }

    pub fn set(self, c: &mut Config, v: f64) {
        match self {
            Param::LnExponent => c.exponent = v.clamp(0.2f64.ln(), 3f64.ln()).exp().clamp(0.2, 3.0),
            Param::LawShape(j) => {
                if let Some(w) = c.law_shape.as_mut().and_then(|w| w.get_mut(j)) {
                    *w = v.clamp(-8.0, 8.0);
                }
            }
            Param::LnFloor => c.r_floor_ohm = v.clamp(-30.0, 30.0).exp(),
            Param::CreepC(j) => {
                if let Some(t) = c.creep.as_mut().and_then(|cr| cr.get_mut(j)) {
                    t.0 = v.clamp(0.0, 2.0);
                }
            }
            Param::CreepLnTau(j) => {
                if let Some(t) = c.creep.as_mut().and_then(|cr| cr.get_mut(j)) {
                    t.1 = v.clamp(0.05f64.ln(), 5000f64.ln()).exp();
                }
            }
            Param::CreepLnRecovery => c.creep_recovery = v.clamp(-3.0, 3.0).exp(),
            Param::HystLnR => {
                if let Some(r) = &mut c.hysteresis {
                    *r = v.clamp(-12.0, 8.0).exp();
                }
            }
            Param::HystMix => c.hyst_mix = v.clamp(-0.9, 4.0),
            Param::HystShare => {
                if let Some(a) = &mut c.hyst_share {
                    *a = v.clamp(-2.0, 2.0);
                }
            }
            Param::HystLnN => c.hyst_bw_n = v.clamp(0.5f64.ln(), 4f64.ln()).exp(),
            Param::HystAsym => c.hyst_bw_asym = v.clamp(-0.9, 0.9),
            Param::HystZ0 => c.hyst_bw_z0 = v.clamp(-1.0, 1.0),
            Param::PreisMu => c.preis_mu = v.clamp(-50.0, 500.0),
            Param::PreisLnSigma => c.preis_sigma = v.clamp(-8.0, 8.0).exp(),
            Param::ThermAlpha => {
                if let Some(Thermal::Recorded { alpha_per_k, .. }) = &mut c.thermal {
                    *alpha_per_k = (v / 100.0).clamp(-0.09, 0.09);
                }
            }
            Param::ThermLnTau => {
                if let Some(Thermal::Recorded { tau_s, .. }) = &mut c.thermal {
                    *tau_s = v.clamp(0.0, 12.0).exp();
                }
            }
            Param::CurvLnK => c.curv_sens = Some(v.clamp(0.0, 12.0).exp()),
            Param::CurvBeta => c.curv_sens = Some(v.clamp(-50.0, 50.0)),
            Param::LnRs => c.crosstalk = Some(v.clamp(-20.0, 10.0).exp()),
            Param::LnSkew => c.scan_skew = Some(v.clamp(-20.0, -2.0).exp()),
            Param::LnSettle => c.scan_settle = v.clamp(-20.0, -3.0).exp(),
        }
    }

    fn step(self) -> f64 {
        match self {
            Param::CreepC(_) => 0.03,
            Param::ThermAlpha => 0.1,
            Param::HystShare => 0.1,
            Param::HystLnN => 0.3,
            Param::HystAsym => 0.3,
            Param::HystZ0 => 0.5,
            Param::PreisMu => 1.0,
            Param::CurvBeta => 0.5,
            Param::LnExponent => 0.05,
            _ => 0.5,
        }
    }
}

/// Minimises `f` with Nelder-Mead from `x0`; returns the best point and value.
pub fn nelder_mead(
    f: &mut dyn FnMut(&[f64]) -> f64,
    x0: &[f64],
    steps: &[f64],
    max_evals: usize,
) -> (Vec<f64>, f64) {
    let d = x0.len();
    if d == 0 {
        return (Vec::new(), f(x0));
    }
    let mut pts: Vec<(Vec<f64>, f64)> = Vec::with_capacity(d + 1);
    pts.push((x0.to_vec(), f(x0)));
    for j in 0..d {
        let mut x = x0.to_vec();
        x[j] += steps[j];
        let v = f(&x);
        pts.push((x, v));
    }
    let mut evals = d + 1;
    while evals < max_evals {
        pts.sort_by(|a, b| a.1.total_cmp(&b.1));
        let spread = pts[d].1 - pts[0].1;
        if spread.abs() <= 1e-9 * pts[0].1.abs().max(1e-300) {
            break;
        }
        let mut c = vec![0.0; d];
        for p in &pts[..d] {
            for (ci, xi) in c.iter_mut().zip(&p.0) {
                *ci += xi / d as f64;
            }
        }
        let along = |t: f64| -> Vec<f64> {
            c.iter()
                .zip(&pts[d].0)
                .map(|(ci, wi)| ci + t * (wi - ci))
                .collect()
        };
        let xr = along(-1.0);
        let fr = f(&xr);
        evals += 1;
        if fr < pts[0].1 {
            let xe = along(-2.0);
            let fe = f(&xe);
            evals += 1;
            pts[d] = if fe < fr { (xe, fe) } else { (xr, fr) };
        } else if fr < pts[d - 1].1 {
            pts[d] = (xr, fr);
        } else {
            let xc = along(0.5);
            let fc = f(&xc);
            evals += 1;
            if fc < pts[d].1 {
                pts[d] = (xc, fc);
            } else {
                let best = pts[0].0.clone();
                for p in pts.iter_mut().skip(1) {
                    let x: Vec<f64> = best
                        .iter()
                        .zip(&p.0)
                        .map(|(b, x)| b + 0.5 * (x - b))
                        .collect();
                    p.1 = f(&x);
                    p.0 = x;
                    evals += 1;
                }
            }
        }
    }
    pts.sort_by(|a, b| a.1.total_cmp(&b.1));
    let best = pts.swap_remove(0);
    (best.0, best.1)
}

/// The search's objective: the training SSE of `cfg` on the samples where `train` holds (every
/// `search_stride`-th one), `f64::MAX` when the model does not evaluate to a finite number.
pub fn train_sse(ctx: &Context, cfg: &Config, train: &dyn Fn(usize) -> bool) -> f64 {
    let v = evaluate_with(ctx, cfg, train, ctx.search_stride(), false).train_sse;
    if v.is_finite() {
        v
    } else {
        f64::MAX
    }
}

/// Fits the listed parameters of `cfg` on the samples where `train` holds: a coarse grid over
/// the alternative starting points `starts`, then Nelder-Mead from the best; a latent drift's
/// knot values and per-trial sensitivities are then re-read from a fit of the result.
pub fn fit(
    ctx: &Context,
    starts: &[Config],
    params: &[Param],
    train: &dyn Fn(usize) -> bool,
    max_evals: usize,
) -> Config {
    let c = fit_unread(ctx, starts, params, train, max_evals);
    reread_fitted_factors(ctx, c, train)
}

/// As [`fit`] without the re-read at its end: the search's result with its start's latent drift
/// and per-trial sensitivities (a cross-validation fold re-reads them in its held-out
/// evaluation, see [`crate::model::evaluate_held_out_rereading`]).
pub fn fit_unread(
    ctx: &Context,
    starts: &[Config],
    params: &[Param],
    train: &dyn Fn(usize) -> bool,
    max_evals: usize,
) -> Config {
    let objective = |c: &Config| train_sse(ctx, c, train);
    // Nothing to choose and nothing to search (a latent drift held out on a fold's fit): the
    // start is the fit, and its training SSE is never read.
    if let ([only], []) = (starts, params) {
        return only.clone();
    }
    let mut best: Option<(Config, f64)> = None;
    for s in starts {
        let v = objective(s);
        if best.as_ref().is_none_or(|b| v < b.1) {
            best = Some((s.clone(), v));
        }
    }
    let Some((start, start_sse)) = best else {
        return Config::base(1.0, 0.0);
    };
    let x0: Vec<f64> = params.iter().map(|p| p.get(&start)).collect();
    let steps: Vec<f64> = params.iter().map(|p| p.step()).collect();
    let mut obj = |x: &[f64]| -> f64 {
        let mut c = start.clone();
        for (p, v) in params.iter().zip(x) {
            p.set(&mut c, *v);
        }
        // The simplex's first point is the best start itself, already evaluated (unless its
        // parameters do not survive the way to the search's coordinates and back unchanged).
        if c == start {
            return start_sse;
        }
        objective(&c)
    };
    let (x, _) = nelder_mead(&mut obj, &x0, &steps, max_evals);
    let mut c = start;
    for (p, v) in params.iter().zip(&x) {
        p.set(&mut c, *v);
    }
    c
}

/// `c` with a latent thermal factor and per-trial sensitivities re-read from an evaluation on
/// the training samples (they are fitted inside every evaluation); unchanged without them.
fn reread_fitted_factors(ctx: &Context, c: Config, train: &dyn Fn(usize) -> bool) -> Config {
    if matches!(&c.thermal, Some(Thermal::Latent { .. })) || c.curv_trials.is_some() {
        // Re-read from a fit on the held-out evaluation's samples, without predictions:
        // every later evaluation refits the knots and the sensitivities from these values.
        let ev = evaluate_with(ctx, &c, train, ctx.held_out_stride(), false);
        return with_fitted_factors(c, ev.latent, ev.trial_gains);
    }
    c
}

/// `c` with a latent drift's knot `values` and per-trial sensitivities `gains` as a fit left
/// them, where there are any.
pub fn with_fitted_factors(
    mut c: Config,
    values: Option<Vec<f64>>,
    gains: Option<Vec<f64>>,
) -> Config {
    if let (Some(Thermal::Latent { values: v, .. }), Some(fitted)) = (&mut c.thermal, values) {
        *v = fitted;
    }
    if gains.is_some() {
        c.curv_trials = gains;
    }
    c
}

/// The static law's searched parameters: the power law's exponent (a spline has none: its
/// coefficients are solved per node).
pub fn law_params(cfg: &Config) -> Vec<Param> {
    match cfg.law {
        Law::Power => match &cfg.law_shape {
            Some(w) => (1..w.len()).map(Param::LawShape).collect(),
            None => vec![Param::LnExponent],
        },
        Law::Spline(_) => Vec::new(),
    }
}

/// The base parameters searched with every model.
pub fn base_params(cfg: &Config) -> Vec<Param> {
    let mut p = law_params(cfg);
    if cfg.sat_in_base || cfg.saturation {
        p.push(Param::LnFloor);
    }
    p
}

/// What a model's held-out test refits on each training fold: the exponent and every parameter
/// of its effects, so no effect parameter is fitted on the half it is tested on. The resistance
/// floor only when saturation is one of the effects: it is slow to search and rarely trades off
/// with the others, so otherwise it stays at the whole-recording fit.
pub fn refit_params(cfg: &Config, has_kappa: bool) -> Vec<Param> {
    all_params(cfg, has_kappa)
        .into_iter()
        .filter(|p| *p != Param::LnFloor || cfg.saturation)
        .collect()
}

/// All parameters of a configuration (for the joint refit after acceptance).
pub fn all_params(cfg: &Config, has_kappa: bool) -> Vec<Param> {
    let mut p = base_params(cfg);
    if let Some(terms) = &cfg.creep {
        for j in 0..terms.len() {
            p.extend([Param::CreepC(j), Param::CreepLnTau(j)]);
        }
        if cfg.creep_recovery != 1.0 {
            p.push(Param::CreepLnRecovery);
        }
    }
    if cfg.hysteresis.is_some() {
        p.push(Param::HystLnR);
        if cfg.hyst_preisach {
            p.extend([Param::PreisMu, Param::PreisLnSigma]);
        } else {
            if cfg.hyst_bouc_wen {
                p.extend([Param::HystLnN, Param::HystAsym]);
                if cfg.hyst_share.is_none() {
                    p.push(Param::HystZ0);
                }
            } else {
                p.push(Param::HystMix);
            }
        }
        if cfg.hyst_share.is_some() {
            p.push(Param::HystShare);
        }
    }
    if let Some(Thermal::Recorded { .. }) = cfg.thermal {
        p.extend([Param::ThermAlpha, Param::ThermLnTau]);
    }
    if cfg.curv_sens.is_some() && cfg.curv_trials.is_none() {
        p.push(if has_kappa {
            Param::CurvLnK
        } else {
            Param::CurvBeta
        });
    }
    if cfg.crosstalk.is_some() {
        p.push(Param::LnRs);
    }
    if cfg.scan_skew.is_some() {
        p.push(Param::LnSkew);
        p.push(Param::LnSettle);
    }
    p
}

/// Convenience: the whole-data fit of a model.
pub fn fit_all(ctx: &Context, starts: &[Config], params: &[Param], max_evals: usize) -> Config {
    fit(ctx, starts, params, &|_| true, max_evals)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nelder_mead_finds_a_quadratic_minimum() {
        let mut f = |x: &[f64]| (x[0] - 1.5).powi(2) + 3.0 * (x[1] + 0.5).powi(2) + 2.0;
        let (x, v) = nelder_mead(&mut f, &[0.0, 0.0], &[0.5, 0.5], 400);
        assert!(
            (x[0] - 1.5).abs() < 1e-3 && (x[1] + 0.5).abs() < 1e-3,
            "{x:?}"
        );
        assert!((v - 2.0).abs() < 1e-6);
    }
}
