//! Features of a no-load baseline, after the paper: the N node readings (standardized by the
//! model's training statistics) plus eight summary statistics of the raw readings: sum, mean,
//! standard deviation, min, max, range, l2 norm and interquartile range. For the 4 x 4 sensor
//! that is 16 + 8 = 24 features.

/// Number of summary statistics appended to the node readings.
pub const N_STATS: usize = 8;
/// Names of the summary statistics, in order.
pub const STAT_NAMES: [&str; N_STATS] = ["sum", "mean", "sd", "min", "max", "range", "l2", "iqr"];

/// Number of features for `n_nodes` nodes.
pub fn n_features(n_nodes: usize) -> usize {
    n_nodes + N_STATS
}

/// Linear-interpolated quantile of sorted data.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let pos = q * (sorted.len() - 1) as f64;
    let i = pos.floor() as usize;
    let f = pos - i as f64;
    if i + 1 < sorted.len() {
        sorted[i] * (1.0 - f) + sorted[i + 1] * f
    } else {
        sorted[i]
    }
}

/// Writes the raw (unstandardized) features of `baseline` into `out` (length
/// `n_features(baseline.len())`). `scratch` is reused for sorting (no allocation once grown).
pub fn raw_features(baseline: &[f64], scratch: &mut Vec<f64>, out: &mut [f64]) {
    let n = baseline.len();
    debug_assert_eq!(out.len(), n_features(n));
    out[..n].copy_from_slice(baseline);
    let sum: f64 = baseline.iter().sum();
    let mean = sum / n as f64;
    let var = baseline
        .iter()
        .map(|v| (v - mean) * (v - mean))
        .sum::<f64>()
        / n as f64;
    scratch.clear();
    scratch.extend_from_slice(baseline);
    scratch.sort_by(f64::total_cmp);
    let min = scratch[0];
    let max = scratch[n - 1];
    let l2 = baseline.iter().map(|v| v * v).sum::<f64>().sqrt();
    let iqr = quantile(scratch, 0.75) - quantile(scratch, 0.25);
    out[n..].copy_from_slice(&[sum, mean, var.sqrt(), min, max, max - min, l2, iqr]);
}

/// Per-feature standardization `(x - mean) / sd`, fitted on training data.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Standardizer {
    pub mean: Vec<f64>,
    pub sd: Vec<f64>,
}

impl Standardizer {
    /// Fits on rows of features (each row one sample).
    pub fn fit(rows: &[Vec<f64>]) -> Standardizer {
        let d = rows.first().map_or(0, |r| r.len());
        let n = rows.len().max(1) as f64;
        let mut mean = vec![0.0; d];
        for r in rows {
            for (m, v) in mean.iter_mut().zip(r) {
                *m += v / n;
            }
        }
        let mut sd = vec![0.0; d];
        for r in rows {
            for ((s, v), m) in sd.iter_mut().zip(r).zip(&mean) {
                *s += (v - m) * (v - m) / n;
            }
        }
        for s in sd.iter_mut() {
            *s = s.sqrt();
            if !s.is_finite() || *s <= 1e-12 {
                *s = 1.0;
            }
        }
        Standardizer { mean, sd }
    }

    /// Standardizes in place.
    pub fn apply(&self, x: &mut [f64]) {
        for ((v, m), s) in x.iter_mut().zip(&self.mean).zip(&self.sd) {
            *v = (*v - m) / s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn summary_statistics() {
        let b = [1.0, 2.0, 3.0, 4.0];
        let mut out = vec![0.0; n_features(4)];
        raw_features(&b, &mut Vec::new(), &mut out);
        assert_eq!(&out[..4], &b);
        let s = &out[4..];
        assert_eq!(s[0], 10.0);
        assert_eq!(s[1], 2.5);
        assert!((s[2] - 1.25f64.sqrt()).abs() < 1e-12);
        assert_eq!((s[3], s[4], s[5]), (1.0, 4.0, 3.0));
        assert!((s[6] - 30f64.sqrt()).abs() < 1e-12);
        assert!((s[7] - 1.5).abs() < 1e-12, "iqr {}", s[7]);
    }

    #[test]
    fn standardizer_centres_and_scales() {
        let rows = vec![vec![1.0, 5.0], vec![3.0, 5.0]];
        let st = Standardizer::fit(&rows);
        let mut x = vec![3.0, 5.0];
        st.apply(&mut x);
        assert_eq!(x, vec![1.0, 0.0]);
    }
}
