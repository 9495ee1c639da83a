//! The diagnosis's forward model: the simulator's physics, written so that every per-node
//! parameter is fitted by weighted linear least squares inside each evaluation and only a few
//! global parameters (force-law exponent, resistance floor, and each effect's own) are searched.
//!
//! Per node `k` and sample `i`: load `L = F` (shifted in time by scan skew, passed through the
//! hysteresis, play operators or a Bouc-Wen state, and the creep low-pass), `p = L^n`;
//! conductance `G = m_i (b_k + [c_k kappa_i] + a_k s_i p)` with the thermal factor `m`, the
//! curvature sensitivity `s` and the curvature baseline term; then the resistance floor
//! `G / (1 + r G)`, the row crosstalk `G (1 - Rs sum_row G)`, and the readout.

use crate::data::{Dataset, ReadoutMap};
pub use crate::numeric::{centre_by_level, play_gap, solve_spd};
use crate::numeric::{hat, lowpass};

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
    pub exponent: f64,
    /// Resistance floor (ohm); used when `sat_in_base` or the saturation effect is on.
    pub r_floor_ohm: f64,
    pub sat_in_base: bool,
    pub saturation: bool,
    /// Creep as two or three Prony terms `(c, tau_s)`: `L + sum c lowpass_tau(L)` (fast and
    /// slow, and a middle one when the criterion pays for it: log-time creep spans decades).
    /// The amplitudes are
    /// non-negative (under a held force the sensor's deformation, and so its conductance, only
    /// grows) and each `tau` is at most `Context::creep_tau_max`.
    pub creep: Option<Vec<(f64, f64)>>,
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
    pub thermal: Option<Thermal>,
    /// Curvature sensitivity: `kappa_s` (1/m) with a curvature column, else `beta` (per unit
    /// log-baseline shift of the trial).
    pub curv_sens: Option<f64>,
    /// Linear form `1 - kappa / v` (or `1 - beta d`) instead of `1 / (1 + kappa / v)`.
    pub curv_linear: bool,
    pub curv_base: bool,
    /// Row crosstalk: switch + thread resistance (ohm).
    pub crosstalk: Option<f64>,
    /// Scan skew: time between two node samples (s).
    pub scan_skew: Option<f64>,
    /// Row-switch settling (s): the first node of each row lags its input by this much more
    /// (part of scan_skew; 0 when absent).
    pub scan_settle: f64,
}

impl Config {
    pub fn base(exponent: f64, r_floor_ohm: f64) -> Config {
        Config {
            exponent,
            r_floor_ohm,
            sat_in_base: r_floor_ohm > 0.0,
            saturation: false,
            creep: None,
            hysteresis: None,
            hyst_mix: 0.0,
            hyst_share: None,
            hyst_bouc_wen: false,
            hyst_bw_n: 1.0,
            thermal: None,
            curv_sens: None,
            curv_linear: false,
            curv_base: false,
            crosstalk: None,
            scan_skew: None,
            scan_settle: 0.0,
        }
    }

    pub fn has(&self, e: EffectKind) -> bool {
        match e {
            EffectKind::CurvatureBaseline => self.curv_base,
            EffectKind::CurvatureSensitivity => self.curv_sens.is_some(),
            EffectKind::Saturation => self.saturation,
            EffectKind::Creep => self.creep.is_some(),
            EffectKind::Hysteresis => self.hysteresis.is_some(),
            EffectKind::ThermalDrift => self.thermal.is_some(),
            EffectKind::Crosstalk => self.crosstalk.is_some(),
            EffectKind::ScanSkew => self.scan_skew.is_some(),
        }
    }

    pub fn without(&self, e: EffectKind) -> Config {
        let mut c = self.clone();
        match e {
            EffectKind::CurvatureBaseline => c.curv_base = false,
            EffectKind::CurvatureSensitivity => c.curv_sens = None,
            EffectKind::Saturation => {
                c.saturation = false;
                if !c.sat_in_base {
                    c.r_floor_ohm = 0.0;
                }
            }
            EffectKind::Creep => c.creep = None,
            EffectKind::Hysteresis => {
                c.hysteresis = None;
                c.hyst_share = None;
                c.hyst_bouc_wen = false;
                c.hyst_bw_n = 1.0;
            }
            EffectKind::ThermalDrift => c.thermal = None,
            EffectKind::Crosstalk => c.crosstalk = None,
            EffectKind::ScanSkew => c.scan_skew = None,
        }
        c
    }

