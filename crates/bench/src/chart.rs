//! Line charts as SVG files (plotters' SVG backend: no fonts or system libraries needed, and the
//! files diff and render well on any Markdown viewer).

use crate::error::BenchError;
use plotters::prelude::*;
use std::path::Path;

/// One line of a chart.
#[derive(Clone, Debug)]
pub struct Series {
    pub label: String,
    /// (x, y) points, drawn in the order given. On a log axis, points with a non-positive or
    /// non-finite coordinate are left out.
    pub points: Vec<(f64, f64)>,
    /// Drawn dashed and grey: a reference (e.g. the 1/√t slope), not a measurement.
    pub reference: bool,
}

impl Series {
    pub fn new(label: impl Into<String>, points: Vec<(f64, f64)>) -> Series {
        Series {
            label: label.into(),
            points,
            reference: false,
        }
    }

    pub fn reference(label: impl Into<String>, points: Vec<(f64, f64)>) -> Series {
        Series {
            reference: true,
            ..Series::new(label, points)
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scale {
    Linear,
    Log,
}

/// Titles and axes of a chart.
#[derive(Clone, Debug)]
pub struct ChartSpec<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    pub y_label: &'a str,
    pub x_scale: Scale,
    pub y_scale: Scale,
}

impl<'a> ChartSpec<'a> {
    /// Log–log axes: the error-against-time charts.
    pub fn log_log(title: &'a str, x_label: &'a str, y_label: &'a str) -> Self {
        ChartSpec {
            title,
            x_label,
            y_label,
            x_scale: Scale::Log,
            y_scale: Scale::Log,
        }
    }

    pub fn linear(title: &'a str, x_label: &'a str, y_label: &'a str) -> Self {
        ChartSpec {
            title,
            x_label,
            y_label,
            x_scale: Scale::Linear,
            y_scale: Scale::Linear,
        }
    }
}

const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

fn usable(p: (f64, f64), spec: &ChartSpec) -> bool {
    let ok = |v: f64, s: Scale| v.is_finite() && (s == Scale::Linear || v > 0.0);
    ok(p.0, spec.x_scale) && ok(p.1, spec.y_scale)
}

/// The axis range covering `values`, padded a little (a factor on log axes).
fn range(values: impl Iterator<Item = f64>, scale: Scale) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() || !hi.is_finite() {
        return match scale {
            Scale::Linear => (0.0, 1.0),
            Scale::Log => (0.1, 10.0),
        };
    }
    match scale {
        Scale::Log => {
            let (lo, hi) = if hi / lo < 1.5 {
                (lo / 1.5, hi * 1.5)
            } else {
                (lo, hi)
            };
            (lo / 1.15, hi * 1.15)
        }
        Scale::Linear => {
            let span = if hi > lo { hi - lo } else { hi.abs().max(1.0) };
            let lo = if lo >= 0.0 && lo < 0.3 * span {
                0.0
            } else {
                lo - 0.05 * span
            };
            (lo, hi + 0.05 * span)
        }
    }
}

/// Draws `series` into an SVG file at `path` (800×500).
pub fn line_chart(path: &Path, spec: &ChartSpec, series: &[Series]) -> Result<(), BenchError> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| BenchError::io(dir, e))?;
    }
    let chart_err = |e: &dyn std::fmt::Display| BenchError::Chart {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let pts: Vec<Vec<(f64, f64)>> = series
        .iter()
        .map(|s| {
            s.points
                .iter()
                .copied()
                .filter(|&p| usable(p, spec))
                .collect()
        })
        .collect();
    let xr = range(pts.iter().flatten().map(|p| p.0), spec.x_scale);
    let yr = range(pts.iter().flatten().map(|p| p.1), spec.y_scale);

    let root = SVGBackend::new(path, (800, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| chart_err(&e))?;
    let mut builder = ChartBuilder::on(&root);
    builder
        .caption(spec.title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(42)
        .y_label_area_size(70);
    // The four axis-scale combinations are four different coordinate types in plotters.
    macro_rules! draw {
        ($chart:expr) => {{
            let mut chart = $chart.map_err(|e| chart_err(&e))?;
            chart
                .configure_mesh()
                .x_desc(spec.x_label)
                .y_desc(spec.y_label)
                .light_line_style(RGBColor(235, 235, 235))
                .draw()
                .map_err(|e| chart_err(&e))?;
            let mut colour = 0;
            for (s, p) in series.iter().zip(&pts) {
                if p.is_empty() {
                    continue;
                }
                let style = if s.reference {
                    RGBColor(150, 150, 150).stroke_width(1)
                } else {
                    let c = PALETTE[colour % PALETTE.len()];
                    colour += 1;
                    c.stroke_width(2)
                };
                let drawn = if s.reference {
                    chart.draw_series(DashedLineSeries::new(p.iter().copied(), 6, 4, style))
                } else {
                    chart.draw_series(LineSeries::new(p.iter().copied(), style))
                };
                let legend_style = style;
                drawn
                    .map_err(|e| chart_err(&e))?
                    .label(s.label.as_str())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 18, y)], legend_style)
                    });
                if !s.reference {
                    chart
                        .draw_series(p.iter().map(|&q| Circle::new(q, 3, style.filled())))
                        .map_err(|e| chart_err(&e))?;
                }
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(RGBColor(200, 200, 200))
                .position(SeriesLabelPosition::UpperRight)
                .draw()
                .map_err(|e| chart_err(&e))?;
        }};
    }
    match (spec.x_scale, spec.y_scale) {
        (Scale::Log, Scale::Log) => {
            draw!(builder.build_cartesian_2d((xr.0..xr.1).log_scale(), (yr.0..yr.1).log_scale()))
        }
        (Scale::Log, Scale::Linear) => {
            draw!(builder.build_cartesian_2d((xr.0..xr.1).log_scale(), yr.0..yr.1))
        }
        (Scale::Linear, Scale::Log) => {
            draw!(builder.build_cartesian_2d(xr.0..xr.1, (yr.0..yr.1).log_scale()))
        }
        (Scale::Linear, Scale::Linear) => draw!(builder.build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)),
    }
    root.present().map_err(|e| chart_err(&e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_a_log_log_svg_with_every_series() {
        let dir = std::env::temp_dir().join(format!("pathfarm-chart-{}", std::process::id()));
        let path = dir.join("c.svg");
        let a = Series::new(
            "mis",
            vec![(0.1, 0.3), (0.2, 0.21), (0.4, 0.15), (0.0, 9.0)],
        );
        let r = Series::reference("1/√t", vec![(0.1, 0.3), (0.4, 0.15)]);
        line_chart(&path, &ChartSpec::log_log("t", "time (s)", "RMSE"), &[a, r]).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        assert!(svg.starts_with("<svg"), "{}", &svg[..40.min(svg.len())]);
        assert!(svg.contains("mis") && svg.contains("1/√t") && svg.contains("RMSE"));
        let _ = std::fs::remove_dir_all(dir);
    }
}
