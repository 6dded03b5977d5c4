//! Finding the pipette's tip in a top-view image, from the image alone (never from
//! the commanded position).
//!
//! The pipette enters the image from its top edge and tapers down to its tip. The
//! locator takes the dark component that touches the top edge, its lowest pixel as a
//! first guess and the principal axis of its last 60 µm as the direction; refines the
//! axis as the line through the tube's darkness-weighted centres across it, 8-50 µm
//! behind the tip; then, along that axis, fits the darkness integrated across the tube
//! with a step of height `a` and a ramp of slope `c` (the tube ends at the tip and
//! widens behind it) that both start at `t`, blurred by a Gaussian of `σ`:
//! `M(s) = a·Φ(z) + c·σ·(z·Φ(z) + φ(z))`, `z = (t − s)/σ`, by a search over `t` and `σ`
//! with `a`, `c` by least squares. The tip is the axis point at `t`.
//!
//! In one noisy frame `t` and `σ` trade against each other (a blurrier end further
//! ahead looks much like a sharper one further back): the free fit's `σ` ranges from
//! 0.3 to 6 px for a tip whose blur is 0.6 px, and the tip moves back with it (by
//! 1.3 px on average for `σ` over 2.5 px, by up to 5 px). The blur is the optics' at the
//! focus, the same in every frame taken there, so a caller that has measured it (the
//! median of many frames' free fits) passes it to [`locate_with`], whose fit finds
//! only `t`.

use crate::CellsError;

/// The tip found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tip {
    /// Pixels, column.
    pub x: f64,
    /// Pixels, row.
    pub y: f64,
    /// Unit vector along the pipette towards its tip (column, row).
    pub axis: [f64; 2],
    /// Pixels, the blur of the tip's end along the axis.
    pub sigma: f64,
}

/// The standard normal CDF.
fn phi(u: f64) -> f64 {
    0.5 * (1.0 + cellinject_numeric::erf(u / std::f64::consts::SQRT_2))
}

/// Bilinear sample of the darkness `d` at (x, y) pixels; 0 outside the image.
fn sample(d: &Darkness<'_>, x: f64, y: f64) -> f64 {
    let (w, h) = (d.w, d.h);
    if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f64 && y <= (h - 1) as f64) {
        return 0.0;
    }
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let a = d.at(x0, y0) * (1.0 - fx) + d.at(x1, y0) * fx;
    let b = d.at(x0, y1) * (1.0 - fx) + d.at(x1, y1) * fx;
    a * (1.0 - fy) + b * fy
}

/// Finds the tip in a `width × height` image at `pixel_size` m per pixel, its blur
/// fitted with its position.
pub fn locate(
    pixels: &[u16],
    width: usize,
    height: usize,
    pixel_size: f64,
) -> Result<Tip, CellsError> {
    locate_with(pixels, width, height, pixel_size, None)
}

/// [`locate`], with the blur of the tip's end along the axis known (`blur`, pixels:
/// see [`Tip::sigma`]): the fit then finds only the position. `None`: the blur is
/// fitted too.
pub fn locate_with(
    pixels: &[u16],
    width: usize,
    height: usize,
    pixel_size: f64,
    blur: Option<f64>,
) -> Result<Tip, CellsError> {
    locate_tapered(pixels, width, height, pixel_size, blur, 0.12)
}

/// [`locate_with`] for a tube whose radius grows by `taper` per unit length behind
/// the tip in the image (0.12 for a glass lying in the image plane; a glass tilted
/// out of it by `a` looks tapered by its own taper over `cos a`).
pub fn locate_tapered(
    pixels: &[u16],
    width: usize,
    height: usize,
    pixel_size: f64,
    blur: Option<f64>,
    taper: f64,
) -> Result<Tip, CellsError> {
    check_inputs(pixels.len(), (width, height), pixel_size, blur, taper)?;
    let dark = Darkness::new(pixels, width, height);
    fit_tip(&dark, pixel_size, blur, taper).map(|(tip, _)| tip)
}

