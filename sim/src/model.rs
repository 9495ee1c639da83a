//! The sensor model's parameters: every one named, with its unit in the name and a documented
//! meaning. A model is plain data (TOML-loadable, `deny_unknown_fields`); optional effect layers
//! are `None` when switched off.

use serde::{Deserialize, Serialize};

use crate::footprint::ContactModel;
use crate::forms::{BaselineForm, Law, SensitivityForm};
use crate::noise::NoiseModel;
use crate::SimError;

/// Defaults of the zoo's parameters, and the predicates that leave them out of the TOML when
/// they hold (so a model without the zoo serializes as before).
macro_rules! zoo_default {
    ($($name:ident: $is:ident = $v:expr;)*) => {
        $(
            const $name: f64 = $v;
            fn $is(v: &f64) -> bool {
                *v == $name
            }
        )*
    };
}

zoo_default! {
    LOG_GAIN_US: is_log_gain_default = 400.0;
    LOG_F0_N: is_log_f0_default = 0.5;
    HYPERBOLIC_GMAX_US: is_gmax_default = 1500.0;
    HYPERBOLIC_HALF_N: is_half_default = 5.0;
    SENS_C0_M1: is_c0_default = 120.0;
    SENS_EXPONENT: is_sens_exponent_default = 1.0;
    SENS_CMAX_M1: is_cmax_default = 200.0;
    SENS_CE_M1: is_ce_default = 150.0;
    BASELINE_CB_M1: is_cb_default = 60.0;
}

fn is_false(v: &bool) -> bool {
    !*v
}

/// What the board reports for each crossing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ReadoutKind {
    /// The paper's board: non-inverting amplifier `Vout = Vref (1 + Rg G)` into the ADC; the
    /// reading rises with force.
    #[default]
    Amplifier,
    /// The crossing's resistance in ohms (`1 / G`), as boards that log a divider ratio times a
    /// reference resistor do; the reading falls with force. Rounded to `resolution_ohm`.
    Resistance,
    /// A voltage divider into the ADC: `code = max_code R / (R + r_ref_ohm)`; falls with force
    /// (or `max_code r_ref_ohm / (R + r_ref_ohm)`, rising, with `divider_rises`).
    Divider,
}

/// The readout electronics. The paper's board (the default) does a row-column scan into a
/// non-inverting amplifier `Vout = Vref (1 + Rg G)` and one ADC; other boards report the
/// resistance or a divider code (`kind`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Readout {
    /// What the reading is: `amplifier` (default), `resistance` or `divider`.
    pub kind: ReadoutKind,
    /// Reference resistor of the divider (ohm; `divider` only).
    pub r_ref_ohm: f64,
    /// Rounding step of a `resistance` reading (ohm; 0 = no rounding).
    pub resolution_ohm: f64,
    /// Reference voltage on the non-inverting inputs and unselected rows (V).
    pub vref_v: f64,
    /// Feedback resistor of each column amplifier (ohm).
    pub rg_ohm: f64,
    /// Output rail of the amplifier (V); `Vout` is clipped to it.
    pub vsat_v: f64,
    /// ADC reference voltage (V): code = round(max_code * Vout / adc_ref_v).
    pub adc_ref_v: f64,
    /// ADC resolution (bits).
    pub adc_bits: u32,
    /// White noise on each reading, one standard deviation (ADC counts, or ohms for
    /// `resistance`), before quantization.
    pub noise_counts: f64,
    /// `divider` only: the crossing sits on the low side of the divider, `code = max_code
    /// r_ref_ohm / (R + r_ref_ohm)`, so the reading rises with force (default false: falls).
    #[serde(skip_serializing_if = "is_false")]
    pub divider_rises: bool,
    /// `amplifier` only: an inverting front end, `reading = max_code - amplifier reading`
    /// (noise included, floored at 0), so the reading falls with force (default false).
    #[serde(skip_serializing_if = "is_false")]
    pub inverted: bool,
}

impl Default for Readout {
    fn default() -> Self {
        Readout {
            kind: ReadoutKind::Amplifier,
            r_ref_ohm: 1000.0,
            resolution_ohm: 1.0,
            vref_v: 0.5,
            rg_ohm: 5600.0,
            vsat_v: 5.0,
            adc_ref_v: 5.0,
            adc_bits: 10,
            noise_counts: 0.5,
            divider_rises: false,
            inverted: false,
        }
    }
}

