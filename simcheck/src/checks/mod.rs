//! Physics an effect must show beyond a lower held-out error: thermal drift inferred without a
//! temperature column must also improve the no-load samples (and, across mountings, the
//! residual within them); thermal drift must act as a gain; hysteresis must be a loop and
//! rate-independent (a set alone: see [`crate::set`]).

use crate::cv::{Cv, Verdict};
use crate::data::Dataset;
use crate::effects::{Config, EffectKind};
use crate::noise::NoiseModel;

mod hysteresis;
pub(crate) use hysteresis::force_rate;
use hysteresis::rate_independent;
pub use hysteresis::{
    loop_kept_within_uncertainty, loop_removed_se, loop_removed_share, loop_share, ramp_betas,
    ramp_betas_se, MIN_LOOP_SHARE, RATE_RATIO,
};

/// Physics an effect must show beyond a lower error: thermal drift inferred without a
/// temperature column must also improve the no-load samples (temperature moves unloaded
/// nodes; creep and hysteresis cannot) and, on a recording of several mountings, the residual
/// within them ([`within_trial_beta`]); thermal drift must act as a gain ([`gain_betas`]);
/// hysteresis must be a loop and rate-independent, or, as a set alone (`form`, the
/// candidate's configuration), move the level at rest at new peaks only
/// ([`crate::set::shows_set`]); creep must act under held loads ([`crate::hold`]).
pub fn signature_check(
    ds: &Dataset,
    noise: &NoiseModel,
    e: EffectKind,
    form: &Config,
    before: &Cv,
    after: &Cv,
    v: &mut Verdict,
) {
    // With a temperature column the correlation with the recorded temperature is the evidence;
    // without one, a slow common-mode factor could also mimic slow creep, so it must show on
    // unloaded samples too: on the readings as recorded (the wander taken out of them took a
    // drift's rest share with it).
    if e == EffectKind::ThermalDrift && ds.temp.is_none() {
        let rest_t = rest_block_t_as_recorded(ds, noise, before, after);
        if rest_t < MIN_REST_T {
            v.accepted = false;
            v.keep = false;
        }
        // Between mountings, a slow factor sampled at a few knots can take the steps each
        // remounting leaves: it must also lower the residual within the mountings.
        if ds.trial_recorded && ds.n_trials >= 2 {
            let beta = within_trial_beta(ds, noise, before, after);
            v.within_trial_beta = beta.is_finite().then_some(beta);
            if beta.is_finite() && beta <= 0.5 {
                v.accepted = false;
                v.keep = false;
            }
        }
    }
    // Thermal drift is a gain: it must carry the residual alike near the rest level and far
    // above it (an additive wander common to the nodes, fitted as a factor, does not).
    if e == EffectKind::ThermalDrift {
        let ([rest, loaded], se_rest) = gain_betas(ds, noise, before, after);
        v.gain_betas = Some([rest, loaded]);
        v.gain_rest_se = se_rest.is_finite().then_some(se_rest);
        if rest.is_finite() && loaded.is_finite() {
            // Matched at rest and overshot under load: a wander fitted as a factor. With a
            // temperature column the factor follows the recorded temperature, not a wander, so
            // there it counts, like the opposite case below, only when the rest beta is measured
            // well enough to say so (a per-node wander at rest can leave it uncertain).
            let rest_uncertain =
                ds.temp.is_some() && rest - loaded / GAIN_RATIO[0] <= 2.0 * se_rest;
            let wander_like =
                loaded <= 0.0 || (rest > 0.0 && loaded < GAIN_RATIO[0] * rest && !rest_uncertain);
            // Far more under load than at rest (an effect of the load standing in for a
            // drift), counted only when the rest beta is measured well enough to say so: a
            // wander at rest can make it uncertain.
            let load_like =
                loaded > GAIN_RATIO[1] * rest && loaded / GAIN_RATIO[1] - rest > 2.0 * se_rest;
            if wander_like || load_like {
                v.accepted = false;
                v.keep = false;
            }
        }
    }
    if e == EffectKind::Creep {
        crate::hold::hold_check(ds, before, after, v);
    }
    // A set alone must move the level at rest across the presses to a new peak only (a loop
    // added on top of a set is judged as a loop).
    if e == EffectKind::Hysteresis && form.hyst_set && form.hysteresis.is_none() {
        let deadband = crate::context::force_deadband(&ds.force);
        if !crate::set::shows_set(ds, deadband, before) {
            v.accepted = false;
            v.keep = false;
        }
        return;
    }
    // Hysteresis must be rate-independent (a loop that grows with the loading rate is a lag),
    // and a loop: what it changes must follow the loading direction.
    if e == EffectKind::Hysteresis {
        let [slow, fast] = ramp_betas(ds, before, after);
        v.ramp_betas = Some([slow, fast]);
        v.loop_share = Some(loop_share(ds, before, after));
        let removed = loop_removed_share(ds, before, after);
        v.loop_removed = Some(removed);
        let is_loop = removed >= MIN_LOOP_SHARE;
        let in_band = (RATE_RATIO[0]..=RATE_RATIO[1]).contains(&(fast / slow));
        if slow > 0.0 && fast > 0.0 && !in_band {
            // Outside the band the betas' standard errors decide (computed only here: the
            // noise views cost a pass each).
            let (_, se) = ramp_betas_se(ds, noise, before, after);
            v.ramp_betas_se = Some(se);
        }
        if !(rate_independent(v) && is_loop) {
            v.accepted = false;
            v.keep = false;
        }
    }
}

