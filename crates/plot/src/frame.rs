//! Camera frames for a figure: the grey image with a scale bar burnt in.

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::style::{self, err};
use crate::{PlotError, Rgb, register_font};

/// `grey` (8-bit, row-major, `width` x `height`) as RGB with a scale bar in the lower
/// right corner: a round length (1, 2 or 5 µm times a power of ten) about a fifth of the
/// width, white with a black outline, labelled above. `pixel_size` is the object-plane
/// size of a pixel, m.
pub fn with_scale_bar(
    grey: &[u8],
    width: u32,
    height: u32,
    pixel_size: f64,
) -> Result<Rgb, PlotError> {
    register_font();
    if grey.len() != width as usize * height as usize
        || !(pixel_size.is_finite() && pixel_size > 0.0)
    {
        return Err(PlotError::Drawing(format!(
            "frame of {width}x{height} with {} pixels and pixel size {pixel_size}",
            grey.len()
        )));
    }
    let mut data: Vec<u8> = grey.iter().flat_map(|&g| [g, g, g]).collect();
    {
        let root = BitMapBackend::with_buffer(&mut data, (width, height)).into_drawing_area();
        let um = style::round_length(0.2 * width as f64 * pixel_size * 1e6);
        let len = (um * 1e-6 / pixel_size).round() as i32;
        let (w, h) = (width as i32, height as i32);
        let thick = (h / 80).max(4);
        let margin = (w / 40).max(8);
        let (x1, y1) = (w - margin, h - margin);
        let (x0, y0) = (x1 - len, y1 - thick);
        root.draw(&Rectangle::new(
            [(x0 - 1, y0 - 1), (x1 + 1, y1 + 1)],
            BLACK.filled(),
        ))
        .map_err(|e| err(&e))?;
        root.draw(&Rectangle::new([(x0, y0), (x1, y1)], WHITE.filled()))
            .map_err(|e| err(&e))?;
        let label = if um >= 1.0 {
            format!("{um:.0} µm")
        } else {
            format!("{:.0} nm", um * 1e3)
        };
        let size = (h / 28).clamp(12, 40);
        let text = ("sans-serif", size)
            .into_font()
            .color(&WHITE)
            .pos(Pos::new(HPos::Center, VPos::Bottom));
        root.draw(&Text::new(label, ((x0 + x1) / 2, y0 - 4), text))
            .map_err(|e| err(&e))?;
        root.present().map_err(|e| err(&e))?;
    }
    Ok(Rgb {
        width,
        height,
        data,
    })
}

/// Grey levels of any range as 8-bit for display: stretched linearly over the
/// values' own range (its least black, its largest white); a flat image as its
/// level (8-bit as is, a 16-bit level divided by 257), clamped to 0..=255.
/// Not-a-number values are left out of the range and shown black.
pub fn stretched(values: &[f64]) -> Vec<u8> {
    let (lo, hi) = values
        .iter()
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |m, v| {
            (m.0.min(*v), m.1.max(*v))
        });
    if hi > lo {
        let scale = 255.0 / (hi - lo);
        values
            .iter()
            .map(|v| ((v - lo) * scale).round().clamp(0.0, 255.0) as u8)
            .collect()
    } else {
        let level = if hi > 255.0 { hi / 257.0 } else { hi };
        let level = if level.is_finite() {
            level.round().clamp(0.0, 255.0) as u8
        } else {
            0
        };
        values
            .iter()
            .map(|v| if v.is_finite() { level } else { 0 })
            .collect()
    }
}

/// `grey` (8-bit, row-major, `width` x `height`) as RGB bytes to draw over, the
/// drawing's font registered; an error when the sizes disagree.
fn rgb_of(grey: &[u8], width: u32, height: u32) -> Result<Vec<u8>, PlotError> {
    register_font();
    if grey.len() != width as usize * height as usize || width == 0 || height == 0 {
        return Err(PlotError::Drawing(format!(
            "frame of {width}x{height} with {} pixels",
            grey.len()
        )));
    }
    Ok(grey.iter().flat_map(|&g| [g, g, g]).collect())
}

/// An outline to draw over a frame ([`with_outlines`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outline {
    /// Pixels, the centre's column and row (from the centre of the top-left pixel).
    pub centre: [f64; 2],
    /// Pixels.
    pub radius: f64,
    /// Drawn green (a cell) when `true`, orange (debris) when `false`.
    pub primary: bool,
}

/// `grey` (8-bit, row-major, `width` x `height`) as RGB with each outline drawn as a
/// circle two pixels wide (about 1/300 of the frame's larger side, at least) and a
/// cross at its centre, numbered from 1 beside it in the outlines' order.
pub fn with_outlines(
    grey: &[u8],
    width: u32,
    height: u32,
    outlines: &[Outline],
) -> Result<Rgb, PlotError> {
    let mut data = rgb_of(grey, width, height)?;
    {
        let root = BitMapBackend::with_buffer(&mut data, (width, height)).into_drawing_area();
        let thick = (width.max(height) / 300).max(2);
        let size = (height as i32 / 30).clamp(12, 40);
        for (k, o) in outlines.iter().enumerate() {
            let colour = if o.primary {
                RGBColor(40, 220, 60)
            } else {
                RGBColor(255, 150, 20)
            };
            let (x, y) = (o.centre[0].round() as i32, o.centre[1].round() as i32);
            let r = o.radius.round().max(1.0) as i32;
            root.draw(&Circle::new((x, y), r, colour.stroke_width(thick)))
                .map_err(|e| err(&e))?;
            let arm = (r / 6).clamp(3, 12);
            for seg in [[(x - arm, y), (x + arm, y)], [(x, y - arm), (x, y + arm)]] {
                root.draw(&PathElement::new(seg, colour.stroke_width(thick.min(2))))
                    .map_err(|e| err(&e))?;
            }
            let text = ("sans-serif", size)
                .into_font()
                .color(&colour)
                .pos(Pos::new(HPos::Left, VPos::Bottom));
            let at = (x + (0.72 * r as f64) as i32, y - (0.72 * r as f64) as i32);
            root.draw(&Text::new(format!("{}", k + 1), at, text))
                .map_err(|e| err(&e))?;
        }
        root.present().map_err(|e| err(&e))?;
    }
    Ok(Rgb {
        width,
        height,
        data,
    })
}

