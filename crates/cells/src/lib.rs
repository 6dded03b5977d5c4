//! # cellinject-cells
//!
//! Finds cells in a bright-field microscope image by classical segmentation:
//!
//! 1. **Background.** The illumination (vignetting) is estimated by a box mean over a
//!    window several cells wide, twice: the second pass leaves out what the first found
//!    darker than the background, so cells do not pull it down.
//! 2. **Darkness.** `d = 1 − image / background`; cells darken their inside by ~10 %,
//!    their membrane by ~30 %; debris by 50 % and more.
//! 3. **Mask and opening.** `d > threshold`, then a morphological opening by a square
//!    of about 4 µm: thin structures (the feeder's walls, fine dust, the neck between
//!    two touching cells) disappear, discs stay; holes inside blobs are filled.
//! 4. **Components** (4-connected). One whose distance transform has a second high
//!    point (at least 3.5 µm from the outside) beyond the first's inscribed disc holds
//!    two touching cells (a doublet): its pixels are shared by power distance to the
//!    two discs, which for touching discs is their common tangent.
//!    A blob cut by the image's border is left out (it cannot be measured).
//! 5. **Kinds.** A blob narrower than `min_cell` (equivalent diameter) or darker on
//!    average than `max_cell_darkness` is debris, never a cell.
//!
//! A cell's centre is the circle fitted (Kåsa) to its outer edge, which a cut between
//! touching cells does not bias, whatever its nucleus; its diameter is where its
//! membrane is darkest along the radius (a kernel mean of the radial profile, its peak
//! refined between bins). Debris is given by centroid and equivalent
//! diameter `2√(A/π)`.
//!
//! **Architecture invariant:** pure computation on pixels it is given: no files, no
//! devices, no clock; pixel coordinates in, pixel coordinates out.

use std::collections::VecDeque;

use thiserror::Error;

pub mod focus;
pub mod pipette;
pub mod tip;
pub mod vision;

/// Why an image could not be searched.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum CellsError {
    /// The pixel buffer does not match the size.
    #[error("{len} pixels for a {width}x{height} image")]
    Size {
        /// Pixels given.
        len: usize,
        /// Columns.
        width: usize,
        /// Rows.
        height: usize,
    },
    /// No pipette in view: nothing dark enters the image from its edge (the top
    /// edge for [`tip::locate`], any for [`tip::find_tip`]) and ends in a tip.
    #[error("no pipette in view: nothing dark enters the image from an edge and ends in a tip")]
    NoPipette,
    /// An option outside its domain.
    #[error("{what} = {value}: {reason}")]
    Invalid {
        /// Which option.
        what: &'static str,
        /// Its value.
        value: f64,
        /// What is wrong.
        reason: &'static str,
    },
}

/// How to search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// m per pixel in the object plane.
    pub pixel_size: f64,
    /// Darkness above which a pixel belongs to something.
    pub threshold: f64,
    /// m, side of the opening's square.
    pub opening: f64,
    /// m, smallest equivalent diameter of a cell.
    pub min_cell: f64,
    /// Mean darkness above which a blob is debris.
    pub max_cell_darkness: f64,
    /// m, side of the background window.
    pub background: f64,
}

impl Options {
    /// Defaults for cells of 10-30 µm at `pixel_size` m per pixel.
    pub fn for_pixel_size(pixel_size: f64) -> Self {
        Options {
            pixel_size,
            threshold: 0.05,
            opening: 4e-6,
            min_cell: 9.5e-6,
            max_cell_darkness: 0.3,
            background: 90e-6,
        }
    }
}

/// What a blob is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A cell.
    Cell,
    /// Not a cell: too small or too dark.
    Debris,
}