/// Thermal drift acts as a gain: the ratio of its betas far above the rest level and at rest
/// must lie in this band, a factor of three either way. Set on training seeds: a shared wander
/// fitted by the latent factor gave 0.15-0.20 (zoo-sat seeds 2, 3), true drifts 0.99-1.17 (the
/// reference world, seed 1) and 2.2 (zoo-sat's two-lag quadratic law with creep, seed 3, where
/// the wander at rest makes the rest beta uncertain).
pub const GAIN_RATIO: [f64; 2] = [1.0 / 3.0, 3.0];

/// How much of the current residual a thermal drift's change explains at rest and far above
/// the rest level. With `r` the current held-out residual and `d` the change the drift makes
/// to the prediction, `beta = sum d (-r) / sum d^2` on no-load samples (force at most 2 % of
/// its peak, every node) and on loaded node-samples (force at least a quarter of the peak,
/// the half of them whose reading lies furthest from the node's rest level). A gain change
/// moves both in proportion to the reading and has about the same beta on each; an additive
/// wander common to the nodes, fitted by a factor, is matched at rest and overshot (or missed)
/// under load. `NaN` where the drift changes nothing (a drift of the force term only leaves
/// the rest level alone: the check does not apply).
pub fn gain_betas(ds: &Dataset, noise: &NoiseModel, before: &Cv, after: &Cv) -> ([f64; 2], f64) {
    let (len, n) = (ds.len(), ds.n);
    let fmax = ds.max_force().max(1e-12);
    let dom: Vec<f64> = ds.y.iter().map(|&y| ds.map.dom(y)).collect();
    let rest: Vec<bool> = ds.force.iter().map(|&f| f <= 0.02 * fmax).collect();
    let level: Vec<f64> = crate::parallel::map(n, |k| {
        let mut v: Vec<f64> = (0..len)
            .filter(|&i| rest[i])
            .map(|i| dom[i * n + k])
            .collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    });
    let mut far: Vec<(f64, usize)> = Vec::new();
    for i in (0..len).filter(|&i| ds.force[i] >= 0.25 * fmax) {
        for (k, lk) in level.iter().enumerate() {
            far.push(((dom[i * n + k] - lk).abs(), i * n + k));
        }
    }
    crate::parallel::sort_by(&mut far, |a, b| b.0.total_cmp(&a.0));
    far.truncate(far.len() / 2);
    let recorded = |j: usize| resid_as_recorded(noise, before, j, n);
    let beta = |idx: &mut dyn Iterator<Item = usize>| -> (f64, f64) {
        let (mut num, mut den, mut count) = (0.0, 0.0, 0usize);
        for j in idx {
            let d = after.resid[j] - before.resid[j];
            num -= d * recorded(j);
            den += d * d;
            count += 1;
        }
        (num / den, den / count.max(1) as f64)
    };
    let (b_rest, d_rest) = beta(
        &mut (0..len)
            .filter(|&i| rest[i])
            .flat_map(|i| (0..n).map(move |k| i * n + k)),
    );
    let (b_far, d_far) = beta(&mut far.iter().map(|p| p.1));
    // A change at rest under 1 % of the loaded one (per sample, squared): the rest says nothing.
    if d_rest.is_nan() || d_far.is_nan() || d_far <= 0.0 || d_rest <= 0.01 * d_far {
        return ([f64::NAN; 2], f64::NAN);
    }
    // The rest beta's standard error in the noise model (its common wander included):
    // `sqrt(d' C d) / d' d` over the rest samples.
    let d_at_rest: Vec<f64> = (0..len * n)
        .map(|j| {
            if rest[j / n.max(1)] {
                after.resid[j] - before.resid[j]
            } else {
                0.0
            }
        })
        .collect();
    let dd: f64 = d_at_rest.iter().map(|v| v * v).sum();
    let se_rest = noise.quadratic(&d_at_rest, n, ds.dt()).sqrt() / dd.max(1e-300);
    ([b_rest, b_far], se_rest)
}

