//! Sub-pixel registration by the inverse-compositional Gauss-Newton algorithm (IC-GN)
//! with the zero-normalised sum of squared differences (ZNSSD), after Pan, Li & Tong,
//! "Fast, robust and accurate digital image correlation calculation without redundant
//! computations", Exp. Mech. 53 (2013), and Baker & Matthews, IJCV 56 (2004).
//!
//! The reference subset's gradients and Hessian are computed once per point; each
//! iteration interpolates the current image at the warped subset (B-spline, quintic in
//! field and point mode, cubic in the tracker: [`crate::bspline`]),
//! solves `Δp = −H⁻¹ Σ Jᵀ [(f − f̄) − (Δf/Δg)(g − ḡ)]` and composes
//! `W(p) ← W(p) ∘ W(Δp)⁻¹`. ZNSSD makes the result insensitive to a change of
//! brightness and contrast between the images.

use std::sync::OnceLock;

use nalgebra::{Matrix3, SMatrix, SVector};

use crate::bspline::{BSpline, Degree, warped_corners};
use crate::image::Image;
use crate::lanes::{V, lane_sums};
pub(crate) use sums::GridSums;
use sums::SubsetSums;

mod mismatch;
mod noise;
mod rounding;
mod sums;
pub use mismatch::*;
pub use noise::*;
pub use rounding::*;

/// The subset shape function.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// First order: u, ∂u/∂x, ∂u/∂y, v, ∂v/∂x, ∂v/∂y.
    Affine,
    /// Translation only (u, v), for tracking a rigid region.
    Rigid,
}

/// The stopping tolerance of a measurement (field and point mode), pixels: the
/// iteration stops when an update moves no subset corner by more than this. Started
/// from a neighbour's solution (the field) or from the integer search (point mode),
/// the iteration contracts fast (Gauss-Newton, mixed by Anderson acceleration where it does
/// not), and what is left after a 5e-4 px update is far below σ. The field's results
/// are unchanged to 1e-5 px from those at 1e-4 px, with a third of the iterations;
/// point mode's (1,024 points of 512 x 512 speckle, 3 seeds) within 2.2e-5 px of
/// those at 1e-5 px (0.4 % of σ), the RMS error unchanged to 5 digits, with 3.85
/// iterations a point instead of 4.95.
pub const MEASUREMENT_TOLERANCE: f64 = 5e-4;

/// What the updates after one of size `step` would still move the solution, pixels,
/// when each shrinks by the contraction `r` (the larger of the last two updates'
/// ratios to the update before: Anderson mixing makes the ratios alternate, so one
/// alone can promise too much): the geometric tail step·r / (1 − r). Infinite where
/// the iteration does not contract, or before a second update (r not finite or 0).
#[inline]
fn predicted_rest(step: f64, r: f64) -> f64 {
    if r > 0.0 && r < 1.0 {
        step * r / (1.0 - r)
    } else {
        f64::INFINITY
    }
}

/// Stopping rule of the iteration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IcgnOptions {
    /// Stop when the update moves no subset corner by more than this, pixels.
    pub tolerance: f64,
    /// Give up after this many iterations.
    pub max_iterations: usize,
    /// Smallest variance of the residual used for the predicted σ, grey levels²: the
    /// noise the two images must hold whatever the residual says, their quantisation
    /// ([`crate::image::quantisation_variance`]; the callers that hold the images set
    /// it). Where a smooth patch is quantised into steps of one grey level, both images
    /// show the same steps and the residual drops far below the rounding noise, while
    /// the rounding has moved the steps to whole pixels.
    pub residual_floor: f64,
    /// Quantisation step of the current image's grey levels (1 for 8-bit data; 0: not
    /// quantised, or unknown). When positive, [`crate::accept::measure`] adds the
    /// rounding error of a grown subset's match to its predicted σ
    /// ([`rounding_error`]).
    pub quantisation_step: f64,
}

impl Default for IcgnOptions {
    fn default() -> Self {
        IcgnOptions {
            tolerance: 1e-5,
            max_iterations: 40,
            residual_floor: 0.0,
            quantisation_step: 0.0,
        }
    }
}

/// The result at one point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointResult {
    /// Point in the reference image (column, row), pixels.
    pub x: f64,
    /// Row.
    pub y: f64,
    /// Displacement along x: the point is found at (x + u, y + v). In field and point
    /// mode ([`crate::accept::measure`]) the spline's simulated interpolation error is
    /// subtracted from it ([`corrected`]).
    pub u: f64,
    /// Displacement along y.
    pub v: f64,
    /// ∂u/∂x, ∂u/∂y, ∂v/∂x, ∂v/∂y (zero in rigid mode).
    pub gradients: [f64; 4],
    /// Zero-normalised cross-correlation at the solution (1 = perfect).
    pub zncc: f64,
    /// Iterations used.
    pub iterations: usize,
    /// Whether the update fell below the tolerance.
    pub converged: bool,
    /// Predicted standard error of u, pixels. From [`refine_prepared`] (the tracker,
    /// at camera rate): the noise term below and the interpolation bias the spline
    /// makes at this sub-pixel position for the subset's spectrum
    /// ([`spline_response`]), in quadrature. From [`crate::accept::measure`] (field
    /// and point mode): the noise term of the corrected match, a share
    /// ([`crate::accept::BIAS_KEPT`]) of the subtracted interpolation error in
    /// quadrature, and, when the current image is quantised, at least the simulated
    /// rounding error ([`rounding_error`]).
    ///
    /// The noise term is the u entry of the sandwich `A_s⁻¹ B A_s⁻¹` over the shape
    /// parameters with offset and gain: `A_s = Σ J̃J̃ᵀ − ν·M` is the information of the
    /// subset's texture, the observed one less what the reference's own noise puts in
    /// its gradients (`ν = σ²·g`, g the spline's [`Degree::derivative_noise_gain`], σ²
    /// half the residual variance,
    /// `M = Σ wwᵀ` on each gradient block, w = (1, dx, dy)); `B = Σ J̃J̃ᵀ r²` weighs
    /// each pixel by its own residual, with the products of neighbours' up to
    /// [`RESIDUAL_CORRELATION_PX`] apart. For white residuals and a subset whose
    /// texture is far above the noise it is Pan et al.'s `√2·σ / √Σ(∂f/∂x)²`
    /// (Opt. Express 2008); where the texture is weak against the noise (a smooth
    /// sky, a dark coat, the rounding steps of an 8-bit image, a straight edge whose
    /// only other "texture" is noise) or the residual sits on the strong gradients (a
    /// mismatch at an edge), it grows as the error does. Infinite when the texture
    /// cannot fix u at all (uniform, a linear ramp of grey levels, or no more texture
    /// than noise).
    pub sigma_u: f64,
    /// Predicted standard error of v.
    pub sigma_v: f64,
    /// Image noise estimated from the correlation residual, grey levels.
    pub sigma_noise: f64,
    /// Side of the square subset that gave this result, pixels: the one requested, or
    /// a larger one the self-adaptive subset grew to ([`crate::accept::measure`]).
    pub subset: usize,
}

/// The reference image with the gradients of its spline at every pixel.
#[derive(Debug, Clone)]
pub struct Reference {
    image: Image,
    spline: BSpline,
    gx: Vec<f64>,
    gy: Vec<f64>,
}

impl Reference {
    /// Precomputes the spline gradients at the pixel centres (default, cubic, spline).
    pub fn new(image: Image) -> Self {
        Reference::with_degree(image, Degree::default())
    }

    /// Precomputes the gradients of the spline of the given degree at the pixel centres.
    pub fn with_degree(image: Image, degree: Degree) -> Self {
        let s = BSpline::with_degree(&image, degree);
        let (gx, gy) = s.node_gradients();
        Reference::from_spline(image, s, (gx, gy))
    }

    /// The reference of `image` from its spline and the spline's
    /// [`BSpline::node_gradients`], made by the caller (beside other work).
    pub(crate) fn from_spline(image: Image, s: BSpline, (gx, gy): (Vec<f64>, Vec<f64>)) -> Self {
        Reference {
            image,
            spline: s,
            gx,
            gy,
        }
    }

    /// The image's spline.
    pub fn spline(&self) -> &BSpline {
        &self.spline
    }

    /// The image.
    pub fn image(&self) -> &Image {
        &self.image
    }

    /// Spline gradient (∂f/∂x, ∂f/∂y) at a pixel.
    #[inline]
    pub fn gradient(&self, x: usize, y: usize) -> (f64, f64) {
        let k = y * self.image.width() + x;
        (self.gx[k], self.gy[k])
    }
}

/// A rectangular subset: `(2·half_w + 1) x (2·half_h + 1)` pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Subset {
    /// Half-width, pixels.
    pub half_w: usize,
    /// Half-height, pixels.
    pub half_h: usize,
}

impl Subset {
    /// A square subset of odd size `n`.
    pub fn square(n: usize) -> Self {
        Subset {
            half_w: n / 2,
            half_h: n / 2,
        }
    }

