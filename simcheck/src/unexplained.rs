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
/// wander every node shares was taken out of the readings, see [`crate::wander`]).
pub fn find_unexplained(
    ctx: &Context,
    base_cv: &Cv,
    cv: &Cv,
    f: &Findings,
    noise: &NoiseModel,
    limit: f64,
) -> Vec<Unexplained> {
    let ds = ctx.ds;
    let with_model = |mut v: Vec<crate::locate::NodeStat>| {
        for s in v.iter_mut() {
            s.noise = s.noise.max(noise.floor(s.node));
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
