//! The recorded temperature beside the common-mode wander: what a thermal drift leaves at rest
//! follows the lagged temperature, and is left in the readings for the drift to explain rather
//! than taken out as wander (see the parent module).

use super::{run, wander_grid, MIN_TAU_S, TAUS_S};
use crate::data::Dataset;

/// What the recorded temperature explains of the wander's observations `obs` (variances `r`,
/// at the samples of `ds`; `r0` the wander grid's unit), jointly with the wander: for every
/// point of the wander's grid and every first-order lag of the temperature on [`TAUS_S`] (or
/// none), the temperature's coefficient by generalised least squares on the filter's
/// innovations (each trial's mean out of the lagged temperature, as out of the observations).
/// Returns the best joint fit's share at every sample, how much it lowers the best
/// likelihood's deviance without the temperature (twice the negative log-likelihood: a squared
/// z of the coefficient under the wander), and its lag (s); `None` without a temperature column.
pub(super) fn temperature_share(
    ds: &Dataset,
    obs: &[f64],
    r: &[f64],
    r0: f64,
) -> Option<(Vec<f64>, f64, f64)> {
    let temp = ds.temp.as_ref()?;
    let t = &ds.t;
    let lags: Vec<f64> = std::iter::once(0.0)
        .chain(
            TAUS_S
                .iter()
                .copied()
                .filter(|l| *l >= MIN_TAU_S && *l <= 0.5 * ds.duration().max(1.0)),
        )
        .collect();
    let xs: Vec<Vec<f64>> = lags.iter().map(|&lag| lagged(ds, temp, lag, r)).collect();
    let grid = wander_grid(r0, ds.duration());
    // The filter over the observed samples only: between two of them it only propagates the
    // state over the gap, which one step over the gap's length does alike.
    let seen: Vec<usize> = (0..obs.len()).filter(|&i| r[i].is_finite()).collect();
    let pick = |v: &[f64]| -> Vec<f64> { seen.iter().map(|&i| v[i]).collect() };
    let (tc, oc, rc) = (pick(t), pick(obs), pick(r));
    let xc: Vec<Vec<f64>> = xs.iter().map(|x| pick(x)).collect();
    // Per grid point: the deviance without the temperature, and with it at each lag.
    let fits = crate::parallel::map(grid.len(), |g| {
        let (var, tau) = grid[g];
        let po = run(&tc, &oc, &rc, var, tau);
        let with: Vec<(f64, f64)> = xc
            .iter()
            .map(|x| {
                let px = run(&tc, x, &rc, var, tau);
                let (mut sxx, mut sxy) = (0.0, 0.0);
                for i in 0..oc.len() {
                    let s = px.pp[i] + rc[i];
                    let (eo, ex) = (oc[i] - po.mp[i], x[i] - px.mp[i]);
                    sxx += ex * ex / s;
                    sxy += ex * eo / s;
                }
                if sxx > 0.0 {
                    (po.nll - sxy * sxy / sxx, sxy / sxx)
                } else {
                    (po.nll, 0.0)
                }
            })
            .collect();
        (po.nll, with)
    });
    let without = fits.iter().map(|f| f.0).fold(f64::INFINITY, f64::min);
    let mut best = (f64::INFINITY, 0usize, 0.0);
    for (_, with) in &fits {
        for (l, &(nll, beta)) in with.iter().enumerate() {
            if nll < best.0 {
                best = (nll, l, beta);
            }
        }
    }
    let (nll, l, beta) = best;
    if !nll.is_finite() {
        return None;
    }
    let share = xs[l].iter().map(|v| beta * v).collect();
    Some((share, without - nll, lags[l]))
}

/// The temperature `temp` through a first-order lag of `lag` seconds (0: none), started at its
/// first value, with each trial's mean over the observed samples (`r` finite) taken out.
fn lagged(ds: &Dataset, temp: &[f64], lag: f64, r: &[f64]) -> Vec<f64> {
    let t = &ds.t;
    let mut state = temp.first().copied().unwrap_or(0.0);
    let mut x: Vec<f64> = (0..temp.len())
        .map(|i| {
            if lag == 0.0 {
                state = temp[i];
            } else if i > 0 {
                let dt = (t[i] - t[i - 1]).max(0.0);
                state += (temp[i] - state) * (1.0 - (-dt / lag).exp());
            }
            state
        })
        .collect();
    let trials = ds.n_trials.max(1);
    let (mut sw, mut swx) = (vec![0.0; trials], vec![0.0; trials]);
    for (i, v) in x.iter().enumerate() {
        if r[i].is_finite() && r[i] > 0.0 {
            sw[ds.trial[i]] += 1.0 / r[i];
            swx[ds.trial[i]] += v / r[i];
        }
    }
    for (i, v) in x.iter_mut().enumerate() {
        *v -= swx[ds.trial[i]] / sw[ds.trial[i]].max(1e-300);
    }
    x
}

