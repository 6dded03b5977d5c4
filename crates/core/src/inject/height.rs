//! The tip's height from the side camera: where the stage must stand for the tip to
//! be in focus.
//!
//! The option's focus is the stage height that puts the resting tip in the focal
//! plane as the session's first run finds the bench. Since then the tip has moved
//! against the stage without the stage moving: the stacks creep back from the
//! identification or an earlier run, and the drives expand as the lab warms (300 nm/K
//! each on the prototype, some 6 um of tip height over 3 K). The stacks' sensors see
//! the creep only, through the mechanism model's Jacobian (16 % off on the twin), and
//! drift with temperature themselves; the side camera sees the tip's height itself
//! (its columns run along the stage's height axis, [`crate::vision::Which::Side`]).
//!
//! So the session's first run takes a **reference** of the marker tab in the side
//! camera with the stage at a fixed point and the stacks at rest, before anything
//! moves; every later measurement brings the stage back to that point and tracks the
//! tab by DIC against it. The tab is tracked at two places along the columns: the
//! side camera's magnification drifts with temperature too (the frames still report
//! the nominal pixel), which moves a point by the drift times its distance from the
//! sensor's centre, so the displacement is extrapolated linearly to the sensor's
//! centre column, where the drift moves nothing. The sign of the columns against the
//! stage's height is learnt once, by a known stage move.

use cellinject_dic::track::{Roi, Status, Tracker};
use cellinject_dic::{Image, Shape};
use cellinject_hw::{Camera, CameraSettings, Clock, Frame, HwError, Stage, vga_settings};
use cellinject_rig::Backend;

use super::{Workflow, WorkflowError, dev};

/// m, the stage's height move that tells which way the side camera's columns run.
const PROBE: f64 = 20e-6;

/// Frames averaged for one height measurement.
const FRAMES: usize = 8;

/// m, side of each tracked subset in the object plane (two of them fit the 80 um tab
/// side by side with room for where the tab was found).
const SUBSET: f64 = 27e-6;

/// m, distance between the two subsets' centres along the columns.
const APART: f64 = 32e-6;

/// m, side of the window the tab is looked for with (the tab's own size).
const TAB: f64 = 80e-6;

/// Lowest ZNCC a side frame's match may have.
const MIN_ZNCC: f64 = 0.9;

/// m, farthest the stage may stand from the reference's point before it is brought
/// back there to measure.
const AT_POINT: f64 = 0.05e-6;

/// What the side camera saw of the marker tab when a session's reference was taken:
/// enough to track the tab against it in any later run of the session.
#[derive(Debug, Clone, PartialEq)]
pub struct SideReference {
    frame: Frame,
    settings: CameraSettings,
    /// Output pixels: the two subsets' centres (column, row).
    centres: [[f64; 2]; 2],
    /// Output pixels: the subsets' side.
    side: u32,
    /// Output pixels: the sensor's centre column in the frame.
    centre_column: f64,
    /// m of tip height per output pixel along the columns (its sign: which way the
    /// columns run).
    metres_per_px: f64,
    /// m, the stage's position (x, height, z) the reference was taken at.
    pub stage: [f64; 3],
}

/// One height measurement against a [`SideReference`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Height {
    /// m, how much higher the tip stands than at the reference (stage at the same
    /// point).
    pub above: f64,
    /// Relative change of the side camera's magnification since the reference.
    pub scale: f64,
    /// m, standard error of `above` over the frames.
    pub sigma: f64,
}