/// How well [`fit_tip`]'s tip fits.
#[derive(Debug, Clone, Copy)]
struct Fit {
    /// The share of the profile's variance its model explains (R², 0 to 1).
    explained: f64,
    /// The pipette's width where it enters: pixels of the top row it covers.
    entry: usize,
    /// Whether it also reaches the bottom row (a tube crossing the frame: its tip is
    /// out of view).
    through: bool,
}

/// [`locate_tapered`] on the image's darkness, and how well it fits ([`Fit`]).
fn fit_tip(
    dark: &Darkness<'_>,
    pixel_size: f64,
    blur: Option<f64>,
    taper: f64,
) -> Result<(Tip, Fit), CellsError> {
    let (width, height) = (dark.w, dark.h);
    let um = |v: f64| v * 1e-6 / pixel_size;
    let mask = dark.mask(0.05);
    // The pipette: of the dark components that enter from the top edge, the widest
    // there (the shank; a feeder wall is a thin line).
    // (Only those are searched: components from the top row's pixels, in the order
    // and the pixel order `components` gives them.)
    let (entry, pipette) = crate::components_from(&mask, width, height, 0..width)
        .into_iter()
        .map(|c| (c.iter().filter(|&&i| i < width).count(), c))
        .filter(|(top, _)| *top > 0)
        .max_by_key(|(top, _)| *top)
        .ok_or(CellsError::NoPipette)?;
    if pipette.len() < 50 {
        return Err(CellsError::NoPipette);
    }
    // First guess: the lowest pixels.
    let ymax = pipette.iter().map(|&i| i / width).max().unwrap_or(0);
    let low: Vec<usize> = pipette
        .iter()
        .copied()
        .filter(|&i| i / width == ymax)
        .collect();
    let gx = low.iter().map(|&i| (i % width) as f64).sum::<f64>() / low.len() as f64;
    let (gx, gy) = (gx, ymax as f64);
    // Direction: principal axis of the last 60 µm, pointing down the image.
    let near: Vec<(f64, f64)> = pipette
        .iter()
        .map(|&i| ((i % width) as f64, (i / width) as f64))
        .filter(|(x, y)| (x - gx).hypot(y - gy) < um(60.0))
        .collect();
    let mut u = principal(&near);
    if u[1] < 0.0 {
        u = [-u[0], -u[1]];
    }
    // The axis: centres of darkness across the tube behind the tip.
    let centres = axis_centres(dark, (gx, gy), u, taper, pixel_size);
    let (ax, ay) = if centres.len() >= 3 {
        let n = centres.len() as f64;
        let m = centres
            .iter()
            .fold((0.0, 0.0), |a, p| (a.0 + p.0 / n, a.1 + p.1 / n));
        let mut d = principal(&centres);
        if d[1] < 0.0 {
            d = [-d[0], -d[1]];
        }
        u = d;
        m
    } else {
        (gx, gy)
    };
    // Project the first guess onto the axis: the origin of s.
    let t0 = (gx - ax) * u[0] + (gy - ay) * u[1];
    let (ox, oy) = (ax + t0 * u[0], ay + t0 * u[1]);
    // Darkness integrated across the tube along the axis, s forward (towards and beyond
    // the tip), from 25 µm behind to 15 µm beyond, quarter-pixel steps.
    // Across, the tube's half-width (0.5 µm at the tip, growing by `taper` of the
    // distance behind it) and 3 blurs; 5 µm when the blur is not known (a defocused tip).
    let reach = blur.map_or(um(5.0), |b| um(0.5) + 3.0 * b);
    let n = [-u[1], u[0]];
    let mut prof = Vec::new();
    let mut s = -um(25.0);
    while s <= um(15.0) {
        let (px, py) = (ox + s * u[0], oy + s * u[1]);
        let behind = (-s).max(0.0);
        let half = taper * behind + reach;
        let mut m = 0.0;
        let mut o = -half;
        while o <= half {
            m += sample(dark, px + o * n[0], py + o * n[1]) * 0.5;
            o += 0.5;
        }
        prof.push((s, m));
        s += 0.25;
    }
    // Fit t (within 8 µm of the guess) and σ (up to 10 µm: a defocused tip; or the
    // known blur), coarse then fine; a, c by least squares.
    let search =
        |best: &mut (f64, f64, f64), t_range: (f64, f64, f64), s_range: (f64, f64, f64)| {
            let mut sig = s_range.0;
            while sig <= s_range.1 {
                let mut t = t_range.0;
                while t <= t_range.1 {
                    let r = residual(&prof, t, sig);
                    if r < best.0 {
                        *best = (r, t, sig);
                    }
                    t += t_range.2;
                }
                sig += s_range.2;
            }
        };
    let mut best = (f64::INFINITY, 0.0, 1.0);
    let coarse = blur.map_or((0.5, um(10.0).max(1.0), 0.5), |b| (b, b, 1.0));
    search(&mut best, (-um(8.0), um(8.0), 0.5), coarse);
    let (_, t1, s1) = best;
    let fine = blur.map_or(((s1 - 0.5).max(0.3), s1 + 0.5, 0.1), |b| (b, b, 1.0));
    search(&mut best, (t1 - 0.6, t1 + 0.6, 0.05), fine);
    let (r, t, sigma) = best;
    let mean = prof.iter().map(|p| p.1).sum::<f64>() / prof.len().max(1) as f64;
    let spread: f64 = prof.iter().map(|p| (p.1 - mean).powi(2)).sum();
    let explained = if spread > 0.0 {
        (1.0 - r / spread).clamp(0.0, 1.0)
    } else {
        0.0
    };
    Ok((
        Tip {
            x: ox + t * u[0],
            y: oy + t * u[1],
            axis: u,
            sigma,
        },
        Fit {
            explained,
            entry,
            through: ymax + 1 >= height,
        },
    ))
}

