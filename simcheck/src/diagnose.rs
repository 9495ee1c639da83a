//! The diagnosis: fit the base model, test every applicable effect of the library on held-out
//! blocks, add the best accepted one and repeat, then drop any effect the others made
//! unnecessary; finally check what structure is left and say where it is.

use std::collections::BTreeMap;
use std::time::Instant;

use serde::Serialize;
use taxel_sim::SensorModel;

use crate::candidates::{applicable, candidates, n_params, ParamCount};
use crate::checks::signature_check;
use crate::context::Context;
use crate::cv::{compare, cross_validate, cross_validate_from, Cv, Verdict};
use crate::data::Dataset;
use crate::effects::{Config, EffectKind};
use crate::forms::max_scan_skew;
use crate::law::Law;
use crate::locate::{locate, Findings};
use crate::model::evaluate;
use crate::named::{effect_params, evidence};
pub use crate::named::{hysteresis_weight, in_load_as_sim, NamedEffect};
use crate::noise::NoiseModel;
use crate::search::{all_params, base_params, fit_all, refit_params, train_sse, Param};
use crate::unexplained::find_unexplained;
pub use crate::unexplained::Unexplained;

/// A variant of a candidate effect: its starting points and searched parameters.
type Variant = (Vec<Config>, Vec<Param>);

/// A candidate held out: its cross-validation, verdict, and whether the verdict is the
/// screening's.
type Tested = (Cv, Verdict, bool);

/// The best candidate of a round: effect, its cross-validation and verdict.
type Best = (EffectKind, Cv, Verdict);

/// Search effort.
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Nelder-Mead evaluations per fit.
    pub max_evals: usize,
    /// Most effects named.
    pub max_effects: usize,
    /// Residual-to-noise ratio above which structure counts as unexplained.
    pub unexplained_ratio: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            max_evals: 40,
            max_effects: 4,
            unexplained_ratio: 3.0,
        }
    }
}

/// One test of a candidate effect (every round, accepted or not).
#[derive(Debug, Clone, Serialize)]
pub struct Trial {
    pub round: usize,
    pub effect: String,
    pub verdict: Verdict,
    /// Time spent testing it (s).
    pub seconds: f64,
    /// The verdict is the screening's (see [`crate::screen`]): the candidate was not worth the
    /// full held-out test.
    pub screened: bool,
}

/// Everything the diagnosis found (report.json is this, plus file names).
pub struct Diagnosis {
    pub verdict: &'static str,
    pub effects: Vec<NamedEffect>,
    pub unexplained: Vec<Unexplained>,
    /// Held-out RMSE of the start model's static law (the power law, with the start model's
    /// floor) before round 0 chose the static law.
    pub rmse_start_law: f64,
    /// Held-out RMSE of the base model: the best static law (round 0), before any effect.
    pub rmse_base: f64,
    pub rmse_final: f64,
    pub base: Config,
    pub final_cfg: Config,
    pub trials: Vec<Trial>,
    pub skipped: Vec<(String, String)>,
    pub base_findings: Findings,
    pub final_findings: Findings,
    pub base_cv: Cv,
    pub final_cv: Cv,
    /// Whole-data predictions (residual domain) of the base and final models.
    pub base_pred: Vec<f64>,
    pub final_pred: Vec<f64>,
    pub final_theta: Vec<Vec<f64>>,
    /// The final model with the power law (the simulator's), fitted when the diagnosis chose a
    /// spline, and its per-node parameters: what SIM.toml is written from.
    pub sim_cfg: Config,
    pub sim_theta: Vec<Vec<f64>>,
    pub latent_m: Option<Vec<f64>>,
    /// The noise model the criterion and the `unexplained` rule used.
    pub noise: NoiseModel,
    /// What the report needs of the context: each node's share of the load (inverted, see
    /// `Context::load_scale`), each node's responsiveness under the final model, and the
    /// loading direction per sample.
    pub load_scale: Vec<f64>,
    pub responsiveness: Vec<f64>,
    pub direction: Vec<i8>,
    pub seconds: f64,
}
/// Where a diagnosis is, for a progress display: a stage and a step of it.
#[derive(Debug, Clone, Copy)]
pub struct Progress<'a> {
    pub stage: &'a str,
    pub step: usize,
    pub of: usize,
}

