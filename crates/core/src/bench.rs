//! The bench as the experiments and calibrations use it: a guarded rig, its two
//! cameras tracking the marker, the stack sensors zeroed at rest, and a runner that
//! steps a [`Controller`] at its rate between camera frames.
//!
//! Timing of the runner: the control step runs every `1 / rate` s (1 kHz); the cameras
//! are triggered together at their frame rate (30 fps for VGA); a frame's measurement
//! reaches the controller `exposure + latency` after the exposure starts (readout and
//! correlation; 15 ms by default), never earlier. A frame that is lost or whose
//! correlation is rejected by either camera reaches it as [`Vision::Rejected`].
//!
//! The twin's truth, when the backend has one, is read through a closure at every
//! frame, so that reports can say how far the cameras were from it.

use cellinject_control::{Controller, Measurement, Vision};
use cellinject_hw::{Camera, Clock, HwError, PositionSensor, Stage};
use cellinject_rig::{Backend, Rig};
use serde::Serialize;
use thiserror::Error;

use crate::vision::{self, Acquisition, PixelMap, View, VisionError, Which, settings_for};

/// Why a bench operation failed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum BenchError {
    /// A device failed or refused.
    #[error("{what}: {source}")]
    Device {
        /// What was being done.
        what: &'static str,
        /// The device's error.
        source: HwError,
    },
    /// A camera measurement failed.
    #[error(transparent)]
    Vision(#[from] VisionError),
    /// An argument out of its domain.
    #[error("{arg} {reason}, got {value}")]
    Invalid {
        /// The argument.
        arg: &'static str,
        /// Its value.
        value: f64,
        /// What is wrong.
        reason: String,
    },
    /// A calibration's own check failed.
    #[error("the {what} calibration failed its check: {reason}")]
    Calibration {
        /// Which calibration.
        what: &'static str,
        /// What is wrong, with the numbers.
        reason: String,
    },
    /// The cameras lost the marker.
    #[error(
        "the {camera} camera lost the marker during {what}: {rejected} frames rejected, the best match reaching ZNCC {zncc:.3} (at least {min_zncc} needed) against the reference sharp and blurred by up to {blur_px} px (out of focus){tried}; the marker left the field of view, moved too far between frames, or is hidden"
    )]
    Lost {
        /// What was being done.
        what: &'static str,
        /// The camera that lost it last.
        camera: &'static str,
        /// Frames rejected (both cameras).
        rejected: u64,
        /// The best ZNCC of its last rejected frame.
        zncc: f64,
        /// The threshold.
        min_zncc: f64,
        /// Pixels, the largest blur tried on the reference.
        blur_px: f64,
        /// What was tried to recover (empty, or "; tried: ...").
        tried: String,
    },
}

pub(crate) fn dev(what: &'static str) -> impl Fn(HwError) -> BenchError {
    move |source| BenchError::Device { what, source }
}

/// Timing of the runner.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timing {
    /// Hz, control steps per second.
    pub rate: f64,
    /// s, from the end of a frame's exposure to its measurement reaching the controller.
    pub latency: f64,
}

impl Default for Timing {
    fn default() -> Self {
        Timing {
            rate: 1000.0,
            latency: 0.015,
        }
    }
}

/// What one camera frame pair showed.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `t` | s | start of the exposure, from the start of the run |
/// | `reference` | m | the stacks' reference (A1, A2) in the middle of the exposure (where the tip should be in this frame) |
/// | `measured` | m | end-effector displacement from rest (x from the top camera, y from the side camera, z from the top camera); absent if a camera rejected the frame |
/// | `views` | m | each camera's own measurement (top: x, z; side: y, z); absent where it rejected the frame |
/// | `truth` | m | the twin's true displacement during the exposure (mean of its start and end), where known |
/// | `volts` | V | A1, A2 as applied then |
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FrameRecord {
    /// s.
    pub t: f64,
    /// m.
    pub reference: [f64; 2],
    /// m: x, y, z.
    pub measured: Option<[f64; 3]>,
    /// m: top (x, z), side (y, z).
    pub views: [Option<[f64; 2]>; 2],
    /// m: x, y, z.
    pub truth: Option<[f64; 3]>,
    /// V.
    pub volts: [f64; 2],
}