/// One thing found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Blob {
    /// Pixels, centroid column.
    pub x: f64,
    /// Pixels, centroid row.
    pub y: f64,
    /// m, equivalent diameter.
    pub diameter: f64,
    /// Mean darkness over the blob.
    pub darkness: f64,
    /// Cell or debris.
    pub kind: Kind,
    /// Whether it was split from a touching neighbour.
    pub split: bool,
    /// m, the diameter's standard error from the four quarters around the centre
    /// (the standard deviation of their membrane diameters over √(quarters)): how well
    /// the size is known (under 0.1 µm for a round cell on its own, up to 0.6 µm for
    /// a small cell cut by its partner); `None` for debris and where fewer than three
    /// quarters show the membrane.
    pub diameter_se: Option<f64>,
}

/// Finds the blobs of a `width × height` image (row-major `pixels`); `exclude` (same
/// size, or empty) marks pixels never to be counted (e.g. outside the plate).
pub fn detect(
    pixels: &[u16],
    width: usize,
    height: usize,
    exclude: &[bool],
    o: &Options,
) -> Result<Vec<Blob>, CellsError> {
    if pixels.len() != width * height || (!exclude.is_empty() && exclude.len() != pixels.len()) {
        return Err(CellsError::Size {
            len: pixels.len(),
            width,
            height,
        });
    }
    for (what, v) in [
        ("pixel_size", o.pixel_size),
        ("opening", o.opening),
        ("min_cell", o.min_cell),
        ("background", o.background),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(CellsError::Invalid {
                what,
                value: v,
                reason: "must be a positive length",
            });
        }
    }
    for (what, v) in [
        ("threshold", o.threshold),
        ("max_cell_darkness", o.max_cell_darkness),
    ] {
        if !(v.is_finite() && v > 0.0 && v < 1.0) {
            return Err(CellsError::Invalid {
                what,
                value: v,
                reason: "must lie in (0, 1)",
            });
        }
    }
    let dark = darkness(pixels, width, height, o.background / o.pixel_size);
    let mut mask: Vec<bool> = dark
        .iter()
        .enumerate()
        .map(|(i, d)| *d > o.threshold && (exclude.is_empty() || !exclude[i]))
        .collect();
    let r = ((0.5 * o.opening / o.pixel_size).round() as usize).max(1);
    mask = opening(&mask, width, height, r);
    fill_holes(&mut mask, width, height);
    let mut blobs = Vec::new();
    let on_border = |i: usize| {
        let (x, y) = (i % width, i / width);
        x == 0 || y == 0 || x + 1 == width || y + 1 == height
    };
    for comp in components(&mask, width, height) {
        // A second disc must be at least a small cell: 3.5 µm from its outside.
        let members: std::collections::HashSet<usize> = comp.iter().copied().collect();
        for (part, split) in split_discs(&comp, width, 3.5e-6 / o.pixel_size) {
            // Cut by the image's border: not measurable here.
            if part.iter().any(|&i| on_border(i)) {
                continue;
            }
            if let Some(b) = blob(&part, &members, &dark, width, o, split) {
                blobs.push(b);
            }
        }
    }
    Ok(blobs)
}

/// `1 − image / background` per pixel, the background a box mean over `window` pixels,
/// taken twice: the second pass leaves out what the first found clearly darker.
pub(crate) fn darkness(pixels: &[u16], width: usize, height: usize, window: f64) -> Vec<f64> {
    let img: Vec<f64> = pixels.iter().map(|&p| p as f64).collect();
    let win = (window.round() as usize).max(3) | 1;
    let all = vec![true; img.len()];
    let bg0 = box_mean(&img, &all, width, height, win / 2);
    let keep: Vec<bool> = img
        .iter()
        .zip(&bg0)
        .map(|(v, b)| *b > 0.0 && *v > 0.97 * b)
        .collect();
    let bg = box_mean(&img, &keep, width, height, win / 2);
    img.iter()
        .zip(bg.iter().zip(&bg0))
        .map(|(v, (b, b0))| {
            let b = if *b > 0.0 { *b } else { *b0 };
            if b > 0.0 { 1.0 - v / b } else { 0.0 }
        })
        .collect()
}

