//! The twin behind the hardware traits of `cellinject-hw`: three amplifier channels, a
//! camera, a stage, an injector and a clock sharing one simulated world.
//!
//! Commands take effect at once and cost no simulated time; time passes only through
//! [`Clock::sleep`], [`Camera::grab_into`] (which waits for the next frame and its
//! exposure) and [`Injector::pulse`] (which lasts its duration).

use std::sync::{Arc, Mutex, MutexGuard};

use cellinject_hw::{
    Camera, CameraSettings, Clock, Frame, HwError, Injector, Optics, PiezoChannel, PositionSensor,
    Stage, check_range,
};
use cellinject_model::{ACTUATOR_NAMES, Design};
use cellinject_numeric::Rng;
use cellinject_rig::{Backend, Devices, Rig, RigError};

use crate::biology::{Biology, Fault};
use crate::camera::{Grid, Microscope, PipetteView, TipPose};
use crate::scene::Scene;
use crate::surface::PlateSurface;
pub use crate::world::TwinParams;
use crate::world::{TwinError, World};

/// Which camera of the twin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum View {
    /// The microscope, looking along y: x in the image columns, z in the rows, y as
    /// defocus.
    Top,
    /// The side camera, looking along x: y in the image columns, z in the rows, x as
    /// defocus.
    Side,
}

/// One exposure of the cameras (both are triggered together: a frame one camera has
/// not fetched yet waits in its buffer until the next exposure starts).
#[derive(Debug, Clone, Copy)]
struct Exposure {
    index: u64,
    start: f64,
    period: f64,
    exposure: f64,
    /// Tip at the start and end of the exposure, in the top view's terms.
    from: TipPose,
    to: TipPose,
}

/// The world and its two cameras.
#[derive(Debug, Clone)]
pub struct Twin {
    /// Mechanism, stacks, stage, injector.
    pub world: World,
    /// The microscope camera (top view).
    pub camera: Microscope,
    /// The side camera. Its lens is fixed at the rig's `optics.zoom`; the zoom device
    /// drives the microscope only.
    pub side: Microscope,
    /// End-effector displacement at which the optics were aligned and focused.
    origin: [f64; 3],
    last_frame: [Option<u64>; 2],
    exposure: Option<Exposure>,
    /// The loaded plate's cells as living things (see [`Twin::load_plate`]).
    pub biology: Option<Biology>,
    pulse_rng: Rng,
    /// Frames rendered by [`Twin::peek`].
    peeks: u64,
    /// The loaded plate's floor (flat without a plate).
    surface: PlateSurface,
}

/// A twin shared by its device handles.
pub type SharedTwin = Arc<Mutex<Twin>>;

fn lock(t: &SharedTwin) -> MutexGuard<'_, Twin> {
    t.lock().unwrap_or_else(|e| e.into_inner())
}

impl Twin {
    /// Puts the cells and debris of `plate` under the microscope (in place of the
    /// feeder the twin generated from its seed): see [`Scene::from_plate`].
    pub fn load_plate(&mut self, plate: &cellinject_plate::Plate) {
        let params = *self.world.params();
        let seed = params.sim.seed;
        self.camera.set_scene(Scene::from_plate(plate, seed));
        // The floor tilted and bowed about the plate's centre: the feeder must focus
        // each field.
        let q = 0.5 * plate.pitch;
        let extent = [
            plate.origin[0] - q,
            plate.origin[1] - q,
            plate.origin[0] + plate.cols.saturating_sub(1) as f64 * plate.pitch + q,
            plate.origin[1] + plate.rows.saturating_sub(1) as f64 * plate.pitch + q,
        ];
        self.surface = PlateSurface::draw(
            &params.sim.feeder,
            extent,
            &mut Rng::new(seed, crate::world::stream::SURFACE),
        );
        self.camera.set_surface(self.surface);
        let mut rng = Rng::new(seed, crate::world::stream::BIOLOGY);
        self.biology = Some(Biology::new(
            params.sim.biology,
            params.rig.pipette,
            plate
                .cells
                .iter()
                .map(|o| (plate.centre(o), 0.5 * o.diameter)),
            &mut rng,
        ));
    }

