//! The rig file: one TOML that names the driver of each device of a bench, so that a
//! lab writes its bench once (like Micro-Manager's hardware configuration) and every
//! command that drives hardware takes it (`--rig FILE`).
//!
//! ```toml
//! name = "bench 2, room 114"          # optional, shown by `rig check`
//! [piezo]
//! driver = "gcs://192.168.0.20:50000" # twin | gcs://HOST[:PORT] | gcs-serial://PATH[?baud=N]
//! axes = ["1", "2", "3"]              # the controller's axes of A1, A2, A3 (optional)
//! [camera.top]
//! driver = "aravis:Basler-12345"      # twin | bench://HOST:PORT | aravis:ID | dir:PATH
//! [camera.side]
//! driver = "dir:frames/side"          # a folder another program writes frames into
//! fps = 15                            # dir: only; frames per second (default 30)
//! [stage.macro]
//! driver = "bench://192.168.0.20:50001"
//! [stage.feeder]
//! driver = "bench://192.168.0.20:50001"
//! [injector]
//! driver = "bench://192.168.0.20:50001"
//! [optics]
//! driver = "bench://192.168.0.20:50001"
//! # or a Sensapex uMs's lens changer: driver = "sensapex-ums://169.254.255.255?dev=21"
//! # with lenses = [2.5, 10], the magnifications of its lens positions 1 and 2
//! ```
//!
//! The twin is a whole simulated bench: with `[piezo] driver = "twin"` every other
//! section may be left out, and one that is given must say `twin` too. Any other piezo
//! driver needs every section. This module checks the file's shape and each driver's
//! form; the session library parses the controller's address in full and opens the
//! devices. `docs/rig.md` documents every driver and key.

use crate::ConfigError;
use crate::section::Section;

/// The piezo stacks' controller.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PiezoDriver {
    /// The digital twin (the whole bench simulated).
    Twin,
    /// A PI GCS 2.0 controller: `gcs://HOST[:PORT]` or `gcs-serial://PATH[?baud=N]`,
    /// kept as written (the session library parses it).
    Gcs {
        /// The address as written.
        url: String,
        /// The controller's axis identifiers of A1, A2 and A3.
        axes: [String; 3],
    },
}

/// A camera's driver.
#[derive(Debug, Clone, PartialEq)]
pub enum CameraDriver {
    /// The twin's camera.
    Twin,
    /// A camera served by a bench endpoint (`bench://HOST:PORT`, e.g. `cellinject
    /// emulate gcs`), its `HOST:PORT`.
    Bench(String),
    /// A GenICam camera (GigE Vision, USB3 Vision) by any id Aravis gives it.
    Aravis(String),
    /// A folder another acquisition program writes frames into (PNG or TIFF, taken in
    /// name order), at `fps` frames per second.
    Dir {
        /// The folder, as written (relative to the rig file's folder when relative;
        /// the reader of the file resolves it).
        path: String,
        /// Frames per second, > 0.
        fps: f64,
    },
}

/// The driver of a stage, the injector or the optics.
#[derive(Debug, Clone, PartialEq)]
pub enum DeviceDriver {
    /// The twin's device.
    Twin,
    /// The device of a bench endpoint, its `HOST:PORT`.
    Bench(String),
    /// A Sensapex device over SMCP1 (`sensapex://`, `sensapex-ums://`,
    /// `sensapex-pressure://`).
    Sensapex(SensapexDevice),
}

/// Which Sensapex device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SensapexKind {
    /// A uMp micromanipulator (`sensapex://`): a stage.
    Manipulator,
    /// A uMs stage (`sensapex-ums://`).
    Stage,
    /// A channel of a uMv / uMc pressure controller (`sensapex-pressure://`): the
    /// injector.
    Pressure,
}

impl SensapexKind {
    /// The driver's scheme.
    pub fn scheme(self) -> &'static str {
        match self {
            SensapexKind::Manipulator => "sensapex",
            SensapexKind::Stage => "sensapex-ums",
            SensapexKind::Pressure => "sensapex-pressure",
        }
    }
}