/// Mean of `img` over the `(2h+1)²` window around each pixel, counting only `keep`
/// pixels (summed-area tables).
pub(crate) fn box_mean(img: &[f64], keep: &[bool], w: usize, h: usize, half: usize) -> Vec<f64> {
    let (w1, h1) = (w + 1, h + 1);
    let mut s = vec![0.0; w1 * h1];
    let mut n = vec![0.0; w1 * h1];
    for y in 0..h {
        let (mut rs, mut rn) = (0.0, 0.0);
        for x in 0..w {
            let i = y * w + x;
            if keep[i] {
                rs += img[i];
                rn += 1.0;
            }
            s[(y + 1) * w1 + x + 1] = s[y * w1 + x + 1] + rs;
            n[(y + 1) * w1 + x + 1] = n[y * w1 + x + 1] + rn;
        }
    }
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        let (y0, y1) = (y.saturating_sub(half), (y + half + 1).min(h));
        for x in 0..w {
            let (x0, x1) = (x.saturating_sub(half), (x + half + 1).min(w));
            let sum = s[y1 * w1 + x1] - s[y0 * w1 + x1] - s[y1 * w1 + x0] + s[y0 * w1 + x0];
            let cnt = n[y1 * w1 + x1] - n[y0 * w1 + x1] - n[y1 * w1 + x0] + n[y0 * w1 + x0];
            out[y * w + x] = if cnt > 0.0 { sum / cnt } else { 0.0 };
        }
    }
    out
}

/// Erosion then dilation by the `(2r+1)²` square (separable; outside counts as empty).
pub(crate) fn opening(mask: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    let eroded = filter(mask, w, h, r, true);
    filter(&eroded, w, h, r, false)
}

/// Separable min (`erode`) or max filter over the `(2r+1)²` square.
fn filter(mask: &[bool], w: usize, h: usize, r: usize, erode: bool) -> Vec<bool> {
    let pass = |src: &[bool], along_x: bool| -> Vec<bool> {
        let mut out = vec![false; w * h];
        let (n, m) = if along_x { (h, w) } else { (w, h) };
        let at = |a: usize, b: usize| if along_x { a * w + b } else { b * w + a };
        for a in 0..n {
            // Running count of set pixels in the window.
            let mut count = 0usize;
            for b in 0..r.min(m) {
                count += src[at(a, b)] as usize;
            }
            for b in 0..m {
                if b + r < m {
                    count += src[at(a, b + r)] as usize;
                }
                if b > r {
                    count -= src[at(a, b - r - 1)] as usize;
                }
                out[at(a, b)] = if erode { count == 2 * r + 1 } else { count > 0 };
            }
        }
        out
    };
    let a = pass(mask, true);
    pass(&a, false)
}

/// The 4-neighbours of pixel `i` inside a `w × h` image.
fn neighbours(i: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    let (x, y) = (i % w, i / w);
    [
        (x > 0).then(|| i - 1),
        (x + 1 < w).then(|| i + 1),
        (y > 0).then(|| i - w),
        (y + 1 < h).then(|| i + w),
    ]
    .into_iter()
    .flatten()
}

/// Sets the pixels the outside cannot reach (holes inside a blob, where noise left a
/// cell's pale inside below the threshold): a hole would pull the distance transform
/// off the cell's centre.
pub(crate) fn fill_holes(mask: &mut [bool], w: usize, h: usize) {
    let mut reached = vec![false; mask.len()];
    let mut queue = VecDeque::new();
    for i in 0..mask.len() {
        let (x, y) = (i % w, i / w);
        if (x == 0 || y == 0 || x + 1 == w || y + 1 == h) && !mask[i] {
            reached[i] = true;
            queue.push_back(i);
        }
    }
    while let Some(i) = queue.pop_front() {
        for j in neighbours(i, w, h) {
            if !mask[j] && !reached[j] {
                reached[j] = true;
                queue.push_back(j);
            }
        }
    }
    for (m, r) in mask.iter_mut().zip(&reached) {
        *m = !*r;
    }
}

/// 4-connected components, each a list of pixel indices.
pub(crate) fn components(mask: &[bool], w: usize, h: usize) -> Vec<Vec<usize>> {
    components_from(mask, w, h, 0..mask.len())
}