    pub fn effects(&self) -> Vec<EffectKind> {
        EffectKind::ALL
            .iter()
            .copied()
            .filter(|e| self.has(*e))
            .collect()
    }

    fn floor(&self) -> f64 {
        if self.sat_in_base || self.saturation {
            self.r_floor_ohm.max(0.0)
        } else {
            0.0
        }
    }
}

/// Precomputed views of a dataset shared by every evaluation.
pub struct Context<'a> {
    pub ds: &'a Dataset,
    /// Observed conductance (S), sample-major.
    pub g_obs: Vec<f64>,
    /// Observed reading in the residual domain.
    pub dom_obs: Vec<f64>,
    /// Observation usable (not on the rail).
    pub usable: Vec<bool>,
    /// Per-trial common log-shift of the no-load conductance against the whole recording.
    pub trial_shift: Vec<f64>,
    /// Cross-validation block of each sample and its fold (0 or 1).
    pub block: Vec<usize>,
    pub n_blocks: usize,
    /// Longest creep time constant the recording can show (s): three times its longest
    /// continuous loaded span. Creep is seen while a load is held; a slower "creep" could not be
    /// told from a drift, so it is not allowed to stand in for one.
    pub creep_tau_max: f64,
    /// Per node: the total force that moves the node as much as one newton moves the most
    /// loaded node (>= 1), from the nodes' loaded-minus-rest conductance (see `load_scale`).
    /// In-load hysteresis uses it to turn a local half-width into total-force units.
    pub load_scale: Vec<f64>,
    /// Half-width (N) of the play that takes the load cell's noise out of the force before a
    /// memoryless hysteresis state sees it: three standard deviations of the force noise,
    /// estimated from the first differences (median absolute difference / 0.954).
    pub force_deadband: f64,
}

