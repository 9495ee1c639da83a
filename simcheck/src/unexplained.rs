//! The `unexplained` rule: structure left after the final model that the named effects do not
//! account for, located by node and time span.

use serde::Serialize;

use crate::context::Context;
use crate::cv::Cv;
use crate::locate::{node_stats, spans, Findings};
use crate::noise::NoiseModel;

#[derive(Debug, Clone, Serialize)]
pub struct Unexplained {
    pub nodes: Vec<usize>,
    pub t_s: [f64; 2],
    pub description: String,
}

/// Structure left after the final model: nodes whose held-out residual stands far above their
/// own noise floor and above the other nodes, or the whole array when every node does. Structure
/// counts as unexplained only where the named effects removed less than three quarters of the
/// base model's excess over noise there (what is left of a named effect whose true form differs
/// from the tool's is not "unexplained"). Each node's noise is the noise model's whole noise
/// at rest (white, fast and slow parts; [`NoiseModel::floor`]) or the white floor from its
/// sample-to-sample differences, whichever is larger: a wander is noise, not structure (and the
/// wander every node shares was taken out of the readings, see [`crate::wander`]). To it adds
/// what the load cell's noise leaves through each node's slope ([`force_noise_var`]; `pred`:
/// the final model's prediction of every sample).
pub fn find_unexplained(
    ctx: &Context,
    base_cv: &Cv,
    cv: &Cv,
    pred: &[f64],
    f: &Findings,
    noise: &NoiseModel,
    limit: f64,
) -> Vec<Unexplained> {
    let ds = ctx.ds;
    let from_force = force_noise_var(ctx, pred);
    let with_model = |mut v: Vec<crate::locate::NodeStat>| {
        for s in v.iter_mut() {
            let floor = s.noise.max(noise.floor(s.node));
            s.noise = (floor * floor + from_force[s.node]).sqrt();
            s.ratio = if s.noise > 0.0 { s.rms / s.noise } else { 0.0 };
        }
        v
    };
    let resid = &cv.resid;
    let stats = with_model(node_stats(ctx, resid));
    let base_stats = with_model(node_stats(ctx, &base_cv.resid));
    let excess = |s: &crate::locate::NodeStat| (s.rms * s.rms - s.noise * s.noise).max(0.0);
    let mostly_left = |k: usize| excess(&stats[k]) > 0.25 * excess(&base_stats[k]);
    let mut ratios: Vec<f64> = stats.iter().map(|s| s.ratio).collect();
    ratios.sort_by(f64::total_cmp);
    let median = ratios[ratios.len() / 2];
    let mut out = Vec::new();
    let strongest = f
        .correlations
        .iter()
        .filter(|c| c.significant)
        .max_by(|a, b| a.r.abs().total_cmp(&b.r.abs()));
    let corr_text = strongest.map_or(
        "no named regressor correlates significantly".to_string(),
        |c| {
            format!(
                "strongest named correlate: {} (r = {:.2})",
                c.regressor, c.r
            )
        },
    );
    if ds.n >= 3 {
        let bad: Vec<usize> = stats
            .iter()
            .filter(|s| s.ratio > limit && s.ratio > 2.5 * median.max(1.0) && mostly_left(s.node))
            .map(|s| s.node)
            .collect();
        for &k in &bad {
            let sp = spans(ctx, resid, &[k], 3.0);
            let (t0, t1) = sp
                .first()
                .map_or((ds.t[0], ds.t[ds.len() - 1]), |s| (s.t_s[0], s.t_s[1]));
            let first = sp.iter().map(|s| s.t_s[0]).fold(f64::INFINITY, f64::min);
            let last = sp
                .iter()
                .map(|s| s.t_s[1])
                .fold(f64::NEG_INFINITY, f64::max);
            out.push(Unexplained {
                nodes: vec![k],
                t_s: if sp.is_empty() { [t0, t1] } else { [first, last] },
                description: format!(
                    "node {k} (row {}, col {}): held-out residual {:.1}x its noise floor vs median {:.1}x over nodes, in {} span(s) (worst {:.1}-{:.1} s); no library effect explains it",
                    k / ds.cols,
                    k % ds.cols,
                    stats[k].ratio,
                    median,
                    sp.len(),
                    t0,
                    t1
                ),
            });
        }
        if !bad.is_empty() {
            return out;
        }
    }
    let left: f64 = stats.iter().map(excess).sum();
    let was: f64 = base_stats.iter().map(excess).sum();
    if median > limit && left > 0.25 * was {
        let all: Vec<usize> = (0..ds.n).collect();
        let sp = spans(ctx, resid, &all, 2.0);
        let (t0, t1) = sp
            .first()
            .map_or((ds.t[0], ds.t[ds.len() - 1]), |s| (s.t_s[0], s.t_s[1]));
        out.push(Unexplained {
            nodes: all,
            t_s: [t0, t1],
            description: format!(
                "structured residual on every node: held-out RMSE {:.1}x the noise floor (median over nodes), residual memory {:.0} samples; worst span {:.1}-{:.1} s; {}",
                median, f.tau_int_samples, t0, t1, corr_text
            ),
        });
    }
    out
}

