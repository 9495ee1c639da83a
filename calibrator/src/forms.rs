//! The calibration model forms: how a block's reading `S` and the curvature `C` map to force,
//! as written in the file (`ModelSpec`) and as evaluated (`Model`).
//!
//! - `poly`: the paper's polynomial `F = sum coef S^s C^c`.
//! - `physics`: curvature scales the sensitivity: `F = h(S (1 + g1 C + g2 C^2))`, `h` a strictly
//!   increasing piecewise-linear curve through the knots `(x, f)`.
//! - `monotone`: no functional shape at all. At each fixture curvature `c_j` the file lists the
//!   reading `s[j][i]` at which the force reaches `f[i]` (strictly increasing in `i`); at a
//!   curvature between two fixtures the readings are interpolated linearly at equal force, and
//!   the force is the piecewise-linear inverse through them. A convex combination of strictly
//!   increasing rows is strictly increasing, so the surface is monotone in `S` at every
//!   curvature by construction. Beyond the first and last knot it continues with the end
//!   slopes; curvatures beyond the fixtures are clamped (and flagged by the block's range).

use serde::{Deserialize, Serialize};

/// One monomial `coef * S^s * C^c` of a polynomial model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Term {
    /// Power of the reading S.
    pub s: u32,
    /// Power of the curvature C.
    pub c: u32,
    /// Coefficient (N per count^s per (1/m)^c).
    pub coef: f64,
}

/// The model of one block, as written in the file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "form", deny_unknown_fields)]
pub enum ModelSpec {
    /// `F = sum coef S^s C^c` (the paper's form: total degree <= 3).
    #[serde(rename = "poly")]
    Poly { terms: Vec<Term> },
    /// Physics-derived: curvature scales the sensitivity, so the reading is first brought back
    /// to its flat equivalent `x = S (1 + g1 C + g2 C^2)`, then the inverse static law
    /// `F = h(x)` is a strictly increasing piecewise-linear curve through the knots `(x, f)`
    /// (extended with its end slopes), monotone in S by construction.
    #[serde(rename = "physics")]
    Physics {
        /// `[g1 (m), g2 (m^2)]`.
        curvature_gain: [f64; 2],
        /// Knot positions in flat-equivalent counts, strictly increasing.
        x: Vec<f64>,
        /// Force at each knot (N), strictly increasing.
        f: Vec<f64>,
    },
    /// No functional shape: per fixture curvature, the reading at each force knot.
    #[serde(rename = "monotone")]
    Monotone {
        /// Fixture curvatures (1/m), strictly increasing.
        curvature_m1: Vec<f64>,
        /// Force knots (N), strictly increasing.
        f: Vec<f64>,
        /// `s[j][i]`: reading at force `f[i]` on fixture `j`, strictly increasing in `i`.
        s: Vec<Vec<f64>>,
    },
}

/// A validated model.
#[derive(Debug, Clone, PartialEq)]
pub enum Model {
    Poly(Vec<Term>),
    Physics {
        gain: [f64; 2],
        x: Vec<f64>,
        f: Vec<f64>,
    },
    Monotone {
        c: Vec<f64>,
        f: Vec<f64>,
        /// Fixture-major: `s[j * f.len() + i]`.
        s: Vec<f64>,
    },
}

/// The piecewise-linear curve through `(x, f)` at `u`, extended with its end slopes; and its
/// slope there.
#[inline]
fn piecewise(x: &[f64], f: &[f64], u: f64) -> (f64, f64) {
    let n = x.len();
    let i = x.partition_point(|&k| k <= u).clamp(1, n - 1);
    let (x0, x1, f0, f1) = (x[i - 1], x[i], f[i - 1], f[i]);
    let slope = (f1 - f0) / (x1 - x0);
    (f0 + slope * (u - x0), slope)
}

/// Where curvature `c` falls between the fixtures: the lower fixture and the weight of the
/// upper one (clamped to the fixtures' range).
#[inline]
fn fixture_weight(cs: &[f64], c: f64) -> (usize, f64) {
    let k = cs.len();
    if k == 1 || c <= cs[0] {
        return (0, 0.0);
    }
    if c >= cs[k - 1] {
        return (k - 1, 0.0);
    }
    let j = cs.partition_point(|&v| v <= c).clamp(1, k - 1) - 1;
    (j, (c - cs[j]) / (cs[j + 1] - cs[j]))
}

