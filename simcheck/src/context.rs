//! What every evaluation of a recording shares: the observed conductance and residual-domain
//! readings, which observations are usable, each trial's no-load shift, the cross-validation
//! blocks, and the bounds and scales the effects need (creep's longest time constant, each
//! node's share of the load, the force noise's deadband).

use std::sync::{Arc, Mutex};

use crate::data::Dataset;
use crate::model::{Observed, ObservedKey};
use crate::numeric::LevelBins;

/// Most samples the parameter search looks at per evaluation: what it looks at in a 5-minute
/// recording at 100 Hz (every fourth sample), the zoo's length. A longer recording is fitted
/// like one of that length and held out on every sample (see [`FIT_SAMPLES`]).
pub const SEARCH_SAMPLES: usize = 7_500;

/// Most samples the parameter search runs the effects' states through: every second sample of
/// a 5-minute recording at 100 Hz.
pub const STATE_SAMPLES: usize = 15_000;

/// Most samples (both folds together) a held-out evaluation fits the per-node parameters on:
/// every sample of a 5-minute recording at 100 Hz. Its predictions cover every held-out sample
/// whatever the length. With [`SEARCH_SAMPLES`] and [`STATE_SAMPLES`] as they are since
/// 2026-11-27 (10 000, 20 000 and none before), the zoo's 5-minute recordings at 100 Hz are
/// diagnosed exactly as before and a 10-minute one in about a sixth less time.
pub const FIT_SAMPLES: usize = 30_000;

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
    /// Shortest creep time constant (s): the median time a press takes to rise (see
    /// [`median_rise_time`]). A low-pass faster than the load's own rise follows the load within
    /// the ramp, a function of the load as it stands: a static law's shape (under load: a step
    /// in the law where the load comes on), not creep.
    pub creep_tau_min: f64,
    /// Widest hysteresis (N): a third of the peak force. A play or a Bouc-Wen saturation that
    /// only the largest presses reach is a memory of the largest load, not a loop; it would
    /// stand in for what another effect's form leaves.
    pub hyst_r_max: f64,
    /// Per node: the total force that moves the node as much as one newton moves the most
    /// loaded node (>= 1), from the nodes' loaded-minus-rest conductance (see `load_scale`).
    /// In-load hysteresis uses it to turn a local half-width into total-force units.
    pub load_scale: Vec<f64>,
    /// Half-width (N) of the play that takes the load cell's noise out of the force before a
    /// memoryless hysteresis state sees it: three standard deviations of the force noise,
    /// estimated from the first differences (median absolute difference / 0.954).
    pub force_deadband: f64,
    /// The force the forward model is driven with: the recorded force, 0 where it lies within
    /// the load cell's noise of zero (below `force_deadband`, and below 2 % of the peak). A law that rises steeply from
    /// zero load (a logarithmic one) would otherwise turn the load cell's noise at rest into
    /// counts of predicted reading.
    pub force_model: Vec<f64>,
    /// The force bins a hysteresis term is centred on (see [`LevelBins`]), of `force_model`.
    pub level_bins: Arc<LevelBins>,
    /// The observations undone through the floor and crosstalk, for the last few sample sets
    /// and parameters (see `model::Observed`).
    pub(crate) observed: ObservedCache,
    /// Readings taken out as one-frame spikes (see [`crate::noise::spikes`]).
    pub spikes: usize,
    /// The effects' states' grids by step (see [`Context::state_grid`]).
    grids: Mutex<Vec<(usize, Arc<StateGrid>)>>,
    /// How much sparser than usual the parameter search looks and runs the effects' states
    /// (1; more in the screening view, see [`Context::coarser`]).
    pub coarse: usize,
}

/// Every `step`-th sample's time (s), interval (s) and model force (N).
pub struct StateGrid {
    pub t: Vec<f64>,
    pub dt: Vec<f64>,
    pub force: Vec<f64>,
}

/// A few [`Observed`]s by what they depend on.
pub(crate) type ObservedCache = Mutex<Vec<(ObservedKey, Arc<Observed>)>>;

