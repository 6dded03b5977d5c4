//! # cellinject-session
//!
//! A bench opened for a session, the same way for every front end: a rig file (or
//! the twin) read and checked ([`load_rig`], [`validate`]), each device opened
//! through its driver ([`open`]), the safety guards put round them, the stacks
//! brought to a known start; and a rig's devices asked whether they answer
//! ([`check`], `cellinject rig check`).
//!
//! **Architecture invariant:** front ends (the binary, the dashboard, Python) open
//! benches only through this crate; a new driver kind is one module and one match
//! arm here and in [`cellinject_config::rigfile`].
//!
//! **Architecture invariant:** a rig that is refused is refused before any device
//! is opened: [`open`] validates the whole rig first.

use std::path::Path;
use std::time::Duration;

use cellinject_config::Description;
use cellinject_config::rigfile::{self, CameraDriver, PiezoDriver, RigFile};
use cellinject_gcs::Endpoint;
use cellinject_gcs::devices::{SharedGcs, stacks};
use cellinject_gcs_emulator::bench::{Bench, ViewName};
use cellinject_hw::{Camera, Clock, Optics, PiezoChannel, PositionSensor};
use cellinject_model::{ACTUATOR_NAMES, Approach};
use cellinject_rig::{Devices, DynBackend, Rig};
use cellinject_twin::{SharedTwin, Twin, TwinParams};
use drivers::{Drivers, SharedOptics, StageRole};
use thiserror::Error;

pub mod calibration;
mod check;
mod drivers;
pub mod report;
pub mod run;
mod sensapex;

pub use check::{Answer, CheckReport, DeviceReport, check, text as check_text};

/// Why a bench could not be opened.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum SessionError {
    /// The rig (a file, or the options that stand for one) is not valid: bad input,
    /// refused before anything is opened.
    #[error("{what}: {reason}")]
    Refused {
        /// What is at fault: `FILE: key `piezo.driver`` or the option.
        what: String,
        /// Why.
        reason: String,
    },
    /// A device did not open or did not answer.
    #[error("{device}: {reason}")]
    Device {
        /// The device, by its driver (`gcs://HOST:PORT`, `bench://HOST:PORT`).
        device: String,
        /// What went wrong.
        reason: String,
    },
}

impl SessionError {
    /// Whether this is bad input (exit 2) rather than a device that failed.
    pub fn is_refusal(&self) -> bool {
        matches!(self, SessionError::Refused { .. })
    }
}

pub(crate) fn refused(what: impl Into<String>, reason: impl ToString) -> SessionError {
    SessionError::Refused {
        what: what.into(),
        reason: reason.to_string(),
    }
}

pub(crate) fn device(device: impl Into<String>, reason: impl ToString) -> SessionError {
    SessionError::Device {
        device: device.into(),
        reason: reason.to_string(),
    }
}

/// Reads and checks a rig file: its shape ([`rigfile::parse`]) and each driver in
/// full ([`validate`]); a `dir:` camera's relative folder is taken from the rig
/// file's folder. Every error names the file and the dotted key.
pub fn load_rig(path: &Path) -> Result<RigFile, SessionError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|e| refused(file.clone(), format!("cannot read the rig file: {e}")))?;
    let mut rig = rigfile::parse(&text).map_err(|e| refused(file.clone(), e))?;
    let base = path.parent().unwrap_or(Path::new(""));
    for cam in [&mut rig.camera_top, &mut rig.camera_side] {
        if let CameraDriver::Dir { path, .. } = cam
            && Path::new(path).is_relative()
        {
            *path = base.join(&*path).display().to_string();
        }
    }
    validate(&rig).map_err(|(key, reason)| refused(format!("{file}: key `{key}`"), reason))?;
    Ok(rig)
}

/// Checks each driver of `rig` in full, without opening anything: the controller's
/// address, the GenICam ids (and that this build has GenICam). The error is the
/// dotted key and why.
pub fn validate(rig: &RigFile) -> Result<(), (String, String)> {
    if let PiezoDriver::Gcs { url, .. } = &rig.piezo {
        Endpoint::parse(url).map_err(|e| ("piezo.driver".to_string(), e))?;
    }
    for (key, cam) in [
        ("camera.top.driver", &rig.camera_top),
        ("camera.side.driver", &rig.camera_side),
    ] {
        if let CameraDriver::Aravis(id) = cam
            && !cfg!(feature = "genicam")
        {
            return Err((
                key.to_string(),
                format!(
                    "aravis:{id}: this cellinject was built without GenICam cameras (install Debian's libaravis-dev, then `cargo install --path crates/cellinject --features genicam`; docs/cameras.md)"
                ),
            ));
        }
    }
    Ok(())
}

