//! Named sensor models. `default` is the plain model; `paper-dataset` adds what separates real
//! sensors and real mountings (build-to-build baseline spread, mounting scatter) and is the model
//! behind the shipped curvature dataset and the demo; `alt` is another parameterisation
//! (stronger nonlinearity, crosstalk, more noise and spread) used only to check that training
//! methods generalize, never to tune them.
//!
//! The zoo presets are worlds whose laws differ from the default (see docs/sim.md,
//! "Functional-form families"), each with no-load readings well inside the ADC range at
//! 0-100 1/m, no saturation at 20 N on the central block, distinguishable 1-20 N, and a 20-50 %
//! loss of response from 0 to 80 1/m:
//! - `zoo-log`: logarithmic law, hyperbolic curvature sensitivity, exponential baseline rise,
//!   a 12-bit divider (falling with force), a Gaussian contact that moves at every press,
//!   per-node wander, 2 counts of noise and rare spikes;
//! - `zoo-sat`: saturating (hyperbolic) law with per-node shape spread, linear curvature
//!   sensitivity, the 10-bit amplifier, common-mode wander, 1.4 counts of noise;
//! - `zoo-pow`: power law with a strong per-node exponent spread, exponential curvature
//!   sensitivity, an inverted 10-bit amplifier, 0.5 counts of noise, per-node wander;
//! - `zoo-amp`: the paper's board (10-bit non-inverting amplifier) with a steeper power law and
//!   a per-node exponent spread, a strong common-mode wander plus a per-node one, 1 count of
//!   noise and rare spikes.

use crate::footprint::Footprint;
use crate::forms::{BaselineForm, Law, SensitivityForm};
use crate::model::{ReadoutKind, SensorModel};
use crate::noise::{Wander, WanderMode};

/// Names accepted by [`preset`].
pub const NAMES: [&str; 7] = [
    "default",
    "paper-dataset",
    "alt",
    "zoo-log",
    "zoo-sat",
    "zoo-pow",
    "zoo-amp",
];

/// The model called `name`.
pub fn preset(name: &str) -> Option<SensorModel> {
    let mut m = SensorModel::default();
    match name {
        "default" => {}
        "paper-dataset" => {
            m.spread.build_g0_log_sd = 0.25;
            m.curvature.mount_curvature_scatter = 0.04;
            m.curvature.mount_baseline_log_sd = 0.01;
            // Mild creep and hysteresis: loading history matters a little, as on real
            // Velostat (no effect on unloaded frames, so baselines are unchanged).
            m.creep = Some(crate::model::Creep {
                amplitudes: vec![0.02, 0.02],
                tau_s: vec![2.0, 60.0],
            });
            m.hysteresis = Some(crate::model::Hysteresis {
                weight: 0.06,
                thresholds_n: vec![0.1, 0.3, 0.6, 1.0],
                ..Default::default()
            });
        }
        "alt" => {
            m.spread.build_g0_log_sd = 0.35;
            m.spread.build_gain_log_sd = 0.1;
            m.spread.node_g0_log_sd = 0.1;
            m.readout.noise_counts = 0.8;
            m.material.g0_us = 35.0;
            m.curvature.baseline_g1_m = 0.003;
            m.curvature.baseline_g1_flipped_m = 0.0045;
            m.curvature.baseline_g2_m2 = 4e-5;
            m.curvature.pattern_quad_m = -0.003;
            m.curvature.pattern_lin_m = 0.0035;
            m.curvature.mount_curvature_scatter = 0.06;
            m.curvature.mount_baseline_log_sd = 0.015;
            m.crosstalk = Some(Default::default());
        }
        "zoo-log" => {
            m.material.law = Law::Log;
            m.material.log_gain_us = 250.0;
            m.material.log_f0_n = 0.5;
            m.curvature.sensitivity_form = SensitivityForm::Hyperbolic;
            m.curvature.sensitivity_c0_m1 = 60.0;
            m.curvature.sensitivity_exponent = 1.5;
            m.curvature.baseline_form = BaselineForm::Exponential;
            m.curvature.baseline_cb_m1 = 60.0;
            m.readout.kind = ReadoutKind::Divider;
            m.readout.adc_bits = 12;
            m.readout.r_ref_ohm = 10_000.0;
            m.readout.noise_counts = 2.0;
            m.contact.footprint = Footprint::Gaussian;
            m.contact.width_nodes = 0.7;
            m.contact.jitter_nodes = 0.15;
            m.noise.wander = Some(Wander {
                sd_counts: 1.5,
                tau_s: 20.0,
                mode: WanderMode::PerNode,
            });
            m.noise.spike_rate_hz = 0.02;
            m.noise.spike_counts = 25.0;
        }
        "zoo-sat" => {
            m.material.law = Law::Hyperbolic;
            m.material.hyperbolic_gmax_us = 1200.0;
            m.material.hyperbolic_half_n = 3.0;
            m.spread.node_exponent_log_sd = 0.1;
            m.curvature.sensitivity_form = SensitivityForm::Linear;
            m.curvature.sensitivity_cmax_m1 = 230.0;
            m.readout.noise_counts = 1.4;
            m.noise.wander = Some(Wander {
                sd_counts: 1.5,
                tau_s: 30.0,
                mode: WanderMode::Common,
            });
        }
        "zoo-pow" => {
            m.material.gain_us_per_n = 120.0;
            m.material.exponent = 1.1;
            m.spread.node_exponent_log_sd = 0.15;
            m.curvature.sensitivity_form = SensitivityForm::Exponential;
            m.curvature.sensitivity_ce_m1 = 200.0;
            m.readout.inverted = true;
            m.readout.noise_counts = 0.5;
            m.noise.wander = Some(Wander {
                sd_counts: 0.8,
                tau_s: 15.0,
                mode: WanderMode::PerNode,
            });
        }
        "zoo-amp" => {
            m.material.gain_us_per_n = 200.0;
            m.material.exponent = 1.2;
            m.material.r_floor_ohm = 300.0;
            m.spread.node_exponent_log_sd = 0.12;
            m.readout.noise_counts = 1.0;
            m.noise.wander = Some(Wander {
                sd_counts: 2.0,
                tau_s: 40.0,
                mode: WanderMode::Common,
            });
            m.noise.second_wander = Some(Wander {
                sd_counts: 0.7,
                tau_s: 8.0,
                mode: WanderMode::PerNode,
            });
            m.noise.spike_rate_hz = 0.01;
            m.noise.spike_counts = 20.0;
        }
        _ => return None,
    }
    Some(m)
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_preset_is_valid() {
        for n in super::NAMES {
            super::preset(n).expect("known").validate().expect("valid");
        }
        assert!(super::preset("nope").is_none());
    }
}
