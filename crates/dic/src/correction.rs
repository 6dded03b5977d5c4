//! Per-image tables of the two corrections that every field and point match gets
//! ([`crate::accept::measure`]): the spline's interpolation error, simulated and
//! taken out, and the current image's rounding, which bounds σ from below.
//!
//! Both depend on the reference image and on the match's sub-pixel phase, not on
//! where the subset lies: so they are simulated once per image (and per phase) over
//! the whole image, and each match reads its subset's pixels out of the tables,
//! instead of simulating its own window (a windowed-sinc resampling, a spline and
//! five rounding simulations per point, 1.9 ms of the 2.2 ms a point took).
//!
//! - **Interpolation error** ([`icgn::interpolation_mismatch`] does it per subset,
//!   in two dimensions): at phase t along x, each row of the reference is resampled at
//!   m − t by the Kaiser-windowed sinc (band-limited: the image a camera would take of
//!   the shifted scene), its spline interpolated back at m + t, and the reference
//!   subtracted; the same along y. A match at phase (tu, tv) reads the sum of the x
//!   table at tu and the y table at tv, each interpolated linearly between the
//!   [`PHASES`] phases a pixel is cut into. The separable sum leaves out the product
//!   of the two axes' errors (second order: a few per cent of the correction), and
//!   the rows see the whole image instead of a window of the subset with a margin.
//!   Tables are made when a match first needs a phase.
//! - **Rounding** ([`icgn::rounding_error`] does it per subset): at the sub-pixel
//!   phases [`icgn::ROUNDING_PHASES`] (a, a), the current image a translation by
//!   (a, a) makes of the reference's spline is rounded to the quantisation step, and
//!   the rounding residual interpolated back at the reference's pixels. Phase 0 is the
//!   reference itself, whose grey levels are already whole steps: no residual. The
//!   affine part of a match is left out (it moves a pixel by well under the phases'
//!   spacing over a subset).

use std::sync::OnceLock;

use crate::bspline::{self, BSpline, Degree, TAPS, transpose};
use crate::icgn::{self, Reference, SINC_HALF, Subset, sinc_weights};

/// Phases per pixel of the interpolation-error tables. The error is a smooth,
/// periodic function of the phase, zero at whole pixels; linear interpolation
/// between phases 1/32 px apart errs by about 0.5 % of it.
pub const PHASES: usize = 32;

/// Lines per block of the interpolation-error tables.
pub const BLOCK: usize = 16;

/// The tables of one reference image, for a current image whose spline has the given
/// degree and whose grey levels are rounded to the given step.
pub struct Corrections<'a> {
    reference: &'a Reference,
    degree: Degree,
    /// The interpolation error along x (0) and y (1) at phases p / PHASES,
    /// p = 1..PHASES (slot p − 1; phase 0 has none), in blocks of [`BLOCK`] lines
    /// (rows for x, columns for y), each made when a match first reads it: a
    /// field whose phase drifts across the image (a rotation, a strain) makes only
    /// the blocks each phase is met in.
    mismatch: [Vec<Vec<OnceLock<Vec<f32>>>>; 2],
    /// The reference's columns as rows (the lines of the y tables), made when first
    /// needed.
    columns: OnceLock<Vec<f64>>,
    /// The rounding residual at the reference's pixels for the phases
    /// `ROUNDING_PHASES[1..]` (empty when the current image is not quantised).
    rounding: Vec<Vec<f32>>,
}

impl std::fmt::Debug for Corrections<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let made = self
            .mismatch
            .iter()
            .flatten()
            .flatten()
            .filter(|s| s.get().is_some())
            .count();
        f.debug_struct("Corrections")
            .field("degree", &self.degree)
            .field("mismatch_blocks", &made)
            .field("rounding_tables", &self.rounding.len())
            .finish()
    }
}

impl<'a> Corrections<'a> {
    /// The tables of `reference` for a current image interpolated by a spline of
    /// `degree` and quantised to `quantisation_step` grey levels (0: not quantised).
    /// The rounding tables are made now, in parallel; the interpolation error's
    /// when a match first needs them.
    pub fn new(reference: &'a Reference, degree: Degree, quantisation_step: f64) -> Self {
        Self::with_rounding(
            reference,
            degree,
            rounding_tables(reference.spline(), quantisation_step),
        )
    }