/// A guarded rig with both cameras tracking the marker.
pub struct Bench<'r, B: Backend> {
    /// The rig.
    pub rig: &'r mut Rig<B>,
    views: [View; 2],
    rest: [f64; 2],
    truth: Option<Box<dyn FnMut() -> [f64; 3] + 'r>>,
    truth0: [f64; 3],
    timing: Timing,
    period: f64,
    next_frame: f64,
    /// A frame's measurement waiting for its latency: when it is due, what it saw, and
    /// the references in effect while it was exposed.
    pending: Option<(f64, Vision, [f64; 2])>,
    volts: [f64; 2],
    /// Told the device time since it was set, s, after every frame ([`Bench::watch`]).
    watch: Option<Watch<'r>>,
}

/// [`Bench::watch`]'s observer: the device time it was set at, s, and the callback.
type Watch<'r> = (f64, Box<dyn FnMut(f64) + 'r>);

/// The object-plane size of a sensor pixel of `camera`, from one frame grabbed with
/// its current settings (the camera states its output pixel's size).
fn sensor_pixel(camera: &mut dyn Camera, which: Which) -> Result<f64, BenchError> {
    let f = camera.grab().map_err(|source| VisionError::Device {
        camera: which.name(),
        source,
    })?;
    Ok(f.pixel_size / camera.settings().binning as f64)
}

impl<'r, B: Backend> Bench<'r, B> {
    /// Sets both cameras to `acquisition`, takes their reference frames with the
    /// stacks at rest (0 V on A1 and A2 for `settle` s first), zeroes the stack
    /// sensors, and measures with the pixel maps `maps` (top, side).
    pub fn new(
        rig: &'r mut Rig<B>,
        acquisition: Acquisition,
        marker: [f64; 2],
        maps: [PixelMap; 2],
        truth: Option<Box<dyn FnMut() -> [f64; 3] + 'r>>,
        timing: Timing,
    ) -> Result<Self, BenchError> {
        if !(timing.rate.is_finite() && (50.0..=100_000.0).contains(&timing.rate)) {
            return Err(BenchError::Invalid {
                arg: "--rate",
                value: timing.rate,
                reason: "must lie in [50, 100000] Hz".into(),
            });
        }
        if !(timing.latency.is_finite() && (0.0..=1.0).contains(&timing.latency)) {
            return Err(BenchError::Invalid {
                arg: "--latency",
                value: timing.latency,
                reason: "must lie in [0, 1] s".into(),
            });
        }
        rig.command_tilt([0.0, 0.0]).map_err(dev("rest"))?;
        rig.clock.sleep(0.2).map_err(dev("rest"))?;
        let mut ats = [[0.0; 2]; 2];
        for which in Which::BOTH {
            let cam: &mut dyn Camera = match which {
                Which::Top => &mut rig.camera,
                Which::Side => &mut rig.side_camera,
            };
            let sp = sensor_pixel(cam, which)?;
            let (s, at) = settings_for(cam, which, acquisition, marker, sp)?;
            cam.configure(s).map_err(|source| VisionError::Device {
                camera: which.name(),
                source,
            })?;
            ats[which as usize] = at;
        }
        // Reference frames, taken together.
        let top = rig.camera.grab().map_err(dev("top camera"))?;
        let side = rig.side_camera.grab().map_err(dev("side camera"))?;
        let period = 1.0 / rig.camera.frame_rate();
        let next_frame = top.timestamp + period;
        let views = [
            View::new(
                Which::Top,
                top,
                ats[0],
                rig.camera.settings().binning,
                maps[0],
            )?,
            View::new(
                Which::Side,
                side,
                ats[1],
                rig.side_camera.settings().binning,
                maps[1],
            )?,
        ];
        let mut truth = truth;
        let truth0 = truth.as_mut().map(|f| f()).unwrap_or([0.0; 3]);
        let mut bench = Bench {
            rig,
            views,
            rest: [0.0; 2],
            truth,
            truth0,
            timing,
            period,
            next_frame,
            pending: None,
            volts: [0.0; 2],
            watch: None,
        };
        bench.rest = bench.read_stacks(20)?;
        Ok(bench)
    }

