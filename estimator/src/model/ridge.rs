//! Ridge regression on standardized features, with the regularization chosen by k-fold
//! cross-validation over a log grid (faer for the normal equations).

use faer::prelude::*;
use faer::Mat;
use serde::{Deserialize, Serialize};
use taxel_sim::rng::Rng;

/// A fitted ridge model: `y = bias + w . x` on standardized features.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Ridge {
    pub weights: Vec<f64>,
    pub bias: f64,
    pub lambda: f64,
    /// (X^T X + lambda I)^-1 of the training data, for the leverage of new points.
    pub inv_gram: Vec<f64>,
}

/// Solves ridge on `x` (rows) and `y`; the intercept is not penalized.
pub fn solve(x: &[Vec<f64>], y: &[f64], lambda: f64) -> Ridge {
    let n = x.len();
    let d = x.first().map_or(0, |r| r.len());
    let xm: Vec<f64> = (0..d)
        .map(|j| x.iter().map(|r| r[j]).sum::<f64>() / n.max(1) as f64)
        .collect();
    let ym = y.iter().sum::<f64>() / n.max(1) as f64;
    let xc = Mat::<f64>::from_fn(n, d, |i, j| x[i][j] - xm[j]);
    let yc = Mat::<f64>::from_fn(n, 1, |i, _| y[i] - ym);
    let mut gram = xc.transpose() * &xc;
    for j in 0..d {
        gram[(j, j)] += lambda;
    }
    let rhs = xc.transpose() * &yc;
    let lu = gram.partial_piv_lu();
    let w = lu.solve(&rhs);
    let inv = lu.solve(Mat::<f64>::identity(d, d));
    let weights: Vec<f64> = (0..d).map(|j| w[(j, 0)]).collect();
    let bias = ym - weights.iter().zip(&xm).map(|(a, b)| a * b).sum::<f64>();
    Ridge {
        weights,
        bias,
        lambda,
        inv_gram: (0..d * d).map(|k| inv[(k / d, k % d)]).collect(),
    }
}

impl Ridge {
    pub fn predict(&self, x: &[f64]) -> f64 {
        self.bias + self.weights.iter().zip(x).map(|(a, b)| a * b).sum::<f64>()
    }

    /// Leverage-like spread of a new point: `x^T (X^T X + lambda I)^-1 x`.
    pub fn leverage(&self, x: &[f64]) -> f64 {
        let d = self.weights.len();
        let s: f64 = self
            .inv_gram
            .chunks_exact(d)
            .zip(x)
            .map(|(row, xi)| xi * row.iter().zip(x).map(|(a, b)| a * b).sum::<f64>())
            .sum();
        s.max(0.0)
    }
}

/// Fold index of each sample (shuffled, seeded).
pub fn folds(n: usize, k: usize, seed: u64) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..n).collect();
    let mut rng = Rng::new(seed, 77);
    for i in (1..n).rev() {
        let j = (rng.next_u64() % (i as u64 + 1)) as usize;
        idx.swap(i, j);
    }
    let mut fold = vec![0; n];
    for (pos, &i) in idx.iter().enumerate() {
        fold[i] = pos % k;
    }
    fold
}

/// Fits ridge with lambda from a 10^-4 .. 10^4 grid chosen by k-fold CV RMSE. Returns the model
/// refitted on all data and the CV RMSE of the chosen lambda.
pub fn fit_cv(x: &[Vec<f64>], y: &[f64], k: usize, seed: u64) -> (Ridge, f64) {
    let n = x.len();
    let k = k.clamp(2, n.max(2));
    let fold = folds(n, k, seed);
    let grid: Vec<f64> = (0..=32)
        .map(|i| 10f64.powf(-4.0 + i as f64 * 0.25))
        .collect();
    let mut best = (f64::INFINITY, 1.0);
    for &lambda in &grid {
        let mut sse = 0.0;
        for f in 0..k {
            let (mut xt, mut yt) = (Vec::new(), Vec::new());
            for i in 0..n {
                if fold[i] != f {
                    xt.push(x[i].clone());
                    yt.push(y[i]);
                }
            }
            if xt.is_empty() {
                continue;
            }
            let m = solve(&xt, &yt, lambda);
            for i in 0..n {
                if fold[i] == f {
                    sse += (m.predict(&x[i]) - y[i]).powi(2);
                }
            }
        }
        let rmse = (sse / n as f64).sqrt();
        if rmse < best.0 {
            best = (rmse, lambda);
        }
    }
    (solve(x, y, best.1), best.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_linear_law_and_picks_small_lambda() {
        let mut rng = Rng::new(1, 1);
        let x: Vec<Vec<f64>> = (0..200)
            .map(|_| (0..5).map(|_| rng.normal()).collect())
            .collect();
        let y: Vec<f64> = x
            .iter()
            .map(|r| 3.0 + 2.0 * r[0] - r[3] + 0.01 * rng.normal())
            .collect();
        let (m, cv) = fit_cv(&x, &y, 5, 3);
        assert!(cv < 0.02, "cv rmse {cv}");
        assert!((m.weights[0] - 2.0).abs() < 0.01 && (m.bias - 3.0).abs() < 0.01);
        assert!(m.lambda <= 1.0);
        assert!(m.leverage(&x[0]) > 0.0);
    }
}