impl Readout {
    /// Highest ADC code.
    pub fn max_code(&self) -> f64 {
        ((1u64 << self.adc_bits) - 1) as f64
    }
}

/// The Velostat crossing's static law: `G = G0 + a F^n` (or another `law`, see
/// [`Law`]), saturated by a series resistance floor `G_sat = G / (1 + G R_floor)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Material {
    /// Unloaded conductance of one crossing, `G0` (microsiemens).
    pub g0_us: f64,
    /// Force gain `a` of one crossing (microsiemens per N^n).
    pub gain_us_per_n: f64,
    /// Exponent `n` of the power law (dimensionless; 0.9-1.4 on real Velostat).
    pub exponent: f64,
    /// Resistance floor that saturates the crossing at high force (ohm).
    pub r_floor_ohm: f64,
    /// Shape of the force term: `power` (default, `a F^n`), `log` (`k ln(1 + F / F0)`) or
    /// `hyperbolic` (`gmax F / (F + Fh)`).
    #[serde(skip_serializing_if = "Law::is_power")]
    pub law: Law,
    /// `log` law: the gain `k` (microsiemens per unit of `ln(1 + F / F0)`).
    #[serde(skip_serializing_if = "is_log_gain_default")]
    pub log_gain_us: f64,
    /// `log` law: the force scale `F0` (N) at which the rise turns from linear to logarithmic.
    #[serde(skip_serializing_if = "is_log_f0_default")]
    pub log_f0_n: f64,
    /// `hyperbolic` law: the conductance `gmax` approached at high force (microsiemens).
    #[serde(skip_serializing_if = "is_gmax_default")]
    pub hyperbolic_gmax_us: f64,
    /// `hyperbolic` law: the force `Fh` at which the force term reaches half of `gmax` (N).
    #[serde(skip_serializing_if = "is_half_default")]
    pub hyperbolic_half_n: f64,
}

impl Default for Material {
    fn default() -> Self {
        Material {
            g0_us: 25.0,
            gain_us_per_n: 150.0,
            exponent: 1.0,
            r_floor_ohm: 400.0,
            law: Law::Power,
            log_gain_us: LOG_GAIN_US,
            log_f0_n: LOG_F0_N,
            hyperbolic_gmax_us: HYPERBOLIC_GMAX_US,
            hyperbolic_half_n: HYPERBOLIC_HALF_N,
        }
    }
}

/// Part-to-part spread, drawn once per seed: lognormal factors (standard deviation of the
/// natural log) on each crossing's gain and unloaded conductance, and on the whole build.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Spread {
    /// Per-crossing gain spread (log sd; 0.06 = about +-6 %).
    pub node_gain_log_sd: f64,
    /// Per-crossing unloaded-conductance spread (log sd).
    pub node_g0_log_sd: f64,
    /// Whole-build gain spread (log sd), one draw per seed.
    pub build_gain_log_sd: f64,
    /// Whole-build unloaded-conductance spread (log sd), one draw per seed; builds differ 2-3x.
    pub build_g0_log_sd: f64,
    /// Seed of the spread draws: the identity of one physical sensor. When absent the
    /// scenario's seed is used, so every scenario seed is another sensor.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub build_seed: Option<u64>,
    /// Per-crossing spread of the law's shape parameter (log sd, drawn once per build like the
    /// others): the exponent `n` of `power`, `F0` of `log`, `Fh` of `hyperbolic` is multiplied
    /// by the node's lognormal factor. 0 (default) = none.
    #[serde(skip_serializing_if = "is_zero")]
    pub node_exponent_log_sd: f64,
}

impl Default for Spread {
    fn default() -> Self {
        Spread {
            node_gain_log_sd: 0.06,
            node_g0_log_sd: 0.06,
            build_gain_log_sd: 0.0,
            build_g0_log_sd: 0.0,
            build_seed: None,
            node_exponent_log_sd: 0.0,
        }
    }
}

