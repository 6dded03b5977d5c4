//! `--backend`: the twin (default) or a GCS 2.0 controller, with the rest of the bench
//! (cameras, stage, injector, zoom) from an emulator's bench endpoint.

use std::time::Duration;

use anyhow::Result;
use cellinject_config::Description;
use cellinject_gcs::Endpoint;
use cellinject_gcs::devices::{SharedGcs, stacks};
use cellinject_gcs_emulator::bench::{Bench, ViewName};
use cellinject_hw::{Camera, Clock, Injector, Optics, PiezoChannel, PositionSensor, Stage};
use cellinject_model::{ACTUATOR_NAMES, Approach};
use cellinject_rig::{Devices, DynBackend, Rig};
use cellinject_twin::SharedTwin;
use clap::Args;

use crate::InputError;
use crate::sim::TwinArgs;

/// Where the commands go.
#[derive(Debug, Clone, Args)]
pub struct BackendArgs {
    /// The hardware: `twin` (the digital twin, default), `gcs://HOST[:PORT]` (a PI GCS
    /// 2.0 controller over TCP, port 50000 by default, e.g. `cellinject emulate gcs`) or
    /// `gcs-serial:///dev/ttyX[?baud=N]` (115200 baud by default). On connecting, the
    /// controller's servos are switched off and the stacks brought to 0 V, A3 first.
    #[arg(
        long,
        default_value = "twin",
        value_name = "twin|gcs://HOST:PORT|gcs-serial://PATH"
    )]
    pub backend: String,
    /// With a GCS backend: the bench endpoint serving the cameras, stage, injector and
    /// zoom (default for gcs://HOST:PORT: HOST:PORT+1, where `cellinject emulate gcs`
    /// serves them).
    #[arg(long, value_name = "HOST:PORT")]
    pub bench: Option<String>,
    /// With a GCS backend: the microscope's top camera instead of the bench endpoint's:
    /// `aravis:ID`, a GenICam camera (GigE Vision, USB3 Vision) by any id Aravis gives
    /// it, its serial number or its IP address (a build with the `genicam` feature), or
    /// DIR, the image files another acquisition program writes into it (PNG or TIFF,
    /// 8- or 16-bit grey, taken in name order; write each whole, then rename it).
    #[arg(long, value_name = "aravis:ID|DIR")]
    pub camera: Option<std::path::PathBuf>,
    /// With a GCS backend: the side camera, in the same forms as --camera.
    #[arg(long, value_name = "aravis:ID|DIR")]
    pub side_camera: Option<std::path::PathBuf>,
    /// Frames per second of a folder acquisition (default 30).
    #[arg(long, value_name = "FPS")]
    pub camera_fps: Option<f64>,
}

impl Default for BackendArgs {
    fn default() -> Self {
        BackendArgs {
            backend: "twin".into(),
            bench: None,
            camera: None,
            side_camera: None,
            camera_fps: None,
        }
    }
}

impl BackendArgs {
    /// Whether this is the twin.
    pub fn is_twin(&self) -> bool {
        self.backend == "twin"
    }

    /// Refuses a backend that is not one (before anything is opened or written).
    pub fn check(&self) -> Result<Option<Endpoint>> {
        if self.is_twin() {
            if let Some(bench) = &self.bench {
                return Err(InputError(format!(
                    "--bench {bench}: the twin has its own bench (give --backend gcs://...)"
                ))
                .into());
            }
            for (arg, c) in [
                ("--camera", &self.camera),
                ("--side-camera", &self.side_camera),
            ] {
                if let Some(c) = c {
                    return Err(InputError(format!(
                        "{arg} {}: the twin has its own cameras (give --backend gcs://...)",
                        c.display()
                    ))
                    .into());
                }
            }
            if self.camera_fps.is_some() {
                return Err(
                    InputError("--camera-fps goes with --camera and a GCS backend".into()).into(),
                );
            }
            return Ok(None);
        }
        if let Some(f) = self.camera_fps
            && !(f.is_finite() && f > 0.0)
        {
            return Err(InputError(format!("--camera-fps must be positive, got {f}")).into());
        }
        for (arg, c) in [
            ("--camera", &self.camera),
            ("--side-camera", &self.side_camera),
        ] {
            if let Some(c) = c {
                let spec = c.to_string_lossy();
                match cellinject_genicam::parse_id(&spec) {
                    Err(e) => return Err(InputError(format!("{arg}: {e}")).into()),
                    Ok(Some(_)) if !cfg!(feature = "genicam") => {
                        return Err(InputError(format!(
                            "{arg} {spec}: this cellinject was built without GenICam cameras (install Debian's libaravis-dev, then `cargo install --path crates/cellinject --features genicam`; docs/cameras.md)"
                        ))
                        .into());
                    }
                    _ => {}
                }
            }
        }
        if let Some(b) = &self.bench {
            let port = b.rsplit_once(':').map(|(_, p)| p);
            if !port.is_some_and(|p| p.parse::<u16>().is_ok_and(|p| p > 0)) {
                return Err(InputError(format!(
                    "--bench `{b}` is not HOST:PORT (a port in 1..65535)"
                ))
                .into());
            }
        }
        Endpoint::parse(&self.backend)
            .map(Some)
            .map_err(|e| InputError(format!("--backend {e}")).into())
    }
}

