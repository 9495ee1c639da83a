//! The alternations: each node's parameters fitted with the factors the nodes share or fit
//! per trial (a latent drift's knot values, per-trial sensitivities), alternately, on the
//! samples or on sums taken once over them (see `factors.rs` and `latent.rs`).

use super::fit::{Locals, NodeFit};
use super::terms::Terms;
use super::{apply_latent, latent, FirstRound, Observed};
use crate::context::Context;
use crate::effects::Config;

/// Each node's parameters and local regressors, as the per-node fits leave them.
pub(super) type Fitted = (Vec<Vec<f64>>, Vec<std::sync::Arc<Locals>>);

/// What an alternation refits between the node fits: the thermal factor per sample, a latent
/// drift's knots and values, and per-trial sensitivities.
pub(super) type Factors<'x> = (
    &'x mut Vec<f64>,
    &'x mut Option<(Vec<f64>, Vec<f64>)>,
    &'x mut Option<Vec<f64>>,
);

/// Each node's parameters and local regressors with the factors fitted alternately,
/// `iterations` fits (see [`fit_alternately`]): on the sums where they stand for the samples
/// ([`fit_node_factors`], [`fit_latent_blocks`]), else on the samples.
pub(super) fn fit_round(
    ctx: &Context,
    cfg: &Config,
    terms: &mut Terms,
    fit_data: (&Observed, &[usize]),
    (m, latent, gains): Factors,
    iterations: usize,
) -> Fitted {
    match gains {
        Some(g) if latent.is_none() && cfg.curv_per_node.is_some() => {
            let updates = (iterations - 1, None);
            fit_node_factors(ctx, cfg, terms, (fit_data, m), g, updates).0
        }
        _ => {
            let factors = (&mut *m, &mut *latent, &mut *gains);
            match fit_latent_blocks(ctx, cfg, terms, fit_data, factors, iterations, None) {
                Some((fitted, _)) => fitted,
                None => fit_alternately(ctx, cfg, terms, fit_data, (m, latent, gains), iterations),
            }
        }
    }
}

/// [`fit_round`] in two rounds when `rounds` is 2 and there is something to alternate, the
/// second from the factors the first left, and those factors: what a search's end re-reads
/// and the held-out evaluation then refits from (see [`super::evaluate_held_out_rereading`]).
/// On the sums the second round continues the first's alternation (its fits and factors are
/// the next iterations of the same sums, so the first round's last fit, which would go to the
/// samples, is left out); elsewhere the rounds run one after the other. Either way the same
/// fits and factors as the two rounds run in turn.
pub(super) fn fit_rounds(
    ctx: &Context,
    cfg: &Config,
    terms: &mut Terms,
    fit_data: (&Observed, &[usize]),
    (m, latent, gains): Factors,
    (iterations, rounds): (usize, usize),
) -> (Fitted, Option<FirstRound>) {
    if rounds < 2 || iterations < 2 {
        let fitted = fit_round(ctx, cfg, terms, fit_data, (m, latent, gains), iterations);
        return (fitted, None);
    }
    let updates = iterations - 1;
    match gains {
        Some(g) if latent.is_none() && cfg.curv_per_node.is_some() => {
            let twice = (2 * updates, Some(updates));
            let (fitted, first) = fit_node_factors(ctx, cfg, terms, (fit_data, m), g, twice);
            return (fitted, Some((None, first)));
        }
        _ => {
            let factors = (&mut *m, &mut *latent, &mut *gains);
            let twice = 2 * updates + 1;
            if let Some(out) =
                fit_latent_blocks(ctx, cfg, terms, fit_data, factors, twice, Some(updates))
            {
                return out;
            }
        }
    }
    let factors = (&mut *m, &mut *latent, &mut *gains);
    fit_round(ctx, cfg, terms, fit_data, factors, iterations);
    let first = (latent.as_ref().map(|l| l.1.clone()), gains.clone());
    let fitted = fit_round(ctx, cfg, terms, fit_data, (m, latent, gains), iterations);
    (fitted, Some(first))
}

