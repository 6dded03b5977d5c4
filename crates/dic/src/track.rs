//! Tracking one region through a sequence of frames (the closed loop's measurement):
//! the region of the first frame is the reference subset; each frame is predicted from
//! the previous motion (constant velocity), refined by IC-GN on a spline of a small
//! window only (not the whole frame), re-searched by FFT if that fails, matched against
//! blurred copies of the reference if the region went out of focus, and rejected (no
//! number reported) if the ZNCC stays below the threshold.
//!
//! **Defocus.** A camera sees the axis along its optical axis only as blur: the marker
//! moved along it matches its sharp reference worse and worse (ZNCC 0.99 in focus, 0.75
//! with a blur of 6 px), although it is still plainly there. A symmetric blur does not
//! move the region's centre, so the displacement measured against a reference blurred
//! by the same amount is unbiased. When every sharp attempt is rejected, the tracker
//! climbs a ladder of Gaussian blurs of the reference ([`BLUR_LADDER`], prepared once
//! each, when first needed) from the level that matched last, keeps the level whose
//! ZNCC is highest, and accepts it only above the same threshold.

use crate::icgn::{self, IcgnOptions, Reference, Shape, Subset};
use crate::{BSpline, DicError, Image, search};

/// A region of interest, pixels: the hardware layer's [`Roi`] (top-left corner and
/// size); odd sizes keep the centre on a pixel, even ones are shrunk by one.
pub use cellinject_hw::Roi;

/// What happened to one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Status {
    /// Measured.
    Tracked,
    /// Measured after a fresh FFT search (the prediction was off).
    Recovered,
    /// Measured against a blurred copy of the reference: the region is out of focus
    /// ([`TrackPoint::blur`] says by how much).
    Defocused,
    /// No trustworthy match: no displacement reported.
    Rejected,
}

/// The measurement in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackPoint {
    /// Displacement of the region's centre from the first frame, pixels (NaN if rejected).
    pub u: f64,
    /// Along y.
    pub v: f64,
    /// ZNCC of the match; for a rejected frame, the best ZNCC an attempt reached (0
    /// if none converged to anything).
    pub zncc: f64,
    /// IC-GN iterations.
    pub iterations: usize,
    /// Predicted standard error of u, pixels.
    pub sigma_u: f64,
    /// Pixels: the Gaussian blur (σ) added to the reference for the match (0 in focus).
    /// For a rejected frame, the largest blur tried.
    pub blur: f64,
    /// What happened.
    pub status: Status,
}

/// The Gaussian blurs (σ, pixels) a tracker tries on its reference when the region went
/// out of focus: spaced so that neighbouring levels overlap (a match between two
/// levels loses little ZNCC).
pub const BLUR_LADDER: [f64; 8] = [1.0, 1.7, 2.5, 3.5, 5.0, 7.0, 9.5, 13.0];

/// The best match a frame's attempts reached, accepted or not.
struct Seen {
    zncc: f64,
    /// Where it converged.
    at: (f64, f64),
}

impl Seen {
    fn note(&mut self, r: &icgn::PointResult) {
        if r.zncc.is_finite() && r.zncc > self.zncc {
            self.zncc = r.zncc;
            self.at = (r.u, r.v);
        }
    }
}

/// Pixels beyond the reference crop that the ladder's blur reads (4σ of its largest
/// rung).
const BLUR_REACH: usize = 52;

/// One rung of the defocus ladder: the reference subset blurred, prepared.
#[derive(Debug, Clone)]
struct Rung {
    prepared: icgn::Prepared,
}

/// Follows a region.
#[derive(Debug, Clone)]
pub struct Tracker {
    reference: Reference,
    prepared: icgn::Prepared,
    /// Centre of the subset in reference-crop coordinates.
    centre: (usize, usize),
    /// Offset of the crop in the frame.
    offset: (usize, usize),
    subset: Subset,
    min_zncc: f64,
    search_radius: usize,
    opts: IcgnOptions,
    last: Option<(f64, f64)>,
    velocity: (f64, f64),
    frame_size: (usize, usize),
    shape: Shape,
    /// The first frame around the region, wider than the reference crop by
    /// [`BLUR_REACH`] where the frame allows, and where the crop starts in it.
    wide: Image,
    wide_at: (usize, usize),
    /// The defocus ladder's rungs prepared so far (`None`: not yet, or no texture left).
    rungs: Vec<Option<Option<Rung>>>,
    /// The rung that matched last (0: in focus; k: `BLUR_LADDER[k - 1]`).
    level: usize,
}