/// How the mounting curvature `kappa` changes the crossing. The force gain falls as
/// `1 / (1 + kappa / kappa_s)`; the unloaded conductance changes by
/// `G0 (1 + kappa (g1 + q p2(u) + l u) + g2 kappa^2)`, where `u` in (-1, 1) is the crossing's
/// position across the bend (which sensor axis that is, and its sign, follow the sensor's rotation
/// and flip) and `p2(u) = u^2 - mean(u^2)`. `g1` differs between face-up and flipped mounting
/// because the two thread layers are not symmetric. `sensitivity_form` and `baseline_form`
/// select other shapes of the two (see [`SensitivityForm`] and [`BaselineForm`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Curvature {
    /// Curvature at which force sensitivity has halved, `kappa_s` (1/m).
    pub sensitivity_kappa_s_m1: f64,
    /// Uniform baseline change per unit curvature, face up, `g1` (m).
    pub baseline_g1_m: f64,
    /// Uniform baseline change per unit curvature, flipped (m).
    pub baseline_g1_flipped_m: f64,
    /// Quadratic baseline change `g2` (m^2).
    pub baseline_g2_m2: f64,
    /// Weight `q` of the across-bend quadratic pattern (m).
    pub pattern_quad_m: f64,
    /// Weight `l` of the across-bend linear pattern (m).
    pub pattern_lin_m: f64,
    /// Relative scatter (1 sd) of the curvature the sheet actually takes at each mounting: how
    /// well it conforms to the fixture (0 = perfectly).
    pub mount_curvature_scatter: f64,
    /// Per-node baseline scatter at each mounting (log sd): tape tension, thread seating.
    pub mount_baseline_log_sd: f64,
    /// Shape of the sensitivity's fall: `current` (default, `1 / (1 + kappa / kappa_s)`),
    /// `hyperbolic`, `linear` or `exponential`.
    #[serde(skip_serializing_if = "SensitivityForm::is_current")]
    pub sensitivity_form: SensitivityForm,
    /// `hyperbolic` sensitivity: the curvature `C0` at which it has halved (1/m).
    #[serde(skip_serializing_if = "is_c0_default")]
    pub sensitivity_c0_m1: f64,
    /// `hyperbolic` sensitivity: the exponent `p` of `1 / (1 + (kappa / C0)^p)`
    /// (dimensionless, 0.2..=5; 1 = the shape of `current`).
    #[serde(skip_serializing_if = "is_sens_exponent_default")]
    pub sensitivity_exponent: f64,
    /// `linear` sensitivity: the curvature `Cmax` at which `1 - kappa / Cmax` would reach 0
    /// (1/m); the factor is floored at 0.1.
    #[serde(skip_serializing_if = "is_cmax_default")]
    pub sensitivity_cmax_m1: f64,
    /// `exponential` sensitivity: the curvature `Ce` of `exp(-kappa / Ce)` (1/m).
    #[serde(skip_serializing_if = "is_ce_default")]
    pub sensitivity_ce_m1: f64,
    /// Shape of the baseline's rise: `polynomial` (default) or `exponential`.
    #[serde(skip_serializing_if = "BaselineForm::is_polynomial")]
    pub baseline_form: BaselineForm,
    /// `exponential` baseline: the curvature `Cb` above which the rise levels off (1/m).
    #[serde(skip_serializing_if = "is_cb_default")]
    pub baseline_cb_m1: f64,
    /// Accept mountings at any whole-degree rotation 0..360 (default false: 0, 90, 180, 270);
    /// the across-bend position then turns continuously, `u = x cos(rot) + y sin(rot)`.
    #[serde(skip_serializing_if = "is_false")]
    pub any_angle: bool,
}

impl Default for Curvature {
    fn default() -> Self {
        Curvature {
            sensitivity_kappa_s_m1: 120.0,
            baseline_g1_m: 0.005,
            baseline_g1_flipped_m: 0.003,
            baseline_g2_m2: 0.0,
            pattern_quad_m: 0.004,
            pattern_lin_m: 0.002,
            mount_curvature_scatter: 0.0,
            mount_baseline_log_sd: 0.0,
            sensitivity_form: SensitivityForm::Current,
            sensitivity_c0_m1: SENS_C0_M1,
            sensitivity_exponent: SENS_EXPONENT,
            sensitivity_cmax_m1: SENS_CMAX_M1,
            sensitivity_ce_m1: SENS_CE_M1,
            baseline_form: BaselineForm::Polynomial,
            baseline_cb_m1: BASELINE_CB_M1,
            any_angle: false,
        }
    }
}