/// Each node's parameters and local regressors, with a latent drift's thermal factor `m` (its
/// knot values in `latent`) or per-trial sensitivities `gains` refitted between the node fits
/// (`iterations` fits; all updated). The fits before the last take the linearisation at the
/// observations only: the factors are fitted at that linearisation too, and the last fit
/// takes the Gauss-Newton passes from there.
pub(super) fn fit_alternately(
    ctx: &Context,
    cfg: &Config,
    terms: &mut Terms,
    (obs, fit_idx): (&Observed, &[usize]),
    (m, latent, gains): Factors,
    iterations: usize,
) -> Fitted {
    let ds = ctx.ds;
    let n = ds.n;
    let mut theta: Vec<Vec<f64>> = Vec::new();
    let mut locals: Vec<std::sync::Arc<Locals>> = Vec::new();
    // The local regressors carry neither the thermal factor nor a node's own per-trial
    // factors: built once, unless a per-trial sensitivity shared by the nodes changes them.
    let shared_trial_gains = gains.is_some() && cfg.curv_per_node.is_none();
    let mut groups = Vec::new();
    for it in 0..iterations {
        if let Some((knots, values)) = &*latent {
            apply_latent(ctx, knots, values, m);
        }
        match (&*gains, cfg.curv_per_node) {
            (Some(g), Some(_)) => terms.set_node_factors(g, &ds.trial),
            (Some(g), None) => terms.sens = ds.trial.iter().map(|&j| g[j]).collect(),
            _ => {}
        }
        let rebuild = it == 0 || shared_trial_gains;
        if rebuild {
            groups = shared_locals(terms, n, fit_idx);
        }
        let fit = NodeFit::new(ctx, cfg, terms, (obs, fit_idx), groups.clone(), m);
        // After the first iteration each node starts from its own last parameters.
        let last = it + 1 == iterations;
        let warm = (it > 0).then_some(&theta);
        let reuse = if rebuild { &[][..] } else { &locals[..] };
        (theta, locals) = crate::parallel::map(n, |k| {
            fit.node(k, warm.map(|t| t[k].as_slice()), !last, reuse.get(k), None)
        })
        .into_iter()
        .unzip();
        if last {
            break;
        }
        // Latent thermal: refit the common-mode factor on the knots.
        if let Some((knots, values)) = latent {
            *values = fit.latent(knots, &theta);
        }
        if let Some(g) = gains {
            *g = match cfg.curv_per_node {
                Some(nn) => fit.node_trial_gains(&theta, &locals, g.len() / nn.max(1)),
                None => fit.trial_gains(&theta, g.len()),
            };
        }
    }
    (theta, locals)
}

/// As [`fit_alternately`] for a latent drift, with per-trial sensitivities per node or none:
/// every fit before the last, and the factors between them, solved from each node's normal
/// equations per trial and knot segment (one pass over its samples, see `latent.rs`); the last
/// fit from the samples. None, with nothing changed, where those sums do not stand for the
/// samples (shared per-trial sensitivities, fewer than two knots, a knot's value below
/// [`latent::LEAST`]): the caller alternates on the samples.
pub(super) fn fit_latent_blocks(
    ctx: &Context,
    cfg: &Config,
    terms: &mut Terms,
    (obs, fit_idx): (&Observed, &[usize]),
    (m, latent, gains): Factors,
    iterations: usize,
    mark: Option<usize>,
) -> Option<(Fitted, Option<FirstRound>)> {
    let ds = ctx.ds;
    let n = ds.n;
    let (knots, values) = latent.as_mut()?;
    let usable = |v: &[f64]| v.iter().all(|&x| x >= latent::LEAST);
    let shared_gains = gains.is_some() && cfg.curv_per_node.is_none();
    if knots.len() < 2 || iterations < 2 || shared_gains || !usable(values) {
        return None;
    }
    let trials = gains.as_ref().map_or(1, |g| g.len() / n.max(1));
    let mut own: Vec<Vec<f64>> = (0..n)
        .map(|k| match &*gains {
            Some(g) => (0..trials).map(|t| g[t * n + k]).collect(),
            None => vec![1.0],
        })
        .collect();
    if let Some(g) = &*gains {
        terms.set_node_factors(g, &ds.trial);
    }
    let groups = shared_locals(terms, n, fit_idx);
    let mut vals = values.clone();
    let mut first = None;
    let (theta, locals) = {
        let fit = NodeFit::new(ctx, cfg, terms, (obs, fit_idx), groups.clone(), m);
        let blocks = own.first().map_or(1, Vec::len);
        let (mo, locals): (Vec<latent::Moments>, Vec<_>) = crate::parallel::map(n, |k| {
            let loc = fit.locals(k, None);
            (fit.moments(k, &loc, knots, blocks), loc)
        })
        .into_iter()
        .unzip();
        let h = terms.lay.hyst_index();
        let kk = knots.len();
        let mut theta = Vec::new();
        for it in 0..iterations - 1 {
            let solved = crate::parallel::map(n, |k| fit.solve_moments(&mo[k], &vals, &own[k]));
            let (mut a, mut b) = (vec![0.0; kk * kk], vec![0.0; kk]);
            for (k, (th, _)) in solved.iter().enumerate() {
                mo[k].add_latent((th, &own[k], h), &mut a, &mut b);
            }
            let next = latent::latent_values(a, b, kk);
            if gains.is_some() {
                own = crate::parallel::map(n, |k| {
                    fit.factors_from(&solved[k].0, &solved[k].1, &own[k])
                });
            }
            theta = solved.into_iter().map(|(th, _)| th).collect::<Vec<_>>();
            if !usable(&next) {
                return None;
            }
            vals = next;
            if mark == Some(it + 1) {
                first = Some((Some(vals.clone()), gains.is_some().then(|| by_trial(&own))));
            }
        }
        (theta, locals)
    };
    *values = vals;
    apply_latent(ctx, knots, values, m);
    if let Some(g) = gains {
        g.iter_mut().zip(by_trial(&own)).for_each(|(d, f)| *d = f);
        terms.set_node_factors(g, &ds.trial);
    }
    // The last fit from the samples, as the alternation's: one Gauss-Newton pass from the
    // node's last parameters (the amplifier's linear fit).
    let fit = NodeFit::new(ctx, cfg, terms, (obs, fit_idx), groups, m);
    let (theta, locals): (Vec<_>, Vec<_>) = crate::parallel::map(n, |k| {
        fit.node(k, Some(&theta[k]), false, Some(&locals[k]), None)
    })
    .into_iter()
    .unzip();
    Some(((theta, locals), first))
}