impl<'a> Context<'a> {
    pub fn new(ds: &'a Dataset) -> Context<'a> {
        let n = ds.n;
        let g_obs: Vec<f64> = ds.y.iter().map(|&y| ds.map.to_g(y)).collect();
        let dom_obs: Vec<f64> = ds.y.iter().map(|&y| ds.map.dom(y)).collect();
        let mut usable: Vec<bool> = ds.y.iter().map(|&y| !ds.map.on_rail(y)).collect();
        // One-frame spikes are not the sensor's: out before any fit.
        let spikes = crate::noise::spikes(&dom_obs, n, &mut usable);
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
        let creep_tau_min = median_rise_time(ds).min(creep_tau_max);
        let load_scale = load_scale(ds, &g_obs, &rest);
        let force_deadband = force_deadband(&ds.force);
        // At most 2 % of the peak force: on a slowly sampled recording the first differences
        // are the signal, not the load cell's noise.
        let zero_below = force_deadband.min(0.02 * ds.max_force());
        let force_model = ds
            .force
            .iter()
            .map(|&f| if f < zero_below { 0.0 } else { f })
            .collect::<Vec<f64>>();
        let level_bins = Arc::new(LevelBins::new(&force_model));
        Context {
            ds,
            g_obs,
            dom_obs,
            usable,
            trial_shift,
            block,
            n_blocks,
            creep_tau_max,
            creep_tau_min,
            hyst_r_max: ds.max_force() / 3.0,
            load_scale,
            force_deadband,
            force_model,
            level_bins,
            observed: Mutex::new(Vec::new()),
            spikes,
            grids: Mutex::new(Vec::new()),
            coarse: 1,
        }
    }

    /// The same recording with the parameter search `factor` times sparser (its grid of the
    /// effects' states too): the candidates' screening view. Held-out predictions still cover
    /// every sample, so its held-out results compare with the full view's.
    pub fn coarser(&self, factor: usize) -> Context<'a> {
        self.derived(self.block.clone(), self.coarse * factor.max(1))
    }

