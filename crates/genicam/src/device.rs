//! GenICam cameras through Aravis (the `aravis` feature).
//!
//! [`list`] enumerates the cameras Aravis sees; [`GenicamCamera::open`] connects to one
//! by any id Aravis accepts (its device id such as `Aravis-GV01`, its serial number or
//! its IP address), trying for a bounded time. [`GenicamCamera`] implements the bench's
//! [`Camera`] trait: exposure, gain, region and binning are GenICam features set through
//! Aravis's camera API, which falls back between the standard names and the older ones
//! (`ExposureTime`/`ExposureTimeAbs`, `Gain`/`GainRaw`, ...); frames are streamed into a
//! ring of buffers that Aravis fills in place and that are unpacked straight into the
//! caller's [`Frame`] (no intermediate copy); the camera's own timestamps are kept;
//! incomplete frames are counted, skipped and reported ([`StreamStats`]); a camera that
//! stops answering ends the grab with [`GenicamError::Device`].
//!
//! [`GenicamCamera::open_fake`] is Aravis's in-process simulated camera, whose image a
//! test can paint ([`Pattern`]).
//!
//! Three things the Rust binding does not wrap are called through `aravis-sys`, one
//! `unsafe` block each: the device list with serial numbers, the image data of a
//! buffer in place, and the fake camera's fill-pattern callback.

#![allow(unsafe_code)]

use std::ffi::{CStr, c_void};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use aravis::glib::object::Cast;
use aravis::glib::translate::ToGlibPtr;
use aravis::prelude::*;
use aravis::{AcquisitionMode, BufferStatus};
use cellinject_hw::{Camera, CameraSettings, Frame, HwError, Roi};
use gio::prelude::*;

use crate::{GenicamError, Limits, PixelFormat, Region, Request};

/// One camera Aravis sees.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceInfo {
    /// Aravis's device id (`Aravis-GV01`, `Basler-21234567`, ...).
    pub id: String,
    /// Vendor name.
    pub vendor: String,
    /// Model name.
    pub model: String,
    /// Serial number.
    pub serial: String,
    /// Network or bus address.
    pub address: String,
    /// Interface protocol (`GigEVision`, `USB3Vision`, `Fake`).
    pub interface: String,
}

impl DeviceInfo {
    /// `camera list`'s line: id, vendor and model, serial, interface and address.
    pub fn line(&self) -> String {
        format!(
            "{}  {} {}  serial {}  {} {}",
            self.id, self.vendor, self.model, self.serial, self.interface, self.address
        )
    }
}

/// Aravis's device list is global state, and its GenICam parser (libxml2's SAX with
/// Aravis's DOM builder) is not safe to run on two threads at once (two cameras opened
/// together corrupt each other's feature tree): one list or open at a time.
static ARAVIS: Mutex<()> = Mutex::new(());

fn aravis_lock() -> std::sync::MutexGuard<'static, ()> {
    ARAVIS
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn text(p: *const std::ffi::c_char) -> String {
    if p.is_null() {
        String::new()
    } else {
        // SAFETY: Aravis returns NUL-terminated strings it owns until the next update
        // of the device list, which ARAVIS keeps from happening meanwhile.
        unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
    }
}

/// Every camera Aravis can see now (GigE Vision discovery, USB3 Vision enumeration).
pub fn list() -> Vec<DeviceInfo> {
    let _guard = aravis_lock();
    // SAFETY: the device list is only read under ARAVIS, by index below its count.
    unsafe {
        aravis_sys::arv_update_device_list();
        let n = aravis_sys::arv_get_n_devices();
        (0..n)
            .map(|i| DeviceInfo {
                id: text(aravis_sys::arv_get_device_id(i)),
                vendor: text(aravis_sys::arv_get_device_vendor(i)),
                model: text(aravis_sys::arv_get_device_model(i)),
                serial: text(aravis_sys::arv_get_device_serial_nbr(i)),
                address: text(aravis_sys::arv_get_device_address(i)),
                interface: text(aravis_sys::arv_get_device_protocol(i)),
            })
            .collect()
    }
}

/// What a camera is and what it accepts (`camera info`).
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    /// The id the camera was opened by.
    pub id: String,
    /// Vendor name.
    pub vendor: String,
    /// Model name.
    pub model: String,
    /// Serial number.
    pub serial: String,
    /// The camera's limits.
    pub limits: Limits,
    /// Current region of interest.
    pub region: Region,
    /// Current binning.
    pub binning: u32,
    /// Current exposure time, s.
    pub exposure: f64,
    /// Current gain, dB (`None` without a gain feature).
    pub gain: Option<f64>,
    /// Current pixel format, by GenICam name.
    pub pixel_format: String,
    /// Current frame rate, frames per second.
    pub frame_rate: f64,
}

