//! # cellinject-plot
//!
//! The plots of cellinject's commands: line charts ([`svg`], [`rgb`]), maps of a
//! quantity over a grid ([`map`]) and deformed-structure drawings ([`contour`]), each
//! as an SVG document or an RGB pixel buffer the caller encodes as PNG. One style
//! ([`style`]) for all: fonts, margins, ticks, colours, colour map and colour bars.
//! Text is laid out with DejaVu Sans, embedded in the crate, so a fresh machine needs no
//! font library.
//!
//! **Architecture invariant:** plotting returns text or pixels; it writes no file.

use std::sync::OnceLock;

pub mod contour;
pub mod frame;
mod legend;
pub mod map;
pub mod style;

use plotters::chart::SeriesLabelPosition;
use plotters::coord::Shift;
use plotters::prelude::*;
use style::err;
use thiserror::Error;

/// The embedded font (DejaVu Sans, Bitstream Vera licence: assets/fonts/DejaVu-LICENSE.txt).
const FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");

/// Why a chart could not be drawn.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PlotError {
    /// A series holds no finite point.
    #[error("chart `{chart}` has no finite data")]
    NoData {
        /// Chart title.
        chart: String,
    },
    /// The drawing backend failed.
    #[error("drawing failed: {0}")]
    Drawing(String),
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Style {
    /// A polyline through the points.
    #[default]
    Line,
    /// A dot at each point (a scatter plot).
    Dots,
}

/// One line (or cloud of dots) of a chart.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend entry.
    pub name: String,
    /// (x, y) points in drawing order.
    pub points: Vec<(f64, f64)>,
    /// Line or dots.
    pub style: Style,
}

/// One panel.
#[derive(Debug, Clone, PartialEq)]
pub struct Chart {
    /// Title above the panel.
    pub title: String,
    /// Label of the horizontal axis (with its unit).
    pub x_label: String,
    /// Label of the vertical axis (with its unit).
    pub y_label: String,
    /// Lines.
    pub series: Vec<Series>,
}

