//! # cellinject-dic
//!
//! Digital image correlation: nanometre measurement of the end-effector from microscope
//! frames (paper Sec. 4), fast enough to close a loop at camera rate.
//!
//! Pipeline (the one of the best open tools): integer search by FFT-based ZNCC, coarse
//! to fine ([`search`]); sub-pixel refinement by IC-GN with the ZNSSD criterion and a
//! first-order or translation shape function ([`icgn`]); quintic (or cubic) B-spline interpolation
//! with the recursive prefilter ([`bspline`]). On top: points ([`correlate_points`]),
//! full fields with reliability-guided propagation in parallel ([`field`]), tracking of a
//! region through a sequence ([`track`]), and the image-to-stage calibration
//! ([`calib`]). [`synth`] makes exact synthetic speckle images for tests and benchmarks.
//!
//! Coordinates are pixels, x = column, y = row, origin at the centre of the top-left
//! pixel; a point (x, y) of the reference is found at (x + u, y + v) in the current image.
//!
//! **Architecture invariant:** pure computation: images in, numbers out. No file, no
//! clock, no device.

pub mod accept;
pub mod bspline;
pub mod calib;
pub mod correction;
pub mod field;
pub mod icgn;
pub mod image;
mod lanes;
pub mod search;
pub mod synth;
pub mod track;
pub mod warp;

use rayon::prelude::*;
use thiserror::Error;

pub use accept::{Acceptance, Dropped, Rejection, judge};
pub use bspline::{BSpline, Degree};
pub use icgn::{IcgnOptions, PointResult, Reference, Shape, Subset};
pub use image::Image;

/// Smallest and largest subset size, pixels.
pub const SUBSET_RANGE: (usize, usize) = (7, 401);

/// What the DIC refuses.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum DicError {
    /// The image is empty, of the wrong size, or holds non-finite values.
    #[error("bad image: {reason}")]
    BadImage {
        /// What is wrong.
        reason: String,
    },
    /// Reference and current images differ in size.
    #[error("the images differ in size: {a:?} and {b:?}")]
    SizeMismatch {
        /// Reference (width, height).
        a: (usize, usize),
        /// Current (width, height).
        b: (usize, usize),
    },
    /// A subset size outside the allowed range, or even.
    #[error("subset {size} must be an odd number of pixels in [{min}, {max}]")]
    SubsetSize {
        /// Requested size.
        size: usize,
        /// Smallest allowed.
        min: usize,
        /// Largest allowed.
        max: usize,
    },
    /// The subset around a point leaves the image.
    #[error(
        "the {size}x{size} subset at ({}, {}) leaves the {width}x{height} image",
        short(.x),
        short(.y)
    )]
    SubsetOutside {
        /// Point.
        x: f64,
        /// Point.
        y: f64,
        /// Subset size.
        size: usize,
        /// Image width.
        width: usize,
        /// Image height.
        height: usize,
    },
    /// The region to track has no texture (a uniform patch: nothing to correlate).
    #[error("the region at ({x}, {y}) has no texture to correlate")]
    NoTexture {
        /// Centre, pixels.
        x: f64,
        /// Centre, pixels.
        y: f64,
    },
    /// The worker threads could not be started.
    #[error("cannot start {threads} worker threads: {reason}")]
    Threads {
        /// Threads asked for.
        threads: usize,
        /// What the system said.
        reason: String,
    },
    /// A fit needs more or better-conditioned data.
    #[error("calibration: {reason}")]
    Calibration {
        /// What is missing.
        reason: String,
    },
}

/// Checks a subset size.
pub fn check_subset(size: usize) -> Result<Subset, DicError> {
    let (min, max) = SUBSET_RANGE;
    if size % 2 == 0 || size < min || size > max {
        return Err(DicError::SubsetSize { size, min, max });
    }
    Ok(Subset::square(size))
}