/// A camera of `--camera` or `--side-camera`: a GenICam camera (`aravis:ID`) or a
/// folder of frames. Its pixels measure the sensor's `pitch` over the bench lens's zoom
/// in the object plane.
fn camera(
    arg: &str,
    spec: &std::path::Path,
    b: &BackendArgs,
    bench: &Bench,
    pitch: f64,
) -> Result<Box<dyn Camera>> {
    let lens = bench.clone();
    let pixel_size = Box::new(move || lens.zoom().map_or(f64::NAN, |z| pitch / z));
    let text = spec.to_string_lossy();
    if let Ok(Some(id)) = cellinject_genicam::parse_id(&text) {
        let clock = bench
            .clock()
            .map_err(|e| anyhow::anyhow!("{arg}: the bench's clock: {e}"))?;
        return Ok(Box::new(cellinject_genicam::OnClock::new(
            genicam(arg, id, pixel_size)?,
            Box::new(clock),
        )));
    }
    let cam = cellinject_cameras::FolderCamera::new(
        spec,
        pixel_size,
        b.camera_fps.unwrap_or(30.0),
        Duration::from_secs(5),
    )
    .map_err(|e| InputError(format!("{arg}: {e}")))?;
    Ok(Box::new(cam))
}

#[cfg(feature = "genicam")]
fn genicam(
    arg: &str,
    id: &str,
    pixel_size: Box<dyn Fn() -> f64 + Send>,
) -> Result<Box<dyn Camera>> {
    use cellinject_genicam::GenicamError;
    match cellinject_genicam::device::GenicamCamera::open(id, Duration::from_secs(10), pixel_size) {
        Ok(c) => Ok(Box::new(c)),
        Err(e @ GenicamError::Invalid { .. }) => Err(InputError(format!("{arg}: {e}")).into()),
        Err(e) => Err(anyhow::anyhow!("{arg}: {e}")),
    }
}

#[cfg(not(feature = "genicam"))]
fn genicam(arg: &str, id: &str, _: Box<dyn Fn() -> f64 + Send>) -> Result<Box<dyn Camera>> {
    // `check` refuses this before anything is opened; kept for completeness.
    Err(InputError(format!(
        "{arg} aravis:{id}: this cellinject was built without GenICam cameras"
    ))
    .into())
}

/// An opened bench.
pub struct Opened {
    /// The twin, when the backend is the twin (its truth, its plate, its faults).
    pub twin: Option<SharedTwin>,
    /// The guarded devices.
    pub rig: Rig<DynBackend>,
    /// `twin` or the controller's address.
    pub name: String,
    /// The approach the rig was assembled with.
    pub approach: Approach,
}

/// Opens the backend of `b` for description `d` (with the twin's options of `t`).
pub fn open(d: &Description, t: &TwinArgs, b: &BackendArgs) -> Result<Opened> {
    open_with(d, t, b, |devices| devices)
}