/// The tube's darkness-weighted centres across it, 8-50 µm behind the first guess
/// `(gx, gy)` of the tip along `-u`, every 2 µm; a cross-section the image's edge cuts
/// is left out.
fn axis_centres(
    dark: &Darkness<'_>,
    (gx, gy): (f64, f64),
    u: [f64; 2],
    taper: f64,
    pixel_size: f64,
) -> Vec<(f64, f64)> {
    let (width, height) = (dark.w, dark.h);
    let um = |v: f64| v * 1e-6 / pixel_size;
    let mut centres = Vec::new();
    let mut b = um(8.0);
    while b <= um(50.0) {
        let (px, py) = (gx - b * u[0], gy - b * u[1]);
        let n = [-u[1], u[0]];
        let half = taper * b + um(5.0);
        // A cross-section the image's edge cuts has its centre pulled inwards (a
        // tube slanting out of the frame): only whole ones.
        let inside = |o: f64| {
            let (x, y) = (px + o * n[0], py + o * n[1]);
            x >= 0.0 && y >= 0.0 && x <= (width - 1) as f64 && y <= (height - 1) as f64
        };
        if !(inside(-half) && inside(half)) {
            b += um(2.0);
            continue;
        }
        let (mut sw, mut swo) = (0.0, 0.0);
        let mut o = -half;
        while o <= half {
            let v = sample(dark, px + o * n[0], py + o * n[1]).max(0.0);
            sw += v;
            swo += v * o;
            o += 0.5;
        }
        if sw > 0.0 {
            let c = swo / sw;
            centres.push((px + c * n[0], py + c * n[1]));
        }
        b += um(2.0);
    }
    centres
}

/// The pipette's tip in an image in which the pipette may enter from any edge, as
/// `vision tip` reports it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FoundTip {
    /// Pixels, column of the tip.
    pub x: f64,
    /// Pixels, row of the tip.
    pub y: f64,
    /// rad, the direction of the pipette's axis from the tip towards the shank:
    /// `atan2(dy, dx)` with x along the columns and y along the rows (down the image).
    pub axis_rad: f64,
    /// Pixels, the tube's width [`WIDTH_BEHIND`] behind the tip: where its darkness
    /// across the axis is at least half the highest.
    pub width: f64,
    /// 0 to 1, how well the darkness along the axis fits a tube ending at the tip:
    /// the share of its variance the fitted model explains.
    pub confidence: f64,
}