/// A Sensapex device: `SCHEME://ADDRESS?dev=N[&group=G][&channel=C]`, with the
/// stage's optional `origin` (m) and `speed` (m/s).
#[derive(Debug, Clone, PartialEq)]
pub struct SensapexDevice {
    /// Which device.
    pub kind: SensapexKind,
    /// The devices' IP address: a device's own, the link-local broadcast
    /// 169.254.255.255, or 127.0.0.1 for `cellinject emulate sensapex`.
    pub address: std::net::IpAddr,
    /// Group 0..10 (UDP port 55555 + group).
    pub group: u16,
    /// Device id 1..254.
    pub dev: u16,
    /// Pressure channel 1..8 (pressure controllers only).
    pub channel: Option<u8>,
    /// The device's coordinates of stage position 0, m, one per axis (empty: the
    /// middle of each axis's travel).
    pub origin: Vec<f64>,
    /// Speed of the stage's moves, m/s.
    pub speed: f64,
    /// A uMs named by `[optics]`: the magnification of its lens changer's
    /// positions 1 and 2 (`lenses`; empty for any other section).
    pub lenses: Vec<f64>,
}

impl SensapexDevice {
    /// The driver as written (without `origin` and `speed`).
    pub fn url(&self) -> String {
        let mut u = format!("{}://{}?dev={}", self.kind.scheme(), self.address, self.dev);
        if self.group != 0 {
            u += &format!("&group={}", self.group);
        }
        if let Some(c) = self.channel {
            u += &format!("&channel={c}");
        }
        u
    }
}

/// Speed of a Sensapex stage's moves when `speed` is not given, m/s.
pub const DEFAULT_SENSAPEX_SPEED: f64 = 1e-3;

/// A parsed rig file.
#[derive(Debug, Clone, PartialEq)]
pub struct RigFile {
    /// The bench's name (`name`), if given.
    pub name: Option<String>,
    /// `[piezo]`.
    pub piezo: PiezoDriver,
    /// `[camera.top]`: the microscope's camera.
    pub camera_top: CameraDriver,
    /// `[camera.side]`: the side camera.
    pub camera_side: CameraDriver,
    /// `[stage.macro]`: the macro-manipulator bringing the pipette to the cells.
    pub stage_macro: DeviceDriver,
    /// `[stage.feeder]`: the matrix feeder's stage.
    pub stage_feeder: DeviceDriver,
    /// `[injector]`: the pressure injector.
    pub injector: DeviceDriver,
    /// `[optics]`: the microscope's zoom.
    pub optics: DeviceDriver,
}

/// Frames per second of a `dir:` camera when `fps` is not given.
pub const DEFAULT_DIR_FPS: f64 = 30.0;

/// The controller's axes of A1, A2, A3 when `axes` is not given.
pub const DEFAULT_AXES: [&str; 3] = ["1", "2", "3"];

impl RigFile {
    /// The twin: every device simulated.
    pub fn twin() -> Self {
        RigFile {
            name: None,
            piezo: PiezoDriver::Twin,
            camera_top: CameraDriver::Twin,
            camera_side: CameraDriver::Twin,
            stage_macro: DeviceDriver::Twin,
            stage_feeder: DeviceDriver::Twin,
            injector: DeviceDriver::Twin,
            optics: DeviceDriver::Twin,
        }
    }

    /// Whether this is the twin.
    pub fn is_twin(&self) -> bool {
        self.piezo == PiezoDriver::Twin
    }

    /// The bench's identity in the run records (`backend`): `twin`, or the piezo
    /// controller's address as written. A run resumes only on the same one.
    pub fn backend(&self) -> &str {
        match &self.piezo {
            PiezoDriver::Twin => "twin",
            PiezoDriver::Gcs { url, .. } => url,
        }
    }
}

/// The sections of a rig file, with their subsections.
const SECTIONS: [(&str, &[&str]); 5] = [
    ("piezo", &[]),
    ("camera", &["top", "side"]),
    ("stage", &["macro", "feeder"]),
    ("injector", &[]),
    ("optics", &[]),
];