/// The centre (column, row) of the window of side `window` with the most texture
/// (the sum of squared differences to the right and below), or `None` when the best
/// window's texture is under four times the median window's (no tab in view).
pub fn find_tab(img: &Image, window: usize) -> Option<[usize; 2]> {
    let (w, h) = (img.width(), img.height());
    if window < 3 || w <= window + 1 || h <= window + 1 {
        return None;
    }
    // Integral image of the texture.
    let mut sum = vec![0.0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0.0;
        for x in 0..w {
            let g = img.at(x, y);
            let gx = if x + 1 < w { img.at(x + 1, y) - g } else { 0.0 };
            let gy = if y + 1 < h { img.at(x, y + 1) - g } else { 0.0 };
            row += gx * gx + gy * gy;
            sum[(y + 1) * (w + 1) + x + 1] = sum[y * (w + 1) + x + 1] + row;
        }
    }
    let at = |x: usize, y: usize| sum[y * (w + 1) + x];
    let step = (window / 8).max(1);
    let mut all = Vec::new();
    let mut best = (f64::NEG_INFINITY, [0, 0]);
    for y in (0..h - window).step_by(step) {
        for x in (0..w - window).step_by(step) {
            let s = at(x + window, y + window) - at(x, y + window) - at(x + window, y) + at(x, y);
            all.push(s);
            if s > best.0 {
                best = (s, [x + window / 2, y + window / 2]);
            }
        }
    }
    let n = all.len();
    let median = *all.select_nth_unstable_by(n / 2, f64::total_cmp).1;
    (best.0 > 4.0 * median.max(f64::MIN_POSITIVE)).then_some(best.1)
}

/// The displacement at column `at` of a body whose image moved by `u[k]` at columns
/// `columns[k]` (pixels): a magnification change moves a point in proportion to its
/// distance from the column the magnification scales about, so the displacement is
/// linear in the column. Returns (the displacement at `at`, the relative scale
/// change).
pub fn at_column(u: [f64; 2], columns: [f64; 2], at: f64) -> (f64, f64) {
    let scale = (u[1] - u[0]) / (columns[1] - columns[0]);
    (u[0] + scale * (at - columns[0]), scale)
}

impl SideReference {
    /// Tracks the tab in `frames` frames of `camera` (set to the reference's
    /// settings) against the reference: the tip's height above the reference, or
    /// why it could not be measured.
    fn measure(
        &self,
        camera: &mut dyn Camera,
        frames: usize,
    ) -> Result<Result<Height, String>, HwError> {
        if camera.settings() != self.settings {
            camera.configure(self.settings)?;
        }
        let reference = match Image::from_frame(&self.frame) {
            Ok(i) => i,
            Err(e) => return Ok(Err(format!("the side reference: {e}"))),
        };
        let mut trackers = Vec::with_capacity(2);
        for c in self.centres {
            let roi = Roi {
                x: (c[0] - (self.side / 2) as f64).round() as u32,
                y: (c[1] - (self.side / 2) as f64).round() as u32,
                width: self.side,
                height: self.side,
            };
            match Tracker::new(&reference, roi, Shape::Rigid, MIN_ZNCC) {
                Ok(t) => trackers.push(t),
                Err(e) => return Ok(Err(format!("the side reference: {e}"))),
            }
        }
        let mut frame = Frame::default();
        let (mut sum, mut sum2, mut scales) = (0.0, 0.0, 0.0);
        for k in 0..frames.max(2) {
            camera.grab_into(&mut frame)?;
            let img = match Image::from_frame(&frame) {
                Ok(i) => i,
                Err(e) => return Ok(Err(format!("side frame: {e}"))),
            };
            let mut u = [0.0; 2];
            for (t, u) in trackers.iter_mut().zip(&mut u) {
                let p = match t.track(&img) {
                    Ok(p) => p,
                    Err(e) => return Ok(Err(format!("side frame {k}: {e}"))),
                };
                if p.status == Status::Rejected || !p.u.is_finite() {
                    return Ok(Err(format!(
                        "side frame {k}: the marker tab matched its reference with ZNCC {:.2} (at least {MIN_ZNCC} needed)",
                        p.zncc
                    )));
                }
                *u = p.u;
            }
            let (d, s) = at_column(
                u,
                [self.centres[0][0], self.centres[1][0]],
                self.centre_column,
            );
            sum += d;
            sum2 += d * d;
            scales += s;
        }
        let n = frames.max(2) as f64;
        let mean = sum / n;
        let var = ((sum2 - n * mean * mean) / (n - 1.0)).max(0.0);
        Ok(Ok(Height {
            above: mean * self.metres_per_px,
            scale: scales / n,
            sigma: (var / n).sqrt() * self.metres_per_px.abs(),
        }))
    }
}

