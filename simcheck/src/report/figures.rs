//! The figures (PNG and SVG): the recording against the simulation before and after, the
//! held-out residual over time, and the residual against the variable that located each effect.

use std::path::Path;

use taxel_plot::{Chart, Mark, Series};

use crate::data::Dataset;
use crate::diagnose::Diagnosis;
use crate::named::NamedEffect;

/// Draws every figure into `dir`; returns their file names. `resim_pred` is taxel-sim's
/// re-simulation of the recording from SIM.toml (empty when it could not run).
pub fn figures(
    dir: &Path,
    ds: &Dataset,
    d: &Diagnosis,
    resim_pred: &[f64],
) -> anyhow::Result<Vec<String>> {
    let n = ds.n;
    let resp = &d.responsiveness;
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| resp[b].total_cmp(&resp[a]));
    let top = order[0];
    let responsive: Vec<usize> = order
        .iter()
        .copied()
        .filter(|&k| resp[k] > 0.2 * resp[top])
        .collect();
    let mut figures = Vec::new();
    figures.extend(both(dir, "overlay", &overlay(ds, d, resim_pred, top))?);
    figures.extend(both(dir, "residual_time", &residual_time(ds, d))?);
    // Per effect: residual against its locating variable.
    let all: Vec<usize> = (0..n).collect();
    let dir_sign = &d.direction;
    let mut dtv = vec![ds.dt()];
    dtv.extend(ds.t.windows(2).map(|p| (p[1] - p[0]).max(1e-9)));
    for e in &d.effects {
        let (xlabel, x) = locating_variable(ds, e, dir_sign, &dtv);
        let nodes: &[usize] = if e.name.starts_with("thermal") || e.name == "curvature_baseline" {
            &all
        } else {
            &responsive
        };
        let unit = ds.map.dom_unit();
        let chart = Chart {
            title: format!(
                "{}: held-out residual vs the variable that located it",
                e.name
            ),
            x_label: xlabel,
            y_label: format!("mean residual, sim - rec ({unit})"),
            series: vec![
                Series {
                    name: "base model".into(),
                    points: binned(ds, &d.base_cv.resid, nodes, &*x, 24),
                    mark: Mark::LinePoints,
                },
                Series {
                    name: "with the named effects".into(),
                    points: binned(ds, &d.final_cv.resid, nodes, &*x, 24),
                    mark: Mark::LinePoints,
                },
            ],
            x_range: None,
            y_range: None,
        };
        figures.extend(both(dir, &format!("residual_{}", e.name), &chart)?);
    }
    Ok(figures)
}

/// Recording, base model, the model with the named effects and taxel-sim running SIM.toml, on
/// node `top`, in a window around the worst base span (or the first 30 s).
fn overlay(ds: &Dataset, d: &Diagnosis, resim_pred: &[f64], top: usize) -> Chart {
    let n = ds.n;
    let (w0, w1) = d
        .base_findings
        .spans
        .first()
        .map_or((ds.t[0], ds.t[0] + 30.0), |s| {
            let mid = 0.5 * (s.t_s[0] + s.t_s[1]);
            (mid - 15.0, mid + 15.0)
        });
    let idx: Vec<usize> = (0..ds.len())
        .filter(|&i| ds.t[i] >= w0 && ds.t[i] <= w1)
        .collect();
    let step = (idx.len() / 1500).max(1);
    let pick = |v: &dyn Fn(usize) -> f64| -> Vec<(f64, f64)> {
        idx.iter().step_by(step).map(|&i| (ds.t[i], v(i))).collect()
    };
    let unit = ds.map.dom_unit();
    Chart {
        title: format!("Recording vs simulation, node {top} (most responsive)"),
        x_label: "time (s)".into(),
        y_label: format!("reading ({unit})"),
        series: vec![
            Series {
                name: "recording".into(),
                points: pick(&|i| ds.map.dom(ds.y[i * n + top])),
                mark: Mark::Line,
            },
            Series {
                name: "base model".into(),
                points: pick(&|i| d.base_pred[i * n + top]),
                mark: Mark::Line,
            },
            Series {
                name: "with the named effects".into(),
                points: pick(&|i| d.final_pred[i * n + top]),
                mark: Mark::Line,
            },
            Series {
                name: "taxel-sim running SIM.toml".into(),
                points: if resim_pred.is_empty() {
                    Vec::new()
                } else {
                    pick(&|i| resim_pred[i * n + top])
                },
                mark: Mark::Line,
            },
        ],
        x_range: None,
        y_range: None,
    }
}

