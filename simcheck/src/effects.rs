//! The effect library's configuration: which effects a model holds and their global
//! parameters (the per-node ones are solved inside each evaluation, see [`crate::model`]).

use crate::law::Law;

/// The effects the tool can name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum EffectKind {
    CurvatureBaseline,
    CurvatureSensitivity,
    Saturation,
    Creep,
    Hysteresis,
    ThermalDrift,
    Crosstalk,
    ScanSkew,
}

impl EffectKind {
    pub const ALL: [EffectKind; 8] = [
        EffectKind::CurvatureBaseline,
        EffectKind::CurvatureSensitivity,
        EffectKind::Saturation,
        EffectKind::Creep,
        EffectKind::Hysteresis,
        EffectKind::ThermalDrift,
        EffectKind::Crosstalk,
        EffectKind::ScanSkew,
    ];

    pub fn name(self) -> &'static str {
        match self {
            EffectKind::CurvatureBaseline => "curvature_baseline",
            EffectKind::CurvatureSensitivity => "curvature_sensitivity",
            EffectKind::Saturation => "saturation",
            EffectKind::Creep => "creep",
            EffectKind::Hysteresis => "hysteresis",
            EffectKind::ThermalDrift => "thermal_drift",
            EffectKind::Crosstalk => "crosstalk",
            EffectKind::ScanSkew => "scan_skew",
        }
    }
}

/// Thermal drift: from the recorded temperature, or a latent common-mode factor when the
/// recording has no temperature column.
#[derive(Debug, Clone, PartialEq)]
pub enum Thermal {
    /// `m = 1 + alpha (T_s - t0)`, `T_s` the temperature low-passed with `tau_s`.
    Recorded { alpha_per_k: f64, tau_s: f64 },
    /// `m(t)` piecewise linear through `values` at `knots_s`, fitted with the nodes.
    Latent { knots_s: Vec<f64>, values: Vec<f64> },
}