impl<'a> Context<'a> {
    pub fn new(ds: &'a Dataset) -> Context<'a> {
        let n = ds.n;
        let g_obs: Vec<f64> = ds.y.iter().map(|&y| ds.map.to_g(y)).collect();
        let dom_obs = ds.y.iter().map(|&y| ds.map.dom(y)).collect();
        let usable = ds.y.iter().map(|&y| !ds.map.on_rail(y)).collect();
        // Rest samples: force below 2 % of the peak.
        let fmax = ds.max_force();
        let rest: Vec<bool> = ds.force.iter().map(|&f| f <= 0.02 * fmax).collect();
        let mut overall = vec![Vec::new(); n];
        let mut per_trial = vec![vec![Vec::new(); n]; ds.n_trials];
        for i in 0..ds.len() {
            if rest[i] {
                for k in 0..n {
                    let g = g_obs[i * n + k].max(1e-12).ln();
                    overall[k].push(g);
                    per_trial[ds.trial[i]][k].push(g);
                }
            }
        }
        let med = |v: &mut Vec<f64>| -> Option<f64> {
            if v.is_empty() {
                return None;
            }
            v.sort_by(f64::total_cmp);
            Some(v[v.len() / 2])
        };
        // A node's rest level is a trimmed mean, not a median: the readings are whole ADC
        // counts, and a curvature's baseline shift is often under one count, which the median
        // of integer codes rounds away (two trials a count apart then both read as no shift).
        // The noise dithers the codes, so their mean resolves fractions of a count.
        let level = |v: &mut Vec<f64>| -> Option<f64> {
            if v.is_empty() {
                return None;
            }
            v.sort_by(f64::total_cmp);
            let cut = v.len() / 10;
            let kept = &v[cut..v.len() - cut];
            Some(kept.iter().sum::<f64>() / kept.len() as f64)
        };
        let overall: Vec<Option<f64>> = overall.iter_mut().map(level).collect();
        let trial_shift = per_trial
            .iter_mut()
            .map(|nodes| {
                let mut d: Vec<f64> = nodes
                    .iter_mut()
                    .zip(&overall)
                    .filter_map(|(v, o)| Some(level(v)? - (*o)?))
                    .collect();
                med(&mut d).unwrap_or(0.0)
            })
            .collect();
        let (block, n_blocks) = blocks(ds);
        let creep_tau_max = 3.0 * longest_loaded_span(ds);
        let load_scale = load_scale(ds, &g_obs, &rest);
        let force_deadband = force_deadband(&ds.force);
        Context {
            ds,
            g_obs,
            dom_obs,
            usable,
            trial_shift,
            block,
            n_blocks,
            creep_tau_max,
            load_scale,
            force_deadband,
        }
    }

    /// Every how many samples the parameter search looks (about 50 per second).
    pub fn search_stride(&self) -> usize {
        ((1.0 / self.ds.dt() / 50.0).round() as usize).max(1)
    }

    pub fn fold(&self, i: usize) -> usize {
        self.block[i] % 2
    }
}

/// The Bouc-Wen input's deadband (see [`Context::force_deadband`]): three standard deviations
/// of the white noise on `f`, estimated from its first differences, whose median absolute value
/// is 0.6745 sqrt(2) sd (ramps are a minority of the samples and barely move the median).
pub fn force_deadband(f: &[f64]) -> f64 {
    let mut d: Vec<f64> = f.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
    if d.is_empty() {
        return 0.0;
    }
    d.sort_by(f64::total_cmp);
    3.0 * d[d.len() / 2] / (0.6745 * std::f64::consts::SQRT_2)
}

/// Each node's share of the load relative to the most loaded node, inverted (see
/// [`Context::load_scale`]): the median conductance rise over the rest level on samples above
/// half the peak force, to the power 1 / 1.1 (a typical force-law exponent), clamped to 1..=100.
fn load_scale(ds: &Dataset, g_obs: &[f64], rest: &[bool]) -> Vec<f64> {
    let n = ds.n;
    let fmax = ds.max_force();
    let med = |mut v: Vec<f64>| -> f64 {
        if v.is_empty() {
            return 0.0;
        }
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let rise: Vec<f64> = (0..n)
        .map(|k| {
            let column = |keep: &dyn Fn(usize) -> bool| -> Vec<f64> {
                (0..ds.len())
                    .filter(|&i| keep(i))
                    .map(|i| g_obs[i * n + k])
                    .collect()
            };
            let high = med(column(&|i| ds.force[i] >= 0.5 * fmax));
            let low = med(column(&|i| rest[i]));
            (high - low).max(0.0)
        })
        .collect();
    let top = rise.iter().cloned().fold(0.0, f64::max);
    rise.iter()
        .map(|&r| {
            if top > 0.0 && r > 0.0 {
                (top / r).powf(1.0 / 1.1).clamp(1.0, 100.0)
            } else {
                100.0
            }
        })
        .collect()
}

/// Contiguous time blocks, cut at trial changes too, about 1/24 of the recording each (at
/// least 2 s and 20 samples); consecutive blocks alternate between the two folds.
#[allow(clippy::needless_range_loop)]
fn blocks(ds: &Dataset) -> (Vec<usize>, usize) {
    let len = ds.len();
    let target = (ds.duration() / 24.0).max(2.0);
    let mut block = vec![0usize; len];
    let mut b = 0usize;
    let mut start_t = ds.t[0];
    let mut start_i = 0usize;
    for i in 0..len {
        let new_trial = i > 0 && ds.trial[i] != ds.trial[i - 1];
        if i > start_i && (new_trial || (ds.t[i] - start_t >= target && i - start_i >= 20)) {
            b += 1;
            start_t = ds.t[i];
            start_i = i;
        }
        block[i] = b;
    }
    (block, b + 1)
}

/// Result of one evaluation.
pub struct Eval {
    /// Predicted reading in the residual domain, sample-major.
    pub pred: Vec<f64>,
    /// Per-node linear parameters: intercept(s), [curvature slope], gain.
    pub theta: Vec<Vec<f64>>,
    /// Thermal factor per sample (1 without thermal drift).
    pub m: Vec<f64>,
    /// The latent thermal values at the knots after fitting (if latent).
    pub latent: Option<Vec<f64>>,
    /// Training SSE (only when predictions were not requested).
    pub train_sse: f64,
}

/// Most Prony terms a creep model has.
pub const MAX_CREEP_TERMS: usize = 3;

/// The load transform: creep, then the power law. (Hysteresis enters as its own per-node
/// term, see [`play_gap`].)
/// Only every `every`-th sample gets its power law (the others are left 0: the parameter
/// search looks at every `stride`-th sample only); the creep states follow every sample.
pub fn load_series(
    f: impl Iterator<Item = f64>,
    dt: &[f64],
    cfg: &Config,
    tau_max: f64,
    every: usize,
    out: &mut Vec<f64>,
) {
    let every = every.max(1);
    out.clear();
    let mut s = [0.0f64; MAX_CREEP_TERMS];
    for (i, fi) in f.enumerate() {
        let mut l = fi.max(0.0);
        if let Some(terms) = &cfg.creep {
            let base = l;
            for (st, &(c, tau)) in s.iter_mut().zip(terms) {
                if i > 0 {
                    *st += (base - *st) * (1.0 - (-dt[i] / tau.min(tau_max)).exp());
                }
                l += c * *st;
            }
        }
        out.push(if i % every == 0 {
            l.max(0.0).powf(cfg.exponent)
        } else {
            0.0
        });
    }
}

/// The load through a Bouc-Wen hysteresis state (see [`Config::hyst_bouc_wen`]):
/// `F + share sc z`, with `z` driven by the node's own load `u = play_eps(F) / sc` and saturating
/// at `r` with the exponent `knee` was tabulated for. It starts at 0, the textbook virgin state. (Started at
/// `-r`, a sensor last unloaded, the classic Bouc-Wen reference world's hysteresis recording
/// re-fitted at 0.891 instead of 0.795 counts with the world's own parameters: a node whose load
/// never saturates the state keeps its start for good.)
pub fn bouc_wen_load<'a>(
    force: &'a [f64],
    r: f64,
    knee: &'a Knee,
    share: f64,
    sc: f64,
    deadband: f64,
) -> impl Iterator<Item = f64> + 'a {
    let r = r.max(1e-12);
    let (mut z, mut u_prev, mut play) = (0.0f64, 0.0f64, 0.0f64);
    force.iter().map(move |&fi| {
        let l = fi.max(0.0);
        play = play.clamp(l - deadband, l + deadband);
        let u = play.max(0.0) / sc;
        let du = u - u_prev;
        u_prev = u;
        if du != 0.0 {
            z += du - (du.abs() * z + du * z.abs()) * knee.at(z.abs() / r) / (2.0 * r);
        }
        z = z.clamp(-r, r);
        fi + share * sc * z
    })
}