/// m, how far behind the tip [`FoundTip::width`] is measured.
pub const WIDTH_BEHIND: f64 = 5e-6;

/// Least [`FoundTip::confidence`] of a pipette: below it, what enters the image is
/// not a tube ending in a tip (a wall, a shadow, a cell at the edge).
pub const MIN_TIP_CONFIDENCE: f64 = 0.6;

/// The edge a pipette enters the image from, as the view of the image that brings
/// that edge to the top (where [`locate_tapered`] looks for it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum View {
    Top,
    Bottom,
    Left,
    Right,
}

impl View {
    /// The view's width and height for an image `w` x `h`.
    fn size(self, w: usize, h: usize) -> (usize, usize) {
        match self {
            View::Top | View::Bottom => (w, h),
            View::Left | View::Right => (h, w),
        }
    }

    /// The image's pixel seen at (i, j) of the view.
    fn source(self, i: usize, j: usize, w: usize, h: usize) -> usize {
        let (x, y) = match self {
            View::Top => (i, j),
            View::Bottom => (i, h - 1 - j),
            View::Left => (j, i),
            View::Right => (w - 1 - j, i),
        };
        y * w + x
    }

    /// The view of `pixels` (`w` x `h`).
    fn pixels(self, pixels: &[u16], w: usize, h: usize) -> Vec<u16> {
        let (vw, vh) = self.size(w, h);
        let mut out = Vec::with_capacity(vw * vh);
        for j in 0..vh {
            out.extend((0..vw).map(|i| pixels[self.source(i, j, w, h)]));
        }
        out
    }

    /// A point (x, y) of the view in the image's pixels.
    fn point(self, (x, y): (f64, f64), w: usize, h: usize) -> (f64, f64) {
        match self {
            View::Top => (x, y),
            View::Bottom => (x, (h - 1) as f64 - y),
            View::Left => (y, x),
            View::Right => ((w - 1) as f64 - y, x),
        }
    }

    /// A direction of the view in the image's.
    fn direction(self, [dx, dy]: [f64; 2]) -> [f64; 2] {
        match self {
            View::Top => [dx, dy],
            View::Bottom => [dx, -dy],
            View::Left => [dy, dx],
            View::Right => [-dy, dx],
        }
    }
}

