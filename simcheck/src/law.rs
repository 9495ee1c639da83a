//! The crossing's static law in the forward model. Either the start model's power law,
//! `a_k L^n` (one gain per node, the exponent `n` searched), or a monotone spline per node,
//! `sum_j c_kj Phi_j(L)` with `c_kj >= 0`: the `Phi_j` are the integrals of piecewise-linear
//! hats on knots shared by every node, so each node's law is any increasing, smooth
//! (continuously differentiable) function of the load with a slope that is piecewise linear
//! between the knots, extended with its last slope beyond the top knot. A power law with any
//! exponent, a logarithmic rise or a soft saturation, with a shape of its own on every node,
//! is such a function. The number of knots is the spline's one smoothness setting, shared by
//! every node, and the criterion charges `m` parameters per node for it.
//!
//! In the per-node least squares a sample's regressors are written as "local" values (a
//! constant, the other regressors, and the law's one or two values that vary within the
//! sample's knot segment) and a sparse map from them to the full row (see [`RowMap`]), so the
//! normal equations are accumulated per segment at the cost of the local values only.

/// Which static law the forward model uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Law {
    /// `a_k L^n`.
    Power,
    /// A monotone spline with this many basis functions per node (knots `0`, ...,
    /// `L_max (j / (m - 1))^2`: denser at small loads, where laws bend most).
    Spline(usize),
}

impl Law {
    /// Parameters per node.
    pub fn per_node(self) -> usize {
        match self {
            Law::Power => 1,
            Law::Spline(m) => m,
        }
    }
}

/// The spline's basis on the normalised load `x = L / L_max`.
#[derive(Debug, Clone)]
pub struct Basis {
    /// Knots `0 = k_0 < ... < k_(m-1) = 1`.
    knots: Vec<f64>,
    /// Each `Phi_j`'s full area (its value beyond the hat's right end).
    full: Vec<f64>,
    /// Each hat's left half area (`Phi_j` at its own knot).
    left: Vec<f64>,
    /// `1 / (2 (k_(j+1) - k_j))` per segment.
    inv_2d: Vec<f64>,
    /// `1 / L_max`.
    inv_scale: f64,
}

impl Basis {
    /// `m >= 2` basis functions on loads up to `l_max`.
    pub fn new(m: usize, l_max: f64) -> Basis {
        let m = m.max(2);
        let knots: Vec<f64> = (0..m)
            .map(|j| (j as f64 / (m - 1) as f64).powi(2))
            .collect();
        let left: Vec<f64> = (0..m)
            .map(|j| {
                if j == 0 {
                    0.0
                } else {
                    0.5 * (knots[j] - knots[j - 1])
                }
            })
            .collect();
        let full: Vec<f64> = (0..m)
            .map(|j| {
                left[j]
                    + if j + 1 < m {
                        0.5 * (knots[j + 1] - knots[j])
                    } else {
                        0.0
                    }
            })
            .collect();
        let inv_2d = (0..m)
            .map(|j| {
                if j + 1 < m {
                    0.5 / (knots[j + 1] - knots[j])
                } else {
                    0.0
                }
            })
            .collect();
        Basis {
            knots,
            full,
            left,
            inv_2d,
            inv_scale: 1.0 / l_max.max(1e-12),
        }
    }

    pub fn dim(&self) -> usize {
        self.knots.len()
    }

    /// The segment `s` of load `l` and the values of `Phi_s` and `Phi_(s+1)` there (`Phi_j` is
    /// its full area for `j < s` and 0 for `j > s + 1`; `s = m - 1` beyond the top knot, where
    /// only `Phi_(m-1)` still grows).
    pub fn local(&self, l: f64) -> (usize, f64, f64) {
        let x = (l * self.inv_scale).max(0.0);
        let m = self.knots.len();
        // The segment: how many knots after the first lie at or below `x` (a count without
        // branches; the knots are few).
        let s = self.knots[1..]
            .iter()
            .map(|&k| usize::from(x >= k))
            .sum::<usize>();
        let u = x - self.knots[s];
        if s + 1 == m {
            return (s, self.left[s] + u, 0.0);
        }
        let right = u * u * self.inv_2d[s];
        (s, self.left[s] + u - right, right)
    }

    /// `sum_j c_j Phi_j(l)`.
    pub fn value(&self, c: &[f64], l: f64) -> f64 {
        let (s, a, b) = self.local(l);
        let below: f64 = c[..s].iter().zip(&self.full).map(|(c, f)| c * f).sum();
        below + c[s] * a + c.get(s + 1).map_or(0.0, |cn| cn * b)
    }

    /// [`Basis::value`] with the sums `below[s]` over the full hats below each segment `s`
    /// summed already (see the model's `Coefs`).
    pub fn value_with(&self, c: &[f64], below: &[f64], l: f64) -> f64 {
        let (s, a, b) = self.local(l);
        below[s] + c[s] * a + c.get(s + 1).map_or(0.0, |cn| cn * b)
    }

    /// The full row of basis values at load `l`.
    pub fn row(&self, l: f64, out: &mut [f64]) {
        let (s, a, b) = self.local(l);
        for (j, o) in out.iter_mut().enumerate() {
            *o = if j < s {
                self.full[j]
            } else if j == s {
                a
            } else if j == s + 1 {
                b
            } else {
                0.0
            };
        }
    }

    /// Each basis function's full area (for [`RowMap`]).
    pub fn full(&self) -> &[f64] {
        &self.full
    }
}