/// The twin's options a front end may set over the description's.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TwinOptions {
    /// The pre-tensioning approach (default: the description's `twin.approach`).
    pub approach: Option<Approach>,
    /// The seed of the twin's random processes (default: the description's
    /// `twin.seed`). A real bench has none: giving one with it is refused.
    pub seed: Option<u64>,
}

/// J3's yield check for the safety envelope of a bench assembled with `approach`:
/// the structural model on level-1 FEM joints (from the joint cache when it holds
/// them), reduced to numbers the envelope evaluates without the FEM.
pub fn j3_yield_check(
    d: &Description,
    approach: Approach,
) -> Result<cellinject_rig::guard::YieldCheck, SessionError> {
    let store = cellinject_fea::default_store(true);
    cellinject_fea::j3_yield_check(&d.design, &d.structure, approach, store.as_ref()).map_err(
        |e| {
            device(
                "the safety envelope",
                format!(
                    "it checks J3 against its yield strength with the structural model, which failed: {e}"
                ),
            )
        },
    )
}

/// The twin of description `d` (its J3 yield check from the FEA cache).
pub fn twin(d: &Description, opts: TwinOptions) -> Result<SharedTwin, SessionError> {
    let mut p = TwinParams {
        rig: d.rig,
        sim: d.sim,
    };
    if let Some(a) = opts.approach {
        p.rig.approach = a;
    }
    if let Some(s) = opts.seed {
        p.sim.seed = s;
    }
    p.rig.j3_yield = Some(j3_yield_check(d, p.rig.approach)?);
    Ok(Twin::new(&d.design, p)
        .map_err(|e| refused("the description", format!("cannot build the twin: {e}")))?
        .into_shared())
}

/// An opened bench.
pub struct Opened {
    /// The twin, when the rig is the twin (its truth, its plate, its faults).
    pub twin: Option<SharedTwin>,
    /// The guarded devices.
    pub rig: Rig<DynBackend>,
    /// The bench's identity in the records: `twin` or the controller's address.
    pub name: String,
    /// The approach the rig was assembled with.
    pub approach: Approach,
}

/// Opens the bench of `rig` for description `d`.
pub fn open(d: &Description, rig: &RigFile, opts: TwinOptions) -> Result<Opened, SessionError> {
    open_with(d, rig, opts, |devices| devices)
}

/// [`open`], the devices wrapped by `wrap` before the guards go round them (a
/// dashboard watching them).
pub fn open_with(
    d: &Description,
    rig: &RigFile,
    opts: TwinOptions,
    wrap: impl FnOnce(Devices<DynBackend>) -> Devices<DynBackend>,
) -> Result<Opened, SessionError> {
    validate(rig).map_err(|(key, reason)| refused(format!("the rig's `{key}`"), reason))?;
    let PiezoDriver::Gcs { url, axes } = &rig.piezo else {
        let twin = twin(d, opts)?;
        let guarded =
            cellinject_twin::guarded(&twin, wrap(cellinject_twin::devices(&twin).boxed()))
                .map_err(|e| refused("the description", format!("cannot build the twin: {e}")))?;
        let approach = twin
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .world
            .params()
            .rig
            .approach;
        return Ok(Opened {
            twin: Some(twin),
            rig: guarded,
            name: "twin".into(),
            approach,
        });
    };
    if opts.seed.is_some() {
        return Err(refused(
            "--seed",
            "it sets the twin's random processes: a GCS backend has none (seed the emulator: `cellinject emulate gcs --seed N`)",
        ));
    }
    let devices = real_devices(d, rig, url, axes)?;
    let mut p = d.rig;
    if let Some(a) = opts.approach {
        p.approach = a;
    }
    p.j3_yield = Some(j3_yield_check(d, p.approach)?);
    let mut guarded =
        Rig::new(wrap(devices), &d.design, &p).map_err(|e| refused(url.clone(), e))?;
    // A known start: the stacks at 0 V, A3 first (the pipette out), then A1 and A2;
    // a second for their creep if they were elsewhere.
    let was = [0, 1, 2].map(|k| guarded.piezo[k].commanded_voltage());
    let rest = |e| device(url.clone(), format!("bringing the stacks to 0 V: {e}"));
    guarded.piezo[2].set_voltage(0.0).map_err(rest)?;
    guarded.command_tilt([0.0, 0.0]).map_err(rest)?;
    if was.iter().any(|v| v.abs() > 0.5) {
        guarded.clock.sleep(1.0).map_err(rest)?;
    }
    Ok(Opened {
        twin: None,
        rig: guarded,
        name: url.clone(),
        approach: p.approach,
    })
}

