//! taxel-plot owns the figures that offline commands write next to their reports: scatter and
//! line charts with titled axes, units and legends, as SVG (`.svg`) or PNG (`.png`). PNG text is
//! drawn with the bundled DejaVu Sans (assets/, with its licence), so no system font library is
//! needed.

use std::path::{Path, PathBuf};
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;

static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

fn register_font() {
    REGISTER.call_once(|| {
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mark {
    Line,
    Points,
    /// A line with a dot at every point.
    LinePoints,
}

/// One named series.
#[derive(Debug, Clone)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub mark: Mark,
}

/// A chart: title, axis labels (with units), series, and axis ranges (None: from the data).
#[derive(Debug, Clone)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    pub x_range: Option<(f64, f64)>,
    pub y_range: Option<(f64, f64)>,
}

const COLORS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(90, 90, 90),
];

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if hi - lo < 1e-12 {
        return (lo - 1.0, hi + 1.0);
    }
    let pad = 0.04 * (hi - lo);
    (lo - pad, hi + pad)
}

fn draw<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, c: &Chart) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let xr = c
        .x_range
        .unwrap_or_else(|| range(c.series.iter().flat_map(|s| s.points.iter().map(|p| p.0))));
    let yr = c
        .y_range
        .unwrap_or_else(|| range(c.series.iter().flat_map(|s| s.points.iter().map(|p| p.1))));
    let mut chart = ChartBuilder::on(&root)
        .caption(&c.title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    chart
        .configure_mesh()
        .x_desc(c.x_label.as_str())
        .y_desc(c.y_label.as_str())
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    for (i, s) in c.series.iter().enumerate() {
        let color = COLORS[i % COLORS.len()];
        let anno = match s.mark {
            Mark::Line => chart
                .draw_series(LineSeries::new(
                    s.points.iter().copied(),
                    color.stroke_width(2),
                ))
                .map_err(|e| anyhow::anyhow!("{e:?}"))?,
            Mark::Points => chart
                .draw_series(
                    s.points
                        .iter()
                        .map(|&p| Circle::new(p, 3, color.mix(0.7).filled())),
                )
                .map_err(|e| anyhow::anyhow!("{e:?}"))?,
            Mark::LinePoints => {
                chart
                    .draw_series(s.points.iter().map(|&p| Circle::new(p, 4, color.filled())))
                    .map_err(|e| anyhow::anyhow!("{e:?}"))?;
                chart
                    .draw_series(LineSeries::new(
                        s.points.iter().copied(),
                        color.stroke_width(2),
                    ))
                    .map_err(|e| anyhow::anyhow!("{e:?}"))?
            }
        };
        anno.label(s.name.as_str())
            .legend(move |(x, y)| Rectangle::new([(x, y - 4), (x + 14, y + 4)], color.filled()));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .position(SeriesLabelPosition::UpperLeft)
        .draw()
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    root.present().map_err(|e| anyhow::anyhow!("{e:?}"))?;
    Ok(())
}

/// Writes the chart to `path` (`.svg` or `.png`, 900 x 650).
pub fn write(path: &Path, chart: &Chart) -> anyhow::Result<()> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let size = (900, 650);
    // Both backends lay text out with the font's metrics.
    register_font();
    match ext.as_str() {
        "svg" => draw(SVGBackend::new(path, size).into_drawing_area(), chart),
        "png" => draw(BitMapBackend::new(path, size).into_drawing_area(), chart),
        _ => Err(anyhow::anyhow!(
            "{}: plot files must end in .svg or .png",
            path.display()
        )),
    }
    .map_err(|e| anyhow::anyhow!("{}: {e:#}", path.display()))
}

/// Writes one figure twice, as `DIR/STEM.svg` and `DIR/STEM.png` (DIR is created), with
/// `draw(path)`; returns both paths. Offline commands use it for their `--plots DIR`.
pub fn svg_and_png(
    dir: &Path,
    stem: &str,
    mut draw: impl FnMut(&Path) -> anyhow::Result<()>,
) -> anyhow::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?;
    let mut out = Vec::new();
    for ext in ["svg", "png"] {
        let p = dir.join(format!("{stem}.{ext}"));
        draw(&p)?;
        out.push(p);
    }
    Ok(out)
}

/// Scatter of `points` with the identity line over `range` (predicted vs true plots).
pub fn scatter_with_identity(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    points: &[(f64, f64)],
    range: (f64, f64),
) -> anyhow::Result<()> {
    write(
        path,
        &Chart {
            title: title.to_string(),
            x_label: x_label.to_string(),
            y_label: y_label.to_string(),
            series: vec![
                Series {
                    name: "ideal (y = x)".into(),
                    points: vec![(range.0, range.0), (range.1, range.1)],
                    mark: Mark::Line,
                },
                Series {
                    name: "samples".into(),
                    points: points.to_vec(),
                    mark: Mark::Points,
                },
            ],
            x_range: Some(range),
            y_range: Some(range),
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_svg_and_png_and_refuses_other_names() {
        let dir = tempfile::tempdir().expect("tempdir");
        let pts: Vec<(f64, f64)> = (0..20).map(|i| (i as f64, i as f64 * 1.1)).collect();
        for name in ["a.svg", "a.png"] {
            let p = dir.path().join(name);
            scatter_with_identity(&p, "t", "x (1/m)", "y (1/m)", &pts, (0.0, 25.0)).expect("plot");
            let bytes = std::fs::read(&p).expect("read");
            assert!(bytes.len() > 1000, "{name}: {} bytes", bytes.len());
        }
        let svg = std::fs::read_to_string(dir.path().join("a.svg")).expect("svg");
        assert!(svg.contains("x (1/m)") && svg.contains("samples"));
        let png = std::fs::read(dir.path().join("a.png")).expect("png");
        assert_eq!(&png[..4], b"\x89PNG");
        assert!(
            scatter_with_identity(&dir.path().join("a.jpg"), "t", "x", "y", &pts, (0.0, 1.0))
                .is_err()
        );
        let both = svg_and_png(&dir.path().join("sub"), "b", |p| {
            scatter_with_identity(p, "t", "x (N)", "y (N)", &pts, (0.0, 25.0))
        })
        .expect("both");
        assert_eq!(both.len(), 2);
        assert!(both.iter().all(|p| p.exists()), "{both:?}");
    }
}
