//! A latent drift fitted with the nodes, alternately, on each node's normal equations per
//! trial and knot segment: the alternation's linear steps never return to the samples.
//!
//! The latent thermal factor is piecewise linear in time, `m = a (1 - u) + b u` in the knot
//! segment with values `a`, `b` at its ends (`u` the sample's place in it). A node's normal
//! equations at the linearisation at the observations weigh each sample by `m^2`, and its
//! right side by `m`: summed once per trial and knot segment against `(1 - u)^2`, `u (1 - u)`
//! and `u^2` (and `1 - u`, `u` on the right), they are the node's normal equations for any
//! values of the factor. The factor's own least squares given the nodes' parameters reads the
//! same sums (its regressor is the node's prediction times the hat weights), and so do a
//! node's per-trial sensitivities (see `factors.rs`).

use super::fit::{Locals, NodeFit};
use crate::law::{Basis, RowMap};
use crate::numeric::{hat, solve_spd};

/// The least value of the latent factor at a knot for which the sums stand for the samples
/// (the per-sample factor is held at or above it, see `apply_latent`).
pub(super) const LEAST: f64 = 0.05;

/// One node's normal equations per trial and knot segment (full rows, lower triangles).
pub(super) struct Moments {
    pdim: usize,
    /// Knot segments.
    segs: usize,
    /// Trials (blocks of the node's own factors; one without them).
    blocks: usize,
    /// Per trial `t` and segment `j`, at `(t segs + j) 3 + mu`: the sums of `w x x'` times
    /// `(1 - u)^2`, `u (1 - u)`, `u^2`.
    a: Vec<f64>,
    /// At `(t segs + j) 2 + mu`: the sums of `w g x` times `1 - u`, `u`.
    b: Vec<f64>,
}

impl Moments {
    /// The node's normal equations per trial with the factor at `values` on the knots.
    pub(super) fn at(&self, values: &[f64]) -> Vec<(Vec<f64>, Vec<f64>)> {
        let (p, segs) = (self.pdim, self.segs);
        let pp = p * p;
        (0..self.blocks)
            .map(|t| {
                let mut a = vec![0.0; pp];
                let mut b = vec![0.0; p];
                for j in 0..segs {
                    let (va, vb) = (values[j], values[j + 1]);
                    let c = [va * va, 2.0 * va * vb, vb * vb];
                    let cell = t * segs + j;
                    for (mu, cm) in c.iter().enumerate() {
                        let s = &self.a[(cell * 3 + mu) * pp..(cell * 3 + mu + 1) * pp];
                        a.iter_mut().zip(s).for_each(|(x, y)| *x += cm * y);
                    }
                    for (mu, cm) in [va, vb].iter().enumerate() {
                        let r = &self.b[(cell * 2 + mu) * p..(cell * 2 + mu + 1) * p];
                        b.iter_mut().zip(r).for_each(|(x, y)| *x += cm * y);
                    }
                }
                (a, b)
            })
            .collect()
    }

    /// Adds the node's share of the latent factor's normal equations (`kk` knots, `a_lat`
    /// full, and `b_lat`) given its parameters `th` and own factor per trial `own`
    /// (scaling the regressors from `h` on).
    pub(super) fn add_latent(
        &self,
        (th, own, h): (&[f64], &[f64], usize),
        a_lat: &mut [f64],
        b_lat: &mut [f64],
    ) {
        let (p, segs) = (self.pdim, self.segs);
        let kk = segs + 1;
        let pp = p * p;
        let mut ths = vec![0.0; p];
        for t in 0..self.blocks {
            let f = own.get(t).copied().unwrap_or(1.0);
            for (u, x) in ths.iter_mut().enumerate() {
                *x = if u >= h { f * th[u] } else { th[u] };
            }
            for j in 0..segs {
                let cell = t * segs + j;
                let q: Vec<f64> = (0..3)
                    .map(|mu| {
                        quad(
                            &self.a[(cell * 3 + mu) * pp..(cell * 3 + mu + 1) * pp],
                            &ths,
                        )
                    })
                    .collect();
                a_lat[j * kk + j] += q[0];
                a_lat[j * kk + j + 1] += q[1];
                a_lat[(j + 1) * kk + j] += q[1];
                a_lat[(j + 1) * kk + j + 1] += q[2];
                for mu in 0..2 {
                    let r = &self.b[(cell * 2 + mu) * p..(cell * 2 + mu + 1) * p];
                    b_lat[j + mu] += r.iter().zip(&ths).map(|(x, y)| x * y).sum::<f64>();
                }
            }
        }
    }
}

