//! Locating a mismatch before naming it: where the residual (sim - rec) is structured. Per-node
//! size against each node's own noise floor, time spans, memory (autocorrelation), correlation
//! with named regressors built from the stimulus (with block-bootstrap confidence intervals, so
//! slowly varying inputs do not pass a white-noise band by chance), and splits by loading
//! direction, force range and trial.

use serde::Serialize;

use crate::context::Context;

#[derive(Debug, Clone, Serialize)]
pub struct NodeStat {
    pub node: usize,
    pub row: usize,
    pub col: usize,
    /// RMS of the residual (residual-domain units).
    pub rms: f64,
    /// White-noise floor estimated from sample-to-sample differences.
    pub noise: f64,
    /// rms / noise: about 1 when only noise is left.
    pub ratio: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct Span {
    pub t_s: [f64; 2],
    /// Windowed RMS over the recording's median windowed RMS.
    pub rms_ratio: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct Corr {
    pub regressor: String,
    pub r: f64,
    pub ci95: [f64; 2],
    /// The interval excludes zero.
    pub significant: bool,
}

#[derive(Debug, Clone, Serialize)]
pub struct Group {
    pub label: String,
    pub mean: f64,
    pub ci95_half: f64,
    pub count: usize,
}

#[derive(Debug, Clone, Serialize)]
pub struct Split {
    pub by: String,
    pub groups: Vec<Group>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Findings {
    pub nodes: Vec<NodeStat>,
    pub spans: Vec<Span>,
    /// Residual autocorrelation at lag 1 sample and at about 1 s (mean over nodes).
    pub acf_lag1: f64,
    pub acf_1s: f64,
    /// Integrated autocorrelation time (samples).
    pub tau_int_samples: f64,
    pub correlations: Vec<Corr>,
    pub splits: Vec<Split>,
    /// How much the loaded residual differs from one press (a run of force above 10 % of the
    /// peak) to the next: each press's mean residual on responsive nodes.
    pub presses: Option<PressSpread>,
}

#[derive(Debug, Clone, Serialize)]
pub struct PressSpread {
    pub presses: usize,
    /// Standard deviation of the per-press mean residual.
    pub sd_between: f64,
    /// The same spread relative to the overall loaded residual RMS (1 = all of it).
    pub share_of_rms: f64,
}

fn press_spread(ctx: &Context, resid: &[f64], w: &[f64]) -> Option<PressSpread> {
    let ds = ctx.ds;
    let n = ds.n;
    let limit = 0.1 * ds.max_force();
    let mut means = Vec::new();
    let (mut acc, mut cnt) = (0.0, 0usize);
    let (mut all2, mut all_n) = (0.0, 0usize);
    for i in 0..=ds.len() {
        let loaded = i < ds.len() && ds.force[i] > limit;
        if loaded {
            for k in 0..n {
                if ctx.usable[i * n + k] && w[k] > 0.2 {
                    acc += resid[i * n + k];
                    all2 += resid[i * n + k].powi(2);
                    cnt += 1;
                    all_n += 1;
                }
            }
        } else if cnt > 0 {
            means.push(acc / cnt as f64);
            acc = 0.0;
            cnt = 0;
        }
    }
    if means.len() < 3 || all_n == 0 {
        return None;
    }
    let m = means.iter().sum::<f64>() / means.len() as f64;
    let sd = (means.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (means.len() - 1) as f64).sqrt();
    let rms = (all2 / all_n as f64).sqrt();
    Some(PressSpread {
        presses: means.len(),
        sd_between: sd,
        share_of_rms: if rms > 0.0 { sd / rms } else { 0.0 },
    })
}

/// Per-node noise floor: sqrt of the 80 % trimmed mean of (r[i+1]-r[i])^2 / 2.
pub fn noise_floor(ctx: &Context, resid: &[f64], k: usize) -> f64 {
    let (len, n) = (ctx.ds.len(), ctx.ds.n);
    let mut d: Vec<f64> = (1..len)
        .filter(|&i| ctx.usable[i * n + k] && ctx.usable[(i - 1) * n + k])
        .map(|i| (resid[i * n + k] - resid[(i - 1) * n + k]).powi(2) / 2.0)
        .collect();
    if d.is_empty() {
        return 0.0;
    }
    d.sort_by(f64::total_cmp);
    let keep = (d.len() as f64 * 0.8).ceil() as usize;
    let keep = keep.clamp(1, d.len());
    // The trimmed mean of a chi-square(1) underestimates its mean; 0.8 keeps ~ 0.44 of it.
    let m = d[..keep].iter().sum::<f64>() / keep as f64 / 0.44;
    m.sqrt()
}

pub fn node_stats(ctx: &Context, resid: &[f64]) -> Vec<NodeStat> {
    let ds = ctx.ds;
    let (len, n) = (ds.len(), ds.n);
    // Node by node, nodes side by side.
    crate::parallel::map(n, |k| {
        let (mut s, mut c) = (0.0, 0usize);
        for i in 0..len {
            if ctx.usable[i * n + k] {
                s += resid[i * n + k].powi(2);
                c += 1;
            }
        }
        let rms = (s / c.max(1) as f64).sqrt();
        let noise = noise_floor(ctx, resid, k);
        NodeStat {
            node: k,
            row: k / ds.cols,
            col: k % ds.cols,
            rms,
            noise,
            ratio: if noise > 0.0 { rms / noise } else { 0.0 },
        }
    })
}

/// Windows (about 1 s) whose RMS over `nodes` exceeds `factor` times the median window.
pub fn spans(ctx: &Context, resid: &[f64], nodes: &[usize], factor: f64) -> Vec<Span> {
    let ds = ctx.ds;
    let n = ds.n;
    let win = ((1.0 / ds.dt()).round() as usize).clamp(5, ds.len().max(5));
    let mut w: Vec<(f64, f64, f64)> = Vec::new();
    let mut i = 0;
    while i < ds.len() {
        let j = (i + win).min(ds.len());
        let (mut s, mut c) = (0.0, 0usize);
        for ii in i..j {
            for &k in nodes {
                if ctx.usable[ii * n + k] {
                    s += resid[ii * n + k].powi(2);
                    c += 1;
                }
            }
        }
        w.push((ds.t[i], ds.t[j - 1], (s / c.max(1) as f64).sqrt()));
        i = j;
    }
    let mut sorted: Vec<f64> = w.iter().map(|x| x.2).collect();
    sorted.sort_by(f64::total_cmp);
    let med = sorted
        .get(sorted.len() / 2)
        .copied()
        .unwrap_or(0.0)
        .max(1e-12);
    let mut out: Vec<Span> = Vec::new();
    for (t0, t1, r) in w {
        if r > factor * med {
            match out.last_mut() {
                Some(last) if (t0 - last.t_s[1]) <= 1.5 * win as f64 * ds.dt() => {
                    last.t_s[1] = t1;
                    last.rms_ratio = last.rms_ratio.max(r / med);
                }
                _ => out.push(Span {
                    t_s: [t0, t1],
                    rms_ratio: r / med,
                }),
            }
        }
    }
    out.sort_by(|a, b| b.rms_ratio.total_cmp(&a.rms_ratio));
    out.truncate(8);
    out
}

fn acf(ctx: &Context, resid: &[f64], lag: usize) -> f64 {
    let (len, n) = (ctx.ds.len(), ctx.ds.n);
    if lag >= len {
        return 0.0;
    }
    let mut acc = 0.0;
    let mut used = 0;
    for k in 0..n {
        let x: Vec<f64> = (0..len).map(|i| resid[i * n + k]).collect();
        let mean = x.iter().sum::<f64>() / len as f64;
        let var: f64 = x.iter().map(|v| (v - mean).powi(2)).sum();
        if var <= 0.0 {
            continue;
        }
        let c: f64 = (0..len - lag)
            .map(|i| (x[i] - mean) * (x[i + lag] - mean))
            .sum();
        acc += c / var;
        used += 1;
    }
    if used == 0 {
        0.0
    } else {
        acc / used as f64
    }
}

/// A simple deterministic generator for the bootstrap.
struct Lcg(u64);
impl Lcg {
    fn below(&mut self, n: usize) -> usize {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 33) as usize) % n.max(1)
    }
}

/// Pearson r between the residual and a regressor over node-samples, with a 95 % interval
/// from a bootstrap over the cross-validation blocks.
fn correlate(ctx: &Context, resid: &[f64], x: &dyn Fn(usize, usize) -> f64, name: &str) -> Corr {
    let ds = ctx.ds;
    let n = ds.n;
    let nb = ctx.n_blocks;
    let mut sums = vec![[0.0f64; 6]; nb];
    for i in 0..ds.len() {
        let b = ctx.block[i];
        for k in 0..n {
            if !ctx.usable[i * n + k] {
                continue;
            }
            let xv = x(i, k);
            let yv = resid[i * n + k];
            let s = &mut sums[b];
            s[0] += 1.0;
            s[1] += xv;
            s[2] += yv;
            s[3] += xv * xv;
            s[4] += yv * yv;
            s[5] += xv * yv;
        }
    }
    let r_of = |pick: &mut dyn FnMut() -> usize| -> f64 {
        let mut t = [0.0f64; 6];
        for _ in 0..nb {
            let s = sums[pick()];
            for j in 0..6 {
                t[j] += s[j];
            }
        }
        let nn = t[0].max(1.0);
        let cov = t[5] / nn - t[1] * t[2] / nn / nn;
        let vx = t[3] / nn - (t[1] / nn).powi(2);
        let vy = t[4] / nn - (t[2] / nn).powi(2);
        if vx <= 1e-300 || vy <= 1e-300 {
            0.0
        } else {
            cov / (vx * vy).sqrt()
        }
    };
    let mut idx = 0usize;
    let r = r_of(&mut || {
        let v = idx;
        idx += 1;
        v
    });
    let mut rng = Lcg(0x5eed ^ name.len() as u64);
    let mut boots: Vec<f64> = (0..200).map(|_| r_of(&mut || rng.below(nb))).collect();
    boots.sort_by(f64::total_cmp);
    let ci95 = [boots[5], boots[194]];
    Corr {
        regressor: name.to_string(),
        r,
        ci95,
        significant: ci95[0] > 0.0 || ci95[1] < 0.0,
    }
}

fn group_stats(
    ctx: &Context,
    resid: &[f64],
    by: &str,
    labels: &[String],
    group_of: &dyn Fn(usize, usize) -> Option<usize>,
) -> Split {
    let ds = ctx.ds;
    let n = ds.n;
    let g = labels.len();
    // Per group and block: sum and count, for a block-level standard error.
    let mut s = vec![vec![(0.0f64, 0usize); ctx.n_blocks]; g];
    for i in 0..ds.len() {
        for k in 0..n {
            if !ctx.usable[i * n + k] {
                continue;
            }
            if let Some(gi) = group_of(i, k) {
                let e = &mut s[gi][ctx.block[i]];
                e.0 += resid[i * n + k];
                e.1 += 1;
            }
        }
    }
    let groups = labels
        .iter()
        .zip(&s)
        .map(|(label, blocks)| {
            let count: usize = blocks.iter().map(|b| b.1).sum();
            let mean = blocks.iter().map(|b| b.0).sum::<f64>() / count.max(1) as f64;
            let bm: Vec<f64> = blocks
                .iter()
                .filter(|b| b.1 > 0)
                .map(|b| b.0 / b.1 as f64)
                .collect();
            let nb = bm.len();
            let half = if nb >= 2 {
                let m = bm.iter().sum::<f64>() / nb as f64;
                let v = bm.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (nb - 1) as f64;
                1.96 * (v / nb as f64).sqrt()
            } else {
                f64::NAN
            };
            Group {
                label: label.clone(),
                mean,
                ci95_half: half,
                count,
            }
        })
        .collect();
    Split {
        by: by.to_string(),
        groups,
    }
}

/// Loading (+1), unloading (-1) or neither (0) at each sample, from the force change over
/// about 50 ms, for samples above 10 % of the peak force.
pub fn direction(ctx: &Context) -> Vec<i8> {
    let ds = ctx.ds;
    let h = ((0.05 / ds.dt()).round() as usize).max(1);
    let fmax = ds.max_force();
    (0..ds.len())
        .map(|i| {
            let a = ds.force[i.saturating_sub(h)];
            let b = ds.force[(i + h).min(ds.len() - 1)];
            if ds.force[i] < 0.1 * fmax || (b - a).abs() < 0.02 * fmax {
                0
            } else if b > a {
                1
            } else {
                -1
            }
        })
        .collect()
}

/// How much each node responds to force: the spread of its predicted reading.
pub fn responsiveness(ctx: &Context, pred: &[f64]) -> Vec<f64> {
    let (len, n) = (ctx.ds.len(), ctx.ds.n);
    (0..n)
        .map(|k| {
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for i in 0..len {
                lo = lo.min(pred[i * n + k]);
                hi = hi.max(pred[i * n + k]);
            }
            if hi > lo {
                hi - lo
            } else {
                0.0
            }
        })
        .collect()
}

/// All findings for a residual (`pred` is the model's prediction, to weigh nodes).
pub fn locate(ctx: &Context, resid: &[f64], pred: &[f64]) -> Findings {
    let ds = ctx.ds;
    let (len, n) = (ds.len(), ds.n);
    let nodes = node_stats(ctx, resid);
    let all: Vec<usize> = (0..n).collect();
    let span_list = spans(ctx, resid, &all, 3.0);
    let lag_1s = ((1.0 / ds.dt()).round() as usize).max(1);
    let resp = responsiveness(ctx, pred);
    let rmax = resp.iter().cloned().fold(0.0, f64::max).max(1e-12);
    let w: Vec<f64> = resp.iter().map(|r| r / rmax).collect();
    let dir = direction(ctx);
    let corrs = correlations(ctx, resid, &w, &dir);
    let splits = splits(ctx, resid, &w, &dir);
    let presses = press_spread(ctx, resid, &w);
    Findings {
        nodes,
        presses,
        spans: span_list,
        acf_lag1: acf(ctx, resid, 1),
        acf_1s: acf(ctx, resid, lag_1s),
        tau_int_samples: crate::cv::tau_int(resid, len, n),
        correlations: corrs,
        splits,
    }
}

/// The residual's correlation with each named regressor built from the stimulus (`w`: each
/// node's responsiveness relative to the most responsive; `dir`: the loading direction).
fn correlations(ctx: &Context, resid: &[f64], w: &[f64], dir: &[i8]) -> Vec<Corr> {
    let ds = ctx.ds;
    let (len, n) = (ds.len(), ds.n);
    let fmax = ds.max_force().max(1e-12);
    let mut dt = vec![ds.dt()];
    dt.extend(ds.t.windows(2).map(|p| (p[1] - p[0]).max(1e-9)));
    let lp = |tau: f64| -> Vec<f64> {
        let mut s = ds.force[0];
        ds.force
            .iter()
            .zip(&dt)
            .map(|(f, d)| {
                s += (f - s) * (1.0 - (-d / tau).exp());
                s / fmax
            })
            .collect()
    };
    let lp3 = lp(3.0);
    let lp30 = lp(30.0);
    let h = ((0.02 / ds.dt()).round() as usize).max(1);
    let dfdt: Vec<f64> = (0..len)
        .map(|i| {
            let a = ds.force[i.saturating_sub(h)];
            let b = ds.force[(i + h).min(len - 1)];
            (b - a) / fmax
        })
        .collect();
    let tmean = ds.t.iter().sum::<f64>() / len as f64;
    let mut corrs = vec![
        correlate(
            ctx,
            resid,
            &|i, k| w[k] * ds.force[i] / fmax,
            "force level (node-weighted)",
        ),
        correlate(
            ctx,
            resid,
            &|i, k| w[k] * (lp3[i] - ds.force[i] / fmax),
            "time under load: low-pass(F, 3 s) - F",
        ),
        correlate(
            ctx,
            resid,
            &|i, k| w[k] * (lp30[i] - ds.force[i] / fmax),
            "time under load: low-pass(F, 30 s) - F",
        ),
        correlate(
            ctx,
            resid,
            &|i, k| w[k] * dir[i] as f64 * ds.force[i] / fmax,
            "loading direction x level",
        ),
        correlate(
            ctx,
            resid,
            &|i, k| w[k] * k as f64 / n as f64 * dfdt[i],
            "scan index x dF/dt",
        ),
        correlate(
            ctx,
            resid,
            &|i, _| ds.t[i] - tmean,
            "time (slow drift, all nodes)",
        ),
    ];
    if let Some(temp) = &ds.temp {
        corrs.push(correlate(ctx, resid, &|i, _| temp[i], "temperature"));
    }
    if let Some(kappa) = &ds.kappa {
        corrs.push(correlate(
            ctx,
            resid,
            &|i, k| w[k] * kappa[i] * ds.force[i] / fmax,
            "curvature x force",
        ));
        corrs.push(correlate(
            ctx,
            resid,
            &|i, _| kappa[i],
            "curvature (no-load offset)",
        ));
    }
    if ds.rows >= 2 && ds.cols >= 2 {
        let cols = ds.cols;
        corrs.push(correlate(
            ctx,
            resid,
            &|i, k| {
                let row = k / cols;
                let others: f64 = (0..cols)
                    .filter(|&c| row * cols + c != k)
                    .map(|c| w[row * cols + c])
                    .sum();
                w[k] * others * ds.force[i] / fmax
            },
            "same-row load (crosstalk)",
        ));
    }
    corrs
}

/// The residual split by loading direction, force range, trial, row and column.
fn splits(ctx: &Context, resid: &[f64], w: &[f64], dir: &[i8]) -> Vec<Split> {
    let ds = ctx.ds;
    let fmax = ds.max_force().max(1e-12);
    let mut splits = Vec::new();
    splits.push(group_stats(
        ctx,
        resid,
        "loading direction (responsive nodes)",
        &["loading".to_string(), "unloading".to_string()],
        &|i, k| match (dir[i], w[k] > 0.2) {
            (1, true) => Some(0),
            (-1, true) => Some(1),
            _ => None,
        },
    ));
    let bins = ["0-20 %", "20-40 %", "40-60 %", "60-80 %", "80-100 %"];
    splits.push(group_stats(
        ctx,
        resid,
        "force (share of peak; responsive nodes)",
        &bins.iter().map(|s| s.to_string()).collect::<Vec<_>>(),
        &|i, k| (w[k] > 0.2).then(|| ((ds.force[i] / fmax * 5.0) as usize).min(4)),
    ));
    let rest_limit = 0.02 * fmax;
    if ds.n_trials >= 2 {
        let labels: Vec<String> = (0..ds.n_trials).map(|j| format!("trial {j}")).collect();
        splits.push(group_stats(
            ctx,
            resid,
            "trial, no load",
            &labels,
            &|i, _| (ds.force[i] <= rest_limit).then_some(ds.trial[i]),
        ));
        splits.push(group_stats(
            ctx,
            resid,
            "trial, loaded (responsive nodes)",
            &labels,
            &|i, k| (ds.force[i] > 0.2 * fmax && w[k] > 0.2).then_some(ds.trial[i]),
        ));
    }
    if ds.rows >= 2 {
        let labels: Vec<String> = (0..ds.rows).map(|r| format!("row {r}")).collect();
        splits.push(group_stats(ctx, resid, "row, loaded", &labels, &|i, k| {
            (ds.force[i] > 0.2 * fmax).then_some(k / ds.cols)
        }));
    }
    if ds.cols >= 2 {
        let labels: Vec<String> = (0..ds.cols).map(|c| format!("col {c}")).collect();
        splits.push(group_stats(
            ctx,
            resid,
            "column, loaded",
            &labels,
            &|i, k| (ds.force[i] > 0.2 * fmax).then_some(k % ds.cols),
        ));
    }
    splits
}