/// `x^(n-1)` on `0..=1`, tabulated (a `powf` per node and sample was most of an evaluation's
/// time): linear interpolation between 1024 steps, exact for `n = 1` and `n = 2`.
pub struct Knee {
    table: Vec<f64>,
}

impl Knee {
    const STEPS: usize = 1024;

    pub fn new(n: f64) -> Knee {
        Knee {
            table: (0..=Self::STEPS)
                .map(|j| (j as f64 / Self::STEPS as f64).powf(n - 1.0))
                .collect(),
        }
    }

    fn at(&self, x: f64) -> f64 {
        let pos = x.clamp(0.0, 1.0) * Self::STEPS as f64;
        let j = (pos as usize).min(Self::STEPS - 1);
        let w = pos - j as f64;
        self.table[j] * (1.0 - w) + self.table[j + 1] * w
    }
}

/// The longest time (s) the force stays above 10 % of its peak without a break (at least one
/// sample interval).
pub fn longest_loaded_span(ds: &Dataset) -> f64 {
    let limit = 0.1 * ds.max_force();
    let (mut best, mut start): (f64, Option<f64>) = (0.0, None);
    for (t, f) in ds.t.iter().zip(&ds.force) {
        if *f > limit {
            let s = *start.get_or_insert(*t);
            best = best.max(t - s);
        } else {
            start = None;
        }
    }
    best.max(ds.dt())
}

/// The largest possible scan skew (s per node): every node of a frame is read within one frame
/// period, so the first and last node are at most one period apart.
pub fn max_scan_skew(ds: &Dataset) -> f64 {
    ds.dt() / (ds.n.max(2) - 1) as f64
}

/// Latent thermal knots for a recording: about one per 60 s (at least 4, at most 24).
pub fn latent_knots(ds: &Dataset) -> Vec<f64> {
    let k = ((ds.duration() / 60.0).round() as usize + 1).clamp(4, 24);
    latent_knots_n(ds, k)
}

/// The resolutions a latent drift is tried at: 2 knots (a straight drift), 3, 5, 8, ... up to
/// [`latent_knots`] (one per minute). The criterion picks among them, so a drift that is nearly
/// straight pays for two parameters, not one per minute.
pub fn latent_resolutions(ds: &Dataset) -> Vec<usize> {
    let full = latent_knots(ds).len();
    let mut v: Vec<usize> = [2, 3, 5, 8, 12, 18]
        .into_iter()
        .filter(|&k| k < full)
        .collect();
    v.push(full);
    v
}