    /// Whether the subset centred at (x, y) lies inside a `w x h` image (false, not an
    /// overflow, for a centre near `usize::MAX`).
    pub fn fits(&self, x: usize, y: usize, w: usize, h: usize) -> bool {
        x >= self.half_w
            && y >= self.half_h
            && x.checked_add(self.half_w).is_some_and(|r| r < w)
            && y.checked_add(self.half_h).is_some_and(|b| b < h)
    }
}

/// Precomputed reference data of one subset.
#[derive(Debug, Clone)]
struct RefSubset {
    dx: Vec<f64>,
    dy: Vec<f64>,
    f: Vec<f64>,
    gx: Vec<f64>,
    gy: Vec<f64>,
    df: f64,
    sum_gx2: f64,
    sum_gy2: f64,
    /// Σ1, Σdx², Σdy² over the subset (Σdx, Σdy and Σdx·dy vanish).
    moments: [f64; 3],
    /// The subset's half sizes, which alone decide `dx` and `dy`.
    halves: (usize, usize),
}

/// Number of frequencies of the subset's gradient spectrum kept for the bias term.
const SPECTRUM_BINS: usize = 16;

/// Gradient power of a subset along x and y at the frequencies `π·(k + ½)/SPECTRUM_BINS`,
/// k = 0..SPECTRUM_BINS: Hann-windowed DFTs of each row of ∂f/∂x (each column of ∂f/∂y),
/// summed. It weights the spline's per-frequency bias into the subset's bias.
#[derive(Debug, Clone, Copy)]
struct Spectrum {
    x: [f64; SPECTRUM_BINS],
    y: [f64; SPECTRUM_BINS],
    /// What white noise of unit variance in the gradients puts in each bin of `x`
    /// (`y`): the window's energy times the number of lines.
    white_x: f64,
    white_y: f64,
}

fn bin_frequency(k: usize) -> f64 {
    std::f64::consts::PI * (k as f64 + 0.5) / SPECTRUM_BINS as f64
}

impl Spectrum {
    fn new(rs: &RefSubset, s: Subset) -> Self {
        let (nw, nh) = (2 * s.half_w + 1, 2 * s.half_h + 1);
        let hann = |n: usize| -> Vec<f64> {
            (0..n)
                .map(|i| {
                    let t = std::f64::consts::PI * (i as f64 + 0.5) / n as f64;
                    t.sin().powi(2)
                })
                .collect()
        };
        // The window times the DFT's cosines and sines, per sample and bin.
        let basis = |n: usize| -> Vec<[(f64, f64); SPECTRUM_BINS]> {
            let window = hann(n);
            (0..n)
                .map(|i| {
                    std::array::from_fn(|k| {
                        let (sn, cs) = (bin_frequency(k) * i as f64).sin_cos();
                        (window[i] * cs, window[i] * sn)
                    })
                })
                .collect()
        };
        // One line of samples: its windowed power at every bin.
        let power = |line: &mut dyn Iterator<Item = f64>,
                     basis: &[[(f64, f64); SPECTRUM_BINS]],
                     out: &mut [f64; SPECTRUM_BINS]| {
            let mut acc = [(0.0, 0.0); SPECTRUM_BINS];
            for (a, b) in line.zip(basis) {
                for (s, (c, n)) in acc.iter_mut().zip(b) {
                    s.0 += a * c;
                    s.1 += a * n;
                }
            }
            for (o, (re, im)) in out.iter_mut().zip(acc) {
                *o += re * re + im * im;
            }
        };
        let energy = |n: usize| hann(n).iter().map(|w| w * w).sum::<f64>();
        let mut out = Spectrum {
            x: [0.0; SPECTRUM_BINS],
            y: [0.0; SPECTRUM_BINS],
            white_x: nh as f64 * energy(nw),
            white_y: nw as f64 * energy(nh),
        };
        let (bx, by) = (basis(nw), basis(nh));
        for j in 0..nh {
            power(
                &mut rs.gx[j * nw..(j + 1) * nw].iter().copied(),
                &bx,
                &mut out.x,
            );
        }
        for i in 0..nw {
            power(&mut (0..nh).map(|j| rs.gy[j * nw + i]), &by, &mut out.y);
        }
        out
    }
}

/// The B-spline interpolant of the given degree at fractional offset `t` for a
/// sinusoid of angular frequency `w` (rad/px) of unit amplitude: its position error
/// (−arg of the response relative to the exact `e^{iωt}`, over ω; the ideal
/// band-limited interpolant has none) and its gain (Thévenaz, Blu & Unser, IEEE TMI
/// 19, 2000: the kernel's taps times the prefilter's gain `1/Σ βⁿ(k) cos kω`).
pub fn spline_response(degree: Degree, t: f64, w: f64) -> (f64, f64) {
    let wt = degree.weights(t);
    let (mut re, mut im) = (0.0, 0.0);
    for (j, a) in wt.iter().enumerate() {
        let ph = w * (j as f64 - 2.0 - t);
        re += a * ph.cos();
        im += a * ph.sin();
    }
    let gain = re.hypot(im) / degree.sampled_response(w);
    (-im.atan2(re) / w, gain)
}

/// The bias of a translation measured by matching a subset through the spline of the
/// current image (`current`) at fractional offset `t`, for the power `power` of the
/// subset's spline gradients (the reference's spline, `reference`) over the bins: the
/// per-frequency position errors weighted by each frequency's weight in the
/// Gauss-Newton normal equations (Schreier, Braasch & Sutton, Opt. Eng. 39, 2000):
/// |F|²ω² times the reference gradient's gain and the interpolant's gain.
fn interpolation_bias_1d(
    current: Degree,
    reference: Degree,
    t: f64,
    power: &[f64; SPECTRUM_BINS],
    noise: f64,
) -> f64 {
    let t = t - t.floor();
    let (mut num, mut den) = (0.0, 0.0);
    for (k, p) in power.iter().enumerate() {
        let w = bin_frequency(k);
        let (err, gain) = spline_response(current, t, w);
        // The reference's noise, white, in its spline gradients: `noise` times the
        // derivative's power response. It is in the observed power, not in the
        // texture the current image's spline interpolates.
        let p = (p - noise * (w * reference.derivative_gain(w)).powi(2)).max(0.0);
        // `power` holds |F|²ω²·D²: one D too many.
        let weight = p * gain / reference.derivative_gain(w);
        num += weight * err;
        den += weight;
    }
    if den > 0.0 { num / den } else { 0.0 }
}

impl RefSubset {
    /// The grey levels less their mean, the gradients and the offsets from the centre,
    /// each as long as the subset (one length the compiler sees, for the loops over
    /// them to run unchecked).
    #[inline(always)]
    fn slices(&self) -> [&[f64]; 5] {
        let n = self.f.len();
        [
            &self.f[..n],
            &self.gx[..n],
            &self.gy[..n],
            &self.dx[..n],
            &self.dy[..n],
        ]
    }

    /// The subset centred at (x, y), in the buffers of `spare` (a subset measured
    /// before, whose offsets are kept when its size is the same): no allocation from
    /// point to point.
    #[inline(always)]
    fn new(r: &Reference, x: usize, y: usize, s: Subset, spare: Option<RefSubset>) -> Self {
        let (nw, nh) = (2 * s.half_w + 1, 2 * s.half_h + 1);
        let n = nw * nh;
        let halves = (s.half_w, s.half_h);
        let mut out = spare.unwrap_or_else(|| RefSubset {
            dx: Vec::with_capacity(n),
            dy: Vec::with_capacity(n),
            f: Vec::with_capacity(n),
            gx: Vec::with_capacity(n),
            gy: Vec::with_capacity(n),
            df: 0.0,
            sum_gx2: 0.0,
            sum_gy2: 0.0,
            moments: [0.0; 3],
            halves: (usize::MAX, usize::MAX),
        });
        let offsets = out.halves != halves || out.dx.len() != n;
        out.f.clear();
        out.gx.clear();
        out.gy.clear();
        if offsets {
            out.dx.clear();
            out.dy.clear();
        }
        (out.df, out.sum_gx2, out.sum_gy2, out.halves) = (0.0, 0.0, 0.0, halves);
        let w = r.image.width();
        let data = r.image.data();
        for j in 0..nh {
            let start = (y + j - s.half_h) * w + x - s.half_w;
            out.f.extend_from_slice(&data[start..start + nw]);
            out.gx.extend_from_slice(&r.gx[start..start + nw]);
            out.gy.extend_from_slice(&r.gy[start..start + nw]);
            if offsets {
                let dy = j as f64 - s.half_h as f64;
                out.dy.extend(std::iter::repeat_n(dy, nw));
                out.dx.extend((0..nw).map(|i| i as f64 - s.half_w as f64));
            }
        }
        // Σ1, Σdx², Σdy² of a centred rectangle.
        let square_sum = |h: usize| (1..=h).map(|d| 2.0 * (d * d) as f64).sum::<f64>();
        out.moments = [
            n as f64,
            nh as f64 * square_sum(s.half_w),
            nw as f64 * square_sum(s.half_h),
        ];
        out
    }
}

