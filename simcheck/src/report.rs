//! What the diagnosis writes: report.json (for programs), report.md (findings first, then the
//! evidence and plots), SIM.toml (the start model extended with the fitted base and effects,
//! loadable by taxel-sim and the publisher's sim source), and the figures (PNG and SVG): the
//! recording against the simulation before and after, and the residual against the variable
//! that located each effect, before and after.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context as _;
use serde_json::json;
use taxel_plot::{Chart, Mark, Series};
use taxel_sim::model::{Creep, Crosstalk, Hysteresis, NodeFactors, ScanSkew, ThermalDrift};
use taxel_sim::SensorModel;

use crate::data::{Dataset, ReadoutMap};
use crate::diagnose::Diagnosis;
use crate::model::{Config, Thermal};

/// The start model extended with what was fitted. Returns the model and notes on what it
/// cannot express.
pub fn extended_model(
    start: &SensorModel,
    ds: &Dataset,
    d: &Diagnosis,
) -> (SensorModel, Vec<String>) {
    let cfg = &d.final_cfg;
    let mut m = start.clone();
    let mut notes = Vec::new();
    m.rows = ds.rows;
    m.cols = ds.cols;
    m.readout.kind = ds.map.kind();
    m.readout.inverted = matches!(ds.map, ReadoutMap::Amplifier { inverted: true, .. });
    m.readout.divider_rises = matches!(ds.map, ReadoutMap::Divider { rises: true, .. });
    m.material.exponent = cfg.exponent;
    m.material.r_floor_ohm = if cfg.sat_in_base || cfg.saturation {
        cfg.r_floor_ohm
    } else {
        0.0
    };
    // The simulator needs b >= 0 and a >= 0. Where the fit traded a negative baseline against a
    // larger gain (collinear, e.g. a constant force), keep the conductance at the typical load.
    let fmax = ds.max_force();
    let loaded: Vec<f64> = ds
        .force
        .iter()
        .filter(|&&f| f > 0.1 * fmax)
        .map(|f| f.powf(cfg.exponent))
        .collect();
    let p_bar = (loaded.iter().sum::<f64>() / loaded.len().max(1) as f64).max(1e-12);
    let mut b = Vec::with_capacity(ds.n);
    let mut a = Vec::with_capacity(ds.n);
    for t in &d.final_theta {
        let (mut bk, mut ak) = (t[0], t.last().copied().unwrap_or(0.0));
        if bk <= 0.0 {
            ak = (ak + bk / p_bar).max(0.0);
            bk = 1e-3 * (ak * p_bar).max(1e-12);
            ak = (ak - bk / p_bar).max(0.0);
        }
        b.push(bk.max(1e-12));
        a.push(ak.max(0.0));
    }
    let med = |v: &[f64]| -> f64 {
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        s[s.len() / 2]
    };
    let b_med = med(&b).max(1e-12);
    // In-load hysteresis acts on each node's own load, F / load_scale: the simulator gets the
    // nodes' shares of a driven force, and each gain grows by load_scale^n to match.
    let load_scale = cfg
        .hyst_share
        .and(cfg.hysteresis)
        .map(|_| crate::model::Context::new(ds).load_scale);
    if let Some(sc) = &load_scale {
        for (ak, s) in a.iter_mut().zip(sc) {
            *ak *= s.powf(cfg.exponent);
        }
    }
    let a_ref = {
        let m = med(&a);
        if m > 0.0 {
            m
        } else {
            a.iter().cloned().fold(0.0, f64::max).max(1e-12)
        }
    };
    m.material.g0_us = b_med * 1e6;
    m.material.gain_us_per_n = a_ref * 1e6;
    m.nodes = Some(NodeFactors {
        g0: b.iter().map(|v| v / b_med).collect(),
        gain: a.iter().map(|v| v / a_ref).collect(),
        load_share: load_scale.map(|sc| sc.iter().map(|s| 1.0 / s).collect()),
    });
    m.spread.node_gain_log_sd = 0.0;
    m.spread.node_g0_log_sd = 0.0;
    m.spread.build_gain_log_sd = 0.0;
    m.spread.build_g0_log_sd = 0.0;
    // Curvature: only what was found.
    let c = &mut m.curvature;
    c.mount_curvature_scatter = 0.0;
    c.mount_baseline_log_sd = 0.0;
    match (cfg.curv_sens, &ds.kappa) {
        (Some(ks), Some(kappa)) if cfg.curv_linear => {
            // The simulator has the hyperbolic form: match it at the mean curvature.
            let kbar = kappa.iter().sum::<f64>() / kappa.len().max(1) as f64;
            c.sensitivity_kappa_s_m1 = (ks - kbar).max(1.0);
            notes.push(format!("curvature_sensitivity fitted in the linear form 1 - kappa/{ks:.1}; SIM.toml has the simulator's 1/(1 + kappa/kappa_s), matched at the mean curvature {kbar:.1} 1/m"));
        }
        (Some(ks), Some(_)) => c.sensitivity_kappa_s_m1 = ks.max(1e-3),
        (Some(_), None) => {
            c.sensitivity_kappa_s_m1 = 1e9;
            notes.push("curvature_sensitivity was found per trial without a curvature column: SIM.toml cannot tie it to a curvature (sensitivity_kappa_s_m1 left off)".into());
        }
        _ => c.sensitivity_kappa_s_m1 = 1e9,
    }
    if cfg.curv_base && ds.kappa.is_some() {
        let slopes: Vec<f64> = d
            .final_theta
            .iter()
            .filter(|t| t.len() >= 3 && t[0] > 0.0)
            .map(|t| t[1] / t[0])
            .collect();
        c.baseline_g1_m = slopes.iter().sum::<f64>() / slopes.len().max(1) as f64;
        c.baseline_g1_flipped_m = c.baseline_g1_m;
        notes.push("curvature_baseline: per-node slopes are summarised by their mean (baseline_g1_m); the across-bend pattern is not written".into());
    } else {
        c.baseline_g1_m = 0.0;
        c.baseline_g1_flipped_m = 0.0;
        if cfg.curv_base {
            notes.push("curvature_baseline was found as per-trial baselines without a curvature column: SIM.toml cannot tie them to a curvature".into());
        }
    }
    c.baseline_g2_m2 = 0.0;
    c.pattern_quad_m = 0.0;
    c.pattern_lin_m = 0.0;
    m.creep = cfg.creep.as_ref().map(|terms| Creep {
        amplitudes: terms.iter().map(|t| t.0.clamp(-0.99, 0.99)).collect(),
        tau_s: terms.iter().map(|t| t.1).collect(),
    });
    m.hysteresis = cfg.hysteresis.map(|r| match cfg.hyst_share {
        Some(share) if cfg.hyst_bouc_wen => Hysteresis {
            weight: share.clamp(-1.0, 1.0),
            thresholds_n: Vec::new(),
            bouc_wen_saturation_n: Some(r),
            bouc_wen_exponent: cfg.hyst_bw_n,
            input_deadband_n: crate::model::force_deadband(&ds.force),
        },
        Some(share) => {
            let (weight, thresholds_n) = crate::diagnose::in_load_as_sim(r, cfg.hyst_mix, share);
            Hysteresis {
                weight,
                thresholds_n,
                ..Hysteresis::default()
            }
        }
        None => Hysteresis {
            weight: crate::diagnose::hysteresis_weight(ds, cfg, &d.final_theta),
            thresholds_n: vec![r, 4.0 * r],
            ..Hysteresis::default()
        },
    });
    if cfg.hyst_bouc_wen {
        notes.push(format!("hysteresis: the tool fits a Bouc-Wen state in the load path, F + share z per node, z saturating at r = {r:.3} N of the most loaded node's load with exponent n = {n:.2}, driven by the node's own load (nodes.load_share, estimated from its signal); its input is the recorded force through a play of half-width {deadband:.3} N (three standard deviations of the load cell's noise), since a state without return-point memory would ratchet on that noise. SIM.toml gets the same form (bouc_wen_saturation_n, bouc_wen_exponent, input_deadband_n, weight = share)", r = cfg.hysteresis.unwrap_or(0.0), n = cfg.hyst_bw_n, deadband = crate::model::force_deadband(&ds.force)));
    } else if cfg.hyst_share.is_some() {
        notes.push(format!("hysteresis: the tool fits the load path F + share (gap_r + mix gap_4r) per node, with each node's half-widths scaled to its share of the load (nodes.load_share, estimated from its signal); SIM.toml gets the simulator's equal-weight form: half-widths r and 4r (in newtons of the most loaded node's load) repeated in the ratio closest to mix = {:.2}, and weight = share x (number of operators) / (number at r)", cfg.hyst_mix));
    } else if cfg.hysteresis.is_some() {
        notes.push("hysteresis: the tool fits two play operators (half-widths r and 4r, mixed as gap_r + mix gap_4r) on the total force with one amplitude per node; SIM.toml gets both half-widths and the median share of the load (weight; negative when the loading branch lies above the unloading one)".into());
    }
    m.thermal_drift = match &cfg.thermal {
        Some(Thermal::Recorded { alpha_per_k, tau_s }) => {
            let t0 = ds
                .temp
                .as_ref()
                .map_or(25.0, |t| t.iter().sum::<f64>() / t.len().max(1) as f64);
            Some(ThermalDrift {
                alpha_per_k: *alpha_per_k,
                tau_s: *tau_s,
                t0_c: t0,
            })
        }
        Some(Thermal::Latent { .. }) => {
            notes.push("thermal_drift was found without a temperature column: SIM.toml gets alpha = -0.003 /K and the inferred sensor temperature is written to latent_temperature.csv".into());
            Some(ThermalDrift {
                alpha_per_k: -0.003,
                tau_s: 1e-3,
                t0_c: 25.0,
            })
        }
        None => None,
    };
    m.crosstalk = cfg.crosstalk.map(|rs| Crosstalk {
        rs_ohm: rs,
        vos_max_v: 0.0,
    });
    m.scan_skew = cfg.scan_skew.map(|dt| ScanSkew { dt_node_s: dt });
    if cfg.scan_skew.is_some() && cfg.scan_settle > 1e-5 {
        notes.push(format!("scan_skew: the row-switch settling ({:.2} ms) is not part of taxel-sim's scan skew; SIM.toml carries dt_node_s only", 1e3 * cfg.scan_settle));
    }
    if cfg.scan_skew.is_some() {
        notes.push("scan_skew acts in scenario runs; re-simulating a recording (driven mode) cannot look ahead in the recorded force, so the check below runs without it".into());
    }
    (m, notes)
}