/// Force and slope of a monotone surface at `(s, c)`.
fn monotone(cs: &[f64], f: &[f64], rows: &[f64], s: f64, c: f64) -> (f64, f64) {
    let m = f.len();
    let (j, w) = fixture_weight(cs, c);
    let row = |i: usize| {
        let lo = rows[j * m + i];
        if w == 0.0 {
            lo
        } else {
            lo + w * (rows[(j + 1) * m + i] - lo)
        }
    };
    // Binary search for the segment whose interpolated readings bracket s.
    let (mut lo, mut hi) = (1usize, m - 1);
    while lo < hi {
        let mid = (lo + hi) / 2;
        if row(mid) <= s {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    let (s0, s1) = (row(lo - 1), row(lo));
    let slope = (f[lo] - f[lo - 1]) / (s1 - s0);
    (f[lo - 1] + slope * (s - s0), slope)
}

impl Model {
    /// The form's name as in the calibration file (`poly`, `physics`, `monotone`).
    pub fn name(&self) -> &'static str {
        match self {
            Model::Poly(_) => "poly",
            Model::Physics { .. } => "physics",
            Model::Monotone { .. } => "monotone",
        }
    }

    /// Force without range handling.
    #[inline]
    pub fn value(&self, s: f64, c: f64) -> f64 {
        match self {
            Model::Poly(terms) => terms
                .iter()
                .map(|t| t.coef * s.powi(t.s as i32) * c.powi(t.c as i32))
                .sum(),
            Model::Physics { gain, x, f } => {
                piecewise(x, f, s * (1.0 + gain[0] * c + gain[1] * c * c)).0
            }
            Model::Monotone { c: cs, f, s: rows } => monotone(cs, f, rows, s, c).0,
        }
    }

    /// dF/dS without range handling.
    pub fn slope(&self, s: f64, c: f64) -> f64 {
        match self {
            Model::Poly(terms) => terms
                .iter()
                .filter(|t| t.s > 0)
                .map(|t| t.coef * t.s as f64 * s.powi(t.s as i32 - 1) * c.powi(t.c as i32))
                .sum(),
            Model::Physics { gain, x, f } => {
                let m = 1.0 + gain[0] * c + gain[1] * c * c;
                m * piecewise(x, f, s * m).1
            }
            Model::Monotone { c: cs, f, s: rows } => monotone(cs, f, rows, s, c).1,
        }
    }
}

fn strictly_increasing(v: &[f64]) -> bool {
    v.windows(2).all(|w| w[1] > w[0])
}

/// Validates a model's parameters (not yet its monotonicity over a range, which depends on
/// the range; `monotone` and `physics` are monotone by construction).
pub fn validate_model(name: &str, spec: &ModelSpec) -> Result<Model, String> {
    match spec {
        ModelSpec::Poly { terms } => {
            if terms.is_empty() || !terms.iter().any(|t| t.s > 0) {
                return Err(format!("block {name:?}: the model has no term in S"));
            }
            for t in terms {
                if !t.coef.is_finite() {
                    return Err(format!(
                        "block {name:?}: coefficient of S^{} C^{} is not finite",
                        t.s, t.c
                    ));
                }
                if u64::from(t.s) + u64::from(t.c) > 6 {
                    return Err(format!(
                        "block {name:?}: term S^{} C^{} exceeds total degree 6",
                        t.s, t.c
                    ));
                }
            }
            Ok(Model::Poly(terms.clone()))
        }
        ModelSpec::Physics {
            curvature_gain,
            x,
            f,
        } => {
            if x.len() != f.len() || x.len() < 2 || x.len() > 256 {
                return Err(format!(
                    "block {name:?}: x and f need the same length, 2 to 256 knots"
                ));
            }
            let finite = x
                .iter()
                .chain(f)
                .chain(curvature_gain)
                .all(|v| v.is_finite());
            if !finite {
                return Err(format!("block {name:?}: a knot or gain is not finite"));
            }
            if !strictly_increasing(x) || !strictly_increasing(f) {
                return Err(format!(
                    "block {name:?}: knots x and forces f must both be strictly increasing"
                ));
            }
            Ok(Model::Physics {
                gain: *curvature_gain,
                x: x.clone(),
                f: f.clone(),
            })
        }
        ModelSpec::Monotone { curvature_m1, f, s } => {
            let m = f.len();
            if !(2..=256).contains(&m) || curvature_m1.is_empty() || curvature_m1.len() > 64 {
                return Err(format!(
                    "block {name:?}: monotone needs 2 to 256 force knots and 1 to 64 fixture curvatures"
                ));
            }
            if s.len() != curvature_m1.len() {
                return Err(format!(
                    "block {name:?}: {} reading rows for {} fixture curvatures",
                    s.len(),
                    curvature_m1.len()
                ));
            }
            let finite = curvature_m1.iter().chain(f).all(|v| v.is_finite());
            if !finite || !strictly_increasing(curvature_m1) || !strictly_increasing(f) {
                return Err(format!(
                    "block {name:?}: curvature_m1 and f must be finite and strictly increasing"
                ));
            }
            for (j, row) in s.iter().enumerate() {
                if row.len() != m {
                    return Err(format!(
                        "block {name:?}: reading row {j} has {} entries for {m} force knots",
                        row.len()
                    ));
                }
                if !row.iter().all(|v| v.is_finite()) || !strictly_increasing(row) {
                    return Err(format!(
                        "block {name:?}: reading row {j} (C = {} 1/m) must be finite and strictly increasing",
                        curvature_m1[j]
                    ));
                }
            }
            Ok(Model::Monotone {
                c: curvature_m1.clone(),
                f: f.clone(),
                s: s.concat(),
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn surface() -> Model {
        let spec = ModelSpec::Monotone {
            curvature_m1: vec![0.0, 40.0],
            f: vec![0.0, 1.0, 2.0, 4.0],
            s: vec![vec![0.0, 100.0, 180.0, 300.0], vec![0.0, 50.0, 90.0, 150.0]],
        };
        validate_model("t", &spec).expect("valid")
    }

    #[test]
    fn monotone_surface_interpolates_readings_at_equal_force() {
        let m = surface();
        // On the fixtures: the knots themselves.
        assert!((m.value(180.0, 0.0) - 2.0).abs() < 1e-12);
        assert!((m.value(90.0, 40.0) - 2.0).abs() < 1e-12);
        // Half way: the reading at 2 N is (180 + 90) / 2 = 135.
        assert!((m.value(135.0, 20.0) - 2.0).abs() < 1e-12);
        // Beyond the last knot: the end slope (4 - 2) / (300 - 180) per count.
        assert!((m.value(360.0, 0.0) - (4.0 + 60.0 * 2.0 / 120.0)).abs() < 1e-12);
        // Curvature beyond the fixtures is clamped.
        assert_eq!(m.value(90.0, 80.0), m.value(90.0, 40.0));
        // Strictly increasing in S everywhere.
        for c in [0.0, 7.0, 20.0, 33.0, 40.0] {
            let mut last = f64::NEG_INFINITY;
            for i in 0..400 {
                let s = -20.0 + i as f64;
                let v = m.value(s, c);
                assert!(v > last && m.slope(s, c) > 0.0, "C {c} S {s}");
                last = v;
            }
        }
    }

    #[test]
    fn bad_monotone_specs_are_refused() {
        let bad = [
            ModelSpec::Monotone {
                curvature_m1: vec![0.0, 40.0],
                f: vec![0.0, 1.0],
                s: vec![vec![0.0, 100.0]],
            },
            ModelSpec::Monotone {
                curvature_m1: vec![0.0],
                f: vec![0.0, 1.0],
                s: vec![vec![10.0, 10.0]],
            },
            ModelSpec::Monotone {
                curvature_m1: vec![40.0, 0.0],
                f: vec![0.0, 1.0],
                s: vec![vec![0.0, 1.0], vec![0.0, 2.0]],
            },
            ModelSpec::Monotone {
                curvature_m1: vec![0.0],
                f: vec![0.0, f64::NAN],
                s: vec![vec![0.0, 1.0]],
            },
        ];
        for spec in bad {
            let e = validate_model("b", &spec).expect_err("refused");
            assert!(e.starts_with("block \"b\""), "{e}");
        }
    }
}
