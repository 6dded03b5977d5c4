//! Cells in a lab's own micrograph, of either contrast: the phase-contrast cell (a
//! bright body inside a dark halo), its inverse, and a bright-field cell darker than
//! its surroundings, under uneven illumination, noise and JPEG blocks.
//!
//! 1. **Smoothing and background.** The image is smoothed by a box mean taken twice
//!    (about a twenty-fifth of the smallest cell: noise and JPEG blocks go, a cell's
//!    outline stays), and divided by its illumination: a quadratic surface fitted
//!    three times, each time without what lies off the last one (a cell and its halo
//!    do not pull it; a ramp or vignetting across the frame is followed). A box mean
//!    over a few cells did not: with the largest cell at 280 px, its window spanned
//!    the whole photograph, and an inverted cell under a ±25 % ramp was lost.
//! 2. **Contrast mask.** `c = image / background − 1`; a pixel belongs to something
//!    where `|c|` exceeds four times the image's robust spread of `c` (its median
//!    absolute deviation) and 3 %; an opening by a tenth of the smallest cell removes
//!    thin structures; holes are filled. A component touching the image's border is
//!    left out (it cannot be measured).
//! 3. **Outline.** From the component's centroid, 72 rays; along each, the radius
//!    where the smoothed image changes fastest in the component's direction (falling
//!    from a bright body into its halo, rising from a dark body into its
//!    surroundings); a circle fitted to those points (Kåsa), the points more than
//!    `max(1.5 px, 5 %)` off it dropped, then the rays cast again from the fitted
//!    centre. The body's polarity is the sign of `c` over the inner third of the
//!    component.
//! 4. **Verdict.** An in-focus outline is sharp: along each ray, the contrast across
//!    the edge over the steepest slope is a width, under a tenth of the radius for a
//!    cell in focus and near the radius for a defocused shadow. The confidence is the
//!    share of rays on the circle times how sharp the outline is (1 at a tenth of the
//!    radius, 0 at three tenths). A sharp outline within the diameter range is a cell;
//!    a smaller one debris; a larger one, or one with confidence under 0.5, neither.
//!
//! Pixel coordinates: x along the columns, y along the rows, the origin at the centre
//! of the top-left pixel.

use crate::{CellsError, box_mean, components, fill_holes, fit_circle, opening, split_discs};

/// Which cells to look for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Contrast {
    /// Both kinds.
    Auto,
    /// Cells darker than their surroundings (bright field).
    Dark,
    /// Cells brighter than their surroundings (phase contrast).
    Bright,
}

/// Which way a cell's body differs from its surroundings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Polarity {
    /// Darker.
    Dark,
    /// Brighter.
    Bright,
}

impl Polarity {
    /// `dark` or `bright`.
    pub fn name(self) -> &'static str {
        match self {
            Polarity::Dark => "dark",
            Polarity::Bright => "bright",
        }
    }
}

/// How to search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisionOptions {
    /// Pixels, the smallest and the largest diameter of a cell.
    pub diameter_px: [f64; 2],
    /// Which cells to look for.
    pub contrast: Contrast,
}

/// One thing found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Found {
    /// Pixels, the centre's column.
    pub x: f64,
    /// Pixels, the centre's row.
    pub y: f64,
    /// Pixels, the diameter of its outline.
    pub diameter: f64,
    /// 0-1: the share of rays on its outline times the outline's sharpness.
    pub confidence: f64,
    /// How its body differs from its surroundings.
    pub polarity: Polarity,
}

/// What an image holds.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Census {
    /// Cells, by confidence (highest first).
    pub cells: Vec<Found>,
    /// Sharp outlines smaller than the smallest cell, by confidence.
    pub debris: Vec<Found>,
}

/// Rays cast from a centre.
const RAYS: usize = 72;

/// What a front end asks of [`find_cells`] in the units a user gives (`vision cells`'s
/// options, `cellinject.vision.cells`'s arguments): checked and turned into pixels
/// once, for all of them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Request {
    /// m per pixel in the object plane, if known.
    pub pixel_size: Option<f64>,
    /// m, the smallest and largest diameter of a cell (needs `pixel_size`); by default
    /// 9.5-30 µm with a pixel size, 8 px to half the image's shorter side without.
    pub diameter: Option<[f64; 2]>,
    /// Which cells to look for.
    pub contrast: Contrast,
}