impl CameraInfo {
    /// `camera info`'s text: what the camera is, its sensor, pixel formats, exposure,
    /// gain, region, binning and frame rate, each with its range.
    pub fn text(&self) -> String {
        let l = &self.limits;
        let gain = match (l.gain, self.gain) {
            (Some((lo, hi)), Some(g)) => format!("{g:.2} dB (from {lo:.2} to {hi:.2} dB)"),
            _ => "none".into(),
        };
        let binning = match l.binning {
            Some((lo, hi)) => format!("{} (from {lo} to {hi})", self.binning),
            None => "not available".into(),
        };
        let rate = match l.frame_rate {
            Some((lo, hi)) => format!("{:.2} frames/s (from {lo:.2} to {hi:.2})", self.frame_rate),
            None => format!("{:.2} frames/s (fixed)", self.frame_rate),
        };
        let r = &self.region;
        [
            format!(
                "{} ({} {}, serial {})",
                self.id, self.vendor, self.model, self.serial
            ),
            format!("sensor        {} x {} pixels", l.sensor.0, l.sensor.1),
            format!("pixel formats {}", l.pixel_formats.join(", ")),
            format!(
                "exposure      {:.1} µs (from {:.1} to {:.1} µs)",
                self.exposure * 1e6,
                l.exposure.0 * 1e6,
                l.exposure.1 * 1e6
            ),
            format!("gain          {gain}"),
            format!(
                "region        {},{},{},{} (width {}..{} step {}, height {}..{} step {})",
                r.x,
                r.y,
                r.width,
                r.height,
                l.width.0,
                l.width.1,
                l.width.2,
                l.height.0,
                l.height.1,
                l.height.2
            ),
            format!("binning       {binning}"),
            format!("pixel format  {}", self.pixel_format),
            format!("frame rate    {rate}"),
        ]
        .iter()
        .map(|line| format!("{line}\n"))
        .collect()
    }
}

/// The stream's counters since the acquisition started.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StreamStats {
    /// Frames received whole.
    pub completed: u64,
    /// Frames that arrived incomplete (missing packets, timeouts) and were skipped.
    pub incomplete: u64,
    /// Frames the camera sent while no buffer was free (lost).
    pub underruns: u64,
    /// Gaps in the camera's frame ids between frames handed out (frames lost anywhere).
    pub dropped: u64,
}

/// The metadata of one grabbed frame beside its pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grabbed {
    /// The camera's timestamp of the frame, ns (its own clock).
    pub timestamp_ns: u64,
    /// The camera's frame id.
    pub frame_id: u64,
    /// Pixel format of the payload.
    pub pixel_format: PixelFormat,
}

/// Paints the in-process fake camera's image: called with the frame id, the image's
/// width and height, and its bytes (Mono8: one per pixel) to fill.
pub type Pattern = Box<dyn Fn(u64, usize, usize, &mut [u8]) + Send + Sync>;

/// Keeps the fake camera's painter alive while Aravis may call it, and tells Aravis to
/// stop calling it before it is freed.
struct Painter {
    fake: aravis::FakeCamera,
    pattern: *mut Pattern,
}

// SAFETY: the pattern is `Send + Sync`; the pointer is only dereferenced by Aravis's
// fill callback under the fake camera's fill mutex, and freed after the callback has
// been removed under that same mutex.
unsafe impl Send for Painter {}

impl Drop for Painter {
    fn drop(&mut self) {
        let fake: *mut aravis_sys::ArvFakeCamera = self.fake.to_glib_none().0;
        // SAFETY: a null callback restores Aravis's own ramp under the fill mutex, so
        // no fill can be using the pattern when it is freed just after.
        unsafe {
            aravis_sys::arv_fake_camera_set_fill_pattern(fake, None, std::ptr::null_mut());
            drop(Box::from_raw(self.pattern));
        }
    }
}