    /// [`Corrections::new`] with the rounding tables already made
    /// ([`rounding_tables`] of the same reference).
    pub(crate) fn with_rounding(
        reference: &'a Reference,
        degree: Degree,
        rounding: Vec<Vec<f32>>,
    ) -> Self {
        let img = reference.image();
        let slots = |lines: usize| {
            (1..PHASES)
                .map(|_| {
                    (0..lines.div_ceil(BLOCK))
                        .map(|_| OnceLock::new())
                        .collect()
                })
                .collect()
        };
        Corrections {
            reference,
            degree,
            mismatch: [slots(img.height()), slots(img.width())],
            columns: OnceLock::new(),
            rounding,
        }
    }

    /// The rounding tables (phases `ROUNDING_PHASES[1..]`), row-major over the
    /// reference image; empty when the image is not quantised.
    pub(crate) fn rounding(&self) -> &[Vec<f32>] {
        &self.rounding
    }

    /// Block `b` of the table of `axis` (0: x, 1: y) at phase `p / PHASES`: lines
    /// `b·BLOCK..` of `n` samples each, `None` at whole pixels.
    fn block(&self, axis: usize, p: usize, b: usize) -> Option<&[f32]> {
        if p == 0 || p >= PHASES {
            return None;
        }
        let t = p as f64 / PHASES as f64;
        Some(self.mismatch[axis][p - 1][b].get_or_init(|| {
            let img = self.reference.image();
            let (w, h) = (img.width(), img.height());
            let (lines, n, count) = if axis == 0 {
                (img.data(), w, h)
            } else {
                let columns = self.columns.get_or_init(|| transpose(img.data(), w, h));
                (&columns[..], h, w)
            };
            let last = ((b + 1) * BLOCK).min(count);
            let table = pulp::Arch::new().dispatch(MismatchTable {
                lines: &lines[b * BLOCK * n..last * n],
                n,
                t,
                degree: self.degree,
            });
            if axis == 0 {
                table
            } else {
                // The y table's block back in the image's orientation (`h` rows of
                // the block's columns), so that a subset reads it row by row.
                let cols = last - b * BLOCK;
                let mut rows = vec![0.0f32; table.len()];
                for (c, line) in table.chunks_exact(n).enumerate() {
                    for (y, e) in line.iter().enumerate() {
                        rows[y * cols + c] = *e;
                    }
                }
                rows
            }
        }))
    }

    /// The interpolation error at the pixels of the subset `s` centred at (x, y) for a
    /// match at sub-pixel phase (u, v) (their fractional parts are used), in the
    /// subset's pixel order, grey levels: interpolated minus band-limited value.
    #[inline(always)]
    pub(crate) fn mismatch(
        &self,
        x: usize,
        y: usize,
        s: Subset,
        u: f64,
        v: f64,
        out: &mut Vec<f64>,
    ) {
        let img = self.reference.image();
        let (w, h) = (img.width(), img.height());
        let (nw, nh) = (2 * s.half_w + 1, 2 * s.half_h + 1);
        out.clear();
        out.resize(nw * nh, 0.0);
        let (x0, y0) = (x - s.half_w, y - s.half_h);
        for (axis, t) in [u, v].into_iter().enumerate() {
            let scaled = (t - t.floor()) * PHASES as f64;
            let p = (scaled as usize).min(PHASES - 1);
            let alpha = scaled - p as f64;
            for (phase, weight) in [(p, 1.0 - alpha), (p + 1, alpha)] {
                if axis == 0 {
                    // Row y0 + j of the subset is line y0 + j of the x table.
                    for (j, row) in out.chunks_exact_mut(nw).enumerate() {
                        let line = y0 + j;
                        let Some(block) = self.block(0, phase, line / BLOCK) else {
                            break;
                        };
                        let start = (line % BLOCK) * w + x0;
                        for (o, e) in row.iter_mut().zip(&block[start..start + nw]) {
                            *o += weight * f64::from(*e);
                        }
                    }
                } else {
                    // Columns x0..x0 + nw, block by block: each block holds its
                    // columns row by row.
                    let mut i = 0;
                    while i < nw {
                        let line = x0 + i;
                        let Some(block) = self.block(1, phase, line / BLOCK) else {
                            break;
                        };
                        let cols = block.len() / h;
                        let (c0, take) = (line % BLOCK, (cols - line % BLOCK).min(nw - i));
                        for (j, row) in out.chunks_exact_mut(nw).enumerate() {
                            let start = (y0 + j) * cols + c0;
                            let src = &block[start..start + take];
                            for (o, e) in row[i..i + take].iter_mut().zip(src) {
                                *o += weight * f64::from(*e);
                            }
                        }
                        i += take;
                    }
                }
            }
        }
    }
}