/// Each node's parameters, local regressors and per-trial factors `g` (trial `j`, node `k` at
/// `j n + k`; updated), fitted node by node: `updates` alternations (see
/// [`NodeFit::node_with_factors`]), and the factors after the first `mark` of them. `terms`
/// are left with the factors the nodes were fitted with last.
pub(super) fn fit_node_factors(
    ctx: &Context,
    cfg: &Config,
    terms: &mut Terms,
    ((obs, fit_idx), m): ((&Observed, &[usize]), &[f64]),
    g: &mut [f64],
    (updates, mark): (usize, Option<usize>),
) -> (Fitted, Option<Vec<f64>>) {
    let n = ctx.ds.n;
    terms.set_node_factors(g, &ctx.ds.trial);
    let trials = g.len() / n.max(1);
    let per_node = {
        let groups = shared_locals(terms, n, fit_idx);
        let fit = NodeFit::new(ctx, cfg, terms, (obs, fit_idx), groups, m);
        let g: &[f64] = g;
        crate::parallel::map(n, |k| {
            let own = (0..trials).map(|t| g[t * n + k]).collect();
            fit.node_with_factors(k, own, updates, mark)
        })
    };
    let mut theta = Vec::with_capacity(n);
    let mut locals = Vec::with_capacity(n);
    let mut own = Vec::with_capacity(n);
    let mut marked = Vec::with_capacity(n);
    for (th, loc, o, at_mark) in per_node {
        theta.push(th);
        locals.push(loc);
        own.push(o);
        marked.extend(at_mark);
    }
    g.iter_mut().zip(by_trial(&own)).for_each(|(d, f)| *d = f);
    terms.set_node_factors(g, &ctx.ds.trial);
    let first = (marked.len() == n).then(|| by_trial(&marked));
    ((theta, locals), first)
}

/// Each node's per-trial factors (`own[k][j]`) laid out trial by trial (trial `j`, node `k` at
/// `j n + k`).
fn by_trial(own: &[Vec<f64>]) -> Vec<f64> {
    let n = own.len();
    let trials = own.first().map_or(0, Vec::len);
    let mut g = vec![1.0; trials * n];
    for (k, o) in own.iter().enumerate() {
        for (t, f) in o.iter().enumerate() {
            g[t * n + k] = *f;
        }
    }
    g
}