/// Why a [`Request`] cannot be met; each front end names its own argument.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum RequestError {
    /// The pixel size is not a positive length.
    #[error("must be a positive length in metres, got {0}")]
    PixelSize(f64),
    /// A diameter range in metres without a pixel size to turn it into pixels.
    #[error("is in metres: it needs the pixel size (the image's m per pixel) too")]
    DiameterWithoutPixelSize,
    /// The diameters are not two positive lengths, the smaller first.
    #[error("must be two positive lengths in metres, the smaller first, got {0}, {1}")]
    Diameter(f64, f64),
    /// The smallest cell is wider than the image's shorter side (pixels).
    #[error("makes the smallest cell {0:.0} px across, wider than the image ({1} px)")]
    Large(f64, usize),
    /// At this pixel size the smallest cell spans fewer than 4 pixels (blamed on the
    /// diameter range when one was given, else on the pixel size).
    #[error("makes the smallest cell {0:.3} px across: at least 4 px are needed to find it")]
    Coarse(f64, Arg),
}

/// A [`Request`]'s argument.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Arg {
    /// [`Request::pixel_size`].
    PixelSize,
    /// [`Request::diameter`].
    Diameter,
}

impl RequestError {
    /// The argument at fault, for the front end to name.
    pub fn arg(&self) -> Arg {
        match self {
            RequestError::PixelSize(_) => Arg::PixelSize,
            RequestError::Large(..) => Arg::Diameter,
            RequestError::Coarse(_, a) => *a,
            _ => Arg::Diameter,
        }
    }
}

impl Request {
    /// The search options for a `width` x `height` image.
    pub fn options(&self, width: usize, height: usize) -> Result<VisionOptions, RequestError> {
        if let Some(p) = self.pixel_size
            && !(p.is_finite() && p > 0.0)
        {
            return Err(RequestError::PixelSize(p));
        }
        if let Some([lo, hi]) = self.diameter
            && !(lo.is_finite() && hi.is_finite() && lo > 0.0 && hi > lo)
        {
            return Err(RequestError::Diameter(lo, hi));
        }
        let diameter_px = match (self.pixel_size, self.diameter) {
            (Some(p), Some([lo, hi])) => [lo / p, hi / p],
            (Some(p), None) => [9.5e-6 / p, 30e-6 / p],
            (None, Some(_)) => return Err(RequestError::DiameterWithoutPixelSize),
            (None, None) => [8.0, (0.5 * width.min(height) as f64).max(16.0)],
        };
        // (An image under 8 px a side is find_cells's to refuse, naming the image.)
        if width.min(height) >= 8 && diameter_px[0] > width.min(height) as f64 {
            return Err(RequestError::Large(diameter_px[0], width.min(height)));
        }
        if diameter_px[0].is_nan() || diameter_px[0] < 4.0 {
            let blamed = if self.diameter.is_some() {
                Arg::Diameter
            } else {
                Arg::PixelSize
            };
            return Err(RequestError::Coarse(diameter_px[0], blamed));
        }
        Ok(VisionOptions {
            diameter_px,
            contrast: self.contrast,
        })
    }
}

/// Least confidence of a cell or a piece of debris.
pub const MIN_CONFIDENCE: f64 = 0.5;