/// [`open`], the devices wrapped by `wrap` before the guards go round them (a
/// dashboard watching them).
pub fn open_with(
    d: &Description,
    t: &TwinArgs,
    b: &BackendArgs,
    wrap: impl FnOnce(Devices<DynBackend>) -> Devices<DynBackend>,
) -> Result<Opened> {
    let Some(endpoint) = b.check()? else {
        let twin = crate::sim::twin(d, t)?;
        let rig = cellinject_twin::guarded(&twin, wrap(cellinject_twin::devices(&twin).boxed()))
            .map_err(|e| InputError(format!("cannot build the twin: {e}")))?;
        let approach = twin
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .world
            .params()
            .rig
            .approach;
        return Ok(Opened {
            twin: Some(twin),
            rig,
            name: "twin".into(),
            approach,
        });
    };
    if t.seed_given() {
        return Err(InputError("--seed sets the twin's random processes: a GCS backend has none (seed the emulator: `cellinject emulate gcs --seed N`)".into()).into());
    }
    let bench_addr = match (&b.bench, &endpoint) {
        (Some(a), _) => a.clone(),
        (None, Endpoint::Tcp(a)) => {
            let (host, port) = a.rsplit_once(':').unwrap_or((a.as_str(), "50000"));
            let port: u16 = port.parse().unwrap_or(50000);
            format!("{host}:{}", port.wrapping_add(1))
        }
        (None, Endpoint::Serial { .. }) => {
            return Err(InputError("--backend gcs-serial://...: the controller carries only the stacks; give --bench HOST:PORT for the cameras, stage, injector and zoom".into()).into());
        }
    };
    let timeout = Duration::from_secs(2);
    let gcs = endpoint
        .open(timeout)
        .map_err(|e| anyhow::anyhow!("--backend {}: {e}", b.backend))?;
    // Whatever the controller was left doing: closed loops off (SVA needs them off).
    let mut gcs = gcs;
    gcs.set_servo(&[("1", false), ("2", false), ("3", false)])
        .map_err(|e| anyhow::anyhow!("--backend {}: {e}", b.backend))?;
    let gcs: SharedGcs = std::sync::Arc::new(std::sync::Mutex::new(gcs));
    let ranges = [0, 1, 2].map(|k| (0.0, d.rig.amplifiers[k].v_max));
    let noise = [d.sim.sensors.noise; 3];
    let (piezo, sensors) = stacks(&gcs, ["1", "2", "3"], ACTUATOR_NAMES, ranges, noise)
        .map_err(|e| anyhow::anyhow!("--backend {}: {e}", b.backend))?;
    let bench = Bench::connect(&bench_addr, Duration::from_secs(5))
        .map_err(|e| anyhow::anyhow!("--bench {bench_addr}: {e}"))?;
    let bench_err = |e| anyhow::anyhow!("--bench {bench_addr}: {e}");
    let devices: Devices<DynBackend> = Devices {
        piezo: piezo.map(|p| Box::new(p) as Box<dyn PiezoChannel>),
        sensors: sensors.map(|s| Box::new(s) as Box<dyn PositionSensor>),
        camera: match &b.camera {
            None => Box::new(bench.camera(ViewName::Top).map_err(bench_err)?) as Box<dyn Camera>,
            Some(spec) => camera("--camera", spec, b, &bench, d.sim.camera.pixel_size)?,
        },
        side_camera: match &b.side_camera {
            None => Box::new(bench.camera(ViewName::Side).map_err(bench_err)?) as Box<dyn Camera>,
            Some(spec) => camera("--side-camera", spec, b, &bench, d.sim.camera.pixel_size)?,
        },
        stage: Box::new(bench.stage().map_err(bench_err)?) as Box<dyn Stage>,
        feeder: Box::new(bench.feeder().map_err(bench_err)?) as Box<dyn Stage>,
        injector: Box::new(bench.injector().map_err(bench_err)?) as Box<dyn Injector>,
        optics: Box::new(bench.optics().map_err(bench_err)?) as Box<dyn Optics>,
        clock: Box::new(bench.clock().map_err(bench_err)?) as Box<dyn Clock>,
    };
    let mut p = d.rig;
    if let Some(a) = t.approach_given() {
        p.approach = a;
    }
    p.j3_yield = Some(crate::fea::j3_yield_check(d, p.approach)?);
    let mut rig = Rig::new(wrap(devices), &d.design, &p)
        .map_err(|e| InputError(format!("--backend {}: {e}", b.backend)))?;
    // A known start: the stacks at 0 V, A3 first (the pipette out), then A1 and A2;
    // a second for their creep if they were elsewhere.
    let was = [0, 1, 2].map(|k| rig.piezo[k].commanded_voltage());
    let rest = |e| anyhow::anyhow!("--backend {}: bringing the stacks to 0 V: {e}", b.backend);
    rig.piezo[2].set_voltage(0.0).map_err(rest)?;
    rig.command_tilt([0.0, 0.0]).map_err(rest)?;
    if was.iter().any(|v| v.abs() > 0.5) {
        rig.clock.sleep(1.0).map_err(rest)?;
    }
    Ok(Opened {
        twin: None,
        rig,
        name: b.backend.clone(),
        approach: p.approach,
    })
}
