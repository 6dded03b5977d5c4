//! `cellinject camera list|info|grab`: GenICam cameras (GigE Vision, USB3 Vision)
//! through Aravis, in a build with the `genicam` feature.

use std::path::PathBuf;

use anyhow::Result;
use cellinject_genicam::{GenicamError, PixelFormat, Region, Request};
use clap::{Args, Subcommand};

use crate::Format;
use crate::InputError;

/// The GenICam cameras.
#[derive(Debug, Subcommand)]
pub enum CameraCommand {
    /// Every camera Aravis sees: id, vendor, model, serial, address, interface.
    #[command(
        after_help = "Examples:\n  cellinject camera list\n  cellinject camera list --format json"
    )]
    List {
        /// Output format.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// One camera: sensor size, pixel formats, exposure and gain ranges, region and binning limits, current settings.
    #[command(
        after_help = "Examples:\n  cellinject camera info --camera aravis:Aravis-GV01\n  cellinject camera info --camera aravis:192.168.0.40 --format json"
    )]
    Info {
        /// The camera: `aravis:ID` (an id from `camera list`, a serial number or an IP address).
        #[arg(long, value_name = "aravis:ID")]
        camera: String,
        /// Seconds to keep trying to reach the camera.
        #[arg(long, default_value_t = 10.0, value_name = "S")]
        timeout: f64,
        /// Output format.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// Grab frames to PNG or TIFF files (several frames share the stem with an index: g_000.tif, g_001.tif, ...).
    #[command(
        after_help = "Examples:\n  cellinject camera grab --camera aravis:Aravis-GV01 --out frame.png\n  cellinject camera grab --camera aravis:Aravis-GV01 --frames 3 --exposure 5e-3 --roi 0,0,512,512 --out g.tif --format json\n\nThe settings stay on the camera after the grab. Exit 1 when the camera cannot be reached or stops answering (the frames written so far stay); 2 for a setting the camera does not take."
    )]
    Grab(GrabArgs),
}

/// `camera grab`.
#[derive(Debug, Args)]
pub struct GrabArgs {
    /// The camera: `aravis:ID` (an id from `camera list`, a serial number or an IP address).
    #[arg(long, value_name = "aravis:ID")]
    camera: String,
    /// Frames to grab.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    frames: u32,
    /// Exposure time, s.
    #[arg(long, value_name = "S")]
    exposure: Option<f64>,
    /// Gain, dB.
    #[arg(long, value_name = "DB")]
    gain: Option<f64>,
    /// Acquisition frame rate, frames/s (the camera's AcquisitionFrameRate).
    #[arg(long, value_name = "HZ")]
    frame_rate: Option<f64>,
    /// Region of interest X,Y,W,H in (binned) pixels; default the camera's current region.
    #[arg(long, value_name = "X,Y,W,H", allow_hyphen_values = true)]
    roi: Option<String>,
    /// Binning (the same in x and y).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=64))]
    binning: Option<u32>,
    /// Pixel format: mono8, mono12 or mono16 (default the camera's current one).
    #[arg(long, value_name = "FORMAT")]
    pixel_format: Option<String>,
    /// Output file (.png or .tif); Mono12 and Mono16 frames are written as 16-bit.
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    /// Seconds to keep trying to reach the camera.
    #[arg(long, default_value_t = 10.0, value_name = "S")]
    timeout: f64,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
}

/// The Aravis id in `--camera aravis:ID`.
fn camera_id(spec: &str) -> Result<&str> {
    match cellinject_genicam::parse_id(spec) {
        Ok(Some(id)) => Ok(id),
        Ok(None) => Err(InputError(format!(
            "--camera `{spec}`: `camera` commands take a GenICam camera as `aravis:ID` (see `cellinject camera list`)"
        ))
        .into()),
        Err(e) => Err(InputError(e.to_string()).into()),
    }
}

fn timeout(s: f64) -> Result<std::time::Duration> {
    if !(s.is_finite() && s > 0.0 && s <= 3600.0) {
        return Err(InputError(format!("--timeout {s}: give seconds in (0, 3600]")).into());
    }
    Ok(std::time::Duration::from_secs_f64(s))
}