    /// Schedules faults on the loaded plate's cells (see [`Fault`]); refused without a
    /// plate or for a cell the plate does not have.
    pub fn set_faults(&mut self, faults: &[Fault]) -> Result<(), TwinError> {
        let Some(b) = self.biology.as_mut() else {
            return Err(TwinError::Invalid {
                key: "fault".into(),
                reason: "faults act on a plate's cells: load a plate first".into(),
            });
        };
        if let Some(f) = faults.iter().find(|f| f.cell() >= b.cells.len()) {
            return Err(TwinError::Invalid {
                key: "fault".into(),
                reason: format!(
                    "cell {} does not exist: the plate has {} cells (numbered from 0)",
                    f.cell(),
                    b.cells.len()
                ),
            });
        }
        b.set_faults(faults);
        Ok(())
    }

    /// Lets `seconds` pass in steps of at most 1 ms, updating the cells' contact with
    /// the tip after each.
    pub fn advance(&mut self, seconds: f64) {
        self.advance_to(self.world.time() + seconds);
    }

    /// Advances to time `t` (see [`Twin::advance`]).
    pub fn advance_to(&mut self, t: f64) {
        if self.biology.is_none() {
            self.world.advance_to(t);
            return;
        }
        while self.world.time() < t - 1e-12 {
            let before = self.world.time();
            let next = (before + 1e-3).min(t);
            self.world.advance_to(next);
            if self.world.time() == before {
                // Less than one integration step left.
                break;
            }
            self.interact();
        }
        self.interact();
    }

    fn interact(&mut self) {
        // The cells lie where the feeder has moved the plate: the tip in the plate's
        // frame meets them there.
        let mut tip = self.tip();
        let o = self.plate_offset();
        tip.x -= o[0];
        tip.z -= o[1];
        // The floor under the tip stands `surface` higher (flat at a cell's scale).
        tip.depth -= o[2] + self.surface.height([tip.x, tip.z]);
        if let Some(b) = self.biology.as_mut() {
            let fx = b.interact(&tip);
            if fx.dark_frames > 0 {
                self.camera.go_dark(fx.dark_frames);
            }
            if fx.stall_stage {
                b.stall_pending = true;
            }
        }
    }

    /// A pressure pulse through the pipette: the volume its conductance lets through
    /// (nominal geometry, this pipette's deviation, clog or break, pulse-to-pulse
    /// scatter) goes into the cell the tip is in, or into the medium; then the pulse's
    /// duration passes.
    pub fn pulse(&mut self, pressure: f64, duration: f64) {
        let p = *self.world.params();
        let flow = self.biology.as_ref().map_or(1.0, |b| b.flow);
        let scatter = 1.0 + p.sim.injector.pulse_noise * self.pulse_rng.gaussian_exact();
        let g = p.rig.pipette.conductance() * (1.0 + p.sim.injector.conductance_error);
        let volume = (g * flow * pressure * duration * scatter).max(0.0);
        if let Some(b) = self.biology.as_mut() {
            b.pulse(volume, pressure, 0.8 * p.rig.injector_max_pressure);
        }
        self.world.record_pulse(pressure, duration, volume);
        self.advance(duration);
    }

    /// A twin of `design` at rest, assembled with `params.approach`.
    pub fn new(design: &Design, params: TwinParams) -> Result<Self, TwinError> {
        let world = World::new(design, params)?;
        let sim = &params.sim;
        let scene = Scene::generate(&sim.feeder, sim.seed);
        let mut camera = Microscope::new(sim.camera, sim.lens, params.rig.optics, scene);
        let zoom_error = |e: HwError| TwinError::Invalid {
            key: "optics.zoom".into(),
            reason: e.to_string(),
        };
        camera
            .set_zoom(params.rig.optics.zoom)
            .map_err(zoom_error)?;
        let mut side = Microscope::new(
            sim.camera,
            sim.lens,
            params.rig.optics,
            Scene::side(sim.seed),
        )
        .with_noise_stream(crate::world::stream::SIDE_CAMERA);
        side.set_zoom(params.rig.optics.zoom).map_err(zoom_error)?;
        // The glass as each camera sees it: the microscope looks down on it
        // (foreshortened, rising out of focus behind the tip); the side camera sees it
        // at its angle, in focus along its length.
        let pip = params.rig.pipette;
        let (sin, cos) = (pip.angle.sin(), pip.angle.cos());
        camera.set_pipette(PipetteView::new(&pip, [0.0, -1.0], cos, sin));
        side.set_pipette(PipetteView::new(&pip, [sin, -cos], 1.0, 0.0));
        let x = world.snapshot().x;
        Ok(Twin {
            world,
            camera,
            side,
            origin: [x[0], x[1], x[2]],
            last_frame: [None; 2],
            exposure: None,
            biology: None,
            pulse_rng: Rng::new(sim.seed, crate::world::stream::PULSES),
            peeks: 0,
            surface: PlateSurface::FLAT,
        })
    }

