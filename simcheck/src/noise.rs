//! The noise model: what the readings do when nothing but noise moves them, estimated on the
//! no-load spans of the base model's held-out residual, so that neither a slow wander nor a
//! rare spike passes for missing physics.
//!
//! Per node, the residual at rest is white noise plus two first-order autoregressive parts, a
//! fast one (sample-to-sample correlation of the readout) and a slow wander (a reference or a
//! contact drifting over seconds to minutes); a common-mode share of the wander moves every
//! node together (kept at 0: see [`NoiseModel::common`]). The autocovariance `gamma(l) = w delta(l) + f rho_f^l + s rho_s^l` is fitted
//! from lags 0, 1, 2, one second and two seconds. Rare one-frame spikes are taken out of the
//! readings before any fit ([`spikes`]).
//!
//! The criterion uses it through [`NoiseModel::seen_by`]: the noise variance that a change `d`
//! of the prediction is measured against, `d' C d / d' d` with `C` the noise covariance. A fast
//! change (a loop on every ramp) is measured against about the white noise; a slow one (a
//! drift) against the wander as well, so a wander is not evidence of a drift. The `unexplained`
//! rule measures each node's residual against its whole noise ([`NoiseModel::floor`]).

use serde::Serialize;

use crate::context::Context;
use crate::wander::CommonWander;

/// The longer lag (s) at which [`NoiseModel::colours`] measures a residual's slow part.
pub const LONG_LAG_S: f64 = 5.0;

/// One node's (or the common mode's) noise: variances and per-sample correlations.
#[derive(Debug, Clone, Copy, Serialize, Default)]
pub struct Parts {
    /// White variance.
    pub white: f64,
    /// Fast autoregressive part: variance and lag-one correlation.
    pub fast: f64,
    pub rho_fast: f64,
    /// Slow wander: variance and lag-one correlation.
    pub slow: f64,
    pub rho_slow: f64,
}

impl Parts {
    pub fn total(&self) -> f64 {
        self.white + self.fast + self.slow
    }
}

/// The estimated noise.
#[derive(Debug, Clone, Serialize)]
pub struct NoiseModel {
    pub nodes: Vec<Parts>,
    /// The wander shared by every node (its variance is part of each node's `slow`). Not
    /// estimated (0): at rest it cannot be told from a common drift, which is an effect.
    pub common: Parts,
    /// Correlation time of the slow wander (s), for the report.
    pub wander_tau_s: f64,
    /// How many no-load samples the estimate rests on.
    pub rest_samples: usize,
    /// Readings taken out as one-frame spikes before the fit.
    pub spikes_rejected: usize,
    /// The wander every node shares, estimated from the nodes at rest and taken out of the
    /// held-out residuals before models are compared (see [`crate::wander`]).
    pub wander: CommonWander,
}

/// Autocovariances at lags `lags` of `x` over the runs of consecutive samples where `keep`
/// holds (pairs must both be kept), about the mean of the kept samples. All lags in one pass
/// over the samples (each lag's sum in the same order as a pass of its own).
fn autocov<const L: usize>(x: &[f64], keep: &[bool], lags: &[usize; L]) -> Vec<f64> {
    let kept: Vec<f64> = x
        .iter()
        .zip(keep)
        .filter(|(_, k)| **k)
        .map(|(v, _)| *v)
        .collect();
    if kept.len() < 10 {
        return vec![0.0; L];
    }
    let mean = kept.iter().sum::<f64>() / kept.len() as f64;
    let len = x.len().min(keep.len());
    let (mut s, mut c) = ([0.0; L], [0usize; L]);
    for i in 0..len {
        if !keep[i] {
            continue;
        }
        let xi = x[i] - mean;
        for q in 0..L {
            let j = i + lags[q];
            if j < len && keep[j] {
                s[q] += xi * (x[j] - mean);
                c[q] += 1;
            }
        }
    }
    (0..L)
        .map(|q| if c[q] > 5 { s[q] / c[q] as f64 } else { 0.0 })
        .collect()
}