/// Margin kept around a region for the spline and the prediction error, pixels.
const MARGIN: usize = 12;

impl Tracker {
    /// A tracker of `roi` in `first`, refusing matches below `min_zncc`.
    pub fn new(first: &Image, roi: Roi, shape: Shape, min_zncc: f64) -> Result<Self, DicError> {
        let (w, h) = (first.width(), first.height());
        let (rx, ry) = (roi.x as usize, roi.y as usize);
        let hw = (roi.width as usize).saturating_sub(1) / 2;
        let hh = (roi.height as usize).saturating_sub(1) / 2;
        let (cx, cy) = (rx + hw, ry + hh);
        let size = roi.width.max(roi.height) as usize;
        if hw < 3 || hh < 3 || rx + 2 * hw >= w || ry + 2 * hh >= h {
            return Err(DicError::SubsetOutside {
                x: cx as f64,
                y: cy as f64,
                size,
                width: w,
                height: h,
            });
        }
        let ox = cx.saturating_sub(hw + MARGIN);
        let oy = cy.saturating_sub(hh + MARGIN);
        let crop = first.crop(ox, oy, 2 * (hw + MARGIN) + 1, 2 * (hh + MARGIN) + 1);
        // The ladder blurs a wider crop, so that what the blur brings in from around the
        // region is the frame's, not a mirror image.
        let wx = cx.saturating_sub(hw + MARGIN + BLUR_REACH);
        let wy = cy.saturating_sub(hh + MARGIN + BLUR_REACH);
        let wide = first.crop(
            wx,
            wy,
            2 * (hw + MARGIN + BLUR_REACH) + 1,
            2 * (hh + MARGIN + BLUR_REACH) + 1,
        );
        let wide_at = (ox - wx, oy - wy);
        let reference = Reference::new(crop);
        let subset = Subset {
            half_w: hw,
            half_h: hh,
        };
        let prepared = icgn::prepare(&reference, cx - ox, cy - oy, subset, shape).ok_or(
            DicError::NoTexture {
                x: cx as f64,
                y: cy as f64,
            },
        )?;
        Ok(Tracker {
            reference,
            prepared,
            centre: (cx - ox, cy - oy),
            offset: (ox, oy),
            subset,
            min_zncc,
            search_radius: 48,
            opts: IcgnOptions {
                tolerance: 1e-4,
                max_iterations: 20,
                // Every frame is rounded like the first.
                residual_floor: 2.0 * crate::image::quantisation_variance(first),
                // At camera rate the rounding is not simulated (`refine_prepared`).
                quantisation_step: 0.0,
            },
            last: None,
            velocity: (0.0, 0.0),
            frame_size: (w, h),
            shape,
            wide,
            wide_at,
            rungs: vec![None; BLUR_LADDER.len()],
            level: 0,
        })
    }

    /// Forgets the motion seen so far: the next frame is looked for around the
    /// reference position first (after the marker was brought back to rest, say), then by
    /// the FFT search around it.
    pub fn forget(&mut self) {
        self.last = None;
        self.velocity = (0.0, 0.0);
        self.level = 0;
    }

    /// The prepared reference of ladder level `level` (0: the sharp reference).
    fn prepared_at(&mut self, level: usize) -> Option<&icgn::Prepared> {
        if level == 0 {
            return Some(&self.prepared);
        }
        let k = level - 1;
        if self.rungs[k].is_none() {
            let (w, h) = (
                self.reference.image().width(),
                self.reference.image().height(),
            );
            let blurred = gaussian_blur(&self.wide, BLUR_LADDER[k]).crop(
                self.wide_at.0,
                self.wide_at.1,
                w,
                h,
            );
            let reference = Reference::new(blurred);
            let rung = icgn::prepare(
                &reference,
                self.centre.0,
                self.centre.1,
                self.subset,
                self.shape,
            )
            .map(|prepared| Rung { prepared });
            self.rungs[k] = Some(rung);
        }
        self.rungs[k]
            .as_ref()
            .and_then(|r| r.as_ref())
            .map(|r| &r.prepared)
    }

    /// The match at ladder level `level` from `guess`, if it converged to anything.
    fn attempt_at(
        &mut self,
        frame: &Image,
        guess: (f64, f64),
        level: usize,
    ) -> Option<icgn::PointResult> {
        let window = self.window(frame, guess);
        let init = [guess.0, 0.0, 0.0, guess.1, 0.0, 0.0];
        let opts = self.opts;
        let prepared = self.prepared_at(level)?;
        icgn::refine_prepared(prepared, &window, init, &opts)
    }