    /// Where the feeder stage has moved the plate now, m: object x and z (plate x and
    /// y) and depth (the plate's height along the optical axis, 0 in the focal
    /// plane), residual vibration included.
    pub fn plate_offset(&self) -> [f64; 3] {
        [
            self.world.feeder.true_position(0),
            self.world.feeder.true_position(1),
            self.world.feeder.true_position(2),
        ]
    }

    /// The loaded plate's floor: how much higher than at the plate's centre it lies
    /// at each plate point ([`PlateSurface::FLAT`] without a plate). The truth a
    /// focusing routine is measured against.
    pub fn surface(&self) -> PlateSurface {
        self.surface
    }

    /// Where the pipette tip is in the object plane now (stage plus end-effector,
    /// relative to where the optics were aligned and focused after assembly).
    pub fn tip(&self) -> TipPose {
        let s = self.world.snapshot();
        let o = self.origin;
        let lost = self.biology.as_ref().map_or(0.0, |b| b.tip_loss);
        // A3 drives the tip along the pipette's axis: forward along z and down.
        let angle = self.world.params().rig.pipette.angle;
        let e3 = s.x[2] - o[2] - lost;
        TipPose {
            x: self.world.stage.true_position(0) + s.x[0] - o[0],
            z: self.world.stage.true_position(2) + e3 * angle.cos(),
            depth: self.world.stage.true_position(1) + s.x[1] - o[1] - e3 * angle.sin(),
            vx: 0.0,
            vz: 0.0,
        }
    }

    /// The displacement of actuator `ch`'s end as the mechanism sees it, m (positive:
    /// the stack extends; for A1, A2 the drive shift is Δl2 = −e, eq. 44's sign).
    pub fn actuator_displacement(&self, ch: usize) -> f64 {
        displacement_in(&self.world.snapshot(), ch)
    }

    /// Waits for the microscope's next frame, integrating the world through its
    /// exposure, and renders it.
    pub fn grab_into(&mut self, frame: &mut Frame) {
        self.grab_view(View::Top, frame);
    }

    /// Waits for the next frame of camera `view` and renders it. The cameras are
    /// triggered together: if the other camera already exposed the current frame (and
    /// the next has not started), this one returns the same exposure.
    pub fn grab_view(&mut self, view: View, frame: &mut Frame) {
        let v = view as usize;
        let cam = match view {
            View::Top => &self.camera,
            View::Side => &self.side,
        };
        let settings = cam.settings();
        let period = 1.0 / cam.frame_rate_for(&settings);
        let exposure = settings.exposure;
        let now = self.world.time();
        let buffered = self.exposure.filter(|e| {
            e.period == period
                && e.exposure == exposure
                && self.last_frame[v].is_none_or(|l| e.index > l)
                && now < e.start + period - 1e-9
        });
        let e = match buffered {
            Some(e) => e,
            None => {
                let mut k = (now / period - 1e-9).ceil().max(0.0) as u64;
                // The next frame starts after the last exposure (of either camera), at
                // the next boundary of this frame period; the frame counter only goes
                // up. (A frame rate changed since then does not move the clock: the
                // counter of a faster rate may be ahead of this rate's boundaries.)
                if let Some(last) = self.exposure {
                    let after = ((last.start / period + 1e-9).floor() + 1.0).max(0.0) as u64;
                    k = k.max(after);
                }
                let start = k as f64 * period;
                if let Some(last) = self.last_frame.iter().flatten().max() {
                    k = k.max(last + 1);
                }
                self.advance_to(start);
                let from = self.tip();
                self.advance(exposure);
                let to = self.tip();
                let e = Exposure {
                    index: k,
                    start,
                    period,
                    exposure,
                    from,
                    to,
                };
                self.exposure = Some(e);
                e
            }
        };
        let (a, b) = match view {
            View::Top => (e.from, e.to),
            View::Side => (side_pose(&e.from), side_pose(&e.to)),
        };
        let t = e.exposure;
        let pose = TipPose {
            x: 0.5 * (a.x + b.x),
            z: 0.5 * (a.z + b.z),
            depth: 0.5 * (a.depth + b.depth),
            vx: (b.x - a.x) / t,
            vz: (b.z - a.z) / t,
        };
        let seed = self.world.params().sim.seed;
        if let (View::Top, Some(b)) = (view, self.biology.as_ref()) {
            self.camera.set_cell_looks(&b.looks());
        }
        let thermal = self.world.params().sim.thermal;
        let drift = thermal.magnification * self.world.delta_t(e.start);
        let plate = self.plate_offset();
        let cam = match view {
            View::Top => &mut self.camera,
            View::Side => &mut self.side,
        };
        cam.set_magnification_drift(drift);
        cam.set_plate_offset(plate);
        cam.render(&pose, e.start, e.index, seed, frame);
        self.last_frame[v] = Some(e.index);
    }

