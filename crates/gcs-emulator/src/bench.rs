//! The bench endpoint: the rest of an emulated bench (the twin's two cameras, macro
//! stage, injector and zoom, and the emulator's clock) for a client process, over
//! TCP. One JSON request per line, one JSON reply per line: `{"ok": VALUE}` or
//! `{"error": "message"}`; a frame's reply is followed by its pixels (little-endian
//! `u16`, row-major, `bytes` of them). [`Bench`] is the client, with one handle per
//! device behind cellinject's hardware traits.
//!
//! Requests (`op` and its fields):
//! `camera_info {view}`, `camera_configure {view, roi: [x, y, w, h], binning, exposure,
//! bit_depth}`, `grab {view}` (waits for the next frame in wall-clock time),
//! `stage_move {axis, position}`, `stage_position {axis}`, `stage_busy`,
//! `stage_travel {axis}`, `pulse {pressure, duration}` (returns when the pulse ended),
//! `max_pressure`, `zoom`, `set_zoom {zoom}`, `zoom_range`, `time` (s, the emulator's
//! clock). `view` is `top` or `side`. SI units throughout.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use cellinject_hw::{
    Camera, CameraSettings, Clock, Frame, HwError, Injector, Optics, Roi, Stage, check_range,
};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

/// Which camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ViewName {
    /// The microscope (top view).
    Top,
    /// The side camera.
    Side,
}

/// Which of the bench's stages a stage request addresses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StageUnit {
    /// The macro stage carrying the micromanipulator (x, y, z); the default, so
    /// requests without a `unit` keep their meaning.
    #[default]
    Macro,
    /// The feeder stage carrying the plate (plate x, y, height).
    Feeder,
}

impl StageUnit {
    fn name(self) -> &'static str {
        match self {
            StageUnit::Macro => "stage",
            StageUnit::Feeder => "feeder stage",
        }
    }
}

/// One request of the bench protocol.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case", deny_unknown_fields)]
pub enum Request {
    /// Sensor size, settings and frame rate.
    CameraInfo {
        /// Camera.
        view: ViewName,
    },
    /// New acquisition settings.
    CameraConfigure {
        /// Camera.
        view: ViewName,
        /// x, y, width, height in sensor pixels.
        roi: [u32; 4],
        /// Binning factor.
        binning: u32,
        /// s.
        exposure: f64,
        /// 8 or 12.
        bit_depth: u8,
    },
    /// The next frame.
    Grab {
        /// Camera.
        view: ViewName,
    },
    /// Starts a stage move.
    StageMove {
        /// Which stage (default: the macro stage).
        #[serde(default)]
        unit: StageUnit,
        /// Axis 0..3.
        axis: usize,
        /// m.
        position: f64,
    },
    /// An axis's encoder, m.
    StagePosition {
        /// Which stage (default: the macro stage).
        #[serde(default)]
        unit: StageUnit,
        /// Axis.
        axis: usize,
    },
    /// Whether the stage moves.
    StageBusy {
        /// Which stage (default: the macro stage).
        #[serde(default)]
        unit: StageUnit,
    },
    /// An axis's travel, m.
    StageTravel {
        /// Which stage (default: the macro stage).
        #[serde(default)]
        unit: StageUnit,
        /// Axis.
        axis: usize,
    },
    /// The number of axes of a stage.
    StageAxes {
        /// Which stage.
        #[serde(default)]
        unit: StageUnit,
    },
    /// A pressure pulse.
    Pulse {
        /// Pa.
        pressure: f64,
        /// s.
        duration: f64,
    },
    /// The injector's limit, Pa.
    MaxPressure,
    /// The magnification.
    Zoom,
    /// Sets the magnification.
    SetZoom {
        /// Magnification.
        zoom: f64,
    },
    /// The zoom range.
    ZoomRange,
    /// The emulator's clock, s.
    Time,
}

/// The header of a frame reply.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FrameHeader {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// 8 or 12.
    pub bit_depth: u8,
    /// s, start of exposure on the emulator's clock.
    pub timestamp: f64,
    /// s.
    pub exposure: f64,
    /// m.
    pub pixel_size: f64,
    /// Frame counter.
    pub index: u64,
    /// Bytes of pixels that follow.
    pub bytes: usize,
}