/// The 4-connected components of `mask` that hold a pixel of `starts`, in the order of
/// the first such pixel, each in breadth-first order from it.
pub(crate) fn components_from(
    mask: &[bool],
    w: usize,
    h: usize,
    starts: std::ops::Range<usize>,
) -> Vec<Vec<usize>> {
    let mut seen = vec![false; mask.len()];
    let mut out = Vec::new();
    let mut queue = VecDeque::new();
    for start in starts {
        if !mask[start] || seen[start] {
            continue;
        }
        let mut comp = Vec::new();
        seen[start] = true;
        queue.push_back(start);
        while let Some(i) = queue.pop_front() {
            comp.push(i);
            for j in neighbours(i, w, h) {
                if mask[j] && !seen[j] {
                    seen[j] = true;
                    queue.push_back(j);
                }
            }
        }
        out.push(comp);
    }
    out
}

/// Chamfer (3-4) distance of each pixel of a component to its outside, pixels: `(x0,
/// y0, bw, bh, dt)` over the component's bounding box.
fn distance(comp: &[usize], w: usize) -> (usize, usize, usize, usize, Vec<f64>) {
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for &i in comp {
        let (x, y) = (i % w, i / w);
        x0 = x0.min(x);
        y0 = y0.min(y);
        x1 = x1.max(x);
        y1 = y1.max(y);
    }
    // One pixel of outside all round.
    let (bw, bh) = (x1 - x0 + 3, y1 - y0 + 3);
    const FAR: f64 = 1e9;
    let mut d = vec![0.0; bw * bh];
    for &i in comp {
        d[(i / w - y0 + 1) * bw + (i % w - x0 + 1)] = FAR;
    }
    let (a, b) = (1.0, 4.0 / 3.0);
    for y in 1..bh - 1 {
        for x in 1..bw - 1 {
            let k = y * bw + x;
            if d[k] > 0.0 {
                d[k] = d[k]
                    .min(d[k - 1] + a)
                    .min(d[k - bw] + a)
                    .min(d[k - bw - 1] + b)
                    .min(d[k - bw + 1] + b);
            }
        }
    }
    for y in (1..bh - 1).rev() {
        for x in (1..bw - 1).rev() {
            let k = y * bw + x;
            if d[k] > 0.0 {
                d[k] = d[k]
                    .min(d[k + 1] + a)
                    .min(d[k + bw] + a)
                    .min(d[k + bw + 1] + b)
                    .min(d[k + bw - 1] + b);
            }
        }
    }
    (x0, y0, bw, bh, d)
}

/// A component (pixel indices in an image `w` wide) as it is, or split in two if it
/// holds two discs: the distance transform's highest point is one disc's centre (its
/// value the radius); the highest point outside that disc, if it is at least
/// `min_radius` pixels from the outside, is a second disc. Pixels go to the disc of the
/// smaller power distance `|p − c|² − r²` (for two touching discs: their common
/// tangent).
pub(crate) fn split_discs(comp: &[usize], w: usize, min_radius: f64) -> Vec<(Vec<usize>, bool)> {
    if comp.len() < 20 {
        return vec![(comp.to_vec(), false)];
    }
    let (x0, y0, bw, _bh, d) = distance(comp, w);
    let at = |i: usize| (i % w - x0 + 1, i / w - y0 + 1);
    let dt = |i: usize| {
        let (x, y) = at(i);
        d[y * bw + x]
    };
    let Some(&c1) = comp.iter().max_by(|a, b| dt(**a).total_cmp(&dt(**b))) else {
        return vec![(comp.to_vec(), false)];
    };
    let r1 = dt(c1);
    let (x1, y1) = at(c1);
    let far = |i: usize| {
        let (x, y) = at(i);
        (x as f64 - x1 as f64).hypot(y as f64 - y1 as f64) > r1 + 1.0
    };
    let Some(&c2) = comp
        .iter()
        .filter(|i| far(**i))
        .max_by(|a, b| dt(**a).total_cmp(&dt(**b)))
    else {
        return vec![(comp.to_vec(), false)];
    };
    let r2 = dt(c2);
    if r2 < min_radius {
        return vec![(comp.to_vec(), false)];
    }
    let (x2, y2) = at(c2);
    let (mut one, mut two) = (Vec::new(), Vec::new());
    for &i in comp {
        let (x, y) = at(i);
        let p1 = (x as f64 - x1 as f64).powi(2) + (y as f64 - y1 as f64).powi(2) - r1 * r1;
        let p2 = (x as f64 - x2 as f64).powi(2) + (y as f64 - y2 as f64).powi(2) - r2 * r2;
        if p1 <= p2 {
            one.push(i);
        } else {
            two.push(i);
        }
    }
    vec![(one, true), (two, true)]
}