/// Re-simulates the recording with taxel-sim itself (driven mode, no noise) from `model`;
/// returns the RMSE against the recording in the residual domain and the predictions.
pub fn resimulate(
    model: &SensorModel,
    ds: &Dataset,
    latent_temp: Option<&[f64]>,
) -> (f64, Vec<f64>) {
    let mut m = model.clone();
    m.readout.noise_counts = 0.0;
    m.readout.resolution_ohm = 0.0;
    let Ok(mut sim) = taxel_sim::Simulator::new(&m, &taxel_sim::Scenario::default()) else {
        return (f64::NAN, Vec::new());
    };
    let n = ds.n;
    let mut out = vec![0f32; n];
    let mut pred = Vec::with_capacity(ds.y.len());
    let (mut s, mut c) = (0.0, 0usize);
    for i in 0..ds.len() {
        let kappa = ds.kappa.as_ref().map_or(0.0, |k| k[i]);
        let temp = match (latent_temp, &ds.temp) {
            (Some(lt), _) => lt[i],
            (None, Some(t)) => t[i],
            _ => 25.0,
        };
        sim.step_driven(
            ds.t[i],
            ds.force[i],
            kappa,
            temp,
            ds.trial[i] as u32,
            &mut out,
        );
        for (k, o) in out.iter().enumerate() {
            let p = ds.map.dom(*o as f64);
            pred.push(p);
            let y = ds.y[i * n + k];
            if !ds.map.on_rail(y) {
                s += (p - ds.map.dom(y)).powi(2);
                c += 1;
            }
        }
    }
    ((s / c.max(1) as f64).sqrt(), pred)
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

/// Writes every output into `dir`; returns the list of files.
pub fn write_all(
    dir: &Path,
    ds: &Dataset,
    start: &SensorModel,
    d: &Diagnosis,
    notes_in: &[String],
) -> anyhow::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut files = Vec::new();
    let n = ds.n;
    let (model, mut notes) = extended_model(start, ds, d);
    notes.extend(notes_in.iter().cloned());
    let sim_path = dir.join("SIM.toml");
    let header = format!(
        "# Written by taxel-simcheck diagnose from {}\n# verdict: {}; effects: {}\n",
        ds.path,
        d.verdict,
        if d.effects.is_empty() {
            "none".to_string()
        } else {
            d.effects
                .iter()
                .map(|e| e.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        }
    );
    std::fs::write(&sim_path, header + &model.to_toml_string())
        .with_context(|| format!("cannot write {}", sim_path.display()))?;
    files.push(sim_path);
    // The latent temperature, when thermal drift was inferred without a column.
    let latent_temp: Option<Vec<f64>> = d
        .latent_m
        .as_ref()
        .map(|m| m.iter().map(|f| 25.0 + (f - 1.0) / -0.003).collect());
    if let Some(lt) = &latent_temp {
        let p = dir.join("latent_temperature.csv");
        let mut s = String::from("t_s,temp_c\n");
        for (t, v) in ds.t.iter().zip(lt) {
            let _ = writeln!(s, "{t},{v:.4}");
        }
        std::fs::write(&p, s).with_context(|| format!("cannot write {}", p.display()))?;
        files.push(p);
    }
    // The check that SIM.toml reproduces the fit when taxel-sim runs it.
    let (resim_rmse, resim_pred) = resimulate(&model, ds, latent_temp.as_deref());
    // Figures.
    let resp = crate::locate::responsiveness(&crate::model::Context::new(ds), &d.final_pred);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| resp[b].total_cmp(&resp[a]));
    let top = order[0];
    let responsive: Vec<usize> = order
        .iter()
        .copied()
        .filter(|&k| resp[k] > 0.2 * resp[top])
        .collect();
    let mut figures = Vec::new();
    // Overlay: a window around the worst base span (or the first 30 s).
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
    let overlay = Chart {
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
    };
    figures.extend(both(dir, "overlay", &overlay)?);
    // Residual over time (mean over responsive nodes, held-out), before and after.
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
    figures.extend(both(
        dir,
        "residual_time",
        &Chart {
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
        },
    )?);
    // Per effect: residual against its locating variable.
    let fmax = ds.max_force().max(1e-12);
    let dir_sign = crate::locate::direction(&crate::model::Context::new(ds));
    let mut dtv = vec![ds.dt()];
    dtv.extend(ds.t.windows(2).map(|p| (p[1] - p[0]).max(1e-9)));
    let dir_sign = &dir_sign;
    for e in &d.effects {
        let (xlabel, x): (String, Box<dyn Fn(usize) -> Option<f64>>) = match e.name.as_str() {
            "creep" => {
                let tau = e.params.get("tau_fast_s").copied().unwrap_or(3.0);
                let mut s = ds.force[0];
                let lp: Vec<f64> = ds
                    .force
                    .iter()
                    .zip(&dtv)
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
        };
        let nodes: &[usize] = if e.name.starts_with("thermal") || e.name == "curvature_baseline" {
            &all
        } else {
            &responsive
        };
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
    for f in &figures {
        files.push(dir.join(f));
    }
    // report.json
    let j = json!({
        "verdict": d.verdict,
        "effects": d.effects,
        "unexplained": d.unexplained,
        "rmse_base": d.rmse_base,
        "rmse_final": d.rmse_final,
        "recording": ds.path,
        "samples": ds.len(),
        "nodes": n,
        "readout": format!("{:?}", ds.map.kind()).to_lowercase(),
        "residual_unit": unit,
        "base": base_json(&d.base),
        "final": base_json(&d.final_cfg),
        "candidates": d.trials,
        "skipped": d.skipped.iter().map(|(e, w)| json!({"effect": e, "why": w})).collect::<Vec<_>>(),
        "findings_base": d.base_findings,
        "findings_final": d.final_findings,
        "resim_rmse_taxel_sim": resim_rmse,
        "notes": notes,
        "figures": figures,
        "seconds": d.seconds,
    });
    let jp = dir.join("report.json");
    std::fs::write(&jp, serde_json::to_string_pretty(&j)? + "\n")
        .with_context(|| format!("cannot write {}", jp.display()))?;
    files.push(jp);
    let mp = dir.join("report.md");
    std::fs::write(&mp, markdown(ds, d, &notes, &figures, resim_rmse))
        .with_context(|| format!("cannot write {}", mp.display()))?;
    files.push(mp);
    Ok(files)
}

fn base_json(c: &Config) -> serde_json::Value {
    json!({
        "exponent": c.exponent,
        "r_floor_ohm": if c.sat_in_base || c.saturation { c.r_floor_ohm } else { 0.0 },
    })
}

fn markdown(
    ds: &Dataset,
    d: &Diagnosis,
    notes: &[String],
    figures: &[String],
    resim: f64,
) -> String {
    let mut s = String::new();
    let unit = ds.map.dom_unit();
    let _ = writeln!(s, "# Sim vs recording: {}\n", ds.path);
    let _ = writeln!(s, "## Findings\n");
    let _ = writeln!(
        s,
        "**Verdict: {}.** Held-out RMSE (two-fold, alternating time blocks) {:.4} -> {:.4} {unit} ({:+.1} %).\n",
        d.verdict,
        d.rmse_base,
        d.rmse_final,
        100.0 * (d.rmse_final / d.rmse_base.max(1e-300) - 1.0)
    );
    if d.effects.is_empty() {
        let _ = writeln!(s, "No effect of the library improved the held-out error by more than its parameters buy.\n");
    } else {
        let _ = writeln!(
            s,
            "| effect | parameters | held-out RMSE without -> with |\n|---|---|---|"
        );
        for e in &d.effects {
            let p: Vec<String> = e
                .params
                .iter()
                .map(|(k, v)| format!("{k} = {v:.4}"))
                .collect();
            let _ = writeln!(
                s,
                "| {} | {} | {:.4} -> {:.4} |",
                e.name,
                p.join(", "),
                e.heldout_rmse_before,
                e.heldout_rmse_after
            );
        }
        let _ = writeln!(s);
        for e in &d.effects {
            let _ = writeln!(s, "- **{}**: {}", e.name, e.evidence);
        }
        let _ = writeln!(s);
    }
    for u in &d.unexplained {
        let _ = writeln!(
            s,
            "- **Unexplained** at nodes {:?}, {:.1}-{:.1} s: {}",
            u.nodes, u.t_s[0], u.t_s[1], u.description
        );
    }
    let _ = writeln!(s, "\nBase model: force-law exponent {:.3}, resistance floor {:.1} ohm; final: exponent {:.3}, floor {:.1} ohm. Readout: {:?}. {} samples x {} nodes, {:.1} s, analysed in {:.1} s.\n",
        d.base.exponent, if d.base.sat_in_base { d.base.r_floor_ohm } else { 0.0 }, d.final_cfg.exponent,
        if d.final_cfg.sat_in_base || d.final_cfg.saturation { d.final_cfg.r_floor_ohm } else { 0.0 },
        ds.map.kind(), ds.len(), ds.n, ds.duration(), d.seconds);
    let _ = writeln!(s, "SIM.toml re-simulated by taxel-sim (driven by the recorded force, no noise): RMSE {resim:.4} {unit} over the whole recording.\n");
    for n in notes {
        let _ = writeln!(s, "- note: {n}");
    }
    let _ = writeln!(
        s,
        "\n## Evidence\n\n### Where the base model's residual is structured\n"
    );
    let f = &d.base_findings;
    let _ = writeln!(s, "Residual memory: autocorrelation {:.2} at lag 1, {:.2} at 1 s; integrated autocorrelation time {:.0} samples (white noise: 1).\n", f.acf_lag1, f.acf_1s, f.tau_int_samples);
    let _ = writeln!(
        s,
        "| regressor | r | 95 % CI (block bootstrap) | |\n|---|---|---|---|"
    );
    for c in &f.correlations {
        let _ = writeln!(
            s,
            "| {} | {:.3} | [{:.3}, {:.3}] | {} |",
            c.regressor,
            c.r,
            c.ci95[0],
            c.ci95[1],
            if c.significant { "significant" } else { "" }
        );
    }
    let _ = writeln!(
        s,
        "\n| split | groups (mean residual +- 95 % CI) |\n|---|---|"
    );
    for sp in &f.splits {
        let g: Vec<String> = sp
            .groups
            .iter()
            .map(|g| format!("{}: {:.3} +- {:.3}", g.label, g.mean, g.ci95_half))
            .collect();
        let _ = writeln!(s, "| {} | {} |", sp.by, g.join("; "));
    }
    let _ = writeln!(
        s,
        "\n| node | row | col | RMS | noise floor | ratio |\n|---|---|---|---|---|---|"
    );
    for nst in &f.nodes {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.3} | {:.3} | {:.1} |",
            nst.node, nst.row, nst.col, nst.rms, nst.noise, nst.ratio
        );
    }
    if let Some(p) = &f.presses {
        let _ = writeln!(s, "\nPress to press: {} presses, standard deviation of the per-press mean residual {:.3} ({:.0} % of the loaded residual RMS).", p.presses, p.sd_between, 100.0 * p.share_of_rms);
    }
    if !f.spans.is_empty() {
        let _ = writeln!(
            s,
            "\nTime spans with the largest residual (windowed RMS over the median window):\n"
        );
        for sp in &f.spans {
            let _ = writeln!(
                s,
                "- {:.1}-{:.1} s: {:.1}x",
                sp.t_s[0], sp.t_s[1], sp.rms_ratio
            );
        }
    }
    let _ = writeln!(s, "\n### Every candidate tested\n\n| round | effect | held-out RMSE before -> after | SSE gain | block t | signed-rank z | blocks better | information gain | accepted | time (s) |\n|---|---|---|---|---|---|---|---|---|---|");
    for t in &d.trials {
        let v = &t.verdict;
        let _ = writeln!(
            s,
            "| {} | {} | {:.4} -> {:.4} | {:.1} % | {:.1} | {:.1} | {:.0} % | {:.0} | {} | {:.1} |",
            t.round,
            t.effect,
            v.rmse_before,
            v.rmse_after,
            100.0 * v.rel_gain,
            v.block_t,
            v.rank_z,
            100.0 * v.blocks_improved,
            v.ic_gain,
            if v.accepted { "yes" } else { "no" },
            t.seconds,
        );
    }
    for (e, why) in &d.skipped {
        let _ = writeln!(s, "\n- {e} not testable here: {why}");
    }
    let _ = writeln!(s, "\nAn effect is accepted when its held-out SSE gain is at least {:.0} %, its block t statistic (or the Wilcoxon signed-rank test over blocks, as a z score) at least {:.0}, and n_eff ln(SSE0/SSE1) exceeds k ln(n_eff) for its k extra parameters (n_eff = time samples / integrated autocorrelation time of the richer model's held-out residual).\n", 100.0 * crate::search::MIN_REL_GAIN, crate::search::MIN_BLOCK_T);
    let _ = writeln!(s, "## Figures\n");
    for fig in figures.iter().filter(|f| f.ends_with(".png")) {
        let _ = writeln!(s, "![{fig}]({fig})\n");
    }
    s
}