fn warp_matrix(p: &[f64; 6]) -> Matrix3<f64> {
    Matrix3::new(
        1.0 + p[1],
        p[2],
        p[0],
        p[4],
        1.0 + p[5],
        p[3],
        0.0,
        0.0,
        1.0,
    )
}

fn params_of(w: &Matrix3<f64>) -> [f64; 6] {
    [
        w[(0, 2)],
        w[(0, 0)] - 1.0,
        w[(0, 1)],
        w[(1, 2)],
        w[(1, 0)],
        w[(1, 1)] - 1.0,
    ]
}

/// A reference subset with its steepest-descent Hessian, prepared once for many
/// refinements against successive frames (tracking).
#[derive(Debug, Clone)]
pub struct Prepared {
    rs: RefSubset,
    x: usize,
    y: usize,
    subset: Subset,
    shape: Shape,
    h6_inv: Option<SMatrix<f64, 6, 6>>,
    h2_inv: Option<SMatrix<f64, 2, 2>>,
    /// The information matrix of the shape parameters with offset and gain (see
    /// [`Information`]).
    info: Information,
    /// The gradients' spectrum, for the spectral bias of [`refine_prepared`] (the
    /// tracker's σ): made when first asked for.
    spectrum: OnceLock<Spectrum>,
    /// Degree of the reference's spline (its gradients' gain and noise gain).
    degree: Degree,
}

/// White-noise gain of the cubic spline derivative at the pixels: the variance of
/// ∂f/∂x when f is white noise of unit variance, `(1/2π)∫|D(ω)|²dω` with
/// `D(ω) = 6 sin ω/(4 + 2 cos ω)`
/// ([`Degree::derivative_gain`] times ω), which is `6√3 − 9`; see
/// [`Degree::derivative_noise_gain`] for the quintic's.
pub const DERIVATIVE_NOISE_GAIN: f64 = 1.392_304_845_413_264;

/// The information matrix `A = Σ J̃J̃ᵀ` of a subset, `J̃ = (J, 1, f − f̄)`: the shape
/// parameters' steepest-descent images and the two nuisance parameters ZNSSD
/// eliminates, offset and gain; and the geometry that gives the part of it the
/// reference image's own noise makes.
// One per prepared subset (which holds a 6x6 inverse as well): no point boxing.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy)]
enum Information {
    Affine(SMatrix<f64, 8, 8>),
    Rigid(SMatrix<f64, 4, 4>),
}

/// The covariance of u and v of a subset match, `A_s⁻¹ B A_s⁻¹` (u at 0, v at `iv`):
///
/// - `A_s = A − ν M` is the information of the subset's *signal*: the reference's
///   gradients are measured on a noisy image, and white noise of variance ν adds
///   `ν·g·Σ wwᵀ` (g the spline's [`Degree::derivative_noise_gain`]) to each gradient block of the observed `A`
///   (`noise`, w = (1, dx, dy) for the affine shape) that carries no information on the
///   displacement (errors in variables). Where the texture is weak against the noise
///   the observed `A` looks well-conditioned while `A_s` is not: the noise's own
///   gradients have no direction, so they hide the aperture problem of an edge too;
/// - `B = Σ J̃J̃ᵀ r²` (the residuals r at the solution, scaled to the residual variance
///   used, and with the products of neighbours: see `meat`) is the sandwich "meat":
///   it equals `σ²A` for white residuals, and grows where the residual concentrates
///   on the strong gradients (a mismatch at an edge) rather than spreading like
///   noise, or keeps its sign over neighbouring pixels.
///
/// Infinite where `A_s` is singular or not positive (no texture above the noise, a
/// uniform or linear ramp of grey levels that offset and gain explain, a straight
/// edge).
#[inline(always)]
fn projections<const N: usize>(
    a: &SMatrix<f64, N, N>,
    noise: &SMatrix<f64, N, N>,
    iv: usize,
) -> Option<([f64; N], [f64; N])> {
    let a_s = a - noise;
    // Scaled to unit diagonal first, so the test for singularity is relative.
    let d = SVector::<f64, N>::from_fn(|i, _| a_s[(i, i)].max(0.0).sqrt());
    if d.iter().any(|v| *v == 0.0 || !v.is_finite()) {
        return None;
    }
    let scaled = SMatrix::<f64, N, N>::from_fn(|i, j| a_s[(i, j)] / (d[i] * d[j]));
    match scaled.cholesky() {
        Some(c) if c.l().diagonal().iter().all(|v| *v > 1e-6) => {
            let inv = c.inverse();
            // Columns u and v of A_s⁻¹ = D⁻¹ S⁻¹ D⁻¹.
            Some((
                std::array::from_fn(|i| inv[(i, 0)] / (d[i] * d[0])),
                std::array::from_fn(|i| inv[(i, iv)] / (d[i] * d[iv])),
            ))
        }
        _ => None,
    }
}

/// Reach of the residual's correlation the sandwich allows for, pixels: residuals up
/// to this far apart (in x and in y) are summed with Bartlett weights. A residual that
/// is not noise (the interpolant's mismatch along a sharp edge, a saturated highlight,
/// noise blurred by `--prefilter`) keeps its sign over neighbouring pixels, and counted
/// as independent its effect on u is underestimated. On the photographs of
/// `tests/real_images.rs`, 2 px cuts the points kept over 0.1 px off from 14 to 4.
pub const RESIDUAL_CORRELATION_PX: usize = 2;

/// The sandwich's meat `B = Σ_k Σ_l K(k, l) q_k q_lᵀ` with `q_k = J̃_k r_k` (the rows
/// of J̃ and the residuals r) and the Bartlett kernel
/// `K = (1 − |Δx|/(L + 1))(1 − |Δy|/(L + 1))` for |Δx|, |Δy| ≤ L =
/// [`RESIDUAL_CORRELATION_PX`] (Newey & West, Econometrica 55, 1987; positive
/// semi-definite), which is `Σ J̃J̃ᵀ r²` for L = 0, projected on `z` (a column of
/// `A_s⁻¹`): `zᵀBz`, the only entry the covariance needs. With the scores
/// `s_k = (z·J̃_k) r_k` it is `Σ_k Σ_l K(k, l) s_k s_l`: the scores' autocorrelation
/// `R(Δ) = Σ_k s_k s_{k+Δ}` at the (2L + 1)² lags, weighted by K, and `R(−Δ) = R(Δ)`
/// leaves `(L + 1) + L(2L + 1)` of them. The scores are laid out `nw + L` apart row
/// to row, with L zero columns after each row and zeros after the last
/// ([`padded_scores`]): a lag then is one offset into the buffer, the pairs across a
/// row's end meet the zeros, and every lag of both projections (u and v) is summed
/// in one pass over the buffer, a vector of pixels at a time. The caller scales the
/// results so that the residuals' mean square is the variance the noise model uses.
///
/// In single precision (twice the lanes of a vector): the scores' rounding (6e-8 of
/// each) and the sums' (a lane adds some 80 products) move the meat by a few parts
/// in a million, where its own sampling error over a subset's thousand residuals is
/// a few per cent. The scores are displacements (their weighted products sum to σ²,
/// pixels squared), so their size does not follow the images' grey-level units: a σ
/// of 1e-6 to 1 px puts them some ten orders of magnitude inside f32's range.
#[inline(always)]
fn meat(u: &[f32], v: &[f32], nw: usize, nh: usize) -> (f64, f64) {
    pulp::Arch::new().dispatch(Meat { u, v, nw, nh })
}

/// [`meat`]'s arguments, for its loop on the machine's vector units.
struct Meat<'a> {
    u: &'a [f32],
    v: &'a [f32],
    nw: usize,
    nh: usize,
}

impl pulp::WithSimd for Meat<'_> {
    type Output = (f64, f64);

    /// One pass over each buffer, a vector of pixels k at a time: the lags' weighted
    /// sum `t_k = Σ_m c_m s_{k + off_m}` by fused multiply-adds of unaligned loads,
    /// then `Σ_k s_k t_k` (the vector past the last row reads the padding's zeros).
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) -> Self::Output {
        const L: usize = RESIDUAL_CORRELATION_PX;
        const LAGS: usize = (L + 1) + L * (2 * L + 1);
        let Meat { u, v, nw, nh } = self;
        let stride = nw + L;
        let weight = |d: usize| 1.0 - d as f64 / (L as f64 + 1.0);
        let mut offsets = [0usize; LAGS];
        let mut coef = [simd.splat_f32s(0.0); LAGS];
        let mut m = 0;
        for dy in 0..=L {
            for dx in -(L as isize)..=L as isize {
                if dy == 0 && dx < 0 {
                    continue;
                }
                offsets[m] = (dy as isize * stride as isize + dx) as usize;
                let pair = if dy == 0 && dx == 0 { 1.0 } else { 2.0 };
                coef[m] = simd.splat_f32s((pair * weight(dx.unsigned_abs()) * weight(dy)) as f32);
                m += 1;
            }
        }
        // The buffers hold `MEAT_LANES` zeros past the farthest lag.
        const { assert!(S::F32_LANES <= MEAT_LANES) };
        let lanes = S::F32_LANES;
        let n = nh * stride;
        let whole = |s: &[f32], at: usize| S::as_simd_f32s(&s[at..at + lanes]).0[0];
        let mut out = [0.0f64; 2];
        for (o, s) in out.iter_mut().zip([u, v]) {
            let mut acc = simd.splat_f32s(0.0);
            let mut k = 0;
            while k < n {
                let mut t = simd.mul_f32s(coef[0], whole(s, k + offsets[0]));
                for (c, off) in coef.iter().zip(&offsets).skip(1) {
                    t = simd.mul_add_e_f32s(*c, whole(s, k + off), t);
                }
                acc = simd.mul_add_e_f32s(whole(s, k), t, acc);
                k += lanes;
            }
            *o = f64::from(simd.reduce_sum_f32s(acc));
        }
        (out[0], out[1])
    }
}