/// The GCS controller of `url`, its servos off (SVA needs them off).
fn controller(url: &str) -> Result<SharedGcs, SessionError> {
    let endpoint = Endpoint::parse(url).map_err(|e| refused("the rig's `piezo.driver`", e))?;
    // The driver's errors may name the controller already: named once.
    let named = |e: &dyn std::fmt::Display| {
        let s = e.to_string();
        let reason = s.strip_prefix(&format!("{url}: ")).unwrap_or(&s);
        device(url, reason)
    };
    let mut gcs = endpoint
        .open(Duration::from_secs(2))
        .map_err(|e| named(&e))?;
    gcs.set_servo(&[("1", false), ("2", false), ("3", false)])
        .map_err(|e| named(&e))?;
    Ok(std::sync::Arc::new(std::sync::Mutex::new(gcs)))
}

fn real_devices(
    d: &Description,
    rig: &RigFile,
    url: &str,
    axes: &[String; 3],
) -> Result<Devices<DynBackend>, SessionError> {
    let gcs = controller(url)?;
    let ranges = [0, 1, 2].map(|k| (0.0, d.rig.amplifiers[k].v_max));
    let noise = [d.sim.sensors.noise; 3];
    let axes = [axes[0].as_str(), axes[1].as_str(), axes[2].as_str()];
    let (piezo, sensors) =
        stacks(&gcs, axes, ACTUATOR_NAMES, ranges, noise).map_err(|e| device(url, e))?;
    let mut drivers = Drivers::default();
    let main = drivers.first(rig)?;
    let optics = SharedOptics::new(drivers.optics(&rig.optics)?);
    let pitch = d.sim.camera.pixel_size;
    let mut camera = |key: &str, driver: &CameraDriver, view: ViewName| match driver {
        CameraDriver::Bench(a) => {
            let b = drivers.endpoint(a)?;
            Ok(Box::new(
                b.camera(view)
                    .map_err(|e| device(format!("bench://{a}"), e))?,
            ) as Box<dyn Camera>)
        }
        other => own_camera(key, other, &main, optics.pixel_size(pitch)),
    };
    let top = camera("camera.top", &rig.camera_top, ViewName::Top)?;
    let side = camera("camera.side", &rig.camera_side, ViewName::Side)?;
    let stage = drivers.stage(&rig.stage_macro, StageRole::Macro)?;
    let feeder = drivers.stage(&rig.stage_feeder, StageRole::Feeder)?;
    let injector = drivers.injector(&rig.injector, d.rig.injector_max_pressure)?;
    let optics = Box::new(optics) as Box<dyn Optics>;
    let clock =
        Box::new(main.clock().map_err(|e| device("the bench's clock", e))?) as Box<dyn Clock>;
    Ok(Devices {
        piezo: piezo.map(|p| Box::new(p) as Box<dyn PiezoChannel>),
        sensors: sensors.map(|s| Box::new(s) as Box<dyn PositionSensor>),
        camera: top,
        side_camera: side,
        stage,
        feeder,
        injector,
        optics,
        clock,
    })
}

/// A camera of its own (not a bench endpoint's): a GenICam camera or a folder of
/// frames, on `bench`'s clock, its pixels measuring `pixel_size()` in the object
/// plane (the sensor's pitch over the rig's optics' zoom).
fn own_camera(
    key: &str,
    driver: &CameraDriver,
    bench: &Bench,
    pixel_size: Box<dyn Fn() -> f64 + Send>,
) -> Result<Box<dyn Camera>, SessionError> {
    match driver {
        CameraDriver::Aravis(id) => {
            let clock = bench.clock().map_err(|e| {
                device(
                    format!("{key} aravis:{id}"),
                    format!("the bench's clock: {e}"),
                )
            })?;
            Ok(Box::new(cellinject_genicam::OnClock::new(
                genicam(key, id, pixel_size)?,
                Box::new(clock),
            )))
        }
        CameraDriver::Dir { path, fps } => {
            let cam = cellinject_cameras::FolderCamera::new(
                Path::new(path),
                pixel_size,
                *fps,
                Duration::from_secs(5),
            )
            .map_err(|e| refused(key, e))?;
            Ok(Box::new(cam))
        }
        CameraDriver::Twin | CameraDriver::Bench(_) => Err(refused(
            key,
            "not a camera of its own (the twin's or a bench endpoint's)",
        )),
    }
}

