//! The GenICam backend against Aravis's own simulated cameras: the in-process fake
//! camera (deterministic, no network) and `arv-fake-gv-camera-0.8` on 127.0.0.1 (GigE
//! Vision discovery, control and streaming over loopback).
//!
//! Run with the feature on: `cargo test -p cellinject-genicam --features aravis`
//! (needs Debian's `libaravis-dev` and, for the GigE Vision tests, `aravis-tools`).

#![cfg(feature = "aravis")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::Mutex;
use std::time::{Duration, Instant};

use cellinject_dic::track::{Status, Tracker};
use cellinject_dic::{Image, Shape};
use cellinject_genicam::device::{GenicamCamera, Pattern, list};
use cellinject_genicam::simulator::GvSimulator;
use cellinject_genicam::{GenicamError, PixelFormat, Region, Request};
use cellinject_hw::{Camera, Frame, Roi};

fn pitch() -> Box<dyn Fn() -> f64 + Send> {
    Box::new(|| 1e-6)
}

/// The shift of the painted texture in frame `id`, pixels: a known sub-pixel step per
/// frame, cycling every 8 frames (GigE Vision frame ids wrap).
fn shift(id: u64) -> (f64, f64) {
    let k = (id % 8) as f64;
    (0.37 * k, -0.23 * k)
}

/// A smooth random texture (a sum of plane waves), band-limited well below Nyquist,
/// so its shifted copy is exact and independent of the DIC's interpolant.
fn texture(seed: u64) -> Vec<(f64, f64, f64, f64)> {
    let mut s = seed;
    let mut next = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..24)
        .map(|_| {
            let angle = next() * std::f64::consts::TAU;
            let wavelength = 6.0 + 14.0 * next();
            let k = std::f64::consts::TAU / wavelength;
            (
                k * angle.cos(),
                k * angle.sin(),
                next() * std::f64::consts::TAU,
                0.6 + 0.4 * next(),
            )
        })
        .collect()
}

fn painter(waves: Vec<(f64, f64, f64, f64)>) -> Pattern {
    let norm: f64 = waves.iter().map(|w| w.3).sum();
    Box::new(move |id, w, h, bytes| {
        let (dx, dy) = shift(id);
        for y in 0..h {
            for x in 0..w {
                let (px, py) = (x as f64 - dx, y as f64 - dy);
                let v: f64 = waves
                    .iter()
                    .map(|&(kx, ky, ph, a)| a * (kx * px + ky * py + ph).cos())
                    .sum();
                bytes[y * w + x] = (127.5 + 110.0 * v / norm * 2.5).round().clamp(0.0, 255.0) as u8;
            }
        }
    })
}

#[test]
fn the_fake_camera_streams_painted_frames_that_dic_tracks_to_the_painted_shift() {
    let mut cam = GenicamCamera::open_fake("DIC01", Some(painter(texture(3))), pitch()).unwrap();
    cam.apply(&Request {
        roi: Some(Region {
            x: 0,
            y: 0,
            width: 256,
            height: 192,
        }),
        pixel_format: Some(PixelFormat::Mono8),
        ..Request::default()
    })
    .unwrap();
    let mut frame = Frame::default();
    let mut ids = Vec::new();
    let mut stamps = Vec::new();
    let mut tracker: Option<Tracker> = None;
    let mut worst = 0.0f64;
    for _ in 0..10 {
        let g = cam.next(&mut frame, Duration::from_secs(10)).unwrap();
        assert_eq!((frame.width, frame.height, frame.bit_depth), (256, 192, 8));
        assert_eq!(g.pixel_format, PixelFormat::Mono8);
        ids.push(g.frame_id);
        stamps.push(g.timestamp_ns);
        let img = Image::from_frame(&frame).unwrap();
        match &mut tracker {
            None => {
                let roi = Roi {
                    x: 96,
                    y: 64,
                    width: 61,
                    height: 61,
                };
                tracker = Some(Tracker::new(&img, roi, Shape::Rigid, 0.9).unwrap());
            }
            Some(t) => {
                let p = t.track(&img).unwrap();
                assert_ne!(p.status, Status::Rejected);
                let (a, b) = (shift(ids[0]), shift(g.frame_id));
                let (eu, ev) = (p.u - (b.0 - a.0), p.v - (b.1 - a.1));
                worst = worst.max(eu.hypot(ev));
            }
        }
    }
    // Consecutive frames from the camera's stream, stamped by its clock.
    assert!(stamps.windows(2).all(|w| w[1] > w[0]), "{stamps:?}");
    assert!(
        worst < 0.05,
        "worst tracking error {worst} px against the painted shift"
    );
    let s = cam.stats();
    assert!(s.completed >= 10, "{s:?}");
    assert_eq!(s.incomplete, 0);
}