struct Conn {
    reader: BufReader<TcpStream>,
    writer: TcpStream,
    address: String,
    timeout: Duration,
}

/// A connection to an emulator's bench endpoint.
#[derive(Clone)]
pub struct Bench {
    conn: Arc<Mutex<Conn>>,
}

fn device(address: &str, message: impl std::fmt::Display) -> HwError {
    HwError::Device {
        device: format!("bench {address}"),
        message: message.to_string(),
    }
}

impl Bench {
    /// Connects to `address` (`host:port`); every reply must come within `timeout`
    /// (frames and pulses add their own duration).
    pub fn connect(address: &str, timeout: Duration) -> Result<Self, HwError> {
        let s = TcpStream::connect(address)
            .map_err(|e| device(address, format!("cannot connect: {e}")))?;
        s.set_nodelay(true).map_err(|e| device(address, e))?;
        s.set_read_timeout(Some(timeout))
            .map_err(|e| device(address, e))?;
        let writer = s.try_clone().map_err(|e| device(address, e))?;
        Ok(Bench {
            conn: Arc::new(Mutex::new(Conn {
                reader: BufReader::new(s),
                writer,
                address: address.to_string(),
                timeout,
            })),
        })
    }

    fn lock(&self) -> MutexGuard<'_, Conn> {
        self.conn.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Sends `req` and returns its `ok` value.
    pub fn request(&self, req: &Request) -> Result<Value, HwError> {
        let mut c = self.lock();
        Self::exchange(&mut c, req)
    }

