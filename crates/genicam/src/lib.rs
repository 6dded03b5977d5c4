//! # cellinject-genicam
//!
//! GenICam cameras (GigE Vision, USB3 Vision) for real benches, through the Aravis
//! library. The part that talks to Aravis is the `aravis` cargo feature (module
//! [`device`]): it needs the system library (Debian: `libaravis-dev`), so the default
//! build of the workspace does not compile it. The rest is pure and always built:
//! camera ids (`aravis:ID`), the requested settings and their validation against a
//! camera's limits ([`Request`], [`Limits`]), the unpacking of Mono8, Mono12 and Mono16
//! payloads into a [`Frame`](cellinject_hw::Frame)'s pixels ([`unpack`]) and the file
//! names of a grabbed series ([`frame_path`]).
//!
//! **Architecture invariant:** only [`device`] calls Aravis; nothing here writes files
//! (the binary and the cameras crate save frames).

#[cfg(feature = "aravis")]
pub mod device;
#[cfg(feature = "aravis")]
pub mod simulator;

use std::path::{Path, PathBuf};

use cellinject_hw::{Camera, CameraSettings, Clock, Frame, HwError};

/// What can go wrong with a GenICam camera.
#[derive(Debug, thiserror::Error)]
pub enum GenicamError {
    /// A requested setting or argument that cannot be used (a user error).
    #[error("{argument}: {message}")]
    Invalid {
        /// The argument or setting (`--roi`, `--exposure`, ...).
        argument: &'static str,
        /// What is wrong with it.
        message: String,
    },
    /// No camera answered to the id within the time allowed.
    #[error("no GenICam camera `{id}` answered within {seconds:.0} s (tried: {tried})")]
    NotFound {
        /// The id asked for.
        id: String,
        /// How long the search lasted, s.
        seconds: f64,
        /// What was tried, and the cameras that were seen.
        tried: String,
    },
    /// The camera refused a request or stopped answering.
    #[error("camera `{id}`: {message}")]
    Device {
        /// The camera's id.
        id: String,
        /// What happened.
        message: String,
    },
}

/// The prefix of a GenICam camera's id on the command line (`aravis:ID`).
pub const SCHEME: &str = "aravis:";

/// The Aravis id in `aravis:ID`, or `None` when `spec` is not of that form (a folder
/// then). An empty id is an error.
pub fn parse_id(spec: &str) -> Result<Option<&str>, GenicamError> {
    match spec.strip_prefix(SCHEME) {
        None => Ok(None),
        Some("") => Err(GenicamError::Invalid {
            argument: "--camera",
            message: "`aravis:` needs a camera id after it (an id from `cellinject camera list`, a serial number or an IP address)".into(),
        }),
        Some(id) => Ok(Some(id)),
    }
}

/// The monochrome pixel formats the bench reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelFormat {
    /// 8 bits per pixel.
    Mono8,
    /// 12 significant bits in 16-bit little-endian containers (unpacked).
    Mono12,
    /// 16 bits per pixel, little-endian.
    Mono16,
}

impl PixelFormat {
    /// Every format, in the order `--pixel-format` lists them.
    pub const ALL: [PixelFormat; 3] =
        [PixelFormat::Mono8, PixelFormat::Mono12, PixelFormat::Mono16];

    /// The GenICam (PFNC) name.
    pub fn name(self) -> &'static str {
        match self {
            PixelFormat::Mono8 => "Mono8",
            PixelFormat::Mono12 => "Mono12",
            PixelFormat::Mono16 => "Mono16",
        }
    }

    /// Significant bits of a pixel value.
    pub fn bit_depth(self) -> u8 {
        match self {
            PixelFormat::Mono8 => 8,
            PixelFormat::Mono12 => 12,
            PixelFormat::Mono16 => 16,
        }
    }

    /// Bytes of payload per pixel.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Mono8 => 1,
            PixelFormat::Mono12 | PixelFormat::Mono16 => 2,
        }
    }

    /// The format of a GenICam name, case-insensitively (`mono8`, `Mono12`, ...).
    pub fn from_name(name: &str) -> Option<PixelFormat> {
        PixelFormat::ALL
            .into_iter()
            .find(|f| f.name().eq_ignore_ascii_case(name))
    }

    /// Parses `--pixel-format`.
    pub fn parse(s: &str) -> Result<PixelFormat, GenicamError> {
        PixelFormat::from_name(s).ok_or_else(|| GenicamError::Invalid {
            argument: "--pixel-format",
            message: format!("unknown pixel format `{s}`: use mono8, mono12 or mono16"),
        })
    }
}

