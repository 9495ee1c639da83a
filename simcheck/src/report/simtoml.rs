//! SIM.toml: the start model extended with what the diagnosis fitted (base law, per-node
//! factors, curvature, effect layers), and the check that taxel-sim running it reproduces the
//! recording.

use taxel_sim::model::{Creep, Crosstalk, Hysteresis, NodeFactors, ScanSkew, ThermalDrift};
use taxel_sim::SensorModel;

use crate::data::{Dataset, ReadoutMap};
use crate::diagnose::Diagnosis;
use crate::effects::{Config, Thermal};

/// The start model extended with what was fitted. Returns the model and notes on what it
/// cannot express.
pub fn extended_model(
    start: &SensorModel,
    ds: &Dataset,
    d: &Diagnosis,
) -> (SensorModel, Vec<String>) {
    let cfg = &d.sim_cfg;
    let mut m = start.clone();
    let mut notes = Vec::new();
    m.rows = ds.rows;
    m.cols = ds.cols;
    m.readout.kind = ds.map.kind();
    m.readout.inverted = matches!(ds.map, ReadoutMap::Amplifier { inverted: true, .. });
    m.readout.divider_rises = matches!(ds.map, ReadoutMap::Divider { rises: true, .. });
    // The converter as the recording was read: readings beyond the start model's range widen
    // it (a 12-bit board read with a 10-bit model), and taxel-sim must write the same codes.
    if let Some(bits) = ds.map.adc_bits() {
        m.readout.adc_bits = bits;
    }
    base_law(&mut m, ds, cfg, &d.sim_theta, &d.load_scale);
    curvature(&mut m, ds, cfg, &d.sim_theta, &mut notes);
    m.creep = cfg.creep.as_ref().map(|terms| Creep {
        amplitudes: terms.iter().map(|t| t.0.clamp(-0.99, 0.99)).collect(),
        tau_s: terms.iter().map(|t| t.1).collect(),
    });
    if cfg.thermal_gain_only {
        notes.push("thermal_drift was found on the force term only (the unloaded conductance does not follow the temperature); taxel-sim's thermal drift scales the whole conductance: SIM.toml carries alpha and tau in that form".into());
    }
    if cfg.creep.is_some() && cfg.creep_recovery != 1.0 {
        notes.push(format!("creep was found recovering at its own pace: after the load falls each term's time constant is {:.2} times its creep's; taxel-sim's Prony creep recovers with the same time constants: SIM.toml carries the creep's", cfg.creep_recovery));
    }
    if cfg.creep_under_load && cfg.creep_level {
        notes.push("creep was found in the form that stays with the load and grows with its level (L = F (1 + sum c lowpass(F / F_max))); taxel-sim's creep is the Prony form, which recovers after unloading: SIM.toml carries the same amplitudes and time constants in that form".into());
    } else if cfg.creep_under_load {
        notes.push("creep was found in the form that stays with the load (L = F (1 + sum c lowpass(load on)), no recovery tail after unloading); taxel-sim's creep is the Prony form, which recovers after unloading: SIM.toml carries the same amplitudes and time constants in that form".into());
    }
    hysteresis(&mut m, ds, cfg, &d.sim_theta, &mut notes);
    thermal(&mut m, ds, cfg, &mut notes);
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

/// The force law and the per-node factors (`nodes.g0/gain`, and the load shares when
/// hysteresis acts in the load path).
fn base_law(
    m: &mut SensorModel,
    ds: &Dataset,
    cfg: &Config,
    theta: &[Vec<f64>],
    load_scale: &[f64],
) {
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
    for t in theta {
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
        .map(|_| load_scale.to_vec());
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
}

/// Curvature: only what was found.
fn curvature(
    m: &mut SensorModel,
    ds: &Dataset,
    cfg: &Config,
    theta: &[Vec<f64>],
    notes: &mut Vec<String>,
) {
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
    if cfg.curv_trials.is_some() {
        let what = if cfg.curv_per_node.is_some() {
            "one factor per trial and node (the contact's load map moves with the mounting)"
        } else {
            "one factor per trial"
        };
        notes.push(format!("curvature_sensitivity was found as {what}: SIM.toml cannot tie it to a curvature (sensitivity_kappa_s_m1 left off)"));
    }
    if cfg.curv_base && ds.kappa.is_some() {
        let slopes: Vec<f64> = theta
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
}

/// The hysteresis layer in the simulator's form, with a note on how it was translated.
fn hysteresis(
    m: &mut SensorModel,
    ds: &Dataset,
    cfg: &Config,
    theta: &[Vec<f64>],
    notes: &mut Vec<String>,
) {
    if cfg.hyst_set {
        notes.push(format!("hysteresis: the tool fits a set: each node's reading raised for good by its own piecewise-linear function of the largest force so far, between the levels that force held ({:.3?} N){}; taxel-sim has no set, and SIM.toml leaves it out", cfg.set_levels, if cfg.hysteresis.is_some() { ", beside the loop below" } else { ", with no loop" }));
    }
    m.hysteresis = cfg.hysteresis.map(|r| match cfg.hyst_share {
        Some(share) if cfg.hyst_bouc_wen => Hysteresis {
            weight: share.clamp(-1.0, 1.0),
            thresholds_n: Vec::new(),
            bouc_wen_saturation_n: Some(r),
            bouc_wen_exponent: cfg.hyst_bw_n,
            input_deadband_n: crate::context::force_deadband(&ds.force),
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
            weight: crate::diagnose::hysteresis_weight(ds, cfg, theta),
            thresholds_n: vec![r, 4.0 * r],
            ..Hysteresis::default()
        },
    });
    if cfg.hyst_preisach {
        notes.push(format!("hysteresis: the tool fits Preisach relays in the load path (median half-width {:.3} N, centres {:.3} +- {:.3} N of the most loaded node's load, virgin start); taxel-sim has no Preisach form: SIM.toml gets play operators at the median half-width and four times it with the fitted share", cfg.hysteresis.unwrap_or(0.0), cfg.preis_mu, cfg.preis_sigma));
    } else if cfg.hyst_bouc_wen && cfg.hyst_share.is_none() {
        notes.push(format!("hysteresis: the tool fits a Bouc-Wen state on the total force (saturation r = {r:.3} N, exponent n = {n:.2}, asymmetry a = {a:.2}, started at {z0:.2} r) with {amps} amplitudes per node (on z, z u{quad}, u = F / F_max: each node's loop and how it changes with the load){remnant}; taxel-sim has no such form: SIM.toml gets play operators at r and 4r with the median share of the load (weight), as for the additive plays", r = cfg.hysteresis.unwrap_or(0.0), n = cfg.hyst_bw_n, a = cfg.hyst_bw_asym, z0 = cfg.hyst_bw_z0, amps = if cfg.hyst_bw_quad { "three" } else { "two" }, quad = if cfg.hyst_bw_quad { " and z u^2" } else { "" }, remnant = if cfg.hyst_remnant { ", and a remnant at rest that grows with the largest force so far, each node's own function of it (three ramps over thirds of the peak force; taxel-sim has no remnant)" } else { "" }));
    } else if cfg.hyst_bouc_wen {
        notes.push(format!("hysteresis: the tool fits a Bouc-Wen state in the load path, F + share z per node, z saturating at r = {r:.3} N of the most loaded node's load with exponent n = {n:.2}, driven by the node's own load (nodes.load_share, estimated from its signal); its input is the recorded force through a play of half-width {deadband:.3} N (three standard deviations of the load cell's noise), since a state without return-point memory would ratchet on that noise. SIM.toml gets the same form (bouc_wen_saturation_n, bouc_wen_exponent, input_deadband_n, weight = share){asym}", r = cfg.hysteresis.unwrap_or(0.0), n = cfg.hyst_bw_n, asym = if cfg.hyst_bw_asym == 0.0 { String::new() } else { format!(" without its asymmetry a = {:.2} (taxel-sim's Bouc-Wen is symmetric)", cfg.hyst_bw_asym) }, deadband = crate::context::force_deadband(&ds.force)));
    } else if cfg.hyst_share.is_some() {
        notes.push(format!("hysteresis: the tool fits the load path F + share (gap_r + mix gap_4r) per node, with each node's half-widths scaled to its share of the load (nodes.load_share, estimated from its signal); SIM.toml gets the simulator's equal-weight form: half-widths r and 4r (in newtons of the most loaded node's load) repeated in the ratio closest to mix = {:.2}, and weight = share x (number of operators) / (number at r)", cfg.hyst_mix));
    } else if cfg.hysteresis.is_some() {
        notes.push("hysteresis: the tool fits two play operators (half-widths r and 4r, mixed as gap_r + mix gap_4r) on the total force with one amplitude per node; SIM.toml gets both half-widths and the median share of the load (weight; negative when the loading branch lies above the unloading one)".into());
    }
}

/// The thermal drift layer (from the recorded temperature, or a stand-in for a latent one).
fn thermal(m: &mut SensorModel, ds: &Dataset, cfg: &Config, notes: &mut Vec<String>) {
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