/// [`mismatch_table`] compiled for the machine's vector units.
struct MismatchTable<'a> {
    lines: &'a [f64],
    n: usize,
    t: f64,
    degree: Degree,
}

impl pulp::WithSimd for MismatchTable<'_> {
    type Output = Vec<f32>;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> Self::Output {
        mismatch_table(self.lines, self.n, self.t, self.degree)
    }
}

/// The interpolation error along each of the `lines` (of `n` samples each, back to
/// back) at phase `t` (see the module's doc).
#[inline(always)]
fn mismatch_table(lines: &[f64], n: usize, t: f64, degree: Degree) -> Vec<f32> {
    let mut out = vec![0.0f32; lines.len()];
    // Weight i of the sinc belongs to node m − (i − SINC_HALF + 1): reversed, tap j
    // reads the padded line at m + pad − SINC_HALF + j.
    let mut sinc = sinc_weights(t);
    sinc.reverse();
    let spline = degree.weights(t);
    let half = SINC_HALF as usize;
    let pad = 2 * half;
    let mut ext = vec![0.0; n + 2 * pad];
    // Each line resampled at m − t (each tap a pass over the line), all the lines
    // first: their splines are then made side by side.
    let mut sims = vec![0.0; lines.len()];
    for (line, sim) in lines.chunks_exact(n).zip(sims.chunks_exact_mut(n)) {
        // The line mirrored about its half-sample edges, as the subset's own
        // simulation mirrors the image.
        let half_sample = |i: usize| {
            let m = (i as isize - pad as isize).rem_euclid(2 * n as isize) as usize;
            line[if m < n { m } else { 2 * n - 1 - m }]
        };
        ext[pad..pad + n].copy_from_slice(line);
        for i in (0..pad).chain(pad + n..n + 2 * pad) {
            ext[i] = half_sample(i);
        }
        convolve(&ext[pad - half..], &sinc, sim);
    }
    bspline::prefilter_lines(&mut sims, n, degree);
    // Each spline interpolated back at m + t: taps m − 2..=m + 3.
    let edge = TAPS - 1;
    let mut coef = vec![0.0; n + 2 * (TAPS - 1)];
    let mut acc = vec![0.0; n];
    for ((line, sim), dst) in lines
        .chunks_exact(n)
        .zip(sims.chunks_exact(n))
        .zip(out.chunks_exact_mut(n))
    {
        coef[edge..edge + n].copy_from_slice(sim);
        for i in (0..edge).chain(edge + n..n + 2 * edge) {
            coef[i] = sim[bspline::mirror(i as isize - edge as isize, n)];
        }
        convolve(&coef[TAPS - 3..], &spline, &mut acc);
        for ((d, a), f) in dst.iter_mut().zip(&acc).zip(line) {
            *d = (a - f) as f32;
        }
    }
    out
}

/// Outputs a convolution computes at a time, in registers ([`convolve`]).
const CONVOLVE_BLOCK: usize = 32;

/// `out[i] = Σ_j w[j]·src[i + j]` for every `i < out.len()` (`src` holds at least
/// `out.len() + T − 1` samples), the taps added in order from 0.0, as a pass per tap
/// adds them: [`CONVOLVE_BLOCK`] outputs are kept in registers across the taps, where
/// a pass per tap loads and stores every output once per tap.
#[inline(always)]
fn convolve<const T: usize>(src: &[f64], w: &[f64; T], out: &mut [f64]) {
    let n = out.len();
    let full = n - n % CONVOLVE_BLOCK;
    for (c, o) in out[..full].chunks_exact_mut(CONVOLVE_BLOCK).enumerate() {
        let at = c * CONVOLVE_BLOCK;
        let mut acc = [0.0; CONVOLVE_BLOCK];
        for (j, wj) in w.iter().enumerate() {
            let s = &src[at + j..at + j + CONVOLVE_BLOCK];
            for (a, v) in acc.iter_mut().zip(s) {
                *a += wj * v;
            }
        }
        o.copy_from_slice(&acc);
    }
    for (i, o) in out.iter_mut().enumerate().skip(full) {
        *o = w
            .iter()
            .enumerate()
            .fold(0.0, |a, (j, wj)| a + wj * src[i + j]);
    }
}