/// The cells (and debris) of a `width × height` grey image (row-major `grey`, any
/// units).
pub fn find_cells(
    grey: &[f64],
    width: usize,
    height: usize,
    o: &VisionOptions,
) -> Result<Census, CellsError> {
    if grey.len() != width * height {
        return Err(CellsError::Size {
            len: grey.len(),
            width,
            height,
        });
    }
    if width < 8 || height < 8 {
        return Err(CellsError::Invalid {
            what: "image size",
            value: width.min(height) as f64,
            reason: "an image must be at least 8 x 8 pixels",
        });
    }
    let [dmin, dmax] = o.diameter_px;
    if !(dmin.is_finite() && dmin >= 4.0) {
        return Err(CellsError::Invalid {
            what: "smallest diameter",
            value: dmin,
            reason: "must be at least 4 pixels",
        });
    }
    if !(dmax.is_finite() && dmax > dmin) {
        return Err(CellsError::Invalid {
            what: "largest diameter",
            value: dmax,
            reason: "must be larger than the smallest",
        });
    }
    if let Some(v) = grey.iter().find(|v| !v.is_finite()) {
        return Err(CellsError::Invalid {
            what: "pixel",
            value: *v,
            reason: "grey levels must be finite",
        });
    }
    let all = vec![true; grey.len()];
    let half = ((dmin / 25.0).round() as usize).max(1);
    let smooth = box_mean(
        &box_mean(grey, &all, width, height, half),
        &all,
        width,
        height,
        half,
    );
    let bg = background(&smooth, width, height);
    let floor = 1e-9 * grey.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
    let c: Vec<f64> = smooth
        .iter()
        .zip(&bg)
        .map(|(v, b)| if *b > floor { v / b - 1.0 } else { 0.0 })
        .collect();
    let spread = 1.4826 * median_abs_deviation(&c);
    let level = (4.0 * spread).max(0.03);
    let mut mask: Vec<bool> = c.iter().map(|v| v.abs() > level).collect();
    mask = opening(
        &mask,
        width,
        height,
        ((dmin / 10.0).round() as usize).max(1),
    );
    fill_holes(&mut mask, width, height);
    let img = Sampled {
        v: &smooth,
        w: width,
        h: height,
    };
    let mut census = Census::default();
    // Two cells whose halos touch make one piece: split where its distance transform
    // has two discs (as the workflow's detector splits a doublet), each outlined from
    // its own centre.
    let pieces = components(&mask, width, height)
        .into_iter()
        .flat_map(|c| split_discs(&c, width, 0.25 * dmin))
        .map(|(part, _)| part);
    for comp in pieces {
        let r0 = (comp.len() as f64 / std::f64::consts::PI).sqrt();
        if 2.0 * r0 < 0.3 * dmin || 2.0 * r0 > 2.5 * dmax {
            continue;
        }
        let n = comp.len() as f64;
        let (cx, cy) = comp.iter().fold((0.0, 0.0), |a, &i| {
            (a.0 + (i % width) as f64 / n, a.1 + (i / width) as f64 / n)
        });
        let inner: Vec<f64> = comp
            .iter()
            .filter(|&&i| {
                let (dx, dy) = ((i % width) as f64 - cx, (i / width) as f64 - cy);
                dx.hypot(dy) < r0 / 3.0
            })
            .map(|&i| c[i])
            .collect();
        let polarity = if inner.iter().sum::<f64>() >= 0.0 {
            Polarity::Bright
        } else {
            Polarity::Dark
        };
        let wanted = match o.contrast {
            Contrast::Auto => true,
            Contrast::Dark => polarity == Polarity::Dark,
            Contrast::Bright => polarity == Polarity::Bright,
        };
        if !wanted {
            continue;
        }
        let Some(f) = outline(&img, (cx, cy), r0, polarity) else {
            continue;
        };
        // A halo may reach the border; the outline must lie within the image.
        let inside = f.x - 0.5 * f.diameter >= 0.0
            && f.y - 0.5 * f.diameter >= 0.0
            && f.x + 0.5 * f.diameter <= (width - 1) as f64
            && f.y + 0.5 * f.diameter <= (height - 1) as f64;
        if !inside || f.confidence < MIN_CONFIDENCE || f.diameter > dmax {
            continue;
        }
        if f.diameter < dmin {
            census.debris.push(f);
        } else {
            census.cells.push(f);
        }
    }
    Ok(once_each(census))
}

/// The census sorted by confidence, each outline once: one found from two pieces (a
/// cell and a piece of its halo) is one cell (of outlines whose centres lie within a
/// quarter of the larger diameter, the most confident), and debris inside a cell is
/// not listed.
fn once_each(mut census: Census) -> Census {
    let by_confidence = |a: &Found, b: &Found| b.confidence.total_cmp(&a.confidence);
    census.cells.sort_by(by_confidence);
    census.debris.sort_by(by_confidence);
    let once = |found: Vec<Found>| {
        let mut kept: Vec<Found> = Vec::new();
        for f in found {
            let seen = kept
                .iter()
                .any(|k| (k.x - f.x).hypot(k.y - f.y) < 0.25 * k.diameter.max(f.diameter));
            if !seen {
                kept.push(f);
            }
        }
        kept
    };
    census.cells = once(census.cells);
    census.debris = once(census.debris);
    census.debris.retain(|d| {
        !census
            .cells
            .iter()
            .any(|c| (c.x - d.x).hypot(c.y - d.y) < 0.5 * c.diameter)
    });
    census
}