/// Global parameters of the forward model; `None` = effect absent.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// The static law: the power law `a_k L^n` with this exponent, or a monotone spline per
    /// node (see [`crate::law`]; the exponent is then not used).
    pub law: Law,
    /// With the power law: instead of `L^n`, one monotone shape every node shares, `S(L) =
    /// sum_j exp(w_j) Phi_j(L)` on the spline's basis (see [`crate::law`]), `w_0 = 0` (each
    /// node's gain carries the scale); these are the `w_j`. A static law of any smooth
    /// increasing form for `m - 1` global parameters, where the spline per node pays `m - 1`
    /// per node.
    pub law_shape: Option<Vec<f64>>,
    pub exponent: f64,
    /// Resistance floor (ohm); used when `sat_in_base` or the saturation effect is on.
    pub r_floor_ohm: f64,
    pub sat_in_base: bool,
    pub saturation: bool,
    /// Creep as two or three Prony terms `(c, tau_s)`: `L + sum c lowpass_tau(L)` (fast and
    /// slow, and a middle one when the criterion pays for it: log-time creep spans decades).
    /// The amplitudes are
    /// non-negative (under a held force the sensor's deformation, and so its conductance, only
    /// grows) and each `tau` lies within `Context::creep_tau_min..=creep_tau_max`.
    pub creep: Option<Vec<(f64, f64)>>,
    /// Creep that stays with the load (`L = F (1 + sum c lowpass_tau(on))`, `on` = 1 while the
    /// force is above 5 % of its peak): it grows under a held load and is gone as the load is,
    /// with no recovery tail, where the Prony form above (linear viscoelastic superposition)
    /// recovers with the same time constants after unloading.
    pub creep_under_load: bool,
    /// With `creep_under_load`: creep that grows with the load's level, not only with the load
    /// being on (`L = F (1 + sum c lowpass_tau(F / F_max))`, `F_max` the recording's peak): a
    /// press to half the peak creeps half as much, relative to its load, as one to the peak
    /// (the creep compliance of a polymer grows with the stress: nonlinear viscoelasticity).
    /// The states recover with their own time constants after unloading, unseen at rest (the
    /// factor multiplies the load) but carried into the next press.
    pub creep_level: bool,
    /// Creep that recovers more slowly (or faster) than it grows: while a term's state falls
    /// (the load, or the load being on, has dropped below it) its time constant is this many
    /// times its growth's (1: linear viscoelastic recovery with the same time constants; a
    /// polymer's creep often recovers more slowly than it set in).
    pub creep_recovery: f64,
    /// Hysteresis: half-width `r` (N) of the play operators; the amplitudes are per node.
    pub hysteresis: Option<f64>,
    /// Hysteresis loop shape: the gap is `gap_r + mix gap_4r` (0: sharp corners; larger:
    /// rounder loops). One global number, so each node pays for one amplitude only.
    pub hyst_mix: f64,
    /// Hysteresis in the load path, as the simulator and the material have it: each node's load
    /// becomes `F + share gap_k(F)` before the force law, where `gap_k` has the half-widths
    /// scaled to the node's share of the load (`Context::load_scale`: a node carrying a tenth
    /// of the load needs ten times the total force to cross the same local play); one global
    /// share and no per-node amplitude. `None`: the additive form above.
    pub hyst_share: Option<f64>,
    /// In-load hysteresis as a Bouc-Wen state instead of the play operators: `F + share z_k`,
    /// `dz = du - (|du| z + du |z|) / (2 r)` (exponent `hyst_bw_n` = 1) on the node's own load
    /// `u = F / load_scale` (`r`: the state's saturation, in newtons of the most loaded node's
    /// load). Unlike the plays it has no return-point memory: a small reversal moves it at
    /// once and a reload does not retrace, and the loop saturates smoothly. Its input is the
    /// recorded force through a play of the force noise's width (`Context::force_deadband`):
    /// without memory the state would otherwise ratchet on the load cell's noise.
    pub hyst_bouc_wen: bool,
    /// The Bouc-Wen state's exponent `n` (1: the classic exponential approach to saturation;
    /// larger: a sharper knee): `dz = du - (|du| z + du |z|) |z|^(n-1) / (2 r^n)`.
    pub hyst_bw_n: f64,
    /// The Bouc-Wen state's asymmetry `a` in -0.9..=0.9 (0: the symmetric loop):
    /// `dz = du - ((1 + a) |du| z + (1 - a) du |z|) |z|^(n-1) / (2 r^n)`, so the loop still
    /// saturates at `r` while loading and unloading approach it at different rates (beta and
    /// gamma of the textbook form, `beta + gamma = 1`).
    pub hyst_bw_asym: f64,
    /// The additive Bouc-Wen form (`hyst_bouc_wen` without `hyst_share`, see
    /// [`crate::forms::bouc_wen_gap`]): the state at the recording's start as a fraction of its
    /// saturation, -1..=1 (0: the virgin state; -1: last unloaded from a large load). A
    /// recording starts with whatever history the sensor had.
    pub hyst_bw_z0: f64,
    /// The additive Bouc-Wen form with a third amplitude per node, on `z u^2` (`u = F /
    /// F_max`), beside `z` and `z u`: how each node's loop changes with the load as a
    /// quadratic (see [`crate::forms::bouc_wen_gap`]). Not a form of its own but each additive
    /// Bouc-Wen form's twin: held out only when that form wins a round's test, and kept only
    /// when the criterion prefers it (see `Selection::best_variant`).
    pub hyst_bw_quad: bool,
    /// With the additive Bouc-Wen: a remnant, each node's own function of the largest force so
    /// far ([`REMNANT_RAMPS`] ramps, one amplitude each per node). A first load to a new
    /// level leaves the reading at rest raised for good (the Mullins effect of a filled
    /// polymer, why piezoresistive sensors are pre-conditioned); a loop alone returns to its
    /// rest level.
    pub hyst_remnant: bool,
    /// Hysteresis as a set: each node's reading raised for good by its own function of the
    /// largest force so far, `M` (the Mullins effect of a filled polymer, as
    /// [`Config::hyst_remnant`]). The function is piecewise linear between the levels `M` held
    /// for a while (see [`crate::set::levels`]), one amplitude per level and node: a node's set
    /// may be full after the first press (a node that carries much of the load) or come only
    /// with the largest (a node at the edge of the contact). Alone (`hysteresis` is `None`) or
    /// with a loop: a set is tested alone first, and a loop on top of it in a later round (or
    /// the other way round).
    pub hyst_set: bool,
    /// The set's levels (N of the total force, rising; see [`crate::set::levels`]).
    pub set_levels: Vec<f64>,
    /// In-load hysteresis as a Preisach model instead (see [`crate::preisach`]): relays on the
    /// node's own load, half-widths around `hysteresis` (N), centres around `preis_mu` (N)
    /// with sd `preis_sigma` (N); the share is `hyst_share`.
    pub hyst_preisach: bool,
    pub preis_mu: f64,
    pub preis_sigma: f64,
    pub thermal: Option<Thermal>,
    /// Recorded thermal drift acting on the force term only (the sensitivity), not on the
    /// unloaded conductance.
    pub thermal_gain_only: bool,
    /// Curvature sensitivity: `kappa_s` (1/m) with a curvature column, else `beta` (per unit
    /// log-baseline shift of the trial).
    pub curv_sens: Option<f64>,
    /// Linear form `1 - kappa / v` (or `1 - beta d`) instead of `1 / (1 + kappa / v)`.
    pub curv_linear: bool,
    /// Curvature sensitivity as one factor per trial (any loss, monotone or not, of each
    /// mounting's sensitivity), fitted with the nodes; without a curvature column.
    pub curv_trials: Option<Vec<f64>>,
    /// With `Some(n)` (the nodes), `curv_trials` holds one factor per trial and node (trial
    /// `j`, node `k` at `j n + k`): each mounting's sensitivity lost or gained node by node, as
    /// when the contact's footprint moves with the mounting and every node's share of the load
    /// changes.
    pub curv_per_node: Option<usize>,
    pub curv_base: bool,
    /// Row crosstalk: switch + thread resistance (ohm).
    pub crosstalk: Option<f64>,
    /// Scan skew: time between two node samples (s).
    pub scan_skew: Option<f64>,
    /// Row-switch settling (s): the first node of each row lags its input by this much more
    /// (part of scan_skew; 0 when absent).
    pub scan_settle: f64,
    /// Scan skew's placebo: every node shifted in time alike (by the middle node's shift), no
    /// row settling. Held out only against a scan skew (`selection/scan_placebo.rs`); never
    /// joins a model.
    pub scan_uniform: bool,
}