/// The request `camera grab` makes, checked for what can be checked without a camera.
fn request(a: &GrabArgs) -> Result<Request> {
    let bad = |e: GenicamError| -> anyhow::Error { InputError(e.to_string()).into() };
    if let Some(e) = a.exposure
        && !(e.is_finite() && e > 0.0)
    {
        return Err(InputError(format!(
            "--exposure {e}: an exposure time is a positive number of seconds"
        ))
        .into());
    }
    if let Some(f) = a.frame_rate
        && !(f.is_finite() && f > 0.0)
    {
        return Err(InputError(format!(
            "--frame-rate {f}: a frame rate is a positive number of frames/s"
        ))
        .into());
    }
    Ok(Request {
        exposure: a.exposure,
        gain: a.gain,
        roi: a
            .roi
            .as_deref()
            .map(Region::parse)
            .transpose()
            .map_err(bad)?,
        binning: a.binning,
        frame_rate: a.frame_rate,
        pixel_format: a
            .pixel_format
            .as_deref()
            .map(PixelFormat::parse)
            .transpose()
            .map_err(bad)?,
    })
}

/// Runs a `camera` command.
pub fn run(cmd: &CameraCommand) -> Result<()> {
    match cmd {
        CameraCommand::List { .. } => imp::list(cmd),
        CameraCommand::Info {
            camera,
            timeout: t,
            format,
        } => {
            let id = camera_id(camera)?;
            imp::info(id, timeout(*t)?, *format)
        }
        CameraCommand::Grab(a) => {
            let id = camera_id(&a.camera)?;
            let req = request(a)?;
            let t = timeout(a.timeout)?;
            // The first frame's file stands for all: same directory, same extension.
            let mut plan = cellinject_files::Plan::new();
            let first = cellinject_genicam::frame_path(&a.out, 0, a.frames as usize);
            plan.output(
                "--out",
                &first,
                &[cellinject_files::Kind::Png, cellinject_files::Kind::Tiff],
            )?;
            plan.check()?;
            imp::grab(id, &req, t, a)
        }
    }
}

#[cfg(not(feature = "genicam"))]
mod imp {
    use super::*;

    fn unavailable() -> anyhow::Error {
        InputError(
            "this cellinject was built without GenICam cameras: install Debian's libaravis-dev, then `cargo install --path crates/cellinject --features genicam` (docs/cameras.md)"
                .into(),
        )
        .into()
    }

    pub fn list(_: &CameraCommand) -> Result<()> {
        Err(unavailable())
    }

    pub fn info(_: &str, _: std::time::Duration, _: Format) -> Result<()> {
        Err(unavailable())
    }

    pub fn grab(_: &str, _: &Request, _: std::time::Duration, _: &GrabArgs) -> Result<()> {
        Err(unavailable())
    }
}

#[cfg(feature = "genicam")]
mod imp {
    use std::time::{Duration, Instant};

    use anyhow::Context as _;
    use cellinject_genicam::device::{CameraInfo, GenicamCamera, list as devices};
    use cellinject_hw::Frame;
    use serde_json::json;

    use super::*;

    /// A camera error: the user's (exit 2) or the camera's (exit 1).
    fn error(e: GenicamError) -> anyhow::Error {
        match e {
            GenicamError::Invalid { .. } => InputError(e.to_string()).into(),
            _ => anyhow::anyhow!("{e}"),
        }
    }

    fn open(id: &str, t: Duration) -> Result<GenicamCamera> {
        // `camera` commands work in pixels: the object-plane size is the bench's business.
        GenicamCamera::open(id, t, Box::new(|| f64::NAN)).map_err(error)
    }

    pub fn list(cmd: &CameraCommand) -> Result<()> {
        let CameraCommand::List { format } = cmd else {
            unreachable!("list")
        };
        let found = devices();
        match format {
            Format::Json => {
                let v: Vec<_> = found
                    .iter()
                    .map(|d| {
                        json!({"id": d.id, "vendor": d.vendor, "model": d.model, "serial": d.serial, "address": d.address, "interface": d.interface})
                    })
                    .collect();
                outln!("{}", serde_json::to_string_pretty(&json!({"cameras": v}))?);
            }
            Format::Text => {
                if found.is_empty() {
                    outln!(
                        "no GenICam camera found (GigE Vision discovery on every network interface, USB3 Vision enumeration)"
                    );
                }
                for d in &found {
                    outln!("{}", d.line());
                }
            }
        }
        Ok(())
    }

    fn info_json(i: &CameraInfo) -> serde_json::Value {
        let l = &i.limits;
        json!({
            "id": i.id, "vendor": i.vendor, "model": i.model, "serial": i.serial,
            "sensor": {"width": l.sensor.0, "height": l.sensor.1},
            "pixel_formats": l.pixel_formats,
            "exposure_s": {"min": l.exposure.0, "max": l.exposure.1, "value": i.exposure},
            "gain_db": l.gain.map(|(lo, hi)| json!({"min": lo, "max": hi, "value": i.gain})),
            "width": {"min": l.width.0, "max": l.width.1, "increment": l.width.2},
            "height": {"min": l.height.0, "max": l.height.1, "increment": l.height.2},
            "binning": {"range": l.binning.map(|(lo, hi)| [lo, hi]), "value": i.binning},
            "roi": {"x": i.region.x, "y": i.region.y, "width": i.region.width, "height": i.region.height},
            "pixel_format": i.pixel_format,
            "frame_rate_hz": i.frame_rate,
            "frame_rate_range_hz": l.frame_rate.map(|(lo, hi)| [lo, hi]),
        })
    }