/// The illumination under `img`: a quadratic surface in x and y fitted by least
/// squares to every fourth pixel of every fourth row, three times, each time without
/// the pixels more than three robust spreads (and 3 %) off the last surface, starting
/// from the samples' median level: a cell, its halo and debris do not pull it; a ramp
/// or a vignetting across the frame is followed. A first fit over every sample leant
/// to a large bright cell (a disc over an eighth of the frame bent it into a dome of
/// 124 grey levels over a field of 70, its corners near 1), and nothing stood out.
fn background(img: &[f64], w: usize, h: usize) -> Vec<f64> {
    let basis = |x: usize, y: usize| {
        let u = 2.0 * x as f64 / (w - 1) as f64 - 1.0;
        let v = 2.0 * y as f64 / (h - 1) as f64 - 1.0;
        [1.0, u, v, u * u, u * v, v * v]
    };
    let samples: Vec<(usize, usize)> = (0..h)
        .step_by(4)
        .flat_map(|y| (0..w).step_by(4).map(move |x| (x, y)))
        .collect();
    let surface = |coef: &[f64; 6], x: usize, y: usize| {
        basis(x, y)
            .iter()
            .zip(coef)
            .map(|(b, c)| b * c)
            .sum::<f64>()
    };
    let mut levels: Vec<f64> = samples.iter().map(|&(x, y)| img[y * w + x]).collect();
    let mut coef = [median_in_place(&mut levels), 0.0, 0.0, 0.0, 0.0, 0.0];
    for _ in 0..3 {
        let rel: Vec<f64> = samples
            .iter()
            .map(|&(x, y)| {
                let b = surface(&coef, x, y);
                if b.abs() > 0.0 {
                    img[y * w + x] / b - 1.0
                } else {
                    0.0
                }
            })
            .collect();
        let limit = (3.0 * 1.4826 * median_abs_deviation(&rel)).max(0.03);
        let mut m = [[0.0f64; 6]; 6];
        let mut rhs = [0.0f64; 6];
        for (&(x, y), _) in samples.iter().zip(&rel).filter(|(_, r)| r.abs() <= limit) {
            let b = basis(x, y);
            for i in 0..6 {
                for j in 0..6 {
                    m[i][j] += b[i] * b[j];
                }
                rhs[i] += b[i] * img[y * w + x];
            }
        }
        let scale = m.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
        match crate::solve(m, rhs, 1e-12 * scale) {
            Some(c) if c.iter().all(|v| v.is_finite()) => coef = c,
            _ => break,
        }
    }
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| surface(&coef, x, y))
        .collect()
}

/// The median of `|v − median(v)|`.
fn median_abs_deviation(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    let m = median_in_place(&mut s);
    let mut d: Vec<f64> = v.iter().map(|x| (x - m).abs()).collect();
    median_in_place(&mut d)
}

fn median_in_place(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let k = v.len() / 2;
    *v.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1
}

/// A row-major image read between its pixels.
struct Sampled<'a> {
    v: &'a [f64],
    w: usize,
    h: usize,
}

impl Sampled<'_> {
    /// Bilinear value at (x, y), `None` outside.
    fn at(&self, x: f64, y: f64) -> Option<f64> {
        if !(x >= 0.0 && y >= 0.0 && x <= (self.w - 1) as f64 && y <= (self.h - 1) as f64) {
            return None;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.w - 1), (y0 + 1).min(self.h - 1));
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let p = |x: usize, y: usize| self.v[y * self.w + x];
        Some(
            (1.0 - fy) * ((1.0 - fx) * p(x0, y0) + fx * p(x1, y0))
                + fy * ((1.0 - fx) * p(x0, y1) + fx * p(x1, y1)),
        )
    }
}

/// Where the image changes fastest along one ray, and how sharply.
struct Edge {
    point: (f64, f64),
    /// Pixels, the contrast across the edge over its steepest slope.
    width: f64,
}