/// Held-out residual over time (mean of all nodes), before and after.
fn residual_time(ds: &Dataset, d: &Diagnosis) -> Chart {
    let n = ds.n;
    let unit = ds.map.dom_unit();
    let tstep = (ds.len() / 2000).max(1);
    let mean_resid = |r: &[f64], nodes: &[usize]| -> Vec<(f64, f64)> {
        (0..ds.len())
            .step_by(tstep)
            .map(|i| {
                let s: f64 = nodes.iter().map(|&k| r[i * n + k]).sum();
                (ds.t[i], s / nodes.len().max(1) as f64)
            })
            .collect()
    };
    let all: Vec<usize> = (0..n).collect();
    Chart {
        title: "Held-out residual (sim - rec) over time, mean of all nodes".into(),
        x_label: "time (s)".into(),
        y_label: format!("residual ({unit})"),
        series: vec![
            Series {
                name: "base model".into(),
                points: mean_resid(&d.base_cv.resid, &all),
                mark: Mark::Line,
            },
            Series {
                name: "with the named effects".into(),
                points: mean_resid(&d.final_cv.resid, &all),
                mark: Mark::Line,
            },
        ],
        x_range: None,
        y_range: None,
    }
}

/// The variable that located effect `e` (its label and value per sample; `None` where it
/// does not apply).
#[allow(clippy::type_complexity)]
fn locating_variable<'a>(
    ds: &'a Dataset,
    e: &NamedEffect,
    dir_sign: &'a [i8],
    dtv: &[f64],
) -> (String, Box<dyn Fn(usize) -> Option<f64> + 'a>) {
    let fmax = ds.max_force().max(1e-12);
    match e.name.as_str() {
        "creep" => {
            let tau = e.params.get("tau_fast_s").copied().unwrap_or(3.0);
            let mut s = ds.force[0];
            let lp: Vec<f64> = ds
                .force
                .iter()
                .zip(dtv)
                .map(|(f, d)| {
                    s += (f - s) * (1.0 - (-d / tau).exp());
                    s
                })
                .collect();
            (
                "low-pass of force minus force, tau from the fit (N)".into(),
                Box::new(move |i| (ds.force[i] > 0.1 * fmax).then(|| lp[i] - ds.force[i])),
            )
        }
        "hysteresis" => (
            "force x loading direction (N; + loading, - unloading)".into(),
            Box::new(move |i| (dir_sign[i] != 0).then(|| dir_sign[i] as f64 * ds.force[i])),
        ),
        "scan_skew" => {
            let h = ((0.02 / ds.dt()).round() as usize).max(1);
            (
                "dF/dt (N/s)".into(),
                Box::new(move |i| {
                    let a = ds.force[i.saturating_sub(h)];
                    let b = ds.force[(i + h).min(ds.len() - 1)];
                    let dt = ds.t[(i + h).min(ds.len() - 1)] - ds.t[i.saturating_sub(h)];
                    (dt > 0.0).then(|| (b - a) / dt)
                }),
            )
        }
        "thermal_drift" => match &ds.temp {
            Some(t) => ("temperature (degC)".into(), Box::new(move |i| Some(t[i]))),
            None => ("time (s)".into(), Box::new(move |i| Some(ds.t[i]))),
        },
        "curvature_sensitivity" | "curvature_baseline" => match &ds.kappa {
            Some(k) => ("curvature (1/m)".into(), Box::new(move |i| Some(k[i]))),
            None => ("trial".into(), Box::new(move |i| Some(ds.trial[i] as f64))),
        },
        _ => ("force (N)".into(), Box::new(move |i| Some(ds.force[i]))),
    }
}

fn both(dir: &Path, stem: &str, chart: &Chart) -> anyhow::Result<Vec<String>> {
    let mut names = Vec::new();
    for ext in ["png", "svg"] {
        let name = format!("{stem}.{ext}");
        taxel_plot::write(&dir.join(&name), chart)?;
        names.push(name);
    }
    Ok(names)
}

/// Mean of the residual of responsive nodes, binned by `x`.
fn binned(
    ds: &Dataset,
    resid: &[f64],
    nodes: &[usize],
    x: &dyn Fn(usize) -> Option<f64>,
    bins: usize,
) -> Vec<(f64, f64)> {
    let n = ds.n;
    let xs: Vec<(usize, f64)> = (0..ds.len()).filter_map(|i| x(i).map(|v| (i, v))).collect();
    if xs.is_empty() {
        return Vec::new();
    }
    let lo = xs.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
    let hi = xs.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
    let width = ((hi - lo) / bins as f64).max(1e-12);
    let mut acc = vec![(0.0, 0usize); bins];
    for (i, v) in xs {
        let b = (((v - lo) / width) as usize).min(bins - 1);
        for &k in nodes {
            acc[b].0 += resid[i * n + k];
            acc[b].1 += 1;
        }
    }
    acc.iter()
        .enumerate()
        .filter(|(_, a)| a.1 > 0)
        .map(|(b, a)| (lo + (b as f64 + 0.5) * width, a.0 / a.1 as f64))
        .collect()
}
