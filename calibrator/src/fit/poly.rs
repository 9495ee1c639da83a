//! The paper's form: a least-squares polynomial in `S` and `C` (faer), and the goodness of any
//! model on observations.

use faer::prelude::*;
use faer::Mat;

use super::{FitError, Observation};
use crate::calibration::Term;

/// Goodness of a fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitStats {
    pub n: usize,
    pub r2: f64,
    pub rmse_n: f64,
}

/// The paper's form: every monomial `S^i C^j` with `i >= 1` and `i + j <= degree`, so F = 0 at
/// S = 0. With `flat`, curvature terms are left out.
pub fn paper_terms(degree: u32, flat: bool) -> Vec<(u32, u32)> {
    let mut t = Vec::new();
    for i in 1..=degree {
        for j in 0..=(degree - i) {
            if flat && j > 0 {
                continue;
            }
            t.push((i, j));
        }
    }
    t
}

/// Least-squares fit of `F = sum coef S^i C^j` over `powers`, on scaled variables for
/// conditioning.
pub fn fit_poly(
    obs: &[Observation],
    powers: &[(u32, u32)],
) -> Result<(Vec<Term>, FitStats), FitError> {
    let m = obs.len();
    let p = powers.len();
    if m < 2 * p {
        return Err(FitError::TooFew(m, p));
    }
    let s_scale = obs.iter().map(|o| o.s.abs()).fold(1e-9, f64::max);
    let c_scale = obs.iter().map(|o| o.c.abs()).fold(0.0, f64::max).max(1.0);
    let a = Mat::<f64>::from_fn(m, p, |r, k| {
        let (i, j) = powers[k];
        (obs[r].s / s_scale).powi(i as i32) * (obs[r].c / c_scale).powi(j as i32)
    });
    let b = Mat::<f64>::from_fn(m, 1, |r, _| obs[r].f);
    let x = a.col_piv_qr().solve_lstsq(&b);
    let terms: Vec<Term> = powers
        .iter()
        .enumerate()
        .map(|(k, &(i, j))| Term {
            s: i,
            c: j,
            coef: x[(k, 0)] / (s_scale.powi(i as i32) * c_scale.powi(j as i32)),
        })
        .collect();
    let stats = stats(obs, |s, c| {
        terms
            .iter()
            .map(|t| t.coef * s.powi(t.s as i32) * c.powi(t.c as i32))
            .sum()
    });
    Ok((terms, stats))
}

/// R^2 and RMSE of `model` on `obs`.
pub fn stats(obs: &[Observation], model: impl Fn(f64, f64) -> f64) -> FitStats {
    let n = obs.len();
    let mean = obs.iter().map(|o| o.f).sum::<f64>() / n.max(1) as f64;
    let (mut ss_res, mut ss_tot) = (0.0, 0.0);
    for o in obs {
        ss_res += (o.f - model(o.s, o.c)).powi(2);
        ss_tot += (o.f - mean).powi(2);
    }
    FitStats {
        n,
        r2: if ss_tot > 0.0 {
            1.0 - ss_res / ss_tot
        } else {
            0.0
        },
        rmse_n: (ss_res / n.max(1) as f64).sqrt(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_known_polynomial() {
        let truth = |s: f64, c: f64| 0.01 * s + 2e-6 * s * s - 5e-5 * s * c;
        let mut obs = Vec::new();
        for c in [0.0, 20.0, 40.0, 60.0, 80.0] {
            for k in 0..50 {
                let s = k as f64 * 10.0;
                obs.push(Observation {
                    s,
                    c,
                    f: truth(s, c),
                    trial: c as i64,
                });
            }
        }
        let (terms, st) = fit_poly(&obs, &paper_terms(3, false)).expect("fits");
        assert!(st.r2 > 0.999_999, "{st:?}");
        assert!(st.rmse_n < 1e-6, "{st:?}");
        let s1 = terms.iter().find(|t| (t.s, t.c) == (1, 0)).map(|t| t.coef);
        assert!((s1.unwrap_or(0.0) - 0.01).abs() < 1e-8);
        let range = super::super::range::fitted_range(
            &obs,
            &crate::calibration::Model::Poly(terms.clone()),
        )
        .expect("monotone");
        assert_eq!(range.curvature_m1, [0.0, 80.0]);
    }

    #[test]
    fn flat_form_has_no_curvature_terms() {
        assert_eq!(paper_terms(3, true), vec![(1, 0), (2, 0), (3, 0)]);
        assert_eq!(paper_terms(3, false).len(), 6);
    }
}