    /// Calls `progress` after every frame with the device time since now, s: a
    /// front end's progress over an experiment whose device time is known
    /// ([`crate::experiment::range_seconds`], [`crate::experiment::TrackingOptions::seconds`]).
    pub fn watch(&mut self, progress: impl FnMut(f64) + 'r) {
        self.watch = Some((self.rig.clock.now(), Box::new(progress)));
    }

    /// The timing.
    pub fn timing(&self) -> Timing {
        self.timing
    }

    /// Seconds between camera frames.
    pub fn frame_period(&self) -> f64 {
        self.period
    }

    /// The last frame of camera `which`.
    pub fn view_frame(&self, which: Which) -> &cellinject_hw::Frame {
        &self.views[which as usize].frame
    }

    /// Frames rejected by each camera's correlation so far (top, side).
    pub fn rejected(&self) -> [u64; 2] {
        [self.views[0].rejected, self.views[1].rejected]
    }

    /// Frames each camera measured out of focus (against a blurred reference) so far.
    pub fn defocused(&self) -> [u64; 2] {
        [self.views[0].defocused, self.views[1].defocused]
    }

    /// The error that says the cameras lost the marker during `what`, with what the
    /// camera that lost it last reached, and what was tried (`tried`, may be empty).
    pub fn lost(&self, what: &'static str, tried: &str) -> BenchError {
        let last = Which::BOTH
            .into_iter()
            .filter_map(|w| self.views[w as usize].last_rejection.map(|r| (w, r)))
            .max_by(|a, b| a.1.t.total_cmp(&b.1.t));
        let (camera, zncc, blur) = match last {
            Some((w, r)) => (w.name(), r.zncc, r.blur),
            None => ("top", f64::NAN, 0.0),
        };
        BenchError::Lost {
            what,
            camera,
            rejected: self.rejected().iter().sum(),
            zncc,
            min_zncc: vision::MIN_ZNCC,
            blur_px: blur,
            tried: if tried.is_empty() {
                String::new()
            } else {
                format!("; tried: {tried}")
            },
        }
    }

    /// Looks for the marker afresh in both cameras (after it was lost and the stacks
    /// were brought back to rest): the trackers forget the motion they saw, and one
    /// frame pair is measured.
    pub fn refind(&mut self) -> Result<[Option<[f64; 2]>; 2], BenchError> {
        for v in &mut self.views {
            v.forget();
        }
        self.measure_views(1)
    }

    /// The stacks' extensions from rest (A1, A2), m, averaged over `n` readings.
    pub fn read_stacks(&mut self, n: usize) -> Result<[f64; 2], BenchError> {
        let mut sum = [0.0; 2];
        for _ in 0..n.max(1) {
            for i in 0..2 {
                sum[i] += self.rig.sensors[i].read().map_err(dev("stack sensor"))?;
            }
        }
        let k = n.max(1) as f64;
        Ok([0, 1].map(|i| sum[i] / k - self.rest[i]))
    }

    fn truth_now(&mut self) -> Option<[f64; 3]> {
        let t0 = self.truth0;
        self.truth
            .as_mut()
            .map(|f| f())
            .map(|p| [p[0] - t0[0], p[1] - t0[1], p[2] - t0[2]])
    }

    /// Grabs a frame from each camera (top, then side) and measures both, in parallel.
    fn grab_views(&mut self) -> Result<[Option<[f64; 2]>; 2], BenchError> {
        self.views[0].grab(&mut self.rig.camera)?;
        self.views[1].grab(&mut self.rig.side_camera)?;
        Ok(vision::measure_pair(&mut self.views)?)
    }