/// The block t statistic of the held-out SSE's fall on no-load samples (force at most 2 % of
/// its peak) with the wander taken out of the readings put back (`Verdict::rest_block_t` is
/// on the readings without it).
fn rest_block_t_as_recorded(ds: &Dataset, noise: &NoiseModel, before: &Cv, after: &Cv) -> f64 {
    let w = &noise.wander.taken_out;
    if w.is_empty() {
        return crate::cv::block_t_of(&before.rest_block_sse, &after.rest_block_sse);
    }
    let n = ds.n;
    let limit = 0.02 * ds.max_force();
    let blocks = before.block_sse.len();
    let (mut b, mut a) = (vec![0.0; blocks], vec![0.0; blocks]);
    let block = crate::context::block_of(ds);
    for i in (0..ds.len()).filter(|&i| ds.force[i] <= limit) {
        for k in 0..n {
            let idx = i * n + k;
            if before.resid[idx] == 0.0 && after.resid[idx] == 0.0 {
                continue;
            }
            b[block[i]] += (before.resid[idx] + w[i]).powi(2);
            a[block[i]] += (after.resid[idx] + w[i]).powi(2);
        }
    }
    crate::cv::block_t_of(&b, &a)
}

/// The held-out residual at node-sample `idx` (`n` nodes) as recorded: the common wander taken
/// out of the readings put back (it took a drift's rest share with it).
fn resid_as_recorded(noise: &NoiseModel, before: &Cv, idx: usize, n: usize) -> f64 {
    let w = &noise.wander.taken_out;
    before.resid[idx] + w.get(idx / n.max(1)).copied().unwrap_or(0.0)
}