/// The pipette's tip in a `width × height` image at `pixel_size` m per pixel (from
/// the image alone, the pipette entering from any edge): [`locate_tapered`] (its blur
/// fitted, the taper of a glass in the image plane) in each view that brings an edge
/// to the top; of the views whose tip lies inside the frame (at least [`BORDER`]
/// from its edges: on the border the tube leaves the frame), whose tube does not cross
/// the frame, is at most [`MAX_TIP_WIDTH`] wide near the tip and fits a tube ending in
/// a tip at least [`MIN_TIP_CONFIDENCE`], the one whose pipette enters widest.
/// [`CellsError::NoPipette`] when there is none; [`CellsError::Invalid`] for a pixel size that makes the locator's lengths
/// ([`SPAN`]) smaller than a few pixels or larger than the image.
pub fn find_tip(
    pixels: &[u16],
    width: usize,
    height: usize,
    pixel_size: f64,
) -> Result<FoundTip, CellsError> {
    let taper = 0.12;
    check_inputs(pixels.len(), (width, height), pixel_size, None, taper)?;
    let span = SPAN / pixel_size;
    if !(MIN_SPAN_PX..=2.0 * width.max(height) as f64).contains(&span) {
        return Err(CellsError::Invalid {
            what: "pixel_size",
            value: pixel_size,
            reason: "must make the pipette's last 60 µm (the tube the locator reads) between 8 pixels and twice the image's larger side",
        });
    }
    // A tip on the image's border is where the tube leaves the frame, not its end.
    let inside = |x: f64, y: f64| {
        let m = BORDER;
        x >= m && y >= m && x <= (width - 1) as f64 - m && y <= (height - 1) as f64 - m
    };
    // Of the views with a tip inside the frame and a good fit, the one whose pipette
    // enters widest: the shank crosses the edge it comes from (a tip near a side edge
    // touches that edge too, and the tube cut along it may be longer).
    let mut best: Option<(usize, FoundTip)> = None;
    for view in [View::Top, View::Bottom, View::Left, View::Right] {
        let (vw, vh) = view.size(width, height);
        let seen = view.pixels(pixels, width, height);
        let dark = Darkness::new(&seen, vw, vh);
        let (tip, fit) = match fit_tip(&dark, pixel_size, None, taper) {
            Ok(found) => found,
            Err(CellsError::NoPipette) => continue,
            Err(e) => return Err(e),
        };
        let (x, y) = view.point((tip.x, tip.y), width, height);
        if fit.explained < MIN_TIP_CONFIDENCE
            || fit.through
            || !inside(x, y)
            || best.is_some_and(|(entry, _)| entry >= fit.entry)
        {
            continue;
        }
        let behind = WIDTH_BEHIND / pixel_size;
        let tube = tube_width(&dark, &tip, behind, taper);
        // A glass's tip is a few micrometres wide there; far wider is not one.
        if tube * pixel_size > MAX_TIP_WIDTH {
            continue;
        }
        let [ax, ay] = view.direction(tip.axis);
        best = Some((
            fit.entry,
            FoundTip {
                x,
                y,
                axis_rad: (-ay).atan2(-ax),
                width: tube,
                confidence: fit.explained,
            },
        ));
    }
    best.map(|(_, t)| t).ok_or(CellsError::NoPipette)
}

/// m, the widest [`FoundTip::width`] of a pipette's tip (a pulled glass is 2-3 µm
/// wide 5 µm behind its tip; blur and a blunt tip add a few).
pub const MAX_TIP_WIDTH: f64 = 12e-6;

/// Pixels, how far inside the image's border a tip must lie for [`find_tip`] to report
/// it: nearer, the tube may run on out of the frame.
pub const BORDER: f64 = 2.0;

/// m, the length of tube whose direction the locator reads (its last 60 µm); a pixel
/// size must make it between [`MIN_SPAN_PX`] pixels and twice the image's larger side.
pub const SPAN: f64 = 60e-6;

/// Fewest pixels [`SPAN`] may cover.
pub const MIN_SPAN_PX: f64 = 8.0;

/// m, the length the shorter side of an image is taken to span when no pixel size is
/// given ([`find_tip_in`]): the locator's lengths (the last 60 µm of the tube give its
/// direction) then keep the same share of any image, whatever its resolution.
pub const DEFAULT_SHORT_SIDE: f64 = 240e-6;

/// [`find_tip`] for any front end: `values` are the image's grey levels (any scale,
/// none negative), `pixel_size` m per pixel or `None` (the image's shorter side then
/// spans [`DEFAULT_SHORT_SIDE`]). The levels are scaled into 16 bits by one factor,
/// which keeps every ratio to the background (the darkness the locator reads).
pub fn find_tip_in(
    values: &[f64],
    width: usize,
    height: usize,
    pixel_size: Option<f64>,
) -> Result<FoundTip, CellsError> {
    // A pixel size given is checked by `find_tip` with the rest.
    if values.len() != width * height || width < 8 || height < 8 {
        return Err(CellsError::Size {
            len: values.len(),
            width,
            height,
        });
    }
    if let Some(&bad) = values.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
        return Err(CellsError::Invalid {
            what: "image",
            value: bad,
            reason: "grey levels must be finite and not negative",
        });
    }
    let top = values.iter().copied().fold(0.0f64, f64::max);
    if top <= 0.0 {
        return Err(CellsError::NoPipette);
    }
    let scale = 60_000.0 / top;
    let pixels: Vec<u16> = values.iter().map(|v| (v * scale).round() as u16).collect();
    let pixel = pixel_size.unwrap_or(DEFAULT_SHORT_SIDE / width.min(height) as f64);
    find_tip(&pixels, width, height, pixel)
}

