//! Maps of a quantity over a grid (the DIC displacement fields): one panel per quantity,
//! with axes in pixels or micrometres, a colour bar with ticks and the quantity's unit,
//! and grey where there is no value.

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::style::{self, err};
use crate::{PlotError, Rgb, register_font};

/// A quantity sampled on a regular grid.
#[derive(Debug, Clone, PartialEq)]
pub struct GridMap {
    /// Title above the panel.
    pub title: String,
    /// Horizontal axis label, with unit.
    pub x_label: String,
    /// Vertical axis label, with unit (the axis runs downwards, as in an image).
    pub y_label: String,
    /// Colour-bar label: quantity and unit.
    pub value_label: String,
    /// Axis coordinate of the first column's centre, and the step between columns.
    pub x: (f64, f64),
    /// The same for rows.
    pub y: (f64, f64),
    /// Columns.
    pub nx: usize,
    /// Rows.
    pub ny: usize,
    /// Row-major values; `None` where nothing was measured.
    pub values: Vec<Option<f64>>,
}

/// The finite range of a map's values.
fn range(m: &GridMap) -> Option<(f64, f64)> {
    m.values
        .iter()
        .flatten()
        .filter(|v| v.is_finite())
        .fold(None, |r, &v| {
            Some(match r {
                None => (v, v),
                Some((a, b)) => (a.min(v), b.max(v)),
            })
        })
}

fn draw_map<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    m: &GridMap,
) -> Result<(), PlotError> {
    let (lo, hi) = range(m).ok_or_else(|| PlotError::NoData {
        chart: m.title.clone(),
    })?;
    let span = if hi > lo { hi - lo } else { 1.0 };
    let (w, _) = area.dim_in_pixel();
    let (plot, bar) = area.split_horizontally(w.saturating_sub(style::COLOUR_BAR_WIDTH));
    let half = (0.5 * m.x.1, 0.5 * m.y.1);
    let x0 = m.x.0 - half.0;
    let x1 = m.x.0 + m.x.1 * m.nx as f64 - half.0;
    let y0 = m.y.0 - half.1;
    let y1 = m.y.0 + m.y.1 * m.ny as f64 - half.1;
    let mut c = ChartBuilder::on(&plot)
        .caption(&m.title, style::title())
        .margin(style::MARGIN)
        .x_label_area_size(style::X_LABEL_AREA)
        .y_label_area_size(style::Y_LABEL_AREA)
        // Rows run downwards, as in the image.
        .build_cartesian_2d(x0..x1, y1..y0)
        .map_err(|e| err(&e))?;
    c.configure_mesh()
        .x_desc(m.x_label.as_str())
        .y_desc(m.y_label.as_str())
        .label_style(style::label())
        .axis_desc_style(style::label())
        .x_labels(style::TICKS)
        .y_labels(style::TICKS)
        .x_label_formatter(&style::tick_formatter(x0, x1))
        .y_label_formatter(&style::tick_formatter(y0, y1))
        .disable_mesh()
        .draw()
        .map_err(|e| err(&e))?;
    c.draw_series(m.values.iter().enumerate().map(|(k, v)| {
        let (i, j) = ((k % m.nx) as f64, (k / m.nx) as f64);
        let cx = m.x.0 + i * m.x.1;
        let cy = m.y.0 + j * m.y.1;
        let colour = match v {
            Some(v) if v.is_finite() => style::colour_map((v - lo) / span),
            _ => style::MISSING,
        };
        Rectangle::new(
            [(cx - half.0, cy - half.1), (cx + half.0, cy + half.1)],
            colour.filled(),
        )
    }))
    .map_err(|e| err(&e))?;
    style::colour_bar(&bar, lo, hi, &m.value_label)
}

/// Panels side by side into an SVG document.
pub fn maps_svg(maps: &[GridMap], panel: (u32, u32)) -> Result<String, PlotError> {
    register_font();
    let mut out = String::new();
    {
        let size = (panel.0 * maps.len().max(1) as u32, panel.1);
        let root = SVGBackend::with_string(&mut out, size).into_drawing_area();
        draw_all(&root, maps)?;
        root.present().map_err(|e| err(&e))?;
    }
    Ok(out)
}

/// Panels side by side as RGB pixels, for the caller to encode as PNG.
pub fn maps_rgb(maps: &[GridMap], panel: (u32, u32)) -> Result<Rgb, PlotError> {
    register_font();
    let size = (panel.0 * maps.len().max(1) as u32, panel.1);
    let mut buf = vec![0u8; size.0 as usize * size.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        draw_all(&root, maps)?;
        root.present().map_err(|e| err(&e))?;
    }
    Ok(Rgb {
        width: size.0,
        height: size.1,
        data: buf,
    })
}

fn draw_all<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    maps: &[GridMap],
) -> Result<(), PlotError> {
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let areas = root.split_evenly((1, maps.len().max(1)));
    for (m, area) in maps.iter().zip(areas.iter()) {
        draw_map(area, m)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map() -> GridMap {
        GridMap {
            title: "u".into(),
            x_label: "x [px]".into(),
            y_label: "y [px]".into(),
            value_label: "u [px]".into(),
            x: (15.0, 5.0),
            y: (15.0, 5.0),
            nx: 4,
            ny: 3,
            values: (0..12)
                .map(|k| (k != 5).then_some(k as f64 * 0.01))
                .collect(),
        }
    }

    #[test]
    fn a_map_has_axes_a_colour_bar_and_units() {
        let s = maps_svg(&[map(), map()], (500, 400)).unwrap();
        assert!(s.contains("x [px]") && s.contains("u [px]"));
        // The colour bar's extreme ticks are the data's range.
        assert!(s.contains("0.110") && s.contains("0.000"), "{s}");
        let Rgb {
            width: w,
            height: h,
            data: px,
        } = maps_rgb(&[map()], (500, 400)).unwrap();
        assert_eq!((w, h, px.len()), (500, 400, 500 * 400 * 3));
        // Not blank: the colour map paints some pixels that are neither white nor black.
        assert!(px.chunks(3).any(|p| p[0] != p[1] || p[1] != p[2]));
    }

    #[test]
    fn a_map_without_values_is_an_error() {
        let mut m = map();
        m.values = vec![None; 12];
        assert!(matches!(
            maps_svg(&[m], (300, 300)),
            Err(PlotError::NoData { .. })
        ));
    }
}
