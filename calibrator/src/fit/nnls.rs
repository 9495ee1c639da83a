//! Non-negative least squares on the normal equations (Lawson and Hanson's active set method),
//! for the small designs of the dynamic terms (a few dozen columns, any number of rows).

/// Normal equations `G = X^T X`, `b = X^T y` of a design, accumulated row by row.
#[derive(Debug, Clone)]
pub struct Normal {
    pub g: Vec<Vec<f64>>,
    pub b: Vec<f64>,
    /// `y^T y`.
    pub yy: f64,
}

impl Normal {
    pub fn new(n: usize) -> Normal {
        Normal {
            g: vec![vec![0.0; n]; n],
            b: vec![0.0; n],
            yy: 0.0,
        }
    }

    /// Adds one row `x` with target `y`.
    pub fn add(&mut self, x: &[f64], y: f64) {
        self.yy += y * y;
        for (i, xi) in x.iter().enumerate() {
            if *xi == 0.0 {
                continue;
            }
            self.b[i] += xi * y;
            for (gij, xj) in self.g[i].iter_mut().zip(x) {
                *gij += xi * xj;
            }
        }
    }

    /// The coefficients `a >= 0` that minimise `|X a - y|^2`.
    pub fn solve_nonneg(&self) -> Vec<f64> {
        nnls(&self.g, &self.b)
    }

    /// `|X a - y|^2`.
    pub fn sse(&self, a: &[f64]) -> f64 {
        let mut s = self.yy;
        for (i, ai) in a.iter().enumerate() {
            s -= 2.0 * ai * self.b[i];
            for (j, aj) in a.iter().enumerate() {
                s += ai * self.g[i][j] * aj;
            }
        }
        s
    }
}

/// Solves `g[set][set] z = b[set]` (Gaussian elimination with partial pivoting, a tiny ridge
/// for nearly collinear columns); None when singular.
fn solve_on(g: &[Vec<f64>], b: &[f64], set: &[usize]) -> Option<Vec<f64>> {
    let m = set.len();
    let scale = set.iter().map(|&i| g[i][i].abs()).fold(0.0, f64::max);
    let mut a: Vec<Vec<f64>> = set
        .iter()
        .map(|&i| {
            let mut row: Vec<f64> = set
                .iter()
                .map(|&j| g[i][j] + if i == j { 1e-12 * scale } else { 0.0 })
                .collect();
            row.push(b[i]);
            row
        })
        .collect();
    for c in 0..m {
        let p = (c..m).max_by(|&x, &y| a[x][c].abs().total_cmp(&a[y][c].abs()))?;
        if a[p][c] == 0.0 || !a[p][c].is_finite() {
            return None;
        }
        a.swap(c, p);
        let pivot = a[c].clone();
        for (r, row) in a.iter_mut().enumerate() {
            if r != c {
                let k = row[c] / pivot[c];
                for (v, pv) in row[c..].iter_mut().zip(&pivot[c..]) {
                    *v -= k * pv;
                }
            }
        }
    }
    Some((0..m).map(|i| a[i][m] / a[i][i]).collect())
}

/// Lawson-Hanson NNLS on normal equations `g a = b`, `a >= 0`.
pub fn nnls(g: &[Vec<f64>], b: &[f64]) -> Vec<f64> {
    let n = b.len();
    let mut x = vec![0.0; n];
    let mut passive = vec![false; n];
    let scale = b.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1e-300);
    let tol = 1e-10 * scale;
    for _outer in 0..3 * n + 10 {
        // Gradient of the objective's negative half: b - G x.
        let w: Vec<f64> = (0..n)
            .map(|i| b[i] - (0..n).map(|j| g[i][j] * x[j]).sum::<f64>())
            .collect();
        let Some(j) = (0..n)
            .filter(|&i| !passive[i] && g[i][i] > 0.0)
            .max_by(|&p, &q| w[p].total_cmp(&w[q]))
        else {
            break;
        };
        if w[j] <= tol {
            break;
        }
        passive[j] = true;
        for _inner in 0..3 * n + 10 {
            let set: Vec<usize> = (0..n).filter(|&i| passive[i]).collect();
            let Some(z) = solve_on(g, b, &set) else {
                // Collinear with the set: drop the newest column and stop here.
                passive[j] = false;
                return x;
            };
            if z.iter().all(|&v| v > 0.0) {
                for (k, &i) in set.iter().enumerate() {
                    x[i] = z[k];
                }
                break;
            }
            // Step toward z until the first coefficient reaches zero.
            let mut alpha = 1.0f64;
            for (k, &i) in set.iter().enumerate() {
                if z[k] <= 0.0 {
                    let d = x[i] - z[k];
                    if d > 0.0 {
                        alpha = alpha.min(x[i] / d);
                    }
                }
            }
            for (k, &i) in set.iter().enumerate() {
                x[i] += alpha * (z[k] - x[i]);
                if x[i] <= 1e-15 {
                    x[i] = 0.0;
                    passive[i] = false;
                }
            }
        }
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_non_negative_coefficients_and_clips_negative_ones() {
        // y = 2 x0 + 0.5 x2, with x1 pulling toward a negative coefficient.
        let mut n = Normal::new(3);
        for k in 0..200 {
            let t = k as f64 * 0.1;
            let x = [t.sin(), (0.7 * t).cos(), 1.0 + 0.01 * t];
            let y = 2.0 * x[0] - 0.3 * x[1] + 0.5 * x[2];
            n.add(&x, y);
        }
        let a = n.solve_nonneg();
        assert_eq!(a[1], 0.0, "{a:?}");
        assert!(a[0] > 1.5 && a[2] > 0.3, "{a:?}");
        let mut exact = Normal::new(2);
        for k in 0..50 {
            let x = [k as f64, (k * k) as f64 * 0.01];
            exact.add(&x, 3.0 * x[0] + 0.25 * x[1]);
        }
        let a = exact.solve_nonneg();
        assert!(
            (a[0] - 3.0).abs() < 1e-6 && (a[1] - 0.25).abs() < 1e-6,
            "{a:?}"
        );
    }
}
