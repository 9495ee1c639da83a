//! Fitting and model selection: Nelder-Mead over a few global parameters (per-node parameters
//! are solved inside each evaluation), two-fold cross-validation over alternating time blocks,
//! and the acceptance rule for an effect: it must lower the held-out error consistently across
//! blocks (block t statistic), by more than an information criterion charges for its
//! parameters, and by a minimum relative amount.

use crate::model::{
    evaluate, evaluate_with, latent_knots, latent_knots_n, latent_resolutions, Config, Context,
    EffectKind, Eval, Thermal,
};

/// Acceptance thresholds (documented in docs/simcheck.md).
pub const MIN_BLOCK_T: f64 = 3.0;
pub const MIN_REL_GAIN: f64 = 0.01;
/// Block t statistic an effect must keep to stay in the model in the backward pass.
pub const MIN_KEEP_T: f64 = 2.0;

/// A global parameter the search moves, in an unconstrained coordinate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Param {
    LnExponent,
    LnFloor,
    CreepC(usize),
    CreepLnTau(usize),
    HystLnR,
    HystMix,
    HystShare,
    HystLnN,
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
            Param::LnFloor => c.r_floor_ohm.max(1e-9).ln(),
            Param::CreepC(j) => c.creep.as_ref().and_then(|v| v.get(j)).map_or(0.0, |t| t.0),
            Param::CreepLnTau(j) => c
                .creep
                .as_ref()
                .and_then(|v| v.get(j))
                .map_or(0.0, |t| t.1.ln()),
            Param::HystLnR => c.hysteresis.map_or(0.0, |r| r.max(1e-9).ln()),
            Param::HystMix => c.hyst_mix,
            Param::HystShare => c.hyst_share.unwrap_or(0.0),
            Param::HystLnN => c.hyst_bw_n.ln(),
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
/// the alternative starting points `starts`, then Nelder-Mead from the best.
pub fn fit(
    ctx: &Context,
    starts: &[Config],
    params: &[Param],
    train: &dyn Fn(usize) -> bool,
    max_evals: usize,
) -> Config {
    let objective = |c: &Config| train_sse(ctx, c, train);
    let mut best: Option<(Config, f64)> = None;
    for s in starts {
        let v = objective(s);
        if best.as_ref().is_none_or(|b| v < b.1) {
            best = Some((s.clone(), v));
        }
    }
    let Some((start, _)) = best else {
        return Config::base(1.0, 0.0);
    };
    let x0: Vec<f64> = params.iter().map(|p| p.get(&start)).collect();
    let steps: Vec<f64> = params.iter().map(|p| p.step()).collect();
    let mut obj = |x: &[f64]| -> f64 {
        let mut c = start.clone();
        for (p, v) in params.iter().zip(x) {
            p.set(&mut c, *v);
        }
        objective(&c)
    };
    let (x, _) = nelder_mead(&mut obj, &x0, &steps, max_evals);
    let mut c = start;
    for (p, v) in params.iter().zip(&x) {
        p.set(&mut c, *v);
    }
    // A latent thermal factor is re-read from the final evaluation.
    if let Some(Thermal::Latent { .. }) = &c.thermal {
        let ev = evaluate(ctx, &c, train);
        if let (Some(Thermal::Latent { values, .. }), Some(v)) = (&mut c.thermal, ev.latent) {
            *values = v;
        }
    }
    c
}

/// The base parameters searched with every model.
pub fn base_params(cfg: &Config) -> Vec<Param> {
    let mut p = vec![Param::LnExponent];
    if cfg.sat_in_base || cfg.saturation {
        p.push(Param::LnFloor);
    }
    p
}