/// Options of [`correlate_points`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointOptions {
    /// Odd subset size, pixels.
    pub subset: usize,
    /// Self-adaptive subset: a point whose result `acceptance` rejects only for its
    /// predicted σ is tried again with larger subsets, up to twice the size
    /// ([`accept::measure`]).
    pub adaptive_subset: bool,
    /// The rule that decides when the subset grows (the caller judges the results with
    /// it too).
    pub acceptance: Acceptance,
    /// Shape function.
    pub shape: Shape,
    /// Largest displacement searched for, pixels.
    pub search_radius: usize,
    /// Sigma of an optional Gaussian prefilter of both images, pixels (0 = none).
    pub prefilter: f64,
    /// Degree of the B-spline interpolant of both images (quintic by default here; cubic
    /// for comparison: [`bspline::Degree`]).
    pub spline: Degree,
    /// Iteration control (by default the field's: [`icgn::MEASUREMENT_TOLERANCE`]).
    pub icgn: IcgnOptions,
}

impl Default for PointOptions {
    fn default() -> Self {
        PointOptions {
            subset: 31,
            adaptive_subset: true,
            acceptance: Acceptance::default(),
            shape: Shape::Affine,
            search_radius: 64,
            prefilter: 0.0,
            spline: Degree::Quintic,
            icgn: IcgnOptions {
                tolerance: icgn::MEASUREMENT_TOLERANCE,
                ..IcgnOptions::default()
            },
        }
    }
}

/// A pair of images made ready for correlation: the reference with its gradients, the
/// current image's spline, both pyramids for the integer search, and the rounding
/// tables of the corrections ([`correction::Corrections`]).
pub(crate) struct Prepared {
    pub(crate) r: Reference,
    pub(crate) s: BSpline,
    pub(crate) pr: Vec<Image>,
    pub(crate) pc: Vec<Image>,
    /// Variance of the rounding noise of both images after the prefilter, grey levels²:
    /// the floor of the residual variance ([`IcgnOptions::residual_floor`]).
    pub(crate) floor: f64,
    /// The quantisation step the matches use ([`IcgnOptions::quantisation_step`]):
    /// the larger of the caller's and the current image's own (0 if not quantised or
    /// prefiltered: the rounding is simulated on unfiltered data only).
    pub(crate) step: f64,
    /// The rounding tables at `step` ([`correction::rounding_tables`]).
    pub(crate) rounding: Vec<Vec<f32>>,
}

impl Prepared {
    /// Pyramid depth: enough levels that a `search_radius` jump is ~8 px at the top.
    /// A `prefilter` sigma > 0 low-passes both images first (against aliasing of
    /// undersampled speckles, at the cost of some noise averaging). The step the
    /// matches use, and the rounding tables', is the larger of the current image's
    /// quantisation step and `min_step` (the caller's
    /// [`IcgnOptions::quantisation_step`]).
    pub(crate) fn new(
        reference: &Image,
        current: &Image,
        search_radius: usize,
        prefilter: f64,
        spline: Degree,
        min_step: f64,
    ) -> Self {
        let blurred = (prefilter > 0.0).then(|| {
            (
                reference.gaussian_blur(prefilter),
                current.gaussian_blur(prefilter),
            )
        });
        // The rounding noise of the images as given (before any prefilter).
        let (given_r, given_c) = (reference, current);
        let (reference, current) = match &blurred {
            Some((r, c)) => (r, c),
            None => (reference, current),
        };
        let levels = (search_radius as f64 / 8.0).log2().ceil().clamp(0.0, 5.0) as usize;
        // The current image's quantisation step and the reference's spline, then the
        // rounding tables beside the spline's gradients; on the other side the
        // reference's quantisation noise, the current image's spline (and its single
        // precision, which every match's warp reads) and both pyramids. The tables need
        // only the reference's spline and the step, and rayon hands their bands to
        // whichever thread is free.
        let step_of = |qc: f64| {
            if prefilter > 0.0 {
                0.0
            } else {
                (12.0 * qc).sqrt()
            }
        };
        let ((qc, step, r, rounding), (qr, ((pr, pc), s))) = rayon::join(
            || {
                let qc = image::quantisation_variance(given_c);
                let step = step_of(qc).max(min_step);
                let rs = BSpline::with_degree(reference, spline);
                let (gradients, rounding) = rayon::join(
                    || rs.node_gradients(),
                    || correction::rounding_tables(&rs, step),
                );
                let r = Reference::from_spline(reference.clone(), rs, gradients);
                (qc, step, r, rounding)
            },
            || {
                let qr = image::quantisation_variance(given_r);
                let rest = rayon::join(
                    || {
                        rayon::join(
                            || search::pyramid(reference, levels),
                            || search::pyramid(current, levels),
                        )
                    },
                    || {
                        let s = BSpline::with_degree(current, spline);
                        s.prepare_single();
                        s
                    },
                );
                (qr, rest)
            },
        );
        let floor = (qr + qc) * image::blur_noise_gain(prefilter);
        Prepared {
            pr,
            pc,
            s,
            r,
            floor,
            step,
            rounding,
        }
    }
}