/// Force bins of [`force_noise_var`], spaced in the square root of the force (fine near zero,
/// where a law that rises steeply from zero load is steepest).
const FORCE_BINS: usize = 40;

/// The variance each node's held-out residual takes from the load cell's noise: the recorded
/// force drives the model, so its noise (standard deviation `Context::force_deadband / 3`)
/// reaches the prediction through the node's slope, `(dy/dF)^2 sd_F^2`. It is large where a
/// law rises steeply from zero load (a logarithmic law read through a divider: thousands of
/// counts per newton in the first tenth of a newton), and a node that carries much of the load
/// is then not "unexplained" for it. The slope is the prediction's: its mean over each force
/// bin, differenced between the neighbouring bins, at each usable sample's force; samples the
/// model sees at zero force (within the load cell's noise of it) take nothing.
pub(crate) fn force_noise_var(ctx: &Context, pred: &[f64]) -> Vec<f64> {
    let ds = ctx.ds;
    let (len, n) = (ds.len(), ds.n);
    let sd_f = ctx.force_deadband / 3.0;
    let fmax = ds.max_force();
    if sd_f <= 0.0 || fmax <= 0.0 || pred.len() != len * n {
        return vec![0.0; n];
    }
    let force = &ctx.force_model;
    let bin = |f: f64| ((f.max(0.0) / fmax).sqrt() * FORCE_BINS as f64) as usize;
    let bin = |f: f64| bin(f).min(FORCE_BINS - 1);
    (0..n)
        .map(|k| {
            let (mut sf, mut sy, mut cnt) =
                ([0.0; FORCE_BINS], [0.0; FORCE_BINS], [0usize; FORCE_BINS]);
            for i in (0..len).filter(|&i| force[i] > 0.0 && ctx.usable[i * n + k]) {
                let b = bin(force[i]);
                sf[b] += force[i];
                sy[b] += pred[i * n + k];
                cnt[b] += 1;
            }
            // Bins with a few samples at least, as (mean force, mean prediction).
            let pts: Vec<(usize, f64, f64)> = (0..FORCE_BINS)
                .filter(|&b| cnt[b] >= 5)
                .map(|b| (b, sf[b] / cnt[b] as f64, sy[b] / cnt[b] as f64))
                .collect();
            if pts.len() < 2 {
                return 0.0;
            }
            let mut slope = [0.0f64; FORCE_BINS];
            for (j, &(b, _, _)) in pts.iter().enumerate() {
                let (lo, hi) = (pts[j.saturating_sub(1)], pts[(j + 1).min(pts.len() - 1)]);
                if hi.1 > lo.1 {
                    slope[b] = (hi.2 - lo.2) / (hi.1 - lo.1);
                }
            }
            let (mut sum, mut used) = (0.0, 0usize);
            for i in (0..len).filter(|&i| ctx.usable[i * n + k]) {
                used += 1;
                if force[i] > 0.0 {
                    sum += slope[bin(force[i])].powi(2);
                }
            }
            sd_f * sd_f * sum / used.max(1) as f64
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_load_cells_noise_reaches_a_node_through_its_slope() {
        // Two nodes under the same presses with a noisy load cell: node 0's prediction rises
        // 100 units per newton, node 1's is flat.
        let mut ds = crate::testdata::presses_on(1, 2);
        let len = ds.len();
        ds.y = vec![1000.0; len * 2];
        let mut state = 12345u64;
        for f in ds.force.iter_mut() {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = (state >> 11) as f64 / (1u64 << 53) as f64;
            *f += 0.02 * (u - 0.5);
        }
        let ctx = Context::new(&ds);
        let pred: Vec<f64> = (0..len * 2)
            .map(|idx| {
                let (i, k) = (idx / 2, idx % 2);
                if k == 0 {
                    100.0 * ctx.force_model[i]
                } else {
                    5.0
                }
            })
            .collect();
        let v = force_noise_var(&ctx, &pred);
        let sd_f = ctx.force_deadband / 3.0;
        let loaded = ctx.force_model.iter().filter(|&&f| f > 0.0).count() as f64 / len as f64;
        let want = (100.0 * sd_f).powi(2) * loaded;
        assert!(sd_f > 0.0);
        assert!((v[0] / want - 1.0).abs() < 0.1, "{} vs {want}", v[0]);
        assert!(v[1].abs() < 1e-12, "{}", v[1]);
    }
}