/// `grey` (8-bit, row-major, `width` x `height`) as RGB with a pipette's tip marked:
/// a cross at `tip` (pixels, from the centre of the top-left pixel), a circle of
/// `width` px around it (at least 4), and the axis drawn from the tip towards the
/// shank along `axis_rad` (`atan2(dy, dx)`, y down) for a fifth of the frame's
/// larger side.
pub fn with_tip(
    grey: &[u8],
    width: u32,
    height: u32,
    tip: [f64; 2],
    axis_rad: f64,
    tip_width: f64,
) -> Result<Rgb, PlotError> {
    let mut data = rgb_of(grey, width, height)?;
    {
        let root = BitMapBackend::with_buffer(&mut data, (width, height)).into_drawing_area();
        let thick = (width.max(height) / 300).max(2);
        let (axis, mark) = (RGBColor(40, 220, 60), RGBColor(255, 60, 40));
        let (x, y) = (tip[0].round() as i32, tip[1].round() as i32);
        let reach = 0.2 * f64::from(width.max(height));
        let end = (
            (tip[0] + reach * axis_rad.cos()).round() as i32,
            (tip[1] + reach * axis_rad.sin()).round() as i32,
        );
        root.draw(&PathElement::new([(x, y), end], axis.stroke_width(thick)))
            .map_err(|e| err(&e))?;
        let r = (0.5 * tip_width).round().max(4.0) as i32;
        root.draw(&Circle::new((x, y), r, mark.stroke_width(thick)))
            .map_err(|e| err(&e))?;
        let arm = 2 * r;
        for seg in [[(x - arm, y), (x + arm, y)], [(x, y - arm), (x, y + arm)]] {
            root.draw(&PathElement::new(seg, mark.stroke_width(thick.min(2))))
                .map_err(|e| err(&e))?;
        }
        root.present().map_err(|e| err(&e))?;
    }
    Ok(Rgb {
        width,
        height,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The range stretched to 0..=255; a flat 8-bit image keeps its level, a flat
    /// 16-bit one is scaled to 8 bits; NaN is black and does not widen the range.
    #[test]
    fn grey_is_stretched_over_its_own_range() {
        assert_eq!(stretched(&[10.0, 20.0, 30.0]), vec![0, 128, 255]);
        assert_eq!(stretched(&[1000.0, 3000.0]), vec![0, 255]);
        assert_eq!(stretched(&[77.0, 77.0]), vec![77, 77]);
        assert_eq!(stretched(&[25700.0; 2]), vec![100, 100]);
        assert_eq!(stretched(&[f64::NAN, 0.0, 2.0]), vec![0, 0, 255]);
        assert_eq!(stretched(&[f64::NAN; 2]), vec![0, 0]);
        assert!(stretched(&[]).is_empty());
    }

    /// A cell's circle crosses the row through its centre at its radius, in green; a
    /// debris outline is orange; the pixels far from both stay grey.
    #[test]
    fn outlines_are_drawn_where_they_lie() {
        let g = vec![90u8; 200 * 150];
        let rgb = with_outlines(
            &g,
            200,
            150,
            &[
                Outline {
                    centre: [60.0, 70.0],
                    radius: 30.0,
                    primary: true,
                },
                Outline {
                    centre: [160.0, 40.0],
                    radius: 8.0,
                    primary: false,
                },
            ],
        )
        .unwrap();
        let px = |x: usize, y: usize| {
            let i = (y * 200 + x) * 3;
            [rgb.data[i], rgb.data[i + 1], rgb.data[i + 2]]
        };
        let green = (85..95).any(|x| px(x, 70) == [40, 220, 60]);
        assert!(
            green,
            "{:?}",
            (85..95).map(|x| px(x, 70)).collect::<Vec<_>>()
        );
        let orange = (165..172).any(|x| px(x, 40) == [255, 150, 20]);
        assert!(orange);
        assert_eq!(px(10, 140), [90, 90, 90]);
        assert!(with_outlines(&g, 10, 10, &[]).is_err());
    }

    #[test]
    fn the_bar_has_its_round_length_in_pixels() {
        // 640 px of 0.88 µm: a fifth is 113 µm, so the bar is 100 µm = 114 px.
        let g = vec![60u8; 640 * 480];
        let rgb = with_scale_bar(&g, 640, 480, 0.88e-6).unwrap();
        let row = 480 - 16 - 2; // inside the bar
        let white: Vec<usize> = (0..640)
            .filter(|&x| rgb.data[(row * 640 + x) * 3] == 255)
            .collect();
        let n = white.len() as i32;
        assert!((n - 114).abs() <= 2, "{n}");
        assert_eq!(style::round_length(113.0), 100.0);
        assert_eq!(style::round_length(0.3), 0.2);
        assert!(with_scale_bar(&g, 10, 10, 1e-6).is_err());
    }
}