unsafe extern "C" fn paint(
    buffer: *mut aravis_sys::ArvBuffer,
    data: *mut c_void,
    _exposure_us: u32,
    _gain: u32,
    pixel_format: aravis_sys::ArvPixelFormat,
) {
    // SAFETY: `data` is the Painter's live pattern (see Painter); the buffer is the one
    // Aravis is filling, which it has checked holds the payload (w x h bytes in Mono8)
    // before calling (its received size is not set yet, so it is not asked).
    unsafe {
        let pattern = &*(data as *const Pattern);
        let w = usize::try_from(aravis_sys::arv_buffer_get_image_width(buffer)).unwrap_or(0);
        let h = usize::try_from(aravis_sys::arv_buffer_get_image_height(buffer)).unwrap_or(0);
        let p = aravis_sys::arv_buffer_get_data(buffer, std::ptr::null_mut());
        if p.is_null() || pixel_format != aravis_sys::ARV_PIXEL_FORMAT_MONO_8 {
            return;
        }
        let frame_id = aravis_sys::arv_buffer_get_frame_id(buffer);
        let bytes = std::slice::from_raw_parts_mut(p, w * h);
        pattern(frame_id, w, h, bytes);
    }
}

/// Settings read when an acquisition starts.
#[derive(Debug, Clone, Copy)]
struct Acquiring {
    /// Exposure time, s.
    exposure: f64,
    /// Frame period, s.
    period: f64,
    /// Binning.
    binning: u32,
}

/// The GigE Vision packet size used on loopback (a camera on 127.0.0.1, as Aravis's
/// simulator). Loopback carries 64 KiB datagrams, so larger packets than Ethernet's
/// 1500 bytes mean fewer of them per frame. Measured with Aravis's own
/// `arv-camera-test-0.8 --auto` against `arv-fake-gv-camera-0.8` (0.8.26): 16000 bytes
/// gives every frame at 512 x 512, 640 x 480, 1000 x 1000 and 2048 x 2048, where 8192
/// lost most 512 x 512 frames and 1400 slowed 2048 x 2048 frames to 16 frames/s.
const LOOPBACK_PACKET_SIZE: i32 = 16000;

/// A GenICam camera.
pub struct GenicamCamera {
    id: String,
    camera: aravis::Camera,
    stream: Option<aravis::Stream>,
    buffers: usize,
    /// Bytes of each stream buffer (the camera's payload when the stream started).
    payload: usize,
    /// A GigE Vision camera on 127.0.0.1 (a simulator).
    loopback: bool,
    /// A GigE Vision camera's control address (GVCP).
    gvcp: Option<std::net::SocketAddr>,
    /// The camera stopped answering.
    dead: bool,
    /// Settings that hold while the acquisition runs.
    acquiring: Acquiring,
    lost: Arc<AtomicBool>,
    limits: Limits,
    pixel_size: Box<dyn Fn() -> f64 + Send>,
    last_frame_id: Option<u64>,
    dropped: u64,
    incomplete: u64,
    index: u64,
    painter: Option<Painter>,
}

fn to_u32(v: i32) -> u32 {
    u32::try_from(v.max(0)).unwrap_or(0)
}

impl GenicamCamera {
    /// Connects to the camera Aravis knows as `id`, trying every half second for at
    /// most `timeout`. Its pixels measure `pixel_size()` m in the object plane at
    /// binning 1 (the sensor's pitch over the lens's magnification).
    pub fn open(
        id: &str,
        timeout: Duration,
        pixel_size: Box<dyn Fn() -> f64 + Send>,
    ) -> Result<GenicamCamera, GenicamError> {
        let start = Instant::now();
        let mut attempts = 0u32;
        let camera = loop {
            attempts += 1;
            let opened = {
                let _guard = aravis_lock();
                aravis::Camera::new(Some(id))
            };
            match opened {
                Ok(c) => break c,
                Err(e) => {
                    if start.elapsed() >= timeout {
                        let seen = list();
                        let seen = if seen.is_empty() {
                            "none".to_string()
                        } else {
                            seen.iter()
                                .map(|d| format!("{} ({}, {})", d.id, d.interface, d.address))
                                .collect::<Vec<_>>()
                                .join(", ")
                        };
                        return Err(GenicamError::NotFound {
                            id: id.into(),
                            seconds: start.elapsed().as_secs_f64(),
                            tried: format!(
                                "{attempts} connection attempts by Aravis's device id, serial number and address over GigE Vision and USB3 Vision, the last saying \"{}\"; cameras seen: {seen}",
                                e.message()
                            ),
                        });
                    }
                    std::thread::sleep(Duration::from_millis(500));
                }
            }
        };
        GenicamCamera::with_camera(id, camera, pixel_size)
    }