/// Writes the scores `score(k)` of the pixels k of an `nw x nh` subset (row-major)
/// into the padded layouts of [`padded_scores`] (`stride` apart).
#[inline(always)]
fn fill_padded(
    (su, sv): (&mut [f32], &mut [f32]),
    (nw, nh, stride): (usize, usize, usize),
    score: impl Fn(usize) -> (f64, f64),
) {
    let rows = su.chunks_exact_mut(stride).zip(sv.chunks_exact_mut(stride));
    for (j, (ru, rv)) in rows.take(nh).enumerate() {
        for (i, (a, b)) in ru[..nw].iter_mut().zip(&mut rv[..nw]).enumerate() {
            let (u, v) = score(j * nw + i);
            (*a, *b) = (u as f32, v as f32);
        }
    }
}

/// Most f32 lanes of a vector [`meat`] may meet (the zeros it may read past the
/// scores).
const MEAT_LANES: usize = 16;

/// Resizes `buf` to hold the scores of an `nw x nh` subset laid out for [`meat`]:
/// rows `nw + L` apart, the gaps zero, and zeros after the last row as far as the
/// farthest lag reaches. Returns the stride.
fn padded_scores(buf: &mut Vec<f32>, nw: usize, nh: usize) -> usize {
    let stride = nw + RESIDUAL_CORRELATION_PX;
    buf.clear();
    // [`meat`] reads whole vectors: up to a vector past the farthest lag.
    buf.resize(
        (nh + RESIDUAL_CORRELATION_PX) * stride + RESIDUAL_CORRELATION_PX + MEAT_LANES,
        0.0,
    );
    stride
}

/// The information matrix: `h` bordered by Σ J, Σ J·(f − f̄), n, 0 and Σ(f − f̄)².
fn augment<const M: usize, const N: usize>(
    h: &SMatrix<f64, M, M>,
    s1: [f64; M],
    sf: [f64; M],
    n: f64,
    ff: f64,
) -> SMatrix<f64, N, N> {
    let mut a = SMatrix::<f64, N, N>::zeros();
    a.fixed_view_mut::<M, M>(0, 0).copy_from(h);
    for i in 0..M {
        a[(i, M)] = s1[i];
        a[(M, i)] = s1[i];
        a[(i, M + 1)] = sf[i];
        a[(M + 1, i)] = sf[i];
    }
    a[(M, M)] = n;
    a[(M + 1, M + 1)] = ff;
    a
}

/// Prepares the subset centred at integer (x, y) of the reference; `None` when it does
/// not fit in the reference or has no texture.
#[inline(always)]
pub fn prepare(
    reference: &Reference,
    x: usize,
    y: usize,
    subset: Subset,
    shape: Shape,
) -> Option<Prepared> {
    prepare_reusing(reference, x, y, subset, shape, None, None)
}

/// [`prepare`] in the buffers of the subset `scratch` holds from the last
/// [`recycle`] (none at first): the field and point modes' way, with no allocation
/// from point to point.
#[inline(always)]
pub(crate) fn prepare_in(
    reference: &Reference,
    x: usize,
    y: usize,
    subset: Subset,
    shape: Shape,
    scratch: &mut Scratch,
    grid: Option<&GridSums>,
) -> Option<Prepared> {
    let sums = grid
        .filter(|_| subset.half_w == subset.half_h)
        .and_then(|g| g.at(x, y, subset.half_w));
    prepare_reusing(reference, x, y, subset, shape, scratch.spare.take(), sums)
}

/// The reference-only sums of a subset, pixel by pixel (the sums of a field's grid
/// are made together: [`GridSums`]): Σf, Σ J and Σ J·f, then the Hessian's moments.
#[inline(always)]
fn subset_sums(rs: &RefSubset) -> ([f64; 13], [f64; 18]) {
    let n = rs.f.len();
    // Two passes over the pixels. The first: the grey levels' sum, and the sums of
    // the steepest-descent images J = [gx, gx·dx, gx·dy, gy, gy·dx, gy·dy] alone and
    // times f (for the covariance with offset and gain eliminated; times f − f̄
    // below).
    let [f, gx, gy, dx, dy] = rs.slices();
    let first = lane_sums!(n, |a| {
        let (gx, gy, dx, dy, f) = (a.of(gx), a.of(gy), a.of(dx), a.of(dy), a.of(f));
        let (hx, hy) = (gx * f, gy * f);
        [
            f,
            gx,
            gx * dx,
            gx * dy,
            gy,
            gy * dx,
            gy * dy,
            hx,
            hx * dx,
            hx * dy,
            hy,
            hy * dx,
            hy * dy,
        ]
    },);
    // The second: the Hessian of the steepest-descent images (constant: computed
    // once), its 21 distinct products from 6 moments w = 1, dx, dy, dx², dx·dy, dy²
    // of each gradient product: mom[a][b] for a in {xx, xy, yy}.
    let second = lane_sums!(n, |a| {
        let (gx, gy, dx, dy) = (a.of(gx), a.of(gy), a.of(dx), a.of(dy));
        let w = [V::splat(1.0), dx, dy, dx * dx, dx * dy, dy * dy];
        let (xx, xy, yy) = (gx * gx, gx * gy, gy * gy);
        [
            xx * w[0],
            xx * w[1],
            xx * w[2],
            xx * w[3],
            xx * w[4],
            xx * w[5],
            xy * w[0],
            xy * w[1],
            xy * w[2],
            xy * w[3],
            xy * w[4],
            xy * w[5],
            yy * w[0],
            yy * w[1],
            yy * w[2],
            yy * w[3],
            yy * w[4],
            yy * w[5],
        ]
    },);
    (first, second)
}

/// Hands the buffers of a subset done with back to `scratch`, for [`prepare_in`].
pub(crate) fn recycle(prepared: Prepared, scratch: &mut Scratch) {
    scratch.spare = Some(prepared.rs);
}

#[inline(always)]
fn prepare_reusing(
    reference: &Reference,
    x: usize,
    y: usize,
    subset: Subset,
    shape: Shape,
    spare: Option<RefSubset>,
    sums: Option<&SubsetSums>,
) -> Option<Prepared> {
    let img = reference.image();
    if !subset.fits(x, y, img.width(), img.height()) {
        return None;
    }
    let mut rs = RefSubset::new(reference, x, y, subset, spare);
    let n = rs.f.len();
    let (first, second) = match sums {
        Some(s) => (s.first, s.second),
        None => subset_sums(&rs),
    };
    let mom: [[f64; 6]; 3] = std::array::from_fn(|a| std::array::from_fn(|b| second[6 * a + b]));
    let mean = first[0] / n as f64;
    rs.sum_gx2 = mom[0][0];
    rs.sum_gy2 = mom[2][0];
    for v in &mut rs.f {
        *v -= mean;
    }
    // From the centred values (exactly zero on a uniform subset).
    let f = &rs.f[..n];
    rs.df = lane_sums!(n, |a| [a.of(f) * a.of(f)])[0].sqrt();
    if rs.df == 0.0 || rs.sum_gx2 == 0.0 || rs.sum_gy2 == 0.0 {
        return None;
    }
    let s1: [f64; 6] = std::array::from_fn(|i| first[1 + i]);
    let sf: [f64; 6] = std::array::from_fn(|i| first[7 + i] - mean * s1[i]);
    let mut h6 = SMatrix::<f64, 6, 6>::zeros();
    let mut h2 = SMatrix::<f64, 2, 2>::zeros();
    let ff = rs.df * rs.df;
    match shape {
        Shape::Affine => {
            // Index of the weight (1, dx, dy) products: [i][j] -> moment column.
            let prod = [[0usize, 1, 2], [1, 3, 4], [2, 4, 5]];
            for r in 0..6 {
                for c in 0..6 {
                    let (gr, wr) = (r / 3, r % 3);
                    let (gc, wc) = (c / 3, c % 3);
                    let a = match (gr, gc) {
                        (0, 0) => 0,
                        (1, 1) => 2,
                        _ => 1,
                    };
                    h6[(r, c)] = mom[a][prod[wr][wc]];
                }
            }
        }
        Shape::Rigid => {
            h2[(0, 0)] = mom[0][0];
            h2[(0, 1)] = mom[1][0];
            h2[(1, 0)] = mom[1][0];
            h2[(1, 1)] = mom[2][0];
        }
    }
    let info = match shape {
        Shape::Affine => Information::Affine(augment::<6, 8>(&h6, s1, sf, n as f64, ff)),
        Shape::Rigid => Information::Rigid(augment::<2, 4>(
            &h2,
            [s1[0], s1[3]],
            [sf[0], sf[3]],
            n as f64,
            ff,
        )),
    };
    Some(Prepared {
        rs,
        x,
        y,
        subset,
        shape,
        h6_inv: h6.cholesky().map(|c| c.inverse()),
        h2_inv: h2.try_inverse(),
        info,
        spectrum: OnceLock::new(),
        degree: reference.spline.degree(),
    })
}