/// Whether an effect can be tested on this recording, and why not.
pub fn applicable(ctx: &Context, cur: &Config, e: EffectKind) -> Result<(), &'static str> {
    let ds = ctx.ds;
    let kappa_varies = ds.kappa.as_ref().is_some_and(|k| {
        let lo = k.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = k.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        hi - lo > 1e-9
    });
    match e {
        EffectKind::CurvatureBaseline => {
            if kappa_varies || (ds.kappa.is_none() && ds.n_trials >= 2) {
                Ok(())
            } else {
                Err("needs two or more curvatures or trials")
            }
        }
        EffectKind::CurvatureSensitivity => {
            let shifts = &ctx.trial_shift;
            let mean = shifts.iter().sum::<f64>() / shifts.len().max(1) as f64;
            let sd = (shifts.iter().map(|s| (s - mean).powi(2)).sum::<f64>()
                / shifts.len().max(1) as f64)
                .sqrt();
            if kappa_varies || (ds.kappa.is_none() && ds.n_trials >= 3 && sd > 0.005) {
                Ok(())
            } else {
                Err("needs two or more curvatures, or three or more trials whose no-load baselines differ")
            }
        }
        EffectKind::Saturation => {
            if cur.sat_in_base {
                Err("part of the base fit (the starting model has a resistance floor)")
            } else {
                Ok(())
            }
        }
        EffectKind::Crosstalk => {
            if ds.rows >= 2 && ds.cols >= 2 && ds.map.kind() == taxel_sim::ReadoutKind::Amplifier {
                Ok(())
            } else {
                Err("needs a row-column matrix read through the amplifier")
            }
        }
        EffectKind::ScanSkew => {
            if ds.n >= 2 {
                Ok(())
            } else {
                Err("needs two or more nodes")
            }
        }
        EffectKind::ThermalDrift => {
            if ds.temp.is_some() || ds.duration() >= 60.0 {
                Ok(())
            } else {
                Err("no temperature column and shorter than 60 s")
            }
        }
        EffectKind::Creep | EffectKind::Hysteresis => Ok(()),
    }
}

