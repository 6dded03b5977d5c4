//! Deformed-structure drawings coloured by a displacement component, like the contour
//! screens of a CAD package's FEA (the paper's Fig. 4).

use plotters::prelude::*;

use crate::{PlotError, register_font};

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

/// Blue → cyan → green → yellow → red, for t in [0, 1].
pub fn rainbow(t: f64) -> RGBColor {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let stops = [
        (0.0, (48.0, 18.0, 180.0)),
        (0.25, (30.0, 150.0, 230.0)),
        (0.5, (60.0, 190.0, 80.0)),
        (0.75, (240.0, 200.0, 40.0)),
        (1.0, (210.0, 30.0, 30.0)),
    ];
    let k = stops
        .windows(2)
        .position(|w| t <= w[1].0)
        .unwrap_or(stops.len() - 2);
    let (a, b) = (stops[k], stops[k + 1]);
    let f = (t - a.0) / (b.0 - a.0);
    let mix = |x: f64, y: f64| (x + (y - x) * f).round() as u8;
    RGBColor(mix(a.1.0, b.1.0), mix(a.1.1, b.1.1), mix(a.1.2, b.1.2))
}

/// Renders panels side by side, each with its own colour bar, into one SVG document.
pub fn structure_svg(panels: &[StructurePanel], panel: (u32, u32)) -> Result<String, PlotError> {
    register_font();
    let mut out = String::new();
    {
        let size = (panel.0 * panels.len().max(1) as u32, panel.1);
        let root = SVGBackend::with_string(&mut out, size).into_drawing_area();
        let err = |e: &dyn std::fmt::Display| PlotError::Drawing(e.to_string());
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
            let (plot_area, bar_area) = area.split_horizontally(panel.0 - 110);
            let mut c = ChartBuilder::on(&plot_area)
                .caption(&p.title, ("sans-serif", 17))
                .margin(10)
                .x_label_area_size(40)
                .y_label_area_size(60)
                .build_cartesian_2d(cx - hw..cx + hw, cy - hh..cy + hh)
                .map_err(|e| err(&e))?;
            c.configure_mesh()
                .x_desc(p.x_label.as_str())
                .y_desc(p.y_label.as_str())
                .label_style(("sans-serif", 12))
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
                    let col = rainbow((v - vmin) / span);
                    c.draw_series(std::iter::once(PathElement::new(
                        vec![seg[0], seg[1]],
                        col.stroke_width(m.width.max(1)),
                    )))
                    .map_err(|e| err(&e))?;
                }
                if let Some(&first) = m.displaced.last() {
                    c.draw_series(std::iter::once(Text::new(
                        m.name.clone(),
                        first,
                        ("sans-serif", 12).into_font(),
                    )))
                    .map_err(|e| err(&e))?;
                }
            }
            // Colour bar.
            let (bw, bh) = bar_area.dim_in_pixel();
            let (top, bottom) = (40i32, bh as i32 - 50);
            let n = 64;
            for i in 0..n {
                let t0 = i as f64 / n as f64;
                let y_hi = bottom - ((bottom - top) as f64 * (t0 + 1.0 / n as f64)) as i32;
                let y_lo = bottom - ((bottom - top) as f64 * t0) as i32;
                bar_area
                    .draw(&Rectangle::new(
                        [(12, y_hi), (36, y_lo)],
                        rainbow(t0 + 0.5 / n as f64).filled(),
                    ))
                    .map_err(|e| err(&e))?;
            }
            let style = ("sans-serif", 12).into_font();
            for (t, v) in [(0.0, vmin), (0.5, 0.5 * (vmin + vmax)), (1.0, vmax)] {
                let y = bottom - ((bottom - top) as f64 * t) as i32;
                bar_area
                    .draw(&Text::new(format!("{v:.3}"), (40, y - 6), style.clone()))
                    .map_err(|e| err(&e))?;
            }
            bar_area
                .draw(&Text::new(
                    p.value_label.clone(),
                    (4, 14),
                    ("sans-serif", 12).into_font(),
                ))
                .map_err(|e| err(&e))?;
            let _ = bw;
        }
        root.present().map_err(|e| err(&e))?;
    }
    Ok(out)
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

    #[test]
    fn the_colour_map_runs_from_blue_to_red() {
        let (lo, hi) = (rainbow(0.0), rainbow(1.0));
        assert!(lo.2 > lo.0 && hi.0 > hi.2);
        assert_eq!(rainbow(f64::NAN), rainbow(0.0));
    }
}