/// The outcome at one requested point: `None` when no match was found.
pub type PointOutcome = Option<PointResult>;

/// Correlates each point of `points` (pixel coordinates in the reference): integer
/// search, then IC-GN. A point at a fractional position uses the subset centred at the
/// nearest pixel, its displacement carried to the point by the shape function.
pub fn correlate_points(
    reference: &Image,
    current: &Image,
    points: &[(f64, f64)],
    opts: &PointOptions,
) -> Result<Vec<PointOutcome>, DicError> {
    let subset = check_subset(opts.subset)?;
    if (reference.width(), reference.height()) != (current.width(), current.height()) {
        return Err(DicError::SizeMismatch {
            a: (reference.width(), reference.height()),
            b: (current.width(), current.height()),
        });
    }
    let (w, h) = (reference.width(), reference.height());
    for &(x, y) in points {
        let (xi, yi) = (x.round(), y.round());
        if !x.is_finite()
            || !y.is_finite()
            || xi < 0.0
            || yi < 0.0
            || !subset.fits(xi as usize, yi as usize, w, h)
        {
            return Err(DicError::SubsetOutside {
                x,
                y,
                size: opts.subset,
                width: w,
                height: h,
            });
        }
    }
    let Prepared {
        r,
        s,
        pr,
        pc,
        floor,
        step,
        rounding,
    } = Prepared::new(
        reference,
        current,
        opts.search_radius,
        opts.prefilter,
        opts.spline,
        opts.icgn.quantisation_step,
    );
    let icgn_opts = IcgnOptions {
        residual_floor: opts.icgn.residual_floor.max(floor),
        quantisation_step: step,
        ..opts.icgn
    };
    let corrections = correction::Corrections::with_rounding(&r, opts.spline, rounding);
    Ok(points
        .par_iter()
        .map_init(icgn::Scratch::default, |scratch, &(x, y)| {
            let (xi, yi) = (x.round() as i64, y.round() as i64);
            let m = (opts.subset / 2) as i64;
            let hit = search::search_pyramid(&pr, &pc, xi, yi, m, opts.search_radius as i64)?;
            // From the correlation's sub-pixel peak: a step of IC-GN fewer than
            // from the whole pixel.
            let (u, v) = hit.refined();
            let init = [u, 0.0, 0.0, v, 0.0, 0.0];
            let mut res = accept::measure(
                &r,
                &s,
                xi as usize,
                yi as usize,
                opts.subset,
                opts.adaptive_subset,
                opts.shape,
                init,
                &icgn_opts,
                &opts.acceptance,
                &corrections,
                scratch,
            )?;
            let (dx, dy) = (x - xi as f64, y - yi as f64);
            let [ux, uy, vx, vy] = res.gradients;
            res.u += ux * dx + uy * dy;
            res.v += vx * dx + vy * dy;
            res.x = x;
            res.y = y;
            Some(res)
        })
        .collect())
}

/// A coordinate for a message: as typed when it is image-sized, in exponent form when
/// it is not (`1e300`, not three hundred digits).
fn short(v: &f64) -> String {
    if v.abs() < 1e9 {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}