/// Pixels, the width of the tube `behind` px behind `tip` (in the view `dark` is
/// of): the span across the axis, in quarter pixels, where the darkness is at least
/// half its highest there.
fn tube_width(dark: &Darkness<'_>, tip: &Tip, behind: f64, taper: f64) -> f64 {
    let u = tip.axis;
    let (px, py) = (tip.x - behind * u[0], tip.y - behind * u[1]);
    let n = [-u[1], u[0]];
    let half = 2.0 * taper * behind + 4.0 + 3.0 * tip.sigma;
    let mut profile = Vec::new();
    let mut o = -half;
    while o <= half {
        profile.push((o, sample(dark, px + o * n[0], py + o * n[1])));
        o += 0.25;
    }
    let top = profile.iter().map(|p| p.1).fold(0.0f64, f64::max);
    if top <= 0.0 {
        return 0.0;
    }
    let inside: Vec<f64> = profile
        .iter()
        .filter(|p| p.1 >= 0.5 * top)
        .map(|p| p.0)
        .collect();
    match (inside.first(), inside.last()) {
        (Some(a), Some(b)) => b - a + 0.25,
        _ => 0.0,
    }
}

/// [`locate_tapered`]'s inputs checked: a positive taper, a frame of at least 8 x 8
/// pixels holding `len` values, a positive pixel size and blur.
fn check_inputs(
    len: usize,
    (width, height): (usize, usize),
    pixel_size: f64,
    blur: Option<f64>,
    taper: f64,
) -> Result<(), CellsError> {
    if !(taper.is_finite() && taper > 0.0) {
        return Err(CellsError::Invalid {
            what: "taper",
            value: taper,
            reason: "must be a positive growth of the radius per length",
        });
    }
    if len != width * height || width < 8 || height < 8 {
        return Err(CellsError::Size { len, width, height });
    }
    if !(pixel_size.is_finite() && pixel_size > 0.0) {
        return Err(CellsError::Invalid {
            what: "pixel_size",
            value: pixel_size,
            reason: "must be a positive length",
        });
    }
    if let Some(b) = blur
        && !(b.is_finite() && b > 0.0)
    {
        return Err(CellsError::Invalid {
            what: "blur",
            value: b,
            reason: "must be a positive number of pixels",
        });
    }
    Ok(())
}

/// Residual of the best `M(s) = a·Φ(z) + c·σ·(z·Φ(z) + φ(z))`, `z = (t − s)/σ` (a step
/// of `a` and a ramp of slope `c` starting at `t`, blurred by a Gaussian of `σ`), with
/// `a > 0` (infinite otherwise): `a`, `c` by least squares.
fn residual(prof: &[(f64, f64)], t: f64, sig: f64) -> f64 {
    let (mut a11, mut a12, mut a22, mut b1, mut b2, mut mm) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for &(s, m) in prof {
        // A step and a ramp starting at t, blurred by a Gaussian of σ.
        let z = (t - s) / sig;
        let f = phi(z);
        let g = sig * (z * f + (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt());
        a11 += f * f;
        a12 += f * g;
        a22 += g * g;
        b1 += f * m;
        b2 += g * m;
        mm += m * m;
    }
    let det = a11 * a22 - a12 * a12;
    if det.abs() <= 1e-12 {
        return f64::INFINITY;
    }
    let a = (b1 * a22 - b2 * a12) / det;
    let c = (a11 * b2 - a12 * b1) / det;
    if a <= 0.0 {
        return f64::INFINITY;
    }
    // |m − F x|² = m·m − 2 x·Fᵀm + xᵀ FᵀF x.
    mm - 2.0 * (a * b1 + c * b2) + a * a * a11 + 2.0 * a * c * a12 + c * c * a22
}

/// The image's darkness, `1 − image / background`, evaluated only where it is asked
/// for (a full frame's worth of `f64` would be 40 MB a frame). The background is a
/// biquadratic surface (smooth illumination and vignetting, across the whole image); a
/// box mean would not do here: the pipette's shank is wider than any window that still
/// follows the vignetting into the corners.
struct Darkness<'a> {
    pixels: &'a [u16],
    w: usize,
    h: usize,
    /// The background surface's coefficients, `None` if it could not be fitted (then
    /// nothing is dark).
    c: Option<[f64; 9]>,
    /// u of each column, −1 to 1.
    us: Vec<f64>,
}