/// Creep as a Prony series on the local load: `F_eff = F + sum_k c_k lowpass_{tau_k}(F)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Creep {
    /// Relative amplitude of each term (fraction of the load).
    pub amplitudes: Vec<f64>,
    /// Time constant of each term (s).
    pub tau_s: Vec<f64>,
}

impl Default for Creep {
    fn default() -> Self {
        Creep {
            amplitudes: vec![0.03, 0.03],
            tau_s: vec![3.0, 100.0],
        }
    }
}

/// Rate-independent hysteresis on the local load, in one of two forms:
/// - a Prandtl-Ishlinskii sum of play operators, `F_eff = (1 - w) F + w mean_r play_r(F)`
///   (`thresholds_n`; return-point memory: a reload retraces the branch it left);
/// - a Bouc-Wen state, `F_eff = F + w z`, `dz = dF - (|dF| z + dF |z|) / (2 z_s)`
///   (`bouc_wen_saturation_n` = `z_s`; no return-point memory, smooth saturation), or with
///   an exponent `n`, `dz = dF - (|dF| z + dF |z|) |z|^(n-1) / (2 z_s^n)` (a sharper knee for
///   `n > 1`). Its input is the total force through a play of half-width `input_deadband_n`,
///   which keeps a noisy driven force from ratcheting the state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Hysteresis {
    /// Share of the load that passes through the play operators, `w` (fraction), or the
    /// Bouc-Wen state's weight. Negative weights turn the loop around (the loading branch above
    /// the unloading one).
    pub weight: f64,
    /// Half-widths of the play operators (N of local load); empty with the Bouc-Wen form.
    #[serde(default)]
    pub thresholds_n: Vec<f64>,
    /// Bouc-Wen form: the state's saturation `z_s` (N of local load).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bouc_wen_saturation_n: Option<f64>,
    /// Bouc-Wen form: the exponent `n` (default 1).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub bouc_wen_exponent: f64,
    /// Bouc-Wen form: half-width (N of total force) of the play that takes load-cell noise out
    /// of the force before the state sees it (0: none).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub input_deadband_n: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn one() -> f64 {
    1.0
}

fn is_one(v: &f64) -> bool {
    *v == 1.0
}

impl Default for Hysteresis {
    fn default() -> Self {
        Hysteresis {
            weight: 0.1,
            thresholds_n: vec![0.1, 0.3, 0.6, 1.0],
            bouc_wen_saturation_n: None,
            bouc_wen_exponent: 1.0,
            input_deadband_n: 0.0,
        }
    }
}

/// Thermal drift: conductance times `1 + alpha (T_s - T0)`, where the sensor temperature `T_s`
/// follows the ambient temperature through a first-order lag.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ThermalDrift {
    /// Temperature coefficient of conductance (1/K).
    pub alpha_per_k: f64,
    /// Thermal time constant of the sensor (s).
    pub tau_s: f64,
    /// Temperature at which the model's conductances hold (degC).
    pub t0_c: f64,
}

impl Default for ThermalDrift {
    fn default() -> Self {
        ThermalDrift {
            alpha_per_k: -0.003,
            tau_s: 120.0,
            t0_c: 25.0,
        }
    }
}

/// Crosstalk of the row-column matrix, solved exactly per row: row switches with on-resistance
/// `Rs` and column amplifiers with input offsets drawn uniformly in `+-vos_max`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Crosstalk {
    /// On-resistance of a row switch plus thread (ohm).
    pub rs_ohm: f64,
    /// Largest op-amp input offset (V).
    pub vos_max_v: f64,
}

impl Default for Crosstalk {
    fn default() -> Self {
        Crosstalk {
            rs_ohm: 80.0,
            vos_max_v: 0.004,
        }
    }
}

/// Scan skew: node `k` (row-major scan order) is sampled `k * dt` after the frame starts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ScanSkew {
    /// Time between two consecutive node samples (s).
    pub dt_node_s: f64,
}

impl Default for ScanSkew {
    fn default() -> Self {
        ScanSkew { dt_node_s: 0.0005 }
    }
}

