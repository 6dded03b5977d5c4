//! B-spline interpolation of degree 3 (cubic) or 5 (quintic) with the recursive
//! prefilter (Unser, Aldroubi & Eden, IEEE TSP 1993; Unser, "Splines: a perfect fit",
//! IEEE SP Mag. 1999; Thévenaz, Blu & Unser, "Interpolation revisited", IEEE TMI 19,
//! 2000): the coefficients `c` are computed so that the spline `Σ c_k βⁿ(x − k)` passes
//! through every pixel exactly; values and gradients anywhere come from the same
//! spline. Mirror-symmetric boundaries.
//!
//! Field and point mode use the quintic spline (the tracker, at camera rate, and
//! [`BSpline::new`] keep the cubic): its interpolation error on a sinusoid falls as
//! ω⁶ instead of ω⁴, which divides the position bias of a subset match (the phase
//! error of the interpolant, largest at fractional offsets near ¼ and ¾) by about 4 at
//! a quarter of the Nyquist frequency and by about 2 near half of it (Schreier,
//! Braasch & Sutton, Opt. Eng. 39, 2000, on the bias of spline degrees in DIC), at the
//! price of 6 × 6 taps per value instead of 4 × 4.

use std::sync::OnceLock;

use crate::image::Image;
use crate::warp::{Lane, Rows};

/// Degree of the B-spline interpolant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Degree {
    /// Degree 3: one prefilter pole, `√3 − 2`; 4 × 4 taps. The default, used by the
    /// tracker at camera rate ([`crate::track`]).
    #[default]
    Cubic,
    /// Degree 5: two prefilter poles; 6 × 6 taps. Used by field and point mode.
    Quintic,
}

/// Number of taps per axis of the widest kernel (quintic): offsets −2..=+3 from the
/// integer part. The cubic kernel uses the middle four (−1..=+2) and zero weights at
/// the ends.
pub const TAPS: usize = 6;

const SIXTH: f64 = 1.0 / 6.0;

impl Degree {
    /// The poles of the prefilter (Unser 1999, Table I; Thévenaz et al. 2000).
    fn poles(self) -> &'static [f64] {
        match self {
            Degree::Cubic => &[-0.267_949_192_431_122_7],
            Degree::Quintic => &[-0.430_575_347_099_973, -0.043_096_288_203_264_7],
        }
    }

    /// Weights of the taps at offsets −2..=+3 from the integer part, for the fractional
    /// offset `t` ∈ [0, 1): `βⁿ(t − k)`.
    #[inline]
    pub fn weights(self, t: f64) -> [f64; TAPS] {
        match self {
            Degree::Cubic => {
                let t2 = t * t;
                let t3 = t2 * t;
                let u = 1.0 - t;
                let w0 = u * u * u * SIXTH;
                let w3 = t3 * SIXTH;
                let w1 = 0.5 * t3 - t2 + 4.0 * SIXTH;
                [0.0, w0, w1, 1.0 - w0 - w1 - w3, w3, 0.0]
            }
            Degree::Quintic => {
                // Thévenaz et al. (2000), the published factorisation.
                let mut w = t;
                let mut w2 = w * w;
                let w5 = (1.0 / 120.0) * w * w2 * w2;
                w2 -= w;
                let w4 = w2 * w2;
                w -= 0.5;
                let tt = w2 * (w2 - 3.0);
                let w0 = (1.0 / 24.0) * (1.0 / 5.0 + w2 + w4) - w5;
                let t0 = (1.0 / 24.0) * (w2 * (w2 - 5.0) + 46.0 / 5.0);
                let t1 = (-1.0 / 12.0) * w * (tt + 4.0);
                let (w2_, w3_) = (t0 + t1, t0 - t1);
                let t0 = (1.0 / 16.0) * (9.0 / 5.0 - tt);
                let t1 = (1.0 / 24.0) * w * (w4 - w2 - 5.0);
                [w0, t0 + t1, w2_, w3_, t0 - t1, w5]
            }
        }
    }

    /// Derivatives of [`Degree::weights`] with respect to `t`.
    #[inline]
    pub fn weights_derivative(self, t: f64) -> [f64; TAPS] {
        match self {
            Degree::Cubic => {
                let t2 = t * t;
                let u = 1.0 - t;
                [
                    0.0,
                    -0.5 * u * u,
                    1.5 * t2 - 2.0 * t,
                    -1.5 * t2 + t + 0.5,
                    0.5 * t2,
                    0.0,
                ]
            }
            Degree::Quintic => std::array::from_fn(|j| quintic_derivative(t - (j as f64 - 2.0))),
        }
    }

    /// Response of the kernel sampled at the integers, `Σ βⁿ(k) cos kω` (the inverse
    /// of the prefilter's gain).
    pub fn sampled_response(self, w: f64) -> f64 {
        match self {
            Degree::Cubic => (4.0 + 2.0 * w.cos()) / 6.0,
            Degree::Quintic => (66.0 + 52.0 * w.cos() + 2.0 * (2.0 * w).cos()) / 120.0,
        }
    }

    /// Gain of the spline's derivative at the pixels relative to the exact `iω`:
    /// for the cubic `(c₊₁ − c₋₁)/2`, for the quintic
    /// `5(c₊₁ − c₋₁)/12 + (c₊₂ − c₋₂)/24` of the prefiltered coefficients.
    pub fn derivative_gain(self, w: f64) -> f64 {
        let d = match self {
            Degree::Cubic => w.sin(),
            Degree::Quintic => (5.0 / 6.0) * w.sin() + (1.0 / 12.0) * (2.0 * w).sin(),
        };
        d / (w * self.sampled_response(w))
    }

    /// White-noise gain of the spline derivative at the pixels: the variance of ∂f/∂x
    /// when f is white noise of unit variance, `(1/π)∫₀^π |ω·derivative_gain(ω)|² dω`:
    /// `6√3 − 9` for the cubic, 1.8940 for the quintic (numerically).
    pub fn derivative_noise_gain(self) -> f64 {
        match self {
            Degree::Cubic => 1.392_304_845_413_264,
            Degree::Quintic => 1.893_960_320_410_752,
        }
    }

    /// How far the kernel reaches from the integer part, pixels (beyond it the
    /// mirrored coefficients are used).
    fn reach(self) -> (isize, isize) {
        match self {
            Degree::Cubic => (1, 2),
            Degree::Quintic => (2, 3),
        }
    }
}

/// `β⁵′(x)`: the derivative of the quintic B-spline.
#[inline]
fn quintic_derivative(x: f64) -> f64 {
    let (a, s) = (x.abs(), x.signum());
    let a2 = a * a;
    if a < 1.0 {
        s * (-a + a2 * a - (5.0 / 12.0) * a2 * a2)
    } else if a < 2.0 {
        s * (5.0 / 8.0 - 3.5 * a + 3.75 * a2 - 1.5 * a2 * a + (5.0 / 24.0) * a2 * a2)
    } else if a < 3.0 {
        let u = 3.0 - a;
        -s * u * u * u * u / 24.0
    } else {
        0.0
    }
}

