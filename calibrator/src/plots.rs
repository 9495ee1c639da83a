//! Figures of calibrations: force against reading at curvatures across the declared range
//! (`taxel calibrator fit --plots`).

use std::path::Path;

use taxel_plot::{Chart, Mark, Series};

use crate::calibration::{Block, Calibration};

/// The calibration surface of the first block (or the array): force against reading at
/// curvatures across the declared range.
pub fn surface(path: &Path, cal: &Calibration) -> anyhow::Result<()> {
    block_surface(path, cal, cal.blocks.first().unwrap_or(&cal.array))
}

/// Force against reading of block `b` of `cal` at curvatures across its declared range.
pub fn block_surface(path: &Path, cal: &Calibration, b: &Block) -> anyhow::Result<()> {
    let (s_range, c_range) = b.ranges();
    let mut series = Vec::new();
    for k in 0..=4 {
        let c = c_range[0] + (c_range[1] - c_range[0]) * k as f64 / 4.0;
        let smax = b.s_max(c);
        let points = (0..=100)
            .map(|i| {
                let s = s_range[0] + (smax - s_range[0]) * i as f64 / 100.0;
                (s, b.evaluate(s, c).force_n)
            })
            .collect();
        series.push(Series {
            name: format!("C = {c:.0} 1/m"),
            points,
            mark: Mark::Line,
        });
    }
    taxel_plot::write(
        path,
        &Chart {
            title: format!(
                "calibration {} v{}: block {:?}",
                cal.id, cal.version, b.name
            ),
            x_label: "reading S (baseline-subtracted counts)".into(),
            y_label: "force (N)".into(),
            series,
            x_range: None,
            y_range: None,
        },
    )
}