#[test]
fn settings_reach_the_fake_camera_and_bad_ones_change_nothing() {
    let mut cam = GenicamCamera::open_fake("SET01", None, pitch()).unwrap();
    let before = cam.info().unwrap();
    assert_eq!(before.vendor, "Aravis");
    assert!(
        before.limits.pixel_formats.iter().any(|f| f == "Mono8"),
        "{:?}",
        before.limits
    );
    cam.apply(&Request {
        exposure: Some(2e-3),
        roi: Some(Region {
            x: 16,
            y: 8,
            width: 320,
            height: 240,
        }),
        frame_rate: Some(40.0),
        ..Request::default()
    })
    .unwrap();
    let after = cam.info().unwrap();
    assert!((after.exposure - 2e-3).abs() < 1e-6, "{}", after.exposure);
    assert!(
        (after.frame_rate - 40.0).abs() < 1e-6,
        "{}",
        after.frame_rate
    );
    assert_eq!(
        after.region,
        Region {
            x: 16,
            y: 8,
            width: 320,
            height: 240
        }
    );
    let (sw, sh) = after.limits.sensor;
    let e = cam
        .apply(&Request {
            exposure: Some(5e-3),
            roi: Some(Region {
                x: sw - 10,
                y: 0,
                width: 64,
                height: 64,
            }),
            ..Request::default()
        })
        .unwrap_err();
    assert!(
        matches!(
            e,
            GenicamError::Invalid {
                argument: "--roi",
                ..
            }
        ),
        "{e}"
    );
    let kept = cam.info().unwrap();
    assert!(
        (kept.exposure - 2e-3).abs() < 1e-6,
        "a refused request changed the exposure"
    );
    assert!(sh > 0);
    // Through the bench's trait: the frame has the region's size.
    let mut s = cam.settings();
    s.roi = Roi {
        x: 0,
        y: 0,
        width: 128,
        height: 96,
    };
    cam.configure(s).unwrap();
    let f = cam.grab().unwrap();
    assert_eq!((f.width, f.height, f.pixels.len()), (128, 96, 128 * 96));
    assert!((f.pixel_size - 1e-6).abs() < 1e-12);
    // The bench's region is in sensor pixels: binned 2x2, 512 x 384 of them make a
    // 256 x 192 frame of pixels twice the size, in 16 bits where 12 are asked for.
    let mut s = cam.settings();
    s.roi = Roi {
        x: 64,
        y: 32,
        width: 512,
        height: 384,
    };
    s.binning = 2;
    s.bit_depth = 12;
    cam.configure(s).unwrap();
    assert_eq!(cam.settings().roi, s.roi);
    let f = cam.grab().unwrap();
    assert_eq!((f.width, f.height, f.bit_depth), (256, 192, 16));
    assert!((f.pixel_size - 2e-6).abs() < 1e-12);
}

/// The GigE Vision simulator on loopback; one at a time (they share UDP port 3956).
static GV: Mutex<()> = Mutex::new(());

#[test]
fn the_gige_simulator_is_listed_streamed_and_exclusive() {
    let _one = GV.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let _sim = GvSimulator::start("GVT1").unwrap();
    let id = "Aravis-GVT1";
    let mut cam = GenicamCamera::open(id, Duration::from_secs(20), pitch()).unwrap();
    let seen = list();
    // Aravis names it vendor-model-serial; it answers to the shorter id above too.
    assert!(
        seen.iter()
            .any(|d| d.serial == "GVT1" && d.address == "127.0.0.1" && d.interface == "GigEVision"),
        "{seen:?}"
    );
    let mut frame = Frame::default();
    let mut first = Vec::new();
    let mut ids = Vec::new();
    for k in 0..3 {
        let g = cam.next(&mut frame, Duration::from_secs(10)).unwrap();
        ids.push(g.frame_id);
        if k == 0 {
            first = frame.pixels.clone();
        }
    }
    assert_ne!(
        first, frame.pixels,
        "the simulator's ramp moves between frames"
    );
    // A second connection while the first holds the control channel.
    let e = GenicamCamera::open(id, Duration::from_secs(5), pitch())
        .err()
        .expect("a second controller was let in");
    assert!(e.to_string().contains("control"), "{e}");
    drop(cam);
}

#[test]
fn a_simulator_killed_mid_stream_ends_the_grab_with_a_device_error() {
    let _one = GV.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let mut sim = GvSimulator::start("GVT2").unwrap();
    let mut cam = GenicamCamera::open("Aravis-GVT2", Duration::from_secs(20), pitch()).unwrap();
    let mut frame = Frame::default();
    cam.next(&mut frame, Duration::from_secs(10)).unwrap();
    eprintln!("kill at {:?}", std::time::SystemTime::now());
    sim.kill();
    let t = Instant::now();
    let e = loop {
        match cam.next(&mut frame, Duration::from_secs(3)) {
            Ok(_) => {
                eprintln!("frame {:.2} s after the kill", t.elapsed().as_secs_f64());
                assert!(
                    t.elapsed() < Duration::from_secs(10),
                    "frames after the kill"
                );
            }
            Err(e) => break e,
        }
    };
    eprintln!(
        "the grab ended {:.2} s after the kill: {e}",
        t.elapsed().as_secs_f64()
    );
    assert!(matches!(e, GenicamError::Device { .. }), "{e}");
    assert!(e.to_string().contains("Aravis-GVT2"), "{e}");
    assert!(t.elapsed() < Duration::from_secs(30), "{:?}", t.elapsed());
}

#[test]
fn an_absent_camera_is_refused_within_the_timeout_naming_what_was_tried() {
    let t = Instant::now();
    let e = GenicamCamera::open("no-such-camera", Duration::from_secs(2), pitch())
        .err()
        .unwrap();
    assert!(t.elapsed() < Duration::from_secs(30), "{:?}", t.elapsed());
    let m = e.to_string();
    assert!(m.contains("no-such-camera") && m.contains("tried"), "{m}");
}