    pub fn info(id: &str, t: Duration, format: Format) -> Result<()> {
        let cam = open(id, t)?;
        let i = cam.info().map_err(error)?;
        match format {
            Format::Json => outln!("{}", serde_json::to_string_pretty(&info_json(&i))?),
            Format::Text => out!("{}", i.text()),
        }
        Ok(())
    }

    pub fn grab(id: &str, req: &Request, t: Duration, a: &GrabArgs) -> Result<()> {
        let mut cam = open(id, t)?;
        cam.apply(req).map_err(error)?;
        let n = a.frames as usize;
        let mut frame = Frame::default();
        let mut written = Vec::new();
        let mut rows = Vec::new();
        let start = Instant::now();
        let mut first_at = None;
        for k in 0..n {
            let g = match cam.next(&mut frame, Duration::from_secs(60)) {
                Ok(g) => g,
                Err(e) => {
                    if cam.is_gone() {
                        // The command ends here: closing a camera that is gone costs
                        // Aravis seconds of retries, which would only delay the exit.
                        std::mem::forget(cam);
                    }
                    let kept = if written.is_empty() {
                        String::new()
                    } else {
                        format!(" ({} frame(s) written and kept)", written.len())
                    };
                    return Err(anyhow::anyhow!("{e}{kept}"));
                }
            };
            // This host's clock on receipt: against the camera's stamp, the latency
            // where the two clocks agree (the same host, or PTP-synchronised).
            let received_ns = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos());
            if k == 0 {
                first_at = Some(Instant::now());
            }
            let path = cellinject_genicam::frame_path(&a.out, k, n);
            let bits = if frame.bit_depth > 8 { 16 } else { 8 };
            let bytes = crate::sim::encode_frame(&frame, bits, &path)?;
            cellinject_files::write_one(&path, &bytes)
                .with_context(|| format!("writing frame {k} to `{}`", path.display()))?;
            rows.push(json!({
                "file": path.display().to_string(),
                "timestamp_ns": g.timestamp_ns,
                "received_ns": received_ns,
                "frame_id": g.frame_id,
                "width": frame.width,
                "height": frame.height,
                "pixel_format": g.pixel_format.name(),
            }));
            written.push((path, g.timestamp_ns));
        }
        let wall = start.elapsed().as_secs_f64();
        // The camera's own clock over the frames after the first: its frame rate.
        let rate = match (written.first(), written.last()) {
            (Some(f), Some(l)) if n > 1 && l.1 > f.1 => {
                Some((n - 1) as f64 / ((l.1 - f.1) as f64 * 1e-9))
            }
            _ => None,
        };
        let host_rate = first_at
            .map(|t0| t0.elapsed().as_secs_f64())
            .filter(|&s| n > 1 && s > 0.0)
            .map(|s| (n - 1) as f64 / s);
        let stats = cam.stats();
        match a.format {
            Format::Json => outln!(
                "{}",
                serde_json::to_string_pretty(&json!({
                    "camera": id,
                    "frames": rows,
                    "frame_rate_hz": rate,
                    "received_rate_hz": host_rate,
                    "wall_s": wall,
                    "stream": {"completed": stats.completed, "incomplete": stats.incomplete, "underruns": stats.underruns, "dropped": stats.dropped},
                }))?
            ),
            Format::Text => {
                let w = &written;
                outln!(
                    "{id}: {} frame(s) of {} x {} {}{}; {} incomplete, {} dropped",
                    n,
                    frame.width,
                    frame.height,
                    rows.last()
                        .and_then(|r| r["pixel_format"].as_str())
                        .unwrap_or(""),
                    rate.map(|r| format!(", {r:.2} frames/s by the camera's clock"))
                        .unwrap_or_default(),
                    stats.incomplete,
                    stats.dropped
                );
                if w.len() == 1 {
                    outln!("wrote {}", w[0].0.display());
                } else if let (Some(f), Some(l)) = (w.first(), w.last()) {
                    outln!(
                        "wrote {} … {} ({} files)",
                        f.0.display(),
                        l.0.display(),
                        w.len()
                    );
                }
            }
        }
        Ok(())
    }
}