    /// Aravis's in-process simulated camera (serial `serial`), painted by `pattern`
    /// (Mono8), or Aravis's moving diagonal ramp without one.
    pub fn open_fake(
        serial: &str,
        pattern: Option<Pattern>,
        pixel_size: Box<dyn Fn() -> f64 + Send>,
    ) -> Result<GenicamCamera, GenicamError> {
        let dev_err = |e: aravis::glib::Error| GenicamError::Device {
            id: format!("fake {serial}"),
            message: e.message().to_string(),
        };
        let _guard = aravis_lock();
        let device = aravis::FakeDevice::new(serial).map_err(dev_err)?;
        let painter = match pattern {
            None => None,
            Some(p) => {
                let fake = device.fake_camera().ok_or_else(|| GenicamError::Device {
                    id: format!("fake {serial}"),
                    message: "the fake device has no fake camera".into(),
                })?;
                let pattern = Box::into_raw(Box::new(p));
                let raw: *mut aravis_sys::ArvFakeCamera = fake.to_glib_none().0;
                // SAFETY: `paint` matches ArvFakeCameraFillPattern; the pattern lives
                // until Painter::drop removes the callback.
                unsafe {
                    aravis_sys::arv_fake_camera_set_fill_pattern(raw, Some(paint), pattern.cast());
                }
                Some(Painter { fake, pattern })
            }
        };
        let camera = aravis::Camera::with_device(&device).map_err(dev_err)?;
        drop(_guard);
        let mut cam = GenicamCamera::with_camera(&format!("fake {serial}"), camera, pixel_size)?;
        cam.painter = painter;
        Ok(cam)
    }

    fn with_camera(
        id: &str,
        camera: aravis::Camera,
        pixel_size: Box<dyn Fn() -> f64 + Send>,
    ) -> Result<GenicamCamera, GenicamError> {
        let lost = Arc::new(AtomicBool::new(false));
        let mut loopback = false;
        let mut gvcp = None;
        if let Some(device) = camera.device() {
            if let Ok(gv) = device.clone().downcast::<aravis::GvDevice>() {
                let inet = gv
                    .device_address()
                    .and_then(|a| a.downcast::<gio::InetSocketAddress>().ok());
                loopback = inet.as_ref().is_some_and(|a| a.address().is_loopback());
                gvcp = inet.and_then(|a| {
                    let ip: std::net::IpAddr = a.address().to_string().parse().ok()?;
                    Some(std::net::SocketAddr::new(ip, a.port()))
                });
                if !gv.is_controller() {
                    return Err(GenicamError::Device {
                        id: id.into(),
                        message: "another program holds the camera's control channel (GigE Vision control privilege): close it (a viewer, another cellinject) and try again".into(),
                    });
                }
            }
            let flag = lost.clone();
            device.connect_control_lost(move |_| flag.store(true, Ordering::SeqCst));
        }
        let mut cam = GenicamCamera {
            id: id.into(),
            camera,
            stream: None,
            buffers: 8,
            payload: 0,
            loopback,
            gvcp,
            dead: false,
            acquiring: Acquiring {
                exposure: f64::NAN,
                period: f64::NAN,
                binning: 1,
            },
            lost,
            limits: Limits {
                sensor: (0, 0),
                exposure: (0.0, 0.0),
                gain: None,
                width: (1, 1, 1),
                height: (1, 1, 1),
                binning: None,
                pixel_formats: Vec::new(),
                frame_rate: None,
            },
            pixel_size,
            last_frame_id: None,
            dropped: 0,
            incomplete: 0,
            index: 0,
            painter: None,
        };
        cam.limits = cam.read_limits()?;
        Ok(cam)
    }

    fn err(&self, what: &str, e: &aravis::glib::Error) -> GenicamError {
        GenicamError::Device {
            id: self.id.clone(),
            message: format!("{what}: {}", e.message()),
        }
    }

    fn read_limits(&self) -> Result<Limits, GenicamError> {
        let c = &self.camera;
        let (sw, sh) = c
            .sensor_size()
            .map_err(|e| self.err("reading the sensor size", &e))?;
        let (elo, ehi) = c
            .exposure_time_bounds()
            .map_err(|e| self.err("reading the exposure time's bounds", &e))?;
        let gain = c.gain_bounds().ok();
        let (wlo, whi) = c
            .width_bounds()
            .map_err(|e| self.err("reading the width's bounds", &e))?;
        let (hlo, hhi) = c
            .height_bounds()
            .map_err(|e| self.err("reading the height's bounds", &e))?;
        let winc = c.width_increment().unwrap_or(1);
        let hinc = c.height_increment().unwrap_or(1);
        let binning = if c.is_binning_available().unwrap_or(false) {
            c.x_binning_bounds()
                .ok()
                .map(|(lo, hi)| (to_u32(lo).max(1), to_u32(hi).max(1)))
        } else {
            None
        };
        let pixel_formats = c
            .dup_available_pixel_formats_as_strings()
            .map(|v| v.iter().map(|s| s.to_string()).collect())
            .unwrap_or_default();
        let frame_rate = if c.is_frame_rate_available().unwrap_or(false) {
            c.frame_rate_bounds().ok()
        } else {
            None
        };
        Ok(Limits {
            sensor: (to_u32(sw), to_u32(sh)),
            exposure: (elo * 1e-6, ehi * 1e-6),
            gain,
            width: (to_u32(wlo), to_u32(whi), to_u32(winc).max(1)),
            height: (to_u32(hlo), to_u32(hhi), to_u32(hinc).max(1)),
            binning,
            pixel_formats,
            frame_rate,
        })
    }

