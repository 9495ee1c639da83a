//! Fitting the monotone form (see `crate::forms`): the observations are grouped by fixture
//! curvature; on each fixture the inverse static law `F = h(S)` is a strictly increasing
//! piecewise-linear curve through 0 (nonnegative least squares on the force increments between
//! knots at quantiles of S, as in the physics form); the file stores, per fixture, the reading
//! at which `h` reaches each of a shared set of force knots (quantiles of the loaded reference
//! forces). No shape is assumed across curvature: between fixtures the readings at equal force
//! are interpolated linearly.
//!
//! A fixture whose reading stops rising with force (the paper left 100 1/m out for this) is
//! found by [`check_fixture`]: the median reading of ten equal-count force bins of its loaded
//! samples falls, somewhere above its running maximum, by more than 3 % of the fixture's span.

use super::physics::{fit_increments, knots};
use super::{FitError, Observation};
use crate::calibration::ModelSpec;

/// Force knots of the surface.
const FORCE_KNOTS: usize = 20;
/// Most fixture groups; beyond this many distinct curvatures, quantile bins.
const MAX_FIXTURES: usize = 24;

/// Observation indices grouped by fixture curvature, with the group's curvature (1/m), sorted
/// by curvature: distinct curvatures (to 0.01 1/m), or quantile bins when there are more than
/// 24.
pub fn fixtures(obs: &[Observation]) -> Vec<(f64, Vec<usize>)> {
    let mut order: Vec<usize> = (0..obs.len()).collect();
    order.sort_by(|&a, &b| obs[a].c.total_cmp(&obs[b].c));
    let key = |c: f64| (c * 100.0).round() as i64;
    let mut distinct: Vec<i64> = order.iter().map(|&i| key(obs[i].c)).collect();
    distinct.dedup();
    let mut groups: Vec<Vec<usize>> = Vec::new();
    if distinct.len() <= MAX_FIXTURES {
        let mut last = None;
        for &i in &order {
            let k = key(obs[i].c);
            if last != Some(k) {
                groups.push(Vec::new());
                last = Some(k);
            }
            if let Some(g) = groups.last_mut() {
                g.push(i);
            }
        }
    } else {
        let per = order.len().div_ceil(MAX_FIXTURES);
        groups = order.chunks(per).map(|c| c.to_vec()).collect();
    }
    groups
        .into_iter()
        .map(|g| {
            let c = g.iter().map(|&i| obs[i].c).sum::<f64>() / g.len() as f64;
            (c, g)
        })
        .collect()
}

/// Where a fixture's reading stops rising with force.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NonMonotone {
    pub curvature_m1: f64,
    /// Median reading and force of the bin where the reading peaks.
    pub peak_s: f64,
    pub peak_f: f64,
    /// The lowest median reading of a bin above the peak, and its force.
    pub low_s: f64,
    pub low_f: f64,
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Checks that a fixture's reading rises with force (see the module comment).
pub fn check_fixture(obs: &[Observation], idx: &[usize], c: f64) -> Option<NonMonotone> {
    let f_max = idx.iter().map(|&i| obs[i].f).fold(0.0, f64::max);
    let mut loaded: Vec<usize> = idx
        .iter()
        .copied()
        .filter(|&i| obs[i].f > 0.05 * f_max)
        .collect();
    if loaded.len() < 50 {
        return None;
    }
    loaded.sort_by(|&a, &b| obs[a].f.total_cmp(&obs[b].f));
    let bins: Vec<(f64, f64)> = loaded
        .chunks(loaded.len().div_ceil(10))
        .map(|b| {
            let mut s: Vec<f64> = b.iter().map(|&i| obs[i].s).collect();
            let mut f: Vec<f64> = b.iter().map(|&i| obs[i].f).collect();
            (median(&mut s), median(&mut f))
        })
        .collect();
    let lo = bins.iter().map(|b| b.0).fold(f64::INFINITY, f64::min);
    let hi = bins.iter().map(|b| b.0).fold(f64::NEG_INFINITY, f64::max);
    let tol = 0.03 * (hi - lo).max(f64::MIN_POSITIVE);
    let mut peak = bins[0];
    let mut worst: Option<NonMonotone> = None;
    for &b in &bins[1..] {
        if b.0 > peak.0 {
            peak = b;
        } else if peak.0 - b.0 > tol && worst.is_none_or(|w| peak.0 - b.0 > w.peak_s - w.low_s) {
            worst = Some(NonMonotone {
                curvature_m1: c,
                peak_s: peak.0,
                peak_f: peak.1,
                low_s: b.0,
                low_f: b.1,
            });
        }
    }
    worst
}