/// The steepest change along the ray at `angle` from `c`, between `from` and `to`
/// pixels out: a fall for a bright body, a rise for a dark one.
fn edge_on_ray(
    img: &Sampled,
    c: (f64, f64),
    angle: f64,
    (from, to): (f64, f64),
    polarity: Polarity,
) -> Option<Edge> {
    let step = 0.5;
    let (dx, dy) = (angle.cos(), angle.sin());
    let n = ((to - from) / step) as usize + 1;
    let mut prof = Vec::with_capacity(n);
    for k in 0..n {
        let r = from + k as f64 * step;
        prof.push(img.at(c.0 + r * dx, c.1 + r * dy)?);
    }
    let sign = match polarity {
        Polarity::Bright => -1.0,
        Polarity::Dark => 1.0,
    };
    // Slope over one pixel (two samples), in the polarity's direction.
    let (k, slope) = (1..n.saturating_sub(1))
        .map(|k| (k, sign * (prof[k + 1] - prof[k - 1])))
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    if slope <= 0.0 {
        return None;
    }
    // Contrast across the edge: inside level (the mean over a fifth of the range
    // inside) against the extreme just outside (the halo's darkest, or the
    // surroundings' brightest, within a fifth outside).
    let span = ((n as f64) / 5.0).ceil() as usize;
    let inside = &prof[k.saturating_sub(span)..k];
    let outside = &prof[k..(k + span).min(n)];
    if inside.is_empty() || outside.is_empty() {
        return None;
    }
    let mean_in = inside.iter().sum::<f64>() / inside.len() as f64;
    let beyond = outside
        .iter()
        .map(|v| sign * v)
        .fold(f64::NEG_INFINITY, f64::max);
    let contrast = beyond - sign * mean_in;
    let r = from + k as f64 * step;
    Some(Edge {
        point: (c.0 + r * dx, c.1 + r * dy),
        width: (contrast / slope).max(0.0),
    })
}

