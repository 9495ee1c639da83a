//! Fitting the physics form: curvature lowers the sensitivity, so the reading is brought back to
//! its flat equivalent `x = S (1 + g1 C + g2 C^2)`, and the inverse static law `F = h(x)` is a
//! strictly increasing piecewise-linear curve through 0 (nonnegative least squares on the force
//! increments between knots at quantiles of x). `g1`, `g2` are found by a coordinate golden-
//! section search on the squared force error. Monotone in S by construction, so it never
//! folds back, and beyond the data it continues with its end slope.

use crate::calibration::ModelSpec;
use crate::fit::Observation;

/// Knots of the inverse static law.
const KNOTS: usize = 12;
/// Most samples the curvature-gain search runs on.
const SEARCH_OBS: usize = 20_000;
/// Least force increase per segment (N): keeps the curve strictly increasing.
const MIN_STEP_N: f64 = 1e-4;

/// Knot positions at quantiles of the loaded readings, starting at 0.
pub(super) fn knots(xs: &[f64]) -> Vec<f64> {
    let mut v: Vec<f64> = xs.iter().copied().filter(|x| *x > 0.0).collect();
    v.sort_by(f64::total_cmp);
    let mut t = vec![0.0];
    if v.is_empty() {
        t.push(1.0);
        return t;
    }
    for k in 1..=KNOTS {
        let q = v[((v.len() - 1) as f64 * k as f64 / KNOTS as f64).round() as usize];
        if q > t[t.len() - 1] * 1.0001 + 1e-9 {
            t.push(q);
        }
    }
    if t.len() < 2 {
        t.push(v[v.len() - 1].max(1.0));
    }
    t
}

/// Basis of segment `k` (1-based) at `x`: the share of the segment covered, the last one
/// unclamped above so the curve continues with its end slope.
fn basis(t: &[f64], k: usize, x: f64) -> f64 {
    let w = t[k] - t[k - 1];
    let r = (x - t[k - 1]) / w;
    if k == t.len() - 1 {
        r.max(0.0)
    } else {
        r.clamp(0.0, 1.0)
    }
}

/// Nonnegative (>= MIN_STEP_N) least squares on the increments, by coordinate descent on the
/// normal equations. Returns the increments and the sum of squared errors.
pub(super) fn fit_increments(t: &[f64], xs: &[f64], fs: &[f64]) -> (Vec<f64>, f64) {
    let k = t.len() - 1;
    let mut a = vec![0.0; k * k];
    let mut b = vec![0.0; k];
    let mut row = vec![0.0; k];
    let mut ff = 0.0;
    for (&x, &f) in xs.iter().zip(fs) {
        for (j, r) in row.iter_mut().enumerate() {
            *r = basis(t, j + 1, x);
        }
        for i in 0..k {
            if row[i] == 0.0 {
                continue;
            }
            b[i] += row[i] * f;
            for j in 0..k {
                a[i * k + j] += row[i] * row[j];
            }
        }
        ff += f * f;
    }
    let mut d = vec![MIN_STEP_N; k];
    for _ in 0..300 {
        let mut moved = 0.0f64;
        for i in 0..k {
            if a[i * k + i] <= 0.0 {
                continue;
            }
            let mut r = b[i];
            for j in 0..k {
                if j != i {
                    r -= a[i * k + j] * d[j];
                }
            }
            let new = (r / a[i * k + i]).max(MIN_STEP_N);
            moved = moved.max((new - d[i]).abs());
            d[i] = new;
        }
        if moved < 1e-10 {
            break;
        }
    }
    // SSE = f'f - 2 d'b + d'A d
    let mut sse = ff;
    for i in 0..k {
        sse -= 2.0 * d[i] * b[i];
        for j in 0..k {
            sse += d[i] * a[i * k + j] * d[j];
        }
    }
    (d, sse.max(0.0))
}

fn flat_equivalent(obs: &[Observation], g: [f64; 2]) -> Vec<f64> {
    obs.iter()
        .map(|o| o.s * (1.0 + g[0] * o.c + g[1] * o.c * o.c))
        .collect()
}

fn sse_at(obs: &[Observation], fs: &[f64], g: [f64; 2]) -> f64 {
    let c_max = obs.iter().map(|o| o.c).fold(0.0, f64::max);
    // The gain must stay positive over the data's curvatures.
    let m_min = (0..=20)
        .map(|i| {
            let c = c_max * i as f64 / 20.0;
            1.0 + g[0] * c + g[1] * c * c
        })
        .fold(f64::INFINITY, f64::min);
    if m_min <= 0.05 {
        return f64::INFINITY;
    }
    let xs = flat_equivalent(obs, g);
    let t = knots(&xs);
    fit_increments(&t, &xs, fs).1
}