/// [`diagnose_with`] without a progress display.
pub fn diagnose(ds: &Dataset, start: &SensorModel, opts: &Options) -> Diagnosis {
    diagnose_with(ds, start, opts, &|_| {})
}

/// Diagnoses `ds` against the start model, telling `progress` where it is.
pub fn diagnose_with(
    ds: &Dataset,
    start: &SensorModel,
    opts: &Options,
    progress: &(dyn Fn(Progress) + Sync),
) -> Diagnosis {
    let t0 = Instant::now();
    progress(Progress {
        stage: "base model",
        step: 0,
        of: 1,
    });
    let whole = crate::timing::span("diagnosis");
    let sp = crate::timing::span("start model");
    let ctx = Context::new(ds);
    let ev_n = opts.max_evals;
    let cfg0 = start_config(&ctx, start);
    let bp = base_params(&cfg0);
    let start_cv = cross_validate(&ctx, std::slice::from_ref(&cfg0), &bp, ev_n);
    let start_fit = fit_all(&ctx, std::slice::from_ref(&cfg0), &bp, ev_n);
    let mut skipped = Vec::new();
    for e in EffectKind::ALL {
        if let Err(why) = applicable(&ctx, &start_fit, e) {
            skipped.push((e.name().to_string(), why.to_string()));
        }
    }
    let screen = ctx.coarser(crate::screen::FACTOR);
    let mut sel = Selection {
        ctx: &ctx,
        screen: &screen,
        ev_n,
        cfg0,
        cur: start_fit,
        cur_cv: start_cv.clone(),
        trials: Vec::new(),
        last: None,
        fixed: BTreeMap::new(),
        noise: NoiseModel::estimate(&ctx, &start_cv.resid),
        spline_m: SPLINE_SIZES[0],
        progress,
    };
    drop(sp);
    // Round 0: the static law (saturation against the start model's law, then the flexible
    // law). What the effects are tested against is the best static law.
    let sp = crate::timing::span("round 0: static law");
    sel.static_law();
    drop(sp);
    let base = sel.cur.clone();
    let base_cv = sel.cur_cv.clone();
    let base_eval = evaluate(&ctx, &base, &|_| true);
    let base_findings = locate(&ctx, &base_cv.resid, &base_eval.pred);
    for round in 1..=opts.max_effects {
        let _sp = crate::timing::span(format!("round {round}"));
        if !sel.round(round) {
            break;
        }
    }
    let sp = crate::timing::span("backward pass");
    let mut contributions = sel.backward();
    drop(sp);
    let sp = crate::timing::span("final model, SIM.toml law, findings");
    let Selection {
        mut cur,
        cur_cv,
        trials,
        fixed,
        noise,
        ..
    } = sel;
    contributions.extend(fixed);
    // The search may leave the skew or a creep time constant beyond the bound where it stops
    // acting; report the value that acts.
    cur.scan_skew = cur.scan_skew.map(|v| v.min(max_scan_skew(ds)));
    if let Some(terms) = &mut cur.creep {
        terms
            .iter_mut()
            .for_each(|t| t.1 = t.1.min(ctx.creep_tau_max));
    }
    cur.hysteresis = cur.hysteresis.map(|r| r.min(ctx.hyst_r_max));
    if cur.hyst_preisach {
        let (h0, mu, sigma) = crate::model::preisach_acting(&ctx, &cur);
        cur.hysteresis = Some(h0);
        cur.preis_mu = mu;
        cur.preis_sigma = sigma;
    }
    let final_eval = evaluate(&ctx, &cur, &|_| true);
    let final_findings = locate(&ctx, &cur_cv.resid, &final_eval.pred);
    let (sim_cfg, sim_theta) = crate::simlaw::power_summary(&ctx, &cur, &final_eval, ev_n);
    let responsiveness = crate::locate::responsiveness(&ctx, &final_eval.pred);
    let effects: Vec<NamedEffect> = cur
        .effects()
        .into_iter()
        .map(|e| {
            let (rb, ra, ev) = match contributions.get(&e) {
                Some((cvm, v)) => (cvm.rmse(), cur_cv.rmse(), evidence(e, v, &base_findings)),
                None => (base_cv.rmse(), cur_cv.rmse(), String::new()),
            };
            NamedEffect {
                name: e.name().to_string(),
                params: {
                    let mut p = effect_params(ds, &sim_cfg, e, &sim_theta);
                    // The asymmetry the tool fitted (SIM.toml's symmetric loop has none).
                    if e == EffectKind::Hysteresis && cur.hyst_bouc_wen {
                        p.insert("asymmetry".into(), cur.hyst_bw_asym);
                    }
                    p
                },
                evidence: ev,
                heldout_rmse_before: rb,
                heldout_rmse_after: ra,
            }
        })
        .collect();
    let unexplained = find_unexplained(
        &ctx,
        &base_cv,
        &cur_cv,
        &final_findings,
        &noise,
        opts.unexplained_ratio,
    );
    drop(sp);
    drop(whole);
    let verdict = if !unexplained.is_empty() {
        "unexplained"
    } else if effects.is_empty() {
        "none"
    } else {
        "explained"
    };
    Diagnosis {
        verdict,
        effects,
        unexplained,
        rmse_start_law: start_cv.rmse(),
        rmse_base: base_cv.rmse(),
        rmse_final: cur_cv.rmse(),
        base,
        final_cfg: cur,
        trials,
        skipped,
        base_findings,
        final_findings,
        base_cv,
        final_cv: cur_cv,
        base_pred: base_eval.pred,
        final_pred: final_eval.pred,
        final_theta: final_eval.theta,
        sim_cfg,
        sim_theta,
        latent_m: match &final_eval.latent {
            Some(_) => Some(final_eval.m.clone()),
            None => None,
        },
        noise,
        load_scale: ctx.load_scale.clone(),
        responsiveness,
        direction: crate::locate::direction(&ctx),
        seconds: t0.elapsed().as_secs_f64(),
    }
}