/// The monotone inverse law of one fixture, `(S knots, F at the knots)`.
fn fixture_law(obs: &[Observation], idx: &[usize]) -> (Vec<f64>, Vec<f64>) {
    let xs: Vec<f64> = idx.iter().map(|&i| obs[i].s).collect();
    let fs: Vec<f64> = idx.iter().map(|&i| obs[i].f).collect();
    let t = knots(&xs);
    let (d, _) = fit_increments(&t, &xs, &fs);
    let mut f = vec![0.0];
    for di in &d {
        let last = f[f.len() - 1];
        f.push(last + di);
    }
    (t, f)
}

/// The reading at which the law `(t, h)` reaches force `f` (extended with its end slopes).
fn invert(t: &[f64], h: &[f64], f: f64) -> f64 {
    let n = h.len();
    let i = h.partition_point(|&v| v <= f).clamp(1, n - 1);
    t[i - 1] + (f - h[i - 1]) * (t[i] - t[i - 1]) / (h[i] - h[i - 1])
}

/// Fits the monotone form.
pub fn fit_monotone(obs: &[Observation]) -> Result<ModelSpec, FitError> {
    let mut loaded: Vec<f64> = obs.iter().map(|o| o.f).filter(|f| *f > 0.0).collect();
    if loaded.len() < 10 {
        return Err(FitError::TooFew(loaded.len(), 10));
    }
    loaded.sort_by(f64::total_cmp);
    let f_top = loaded[loaded.len() - 1];
    let mut fk = vec![0.0];
    for i in 1..FORCE_KNOTS {
        let q = loaded[((loaded.len() - 1) as f64 * i as f64 / (FORCE_KNOTS - 1) as f64) as usize];
        if q > fk[fk.len() - 1] + 1e-6 * f_top {
            fk.push(q);
        }
    }
    let mut cs = Vec::new();
    let mut rows = Vec::new();
    for (c, idx) in fixtures(obs) {
        if idx.iter().filter(|&&i| obs[i].f > 0.0).count() < 10 {
            continue;
        }
        let (t, h) = fixture_law(obs, &idx);
        let mut row: Vec<f64> = fk.iter().map(|&f| invert(&t, &h, f)).collect();
        let eps = 1e-9 * (1.0 + row.iter().fold(0.0f64, |a, v| a.max(v.abs())));
        for i in 1..row.len() {
            if row[i] <= row[i - 1] {
                row[i] = row[i - 1] + eps;
            }
        }
        if cs.last().is_some_and(|&last: &f64| c <= last) {
            continue;
        }
        cs.push(c);
        rows.push(row);
    }
    if cs.is_empty() {
        return Err(FitError::TooFew(obs.len(), 10));
    }
    Ok(ModelSpec::Monotone {
        curvature_m1: cs,
        f: fk,
        s: rows,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::validate_model;

    fn sensor(f: f64, c: f64) -> f64 {
        // A log law whose sensitivity falls linearly with curvature: no polynomial, no
        // 1 + g1 C + g2 C^2 gain.
        300.0 * (1.0 + f / 2.0).ln() * (1.0 - c / 150.0).max(0.1)
    }

    #[test]
    fn interpolates_an_unseen_fixture_of_a_law_of_another_shape() {
        let mut obs = Vec::new();
        for (t, c) in [0.0, 20.0, 40.0, 60.0, 80.0].into_iter().enumerate() {
            for k in 0..=200 {
                let f = k as f64 * 0.1;
                obs.push(Observation {
                    s: sensor(f, c),
                    c,
                    f,
                    trial: t as i64,
                });
            }
        }
        let spec = fit_monotone(&obs).expect("fits");
        let m = validate_model("m", &spec).expect("valid");
        // At 30 1/m (no fixture), within 0.2 N over 1-20 N.
        for k in 10..=200 {
            let f = k as f64 * 0.1;
            let got = m.value(sensor(f, 30.0), 30.0);
            assert!((got - f).abs() < 0.2, "F {f}: {got}");
        }
        assert!(fixtures(&obs).iter().all(|(_, g)| g.len() == 201));
        for (c, g) in fixtures(&obs) {
            assert!(check_fixture(&obs, &g, c).is_none(), "C {c}");
        }
    }

    #[test]
    fn a_fixture_whose_reading_folds_back_is_found() {
        let obs: Vec<Observation> = (0..=400)
            .map(|k| {
                let f = k as f64 * 0.05;
                // Rises to 12 N, then falls (a reading that saturates and folds back).
                let s = if f < 12.0 {
                    50.0 * f
                } else {
                    600.0 - 20.0 * (f - 12.0)
                };
                Observation {
                    s,
                    c: 100.0,
                    f,
                    trial: 0,
                }
            })
            .collect();
        let idx: Vec<usize> = (0..obs.len()).collect();
        let nm = check_fixture(&obs, &idx, 100.0).expect("not monotone");
        assert!(nm.peak_f > 10.0 && nm.peak_f < 14.0, "{nm:?}");
        assert!(nm.low_f > 17.0, "{nm:?}");
    }
}