/// How much of the residual within each mounting (trial) a latent drift's change carries:
/// with `r` the current held-out residual as recorded (the common wander put back, as in
/// [`gain_betas`]) and `d` the change, each taken relative to its mean over the trial per node,
/// `beta = sum d (-r) / sum d^2`. The change lowers the residual's SSE within the trials by
/// `(2 beta - 1) sum d^2`: above 0.5 it helps there, at or below it its gain is all between the
/// trials, where remounting steps a factor can stand in for are. `NaN` when the change does not
/// move within a trial.
pub fn within_trial_beta(ds: &Dataset, noise: &NoiseModel, before: &Cv, after: &Cv) -> f64 {
    let (len, n, trials) = (ds.len(), ds.n, ds.n_trials.max(1));
    let recorded = |idx: usize| resid_as_recorded(noise, before, idx, n);
    let used = |idx: usize| before.resid[idx] != 0.0 || after.resid[idx] != 0.0;
    // Per trial and node: the sums of d and r and the count.
    let mut sums = vec![(0.0, 0.0, 0usize); trials * n];
    for i in 0..len {
        let j = ds.trial[i].min(trials - 1);
        for k in 0..n {
            let idx = i * n + k;
            if used(idx) {
                let s = &mut sums[j * n + k];
                s.0 += after.resid[idx] - before.resid[idx];
                s.1 += recorded(idx);
                s.2 += 1;
            }
        }
    }
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..len {
        let j = ds.trial[i].min(trials - 1);
        for k in 0..n {
            let idx = i * n + k;
            let (sd, sr, c) = sums[j * n + k];
            if !used(idx) || c == 0 {
                continue;
            }
            let d = after.resid[idx] - before.resid[idx] - sd / c as f64;
            let r = recorded(idx) - sr / c as f64;
            num -= d * r;
            den += d * d;
        }
    }
    if den > 0.0 {
        num / den
    } else {
        f64::NAN
    }
}