/// The outline of a blob centred near `c`, about `r0` pixels in radius: two rounds
/// of rays and circle fits (see the module's doc).
fn outline(img: &Sampled, c: (f64, f64), r0: f64, polarity: Polarity) -> Option<Found> {
    let mut centre = c;
    let mut range = (0.25 * r0, 1.25 * r0);
    let mut found = None;
    for _ in 0..2 {
        let edges: Vec<Edge> = (0..RAYS)
            .filter_map(|k| {
                let a = k as f64 * std::f64::consts::TAU / RAYS as f64;
                edge_on_ray(img, centre, a, range, polarity)
            })
            .collect();
        let pts: Vec<(f64, f64)> = edges.iter().map(|e| e.point).collect();
        let (x, y, r) = fit_circle(&pts)?;
        let tol = (0.05 * r).max(1.5);
        let on: Vec<&Edge> = edges
            .iter()
            .filter(|e| ((e.point.0 - x).hypot(e.point.1 - y) - r).abs() <= tol)
            .collect();
        let inl: Vec<(f64, f64)> = on.iter().map(|e| e.point).collect();
        let (x, y, r) = fit_circle(&inl)?;
        let mut widths: Vec<f64> = on.iter().map(|e| e.width).collect();
        let width = median_in_place(&mut widths);
        let sharp = (1.0 - (width / r - 0.1) / 0.2).clamp(0.0, 1.0);
        found = Some(Found {
            x,
            y,
            diameter: 2.0 * r,
            confidence: on.len() as f64 / RAYS as f64 * sharp,
            polarity,
        });
        centre = (x, y);
        range = (0.6 * r, 1.4 * r);
    }
    found
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bright disc of radius `r` inside a dark halo on a grey field, blurred by
    /// about a pixel, with a linear illumination ramp.
    fn phase_cell(w: usize, h: usize, c: (f64, f64), r: f64, ramp: f64) -> Vec<f64> {
        let mut v = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let d = (x as f64 - c.0).hypot(y as f64 - c.1);
                let s = |e: f64| 0.5 * (1.0 + (e / 1.2).tanh());
                let body = s(r - d);
                let halo = s(r + 0.3 * r - d) - body;
                let base = 70.0 + 130.0 * body - 60.0 * halo;
                v[y * w + x] = base * (1.0 + ramp * (x as f64 / w as f64 - 0.5));
            }
        }
        v
    }

    /// One phase-contrast disc, and its inverse: found once each, centre within
    /// 0.5 px and diameter within 3 % of the disc's (the body's edge, not the halo's),
    /// the polarity named; no debris.
    #[test]
    fn a_disc_of_either_contrast_is_found_at_its_outline() {
        let (w, h) = (200, 180);
        let o = VisionOptions {
            diameter_px: [30.0, 90.0],
            contrast: Contrast::Auto,
        };
        for (ramp, invert) in [(0.0, false), (0.4, false), (0.0, true), (-0.3, true)] {
            let mut img = phase_cell(w, h, (96.3, 88.7), 27.0, ramp);
            if invert {
                img.iter_mut().for_each(|v| *v = 255.0 - *v);
            }
            let got = find_cells(&img, w, h, &o).unwrap();
            assert_eq!(got.cells.len(), 1, "{got:?}");
            assert!(got.debris.is_empty(), "{got:?}");
            let f = got.cells[0];
            assert!(
                (f.x - 96.3).abs() < 0.5 && (f.y - 88.7).abs() < 0.5,
                "{f:?}"
            );
            assert!((f.diameter / 54.0 - 1.0).abs() < 0.03, "{f:?}");
            let want = if invert {
                Polarity::Dark
            } else {
                Polarity::Bright
            };
            assert_eq!(f.polarity, want);
            // Asked for the other contrast only: nothing.
            let other = VisionOptions {
                contrast: if invert {
                    Contrast::Bright
                } else {
                    Contrast::Dark
                },
                ..o
            };
            assert!(find_cells(&img, w, h, &other).unwrap().cells.is_empty());
        }
    }

    /// Two phase-contrast discs whose halos overlap (one piece of the contrast mask)
    /// are two cells, each at its own outline, each once.
    #[test]
    fn two_cells_whose_halos_touch_are_two() {
        let (w, h) = (260, 160);
        let a = phase_cell(w, h, (80.0, 80.0), 27.0, 0.0);
        let b = phase_cell(w, h, (168.0, 82.0), 27.0, 0.0);
        // Each disc on the field (70): the sum less one field.
        let img: Vec<f64> = a.iter().zip(&b).map(|(p, q)| p + q - 70.0).collect();
        let o = VisionOptions {
            diameter_px: [30.0, 90.0],
            contrast: Contrast::Auto,
        };
        let got = find_cells(&img, w, h, &o).unwrap();
        assert_eq!(got.cells.len(), 2, "{got:?}");
        let mut xs: Vec<f64> = got.cells.iter().map(|f| f.x).collect();
        xs.sort_by(f64::total_cmp);
        assert!(
            (xs[0] - 80.0).abs() < 1.0 && (xs[1] - 168.0).abs() < 1.0,
            "{got:?}"
        );
        for f in &got.cells {
            assert!((f.diameter / 54.0 - 1.0).abs() < 0.05, "{f:?}");
        }
    }

    /// A blurred shadow as large as a cell (its edge as wide as its radius) is no
    /// cell; a flat field holds nothing.
    #[test]
    fn a_defocused_shadow_and_a_flat_field_hold_no_cell() {
        let (w, h) = (200, 180);
        let o = VisionOptions {
            diameter_px: [30.0, 90.0],
            contrast: Contrast::Auto,
        };
        let mut img = vec![100.0; w * h];
        for y in 0..h {
            for x in 0..w {
                let d = (x as f64 - 100.0).hypot(y as f64 - 90.0);
                img[y * w + x] -= 30.0 * (-(d / 25.0).powi(2)).exp();
            }
        }
        assert_eq!(find_cells(&img, w, h, &o).unwrap(), Census::default());
        let flat = vec![100.0; w * h];
        assert_eq!(find_cells(&flat, w, h, &o).unwrap(), Census::default());
    }

    /// Defaults in pixels from the pixel size, or from the image without one; bad
    /// requests refused.
    #[test]
    fn a_request_is_turned_into_pixels_or_refused() {
        let r = |pixel_size, diameter| Request {
            pixel_size,
            diameter,
            contrast: Contrast::Auto,
        };
        let px = |o: VisionOptions| o.diameter_px;
        let d = px(r(Some(0.5e-6), None).options(100, 80).unwrap());
        assert!(
            (d[0] - 19.0).abs() < 1e-9 && (d[1] - 60.0).abs() < 1e-9,
            "{d:?}"
        );
        assert_eq!(px(r(None, None).options(100, 80).unwrap()), [8.0, 40.0]);
        assert_eq!(px(r(None, None).options(20, 12).unwrap()), [8.0, 16.0]);
        let d = px(r(Some(1e-6), Some([10e-6, 20e-6])).options(40, 40).unwrap());
        assert!(
            (d[0] - 10.0).abs() < 1e-9 && (d[1] - 20.0).abs() < 1e-9,
            "{d:?}"
        );
        for (p, dm, want) in [
            (Some(f64::NAN), None, "PixelSize"),
            (Some(0.0), None, "PixelSize"),
            (None, Some([1e-6, 2e-6]), "DiameterWithoutPixelSize"),
            (Some(1e-6), Some([2e-6, 1e-6]), "Diameter"),
            (Some(1e-6), Some([f64::NAN, 1e-6]), "Diameter"),
            (Some(1e300), None, "Coarse"),
            (Some(1e-6), Some([20e-6, 30e-6]), "Large"),
            (Some(1e-6), Some([2e-6, 9e-6]), "Coarse"),
        ] {
            let e = r(p, dm).options(10, 10).unwrap_err();
            assert!(format!("{e:?}").starts_with(want), "{e:?}");
            let blamed = if dm.is_some() && want != "PixelSize" {
                Arg::Diameter
            } else {
                Arg::PixelSize
            };
            assert_eq!(e.arg(), blamed, "{e:?}");
        }
    }

    /// A hard-edged bright disc over an eighth of a flat field: the illumination stays
    /// the field's level (a least-squares start over every pixel bent it into a dome
    /// and lost the disc), and the disc is found at its edge.
    #[test]
    fn a_large_disc_does_not_pull_the_illumination() {
        let (w, h) = (140usize, 120usize);
        let mut img = vec![70.0; w * h];
        for y in 0..h {
            for x in 0..w {
                if (x as f64 - 70.3).hypot(y as f64 - 60.0) < 25.0 {
                    img[y * w + x] = 200.0;
                }
            }
        }
        let bg = background(&img, w, h);
        assert!(
            bg.iter().all(|b| (b - 70.0).abs() < 0.5),
            "{:?}",
            (bg[0], bg[60 * w + 70])
        );
        let o = VisionOptions {
            diameter_px: [23.75, 75.0],
            contrast: Contrast::Auto,
        };
        let got = find_cells(&img, w, h, &o).unwrap();
        assert_eq!(got.cells.len(), 1, "{got:?}");
        let f = got.cells[0];
        assert!(
            (f.x - 70.3).abs() < 0.3 && (f.y - 60.0).abs() < 0.3,
            "{f:?}"
        );
        assert!((f.diameter - 50.0).abs() < 1.0, "{f:?}");
    }

    #[test]
    fn bad_inputs_are_refused_naming_them() {
        let o = VisionOptions {
            diameter_px: [30.0, 90.0],
            contrast: Contrast::Auto,
        };
        let img = vec![1.0; 100];
        assert!(matches!(
            find_cells(&img, 10, 11, &o),
            Err(CellsError::Size { .. })
        ));
        let small = find_cells(&img[..49], 7, 7, &o).unwrap_err().to_string();
        assert!(small.contains("at least 8 x 8"), "{small}");
        let bad = |d: [f64; 2]| {
            find_cells(
                &img,
                10,
                10,
                &VisionOptions {
                    diameter_px: d,
                    ..o
                },
            )
            .unwrap_err()
            .to_string()
        };
        assert!(bad([f64::NAN, 9.0]).contains("smallest diameter"));
        assert!(bad([20.0, 10.0]).contains("largest diameter"));
        let mut nan = img.clone();
        nan[5] = f64::NAN;
        assert!(
            find_cells(&nan, 10, 10, &o)
                .unwrap_err()
                .to_string()
                .contains("pixel")
        );
    }
}
