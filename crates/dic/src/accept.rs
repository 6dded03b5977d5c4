//! When a correlation is a measurement: one rule for every mode that reports points
//! (`correlate_points`' callers and the full field's propagation), so that a point the
//! point mode refuses is never reported by the field.
//!
//! A match is kept when IC-GN converged, its ZNCC reaches `min_zncc`, and its predicted
//! standard error (noise and interpolation bias, [`PointResult::sigma_u`]) is at most
//! `max_sigma` in both directions. The last test is the one that catches low-texture
//! subsets: on a smooth patch of a photograph (sky, a dark coat) the ZNCC stays near 1
//! at any shift the offset and gain of ZNSSD can absorb, so the ZNCC cannot tell a
//! wrong match from a right one, but the predicted σ, computed with offset and gain
//! eliminated, grows without bound as the texture disappears. It counts only the
//! texture above the image noise (the noise's own gradients carry no information on
//! the displacement, so they are subtracted from the information matrix) and weighs
//! each pixel by its own and its neighbours' residuals (a sandwich estimate robust to
//! residuals that keep their sign along an edge), so a patch whose only texture
//! is noise or rounding steps, or whose residual sits on one sharp edge, is refused
//! rather than reported with the σ a speckle of the same gradient energy would have.

use crate::BSpline;
use crate::correction::Corrections;
use crate::icgn::{self, IcgnOptions, PointResult, Reference, Scratch, Shape, Subset};

/// The thresholds of [`judge`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Acceptance {
    /// Smallest ZNCC of a measurement.
    pub min_zncc: f64,
    /// Largest predicted standard error of u or v, pixels.
    pub max_sigma: f64,
}

impl Default for Acceptance {
    fn default() -> Self {
        Acceptance {
            min_zncc: 0.8,
            max_sigma: DEFAULT_MAX_SIGMA,
        }
    }
}

/// Default largest predicted σ of a measurement, pixels: a point kept at this σ is off
/// by 0.1 px only at 4σ if the prediction is right (about one point in 16 000).
/// `tests/real_images.rs` measures what it keeps and drops on photographs.
pub const DEFAULT_MAX_SIGMA: f64 = 0.025;

/// Why a correlation is not a measurement.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Rejection {
    /// IC-GN did not converge.
    NotConverged,
    /// The ZNCC is below the threshold.
    LowZncc,
    /// The predicted standard error exceeds the threshold (too little texture).
    Uncertain,
}

impl Rejection {
    /// A sentence for a report.
    pub fn reason(self) -> &'static str {
        match self {
            Rejection::NotConverged => "no reliable match: the correlation did not converge",
            Rejection::LowZncc => "no reliable match: the ZNCC is below --min-zncc",
            Rejection::Uncertain => {
                "no reliable match: the predicted error exceeds --max-sigma (too little texture)"
            }
        }
    }
}

/// Whether `p` is a measurement under `a`; the reason if not. NaN thresholds reject.
pub fn judge(p: &PointResult, a: &Acceptance) -> Result<(), Rejection> {
    if !p.converged {
        return Err(Rejection::NotConverged);
    }
    if p.zncc.partial_cmp(&a.min_zncc).is_none_or(|o| o.is_lt()) {
        return Err(Rejection::LowZncc);
    }
    let within = |s: f64| s.partial_cmp(&a.max_sigma).is_some_and(|o| o.is_le());
    if !(within(p.sigma_u) && within(p.sigma_v)) {
        return Err(Rejection::Uncertain);
    }
    Ok(())
}

/// Subset sizes [`measure`] tries at a point, for a requested odd `subset`: the subset,
/// then three larger ones up to twice its half-width, `subset + 2·⌈k·m/3⌉` for k = 1,
/// 2, 3 and m = `subset / 2` (31 → 41, 51, 61).
pub fn subset_sizes(subset: usize) -> [usize; 4] {
    let m = subset / 2;
    [
        subset,
        subset + 2 * m.div_ceil(3),
        subset + 2 * (2 * m).div_ceil(3),
        subset + 2 * m,
    ]
}

/// Share of the simulated interpolation error ([`icgn::corrected`]) that stays in σ
/// after it is subtracted, in quadrature: what the band-limited model of the image
/// misses (the photograph is not band-limited; the simulation resamples the rounded
/// reference). With 0.3 and with 0.15 the 48 runs of `tests/real_images.rs` gave the
/// same summary (no kept point over 0.1 px, the same lowest share kept).
pub const BIAS_KEPT: f64 = 0.3;