impl Prepared {
    /// The RMS of the reference's gradient over the subset along its weaker axis,
    /// grey levels per pixel.
    pub fn weakest_gradient(&self) -> f64 {
        let n = self.rs.f.len() as f64;
        (self.rs.sum_gx2.min(self.rs.sum_gy2) / n).sqrt()
    }

    /// The subset's gradient spectrum (computed once).
    fn spectrum(&self) -> &Spectrum {
        self.spectrum
            .get_or_init(|| Spectrum::new(&self.rs, self.subset))
    }
}

/// Refines the displacement of the subset centred at integer (x, y) of the reference,
/// starting from `initial` = (u, ∂u/∂x, ∂u/∂y, v, ∂v/∂x, ∂v/∂y). Returns `None` when the
/// subset does not fit in the reference, has no texture, or its warp leaves `current`.
#[allow(clippy::too_many_arguments)]
pub fn refine(
    reference: &Reference,
    current: &BSpline,
    x: usize,
    y: usize,
    subset: Subset,
    shape: Shape,
    initial: [f64; 6],
    opts: &IcgnOptions,
) -> Option<PointResult> {
    let p = prepare(reference, x, y, subset, shape)?;
    refine_prepared(&p, current, initial, opts)
}

/// Buffers of one thread's refinements, reused from point to point and iteration to
/// iteration (no allocation inside the correlation).
#[derive(Debug, Default, Clone)]
pub struct Scratch {
    /// The current image at the warped subset.
    g: Vec<f64>,
    /// Separable interpolation's intermediate rows.
    tmp: Vec<f64>,
    /// Residuals at the solution.
    residuals: Vec<f64>,
    /// The interpolation mismatch at the subset's pixels.
    pub(crate) mismatch: Vec<f64>,
    /// The sandwich's buffers.
    sandwich: Sandwich,
    /// What a unit change of the current image at each pixel of the subset does to
    /// the match to first order, u and v, means removed ([`influence`]).
    influence_u: Vec<f64>,
    influence_v: Vec<f64>,
    /// The buffers of the last subset [`recycle`]d.
    spare: Option<RefSubset>,
}

/// Prepares `scratch` for [`Scratch::first_order`] on the subset: the rows of the
/// Gauss-Newton step `−H⁻¹ Σ J (e − ē)` for u and v, as weights on each pixel's `e`.
/// `None` when the subset's Hessian is singular.
#[inline(always)]
pub(crate) fn influence(prepared: &Prepared, scratch: &mut Scratch) -> Option<()> {
    let rs = &prepared.rs;
    let n = rs.f.len();
    let (iu, iv) = (&mut scratch.influence_u, &mut scratch.influence_v);
    iu.resize(n, 0.0);
    iv.resize(n, 0.0);
    let (iu, iv) = (&mut iu[..n], &mut iv[..n]);
    let [_, gx, gy, dx, dy] = rs.slices();
    match prepared.shape {
        Shape::Affine => {
            let h = prepared.h6_inv?;
            let row = |i: usize| -> [f64; 6] { std::array::from_fn(|j| -h[(i, j)]) };
            let (ru, rv) = (row(0), row(3));
            for k in 0..n {
                let (gx, gy, dx, dy) = (gx[k], gy[k], dx[k], dy[k]);
                iu[k] =
                    gx * (ru[0] + ru[1] * dx + ru[2] * dy) + gy * (ru[3] + ru[4] * dx + ru[5] * dy);
                iv[k] =
                    gx * (rv[0] + rv[1] * dx + rv[2] * dy) + gy * (rv[3] + rv[4] * dx + rv[5] * dy);
            }
        }
        Shape::Rigid => {
            let h = -prepared.h2_inv?;
            for k in 0..n {
                iu[k] = h[(0, 0)] * gx[k] + h[(0, 1)] * gy[k];
                iv[k] = h[(1, 0)] * gx[k] + h[(1, 1)] * gy[k];
            }
        }
    }
    let [mu, mv] = lane_sums!(n, |a| [a.of(iu), a.of(iv)]);
    let (mu, mv) = (mu / n as f64, mv / n as f64);
    for k in 0..n {
        iu[k] -= mu;
        iv[k] -= mv;
    }
    Some(())
}

impl Scratch {
    /// [`Scratch::first_order`], for the tests of other modules.
    #[cfg(test)]
    pub(crate) fn first_order_for_test(&self, e: &[f64]) -> (f64, f64) {
        self.first_order(e)
    }

    /// [`first_order_change`] of `e` on the subset of the last [`influence`].
    #[inline(always)]
    fn first_order(&self, e: &[f64]) -> (f64, f64) {
        let n = e.len();
        let (a, b) = (&self.influence_u[..n], &self.influence_v[..n]);
        let [u, v] = lane_sums!(n, |at| [at.of(a) * at.of(e), at.of(b) * at.of(e)]);
        (u, v)
    }
}

/// Buffers of the sandwich covariance: the scores of its projections on u and v, laid
/// out for [`meat`].
#[derive(Debug, Default, Clone)]
struct Sandwich {
    scores_u: Vec<f32>,
    scores_v: Vec<f32>,
}

/// The outcome of the iteration alone (no σ): the residuals stay in the scratch.
#[derive(Debug, Clone, Copy)]
#[doc(hidden)]
pub struct Iterated {
    pub(crate) p: [f64; 6],
    /// The parameters of the last warp: the current image's values at them stay in the
    /// scratch (`p` is one update further).
    pub(crate) sampled: [f64; 6],
    /// The spread `√Σ(g − ḡ)²` of those values.
    pub(crate) spread: f64,
    pub(crate) iterations: usize,
    pub(crate) converged: bool,
    pub(crate) zncc: f64,
    /// Σ r² of the residuals.
    pub(crate) residual2: f64,
}

/// Phases per pixel of the table of [`LineResponses`].
const LINE_PHASES: usize = 64;

/// [`LineResponses`] at phase `t`, interpolated linearly in a table over the phase
/// kept for the process and pair of degrees (the responses are smooth in `t`). Each
/// of the table's phases is made when a match first reads it: a field meets a few
/// (its shifts' fractional parts), and the whole table, three line splines per phase,
/// took 4 ms of one thread while the other waited for it.
#[inline(always)]
fn line_responses(current: Degree, reference: Degree, t: f64) -> LineResponses {
    type Table = [OnceLock<LineResponses>; LINE_PHASES + 1];
    static TABLES: [Table; 4] = [const { [const { OnceLock::new() }; LINE_PHASES + 1] }; 4];
    let k = 2 * usize::from(current == Degree::Quintic) + usize::from(reference == Degree::Quintic);
    let at = |p: usize| {
        TABLES[k][p]
            .get_or_init(|| LineResponses::new(current, reference, p as f64 / LINE_PHASES as f64))
    };
    let scaled = (t - t.floor()) * LINE_PHASES as f64;
    let p = (scaled as usize).min(LINE_PHASES - 1);
    let a = scaled - p as f64;
    let (l0, l1) = (at(p), at(p + 1));
    let mix = |x: f64, y: f64| (1.0 - a) * x + a * y;
    LineResponses {
        gain: mix(l0.gain, l1.gain),
        mismatch_noise: mix(l0.mismatch_noise, l1.mismatch_noise),
        centre: mix(l0.centre, l1.centre),
    }
}

