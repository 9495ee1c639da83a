//! How a named effect is reported: its parameters in physical units, the simulator's form of
//! the fitted hysteresis, and the evidence (held-out gain and the locating statistics that
//! speak for it).

use std::collections::BTreeMap;

use serde::Serialize;

use crate::cv::Verdict;
use crate::data::Dataset;
use crate::effects::{Config, EffectKind, Thermal};
use crate::locate::Findings;

#[derive(Debug, Clone, Serialize)]
pub struct NamedEffect {
    pub name: String,
    pub params: BTreeMap<String, f64>,
    pub evidence: String,
    pub heldout_rmse_before: f64,
    pub heldout_rmse_after: f64,
}

pub fn effect_params(
    ds: &Dataset,
    cfg: &Config,
    e: EffectKind,
    theta: &[Vec<f64>],
) -> BTreeMap<String, f64> {
    let mut p = BTreeMap::new();
    match e {
        EffectKind::Creep => {
            if cfg.creep.is_some() {
                p.insert(
                    "under_load".into(),
                    f64::from(u8::from(cfg.creep_under_load)),
                );
            }
            if cfg.creep.is_some() && cfg.creep_under_load {
                p.insert("by_level".into(), f64::from(u8::from(cfg.creep_level)));
            }
            if cfg.creep.is_some() && cfg.creep_recovery != 1.0 {
                p.insert("recovery_factor".into(), cfg.creep_recovery);
            }
            if let Some(terms) = &cfg.creep {
                let mut t = terms.clone();
                t.sort_by(|a, b| a.1.total_cmp(&b.1));
                let names: &[&str] = if t.len() == 3 {
                    &["fast", "mid", "slow"]
                } else {
                    &["fast", "slow"]
                };
                for (name, (c, tau)) in names.iter().zip(&t) {
                    p.insert(format!("amplitude_{name}"), *c);
                    p.insert(format!("tau_{name}_s"), *tau);
                }
            }
        }
        EffectKind::Hysteresis => {
            if cfg.hyst_set {
                p.insert("set".into(), 1.0);
                for (j, l) in cfg.set_levels.iter().enumerate() {
                    p.insert(format!("set_level_{j}_n"), *l);
                }
            }
            if let Some(r) = cfg.hysteresis {
                p.insert("weight".into(), hysteresis_weight(ds, cfg, theta));
                if cfg.hyst_preisach {
                    p.insert("preisach".into(), 1.0);
                    p.insert("median_half_width_n".into(), r);
                    p.insert("centre_n".into(), cfg.preis_mu);
                    p.insert("centre_sd_n".into(), cfg.preis_sigma);
                } else if cfg.hyst_bouc_wen {
                    p.insert("bouc_wen".into(), 1.0);
                    p.insert("saturation_n".into(), r);
                    p.insert("exponent".into(), cfg.hyst_bw_n);
                    p.insert("asymmetry".into(), cfg.hyst_bw_asym);
                    if cfg.hyst_share.is_none() {
                        p.insert("additive".into(), 1.0);
                        p.insert("start_state".into(), cfg.hyst_bw_z0);
                        if cfg.hyst_remnant {
                            p.insert("remnant".into(), 1.0);
                        }
                        if cfg.hyst_bw_quad {
                            p.insert("quadratic".into(), 1.0);
                        }
                    }
                } else {
                    p.insert("threshold_n".into(), r);
                    p.insert("mix".into(), cfg.hyst_mix);
                }
                if let Some(share) = cfg.hyst_share {
                    p.insert("share".into(), share);
                }
            }
        }
        EffectKind::ThermalDrift => match &cfg.thermal {
            Some(Thermal::Recorded { alpha_per_k, tau_s }) => {
                p.insert(
                    "gain_only".into(),
                    f64::from(u8::from(cfg.thermal_gain_only)),
                );
                p.insert("alpha_per_k".into(), *alpha_per_k);
                p.insert("tau_s".into(), *tau_s);
            }
            Some(Thermal::Latent { values, knots_s }) => {
                let lo = values.iter().cloned().fold(f64::INFINITY, f64::min);
                let hi = values.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
                p.insert("latent_knots".into(), knots_s.len() as f64);
                p.insert("factor_min".into(), lo);
                p.insert("factor_max".into(), hi);
            }
            None => {}
        },
        EffectKind::CurvatureSensitivity => {
            if let Some(g) = &cfg.curv_trials {
                let lo = g.iter().cloned().fold(f64::INFINITY, f64::min);
                let hi = g.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
                p.insert("per_trial".into(), 1.0);
                let nn = cfg.curv_per_node.unwrap_or(1).max(1);
                p.insert("trials".into(), (g.len() / nn) as f64);
                if cfg.curv_per_node.is_some() {
                    p.insert("per_node".into(), 1.0);
                }
                p.insert("sensitivity_min_over_max".into(), lo / hi.max(1e-12));
            }
            if let Some(v) = cfg.curv_sens {
                let form = if cfg.curv_linear { 1.0 } else { 0.0 };
                p.insert("linear_form".into(), form);
                match (ds.kappa.is_some(), cfg.curv_linear) {
                    (true, false) => p.insert("kappa_s_m1".into(), v),
                    (true, true) => p.insert("kappa_zero_m1".into(), v),
                    (false, _) => p.insert("beta_per_log_baseline_shift".into(), v),
                };
            }
        }
        EffectKind::CurvatureBaseline => {
            let slopes: Vec<f64> = theta
                .iter()
                .filter(|t| t.len() >= 3 && t[0].abs() > 0.0)
                .map(|t| t[1] / t[0])
                .collect();
            let mean = slopes.iter().sum::<f64>() / slopes.len().max(1) as f64;
            let lo = slopes.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = slopes.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            if ds.kappa.is_some() {
                p.insert("mean_g1_m".into(), mean);
                p.insert("min_g1_m".into(), lo);
                p.insert("max_g1_m".into(), hi);
            } else {
                p.insert("trials".into(), ds.n_trials as f64);
                p.insert("mean_slope_per_log_shift".into(), mean);
                p.insert("min_slope_per_log_shift".into(), lo);
                p.insert("max_slope_per_log_shift".into(), hi);
            }
        }
        EffectKind::Saturation => {
            p.insert("r_floor_ohm".into(), cfg.r_floor_ohm);
        }
        EffectKind::Crosstalk => {
            if let Some(v) = cfg.crosstalk {
                p.insert("rs_ohm".into(), v);
            }
        }
        EffectKind::ScanSkew => {
            if let Some(v) = cfg.scan_skew {
                p.insert("dt_node_s".into(), v);
                p.insert("row_settle_s".into(), cfg.scan_settle);
            }
        }
    }
    p
}