/// Parses a rig file's text. Every error names the dotted key at fault
/// (`camera.top.driver`); the caller adds the file's name.
pub fn parse(text: &str) -> Result<RigFile, ConfigError> {
    let root = crate::toml_table(text)?;
    let mut top = Section::root(&root);
    let name = if top.has("name") {
        Some(top.string("name")?)
    } else {
        None
    };
    let mut p = top.table("piezo")?;
    let piezo = piezo(&mut p)?;
    p.finish()?;
    let twin = piezo == PiezoDriver::Twin;
    // A section another driver than the twin's needs, or the twin's default.
    let mut camera = top.opt_table("camera")?;
    let mut stage = top.opt_table("stage")?;
    let top_cam = read_camera(camera.as_mut(), "camera", "top", twin)?;
    let side_cam = read_camera(camera.as_mut(), "camera", "side", twin)?;
    let stage_macro = read_device(stage.as_mut(), "stage", "macro", twin)?;
    let stage_feeder = read_device(stage.as_mut(), "stage", "feeder", twin)?;
    if let Some(c) = camera {
        c.finish()?;
    }
    if let Some(s) = stage {
        s.finish()?;
    }
    let injector = read_device(Some(&mut top), "", "injector", twin)?;
    let optics = read_device(Some(&mut top), "", "optics", twin)?;
    top.finish().map_err(|e| match e {
        ConfigError::Unknown { key, .. } => ConfigError::Unknown {
            key,
            expected: format!("name, {}", SECTIONS.map(|(s, _)| s).join(", ")),
        },
        other => other,
    })?;
    Ok(RigFile {
        name,
        piezo,
        camera_top: top_cam,
        camera_side: side_cam,
        stage_macro,
        stage_feeder,
        injector,
        optics,
    })
}

fn piezo(p: &mut Section) -> Result<PiezoDriver, ConfigError> {
    let driver = p.string("driver")?;
    let key = p.key("driver");
    if driver == "twin" {
        if p.has("axes") {
            return Err(ConfigError::Invalid {
                key: p.key("axes"),
                reason: "the twin's stacks have no controller axes (axes goes with gcs:// and gcs-serial://)".into(),
            });
        }
        return Ok(PiezoDriver::Twin);
    }
    if !(driver.starts_with("gcs://") || driver.starts_with("gcs-serial://")) {
        return Err(ConfigError::Invalid {
            key,
            reason: format!(
                "`{driver}` is not a piezo driver: twin, gcs://HOST[:PORT] or gcs-serial://PATH[?baud=N]"
            ),
        });
    }
    let axes = if p.has("axes") {
        let key = p.key("axes");
        let bad = |found: String| ConfigError::Type {
            key: key.clone(),
            expected: "an array of 3 axis names (A1, A2, A3), e.g. [\"1\", \"2\", \"3\"]".into(),
            found,
        };
        match p.get("axes") {
            Some(toml::Value::Array(items)) if items.len() == 3 => {
                let names: Vec<String> = items
                    .iter()
                    .filter_map(|v| v.as_str())
                    .map(str::to_string)
                    .collect();
                if names.len() != 3 {
                    return Err(bad("an element that is not a string".into()));
                }
                if let Some(n) = names.iter().find(|n| !is_axis_name(n)) {
                    return Err(ConfigError::Invalid {
                        key,
                        reason: format!(
                            "`{n}` is not a GCS axis name (1 to 16 letters, digits or _)"
                        ),
                    });
                }
                if names[0] == names[1] || names[0] == names[2] || names[1] == names[2] {
                    return Err(ConfigError::Invalid {
                        key,
                        reason: "A1, A2 and A3 need three different axes".into(),
                    });
                }
                [names[0].clone(), names[1].clone(), names[2].clone()]
            }
            Some(toml::Value::Array(items)) => {
                return Err(bad(format!("{} elements", items.len())));
            }
            _ => return Err(bad("another type".into())),
        }
    } else {
        DEFAULT_AXES.map(str::to_string)
    };
    Ok(PiezoDriver::Gcs { url: driver, axes })
}

/// A GCS 2.0 axis identifier: up to 16 characters, letters, digits and underscores.
fn is_axis_name(n: &str) -> bool {
    !n.is_empty() && n.len() <= 16 && n.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_')
}

/// The `[parent.name]` (or top-level `[name]` when `parent` is empty) table of a
/// device, or `None` when absent.
fn device_table<'a>(
    parent: Option<&mut Section<'a>>,
    parent_name: &str,
    name: &str,
    twin: bool,
) -> Result<Option<Section<'a>>, ConfigError> {
    let dotted = if parent_name.is_empty() {
        name.to_string()
    } else {
        format!("{parent_name}.{name}")
    };
    let table = match parent {
        Some(p) => p.opt_table(name)?,
        None => None,
    };
    if table.is_none() && !twin {
        return Err(ConfigError::Missing {
            key: format!("{dotted}.driver"),
        });
    }
    Ok(table)
}