impl Config {
    pub fn base(exponent: f64, r_floor_ohm: f64) -> Config {
        Config {
            law: Law::Power,
            law_shape: None,
            exponent,
            r_floor_ohm,
            sat_in_base: r_floor_ohm > 0.0,
            saturation: false,
            creep: None,
            creep_under_load: false,
            creep_level: false,
            creep_recovery: 1.0,
            hysteresis: None,
            hyst_mix: 0.0,
            hyst_share: None,
            hyst_bouc_wen: false,
            hyst_bw_n: 1.0,
            hyst_bw_asym: 0.0,
            hyst_bw_z0: 0.0,
            hyst_bw_quad: false,
            hyst_preisach: false,
            hyst_remnant: false,
            hyst_set: false,
            set_levels: Vec::new(),
            preis_mu: 0.0,
            preis_sigma: 1.0,
            thermal: None,
            thermal_gain_only: false,
            curv_sens: None,
            curv_linear: false,
            curv_trials: None,
            curv_per_node: None,
            curv_base: false,
            crosstalk: None,
            scan_skew: None,
            scan_uniform: false,
            scan_settle: 0.0,
        }
    }

    pub fn has(&self, e: EffectKind) -> bool {
        match e {
            EffectKind::CurvatureBaseline => self.curv_base,
            EffectKind::CurvatureSensitivity => {
                self.curv_sens.is_some() || self.curv_trials.is_some()
            }
            EffectKind::Saturation => self.saturation,
            EffectKind::Creep => self.creep.is_some(),
            EffectKind::Hysteresis => self.hysteresis.is_some() || self.hyst_set,
            EffectKind::ThermalDrift => self.thermal.is_some(),
            EffectKind::Crosstalk => self.crosstalk.is_some(),
            EffectKind::ScanSkew => self.scan_skew.is_some(),
        }
    }