/// A region of interest on the sensor, in sensor pixels after binning.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Region {
    /// First column.
    pub x: u32,
    /// First row.
    pub y: u32,
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
}

impl Region {
    /// Parses `X,Y,W,H` (whole pixels; width and height at least 1).
    pub fn parse(s: &str) -> Result<Region, GenicamError> {
        let bad = |m: String| GenicamError::Invalid {
            argument: "--roi",
            message: m,
        };
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        if parts.len() != 4 {
            return Err(bad(format!(
                "`{s}`: expected X,Y,W,H (four whole numbers of pixels, e.g. 0,0,512,512)"
            )));
        }
        let mut v = [0u32; 4];
        for (k, p) in parts.iter().enumerate() {
            v[k] = p.parse().map_err(|_| {
                bad(format!(
                    "`{p}` in `{s}` is not a whole number of pixels (X,Y,W,H, none negative)"
                ))
            })?;
        }
        if v[2] == 0 || v[3] == 0 {
            return Err(bad(format!(
                "`{s}`: width and height must be at least 1 pixel"
            )));
        }
        Ok(Region {
            x: v[0],
            y: v[1],
            width: v[2],
            height: v[3],
        })
    }
}

/// Settings to apply to a camera; `None` leaves the camera's current value.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Request {
    /// Exposure time, s.
    pub exposure: Option<f64>,
    /// Gain, dB.
    pub gain: Option<f64>,
    /// Region of interest.
    pub roi: Option<Region>,
    /// Binning, the same in x and y.
    pub binning: Option<u32>,
    /// Pixel format.
    pub pixel_format: Option<PixelFormat>,
    /// Acquisition frame rate, frames/s (GenICam `AcquisitionFrameRate`).
    pub frame_rate: Option<f64>,
}

/// What a camera accepts, read from its GenICam features.
#[derive(Debug, Clone, PartialEq)]
pub struct Limits {
    /// Sensor size (columns, rows).
    pub sensor: (u32, u32),
    /// Exposure time bounds, s.
    pub exposure: (f64, f64),
    /// Gain bounds, dB (`None` when the camera has no gain).
    pub gain: Option<(f64, f64)>,
    /// Width bounds and increment, pixels.
    pub width: (u32, u32, u32),
    /// Height bounds and increment, pixels.
    pub height: (u32, u32, u32),
    /// Binning bounds (`None` when the camera cannot bin).
    pub binning: Option<(u32, u32)>,
    /// The pixel formats the camera offers, by GenICam name.
    pub pixel_formats: Vec<String>,
    /// Frame rate bounds, frames/s (`None` when the camera's rate cannot be set).
    pub frame_rate: Option<(f64, f64)>,
}