/// `x' A x` for the symmetric `A` given by its lower triangle.
fn quad(a: &[f64], x: &[f64]) -> f64 {
    let p = x.len();
    let mut s = 0.0;
    for u in 0..p {
        let mut row = 0.0;
        for w in 0..u {
            row += a[u * p + w] * x[w];
        }
        s += x[u] * (a[u * p + u] * x[u] + 2.0 * row);
    }
    s
}

/// The latent factor's values at `kk` knots from its normal equations summed over the nodes,
/// with a light pull towards 1 (knots without training data stay at 1), normalised to a mean
/// of 1 (from the samples' sums too: `NodeFit::latent`).
pub(super) fn latent_values(mut a: Vec<f64>, mut b: Vec<f64>, kk: usize) -> Vec<f64> {
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

impl NodeFit<'_> {
    /// Node `k`'s [`Moments`] over its local regressors `locals` with the latent factor's
    /// `knots` (two or more) and `blocks` trials of own factors (one without them), at the
    /// linearisation at the observations.
    pub(super) fn moments(
        &self,
        k: usize,
        locals: &Locals,
        knots: &[f64],
        blocks: usize,
    ) -> Moments {
        let ds = self.ctx.ds;
        let lay = &self.terms.lay;
        let (pdim, vdim) = (lay.dim(), self.terms.vdim());
        let vsegs = self.terms.basis.as_ref().map_or(1, Basis::dim);
        let segs = knots.len().saturating_sub(1).max(1);
        let cells = vsegs * blocks * segs;
        let vv = vdim * vdim;
        let mut s = vec![0.0; cells * 3 * vv];
        let mut r = vec![0.0; cells * 2 * vdim];
        let base = k * self.fit_idx.len();
        for (j, &i) in self.fit_idx.iter().enumerate() {
            let w = self.obs.wgt[base + j];
            if w == 0.0 {
                continue;
            }
            let (seg, v) = locals.at(j);
            let t = if blocks > 1 { self.terms.trials[i] } else { 0 };
            let (kj, u) = hat(knots, ds.t[i]);
            let cell = (seg * blocks + t) * segs + kj;
            let c = [w * (1.0 - u) * (1.0 - u), w * u * (1.0 - u), w * u * u];
            let s3 = &mut s[cell * 3 * vv..(cell + 1) * 3 * vv];
            for p in 0..vdim {
                let xp = v[p];
                if xp == 0.0 {
                    continue;
                }
                for q in 0..=p {
                    let x = xp * v[q];
                    s3[p * vdim + q] += c[0] * x;
                    s3[vv + p * vdim + q] += c[1] * x;
                    s3[2 * vv + p * vdim + q] += c[2] * x;
                }
            }
            let g = w * self.obs.g2[base + j];
            let r2 = &mut r[cell * 2 * vdim..(cell + 1) * 2 * vdim];
            let (g0, g1) = (g * (1.0 - u), g * u);
            for p in 0..vdim {
                r2[p] += g0 * v[p];
                r2[vdim + p] += g1 * v[p];
            }
        }
        // Each cell's sums mapped to the full row (see `NodeFit::block_equations`).
        let pp = pdim * pdim;
        let mut a = vec![0.0; blocks * segs * 3 * pp];
        let mut b = vec![0.0; blocks * segs * 2 * pdim];
        let (zeros, mut scratch) = (vec![0.0; vdim], vec![0.0; pdim]);
        for seg in 0..vsegs {
            let map = RowMap::new(self.terms.basis.as_ref(), seg, lay.law_start() - 1);
            for t in 0..blocks {
                for kj in 0..segs {
                    let (cell, out) = ((seg * blocks + t) * segs + kj, t * segs + kj);
                    for mu in 0..3 {
                        let s_loc = &s[(cell * 3 + mu) * vv..(cell * 3 + mu + 1) * vv];
                        let a_out = &mut a[(out * 3 + mu) * pp..(out * 3 + mu + 1) * pp];
                        if mu < 2 {
                            let r_loc = &r[(cell * 2 + mu) * vdim..(cell * 2 + mu + 1) * vdim];
                            let b_out = &mut b[(out * 2 + mu) * pdim..(out * 2 + mu + 1) * pdim];
                            map.add(s_loc, r_loc, vdim, a_out, b_out);
                        } else {
                            map.add(s_loc, &zeros, vdim, a_out, &mut scratch);
                        }
                    }
                }
            }
        }
        Moments {
            pdim,
            segs,
            blocks,
            a,
            b,
        }
    }

    /// Node `k`'s parameters solved from its moments `mo` with the factor at `values` and its
    /// own per-trial factors `own`; with the per-trial normal equations they came from.
    #[allow(clippy::type_complexity)]
    pub(super) fn solve_moments(
        &self,
        mo: &Moments,
        values: &[f64],
        own: &[f64],
    ) -> (Vec<f64>, Vec<(Vec<f64>, Vec<f64>)>) {
        let eqs = mo.at(values);
        let (mut a, mut b) = self.combine(eqs.clone(), own);
        (self.solve(&mut a, &mut b), eqs)
    }
}