    /// A copy of the microscope for a live display: the whole field, binned 4 x 4,
    /// 8 bits, drawing its own noise. Render with [`Twin::peek`]; make a new one when
    /// another plate is loaded.
    pub fn view_camera(&self) -> Microscope {
        let mut cam = self
            .camera
            .clone()
            .with_noise_stream(crate::world::stream::VIEW);
        let (w, h) = (cam.params().width, cam.params().height);
        let s = CameraSettings {
            roi: cellinject_hw::Roi {
                x: 0,
                y: 0,
                width: w - w % 4,
                height: h - h % 4,
            },
            binning: 4,
            bit_depth: 8,
            ..cam.settings()
        };
        // Settings of the camera's own family: valid by construction.
        let _ = cam.configure(s);
        cam
    }

    /// Renders the scene as it is now through `cam` (from [`Twin::view_camera`]) into
    /// `frame`, for a display: no frame is waited for, time does not move and the
    /// microscope's own frames are untouched. Returns the output grid (where the
    /// frame's pixels lie in the object plane).
    pub fn peek(&mut self, cam: &mut Microscope, frame: &mut Frame) -> Grid {
        if cam.zoom() != self.camera.zoom() {
            let _ = cam.set_zoom(self.camera.zoom());
        }
        if let Some(b) = self.biology.as_ref() {
            cam.set_cell_looks(&b.looks());
        }
        let pose = self.tip();
        let now = self.world.time();
        self.peeks += 1;
        let seed = self.world.params().sim.seed;
        let thermal = self.world.params().sim.thermal;
        cam.set_magnification_drift(thermal.magnification * self.world.delta_t(now));
        cam.set_plate_offset(self.plate_offset());
        cam.render(&pose, now, self.peeks, seed, frame);
        cam.grid()
    }

    /// Puts the twin behind shared device handles.
    pub fn into_shared(self) -> SharedTwin {
        Arc::new(Mutex::new(self))
    }
}

/// The tip as the side camera sees it: y along its columns, z along its rows, x as
/// distance from its focal plane.
fn side_pose(top: &TipPose) -> TipPose {
    TipPose {
        x: top.depth,
        z: top.z,
        depth: top.x,
        vx: 0.0,
        vz: 0.0,
    }
}

/// The displacement of actuator `ch`'s end in a snapshot, m (see
/// [`Twin::actuator_displacement`]).
pub fn displacement_in(s: &crate::Snapshot, ch: usize) -> f64 {
    if ch < 2 { -s.dl[ch] } else { s.q[2] }
}

/// One amplifier channel of the twin.
pub struct TwinPiezo {
    twin: SharedTwin,
    channel: usize,
}

impl PiezoChannel for TwinPiezo {
    fn name(&self) -> &str {
        ACTUATOR_NAMES[self.channel]
    }
    fn voltage_range(&self) -> (f64, f64) {
        (
            0.0,
            lock(&self.twin).world.params().rig.amplifiers[self.channel].v_max,
        )
    }
    fn set_voltage(&mut self, volts: f64) -> Result<(), HwError> {
        let mut t = lock(&self.twin);
        let hi = t.world.params().rig.amplifiers[self.channel].v_max;
        let what = ["A1 voltage", "A2 voltage", "A3 voltage"][self.channel];
        check_range(what, volts, 0.0, hi)?;
        t.world.set_voltage(self.channel, volts);
        Ok(())
    }
    fn commanded_voltage(&self) -> f64 {
        lock(&self.twin).world.commanded_voltage(self.channel)
    }
    fn read_voltage(&mut self) -> Result<f64, HwError> {
        Ok(lock(&self.twin).world.output_voltage(self.channel))
    }
}