    /// Whether the model holds a state from before the recording that only its first
    /// seconds show: the largest load so far (a set or a remnant, see [`crate::set`]), or the
    /// additive Bouc-Wen state's start ([`Config::hyst_bw_z0`], fitted). A fold whose
    /// training blocks all come after the first press never sees it (see
    /// [`crate::context::Context::virgin_rest_shared`]); a set or a remnant always moves the
    /// selection to folds that share that rest, the start state when they predict better
    /// (`Selection::move_folds_if_better`).
    pub fn remembers_the_start(&self) -> bool {
        let bw_start = self.hysteresis.is_some() && self.hyst_bouc_wen && self.hyst_share.is_none();
        self.hyst_set || self.hyst_remnant || bw_start
    }

    /// Whether effect `e` can still be added: it is not in, or it is hysteresis with a loop
    /// but no set or a set but no loop (see [`Config::hyst_set`]).
    pub fn open_to(&self, e: EffectKind) -> bool {
        !self.has(e)
            || (e == EffectKind::Hysteresis && (self.hysteresis.is_some() != self.hyst_set))
    }

    pub fn without(&self, e: EffectKind) -> Config {
        let mut c = self.clone();
        match e {
            EffectKind::CurvatureBaseline => c.curv_base = false,
            EffectKind::CurvatureSensitivity => {
                c.curv_sens = None;
                c.curv_trials = None;
                c.curv_per_node = None;
            }
            EffectKind::Saturation => {
                c.saturation = false;
                if !c.sat_in_base {
                    c.r_floor_ohm = 0.0;
                }
            }
            EffectKind::Creep => {
                c.creep = None;
                c.creep_under_load = false;
                c.creep_level = false;
                c.creep_recovery = 1.0;
            }
            EffectKind::Hysteresis => {
                c.hysteresis = None;
                c.hyst_share = None;
                c.hyst_bouc_wen = false;
                c.hyst_bw_n = 1.0;
                c.hyst_bw_asym = 0.0;
                c.hyst_bw_z0 = 0.0;
                c.hyst_bw_quad = false;
                c.hyst_preisach = false;
                c.hyst_remnant = false;
                c.hyst_set = false;
                c.set_levels = Vec::new();
            }
            EffectKind::ThermalDrift => {
                c.thermal = None;
                c.thermal_gain_only = false;
            }
            EffectKind::Crosstalk => c.crosstalk = None,
            EffectKind::ScanSkew => {
                c.scan_skew = None;
                c.scan_uniform = false;
            }
        }
        c
    }

