//! # cellinject-cameras
//!
//! Camera backends for real benches. [`FolderCamera`]: the frames another acquisition
//! program (a vendor's viewer, µManager, a script) writes into a folder, one PNG or TIFF
//! file per frame (8- or 16-bit grey), taken in the order of their names; the region of
//! interest and binning are applied here, in software, so the workflow's acquisitions
//! (full frame, VGA, a region around the tip) work unchanged.
//!
//! The acquisition program must write each frame whole before it appears under its
//! final name (write `frame-000123.png.part`, then rename): names starting with `.` or
//! ending in anything but `.png`, `.tif`, `.tiff` are ignored.
//!
//! [`list`]: the frame files a command line names (a folder, or a pattern in one).
//!
//! **Architecture invariant:** the only file IO of a camera; it never deletes or
//! rewrites a frame it read.

pub mod list;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use cellinject_hw::{Camera, CameraSettings, Frame, HwError, Roi};

/// Frames from a folder.
pub struct FolderCamera {
    dir: PathBuf,
    sensor: (u32, u32),
    settings: CameraSettings,
    rate: f64,
    pixel_size: Box<dyn Fn() -> f64 + Send>,
    timeout: Duration,
    last: Option<String>,
    index: u64,
    start: Instant,
}

fn device(dir: &Path, message: impl std::fmt::Display) -> HwError {
    HwError::Device {
        device: format!("camera folder `{}`", dir.display()),
        message: message.to_string(),
    }
}

fn is_frame(name: &str) -> bool {
    let lower = name.to_ascii_lowercase();
    !name.starts_with('.')
        && (lower.ends_with(".png") || lower.ends_with(".tif") || lower.ends_with(".tiff"))
}

/// Reads one frame file as grey values and their bit depth.
pub fn read_frame(path: &Path) -> Result<(u32, u32, Vec<u16>, u8), String> {
    let img = image::ImageReader::open(path)
        .map_err(|e| e.to_string())?
        .with_guessed_format()
        .map_err(|e| e.to_string())?
        .decode()
        .map_err(|e| e.to_string())?;
    let (w, h) = (img.width(), img.height());
    match img {
        image::DynamicImage::ImageLuma8(g) => {
            Ok((w, h, g.into_raw().into_iter().map(u16::from).collect(), 8))
        }
        image::DynamicImage::ImageLuma16(g) => Ok((w, h, g.into_raw(), 16)),
        other => Err(format!(
            "{:?} pixels: a frame must be 8- or 16-bit grey",
            other.color()
        )),
    }
}

impl FolderCamera {
    /// Watches `dir`: frames whose pixels (binning 1) measure `pixel_size()` m in the
    /// object plane when grabbed (the sensor's pitch over the lens's magnification then),
    /// arriving at about `frame_rate` per second; a grab waits at most `timeout` for a
    /// new file. The sensor size is the first frame's (read now: the folder must hold
    /// one).
    pub fn new(
        dir: &Path,
        pixel_size: Box<dyn Fn() -> f64 + Send>,
        frame_rate: f64,
        timeout: Duration,
    ) -> Result<Self, HwError> {
        let p = pixel_size();
        if !(p.is_finite() && p > 0.0) {
            return Err(device(dir, format!("pixel size {p} m must be positive")));
        }
        if !(frame_rate.is_finite() && frame_rate > 0.0) {
            return Err(device(
                dir,
                format!("frame rate {frame_rate} must be positive"),
            ));
        }
        let mut cam = FolderCamera {
            dir: dir.to_path_buf(),
            sensor: (0, 0),
            settings: CameraSettings {
                roi: Roi {
                    x: 0,
                    y: 0,
                    width: 0,
                    height: 0,
                },
                binning: 1,
                exposure: 1.0 / frame_rate,
                bit_depth: 8,
            },
            rate: frame_rate,
            pixel_size,
            timeout,
            last: None,
            index: 0,
            start: Instant::now(),
        };
        let names = cam.frames()?;
        let Some(first) = names.first() else {
            return Err(device(
                dir,
                "holds no frame yet (PNG or TIFF): start the acquisition first",
            ));
        };
        let (w, h, _, bits) =
            read_frame(&dir.join(first)).map_err(|e| device(dir, format!("{first}: {e}")))?;
        cam.sensor = (w, h);
        cam.settings.roi = Roi {
            x: 0,
            y: 0,
            width: w,
            height: h,
        };
        cam.settings.bit_depth = if bits == 8 { 8 } else { 12 };
        // Frames already there are the past: a grab waits for the next one.
        cam.last = names.last().cloned();
        Ok(cam)
    }