/// Grey-level steps per pixel (RMS gradient along a subset's weaker axis) under which
/// the rounding is simulated for the subset itself, at phases relative to its own
/// match ([`icgn::rounding_error`]), rather than read from the image's tables at
/// fixed phases ([`crate::correction::Corrections`]). Where the grey levels change by
/// a few steps per pixel or more, rounding is white noise and the tables' four phases
/// see what any four would; where they change by less (a sky, a dark coat), it moves
/// runs of pixels together, its error is a sawtooth of the sub-pixel position, and
/// only the match's own phase shows how large it is there. On the sky of
/// `tests/real_images.rs` the tables' phases alone kept 3 points 0.10-0.18 px off on
/// the coarse grid; with the bound at 4 steps the full grid still kept one 0.144 px
/// off (camera_sky_coat, both frames exposed, noise 0); at 8 none is over 0.1 px
/// (worst 0.095 px, as with every subset simulated on its own).
pub const COHERENT_ROUNDING: f64 = 8.0;

/// Refines the point (x, y) from `initial` and judges it; when `adaptive`, a result
/// rejected only for its predicted σ is refined again with larger subsets
/// ([`subset_sizes`], each started from the last solution, those its σ shows would
/// still miss the bound skipped: `next_size`) until one is accepted, one
/// does not converge or none fits: a self-adaptive subset after Pan et al., "Study on
/// subset size selection in digital image correlation for speckle patterns", Opt.
/// Express 16 (2008), which sizes each subset by its sum of squared intensity
/// gradients (SSSIG) so that the predicted noise error meets a bound. Here the bound
/// is the acceptance rule's own `max_sigma` and the error is the full predicted σ,
/// so the subset grows only where the requested one gives no measurement, and a
/// point that is one keeps its result unchanged.
///
/// Near a border, where a larger square leaves the reference or (displaced) the
/// current image, a grown subset is a rectangle of about the same area, as tall (wide)
/// as fits: [`grown_subset`]. On brick under noise (its mortar lines at a subset's
/// edge, rows 21 and 231-236 of a 256 px image) square growth stopped at the border
/// and 6 of 51 textured points were dropped; rectangles keep all of them.
///
/// Every result is then corrected and bounded for the two errors that more pixels do
/// not average out:
/// - the spline's interpolation error, simulated and subtracted
///   ([`icgn::corrected`]; [`BIAS_KEPT`] of it stays in σ);
/// - the current image's rounding when it is quantised
///   ([`IcgnOptions::quantisation_step`]): σ is at least the RMS of the simulated
///   rounding error over four sub-pixel phases ([`icgn::rounding_error`]). Where the
///   grey levels change by several steps per pixel rounding is the white noise the
///   residual floor counts; where they change by less (a sky, a dark coat, a brick's
///   face) it moves runs of pixels to the same contour, keeps its sign over the
///   subset, and is the largest error of a grown subset.
///
/// Measured on the 48 runs of `tests/real_images.rs` with the photograph as the
/// reference (6 photographs, 4 sub-pixel shifts, noise 0 and 2 grey levels, a grid
/// step of 5 px; the file now also runs pairs with both frames exposed, and reads σ
/// point by point as well): no kept point more than
/// 0.1 px off (worst 0.095 px), at least 91.8 % of the textured points kept (median
/// 100 %), RMS error / σ 0.80-1.03 on the 24 runs with noise in both frames and
/// 0.39-1.26 on the 24 without (σ is conservative there, up to 2.6 times: the
/// rounding's RMS over the phases, where the one phase of the run may see less of
/// it). Before (spectral bias in σ, the rounding on grown subsets only, square
/// subsets): 4 points over 0.1 px, 81.0 % kept in the worst run, RMS error / σ
/// 0.68-1.41. The corrections cost a sinc resampling and four rounding simulations
/// per point: about 190 s for the 48 runs in a release build instead of 64 s.
///
/// Returns the last result computed (the accepted one, or the one of the largest
/// subset tried), `None` when the requested subset gives none.
#[allow(clippy::too_many_arguments)]
pub fn measure(
    reference: &Reference,
    current: &BSpline,
    x: usize,
    y: usize,
    subset: usize,
    adaptive: bool,
    shape: Shape,
    initial: [f64; 6],
    opts: &IcgnOptions,
    acceptance: &Acceptance,
    corrections: &Corrections,
    scratch: &mut Scratch,
) -> Option<PointResult> {
    measure_on_grid(
        reference,
        current,
        (x, y),
        (subset, adaptive, shape),
        initial,
        (opts, acceptance),
        corrections,
        scratch,
        None,
    )
}

