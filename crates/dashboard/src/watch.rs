//! What the web side sees of the bench without asking the control thread: the run's
//! switches ([`Control`]) and the devices' last readings ([`Telemetry`]), filled in by
//! thin wrappers around any backend's devices ([`instrument`]). The wrappers add no
//! behaviour of their own but two, both in the clock: the twin paced to wall time for
//! viewing (unless fast), and an abort delivered as an interruption at the next tick.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use cellinject_core::inject::ImageMap;
use cellinject_hw::{
    Camera, CameraSettings, Clock, Frame, HwError, Injector, Optics, PiezoChannel, PositionSensor,
    Stage,
};
use cellinject_rig::{Devices, DynBackend};

/// Locks a mutex, taking over a poisoned one (a panicking holder leaves data that is
/// still a valid reading).
pub(crate) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The switches of whatever the control thread is doing: set from any thread, read by
/// the control thread between steps.
#[derive(Debug, Default)]
pub struct Control {
    abort: AtomicBool,
    interrupt: AtomicBool,
    pause: AtomicBool,
    fast: AtomicBool,
}

impl Control {
    /// A control, paced to wall time unless `fast`.
    pub fn new(fast: bool) -> Self {
        let c = Control::default();
        c.fast.store(fast, Ordering::SeqCst);
        c
    }
    /// Asks the current task to end: the next clock tick is interrupted and the run
    /// stops before its next cell; a pause is lifted.
    pub fn abort(&self) {
        // One interruption per task: a second click must not interrupt the way to
        // the safe state the first one started.
        if !self.abort.swap(true, Ordering::SeqCst) {
            self.interrupt.store(true, Ordering::SeqCst);
        }
        self.pause.store(false, Ordering::SeqCst);
    }
    /// An abort was asked since the task began.
    pub fn aborted(&self) -> bool {
        self.abort.load(Ordering::SeqCst)
    }
    /// Holds the run before its next cell.
    pub fn pause(&self, on: bool) {
        if !(on && self.aborted()) {
            self.pause.store(on, Ordering::SeqCst);
        }
    }
    /// The run is asked to hold.
    pub fn paused(&self) -> bool {
        self.pause.load(Ordering::SeqCst)
    }
    /// Flat out (true) or paced to wall time.
    pub fn fast(&self) -> bool {
        self.fast.load(Ordering::SeqCst)
    }
    /// A new task starts: no abort, no pause.
    pub fn reset(&self) {
        self.abort.store(false, Ordering::SeqCst);
        self.interrupt.store(false, Ordering::SeqCst);
        self.pause.store(false, Ordering::SeqCst);
    }
    /// Takes a pending interruption (one per abort).
    fn take_interrupt(&self) -> bool {
        self.interrupt.swap(false, Ordering::SeqCst)
    }
}

/// Points of the hysteresis loop kept for the plot.
pub const LOOP_POINTS: usize = 600;

/// The devices' last readings.
#[derive(Debug, Clone, Default)]
pub struct Readings {
    /// V, the commanded voltages of A1, A2, A3.
    pub volts: [f64; 3],
    /// m, the stack sensors' last readings.
    pub sensors: [f64; 3],
    /// m, the stage's last known position (x, y, z).
    pub stage: [f64; 3],
    /// The zoom.
    pub zoom: f64,
    /// s, the device clock.
    pub time: f64,
    /// (V, m) of A1 as its sensor is read: the loop being traced, oldest first.
    pub loop_a1: VecDeque<[f64; 2]>,
    /// Sensor reads since the last loop point.
    loop_skip: u32,
}

/// Readings shared between the devices' wrappers and the web side.
#[derive(Debug, Default)]
pub struct Telemetry {
    readings: Mutex<Readings>,
    /// The frame the workflow grabbed last (the microscope) and the camera's settings
    /// it was taken with, for a backend without a renderer.
    last_frame: Mutex<Option<(Frame, CameraSettings)>>,
    frames: AtomicU64,
    /// The run's image-to-stage map, once the workflow has it.
    map: Mutex<Option<ImageMap>>,
}