/// A stack's strain-gauge sensor on the twin: the stack's true extension, with the
/// sensor's noise (its own random stream) and its drift with temperature. It sees the
/// stack only: the joints' stick-slip and the lever are beyond it.
pub struct TwinSensor {
    twin: SharedTwin,
    channel: usize,
    rng: Rng,
}

impl PositionSensor for TwinSensor {
    fn name(&self) -> &str {
        ACTUATOR_NAMES[self.channel]
    }
    fn read(&mut self) -> Result<f64, HwError> {
        let t = lock(&self.twin);
        let p = t.world.params().sim;
        let extension = t.world.extension(self.channel);
        let drift = p.sensors.thermal_drift * t.world.delta_t(t.world.time());
        Ok(extension + drift + p.sensors.noise * self.rng.gaussian_exact())
    }
    fn noise(&self) -> f64 {
        lock(&self.twin).world.params().sim.sensors.noise
    }
}

/// One of the twin's cameras.
pub struct TwinCamera {
    twin: SharedTwin,
    view: View,
}

impl TwinCamera {
    fn with<R>(&self, f: impl FnOnce(&Microscope) -> R) -> R {
        let t = lock(&self.twin);
        match self.view {
            View::Top => f(&t.camera),
            View::Side => f(&t.side),
        }
    }

    /// Which camera this is.
    pub fn view(&self) -> View {
        self.view
    }
}

impl Camera for TwinCamera {
    fn sensor_size(&self) -> (u32, u32) {
        self.with(|c| (c.params().width, c.params().height))
    }
    fn settings(&self) -> CameraSettings {
        self.with(|c| c.settings())
    }
    fn configure(&mut self, settings: CameraSettings) -> Result<(), HwError> {
        let mut t = lock(&self.twin);
        match self.view {
            View::Top => t.camera.configure(settings),
            View::Side => t.side.configure(settings),
        }
    }
    fn frame_rate(&self) -> f64 {
        self.with(|c| c.frame_rate_for(&c.settings()))
    }
    fn grab_into(&mut self, frame: &mut Frame) -> Result<(), HwError> {
        lock(&self.twin).grab_view(self.view, frame);
        Ok(())
    }
}

/// One of the twin's stages: the macro stage carrying the micromanipulator (x, the
/// optical axis y, z) or the feeder stage carrying the plate (plate x, plate y, and
/// its height along the optical axis: the plate's focus).
pub struct TwinStage {
    twin: SharedTwin,
    feeder: bool,
}

impl TwinStage {
    fn sim(t: &mut Twin, feeder: bool) -> &mut crate::stage::StageSim {
        if feeder {
            &mut t.world.feeder
        } else {
            &mut t.world.stage
        }
    }

    fn name(&self) -> &'static str {
        if self.feeder { "feeder stage" } else { "stage" }
    }
}

impl Stage for TwinStage {
    fn axes(&self) -> usize {
        3
    }
    fn travel(&self, _axis: usize) -> (f64, f64) {
        let t = lock(&self.twin);
        if self.feeder {
            t.world.feeder.travel()
        } else {
            t.world.stage.travel()
        }
    }
    fn move_to(&mut self, axis: usize, position: f64) -> Result<(), HwError> {
        let (lo, hi) = self.travel(axis);
        let name = self.name();
        check_range(name, axis as f64, 0.0, (self.axes() - 1) as f64)?;
        check_range(name, position, lo, hi)?;
        let mut t = lock(&self.twin);
        if let Some(b) = t.biology.as_mut()
            && b.stall_pending
            && !self.feeder
        {
            b.stall_pending = false;
            t.world.stage.stall();
        }
        Self::sim(&mut t, self.feeder).move_to(axis, position);
        Ok(())
    }
    fn position(&mut self, axis: usize) -> Result<f64, HwError> {
        check_range(self.name(), axis as f64, 0.0, (self.axes() - 1) as f64)?;
        Ok(Self::sim(&mut lock(&self.twin), self.feeder).encoder(axis))
    }
    fn is_busy(&mut self) -> Result<bool, HwError> {
        Ok(Self::sim(&mut lock(&self.twin), self.feeder).busy())
    }
}