    /// This configuration with effect `e`'s fields (its form and parameters) taken from
    /// `from`: a fit of `e` from an earlier round, as a starting point on the current model.
    pub fn with_effect_of(&self, e: EffectKind, from: &Config) -> Config {
        let mut c = self.clone();
        match e {
            EffectKind::CurvatureBaseline => c.curv_base = from.curv_base,
            EffectKind::CurvatureSensitivity => {
                c.curv_sens = from.curv_sens;
                c.curv_linear = from.curv_linear;
                c.curv_trials.clone_from(&from.curv_trials);
                c.curv_per_node = from.curv_per_node;
            }
            EffectKind::Saturation => {
                c.saturation = from.saturation;
                c.r_floor_ohm = from.r_floor_ohm;
            }
            EffectKind::Creep => {
                c.creep.clone_from(&from.creep);
                c.creep_under_load = from.creep_under_load;
                c.creep_level = from.creep_level;
                c.creep_recovery = from.creep_recovery;
            }
            EffectKind::Hysteresis => {
                c.hysteresis = from.hysteresis;
                c.hyst_mix = from.hyst_mix;
                c.hyst_share = from.hyst_share;
                c.hyst_bouc_wen = from.hyst_bouc_wen;
                c.hyst_bw_n = from.hyst_bw_n;
                c.hyst_bw_asym = from.hyst_bw_asym;
                c.hyst_bw_z0 = from.hyst_bw_z0;
                c.hyst_bw_quad = from.hyst_bw_quad;
                c.hyst_preisach = from.hyst_preisach;
                c.hyst_remnant = from.hyst_remnant;
                c.hyst_set = from.hyst_set;
                c.set_levels.clone_from(&from.set_levels);
                c.preis_mu = from.preis_mu;
                c.preis_sigma = from.preis_sigma;
            }
            EffectKind::ThermalDrift => {
                c.thermal.clone_from(&from.thermal);
                c.thermal_gain_only = from.thermal_gain_only;
            }
            EffectKind::Crosstalk => c.crosstalk = from.crosstalk,
            EffectKind::ScanSkew => {
                c.scan_skew = from.scan_skew;
                c.scan_settle = from.scan_settle;
                c.scan_uniform = from.scan_uniform;
            }
        }
        c
    }

    /// The additive Bouc-Wen's amplitudes per node: on `z` and `z u`, and on `z u^2` with
    /// [`Config::hyst_bw_quad`] (see [`crate::forms::bouc_wen_gap`]).
    pub fn bw_terms(&self) -> usize {
        2 + usize::from(self.hyst_bw_quad)
    }

    /// Whether `self` and `other` hold effect `e` in the same form (the fields the search does
    /// not move: creep's terms and kind, the hysteresis form, the drift's kind and knots).
    pub fn same_form(&self, e: EffectKind, other: &Config) -> bool {
        match e {
            EffectKind::Creep => {
                self.creep.as_ref().map(Vec::len) == other.creep.as_ref().map(Vec::len)
                    && self.creep_under_load == other.creep_under_load
                    && self.creep_level == other.creep_level
                    && (self.creep_recovery == 1.0) == (other.creep_recovery == 1.0)
            }
            EffectKind::Hysteresis => {
                self.hyst_share.is_some() == other.hyst_share.is_some()
                    && self.hyst_bouc_wen == other.hyst_bouc_wen
                    && self.hyst_preisach == other.hyst_preisach
                    && self.hyst_remnant == other.hyst_remnant
                    && self.hyst_bw_quad == other.hyst_bw_quad
                    && self.hyst_set == other.hyst_set
                    && self.hysteresis.is_some() == other.hysteresis.is_some()
            }
            EffectKind::ThermalDrift => {
                let knots = |c: &Config| match &c.thermal {
                    Some(Thermal::Latent { knots_s, .. }) => Some(knots_s.len()),
                    _ => None,
                };
                self.thermal.is_some() == other.thermal.is_some()
                    && knots(self) == knots(other)
                    && self.thermal_gain_only == other.thermal_gain_only
            }
            EffectKind::CurvatureSensitivity => {
                self.curv_trials.is_some() == other.curv_trials.is_some()
                    && self.curv_per_node == other.curv_per_node
            }
            _ => true,
        }
    }

    pub fn effects(&self) -> Vec<EffectKind> {
        EffectKind::ALL
            .iter()
            .copied()
            .filter(|e| self.has(*e))
            .collect()
    }

    pub(crate) fn floor(&self) -> f64 {
        if self.sat_in_base || self.saturation {
            self.r_floor_ohm.max(0.0)
        } else {
            0.0
        }
    }
}

/// Most Prony terms a creep model has.
/// The remnant's ramps per node (see [`Config::hyst_remnant`]).
pub const REMNANT_RAMPS: usize = 3;

pub const MAX_CREEP_TERMS: usize = 3;