/// Spline coefficients of an image (same size; mirror boundary conditions).
#[derive(Debug, Clone)]
pub struct BSpline {
    width: usize,
    height: usize,
    c: Vec<f64>,
    /// `c` in single precision, for [`BSpline::warped_block_with`] (made when first
    /// asked for).
    c32: OnceLock<Vec<f32>>,
    /// Offset of the image origin inside a larger image (for local windows).
    origin: (f64, f64),
    degree: Degree,
}

/// In-place causal/anticausal recursion of one pole `z` along a line of `n` samples
/// with stride `s` (the overall gain is applied by the caller): one line alone, the
/// reference the side-by-side [`Columns`] is tested against.
#[cfg(test)]
fn prefilter_line(d: &mut [f64], start: usize, n: usize, s: usize, z: f64) {
    if n < 2 {
        return;
    }
    // Causal initialisation (mirror boundary): a sum truncated at machine precision when
    // the line is long enough, the exact mirrored sum otherwise (Unser 1999).
    let horizon = (f64::EPSILON.ln() / z.abs().ln()).ceil() as usize;
    if horizon < n {
        let mut zn = z;
        let mut sum = d[start];
        for k in 1..horizon {
            sum += zn * d[start + k * s];
            zn *= z;
        }
        d[start] = sum;
    } else {
        let iz = 1.0 / z;
        let mut zn = z;
        let mut z2n = z.powi(n as i32 - 1);
        let mut sum = d[start] + z2n * d[start + (n - 1) * s];
        z2n = z2n * z2n * iz;
        for k in 1..n - 1 {
            sum += (zn + z2n) * d[start + k * s];
            zn *= z;
            z2n *= iz;
        }
        d[start] = sum / (1.0 - zn * zn);
    }
    for k in 1..n {
        d[start + k * s] += z * d[start + (k - 1) * s];
    }
    // Anticausal initialisation.
    let last = start + (n - 1) * s;
    d[last] = (z / (z * z - 1.0)) * (z * d[start + (n - 2) * s] + d[last]);
    for k in (0..n - 1).rev() {
        d[start + k * s] = z * (d[start + (k + 1) * s] - d[start + k * s]);
    }
}

/// `dst[x] = Σ_i w_i·lines_i[x]`, the sum in the order of i, written once: a vector
/// of outputs at a time, its six products summed in registers ([`Separable`]'s
/// passes along x, with `lines_i` the padded row shifted by i, and along y).
#[inline(always)]
fn weighted_lines(dst: &mut [f64], w: &[f64; TAPS], lines: &[&[f64]; TAPS]) {
    let whole = dst.len() / SEPARABLE_CHUNK * SEPARABLE_CHUNK;
    for (k, d) in dst[..whole].chunks_exact_mut(SEPARABLE_CHUNK).enumerate() {
        let at = k * SEPARABLE_CHUNK;
        let mut acc = [0.0; SEPARABLE_CHUNK];
        for (wi, line) in w.iter().zip(lines) {
            let v: &[f64; SEPARABLE_CHUNK] = line[at..at + SEPARABLE_CHUNK]
                .try_into()
                .expect("SEPARABLE_CHUNK values");
            for l in 0..SEPARABLE_CHUNK {
                acc[l] += wi * v[l];
            }
        }
        d.copy_from_slice(&acc);
    }
    for (x, d) in dst.iter_mut().enumerate().skip(whole) {
        *d = w
            .iter()
            .zip(lines)
            .fold(0.0, |a, (wi, line)| a + wi * line[x]);
    }
}

/// [`BSpline::separable`] compiled for the machine's vector units: each row filtered
/// along x (mirror-padded), then each output row from six of them, both by
/// [`weighted_lines`]. It writes the output's rows `y0..` into `out` (a band of whole
/// rows: the bands of a large image are made in parallel).
struct Separable<'a> {
    c: &'a [f64],
    w: usize,
    h: usize,
    shift: isize,
    wx: &'a [f64; TAPS],
    wy: &'a [f64; TAPS],
    y0: usize,
    out: &'a mut [f64],
}

impl pulp::WithSimd for Separable<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> Self::Output {
        let Separable {
            c,
            w,
            h,
            shift,
            wx,
            wy,
            y0,
            out,
        } = self;
        // Tap i of output m reads m + shift − 2 + i: the padded row starts at
        // −(TAPS − 1) so that every index is non-negative.
        let pad = TAPS as isize - 1;
        let mut ext = vec![0.0; w + 2 * pad as usize];
        // The rows filtered along x, made as the output first needs them, in
        // [`ROW_SLOTS`] slots (row r in slot r mod ROW_SLOTS): an output row reads
        // six rows within a window of six (mirrored at the edges), so a row is made
        // once and stays until the window has passed it; no image-sized temporary.
        let mut rows = vec![0.0; ROW_SLOTS * w];
        let mut held = [usize::MAX; ROW_SLOTS];
        for (y, dst) in out.chunks_exact_mut(w).enumerate() {
            let y = y0 + y;
            let need: [usize; TAPS] =
                std::array::from_fn(|j| mirror(y as isize + shift - 2 + j as isize, h));
            for &r in &need {
                let slot = r % ROW_SLOTS;
                if held[slot] == r {
                    continue;
                }
                held[slot] = r;
                let src = &c[r * w..(r + 1) * w];
                let row = &mut rows[slot * w..(slot + 1) * w];
                let p = pad as usize;
                ext[p..p + w].copy_from_slice(src);
                for i in (0..p).chain(p + w..w + 2 * p) {
                    ext[i] = src[mirror(i as isize - pad, w)];
                }
                let from = (pad + shift - 2) as usize;
                let taps: [&[f64]; TAPS] = std::array::from_fn(|i| &ext[from + i..from + i + w]);
                weighted_lines(row, wx, &taps);
            }
            // `out` is fresh zeroed memory, written once and never read first: a read
            // before the first write maps the shared zero page, whose replacement at
            // the write costs every other core a TLB flush (an inter-processor
            // interrupt per page, a third of a step-10 field's time).
            let src: [&[f64]; TAPS] = std::array::from_fn(|j| {
                let slot = need[j] % ROW_SLOTS;
                &rows[slot * w..(slot + 1) * w]
            });
            weighted_lines(dst, wy, &src);
        }
    }
}

/// Slots of [`Separable`]'s x-filtered rows: twice the rows one output row reads, so
/// that the rows of one output never share a slot.
const ROW_SLOTS: usize = 2 * TAPS;

/// A `w x h` row-major array transposed (`h x w`).
///
/// In blocks of [`TILE`] x [`TILE`], each read as [`TILE`] rows and written as
/// [`TILE`] columns through fixed-size arrays the compiler turns into vector
/// shuffles (compiled for the machine's vector units); the edges that do not fill a
/// block one value at a time. Row by row with an index per value, the transposes of
/// the splines' row prefilter took three times as long as the prefilter itself.
pub(crate) fn transpose(a: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mut out = vec![0.0; w * h];
    transpose_into(a, w, h, &mut out);
    out
}

