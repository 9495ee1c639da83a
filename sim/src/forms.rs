//! Functional-form families ("the zoo"): alternative shapes of the crossing's static law and of
//! the curvature effects, so that calibration methods can be tested on worlds whose laws differ
//! from the default. Every family defaults to the original form (`power`, `current`,
//! `polynomial`), which is computed by exactly the original expressions, so existing models give
//! bit-identical frames.

use serde::{Deserialize, Serialize};

use crate::model::{Curvature, Material};

/// The shape of the crossing's force term `L(F)` in `G = G0 + L(F)` (before the resistance
/// floor). Each law has one shape parameter that `spread.node_exponent_log_sd` varies per node
/// (the node's factor `s_k`, a lognormal draw).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Law {
    /// `L = a F^(n s_k)`: `a` = `material.gain_us_per_n`, `n` = `material.exponent`.
    #[default]
    Power,
    /// `L = k ln(1 + F / (F0 s_k))`: a logarithmic rise, `k` = `material.log_gain_us`,
    /// `F0` = `material.log_f0_n`.
    Log,
    /// `L = gmax F / (F + Fh s_k)`: soft saturation, `gmax` = `material.hyperbolic_gmax_us`,
    /// `Fh` = `material.hyperbolic_half_n` (the force at half of `gmax`).
    Hyperbolic,
}

impl Law {
    pub fn is_power(&self) -> bool {
        *self == Law::Power
    }
}

/// How the force sensitivity `S(kappa)` falls with the mounting curvature `kappa` (1/m).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SensitivityForm {
    /// `S = 1 / (1 + kappa / kappa_s)`, `kappa_s` = `curvature.sensitivity_kappa_s_m1`.
    #[default]
    Current,
    /// `S = 1 / (1 + (kappa / C0)^p)`, `C0` = `curvature.sensitivity_c0_m1`,
    /// `p` = `curvature.sensitivity_exponent` (1 gives the shape of `current`).
    Hyperbolic,
    /// `S = max(0.1, 1 - kappa / Cmax)`, `Cmax` = `curvature.sensitivity_cmax_m1`.
    Linear,
    /// `S = exp(-kappa / Ce)`, `Ce` = `curvature.sensitivity_ce_m1`.
    Exponential,
}

impl SensitivityForm {
    pub fn is_current(&self) -> bool {
        *self == SensitivityForm::Current
    }
}

/// How the unloaded conductance rises with curvature. With `h_k = g1 + q p2(u_k) + l u_k` the
/// node's across-bend shape (m):
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BaselineForm {
    /// `B_k = 1 + kappa h_k + g2 kappa^2`.
    #[default]
    Polynomial,
    /// `B_k = 1 + Cb h_k (1 - exp(-kappa / Cb)) + g2 kappa^2`, `Cb` =
    /// `curvature.baseline_cb_m1`: the same slope at flat, levelling off above `Cb`.
    Exponential,
}

impl BaselineForm {
    pub fn is_polynomial(&self) -> bool {
        *self == BaselineForm::Polynomial
    }
}

/// The law's amplitude (microsiemens, or microsiemens per N^n for `power`) and its force term
/// without the amplitude, for a local load `f` (N) on a node whose shape factor is `shape`.
/// `power` with `shape = 1` is the original `f.max(0).powf(n)` bit for bit.
pub fn force_term(m: &Material, shape: f64, f: f64) -> (f64, f64) {
    let f = f.max(0.0);
    match m.law {
        Law::Power => (m.gain_us_per_n, f.powf(m.exponent * shape)),
        Law::Log => (m.log_gain_us, (f / (m.log_f0_n * shape)).ln_1p()),
        Law::Hyperbolic => (m.hyperbolic_gmax_us, f / (f + m.hyperbolic_half_n * shape)),
    }
}

/// Force-sensitivity factor at curvature `kappa_m1` (1 when flat).
pub fn sensitivity(c: &Curvature, kappa_m1: f64) -> f64 {
    let k = kappa_m1.max(0.0);
    match c.sensitivity_form {
        SensitivityForm::Current => 1.0 / (1.0 + k / c.sensitivity_kappa_s_m1),
        SensitivityForm::Hyperbolic => {
            1.0 / (1.0 + (k / c.sensitivity_c0_m1).powf(c.sensitivity_exponent))
        }
        SensitivityForm::Linear => (1.0 - k / c.sensitivity_cmax_m1).max(0.1),
        SensitivityForm::Exponential => (-k / c.sensitivity_ce_m1).exp(),
    }
}

