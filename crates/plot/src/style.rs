//! The one style of every cellinject plot: fonts and sizes, margins, the number of
//! ticks, the line colours, the colour map and its colour bar.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::PlotError;

/// Margin around a panel, px.
pub const MARGIN: u32 = 12;
/// Height of the horizontal axis's labels, px.
pub const X_LABEL_AREA: u32 = 44;
/// Width of the vertical axis's labels, px.
pub const Y_LABEL_AREA: u32 = 76;
/// Approximate number of ticks on an axis.
pub const TICKS: usize = 8;
/// Width of a colour bar with its ticks and label, px.
pub const COLOUR_BAR_WIDTH: u32 = 120;
/// Points above which a line series is drawn one pixel wide.
pub const DENSE: usize = 1000;
/// Radius of a scatter plot's dots, px.
pub const DOT: i32 = 3;
/// Where a map has no value.
pub const MISSING: RGBColor = RGBColor(200, 200, 200);

/// Line colours, in order.
pub const LINES: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
];

/// A panel's title.
pub fn title() -> TextStyle<'static> {
    ("sans-serif", 18).into_font().into()
}

/// Tick and axis labels.
pub fn label() -> TextStyle<'static> {
    ("sans-serif", 13).into_font().into()
}

/// A drawing error as a [`PlotError`].
pub fn err(e: &dyn std::fmt::Display) -> PlotError {
    PlotError::Drawing(e.to_string())
}

/// The colour map for t in [0, 1]: perceptually uniform, dark blue to yellow (viridis,
/// by its published stops), legible in grey print and to colour-blind readers.
pub fn colour_map(t: f64) -> RGBColor {
    const STOPS: [(f64, f64, f64); 9] = [
        (68.0, 1.0, 84.0),
        (71.0, 44.0, 122.0),
        (59.0, 81.0, 139.0),
        (44.0, 113.0, 142.0),
        (33.0, 144.0, 141.0),
        (39.0, 173.0, 129.0),
        (92.0, 200.0, 99.0),
        (170.0, 220.0, 50.0),
        (253.0, 231.0, 37.0),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * (STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f64;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    let mix = |p: f64, q: f64| (p + (q - p) * f).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// Round tick values covering [lo, hi]: steps of 1, 2 or 5 times a power of ten, about
/// `n` of them.
pub fn ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return vec![lo];
    }
    let raw = (hi - lo) / n.max(1) as f64;
    let p = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * p)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * p);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// Decimals that show a tick step without noise.
fn decimals(lo: f64, hi: f64) -> usize {
    let t = ticks(lo, hi, 6);
    let step = if t.len() > 1 {
        t[1] - t[0]
    } else {
        (hi - lo).abs().max(1e-300)
    };
    (-step.log10().floor()).clamp(0.0, 12.0) as usize
}