    /// The same recording with the rest before the first press seen by both folds, when that
    /// rest (at least 40 samples) lies in the first block alone: its first half joins the
    /// second block (the other fold), and every other block keeps its bounds. None when the
    /// folds would not change.
    ///
    /// A model that remembers the largest load so far (a hysteresis set or a remnant, see
    /// [`crate::set`]) needs it: a first press that sets the sensor for good leaves the rest
    /// before it unseen by the fold whose training blocks all come after it, and that fold's
    /// prediction of the virgin rest is an extrapolation (on world B's creep + hysteresis case
    /// it held 60 % of the held-out SSE, and left node 10 `unexplained`). So may the additive
    /// Bouc-Wen state's start (zoo-hys's creep + hysteresis, seed 271: the rest before the
    /// first press held 42 % of the held-out SSE, and creep, which a joint refit's new start
    /// state credited with it, was refused). The diagnosis moves to these folds only once
    /// such a model has joined ([`crate::effects::Config::remembers_the_start`], see
    /// `Selection::join`; for the start state only when they predict better): every
    /// recording without one keeps the folds it always had.
    pub fn virgin_rest_shared(&self) -> Option<Context<'a>> {
        let ds = self.ds;
        let first_press = ds.force.iter().position(|&f| f > 0.02 * ds.max_force())?;
        let alone =
            first_press >= 40 && self.n_blocks >= 2 && self.block[first_press - 1] == self.block[0];
        if !alone {
            return None;
        }
        let mut block = self.block.clone();
        block[..first_press / 2].fill(self.block[0] + 1);
        Some(self.derived(block, self.coarse))
    }

    /// The same recording with folds whose largest loads are closer to the recording's peak,
    /// when this context's folds leave one of them under [`FOLD_PEAK_SHARE`] of it: the first
    /// block shortened by a quarter, a half or three quarters of a block (every later cut
    /// moves with it), the phase whose folds share the peak best. None when the folds already
    /// share it or no phase does better. Shortened, not lengthened: the first block holds the
    /// sensor's state at the start, which the other fold's fit never sees (lengthened, the
    /// first block left zoo-hys 228's loop, started from its last unloading, with node 5
    /// `unexplained` over the first 6 s).
    ///
    /// A held-out prediction above every load its fold trained on extrapolates each node's
    /// law, and a convex law extrapolated looks like a broken node: on zoo-hys seed 249 the odd
    /// fold never trained above 89 % of the peak, and node 10 was named `unexplained` in the
    /// loop's case. A node the
    /// `unexplained` rule names must show on these folds too (see `diagnose`); the selection
    /// keeps its own (moving them for the whole selection named false drifts on zoo-hys seeds
    /// 228 and 236).
    pub fn peak_shared(&self) -> Option<Context<'a>> {
        let ds = self.ds;
        let mut best = fold_peak_share(ds, &self.block);
        if best >= FOLD_PEAK_SHARE {
            return None;
        }
        let target = block_target(ds);
        let mut found = None;
        for q in [0.25, 0.5, 0.75] {
            let (block, n_blocks) = blocks_from(ds, target, q * target);
            let share = fold_peak_share(ds, &block);
            if share > best {
                best = share;
                found = Some((block, n_blocks));
            }
        }
        let (block, n_blocks) = found?;
        let mut ctx = self.derived(block, self.coarse);
        ctx.n_blocks = n_blocks;
        Some(ctx)
    }

    /// A copy of this context with other blocks and search sparseness (caches empty).
    fn derived(&self, block: Vec<usize>, coarse: usize) -> Context<'a> {
        Context {
            ds: self.ds,
            g_obs: self.g_obs.clone(),
            dom_obs: self.dom_obs.clone(),
            usable: self.usable.clone(),
            trial_shift: self.trial_shift.clone(),
            block,
            n_blocks: self.n_blocks,
            creep_tau_max: self.creep_tau_max,
            creep_tau_min: self.creep_tau_min,
            hyst_r_max: self.hyst_r_max,
            load_scale: self.load_scale.clone(),
            force_deadband: self.force_deadband,
            force_model: self.force_model.clone(),
            level_bins: self.level_bins.clone(),
            observed: Mutex::new(Vec::new()),
            spikes: self.spikes,
            grids: Mutex::new(Vec::new()),
            coarse,
        }
    }

    /// Every how many samples the parameter search looks: about 50 per second, and at most
    /// [`SEARCH_SAMPLES`] samples in all (a long recording is searched on a sparser grid; each
    /// evaluation still runs the effects' states through every sample, and the held-out
    /// predictions use every sample).
    pub fn search_stride(&self) -> usize {
        let by_rate = ((1.0 / self.ds.dt() / 50.0).round() as usize).max(1);
        let s = by_rate.max(self.ds.len().div_ceil(SEARCH_SAMPLES)) * self.coarse;
        // A multiple of the state stride, so the fit's samples lie on the states' grid.
        s.div_ceil(self.state_stride()) * self.state_stride()
    }

    /// Every how many training samples a held-out evaluation fits the per-node parameters on:
    /// 1 up to [`FIT_SAMPLES`] samples, every second sample of a 10-minute recording at 100 Hz.
    pub fn held_out_stride(&self) -> usize {
        self.ds.len().div_ceil(FIT_SAMPLES).max(1)
    }

    /// The hysteresis width that acts for a fitted `r` (N: a play's half-width, a Bouc-Wen
    /// state's saturation): at most [`Context::hyst_r_max`], and at least the load cell's noise
    /// (`force_deadband`, three of its standard deviations): a loop narrower than the noise of
    /// the force it is read against cannot be told from that noise, and on a law that rises
    /// steeply from zero load it fits the noise and lag near zero as a "loop" (zoo-log 231's
    /// null case: plays 0.018 N wide).
    pub fn hyst_r(&self, r: f64) -> f64 {
        r.min(self.hyst_r_max)
            .max(self.force_deadband.min(self.hyst_r_max))
    }

    /// On which grid the parameter search runs the effects' states (creep, hysteresis): every
    /// sample, or every second or later one when a recording is longer than
    /// [`STATE_SAMPLES`] (a 10-minute recording at 100 Hz: every fourth sample, 25 Hz). The
    /// held-out predictions and the final fit run them on every sample.
    pub fn state_stride(&self) -> usize {
        self.ds.len().div_ceil(STATE_SAMPLES).max(1) * self.coarse
    }

    /// Every `step`-th sample's time, interval (the first: `step` median steps) and the force
    /// the model is driven with: the grid the effects' states run on, built once per step.
    pub fn state_grid(&self, step: usize) -> Arc<StateGrid> {
        let step = step.max(1);
        if let Ok(grids) = self.grids.lock() {
            if let Some((_, g)) = grids.iter().find(|(s, _)| *s == step) {
                return g.clone();
            }
        }
        let ds = self.ds;
        let t: Vec<f64> = ds.t.iter().step_by(step).copied().collect();
        let mut dt: Vec<f64> = Vec::with_capacity(t.len());
        dt.push(step as f64 * ds.dt());
        dt.extend(t.windows(2).map(|w| (w[1] - w[0]).max(1e-9)));
        let force = self.force_model.iter().step_by(step).copied().collect();
        let g = Arc::new(StateGrid { t, dt, force });
        if let Ok(mut grids) = self.grids.lock() {
            grids.push((step, g.clone()));
        }
        g
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

/// Each sample's cross-validation block (see [`Context::block`]).
pub fn block_of(ds: &Dataset) -> Vec<usize> {
    blocks(ds).0
}

/// Contiguous time blocks, cut at trial changes too, about 1/24 of the recording each (at
/// least 2 s and 20 samples); consecutive blocks alternate between the two folds.
fn blocks(ds: &Dataset) -> (Vec<usize>, usize) {
    blocks_from(ds, block_target(ds), 0.0)
}

/// The blocks' length (s).
fn block_target(ds: &Dataset) -> f64 {
    (ds.duration() / 24.0).max(2.0)
}

/// The least share of the recording's peak load each fold's largest load must reach before
/// the `unexplained` rule holds the models out on other folds (see [`Context::peak_shared`]).
pub const FOLD_PEAK_SHARE: f64 = 0.9;

/// The smaller of the two folds' largest loads, as a share of the recording's peak (1 without
/// a load).
fn fold_peak_share(ds: &Dataset, block: &[usize]) -> f64 {
    let mut peak = [0.0f64; 2];
    for (f, b) in ds.force.iter().zip(block) {
        peak[b % 2] = peak[b % 2].max(*f);
    }
    let top = ds.max_force();
    if top > 0.0 {
        peak[0].min(peak[1]) / top
    } else {
        1.0
    }
}

/// [`blocks`] cut every `target` seconds, the first block `first` seconds shorter.
#[allow(clippy::needless_range_loop)]
fn blocks_from(ds: &Dataset, target: f64, first: f64) -> (Vec<usize>, usize) {
    let len = ds.len();
    let mut block = vec![0usize; len];
    let mut b = 0usize;
    let mut start_t = ds.t[0] - first;
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

/// The median time a press takes to rise (s): over each span above 5 % of the peak force that
/// reaches 20 % of it (smaller spans are the load cell's noise or a touch), the time from the
/// span's start to its first sample at 90 % of the span's own peak. 0 without such a span.
pub fn median_rise_time(ds: &Dataset) -> f64 {
    let fmax = ds.max_force();
    let on = 0.05 * fmax;
    let mut rises = Vec::new();
    let mut i = 0;
    while i < ds.len() {
        if ds.force[i] <= on {
            i += 1;
            continue;
        }
        let start = i;
        while i < ds.len() && ds.force[i] > on {
            i += 1;
        }
        let span = &ds.force[start..i];
        let peak = span.iter().copied().fold(0.0, f64::max);
        if peak >= 0.2 * fmax {
            if let Some(j) = span.iter().position(|&f| f >= 0.9 * peak) {
                rises.push(ds.t[start + j] - ds.t[start]);
            }
        }
    }
    if rises.is_empty() {
        return 0.0;
    }
    rises.sort_by(f64::total_cmp);
    rises[rises.len() / 2]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testdata::presses;

    #[test]
    fn the_unexplained_rule_gets_folds_that_train_on_the_largest_loads() {
        let mut ds = presses();
        let target = block_target(&ds);
        // Presses to 5 N everywhere, and to 10 N only in the middle of even blocks: with the
        // plain cuts the odd fold never trains above half the peak.
        for (t, f) in ds.t.iter().zip(ds.force.iter_mut()) {
            let phase = t / target;
            let within = phase - phase.floor();
            *f = if (phase.floor() as usize).is_multiple_of(2) && (0.4..0.6).contains(&within) {
                10.0
            } else {
                f.min(5.0)
            };
        }
        let ctx = Context::new(&ds);
        assert!(fold_peak_share(&ds, &ctx.block) < 0.6);
        let moved = ctx.peak_shared().expect("folds that share the peak");
        assert!(fold_peak_share(&ds, &moved.block) > 0.99);
        assert_eq!(moved.n_blocks, moved.block[ds.len() - 1] + 1);
        let steps = moved.block.windows(2);
        assert!(steps.clone().all(|w| w[1] == w[0] || w[1] == w[0] + 1));
        // A recording whose folds already share the peak keeps them.
        let ds = presses();
        let ctx = Context::new(&ds);
        assert!(fold_peak_share(&ds, &ctx.block) >= FOLD_PEAK_SHARE);
        assert!(ctx.peak_shared().is_none());
    }

    #[test]
    fn the_longest_loaded_span_bounds_creep() {
        let ds = presses();
        // The longest press: two 2 s ramps around a 1 s hold, above 10 % of the 14 N peak.
        let span = longest_loaded_span(&ds);
        assert!(span > 4.0 && span < 5.0, "{span}");
    }

    #[test]
    fn the_median_rise_time_bounds_creep_from_below() {
        let mut ds = presses();
        // 1 s at rest, a 1 s ramp to 10 N, 2 s held, 1 s down, over and over: from 5 % to 90 %
        // of the peak takes 0.85 s. A one-sample blip to 1 N (under 20 % of the peak) in each
        // rest is not a press.
        for (i, f) in ds.force.iter_mut().enumerate() {
            let s = (i % 500) as f64 * 0.01;
            *f = match s {
                s if s < 1.0 => {
                    if i % 500 == 50 {
                        1.0
                    } else {
                        0.0
                    }
                }
                s if s < 2.0 => 10.0 * (s - 1.0),
                s if s < 4.0 => 10.0,
                s => 10.0 * (5.0 - s),
            };
        }
        let rise = median_rise_time(&ds);
        assert!((rise - 0.85).abs() < 0.015, "{rise}");
    }

    #[test]
    fn a_loop_is_no_narrower_than_the_load_cells_noise_nor_wider_than_a_third_of_the_peak() {
        let mut ds = presses();
        // A load cell whose first differences alternate by 0.04 N: deadband 3 x 0.04 / 0.954.
        for (i, f) in ds.force.iter_mut().enumerate() {
            *f += if i % 2 == 0 { 0.02 } else { -0.02 };
        }
        let ctx = Context::new(&ds);
        assert!(
            ctx.force_deadband > 0.1 && ctx.force_deadband < 0.2,
            "{}",
            ctx.force_deadband
        );
        assert_eq!(ctx.hyst_r(0.01), ctx.force_deadband);
        assert_eq!(ctx.hyst_r(1.0), 1.0);
        assert_eq!(ctx.hyst_r(100.0), ctx.hyst_r_max);
    }

    #[test]
    fn the_rest_before_the_first_press_can_be_shared_by_both_folds() {
        // 3 s of rest before the first press, inside the first block: its first half joins
        // the second block (the other fold); every other sample keeps its block.
        let ds = crate::testdata::presses_with_rest(3.0);
        let ctx = Context::new(&ds);
        let Some(shared) = ctx.virgin_rest_shared() else {
            panic!("the virgin rest lies in the first block alone");
        };
        let first = ds.force.iter().position(|&f| f > 0.02 * ds.max_force());
        let first = first.unwrap_or(0);
        assert!(first >= 40);
        assert_eq!(ctx.block[0], 0);
        assert_eq!(shared.block[0], 1);
        assert_eq!(shared.block[first / 2 - 1], 1);
        assert_eq!(shared.block[first / 2..], ctx.block[first / 2..]);
        let folds: std::collections::BTreeSet<usize> = (0..first).map(|i| shared.fold(i)).collect();
        assert_eq!(folds.len(), 2);
        // A recording that starts under load has no virgin rest to share.
        let loaded = crate::testdata::presses_with_rest(0.0);
        assert!(Context::new(&loaded).virgin_rest_shared().is_none());
    }
}