/// The rounding tables of `reference` for a current image quantised to
/// `quantisation_step` grey levels, one per phase of `ROUNDING_PHASES[1..]` (empty
/// when the step is 0: not quantised). The phases in turn, each spread over the
/// threads, through one image-sized buffer: three phases side by side touched three
/// times the fresh memory (15 MB on a 512² image), and the first touch of a page
/// costs more than the arithmetic on it.
pub(crate) fn rounding_tables(reference: &BSpline, quantisation_step: f64) -> Vec<Vec<f32>> {
    if quantisation_step <= 0.0 {
        return Vec::new();
    }
    let mut buffer = Vec::new();
    icgn::ROUNDING_PHASES[1..]
        .iter()
        .map(|&a| rounding_table(reference, a, quantisation_step, &mut buffer))
        .collect()
}

/// The rounding residual at the pixels of the reference whose spline is `reference`
/// for a current image translated by (a, a) (see the module's doc), row-major;
/// `buffer` is the image-sized scratch.
fn rounding_table(reference: &BSpline, a: f64, step: f64, buffer: &mut Vec<f64>) -> Vec<f32> {
    let (w, h) = (reference.width(), reference.height());
    // The current image: the reference's spline at (x − a, y − a), rounded.
    reference.translated_image_into(-a, buffer);
    let finite = pulp::Arch::new().dispatch(Residual {
        values: buffer,
        step,
    });
    if !finite {
        return vec![0.0; w * h];
    }
    // Interpolated where the reference's pixels lie in it, at (x + a, y + a).
    let spline = BSpline::from_values(w, h, std::mem::take(buffer), reference.degree());
    let table = spline.translated_image_f32(a);
    *buffer = spline.into_coefficients();
    table
}

/// Each value replaced by its rounding residual to `step` (rounded minus value),
/// compiled for the machine's vector units; whether all are finite.
struct Residual<'a> {
    values: &'a mut [f64],
    step: f64,
}

impl pulp::WithSimd for Residual<'_> {
    type Output = bool;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> Self::Output {
        let step = self.step;
        for v in self.values.iter_mut() {
            *v = (*v / step).round() * step - *v;
        }
        self.values.iter().all(|v| v.is_finite())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::icgn::{IcgnOptions, Scratch, Shape, influence, prepare, refine_prepared};
    use crate::synth::{Speckle, SpeckleParams};

    /// The tables give the per-subset simulation's answer: the first-order change the
    /// interpolation error makes in a match, to 3 % of it or 1e-4 px, over three
    /// shifts and three places.
    #[test]
    fn the_tables_agree_with_the_per_subset_simulations() {
        let sp = Speckle::new(&SpeckleParams::default_for(160, 160), 21);
        let r = Reference::with_degree(sp.render_shifted(0.0, 0.0, 0.0, 1), Degree::Quintic);
        let opts = IcgnOptions {
            quantisation_step: 1.0,
            residual_floor: 1.0 / 6.0,
            ..IcgnOptions::default()
        };
        let tables = Corrections::new(&r, Degree::Quintic, 1.0);
        let mut scratch = Scratch::default();
        let mut worst = 0.0f64;
        for (k, (u, v)) in [(0.3, -0.15), (1.72, 0.41), (-0.55, 2.9)]
            .into_iter()
            .enumerate()
        {
            let c =
                BSpline::with_degree(&sp.render_shifted(u, v, 0.0, 2 + k as u64), Degree::Quintic);
            for (x, y) in [(50, 50), (80, 70), (110, 100)] {
                let s = Subset::square(31);
                let p = prepare(&r, x, y, s, Shape::Affine).unwrap();
                let res = refine_prepared(&p, &c, [u, 0.0, 0.0, v, 0.0, 0.0], &opts).unwrap();
                influence(&p, &mut scratch).unwrap();
                let exact = icgn::interpolation_mismatch(&r, &p, &res, Degree::Quintic).unwrap();
                let (eu, ev) = scratch.first_order_for_test(&exact);
                tables.mismatch(x, y, s, res.u, res.v, &mut scratch.mismatch);
                let e = scratch.mismatch.clone();
                let (tu, tv) = scratch.first_order_for_test(&e);
                for (a, b) in [(tu, eu), (tv, ev)] {
                    assert!(
                        (a - b).abs() <= 0.03 * b.abs() + 1e-4,
                        "({x}, {y}) at ({u}, {v}): {a} from the tables, {b} per subset"
                    );
                    worst = worst.max((a - b).abs());
                }
            }
        }
        assert!(worst > 0.0);
    }
}