    /// The camera's id as it was opened.
    pub fn id(&self) -> &str {
        &self.id
    }

    /// The camera's limits, as read when it was opened.
    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    /// The current binning (1 when the camera cannot bin).
    pub fn binning(&self) -> u32 {
        self.camera.binning().map_or(1, |(x, _)| to_u32(x).max(1))
    }

    /// The current pixel format, when it is one the bench reads.
    pub fn pixel_format(&self) -> Option<PixelFormat> {
        self.camera
            .pixel_format_as_string()
            .ok()
            .and_then(|s| PixelFormat::from_name(&s))
    }

    /// What the camera is and what it accepts now.
    pub fn info(&self) -> Result<CameraInfo, GenicamError> {
        let c = &self.camera;
        let s = |r: Result<aravis::glib::GString, aravis::glib::Error>| {
            r.map_or_else(|_| String::new(), |g| g.to_string())
        };
        let (x, y, w, h) = c.region().map_err(|e| self.err("reading the region", &e))?;
        Ok(CameraInfo {
            id: self.id.clone(),
            vendor: s(c.vendor_name()),
            model: s(c.model_name()),
            serial: s(c.device_serial_number()),
            limits: self.limits.clone(),
            region: Region {
                x: to_u32(x),
                y: to_u32(y),
                width: to_u32(w),
                height: to_u32(h),
            },
            binning: self.binning(),
            exposure: c
                .exposure_time()
                .map_err(|e| self.err("reading the exposure time", &e))?
                * 1e-6,
            gain: c.gain().ok(),
            pixel_format: s(c.pixel_format_as_string()),
            frame_rate: c.frame_rate().unwrap_or(f64::NAN),
        })
    }

    /// Applies `request`, after checking all of it against the camera's limits (a
    /// refused request changes nothing). Stops the acquisition first when it runs.
    pub fn apply(&mut self, request: &Request) -> Result<(), GenicamError> {
        request.validate(&self.limits, self.binning())?;
        self.stop();
        let c = self.camera.clone();
        if let Some(b) = request.binning {
            let b = i32::try_from(b).unwrap_or(i32::MAX);
            c.set_binning(b, b)
                .map_err(|e| self.err("setting the binning", &e))?;
        }
        if let Some(f) = request.pixel_format {
            c.set_pixel_format_from_string(f.name())
                .map_err(|e| self.err("setting the pixel format", &e))?;
        }
        if let Some(r) = request.roi {
            let v = |u: u32| i32::try_from(u).unwrap_or(i32::MAX);
            c.set_region(v(r.x), v(r.y), v(r.width), v(r.height))
                .map_err(|e| self.err("setting the region", &e))?;
        }
        if let Some(e) = request.exposure {
            c.set_exposure_time(e * 1e6)
                .map_err(|er| self.err("setting the exposure time", &er))?;
        }
        if let Some(g) = request.gain {
            c.set_gain(g)
                .map_err(|e| self.err("setting the gain", &e))?;
        }
        // After the exposure: a camera bounds its rate by the exposure time.
        if let Some(f) = request.frame_rate {
            c.set_frame_rate(f)
                .map_err(|e| self.err("setting the frame rate", &e))?;
        }
        Ok(())
    }