    /// Grabs the next frame pair now and measures it: the exposure's start, the tip
    /// (and each camera's view) from rest, and the truth during the exposure.
    pub fn grab(&mut self) -> Result<FrameRecord, BenchError> {
        // The truth around the exposure: just before the frame starts and at its end.
        let before = self.truth_now();
        let [top, side] = self.grab_views()?;
        let t = self.views[0].frame.timestamp;
        self.next_frame = t + self.period;
        if let Some((t0, progress)) = &mut self.watch {
            progress(self.rig.clock.now() - *t0);
        }
        let measured = match (top, side) {
            (Some(a), Some(b)) => Some([a[0], b[0], a[1]]),
            _ => None,
        };
        let views = [top, side];
        let after = self.truth_now();
        let truth = before
            .zip(after)
            .map(|(a, b)| [0, 1, 2].map(|i| 0.5 * (a[i] + b[i])));
        Ok(FrameRecord {
            t,
            reference: [f64::NAN; 2],
            measured,
            views,
            truth,
            volts: self.volts,
        })
    }

    /// Sets A1 and A2 through the safety envelope (the farthest safe point towards
    /// `volts`); returns what was applied.
    pub fn command(&mut self, volts: [f64; 2]) -> Result<[f64; 2], BenchError> {
        let v = self.rig.command_tilt(volts).map_err(dev("command"))?;
        self.volts = v;
        Ok(v)
    }

    /// Holds `volts` for `seconds` without looking (no frames are grabbed: the cameras
    /// pick up where the tip is when the next measurement starts).
    pub fn rest(&mut self, volts: [f64; 2], seconds: f64) -> Result<[f64; 2], BenchError> {
        let v = self.command(volts)?;
        self.rig.clock.sleep(seconds).map_err(dev("clock"))?;
        self.align_frames();
        Ok(v)
    }

    /// The next frame after a pause: the cameras keep their rhythm while nobody grabs.
    fn align_frames(&mut self) {
        let now = self.rig.clock.now();
        if self.next_frame < now {
            let missed = ((now - self.next_frame) / self.period).ceil();
            self.next_frame += missed * self.period;
        }
    }

    /// Holds `volts` for `seconds`, measuring every frame.
    pub fn hold_volts(
        &mut self,
        volts: [f64; 2],
        seconds: f64,
        out: &mut Vec<FrameRecord>,
    ) -> Result<[f64; 2], BenchError> {
        let v = self.command(volts)?;
        let end = self.rig.clock.now() + seconds;
        loop {
            let now = self.rig.clock.now();
            if self.next_frame + 1e-4 > end {
                self.rig
                    .clock
                    .sleep((end - now).max(0.0))
                    .map_err(dev("clock"))?;
                break;
            }
            self.rig
                .clock
                .sleep((self.next_frame - 1e-4 - now).max(0.0))
                .map_err(dev("clock"))?;
            let mut f = self.grab()?;
            f.volts = v;
            out.push(f);
        }
        Ok(v)
    }

    /// Moves A1 and A2 linearly from where they are to `volts` over `seconds`,
    /// measuring every frame (the cameras follow motion of a few pixels per frame).
    pub fn ramp_volts(
        &mut self,
        volts: [f64; 2],
        seconds: f64,
        out: &mut Vec<FrameRecord>,
    ) -> Result<[f64; 2], BenchError> {
        let from = self.volts;
        let steps = (seconds / self.period).ceil().max(1.0) as usize;
        let mut v = from;
        for k in 1..=steps {
            let a = k as f64 / steps as f64;
            v = self.hold_volts(
                [
                    from[0] + a * (volts[0] - from[0]),
                    from[1] + a * (volts[1] - from[1]),
                ],
                seconds / steps as f64,
                out,
            )?;
        }
        Ok(v)
    }

    /// Runs `controller` for `seconds` towards `reference(t)` (stack extensions from
    /// rest, m; `t` from the start of the run), recording every frame pair.
    pub fn run(
        &mut self,
        controller: &mut dyn Controller,
        seconds: f64,
        reference: impl FnMut(f64) -> [f64; 2],
        out: &mut Vec<FrameRecord>,
    ) -> Result<(), BenchError> {
        self.pending = None;
        self.run_on(controller, 0.0, seconds, reference, out)
    }

