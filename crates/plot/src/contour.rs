//! Deformed-structure drawings coloured by a displacement component, like the contour
//! screens of a CAD package's FEA (the paper's Fig. 4).

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::style::{self, err};
use crate::{PlotError, Rgb, register_font};

/// A member drawn as a polyline, at rest (grey) and displaced (coloured).
#[derive(Debug, Clone, PartialEq)]
pub struct Member {
    /// Label written next to the member's first displaced point.
    pub name: String,
    /// Drawing coordinates at rest.
    pub rest: Vec<(f64, f64)>,
    /// Drawing coordinates displaced (magnified as the caller wishes).
    pub displaced: Vec<(f64, f64)>,
    /// The coloured quantity at each point.
    pub values: Vec<f64>,
    /// Line width, px.
    pub width: u32,
}

/// One panel of members.
#[derive(Debug, Clone, PartialEq)]
pub struct StructurePanel {
    /// Title.
    pub title: String,
    /// Horizontal axis label.
    pub x_label: String,
    /// Vertical axis label.
    pub y_label: String,
    /// Colour-bar label (quantity and unit).
    pub value_label: String,
    /// Members.
    pub members: Vec<Member>,
}

fn draw_structure<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    panels: &[StructurePanel],
    panel: (u32, u32),
) -> Result<(), PlotError> {
    {
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let areas = root.split_evenly((1, panels.len().max(1)));
        for (p, area) in panels.iter().zip(areas.iter()) {
            let pts = p
                .members
                .iter()
                .flat_map(|m| m.rest.iter().chain(&m.displaced))
                .filter(|q| q.0.is_finite() && q.1.is_finite());
            let (mut x0, mut x1, mut y0, mut y1) = (
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
            );
            for q in pts {
                x0 = x0.min(q.0);
                x1 = x1.max(q.0);
                y0 = y0.min(q.1);
                y1 = y1.max(q.1);
            }
            if !x0.is_finite() {
                return Err(PlotError::NoData {
                    chart: p.title.clone(),
                });
            }
            // Equal scales: widen the narrower range.
            let (w, h) = (x1 - x0, y1 - y0);
            let aspect = (panel.0 as f64 - 190.0) / (panel.1 as f64 - 80.0);
            let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
            let (hw, hh) = if w / h > aspect {
                (0.55 * w, 0.55 * w / aspect)
            } else {
                (0.55 * h * aspect, 0.55 * h)
            };
            let (vmin, vmax) = p
                .members
                .iter()
                .flat_map(|m| m.values.iter())
                .filter(|v| v.is_finite())
                .fold((f64::INFINITY, f64::NEG_INFINITY), |a, &v| {
                    (a.0.min(v), a.1.max(v))
                });
            let span = if vmax > vmin { vmax - vmin } else { 1.0 };
            let (plot_area, bar_area) =
                area.split_horizontally(panel.0.saturating_sub(style::COLOUR_BAR_WIDTH));
            let mut c = ChartBuilder::on(&plot_area)
                .caption(&p.title, style::title())
                .margin(style::MARGIN)
                .x_label_area_size(style::X_LABEL_AREA)
                .y_label_area_size(style::Y_LABEL_AREA)
                .build_cartesian_2d(cx - hw..cx + hw, cy - hh..cy + hh)
                .map_err(|e| err(&e))?;
            c.configure_mesh()
                .x_desc(p.x_label.as_str())
                .y_desc(p.y_label.as_str())
                .label_style(style::label())
                .axis_desc_style(style::label())
                .x_labels(style::TICKS)
                .y_labels(style::TICKS)
                .x_label_formatter(&style::tick_formatter(cx - hw, cx + hw))
                .y_label_formatter(&style::tick_formatter(cy - hh, cy + hh))
                .light_line_style(WHITE)
                .draw()
                .map_err(|e| err(&e))?;
            for m in &p.members {
                c.draw_series(LineSeries::new(
                    m.rest.iter().copied(),
                    RGBColor(190, 190, 190).stroke_width(m.width.max(1)),
                ))
                .map_err(|e| err(&e))?;
            }
            for m in &p.members {
                for (k, seg) in m.displaced.windows(2).enumerate() {
                    let v = 0.5 * (m.values[k] + m.values[(k + 1).min(m.values.len() - 1)]);
                    let col = style::colour_map((v - vmin) / span);
                    c.draw_series(std::iter::once(PathElement::new(
                        vec![seg[0], seg[1]],
                        col.stroke_width(m.width.max(1)),
                    )))
                    .map_err(|e| err(&e))?;
                }
            }
            // Labels: each member's name where it overlaps no other label, trying points
            // along the member (middle first) and sides of it.
            let mut placed: Vec<(i32, i32, i32, i32)> = Vec::new();
            for m in &p.members {
                let n = m.displaced.len();
                if n == 0 {
                    continue;
                }
                let (w, h) = (7 * m.name.chars().count() as i32 + 4, 16);
                let candidates = [n / 2, n - 1, 0, n / 4, 3 * n / 4];
                let offsets = [(8, -8), (8, 10), (-w - 8, -8), (-w - 8, 10)];
                let spot = candidates.iter().flat_map(|&k| {
                    let (px, py) = c.backend_coord(&m.displaced[k.min(n - 1)]);
                    offsets.iter().map(move |&(dx, dy)| (px + dx, py + dy))
                });
                let free = |(x, y): (i32, i32), placed: &[(i32, i32, i32, i32)]| {
                    placed
                        .iter()
                        .all(|&(a, b, c2, d)| x + w < a || x > c2 || y + h < b || y > d)
                };
                let chosen = spot.clone().find(|&q| free(q, &placed));
                // Every spot taken: the first one (a crowded drawing still names all).
                let Some((x, y)) = chosen.or_else(|| spot.clone().next()) else {
                    continue;
                };
                placed.push((x, y, x + w, y + h));
                root.draw(&Text::new(m.name.clone(), (x, y), style::label()))
                    .map_err(|e| err(&e))?;
            }
            style::colour_bar(&bar_area, vmin, vmax, &p.value_label)?;
        }
    }
    Ok(())
}