    /// Climbs the defocus ladder from the level that matched last (at least the first
    /// rung): the best level near it by ZNCC, then, if that is below the threshold, every
    /// level. Returns the best match and its level.
    fn refocus(&mut self, frame: &Image, guess: (f64, f64)) -> Option<(icgn::PointResult, usize)> {
        let top = BLUR_LADDER.len();
        let mut zncc = vec![None::<f64>; top + 1];
        let mut best: Option<(icgn::PointResult, usize)> = None;
        let mut consider = |tracker: &mut Self, level: usize| -> f64 {
            if let Some(z) = zncc[level] {
                return z;
            }
            let r = tracker
                .attempt_at(frame, guess, level)
                .filter(|r| r.zncc.is_finite());
            let z = r.map_or(f64::NEG_INFINITY, |r| r.zncc);
            if let Some(r) = r
                && best.as_ref().is_none_or(|(b, _)| r.zncc > b.zncc)
            {
                best = Some((r, level));
            }
            zncc[level] = Some(z);
            z
        };
        // Hill-climb from the level that matched last (at least the first rung).
        let mut level = self.level.clamp(1, top);
        let mut z = consider(self, level);
        loop {
            let up = if level < top {
                consider(self, level + 1)
            } else {
                f64::NEG_INFINITY
            };
            let down = if level > 1 {
                consider(self, level - 1)
            } else {
                f64::NEG_INFINITY
            };
            if up > z && up >= down {
                level += 1;
                z = up;
            } else if down > z {
                level -= 1;
                z = down;
            } else {
                break;
            }
        }
        if z < self.min_zncc {
            for l in 1..=top {
                consider(self, l);
            }
        }
        best
    }

    /// The spline of the frame's window around the predicted region, addressed in the
    /// reference crop's coordinates.
    fn window(&self, frame: &Image, guess: (f64, f64)) -> BSpline {
        let (hw, hh) = (self.subset.half_w as f64, self.subset.half_h as f64);
        let m = MARGIN as f64;
        let cx = (self.offset.0 + self.centre.0) as f64 + guess.0;
        let cy = (self.offset.1 + self.centre.1) as f64 + guess.1;
        let x0 = (cx - hw - m).floor().max(0.0) as usize;
        let y0 = (cy - hh - m).floor().max(0.0) as usize;
        let w = (2.0 * (hw + m) + 2.0) as usize;
        let h = (2.0 * (hh + m) + 2.0) as usize;
        let mut spline = BSpline::window(frame, x0, y0, w, h);
        spline.shift_origin(-(self.offset.0 as f64), -(self.offset.1 as f64));
        spline
    }

    fn attempt(&self, frame: &Image, guess: (f64, f64)) -> Option<icgn::PointResult> {
        let spline = self.window(frame, guess);
        let init = [guess.0, 0.0, 0.0, guess.1, 0.0, 0.0];
        icgn::refine_prepared(&self.prepared, &spline, init, &self.opts)
    }

