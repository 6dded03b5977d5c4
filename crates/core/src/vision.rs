//! Measuring the end-effector through the two cameras: each camera tracks the speckled
//! marker tab by DIC ([`cellinject_dic::track::Tracker`]) from a reference frame, and
//! its pixel calibration turns the image displacement into metres.
//!
//! Which camera measures which axis: the microscope (top view, looking along y) sees
//! x in its columns and z in its rows; the side camera (looking along x) sees y in its
//! columns and z in its rows. So x comes from the top view, y from the side view, and
//! z from the top view (the side view's z is a cross-check). Neither camera sees the
//! axis along its optical axis except as defocus.

use cellinject_dic::track::{Roi, Status, Tracker};
use cellinject_dic::{DicError, Image, Shape};
use cellinject_hw::{Camera, CameraSettings, Frame, HwError, vga_settings};
use nalgebra::{Matrix2, Vector2};
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// One of the two cameras.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Which {
    /// The microscope, looking along y: x in its columns, z in its rows.
    Top,
    /// The side camera, looking along x: y in its columns, z in its rows.
    Side,
}

impl Which {
    /// Both, top first.
    pub const BOTH: [Which; 2] = [Which::Top, Which::Side];

    /// Its name in files.
    pub fn name(self) -> &'static str {
        match self {
            Which::Top => "top",
            Which::Side => "side",
        }
    }

    /// The stage axes (0 = x, 1 = y, 2 = z) along the image columns and rows.
    pub fn stage_axes(self) -> [usize; 2] {
        match self {
            Which::Top => [0, 2],
            Which::Side => [1, 2],
        }
    }
}

/// How a camera acquires while tracking.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Acquisition {
    /// 640x480 at full resolution centred on the marker (30 fps, the finest pixels:
    /// for positioning to nanometres over tens of micrometres).
    Marker,
    /// 640x480 by 4x4 binning of the sensor's centre (30 fps, the widest field: for
    /// the whole range of motion).
    Wide,
}

/// Why a camera measurement could not be set up or made.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum VisionError {
    /// A device failed.
    #[error("{camera} camera: {source}")]
    Device {
        /// Which camera.
        camera: &'static str,
        /// The device's error.
        source: HwError,
    },
    /// The correlation could not be set up.
    #[error("{camera} camera: {source}")]
    Dic {
        /// Which camera.
        camera: &'static str,
        /// The DIC's error.
        source: DicError,
    },
    /// The marker is not where the rig description says.
    #[error(
        "{camera} camera: the marker at {offset_um:?} µm from the view's centre is outside the {width}x{height} sensor (optics.marker)"
    )]
    MarkerOutside {
        /// Which camera.
        camera: &'static str,
        /// µm.
        offset_um: [f64; 2],
        /// px.
        width: u32,
        /// px.
        height: u32,
    },
}

/// A camera's map from stage motion (m, along the two axes it sees) to image motion
/// (pixels of binning 1): `px = A · m`, fitted from stage moves (paper Sec. 4: the
/// stage's 0.1 µm encoders calibrate the image space).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PixelMap {
    /// Which camera.
    pub camera: Which,
    /// Magnification it was made at.
    pub zoom: f64,
    /// Pixels (binning 1) per metre: rows u, v; columns the stage axes (columns, rows).
    pub pixels_per_metre: [[f64; 2]; 2],
    /// m per pixel along the columns and rows (binning 1).
    pub metres_per_pixel: [f64; 2],
    /// The camera's own statement of its pixel in the object plane, m (binning 1).
    pub nominal_pixel: f64,
    /// rad, rotation of the stage axes in the image.
    pub rotation: f64,
    /// rad, shear between the axes.
    pub skew: f64,
    /// px, RMS residual of the fit.
    pub rms_px: f64,
    /// Stage positions used.
    pub moves: usize,
}

impl PixelMap {
    /// A map that reports pixels of binning 1 as if they were metres (for the
    /// calibration itself).
    pub fn identity(camera: Which, zoom: f64) -> Self {
        PixelMap {
            camera,
            zoom,
            pixels_per_metre: [[1.0, 0.0], [0.0, 1.0]],
            metres_per_pixel: [1.0, 1.0],
            nominal_pixel: 1.0,
            rotation: 0.0,
            skew: 0.0,
            rms_px: 0.0,
            moves: 0,
        }
    }