    fn exchange(c: &mut Conn, req: &Request) -> Result<Value, HwError> {
        let mut line = serde_json::to_string(req).map_err(|e| device(&c.address, e))?;
        line.push('\n');
        c.writer
            .write_all(line.as_bytes())
            .map_err(|e| device(&c.address, format!("lost: {e}")))?;
        let mut answer = String::new();
        match c.reader.read_line(&mut answer) {
            Ok(0) => return Err(device(&c.address, "the emulator closed the connection")),
            Ok(_) => {}
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                return Err(HwError::Timeout {
                    device: format!("bench {}", c.address),
                    seconds: c.timeout.as_secs_f64(),
                });
            }
            Err(e) => return Err(device(&c.address, e)),
        }
        let v: Value = serde_json::from_str(&answer)
            .map_err(|e| device(&c.address, format!("unreadable reply {answer:?}: {e}")))?;
        if let Some(e) = v.get("error") {
            return Err(device(&c.address, e.as_str().unwrap_or("error")));
        }
        v.get("ok")
            .cloned()
            .ok_or_else(|| device(&c.address, format!("reply without `ok`: {answer:?}")))
    }

    /// The lens's magnification now.
    pub fn zoom(&self) -> Result<f64, HwError> {
        self.number(&Request::Zoom)
    }

    fn number(&self, req: &Request) -> Result<f64, HwError> {
        let v = self.request(req)?;
        v.as_f64()
            .ok_or_else(|| device("", format!("{req:?}: expected a number, got {v}")))
    }

    fn grab(&self, view: ViewName, frame: &mut Frame) -> Result<(), HwError> {
        let mut c = self.lock();
        let v = Self::exchange(&mut c, &Request::Grab { view })?;
        let h: FrameHeader = serde_json::from_value(v)
            .map_err(|e| device(&c.address, format!("frame header: {e}")))?;
        if h.bytes != 2 * (h.width as usize) * (h.height as usize) {
            return Err(device(
                &c.address,
                format!("frame of {}x{} with {} bytes", h.width, h.height, h.bytes),
            ));
        }
        let mut bytes = vec![0u8; h.bytes];
        c.reader
            .read_exact(&mut bytes)
            .map_err(|e| device(&c.address, format!("frame pixels: {e}")))?;
        frame.width = h.width;
        frame.height = h.height;
        frame.bit_depth = h.bit_depth;
        frame.timestamp = h.timestamp;
        frame.exposure = h.exposure;
        frame.pixel_size = h.pixel_size;
        frame.index = h.index;
        frame.pixels.clear();
        frame.pixels.extend(
            bytes
                .chunks_exact(2)
                .map(|b| u16::from_le_bytes([b[0], b[1]])),
        );
        Ok(())
    }

    /// A camera.
    pub fn camera(&self, view: ViewName) -> Result<BenchCamera, HwError> {
        let mut c = BenchCamera {
            bench: self.clone(),
            view,
            sensor: (0, 0),
            settings: CameraSettings {
                roi: Roi {
                    x: 0,
                    y: 0,
                    width: 0,
                    height: 0,
                },
                binning: 1,
                exposure: 0.0,
                bit_depth: 8,
            },
            rate: 0.0,
        };
        c.refresh()?;
        Ok(c)
    }

    /// The macro stage.
    pub fn stage(&self) -> Result<BenchStage, HwError> {
        self.stage_unit(StageUnit::Macro)
    }

    /// The feeder stage.
    pub fn feeder(&self) -> Result<BenchStage, HwError> {
        self.stage_unit(StageUnit::Feeder)
    }

    fn stage_unit(&self, unit: StageUnit) -> Result<BenchStage, HwError> {
        let axes = self.number(&Request::StageAxes { unit })?;
        let travel = (0..axes as usize)
            .map(|axis| {
                let v = self.request(&Request::StageTravel { unit, axis })?;
                serde_json::from_value::<[f64; 2]>(v)
                    .map(|t| (t[0], t[1]))
                    .map_err(|e| device(unit.name(), e))
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(BenchStage {
            bench: self.clone(),
            unit,
            travel,
        })
    }

    /// The injector.
    pub fn injector(&self) -> Result<BenchInjector, HwError> {
        Ok(BenchInjector {
            bench: self.clone(),
            max: self.number(&Request::MaxPressure)?,
        })
    }

    /// The zoom lens.
    pub fn optics(&self) -> Result<BenchOptics, HwError> {
        let range: [f64; 2] = serde_json::from_value(self.request(&Request::ZoomRange)?)
            .map_err(|e| device("zoom", e))?;
        Ok(BenchOptics {
            bench: self.clone(),
            zoom: self.number(&Request::Zoom)?,
            range: (range[0], range[1]),
        })
    }

    /// A wall clock reading the emulator's time.
    pub fn clock(&self) -> Result<WallClock, HwError> {
        let t = self.number(&Request::Time)?;
        Ok(WallClock {
            origin: t,
            start: Instant::now(),
        })
    }
}

/// A camera of the emulated bench.
pub struct BenchCamera {
    bench: Bench,
    view: ViewName,
    sensor: (u32, u32),
    settings: CameraSettings,
    rate: f64,
}

impl BenchCamera {
    fn refresh(&mut self) -> Result<(), HwError> {
        let v = self
            .bench
            .request(&Request::CameraInfo { view: self.view })?;
        let get = |k: &str| v.get(k).cloned().unwrap_or(Value::Null);
        let bad = |e| device("camera", e);
        let sensor: [u32; 2] = serde_json::from_value(get("sensor")).map_err(bad)?;
        let roi: [u32; 4] = serde_json::from_value(get("roi")).map_err(bad)?;
        self.sensor = (sensor[0], sensor[1]);
        self.settings = CameraSettings {
            roi: Roi {
                x: roi[0],
                y: roi[1],
                width: roi[2],
                height: roi[3],
            },
            binning: serde_json::from_value(get("binning")).map_err(bad)?,
            exposure: serde_json::from_value(get("exposure")).map_err(bad)?,
            bit_depth: serde_json::from_value(get("bit_depth")).map_err(bad)?,
        };
        self.rate = serde_json::from_value(get("frame_rate")).map_err(bad)?;
        Ok(())
    }
}

impl Camera for BenchCamera {
    fn sensor_size(&self) -> (u32, u32) {
        self.sensor
    }
    fn settings(&self) -> CameraSettings {
        self.settings
    }
    fn configure(&mut self, s: CameraSettings) -> Result<(), HwError> {
        self.bench.request(&Request::CameraConfigure {
            view: self.view,
            roi: [s.roi.x, s.roi.y, s.roi.width, s.roi.height],
            binning: s.binning,
            exposure: s.exposure,
            bit_depth: s.bit_depth,
        })?;
        self.refresh()
    }
    fn frame_rate(&self) -> f64 {
        self.rate
    }
    fn grab_into(&mut self, frame: &mut Frame) -> Result<(), HwError> {
        self.bench.grab(self.view, frame)
    }
}

/// One of the emulated bench's stages (the macro stage or the feeder stage).
pub struct BenchStage {
    bench: Bench,
    unit: StageUnit,
    travel: Vec<(f64, f64)>,
}

impl Stage for BenchStage {
    fn axes(&self) -> usize {
        self.travel.len()
    }
    fn travel(&self, axis: usize) -> (f64, f64) {
        self.travel.get(axis).copied().unwrap_or((0.0, 0.0))
    }
    fn move_to(&mut self, axis: usize, position: f64) -> Result<(), HwError> {
        let (lo, hi) = self.travel(axis);
        check_range("stage position", position, lo, hi)?;
        let unit = self.unit;
        self.bench
            .request(&Request::StageMove {
                unit,
                axis,
                position,
            })
            .map(|_| ())
    }
    fn position(&mut self, axis: usize) -> Result<f64, HwError> {
        let unit = self.unit;
        self.bench.number(&Request::StagePosition { unit, axis })
    }
    fn is_busy(&mut self) -> Result<bool, HwError> {
        let unit = self.unit;
        let v = self.bench.request(&Request::StageBusy { unit })?;
        v.as_bool()
            .ok_or_else(|| device(unit.name(), format!("busy: expected a boolean, got {v}")))
    }
}

/// The emulated bench's injector.
pub struct BenchInjector {
    bench: Bench,
    max: f64,
}

impl Injector for BenchInjector {
    fn max_pressure(&self) -> f64 {
        self.max
    }
    fn pulse(&mut self, pressure: f64, duration: f64) -> Result<(), HwError> {
        check_range("pressure", pressure, 0.0, self.max)?;
        check_range("pulse duration", duration, 0.0, 10.0)?;
        self.bench
            .request(&Request::Pulse { pressure, duration })
            .map(|_| ())
    }
}

/// The emulated bench's zoom lens.
pub struct BenchOptics {
    bench: Bench,
    zoom: f64,
    range: (f64, f64),
}

impl Optics for BenchOptics {
    fn zoom(&self) -> f64 {
        self.zoom
    }
    fn zoom_range(&self) -> (f64, f64) {
        self.range
    }
    fn set_zoom(&mut self, zoom: f64) -> Result<(), HwError> {
        check_range("zoom", zoom, self.range.0, self.range.1)?;
        self.bench.request(&Request::SetZoom { zoom })?;
        self.zoom = zoom;
        Ok(())
    }
}

/// Wall-clock time on the emulator's time base (read once at connection).
pub struct WallClock {
    origin: f64,
    start: Instant,
}

impl WallClock {
    /// A wall clock starting at 0 now (for real benches).
    pub fn new() -> Self {
        WallClock {
            origin: 0.0,
            start: Instant::now(),
        }
    }
}

impl Default for WallClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for WallClock {
    fn now(&self) -> f64 {
        self.origin + self.start.elapsed().as_secs_f64()
    }
    fn sleep(&mut self, seconds: f64) -> Result<(), HwError> {
        check_range("sleep", seconds, 0.0, 1.0e6)?;
        std::thread::sleep(Duration::from_secs_f64(seconds));
        Ok(())
    }
}

/// `{"ok": v}`.
pub(crate) fn ok(v: Value) -> String {
    let mut s = json!({ "ok": v }).to_string();
    s.push('\n');
    s
}

/// `{"error": message}`.
pub(crate) fn error(message: impl std::fmt::Display) -> String {
    let mut s = json!({ "error": message.to_string() }).to_string();
    s.push('\n');
    s
}