/// `k` evenly spaced knots over the recording.
pub fn latent_knots_n(ds: &Dataset, k: usize) -> Vec<f64> {
    let k = k.max(2);
    let t0 = ds.t[0];
    let span = ds.duration().max(1e-9);
    (0..k)
        .map(|j| t0 + span * j as f64 / (k - 1) as f64)
        .collect()
}

/// Evaluates `cfg`: fits the per-node linear parameters on the samples where `train(i)` is
/// true and predicts every sample.
pub fn evaluate(ctx: &Context, cfg: &Config, train: &dyn Fn(usize) -> bool) -> Eval {
    evaluate_with(ctx, cfg, train, 1, true)
}

/// As [`evaluate`], fitting on every `stride`-th training sample; with `want_pred` false only
/// the training SSE over those samples is computed (`Eval::train_sse`; `pred` stays empty).
#[allow(clippy::needless_range_loop)] // index-heavy numeric code reads better with indices
pub fn evaluate_with(
    ctx: &Context,
    cfg: &Config,
    train: &dyn Fn(usize) -> bool,
    stride: usize,
    want_pred: bool,
) -> Eval {
    let stride = stride.max(1);
    let ds = ctx.ds;
    let (len, n) = (ds.len(), ds.n);
    let mut dt: Vec<f64> = Vec::with_capacity(len);
    dt.push(ds.dt());
    dt.extend(ds.t.windows(2).map(|w| (w[1] - w[0]).max(1e-9)));
    let skew = cfg.scan_skew.map_or(0.0, |v| v.min(max_scan_skew(ds)));
    // The slopes scan skew needs read the neighbours of each sample.
    let every = if want_pred || skew != 0.0 { 1 } else { stride };
    // Loads: one series for all nodes (per node with in-load hysteresis); scan skew shifts
    // node k by k * dt_node to first order, p_k(t) = p(t) + k dt_node dp/dt.
    let knee = cfg.hyst_bouc_wen.then(|| Knee::new(cfg.hyst_bw_n));
    let loads: Vec<Vec<f64>> = match (cfg.hysteresis, cfg.hyst_share) {
        (Some(r), Some(share)) => ctx
            .load_scale
            .iter()
            .map(|&sc| {
                if let Some(knee) = &knee {
                    let f = bouc_wen_load(&ds.force, r, knee, share, sc, ctx.force_deadband);
                    let mut p = Vec::with_capacity(len);
                    load_series(f, &dt, cfg, ctx.creep_tau_max, every, &mut p);
                    return p;
                }
                // The two play operators of `play_gap`, run inline (no temporary series).
                let (r1, r4) = (r * sc, 4.0 * r * sc);
                let mut z: Option<(f64, f64)> = None;
                let f = ds.force.iter().map(|&fi| {
                    let l = fi.max(0.0);
                    let (a, b) = z.map_or((l + r1, l + r4), |(a, b)| {
                        (a.clamp(l - r1, l + r1), b.clamp(l - r4, l + r4))
                    });
                    z = Some((a, b));
                    fi + share * ((a - l) + cfg.hyst_mix * (b - l))
                });
                let mut p = Vec::with_capacity(len);
                load_series(f, &dt, cfg, ctx.creep_tau_max, every, &mut p);
                p
            })
            .collect(),
        _ => {
            let mut p = Vec::new();
            let f = ds.force.iter().copied();
            load_series(f, &dt, cfg, ctx.creep_tau_max, every, &mut p);
            vec![p]
        }
    };
    let slopes: Vec<Vec<f64>> = if skew != 0.0 {
        loads
            .iter()
            .map(|p| {
                (0..len)
                    .map(|i| {
                        let (a, b) = (i.saturating_sub(1), (i + 1).min(len - 1));
                        let span = ds.t[b] - ds.t[a];
                        if span > 0.0 {
                            (p[b] - p[a]) / span
                        } else {
                            0.0
                        }
                    })
                    .collect()
            })
            .collect()
    } else {
        Vec::new()
    };
    // Node k reads the force k * dt_node later in the frame; the first node of each row also
    // settles after the row switch, a lag of `scan_settle`.
    let settle = cfg.scan_settle;
    let cols_n = ds.cols.max(1);
    let p_at = |k: usize, i: usize| -> f64 {
        let j = k.min(loads.len() - 1);
        if slopes.is_empty() {
            loads[j][i]
        } else {
            let lag = if k.is_multiple_of(cols_n) {
                settle
            } else {
                0.0
            };
            (loads[j][i] + (skew * k as f64 - lag) * slopes[j][i]).max(0.0)
        }
    };
    // Curvature sensitivity per sample.
    let form = |x: f64| -> f64 {
        if cfg.curv_linear {
            (1.0 - x).max(0.05)
        } else {
            1.0 / (1.0 + x).max(0.05)
        }
    };
    let sens: Vec<f64> = match (cfg.curv_sens, &ds.kappa) {
        (Some(ks), Some(kappa)) => kappa
            .iter()
            .map(|&k| form(k.max(0.0) / ks.max(1e-6)))
            .collect(),
        (Some(beta), None) => ds
            .trial
            .iter()
            .map(|&j| form(beta * ctx.trial_shift[j]))
            .collect(),
        _ => vec![1.0; len],
    };
    // Thermal factor.
    let mut m = vec![1.0; len];
    let mut latent: Option<(Vec<f64>, Vec<f64>)> = None;
    match &cfg.thermal {
        Some(Thermal::Recorded { alpha_per_k, tau_s }) => {
            if let Some(temp) = &ds.temp {
                let t0 = temp.iter().sum::<f64>() / len as f64;
                let ts = lowpass(temp, &dt, *tau_s);
                for (mi, t) in m.iter_mut().zip(&ts) {
                    *mi = (1.0 + alpha_per_k * (t - t0)).max(0.05);
                }
            }
        }
        Some(Thermal::Latent { knots_s, values }) => {
            latent = Some((knots_s.clone(), values.clone()));
        }
        None => {}
    }
    let r = cfg.floor();
    let rs = cfg.crosstalk.unwrap_or(0.0);
    let (rows, cols) = (ds.rows, ds.cols);
    // Observed conductance undone through crosstalk and the floor: `g2`, with a weight.
    let mut g2 = vec![0.0; len * n];
    let mut wgt = vec![0.0; len * n];
    for i in 0..len {
        if !want_pred && i % stride != 0 {
            continue;
        }
        for row in 0..rows {
            let base = i * n + row * cols;
            let srow: f64 = if rs > 0.0 {
                ctx.g_obs[base..base + cols].iter().sum()
            } else {
                0.0
            };
            let xf = (1.0 - rs * srow).max(0.05);
            for c in 0..cols {
                let idx = base + c;
                let g1 = ctx.g_obs[idx] / xf;
                let rg = r * g1;
                if !ctx.usable[idx] || rg >= 0.9 {
                    continue;
                }
                g2[idx] = g1 / (1.0 - rg);
                let d = ds.map.ddom_dg(ctx.g_obs[idx]) * xf * (1.0 - rg).powi(2);
                wgt[idx] = d * d;
            }
        }
    }
    // Curvature baseline: a per-node slope on the curvature, or, without a curvature column,
    // on the trial's common no-load shift (the curvature's footprint: rank one in trial x node).
    let curv_k = cfg.curv_base;
    let n_int = 1;
    let curv_x: Vec<f64> = if curv_k {
        match &ds.kappa {
            Some(k) => k.clone(),
            None => ds.trial.iter().map(|&j| ctx.trial_shift[j]).collect(),
        }
    } else {
        Vec::new()
    };
    // Hysteresis: two play operators (half-widths r and 4 r) mixed by one global weight, so
    // the loop's shape (sharp or rounded corners) is fitted, not assumed; one amplitude per
    // node. The gap is centred on its mean at the same force level, so the term only carries
    // the difference between branches (a loop), never a level-dependent offset the static law
    // should carry.
    let hyst: Vec<f64> = match cfg.hysteresis {
        Some(r) if cfg.hyst_share.is_none() => {
            let narrow = play_gap(&ds.force, r);
            let wide = play_gap(&ds.force, 4.0 * r);
            let mixed = narrow
                .iter()
                .zip(&wide)
                .map(|(a, b)| a + cfg.hyst_mix * b)
                .collect();
            centre_by_level(&ds.force, mixed)
        }
        _ => Vec::new(),
    };
    let lay = Layout {
        n_int,
        curv_k,
        hyst: !hyst.is_empty(),
    };
    let pdim = lay.dim();
    let mut theta = vec![vec![0.0; pdim]; n];
    let iterations = if latent.is_some() { 3 } else { 1 };
    for it in 0..iterations {
        if let Some((knots, values)) = &latent {
            for (i, mi) in m.iter_mut().enumerate() {
                let (j, w) = hat(knots, ds.t[i]);
                let v = if knots.len() < 2 {
                    values[0]
                } else {
                    values[j] * (1.0 - w) + values[j + 1] * w
                };
                *mi = v.max(0.05);
            }
        }
        // Per-node weighted least squares; for readouts that are not linear in conductance
        // (resistance, divider) a few Gauss-Newton passes linearise the residual domain around
        // the current prediction instead of the observation (whose 1/G^2 weights would favour
        // the highest-resistance samples).
        let gn_passes = if matches!(ds.map, ReadoutMap::Amplifier { .. }) {
            0
        } else {
            2
        };
        let mut xrow = vec![0.0; pdim];
        for (k, th) in theta.iter_mut().enumerate() {
            for pass in 0..=gn_passes {
                let mut a = vec![0.0; pdim * pdim];
                let mut b = vec![0.0; pdim];
                for i in (0..len).step_by(stride) {
                    let idx = i * n + k;
                    let w = wgt[idx];
                    if w == 0.0 || !train(i) {
                        continue;
                    }
                    let mi = m[i];
                    xrow.iter_mut().for_each(|v| *v = 0.0);
                    xrow[0] = 1.0;
                    if curv_k {
                        xrow[n_int] = curv_x[i];
                    }
                    if lay.hyst {
                        xrow[pdim - 2] = sens[i] * hyst[i];
                    }
                    xrow[pdim - 1] = sens[i] * p_at(k, i);
                    let (z, w) = if pass == 0 {
                        (g2[idx] / mi, w * mi * mi)
                    } else {
                        let zh: f64 = xrow.iter().zip(th.iter()).map(|(x, t)| x * t).sum();
                        let zh = zh.max(1e-15);
                        let dom_of = |z: f64| {
                            let g = (mi * z).max(1e-15);
                            ds.map.dom(ds.map.from_g(g / (1.0 + r * g)))
                        };
                        let f0 = dom_of(zh);
                        let d = (dom_of(zh * (1.0 + 1e-4)) - f0) / (zh * 1e-4);
                        if !d.is_finite() || d == 0.0 {
                            continue;
                        }
                        (zh + (ctx.dom_obs[idx] - f0) / d, d * d)
                    };
                    for u in 0..pdim {
                        if xrow[u] == 0.0 {
                            continue;
                        }
                        b[u] += w * xrow[u] * z;
                        for v in 0..=u {
                            a[u * pdim + v] += w * xrow[u] * xrow[v];
                        }
                    }
                }
                for u in 0..pdim {
                    for v in u + 1..pdim {
                        a[u * pdim + v] = a[v * pdim + u];
                    }
                }
                *th = solve_spd(&a, &b, pdim);
                if th[0] < 0.0 {
                    // A conductance baseline cannot be negative (a constant force, for one,
                    // cannot separate it from the gain): refit with the baseline at zero.
                    for u in 0..pdim {
                        a[u * pdim] = 0.0;
                        a[u] = 0.0;
                    }
                    a[0] = 1.0;
                    b[0] = 0.0;
                    *th = solve_spd(&a, &b, pdim);
                }
            }
        }
        // Latent thermal: refit the common-mode factor on the knots.
        if let Some((knots, values)) = &mut latent {
            if it + 1 == iterations {
                break;
            }
            let kk = knots.len();
            let mut a = vec![0.0; kk * kk];
            let mut b = vec![0.0; kk];
            for i in (0..len).step_by(stride) {
                if !train(i) {
                    continue;
                }
                let (j, w) = hat(knots, ds.t[i]);
                for k in 0..n {
                    let idx = i * n + k;
                    let wt = wgt[idx];
                    if wt == 0.0 {
                        continue;
                    }
                    let hv = if lay.hyst { sens[i] * hyst[i] } else { 0.0 };
                    let cx = if curv_k { curv_x[i] } else { 0.0 };
                    let q = zhat(&theta[k], &lay, cx, hv, sens[i] * p_at(k, i));
                    let phi = [(j, (1.0 - w) * q), (j + 1, w * q)];
                    for &(u, xu) in &phi {
                        if u >= kk {
                            continue;
                        }
                        b[u] += wt * xu * g2[idx];
                        for &(v, xv) in &phi {
                            if v < kk {
                                a[u * kk + v] += wt * xu * xv;
                            }
                        }
                    }
                }
            }
            // A light pull towards 1 keeps knots without training data at 1.
            let diag = (0..kk).map(|u| a[u * kk + u]).fold(0.0, f64::max) * 1e-4 + 1e-300;
            for u in 0..kk {
                a[u * kk + u] += diag;
                b[u] += diag;
            }
            let mut v = solve_spd(&a, &b, kk);
            let mean = v.iter().sum::<f64>() / kk as f64;
            if mean > 0.0 {
                v.iter_mut().for_each(|x| *x /= mean);
            }
            *values = v;
        }
    }
    // Forward prediction (or only the training SSE).
    let mut pred = if want_pred {
        vec![0.0; len * n]
    } else {
        Vec::new()
    };
    let mut train_sse = 0.0;
    let mut gs = vec![0.0; cols];
    for i in 0..len {
        if !want_pred && (i % stride != 0 || !train(i)) {
            continue;
        }
        for row in 0..rows {
            let mut srow = 0.0;
            for c in 0..cols {
                let k = row * cols + c;
                let hv = if lay.hyst { sens[i] * hyst[i] } else { 0.0 };
                let cx = if curv_k { curv_x[i] } else { 0.0 };
                let z = zhat(&theta[k], &lay, cx, hv, sens[i] * p_at(k, i));
                let g = (m[i] * z).max(1e-12);
                gs[c] = g / (1.0 + r * g);
                srow += gs[c];
            }
            let xf = (1.0 - rs * srow).max(0.05);
            for c in 0..cols {
                let idx = i * n + row * cols + c;
                let v = ds.map.dom(ds.map.from_g(gs[c] * xf));
                if want_pred {
                    pred[idx] = v;
                } else if ctx.usable[idx] {
                    train_sse += (v - ctx.dom_obs[idx]).powi(2);
                }
            }
        }
    }
    Eval {
        pred,
        theta,
        m,
        latent: latent.map(|l| l.1),
        train_sse,
    }
}