/// [`measure`] of a point of a field's grid, whose subsets' reference-only sums
/// `grid` holds ([`icgn::GridSums`]; a larger subset's are made for it alone).
#[allow(clippy::too_many_arguments)]
#[inline]
pub(crate) fn measure_on_grid(
    reference: &Reference,
    current: &BSpline,
    (x, y): (usize, usize),
    (subset, adaptive, shape): (usize, bool, Shape),
    initial: [f64; 6],
    (opts, acceptance): (&IcgnOptions, &Acceptance),
    corrections: &Corrections,
    scratch: &mut Scratch,
    grid: Option<&icgn::GridSums>,
) -> Option<PointResult> {
    pulp::Arch::new().dispatch(Measure {
        reference,
        current,
        x,
        y,
        subset,
        adaptive,
        shape,
        initial,
        opts,
        acceptance,
        corrections,
        scratch,
        grid,
    })
}

/// [`measure`]'s arguments, for compiling it for the machine's vector units (the
/// whole per-point pipeline is inlined into each of pulp's targets).
struct Measure<'a, 'b> {
    reference: &'a Reference,
    current: &'a BSpline,
    x: usize,
    y: usize,
    subset: usize,
    adaptive: bool,
    shape: Shape,
    initial: [f64; 6],
    opts: &'a IcgnOptions,
    acceptance: &'a Acceptance,
    corrections: &'a Corrections<'b>,
    scratch: &'a mut Scratch,
    grid: Option<&'a icgn::GridSums>,
}

impl pulp::WithSimd for Measure<'_, '_> {
    type Output = Option<PointResult>;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> Self::Output {
        let Measure {
            reference,
            current,
            x,
            y,
            subset,
            adaptive,
            shape,
            initial,
            opts,
            acceptance,
            corrections,
            scratch,
            grid,
        } = self;
        let sizes = subset_sizes(subset);
        let count = if adaptive { sizes.len() } else { 1 };
        let mut best: Option<PointResult> = None;
        let mut last = Subset::square(subset);
        let (iw, ih) = (reference.image().width(), reference.image().height());
        let mut k = 0;
        while k < count {
            let size = sizes[k];
            let start = match &best {
                None => initial,
                Some(b) => {
                    let [ux, uy, vx, vy] = b.gradients;
                    [b.u, ux, uy, b.v, vx, vy]
                }
            };
            let sub = if best.is_some() {
                match grown_subset(size, x, y, iw, ih, (start[0], start[3]), last) {
                    Some(s) => s,
                    None => break,
                }
            } else {
                Subset::square(size)
            };
            last = sub;
            let Some(prepared) = icgn::prepare_in(reference, x, y, sub, shape, scratch, grid)
            else {
                break;
            };
            // The subset's buffers go back to the scratch whichever way this ends.
            let stop = 'point: {
                let Some(it) = icgn::iterate(&prepared, current, start, opts, scratch) else {
                    break 'point true;
                };
                if icgn::influence(&prepared, scratch).is_none() {
                    break 'point true;
                }
                let grown = best.is_some();
                // The spline's interpolation error, simulated and taken out: no shift can
                // move it, and on the photographs it is the largest error of strong texture.
                // A point whose correction cannot be computed has no bound: not a
                // measurement (its σ is infinite, so a larger subset is still tried).
                corrections.mismatch(x, y, sub, it.p[0], it.p[3], &mut scratch.mismatch);
                let mut p = icgn::correct(&prepared, &it, current, scratch, opts, BIAS_KEPT)
                    .unwrap_or(it.result(&prepared));
                // The current image's rounding (see above). It only raises σ: computed only
                // when the rest would pass.
                if opts.quantisation_step > 0.0 && judge(&p, acceptance).is_ok() {
                    // One that cannot be computed leaves the point without a bound: not a
                    // measurement.
                    let tables = corrections.rounding();
                    let coherent =
                        prepared.weakest_gradient() < COHERENT_ROUNDING * opts.quantisation_step;
                    let bound = if tables.is_empty() || coherent {
                        icgn::rounding_error_translated(reference, &prepared, &p, opts, scratch)
                    } else {
                        Some(icgn::rounding_from_tables(&prepared, tables, iw, scratch))
                    };
                    let (du, dv) = bound.unwrap_or((f64::INFINITY, f64::INFINITY));
                    p.sigma_u = p.sigma_u.max(du);
                    p.sigma_v = p.sigma_v.max(dv);
                }
                // A larger subset that does not converge leaves the last result.
                if grown && !p.converged {
                    break 'point true;
                }
                best = Some(p);
                if judge(&p, acceptance) != Err(Rejection::Uncertain) {
                    break 'point true;
                }
                let side = (((2 * sub.half_w + 1) * (2 * sub.half_h + 1)) as f64).sqrt();
                k = next_size(
                    &sizes[..count],
                    k,
                    side,
                    p.sigma_u.max(p.sigma_v),
                    acceptance,
                );
                false
            };
            icgn::recycle(prepared, scratch);
            if stop {
                break;
            }
        }
        best
    }
}