/// How a segment's local values `v` make the full row `x` (the intercept, the other
/// regressors, then the law's parameters): `x_u = alpha_u v[col_u]`, one term per row. `v` is
/// `1`, the `n_other` other regressors, then for the power law its one value, and for a spline
/// the sensitivity factor `s` (the hats below the segment contribute `s` times their full
/// areas) and `s Phi_s`, `s Phi_(s+1)`.
#[derive(Debug, Clone)]
pub struct RowMap {
    pub col: Vec<usize>,
    pub alpha: Vec<f64>,
}

impl RowMap {
    /// The map for segment `s` of `basis` (`None`: the power law, one law value).
    pub fn new(basis: Option<&Basis>, s: usize, n_other: usize) -> RowMap {
        let mut col: Vec<usize> = (0..=n_other).collect();
        let mut alpha = vec![1.0; n_other + 1];
        let loc = n_other + 1;
        match basis {
            None => {
                col.push(loc);
                alpha.push(1.0);
            }
            Some(b) => {
                for j in 0..b.dim() {
                    let (c, a) = if j < s {
                        (loc, b.full()[j])
                    } else if j == s {
                        (loc + 1, 1.0)
                    } else if j == s + 1 {
                        (loc + 2, 1.0)
                    } else {
                        (0, 0.0)
                    };
                    col.push(c);
                    alpha.push(a);
                }
            }
        }
        RowMap { col, alpha }
    }

    /// Adds the local sums `s_loc` (`vdim x vdim`, lower triangle filled) and `r_loc` to the
    /// full normal equations `a` (lower triangle) and `b`.
    pub fn add(&self, s_loc: &[f64], r_loc: &[f64], vdim: usize, a: &mut [f64], b: &mut [f64]) {
        let p = self.col.len();
        for u in 0..p {
            if self.alpha[u] == 0.0 {
                continue;
            }
            let cu = self.col[u];
            b[u] += self.alpha[u] * r_loc[cu];
            for w in 0..=u {
                if self.alpha[w] == 0.0 {
                    continue;
                }
                let cw = self.col[w];
                let (hi, lo) = if cu >= cw { (cu, cw) } else { (cw, cu) };
                a[u * p + w] += self.alpha[u] * self.alpha[w] * s_loc[hi * vdim + lo];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spline_basis_integrates_its_hats_and_stays_monotone() {
        let b = Basis::new(5, 10.0);
        let mut row = vec![0.0; 5];
        let mut prev = vec![-1.0; 5];
        for i in 0..=1200 {
            let l = i as f64 * 0.01;
            b.row(l, &mut row);
            // Each basis function rises with the load (a hat is never negative).
            for (r, p) in row.iter().zip(&prev) {
                assert!(*r >= *p - 1e-12, "l {l}: {row:?}");
            }
            prev.clone_from(&row);
            // Equal coefficients: the hats sum to one, so the law is the load itself.
            let v = b.value(&[1.0; 5], l);
            assert!((v - l / 10.0).abs() < 1e-12, "l {l}: {v}");
        }
        // Beyond the top knot only the last function grows, with slope 1 in x.
        b.row(12.0, &mut row);
        assert!(
            (row[4] - (0.5 * (1.0 - 0.5625) + 0.2)).abs() < 1e-12,
            "{row:?}"
        );
    }

    #[test]
    fn a_load_falls_in_the_segment_whose_knots_bracket_it() {
        for m in [4, 6, 9] {
            let b = Basis::new(m, 20.0);
            for (j, &k) in b.knots.iter().enumerate() {
                let l = k * 20.0;
                assert_eq!(b.local(l).0, j, "m {m}: at knot {j}");
                if j > 0 {
                    assert_eq!(b.local(l * (1.0 - 1e-9)).0, j - 1, "m {m}: below knot {j}");
                }
            }
            assert_eq!(b.local(-3.0).0, 0);
            assert_eq!(b.local(50.0).0, m - 1);
        }
    }

    #[test]
    fn segment_sums_through_the_row_map_give_the_full_normal_equations() {
        let b = Basis::new(4, 1.0);
        let p = 1 + 1 + 4;
        let (mut a_full, mut b_full) = (vec![0.0; p * p], vec![0.0; p]);
        let (mut a_map, mut b_map) = (vec![0.0; p * p], vec![0.0; p]);
        let vdim = 5;
        let mut seg: Vec<(Vec<f64>, Vec<f64>)> = vec![(vec![0.0; 25], vec![0.0; 5]); 4];
        for i in 0..200 {
            let l = 1.2 * i as f64 / 200.0;
            let other = (i as f64 * 0.37).sin();
            let z = 0.3 + l * l + 0.1 * other;
            let mut x = [1.0, other, 0.0, 0.0, 0.0, 0.0];
            b.row(l, &mut x[2..]);
            for u in 0..p {
                b_full[u] += x[u] * z;
                for w in 0..=u {
                    a_full[u * p + w] += x[u] * x[w];
                }
            }
            let (s, va, vb) = b.local(l);
            let v = [1.0, other, 1.0, va, vb];
            for u in 0..vdim {
                seg[s].1[u] += v[u] * z;
                for w in 0..=u {
                    seg[s].0[u * vdim + w] += v[u] * v[w];
                }
            }
        }
        for (s, (sl, rl)) in seg.iter().enumerate() {
            RowMap::new(Some(&b), s, 1).add(sl, rl, vdim, &mut a_map, &mut b_map);
        }
        for u in 0..p {
            assert!((b_full[u] - b_map[u]).abs() < 1e-9, "b[{u}]");
            for w in 0..=u {
                let (x, y) = (a_full[u * p + w], a_map[u * p + w]);
                assert!((x - y).abs() < 1e-9, "a[{u}][{w}]: {x} vs {y}");
            }
        }
    }
}
