//! `--rig FILE`, or its shorthands `--backend`, `--bench`, `--camera`,
//! `--side-camera`: the bench a command drives, opened by `cellinject-session`.

use std::path::PathBuf;

use anyhow::Result;
use cellinject_config::Description;
use cellinject_config::rigfile::{CameraDriver, DeviceDriver, PiezoDriver, RigFile};
use cellinject_gcs::Endpoint;
use cellinject_rig::{Devices, DynBackend};
use cellinject_session::{SessionError, TwinOptions};
use clap::Args;

pub use cellinject_session::Opened;

use crate::InputError;
use crate::sim::TwinArgs;

/// Where the commands go.
#[derive(Debug, Clone, Args)]
pub struct BackendArgs {
    /// The bench as a rig file: one TOML naming each device's driver (docs/rig.md).
    /// The options below are shorthands for one.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["backend", "bench", "camera", "side_camera", "camera_fps"])]
    pub rig: Option<PathBuf>,
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
            rig: None,
            backend: "twin".into(),
            bench: None,
            camera: None,
            side_camera: None,
            camera_fps: None,
        }
    }
}

impl BackendArgs {
    /// The bench these options name: the rig file of `--rig`, or the one its
    /// shorthands stand for. Refused (exit 2, naming the file and key or the option)
    /// before anything is opened or written.
    pub fn rig(&self) -> Result<RigFile> {
        if let Some(path) = &self.rig {
            return cellinject_session::load_rig(path).map_err(session_error);
        }
        if self.backend == "twin" {
            self.twin_alone()?;
            return Ok(RigFile::twin());
        }
        if let Some(f) = self.camera_fps
            && !(f.is_finite() && f > 0.0)
        {
            return Err(InputError(format!("--camera-fps must be positive, got {f}")).into());
        }
        let endpoint =
            Endpoint::parse(&self.backend).map_err(|e| InputError(format!("--backend {e}")))?;
        let bench = match (&self.bench, &endpoint) {
            (Some(b), _) => {
                let port = b.rsplit_once(':').map(|(_, p)| p);
                if !port.is_some_and(|p| p.parse::<u16>().is_ok_and(|p| p > 0)) {
                    return Err(InputError(format!(
                        "--bench `{b}` is not HOST:PORT (a port in 1..65535)"
                    ))
                    .into());
                }
                b.clone()
            }
            (None, Endpoint::Tcp(a)) => {
                let (host, port) = a.rsplit_once(':').unwrap_or((a.as_str(), "50000"));
                let port: u16 = port.parse().unwrap_or(50000);
                format!("{host}:{}", port.wrapping_add(1))
            }
            (None, Endpoint::Serial { .. }) => {
                return Err(InputError("--backend gcs-serial://...: the controller carries only the stacks; give --bench HOST:PORT for the cameras, stage, injector and zoom".into()).into());
            }
        };
        let rig = RigFile {
            name: None,
            piezo: PiezoDriver::Gcs {
                url: self.backend.clone(),
                axes: cellinject_config::rigfile::DEFAULT_AXES.map(str::to_string),
            },
            camera_top: self.camera("--camera", &self.camera, &bench)?,
            camera_side: self.camera("--side-camera", &self.side_camera, &bench)?,
            stage_macro: DeviceDriver::Bench(bench.clone()),
            stage_feeder: DeviceDriver::Bench(bench.clone()),
            injector: DeviceDriver::Bench(bench.clone()),
            optics: DeviceDriver::Bench(bench),
        };
        cellinject_session::validate(&rig).map_err(|(key, reason)| {
            let arg = if key.starts_with("camera.side") {
                "--side-camera"
            } else if key.starts_with("camera") {
                "--camera"
            } else {
                "--backend"
            };
            InputError(format!("{arg}: {reason}"))
        })?;
        Ok(rig)
    }

    /// The twin's shorthand refuses the real bench's options.
    fn twin_alone(&self) -> Result<()> {
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
        Ok(())
    }

    /// The camera of `--camera` or `--side-camera`, else the bench endpoint's.
    fn camera(&self, arg: &str, spec: &Option<PathBuf>, bench: &str) -> Result<CameraDriver> {
        let Some(spec) = spec else {
            return Ok(CameraDriver::Bench(bench.to_string()));
        };
        let text = spec.to_string_lossy();
        match cellinject_genicam::parse_id(&text) {
            Err(e) => Err(InputError(format!("{arg}: {e}")).into()),
            Ok(Some(id)) => Ok(CameraDriver::Aravis(id.to_string())),
            Ok(None) => Ok(CameraDriver::Dir {
                path: text.into_owned(),
                fps: self
                    .camera_fps
                    .unwrap_or(cellinject_config::rigfile::DEFAULT_DIR_FPS),
            }),
        }
    }
}

/// A session's error for the binary: bad input exits 2.
pub fn session_error(e: SessionError) -> anyhow::Error {
    if e.is_refusal() {
        InputError(e.to_string()).into()
    } else {
        anyhow::Error::new(e)
    }
}

/// The twin's options of `t`.
fn twin_options(t: &TwinArgs) -> TwinOptions {
    TwinOptions {
        approach: t.approach_given(),
        seed: t.seed_value(),
    }
}

/// Opens the bench of `rig` for description `d` (with the twin's options of `t`).
pub fn open(d: &Description, t: &TwinArgs, rig: &RigFile) -> Result<Opened> {
    open_with(d, t, rig, |devices| devices)
}

/// [`open`], the devices wrapped by `wrap` before the guards go round them (a
/// dashboard watching them).
pub fn open_with(
    d: &Description,
    t: &TwinArgs,
    rig: &RigFile,
    wrap: impl FnOnce(Devices<DynBackend>) -> Devices<DynBackend>,
) -> Result<Opened> {
    let _p =
        crate::progress::spinner("J3's stresses for the safety envelope (joint FEM or its cache)");
    cellinject_session::open_with(d, rig, twin_options(t), wrap).map_err(session_error)
}