/// Starting points and searched parameters for adding effect `e` to `cur`.
pub fn candidate(ctx: &Context, cur: &Config, e: EffectKind) -> (Vec<Config>, Vec<Param>) {
    let ds = ctx.ds;
    // The resistance floor stays at its current value while a candidate is tested (except
    // saturation itself): it is slow to search and rarely trades off with the others.
    let mut params = vec![Param::LnExponent];
    let mut starts = Vec::new();
    let fmax = ds.max_force().max(1e-9);
    let gmax = ctx
        .g_obs
        .iter()
        .zip(&ctx.usable)
        .filter(|(_, u)| **u)
        .map(|(g, _)| *g)
        .fold(0.0, f64::max)
        .max(1e-12);
    let dur = ds.duration().max(1.0);
    match e {
        EffectKind::Creep => {
            for (t1, t2) in [(0.5f64, 10.0f64), (1.5, 40.0), (4.0, 150.0)] {
                if t1 > dur {
                    continue;
                }
                for c in [0.02, 0.06] {
                    let mut s = cur.clone();
                    s.creep = Some(vec![(c, t1), (c, t2.min(dur))]);
                    starts.push(s);
                }
            }
            params.extend([
                Param::CreepC(0),
                Param::CreepLnTau(0),
                Param::CreepC(1),
                Param::CreepLnTau(1),
            ]);
        }
        EffectKind::Hysteresis => {
            for r in [0.01, 0.03, 0.1, 0.3] {
                for mix in [0.0, 1.0] {
                    let mut s = cur.clone();
                    s.hysteresis = Some(r * fmax);
                    s.hyst_mix = mix;
                    starts.push(s);
                }
            }
            params.extend([Param::HystLnR, Param::HystMix]);
        }
        EffectKind::ThermalDrift => {
            if ds.temp.is_some() {
                for tau in [10.0, 60.0, 300.0] {
                    for a in [-0.003, 0.003] {
                        let mut s = cur.clone();
                        s.thermal = Some(Thermal::Recorded {
                            alpha_per_k: a,
                            tau_s: tau,
                        });
                        starts.push(s);
                    }
                }
                params.extend([Param::ThermAlpha, Param::ThermLnTau]);
            } else {
                // The resolution is chosen among `latent_resolutions` by `candidates`.
                let knots = latent_knots(ds);
                let mut s = cur.clone();
                s.thermal = Some(Thermal::Latent {
                    values: vec![1.0; knots.len()],
                    knots_s: knots,
                });
                starts.push(s);
            }
        }
        EffectKind::CurvatureSensitivity => {
            // Both forms PHYSICS.md names: 1/(1 + kappa/kappa_s) and 1 - kappa/kappa_1; the
            // better start wins, then its parameter is refined.
            let grid: Vec<f64> = if ds.kappa.is_some() {
                vec![100.0, 300.0, 1000.0]
            } else {
                vec![-3.0, -1.0, 1.0, 3.0]
            };
            for linear in [false, true] {
                for &v in &grid {
                    let mut s = cur.clone();
                    s.curv_sens = Some(v);
                    s.curv_linear = linear;
                    starts.push(s);
                }
            }
            params.push(if ds.kappa.is_some() {
                Param::CurvLnK
            } else {
                Param::CurvBeta
            });
        }
        EffectKind::CurvatureBaseline => {
            let mut s = cur.clone();
            s.curv_base = true;
            starts.push(s);
        }
        EffectKind::Saturation => {
            for x in [0.05, 0.2, 0.5] {
                let mut s = cur.clone();
                s.saturation = true;
                s.r_floor_ohm = x / gmax;
                starts.push(s);
            }
            params.push(Param::LnFloor);
        }
        EffectKind::Crosstalk => {
            let srow = gmax * ds.cols as f64;
            for x in [0.01, 0.05, 0.15] {
                let mut s = cur.clone();
                s.crosstalk = Some(x / srow);
                starts.push(s);
            }
            params.push(Param::LnRs);
        }
        EffectKind::ScanSkew => {
            for dt in [1e-4, 4e-4, 1.5e-3] {
                for settle in [1e-5, 1e-3] {
                    let mut s = cur.clone();
                    s.scan_skew = Some(dt);
                    s.scan_settle = settle;
                    starts.push(s);
                }
            }
            params.extend([Param::LnSkew, Param::LnSettle]);
        }
    }
    params.dedup();
    (starts, params)
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

/// The variants of effect `e` to test on top of `cur`: start configurations and the parameters
/// searched on each training fold (the current model's own, see [`refit_params`], and the
/// effect's).
pub fn candidates(ctx: &Context, cur: &Config, e: EffectKind) -> Vec<(Vec<Config>, Vec<Param>)> {
    let held = refit_params(cur, ctx.ds.kappa.is_some());
    candidate_variants(ctx, cur, e)
        .into_iter()
        .map(|(starts, params)| {
            let mut all = held.clone();
            for p in params {
                if !all.contains(&p) {
                    all.push(p);
                }
            }
            (starts, all)
        })
        .collect()
}

/// The variants of candidate `e` to try, with the effect's own parameters: one, except creep,
/// which is also tried with a third Prony term between the other two, and a latent thermal
/// drift, which is tried at each resolution of [`latent_resolutions`] (the caller keeps the
/// variant the criterion likes best).
fn candidate_variants(
    ctx: &Context,
    cur: &Config,
    e: EffectKind,
) -> Vec<(Vec<Config>, Vec<Param>)> {
    let (starts, params) = candidate(ctx, cur, e);
    if e == EffectKind::Creep {
        let three: Vec<Config> = starts
            .iter()
            .map(|s| {
                let mut s = s.clone();
                if let Some(t) = &mut s.creep {
                    if let [(c1, t1), (c2, t2)] = t[..] {
                        *t = vec![(c1, t1), (0.5 * (c1 + c2), (t1 * t2).sqrt()), (c2, t2)];
                    }
                }
                s
            })
            .collect();
        let mut p3 = params.clone();
        p3.extend([Param::CreepC(2), Param::CreepLnTau(2)]);
        return vec![(starts, params), (three, p3)];
    }
    if e == EffectKind::Hysteresis {
        // One start per half-width (the additive starts come twice, with mix 0 and 1), each
        // with both signs of the share.
        let in_load: Vec<Config> = starts
            .iter()
            .filter(|s| s.hyst_mix == 0.0)
            .flat_map(|s| {
                [-0.3, 0.3].map(|a| Config {
                    hyst_share: Some(a),
                    hyst_mix: 1.0,
                    ..s.clone()
                })
            })
            .collect();
        let mut p_load = params.clone();
        p_load.push(Param::HystShare);
        // The Bouc-Wen state in the load path: the same half-widths as saturations, both signs,
        // and its exponent (charged like the plays' mix).
        let bouc_wen: Vec<Config> = in_load
            .iter()
            .map(|s| Config {
                hyst_bouc_wen: true,
                hyst_mix: 0.0,
                ..s.clone()
            })
            .collect();
        let mut p_bw: Vec<Param> = params
            .iter()
            .copied()
            .filter(|p| *p != Param::HystMix)
            .collect();
        p_bw.extend([Param::HystShare, Param::HystLnN]);
        return vec![(starts, params), (in_load, p_load), (bouc_wen, p_bw)];
    }
    if e != EffectKind::ThermalDrift || ctx.ds.temp.is_some() {
        return vec![(starts, params)];
    }
    latent_resolutions(ctx.ds)
        .into_iter()
        .map(|k| {
            let knots = latent_knots_n(ctx.ds, k);
            let s: Vec<Config> = starts
                .iter()
                .map(|s| {
                    let mut s = s.clone();
                    s.thermal = Some(Thermal::Latent {
                        values: vec![1.0; knots.len()],
                        knots_s: knots.clone(),
                    });
                    s
                })
                .collect();
            (s, params.clone())
        })
        .collect()
}

/// All parameters of a configuration (for the joint refit after acceptance).
pub fn all_params(cfg: &Config, has_kappa: bool) -> Vec<Param> {
    let mut p = base_params(cfg);
    if let Some(terms) = &cfg.creep {
        for j in 0..terms.len() {
            p.extend([Param::CreepC(j), Param::CreepLnTau(j)]);
        }
    }
    if cfg.hysteresis.is_some() {
        p.push(Param::HystLnR);
        p.push(if cfg.hyst_bouc_wen {
            Param::HystLnN
        } else {
            Param::HystMix
        });
        if cfg.hyst_share.is_some() {
            p.push(Param::HystShare);
        }
    }
    if let Some(Thermal::Recorded { .. }) = cfg.thermal {
        p.extend([Param::ThermAlpha, Param::ThermLnTau]);
    }
    if cfg.curv_sens.is_some() {
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

/// Parameters an effect adds (for the information criterion): global ones and per node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ParamCount {
    pub global: usize,
    pub per_node: usize,
}

/// Parameters an effect adds.
/// Parameters effect `e` adds to `cfg` (which holds it: a latent drift's knots count).
pub fn n_params(cfg: &Config, e: EffectKind) -> ParamCount {
    let (global, per_node) = match e {
        EffectKind::Creep => (2 * cfg.creep.as_ref().map_or(2, Vec::len), 0),
        // In the load path: half-width, mix and share; or Bouc-Wen saturation, exponent, share.
        EffectKind::Hysteresis if cfg.hyst_share.is_some() => (3, 0),
        EffectKind::Hysteresis => (2, 1),
        EffectKind::ThermalDrift => match &cfg.thermal {
            Some(Thermal::Latent { knots_s, .. }) => (knots_s.len(), 0),
            _ => (2, 0),
        },
        EffectKind::CurvatureBaseline => (0, 1),
        EffectKind::CurvatureSensitivity | EffectKind::Saturation | EffectKind::Crosstalk => (1, 0),
        EffectKind::ScanSkew => (2, 0),
    };
    ParamCount { global, per_node }
}

/// What the criterion needs to know about a held-out residual.
#[derive(Debug, Clone, Copy)]
pub struct ResidStats {
    pub time_samples: usize,
    /// Integrated autocorrelation time (samples), averaged over nodes.
    pub tau_int: f64,
}

/// [`ResidStats`] of a held-out residual (`len` samples x `n` nodes).
pub fn resid_stats(resid: &[f64], len: usize, n: usize) -> ResidStats {
    ResidStats {
        time_samples: len,
        tau_int: tau_int(resid, len, n),
    }
}

/// Held-out (two-fold) result of a model.
#[derive(Debug, Clone)]
pub struct Cv {
    /// Held-out residual (sim - rec) per sample and node, 0 where unusable.
    pub resid: Vec<f64>,
    pub sse: f64,
    pub count: usize,
    /// SSE per block.
    pub block_sse: Vec<f64>,
    /// SSE per node.
    pub node_sse: Vec<f64>,
    /// SSE per block over no-load samples only (force below 2 % of the peak).
    pub rest_block_sse: Vec<f64>,
    /// The configuration fitted on each fold's training half.
    pub fits: [Config; 2],
}

impl Cv {
    pub fn rmse(&self) -> f64 {
        (self.sse / self.count.max(1) as f64).sqrt()
    }
}

/// Two-fold cross-validation: fit on one fold's blocks, predict the other.
pub fn cross_validate(ctx: &Context, starts: &[Config], params: &[Param], max_evals: usize) -> Cv {
    let ds = ctx.ds;
    let n = ds.n;
    let mut resid = vec![0.0; ds.len() * n];
    let mut fits = Vec::with_capacity(2);
    let folds: Vec<(Config, Eval)> = std::thread::scope(|sc| {
        let handles: Vec<_> = (0..2)
            .map(|f| {
                sc.spawn(move || {
                    let train = |i: usize| ctx.fold(i) != f;
                    let cfg = fit(ctx, starts, params, &train, max_evals);
                    let ev = evaluate(ctx, &cfg, &train);
                    (cfg, ev)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
            .collect()
    });
    for (f, (cfg, ev)) in folds.into_iter().enumerate() {
        for i in 0..ds.len() {
            if ctx.fold(i) == f {
                for k in 0..n {
                    let idx = i * n + k;
                    if ctx.usable[idx] {
                        resid[idx] = ev.pred[idx] - ctx.dom_obs[idx];
                    }
                }
            }
        }
        fits.push(cfg);
    }
    let mut block_sse = vec![0.0; ctx.n_blocks];
    let mut node_sse = vec![0.0; n];
    let mut rest_block_sse = vec![0.0; ctx.n_blocks];
    let rest_limit = 0.02 * ds.max_force();
    let mut count = 0;
    for i in 0..ds.len() {
        for (k, node) in node_sse.iter_mut().enumerate() {
            let idx = i * n + k;
            if ctx.usable[idx] {
                let r2 = resid[idx] * resid[idx];
                block_sse[ctx.block[i]] += r2;
                *node += r2;
                if ds.force[i] <= rest_limit {
                    rest_block_sse[ctx.block[i]] += r2;
                }
                count += 1;
            }
        }
    }
    let sse = block_sse.iter().sum();
    let [a, b]: [Config; 2] = match fits.try_into() {
        Ok(v) => v,
        Err(_) => [Config::base(1.0, 0.0), Config::base(1.0, 0.0)],
    };
    Cv {
        resid,
        sse,
        count,
        block_sse,
        node_sse,
        rest_block_sse,
        fits: [a, b],
    }
}

/// How strongly a richer model beats a simpler one on held-out data.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Verdict {
    pub rmse_before: f64,
    pub rmse_after: f64,
    /// Relative fall in held-out SSE.
    pub rel_gain: f64,
    /// Mean per-block SSE reduction over its standard error.
    pub block_t: f64,
    /// Share of blocks that improved.
    pub blocks_improved: f64,
    /// Wilcoxon signed-rank z of the per-block SSE reductions.
    pub rank_z: f64,
    /// Effective sample size used by the criterion.
    pub n_eff: f64,
    /// n_eff ln(SSE0/SSE1) - k ln(n_eff): positive = the parameters pay for themselves.
    pub ic_gain: f64,
    pub accepted: bool,
    /// Block t statistic of the gain on no-load samples alone (thermal drift must show there:
    /// temperature moves unloaded nodes, creep does not).
    pub rest_block_t: f64,
    /// Relative fall in held-out SSE on no-load samples alone.
    pub rest_rel_gain: f64,
    /// Weaker bar for keeping an effect already in the model (backward pass).
    pub keep: bool,
    /// Hysteresis only: the size of its contribution relative to the residual on slow and on
    /// fast ramps (see `diagnose::ramp_betas`).
    pub ramp_betas: Option<[f64; 2]>,
}

/// Block t statistic of the SSE reduction from `a` to `b` per block.
pub fn block_t_of(a: &[f64], b: &[f64]) -> f64 {
    let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    let nb = d.len().max(1) as f64;
    let mean = d.iter().sum::<f64>() / nb;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (nb - 1.0).max(1.0);
    let se = (var / nb).sqrt();
    if se > 0.0 {
        mean / se
    } else {
        0.0
    }
}

/// Wilcoxon signed-rank statistic of `d` as a z score (normal approximation, ties ranked by
/// their mean rank, zeros dropped): positive when the positive values outrank the negative.
pub fn signed_rank_z(d: &[f64]) -> f64 {
    let mut v: Vec<f64> = d.iter().copied().filter(|x| *x != 0.0).collect();
    let n = v.len();
    if n == 0 {
        return 0.0;
    }
    v.sort_by(|a, b| a.abs().total_cmp(&b.abs()));
    let mut w_plus = 0.0;
    let mut i = 0;
    while i < n {
        let mut j = i;
        while j + 1 < n && v[j + 1].abs() == v[i].abs() {
            j += 1;
        }
        let rank = (i + j) as f64 / 2.0 + 1.0;
        w_plus += rank * v[i..=j].iter().filter(|x| **x > 0.0).count() as f64;
        i = j + 1;
    }
    let nf = n as f64;
    let mean = nf * (nf + 1.0) / 4.0;
    let sd = (nf * (nf + 1.0) * (2.0 * nf + 1.0) / 24.0).sqrt();
    (w_plus - mean) / sd
}

pub fn compare(before: &Cv, after: &Cv, k: ParamCount, stats: ResidStats) -> Verdict {
    let d: Vec<f64> = before
        .block_sse
        .iter()
        .zip(&after.block_sse)
        .map(|(a, b)| a - b)
        .collect();
    let nb = d.len().max(1) as f64;
    let mean = d.iter().sum::<f64>() / nb;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (nb - 1.0).max(1.0);
    let se = (var / nb).sqrt();
    let block_t = if se > 0.0 { mean / se } else { 0.0 };
    let improved = d.iter().filter(|x| **x > 0.0).count() as f64 / nb;
    // Signed-rank test over blocks (beside the t statistic): robust where one block dominates
    // the SSE (a start-up transient), and it weighs how much each block gained. An effect whose
    // size varies over the recording (a drift that matters in some blocks more than in others)
    // gains unevenly; the t statistic counts that unevenness as noise, the ranks do not. (It
    // replaced a sign test, which counted many small gains as much as a few large losses.)
    let rank_z = signed_rank_z(&d);
    // Nodes share the stimulus and its errors: count time samples, not node-samples. (Summing
    // per-node evidence instead lets any flexible per-node term absorb what another effect's
    // approximate form leaves behind.) Per-node parameters count once per node with data.
    let n_eff = (stats.time_samples as f64 / stats.tau_int.max(1.0)).max(2.0);
    let ratio = (before.sse / after.sse.max(1e-300)).max(1e-300);
    let n_nodes = after.node_sse.iter().filter(|v| **v > 0.0).count();
    let n_params = k.global + k.per_node * n_nodes;
    let ic_gain = n_eff * ratio.ln() - n_params as f64 * n_eff.ln();
    let rel_gain = 1.0 - after.sse / before.sse.max(1e-300);
    Verdict {
        rmse_before: before.rmse(),
        rmse_after: after.rmse(),
        rel_gain,
        block_t,
        blocks_improved: improved,
        rank_z,
        n_eff,
        ic_gain,
        accepted: rel_gain >= MIN_REL_GAIN
            && (block_t >= MIN_BLOCK_T || rank_z >= MIN_BLOCK_T)
            && ic_gain > 0.0,
        rest_block_t: block_t_of(&before.rest_block_sse, &after.rest_block_sse),
        rest_rel_gain: {
            let (b, a): (f64, f64) = (
                before.rest_block_sse.iter().sum(),
                after.rest_block_sse.iter().sum(),
            );
            if b > 0.0 {
                1.0 - a / b
            } else {
                0.0
            }
        },
        keep: rel_gain >= 0.5 * MIN_REL_GAIN
            && (block_t >= MIN_KEEP_T || rank_z >= MIN_KEEP_T)
            && ic_gain > 0.0,
        ramp_betas: None,
    }
}

/// Integrated autocorrelation time of a residual (per node, averaged), in samples.
pub fn tau_int(resid: &[f64], len: usize, n: usize) -> f64 {
    let mut total = 0.0;
    let mut used = 0;
    let max_lag = (len / 10).clamp(1, 2000);
    for k in 0..n {
        let x: Vec<f64> = (0..len).map(|i| resid[i * n + k]).collect();
        let mean = x.iter().sum::<f64>() / len as f64;
        let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>();
        if var <= 0.0 {
            continue;
        }
        let mut tau = 1.0;
        let mut lag = 1;
        while lag < max_lag {
            let c: f64 = (0..len - lag)
                .map(|i| (x[i] - mean) * (x[i + lag] - mean))
                .sum::<f64>()
                / var;
            if c < 0.05 {
                break;
            }
            // Coarser steps at long lags; each lag stands for the ones it skips.
            let next = if lag < 16 { lag + 1 } else { lag + lag / 8 };
            tau += 2.0 * c * (next - lag) as f64;
            lag = next;
        }
        total += tau;
        used += 1;
    }
    if used == 0 {
        1.0
    } else {
        total / used as f64
    }
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

    #[test]
    fn block_t_and_sign_test_see_consistent_gains_only() {
        let before = vec![10.0; 24];
        let better: Vec<f64> = (0..24).map(|i| 9.0 + 0.01 * i as f64).collect();
        let noise: Vec<f64> = (0..24)
            .map(|i| if i % 2 == 0 { 9.0 } else { 11.0 })
            .collect();
        assert!(block_t_of(&before, &better) > 10.0);
        assert!(block_t_of(&before, &noise).abs() < 1.0);
    }

    #[test]
    fn signed_rank_z_weighs_the_sizes_of_the_gains() {
        // 24 blocks, all better: W+ = 300 against a mean of 150 and an sd of 35.
        let all: Vec<f64> = (1..=24).map(f64::from).collect();
        assert!((signed_rank_z(&all) - 150.0 / 35.0).abs() < 1e-9);
        // 18 of 24 better either way (sign test z = 2.45), but the ranks see whether the
        // gains or the losses are the big ones.
        let small_losses: Vec<f64> = (1..=24)
            .map(|i| if i <= 6 { -f64::from(i) } else { f64::from(i) })
            .collect();
        let big_losses: Vec<f64> = (1..=24)
            .map(|i| if i > 18 { -f64::from(i) } else { f64::from(i) })
            .collect();
        assert!((signed_rank_z(&small_losses) - 129.0 / 35.0).abs() < 1e-9);
        assert!((signed_rank_z(&big_losses) - 21.0 / 35.0).abs() < 1e-9);
        // Ties share their mean rank; a symmetric set is zero; zeros are dropped.
        assert!(signed_rank_z(&[1.0, -1.0, 2.0, -2.0]).abs() < 1e-12);
        assert_eq!(signed_rank_z(&[0.0, 0.0]), 0.0);
    }
}