/// In-load hysteresis `f + share (gap_r + mix gap_4r)` in the simulator's form
/// `f + w mean_j gap_{r_j}`: `a` thresholds at `r` and `b` at `4r` with `b / a` closest to `mix`
/// (`a + b <= 12`), and `w = share (a + b) / a` (clamped to the simulator's -1..=1). A negative
/// `mix` cannot be written with equal weights: the wide operator is then left out.
pub fn in_load_as_sim(r: f64, mix: f64, share: f64) -> (f64, Vec<f64>) {
    let mut best = (1usize, 0usize);
    for a in 1..=12usize {
        for b in 0..=(12 - a) {
            let err = |(a, b): (usize, usize)| (b as f64 / a as f64 - mix).abs();
            if err((a, b)) < err(best) {
                best = (a, b);
            }
        }
    }
    let (a, b) = best;
    let mut thresholds = vec![r; a];
    thresholds.extend(std::iter::repeat_n(4.0 * r, b));
    let w = (share * (a + b) as f64 / a as f64).clamp(-1.0, 1.0);
    (w, thresholds)
}

/// The play operators' share of the load, `w`, implied by the fitted per-node hysteresis
/// amplitudes: `h_k (1 + mix) = a_k n F^(n-1) w` at the mean loaded force (median over
/// responsive nodes), for the simulator's mean of the two plays (half-widths `r` and `4r`).
/// Negative when the loop runs the other way (the loading branch above the unloading one).
pub fn hysteresis_weight(ds: &Dataset, cfg: &Config, theta: &[Vec<f64>]) -> f64 {
    if let (Some(r), Some(share)) = (cfg.hysteresis, cfg.hyst_share) {
        if cfg.hyst_bouc_wen {
            return share.clamp(-1.0, 1.0);
        }
        return in_load_as_sim(r, cfg.hyst_mix, share).0;
    }
    let fmax = ds.max_force();
    let loaded: Vec<f64> = ds
        .force
        .iter()
        .copied()
        .filter(|&f| f > 0.1 * fmax)
        .collect();
    let fbar = loaded.iter().sum::<f64>() / loaded.len().max(1) as f64;
    let amax = theta.iter().map(|t| t[t.len() - 1]).fold(0.0, f64::max);
    let mut w: Vec<f64> = theta
        .iter()
        .filter(|t| t.len() >= 3 && t[t.len() - 1] > 0.2 * amax && amax > 0.0)
        .map(|t| {
            let a = t[t.len() - 1];
            // The additive Bouc-Wen's amplitudes (on z, z u and, if fitted, z u^2, u = F /
            // F_max) at the mean loaded force.
            // The remnant's and a set's ramps sit between them and the law's gain.
            let skip = if cfg.hyst_remnant {
                crate::effects::REMNANT_RAMPS
            } else {
                0
            } + if cfg.hyst_set {
                cfg.set_levels.len()
            } else {
                0
            };
            let terms = cfg.bw_terms();
            let h = if cfg.hyst_bouc_wen && t.len() >= terms + 2 + skip {
                let u = fbar / fmax.max(1e-9);
                let first = t.len() - 1 - terms - skip;
                (0..terms).map(|j| t[first + j] * u.powi(j as i32)).sum()
            } else {
                t[t.len() - 2 - skip] * (1.0 + cfg.hyst_mix)
            };
            h / (a * cfg.exponent * fbar.max(1e-9).powf(cfg.exponent - 1.0))
        })
        .collect();
    if w.is_empty() {
        return 0.0;
    }
    w.sort_by(f64::total_cmp);
    w[w.len() / 2].clamp(-1.0, 1.0)
}