fn golden(mut lo: f64, mut hi: f64, f: impl Fn(f64) -> f64) -> f64 {
    let r = 0.618_033_988_75;
    let mut a = hi - r * (hi - lo);
    let mut b = lo + r * (hi - lo);
    let (mut fa, mut fb) = (f(a), f(b));
    for _ in 0..40 {
        if fa < fb {
            hi = b;
            b = a;
            fb = fa;
            a = hi - r * (hi - lo);
            fa = f(a);
        } else {
            lo = a;
            a = b;
            fa = fb;
            b = lo + r * (hi - lo);
            fb = f(b);
        }
    }
    0.5 * (lo + hi)
}

/// Fits the physics form. With `flat` (or no curvature in the data) the gain stays 1.
pub fn fit_physics(obs: &[Observation], flat: bool) -> ModelSpec {
    let fs: Vec<f64> = obs.iter().map(|o| o.f).collect();
    let c_max = obs.iter().map(|o| o.c).fold(0.0, f64::max);
    let mut g = [0.0, 0.0];
    if !flat && c_max > 0.0 {
        // The gains are searched on an evenly strided subset (at most SEARCH_OBS samples): the
        // curve through the data hardly changes, the search gets many times faster.
        let stride = obs.len().div_ceil(SEARCH_OBS).max(1);
        let sub: Vec<Observation> = obs.iter().step_by(stride).copied().collect();
        let sub_f: Vec<f64> = sub.iter().map(|o| o.f).collect();
        // g1 in [-0.9/c_max, 5/c_max]: from nearly no sensitivity left to six times more.
        let (lo1, hi1) = (-0.9 / c_max, 5.0 / c_max);
        let s2 = 1.0 / (c_max * c_max);
        for _ in 0..3 {
            g[0] = golden(lo1, hi1, |v| sse_at(&sub, &sub_f, [v, g[1]]));
            g[1] = golden(-2.0 * s2, 4.0 * s2, |v| sse_at(&sub, &sub_f, [g[0], v]));
        }
    }
    let xs = flat_equivalent(obs, g);
    let t = knots(&xs);
    let (d, _) = fit_increments(&t, &xs, &fs);
    let mut f = vec![0.0];
    for di in &d {
        let last = f[f.len() - 1];
        f.push(last + di);
    }
    ModelSpec::Physics {
        curvature_gain: g,
        x: t,
        f,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::{Model, ModelSpec};

    #[test]
    fn recovers_a_saturating_law_with_curvature_loss() {
        // S = 100 F^0.9 / (1 + C/120) / (1 + F/60): the sim's kind of sensor.
        let mut obs = Vec::new();
        for c in [0.0, 20.0, 40.0, 60.0, 80.0, 100.0] {
            for k in 0..=80 {
                let f = k as f64 * 0.25;
                let s = 100.0 * f.powf(0.9) / (1.0 + c / 120.0) / (1.0 + f / 60.0);
                obs.push(Observation { s, c, f, trial: 0 });
            }
        }
        let spec = fit_physics(&obs, false);
        let ModelSpec::Physics {
            curvature_gain,
            x,
            f,
        } = spec.clone()
        else {
            panic!("physics form");
        };
        assert!(
            (curvature_gain[0] - 1.0 / 120.0).abs() < 0.002,
            "{curvature_gain:?}"
        );
        let m = Model::Physics {
            gain: curvature_gain,
            x,
            f,
        };
        let worst = obs
            .iter()
            .map(|o| (m.value(o.s, o.c) - o.f).abs())
            .fold(0.0, f64::max);
        assert!(worst < 0.15, "worst error {worst} N");
        for o in &obs {
            assert!(m.slope(o.s, o.c) > 0.0);
        }
    }

    #[test]
    fn flat_fit_ignores_curvature() {
        let obs: Vec<Observation> = (0..50)
            .map(|k| Observation {
                s: k as f64 * 10.0,
                c: 0.0,
                f: k as f64 * 0.1,
                trial: 0,
            })
            .collect();
        let ModelSpec::Physics { curvature_gain, .. } = fit_physics(&obs, true) else {
            panic!("physics form");
        };
        assert_eq!(curvature_gain, [0.0, 0.0]);
    }
}