/// [`transpose`] into `out` (`w·h` values, each overwritten): no allocation.
pub(crate) fn transpose_into(a: &[f64], w: usize, h: usize, out: &mut [f64]) {
    pulp::Arch::new().dispatch(Transpose { a, w, h, out })
}

/// [`transpose`] compiled for the machine's vector units.
struct Transpose<'a> {
    a: &'a [f64],
    w: usize,
    h: usize,
    out: &'a mut [f64],
}

impl pulp::WithSimd for Transpose<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> Self::Output {
        let Transpose { a, w, h, out } = self;
        let out = &mut out[..w * h];
        let (wb, hb) = (w / TILE * TILE, h / TILE * TILE);
        for y0 in (0..hb).step_by(TILE) {
            for x0 in (0..wb).step_by(TILE) {
                let rows: [[f64; TILE]; TILE] = std::array::from_fn(|r| {
                    let at = (y0 + r) * w + x0;
                    a[at..at + TILE].try_into().expect("TILE values")
                });
                for c in 0..TILE {
                    let at = (x0 + c) * h + y0;
                    let col: [f64; TILE] = std::array::from_fn(|r| rows[r][c]);
                    out[at..at + TILE].copy_from_slice(&col);
                }
            }
        }
        // The right edge (columns wb.., every row) and the bottom one (rows hb..).
        for y in 0..h {
            let xs = if y < hb { wb } else { 0 };
            for x in xs..w {
                out[x * h + y] = a[y * w + x];
            }
        }
    }
}

/// Side of [`transpose`]'s blocks: a vector of f64 on AVX-512.
const TILE: usize = 8;

/// Pixels from which [`BSpline::with_degree`] prefilters the rows in parallel.
const PARALLEL_PIXELS: usize = 1 << 16;

/// Outputs [`weighted_lines`] sums side by side: two vectors of f64 on AVX-512.
const SEPARABLE_CHUNK: usize = 16;

/// Output rows per band of [`BSpline::separable`] on a large image: each band
/// filters the five rows around it again along x, 8 % more work, for bands that
/// share out over the threads.
const SEPARABLE_BAND: usize = 64;

/// Rows [`BSpline::with_degree`] prefilters side by side on a large image: two
/// vectors wide, and a group of 512-pixel rows fits the first-level cache.
const ROW_GROUP: usize = 16;

/// The B-spline prefilter (its causal and anticausal recursions) along every column
/// of a `w x h` row-major array at once: each step of the recursions applied to a
/// whole row, so that the columns sit side by side in the vector registers instead
/// of a stride apart in memory.
struct Columns<'a> {
    c: &'a mut [f64],
    w: usize,
    h: usize,
    degree: Degree,
}

impl pulp::WithSimd for Columns<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> Self::Output {
        let Columns { c, w, h, degree } = self;
        if h < 2 {
            return;
        }
        let gain: f64 = degree
            .poles()
            .iter()
            .map(|z| (1.0 - z) * (1.0 - 1.0 / z))
            .product();
        for v in c.iter_mut() {
            *v *= gain;
        }
        let mut first = vec![0.0; w];
        for &z in degree.poles() {
            // Causal initialisation (as `prefilter_line`).
            let horizon = (f64::EPSILON.ln() / z.abs().ln()).ceil() as usize;
            if horizon < h {
                first.copy_from_slice(&c[..w]);
                let mut zn = z;
                for k in 1..horizon {
                    for (f, v) in first.iter_mut().zip(&c[k * w..(k + 1) * w]) {
                        *f += zn * v;
                    }
                    zn *= z;
                }
            } else {
                let iz = 1.0 / z;
                let mut zn = z;
                let mut z2n = z.powi(h as i32 - 1);
                for ((f, a), b) in first.iter_mut().zip(&c[..w]).zip(&c[(h - 1) * w..h * w]) {
                    *f = a + z2n * b;
                }
                z2n = z2n * z2n * iz;
                for k in 1..h - 1 {
                    for (f, v) in first.iter_mut().zip(&c[k * w..(k + 1) * w]) {
                        *f += (zn + z2n) * v;
                    }
                    zn *= z;
                    z2n *= iz;
                }
                let norm = 1.0 - zn * zn;
                for f in first.iter_mut() {
                    *f /= norm;
                }
            }
            c[..w].copy_from_slice(&first);
            for k in 1..h {
                let (done, rest) = c.split_at_mut(k * w);
                let prev = &done[(k - 1) * w..];
                for (v, p) in rest[..w].iter_mut().zip(prev) {
                    *v += z * p;
                }
            }
            // Anticausal initialisation.
            let a = z / (z * z - 1.0);
            {
                let (head, last) = c.split_at_mut((h - 1) * w);
                let before = &head[(h - 2) * w..];
                for (l, b) in last.iter_mut().zip(before) {
                    *l = a * (z * b + *l);
                }
            }
            for k in (0..h - 1).rev() {
                let (head, tail) = c.split_at_mut((k + 1) * w);
                let next = &tail[..w];
                for (v, n) in head[k * w..].iter_mut().zip(next) {
                    *v = z * (n - *v);
                }
            }
        }
    }
}

/// All the poles of `degree` along one line, with the overall gain.
#[cfg(test)]
fn prefilter(d: &mut [f64], start: usize, n: usize, s: usize, degree: Degree) {
    if n < 2 {
        return;
    }
    let gain: f64 = degree
        .poles()
        .iter()
        .map(|z| (1.0 - z) * (1.0 - 1.0 / z))
        .product();
    for k in 0..n {
        d[start + k * s] *= gain;
    }
    for &z in degree.poles() {
        prefilter_line(d, start, n, s, z);
    }
}

/// The B-spline prefilter along each of the lines of `n` samples stored back to back
/// in `d`: side by side in the vector registers (the lines are the columns of the
/// transpose), where one line alone waits on each step of the recursion.
pub(crate) fn prefilter_lines(d: &mut [f64], n: usize, degree: Degree) {
    let mut t = Vec::new();
    prefilter_lines_in(d, n, degree, &mut t);
}

/// [`prefilter_lines`] with `t` as the transpose's buffer (resized; its contents
/// are overwritten): no allocation once it is large enough.
pub(crate) fn prefilter_lines_in(d: &mut [f64], n: usize, degree: Degree, t: &mut Vec<f64>) {
    if n == 0 {
        return;
    }
    let count = d.len() / n;
    let d = &mut d[..count * n];
    t.resize(count * n, 0.0);
    transpose_into(d, n, count, t);
    pulp::Arch::new().dispatch(Columns {
        c: &mut t[..],
        w: count,
        h: n,
        degree,
    });
    transpose_into(t, count, n, d);
}

/// `floor` without a library call (baseline x86-64 has no rounding instruction).
#[inline]
fn fast_floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}

#[inline]
pub(crate) fn mirror(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n == 1 {
        return 0;
    }
    let period = 2 * n - 2;
    let mut m = i.rem_euclid(period);
    if m >= n {
        m = period - m;
    }
    m as usize
}

impl BSpline {
    /// Coefficients of a whole image, with the default (cubic) spline.
    pub fn new(img: &Image) -> Self {
        BSpline::with_degree(img, Degree::default())
    }