/// The index of the next subset size [`measure`] tries after `sizes[k]` (a subset of
/// `side`² pixels) predicted `sigma` over the bound: the smallest larger size at
/// which σ, falling as the side grows (the noise term's `1/√n` on a texture like the
/// one already seen), would meet it, else the largest. The sizes in between would
/// still miss it, and each costs a whole measurement. Where σ is held up by what more
/// pixels do not average out (the rounding's bound), the size this predicts is too
/// small: it misses the bound as well, and the one after it is tried, as before.
fn next_size(sizes: &[usize], k: usize, side: f64, sigma: f64, acceptance: &Acceptance) -> usize {
    let last = sizes.len().saturating_sub(1);
    if k >= last {
        return k + 1;
    }
    let needed = side * sigma / acceptance.max_sigma;
    (k + 1..=last)
        .find(|&j| sizes[j] as f64 >= needed)
        .unwrap_or(last)
}

/// Distance in pixels that [`grown_subset`] keeps between a displaced subset and the
/// current image's edge.
pub const ROOM_MARGIN: f64 = 3.0;

/// The subset of about `size`² pixels centred at (x, y) in a `w x h` image: square
/// where it fits; near a border, as tall (wide) as fits and wider (taller) to keep the
/// area. `None` when that is no larger than `previous`.
///
/// "Fits" means in the reference and, displaced by the current guess `uv`, in the
/// current image with [`ROOM_MARGIN`] pixels to spare: the IC-GN refuses a warped
/// subset closer than 2 px to the current image's edge, and a pixel more leaves room
/// for the iterations to move it.
pub fn grown_subset(
    size: usize,
    x: usize,
    y: usize,
    w: usize,
    h: usize,
    uv: (f64, f64),
    previous: Subset,
) -> Option<Subset> {
    let half = size / 2;
    let room = |c: usize, d: f64, n: usize| -> usize {
        // The last pixel is n − 1.
        let (lo, hi) = (
            (c as f64 + d - ROOM_MARGIN).floor(),
            (n as f64 - 1.0 - ROOM_MARGIN - c as f64 - d).floor(),
        );
        c.min(n.saturating_sub(1 + c))
            .min(lo.max(0.0) as usize)
            .min(hi.max(0.0) as usize)
    };
    let room_w = room(x, uv.0, w);
    let room_h = room(y, uv.1, h);
    let area = (size * size) as f64;
    let (mut hw, mut hh) = (half.min(room_w), half.min(room_h));
    if hh < half {
        let need = ((area / (2 * hh + 1) as f64 - 1.0) / 2.0).ceil() as usize;
        hw = need.min(room_w);
    } else if hw < half {
        let need = ((area / (2 * hw + 1) as f64 - 1.0) / 2.0).ceil() as usize;
        hh = need.min(room_h);
    }
    let s = Subset {
        half_w: hw,
        half_h: hh,
    };
    let larger =
        (2 * hw + 1) * (2 * hh + 1) > (2 * previous.half_w + 1) * (2 * previous.half_h + 1);
    larger.then_some(s)
}

/// How many computed points a rule dropped, by reason.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Dropped {
    /// IC-GN did not converge.
    pub not_converged: usize,
    /// ZNCC below the threshold.
    pub low_zncc: usize,
    /// Predicted σ above the threshold.
    pub uncertain: usize,
    /// Accepted on its own but contradicted by its neighbours in a field, or with no
    /// accepted neighbour to confirm it ([`crate::field::field`]'s normalised median
    /// test).
    pub inconsistent: usize,
}

