//! The range a fitted block declares: where its data reached, and where its model increases.

use super::{FitError, Observation};
use crate::calibration::{Model, RangeSpec};

/// Declared range for a fitted block: S from 0 to the largest observed reading, C over the
/// observed curvatures; S max lowered, if needed, to where the model stops increasing.
pub fn fitted_range(obs: &[Observation], model: &Model) -> Result<RangeSpec, FitError> {
    let s_hi = obs.iter().map(|o| o.s).fold(0.0, f64::max);
    let c_lo = obs.iter().map(|o| o.c).fold(f64::INFINITY, f64::min);
    let c_hi = obs.iter().map(|o| o.c).fold(f64::NEG_INFINITY, f64::max);
    let slope = |s: f64, c: f64| model.slope(s, c);
    let mut s_max = s_hi;
    for ci in 0..=40 {
        let c = c_lo + (c_hi - c_lo) * ci as f64 / 40.0;
        for si in 0..=400 {
            let s = s_hi * si as f64 / 400.0;
            if slope(s, c) <= 0.0 {
                s_max = s_max.min(0.98 * s);
                break;
            }
        }
    }
    if s_max <= 0.0 {
        return Err(FitError::NotMonotone);
    }
    // Where the data reached, per curvature (5 % margin): readings beyond what any fixture
    // produced at that curvature are flagged rather than silently extrapolated.
    let mut groups: std::collections::BTreeMap<i64, (f64, f64, usize)> = Default::default();
    let span = (c_hi - c_lo).max(1e-9);
    let distinct: std::collections::BTreeSet<i64> =
        obs.iter().map(|o| (o.c * 100.0).round() as i64).collect();
    for o in obs {
        let key = if distinct.len() <= 24 {
            (o.c * 100.0).round() as i64
        } else {
            ((o.c - c_lo) / span * 19.0).round() as i64
        };
        let e = groups.entry(key).or_insert((0.0, f64::NEG_INFINITY, 0));
        e.0 += o.c;
        e.1 = e.1.max(o.s);
        e.2 += 1;
    }
    let table: Vec<[f64; 2]> = if groups.len() >= 2 {
        groups
            .values()
            .map(|(sum_c, max_s, n)| {
                [
                    sum_c / *n as f64,
                    (1.05 * max_s).min(s_max).floor().max(1.0),
                ]
            })
            .collect()
    } else {
        Vec::new()
    };
    Ok(RangeSpec {
        s: [0.0, s_max.floor()],
        curvature_m1: [c_lo, c_hi],
        s_max_by_curvature: table,
    })
}
