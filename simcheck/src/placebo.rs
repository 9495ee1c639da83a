//! The crosstalk placebo. With a fixed load map the row droop `G (1 - Rs sum_row G)` is a
//! static function of the force, so a candidate crosstalk can stand in for any static misfit
//! the start law leaves (a per-node law shape, as zoo-sat's saturating law has: training
//! seeds 4 and 5 named crosstalk on the null case at block t 3.9). What only crosstalk has is
//! its coupling along the rows the readout switches. So the same droop is also fitted along
//! the columns, on the recording transposed; crosstalk is accepted only when the rows beat the
//! columns by the acceptance rule (no parameter more), as the readout's physics says they
//! must. Crosstalk is decided in round 0, before any dynamic effect: when one joins later,
//! the rows are held against the columns once more with it in the model, since what a loop
//! the static law cannot follow leaves may have been what the rows fitted better.

use crate::candidates::{candidates, ParamCount};
use crate::context::Context;
use crate::cv::{compare, cross_validate, Cv, Verdict};
use crate::data::Dataset;
use crate::diagnose::Trial;
use crate::effects::{Config, EffectKind};
use crate::noise::NoiseModel;
use crate::search::{all_params, fit_all, refit_params};
use crate::selection::Selection;

impl Selection<'_> {
    /// Before the backward pass: when crosstalk was named in round 0 and a dynamic effect
    /// joined since, the rows are held against the same droop along the columns again, every
    /// other effect in the model (the backward pass never holds round 0's static effects out).
    /// Crosstalk goes when the rows no longer beat the columns (recorded in `backward` as
    /// `crosstalk (rows against the columns, final effects)`).
    pub(crate) fn recheck_crosstalk(&mut self) {
        let ctx = self.ctx;
        let dynamic_joined = self
            .cur
            .effects()
            .iter()
            .any(|e| !self.fixed.contains_key(e));
        if !self.fixed.contains_key(&EffectKind::Crosstalk) || !dynamic_joined {
            return;
        }
        let minus = self.cur.without(EffectKind::Crosstalk);
        let columns = column_crosstalk(ctx, &minus, self.ev_n);
        let v = rows_beat_columns(ctx, &self.noise, &columns, &self.cur_cv);
        self.backward.push(Trial {
            round: self.trials.iter().map(|t| t.round).max().unwrap_or(0),
            effect: "crosstalk (rows against the columns, final effects)".into(),
            verdict: v,
            seconds: 0.0,
            screened: false,
        });
        if v.accepted {
            return;
        }
        let has_kappa = ctx.ds.kappa.is_some();
        self.cur_cv = cross_validate(
            ctx,
            std::slice::from_ref(&minus),
            &refit_params(&minus, has_kappa),
            self.ev_n,
        );
        self.cur = fit_all(
            ctx,
            std::slice::from_ref(&minus),
            &all_params(&minus, has_kappa),
            self.ev_n * 2,
        );
        self.fixed.remove(&EffectKind::Crosstalk);
        self.last = None;
    }
}

/// `ds` transposed (rows and columns swapped, nodes renumbered column-major), with each new
/// node's old index.
pub fn transposed(ds: &Dataset) -> (Dataset, Vec<usize>) {
    let (rows, cols, n) = (ds.rows, ds.cols, ds.n);
    // New node `c * rows + r` is old node `r * cols + c`.
    let old: Vec<usize> = (0..n).map(|k| (k % rows) * cols + k / rows).collect();
    let y =
        ds.y.chunks(n)
            .flat_map(|frame| old.iter().map(|&o| frame[o]).collect::<Vec<_>>())
            .collect();
    let t = Dataset {
        path: format!("{} (transposed)", ds.path),
        rows: cols,
        cols: rows,
        y,
        stats: Default::default(),
        ..ds.clone()
    };
    (t, old)
}

/// The held-out result of crosstalk fitted along the columns: crosstalk's starting points on
/// `cur` held out on the transposed recording, its residual put back in node order.
pub fn column_crosstalk(ctx: &Context, cur: &Config, evals: usize) -> Cv {
    let (tds, old) = transposed(ctx.ds);
    let tctx = Context::new(&tds);
    let (starts, params) = candidates(&tctx, cur, EffectKind::Crosstalk)
        .into_iter()
        .next()
        .unwrap_or_default();
    let mut cv = cross_validate(&tctx, &starts, &params, evals);
    let n = ctx.ds.n;
    let mut resid = vec![0.0; cv.resid.len()];
    let mut node_sse = vec![0.0; n];
    for (knew, &kold) in old.iter().enumerate() {
        node_sse[kold] = cv.node_sse[knew];
        for i in 0..ctx.ds.len() {
            resid[i * n + kold] = cv.resid[i * n + knew];
        }
    }
    cv.resid = resid;
    cv.node_sse = node_sse;
    cv
}

/// Whether the row crosstalk `rows` beats the same droop along the columns `columns` by the
/// acceptance rule.
pub fn rows_beat_columns(ctx: &Context, noise: &NoiseModel, columns: &Cv, rows: &Cv) -> Verdict {
    compare(
        ctx,
        columns,
        rows,
        ParamCount {
            global: 0,
            per_node: 0,
        },
        noise,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transposing_swaps_rows_and_columns_and_keeps_every_reading() {
        let mut ds = crate::testdata::presses_on(2, 3);
        let len = ds.len();
        ds.y = (0..len * 6).map(|v| v as f64).collect();
        let (t, old) = transposed(&ds);
        assert_eq!((t.rows, t.cols, t.n), (3, 2, 6));
        // Old node (row 0, col 1) = 1 is new node (row 1, col 0) = 2.
        assert_eq!(old[2], 1);
        assert_eq!(t.y[2], ds.y[1]);
        assert_eq!(t.y[6 + 3], ds.y[6 + old[3]]);
        let mut a = t.y.clone();
        a.sort_by(f64::total_cmp);
        assert_eq!(a, ds.y);
    }
}