impl Dropped {
    /// Counts one rejection.
    pub fn add(&mut self, r: Rejection) {
        match r {
            Rejection::NotConverged => self.not_converged += 1,
            Rejection::LowZncc => self.low_zncc += 1,
            Rejection::Uncertain => self.uncertain += 1,
        }
    }

    /// All of them.
    pub fn total(&self) -> usize {
        self.not_converged + self.low_zncc + self.uncertain + self.inconsistent
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Image;
    use crate::bspline::Degree;

    fn result(converged: bool, zncc: f64, sigma: f64) -> PointResult {
        PointResult {
            x: 0.0,
            y: 0.0,
            u: 0.0,
            v: 0.0,
            gradients: [0.0; 4],
            zncc,
            iterations: 1,
            converged,
            sigma_u: sigma,
            sigma_v: 0.5 * sigma,
            sigma_noise: 1.0,
            subset: 31,
        }
    }

    #[test]
    fn each_reason_is_found_and_nan_rejects() {
        let a = Acceptance {
            min_zncc: 0.8,
            max_sigma: 0.02,
        };
        assert_eq!(judge(&result(true, 0.9, 0.01), &a), Ok(()));
        assert_eq!(
            judge(&result(false, 0.9, 0.01), &a),
            Err(Rejection::NotConverged)
        );
        assert_eq!(judge(&result(true, 0.7, 0.01), &a), Err(Rejection::LowZncc));
        assert_eq!(
            judge(&result(true, 0.9, 0.03), &a),
            Err(Rejection::Uncertain)
        );
        assert_eq!(
            judge(&result(true, 0.9, f64::INFINITY), &a),
            Err(Rejection::Uncertain)
        );
        let nan = Acceptance {
            min_zncc: f64::NAN,
            max_sigma: f64::NAN,
        };
        assert!(judge(&result(true, 0.9, 0.01), &nan).is_err());
    }

    /// A linear ramp of grey levels: ZNSSD's offset and gain absorb any shift, so the
    /// match converges at ZNCC 1 wherever it starts, and only σ says it is meaningless.
    /// The image is wide enough that the mirrored border's effect on the quintic
    /// spline (`|z₁|^d`, 1e-9 of the ramp at 20 px) does not reach the subset: there
    /// the normal equations are singular, and any residual that is not round-off
    /// moves the match along the ramp without end.
    #[test]
    fn a_ramp_matches_perfectly_and_is_rejected_for_its_sigma() {
        let (w, h) = (128, 128);
        let ramp = |dx: f64| {
            let data = (0..w * h)
                .map(|k| 20.0 + 2.0 * ((k % w) as f64 - dx) + 0.5 * (k / w) as f64)
                .collect();
            Image::new(w, h, data).unwrap()
        };
        let r = Reference::new(ramp(0.0));
        let c = BSpline::new(&ramp(0.4));
        let p = icgn::refine(
            &r,
            &c,
            64,
            64,
            Subset::square(21),
            Shape::Rigid,
            [1.3, 0.0, 0.0, 0.0, 0.0, 0.0],
            &icgn::IcgnOptions::default(),
        )
        .unwrap();
        assert!(p.zncc > 0.9999, "{p:?}");
        assert!(p.sigma_u.is_infinite() || p.sigma_u > 1.0, "{p:?}");
        assert_eq!(judge(&p, &Acceptance::default()), Err(Rejection::Uncertain));
    }

    /// A faint texture (three sinusoids of 3 grey levels) under noise of σ = 2 grey
    /// levels, shifted exactly by (0.3, −0.2) px, in 200 noise realisations: the RMS
    /// error (0.090 px) and the RMS predicted σ (0.090 px) agree. The noise's own
    /// gradients carry about as much energy as the texture's here; counted as texture,
    /// they made the predicted σ half the scatter (0.045 px). With 1.5 grey levels the
    /// old σ was 5 times too small, the new one is infinite in some realisations.
    #[test]
    fn the_predicted_sigma_of_a_faint_texture_under_noise_is_its_scatter() {
        let (w, h) = (64, 64);
        let waves = [(0.55, 0.2, 0.0), (-0.25, 0.6, 1.0), (0.4, -0.45, 2.0)];
        const AMP: f64 = 3.0;
        let texture = |x: f64, y: f64| -> f64 {
            waves
                .iter()
                .map(|(kx, ky, ph)| AMP * (kx * x + ky * y + ph).sin())
                .sum()
        };
        let (u, v) = (0.3, -0.2);
        let mut rng = cellinject_numeric::Rng::new(5, 1);
        let (mut se, mut ss) = (0.0, 0.0);
        let runs = 200;
        for _ in 0..runs {
            let mut frame = |du: f64, dv: f64| {
                let data = (0..w * h)
                    .map(|k| {
                        let (x, y) = ((k % w) as f64, (k / w) as f64);
                        100.0 + texture(x - du, y - dv) + 2.0 * rng.gaussian_exact()
                    })
                    .collect();
                Image::new(w, h, data).unwrap()
            };
            let r = Reference::new(frame(0.0, 0.0));
            let c = BSpline::new(&frame(u, v));
            let p = icgn::refine(
                &r,
                &c,
                32,
                32,
                Subset::square(31),
                Shape::Rigid,
                [u, 0.0, 0.0, v, 0.0, 0.0],
                &icgn::IcgnOptions::default(),
            )
            .unwrap();
            se += (p.u - u).powi(2) + (p.v - v).powi(2);
            ss += p.sigma_u.powi(2) + p.sigma_v.powi(2);
        }
        let ratio = (se / ss).sqrt();
        println!(
            "rms error {:.4} px, rms σ {:.4} px",
            (se / (2.0 * runs as f64)).sqrt(),
            (ss / (2.0 * runs as f64)).sqrt()
        );
        assert!((0.8..1.25).contains(&ratio), "rms error / rms σ = {ratio}");
    }

    /// A faint texture under noise: the 31 px subset's σ is above the bound, so the
    /// point is no measurement; the self-adaptive subset grows it until it is one, says
    /// which size it used, and its error is within its σ's reach.
    #[test]
    fn the_next_size_is_the_first_at_which_sigma_would_meet_the_bound() {
        let sizes = subset_sizes(33);
        assert_eq!(sizes, [33, 45, 55, 65]);
        let a = Acceptance::default();
        // σ ∝ 1/side: 0.03 at 33 px meets 0.025 from 39.6 px, 0.04 from 52.8 px.
        assert_eq!(next_size(&sizes, 0, 33.0, 0.03, &a), 1);
        assert_eq!(next_size(&sizes, 0, 33.0, 0.04, &a), 2);
        assert_eq!(next_size(&sizes, 0, 33.0, 0.0255, &a), 1);
        // Out of reach: the largest, once; after the largest, the end.
        assert_eq!(next_size(&sizes, 0, 33.0, 0.1, &a), 3);
        assert_eq!(next_size(&sizes, 1, 45.0, 0.1, &a), 3);
        assert_eq!(next_size(&sizes, 3, 65.0, 0.1, &a), 4);
        // A rectangle near a border counts by its area; NaN tries the largest.
        assert_eq!(next_size(&sizes, 0, (25.0f64 * 43.0).sqrt(), 0.03, &a), 1);
        assert_eq!(next_size(&sizes, 0, 33.0, f64::NAN, &a), 3);
        assert_eq!(next_size(&sizes[..1], 0, 33.0, 0.04, &a), 1);
    }

    #[test]
    fn a_faint_texture_is_measured_by_a_grown_subset() {
        let (w, h) = (128, 128);
        let waves = [(0.55, 0.2, 0.0), (-0.25, 0.6, 1.0), (0.4, -0.45, 2.0)];
        let (u, v) = (0.3, -0.2);
        let mut rng = cellinject_numeric::Rng::new(9, 1);
        let mut frame = |du: f64, dv: f64| {
            let data = (0..w * h)
                .map(|k| {
                    let (x, y) = ((k % w) as f64 - du, (k / w) as f64 - dv);
                    let t: f64 = waves
                        .iter()
                        .map(|(kx, ky, ph)| 7.0 * (kx * x + ky * y + ph).sin())
                        .sum();
                    100.0 + t + 2.0 * rng.gaussian_exact()
                })
                .collect();
            Image::new(w, h, data).unwrap()
        };
        let r = Reference::new(frame(0.0, 0.0));
        let c = BSpline::new(&frame(u, v));
        let a = Acceptance::default();
        let corrections = Corrections::new(&r, c.degree(), 0.0);
        let at = |adaptive: bool| {
            measure(
                &r,
                &c,
                64,
                64,
                31,
                adaptive,
                Shape::Affine,
                [u, 0.0, 0.0, v, 0.0, 0.0],
                &IcgnOptions::default(),
                &a,
                &corrections,
                &mut Scratch::default(),
            )
            .unwrap()
        };
        let fixed = at(false);
        assert_eq!(fixed.subset, 31);
        assert_eq!(judge(&fixed, &a), Err(Rejection::Uncertain), "{fixed:?}");
        let grown = at(true);
        assert!(grown.subset > 31, "{grown:?}");
        assert_eq!(judge(&grown, &a), Ok(()), "{grown:?}");
        assert!((grown.u - u).abs() < 4.0 * grown.sigma_u, "{grown:?}");
        assert!((grown.v - v).abs() < 4.0 * grown.sigma_v, "{grown:?}");
        assert_eq!(subset_sizes(31), [31, 41, 51, 61]);
    }

    /// `DERIVATIVE_NOISE_GAIN` is `6√3 − 9` and the mean of `|D(ω)|²` over the band.
    #[test]
    fn the_derivative_noise_gain_is_the_spline_derivative_power() {
        let n = 100_000;
        let mean = (0..n)
            .map(|i| {
                let w = std::f64::consts::PI * ((i as f64 + 0.5) / n as f64);
                (6.0 * w.sin() / (4.0 + 2.0 * w.cos())).powi(2)
            })
            .sum::<f64>()
            / n as f64;
        assert!((icgn::DERIVATIVE_NOISE_GAIN - mean).abs() < 1e-9, "{mean}");
        assert!((icgn::DERIVATIVE_NOISE_GAIN - (6.0 * 3f64.sqrt() - 9.0)).abs() < 1e-15);
        for d in [Degree::Cubic, Degree::Quintic] {
            let mean = (0..n)
                .map(|i| {
                    let w = std::f64::consts::PI * ((i as f64 + 0.5) / n as f64);
                    (w * d.derivative_gain(w)).powi(2)
                })
                .sum::<f64>()
                / n as f64;
            assert!(
                (d.derivative_noise_gain() - mean).abs() < 1e-9,
                "{d:?} {mean}"
            );
        }
    }

    /// Inside the image the grown subset is the square; at a border (away from the
    /// corners) it is a rectangle of at least the square's area that fits, displaced,
    /// with the margin; one no larger than the last is not offered.
    #[test]
    fn grown_subsets_fit_and_keep_the_area() {
        let (w, h) = (256, 256);
        let small = Subset::square(31);
        assert_eq!(
            grown_subset(41, 128, 128, w, h, (0.3, -0.8), small),
            Some(Subset::square(41))
        );
        for (x, y, uv) in [
            (101, 21, (0.05, -0.8)),
            (61, 236, (0.05, -0.8)),
            (21, 128, (-1.13, 2.5)),
            (240, 128, (0.37, -0.62)),
        ] {
            for size in [41, 51, 61] {
                let Some(s) = grown_subset(size, x, y, w, h, uv, small) else {
                    continue;
                };
                assert!(
                    (2 * s.half_w + 1) * (2 * s.half_h + 1) >= size * size,
                    "{size} at ({x}, {y}): {s:?}"
                );
                let fits = |c: usize, half: usize, d: f64, n: usize| {
                    c >= half
                        && c + half < n
                        && c as f64 + d - half as f64 >= ROOM_MARGIN
                        && (c + half) as f64 + d <= n as f64 - 1.0 - ROOM_MARGIN
                };
                assert!(fits(x, s.half_w, uv.0, w), "{size} at ({x}, {y}): {s:?}");
                assert!(fits(y, s.half_h, uv.1, h), "{size} at ({x}, {y}): {s:?}");
            }
        }
        // Row 21 displaced by −0.8 px is at 20.2: with the 3 px margin, 17 rows above
        // it; 35 rows by 49 columns (1715 px ≥ 41²).
        assert_eq!(
            grown_subset(41, 101, 21, w, h, (0.05, -0.8), small),
            Some(Subset {
                half_w: 24,
                half_h: 17
            })
        );
        // A corner leaves no room to grow: nothing larger than 31 x 31.
        assert_eq!(grown_subset(41, 16, 16, w, h, (0.0, 0.0), small), None);
    }
}