/// The locating regressor(s) that speak for an effect.
pub fn signature(e: EffectKind) -> &'static [&'static str] {
    match e {
        EffectKind::Creep => &[
            "time under load: low-pass(F, 3 s) - F",
            "time under load: low-pass(F, 30 s) - F",
        ],
        EffectKind::Hysteresis => &["loading direction x level"],
        EffectKind::ScanSkew => &["scan index x dF/dt"],
        EffectKind::ThermalDrift => &["temperature", "time (slow drift, all nodes)"],
        EffectKind::CurvatureSensitivity => &["curvature x force"],
        EffectKind::CurvatureBaseline => &["curvature (no-load offset)"],
        EffectKind::Crosstalk => &["same-row load (crosstalk)"],
        EffectKind::Saturation => &["force level (node-weighted)"],
    }
}

pub fn evidence(e: EffectKind, v: &Verdict, f: &Findings) -> String {
    let mut s = format!(
        "held-out SSE -{:.1} % (RMSE {:.4} -> {:.4}), better in {:.0} % of blocks, block t = {:.1}, signed-rank z = {:.1}, information gain {:.0}",
        100.0 * v.rel_gain,
        v.rmse_before,
        v.rmse_after,
        100.0 * v.blocks_improved,
        v.block_t,
        v.rank_z,
        v.ic_gain
    );
    for name in signature(e) {
        if let Some(c) = f.correlations.iter().find(|c| c.regressor == *name) {
            s.push_str(&format!(
                "; base residual vs {}: r = {:.2} [{:.2}, {:.2}]",
                c.regressor, c.r, c.ci95[0], c.ci95[1]
            ));
        }
    }
    if e == EffectKind::CurvatureBaseline || e == EffectKind::CurvatureSensitivity {
        for sp in &f.splits {
            if sp.by.starts_with("trial") {
                let lo = sp
                    .groups
                    .iter()
                    .map(|g| g.mean)
                    .fold(f64::INFINITY, f64::min);
                let hi = sp
                    .groups
                    .iter()
                    .map(|g| g.mean)
                    .fold(f64::NEG_INFINITY, f64::max);
                s.push_str(&format!(
                    "; base residual by {}: {:.3} to {:.3}",
                    sp.by, lo, hi
                ));
            }
        }
    }
    if e == EffectKind::Hysteresis {
        if let Some(sp) = f
            .splits
            .iter()
            .find(|s| s.by.starts_with("loading direction"))
        {
            if sp.groups.len() == 2 {
                s.push_str(&format!(
                    "; base residual loading {:.3} +- {:.3} vs unloading {:.3} +- {:.3}",
                    sp.groups[0].mean,
                    sp.groups[0].ci95_half,
                    sp.groups[1].mean,
                    sp.groups[1].ci95_half
                ));
            }
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn in_load_hysteresis_goes_into_the_simulator_form() {
        // mix 0.5: two operators at r for one at 4r; w = share x 3 / 2.
        let (w, th) = in_load_as_sim(0.2, 0.5, -0.3);
        assert_eq!(th, vec![0.2, 0.2, 0.8]);
        assert!((w + 0.45).abs() < 1e-12, "{w}");
        // A negative mix cannot be written with equal weights: the wide operator is left out.
        let (w, th) = in_load_as_sim(0.2, -0.5, 0.3);
        assert_eq!((w, th), (0.3, vec![0.2]));
    }
}