/// Block t statistic thermal drift needs on no-load samples.
pub const MIN_REST_T: f64 = 2.0;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effects::Config;
    use crate::testdata::presses;

    fn cv(resid: Vec<f64>) -> Cv {
        crate::testdata::cv_of(resid)
    }

    #[test]
    fn a_gain_carries_the_residual_at_rest_and_under_load_and_an_offset_does_not() {
        let mut ds = presses();
        let fmax = ds.max_force();
        // Readings in counts: 100 at rest, 100 + 40 F under load (one node).
        ds.y = ds.force.iter().map(|f| 100.0 + 40.0 * f).collect();
        ds.map = crate::data::ReadoutMap::from_readout(&taxel_sim::SensorModel::default().readout);
        let dom: Vec<f64> = ds.y.iter().map(|&y| ds.map.dom(y)).collect();
        let slow: Vec<f64> = ds.t.iter().map(|t| (t / 30.0).sin()).collect();
        // A gain drift of 1 % times `slow`: the residual it leaves, and the change that undoes it.
        let gain_r: Vec<f64> = dom.iter().zip(&slow).map(|(y, s)| -0.01 * s * y).collect();
        let after = cv(vec![0.0; ds.len()]);
        let noise = NoiseModel::white(1, 1.0);
        let ([rest, far], _) = gain_betas(&ds, &noise, &cv(gain_r.clone()), &after);
        assert!(
            (rest - 1.0).abs() < 1e-9 && (far - 1.0).abs() < 1e-9,
            "{rest} {far}"
        );
        // An additive offset of the rest level's size, fitted as a gain that matches it at rest:
        // the change overshoots under load by the reading's ratio to its rest level.
        let offset_r: Vec<f64> = slow.iter().zip(&dom).map(|(s, _)| -s).collect();
        let change = cv(offset_r
            .iter()
            .zip(&dom)
            .map(|(r, y)| r - r * y / dom[0])
            .collect());
        let ([rest, far], _) = gain_betas(&ds, &noise, &cv(offset_r), &change);
        assert!(fmax > 0.0 && (rest - 1.0).abs() < 0.05, "{rest}");
        assert!(far / rest < GAIN_RATIO[0], "{rest} {far}");
    }

    #[test]
    fn a_recorded_drift_is_refused_as_a_wander_only_on_a_rest_beta_measured_well() {
        let mut ds = presses();
        ds.y = ds.force.iter().map(|f| 100.0 + 40.0 * f).collect();
        ds.map = crate::data::ReadoutMap::from_readout(&taxel_sim::SensorModel::default().readout);
        let dom: Vec<f64> = ds.y.iter().map(|&y| ds.map.dom(y)).collect();
        let slow: Vec<f64> = ds.t.iter().map(|t| (t / 30.0).sin()).collect();
        // The offset of the test above, fitted as a gain: matched at rest, overshot under load.
        let offset_r: Vec<f64> = slow.iter().map(|s| -s).collect();
        let change: Vec<f64> = offset_r
            .iter()
            .zip(&dom)
            .map(|(r, y)| r - r * y / dom[0])
            .collect();
        let (mut before, mut after) = (cv(offset_r), cv(change));
        // No-load SSE per block falling in every block: the latent drift's rest test passes,
        // so what refuses it below is the gain check.
        before.rest_block_sse = vec![10.0, 11.0, 9.0, 10.5];
        after.rest_block_sse = vec![1.0, 1.2, 0.9, 1.1];
        let verdict = || Verdict {
            rmse_before: 1.0,
            rmse_after: 0.9,
            rel_gain: 0.19,
            block_t: 5.0,
            blocks_improved: 1.0,
            rank_z: 4.0,
            n_eff: 100.0,
            ic_gain: 10.0,
            accepted: true,
            rest_block_t: 5.0,
            rest_rel_gain: 0.2,
            keep: true,
            weighted_t: 5.0,
            change_blocks: 10.0,
            ..Verdict::default()
        };
        let checked = |ds: &Dataset, var: f64| {
            let mut v = verdict();
            let noise = NoiseModel::white(1, var);
            signature_check(
                ds,
                &noise,
                EffectKind::ThermalDrift,
                &Config::base(1.0, 0.0),
                &before,
                &after,
                &mut v,
            );
            v
        };
        // Without a temperature column (the latent drift's case) the bound holds however
        // uncertain the rest beta.
        ds.temp = None;
        for var in [1e-6, 1e6] {
            let v = checked(&ds, var);
            let [rest, far] = v.gain_betas.expect("betas");
            assert!(far / rest < GAIN_RATIO[0], "{rest} {far}");
            assert!(!v.accepted && !v.keep, "latent, noise {var}: {v:?}");
        }
        // With one, a rest beta measured well is still refused, an uncertain one is not.
        ds.temp = Some(vec![25.0; ds.len()]);
        let sharp = checked(&ds, 1e-6);
        assert!(!sharp.accepted && !sharp.keep, "{sharp:?}");
        let vague = checked(&ds, 1e6);
        assert!(vague.gain_rest_se.is_some_and(|se| se > 1.0), "{vague:?}");
        assert!(vague.accepted && vague.keep, "{vague:?}");
    }

    #[test]
    fn a_drift_must_lower_the_residual_within_mountings_not_only_between_them() {
        let mut ds = presses();
        let len = ds.len();
        ds.n_trials = 4;
        ds.trial = (0..len).map(|i| i * 4 / len).collect();
        ds.trial_recorded = true;
        let noise = NoiseModel::white(1, 1.0);
        let slow: Vec<f64> = (0..len).map(|i| i as f64 / len as f64).collect();
        // A drift the residual really has: the change that takes it out carries it within the
        // trials too.
        let drift: Vec<f64> = slow.iter().map(|u| 2.0 * u).collect();
        let beta = within_trial_beta(&ds, &noise, &cv(drift), &cv(vec![1e-9; len]));
        assert!((beta - 1.0).abs() < 1e-6, "{beta}");
        // Remounting steps (constant within each trial) taken by a smooth ramp: its gain is
        // all between the trials.
        let steps: Vec<f64> = ds.trial.iter().map(|&j| [0.0, 1.5, 0.5, 2.0][j]).collect();
        let after: Vec<f64> = steps.iter().zip(&slow).map(|(r, u)| r - 2.0 * u).collect();
        let beta = within_trial_beta(&ds, &noise, &cv(steps), &cv(after));
        assert!(beta.abs() < 1e-6, "{beta}");
    }
}