/// Unloaded-conductance factor of a node whose across-bend shape is `shape_m` (m), at
/// curvature `k` (1/m). `polynomial` is the original expression bit for bit.
pub fn baseline_factor(c: &Curvature, k: f64, shape_m: f64) -> f64 {
    match c.baseline_form {
        BaselineForm::Polynomial => (1.0 + k * shape_m + c.baseline_g2_m2 * k * k).max(0.05),
        BaselineForm::Exponential => {
            let cb = c.baseline_cb_m1;
            (1.0 + cb * shape_m * (1.0 - (-k / cb).exp()) + c.baseline_g2_m2 * k * k).max(0.05)
        }
    }
}

/// Position across the bend of a node at `(x, y)` in (-1, 1)^2 (already mirrored for a
/// flipped mounting), for a rotation of `deg` degrees: the original 90-degree steps, or with
/// `any_angle` the projection `x cos(deg) + y sin(deg)` (which agrees with the steps at their
/// angles and reaches up to sqrt 2 in the corners at 45 degrees).
pub fn across(x: f64, y: f64, deg: u32, any_angle: bool) -> f64 {
    match deg {
        90 => y,
        180 => -x,
        270 => -y,
        0 => x,
        _ if any_angle => {
            let (s, c) = (deg as f64).to_radians().sin_cos();
            x * c + y * s
        }
        _ => x,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn laws_rise_from_zero_and_differ_in_shape() {
        let mut m = Material::default();
        for law in [Law::Power, Law::Log, Law::Hyperbolic] {
            m.law = law;
            let (_, zero) = force_term(&m, 1.0, 0.0);
            assert_eq!(zero, 0.0, "{law:?}");
            let l = |f| force_term(&m, 1.0, f).1;
            assert!(l(1.0) < l(2.0) && l(2.0) < l(8.0), "{law:?} rises");
        }
        // Log and hyperbolic are concave: doubling the force less than doubles the term.
        m.law = Law::Log;
        let l = |m: &Material, f| force_term(m, 1.0, f).1;
        assert!(l(&m, 8.0) < 2.0 * l(&m, 4.0));
        m.law = Law::Hyperbolic;
        assert!(l(&m, 8.0) < 2.0 * l(&m, 4.0));
        assert!(l(&m, 1e6) < 1.0, "saturates at gmax");
        // A larger shape factor: a larger exponent for power (more at F > 1 N), a larger F0 or
        // Fh (less) for the others.
        m.law = Law::Power;
        assert!(force_term(&m, 1.2, 5.0).1 > force_term(&m, 1.0, 5.0).1);
        m.law = Law::Log;
        assert!(force_term(&m, 1.2, 5.0).1 < force_term(&m, 1.0, 5.0).1);
    }

    #[test]
    fn sensitivity_forms_start_at_one_and_fall() {
        let mut c = Curvature::default();
        for form in [
            SensitivityForm::Current,
            SensitivityForm::Hyperbolic,
            SensitivityForm::Linear,
            SensitivityForm::Exponential,
        ] {
            c.sensitivity_form = form;
            assert_eq!(sensitivity(&c, 0.0), 1.0, "{form:?}");
            assert!(sensitivity(&c, 40.0) > sensitivity(&c, 80.0), "{form:?}");
            assert!(sensitivity(&c, 80.0) < 1.0 && sensitivity(&c, 1e4) >= 0.0);
        }
        c.sensitivity_form = SensitivityForm::Linear;
        assert_eq!(sensitivity(&c, 1e4), 0.1, "linear is floored at 0.1");
    }

    #[test]
    fn exponential_baseline_has_the_polynomial_slope_and_levels_off() {
        let mut c = Curvature::default();
        let h = 0.005;
        let poly = |c: &Curvature, k| baseline_factor(c, k, h);
        c.baseline_form = BaselineForm::Exponential;
        let small = 1e-3;
        assert!((baseline_factor(&c, small, h) - 1.0 - small * h).abs() < 1e-9);
        let p = Curvature::default();
        assert!(baseline_factor(&c, 100.0, h) < poly(&p, 100.0));
        assert!(baseline_factor(&c, 1e5, h) <= 1.0 + c.baseline_cb_m1 * h + 1e-12);
    }

    #[test]
    fn any_angle_agrees_with_the_steps_and_turns_continuously() {
        for deg in [0, 90, 180, 270] {
            assert_eq!(across(0.3, -0.7, deg, true), across(0.3, -0.7, deg, false));
        }
        let d45 = across(1.0, 1.0, 45, true);
        assert!((d45 - 2f64.sqrt()).abs() < 1e-12);
        assert_eq!(
            across(0.3, -0.7, 45, false),
            0.3,
            "without any_angle: the 0 degree axis"
        );
    }
}