/// The smoothness settings of the spline law tried in round 0: basis functions per node.
pub const SPLINE_SIZES: [usize; 3] = [4, 6, 9];

/// Least share of the held-out SSE the spline law must remove to replace the start model's.
pub const MIN_LAW_GAIN: f64 = 0.05;

/// What a spline law with `m` basis functions per node adds to the power law: `m - 1` per node
/// (the power law's gain becomes `m` coefficients), less the exponent it no longer searches.
fn law_params_added(m: usize) -> crate::candidates::ParamCount {
    crate::candidates::ParamCount {
        global: 0,
        per_node: m - 1,
    }
}

/// A spline law's basis functions per node (0 for the power law).
fn law_of(cfg: &Config) -> usize {
    match cfg.law {
        Law::Spline(m) => m,
        Law::Power => 0,
    }
}

/// The base model the search starts from: the start model's exponent and resistance floor.
/// The floor must leave room for the highest conductance recorded (a floor above the lowest
/// recorded resistance would make every loaded sample unreachable).
fn start_config(ctx: &Context, start: &SensorModel) -> Config {
    let g_max = ctx
        .g_obs
        .iter()
        .zip(&ctx.usable)
        .filter(|(_, u)| **u)
        .map(|(g, _)| *g)
        .fold(0.0, f64::max);
    let floor = if start.material.r_floor_ohm > 0.0 && g_max > 0.0 {
        start.material.r_floor_ohm.min(0.3 / g_max)
    } else {
        start.material.r_floor_ohm
    };
    Config::base(start.material.exponent, floor)
}