/// `a x = r` by Gaussian elimination with partial pivoting; `None` when a pivot is
/// below `tiny` in magnitude (or not a number).
pub(crate) fn solve<const N: usize>(
    mut a: [[f64; N]; N],
    mut r: [f64; N],
    tiny: f64,
) -> Option<[f64; N]> {
    for k in 0..N {
        let p = (k..N).max_by(|&i, &j| a[i][k].abs().total_cmp(&a[j][k].abs()))?;
        let pivot = a[p][k].abs();
        if pivot.is_nan() || pivot < tiny {
            return None;
        }
        a.swap(k, p);
        r.swap(k, p);
        for i in k + 1..N {
            let f = a[i][k] / a[k][k];
            for j in k..N {
                a[i][j] -= f * a[k][j];
            }
            r[i] -= f * r[k];
        }
    }
    let mut x = [0.0; N];
    for k in (0..N).rev() {
        let s: f64 = (k + 1..N).map(|j| a[k][j] * x[j]).sum();
        x[k] = (r[k] - s) / a[k][k];
    }
    Some(x)
}

/// Circle through points in the least-squares sense (Kåsa): `(cx, cy, r)`, or `None`
/// when the points do not determine one.
pub(crate) fn fit_circle(pts: &[(f64, f64)]) -> Option<(f64, f64, f64)> {
    if pts.len() < 8 {
        return None;
    }
    // Centred for conditioning.
    let n = pts.len() as f64;
    let (mx, my) = pts
        .iter()
        .fold((0.0, 0.0), |a, p| (a.0 + p.0 / n, a.1 + p.1 / n));
    // Minimise Σ (u² + v² + D u + E v + F)², u = x − mx, v = y − my.
    let mut m = [[0.0f64; 3]; 3];
    let mut rhs = [0.0f64; 3];
    for (x, y) in pts {
        let (u, v) = (x - mx, y - my);
        let row = [u, v, 1.0];
        let z = -(u * u + v * v);
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] += row[i] * row[j];
            }
            rhs[i] += row[i] * z;
        }
    }
    let det3 = |a: &[[f64; 3]; 3]| {
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    };
    let det = det3(&m);
    if !(det.is_finite() && det.abs() > 1e-12) {
        return None;
    }
    let mut sol = [0.0; 3];
    for k in 0..3 {
        let mut mk = m;
        for i in 0..3 {
            mk[i][k] = rhs[i];
        }
        sol[k] = det3(&mk) / det;
    }
    let (cu, cv) = (-0.5 * sol[0], -0.5 * sol[1]);
    let r2 = cu * cu + cv * cv - sol[2];
    (r2 > 0.0).then(|| (mx + cu, my + cv, r2.sqrt()))
}