/// Measured per-crossing factors (for example fitted to a recording by taxel-simcheck): when
/// given, they replace the random part-to-part draws of `spread`. Row-major, `rows * cols` each.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NodeFactors {
    /// Multiplier of `material.g0_us` per crossing.
    pub g0: Vec<f64>,
    /// Multiplier of `material.gain_us_per_n` per crossing.
    pub gain: Vec<f64>,
    /// Share of a driven (recorded) force each crossing carries, relative to the most loaded
    /// one (1). Only driven mode uses it (a scenario has its own contact map); default 1 for
    /// every crossing. It matters where an effect acts on the local load, not on the total:
    /// hysteresis half-widths are in newtons of local load.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub load_share: Option<Vec<f64>>,
}

/// The whole sensor model: geometry, readout, static law, spread, curvature and the optional
/// effect layers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SensorModel {
    /// Number of rows (1..=32).
    pub rows: usize,
    /// Number of columns (1..=32).
    pub cols: usize,
    pub readout: Readout,
    pub material: Material,
    pub spread: Spread,
    /// Measured per-crossing factors replacing the spread draws (None = draw them).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nodes: Option<NodeFactors>,
    pub curvature: Curvature,
    /// Effect layers, each `None` (off) unless given.
    pub creep: Option<Creep>,
    pub hysteresis: Option<Hysteresis>,
    pub thermal_drift: Option<ThermalDrift>,
    pub crosstalk: Option<Crosstalk>,
    pub scan_skew: Option<ScanSkew>,
    /// How the indenter's force spreads over the crossings (default: the scenario's rectangle).
    #[serde(skip_serializing_if = "ContactModel::is_default")]
    pub contact: ContactModel,
    /// Wander and spikes on the reading (default: none).
    #[serde(skip_serializing_if = "NoiseModel::is_default")]
    pub noise: NoiseModel,
}

impl Default for SensorModel {
    fn default() -> Self {
        SensorModel {
            rows: 4,
            cols: 4,
            readout: Readout::default(),
            material: Material::default(),
            spread: Spread::default(),
            nodes: None,
            curvature: Curvature::default(),
            creep: None,
            hysteresis: None,
            thermal_drift: None,
            crosstalk: None,
            scan_skew: None,
            contact: ContactModel::default(),
            noise: NoiseModel::default(),
        }
    }
}

fn check(ok: bool, what: &str) -> Result<(), SimError> {
    if ok {
        Ok(())
    } else {
        Err(SimError::Invalid(what.to_string()))
    }
}

fn finite_nonneg(x: f64) -> bool {
    x.is_finite() && x >= 0.0
}

impl SensorModel {
    /// Parses a model from TOML and validates it.
    pub fn from_toml_str(text: &str) -> Result<SensorModel, SimError> {
        let m: SensorModel = toml::from_str(text).map_err(|e| SimError::Parse(e.to_string()))?;
        m.validate()?;
        Ok(m)
    }

    /// The model as TOML.
    pub fn to_toml_string(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_default()
    }

    /// Checks every parameter's range; the message names the parameter.
    pub fn validate(&self) -> Result<(), SimError> {
        self.validate_readout_and_material()?;
        self.validate_zoo()?;
        self.validate_nodes()?;
        self.validate_spread_and_curvature()?;
        self.validate_effects()
    }

    /// The array, the readout and the material.
    fn validate_readout_and_material(&self) -> Result<(), SimError> {
        check(
            (1..=32).contains(&self.rows) && (1..=32).contains(&self.cols),
            "rows and cols must be 1..=32",
        )?;
        let r = &self.readout;
        check(
            r.vref_v.is_finite() && r.vref_v > 0.0,
            "readout.vref_v must be > 0",
        )?;
        check(
            r.rg_ohm.is_finite() && r.rg_ohm > 0.0,
            "readout.rg_ohm must be > 0",
        )?;
        check(
            r.vsat_v.is_finite() && r.vsat_v > r.vref_v,
            "readout.vsat_v must exceed vref_v",
        )?;
        check(
            r.adc_ref_v.is_finite() && r.adc_ref_v > 0.0,
            "readout.adc_ref_v must be > 0",
        )?;
        check(
            (1..=24).contains(&r.adc_bits),
            "readout.adc_bits must be 1..=24",
        )?;
        check(
            finite_nonneg(r.noise_counts),
            "readout.noise_counts must be >= 0",
        )?;
        let m = &self.material;
        check(
            m.g0_us.is_finite() && m.g0_us > 0.0,
            "material.g0_us must be > 0",
        )?;
        check(
            finite_nonneg(m.gain_us_per_n),
            "material.gain_us_per_n must be >= 0",
        )?;
        check(
            m.exponent.is_finite() && (0.2..=3.0).contains(&m.exponent),
            "material.exponent must be in 0.2..=3",
        )?;
        check(
            finite_nonneg(m.r_floor_ohm),
            "material.r_floor_ohm must be >= 0",
        )?;
        check(
            r.r_ref_ohm.is_finite() && r.r_ref_ohm > 0.0,
            "readout.r_ref_ohm must be > 0",
        )?;
        check(
            finite_nonneg(r.resolution_ohm),
            "readout.resolution_ohm must be >= 0",
        )?;
        Ok(())
    }