    fn start(&mut self) -> Result<(), GenicamError> {
        if self.stream.is_some() {
            return Ok(());
        }
        let c = self.camera.clone();
        if self.loopback {
            // Aravis's fast path (a raw packet socket, when run as root) listens on the
            // network card, where a camera on loopback never sends.
            c.gv_set_stream_options(aravis::GvStreamOption::PACKET_SOCKET_DISABLED);
        }
        let _ = c.set_acquisition_mode(AcquisitionMode::Continuous);
        if self.loopback {
            let _ = c.gv_set_packet_size(LOOPBACK_PACKET_SIZE);
        }
        let stream = c
            .create_stream()
            .map_err(|e| self.err("opening the stream", &e))?;
        if let Ok(gv) = stream.clone().downcast::<aravis::GvStream>() {
            // A receive buffer sized to hold a whole frame, as arv-camera-test's --auto:
            // the default drops packets of large frames in bursts.
            gv.set_socket_buffer(aravis::GvStreamSocketBuffer::Auto);
        }
        let payload = c
            .payload()
            .map_err(|e| self.err("reading the payload size", &e))? as usize;
        for _ in 0..self.buffers {
            stream.push_buffer(aravis::Buffer::new_allocate(payload));
        }
        self.payload = payload;
        // Read once per acquisition: every frame carries them, and a read of a camera
        // that is gone costs Aravis's retries.
        self.acquiring = Acquiring {
            exposure: c.exposure_time().map_or(f64::NAN, |e| e * 1e-6),
            period: c.frame_rate().map_or(f64::NAN, |r| 1.0 / r),
            binning: self.binning(),
        };
        c.start_acquisition()
            .map_err(|e| self.err("starting the acquisition", &e))?;
        self.stream = Some(stream);
        self.last_frame_id = None;
        Ok(())
    }

    /// Stops the acquisition (a later grab starts it again).
    pub fn stop(&mut self) {
        if let Some(stream) = self.stream.take() {
            if !self.dead {
                let _ = self.camera.stop_acquisition();
            }
            drop(stream);
        }
    }

    /// The stream's counters.
    pub fn stats(&self) -> StreamStats {
        let (completed, failures, underruns) =
            self.stream.as_ref().map_or((0, 0, 0), |s| s.statistics());
        StreamStats {
            completed,
            incomplete: failures.max(self.incomplete),
            underruns,
            dropped: self.dropped,
        }
    }

    /// Waits at most `timeout` for the next whole frame and unpacks it into `frame`
    /// (its buffer reused). Incomplete frames are counted and skipped. A camera that
    /// stops answering is a [`GenicamError::Device`].
    pub fn next(&mut self, frame: &mut Frame, timeout: Duration) -> Result<Grabbed, GenicamError> {
        if self.dead {
            return Err(self.gone("it stopped answering earlier"));
        }
        self.start()?;
        let begin = Instant::now();
        let deadline = begin + timeout;
        // Without a frame for this long, ask the camera whether it is still there.
        let stall = self.stall();
        let mut quiet_since = begin;
        loop {
            if self.lost.load(Ordering::SeqCst) {
                return Err(self.die("its GigE Vision heartbeat was lost"));
            }
            let now = Instant::now();
            let wait = deadline
                .saturating_duration_since(now)
                .min(Duration::from_millis(250));
            let popped = self.stream.as_ref().and_then(|s| {
                s.timeout_pop_buffer(u64::try_from(wait.as_micros()).unwrap_or(u64::MAX))
            });
            let Some(buffer) = popped else {
                let now = Instant::now();
                if now.duration_since(quiet_since) >= stall || now >= deadline {
                    let alive = self.alive();
                    if !alive {
                        return Err(self.die(&format!(
                            "no frame for {:.1} s, then no reply",
                            now.duration_since(begin).as_secs_f64()
                        )));
                    }
                    quiet_since = Instant::now();
                }
                if Instant::now() >= deadline {
                    self.stop();
                    return Err(GenicamError::Device {
                        id: self.id.clone(),
                        message: format!(
                            "no frame within {:.1} s, though the camera answers (is it waiting for a trigger?)",
                            timeout.as_secs_f64()
                        ),
                    });
                }
                continue;
            };
            let result = self.unpack(&buffer, frame);
            if let Some(s) = self.stream.as_ref() {
                s.push_buffer(buffer);
            }
            match result {
                Ok(Some(g)) => return Ok(g),
                Ok(None) => quiet_since = Instant::now(),
                Err(e) => return Err(e),
            }
        }
    }

    /// Whether the camera is still there. A GigE Vision camera is asked directly, on a
    /// socket of our own, for its bootstrap version register ([`gvcp_answers`]): reads
    /// are open to any host whoever holds control, and Aravis's own channel would
    /// queue our question behind its heartbeat's retries (its verdict comes about 6 s
    /// after the camera's last answer). Any other camera is asked through Aravis for
    /// the register at address 0, the bootstrap's version register on USB3 Vision too
    /// (GenICam features may be computed or cached without asking the camera).
    fn alive(&self) -> bool {
        // (Not `is_controller()`: it waits for Aravis's channel, busy with the heartbeat.)
        if self.lost.load(Ordering::SeqCst) {
            return false;
        }
        if let Some(addr) = self.gvcp {
            return gvcp_answers(addr, Duration::from_millis(200), 3);
        }
        self.camera
            .device()
            .is_some_and(|d| d.read_register(0).is_ok_and(|(ok, _)| ok))
    }

