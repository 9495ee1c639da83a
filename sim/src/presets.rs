//! Named sensor models. `default` is the plain model; `paper-dataset` adds what separates real
//! sensors and real mountings (build-to-build baseline spread, mounting scatter) and is the model
//! behind the shipped curvature dataset and the demo; `alt` is another parameterisation
//! (stronger nonlinearity, crosstalk, more noise and spread) used only to check that training
//! methods generalize, never to tune them.

use crate::model::SensorModel;

/// Names accepted by [`preset`].
pub const NAMES: [&str; 3] = ["default", "paper-dataset", "alt"];

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