/// The local regressors of each group of nodes that share them (see [`Terms::group`]): one set
/// for all nodes when they read the same load, one per load series when fewer series than nodes
/// (nodes with the same load scale); empty when every node has its own.
fn shared_locals(terms: &Terms, n: usize, fit_idx: &[usize]) -> Vec<std::sync::Arc<Locals>> {
    if terms.node_independent() {
        return vec![std::sync::Arc::new(Locals::new(terms, 0, fit_idx))];
    }
    let Some((_, groups)) = terms.group(0) else {
        return Vec::new();
    };
    if groups >= n {
        return Vec::new();
    }
    // The first node of each group stands for it.
    let first: Vec<usize> = (0..groups)
        .map(|g| {
            (0..n)
                .find(|&k| terms.group(k).is_some_and(|(h, _)| h == g))
                .unwrap_or(0)
        })
        .collect();
    crate::parallel::map(groups, |g| {
        std::sync::Arc::new(Locals::new(terms, first[g], fit_idx))
    })
}

#[cfg(test)]
mod tests {
    use super::super::{evaluate_held_out, evaluate_held_out_rereading, evaluate_with, Eval};
    use crate::context::Context;
    use crate::effects::{Config, Thermal};

    fn close(a: &[f64], b: &[f64], what: &str) {
        crate::testdata::assert_close(a, b, 1e-9, what);
    }

    /// What a fold did before the two rounds: the factors re-read from a fit on the held-out
    /// evaluation's samples, then the held-out evaluation from them.
    fn reread_then_held_out(ctx: &Context, cfg: &Config, train: &dyn Fn(usize) -> bool) -> Eval {
        let read = evaluate_with(ctx, cfg, train, ctx.held_out_stride(), false);
        let cfg = crate::search::with_fitted_factors(cfg.clone(), read.latent, read.trial_gains);
        let mut ev = evaluate_held_out(ctx, &cfg, train);
        let values = match &cfg.thermal {
            Some(Thermal::Latent { values, .. }) => Some(values.clone()),
            _ => None,
        };
        ev.first_round = Some((values, cfg.curv_trials.clone()));
        ev
    }

    #[test]
    fn two_rounds_in_one_evaluation_are_the_reread_and_the_held_out_evaluation() {
        let ds = crate::testdata::drifting();
        let ctx = Context::new(&ds);
        let knots = crate::forms::latent_knots_n(&ds, 5);
        let latent = Config {
            thermal: Some(Thermal::Latent {
                values: vec![1.0; knots.len()],
                knots_s: knots,
            }),
            ..Config::base(1.0, 0.0)
        };
        let per_node = |c: &Config| Config {
            curv_trials: Some(vec![1.0; 6]),
            curv_per_node: Some(2),
            ..c.clone()
        };
        let shared = |c: &Config| Config {
            curv_trials: Some(vec![1.0; 3]),
            ..c.clone()
        };
        let base = Config::base(1.0, 0.0);
        // On the sums: per-node sensitivities, a latent drift, both. On the samples: shared
        // sensitivities, alone and with the drift.
        let cases = [
            per_node(&base),
            latent.clone(),
            per_node(&latent),
            shared(&base),
            shared(&latent),
        ];
        let train = |i: usize| !i.is_multiple_of(3);
        for (c, cfg) in cases.iter().enumerate() {
            let want = reread_then_held_out(&ctx, cfg, &train);
            let got = evaluate_held_out_rereading(&ctx, cfg, &train);
            let what = |x: &str| format!("case {c}: {x}");
            close(&got.pred, &want.pred, &what("held-out predictions"));
            let (Some((gv, gg)), Some((wv, wg))) = (&got.first_round, &want.first_round) else {
                panic!("case {c}: no first round");
            };
            close(
                &gv.clone().unwrap_or_default(),
                &wv.clone().unwrap_or_default(),
                &what("re-read knots"),
            );
            close(
                &gg.clone().unwrap_or_default(),
                &wg.clone().unwrap_or_default(),
                &what("re-read factors"),
            );
            // The first round moved the factors from where they started (all ones).
            let moved = gv
                .iter()
                .chain(gg)
                .flatten()
                .any(|x| (x - 1.0).abs() > 0.02);
            assert!(moved, "case {c}: {gv:?} {gg:?}");
            let final_factors = |e: &Eval| {
                let mut f = e.latent.clone().unwrap_or_default();
                f.extend(e.trial_gains.clone().unwrap_or_default());
                f
            };
            close(
                &final_factors(&got),
                &final_factors(&want),
                &what("final factors"),
            );
        }
        // Nothing to alternate: one round, and no first round to read.
        let plain = evaluate_held_out_rereading(&ctx, &base, &train);
        assert!(plain.first_round.is_none());
        close(
            &plain.pred,
            &evaluate_held_out(&ctx, &base, &train).pred,
            "no factors",
        );
    }
}