impl<B: Backend> Workflow<'_, B> {
    /// Takes the session's side reference with the stage where it stands and the
    /// stacks at rest, and learns which way the columns run from a [`PROBE`] move of
    /// the stage's height (up, then back). `Ok(Err(why))`: the side camera cannot
    /// measure the tip's height (the run refers its focus to the stacks' sensors).
    pub(super) fn side_reference(
        &mut self,
    ) -> Result<Result<SideReference, String>, WorkflowError> {
        let mut stage = [0.0; 3];
        for (a, p) in stage.iter_mut().enumerate() {
            *p = self.rig.stage.position(a).map_err(dev("stage"))?;
        }
        let cam = &mut self.rig.side_camera;
        let (sw, sh) = cam.sensor_size();
        // The whole sensor, binned to VGA: the tab is in view wherever the stage's
        // height and the stacks put it, and its speckles are sharp at that pitch.
        let settings = vga_settings((sw, sh), &cam.settings(), true);
        cam.configure(settings).map_err(dev("side camera"))?;
        let settings = cam.settings();
        // The first frame at the new settings is dropped (it may have started before).
        cam.grab().map_err(dev("side camera"))?;
        let frame = cam.grab().map_err(dev("side camera"))?;
        let b = settings.binning.max(1) as f64;
        let pitch = frame.pixel_size;
        if !(pitch.is_finite() && pitch > 0.0) {
            return Ok(Err(format!("the side camera reports a pixel of {pitch} m")));
        }
        let img = match Image::from_frame(&frame) {
            Ok(i) => i,
            Err(e) => return Ok(Err(format!("side frame: {e}"))),
        };
        let Some(tab) = find_tab(&img, (TAB / pitch).round() as usize) else {
            return Ok(Err("no marker tab in the side camera's view".into()));
        };
        let side = ((SUBSET / pitch).round() as u32).max(31) | 1;
        let half = 0.5 * APART / pitch;
        let centres = [-half, half].map(|d| [tab[0] as f64 + d, tab[1] as f64]);
        let r = side as f64 / 2.0;
        if centres.iter().any(|c| {
            c[0] - r < 0.0
                || c[1] - r < 0.0
                || c[0] + r >= img.width() as f64
                || c[1] + r >= img.height() as f64
        }) {
            return Ok(Err("the marker tab lies at the side view's edge".into()));
        }
        let mut reference = SideReference {
            frame,
            settings,
            centres,
            side,
            centre_column: (0.5 * sw as f64 - settings.roi.x as f64) / b - 0.5,
            metres_per_px: 1.0,
            stage,
        };
        // Which way the columns run: the stage up by PROBE (away from the plate).
        if let Err(e) = self.stage_settle(stage[1] + PROBE)? {
            return Ok(Err(e));
        }
        let moved = reference
            .measure(&mut self.rig.side_camera, 4)
            .map_err(dev("side camera"))?;
        if let Err(e) = self.stage_settle(stage[1])? {
            return Ok(Err(e));
        }
        let moved = match moved {
            Ok(h) => h.above,
            Err(why) => {
                return Ok(Err(format!(
                    "the side camera lost the tab on a {:.0} µm stage move: {why}",
                    PROBE * 1e6
                )));
            }
        };
        // `moved` is in pixels here: the scale is the stage's own (the focus is a
        // stage height), the nominal pixel only a check of it.
        let ratio = moved * pitch / PROBE;
        if !(0.8..=1.25).contains(&ratio.abs()) {
            return Ok(Err(format!(
                "the side camera saw {:.2} µm along its columns for the stage's {:.0} µm up (its columns do not run along the height)",
                moved * pitch * 1e6,
                PROBE * 1e6
            )));
        }
        reference.metres_per_px = PROBE / moved;
        Ok(Ok(reference))
    }

    /// The tip's height above the session's side reference, the stage brought back to
    /// the reference's point first (height first: the point is at the lift), with
    /// the loops holding the stacks.
    pub(super) fn side_height(
        &mut self,
        r: &SideReference,
    ) -> Result<Result<Height, String>, WorkflowError> {
        let mut far = 0.0f64;
        for (a, want) in r.stage.iter().enumerate() {
            let now = self.rig.stage.position(a).map_err(dev("stage"))?;
            far = far.max((now - want).abs());
        }
        if far > AT_POINT {
            for p in [[None, Some(r.stage[1]), None], r.stage.map(Some)] {
                if let Err(e) = self.stage_to(p)? {
                    return Ok(Err(e));
                }
            }
        }
        self.wait(0.3)?;
        r.measure(&mut self.rig.side_camera, FRAMES)
            .map_err(dev("side camera"))
    }

    /// Measures the tip's height again (after the image map, and at every re-check:
    /// the tip keeps moving against the stage as the stacks settle and the lab
    /// warms) and moves the focus height by it; the stage comes back to where it
    /// was. What it found, for the record, or why not (the focus then stays).
    pub(super) fn refocus(&mut self) -> Result<Option<String>, WorkflowError> {
        let Some(r) = self.side.clone() else {
            return Ok(None);
        };
        let mut was = [0.0; 3];
        for (a, p) in was.iter_mut().enumerate() {
            *p = self.rig.stage.position(a).map_err(dev("stage"))?;
        }
        let seen = self.side_height(&r)?;
        let up = r.stage[1].max(was[1]);
        for p in [
            [None, Some(up), None],
            [Some(was[0]), None, Some(was[2])],
            [None, Some(was[1]), None],
        ] {
            if let Err(e) = self.stage_to(p)? {
                return Ok(Some(format!(
                    "the stage could not come back from the side camera's point: {e}"
                )));
            }
        }
        Ok(Some(match seen {
            Ok(h) => {
                let before = self.focus;
                self.focus = self.options.focus - h.above;
                self.focus_by = "side camera";
                format!(
                    "the side camera sees the tip {:.2} µm {} than at the session's start: focus height {:.2} µm ({:+.2} µm)",
                    h.above.abs() * 1e6,
                    if h.above < 0.0 { "lower" } else { "higher" },
                    self.focus * 1e6,
                    (self.focus - before) * 1e6
                )
            }
            Err(e) => format!(
                "the side camera could not measure the tip's height again ({e}): the focus stays"
            ),
        }))
    }

    /// The stage's height to `y`, arrived and settled (before the loops run);
    /// `Ok(Err(why))` when the stage refuses the move (its travel).
    fn stage_settle(&mut self, y: f64) -> Result<Result<(), String>, WorkflowError> {
        if let Err(e) = self.rig.stage.move_to(1, y) {
            return Ok(Err(format!(
                "the stage refused the side camera's move to {:.1} µm: {e}",
                y * 1e6
            )));
        }
        self.raise_to(y)?;
        self.rig.clock.sleep(0.3).map_err(dev("clock"))?;
        Ok(Ok(()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A magnified body: the displacement at the scaling column is the body's own,
    /// wherever the two points sit.
    #[test]
    fn the_displacement_is_taken_where_the_magnification_moves_nothing() {
        let (d, m, centre) = (1.7, 2e-3, 300.0);
        let u = |c: f64| d * (1.0 + m) + m * (c - centre);
        let (at, scale) = at_column([u(410.0), u(446.0)], [410.0, 446.0], centre);
        assert!((at - d * (1.0 + m)).abs() < 1e-12, "{at}");
        assert!((scale - m).abs() < 1e-12, "{scale}");
    }

    /// A speckled square on a plain, slightly noisy frame is found at its centre; a
    /// plain frame has no tab.
    #[test]
    fn the_tab_is_found_by_its_texture() {
        let (w, h) = (200usize, 150usize);
        let mut data = vec![0.0; w * h];
        let mut s = 12345u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 33) as f64 / (1u64 << 31) as f64
        };
        for v in data.iter_mut() {
            *v = 100.0 + 2.0 * rnd();
        }
        let plain = Image::new(w, h, data.clone()).unwrap();
        assert_eq!(find_tab(&plain, 40), None);
        for y in 60..100 {
            for x in 120..160 {
                data[y * w + x] = 60.0 + 80.0 * rnd();
            }
        }
        let img = Image::new(w, h, data).unwrap();
        let [x, y] = find_tab(&img, 40).unwrap();
        assert!(
            (x as i64 - 140).abs() <= 5 && (y as i64 - 80).abs() <= 5,
            "{x}, {y}"
        );
    }
}