    /// Goes on with a run [`Bench::run`] started `elapsed` s ago for `seconds` more: the
    /// controller's time and the reference's go on from `elapsed`, and a frame still
    /// waiting for its latency is delivered.
    pub fn run_on(
        &mut self,
        controller: &mut dyn Controller,
        elapsed: f64,
        seconds: f64,
        mut reference: impl FnMut(f64) -> [f64; 2],
        out: &mut Vec<FrameRecord>,
    ) -> Result<(), BenchError> {
        let kind = controller.kind();
        let dt = 1.0 / self.timing.rate;
        // The run's origin on the bench clock.
        let t0 = self.rig.clock.now() - elapsed;
        let end = elapsed + seconds;
        loop {
            let now = self.rig.clock.now();
            let t = now - t0;
            if t >= end - 1e-9 {
                break;
            }
            if now >= self.next_frame - 2e-4 {
                let mut f = self.grab()?;
                let (tf, measured) = (f.t, f.measured);
                // Where the tip should have been while the frame was exposed.
                let exposure = self.views[0].frame.exposure;
                let exposed = reference(tf + 0.5 * exposure - t0);
                f.t -= t0;
                f.reference = exposed;
                out.push(f);
                let vision = match measured {
                    Some(p) => Vision::Tip([p[0], p[1]]),
                    None => Vision::Rejected,
                };
                self.pending = Some((tf + exposure + self.timing.latency, vision, exposed));
            }
            let now = self.rig.clock.now();
            let mut m = Measurement::default();
            if let Some((at, v, exposed)) = self.pending
                && at <= now + 1e-9
            {
                m.vision = v;
                m.frame_reference = Some(exposed);
                self.pending = None;
            }
            if kind.uses_sensors() {
                m.stacks = Some(self.read_stacks(1)?);
            }
            let v = controller.step(now - t0, reference(now - t0), &m);
            let applied = self.command(v)?;
            controller.applied(applied);
            let wake = (now + dt).min(self.next_frame - 1e-4).min(t0 + end);
            self.rig
                .clock
                .sleep((wake - now).max(1e-6))
                .map_err(dev("clock"))?;
        }
        Ok(())
    }

    /// Moves the macro stage by `delta` (m, per axis) from `origin` and waits until it
    /// has settled (at most 10 s); returns the encoders' reading.
    pub fn stage_to(&mut self, origin: [f64; 3], delta: [f64; 3]) -> Result<[f64; 3], BenchError> {
        for axis in 0..3 {
            self.rig
                .stage
                .move_to(axis, origin[axis] + delta[axis])
                .map_err(dev("stage move"))?;
        }
        self.rig
            .wait_stage(10.0, 0.01, "stage")
            .map_err(dev("stage"))?;
        let mut p = [0.0; 3];
        for (axis, p) in p.iter_mut().enumerate() {
            *p = self.rig.stage.position(axis).map_err(dev("stage"))?;
        }
        Ok(p)
    }

    /// Grabs `n` frame pairs and returns each camera's mean image-plane measurement
    /// (m, along the two axes it sees; `None` if any frame was rejected).
    pub fn measure_views(&mut self, n: usize) -> Result<[Option<[f64; 2]>; 2], BenchError> {
        let mut sum = [[0.0; 2]; 2];
        let mut ok = [true; 2];
        for _ in 0..n.max(1) {
            let now = self.rig.clock.now();
            self.rig
                .clock
                .sleep((self.next_frame - 1e-4 - now).max(0.0))
                .map_err(dev("clock"))?;
            for (c, view) in self.grab_views()?.into_iter().enumerate() {
                match view {
                    Some(p) => {
                        sum[c][0] += p[0];
                        sum[c][1] += p[1];
                    }
                    None => ok[c] = false,
                }
            }
            self.next_frame = self.views[0].frame.timestamp + self.period;
        }
        let k = n.max(1) as f64;
        Ok([0, 1].map(|c| ok[c].then(|| [sum[c][0] / k, sum[c][1] / k])))
    }

    /// Replaces the pixel maps (after a calibration that used identity maps).
    pub fn set_maps(&mut self, maps: [PixelMap; 2]) {
        for (v, m) in self.views.iter_mut().zip(maps) {
            v.set_map(m);
        }
    }
}