/// [`corrected`] for a match fresh from [`iterate`], with the subset's [`influence`]
/// and the interpolation error at its pixels already in `scratch` (from the image's tables,
/// [`crate::correction::Corrections::mismatch`]): the field and point modes' way.
#[inline(always)]
pub(crate) fn correct(
    prepared: &Prepared,
    it: &Iterated,
    current_spline: &BSpline,
    scratch: &mut Scratch,
    opts: &IcgnOptions,
    kappa: f64,
) -> Option<PointResult> {
    let res = it.result(prepared);
    let current = current_spline.degree();
    let e = &scratch.mismatch;
    let (bu, bv) = scratch.first_order(e);
    // The reference noise's mean share of it (`LineResponses::mismatch_noise`), taken
    // back; the noise level is the iteration's.
    let n = prepared.rs.f.len();
    let params = match prepared.shape {
        Shape::Affine => 8.0,
        Shape::Rigid => 4.0,
    };
    let noise2 = 0.5 * (it.residual2 / (n as f64 - params).max(1.0)).max(opts.residual_floor);
    let lx = line_responses(current, prepared.degree, res.u);
    let ly = line_responses(current, prepared.degree, res.v);
    let load = n as f64 * noise2;
    let (nu, nv) = noise_share(prepared, &lx, &ly, load)?;
    let (bu, bv) = (bu - nu, bv - nv);
    // The residuals at the corrected solution, the current image's values less the
    // mismatch.
    let rs = &prepared.rs;
    let mut p = it.p;
    p[0] -= bu;
    p[3] -= bv;
    // The current image's values there, from those of the iteration's last warp (at
    // `it.sampled`, within a few hundredths of a pixel of `p`): to first order,
    // moved along the image's gradient by the change of each pixel's position. The
    // gradient is the reference's, scaled by the contrast between the images (the
    // match maps one onto the other): the neglected second-order term is the
    // texture's curvature times the squared move, some 0.01 grey levels here against
    // a noise of grey levels, and a warp of the whole subset is saved.
    let (hw, hh) = (prepared.subset.half_w, prepared.subset.half_h);
    let corners = warped_corners(prepared.x as f64, prepared.y as f64, hw, hh, &p);
    if !corners
        .iter()
        .all(|&(x, y)| current_spline.contains(x, y, 2.0))
    {
        return None;
    }
    let d: [f64; 6] = std::array::from_fn(|i| p[i] - it.sampled[i]);
    let [f, gx, gy, dx, dy] = rs.slices();
    let g = &mut scratch.g[..n];
    let e = &e[..n];
    let contrast = it.spread / rs.df;
    for k in 0..n {
        let (mx, my) = (
            d[0] + d[1] * dx[k] + d[2] * dy[k],
            d[3] + d[4] * dx[k] + d[5] * dy[k],
        );
        g[k] += contrast * (gx[k] * mx + gy[k] * my) - e[k];
    }
    let g = &scratch.g[..n];
    let [sum, sum2] = lane_sums!(n, |a| [a.of(g), a.of(g) * a.of(g)]);
    let gm = sum / n as f64;
    let dg = (sum2 - sum * gm).max(0.0).sqrt();
    if dg == 0.0 {
        return None;
    }
    let ratio = rs.df / dg;
    let r = &mut scratch.residuals[..n];
    for k in 0..n {
        r[k] = f[k] - ratio * (g[k] - gm);
    }
    let r = &scratch.residuals[..n];
    let residual2 = lane_sums!(n, |a| [a.of(r) * a.of(r)])[0];
    let gain = lx.gain * ly.gain;
    let (cov, var) = noise_covariance(
        prepared,
        &scratch.residuals,
        residual2,
        opts,
        gain,
        &mut scratch.sandwich,
    );
    Some(PointResult {
        u: res.u - bu,
        v: res.v - bv,
        zncc: 1.0 - 0.5 * residual2 / (rs.df * rs.df),
        sigma_u: (cov.0 + (kappa * bu).powi(2)).sqrt(),
        sigma_v: (cov.1 + (kappa * bv).powi(2)).sqrt(),
        sigma_noise: (0.5 * var).sqrt(),
        ..res
    })
}

/// [`rounding_error`] from the image's rounding tables (phases
/// `ROUNDING_PHASES[1..]`, row-major over a reference `width` pixels wide; phase 0
/// has no residual): the RMS over the four phases of the first-order change each
/// residual makes in the match. `scratch` holds the subset's [`influence`].
#[inline(always)]
pub(crate) fn rounding_from_tables(
    prepared: &Prepared,
    tables: &[Vec<f32>],
    width: usize,
    scratch: &mut Scratch,
) -> (f64, f64) {
    let s = prepared.subset;
    let nw = 2 * s.half_w + 1;
    let (mut su, mut sv) = (0.0, 0.0);
    for table in tables {
        let mut e = std::mem::take(&mut scratch.mismatch);
        e.clear();
        for j in 0..2 * s.half_h + 1 {
            let start = (prepared.y - s.half_h + j) * width + prepared.x - s.half_w;
            e.extend(table[start..start + nw].iter().map(|v| f64::from(*v)));
        }
        let (du, dv) = scratch.first_order(&e);
        scratch.mismatch = e;
        su += du * du;
        sv += dv * dv;
    }
    let phases = ROUNDING_PHASES.len() as f64;
    ((su / phases).sqrt(), (sv / phases).sqrt())
}

/// [`refine`] with a prepared reference subset.
pub fn refine_prepared(
    prepared: &Prepared,
    current: &BSpline,
    initial: [f64; 6],
    opts: &IcgnOptions,
) -> Option<PointResult> {
    let mut scratch = Scratch::default();
    let it = iterate(prepared, current, initial, opts, &mut scratch)?;
    let (cov, var) = noise_covariance(
        prepared,
        &scratch.residuals,
        it.residual2,
        opts,
        1.0,
        &mut scratch.sandwich,
    );
    let sigma_noise = (0.5 * var).sqrt();
    let spectrum = prepared.spectrum();
    let p = it.p;
    // The reference's noise variance is half the residual's.
    let bias_u = interpolation_bias_1d(
        current.degree(),
        prepared.degree,
        p[0],
        &spectrum.x,
        0.5 * var * spectrum.white_x,
    );
    let bias_v = interpolation_bias_1d(
        current.degree(),
        prepared.degree,
        p[3],
        &spectrum.y,
        0.5 * var * spectrum.white_y,
    );
    Some(PointResult {
        sigma_u: (cov.0 + bias_u * bias_u).sqrt(),
        sigma_v: (cov.1 + bias_v * bias_v).sqrt(),
        sigma_noise,
        ..it.result(prepared)
    })
}

impl Iterated {
    /// The result without σ (infinite) and with the noise unknown (0).
    pub(crate) fn result(&self, prepared: &Prepared) -> PointResult {
        let p = self.p;
        PointResult {
            x: prepared.x as f64,
            y: prepared.y as f64,
            u: p[0],
            v: p[3],
            gradients: [p[1], p[2], p[4], p[5]],
            zncc: self.zncc,
            iterations: self.iterations,
            converged: self.converged,
            sigma_u: f64::INFINITY,
            sigma_v: f64::INFINITY,
            sigma_noise: 0.0,
            subset: 2 * prepared.subset.half_w.max(prepared.subset.half_h) + 1,
        }
    }
}

/// Past iterates [`Anderson`] mixes: enough for the few directions in which a
/// weak texture's iteration contracts slowly (with one, the step that follows a
/// stretched one turns away, and only every other step gains).
const ANDERSON_DEPTH: usize = 3;

/// Largest move of an accelerated iterate away from the plain Gauss-Newton update,
/// as a multiple of the plain step: a contraction ratio of 0.9 along one direction.
const MAX_STRETCH: f64 = 10.0;

/// Anderson acceleration of the IC-GN iteration (Walker and Ni, "Anderson acceleration
/// for fixed-point iterations", SIAM J. Numer. Anal. 49 (2011), eq. (2.1), depth
/// [`ANDERSON_DEPTH`]).
///
/// Why: the inverse-compositional Hessian is the reference's, whose gradients carry
/// the reference's noise, which the current image does not share. Where the texture
/// is weak beside the noise (a sky, a dark coat), every step falls short of the
/// solution by about the noise's share of the gradient energy (0.75-0.8 measured on
/// the photographs' low-texture subsets, where the field's 5e-4 px took 15
/// iterations or more). The iteration is then a linear contraction x ← g(x) near its
/// fixed point, and Anderson's mixing of the last few iterates (GMRES on the linear
/// part) reaches the fixed point in a few steps.
///
/// The fixed point, where the criterion's gradient vanishes, does not depend on the
/// steps' lengths, so neither does the result; the stopping rule still reads the
/// plain Gauss-Newton step at the iterate, whose size is the distance to the fixed
/// point times 1 − r. The parameters are mixed as a vector; a mixed iterate further
/// than [`MAX_STRETCH`] plain steps from the plain update, or a least-squares problem
/// without a solution, restarts the history from the plain update.
struct Anderson {
    /// Iterates x_i, oldest first.
    x: [[f64; 6]; ANDERSON_DEPTH + 1],
    /// Their plain updates g(x_i).
    g: [[f64; 6]; ANDERSON_DEPTH + 1],
    len: usize,
    /// Weights of the parameters in the norm: 1 for a translation, the subset's
    /// corner distance squared for a gradient (the stopping rule's measure).
    w: [f64; 6],
}