impl Telemetry {
    /// A copy of the readings.
    pub fn readings(&self) -> Readings {
        lock(&self.readings).clone()
    }
    fn with<R>(&self, f: impl FnOnce(&mut Readings) -> R) -> R {
        f(&mut lock(&self.readings))
    }
    /// The microscope frame the program grabbed last and the camera's settings then,
    /// if it is newer than `seen` (a count), and the count.
    pub fn grabbed_since(&self, seen: u64) -> Option<(Frame, CameraSettings, u64)> {
        let n = self.frames.load(Ordering::SeqCst);
        if n == seen {
            return None;
        }
        lock(&self.last_frame).clone().map(|(f, s)| (f, s, n))
    }
    /// The workflow mapped the image to the stage.
    pub fn set_map(&self, map: ImageMap) {
        *lock(&self.map) = Some(map);
    }
    /// A new run starts: the last run's map no longer says where things are.
    pub fn clear_map(&self) {
        *lock(&self.map) = None;
    }
    /// The image-to-stage map of the run, if there is one yet.
    pub fn map(&self) -> Option<ImageMap> {
        *lock(&self.map)
    }
}

struct TapPiezo {
    inner: Box<dyn PiezoChannel>,
    ch: usize,
    t: Arc<Telemetry>,
}

impl PiezoChannel for TapPiezo {
    fn name(&self) -> &str {
        self.inner.name()
    }
    fn voltage_range(&self) -> (f64, f64) {
        self.inner.voltage_range()
    }
    fn set_voltage(&mut self, volts: f64) -> Result<(), HwError> {
        self.inner.set_voltage(volts)?;
        self.t.with(|r| r.volts[self.ch] = volts);
        Ok(())
    }
    fn commanded_voltage(&self) -> f64 {
        self.inner.commanded_voltage()
    }
    fn read_voltage(&mut self) -> Result<f64, HwError> {
        self.inner.read_voltage()
    }
}

struct TapSensor {
    inner: Box<dyn PositionSensor>,
    ch: usize,
    t: Arc<Telemetry>,
}

impl PositionSensor for TapSensor {
    fn name(&self) -> &str {
        self.inner.name()
    }
    fn read(&mut self) -> Result<f64, HwError> {
        let v = self.inner.read()?;
        let ch = self.ch;
        self.t.with(|r| {
            r.sensors[ch] = v;
            if ch == 0 {
                r.loop_skip += 1;
                // One point in 8 reads: the loops' 1 kHz reads and the
                // identification's both trace the loop densely enough.
                if r.loop_skip >= 8 {
                    r.loop_skip = 0;
                    if r.loop_a1.len() == LOOP_POINTS {
                        r.loop_a1.pop_front();
                    }
                    r.loop_a1.push_back([r.volts[0], v]);
                }
            }
        });
        Ok(v)
    }
    fn noise(&self) -> f64 {
        self.inner.noise()
    }
}

struct TapStage {
    inner: Box<dyn Stage>,
    t: Arc<Telemetry>,
}

impl Stage for TapStage {
    fn axes(&self) -> usize {
        self.inner.axes()
    }
    fn travel(&self, axis: usize) -> (f64, f64) {
        self.inner.travel(axis)
    }
    fn move_to(&mut self, axis: usize, position: f64) -> Result<(), HwError> {
        self.inner.move_to(axis, position)
    }
    fn position(&mut self, axis: usize) -> Result<f64, HwError> {
        let p = self.inner.position(axis)?;
        if axis < 3 {
            self.t.with(|r| r.stage[axis] = p);
        }
        Ok(p)
    }
    fn is_busy(&mut self) -> Result<bool, HwError> {
        self.inner.is_busy()
    }
}

struct TapCamera {
    inner: Box<dyn Camera>,
    t: Option<Arc<Telemetry>>,
    /// The buffer the next grabbed frame is copied into.
    spare: Frame,
}