/// `bench://HOST:PORT` → `HOST:PORT`, the port a number in 1..65535.
fn bench_address(key: &str, driver: &str) -> Result<Option<String>, ConfigError> {
    let Some(addr) = driver.strip_prefix("bench://") else {
        return Ok(None);
    };
    let addr = addr.trim_end_matches('/');
    let ok = addr
        .rsplit_once(':')
        .is_some_and(|(h, p)| !h.is_empty() && p.parse::<u16>().is_ok_and(|p| p > 0));
    if !ok {
        return Err(ConfigError::Invalid {
            key: key.to_string(),
            reason: format!("`{driver}` is not bench://HOST:PORT (a port in 1..65535)"),
        });
    }
    Ok(Some(addr.to_string()))
}

/// The twin's device given with another piezo driver, or another device with the
/// twin's: refused (the twin simulates the bench whole).
fn mixed(key: String, driver: &str, twin: bool) -> ConfigError {
    ConfigError::Invalid {
        key,
        reason: if twin {
            format!(
                "`{driver}` with [piezo] driver = \"twin\": the twin simulates the whole bench, so each of its devices is `twin` (or left out)"
            )
        } else {
            "`twin` with a real piezo controller: the twin's devices exist only with [piezo] driver = \"twin\"".into()
        },
    }
}

fn read_camera(
    parent: Option<&mut Section>,
    parent_name: &str,
    name: &str,
    twin: bool,
) -> Result<CameraDriver, ConfigError> {
    let Some(mut t) = device_table(parent, parent_name, name, twin)? else {
        return Ok(CameraDriver::Twin);
    };
    let driver = t.string("driver")?;
    let key = t.key("driver");
    let fps = t.opt_number("fps")?;
    let cam = if driver == "twin" {
        CameraDriver::Twin
    } else if let Some(addr) = bench_address(&key, &driver)? {
        CameraDriver::Bench(addr)
    } else if let Some(id) = driver.strip_prefix("aravis:") {
        if id.trim().is_empty() {
            return Err(ConfigError::Invalid {
                key,
                reason: "aravis:ID needs the camera's id (as `arv-tool-0.8` lists it, its serial number or its IP address)".into(),
            });
        }
        CameraDriver::Aravis(id.to_string())
    } else if let Some(path) = driver.strip_prefix("dir:") {
        if path.is_empty() {
            return Err(ConfigError::Invalid {
                key,
                reason: "dir:PATH needs the folder the frames are written into".into(),
            });
        }
        let fps = fps.unwrap_or(DEFAULT_DIR_FPS);
        if !(fps.is_finite() && fps > 0.0) {
            return Err(ConfigError::Invalid {
                key: t.key("fps"),
                reason: format!("frames per second must be positive, got {fps}"),
            });
        }
        CameraDriver::Dir {
            path: path.to_string(),
            fps,
        }
    } else {
        return Err(ConfigError::Invalid {
            key,
            reason: format!(
                "`{driver}` is not a camera driver: twin, bench://HOST:PORT, aravis:ID or dir:PATH"
            ),
        });
    };
    if fps.is_some() && !matches!(cam, CameraDriver::Dir { .. }) {
        return Err(ConfigError::Invalid {
            key: t.key("fps"),
            reason: "fps sets the pace of a dir: camera; the others set their own".into(),
        });
    }
    if (cam == CameraDriver::Twin) != twin {
        return Err(mixed(key, &driver, twin));
    }
    t.finish()?;
    Ok(cam)
}