    /// Metres (along the two stage axes the camera sees) of an image displacement of
    /// `px` output pixels taken at `binning`.
    pub fn to_metres(&self, px: [f64; 2], binning: u32) -> Option<[f64; 2]> {
        let a = Matrix2::new(
            self.pixels_per_metre[0][0],
            self.pixels_per_metre[0][1],
            self.pixels_per_metre[1][0],
            self.pixels_per_metre[1][1],
        ) / binning as f64;
        let m = a.try_inverse()? * Vector2::new(px[0], px[1]);
        Some([m[0], m[1]])
    }

    /// What is wrong with this map, if anything: a residual above 0.3 px, a scale more
    /// than 5 % from the camera's nominal pixel, a shear above 1°. (The stage's 0.1 µm
    /// encoder steps alone leave 0.029 µm RMS: 0.13 px at 10x.)
    pub fn problem(&self) -> Option<String> {
        if !(self.rms_px.is_finite() && self.rms_px <= 0.3) {
            return Some(format!(
                "{} camera: the fit leaves {:.3} px RMS (at most 0.3 px expected: did the stage or the tracking slip?)",
                self.camera.name(),
                self.rms_px
            ));
        }
        for (axis, s) in self.metres_per_pixel.iter().enumerate() {
            let r = s / self.nominal_pixel;
            if !(r.is_finite() && (0.95..=1.05).contains(&r)) {
                return Some(format!(
                    "{} camera: {:.4} µm per pixel along {} is {:.1} % from the camera's nominal {:.4} µm",
                    self.camera.name(),
                    s * 1e6,
                    ["columns", "rows"][axis],
                    (r - 1.0) * 100.0,
                    self.nominal_pixel * 1e6
                ));
            }
        }
        if self.skew.is_nan() || self.skew.abs() > 1f64.to_radians() {
            return Some(format!(
                "{} camera: the stage axes appear sheared by {:.2}° in the image",
                self.camera.name(),
                self.skew.to_degrees()
            ));
        }
        None
    }
}

/// Acquisition settings of `camera` for `acquisition`, and the marker's centre in the
/// output frame (px), from the marker's offset from the view's centre (m) and the
/// object-plane size of a sensor pixel (m).
pub fn settings_for(
    camera: &dyn Camera,
    which: Which,
    acquisition: Acquisition,
    marker: [f64; 2],
    sensor_pixel: f64,
) -> Result<(CameraSettings, [f64; 2]), VisionError> {
    let (w, h) = camera.sensor_size();
    let cx = 0.5 * w as f64 + marker[0] / sensor_pixel;
    let cy = 0.5 * h as f64 + marker[1] / sensor_pixel;
    if !(cx >= 0.0 && cy >= 0.0 && cx < w as f64 && cy < h as f64) {
        return Err(VisionError::MarkerOutside {
            camera: which.name(),
            offset_um: [marker[0] * 1e6, marker[1] * 1e6],
            width: w,
            height: h,
        });
    }
    let current = camera.settings();
    let s = match acquisition {
        Acquisition::Wide => vga_settings((w, h), &current, true),
        Acquisition::Marker => {
            let mut s = vga_settings((w, h), &current, false);
            let rw = s.roi.width as f64;
            let rh = s.roi.height as f64;
            s.roi.x = (cx - 0.5 * rw).round().clamp(0.0, w as f64 - rw) as u32;
            s.roi.y = (cy - 0.5 * rh).round().clamp(0.0, h as f64 - rh) as u32;
            s
        }
    };
    let b = s.binning as f64;
    let at = [(cx - s.roi.x as f64) / b, (cy - s.roi.y as f64) / b];
    Ok((s, at))
}

/// One camera following the marker.
pub struct View {
    which: Which,
    tracker: Tracker,
    map: PixelMap,
    binning: u32,
    /// The last frame grabbed (its buffer is reused).
    pub frame: Frame,
    /// Frames rejected by the correlation since the start.
    pub rejected: u64,
    /// Frames measured against a blurred reference (out of focus) since the start.
    pub defocused: u64,
    /// The last rejected frame: the best ZNCC its attempts reached and the largest blur
    /// (px) tried on the reference.
    pub last_rejection: Option<Rejection>,
}