/// Renders panels side by side, each with its own colour bar, into one SVG document.
pub fn structure_svg(panels: &[StructurePanel], panel: (u32, u32)) -> Result<String, PlotError> {
    register_font();
    let mut out = String::new();
    {
        let size = (panel.0 * panels.len().max(1) as u32, panel.1);
        let root = SVGBackend::with_string(&mut out, size).into_drawing_area();
        draw_structure(&root, panels, panel)?;
        root.present().map_err(|e| err(&e))?;
    }
    Ok(out)
}

/// The same drawing as [`structure_svg`], as RGB pixels for the caller to encode as PNG.
pub fn structure_rgb(panels: &[StructurePanel], panel: (u32, u32)) -> Result<Rgb, PlotError> {
    register_font();
    let size = (panel.0 * panels.len().max(1) as u32, panel.1);
    let mut buf = vec![0u8; size.0 as usize * size.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        draw_structure(&root, panels, panel)?;
        root.present().map_err(|e| err(&e))?;
    }
    Ok(Rgb {
        width: size.0,
        height: size.1,
        data: buf,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_members_and_a_colour_bar() {
        let m = Member {
            name: "beam".into(),
            rest: vec![(0.0, 0.0), (1.0, 0.0)],
            displaced: vec![(0.0, 0.0), (1.0, 0.2)],
            values: vec![0.0, 0.2],
            width: 4,
        };
        let p = StructurePanel {
            title: "δy".into(),
            x_label: "x [mm]".into(),
            y_label: "y [mm]".into(),
            value_label: "δy [µm]".into(),
            members: vec![m],
        };
        let s = structure_svg(&[p], (600, 400)).unwrap();
        assert!(s.starts_with("<svg") && s.contains("δy [µm]") && s.contains("beam"));
    }
}