impl<'a> Darkness<'a> {
    /// The background a biquadratic surface Σᵢⱼ c₃ᵢ₊ⱼ uⁱ vʲ (u, v from −1 to 1 across
    /// the image; smooth illumination and vignetting), fitted by least squares to every
    /// fourth pixel of every fourth row, then again without the pixels darker than 0.97
    /// of the first fit. A tensor product: each row is a quadratic in u with
    /// coefficients qᵢ = Σⱼ c₃ᵢ₊ⱼ vʲ, and the normal equations gather, row by row, the
    /// moments Σ uᵐ (m ≤ 4) and Σ uⁱ·value of the row's fitted pixels.
    fn new(pixels: &'a [u16], w: usize, h: usize) -> Self {
        let us: Vec<f64> = (0..w)
            .map(|x| 2.0 * x as f64 / (w - 1) as f64 - 1.0)
            .collect();
        let fit = |under: Option<&[f64; 9]>| -> Option<[f64; 9]> {
            let mut a = [[0.0f64; 9]; 9];
            let mut r = [0.0f64; 9];
            for y in (0..h).step_by(4) {
                let v = v_of(y, h);
                let pv = [1.0, v, v * v];
                let q = under.map(|c| row_coefficients(c, v));
                let (mut mu, mut ru) = ([0.0f64; 5], [0.0f64; 3]);
                for x in (0..w).step_by(4) {
                    let val = pixels[y * w + x] as f64;
                    let u = us[x];
                    if let Some(q) = q
                        && val <= 0.97 * (q[0] + u * (q[1] + u * q[2]))
                    {
                        continue;
                    }
                    let u2 = u * u;
                    mu[0] += 1.0;
                    mu[1] += u;
                    mu[2] += u2;
                    mu[3] += u2 * u;
                    mu[4] += u2 * u2;
                    ru[0] += val;
                    ru[1] += val * u;
                    ru[2] += val * u2;
                }
                for i in 0..3 {
                    for j in 0..3 {
                        for k in 0..3 {
                            for l in 0..3 {
                                a[3 * i + j][3 * k + l] += mu[i + k] * pv[j] * pv[l];
                            }
                        }
                        r[3 * i + j] += ru[i] * pv[j];
                    }
                }
            }
            crate::solve(a, r, 1e-12)
        };
        let c = fit(None).map(|c0| fit(Some(&c0)).unwrap_or(c0));
        Darkness {
            pixels,
            w,
            h,
            c,
            us,
        }
    }

    /// `1 − image / background` at pixel (x, y) (0 where the surface is not positive).
    fn at(&self, x: usize, y: usize) -> f64 {
        let Some(c) = &self.c else { return 0.0 };
        let q = row_coefficients(c, v_of(y, self.h));
        darkness(self.pixels[y * self.w + x], self.us[x], &q)
    }

    /// The pixels darker than `threshold`.
    fn mask(&self, threshold: f64) -> Vec<bool> {
        let Some(c) = &self.c else {
            return vec![false; self.w * self.h];
        };
        let mut out = Vec::with_capacity(self.w * self.h);
        for (y, row) in self.pixels.chunks_exact(self.w).enumerate() {
            let q = row_coefficients(c, v_of(y, self.h));
            out.extend(
                row.iter()
                    .zip(&self.us)
                    .map(|(&p, &u)| darkness(p, u, &q) > threshold),
            );
        }
        out
    }
}

/// v of row `y` of `h`, −1 to 1.
fn v_of(y: usize, h: usize) -> f64 {
    2.0 * y as f64 / (h - 1) as f64 - 1.0
}