/// The forward selection and backward pass: the current model, its held-out result, and every
/// candidate tested so far.
struct Selection<'a> {
    ctx: &'a Context<'a>,
    /// The screening view of the recording (see [`crate::screen`]).
    screen: &'a Context<'a>,
    ev_n: usize,
    /// The start model's base configuration.
    cfg0: Config,
    cur: Config,
    cur_cv: Cv,
    trials: Vec<Trial>,
    /// The effect that joined last and the held-out result of the model before it joined.
    last: Option<(EffectKind, Cv)>,
    /// Effects decided in round 0 with the static law (saturation), with their held-out
    /// contribution; the backward pass does not revisit them.
    fixed: BTreeMap<EffectKind, (Cv, Verdict)>,
    /// The noise model, from the start model's held-out residual at rest.
    noise: NoiseModel,
    /// The spline size the criterion liked best in round 0 (tried again in later rounds).
    spline_m: usize,
    progress: &'a (dyn Fn(Progress) + Sync),
}

impl Selection<'_> {
    /// Round 0, the static law. First the static effects the start model's law family can
    /// express, each tested alone against it: saturation (when the start model has no floor)
    /// and crosstalk (with a fixed load map, the row droop is a static function of the force
    /// too). Then the monotone spline per node ([`crate::law`]) at a few smoothness settings,
    /// held out against the current model and charged its extra parameters per node; it must
    /// also remove at least [`MIN_LAW_GAIN`] of the held-out SSE (a law with several parameters
    /// per node must earn them). When it joins, the static effects named before are held out
    /// again without it, with the backward pass's rule: one the spline makes unnecessary goes.
    fn static_law(&mut self) {
        (self.progress)(Progress {
            stage: "round 0: static law",
            step: 0,
            of: 1,
        });
        for e in [EffectKind::Saturation, EffectKind::Crosstalk] {
            if applicable(self.ctx, &self.cur, e).is_err() {
                continue;
            }
            let tc = Instant::now();
            let Some((cv, v, screened)) = self.best_variant(e) else {
                continue;
            };
            self.trials.push(Trial {
                round: 0,
                effect: e.name().to_string(),
                verdict: v,
                seconds: tc.elapsed().as_secs_f64(),
                screened,
            });
            if v.accepted {
                let before = self.cur_cv.clone();
                self.join(&cv.fits);
                let k = n_params(&self.cur, e);
                let v = compare(self.ctx, &before, &self.cur_cv, k, &self.noise);
                self.fixed.insert(e, (before, v));
            }
        }
        if self.spline(0, &SPLINE_SIZES) {
            self.retest_static();
        }
    }

    /// The spline law with each of `sizes` basis functions per node against the current law;
    /// true when the best of them joined (tested in `round`). Remembers the best size.
    fn spline(&mut self, round: usize, sizes: &[usize]) -> bool {
        let tc = Instant::now();
        let ds = self.ctx.ds;
        let mut best: Option<(Cv, Verdict)> = None;
        for &m in sizes {
            let cfg = Config {
                law: Law::Spline(m),
                ..self.cur.clone()
            };
            let cv = cross_validate(
                self.ctx,
                std::slice::from_ref(&cfg),
                &refit_params(&cfg, ds.kappa.is_some()),
                self.ev_n,
            );
            let mut v = compare(
                self.ctx,
                &self.cur_cv,
                &cv,
                law_params_added(m),
                &self.noise,
            );
            v.accepted &= v.rel_gain >= MIN_LAW_GAIN;
            if best.as_ref().is_none_or(|b| v.ic_gain > b.1.ic_gain) {
                best = Some((cv, v));
            }
        }
        let Some((cv, v)) = best else {
            return false;
        };
        self.spline_m = law_of(&cv.fits[0]);
        self.trials.push(Trial {
            round,
            effect: format!(
                "static_law (monotone spline, {} per node)",
                law_of(&cv.fits[0])
            ),
            verdict: v,
            seconds: tc.elapsed().as_secs_f64(),
            screened: false,
        });
        if v.accepted {
            self.join(&cv.fits);
        }
        v.accepted
    }

    /// After the spline joined: each static effect named before, held out without it.
    fn retest_static(&mut self) {
        let has_kappa = self.ctx.ds.kappa.is_some();
        let named: Vec<EffectKind> = self.fixed.keys().copied().collect();
        for e in named {
            let minus = self.cur.without(e);
            let cv_minus = cross_validate(
                self.ctx,
                std::slice::from_ref(&minus),
                &refit_params(&minus, has_kappa),
                self.ev_n,
            );
            let k = n_params(&self.cur, e);
            let v = compare(self.ctx, &cv_minus, &self.cur_cv, k, &self.noise);
            if v.keep {
                self.fixed.insert(e, (cv_minus, v));
            } else {
                self.cur = fit_all(
                    self.ctx,
                    std::slice::from_ref(&minus),
                    &all_params(&minus, has_kappa),
                    self.ev_n * 2,
                );
                self.cur_cv = cv_minus;
                self.fixed.remove(&e);
            }
        }
    }

    /// One round of forward selection: tests every applicable effect not yet in the model and
    /// adds the accepted one with the largest held-out gain; false when none was accepted.
    fn round(&mut self, round: usize) -> bool {
        // The static law again once an effect has joined: what the effect took out of the
        // residual may have hidden the law's shape in round 0 (a drift's slow share, for one).
        if round >= 2 && self.cur.law == Law::Power && self.spline(round, &[self.spline_m]) {
            self.retest_static();
        }
        let mut best: Option<Best> = None;
        // Saturation and crosstalk belong to the static law: decided in round 0.
        let todo: Vec<EffectKind> = EffectKind::ALL
            .into_iter()
            .filter(|&e| {
                !matches!(e, EffectKind::Saturation | EffectKind::Crosstalk)
                    && !self.cur.has(e)
                    && applicable(self.ctx, &self.cur, e).is_ok()
            })
            .collect();
        let stage = format!("round {round}: testing effects");
        for (step, &e) in todo.iter().enumerate() {
            (self.progress)(Progress {
                stage: &stage,
                step,
                of: todo.len(),
            });
            let tc = Instant::now();
            let sp = crate::timing::span(format!("  test {}", e.name()));
            let Some((cv, v, screened)) = self.best_variant(e) else {
                continue;
            };
            drop(sp);
            self.trials.push(Trial {
                round,
                effect: e.name().to_string(),
                verdict: v,
                seconds: tc.elapsed().as_secs_f64(),
                screened,
            });
            if v.accepted && best.as_ref().is_none_or(|b| v.rel_gain > b.2.rel_gain) {
                best = Some((e, cv, v));
            }
        }
        let Some((e, cv, _)) = best else {
            return false;
        };
        let before = self.cur_cv.clone();
        let _sp = crate::timing::span(format!("join {}", e.name()));
        self.join(&cv.fits);
        self.last = Some((e, before));
        true
    }

    /// Effect `e`'s variants (a latent drift's resolutions, the hysteresis forms, ...) held out
    /// against the current model: the accepted one with the best held-out fit, or, when none
    /// is accepted, the one the criterion likes best.
    fn best_variant(&self, e: EffectKind) -> Option<Tested> {
        let ds = self.ctx.ds;
        let mut tried: Option<Tested> = None;
        for (starts, params) in self.finalists(e) {
            let Some(first) = starts.first() else {
                continue;
            };
            let (cv, mut v, screened) = self.held_out(&starts, &params, n_params(first, e));
            signature_check(ds, e, &self.cur_cv, &cv, &mut v);
            // Among the variants the rule accepts, the best held-out fit; else the one the
            // criterion likes best (for the report).
            let better = |t: &Tested| match (v.accepted, t.1.accepted) {
                (true, false) => true,
                (false, true) => false,
                (true, true) => v.rel_gain > t.1.rel_gain,
                (false, false) => v.ic_gain > t.1.ic_gain,
            };
            if tried.as_ref().is_none_or(better) {
                tried = Some((cv, v, screened));
            }
        }
        tried
    }

    /// A variant held out against the current model: first in the screening view (see
    /// [`crate::screen`]), then, when the screen leaves it worth one, the full test, whose
    /// verdict alone can accept. True when the verdict is the screen's.
    fn held_out(&self, starts: &[Config], params: &[Param], k: ParamCount) -> Tested {
        let cv = cross_validate(self.screen, starts, params, self.ev_n);
        let v = compare(self.ctx, &self.cur_cv, &cv, k, &self.noise);
        if !crate::screen::worth_full_test(&v) {
            return (cv, v, true);
        }
        // Each fold's search starts where the screen's ended on the same training half.
        let [a, b] = &cv.fits;
        let from = [std::slice::from_ref(a), std::slice::from_ref(b)];
        let evals = crate::screen::full_evals(self.ev_n);
        let cv = cross_validate_from(self.ctx, from, params, evals);
        let v = compare(self.ctx, &self.cur_cv, &cv, k, &self.noise);
        (cv, v, false)
    }

    /// Effect `e`'s variants worth holding out: all of them when there are two or fewer; else
    /// the two whose best starting point on the whole recording scores best,
    /// `T ln(SSE) + 2 k ln(T)` with `T` the time samples over ten (a crude charge for the extra
    /// terms). The held-out test then decides between them and the criterion
    /// charges the one it keeps; a form that a quick fit ranks third or worse rarely wins.
    fn finalists(&self, e: EffectKind) -> Vec<Variant> {
        let all = candidates(self.ctx, &self.cur, e);
        if all.len() <= 2 {
            return all;
        }
        let t = (self.ctx.ds.len() as f64 / 10.0).max(10.0);
        let n = self.ctx.ds.n;
        let mut scored: Vec<(f64, Variant)> = all
            .into_iter()
            .map(|(starts, params)| {
                let Some(first) = starts.first() else {
                    return (f64::INFINITY, (starts, params));
                };
                let k = n_params(first, e);
                let sse = starts
                    .iter()
                    .map(|c| train_sse(self.ctx, c, &|_| true))
                    .fold(f64::INFINITY, f64::min)
                    .max(1e-300);
                let score = t * sse.ln() + 2.0 * (k.global + k.per_node * n) as f64 * t.ln();
                (score, (starts, params))
            })
            .collect();
        scored.sort_by(|a, b| a.0.total_cmp(&b.0));
        scored.into_iter().take(2).map(|(_, v)| v).collect()
    }

    /// The accepted candidate joins: all parameters are refitted on the whole recording, from
    /// the better (on the whole recording) of the candidate's two training-fold fits, and the
    /// refitted model is held out the way the next round's candidates will be.
    fn join(&mut self, fold_fits: &[Config]) {
        let ctx = self.ctx;
        let has_kappa = ctx.ds.kappa.is_some();
        let added = fold_fits
            .iter()
            .map(|c| (c, train_sse(ctx, c, &|_| true)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map_or_else(|| self.cur.clone(), |(c, _)| c.clone());
        let joint = |start: &Config| {
            fit_all(
                ctx,
                std::slice::from_ref(start),
                &all_params(start, has_kappa),
                self.ev_n * 2,
            )
        };
        self.cur = joint(&added);
        // Without the effect just accepted, the base fit may have driven the resistance floor
        // far from where it belongs (to nothing, when a missing sensitivity loss looked like
        // less saturation); the search seldom walks it back that far, and another effect then
        // stands in for it. So when the floor has moved more than fourfold, the joint refit also
        // starts from the start model's floor, and the better fit wins. (A second refit costs
        // about a third of a diagnosis; a floor within a factor of four needs no rescue.)
        let floor0 = self.cfg0.r_floor_ohm;
        let moved = (added.r_floor_ohm / floor0.max(1e-300)).ln().abs() > 4f64.ln();
        if added.r_floor_ohm > 0.0 && floor0 > 0.0 && moved {
            let reset = Config {
                r_floor_ohm: floor0,
                ..added.clone()
            };
            let alt = joint(&reset);
            if train_sse(ctx, &alt, &|_| true) < train_sse(ctx, &self.cur, &|_| true) {
                self.cur = alt;
            }
        }
        // The next round's candidates start from the jointly refitted model and refit all its
        // parameters per fold: the model they must beat is held out the same way. (Comparing
        // them with the accepted candidate's own cross-validation credited every one of them
        // with what the joint refit gained.)
        self.cur_cv = cross_validate(
            ctx,
            std::slice::from_ref(&self.cur),
            &refit_params(&self.cur, has_kappa),
            self.ev_n,
        );
    }

    /// Backward pass: drops an effect the others made unnecessary, until every effect left
    /// keeps its place; returns each remaining effect's held-out contribution (the reduced
    /// model's cross-validation and the verdict). The model without the effect that joined
    /// last is the previous round's model, whose held-out result is at hand (held out the same
    /// way: every parameter refitted on each training fold); it is not computed again.
    fn backward(&mut self) -> BTreeMap<EffectKind, (Cv, Verdict)> {
        let ctx = self.ctx;
        let ds = ctx.ds;
        let has_kappa = ds.kappa.is_some();
        let mut contributions: BTreeMap<EffectKind, (Cv, Verdict)> = BTreeMap::new();
        loop {
            contributions.clear();
            let effects: Vec<EffectKind> = self
                .cur
                .effects()
                .into_iter()
                .filter(|e| !self.fixed.contains_key(e))
                .collect();
            let mut dropped = false;
            for (step, &e) in effects.iter().enumerate() {
                (self.progress)(Progress {
                    stage: "backward pass",
                    step,
                    of: effects.len(),
                });
                let minus = self.cur.without(e);
                let cv_minus = match &self.last {
                    Some((last, cv)) if *last == e => cv.clone(),
                    _ => cross_validate(
                        ctx,
                        std::slice::from_ref(&minus),
                        &refit_params(&minus, has_kappa),
                        self.ev_n,
                    ),
                };
                let mut v = compare(
                    ctx,
                    &cv_minus,
                    &self.cur_cv,
                    n_params(&self.cur, e),
                    &self.noise,
                );
                signature_check(ds, e, &cv_minus, &self.cur_cv, &mut v);
                if !v.keep && effects.len() + self.fixed.len() >= 2 {
                    self.cur = fit_all(
                        ctx,
                        std::slice::from_ref(&minus),
                        &all_params(&minus, has_kappa),
                        self.ev_n * 2,
                    );
                    self.cur_cv = cv_minus;
                    self.last = None;
                    dropped = true;
                    break;
                }
                contributions.insert(e, (cv_minus, v));
            }
            if !dropped && !effects.is_empty() && self.law_redundant() {
                dropped = true;
            }
            if !dropped {
                return contributions;
            }
        }
    }

    /// With effects in the model, the spline law must still pay for itself against the start
    /// model's power law (the effects may have taken what it was taken for: the static part of
    /// a loop the base could not follow before hysteresis joined). When it does not keep its
    /// place, the power law comes back; true then.
    fn law_redundant(&mut self) -> bool {
        let Law::Spline(m) = self.cur.law else {
            return false;
        };
        let ctx = self.ctx;
        let has_kappa = ctx.ds.kappa.is_some();
        let minus = Config {
            law: Law::Power,
            exponent: self.cfg0.exponent,
            ..self.cur.clone()
        };
        let cv_minus = cross_validate(
            ctx,
            std::slice::from_ref(&minus),
            &refit_params(&minus, has_kappa),
            self.ev_n,
        );
        let v = compare(
            ctx,
            &cv_minus,
            &self.cur_cv,
            law_params_added(m),
            &self.noise,
        );
        if v.keep && v.rel_gain >= 0.5 * MIN_LAW_GAIN {
            return false;
        }
        self.trials.push(Trial {
            round: 0,
            effect: format!("static_law (back to the power law from the spline, {m} per node)"),
            verdict: v,
            seconds: 0.0,
            screened: false,
        });
        self.cur = fit_all(
            ctx,
            std::slice::from_ref(&minus),
            &all_params(&minus, has_kappa),
            self.ev_n * 2,
        );
        self.cur_cv = cv_minus;
        self.last = None;
        true
    }
}