    /// Coefficients of a whole image for a spline of the given degree.
    pub fn with_degree(img: &Image, degree: Degree) -> Self {
        BSpline::from_values(img.width(), img.height(), img.data().to_vec(), degree)
    }

    /// [`BSpline::with_degree`] of the `w x h` row-major values `c`, prefiltered in
    /// place (no copy of an image the caller no longer needs). The caller checks the
    /// values are finite and fill `w x h`, as [`Image::new`] does.
    pub(crate) fn from_values(w: usize, h: usize, mut c: Vec<f64>, degree: Degree) -> Self {
        debug_assert_eq!(c.len(), w * h);
        // The rows side by side ([`prefilter_lines`]): on a large image
        // [`ROW_GROUP`] at a time, the groups in parallel (a small one, such as a
        // tracked window, stays on its thread).
        if w * h >= PARALLEL_PIXELS {
            use rayon::prelude::*;
            c.par_chunks_mut(ROW_GROUP * w)
                .for_each(|rows| prefilter_lines(rows, w, degree));
        } else {
            prefilter_lines(&mut c, w, degree);
        }
        BSpline::from_filtered_rows(w, h, c, degree)
    }

    /// [`BSpline::from_values`] of a small array (a window of a subset, prefiltered
    /// on this thread), with `t` as the buffer of the rows' transpose: no
    /// allocation once `t` is large enough.
    pub(crate) fn from_values_in(
        w: usize,
        h: usize,
        mut c: Vec<f64>,
        degree: Degree,
        t: &mut Vec<f64>,
    ) -> Self {
        debug_assert_eq!(c.len(), w * h);
        prefilter_lines_in(&mut c, w, degree, t);
        BSpline::from_filtered_rows(w, h, c, degree)
    }

    /// The spline of values whose rows are already prefiltered: the columns next.
    fn from_filtered_rows(w: usize, h: usize, mut c: Vec<f64>, degree: Degree) -> Self {
        pulp::Arch::new().dispatch(Columns {
            c: &mut c,
            w,
            h,
            degree,
        });
        BSpline {
            width: w,
            height: h,
            c,
            c32: OnceLock::new(),
            origin: (0.0, 0.0),
            degree,
        }
    }

    /// The coefficients' buffer, for reuse (its contents are the coefficients).
    pub(crate) fn into_coefficients(self) -> Vec<f64> {
        self.c
    }

    /// Width of the image, pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height of the image, pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Makes the single-precision coefficients the warps of a measurement read
    /// ([`BSpline::warped_block_with`]) now, rather than in the first match, which
    /// the other threads' first matches would wait for.
    pub(crate) fn prepare_single(&self) {
        self.single();
    }

    /// The coefficients in single precision, made when first needed.
    fn single(&self) -> &[f32] {
        self.c32
            .get_or_init(|| self.c.iter().map(|&v| v as f32).collect())
    }

    /// The spline's degree.
    pub fn degree(&self) -> Degree {
        self.degree
    }

    /// Coefficients of the window `[x0, x0 + w) x [y0, y0 + h)` of `img`, addressed in
    /// the coordinates of the whole image (for tracking a region without filtering the
    /// whole frame).
    pub fn window(img: &Image, x0: usize, y0: usize, w: usize, h: usize) -> Self {
        let crop = img.crop(x0, y0, w, h);
        let mut s = BSpline::new(&crop);
        s.origin = (x0 as f64, y0 as f64);
        s
    }

    /// Moves the coordinate origin by (dx, dy): the spline is then addressed in a frame
    /// whose origin sits at (−dx, −dy) of the current one.
    pub fn shift_origin(&mut self, dx: f64, dy: f64) {
        self.origin.0 += dx;
        self.origin.1 += dy;
    }

    /// Whether (x, y), in image coordinates, lies where the spline is defined away from
    /// the mirrored border by `margin` pixels.
    #[inline]
    pub fn contains(&self, x: f64, y: f64, margin: f64) -> bool {
        let (x, y) = (x - self.origin.0, y - self.origin.1);
        x >= margin
            && y >= margin
            && x <= self.width as f64 - 1.0 - margin
            && y <= self.height as f64 - 1.0 - margin
    }

    #[inline]
    fn coef(&self, x: isize, y: isize) -> f64 {
        self.c[mirror(y, self.height) * self.width + mirror(x, self.width)]
    }

    #[inline]
    fn split(&self, x: f64, y: f64) -> (isize, isize, f64, f64) {
        let (x, y) = (x - self.origin.0, y - self.origin.1);
        let (fx, fy) = (fast_floor(x), fast_floor(y));
        (fx as isize, fy as isize, x - fx, y - fy)
    }

    /// The interpolated value at (x, y).
    #[inline(always)]
    pub fn value(&self, x: f64, y: f64) -> f64 {
        let (ix, iy, tx, ty) = self.split(x, y);
        self.combine(ix, iy, &self.degree.weights(tx), &self.degree.weights(ty))
    }

    /// The value at the integer node (fx, fy), image coordinates, plus a fractional
    /// offset whose weights `wx`, `wy` the caller computed once (translation warps).
    #[inline]
    pub fn value_with(&self, fx: f64, fy: f64, wx: &[f64; TAPS], wy: &[f64; TAPS]) -> f64 {
        let ix = (fx - self.origin.0) as isize;
        let iy = (fy - self.origin.1) as isize;
        self.combine(ix, iy, wx, wy)
    }