/// A blob from its pixels: debris by centroid and equivalent diameter; a cell by a
/// circle fitted to its outer edge (the pixels next to the outside of the whole
/// component `comp`, not the cut between two touching cells), its diameter where the
/// membrane is darkest along the radius.
fn blob(
    part: &[usize],
    comp: &std::collections::HashSet<usize>,
    dark: &[f64],
    w: usize,
    o: &Options,
    split: bool,
) -> Option<Blob> {
    if part.is_empty() {
        return None;
    }
    let n = part.len() as f64;
    let (mut sx, mut sy, mut sd) = (0.0, 0.0, 0.0);
    for &i in part {
        sx += (i % w) as f64;
        sy += (i / w) as f64;
        sd += dark[i];
    }
    let eq = 2.0 * (n / std::f64::consts::PI).sqrt() * o.pixel_size;
    let darkness = sd / n;
    let mut b = Blob {
        x: sx / n,
        y: sy / n,
        diameter: eq,
        darkness,
        kind: Kind::Cell,
        split,
        diameter_se: None,
    };
    if eq < o.min_cell || darkness > o.max_cell_darkness {
        b.kind = Kind::Debris;
        return Some(b);
    }
    let outside = |i: usize| !comp.contains(&i);
    let edge: Vec<(f64, f64)> = part
        .iter()
        .filter(|&&i| {
            let (x, y) = (i % w, i / w);
            x == 0 || y == 0 || outside(i - 1) || outside(i + 1) || outside(i - w) || outside(i + w)
        })
        .map(|&i| ((i % w) as f64, (i / w) as f64))
        .collect();
    let Some((cx, cy, r)) = fit_circle(&edge) else {
        return Some(b);
    };
    b.x = cx;
    b.y = cy;
    match ring_radius(part, dark, w, (cx, cy), r) {
        Some((rho, se)) => {
            b.diameter = 2.0 * rho * o.pixel_size;
            b.diameter_se = se.map(|s| 2.0 * s * o.pixel_size);
        }
        None => b.diameter = 2.0 * r * o.pixel_size,
    }
    Some(b)
}

/// Eighth-pixel bins of a radial profile.
const PER_PX: f64 = 8.0;

/// A radial darkness profile: sums and counts of pixels per eighth-pixel bin of their
/// distance from a centre.
struct Profile {
    sum: Vec<f64>,
    cnt: Vec<f64>,
}

impl Profile {
    fn new(bins: usize) -> Self {
        Profile {
            sum: vec![0.0; bins],
            cnt: vec![0.0; bins],
        }
    }

    fn add(&mut self, rho: f64, d: f64) {
        let k = (PER_PX * rho).round() as usize;
        if k < self.sum.len() {
            self.sum[k] += d;
            self.cnt[k] += 1.0;
        }
    }

    /// px: where the kernel mean (Gaussian in the radius, σ = 0.4 px) is highest
    /// between half and all of `r`, refined between bins by the parabola through the
    /// peak and its neighbours; `None` where fewer than about three pixels' weight
    /// falls at every radius.
    fn peak(&self, r: f64) -> Option<f64> {
        const SIGMA: f64 = 0.4 * PER_PX;
        let bins = self.sum.len();
        let reach = (3.0 * SIGMA).ceil() as usize;
        let smooth = |k: usize| {
            let (mut s, mut c) = (0.0, 0.0);
            for j in k.saturating_sub(reach)..(k + reach + 1).min(bins) {
                let g = (-((j as f64 - k as f64) / SIGMA).powi(2) / 2.0).exp();
                s += g * self.sum[j];
                c += g * self.cnt[j];
            }
            (c >= 3.0).then(|| s / c)
        };
        let (lo, hi) = ((PER_PX * 0.5 * r) as usize, (PER_PX * r) as usize);
        let profile: Vec<Option<f64>> = (lo..=hi + 1).map(smooth).collect();
        let (at, top) = profile[..profile.len() - 1]
            .iter()
            .enumerate()
            .filter_map(|(i, v)| v.map(|v| (i, v)))
            .max_by(|a, b| a.1.total_cmp(&b.1))?;
        let shift = match (at.checked_sub(1).and_then(|i| profile[i]), profile[at + 1]) {
            (Some(a), Some(c)) if a + c - 2.0 * top < 0.0 => {
                (0.5 * (a - c) / (a + c - 2.0 * top)).clamp(-0.5, 0.5)
            }
            _ => 0.0,
        };
        Some(((lo + at) as f64 + shift) / PER_PX)
    }
}