    /// How long a stream may stay silent before the camera is asked whether it is
    /// still there: three frame periods plus the exposure, at least a second.
    fn stall(&self) -> Duration {
        let a = self.acquiring;
        let known = |v: f64| if v.is_finite() && v > 0.0 { v } else { 0.0 };
        Duration::from_secs_f64((3.0 * (known(a.period) + known(a.exposure))).clamp(1.0, 30.0))
    }

    fn gone(&self, why: &str) -> GenicamError {
        GenicamError::Device {
            id: self.id.clone(),
            message: format!(
                "the camera stopped answering ({why}): unplugged, powered off, its network down, or the simulator killed"
            ),
        }
    }

    /// The camera is gone. The stream stays open until the camera is dropped: closing
    /// it asks the camera to stop streaming, which Aravis retries for seconds.
    fn die(&mut self, why: &str) -> GenicamError {
        self.dead = true;
        self.gone(why)
    }

    /// Whether the camera stopped answering (a dropped camera that is gone takes Aravis
    /// a few seconds of retries to close; a program about to exit may `forget` it).
    pub fn is_gone(&self) -> bool {
        self.dead
    }

    /// Unpacks a popped buffer; `None` for an incomplete frame.
    fn unpack(
        &mut self,
        buffer: &aravis::Buffer,
        frame: &mut Frame,
    ) -> Result<Option<Grabbed>, GenicamError> {
        if buffer.status() != BufferStatus::Success {
            self.incomplete += 1;
            return Ok(None);
        }
        let width = usize::try_from(buffer.image_width()).unwrap_or(0);
        let height = usize::try_from(buffer.image_height()).unwrap_or(0);
        let (pad_x, _) = buffer.image_padding();
        let raw_format = buffer.image_pixel_format();
        let format = if raw_format == aravis::PixelFormat::MONO_8 {
            PixelFormat::Mono8
        } else if raw_format == aravis::PixelFormat::MONO_12 {
            PixelFormat::Mono12
        } else if raw_format == aravis::PixelFormat::MONO_16 {
            PixelFormat::Mono16
        } else {
            return Err(GenicamError::Device {
                id: self.id.clone(),
                message: format!(
                    "pixel format 0x{:08x} is not one the bench reads: choose Mono8, Mono12 or Mono16 (--pixel-format)",
                    raw_format.raw()
                ),
            });
        };
        let ptr: *mut aravis_sys::ArvBuffer = buffer.to_glib_none().0;
        let need =
            (width * format.bytes_per_pixel() + usize::try_from(pad_x).unwrap_or(0)) * height;
        // SAFETY: the buffer is popped (Aravis no longer writes it) and borrowed for the
        // whole block; the slice is its image data, or, when the received size is unset
        // (as Aravis's fake camera leaves it behind a custom fill pattern), the start of
        // its data, where a single-part image starts, over the `payload` bytes this
        // stream allocated for every buffer.
        let unpacked = unsafe {
            let mut size = 0usize;
            let mut p = aravis_sys::arv_buffer_get_image_data(ptr, &mut size);
            if size == 0 && need <= self.payload {
                p = aravis_sys::arv_buffer_get_data(ptr, &mut size);
                size = self.payload;
            }
            if p.is_null() {
                Err("the buffer has no data".to_string())
            } else {
                let data = std::slice::from_raw_parts(p.cast_const(), size);
                crate::unpack(
                    format,
                    data,
                    width,
                    height,
                    usize::try_from(pad_x).unwrap_or(0),
                    &mut frame.pixels,
                )
            }
        };
        unpacked.map_err(|m| GenicamError::Device {
            id: self.id.clone(),
            message: m,
        })?;
        let frame_id = buffer.frame_id();
        if let Some(last) = self.last_frame_id {
            // GigE Vision frame ids are 16-bit and skip 0.
            let gap = if frame_id > last {
                frame_id - last
            } else {
                frame_id + 65535 - last
            };
            self.dropped += gap.saturating_sub(1).min(65535);
        }
        self.last_frame_id = Some(frame_id);
        let ts = match buffer.timestamp() {
            0 => buffer.system_timestamp(),
            t => t,
        };
        let binning = self.acquiring.binning;
        frame.width = u32::try_from(width).unwrap_or(0);
        frame.height = u32::try_from(height).unwrap_or(0);
        frame.bit_depth = format.bit_depth();
        frame.timestamp = ts as f64 * 1e-9;
        frame.exposure = self.acquiring.exposure;
        frame.pixel_size = (self.pixel_size)() * f64::from(binning);
        frame.index = self.index;
        self.index += 1;
        Ok(Some(Grabbed {
            timestamp_ns: ts,
            frame_id,
            pixel_format: format,
        }))
    }