/// A vertical colour bar for values from `lo` to `hi`, with round ticks and `label`
/// (quantity and unit) above it.
pub fn colour_bar<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    lo: f64,
    hi: f64,
    label: &str,
) -> Result<(), PlotError> {
    let (_, h) = area.dim_in_pixel();
    let (top, bottom) = (44i32, h as i32 - 56);
    let (left, right) = (10i32, 30i32);
    let n = 128;
    for i in 0..n {
        let t0 = i as f64 / n as f64;
        let y_hi = bottom - ((bottom - top) as f64 * (t0 + 1.0 / n as f64)).round() as i32;
        let y_lo = bottom - ((bottom - top) as f64 * t0).round() as i32;
        area.draw(&Rectangle::new(
            [(left, y_hi), (right, y_lo)],
            colour_map(t0 + 0.5 / n as f64).filled(),
        ))
        .map_err(|e| err(&e))?;
    }
    area.draw(&Rectangle::new([(left, top), (right, bottom)], BLACK))
        .map_err(|e| err(&e))?;
    let span = if hi > lo { hi - lo } else { 1.0 };
    let d = decimals(lo, hi);
    let style = label_style().pos(Pos::new(HPos::Left, VPos::Center));
    let mut marks = ticks(lo, hi, 6);
    if marks.len() < 2 {
        marks = vec![lo, hi];
    }
    for v in marks {
        let y = bottom - ((bottom - top) as f64 * (v - lo) / span).round() as i32;
        area.draw(&PathElement::new(vec![(right, y), (right + 5, y)], BLACK))
            .map_err(|e| err(&e))?;
        area.draw(&Text::new(
            format!("{v:.d$}"),
            (right + 8, y),
            style.clone(),
        ))
        .map_err(|e| err(&e))?;
    }
    // The extremes, exactly, below and above the bar.
    let ends = label_style().pos(Pos::new(HPos::Left, VPos::Center));
    area.draw(&Text::new(
        format!("max {hi:.3}"),
        (left - 4, top - 12),
        ends.clone(),
    ))
    .map_err(|e| err(&e))?;
    area.draw(&Text::new(
        format!("min {lo:.3}"),
        (left - 4, bottom + 14),
        ends,
    ))
    .map_err(|e| err(&e))?;
    area.draw(&Text::new(
        label.to_string(),
        (left - 4, 12),
        label_style().pos(Pos::new(HPos::Left, VPos::Center)),
    ))
    .map_err(|e| err(&e))?;
    Ok(())
}

fn label_style() -> TextStyle<'static> {
    label()
}

/// A round length for a scale bar about `target` long: 1, 2 or 5 times a power of ten.
pub fn round_length(target: f64) -> f64 {
    if !(target.is_finite() && target > 0.0) {
        return 1.0;
    }
    let p = 10f64.powf(target.log10().floor());
    [5.0, 2.0, 1.0]
        .iter()
        .map(|m| m * p)
        .find(|l| *l <= target)
        .unwrap_or(p)
}

/// Labels for the ticks of an axis from `lo` to `hi`: as many decimals as the tick step
/// needs (none for a step of 10), and no negative zero.
pub fn tick_formatter(lo: f64, hi: f64) -> impl Fn(&f64) -> String {
    let (a, b) = if lo <= hi { (lo, hi) } else { (hi, lo) };
    let d = decimals(a, b);
    move |v: &f64| {
        let s = format!("{v:.d$}");
        if s.trim_start_matches('-')
            .chars()
            .all(|c| c == '0' || c == '.')
        {
            s.trim_start_matches('-').to_string()
        } else {
            s
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        assert_eq!(
            ticks(0.0, 1.0, 5),
            vec![0.0, 0.2, 0.4, 0.6000000000000001, 0.8, 1.0]
        );
        let t = ticks(-0.37, 0.81, 6);
        assert!(t.first().unwrap() >= &-0.37 && t.last().unwrap() <= &0.81);
        assert!(
            t.windows(2).all(|w| ((w[1] - w[0]) - 0.2).abs() < 1e-12),
            "{t:?}"
        );
        assert_eq!(ticks(1.0, 1.0, 5), vec![1.0]);
    }

    #[test]
    fn tick_labels_have_the_decimals_of_their_step() {
        let f = tick_formatter(0.0, 200.0);
        assert_eq!((f(&50.0), f(&-0.0)), ("50".to_string(), "0".to_string()));
        let g = tick_formatter(9.12, 9.24);
        assert_eq!(g(&9.14), "9.14");
    }

    #[test]
    fn the_colour_map_darkens_to_one_end() {
        let lum = |c: RGBColor| 0.3 * c.0 as f64 + 0.59 * c.1 as f64 + 0.11 * c.2 as f64;
        let l: Vec<f64> = (0..=10).map(|i| lum(colour_map(i as f64 / 10.0))).collect();
        // Monotonic luminance: the map reads in grey print.
        assert!(l.windows(2).all(|w| w[1] > w[0]), "{l:?}");
        assert_eq!(colour_map(f64::NAN), colour_map(0.0));
    }
}