/// `d` (sample-major, `n` nodes) node by node: node `k`'s column at `k len .. (k + 1) len`
/// (`len` the whole samples in `d`). One pass over `d` for each half of the nodes, side by
/// side, rather than one strided pass per node (each of which reads every cache line of `d`).
pub(crate) fn by_node<T: Copy + Default + Send + Sync>(d: &[T], n: usize) -> Vec<T> {
    let n = n.max(1);
    let len = d.len() / n;
    let mut out = vec![T::default(); len * n];
    let half = n.div_ceil(2);
    crate::parallel::chunks_mut(&mut out, (half * len).max(1), |c, chunk| {
        let k0 = c * half;
        let nodes = chunk.len() / len.max(1);
        for i in 0..len {
            let row = &d[i * n + k0..i * n + k0 + nodes];
            for (kk, v) in row.iter().enumerate() {
                chunk[kk * len + i] = *v;
            }
        }
    });
    out
}

/// No-load samples far from any load: the force at most 2 % of its peak for the last
/// `after_s` seconds (what a release leaves, a hysteresis remnant or a creep recovery, is not
/// noise; the noise model asks for 2 s, the wander for [`crate::wander::QUIET_AFTER_S`]).
pub(crate) fn quiet_rest(ds: &crate::data::Dataset, after_s: f64) -> Vec<bool> {
    let limit = 0.02 * ds.max_force();
    let mut last_load = f64::NEG_INFINITY;
    ds.t.iter()
        .zip(&ds.force)
        .map(|(&t, &f)| {
            if f > limit {
                last_load = t;
            }
            f <= limit && t - last_load >= after_s
        })
        .collect()
}