/// `from` into `to`, reusing `to`'s pixel buffer.
fn copy_frame(to: &mut Frame, from: &Frame) {
    let Frame {
        width,
        height,
        bit_depth,
        pixels,
        timestamp,
        exposure,
        pixel_size,
        index,
    } = from;
    (to.width, to.height, to.bit_depth) = (*width, *height, *bit_depth);
    (to.timestamp, to.exposure) = (*timestamp, *exposure);
    (to.pixel_size, to.index) = (*pixel_size, *index);
    to.pixels.clone_from(pixels);
}

impl Camera for TapCamera {
    fn sensor_size(&self) -> (u32, u32) {
        self.inner.sensor_size()
    }
    fn settings(&self) -> CameraSettings {
        self.inner.settings()
    }
    fn configure(&mut self, settings: CameraSettings) -> Result<(), HwError> {
        self.inner.configure(settings)
    }
    fn frame_rate(&self) -> f64 {
        self.inner.frame_rate()
    }
    fn grab_into(&mut self, frame: &mut Frame) -> Result<(), HwError> {
        self.inner.grab_into(frame)?;
        if let Some(t) = &self.t {
            let settings = self.inner.settings();
            // Copied into a buffer of our own outside the lock, then swapped in: the
            // view thread never waits for the copy, and no frame is allocated per grab.
            copy_frame(&mut self.spare, frame);
            let mut last = lock(&t.last_frame);
            match last.as_mut() {
                Some((f, s)) => {
                    std::mem::swap(f, &mut self.spare);
                    *s = settings;
                }
                None => *last = Some((std::mem::take(&mut self.spare), settings)),
            }
            drop(last);
            t.frames.fetch_add(1, Ordering::SeqCst);
        }
        Ok(())
    }
}

struct TapOptics {
    inner: Box<dyn Optics>,
    t: Arc<Telemetry>,
}

impl Optics for TapOptics {
    fn zoom(&self) -> f64 {
        self.inner.zoom()
    }
    fn zoom_range(&self) -> (f64, f64) {
        self.inner.zoom_range()
    }
    fn set_zoom(&mut self, zoom: f64) -> Result<(), HwError> {
        self.inner.set_zoom(zoom)?;
        self.t.with(|r| r.zoom = zoom);
        Ok(())
    }
}

/// The clock of a bench under the dashboard: paced so that device time does not run
/// ahead of wall time (a twin is watchable; a real bench's clock is wall time already
/// and is never held back), flat out when [`Control::fast`]; and an abort comes back
/// from the next sleep as [`HwError::Interrupted`], once, so that whatever program
/// runs stops there and its way to the safe state, which sleeps too, is not held up.
pub struct PacedClock {
    inner: Box<dyn Clock>,
    control: Arc<Control>,
    t: Arc<Telemetry>,
    /// (device time, wall time) the pace counts from.
    origin: Option<(f64, Instant)>,
}

impl PacedClock {
    fn pace(&mut self) {
        let paced = !self.control.fast() && !self.control.aborted();
        let now = self.inner.now();
        if !paced {
            self.origin = None;
            return;
        }
        let (t0, w0) = *self.origin.get_or_insert((now, Instant::now()));
        let ahead = (now - t0) - w0.elapsed().as_secs_f64();
        if ahead > 0.002 {
            std::thread::sleep(Duration::from_secs_f64(ahead.min(1.0)));
        } else if ahead < -0.25 {
            // Fell behind (a slow render, a pause): count from here, never catch up
            // in a burst.
            self.origin = Some((now, Instant::now()));
        }
    }
}

impl Clock for PacedClock {
    fn now(&self) -> f64 {
        self.inner.now()
    }
    fn sleep(&mut self, seconds: f64) -> Result<(), HwError> {
        if self.control.take_interrupt() {
            return Err(HwError::Interrupted {
                device: "clock".into(),
                reason: "aborted by the operator".into(),
            });
        }
        self.inner.sleep(seconds)?;
        let now = self.inner.now();
        self.t.with(|r| r.time = now);
        self.pace();
        Ok(())
    }
}

