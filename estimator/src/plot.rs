//! Curvature-model figures: predicted vs true, and error vs curvature (SVG, or PNG with the
//! bundled font).

use std::path::Path;

use crate::model::Metrics;

/// Draws predicted against true curvature with the identity line.
pub fn predicted_vs_true(
    path: &Path,
    pairs: &[(f64, f64)],
    m: &Metrics,
    kind: &str,
) -> anyhow::Result<()> {
    let title = format!(
        "{kind}: R\u{b2} {:.3}, MAE {:.2} 1/m, RMSE {:.2} 1/m (n = {})",
        m.r2, m.mae_m1, m.rmse_m1, m.n
    );
    let points: Vec<(f64, f64)> = pairs.to_vec();
    let hi = points
        .iter()
        .flat_map(|p| [p.0, p.1])
        .fold(10.0f64, f64::max)
        * 1.05;
    let lo = points
        .iter()
        .flat_map(|p| [p.0, p.1])
        .fold(0.0f64, f64::min);
    taxel_plot::scatter_with_identity(
        path,
        &title,
        "true curvature (1/m)",
        "predicted curvature (1/m)",
        &points,
        (lo, hi),
    )
}

/// Prediction error (predicted - true) against the true curvature, with the zero line.
pub fn error_vs_curvature(path: &Path, pairs: &[(f64, f64)], kind: &str) -> anyhow::Result<()> {
    use taxel_plot::{Chart, Mark, Series};
    let hi = pairs.iter().map(|p| p.0).fold(10.0f64, f64::max) * 1.05;
    let lo = pairs.iter().map(|p| p.0).fold(0.0f64, f64::min);
    taxel_plot::write(
        path,
        &Chart {
            title: format!("{kind}: curvature error against the true curvature"),
            x_label: "true curvature (1/m)".into(),
            y_label: "error: predicted - true (1/m)".into(),
            series: vec![
                Series {
                    name: "no error".into(),
                    points: vec![(lo, 0.0), (hi, 0.0)],
                    mark: Mark::Line,
                },
                Series {
                    name: "samples".into(),
                    points: pairs.iter().map(|(t, p)| (*t, p - t)).collect(),
                    mark: Mark::Points,
                },
            ],
            x_range: Some((lo, hi)),
            y_range: None,
        },
    )
}