/// The twin's injector.
pub struct TwinInjector {
    twin: SharedTwin,
}

impl Injector for TwinInjector {
    fn max_pressure(&self) -> f64 {
        lock(&self.twin).world.params().rig.injector_max_pressure
    }
    fn pulse(&mut self, pressure: f64, duration: f64) -> Result<(), HwError> {
        check_range("pressure", pressure, 0.0, self.max_pressure())?;
        check_range("pulse duration", duration, 0.0, 10.0)?;
        lock(&self.twin).pulse(pressure, duration);
        Ok(())
    }
}

/// The twin's clock.
pub struct TwinClock {
    twin: SharedTwin,
}

impl Clock for TwinClock {
    fn now(&self) -> f64 {
        lock(&self.twin).world.time()
    }
    fn sleep(&mut self, seconds: f64) -> Result<(), HwError> {
        check_range("sleep", seconds, 0.0, 1.0e6)?;
        lock(&self.twin).advance(seconds);
        Ok(())
    }
}

/// The twin's zoom lens.
pub struct TwinOptics {
    twin: SharedTwin,
}

impl Optics for TwinOptics {
    fn zoom(&self) -> f64 {
        lock(&self.twin).camera.zoom()
    }
    fn zoom_range(&self) -> (f64, f64) {
        lock(&self.twin).camera.zoom_range()
    }
    fn set_zoom(&mut self, zoom: f64) -> Result<(), HwError> {
        lock(&self.twin).camera.set_zoom(zoom)
    }
}

/// The twin as a backend of `cellinject-rig`.
#[derive(Debug, Clone, Copy)]
pub struct TwinBackend;

impl Backend for TwinBackend {
    type Piezo = TwinPiezo;
    type Sensor = TwinSensor;
    type Camera = TwinCamera;
    type Stage = TwinStage;
    type Injector = TwinInjector;
    type Optics = TwinOptics;
    type Clock = TwinClock;
}

/// Handles to every device of a shared twin, unguarded.
pub fn devices(twin: &SharedTwin) -> Devices<TwinBackend> {
    let piezo = [0, 1, 2].map(|channel| TwinPiezo {
        twin: twin.clone(),
        channel,
    });
    let seed = lock(twin).world.params().sim.seed;
    let sensors = [0, 1, 2].map(|channel| TwinSensor {
        twin: twin.clone(),
        channel,
        rng: Rng::new(seed, crate::world::stream::SENSOR + channel as u64),
    });
    Devices {
        piezo,
        sensors,
        camera: TwinCamera {
            twin: twin.clone(),
            view: View::Top,
        },
        side_camera: TwinCamera {
            twin: twin.clone(),
            view: View::Side,
        },
        stage: TwinStage {
            twin: twin.clone(),
            feeder: false,
        },
        feeder: TwinStage {
            twin: twin.clone(),
            feeder: true,
        },
        injector: TwinInjector { twin: twin.clone() },
        optics: TwinOptics { twin: twin.clone() },
        clock: TwinClock { twin: twin.clone() },
    }
}

/// The twin's devices behind the safety guards of its own design and rig description,
/// as a controller should see them.
pub fn rig(twin: &SharedTwin) -> Result<Rig<TwinBackend>, RigError> {
    guarded(twin, devices(twin))
}

/// The same as [`rig`], every device boxed (for front ends that pick their backend at
/// run time).
pub fn dyn_rig(twin: &SharedTwin) -> Result<Rig<cellinject_rig::DynBackend>, RigError> {
    guarded(twin, devices(twin).boxed())
}

/// Devices of `twin` (from [`devices`], possibly wrapped, e.g. by a dashboard that
/// watches them) behind the guards of the twin's own design and rig description.
pub fn guarded<B: Backend>(twin: &SharedTwin, devices: Devices<B>) -> Result<Rig<B>, RigError> {
    let (design, params) = {
        let t = lock(twin);
        (*t.world.mechanism().design(), t.world.params().rig)
    };
    Rig::new(devices, &design, &params)
}