impl Anderson {
    fn new(corner: f64) -> Self {
        let c2 = corner * corner;
        Anderson {
            x: [[0.0; 6]; ANDERSON_DEPTH + 1],
            g: [[0.0; 6]; ANDERSON_DEPTH + 1],
            len: 0,
            w: [1.0, c2, c2, 1.0, c2, c2],
        }
    }

    fn dot(&self, a: &[f64; 6], b: &[f64; 6]) -> f64 {
        (0..6).map(|i| self.w[i] * a[i] * b[i]).sum()
    }

    /// The next iterate after `x`, whose plain Gauss-Newton update is `gx`.
    #[inline(always)]
    fn next(&mut self, x: [f64; 6], gx: [f64; 6]) -> [f64; 6] {
        if self.len == ANDERSON_DEPTH + 1 {
            self.x.copy_within(1.., 0);
            self.g.copy_within(1.., 0);
            self.len -= 1;
        }
        self.x[self.len] = x;
        self.g[self.len] = gx;
        self.len += 1;
        let m = self.len - 1;
        if m == 0 {
            return gx;
        }
        let f = |i: usize| -> [f64; 6] { std::array::from_fn(|k| self.g[i][k] - self.x[i][k]) };
        let last = f(m);
        // Columns ΔF_j = f_{j+1} − f_j; γ = argmin |f_m − ΔF γ| (weighted).
        let df: [[f64; 6]; ANDERSON_DEPTH] = std::array::from_fn(|j| {
            if j < m {
                let (a, b) = (f(j + 1), f(j));
                std::array::from_fn(|k| a[k] - b[k])
            } else {
                [0.0; 6]
            }
        });
        let mut a = SMatrix::<f64, ANDERSON_DEPTH, ANDERSON_DEPTH>::identity();
        let mut rhs = SVector::<f64, ANDERSON_DEPTH>::zeros();
        for i in 0..m {
            rhs[i] = self.dot(&df[i], &last);
            for j in 0..m {
                a[(i, j)] = self.dot(&df[i], &df[j]);
            }
            // A tiny ridge keeps nearly parallel columns solvable.
            a[(i, i)] *= 1.0 + 1e-10;
        }
        let plain = self.dot(&last, &last);
        let mixed = a.cholesky().map(|c| c.solve(&rhs)).and_then(|gamma| {
            let out: [f64; 6] = std::array::from_fn(|k| {
                gx[k]
                    - (0..m)
                        .map(|j| gamma[j] * (self.g[j + 1][k] - self.g[j][k]))
                        .sum::<f64>()
            });
            let moved: [f64; 6] = std::array::from_fn(|k| out[k] - gx[k]);
            (out.iter().all(|v| v.is_finite())
                && self.dot(&moved, &moved) <= MAX_STRETCH * MAX_STRETCH * plain)
                .then_some(out)
        });
        mixed.unwrap_or_else(|| {
            self.x[0] = x;
            self.g[0] = gx;
            self.len = 1;
            gx
        })
    }
}

/// The IC-GN iteration of [`refine_prepared`]: the residuals at the solution are left
/// in `scratch.residuals`.
#[doc(hidden)]
#[inline(always)]
pub fn iterate(
    prepared: &Prepared,
    current: &BSpline,
    initial: [f64; 6],
    opts: &IcgnOptions,
    scratch: &mut Scratch,
) -> Option<Iterated> {
    let Prepared {
        rs,
        x,
        y,
        subset,
        shape,
        h6_inv,
        h2_inv,
        ..
    } = prepared;
    let (x, y, subset, shape, h6_inv, h2_inv) = (*x, *y, *subset, *shape, *h6_inv, *h2_inv);
    let n = rs.f.len();
    let Scratch {
        g, tmp, residuals, ..
    } = scratch;
    residuals.clear();
    residuals.resize(n, 0.0);
    let (xc, yc) = (x as f64, y as f64);
    let corner = subset.half_w.max(subset.half_h) as f64;
    let mut p = match shape {
        Shape::Affine => initial,
        Shape::Rigid => [initial[0], 0.0, 0.0, initial[3], 0.0, 0.0],
    };
    let margin = 2.0;
    let mut iterations = 0;
    let mut converged = false;
    let mut residual2 = 0.0;
    let mut zncc = 0.0;
    let mut sampled = p;
    let mut spread = 0.0;
    let mut anderson = Anderson::new(corner);
    // The last update's size and its ratio to the one before (none yet: 0).
    let (mut last_step, mut last_ratio) = (f64::INFINITY, 0.0);
    // The warp in single precision where the steps it must resolve allow.
    let single = opts.tolerance >= crate::warp::SINGLE_PRECISION_TOLERANCE;
    while iterations < opts.max_iterations {
        iterations += 1;
        sampled = p;
        // Interpolate the current image at the warped subset.
        match shape {
            Shape::Rigid => {
                let (cx, cy) = (xc + p[0], yc + p[3]);
                if !current.contains(cx - subset.half_w as f64, cy - subset.half_h as f64, margin)
                    || !current.contains(
                        cx + subset.half_w as f64,
                        cy + subset.half_h as f64,
                        margin,
                    )
                {
                    return None;
                }
                // One fractional offset for the whole subset: one set of weights, and
                // the subset interpolated as a block (separably).
                let (fx, fy) = (cx.floor(), cy.floor()); // once per iteration
                let d = current.degree();
                let (wx, wy) = (d.weights(cx - fx), d.weights(cy - fy));
                current.translated_block(fx, fy, subset.half_w, subset.half_h, &wx, &wy, tmp, g);
            }
            Shape::Affine => {
                let (hw, hh) = (subset.half_w, subset.half_h);
                if !current.warped_block_with(xc, yc, hw, hh, &p, margin, single, g) {
                    return None;
                }
            }
        }
        let gs = &g[..n];
        let [sum, sum2] = lane_sums!(n, |a| [a.of(gs), a.of(gs) * a.of(gs)]);
        let gm = sum / n as f64;
        let dg = (sum2 - sum * gm).max(0.0).sqrt();
        if dg == 0.0 {
            return None;
        }
        spread = dg;
        let ratio = rs.df / dg;
        // Residual and gradient of the criterion.
        let [f, gx, gy, dx, dy] = rs.slices();
        let res = &mut residuals[..n];
        for k in 0..n {
            res[k] = f[k] - ratio * (gs[k] - gm);
        }
        let res = &residuals[..n];
        let [b0, b1, b2, b3, b4, b5, r2] = lane_sums!(n, |a| {
            let r = a.of(res);
            let (dx, dy) = (a.of(dx), a.of(dy));
            let (ex, ey) = (a.of(gx) * r, a.of(gy) * r);
            [ex, ex * dx, ex * dy, ey, ey * dx, ey * dy, r * r]
        },);
        let b6 = [b0, b1, b2, b3, b4, b5];
        residual2 = r2;
        zncc = 1.0 - 0.5 * residual2 / (rs.df * rs.df);
        let dp: [f64; 6] = match shape {
            Shape::Affine => {
                let d = -(h6_inv?) * SVector::<f64, 6>::from(b6);
                [d[0], d[1], d[2], d[3], d[4], d[5]]
            }
            Shape::Rigid => {
                let d = -(h2_inv?) * SVector::<f64, 2>::new(b6[0], b6[3]);
                [d[0], 0.0, 0.0, d[1], 0.0, 0.0]
            }
        };
        // W(p) ← W(p) ∘ W(Δp)⁻¹, mixed with the last iterates (see `Anderson`).
        let dw = warp_matrix(&dp).try_inverse()?;
        p = anderson.next(p, params_of(&(warp_matrix(&p) * dw)));
        let step = (dp[0] * dp[0]
            + dp[3] * dp[3]
            + corner * corner * (dp[1] * dp[1] + dp[2] * dp[2] + dp[4] * dp[4] + dp[5] * dp[5]))
            .sqrt();
        if !p.iter().all(|v| v.is_finite()) {
            return None;
        }
        let ratio = step / last_step;
        // Stopped where the update is below the tolerance, or where what the updates
        // after it would still move is below a tenth of it (an update saved; the
        // solution then differs from the fully converged one by 5e-5 px at most in
        // the field-against-points test, 1.5e-5 px when each point iterated on).
        if step < opts.tolerance
            || predicted_rest(step, ratio.max(last_ratio)) < 0.1 * opts.tolerance
        {
            converged = true;
            break;
        }
        (last_step, last_ratio) = (step, ratio);
    }
    Some(Iterated {
        p,
        sampled,
        spread,
        iterations,
        converged,
        zncc,
        residual2,
    })
}

#[cfg(test)]
mod tests {
    use super::{
        Anderson, BSpline, Degree, IcgnOptions, MAX_STRETCH, RESIDUAL_CORRELATION_PX, Reference,
        SVector, Shape, Subset, meat, padded_scores, refine,
    };
    use crate::synth::{Speckle, SpeckleParams};