#[cfg(feature = "genicam")]
fn genicam(
    key: &str,
    id: &str,
    pixel_size: Box<dyn Fn() -> f64 + Send>,
) -> Result<Box<dyn Camera>, SessionError> {
    use cellinject_genicam::GenicamError;
    match cellinject_genicam::device::GenicamCamera::open(id, Duration::from_secs(10), pixel_size) {
        Ok(c) => Ok(Box::new(c)),
        Err(e @ GenicamError::Invalid { .. }) => Err(refused(key, e)),
        Err(e) => Err(device(format!("{key} aravis:{id}"), e)),
    }
}

#[cfg(not(feature = "genicam"))]
fn genicam(
    key: &str,
    id: &str,
    _: Box<dyn Fn() -> f64 + Send>,
) -> Result<Box<dyn Camera>, SessionError> {
    // `validate` refuses this before anything is opened; kept for completeness.
    Err(refused(
        key,
        format!("aravis:{id}: this cellinject was built without GenICam cameras"),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).expect("write");
        p
    }

    #[test]
    fn a_rig_file_is_read_with_its_folder_and_its_faults_name_file_and_key() {
        let dir = tempfile::tempdir().expect("tempdir");
        let twin = write(dir.path(), "twin.toml", "[piezo]\ndriver = \"twin\"\n");
        assert_eq!(load_rig(&twin).expect("twin"), RigFile::twin());
        let bench = "[piezo]\ndriver = \"gcs://127.0.0.1:1\"\n[camera.top]\ndriver = \"dir:frames\"\n[camera.side]\ndriver = \"bench://h:2\"\n[stage.macro]\ndriver = \"bench://h:2\"\n[stage.feeder]\ndriver = \"bench://h:2\"\n[injector]\ndriver = \"bench://h:2\"\n[optics]\ndriver = \"bench://h:2\"\n";
        let p = write(dir.path(), "bench.toml", bench);
        let r = load_rig(&p).expect("valid");
        let CameraDriver::Dir { path, .. } = &r.camera_top else {
            panic!("a folder camera: {:?}", r.camera_top)
        };
        assert_eq!(Path::new(path), dir.path().join("frames"));
        // The controller's address is checked in full, naming file and key.
        let bad = write(
            dir.path(),
            "bad.toml",
            &bench.replace("127.0.0.1:1", "h:port"),
        );
        let e = load_rig(&bad).expect_err("a bad port");
        assert!(e.is_refusal());
        let text = e.to_string();
        assert!(
            text.contains("bad.toml") && text.contains("piezo.driver"),
            "{text}"
        );
        // A shape error too.
        let bad = write(
            dir.path(),
            "shape.toml",
            "[piezo]\ndriver = \"twin\"\n[lamp]\n",
        );
        let text = load_rig(&bad).expect_err("unknown section").to_string();
        assert!(
            text.contains("shape.toml") && text.contains("`lamp`"),
            "{text}"
        );
        // A file that is not there.
        let text = load_rig(&dir.path().join("none.toml"))
            .expect_err("missing")
            .to_string();
        assert!(text.contains("none.toml"), "{text}");
    }

    #[test]
    fn a_seed_is_refused_on_a_real_bench_before_anything_is_opened() {
        // Port 1 on the loopback: nothing listens, but nothing is tried either.
        let rig = rigfile::parse("[piezo]\ndriver = \"gcs://127.0.0.1:1\"\n[camera.top]\ndriver = \"bench://127.0.0.1:1\"\n[camera.side]\ndriver = \"bench://127.0.0.1:1\"\n[stage.macro]\ndriver = \"bench://127.0.0.1:1\"\n[stage.feeder]\ndriver = \"bench://127.0.0.1:1\"\n[injector]\ndriver = \"bench://127.0.0.1:1\"\n[optics]\ndriver = \"bench://127.0.0.1:1\"\n").expect("valid");
        let d = cellinject_config::prototype();
        let opts = TwinOptions {
            approach: None,
            seed: Some(3),
        };
        let e = open(&d, &rig, opts).err().expect("refused");
        assert!(e.is_refusal(), "{e}");
        assert!(e.to_string().contains("--seed"), "{e}");
        // Without the seed, the controller that is not there is a device error.
        let e = open(&d, &rig, TwinOptions::default())
            .err()
            .expect("no controller");
        assert!(!e.is_refusal(), "{e}");
        assert!(e.to_string().contains("gcs://127.0.0.1:1"), "{e}");
    }
}