    /// The values at `(fx + dx, fy + dy)` for `dy` in `−hh..=hh` (outer) and `dx` in
    /// `−hw..=hw` (inner), for one fractional offset whose weights are `wx`, `wy`
    /// (a translated subset), written into `out`. Separable: two passes of six taps
    /// instead of thirty-six products per value; `tmp` is scratch. Inlined, so that
    /// it is compiled for the vector units of the caller's context (a measurement).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub fn translated_block(
        &self,
        fx: f64,
        fy: f64,
        hw: usize,
        hh: usize,
        wx: &[f64; TAPS],
        wy: &[f64; TAPS],
        tmp: &mut Vec<f64>,
        out: &mut Vec<f64>,
    ) {
        let (nw, nh) = (2 * hw + 1, 2 * hh + 1);
        let ix0 = (fx - self.origin.0) as isize - hw as isize;
        let iy0 = (fy - self.origin.1) as isize - hh as isize;
        let inner = ix0 >= 2
            && iy0 >= 2
            && ix0 + nw as isize + 3 <= self.width as isize
            && iy0 + nh as isize + 3 <= self.height as isize;
        // The rows filtered along x, then room for one row of coefficients (every
        // value read is written first: resized, not cleared).
        tmp.resize((nh + TAPS - 1) * nw + nw + TAPS - 1, 0.0);
        let (rows, edge) = tmp.split_at_mut((nh + TAPS - 1) * nw);
        // A block reaching past an edge reads its rows' coefficients through the
        // mirror, then is filtered as an inner one (the same sums in the same order
        // as `combine` at each pixel).
        for r in 0..nh + TAPS - 1 {
            let src = if inner {
                let base = (iy0 as usize - 2 + r) * self.width + ix0 as usize - 2;
                &self.c[base..base + nw + TAPS - 1]
            } else {
                let y = iy0 - 2 + r as isize;
                for (i, e) in edge.iter_mut().enumerate() {
                    *e = self.coef(ix0 - 2 + i as isize, y);
                }
                &edge[..]
            };
            let dst = &mut rows[r * nw..(r + 1) * nw];
            for (i, d) in dst.iter_mut().enumerate() {
                let s = &src[i..i + TAPS];
                *d = wx[0] * s[0]
                    + wx[1] * s[1]
                    + wx[2] * s[2]
                    + wx[3] * s[3]
                    + wx[4] * s[4]
                    + wx[5] * s[5];
            }
        }
        // Every value is written: resized, not cleared.
        out.resize(nw * nh, 0.0);
        for (j, dst) in out.chunks_exact_mut(nw).enumerate() {
            let rows: [&[f64]; TAPS] =
                std::array::from_fn(|k| &tmp[(j + k) * nw..(j + k + 1) * nw]);
            for (i, d) in dst.iter_mut().enumerate() {
                *d = wy[0] * rows[0][i]
                    + wy[1] * rows[1][i]
                    + wy[2] * rows[2][i]
                    + wy[3] * rows[3][i]
                    + wy[4] * rows[4][i]
                    + wy[5] * rows[5][i];
            }
        }
    }

    /// The values at the affinely warped rectangle of `2·hw + 1` by `2·hh + 1` pixels:
    /// subset pixel (dx, dy), dx in `−hw..=hw` (inner), dy in `−hh..=hh` (outer), at
    /// `(xc + dx + p₀ + p₁·dx + p₂·dy, yc + dy + p₃ + p₄·dx + p₅·dy)`, image
    /// coordinates, written into `out` (resized). `false`, `out` unspecified, when a
    /// corner of the warped rectangle lies closer than `margin` pixels to the edge
    /// ([`BSpline::contains`]). An affine warp's extremes are its corners, so the
    /// corners alone decide whether every tap lies inside: then the values are read
    /// without the mirror, in a loop compiled for the machine's vector units (AVX2
    /// and FMA where present, chosen at run time); otherwise pixel by pixel.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub fn warped_block(
        &self,
        xc: f64,
        yc: f64,
        hw: usize,
        hh: usize,
        p: &[f64; 6],
        margin: f64,
        out: &mut Vec<f64>,
    ) -> bool {
        self.warped_block_with(xc, yc, hw, hh, p, margin, false, out)
    }

    /// [`BSpline::warped_block`], in single precision where `single` (and the image is
    /// at least 16 pixels wide): twice the lanes, the values within `5e-6·max|c|` of
    /// double precision's (`crate::warp::SINGLE_PRECISION_TOLERANCE` says where the
    /// iteration may use it).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub fn warped_block_with(
        &self,
        xc: f64,
        yc: f64,
        hw: usize,
        hh: usize,
        p: &[f64; 6],
        margin: f64,
        single: bool,
        out: &mut Vec<f64>,
    ) -> bool {
        let (nw, nh) = (2 * hw + 1, 2 * hh + 1);
        let (hwf, hhf) = (hw as f64, hh as f64);
        let corners = warped_corners(xc, yc, hw, hh, p);
        if !corners.iter().all(|&(x, y)| self.contains(x, y, margin)) {
            return false;
        }
        out.clear();
        out.resize(nw * nh, 0.0);
        // Taps from the floor − 2 to the floor + 3 along both axes, for both degrees
        // (the cubic's outer weights are zero).
        let (w, h) = (self.width as f64, self.height as f64);
        let inner = corners.iter().all(|&(x, y)| {
            let (x, y) = (x - self.origin.0, y - self.origin.1);
            x >= 2.0 && y >= 2.0 && x < w - 4.0 && y < h - 4.0
        });
        if !inner {
            for (k, o) in out.iter_mut().enumerate() {
                let (dx, dy) = ((k % nw) as f64 - hwf, (k / nw) as f64 - hhf);
                *o = self.value(
                    xc + dx + p[0] + p[1] * dx + p[2] * dy,
                    yc + dy + p[3] + p[4] * dx + p[5] * dy,
                );
            }
            return true;
        }
        let x0 = xc - self.origin.0 + p[0] - hwf * (1.0 + p[1]);
        let y0 = yc - self.origin.1 + p[3] - hwf * p[4];
        // A vector read past a run's last tap runs `lanes − 2` values into the row
        // after (see `Rows::rows`): 14 of them in single precision.
        if single && self.width >= 16 {
            self.dispatch_rows(self.single(), (x0, y0), p, hhf, nw, out);
        } else {
            self.dispatch_rows(&self.c, (x0, y0), p, hhf, nw, out);
        }
        true
    }

    /// The vectorised rows of [`BSpline::warped_block_with`] on coefficients `c` (this
    /// spline's, in their precision).
    #[inline(always)]
    fn dispatch_rows<T: Lane>(
        &self,
        c: &[T],
        origin: (f64, f64),
        p: &[f64; 6],
        hhf: f64,
        nw: usize,
        out: &mut [f64],
    ) {
        pulp::Arch::new().dispatch(Rows {
            c,
            width: self.width,
            degree: self.degree,
            origin,
            step_x: (1.0 + p[1], p[4]),
            step_y: (p[2], 1.0 + p[5]),
            first_row: -hhf,
            nw,
            out,
        });
    }

    /// The spline's values at every pixel moved by (t, t), `t` in (−1, 1): pixel
    /// (x, y) holds the value at (x + t, y + t), the mirror beyond the edges.
    pub fn translated_image(&self, t: f64) -> Vec<f64> {
        let shift = t.floor();
        let wt = self.degree.weights(t - shift);
        self.separable(shift as isize, &wt, &wt)
    }

    /// The spline's gradient (∂/∂x, ∂/∂y) at every pixel, row-major.
    pub fn node_gradients(&self) -> (Vec<f64>, Vec<f64>) {
        let (w, d) = (
            self.degree.weights(0.0),
            self.degree.weights_derivative(0.0),
        );
        rayon::join(|| self.separable(0, &d, &w), || self.separable(0, &w, &d))
    }

    /// [`BSpline::translated_image`] into `out` (resized to the image; every value
    /// overwritten): a caller making several keeps one buffer, where each fresh
    /// image-sized one costs its pages' first-touch faults (half a pass's time).
    pub(crate) fn translated_image_into(&self, t: f64, out: &mut Vec<f64>) {
        let shift = t.floor();
        let wt = self.degree.weights(t - shift);
        out.resize(self.width * self.height, 0.0);
        self.separable_into(shift as isize, &wt, &wt, out);
    }

    /// [`BSpline::translated_image`] in single precision (each value the double
    /// one rounded), made band by band: no image-sized double-precision temporary.
    pub(crate) fn translated_image_f32(&self, t: f64) -> Vec<f32> {
        let shift = t.floor();
        let wt = self.degree.weights(t - shift);
        let (w, h) = (self.width, self.height);
        let mut out = vec![0.0f32; w * h];
        let band = |y0: usize, rows: &mut [f32], tmp: &mut Vec<f64>| {
            tmp.resize(rows.len(), 0.0);
            self.separable_band(shift as isize, &wt, &wt, y0, tmp);
            for (o, v) in rows.iter_mut().zip(tmp.iter()) {
                *o = *v as f32;
            }
        };
        if w * h >= PARALLEL_PIXELS && w > 0 {
            use rayon::prelude::*;
            out.par_chunks_mut(SEPARABLE_BAND * w)
                .enumerate()
                .for_each_init(Vec::new, |tmp, (b, rows)| {
                    band(b * SEPARABLE_BAND, rows, tmp)
                });
        } else {
            band(0, &mut out, &mut Vec::new());
        }
        out
    }

    /// `Σ_j wy_j Σ_i wx_i c[y + shift − 2 + j][x + shift − 2 + i]` at every pixel
    /// (x, y), the mirror beyond the edges: six taps along the rows, then six along
    /// the columns.
    fn separable(&self, shift: isize, wx: &[f64; TAPS], wy: &[f64; TAPS]) -> Vec<f64> {
        let mut out = vec![0.0; self.width * self.height];
        self.separable_into(shift, wx, wy, &mut out);
        out
    }

    /// [`BSpline::separable`] into `out` (`w·h` values, each overwritten). A large
    /// image in bands of [`SEPARABLE_BAND`] rows, in parallel.
    fn separable_into(&self, shift: isize, wx: &[f64; TAPS], wy: &[f64; TAPS], out: &mut [f64]) {
        let w = self.width;
        if w * self.height >= PARALLEL_PIXELS && w > 0 {
            use rayon::prelude::*;
            out.par_chunks_mut(SEPARABLE_BAND * w)
                .enumerate()
                .for_each(|(b, rows)| self.separable_band(shift, wx, wy, b * SEPARABLE_BAND, rows));
        } else {
            self.separable_band(shift, wx, wy, 0, out);
        }
    }

    /// Rows `y0..` of [`BSpline::separable`], as many as `out` holds.
    fn separable_band(
        &self,
        shift: isize,
        wx: &[f64; TAPS],
        wy: &[f64; TAPS],
        y0: usize,
        out: &mut [f64],
    ) {
        pulp::Arch::new().dispatch(Separable {
            c: &self.c,
            w: self.width,
            h: self.height,
            shift,
            wx,
            wy,
            y0,
            out,
        })
    }

    #[inline(always)]
    fn combine(&self, ix: isize, iy: isize, wx: &[f64; TAPS], wy: &[f64; TAPS]) -> f64 {
        let (lo, hi) = self.degree.reach();
        let inner =
            ix >= lo && iy >= lo && ix + hi < self.width as isize && iy + hi < self.height as isize;
        let mut acc = 0.0;
        match (inner, self.degree) {
            (true, Degree::Cubic) => {
                let base = (iy - 1) as usize * self.width + (ix - 1) as usize;
                for (j, wyj) in wy[1..5].iter().enumerate() {
                    let row = &self.c[base + j * self.width..base + j * self.width + 4];
                    acc +=
                        wyj * (wx[1] * row[0] + wx[2] * row[1] + wx[3] * row[2] + wx[4] * row[3]);
                }
            }
            (true, Degree::Quintic) => {
                let base = (iy - 2) as usize * self.width + (ix - 2) as usize;
                for (j, wyj) in wy.iter().enumerate() {
                    let row = &self.c[base + j * self.width..base + j * self.width + TAPS];
                    acc += wyj
                        * (wx[0] * row[0]
                            + wx[1] * row[1]
                            + wx[2] * row[2]
                            + wx[3] * row[3]
                            + wx[4] * row[4]
                            + wx[5] * row[5]);
                }
            }
            (false, _) => {
                for (j, wyj) in wy.iter().enumerate() {
                    if *wyj == 0.0 {
                        continue;
                    }
                    let mut r = 0.0;
                    for (i, wxi) in wx.iter().enumerate() {
                        if *wxi != 0.0 {
                            r += wxi * self.coef(ix - 2 + i as isize, iy - 2 + j as isize);
                        }
                    }
                    acc += wyj * r;
                }
            }
        }
        acc
    }

    /// The interpolated value and gradient (∂/∂x, ∂/∂y) at (x, y).
    pub fn value_gradient(&self, x: f64, y: f64) -> (f64, f64, f64) {
        let (ix, iy, tx, ty) = self.split(x, y);
        let d = self.degree;
        let (wx, wy) = (d.weights(tx), d.weights(ty));
        let (dx, dy) = (d.weights_derivative(tx), d.weights_derivative(ty));
        let (mut v, mut gx, mut gy) = (0.0, 0.0, 0.0);
        for j in 0..TAPS {
            for i in 0..TAPS {
                let c = self.coef(ix - 2 + i as isize, iy - 2 + j as isize);
                v += wx[i] * wy[j] * c;
                gx += dx[i] * wy[j] * c;
                gy += wx[i] * dy[j] * c;
            }
        }
        (v, gx, gy)
    }
}