/// What the correlation reached on a rejected frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rejection {
    /// The best ZNCC any attempt reached (sharp or blurred reference).
    pub zncc: f64,
    /// Pixels, the largest Gaussian blur tried on the reference.
    pub blur: f64,
    /// s, the frame's timestamp.
    pub t: f64,
}

/// The lowest ZNCC a tracked frame may have.
pub const MIN_ZNCC: f64 = 0.8;

/// Side of the tracked subset in the object plane, m (inside the 80 µm marker tab: 181
/// pixels at 10x, where the correlation's noise is a few nanometres).
pub const SUBSET: f64 = 40e-6;

impl View {
    /// Starts tracking on `camera` (already configured) from `reference` (a frame of
    /// the marker at rest centred near `at`, px), measuring with `map`.
    pub fn new(
        which: Which,
        reference: Frame,
        at: [f64; 2],
        binning: u32,
        map: PixelMap,
    ) -> Result<Self, VisionError> {
        let dic = |source| VisionError::Dic {
            camera: which.name(),
            source,
        };
        let img = Image::from_frame(&reference).map_err(dic)?;
        let side = ((SUBSET / reference.pixel_size).round() as u32).max(31) | 1;
        let roi = Roi {
            x: (at[0] - (side / 2) as f64).round().max(0.0) as u32,
            y: (at[1] - (side / 2) as f64).round().max(0.0) as u32,
            width: side,
            height: side,
        };
        let tracker = Tracker::new(&img, roi, Shape::Rigid, MIN_ZNCC).map_err(dic)?;
        Ok(View {
            which,
            tracker,
            map,
            binning,
            frame: reference,
            rejected: 0,
            defocused: 0,
            last_rejection: None,
        })
    }

    /// Which camera.
    pub fn which(&self) -> Which {
        self.which
    }

    /// Forgets the motion seen so far: the next frame is looked for at the reference
    /// position first, then by a search around it (after the marker was brought back
    /// to rest).
    pub fn forget(&mut self) {
        self.tracker.forget();
    }

    /// Measures with another pixel map from now on.
    pub fn set_map(&mut self, map: PixelMap) {
        self.map = map;
    }

    /// Grabs the next frame of `camera` and measures it: the marker's displacement from
    /// the reference along the two axes this camera sees (m), or `None` if the
    /// correlation rejected the frame.
    pub fn measure(&mut self, camera: &mut dyn Camera) -> Result<Option<[f64; 2]>, VisionError> {
        self.grab(camera)?;
        self.measure_frame()
    }

    /// Grabs the next frame of `camera` into [`View::frame`] without measuring it (a
    /// pair of views can then be measured in parallel, [`measure_pair`]).
    pub fn grab(&mut self, camera: &mut dyn Camera) -> Result<(), VisionError> {
        camera
            .grab_into(&mut self.frame)
            .map_err(|source| VisionError::Device {
                camera: self.which.name(),
                source,
            })
    }

    /// Measures the frame in [`View::frame`].
    pub fn measure_frame(&mut self) -> Result<Option<[f64; 2]>, VisionError> {
        let dic = |source| VisionError::Dic {
            camera: self.which.name(),
            source,
        };
        let img = Image::from_frame(&self.frame).map_err(dic)?;
        let p = self.tracker.track(&img).map_err(dic)?;
        if p.status == Status::Rejected || !p.u.is_finite() || !p.v.is_finite() {
            self.rejected += 1;
            self.last_rejection = Some(Rejection {
                zncc: p.zncc,
                blur: p.blur,
                t: self.frame.timestamp,
            });
            return Ok(None);
        }
        if p.status == Status::Defocused {
            self.defocused += 1;
        }
        Ok(self.map.to_metres([p.u, p.v], self.binning))
    }
}

/// Measures the frames both views hold, the two correlations on two threads (they
/// are independent; the answer is the same as measuring one after the other).
pub fn measure_pair(views: &mut [View; 2]) -> Result<[Option<[f64; 2]>; 2], VisionError> {
    let [a, b] = views;
    let (ra, rb) = rayon::join(|| a.measure_frame(), || b.measure_frame());
    Ok([ra?, rb?])
}