impl Request {
    /// Checks every setting against the camera's limits before anything is sent, so a
    /// bad request changes nothing. `binning_now` is the camera's current binning (the
    /// region is in binned pixels).
    pub fn validate(&self, limits: &Limits, binning_now: u32) -> Result<(), GenicamError> {
        let bad =
            |argument: &'static str, message: String| GenicamError::Invalid { argument, message };
        if let Some(e) = self.exposure {
            let (lo, hi) = limits.exposure;
            if !e.is_finite() || e <= 0.0 {
                return Err(bad(
                    "--exposure",
                    format!("{e} s: an exposure time is a positive number of seconds"),
                ));
            }
            if e < lo || e > hi {
                return Err(bad(
                    "--exposure",
                    format!("{e} s is outside the camera's range [{lo}, {hi}] s"),
                ));
            }
        }
        if let Some(g) = self.gain {
            if !g.is_finite() {
                return Err(bad("--gain", format!("{g} dB is not a number")));
            }
            match limits.gain {
                None => return Err(bad("--gain", "the camera has no gain feature".into())),
                Some((lo, hi)) if g < lo || g > hi => {
                    return Err(bad(
                        "--gain",
                        format!("{g} dB is outside the camera's range [{lo}, {hi}] dB"),
                    ));
                }
                _ => {}
            }
        }
        if let Some(f) = self.frame_rate {
            if !f.is_finite() || f <= 0.0 {
                return Err(bad(
                    "--frame-rate",
                    format!("{f}: a frame rate is a positive number of frames/s"),
                ));
            }
            match limits.frame_rate {
                None => {
                    return Err(bad(
                        "--frame-rate",
                        "the camera's frame rate cannot be set".into(),
                    ));
                }
                Some((lo, hi)) if f < lo || f > hi => {
                    return Err(bad(
                        "--frame-rate",
                        format!("{f} frames/s is outside the camera's range [{lo}, {hi}]"),
                    ));
                }
                _ => {}
            }
        }
        let binning = self.binning.unwrap_or(binning_now).max(1);
        if let Some(b) = self.binning {
            match limits.binning {
                None if b != 1 => {
                    return Err(bad("--binning", format!("{b}: the camera cannot bin")));
                }
                Some((lo, hi)) if b < lo || b > hi => {
                    return Err(bad(
                        "--binning",
                        format!("{b} is outside the camera's range [{lo}, {hi}]"),
                    ));
                }
                _ if b == 0 => return Err(bad("--binning", "0: binning is at least 1".into())),
                _ => {}
            }
        }
        if let Some(r) = self.roi {
            let (sw, sh) = (limits.sensor.0 / binning, limits.sensor.1 / binning);
            let (x_end, y_end) = (
                u64::from(r.x) + u64::from(r.width),
                u64::from(r.y) + u64::from(r.height),
            );
            if x_end > u64::from(sw) || y_end > u64::from(sh) {
                return Err(bad(
                    "--roi",
                    format!(
                        "{},{},{},{} reaches column {x_end} and row {y_end}, outside the {sw}x{sh} sensor{}",
                        r.x,
                        r.y,
                        r.width,
                        r.height,
                        if binning > 1 {
                            format!(" (binned {binning}x{binning})")
                        } else {
                            String::new()
                        }
                    ),
                ));
            }
            // (The largest width and height a camera reports follow its current
            // offsets and binning: the sensor's extent above is the bound.)
            let (wlo, _, winc) = limits.width;
            let (hlo, _, hinc) = limits.height;
            if r.width < wlo || r.height < hlo {
                return Err(bad(
                    "--roi",
                    format!(
                        "{}x{} pixels: the camera takes widths from {wlo} and heights from {hlo}",
                        r.width, r.height
                    ),
                ));
            }
            if r.width % winc.max(1) != 0 || r.height % hinc.max(1) != 0 {
                return Err(bad(
                    "--roi",
                    format!(
                        "{}x{} pixels: the camera takes widths in steps of {winc} and heights in steps of {hinc}",
                        r.width, r.height
                    ),
                ));
            }
        }
        if let Some(f) = self.pixel_format {
            if !limits.pixel_formats.iter().any(|n| n == f.name()) {
                return Err(bad(
                    "--pixel-format",
                    format!(
                        "{}: the camera offers {}",
                        f.name(),
                        limits.pixel_formats.join(", ")
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// Unpacks one image payload of `width x height` pixels in `format` into `out`
/// (resized, its allocation reused). Each row of the payload may end with
/// `row_padding` bytes. A payload shorter than the image is an error.
pub fn unpack(
    format: PixelFormat,
    data: &[u8],
    width: usize,
    height: usize,
    row_padding: usize,
    out: &mut Vec<u16>,
) -> Result<(), String> {
    let bpp = format.bytes_per_pixel();
    let stride = width * bpp + row_padding;
    let need = stride * height.saturating_sub(1) + width * bpp;
    if height > 0 && data.len() < need {
        return Err(format!(
            "a {width}x{height} {} payload needs {need} bytes, the buffer has {}",
            format.name(),
            data.len()
        ));
    }
    out.clear();
    out.reserve(width * height);
    for row in 0..height {
        let line = &data[row * stride..row * stride + width * bpp];
        match format {
            PixelFormat::Mono8 => out.extend(line.iter().map(|&b| u16::from(b))),
            PixelFormat::Mono12 => out.extend(
                line.chunks_exact(2)
                    .map(|c| u16::from_le_bytes([c[0], c[1]]) & 0x0fff),
            ),
            PixelFormat::Mono16 => out.extend(
                line.chunks_exact(2)
                    .map(|c| u16::from_le_bytes([c[0], c[1]])),
            ),
        }
    }
    Ok(())
}

/// The file of frame `index` of a series of `count` grabbed into `out`: `out` itself
/// for a single frame, else the stem with a three-digit index (`g.tif` → `g_000.tif`,
/// `g_001.tif`, ...; more digits past 999).
pub fn frame_path(out: &Path, index: usize, count: usize) -> PathBuf {
    if count <= 1 {
        return out.to_path_buf();
    }
    let stem = out
        .file_stem()
        .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
    let digits = (count - 1).to_string().len().max(3);
    let name = match out.extension() {
        Some(ext) => format!("{stem}_{index:0digits$}.{}", ext.to_string_lossy()),
        None => format!("{stem}_{index:0digits$}"),
    };
    out.with_file_name(name)
}

/// A camera whose frames are stamped on the bench's clock. A GenICam camera stamps its
/// frames with its own clock (nanoseconds from its power-on, or from the epoch), which
/// the bench cannot compare with its own: the first frame after each (re)configuration
/// fixes the offset between the two, as the bench's time on receipt minus the camera's
/// stamp, and every later frame keeps the camera's own spacing. The mapped times are
/// late by the first frame's latency (exposure, readout, transfer), which only makes
/// the bench wait a little longer for a frame it would block on anyway.
pub struct OnClock<C> {
    camera: C,
    clock: Box<dyn Clock>,
    offset: Option<f64>,
}

impl<C: Camera> OnClock<C> {
    /// `camera`'s frames stamped on `clock`.
    pub fn new(camera: C, clock: Box<dyn Clock>) -> Self {
        OnClock {
            camera,
            clock,
            offset: None,
        }
    }
}

impl<C: Camera> Camera for OnClock<C> {
    fn sensor_size(&self) -> (u32, u32) {
        self.camera.sensor_size()
    }

    fn settings(&self) -> CameraSettings {
        self.camera.settings()
    }

    fn configure(&mut self, settings: CameraSettings) -> Result<(), HwError> {
        self.offset = None;
        self.camera.configure(settings)
    }

    fn frame_rate(&self) -> f64 {
        self.camera.frame_rate()
    }

    fn grab_into(&mut self, frame: &mut Frame) -> Result<(), HwError> {
        self.camera.grab_into(frame)?;
        let now = self.clock.now();
        let offset = *self.offset.get_or_insert(now - frame.timestamp);
        frame.timestamp += offset;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn limits() -> Limits {
        Limits {
            sensor: (2048, 2048),
            exposure: (1e-5, 1.0),
            gain: Some((0.0, 10.0)),
            width: (1, 2048, 1),
            height: (1, 2048, 1),
            binning: Some((1, 16)),
            pixel_formats: vec!["Mono8".into(), "Mono16".into()],
            frame_rate: Some((1.0, 1000.0)),
        }
    }

    struct Stamped(f64);

    impl Camera for Stamped {
        fn sensor_size(&self) -> (u32, u32) {
            (4, 4)
        }
        fn settings(&self) -> CameraSettings {
            CameraSettings {
                roi: cellinject_hw::Roi {
                    x: 0,
                    y: 0,
                    width: 4,
                    height: 4,
                },
                binning: 1,
                exposure: 1e-3,
                bit_depth: 8,
            }
        }
        fn configure(&mut self, _: CameraSettings) -> Result<(), HwError> {
            Ok(())
        }
        fn frame_rate(&self) -> f64 {
            25.0
        }
        fn grab_into(&mut self, frame: &mut Frame) -> Result<(), HwError> {
            // A camera clock far from the bench's, ticking 40 ms per frame.
            self.0 += 0.04;
            frame.timestamp = 1.8e9 + self.0;
            Ok(())
        }
    }

    struct Fixed(std::sync::Arc<std::sync::Mutex<f64>>);
    impl Clock for Fixed {
        fn now(&self) -> f64 {
            *self.0.lock().unwrap()
        }
        fn sleep(&mut self, s: f64) -> Result<(), HwError> {
            *self.0.lock().unwrap() += s;
            Ok(())
        }
    }

    #[test]
    fn frames_are_restamped_on_the_bench_clock_keeping_the_camera_spacing() {
        let now = std::sync::Arc::new(std::sync::Mutex::new(12.5));
        let mut c = OnClock::new(Stamped(0.0), Box::new(Fixed(now.clone())));
        let a = c.grab().unwrap();
        assert!((a.timestamp - 12.5).abs() < 1e-9, "{}", a.timestamp);
        *now.lock().unwrap() = 20.0; // the bench's time on receipt no longer matters
        let b = c.grab().unwrap();
        assert!((b.timestamp - a.timestamp - 0.04).abs() < 1e-6);
        // A new configuration fixes a new offset.
        c.configure(c.settings()).unwrap();
        let d = c.grab().unwrap();
        assert!((d.timestamp - 20.0).abs() < 1e-9);
    }

    #[test]
    fn ids_parse() {
        assert_eq!(parse_id("aravis:Aravis-GV01").unwrap(), Some("Aravis-GV01"));
        assert_eq!(parse_id("aravis:192.168.0.7").unwrap(), Some("192.168.0.7"));
        assert_eq!(parse_id("frames/top").unwrap(), None);
        assert!(
            parse_id("aravis:")
                .unwrap_err()
                .to_string()
                .contains("--camera")
        );
    }

    #[test]
    fn regions_parse_and_are_refused_outside_the_sensor() {
        assert_eq!(
            Region::parse("10, 20,512,256").unwrap(),
            Region {
                x: 10,
                y: 20,
                width: 512,
                height: 256
            }
        );
        for bad in [
            "1,2,3",
            "1,2,3,4,5",
            "-1,0,10,10",
            "0,0,0,10",
            "a,0,1,1",
            "0,0,1.5,1",
        ] {
            let e = Region::parse(bad).unwrap_err().to_string();
            assert!(e.starts_with("--roi"), "{bad}: {e}");
        }
        let r = |s| Request {
            roi: Some(Region::parse(s).unwrap()),
            ..Request::default()
        };
        r("0,0,2048,2048").validate(&limits(), 1).unwrap();
        let e = r("1600,0,512,512")
            .validate(&limits(), 1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("column 2112") && e.contains("2048x2048"), "{e}");
        // Binned 2x2 the sensor is 1024 pixels wide.
        let e = r("0,0,2048,2048")
            .validate(&limits(), 2)
            .unwrap_err()
            .to_string();
        assert!(e.contains("binned 2x2"), "{e}");
        let mut l = limits();
        l.width.2 = 16;
        let e = r("0,0,100,64").validate(&l, 1).unwrap_err().to_string();
        assert!(e.contains("steps of 16"), "{e}");
    }

    #[test]
    fn settings_outside_the_limits_are_refused_by_name() {
        let l = limits();
        for (req, arg) in [
            (
                Request {
                    exposure: Some(-1e-3),
                    ..Request::default()
                },
                "--exposure",
            ),
            (
                Request {
                    exposure: Some(f64::NAN),
                    ..Request::default()
                },
                "--exposure",
            ),
            (
                Request {
                    exposure: Some(2.0),
                    ..Request::default()
                },
                "--exposure",
            ),
            (
                Request {
                    gain: Some(11.0),
                    ..Request::default()
                },
                "--gain",
            ),
            (
                Request {
                    gain: Some(f64::INFINITY),
                    ..Request::default()
                },
                "--gain",
            ),
            (
                Request {
                    binning: Some(32),
                    ..Request::default()
                },
                "--binning",
            ),
            (
                Request {
                    binning: Some(0),
                    ..Request::default()
                },
                "--binning",
            ),
            (
                Request {
                    pixel_format: Some(PixelFormat::Mono12),
                    ..Request::default()
                },
                "--pixel-format",
            ),
            (
                Request {
                    frame_rate: Some(0.0),
                    ..Request::default()
                },
                "--frame-rate",
            ),
            (
                Request {
                    frame_rate: Some(2000.0),
                    ..Request::default()
                },
                "--frame-rate",
            ),
        ] {
            let e = req.validate(&l, 1).unwrap_err().to_string();
            assert!(e.starts_with(arg), "{req:?}: {e}");
        }
        Request {
            exposure: Some(0.01),
            gain: Some(3.0),
            binning: Some(2),
            pixel_format: Some(PixelFormat::Mono16),
            roi: Some(Region::parse("0,0,1024,1024").unwrap()),
            frame_rate: Some(30.0),
        }
        .validate(&l, 1)
        .unwrap();
        // A camera whose rate cannot be set refuses a rate by name.
        let fixed = Limits {
            frame_rate: None,
            ..limits()
        };
        let e = Request {
            frame_rate: Some(30.0),
            ..Request::default()
        }
        .validate(&fixed, 1)
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with("--frame-rate") && e.contains("cannot be set"),
            "{e}"
        );
        assert!(
            PixelFormat::parse("rgb8")
                .unwrap_err()
                .to_string()
                .contains("mono8, mono12 or mono16")
        );
        assert_eq!(PixelFormat::parse("MONO16").unwrap(), PixelFormat::Mono16);
    }

    #[test]
    fn payloads_unpack_with_padding_and_masking() {
        let mut out = vec![7; 100];
        unpack(
            PixelFormat::Mono8,
            &[1, 2, 3, 99, 4, 5, 6],
            3,
            2,
            1,
            &mut out,
        )
        .unwrap();
        assert_eq!(out, [1, 2, 3, 4, 5, 6]);
        // Mono12 unpacked: the four high bits of each container are not image.
        unpack(
            PixelFormat::Mono12,
            &[0xff, 0xff, 0x34, 0x02],
            2,
            1,
            0,
            &mut out,
        )
        .unwrap();
        assert_eq!(out, [0x0fff, 0x0234]);
        unpack(
            PixelFormat::Mono16,
            &[0x34, 0x12, 0xff, 0xff],
            2,
            1,
            0,
            &mut out,
        )
        .unwrap();
        assert_eq!(out, [0x1234, 0xffff]);
        let e = unpack(PixelFormat::Mono16, &[0; 7], 2, 2, 0, &mut out).unwrap_err();
        assert!(e.contains("needs 8 bytes"), "{e}");
    }

    #[test]
    fn series_share_the_stem_with_an_index() {
        let p = Path::new("out/g.tif");
        assert_eq!(frame_path(p, 0, 1), Path::new("out/g.tif"));
        assert_eq!(frame_path(p, 2, 3), Path::new("out/g_002.tif"));
        assert_eq!(frame_path(p, 7, 1200), Path::new("out/g_0007.tif"));
        assert_eq!(frame_path(Path::new("g"), 1, 2), Path::new("g_001"));
    }
}
