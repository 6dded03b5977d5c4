//! `cellinject vision cells`'s report: what a micrograph holds, as JSON and as text.

use cellinject_cells::tip::FoundTip;
use cellinject_cells::vision::{Census, Found};
use cellinject_plot::frame::Outline;
use serde::Serialize;

/// One cell or piece of debris (docs/json.md, `vision cells`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Seen {
    /// Pixels, the centre's column (from the centre of the top-left pixel).
    pub x_px: f64,
    /// Pixels, the centre's row.
    pub y_px: f64,
    /// Pixels, the outline's diameter.
    pub diameter_px: f64,
    /// m, the same through the pixel size; `None` without one.
    pub diameter_m: Option<f64>,
    /// 0-1.
    pub confidence: f64,
    /// `bright` or `dark`: how the body differs from its surroundings.
    pub contrast: &'static str,
}

/// The overlay's outlines of a census: the cells (green, numbered first, most
/// confident first), then the debris (orange).
pub fn outlines(census: &Census) -> Vec<Outline> {
    census
        .cells
        .iter()
        .map(|f| (f, true))
        .chain(census.debris.iter().map(|f| (f, false)))
        .map(|(f, primary)| Outline {
            centre: [f.x, f.y],
            radius: 0.5 * f.diameter,
            primary,
        })
        .collect()
}

/// What `vision cells` found in one image.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CellsReport {
    /// m per pixel in the object plane, when given.
    pub pixel_size_m: Option<f64>,
    /// The cells, by confidence.
    pub cells: Vec<Seen>,
    /// Sharp outlines smaller than a cell, by confidence.
    pub debris: Vec<Seen>,
}

impl CellsReport {
    /// The report of `census`, sizes in m too when `pixel_size` (m) is known.
    pub fn new(census: &Census, pixel_size: Option<f64>) -> Self {
        let seen = |f: &Found| Seen {
            x_px: f.x,
            y_px: f.y,
            diameter_px: f.diameter,
            diameter_m: pixel_size.map(|p| f.diameter * p),
            confidence: f.confidence,
            contrast: f.polarity.name(),
        };
        CellsReport {
            pixel_size_m: pixel_size,
            cells: census.cells.iter().map(seen).collect(),
            debris: census.debris.iter().map(seen).collect(),
        }
    }

    /// For people: a summary line naming the image (`name`, `width` x `height` px),
    /// then one line per cell and per piece of debris, numbered as the overlay
    /// numbers them (cells first).
    pub fn text(&self, name: &str, width: usize, height: usize) -> String {
        let count =
            |n: usize, one: &str, many: &str| format!("{n} {}", if n == 1 { one } else { many });
        let scale = self
            .pixel_size_m
            .map(|p| format!(" at {:.4} µm/px", p * 1e6))
            .unwrap_or_default();
        let mut out = format!(
            "{} and {} in {name} ({width}x{height} px{scale})\n",
            count(self.cells.len(), "cell", "cells"),
            count(self.debris.len(), "piece of debris", "pieces of debris"),
        );
        let all = self.cells.iter().map(|s| ("cell", s));
        let all = all.chain(self.debris.iter().map(|s| ("debris", s)));
        for (k, (what, s)) in all.enumerate() {
            let size = s
                .diameter_m
                .map(|d| format!(" ({:.2} µm)", d * 1e6))
                .unwrap_or_default();
            out += &format!(
                "{:>3}  {what:<6}  centre ({:.1}, {:.1}) px  diameter {:.1} px{size}  {}  confidence {:.2}\n",
                k + 1,
                s.x_px,
                s.y_px,
                s.diameter_px,
                s.contrast,
                s.confidence
            );
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cellinject_cells::vision::Polarity;

    #[test]
    fn the_text_numbers_cells_then_debris_and_gives_micrometres_with_a_pixel_size() {
        let f = |x: f64, d: f64| Found {
            x,
            y: 2.0,
            diameter: d,
            confidence: 0.8,
            polarity: Polarity::Bright,
        };
        let census = Census {
            cells: vec![f(10.0, 100.0)],
            debris: vec![f(50.0, 20.0), f(60.0, 21.0)],
        };
        let r = CellsReport::new(&census, Some(0.1e-6));
        assert_eq!(r.cells[0].diameter_m, Some(100.0 * 0.1e-6));
        let t = r.text("a.png", 640, 480);
        let lines: Vec<&str> = t.lines().collect();
        assert_eq!(
            lines[0],
            "1 cell and 2 pieces of debris in a.png (640x480 px at 0.1000 µm/px)"
        );
        assert!(lines[1].starts_with("  1  cell ") && lines[1].contains("(10.00 µm)"));
        assert!(lines[3].starts_with("  3  debris"));
        let bare = CellsReport::new(&census, None);
        assert_eq!(bare.cells[0].diameter_m, None);
        assert!(!bare.text("a.png", 1, 1).contains("µm"));
    }
}

/// What `vision tip` found in one image (docs/json.md, `vision tip`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VisionTip {
    /// m per pixel in the object plane, when given.
    pub pixel_size_m: Option<f64>,
    /// Pixels, the tip's (column, row) from the centre of the top-left pixel.
    pub tip_px: [f64; 2],
    /// rad, the axis from the tip towards the shank (`atan2(dy, dx)`, y down the image).
    pub axis_rad: f64,
    /// Pixels, the tube's width 5 µm behind the tip (its darkness's full width at half
    /// height).
    pub width_px: f64,
    /// m, the same through the pixel size; `None` without one.
    pub width_m: Option<f64>,
    /// 0-1: how well the darkness along the axis fits a tube ending at the tip.
    pub confidence: f64,
}

impl VisionTip {
    /// The report of `tip`, the width in m too when `pixel_size` (m) is known.
    pub fn new(tip: &FoundTip, pixel_size: Option<f64>) -> Self {
        VisionTip {
            pixel_size_m: pixel_size,
            tip_px: [tip.x, tip.y],
            axis_rad: tip.axis_rad,
            width_px: tip.width,
            width_m: pixel_size.map(|p| tip.width * p),
            confidence: tip.confidence,
        }
    }

    /// For people: one line naming the image (`name`, `width` x `height` px).
    pub fn text(&self, name: &str, width: usize, height: usize) -> String {
        let scale = self
            .pixel_size_m
            .map(|p| format!(" at {:.4} µm/px", p * 1e6))
            .unwrap_or_default();
        let size = self
            .width_m
            .map(|w| format!(" ({:.2} µm)", w * 1e6))
            .unwrap_or_default();
        format!(
            "pipette tip at ({:.1}, {:.1}) px in {name} ({width}x{height} px{scale}): axis {:.1}° towards the shank, width {:.1} px{size} near the tip, confidence {:.2}\n",
            self.tip_px[0],
            self.tip_px[1],
            self.axis_rad.to_degrees(),
            self.width_px,
            self.confidence
        )
    }
}