/// The membrane's radius, px, and its standard error from the four quarters around
/// the centre (px, the standard deviation of the quarters' radii over √(quarters);
/// `None` when fewer than three quarters show the ring): where the darkness of `part`'s pixels around
/// `centre` is highest between half and all of the fitted radius `r`
/// ([`Profile::peak`]: a kernel mean over eighth-pixel bins, so a small cell's few
/// pixels per radius do not make its peak jump by their noise; a small cell of a
/// doublet was measured up to 1.9 µm small of 10 µm by the darkest quarter-pixel bin
/// of 5-9 pixels, and every diameter moved in steps of half a pixel). A cell cut by
/// its partner, or not round, shows quarters that disagree.
fn ring_radius(
    part: &[usize],
    dark: &[f64],
    w: usize,
    centre: (f64, f64),
    r: f64,
) -> Option<(f64, Option<f64>)> {
    let bins = (PER_PX * (r + 1.0)).ceil() as usize + 1;
    let mut whole = Profile::new(bins);
    let mut quarters: [Profile; 4] = std::array::from_fn(|_| Profile::new(bins));
    for &i in part {
        let (dx, dy) = ((i % w) as f64 - centre.0, (i / w) as f64 - centre.1);
        let rho = dx.hypot(dy);
        whole.add(rho, dark[i]);
        quarters[usize::from(dx >= 0.0) + 2 * usize::from(dy >= 0.0)].add(rho, dark[i]);
    }
    let radius = whole.peak(r)?;
    let each: Vec<f64> = quarters.iter().filter_map(|q| q.peak(r)).collect();
    let se = (each.len() >= 3).then(|| {
        let n = each.len() as f64;
        let mean = each.iter().sum::<f64>() / n;
        (each.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt()
    });
    Some((radius, se))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    const PS: f64 = 0.88e-6;

    /// A 400 x 300 image at 0.88 µm/px: background 2000 with a gentle vignette, discs
    /// `(x, y, diameter, inside, ring)` in m with their inside and membrane darkness,
    /// blurred edges (σ ≈ 1 µm).
    fn image(discs: &[(f64, f64, f64, f64, f64)]) -> (Vec<u16>, usize, usize) {
        let (w, h) = (400usize, 300usize);
        let s = 1.0e-6;
        let phi = |u: f64| 0.5 * (1.0 + cellinject_numeric::erf(u / std::f64::consts::SQRT_2));
        let mut px = vec![0u16; w * h];
        for j in 0..h {
            for i in 0..w {
                let (x, y) = (i as f64 * PS, j as f64 * PS);
                let u = (i as f64 - 200.0) / 200.0;
                let mut v = 2000.0 * (1.0 - 0.1 * u * u);
                for &(cx, cy, d, inside, ring) in discs {
                    let rho = (x - cx).hypot(y - cy);
                    let r = 0.5 * d;
                    let a = phi((r - rho) / s);
                    let m = (-(rho - r).powi(2) / (2.0 * (0.5e-6f64.powi(2) + s * s))).exp();
                    v *= 1.0 - inside * a - ring * m;
                }
                px[j * w + i] = v.round() as u16;
            }
        }
        (px, w, h)
    }

    fn find(discs: &[(f64, f64, f64, f64, f64)]) -> Vec<Blob> {
        let (px, w, h) = image(discs);
        detect(&px, w, h, &[], &Options::for_pixel_size(PS)).unwrap()
    }

    fn cells(b: &[Blob]) -> Vec<Blob> {
        b.iter().filter(|b| b.kind == Kind::Cell).copied().collect()
    }

    #[test]
    fn a_cell_is_found_at_its_centre_with_its_diameter() {
        let b = find(&[(150e-6, 120e-6, 20e-6, 0.10, 0.32)]);
        let c = cells(&b);
        assert_eq!(c.len(), 1, "{b:?}");
        let (x, y) = (c[0].x * PS, c[0].y * PS);
        assert!((x - 150e-6).hypot(y - 120e-6) < 0.2e-6, "{c:?}");
        assert!((c[0].diameter - 20e-6).abs() < 1e-6, "{c:?}");
    }

    #[test]
    fn debris_is_not_a_cell() {
        let b = find(&[
            (100e-6, 100e-6, 6e-6, 0.7, 0.0),
            (250e-6, 150e-6, 14e-6, 0.6, 0.0),
        ]);
        assert!(cells(&b).is_empty(), "{b:?}");
        assert_eq!(b.len(), 2, "{b:?}");
    }

    #[test]
    fn touching_cells_are_split_even_when_unequal() {
        for (d1, d2) in [(16e-6, 16e-6), (16.2e-6, 10.2e-6), (24e-6, 12e-6)] {
            let (x1, y1) = (150e-6, 120e-6);
            let a = 0.7f64;
            let sep = 0.5 * (d1 + d2);
            let (x2, y2) = (x1 + sep * a.cos(), y1 + sep * a.sin());
            let b = find(&[(x1, y1, d1, 0.10, 0.32), (x2, y2, d2, 0.10, 0.32)]);
            let c = cells(&b);
            assert_eq!(c.len(), 2, "{d1} {d2}: {b:?}");
            for (x, y) in [(x1, y1), (x2, y2)] {
                let e = c
                    .iter()
                    .map(|b| (b.x * PS - x).hypot(b.y * PS - y))
                    .fold(f64::INFINITY, f64::min);
                assert!(e < 1.0e-6, "{d1} {d2}: error {e} {c:?}");
            }
        }
    }

    #[test]
    fn bad_sizes_and_options_are_errors() {
        assert!(matches!(
            detect(&[0; 10], 3, 3, &[], &Options::for_pixel_size(PS)),
            Err(CellsError::Size { .. })
        ));
        let mut o = Options::for_pixel_size(PS);
        o.threshold = f64::NAN;
        assert!(detect(&[0; 9], 3, 3, &[], &o).is_err());
    }

    /// A 10 µm cell touching a 22-30 µm one, at seven angles (issue 36: such partners
    /// were measured 8.1-8.6 µm, by the darkest quarter-pixel ring of a few pixels):
    /// both sized within 1 µm of the drawn discs; a cell alone of 10-30 µm within
    /// 0.5 µm.
    #[test]
    fn a_small_cell_touching_a_large_one_is_sized_on_its_own_ring() {
        for a in [0.0f64, 0.7, 1.6, 2.5, 3.1, 4.0, 5.5] {
            for (d1, d2) in [(26e-6, 10e-6), (22e-6, 10e-6), (30e-6, 10e-6)] {
                let (x1, y1) = (150e-6 + 0.3e-6 * a, 120e-6 - 0.2e-6 * a);
                let sep = 0.5 * (d1 + d2);
                let (x2, y2) = (x1 + sep * a.cos(), y1 + sep * a.sin());
                let c = cells(&find(&[(x1, y1, d1, 0.10, 0.32), (x2, y2, d2, 0.10, 0.32)]));
                assert_eq!(c.len(), 2, "{a} {d1}: {c:?}");
                for (x, y, d) in [(x1, y1, d1), (x2, y2, d2)] {
                    let b = c
                        .iter()
                        .min_by(|p, q| {
                            let e = |b: &&Blob| (b.x * PS - x).hypot(b.y * PS - y);
                            e(p).total_cmp(&e(q))
                        })
                        .unwrap();
                    assert!(
                        (b.diameter - d).abs() < 1e-6,
                        "angle {a}: the {} um cell measured {} um",
                        d * 1e6,
                        b.diameter * 1e6
                    );
                }
            }
        }
        for d in [10e-6, 15e-6, 20e-6, 25e-6, 30e-6] {
            let c = cells(&find(&[(150.3e-6, 120.2e-6, d, 0.10, 0.32)]));
            assert!((c[0].diameter - d).abs() < 0.5e-6, "{d}: {c:?}");
            // Its quarters agree: the size is known.
            assert!(c[0].diameter_se.unwrap() < 0.1e-6, "{d}: {c:?}");
        }
    }
}