#[cfg(test)]
mod tests {
    use super::super::tests::{common_on_four, four_nodes};
    use super::super::{CommonWander, TEMPERATURE_BAR};
    use crate::context::Context;

    /// A slow temperature (24 C plus a 3 K wave of 100 s) at every sample of the four nodes'
    /// recording, and the same through a first-order lag of `lag_s`.
    fn temperature(t: &[f64], lag_s: f64) -> (Vec<f64>, Vec<f64>) {
        let temp: Vec<f64> = t
            .iter()
            .map(|t| 24.0 + 3.0 * (2.0 * std::f64::consts::PI * t / 100.0).sin())
            .collect();
        let mut state = temp[0];
        let lagged = temp
            .iter()
            .zip(
                t.windows(2)
                    .map(|w| w[1] - w[0])
                    .chain(std::iter::once(0.0)),
            )
            .map(|(&temp, dt)| {
                let now = state;
                state += (temp - state) * (1.0 - (-dt / lag_s).exp());
                now
            })
            .collect();
        (temp, lagged)
    }

    #[test]
    fn a_rest_level_that_follows_the_recorded_temperature_is_left_for_the_drift() {
        // A common wander (sd 1, 20 s) and white noise, plus what a drift leaves at rest: 3
        // counts per kelvin of the temperature lagged 30 s, on every node.
        let base = four_nodes(&[]);
        let (temp, lagged) = temperature(&base.t, 30.0);
        let mut extra = common_on_four(11, 1.0, 20.0);
        for (idx, e) in extra.iter_mut().enumerate() {
            *e += 3.0 * (lagged[idx / 4] - 24.0);
        }
        let mut ds = four_nodes(&extra);
        let resid: Vec<f64> = ds.y.iter().map(|y| 100.0 - y).collect();
        // Without the temperature column the drift's rest share is taken for wander.
        let blind = CommonWander::estimate(&Context::new(&ds), &resid, 1.0, 0.0);
        assert!(
            blind.variance >= 4.0 && !blind.temperature_left_in,
            "{blind:?}"
        );
        ds.temp = Some(temp);
        let ctx = Context::new(&ds);
        let mut cw = CommonWander::estimate(&ctx, &resid, 1.0, 0.0);
        assert!(cw.temperature_left_in, "{cw:?}");
        assert!(cw.temperature_deviance_gain >= TEMPERATURE_BAR, "{cw:?}");
        assert!((16.0..=64.0).contains(&cw.temperature_lag_s), "{cw:?}");
        // What is taken out is the wander, not the drift's rest share.
        assert!(cw.variance < 0.5 * blind.variance, "{cw:?}");
        if cw.take_out(&ctx, &resid).is_some() {
            let (mut sxy, mut sxx) = (0.0, 0.0);
            for (w, l) in cw.taken_out.iter().zip(&lagged) {
                sxy += w * (l - 24.0);
                sxx += (l - 24.0) * (l - 24.0);
            }
            // The taken-out series holds minus the readings' extra (a residual's sign).
            assert!((sxy / sxx).abs() < 0.3, "{}", sxy / sxx);
        }
    }

    #[test]
    fn a_temperature_with_no_effect_leaves_the_wander_as_it_was() {
        // A common wander (sd 2, 20 s) and a recorded temperature that does nothing: the
        // wander is estimated and taken out as without the column.
        let extra = common_on_four(12, 2.0, 20.0);
        let mut ds = four_nodes(&extra);
        let resid: Vec<f64> = ds.y.iter().map(|y| 100.0 - y).collect();
        let blind = CommonWander::estimate(&Context::new(&ds), &resid, 1.0, 0.0);
        ds.temp = Some(temperature(&ds.t, 30.0).0);
        let cw = CommonWander::estimate(&Context::new(&ds), &resid, 1.0, 0.0);
        assert!(!cw.temperature_left_in, "{cw:?}");
        assert!(cw.temperature_deviance_gain < TEMPERATURE_BAR, "{cw:?}");
        assert!(cw.active(), "{cw:?}");
        assert_eq!((cw.variance, cw.tau_s), (blind.variance, blind.tau_s));
    }
}