    /// Per-node factors, when given: one per node, finite and non-negative.
    fn validate_nodes(&self) -> Result<(), SimError> {
        if let Some(nf) = &self.nodes {
            let n = self.rows * self.cols;
            check(
                nf.g0.len() == n && nf.gain.len() == n,
                &format!("nodes.g0 and nodes.gain must have rows * cols = {n} entries"),
            )?;
            check(
                nf.g0.iter().chain(&nf.gain).all(|v| finite_nonneg(*v)),
                "nodes.g0 and nodes.gain must be finite and >= 0",
            )?;
            if let Some(share) = &nf.load_share {
                check(
                    share.len() == n && share.iter().all(|v| finite_nonneg(*v)),
                    &format!(
                        "nodes.load_share must have rows * cols = {n} entries, finite and >= 0"
                    ),
                )?;
            }
        }
        Ok(())
    }

    /// The build and node spread, and the curvature response.
    fn validate_spread_and_curvature(&self) -> Result<(), SimError> {
        let s = &self.spread;
        for (v, name) in [
            (s.node_gain_log_sd, "spread.node_gain_log_sd"),
            (s.node_g0_log_sd, "spread.node_g0_log_sd"),
            (s.build_gain_log_sd, "spread.build_gain_log_sd"),
            (s.build_g0_log_sd, "spread.build_g0_log_sd"),
        ] {
            check(
                finite_nonneg(v) && v <= 2.0,
                &format!("{name} must be in 0..=2"),
            )?;
        }
        let c = &self.curvature;
        check(
            c.sensitivity_kappa_s_m1.is_finite() && c.sensitivity_kappa_s_m1 > 0.0,
            "curvature.sensitivity_kappa_s_m1 must be > 0",
        )?;
        for (v, name) in [
            (c.baseline_g1_m, "curvature.baseline_g1_m"),
            (c.baseline_g1_flipped_m, "curvature.baseline_g1_flipped_m"),
            (c.baseline_g2_m2, "curvature.baseline_g2_m2"),
            (c.pattern_quad_m, "curvature.pattern_quad_m"),
            (c.pattern_lin_m, "curvature.pattern_lin_m"),
        ] {
            check(v.is_finite(), &format!("{name} must be finite"))?;
        }
        check(
            finite_nonneg(c.mount_curvature_scatter) && c.mount_curvature_scatter <= 1.0,
            "curvature.mount_curvature_scatter must be in 0..=1",
        )?;
        check(
            finite_nonneg(c.mount_baseline_log_sd) && c.mount_baseline_log_sd <= 1.0,
            "curvature.mount_baseline_log_sd must be in 0..=1",
        )?;
        Ok(())
    }