    #[test]
    fn the_meat_is_the_bartlett_weighted_double_sum_of_the_scores() {
        // Independent: Σ_k Σ_l K(k, l) s_k s_l over every pair of pixels, K the
        // separable Bartlett kernel, on pseudo-random scores of several subset shapes.
        let lag = RESIDUAL_CORRELATION_PX as f64;
        let weight = |d: usize| (1.0 - d as f64 / (lag + 1.0)).max(0.0);
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for (nw, nh) in [(1usize, 1usize), (2, 5), (7, 5), (33, 33), (41, 29)] {
            // Scores as the sandwich stores them: the independent sum reads the
            // same values, in double precision.
            let s: Vec<f64> = (0..nw * nh).map(|_| f64::from(next() as f32)).collect();
            let mut direct = 0.0f64;
            for k in 0..nw * nh {
                for l in 0..nw * nh {
                    let (dx, dy) = ((k % nw).abs_diff(l % nw), (k / nw).abs_diff(l / nw));
                    direct += weight(dx) * weight(dy) * s[k] * s[l];
                }
            }
            let mut buf = Vec::new();
            let stride = padded_scores(&mut buf, nw, nh);
            for (k, v) in s.iter().enumerate() {
                buf[k / nw * stride + k % nw] = *v as f32;
            }
            let (m, same) = meat(&buf, &buf, nw, nh);
            assert_eq!(m, same);
            // Single precision's sums: each product carries a rounding of f32's
            // epsilon (1.2e-7) and each of a lane's terms at most n / lanes more of
            // them (a bound on the sum's error, Higham §4.2), against the sum of the
            // products' magnitudes.
            let magnitude: f64 = (0..nw * nh)
                .map(|k| {
                    (0..nw * nh)
                        .map(|l| {
                            let (dx, dy) = ((k % nw).abs_diff(l % nw), (k / nw).abs_diff(l / nw));
                            (weight(dx) * weight(dy) * s[k] * s[l]).abs()
                        })
                        .sum::<f64>()
                })
                .sum();
            let bound = (2.0 + (nw * nh) as f64 / 8.0) * f64::from(f32::EPSILON) * magnitude;
            assert!(
                (m - direct).abs() <= bound,
                "{nw} x {nh}: {m} against {direct} (bound {bound})"
            );
        }
    }

    #[test]
    fn a_linear_contraction_reaches_its_fixed_point_in_a_few_mixed_steps() {
        // g(x) = M x + c with a contraction M of ratios 0.9, 0.8, 0.6 along three
        // directions (and 0.1 along the rest): plain iteration needs about 200 steps to
        // get within 1e-9 of the fixed point x* = (I − M)⁻¹ c; mixed, the error falls
        // with the depth's directions resolved, and the fixed point is the same.
        let q = nalgebra::Matrix6::<f64>::from_fn(|i, j| ((i * 7 + j * 3) % 11) as f64 - 5.0)
            .qr()
            .q();
        let m =
            q * nalgebra::Matrix6::from_diagonal(&SVector::<f64, 6>::from([
                0.9, 0.8, 0.6, 0.1, 0.1, 0.1,
            ])) * q.transpose();
        let c = SVector::<f64, 6>::from([0.03, -0.01, 0.02, 0.05, 0.0, -0.02]);
        let fixed = (nalgebra::Matrix6::identity() - m).try_inverse().unwrap() * c;
        let g = |x: &[f64; 6]| -> [f64; 6] {
            let y = m * SVector::<f64, 6>::from(*x) + c;
            std::array::from_fn(|k| y[k])
        };
        let mut acc = Anderson::new(1.0);
        let mut x = [0.0; 6];
        let mut steps = 0;
        while (0..6).map(|k| (x[k] - fixed[k]).abs()).fold(0.0, f64::max) > 1e-9 {
            x = acc.next(x, g(&x));
            steps += 1;
            assert!(
                steps <= 25,
                "{steps} mixed steps and still {x:?} against {fixed:?}"
            );
        }
    }

    #[test]
    fn a_mixed_step_never_strays_far_from_the_plain_update() {
        // Iterates that jump about (far from the solution, Gauss-Newton is not a
        // contraction): every mixed iterate stays within MAX_STRETCH plain steps of
        // the plain update.
        let mut acc = Anderson::new(16.0);
        let mut x = [0.3, 0.01, -0.02, -0.4, 0.0, 0.01];
        for k in 0..12 {
            let s = if k % 2 == 0 { 1.0 } else { -0.7 };
            let gx: [f64; 6] = std::array::from_fn(|i| x[i] * (1.0 - s) + 0.05 * s);
            let plain: f64 = (0..6).map(|i| acc.w[i] * (gx[i] - x[i]).powi(2)).sum();
            let next = acc.next(x, gx);
            let moved: f64 = (0..6).map(|i| acc.w[i] * (next[i] - gx[i]).powi(2)).sum();
            assert!(
                moved <= MAX_STRETCH * MAX_STRETCH * plain * (1.0 + 1e-12),
                "step {k}"
            );
            x = next;
        }
    }

    #[test]
    fn the_predicted_rest_is_the_geometric_tail_and_none_without_contraction() {
        // 1e-3 then 1e-4, 1e-5, ...: what is left after 1e-3 is 1e-3·0.1/0.9.
        assert!((super::predicted_rest(1e-3, 0.1) - 1e-3 / 9.0).abs() < 1e-18);
        for r in [0.0, 1.0, 1.5, f64::NAN, f64::INFINITY] {
            assert_eq!(super::predicted_rest(1e-3, r), f64::INFINITY, "r = {r}");
        }
    }

    #[test]
    fn a_weak_texture_converges_to_one_solution_from_either_side() {
        // Faint speckles under noise: the reference's gradients are mostly noise, and
        // each plain Gauss-Newton step falls short by a steady share (about 0.9 here,
        // measured; 0.75-0.8 on the photographs' skies), so plain iteration would take
        // some 150 steps from 0.1 px to 1e-8 px, far beyond the 40 allowed.
        let params = SpeckleParams {
            amplitude: [4.0, 6.0],
            noise: 2.0,
            bits: 0,
            ..SpeckleParams::default_for(96, 96)
        };
        let sp = Speckle::new(&params, 3);
        let reference =
            Reference::with_degree(sp.render_shifted(0.0, 0.0, 0.0, 1), Degree::Quintic);
        let current = BSpline::with_degree(&sp.render_shifted(0.4, -0.3, 0.0, 2), Degree::Quintic);
        let opts = IcgnOptions {
            tolerance: 1e-8,
            max_iterations: 40,
            ..IcgnOptions::default()
        };
        let at = |tolerance: f64, start: [f64; 6]| {
            refine(
                &reference,
                &current,
                48,
                48,
                Subset::square(31),
                Shape::Affine,
                start,
                &IcgnOptions { tolerance, ..opts },
            )
            .expect("a match")
        };
        let solve = |u: f64, v: f64| at(opts.tolerance, [u, 0.0, 0.0, v, 0.0, 0.0]);
        let (a, b) = (solve(0.1, -0.6), solve(0.7, 0.0));
        for r in [&a, &b] {
            assert!(r.converged, "not converged in {} iterations", r.iterations);
        }
        assert!(
            (a.u - b.u).abs() < 1e-7 && (a.v - b.v).abs() < 1e-7,
            "{a:?} {b:?}"
        );
        // At a tolerance of `SINGLE_PRECISION_TOLERANCE` the warp runs in single
        // precision: on this faint texture, where its rounding weighs most, it
        // converges as double precision does, and stops as close to the fixed point
        // (`a`) as double precision's stop just under that tolerance, to within a
        // tenth of it (both stop some 6e-5 px short: the steps shrink by only 0.9
        // each; the precisions' stops were 5e-6 to 8e-6 px apart).
        let t = crate::warp::SINGLE_PRECISION_TOLERANCE;
        for start in [
            [0.1, 0.0, 0.0, -0.6, 0.0, 0.0],
            [0.7, 0.0, 0.0, 0.0, 0.0, 0.0],
        ] {
            let (single, double) = (at(t, start), at(t * (1.0 - 1e-9), start));
            assert!(
                single.converged,
                "single precision: {} iterations",
                single.iterations
            );
            let off = |r: &crate::PointResult| ((r.u - a.u).abs(), (r.v - a.v).abs());
            let (s, d) = (off(&single), off(&double));
            assert!(
                s.0 < d.0 + 0.1 * t && s.1 < d.1 + 0.1 * t,
                "single precision {s:?} px off, double {d:?}: {single:?} {double:?}"
            );
        }
    }

    #[test]
    fn a_subset_fits_exactly_its_image_and_a_centre_near_usize_max_does_not_overflow() {
        let s = Subset::square(31);
        assert!(s.fits(15, 15, 31, 31));
        assert!(!s.fits(15, 15, 30, 31));
        assert!(!s.fits(15, 15, 31, 30));
        assert!(!s.fits(14, 15, 64, 64));
        // `dic --at 1e300,1e300` saturates to usize::MAX: refused, not an overflow.
        assert!(!s.fits(usize::MAX, 20, 64, 64));
        assert!(!s.fits(20, usize::MAX - 3, 64, 64));
    }
}