fn register_font() {
    static DONE: OnceLock<()> = OnceLock::new();
    DONE.get_or_init(|| {
        // The font is embedded and known to parse; a failure would only lose text.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// Closed interval (low, high).
type Range = (f64, f64);

fn bounds(chart: &Chart) -> Result<(Range, Range), PlotError> {
    let mut xr = (f64::INFINITY, f64::NEG_INFINITY);
    let mut yr = (f64::INFINITY, f64::NEG_INFINITY);
    for s in &chart.series {
        for &(x, y) in &s.points {
            if x.is_finite() && y.is_finite() {
                xr = (xr.0.min(x), xr.1.max(x));
                yr = (yr.0.min(y), yr.1.max(y));
            }
        }
    }
    if !xr.0.is_finite() {
        return Err(PlotError::NoData {
            chart: chart.title.clone(),
        });
    }
    let pad = |r: (f64, f64)| {
        let span = (r.1 - r.0).abs();
        let p = if span > 0.0 {
            0.05 * span
        } else {
            1e-12f64.max(r.0.abs() * 0.05)
        };
        (r.0 - p, r.1 + p)
    };
    // A line's ends sit on the frame; dots get room on every side.
    let x = if chart.series.iter().any(|s| s.style == Style::Dots) {
        pad(xr)
    } else {
        (xr.0, xr.1.max(xr.0 + f64::EPSILON))
    };
    Ok((x, pad(yr)))
}

fn draw_charts<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    charts: &[Chart],
    columns: usize,
) -> Result<(), PlotError> {
    let rows = charts.len().div_ceil(columns);
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let areas = root.split_evenly((rows.max(1), columns));
    for (chart, area) in charts.iter().zip(areas.iter()) {
        let ((x0, x1), (y0, y1)) = bounds(chart)?;
        let legend = chart.series.len() > 1 || chart.series.iter().any(|s| !s.name.is_empty());
        // The legend in the corner clear of the data (or above it, the range raised).
        let (corner, y1) = if legend {
            let (w, h) = area.dim_in_pixel();
            let plot_w = f64::from(w.saturating_sub(style::Y_LABEL_AREA + 2 * style::MARGIN));
            let plot_h = f64::from(h.saturating_sub(style::X_LABEL_AREA + 2 * style::MARGIN + 30));
            let chars = chart.series.iter().map(|s| s.name.chars().count()).max();
            let (lw, lh) = legend::size_px(chars.unwrap_or(0), chart.series.len());
            let f = (
                (lw / plot_w.max(1.0)).min(1.0),
                (lh / plot_h.max(1.0)).min(1.0),
            );
            legend::place(chart, (x0, x1), (y0, y1), f)
        } else {
            (SeriesLabelPosition::UpperRight, y1)
        };
        let mut c = ChartBuilder::on(area)
            .caption(&chart.title, style::title())
            .margin(style::MARGIN)
            .x_label_area_size(style::X_LABEL_AREA)
            .y_label_area_size(style::Y_LABEL_AREA)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(|e| err(&e))?;
        c.configure_mesh()
            .x_desc(chart.x_label.as_str())
            .y_desc(chart.y_label.as_str())
            .label_style(style::label())
            .axis_desc_style(style::label())
            .x_labels(style::TICKS)
            .y_labels(style::TICKS)
            .x_label_formatter(&style::tick_formatter(x0, x1))
            .y_label_formatter(&style::tick_formatter(y0, y1))
            .draw()
            .map_err(|e| err(&e))?;
        for (k, s) in chart.series.iter().enumerate() {
            let color = style::LINES[k % style::LINES.len()];
            // Thick polylines are joined with mitres, which shoot far out of the panel
            // where a dense, noisy series turns back on itself: dense series are thin.
            let width = if s.points.len() > style::DENSE { 1 } else { 2 };
            let points = s
                .points
                .iter()
                .copied()
                .filter(|(x, y)| x.is_finite() && y.is_finite());
            let drawn = match s.style {
                Style::Line => c.draw_series(LineSeries::new(points, color.stroke_width(width))),
                Style::Dots => c.draw_series(
                    points.map(move |p| Circle::new(p, style::DOT, color.mix(0.7).filled())),
                ),
            };
            drawn
                .map_err(|e| err(&e))?
                .label(s.name.as_str())
                .legend(move |(x, y)| match s.style {
                    Style::Line => {
                        PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
                            .into_dyn()
                    }
                    Style::Dots => Circle::new((x + 9, y), style::DOT, color.filled()).into_dyn(),
                });
        }
        if legend {
            c.configure_series_labels()
                .position(corner)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(style::label())
                .draw()
                .map_err(|e| err(&e))?;
        }
    }
    Ok(())
}

fn grid_size(n: usize, columns: usize, panel: (u32, u32)) -> (u32, u32) {
    let rows = n.div_ceil(columns).max(1);
    (panel.0 * columns as u32, panel.1 * rows as u32)
}

/// Renders panels side by side (`columns` per row) into one SVG document.
pub fn svg(charts: &[Chart], columns: usize, panel: (u32, u32)) -> Result<String, PlotError> {
    register_font();
    let columns = columns.max(1);
    let mut out = String::new();
    {
        let size = grid_size(charts.len(), columns, panel);
        let root = SVGBackend::with_string(&mut out, size).into_drawing_area();
        draw_charts(&root, charts, columns)?;
        root.present().map_err(|e| err(&e))?;
    }
    Ok(out)
}

/// The same panels as [`svg`], as RGB pixels (width, height, rows from the top) for the
/// caller to encode as PNG.
pub fn rgb(charts: &[Chart], columns: usize, panel: (u32, u32)) -> Result<Rgb, PlotError> {
    register_font();
    let columns = columns.max(1);
    let size = grid_size(charts.len(), columns, panel);
    let mut buf = vec![0u8; size.0 as usize * size.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        draw_charts(&root, charts, columns)?;
        root.present().map_err(|e| err(&e))?;
    }
    Ok(Rgb {
        width: size.0,
        height: size.1,
        data: buf,
    })
}

/// A rendered picture: 8-bit RGB, rows from the top.
#[derive(Debug, Clone, PartialEq)]
pub struct Rgb {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// `width * height * 3` bytes.
    pub data: Vec<u8>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_an_svg_with_its_labels() {
        let c = Chart {
            title: "loop".into(),
            x_label: "voltage [V]".into(),
            y_label: "displacement [µm]".into(),
            series: vec![Series {
                name: "A1".into(),
                points: (0..50).map(|i| (i as f64, (i as f64).sqrt())).collect(),
                style: Style::Line,
            }],
        };
        let s = svg(&[c.clone(), c], 2, (500, 400)).unwrap();
        assert!(s.starts_with("<svg"));
        assert!(s.contains("voltage [V]") && s.contains("polyline"));
    }

    #[test]
    fn empty_data_is_an_error() {
        let c = Chart {
            title: "empty".into(),
            x_label: String::new(),
            y_label: String::new(),
            series: vec![Series {
                name: String::new(),
                points: vec![(f64::NAN, 1.0)],
                style: Style::Line,
            }],
        };
        assert!(matches!(
            svg(&[c], 1, (100, 100)),
            Err(PlotError::NoData { .. })
        ));
    }
}