    /// Measures one frame.
    pub fn track(&mut self, frame: &Image) -> Result<TrackPoint, DicError> {
        if (frame.width(), frame.height()) != self.frame_size {
            return Err(DicError::SizeMismatch {
                a: self.frame_size,
                b: (frame.width(), frame.height()),
            });
        }
        let guess = match self.last {
            Some((u, v)) => (u + self.velocity.0, v + self.velocity.1),
            None => (0.0, 0.0),
        };
        let min = self.min_zncc;
        // The best match seen, accepted or not: its ZNCC and where it converged (where
        // the ladder looks if the sharp reference is rejected).
        let mut seen = Seen {
            zncc: 0.0,
            at: guess,
        };
        let mut status = Status::Tracked;
        let mut level = 0;
        // The sharp reference first: a blurred one is used only when it is rejected.
        let first = self.attempt(frame, guess);
        if let Some(r) = &first {
            seen.note(r);
        }
        let mut res = first.filter(|r| r.zncc >= min);
        let mut laddered = false;
        if res.is_none() && self.level > 0 {
            // Out of focus at the last frame: the ladder at the prediction.
            laddered = true;
            if let Some((r, l)) = self.refocus(frame, guess) {
                seen.note(&r);
                if r.zncc >= min {
                    res = Some(r);
                    level = l;
                    status = Status::Defocused;
                }
            }
        }
        if res.is_none()
            && let Some(last) = self.last
            && last != guess
        {
            // The motion stopped (a positioning move): try where it was last.
            let again = self.attempt(frame, last);
            if let Some(r) = &again {
                seen.note(r);
            }
            res = again.filter(|r| r.zncc >= min);
        }
        if res.is_none() {
            // The prediction failed: search by FFT within `search_radius` of the last
            // position (the reference's at first), then refine. The frame window is
            // addressed so that the reference crop's origin sits at (sx, sy) inside it.
            let ref_img = self.reference.image();
            let r = self.search_radius as i64;
            let (du, dv) = self
                .last
                .map(|(u, v)| (u.round() as i64, v.round() as i64))
                .unwrap_or((0, 0));
            let fx0 = (self.offset.0 as i64 + du - r).max(0);
            let fy0 = (self.offset.1 as i64 + dv - r).max(0);
            let (sx, sy) = (self.offset.0 as i64 - fx0, self.offset.1 as i64 - fy0);
            let window = frame.crop(
                fx0 as usize,
                fy0 as usize,
                ref_img.width() + 2 * r as usize,
                ref_img.height() + 2 * r as usize,
            );
            let m = self.subset.half_w.min(self.subset.half_h) as i64;
            let hit = search::search(
                ref_img,
                &window,
                self.centre.0 as i64,
                self.centre.1 as i64,
                m,
                r,
                sx + du,
                sy + dv,
            );
            if let Some(hit) = hit {
                let guess = ((hit.u - sx) as f64, (hit.v - sy) as f64);
                let again = self.attempt(frame, guess);
                match &again {
                    Some(r) => seen.note(r),
                    // Nothing converged there: still the best place to look.
                    None if seen.zncc == 0.0 => seen.at = guess,
                    None => {}
                }
                res = again.filter(|p| p.zncc >= min);
                status = Status::Recovered;
            }
        }
        if res.is_none() && (!laddered || seen.at != guess) {
            // Rejected in focus: the region may be out of focus (see the module's doc).
            if let Some((r, l)) = self.refocus(frame, seen.at) {
                seen.note(&r);
                if r.zncc >= min {
                    res = Some(r);
                    level = l;
                    status = Status::Defocused;
                }
            }
        }
        let blur = |l: usize| if l == 0 { 0.0 } else { BLUR_LADDER[l - 1] };
        Ok(match res {
            Some(p) => {
                if let Some((lu, lv)) = self.last {
                    self.velocity = (p.u - lu, p.v - lv);
                }
                self.last = Some((p.u, p.v));
                self.level = level;
                TrackPoint {
                    u: p.u,
                    v: p.v,
                    zncc: p.zncc,
                    iterations: p.iterations,
                    sigma_u: p.sigma_u,
                    blur: blur(level),
                    status,
                }
            }
            None => TrackPoint {
                u: f64::NAN,
                v: f64::NAN,
                zncc: seen.zncc,
                iterations: 0,
                sigma_u: f64::NAN,
                blur: blur(BLUR_LADDER.len()),
                status: Status::Rejected,
            },
        })
    }
}

/// `image` blurred by a Gaussian of standard deviation `sigma` pixels (separable, the
/// kernel cut at 4σ and normalised, mirror boundaries).
pub fn gaussian_blur(image: &Image, sigma: f64) -> Image {
    let (w, h) = (image.width(), image.height());
    let r = (4.0 * sigma).ceil().max(1.0) as i64;
    let mut kernel: Vec<f64> = (-r..=r)
        .map(|k| (-0.5 * (k as f64 / sigma).powi(2)).exp())
        .collect();
    let total: f64 = kernel.iter().sum();
    kernel.iter_mut().for_each(|k| *k /= total);
    let mirror = |i: i64, n: usize| -> usize {
        let n = n as i64;
        let period = 2 * n.max(1) - 2;
        if period <= 0 {
            return 0;
        }
        let m = i.rem_euclid(period);
        (if m >= n { period - m } else { m }) as usize
    };
    let src = image.data();
    let mut rows = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            rows[y * w + x] = kernel
                .iter()
                .enumerate()
                .map(|(k, c)| c * src[y * w + mirror(x as i64 + k as i64 - r, w)])
                .sum();
        }
    }
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            out[y * w + x] = kernel
                .iter()
                .enumerate()
                .map(|(k, c)| c * rows[mirror(y as i64 + k as i64 - r, h) * w + x])
                .sum();
        }
    }
    Image::new(w, h, out).unwrap_or_else(|_| image.clone())
}