    fn grab_timeout(&self) -> Duration {
        // The stall check inside ends a grab from a camera that is gone sooner.
        Duration::from_secs(60)
    }
}

impl Drop for GenicamCamera {
    fn drop(&mut self) {
        self.stop();
        // The painter (if any) goes after the stream, which may still be filling.
        self.painter.take();
    }
}

/// Whether a GigE Vision device at `addr` answers a read of its version register
/// (bootstrap address 0): a GVCP READREG command (GigE Vision 2.0, sec. 15: key 0x42,
/// flag "acknowledge", command 0x0080, one 32-bit address), tried `tries` times with
/// `timeout` each.
pub fn gvcp_answers(addr: std::net::SocketAddr, timeout: Duration, tries: u16) -> bool {
    let local = if addr.is_ipv4() {
        "0.0.0.0:0"
    } else {
        "[::]:0"
    };
    let Ok(socket) = std::net::UdpSocket::bind(local) else {
        return false;
    };
    if socket.set_read_timeout(Some(timeout)).is_err() {
        return false;
    }
    for id in 1..=tries {
        let [hi, lo] = (0x7000 + id).to_be_bytes();
        let command = [0x42, 0x01, 0x00, 0x80, 0x00, 0x04, hi, lo, 0, 0, 0, 0];
        if socket.send_to(&command, addr).is_err() {
            return false;
        }
        let mut reply = [0u8; 64];
        let until = Instant::now() + timeout;
        while Instant::now() < until {
            match socket.recv_from(&mut reply) {
                // READREG_ACK (0x0081) with our request id.
                Ok((n, _)) if n >= 8 && reply[2..4] == [0x00, 0x81] && reply[6..8] == [hi, lo] => {
                    return true;
                }
                Ok(_) => continue,
                Err(_) => break,
            }
        }
    }
    false
}

fn hw(e: GenicamError) -> HwError {
    match e {
        GenicamError::Invalid { argument, message } => HwError::Device {
            device: "GenICam camera".into(),
            message: format!("{argument}: {message}"),
        },
        GenicamError::NotFound { ref id, .. } | GenicamError::Device { ref id, .. } => {
            HwError::Device {
                device: format!("camera aravis:{id}"),
                message: e.to_string(),
            }
        }
    }
}

impl Camera for GenicamCamera {
    fn sensor_size(&self) -> (u32, u32) {
        self.limits.sensor
    }

    /// The bench's region is in sensor pixels, GenICam's in binned ones.
    fn settings(&self) -> CameraSettings {
        let (x, y, w, h) = self.camera.region().unwrap_or((0, 0, 0, 0));
        let b = self.binning();
        CameraSettings {
            roi: Roi {
                x: to_u32(x) * b,
                y: to_u32(y) * b,
                width: to_u32(w) * b,
                height: to_u32(h) * b,
            },
            binning: b,
            exposure: self.camera.exposure_time().map_or(f64::NAN, |e| e * 1e-6),
            bit_depth: self.pixel_format().map_or(8, |f| f.bit_depth().min(12)),
        }
    }

    fn configure(&mut self, settings: CameraSettings) -> Result<(), HwError> {
        let offered = |f: PixelFormat| self.limits.pixel_formats.iter().any(|n| n == f.name());
        // 12 bits where the camera offers them, else 16, else 8.
        let pixel_format = match settings.bit_depth {
            8 => PixelFormat::Mono8,
            _ if offered(PixelFormat::Mono12) => PixelFormat::Mono12,
            _ if offered(PixelFormat::Mono16) => PixelFormat::Mono16,
            _ => PixelFormat::Mono8,
        };
        let b = settings.binning.max(1);
        let r = settings.roi;
        let request = Request {
            exposure: Some(settings.exposure),
            gain: None,
            roi: Some(Region {
                x: r.x / b,
                y: r.y / b,
                width: r.width / b,
                height: r.height / b,
            }),
            binning: (b != self.binning()).then_some(b),
            pixel_format: Some(pixel_format),
            // The bench's settings carry no rate: the camera keeps its own.
            frame_rate: None,
        };
        self.apply(&request).map_err(hw)
    }

    fn frame_rate(&self) -> f64 {
        self.camera.frame_rate().unwrap_or(f64::NAN)
    }

    fn grab_into(&mut self, frame: &mut Frame) -> Result<(), HwError> {
        let timeout = self.grab_timeout();
        self.next(frame, timeout).map(|_| ()).map_err(hw)
    }
}
