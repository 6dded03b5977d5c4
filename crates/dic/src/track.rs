//! Tracking one region through a sequence of frames (the closed loop's measurement):
//! the region of the first frame is the reference subset; each frame is predicted from
//! the previous motion (constant velocity), refined by IC-GN on a spline of a small
//! window only (not the whole frame), re-searched by FFT if that fails, and rejected
//! (no number reported) if the ZNCC stays below the threshold.

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
    /// What happened.
    pub status: Status,
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
            },
            last: None,
            velocity: (0.0, 0.0),
            frame_size: (w, h),
        })
    }

    fn attempt(&self, frame: &Image, guess: (f64, f64)) -> Option<icgn::PointResult> {
        let (hw, hh) = (self.subset.half_w as f64, self.subset.half_h as f64);
        let m = MARGIN as f64;
        // Window of the frame around the predicted region.
        let cx = (self.offset.0 + self.centre.0) as f64 + guess.0;
        let cy = (self.offset.1 + self.centre.1) as f64 + guess.1;
        let x0 = (cx - hw - m).floor().max(0.0) as usize;
        let y0 = (cy - hh - m).floor().max(0.0) as usize;
        let w = (2.0 * (hw + m) + 2.0) as usize;
        let h = (2.0 * (hh + m) + 2.0) as usize;
        let mut spline = BSpline::window(frame, x0, y0, w, h);
        // Address the window in the reference crop's coordinates.
        spline.shift_origin(-(self.offset.0 as f64), -(self.offset.1 as f64));
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
        let mut status = Status::Tracked;
        let mut best = 0.0f64;
        let mut res = self.attempt(frame, guess);
        if let Some(r) = &res {
            best = best.max(r.zncc);
        }
        let mut res = res.take().filter(|r| r.zncc >= self.min_zncc);
        if res.is_none()
            && let Some(last) = self.last
            && last != guess
        {
            // The motion stopped (a positioning move): try where it was last.
            let again = self.attempt(frame, last);
            if let Some(r) = &again {
                best = best.max(r.zncc);
            }
            res = again.filter(|r| r.zncc >= self.min_zncc);
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
                if let Some(r) = &again {
                    best = best.max(r.zncc);
                }
                res = again.filter(|p| p.zncc >= self.min_zncc);
                status = Status::Recovered;
            }
        }
        Ok(match res {
            Some(p) => {
                if let Some((lu, lv)) = self.last {
                    self.velocity = (p.u - lu, p.v - lv);
                }
                self.last = Some((p.u, p.v));
                TrackPoint {
                    u: p.u,
                    v: p.v,
                    zncc: p.zncc,
                    iterations: p.iterations,
                    sigma_u: p.sigma_u,
                    status,
                }
            }
            None => TrackPoint {
                u: f64::NAN,
                v: f64::NAN,
                zncc: if best.is_finite() { best } else { 0.0 },
                iterations: 0,
                sigma_u: f64::NAN,
                status: Status::Rejected,
            },
        })
    }
}