    /// The effect layers: creep, hysteresis, thermal drift, crosstalk, scan skew.
    fn validate_effects(&self) -> Result<(), SimError> {
        if let Some(cr) = &self.creep {
            check(
                cr.amplitudes.len() == cr.tau_s.len() && !cr.tau_s.is_empty(),
                "creep.amplitudes and creep.tau_s must have the same, non-zero length",
            )?;
            check(
                cr.amplitudes.iter().all(|a| a.is_finite() && a.abs() < 1.0),
                "creep.amplitudes must be in (-1, 1)",
            )?;
            check(
                cr.tau_s.iter().all(|t| t.is_finite() && *t > 0.0),
                "creep.tau_s must be > 0",
            )?;
        }
        if let Some(h) = &self.hysteresis {
            check(
                h.weight.is_finite() && (-1.0..=1.0).contains(&h.weight),
                "hysteresis.weight must be in -1..=1",
            )?;
            match h.bouc_wen_saturation_n {
                None => check(
                    !h.thresholds_n.is_empty() && h.thresholds_n.iter().all(|r| finite_nonneg(*r)),
                    "hysteresis.thresholds_n must be non-empty and >= 0",
                )?,
                Some(zs) => {
                    check(
                        zs.is_finite() && zs > 0.0,
                        "hysteresis.bouc_wen_saturation_n must be > 0",
                    )?;
                    check(
                        h.thresholds_n.is_empty(),
                        "hysteresis: thresholds_n (play operators) and bouc_wen_saturation_n (Bouc-Wen) exclude each other",
                    )?;
                }
            }
            check(
                h.bouc_wen_exponent.is_finite() && (0.1..=10.0).contains(&h.bouc_wen_exponent),
                "hysteresis.bouc_wen_exponent must be in 0.1..=10",
            )?;
            check(
                finite_nonneg(h.input_deadband_n),
                "hysteresis.input_deadband_n must be >= 0",
            )?;
        }
        if let Some(t) = &self.thermal_drift {
            check(
                t.alpha_per_k.is_finite() && t.alpha_per_k.abs() < 0.1,
                "thermal_drift.alpha_per_k must be in (-0.1, 0.1)",
            )?;
            check(
                t.tau_s.is_finite() && t.tau_s > 0.0,
                "thermal_drift.tau_s must be > 0",
            )?;
            check(t.t0_c.is_finite(), "thermal_drift.t0_c must be finite")?;
        }
        if let Some(x) = &self.crosstalk {
            check(finite_nonneg(x.rs_ohm), "crosstalk.rs_ohm must be >= 0")?;
            check(
                finite_nonneg(x.vos_max_v),
                "crosstalk.vos_max_v must be >= 0",
            )?;
        }
        if let Some(s) = &self.scan_skew {
            check(
                finite_nonneg(s.dt_node_s),
                "scan_skew.dt_node_s must be >= 0",
            )?;
        }
        Ok(())
    }

    /// Checks the parameters of the functional-form families (the zoo).
    fn validate_zoo(&self) -> Result<(), SimError> {
        let r = &self.readout;
        check(
            !r.divider_rises || r.kind == crate::ReadoutKind::Divider,
            "readout.divider_rises needs readout.kind = \"divider\"",
        )?;
        check(
            !r.inverted || r.kind == crate::ReadoutKind::Amplifier,
            "readout.inverted needs readout.kind = \"amplifier\"",
        )?;
        let m = &self.material;
        check(
            finite_nonneg(m.log_gain_us),
            "material.log_gain_us must be >= 0",
        )?;
        check(
            m.log_f0_n.is_finite() && m.log_f0_n > 0.0,
            "material.log_f0_n must be > 0",
        )?;
        check(
            finite_nonneg(m.hyperbolic_gmax_us),
            "material.hyperbolic_gmax_us must be >= 0",
        )?;
        check(
            m.hyperbolic_half_n.is_finite() && m.hyperbolic_half_n > 0.0,
            "material.hyperbolic_half_n must be > 0",
        )?;
        check(
            finite_nonneg(self.spread.node_exponent_log_sd)
                && self.spread.node_exponent_log_sd <= 1.0,
            "spread.node_exponent_log_sd must be in 0..=1",
        )?;
        let c = &self.curvature;
        for (v, name) in [
            (c.sensitivity_c0_m1, "curvature.sensitivity_c0_m1"),
            (c.sensitivity_cmax_m1, "curvature.sensitivity_cmax_m1"),
            (c.sensitivity_ce_m1, "curvature.sensitivity_ce_m1"),
            (c.baseline_cb_m1, "curvature.baseline_cb_m1"),
        ] {
            check(v.is_finite() && v > 0.0, &format!("{name} must be > 0"))?;
        }
        check(
            c.sensitivity_exponent.is_finite() && (0.2..=5.0).contains(&c.sensitivity_exponent),
            "curvature.sensitivity_exponent must be in 0.2..=5",
        )?;
        self.contact.validate()?;
        self.noise.validate()
    }
}
