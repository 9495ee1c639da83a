//! Figures of a calibration's evaluation on a recording: force over time (reference,
//! curvature-aware, flat) and the error per level (`taxel calibrator eval --plots`).

use std::path::Path;

use taxel_plot::{Chart, Mark, Series};

use taxel_formats::Recording;

use crate::protocol::Report;

/// Reference force and the force from the curvature-aware and the flat calibration over the
/// recording's time.
pub fn force_vs_time(path: &Path, rec: &Recording, r: &Report, name: &str) -> anyhow::Result<()> {
    let t0 = rec.t_s.first().copied().unwrap_or(0.0);
    let t = |i: usize| rec.t_s[i] - t0;
    let mut series = Vec::new();
    if let Some(f) = &rec.force_n {
        series.push(Series {
            name: "reference force".into(),
            points: (0..rec.len()).map(|i| (t(i), f[i])).collect(),
            mark: Mark::Line,
        });
    }
    for (k, label) in [(0, "curvature-aware calibration"), (1, "flat calibration")] {
        series.push(Series {
            name: label.into(),
            points: r
                .forces
                .iter()
                .enumerate()
                .take(rec.len())
                .map(|(i, f)| (t(i), if k == 0 { f.0 } else { f.1 } as f64))
                .filter(|p| p.1.is_finite())
                .collect(),
            mark: Mark::Line,
        });
    }
    let statics = r
        .blocks
        .iter()
        .find(|b| b.block == r.headline)
        .map_or(&[][..], |b| &b.static_forces[..]);
    if statics.iter().any(|f| f.is_finite()) {
        series.push(Series {
            name: "curvature-aware, without its dynamic terms".into(),
            points: statics
                .iter()
                .enumerate()
                .take(rec.len())
                .map(|(i, f)| (t(i), *f as f64))
                .filter(|p| p.1.is_finite())
                .collect(),
            mark: Mark::Line,
        });
    }
    taxel_plot::write(
        path,
        &Chart {
            title: format!(
                "{name}: force over time (curvature {} {:.1} 1/m)",
                if r.curvature_given {
                    "given"
                } else {
                    "predicted"
                },
                r.curvature_pred_m1
            ),
            x_label: "time (s)".into(),
            y_label: "force (N)".into(),
            series,
            x_range: None,
            y_range: None,
        },
    )
}

/// Mean absolute force error per force level, flat against curvature-aware.
pub fn error_per_level(path: &Path, r: &Report, name: &str) -> anyhow::Result<()> {
    let pts = |k: usize| -> Vec<(f64, f64)> {
        r.levels
            .iter()
            .filter(|l| l.n > 0)
            .map(|l| {
                (
                    l.target_n,
                    if k == 0 { l.curve_mae_n } else { l.flat_mae_n },
                )
            })
            .collect()
    };
    taxel_plot::write(
        path,
        &Chart {
            title: format!("{name}: mean absolute force error per level"),
            x_label: "force level (N)".into(),
            y_label: "mean absolute error (N)".into(),
            series: vec![
                Series {
                    name: "curvature-aware calibration".into(),
                    points: pts(0),
                    mark: Mark::LinePoints,
                },
                Series {
                    name: "flat calibration".into(),
                    points: pts(1),
                    mark: Mark::LinePoints,
                },
            ],
            x_range: None,
            y_range: None,
        },
    )
}