/// Where each per-node linear parameter sits in `theta`: the intercept, the curvature-baseline
/// slope (on the curvature, or on the trial's no-load shift), the hysteresis amplitude, and
/// last the force gain.
#[derive(Debug, Clone, Copy)]
pub struct Layout {
    pub n_int: usize,
    pub curv_k: bool,
    pub hyst: bool,
}

impl Layout {
    pub fn dim(&self) -> usize {
        self.n_int + usize::from(self.curv_k) + usize::from(self.hyst) + 1
    }
}

fn zhat(th: &[f64], lay: &Layout, cx: f64, hv: f64, sp: f64) -> f64 {
    let mut z = th[0];
    if lay.curv_k {
        z += th[lay.n_int] * cx;
    }
    if lay.hyst {
        z += th[th.len() - 2] * hv;
    }
    z + th[th.len() - 1] * sp
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tabulated_knee_matches_powf() {
        for n in [1.0, 1.5, 2.0, 2.7, 4.0] {
            let k = Knee::new(n);
            for i in 0..=200 {
                let x = i as f64 / 200.0;
                let exact = x.powf(n - 1.0);
                assert!(
                    (k.at(x) - exact).abs() < 2e-3,
                    "n {n} x {x}: {} vs {exact}",
                    k.at(x)
                );
            }
        }
        // Beyond the table's range it holds the end value.
        assert_eq!(Knee::new(3.0).at(1.5), 1.0);
    }

    #[test]
    fn a_bouc_wen_load_saturates_and_ignores_noise_inside_its_deadband() {
        // Ramp to 5 N, then hold with +-0.02 N of alternating noise: with a 0.06 N deadband the
        // state stays at its saturation, and the load is F + share z.
        let mut f: Vec<f64> = (0..=50).map(|i| i as f64 * 0.1).collect();
        f.extend((0..500).map(|i| 5.0 + if i % 2 == 0 { 0.02 } else { -0.02 }));
        let out: Vec<f64> = bouc_wen_load(&f, 0.5, &Knee::new(2.0), 0.4, 1.0, 0.06).collect();
        let last = f.len() - 1;
        assert!(
            (out[last] - f[last] - 0.4 * 0.5).abs() < 1e-3,
            "{}",
            out[last] - f[last]
        );
        // Without the deadband the noise walks the state down.
        let raw: Vec<f64> = bouc_wen_load(&f, 0.5, &Knee::new(1.0), 0.4, 1.0, 0.0).collect();
        assert!(raw[last] - f[last] < 0.4 * 0.25, "{}", raw[last] - f[last]);
    }
}