fn read_device(
    parent: Option<&mut Section>,
    parent_name: &str,
    name: &str,
    twin: bool,
) -> Result<DeviceDriver, ConfigError> {
    let Some(mut t) = device_table(parent, parent_name, name, twin)? else {
        return Ok(DeviceDriver::Twin);
    };
    let driver = t.string("driver")?;
    let key = t.key("driver");
    // The Sensapex devices this section may name.
    let fits: &[SensapexKind] = match name {
        "macro" | "feeder" => &[SensapexKind::Manipulator, SensapexKind::Stage],
        "injector" => &[SensapexKind::Pressure],
        // A uMs's lens changer: the objectives.
        _ => &[SensapexKind::Stage],
    };
    let device = if driver == "twin" {
        DeviceDriver::Twin
    } else if let Some(addr) = bench_address(&key, &driver)? {
        DeviceDriver::Bench(addr)
    } else if let Some(mut s) = sensapex(&key, &driver)? {
        if !fits.contains(&s.kind) {
            let what = if name == "injector" || name == "optics" {
                name.to_string()
            } else {
                format!("{parent_name}.{name}")
            };
            return Err(ConfigError::Invalid {
                key,
                reason: format!(
                    "`{driver}`: a {} is not a device for [{what}] ({})",
                    s.kind.scheme(),
                    match name {
                        "injector" => "sensapex-pressure://ADDRESS?dev=N&channel=C",
                        "optics" => "a uMs's lens changer, sensapex-ums://ADDRESS?dev=N",
                        _ => "sensapex://ADDRESS?dev=N or sensapex-ums://ADDRESS?dev=N",
                    }
                ),
            });
        }
        if name == "optics" {
            s.lenses = lenses(&mut t)?;
        } else if s.kind != SensapexKind::Pressure {
            if let Some(o) = t.opt_array::<3>("origin")? {
                s.origin = o.to_vec();
            }
            if let Some(v) = t.opt_number("speed")? {
                if !(v.is_finite() && v > 0.0 && v <= 0.01) {
                    return Err(ConfigError::Invalid {
                        key: t.key("speed"),
                        reason: format!("a Sensapex stage's speed lies in (0, 0.01] m/s, got {v}"),
                    });
                }
                s.speed = v;
            }
        }
        DeviceDriver::Sensapex(s)
    } else {
        let more = match name {
            "macro" | "feeder" => ", sensapex://ADDRESS?dev=N or sensapex-ums://ADDRESS?dev=N",
            "injector" => " or sensapex-pressure://ADDRESS?dev=N&channel=C",
            _ => " or sensapex-ums://ADDRESS?dev=N (a uMs's lens changer)",
        };
        return Err(ConfigError::Invalid {
            key,
            reason: format!(
                "`{driver}` is not a driver of this device: twin, bench://HOST:PORT{more}"
            ),
        });
    };
    if (device == DeviceDriver::Twin) != twin {
        return Err(mixed(key, &driver, twin));
    }
    t.finish()?;
    Ok(device)
}

/// `[optics]`'s `lenses` for a uMs's lens changer: the magnifications of its positions
/// 1 and 2 (0 is the empty centre), each in (0, 1000].
fn lenses(t: &mut Section) -> Result<Vec<f64>, ConfigError> {
    let Some(l) = t.opt_array::<2>("lenses")? else {
        return Err(ConfigError::Invalid {
            key: t.key("lenses"),
            reason: "a uMs's lens changer as the optics needs the magnification of its lens positions 1 and 2: lenses = [M1, M2] (e.g. [2.5, 10])".into(),
        });
    };
    if let Some(m) = l
        .iter()
        .find(|m| !(m.is_finite() && **m > 0.0 && **m <= 1000.0))
    {
        return Err(ConfigError::Invalid {
            key: t.key("lenses"),
            reason: format!("a magnification lies in (0, 1000], got {m}"),
        });
    }
    Ok(l.to_vec())
}