#[cfg(test)]
mod tests {
    use super::super::alternate::{fit_alternately, fit_latent_blocks};
    use super::super::*;

    /// The fit of `cfg` on every sample: alternating on the sums (`blocks`) or on the samples.
    #[allow(clippy::type_complexity)]
    fn fitted(
        ctx: &Context,
        cfg: &Config,
        blocks: bool,
    ) -> Option<(Vec<Vec<f64>>, Vec<f64>, Option<Vec<f64>>)> {
        let fit_idx: Vec<usize> = (0..ctx.ds.len()).collect();
        let mut terms = Terms::new(ctx, cfg, &fit_idx, false, 1);
        let (mut m, mut latent) = thermal_factor(ctx, cfg);
        let obs = Observed::cached(ctx, cfg, &fit_idx);
        let mut gains = cfg.curv_trials.clone();
        let factors = (&mut m, &mut latent, &mut gains);
        let data = (&*obs, &fit_idx[..]);
        let (theta, _) = if blocks {
            fit_latent_blocks(ctx, cfg, &mut terms, data, factors, 3, None)?.0
        } else {
            fit_alternately(ctx, cfg, &mut terms, data, factors, 3)
        };
        Some((theta, latent.map(|l| l.1)?, gains))
    }

    fn close(a: &[f64], b: &[f64], what: &str) {
        crate::testdata::assert_close(a, b, 1e-8, what);
    }

    #[test]
    fn the_alternation_on_the_sums_is_the_alternation_on_the_samples() {
        let ds = crate::testdata::drifting();
        let ctx = Context::new(&ds);
        let knots = crate::forms::latent_knots_n(&ds, 5);
        let latent = Some(Thermal::Latent {
            values: vec![1.0; knots.len()],
            knots_s: knots,
        });
        // A latent drift alone, and with a sensitivity per trial and node.
        let alone = Config {
            thermal: latent.clone(),
            ..Config::base(1.0, 0.0)
        };
        let per_node = Config {
            curv_trials: Some(vec![1.0; 6]),
            curv_per_node: Some(2),
            ..alone.clone()
        };
        for cfg in [alone, per_node] {
            let (th_b, v_b, g_b) = fitted(&ctx, &cfg, true).expect("the sums stand");
            let (th_s, v_s, g_s) = fitted(&ctx, &cfg, false).expect("a latent drift");
            for (a, b) in th_b.iter().zip(&th_s) {
                close(a, b, "node parameters");
            }
            close(&v_b, &v_s, "latent values");
            close(
                &g_b.unwrap_or_default(),
                &g_s.unwrap_or_default(),
                "factors",
            );
            // And the drift is found: its knots follow the sine, not the ones they started at.
            let spread = v_b.iter().cloned().fold(0.0, f64::max)
                - v_b.iter().cloned().fold(f64::INFINITY, f64::min);
            assert!(spread > 0.2, "{v_b:?}");
        }
    }

    #[test]
    fn a_knot_below_the_least_value_or_shared_factors_go_to_the_samples() {
        let ds = crate::testdata::drifting();
        let ctx = Context::new(&ds);
        let knots = crate::forms::latent_knots_n(&ds, 3);
        let low = Config {
            thermal: Some(Thermal::Latent {
                values: vec![1.0, 0.01, 1.0],
                knots_s: knots.clone(),
            }),
            ..Config::base(1.0, 0.0)
        };
        assert!(fitted(&ctx, &low, true).is_none());
        let shared = Config {
            thermal: Some(Thermal::Latent {
                values: vec![1.0; 3],
                knots_s: knots,
            }),
            curv_trials: Some(vec![1.0; 3]),
            ..Config::base(1.0, 0.0)
        };
        assert!(fitted(&ctx, &shared, true).is_none());
        assert!(fitted(&ctx, &shared, false).is_some());
    }
}