/// The surface's quadratic in u along the row at `v`.
fn row_coefficients(c: &[f64; 9], v: f64) -> [f64; 3] {
    std::array::from_fn(|i| c[3 * i] + v * (c[3 * i + 1] + v * c[3 * i + 2]))
}

/// `1 − p / background` for a pixel of value `p` at `u` on the row whose quadratic is `q`.
fn darkness(p: u16, u: f64, q: &[f64; 3]) -> f64 {
    let b = q[0] + u * (q[1] + u * q[2]);
    if b > 0.0 { 1.0 - p as f64 / b } else { 0.0 }
}

/// The unit principal axis of points.
fn principal(pts: &[(f64, f64)]) -> [f64; 2] {
    let n = pts.len().max(1) as f64;
    let (cx, cy) = pts
        .iter()
        .fold((0.0, 0.0), |a, p| (a.0 + p.0 / n, a.1 + p.1 / n));
    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
    for (x, y) in pts {
        let (dx, dy) = (x - cx, y - cy);
        sxx += dx * dx;
        syy += dy * dy;
        sxy += dx * dy;
    }
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    [angle.cos(), angle.sin()]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn phi_is_the_normal_cdf() {
        assert!((phi(0.0) - 0.5).abs() < 1e-12);
        assert!((phi(1.0) - 0.841_344_746_068_543).abs() < 1e-12);
        assert!((phi(-2.0) - 0.022_750_131_948_179).abs() < 1e-12);
    }

    /// A `w × h` frame (divided by its background, scaled to 2000) of a tube tapering
    /// down to its tip at (`x0`, `y0`) px: 0.5 µm radius at the tip, growing by 0.12 of
    /// the distance behind it, its end and walls blurred by `sigma` px, with noise of
    /// `noise` counts.
    fn tube(
        x0: f64,
        y0: f64,
        sigma: f64,
        noise: f64,
        rng: &mut cellinject_numeric::Rng,
    ) -> Vec<u16> {
        let (w, h, pix) = (120usize, 160usize, 0.88e-6);
        let mut px = Vec::with_capacity(w * h);
        for j in 0..h {
            for i in 0..w {
                let behind = (y0 - j as f64).max(0.0);
                let r = (0.5e-6 + 0.12 * behind * pix) / pix;
                let d = (i as f64 - x0).abs();
                let outer = phi((r - d) / sigma);
                let inner = phi((0.65 * r - d) / sigma);
                let fade = phi((y0 - j as f64) / sigma);
                let dark = fade * (0.12 * outer + 0.45 * (outer - inner));
                px.push((2000.0 * (1.0 - dark) + noise * rng.gaussian()).round() as u16);
            }
        }
        px
    }

    #[test]
    fn with_its_blur_known_the_tip_is_found_along_the_axis_in_every_frame() {
        let mut rng = cellinject_numeric::Rng::new(7, 1);
        let mut worst: f64 = 0.0;
        for k in 0..30 {
            let (x0, y0) = (60.0 + 0.37 * k as f64 % 1.0, 100.0 + 0.61 * k as f64 % 1.0);
            let px = tube(x0, y0, 0.6, 50.0, &mut rng);
            let t = locate_with(&px, 120, 160, 0.88e-6, Some(0.6)).expect("tip");
            assert!(
                (t.x - x0).abs() < 0.3,
                "frame {k}: across {:.2} px off",
                t.x - x0
            );
            worst = worst.max((t.y - y0).abs());
        }
        assert!(
            worst < 1.0,
            "a frame's tip {worst:.2} px off along the axis"
        );
    }

    #[test]
    fn a_blur_that_is_not_a_positive_number_is_refused() {
        let px = vec![1000u16; 64 * 64];
        assert!(matches!(
            locate_with(&px, 64, 64, 1e-6, Some(0.0)),
            Err(CellsError::Invalid { what: "blur", .. })
        ));
    }

    #[test]
    fn an_image_without_a_pipette_says_so() {
        let px = vec![1000u16; 64 * 64];
        assert_eq!(locate(&px, 64, 64, 1e-6), Err(CellsError::NoPipette));
    }
}
