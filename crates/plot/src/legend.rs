//! Where a panel's legend goes: the corner whose box covers the fewest data, and
//! when every corner would cover some, headroom above the data for it.

use plotters::chart::SeriesLabelPosition;

use crate::{Chart, Style};

/// The legend's size as fractions of the plotting area (width, height).
pub(crate) type Fraction = (f64, f64);

/// Samples a line segment is checked at (its ends included): a line can pass under a
/// corner's box between two of its points.
const SEGMENT_SAMPLES: usize = 16;

/// The legend box's size, px, for labels of `chars` characters at most and `entries`
/// of them (label font 13 px: about 7.5 px a character; the marker 18 px and the
/// plotters' paddings).
pub(crate) fn size_px(chars: usize, entries: usize) -> (f64, f64) {
    (40.0 + 7.5 * chars as f64, 10.0 + 19.0 * entries as f64)
}

/// The corners in the order they are preferred on a tie.
const CORNERS: [SeriesLabelPosition; 4] = [
    SeriesLabelPosition::UpperRight,
    SeriesLabelPosition::UpperLeft,
    SeriesLabelPosition::LowerRight,
    SeriesLabelPosition::LowerLeft,
];

/// Whether the point (u, v) in the unit square (v up) lies under a legend of size
/// `f` in `corner` (with a margin of 2 % of the area around the box).
fn covers(corner: &SeriesLabelPosition, f: Fraction, (u, v): (f64, f64)) -> bool {
    let (w, h) = (f.0 + 0.02, f.1 + 0.02);
    let right = matches!(
        corner,
        SeriesLabelPosition::UpperRight | SeriesLabelPosition::LowerRight
    );
    let upper = matches!(
        corner,
        SeriesLabelPosition::UpperRight | SeriesLabelPosition::UpperLeft
    );
    let in_x = if right { u >= 1.0 - w } else { u <= w };
    let in_y = if upper { v >= 1.0 - h } else { v <= h };
    in_x && in_y
}

/// The chart's data in the unit square of the ranges `x` and `y` (v up): each dot, and
/// each line's segments sampled.
fn unit_points(chart: &Chart, x: (f64, f64), y: (f64, f64)) -> Vec<(f64, f64)> {
    let (sx, sy) = (
        (x.1 - x.0).max(f64::MIN_POSITIVE),
        (y.1 - y.0).max(f64::MIN_POSITIVE),
    );
    let unit = |(px, py): (f64, f64)| ((px - x.0) / sx, (py - y.0) / sy);
    let mut out = Vec::new();
    for s in &chart.series {
        let finite = s
            .points
            .iter()
            .copied()
            .filter(|(a, b)| a.is_finite() && b.is_finite())
            .map(unit);
        match s.style {
            Style::Dots => out.extend(finite),
            Style::Line => {
                let pts: Vec<(f64, f64)> = finite.collect();
                if let [only] = pts[..] {
                    out.push(only);
                }
                for pair in pts.windows(2) {
                    let ((a, b), (c, d)) = (pair[0], pair[1]);
                    out.extend((0..=SEGMENT_SAMPLES).map(|k| {
                        let t = k as f64 / SEGMENT_SAMPLES as f64;
                        (a + t * (c - a), b + t * (d - b))
                    }));
                }
            }
        }
    }
    out
}

/// The legend's corner for a chart drawn over the ranges `x` and `y`, and the top of
/// the y range to draw with: `y.1` when a corner is clear of the data; otherwise the
/// range raised so that the data fill only the part below the legend's height, and
/// the upper right corner (clear by construction).
pub(crate) fn place(
    chart: &Chart,
    x: (f64, f64),
    y: (f64, f64),
    f: Fraction,
) -> (SeriesLabelPosition, f64) {
    let pts = unit_points(chart, x, y);
    let count = |c: &SeriesLabelPosition| pts.iter().filter(|&&p| covers(c, f, p)).count();
    for c in CORNERS {
        if count(&c) == 0 {
            return (c, y.1);
        }
    }
    // The data below 1 − (h + margin) of the raised range.
    let keep = (1.0 - f.1 - 0.04).max(0.3);
    (SeriesLabelPosition::UpperRight, y.0 + (y.1 - y.0) / keep)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Series;

    fn chart(series: Vec<Series>) -> Chart {
        Chart {
            title: "t".into(),
            x_label: String::new(),
            y_label: String::new(),
            series,
        }
    }

    fn dots(points: Vec<(f64, f64)>) -> Series {
        Series {
            name: "dots".into(),
            points,
            style: Style::Dots,
        }
    }

    fn is(a: &SeriesLabelPosition, b: &SeriesLabelPosition) -> bool {
        format!("{a:?}") == format!("{b:?}")
    }

    /// A cloud filling the middle leaves the upper right free; one reaching into
    /// the upper right moves the legend to the upper left; data in all four corners
    /// raise the top of the range until the legend's band above the data is empty.
    #[test]
    fn the_legend_goes_where_no_data_is() {
        let f = (0.3, 0.15);
        let mid: Vec<(f64, f64)> = (0..100)
            .map(|k| {
                (
                    0.3 + 0.004 * k as f64,
                    0.3 + 0.004 * ((k * 37) % 100) as f64,
                )
            })
            .collect();
        let (c, top) = place(&chart(vec![dots(mid.clone())]), (0.0, 1.0), (0.0, 1.0), f);
        assert!(is(&c, &SeriesLabelPosition::UpperRight), "{c:?}");
        assert_eq!(top, 1.0);
        let mut ur = mid.clone();
        ur.push((0.95, 0.95));
        let (c, _) = place(&chart(vec![dots(ur)]), (0.0, 1.0), (0.0, 1.0), f);
        assert!(is(&c, &SeriesLabelPosition::UpperLeft), "{c:?}");
        let mut all = mid;
        all.extend([(0.02, 0.02), (0.98, 0.02), (0.02, 0.98), (0.98, 0.98)]);
        let ch = chart(vec![dots(all)]);
        let (c, top) = place(&ch, (0.0, 1.0), (0.0, 1.0), f);
        assert!(is(&c, &SeriesLabelPosition::UpperRight), "{c:?}");
        assert!(top > 1.0);
        // Redrawn over the raised range, the corner is clear.
        let (c2, top2) = place(&ch, (0.0, 1.0), (0.0, top), f);
        assert!(is(&c2, &SeriesLabelPosition::UpperRight));
        assert_eq!(top2, top);
    }

    /// A line that crosses a corner's box between two of its points covers it.
    #[test]
    fn a_line_between_its_points_counts() {
        let line = Series {
            name: "l".into(),
            // From the lower left to the upper right corner, two points only.
            points: vec![(0.0, 0.0), (1.0, 1.0)],
            style: Style::Line,
        };
        let (c, _) = place(&chart(vec![line]), (0.0, 1.0), (0.0, 1.0), (0.3, 0.15));
        assert!(is(&c, &SeriesLabelPosition::UpperLeft), "{c:?}");
    }
}