/// Each node's parts capped at twice the median over nodes: the nodes share one readout, and a
/// node whose rest readings are far noisier than the others' carries structure (a broken
/// thread, a remnant), which must stay visible against the others' noise. The coloured parts
/// together are also capped at three times the white part: at rest a wander cannot be told
/// from what an unnamed effect leaves there (a hysteresis remnant that changes from press to
/// press, a drift), and only the white part is measured without that doubt (the zoo's wanders
/// are 0.2 to 2.6 times their white variance).
fn capped(mut nodes: Vec<Parts>) -> Vec<Parts> {
    let med = |f: &dyn Fn(&Parts) -> f64| {
        let mut v: Vec<f64> = nodes.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    let (w, fa, sl) = (med(&|p| p.white), med(&|p| p.fast), med(&|p| p.slow));
    for p in nodes.iter_mut() {
        p.white = p.white.min(2.0 * w);
        p.fast = p.fast.min(2.0 * fa);
        p.slow = p.slow.min(2.0 * sl);
        let coloured = p.fast + p.slow;
        if coloured > 3.0 * p.white && coloured > 0.0 {
            let k = 3.0 * p.white / coloured;
            p.fast *= k;
            p.slow *= k;
        }
    }
    nodes
}

/// Fits `white + fast rho_f^l + slow rho_s^l` to autocovariances at lags 0, 1, 2, `big` and
/// `2 big`. The coloured part is what lags 1 and 2 still see (one AR(1) through them, or, when
/// lag 2 sees as much as lag 1, a persistent part of lag 1's size); the rest is white. The
/// long lags say how much of the coloured part is the slow wander.
fn parts(g: &[f64], big: usize) -> Parts {
    let (g0, g1, g2, gb, g2b) = (g[0], g[1], g[2], g[3], g[4]);
    if g0 <= 0.0 {
        return Parts::default();
    }
    let coloured = if g1 > 0.0 && g2 > 0.0 {
        let r = (g2 / g1).clamp(1e-3, 1.0);
        (g1 / r).min(g0)
    } else {
        g1.max(0.0).min(g0)
    };
    let white = g0 - coloured;
    // Slow part from the long lags, where the fast part has died out.
    let (slow, rho_slow) = if gb > 0.0 && g2b > 0.0 && g2b < gb {
        let rb = (g2b / gb).clamp(1e-6, 0.999_999);
        ((gb / rb).min(coloured), rb.powf(1.0 / big as f64))
    } else if gb > 0.0 {
        // Flat over the long lags: a wander slower than the span; treat it as constant there.
        (gb.min(coloured), 1.0 - 1.0 / (10.0 * big as f64))
    } else {
        (0.0, 0.0)
    };
    let fast = (coloured - slow).max(0.0);
    let rho_fast = if fast > 0.0 {
        ((g1 - slow * rho_slow) / fast).clamp(0.0, 0.99)
    } else {
        0.0
    };
    Parts {
        white,
        fast,
        rho_fast,
        slow,
        rho_slow,
    }
}

/// `sum_ij x_i x_j rho^|i-j|` in one pass.
fn ar_quadratic(x: &[f64], rho: f64) -> f64 {
    ar_quadratics(x, [rho])[0]
}

/// [`ar_quadratic`] for each of `rhos`, in one pass (each sum in the same order as a pass of
/// its own).
fn ar_quadratics<const R: usize>(x: &[f64], rhos: [f64; R]) -> [f64; R] {
    let mut f = [0.0; R];
    let mut s = [0.0; R];
    for &v in x {
        for q in 0..R {
            f[q] = v + rhos[q] * f[q];
            s[q] += v * (2.0 * f[q] - v);
        }
    }
    s
}

impl NoiseModel {
    /// Estimates the noise from the held-out residual `resid` on the context's no-load samples
    /// (force at most 2 % of the peak).
    pub fn estimate(ctx: &Context, resid: &[f64]) -> NoiseModel {
        Self::estimate_with(ctx, resid, None)
    }

    /// [`NoiseModel::estimate`] with the common wander already known (estimated on another
    /// residual and taken out of the readings): it is kept as it is, not estimated again.
    pub fn estimate_with(ctx: &Context, resid: &[f64], wander: Option<CommonWander>) -> NoiseModel {
        let ds = ctx.ds;
        let (len, n) = (ds.len(), ds.n);
        let big = ((1.0 / ds.dt()).round() as usize).clamp(3, (len / 8).max(3));
        let lags = [0, 1, 2, big, 2 * big];
        let rest = quiet_rest(ds, 2.0);
        // Each node against the mean of the nodes at the same sample: what moves every node
        // together at rest (a drift of temperature, a new mounting's baselines, a common
        // wander) cannot be told apart there and is left to the held-out test; what is left is
        // each node's own noise (the mean's share of it undone by n / (n - 1)).
        let mean: Vec<f64> = (0..len)
            .map(|i| (0..n).map(|k| resid[i * n + k]).sum::<f64>() / n as f64)
            .collect();
        let undo = if n > 1 {
            n as f64 / (n - 1) as f64
        } else {
            1.0
        };
        // Each node's parts on their own (on two threads when free), in node order.
        let (cols, usable) = (by_node(resid, n), by_node(&ctx.usable, n));
        let nodes: Vec<Parts> = crate::parallel::map(n, |k| {
            let col = &cols[k * len..(k + 1) * len];
            let x: Vec<f64> = (0..len)
                .map(|i| col[i] - if n > 1 { mean[i] } else { 0.0 })
                .collect();
            let usable = &usable[k * len..(k + 1) * len];
            let keep: Vec<bool> = (0..len).map(|i| rest[i] && usable[i]).collect();
            let g: Vec<f64> = autocov(&x, &keep, &lags).iter().map(|v| v * undo).collect();
            parts(&g, big)
        });
        let nodes = capped(nodes);
        let common = Parts::default();
        let rho = nodes.iter().map(|p| p.rho_slow).sum::<f64>() / n.max(1) as f64;
        let own = nodes.iter().map(Parts::total).sum::<f64>() / n.max(1) as f64;
        let slow = nodes.iter().map(|p| p.slow + p.fast).sum::<f64>() / n.max(1) as f64;
        NoiseModel {
            wander: wander.unwrap_or_else(|| CommonWander::estimate(ctx, resid, own, slow)),
            wander_tau_s: if rho > 0.0 && rho < 1.0 {
                -ds.dt() / rho.ln()
            } else {
                0.0
            },
            nodes,
            common,
            rest_samples: rest.iter().filter(|r| **r).count(),
            spikes_rejected: ctx.spikes,
        }
    }

    /// The noise variance a change `d` of the held-out prediction (sample-major, `n` nodes) is
    /// measured against: `d' C d / d' d`. Each node's own parts (its parts less the common
    /// ones) act on its own column of `d`; the common parts on the sum over nodes.
    pub fn seen_by(&self, d: &[f64], n: usize) -> f64 {
        let len = d.len() / n.max(1);
        let dd: f64 = d.iter().map(|v| v * v).sum();
        if dd <= 0.0 {
            return self.nodes.iter().map(Parts::total).sum::<f64>() / n.max(1) as f64;
        }
        let c = &self.common;
        // Each node's share computed on its own (on two threads when free), summed in node
        // order: the result does not depend on the split.
        let cols = by_node(d, n);
        let per_node = crate::parallel::map(self.nodes.len(), |k| {
            let p = &self.nodes[k];
            let col = cols.get(k * len..(k + 1) * len).unwrap_or(&[]);
            let own: f64 = col.iter().map(|v| v * v).sum();
            let [fast, slow] = ar_quadratics(col, [p.rho_fast, p.rho_slow]);
            (p.white - c.white).max(0.0) * own
                + (p.fast - c.fast).max(0.0) * fast
                + (p.slow - c.slow).max(0.0) * slow
        });
        let mut q = 0.0;
        for v in per_node {
            q += v;
        }
        if c.total() > 0.0 {
            let sum: Vec<f64> = (0..len)
                .map(|i| d[i * n..(i + 1) * n].iter().sum())
                .collect();
            let ss: f64 = sum.iter().map(|v| v * v).sum();
            let [fast, slow] = ar_quadratics(&sum, [c.rho_fast, c.rho_slow]);
            q += c.white * ss + c.fast * fast + c.slow * slow;
        }
        q / dd
    }

    /// The colour of a residual over every usable sample (not only at rest): each node's
    /// parts, and the part every node shares, from the mean over nodes (whose own parts have
    /// averaged down by `n`). What a model leaves is noise to the criterion too: a change is
    /// measured against this as well as against the noise (see `cv::compare`), so a leftover
    /// that moves every node together, or slowly, does not count as many independent samples.
    /// Two views: the slow part measured at lags of 1 and 2 s, and at 5 and 10 s
    /// ([`LONG_LAG_S`]), where a wander of tens of seconds still shows (at 1 and 2 s it looks
    /// a few seconds long, and a slow change would count it many times over); a change is
    /// measured against the larger.
    pub fn colours(ctx: &Context, resid: &[f64]) -> [NoiseModel; 2] {
        let (short, long) = crate::parallel::join(
            || Self::colour_at(ctx, resid, 1.0),
            || Self::colour_at(ctx, resid, LONG_LAG_S),
        );
        [short, long]
    }

    /// [`NoiseModel::colours`]' view with the slow part measured at lags of `lag_s` and twice
    /// that.
    pub fn colour_at(ctx: &Context, resid: &[f64], lag_s: f64) -> NoiseModel {
        let ds = ctx.ds;
        let (len, n) = (ds.len(), ds.n);
        let big = ((lag_s / ds.dt()).round() as usize).clamp(3, (len / 8).max(3));
        let lags = [0, 1, 2, big, 2 * big];
        // Each node's parts, and the mean's beside them.
        let (nodes, m) = crate::parallel::join(
            || {
                let (cols, usable) = (by_node(resid, n), by_node(&ctx.usable, n));
                crate::parallel::map(n, |k| {
                    let at = k * len..(k + 1) * len;
                    parts(&autocov(&cols[at.clone()], &usable[at], &lags), big)
                })
            },
            || {
                let mean: Vec<f64> = (0..len)
                    .map(|i| (0..n).map(|k| resid[i * n + k]).sum::<f64>() / n as f64)
                    .collect();
                let all = vec![true; len];
                parts(&autocov(&mean, &all, &lags), big)
            },
        );
        let avg = |f: &dyn Fn(&Parts) -> f64| nodes.iter().map(f).sum::<f64>() / n.max(1) as f64;
        let nf = n as f64;
        // var(mean) = common + own / n; the common part cannot exceed the nodes' own.
        let share =
            |mv: f64, own: f64| ((mv - own / nf) * nf / (nf - 1.0).max(1.0)).clamp(0.0, own);
        let common = if n > 1 {
            Parts {
                white: share(m.white, avg(&|p| p.white)),
                fast: share(m.fast, avg(&|p| p.fast)),
                rho_fast: m.rho_fast,
                slow: share(m.slow, avg(&|p| p.slow)),
                rho_slow: m.rho_slow,
            }
        } else {
            Parts::default()
        };
        NoiseModel {
            wander: CommonWander::default(),
            nodes,
            common,
            wander_tau_s: 0.0,
            rest_samples: 0,
            spikes_rejected: 0,
        }
    }

    /// The noise variance of `sum d r` for a residual `r` of pure noise: `d' C d`, with each
    /// node's own parts and the common wander ([`crate::wander`]) on the sum over nodes (`dt`:
    /// the sample interval).
    pub fn quadratic(&self, d: &[f64], n: usize, dt: f64) -> f64 {
        let dd: f64 = d.iter().map(|v| v * v).sum();
        let own = self.seen_by(d, n) * dd;
        let w = &self.wander;
        if w.variance <= 0.0 || n == 0 {
            return own;
        }
        let sum: Vec<f64> = d.chunks(n).map(|c| c.iter().sum()).collect();
        own + w.variance * ar_quadratic(&sum, (-dt / w.tau_s.max(1e-9)).exp())
    }

    /// As [`NoiseModel::seen_by`] for node `k` of the change alone (its whole wander counted
    /// as its own).
    pub fn seen_by_node(&self, d: &[f64], n: usize, k: usize) -> f64 {
        let Some(p) = self.nodes.get(k) else {
            return 0.0;
        };
        let col: Vec<f64> = d.iter().skip(k).step_by(n.max(1)).copied().collect();
        let dd: f64 = col.iter().map(|v| v * v).sum();
        if dd <= 0.0 {
            return p.total();
        }
        let [fast, slow] = ar_quadratics(&col, [p.rho_fast, p.rho_slow]);
        (p.white * dd + p.fast * fast + p.slow * slow) / dd
    }

    /// White noise of variance `var` on each of `n` nodes, nothing else (for tests).
    #[cfg(test)]
    pub(crate) fn white(n: usize, var: f64) -> NoiseModel {
        NoiseModel {
            nodes: vec![
                Parts {
                    white: var,
                    ..Parts::default()
                };
                n
            ],
            common: Parts::default(),
            wander_tau_s: 0.0,
            rest_samples: 0,
            spikes_rejected: 0,
            wander: CommonWander::default(),
        }
    }

    /// Node `k`'s whole noise (standard deviation).
    pub fn floor(&self, k: usize) -> f64 {
        self.nodes.get(k).map_or(0.0, |p| p.total().sqrt())
    }
}

/// One-frame spikes: readings far from both neighbours on the same side, whose neighbours agree
/// with each other (a ramp's corner moves one neighbour as far as the reading). Far is 8 robust
/// standard deviations of the node's second difference. Returns `usable` with the spikes
/// taken out and their count.
pub fn spikes(y: &[f64], n: usize, usable: &mut [bool]) -> usize {
    let len = y.len() / n.max(1);
    if len < 5 {
        return 0;
    }
    let mut count = 0;
    for k in 0..n {
        let d2: Vec<f64> = (1..len - 1)
            .map(|i| y[i * n + k] - 0.5 * (y[(i - 1) * n + k] + y[(i + 1) * n + k]))
            .collect();
        let mut a: Vec<f64> = d2.iter().map(|v| v.abs()).collect();
        a.sort_by(f64::total_cmp);
        let sd = 1.4826 * a[a.len() / 2];
        if sd <= 0.0 {
            continue;
        }
        for (j, &v) in d2.iter().enumerate() {
            let i = j + 1;
            let across = (y[(i + 1) * n + k] - y[(i - 1) * n + k]).abs();
            if v.abs() > 8.0 * sd && across < 0.5 * v.abs() && usable[i * n + k] {
                usable[i * n + k] = false;
                count += 1;
            }
        }
    }
    count
}

#[cfg(test)]
mod tests {
    use super::*;
    use taxel_sim::rng::Rng;

    #[test]
    fn by_node_holds_each_nodes_column_and_the_one_pass_forms_the_passes_of_their_own() {
        // Five nodes (halves of three and two), seven samples: node k's column at k * 7.
        let d: Vec<f64> = (0..35).map(|x| x as f64 * 1.5 - 7.0).collect();
        let cols = by_node(&d, 5);
        for k in 0..5 {
            let want: Vec<f64> = (0..7).map(|i| d[i * 5 + k]).collect();
            assert_eq!(&cols[k * 7..(k + 1) * 7], &want[..], "node {k}");
        }
        // One node: the array itself.
        assert_eq!(by_node(&d, 1), d);
        // Two AR(1) forms in one pass are each the form alone, bit for bit, and the form is
        // the quadratic it names.
        let x = [0.5, -1.0, 2.0, 0.25];
        let [a, b] = ar_quadratics(&x, [0.3, 0.9]);
        assert_eq!(a.to_bits(), ar_quadratic(&x, 0.3).to_bits());
        assert_eq!(b.to_bits(), ar_quadratic(&x, 0.9).to_bits());
        let direct: f64 = (0..4)
            .flat_map(|i| (0..4).map(move |j| (i, j)))
            .map(|(i, j)| x[i] * x[j] * 0.3f64.powi((i as i32 - j as i32).abs()))
            .sum();
        assert!((a - direct).abs() < 1e-12, "{a} against {direct}");
    }

    #[test]
    fn white_fast_and_slow_parts_are_told_apart() {
        // White 1, fast AR(1) 0.5 with rho 0.6, slow AR(1) 2.0 with rho exp(-1/300).
        let mut rng = Rng::new(3, 1);
        let len = 200_000;
        let (rf, rs) = (0.6f64, (-1.0f64 / 300.0).exp());
        let (mut f, mut s) = (0.0, 0.0);
        let x: Vec<f64> = (0..len)
            .map(|_| {
                f = rf * f + (0.5 * (1.0 - rf * rf)).sqrt() * rng.normal();
                s = rs * s + (2.0 * (1.0 - rs * rs)).sqrt() * rng.normal();
                rng.normal() + f + s
            })
            .collect();
        let g = autocov(&x, &vec![true; len], &[0, 1, 2, 100, 200]);
        let p = parts(&g, 100);
        assert!((p.white - 1.0).abs() < 0.15, "{p:?}");
        assert!(
            (p.fast - 0.5).abs() < 0.15 && (p.rho_fast - 0.6).abs() < 0.15,
            "{p:?}"
        );
        // The wander's correlation time (300 samples) within a quarter.
        let tau = -1.0 / p.rho_slow.ln();
        assert!(
            (p.slow - 2.0).abs() < 0.5 && (tau - 300.0).abs() < 75.0,
            "{p:?}"
        );
    }

    #[test]
    fn a_slow_change_sees_the_wander_and_a_fast_one_does_not() {
        let one = NoiseModel {
            nodes: vec![Parts {
                white: 1.0,
                fast: 0.0,
                rho_fast: 0.0,
                slow: 4.0,
                rho_slow: 0.999,
            }],
            common: Parts::default(),
            wander_tau_s: 10.0,
            rest_samples: 0,
            spikes_rejected: 0,
            wander: CommonWander::default(),
        };
        let fast: Vec<f64> = (0..5000)
            .map(|i| if i % 2 == 0 { 1.0 } else { -1.0 })
            .collect();
        let slow = vec![1.0; 5000];
        let (sf, ss) = (one.seen_by(&fast, 1), one.seen_by(&slow, 1));
        assert!(sf < 1.01, "{sf}");
        assert!(ss > 100.0, "{ss}");
    }

    #[test]
    fn a_wander_of_tens_of_seconds_beside_a_faster_part_is_seen_at_the_long_lags() {
        // White 1, a part of 2 s (variance 2) and a wander of 20 s (variance 2), at 100 Hz.
        let ds = crate::testdata::presses_with_rest(100.0);
        let ctx = Context::new(&ds);
        let mut rng = Rng::new(5, 1);
        let (r1, r2) = ((-0.01f64 / 2.0).exp(), (-0.01f64 / 20.0).exp());
        let (mut a, mut b) = (0.0, 0.0);
        let x: Vec<f64> = (0..ds.len())
            .map(|_| {
                a = r1 * a + (2.0 * (1.0 - r1 * r1)).sqrt() * rng.normal();
                b = r2 * b + (2.0 * (1.0 - r2 * r2)).sqrt() * rng.normal();
                rng.normal() + a + b
            })
            .collect();
        let [short, long] = NoiseModel::colours(&ctx, &x);
        // A change held for 100 s, against the variance the true covariance gives it.
        let d = vec![1.0; 10_000];
        let dd = d.len() as f64;
        let truth = 1.0 + 2.0 * (ar_quadratic(&d, r1) + ar_quadratic(&d, r2)) / dd;
        let (s, l) = (short.seen_by(&d, 1), long.seen_by(&d, 1));
        assert!(l > 0.7 * truth && l < 1.3 * truth, "{truth} {l}");
        assert!(s < 0.6 * truth, "{truth} {s}");
    }

    #[test]
    fn isolated_spikes_are_taken_out_and_ramps_are_not() {
        let mut y: Vec<f64> = (0..400)
            .map(|i| {
                if i < 200 {
                    100.0
                } else {
                    100.0 + (i - 200) as f64 * 5.0
                }
            })
            .map(|v: f64| {
                v + if (v as usize).is_multiple_of(3) {
                    0.5
                } else {
                    -0.5
                }
            })
            .collect();
        y[50] += 40.0;
        y[300] -= 60.0;
        let mut usable = vec![true; y.len()];
        let count = spikes(&y, 1, &mut usable);
        assert_eq!(count, 2);
        assert!(!usable[50] && !usable[300]);
        assert!(usable[200] && usable[201]);
    }
}