/// `sensapex[-ums|-pressure]://ADDRESS?dev=N[&group=G][&channel=C]`, or `None`
/// for another driver.
fn sensapex(key: &str, driver: &str) -> Result<Option<SensapexDevice>, ConfigError> {
    let (kind, rest) = if let Some(r) = driver.strip_prefix("sensapex://") {
        (SensapexKind::Manipulator, r)
    } else if let Some(r) = driver.strip_prefix("sensapex-ums://") {
        (SensapexKind::Stage, r)
    } else if let Some(r) = driver.strip_prefix("sensapex-pressure://") {
        (SensapexKind::Pressure, r)
    } else {
        return Ok(None);
    };
    let bad = |reason: String| ConfigError::Invalid {
        key: key.to_string(),
        reason: format!("`{driver}`: {reason}"),
    };
    let (host, query) = rest.split_once('?').unwrap_or((rest, ""));
    let address: std::net::IpAddr = host.trim_end_matches('/').parse().map_err(|_| {
        bad(format!(
            "`{host}` is not an IP address (a device's, 169.254.255.255, or 127.0.0.1 for an emulator)"
        ))
    })?;
    let (mut dev, mut group, mut channel) = (None, 0u16, None);
    for pair in query.split('&').filter(|p| !p.is_empty()) {
        let (k, v) = pair.split_once('=').unwrap_or((pair, ""));
        match k {
            "dev" => {
                dev = Some(
                    v.parse::<u16>()
                        .ok()
                        .filter(|d| (1..=254).contains(d))
                        .ok_or_else(|| bad(format!("dev={v}: a device id is 1..254")))?,
                );
            }
            "group" => {
                group = v
                    .parse::<u16>()
                    .ok()
                    .filter(|g| *g <= 10)
                    .ok_or_else(|| bad(format!("group={v}: a group is 0..10")))?;
            }
            "channel" if kind == SensapexKind::Pressure => {
                channel = Some(
                    v.parse::<u8>()
                        .ok()
                        .filter(|c| (1..=8).contains(c))
                        .ok_or_else(|| bad(format!("channel={v}: a channel is 1..8")))?,
                );
            }
            other => {
                return Err(bad(format!(
                    "unknown parameter `{other}` (dev, group{})",
                    if kind == SensapexKind::Pressure {
                        ", channel"
                    } else {
                        ""
                    }
                )));
            }
        }
    }
    let dev = dev.ok_or_else(|| bad("needs the device id: ?dev=N".into()))?;
    if kind == SensapexKind::Pressure && channel.is_none() {
        return Err(bad("needs the pressure channel: &channel=C (1..8)".into()));
    }
    Ok(Some(SensapexDevice {
        kind,
        address,
        group,
        dev,
        channel,
        origin: Vec::new(),
        speed: DEFAULT_SENSAPEX_SPEED,
        lenses: Vec::new(),
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    const GCS: &str = r#"
name = "bench 2"
[piezo]
driver = "gcs://127.0.0.1:50000"
axes = ["A", "B", "C"]
[camera.top]
driver = "bench://127.0.0.1:50001"
[camera.side]
driver = "dir:frames"
fps = 12.5
[stage.macro]
driver = "bench://127.0.0.1:50001"
[stage.feeder]
driver = "bench://127.0.0.1:50001"
[injector]
driver = "bench://127.0.0.1:50001"
[optics]
driver = "bench://127.0.0.1:50001"
"#;

    fn key_of(text: &str) -> String {
        parse(text)
            .expect_err("refused")
            .key()
            .expect("names a key")
            .to_string()
    }

    #[test]
    fn the_twin_alone_is_a_whole_bench() {
        let r = parse("[piezo]\ndriver = \"twin\"\n").expect("the twin");
        assert_eq!(r, RigFile::twin());
        assert_eq!(r.backend(), "twin");
    }

    #[test]
    fn a_gcs_bench_names_every_device() {
        let r = parse(GCS).expect("valid");
        assert_eq!(r.name.as_deref(), Some("bench 2"));
        assert_eq!(
            r.piezo,
            PiezoDriver::Gcs {
                url: "gcs://127.0.0.1:50000".into(),
                axes: ["A".into(), "B".into(), "C".into()],
            }
        );
        assert_eq!(r.backend(), "gcs://127.0.0.1:50000");
        assert_eq!(r.camera_top, CameraDriver::Bench("127.0.0.1:50001".into()));
        assert_eq!(
            r.camera_side,
            CameraDriver::Dir {
                path: "frames".into(),
                fps: 12.5
            }
        );
        assert_eq!(r.optics, DeviceDriver::Bench("127.0.0.1:50001".into()));
    }

    /// Sensapex devices for the stages and the injector: addresses, ids, groups,
    /// channels and the stages' origin and speed; each fault names its key and says
    /// what fits.
    #[test]
    fn sensapex_devices_parse_and_their_faults_name_the_key() {
        let bench = GCS
            .replace(
                "[stage.macro]\ndriver = \"bench://127.0.0.1:50001\"",
                "[stage.macro]\ndriver = \"sensapex://127.0.0.1?dev=1\"\norigin = [0.01, 0.01, 0.005]\nspeed = 0.002",
            )
            .replace(
                "[stage.feeder]\ndriver = \"bench://127.0.0.1:50001\"",
                "[stage.feeder]\ndriver = \"sensapex-ums://169.254.255.255?dev=21&group=3\"",
            )
            .replace(
                "[injector]\ndriver = \"bench://127.0.0.1:50001\"",
                "[injector]\ndriver = \"sensapex-pressure://127.0.0.1?dev=31&channel=2\"",
            );
        let r = parse(&bench).expect("valid");
        let DeviceDriver::Sensapex(m) = &r.stage_macro else {
            panic!("{:?}", r.stage_macro)
        };
        assert_eq!(
            (m.kind, m.dev, m.group, m.channel),
            (SensapexKind::Manipulator, 1, 0, None)
        );
        assert_eq!(
            (m.origin.clone(), m.speed),
            (vec![0.01, 0.01, 0.005], 0.002)
        );
        assert_eq!(m.url(), "sensapex://127.0.0.1?dev=1");
        let DeviceDriver::Sensapex(f) = &r.stage_feeder else {
            panic!()
        };
        assert_eq!(
            (f.kind, f.group, f.speed),
            (SensapexKind::Stage, 3, DEFAULT_SENSAPEX_SPEED)
        );
        assert_eq!(f.url(), "sensapex-ums://169.254.255.255?dev=21&group=3");
        let DeviceDriver::Sensapex(i) = &r.injector else {
            panic!()
        };
        assert_eq!(
            (i.kind, i.dev, i.channel),
            (SensapexKind::Pressure, 31, Some(2))
        );
        // A uMs's lens changer as the objectives.
        let lens = bench.replace(
            "[optics]\ndriver = \"bench://127.0.0.1:50001\"",
            "[optics]\ndriver = \"sensapex-ums://127.0.0.1?dev=21\"\nlenses = [4, 10]",
        );
        let DeviceDriver::Sensapex(o) = parse(&lens).expect("valid").optics else {
            panic!("{lens}")
        };
        assert_eq!(
            (o.kind, o.dev, o.lenses),
            (SensapexKind::Stage, 21, vec![4.0, 10.0])
        );
        let with = |from: &str, to: &str| {
            let t = bench.replace(from, to);
            assert_ne!(t, bench, "{from}");
            parse(&t).expect_err(to).to_string()
        };
        for (from, to, says) in [
            (
                "sensapex://127.0.0.1?dev=1",
                "sensapex://127.0.0.1",
                "?dev=N",
            ),
            (
                "sensapex://127.0.0.1?dev=1",
                "sensapex://localhost?dev=1",
                "not an IP address",
            ),
            (
                "sensapex://127.0.0.1?dev=1",
                "sensapex://127.0.0.1?dev=300",
                "1..254",
            ),
            (
                "sensapex://127.0.0.1?dev=1",
                "sensapex://127.0.0.1?dev=1&group=11",
                "0..10",
            ),
            (
                "sensapex://127.0.0.1?dev=1",
                "sensapex://127.0.0.1?dev=1&channel=1",
                "unknown parameter `channel`",
            ),
            (
                "sensapex://127.0.0.1?dev=1",
                "sensapex-pressure://127.0.0.1?dev=1&channel=1",
                "not a device for [stage.macro]",
            ),
            ("channel=2", "channel=9", "1..8"),
            ("&channel=2", "", "&channel=C"),
            (
                "sensapex-pressure://127.0.0.1?dev=31&channel=2",
                "sensapex://127.0.0.1?dev=31",
                "not a device for [injector]",
            ),
            ("speed = 0.002", "speed = -1", "(0, 0.01] m/s"),
            (
                "origin = [0.01, 0.01, 0.005]",
                "origin = [0.01]",
                "stage.macro.origin",
            ),
            (
                "[injector]\ndriver = \"sensapex-pressure://127.0.0.1?dev=31&channel=2\"",
                "[injector]\ndriver = \"sensapex-pressure://127.0.0.1?dev=31&channel=2\"\nspeed = 1e-3",
                "injector.speed",
            ),
            (
                "[optics]\ndriver = \"bench://127.0.0.1:50001\"",
                "[optics]\ndriver = \"sensapex://127.0.0.1?dev=1\"",
                "not a device for [optics]",
            ),
            (
                "[optics]\ndriver = \"bench://127.0.0.1:50001\"",
                "[optics]\ndriver = \"sensapex-ums://127.0.0.1?dev=21\"",
                "optics.lenses",
            ),
            (
                "[optics]\ndriver = \"bench://127.0.0.1:50001\"",
                "[optics]\ndriver = \"sensapex-ums://127.0.0.1?dev=21\"\nlenses = [2.5, nan]",
                "(0, 1000], got NaN",
            ),
            (
                "[optics]\ndriver = \"bench://127.0.0.1:50001\"",
                "[optics]\ndriver = \"sensapex-ums://127.0.0.1?dev=21\"\nlenses = [2.5]",
                "optics.lenses",
            ),
        ] {
            let e = with(from, to);
            assert!(e.contains(says), "{to}: {e}");
        }
    }

    #[test]
    fn each_fault_names_its_dotted_key() {
        // A missing device of a real bench.
        let no_optics = GCS.replace("[optics]\ndriver = \"bench://127.0.0.1:50001\"\n", "");
        assert_eq!(key_of(&no_optics), "optics.driver");
        // An unknown driver.
        assert_eq!(
            key_of(&GCS.replace("dir:frames", "usb:3")),
            "camera.side.driver"
        );
        // An unknown section, and an unknown key in a section.
        assert_eq!(key_of(&format!("{GCS}[laser]\ndriver = \"x\"\n")), "laser");
        assert_eq!(
            key_of(&GCS.replace("fps = 12.5", "fps = 12.5\nexposure = 1")),
            "camera.side.exposure"
        );
        assert_eq!(
            key_of(&format!("{GCS}[camera.front]\ndriver = \"twin\"\n")),
            "camera.front"
        );
        // A device of the wrong kind: a camera's driver for a stage, the twin's
        // device on a real bench, a real device on the twin.
        assert_eq!(
            key_of(&GCS.replacen(
                "[stage.macro]\ndriver = \"bench://127.0.0.1:50001\"",
                "[stage.macro]\ndriver = \"aravis:cam1\"",
                1
            )),
            "stage.macro.driver"
        );
        assert_eq!(
            key_of(&GCS.replace(
                "[injector]\ndriver = \"bench://127.0.0.1:50001\"",
                "[injector]\ndriver = \"twin\""
            )),
            "injector.driver"
        );
        assert_eq!(
            key_of("[piezo]\ndriver = \"twin\"\n[camera.top]\ndriver = \"aravis:x\"\n"),
            "camera.top.driver"
        );
        // Bad forms and values.
        assert_eq!(
            key_of("[piezo]\ndriver = \"serial:/dev/tty0\"\n"),
            "piezo.driver"
        );
        assert_eq!(key_of("[piezo]\ndriver = 3\n"), "piezo.driver");
        assert_eq!(key_of("[piezo]\n"), "piezo.driver");
        assert_eq!(key_of("name = \"x\"\n"), "piezo");
        assert_eq!(key_of(&GCS.replace("12.5", "nan")), "camera.side.fps");
        assert_eq!(key_of(&GCS.replace("12.5", "-1")), "camera.side.fps");
        assert_eq!(
            key_of(&GCS.replace(
                "driver = \"bench://127.0.0.1:50001\"\n[camera.side]",
                "driver = \"bench://127.0.0.1:50001\"\nfps = 3\n[camera.side]"
            )),
            "camera.top.fps"
        );
        assert_eq!(
            key_of(&GCS.replacen("bench://127.0.0.1:50001", "bench://127.0.0.1:0", 1)),
            "camera.top.driver"
        );
        assert_eq!(
            key_of(&GCS.replace("\"A\", \"B\", \"C\"", "\"A\", \"A\", \"C\"")),
            "piezo.axes"
        );
        assert_eq!(
            key_of(&GCS.replace("\"A\", \"B\", \"C\"", "\"A\", \"B\"")),
            "piezo.axes"
        );
        assert_eq!(
            key_of("[piezo]\ndriver = \"twin\"\naxes = [\"1\", \"2\", \"3\"]\n"),
            "piezo.axes"
        );
    }

    #[test]
    fn bad_toml_says_where() {
        let e = parse("[piezo\n").expect_err("not TOML");
        assert!(matches!(e, ConfigError::Syntax { .. }), "{e}");
    }
}