/// Wraps every device of `devices` so that their readings reach `t`, the clock paced
/// and interruptible by `control`. `tap_camera`: copy the microscope's frames into
/// `t` (for a live view on a backend that cannot render one of its own).
pub fn instrument(
    devices: Devices<DynBackend>,
    t: &Arc<Telemetry>,
    control: &Arc<Control>,
    tap_camera: bool,
) -> Devices<DynBackend> {
    let Devices {
        piezo,
        sensors,
        camera,
        side_camera,
        stage,
        feeder,
        injector,
        optics,
        clock,
    } = devices;
    let mut ch = 0;
    let piezo = piezo.map(|inner| {
        ch += 1;
        Box::new(TapPiezo {
            inner,
            ch: ch - 1,
            t: t.clone(),
        }) as Box<dyn PiezoChannel>
    });
    let mut ch = 0;
    let sensors = sensors.map(|inner| {
        ch += 1;
        Box::new(TapSensor {
            inner,
            ch: ch - 1,
            t: t.clone(),
        }) as Box<dyn PositionSensor>
    });
    {
        let mut r = lock(&t.readings);
        r.zoom = optics.zoom();
        r.time = clock.now();
        r.volts = [0, 1, 2].map(|k| piezo[k].commanded_voltage());
    }
    Devices {
        piezo,
        sensors,
        camera: Box::new(TapCamera {
            inner: camera,
            t: tap_camera.then(|| t.clone()),
            spare: Frame::default(),
        }),
        side_camera,
        stage: Box::new(TapStage {
            inner: stage,
            t: t.clone(),
        }),
        feeder,
        injector: injector as Box<dyn Injector>,
        optics: Box::new(TapOptics {
            inner: optics,
            t: t.clone(),
        }),
        clock: Box::new(PacedClock {
            inner: clock,
            control: control.clone(),
            t: t.clone(),
            origin: None,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Default)]
    struct SimClock(f64);
    impl Clock for SimClock {
        fn now(&self) -> f64 {
            self.0
        }
        fn sleep(&mut self, seconds: f64) -> Result<(), HwError> {
            self.0 += seconds;
            Ok(())
        }
    }

    /// A camera whose frames are its region of interest of a bright sensor with one
    /// dark sensor pixel, binned as set.
    struct SpotCamera {
        settings: CameraSettings,
        spot: [u32; 2],
    }
    impl Camera for SpotCamera {
        fn sensor_size(&self) -> (u32, u32) {
            (2048, 1536)
        }
        fn settings(&self) -> CameraSettings {
            self.settings
        }
        fn configure(&mut self, settings: CameraSettings) -> Result<(), HwError> {
            self.settings = settings;
            Ok(())
        }
        fn frame_rate(&self) -> f64 {
            30.0
        }
        fn grab_into(&mut self, frame: &mut Frame) -> Result<(), HwError> {
            let (r, b) = (self.settings.roi, self.settings.binning);
            frame.width = r.width / b;
            frame.height = r.height / b;
            frame.bit_depth = 8;
            frame.pixel_size = 0.7e-6 * b as f64;
            frame.pixels = vec![200; (frame.width * frame.height) as usize];
            let (i, j) = ((self.spot[0] - r.x) / b, (self.spot[1] - r.y) / b);
            frame.pixels[(j * frame.width + i) as usize] = 0;
            Ok(())
        }
    }

    /// The view of a bench without a renderer places a stage point where the frame
    /// shows it: a dark sensor pixel put where the image map says a stage point is
    /// imaged lands in the view pixel the frame's `to_view` gives for that point, for a
    /// region of interest off the sensor's corner, binned 2 x 2 by the camera and 2 x 2
    /// again for the view, with the point at several places within its sensor pixel
    /// and within the view's pixel (half a pixel off anywhere shows).
    #[test]
    fn the_grabbed_view_places_stage_points_where_the_frame_shows_them() {
        use cellinject_hw::Roi;
        // A slightly rotated map: 1 / 0.7 um pixels per metre, 10 mrad.
        let (g, th) = (1.0 / 0.7e-6, 0.01f64);
        let map = ImageMap {
            pixel0: [1000.0, 700.0],
            stage0: [1e-3, 2e-3],
            b: [[g * th.cos(), -g * th.sin()], [g * th.sin(), g * th.cos()]],
            residual_px: 0.1,
            a1: [0.0, 1e6],
            a3: [1e6, 0.0],
            pixel_size: 0.7e-6,
        };
        let roi = Roi {
            x: 24,
            y: 100,
            width: 2000,
            height: 1400,
        };
        let settings = CameraSettings {
            roi,
            binning: 2,
            exposure: 1e-3,
            bit_depth: 8,
        };
        let t = Arc::new(Telemetry::default());
        let mut view = crate::bench::GrabbedView::new(t.clone());
        let mut checked = 0;
        for (n, frac) in [0.3, 1.45, 2.4, 2.55, 3.45, 3.6].into_iter().enumerate() {
            // Full-frame pixel: a view pixel of 4 sensor pixels from the region's
            // corner, plus `frac` sensor pixels in the column and 3.9 - frac in the row.
            let p = [
                roi.x as f64 + 4.0 * (60 + n) as f64 + frac,
                roi.y as f64 + 4.0 * (40 + n) as f64 + 3.9 - frac,
            ];
            let point = map.stage_of(p);
            let back = map.pixel_of(point);
            assert!((back[0] - p[0]).hypot(back[1] - p[1]) < 1e-9);
            let spot = [p[0].round() as u32, p[1].round() as u32];
            let mut cam = TapCamera {
                inner: Box::new(SpotCamera { settings, spot }),
                t: Some(t.clone()),
                spare: Frame::default(),
            };
            if n == 0 {
                cam.grab().expect("a frame");
                let v = crate::Viewer::frame(&mut view).expect("a view");
                assert_eq!(v.to_view, None, "no map yet");
                t.set_map(map);
            }
            cam.grab().expect("a frame");
            let v = crate::Viewer::frame(&mut view).expect("a view");
            assert_eq!((v.width, v.height), (500, 350));
            let a = v.to_view.expect("geometry from the map");
            let at = [
                a[0][0] * point[0] + a[0][1] * point[1] + a[0][2],
                a[1][0] * point[0] + a[1][1] * point[1] + a[1][2],
            ];
            let darkest = (0..v.pixels.len())
                .min_by_key(|&i| v.pixels[i])
                .expect("pixels");
            let (i, j) = (darkest % v.width as usize, darkest / v.width as usize);
            assert_eq!(
                (at[0].floor() as usize, at[1].floor() as usize),
                (i, j),
                "{frac}: {at:?}"
            );
            checked += 1;
        }
        assert_eq!(checked, 6);
    }

    #[test]
    fn an_abort_interrupts_the_next_sleep_once() {
        let control = Arc::new(Control::new(true));
        let t = Arc::new(Telemetry::default());
        let mut c = PacedClock {
            inner: Box::new(SimClock::default()),
            control: control.clone(),
            t,
            origin: None,
        };
        c.sleep(0.5).expect("runs");
        control.abort();
        assert!(matches!(c.sleep(0.1), Err(HwError::Interrupted { .. })));
        // The way to the safe state sleeps too.
        c.sleep(0.1).expect("after the interruption");
        assert!((c.now() - 0.6).abs() < 1e-12);
    }

    #[test]
    fn paced_time_does_not_run_ahead_of_the_wall() {
        let control = Arc::new(Control::new(false));
        let t = Arc::new(Telemetry::default());
        let mut c = PacedClock {
            inner: Box::new(SimClock::default()),
            control,
            t,
            origin: None,
        };
        let w = Instant::now();
        for _ in 0..100 {
            c.sleep(0.001).expect("runs");
        }
        // 0.1 s of device time took at least ~0.1 s of wall time.
        assert!(w.elapsed().as_secs_f64() >= 0.095, "{:?}", w.elapsed());
    }
}