    /// The frame files now in the folder, sorted by name.
    fn frames(&self) -> Result<Vec<String>, HwError> {
        let mut names: Vec<String> = std::fs::read_dir(&self.dir)
            .map_err(|e| device(&self.dir, format!("cannot list: {e}")))?
            .filter_map(|e| e.ok())
            .filter_map(|e| e.file_name().into_string().ok())
            .filter(|n| is_frame(n))
            .collect();
        names.sort();
        Ok(names)
    }
}

impl Camera for FolderCamera {
    fn sensor_size(&self) -> (u32, u32) {
        self.sensor
    }
    fn settings(&self) -> CameraSettings {
        self.settings
    }
    fn configure(&mut self, s: CameraSettings) -> Result<(), HwError> {
        let r = s.roi;
        if ![1, 2, 4].contains(&s.binning) {
            return Err(device(
                &self.dir,
                format!("binning {} (1, 2 or 4)", s.binning),
            ));
        }
        if r.width == 0
            || r.height == 0
            || r.x.saturating_add(r.width) > self.sensor.0
            || r.y.saturating_add(r.height) > self.sensor.1
            || r.width % s.binning != 0
            || r.height % s.binning != 0
        {
            return Err(device(
                &self.dir,
                format!(
                    "region {}x{} at ({}, {}) binned {} does not fit the {}x{} frames",
                    r.width, r.height, r.x, r.y, s.binning, self.sensor.0, self.sensor.1
                ),
            ));
        }
        if !(s.exposure.is_finite() && s.exposure > 0.0) {
            return Err(device(&self.dir, format!("exposure {} s", s.exposure)));
        }
        // The exposure and bit depth are the acquisition program's: kept as stated.
        self.settings = CameraSettings {
            exposure: self.settings.exposure,
            bit_depth: self.settings.bit_depth,
            ..s
        };
        Ok(())
    }
    fn frame_rate(&self) -> f64 {
        self.rate
    }
    fn grab_into(&mut self, frame: &mut Frame) -> Result<(), HwError> {
        let t0 = Instant::now();
        let name = loop {
            let names = self.frames()?;
            let next = names
                .into_iter()
                .find(|n| self.last.as_ref().is_none_or(|l| n > l));
            if let Some(n) = next {
                break n;
            }
            if t0.elapsed() >= self.timeout {
                return Err(HwError::Timeout {
                    device: format!("camera folder `{}` (no new frame)", self.dir.display()),
                    seconds: self.timeout.as_secs_f64(),
                });
            }
            std::thread::sleep(Duration::from_millis(2));
        };
        let path = self.dir.join(&name);
        // A frame that cannot be read is reported once and passed over.
        self.last = Some(name.clone());
        let (w, h, px, bits) =
            read_frame(&path).map_err(|e| device(&self.dir, format!("{name}: {e}")))?;
        if (w, h) != self.sensor {
            return Err(device(
                &self.dir,
                format!(
                    "{name}: {w}x{h} pixels, the first frame had {}x{}",
                    self.sensor.0, self.sensor.1
                ),
            ));
        }
        let s = self.settings;
        let b = s.binning;
        let (ow, oh) = (s.roi.width / b, s.roi.height / b);
        // 16-bit files keep their 12 significant bits (the Frame's convention).
        let shift = if bits == 16 { 4 } else { 0 };
        frame.pixels.clear();
        frame.pixels.reserve((ow * oh) as usize);
        for j in 0..oh {
            for i in 0..ow {
                let mut sum = 0u32;
                for dj in 0..b {
                    for di in 0..b {
                        let x = s.roi.x + i * b + di;
                        let y = s.roi.y + j * b + dj;
                        sum += u32::from(px[(y * w + x) as usize] >> shift);
                    }
                }
                frame.pixels.push((sum / (b * b)) as u16);
            }
        }
        frame.width = ow;
        frame.height = oh;
        frame.bit_depth = s.bit_depth;
        frame.timestamp = self.start.elapsed().as_secs_f64();
        frame.exposure = s.exposure;
        frame.pixel_size = (self.pixel_size)() * f64::from(b);
        frame.index = self.index;
        self.index += 1;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d =
            std::env::temp_dir().join(format!("cellinject-folder-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn write(d: &Path, name: &str, w: u32, h: u32, f: impl Fn(u32, u32) -> u16) {
        let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(w, h, |x, y| {
            image::Luma([f(x, y)])
        });
        // As an acquisition program should: whole, then renamed.
        let part = d.join(format!(".{name}.part.png"));
        img.save(&part).unwrap();
        std::fs::rename(&part, d.join(name)).unwrap();
    }

    #[test]
    fn frames_arrive_in_name_order_cropped_and_binned() {
        let d = dir("order");
        write(&d, "f000.png", 8, 6, |_, _| 0);
        let mut cam =
            FolderCamera::new(&d, Box::new(|| 1e-6), 10.0, Duration::from_millis(300)).unwrap();
        assert_eq!(cam.sensor_size(), (8, 6));
        // The frame already there is the past: nothing new yet.
        assert!(matches!(cam.grab(), Err(HwError::Timeout { .. })));
        let d2 = d.clone();
        let writer = std::thread::spawn(move || {
            for k in 1..=3u16 {
                std::thread::sleep(Duration::from_millis(30));
                write(&d2, &format!("f{k:03}.png"), 8, 6, |x, y| {
                    (k * 1000 + (y * 8 + x) as u16) << 4
                });
            }
        });
        let f = cam.grab().unwrap();
        assert_eq!((f.width, f.height, f.index), (8, 6, 0));
        assert_eq!(f.pixels[9], 1009, "16-bit files keep 12 significant bits");
        let mut s = cam.settings();
        s.roi = Roi {
            x: 2,
            y: 2,
            width: 4,
            height: 4,
        };
        s.binning = 2;
        cam.configure(s).unwrap();
        let f = cam.grab().unwrap();
        assert_eq!((f.width, f.height), (2, 2));
        // Mean of (2,2),(3,2),(2,3),(3,3) of frame 2: 2000 + (18+19+26+27)/4.
        assert_eq!(f.pixels[0], 2000 + 22);
        assert!((f.pixel_size - 2e-6).abs() < 1e-18);
        writer.join().unwrap();
        let f = cam.grab().unwrap();
        assert_eq!(f.pixels[0], 3000 + 22);
        assert_eq!(f.index, 2);
    }

    #[test]
    fn bad_folders_frames_and_settings_are_refused_with_the_reason() {
        let d = dir("bad");
        assert!(FolderCamera::new(&d, Box::new(|| 1e-6), 10.0, Duration::from_millis(50)).is_err());
        write(&d, "a.png", 4, 4, |_, _| 0);
        assert!(
            FolderCamera::new(&d, Box::new(|| f64::NAN), 10.0, Duration::from_millis(50)).is_err()
        );
        let mut cam =
            FolderCamera::new(&d, Box::new(|| 1e-6), 10.0, Duration::from_millis(200)).unwrap();
        let mut s = cam.settings();
        s.roi.width = 5;
        assert!(cam.configure(s).is_err());
        std::fs::write(d.join("b.png"), b"not a png").unwrap();
        let e = cam.grab().unwrap_err().to_string();
        assert!(e.contains("b.png"), "{e}");
        write(&d, "c.png", 6, 4, |_, _| 0);
        let e = cam.grab().unwrap_err().to_string();
        assert!(e.contains("6x4"), "{e}");
    }
}