/// The corners of the rectangle `2·hw + 1` x `2·hh + 1` centred at (xc, yc), warped by
/// the affine `p` = (u, ∂u/∂x, ∂u/∂y, v, ∂v/∂x, ∂v/∂y): the extremes of the warped
/// rectangle, so it lies `margin` inside a spline ([`BSpline::contains`]) when they do.
#[inline(always)]
pub(crate) fn warped_corners(
    xc: f64,
    yc: f64,
    hw: usize,
    hh: usize,
    p: &[f64; 6],
) -> [(f64, f64); 4] {
    let (hwf, hhf) = (hw as f64, hh as f64);
    [(-hwf, -hhf), (hwf, -hhf), (-hwf, hhf), (hwf, hhf)].map(|(dx, dy)| {
        (
            xc + dx + p[0] + p[1] * dx + p[2] * dy,
            yc + dy + p[3] + p[4] * dx + p[5] * dy,
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn test_image() -> Image {
        let (w, h) = (23, 17);
        let data = (0..w * h)
            .map(|k| {
                let (x, y) = ((k % w) as f64, (k / w) as f64);
                100.0 + 40.0 * (0.7 * x).sin() * (0.45 * y).cos() + 3.0 * x
            })
            .collect();
        Image::new(w, h, data).unwrap()
    }

    #[test]
    fn translated_image_is_the_value_at_the_moved_pixels() {
        // Pixel (x, y) of translated_image(t) against value(x + t, y + t), mirror
        // beyond the edges included: images shorter than the six rows a value reads
        // (the filtered rows' slots then hold mirrored rows), and taller ones.
        for degree in [Degree::Cubic, Degree::Quintic] {
            for (w, h) in [(5usize, 1usize), (4, 3), (9, 7), (31, 40)] {
                let data = (0..w * h)
                    .map(|k| {
                        let (x, y) = ((k % w) as f64, (k / w) as f64);
                        90.0 + 30.0 * (0.9 * x + 0.2).sin() * (0.7 * y).cos() + 2.0 * y
                    })
                    .collect();
                let spline = BSpline::with_degree(&Image::new(w, h, data).unwrap(), degree);
                for t in [-0.7, -0.25, 0.0, 0.4, 0.95] {
                    let moved = spline.translated_image(t);
                    for (k, m) in moved.iter().enumerate() {
                        let (x, y) = ((k % w) as f64, (k / w) as f64);
                        let v = spline.value(x + t, y + t);
                        assert!(
                            (m - v).abs() <= 1e-11 * v.abs(),
                            "{degree:?} {w} x {h}, t = {t}, pixel ({x}, {y}): {m} against {v}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn transpose_in_tiles_is_the_transpose() {
        // Sizes below, at and across the tile, and a single row and column.
        for (w, h) in [
            (1usize, 1usize),
            (1, 37),
            (37, 1),
            (16, 16),
            (17, 33),
            (50, 21),
        ] {
            let a: Vec<f64> = (0..w * h).map(|k| k as f64).collect();
            let t = transpose(&a, w, h);
            for y in 0..h {
                for x in 0..w {
                    assert_eq!(t[x * h + y], a[y * w + x], "{w} x {h} at ({x}, {y})");
                }
            }
        }
    }

    /// A warped value `o` against the scalar `v`: to rounding in double precision,
    /// within `5e-6·largest` in single (see `warped_block_agrees_with_value`).
    fn agrees(o: f64, v: f64, single: bool, largest: f64, what: impl Fn() -> String) {
        let bound = if single {
            5e-6 * largest
        } else {
            1e-11 * v.abs()
        };
        assert!((o - v).abs() <= bound, "{}: {o} against {v}", what());
    }

    #[test]
    fn warped_block_agrees_with_value() {
        // The vectorised rows (lanes over pixels, masked tails, runs cut where the
        // floor moves) against the scalar value at each warped pixel, for both
        // degrees, a pure translation, small and large strains and a rotation, and
        // subset widths below, at and above a vector's lanes.
        let (w, h) = (96, 80);
        let data = (0..w * h)
            .map(|k| {
                let (x, y) = ((k % w) as f64, (k / w) as f64);
                100.0 + 40.0 * (0.37 * x).sin() * (0.29 * y).cos() + 0.8 * x - 0.3 * y
            })
            .collect();
        let img = Image::new(w, h, data).unwrap();
        let warps: [[f64; 6]; 5] = [
            [0.3, 0.0, 0.0, -0.45, 0.0, 0.0],
            [0.27, 1e-4, -2e-4, 0.61, 3e-4, -1e-4],
            [-1.3, 0.02, -0.015, 2.2, 0.01, 0.03],
            [0.5, -0.08, 0.11, -0.7, 0.09, 0.06],
            [0.0, 0.0087, -0.0872, 0.0, 0.0872, 0.0087],
        ];
        // In single precision each value is a sum of 36 products rounded to f32 and a
        // position rounded to f32 within a run: within some 40·ε₃₂ ≈ 5e-6 of the
        // largest coefficient (the weights are positive and sum to one), the
        // position's rounding adding ε₃₂ times a gradient no larger than it.
        for (degree, single) in [Degree::Cubic, Degree::Quintic]
            .into_iter()
            .flat_map(|d| [(d, false), (d, true)])
        {
            let spline = BSpline::with_degree(&img, degree);
            let largest = spline.c.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let mut out = Vec::new();
            for p in &warps {
                for (hw, hh) in [(0usize, 0usize), (2, 3), (4, 4), (8, 5), (16, 16)] {
                    let (xc, yc) = (47.0, 39.0);
                    assert!(spline.warped_block_with(xc, yc, hw, hh, p, 2.0, single, &mut out));
                    let nw = 2 * hw + 1;
                    for (k, o) in out.iter().enumerate() {
                        let (dx, dy) = ((k % nw) as f64 - hw as f64, (k / nw) as f64 - hh as f64);
                        let v = spline.value(
                            xc + dx + p[0] + p[1] * dx + p[2] * dy,
                            yc + dy + p[3] + p[4] * dx + p[5] * dy,
                        );
                        agrees(*o, v, single, largest, || {
                            format!("{degree:?} single {single} {p:?} {hw}x{hh} pixel {k}")
                        });
                    }
                }
            }
        }
    }

    #[test]
    fn warped_block_at_the_end_of_a_small_image_agrees_with_value() {
        // The vectorised rows read whole vectors past a run's last tap: at the
        // bottom right of an image hardly wider than a vector's reach, they must stay
        // in the coefficients and store only the block's own pixels. Every centre,
        // size and sub-pixel shift of a 16 x 11 image (as narrow as single precision
        // runs on), in both precisions (bounds: `warped_block_agrees_with_value`).
        let (w, h) = (16, 11);
        let data = (0..w * h)
            .map(|k| 90.0 + 30.0 * (0.9 * (k % w) as f64).sin() + 7.0 * (k / w) as f64)
            .collect();
        let spline = BSpline::with_degree(&Image::new(w, h, data).unwrap(), Degree::Quintic);
        let largest = spline.c.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let mut out = Vec::new();
        let mut checked = 0;
        for (hw, hh, single) in [(0usize, 0usize), (1, 1), (2, 1)]
            .into_iter()
            .flat_map(|(a, b)| [(a, b, false), (a, b, true)])
        {
            for yc in 2..h - 2 {
                for xc in 2..w - 2 {
                    for (u, v) in [(0.3, 0.45), (0.85, 0.9), (-0.2, 0.7)] {
                        let p = [u, 0.0, 0.0, v, 0.0, 0.0];
                        let (xc, yc) = (xc as f64, yc as f64);
                        if !spline.warped_block_with(xc, yc, hw, hh, &p, 2.0, single, &mut out) {
                            continue;
                        }
                        let nw = 2 * hw + 1;
                        for (k, o) in out.iter().enumerate() {
                            let (dx, dy) =
                                ((k % nw) as f64 - hw as f64, (k / nw) as f64 - hh as f64);
                            let v = spline.value(xc + dx + u, yc + dy + v);
                            agrees(*o, v, single, largest, || {
                                format!("({xc}, {yc}) {p:?} single {single}")
                            });
                            checked += 1;
                        }
                    }
                }
            }
        }
        assert!(checked > 100, "{checked} pixels");
    }

    #[test]
    fn lines_prefiltered_side_by_side_match_each_line_alone() {
        // The vectorised recursions over many lines at once against the scalar one
        // line at a time, on lines shorter and longer than the poles' horizon.
        let mut state = 99u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 * 255.0
        };
        for degree in [Degree::Cubic, Degree::Quintic] {
            for (n, count) in [(1usize, 3usize), (2, 5), (7, 9), (40, 17), (600, 3)] {
                let lines: Vec<f64> = (0..n * count).map(|_| next()).collect();
                let mut together = lines.clone();
                prefilter_lines(&mut together, n, degree);
                let mut alone = lines.clone();
                for k in 0..count {
                    prefilter(&mut alone, k * n, n, 1, degree);
                }
                for (a, b) in together.iter().zip(&alone) {
                    assert!(
                        (a - b).abs() <= 1e-9,
                        "{degree:?}, n = {n}: {a} against {b}"
                    );
                }
            }
        }
    }

    #[test]
    fn spline_interpolates_every_pixel_exactly() {
        let img = test_image();
        let s = BSpline::new(&img);
        for y in 0..img.height() {
            for x in 0..img.width() {
                let v = s.value(x as f64, y as f64);
                assert!(
                    (v - img.at(x, y)).abs() < 1e-9,
                    "({x},{y}): {v} vs {}",
                    img.at(x, y)
                );
            }
        }
    }

    #[test]
    fn gradient_is_the_derivative_of_the_value() {
        let s = BSpline::new(&test_image());
        let h = 1e-6;
        for &(x, y) in &[(5.3, 7.7), (10.0, 3.25), (1.5, 14.9)] {
            let (_, gx, gy) = s.value_gradient(x, y);
            let nx = (s.value(x + h, y) - s.value(x - h, y)) / (2.0 * h);
            let ny = (s.value(x, y + h) - s.value(x, y - h)) / (2.0 * h);
            assert!((gx - nx).abs() < 1e-5 && (gy - ny).abs() < 1e-5);
            let (v, _, _) = s.value_gradient(x, y);
            assert!((v - s.value(x, y)).abs() < 1e-10);
        }
    }

    /// The spline of `degree` on a `w x h` sampling of `f` reproduces `f` at `points`.
    fn assert_reproduces(
        degree: Degree,
        (w, h): (usize, usize),
        f: impl Fn(f64, f64) -> f64,
        points: &[(f64, f64)],
    ) {
        let data = (0..w * h)
            .map(|k| f((k % w) as f64, (k / w) as f64))
            .collect();
        let s = BSpline::with_degree(&Image::new(w, h, data).unwrap(), degree);
        for &(x, y) in points {
            assert!(
                (s.value(x, y) - f(x, y)).abs() < 1e-6,
                "{degree:?}: {} vs {}",
                s.value(x, y),
                f(x, y)
            );
        }
    }

    #[test]
    fn cubic_polynomials_are_reproduced() {
        // A cubic spline reproduces polynomials of degree ≤ 3 away from the borders.
        let f = |x: f64, y: f64| 0.01 * x * x * x - 0.2 * x * y + 0.5 * y * y + 3.0;
        assert_reproduces(Degree::Cubic, (40, 30), f, &[(15.3, 12.7), (20.5, 14.25)]);
    }

    #[test]
    fn quintic_polynomials_are_reproduced() {
        // A quintic spline reproduces polynomials of degree ≤ 5 away from the borders.
        let f = |x: f64, y: f64| {
            let (x, y) = (x / 10.0, y / 10.0);
            x.powi(5) - 2.0 * x.powi(3) * y * y + y.powi(4) + 3.0 * x * y + 1.0
        };
        assert_reproduces(Degree::Quintic, (60, 50), f, &[(25.3, 22.7), (30.5, 24.25)]);
    }

    #[test]
    fn kernel_weights_partition_unity_and_match_the_samples() {
        for d in [Degree::Cubic, Degree::Quintic] {
            for &t in &[0.0, 0.2, 0.5, 0.77, 0.999] {
                let w = d.weights(t);
                assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-14, "{d:?} {t}");
                // The first moment is the position: Σ w_k (k − 2) = t.
                let m: f64 = w
                    .iter()
                    .enumerate()
                    .map(|(k, a)| a * (k as f64 - 2.0))
                    .sum();
                assert!((m - t).abs() < 1e-14, "{d:?} {t}: {m}");
                let (h, dw) = (1e-6, d.weights_derivative(t.min(0.99)));
                let (a, b) = (d.weights(t.min(0.99) + h), d.weights(t.min(0.99) - h));
                for k in 0..TAPS {
                    assert!(
                        (dw[k] - (a[k] - b[k]) / (2.0 * h)).abs() < 1e-8,
                        "{d:?} {t} {k}"
                    );
                }
            }
        }
        let q = Degree::Quintic.weights(0.0);
        let want = [1.0, 26.0, 66.0, 26.0, 1.0, 0.0].map(|v| v / 120.0);
        for (a, b) in q.iter().zip(want) {
            assert!((a - b).abs() < 1e-15);
        }
    }

    #[test]
    fn the_cubic_option_interpolates_too() {
        let img = test_image();
        let s = BSpline::with_degree(&img, Degree::Cubic);
        let q = BSpline::new(&img);
        for &(x, y) in &[(5.3f64, 7.7f64), (10.0, 3.0), (0.5, 14.9)] {
            let (xi, yi) = (x as usize, y as usize);
            if x.fract() == 0.0 && y.fract() == 0.0 {
                assert!((s.value(x, y) - img.at(xi, yi)).abs() < 1e-9);
            }
            // The two interpolants agree to within the image's high-frequency content.
            assert!((s.value(x, y) - q.value(x, y)).abs() < 5.0);
        }
    }

    #[test]
    fn windows_address_whole_image_coordinates() {
        let (w, h) = (100, 80);
        let data = (0..w * h)
            .map(|k| 100.0 + 40.0 * (0.7 * (k % w) as f64).sin() * (0.45 * (k / w) as f64).cos())
            .collect();
        let img = Image::new(w, h, data).unwrap();
        let whole = BSpline::new(&img);
        let win = BSpline::window(&img, 10, 10, 60, 50);
        // 23 px from the window's border the boundary's influence is |z₁|^23 ≈ 4e-9
        // (the quintic's larger pole, −0.43).
        let (x, y) = (40.4, 35.6);
        assert!((whole.value(x, y) - win.value(x, y)).abs() < 1e-5);
    }

    #[test]
    fn a_translated_block_equals_point_by_point_values() {
        let (w, h) = (60, 50);
        let data = (0..w * h)
            .map(|k| 100.0 + 40.0 * (0.7 * (k % w) as f64).sin() * (0.45 * (k / w) as f64).cos())
            .collect();
        let s = BSpline::new(&Image::new(w, h, data).unwrap());
        let d = s.degree();
        let (wx, wy) = (d.weights(0.3), d.weights(0.8));
        let (mut tmp, mut out) = (Vec::new(), Vec::new());
        // Inside, touching the border, and over two corners (the mirror's rows).
        for (fx, fy) in [(30.0, 25.0), (4.0, 3.0), (0.0, 49.0), (58.0, 1.0)] {
            s.translated_block(fx, fy, 5, 3, &wx, &wy, &mut tmp, &mut out);
            assert_eq!(out.len(), 11 * 7);
            let mut k = 0;
            for dy in -3..=3 {
                for dx in -5..=5 {
                    let v = s.value_with(fx + dx as f64, fy + dy as f64, &wx, &wy);
                    assert!((out[k] - v).abs() < 1e-9, "{fx} {fy} {dx} {dy}");
                    k += 1;
                }
            }
        }
    }
}
