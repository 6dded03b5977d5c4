//! The servers: the GCS port (one client at a time, in turn), the bench endpoint, and
//! the ticker that keeps the twin on the wall clock.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use cellinject_hw::{Camera, CameraSettings, Frame, Injector, Optics, Roi, Stage};
use cellinject_twin::{TwinBackend, TwinCamera};
use serde_json::json;

use crate::bench::{self, FrameHeader, Request, ViewName};
use crate::controller::Controller;

/// Whether an IO error only means "nothing yet" (the 50 ms read timeout that lets a
/// connection notice the shutdown).
fn is_wait(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::WouldBlock
            | std::io::ErrorKind::TimedOut
            | std::io::ErrorKind::Interrupted
    )
}

/// Longest command line accepted; a longer one is dropped with error 1.
pub const MAX_LINE: usize = 4096;

struct Shared {
    ctl: Mutex<Controller>,
    /// Wall instant of twin time `t0`.
    start: Instant,
    t0: f64,
    stop: AtomicBool,
    log: bool,
}

impl Shared {
    fn wall(&self) -> f64 {
        self.t0 + self.start.elapsed().as_secs_f64()
    }

    /// The controller, its twin brought up to the wall clock.
    fn sync(&self) -> MutexGuard<'_, Controller> {
        let mut c = self.ctl.lock().unwrap_or_else(|e| e.into_inner());
        let w = self.wall();
        c.step_to(w);
        c
    }

    fn sleep_until(&self, t: f64) {
        loop {
            let w = self.wall();
            if w >= t || self.stop.load(Ordering::Relaxed) {
                return;
            }
            std::thread::sleep(Duration::from_secs_f64((t - w).min(0.005)));
        }
    }
}

/// A running emulator.
pub struct Running {
    shared: Arc<Shared>,
    /// Where the GCS port listens.
    pub gcs: SocketAddr,
    /// Where the bench endpoint listens.
    pub bench: Option<SocketAddr>,
    threads: Vec<JoinHandle<()>>,
}

impl Running {
    /// Stops serving and joins the threads.
    pub fn shutdown(mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }

    /// Blocks until the process is killed.
    pub fn wait(mut self) {
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// Serves `ctl` on `gcs` (and the bench devices on `bench`), from now on.
pub fn serve(
    ctl: Controller,
    bench_devices: Option<cellinject_rig::Devices<TwinBackend>>,
    gcs: TcpListener,
    bench: Option<TcpListener>,
    log: bool,
) -> std::io::Result<Running> {
    let t0 = ctl.time();
    let shared = Arc::new(Shared {
        ctl: Mutex::new(ctl),
        start: Instant::now(),
        t0,
        stop: AtomicBool::new(false),
        log,
    });
    let gcs_addr = gcs.local_addr()?;
    gcs.set_nonblocking(true)?;
    let mut threads = Vec::new();
    let s = shared.clone();
    threads.push(std::thread::spawn(move || {
        while !s.stop.load(Ordering::Relaxed) {
            drop(s.sync());
            std::thread::sleep(Duration::from_millis(1));
        }
    }));
    let s = shared.clone();
    threads.push(std::thread::spawn(move || accept(&s, &gcs, serve_gcs)));
    let mut bench_addr = None;
    if let (Some(l), Some(d)) = (bench, bench_devices) {
        bench_addr = Some(l.local_addr()?);
        l.set_nonblocking(true)?;
        let s = shared.clone();
        let devices = Mutex::new(d);
        threads.push(std::thread::spawn(move || {
            accept(&s, &l, |s, stream| {
                let mut d = devices.lock().unwrap_or_else(|e| e.into_inner());
                serve_bench(s, stream, &mut d);
            })
        }));
    }
    Ok(Running {
        shared,
        gcs: gcs_addr,
        bench: bench_addr,
        threads,
    })
}

/// Clients one at a time, in turn.
fn accept(s: &Arc<Shared>, l: &TcpListener, mut handle: impl FnMut(&Shared, TcpStream)) {
    while !s.stop.load(Ordering::Relaxed) {
        match l.accept() {
            Ok((stream, peer)) => {
                if s.log {
                    eprintln!(
                        "emulator: {peer} connected to {}",
                        l.local_addr().map(|a| a.to_string()).unwrap_or_default()
                    );
                }
                let _ = stream.set_nonblocking(false);
                let _ = stream.set_nodelay(true);
                let _ = stream.set_read_timeout(Some(Duration::from_millis(50)));
                handle(s, stream);
                if s.log {
                    eprintln!("emulator: {peer} disconnected");
                }
            }
            Err(_) => std::thread::sleep(Duration::from_millis(5)),
        }
    }
}

fn serve_gcs(s: &Shared, mut stream: TcpStream) {
    let mut line: Vec<u8> = Vec::with_capacity(256);
    let mut overflow = false;
    let mut chunk = [0u8; 4096];
    let mut out = Vec::with_capacity(256);
    while !s.stop.load(Ordering::Relaxed) {
        let n = match stream.read(&mut chunk) {
            Ok(0) => return,
            Ok(n) => n,
            Err(e) if is_wait(&e) => {
                continue;
            }
            Err(_) => return,
        };
        out.clear();
        for &b in &chunk[..n] {
            match b {
                crate::MOVING => {
                    let m = s.sync().moving_mask();
                    out.extend_from_slice(format!("{m:X}\n").as_bytes());
                }
                crate::READY => out.extend_from_slice(&[crate::READY_BYTE, b'\n']),
                crate::STOP_ALL => s.sync().stop(&[0, 1, 2]),
                b'\n' => {
                    if overflow {
                        s.sync().raise_syntax();
                    } else {
                        let text = String::from_utf8_lossy(&line);
                        let text = text.trim_end_matches('\r');
                        if s.log {
                            eprintln!("emulator: < {text}");
                        }
                        if let Some(r) = s.sync().execute(text) {
                            if s.log {
                                eprint!("emulator: > {r}");
                            }
                            out.extend_from_slice(r.as_bytes());
                        }
                    }
                    line.clear();
                    overflow = false;
                }
                _ if line.len() < MAX_LINE => line.push(b),
                _ => overflow = true,
            }
        }
        if !out.is_empty() && stream.write_all(&out).is_err() {
            return;
        }
    }
}

fn view_of(v: ViewName) -> usize {
    match v {
        ViewName::Top => 0,
        ViewName::Side => 1,
    }
}

fn serve_bench(s: &Shared, stream: TcpStream, d: &mut cellinject_rig::Devices<TwinBackend>) {
    let Ok(mut writer) = stream.try_clone() else {
        return;
    };
    let mut reader = BufReader::new(stream);
    let mut line = String::new();
    let mut frame = Frame::default();
    while !s.stop.load(Ordering::Relaxed) {
        line.clear();
        match reader.read_line(&mut line) {
            Ok(0) => return,
            Ok(_) => {}
            Err(e) if is_wait(&e) => {
                continue;
            }
            Err(_) => return,
        }
        if line.len() > 64 * 1024 {
            let _ = writer.write_all(bench::error("request longer than 64 KiB").as_bytes());
            continue;
        }
        let req: Request = match serde_json::from_str(line.trim_end()) {
            Ok(r) => r,
            Err(e) => {
                if writer
                    .write_all(bench::error(format!("bad request: {e}")).as_bytes())
                    .is_err()
                {
                    return;
                }
                continue;
            }
        };
        let mut payload: Option<Vec<u8>> = None;
        let reply = handle_bench(s, d, &req, &mut frame, &mut payload);
        if writer.write_all(reply.as_bytes()).is_err() {
            return;
        }
        if let Some(p) = payload
            && writer.write_all(&p).is_err()
        {
            return;
        }
    }
}

fn stage_of(
    d: &mut cellinject_rig::Devices<TwinBackend>,
    unit: bench::StageUnit,
) -> &mut cellinject_twin::devices::TwinStage {
    match unit {
        bench::StageUnit::Macro => &mut d.stage,
        bench::StageUnit::Feeder => &mut d.feeder,
    }
}

fn camera(d: &mut cellinject_rig::Devices<TwinBackend>, v: ViewName) -> &mut TwinCamera {
    if view_of(v) == 0 {
        &mut d.camera
    } else {
        &mut d.side_camera
    }
}

fn handle_bench(
    s: &Shared,
    d: &mut cellinject_rig::Devices<TwinBackend>,
    req: &Request,
    frame: &mut Frame,
    payload: &mut Option<Vec<u8>>,
) -> String {
    let r = |x: Result<serde_json::Value, cellinject_hw::HwError>| match x {
        Ok(v) => bench::ok(v),
        Err(e) => bench::error(e),
    };
    match *req {
        Request::CameraInfo { view } => {
            let _c = s.sync();
            let cam = camera(d, view);
            let st = cam.settings();
            bench::ok(json!({
                "sensor": [cam.sensor_size().0, cam.sensor_size().1],
                "roi": [st.roi.x, st.roi.y, st.roi.width, st.roi.height],
                "binning": st.binning,
                "exposure": st.exposure,
                "bit_depth": st.bit_depth,
                "frame_rate": cam.frame_rate(),
            }))
        }
        Request::CameraConfigure {
            view,
            roi,
            binning,
            exposure,
            bit_depth,
        } => {
            let _c = s.sync();
            r(camera(d, view)
                .configure(CameraSettings {
                    roi: Roi {
                        x: roi[0],
                        y: roi[1],
                        width: roi[2],
                        height: roi[3],
                    },
                    binning,
                    exposure,
                    bit_depth,
                })
                .map(|()| json!(null)))
        }
        Request::Grab { view } => {
            // Wait (unlocked) for the next frame's start, expose it, and answer when
            // the wall clock has reached the end of its exposure.
            let start = {
                let _c = s.sync();
                let cam = camera(d, view);
                let period = 1.0 / cam.frame_rate();
                let now = s.wall();
                (now / period - 1e-9).ceil() * period
            };
            s.sleep_until(start);
            let res = {
                let mut c = s.sync();
                c.step_to(start);
                camera(d, view).grab_into(frame)
            };
            if let Err(e) = res {
                return bench::error(e);
            }
            s.sleep_until(frame.timestamp + frame.exposure);
            let mut bytes = Vec::with_capacity(2 * frame.pixels.len());
            for p in &frame.pixels {
                bytes.extend_from_slice(&p.to_le_bytes());
            }
            let h = FrameHeader {
                width: frame.width,
                height: frame.height,
                bit_depth: frame.bit_depth,
                timestamp: frame.timestamp,
                exposure: frame.exposure,
                pixel_size: frame.pixel_size,
                index: frame.index,
                bytes: bytes.len(),
            };
            *payload = Some(bytes);
            bench::ok(serde_json::to_value(h).unwrap_or_default())
        }
        Request::StageMove {
            unit,
            axis,
            position,
        } => {
            let _c = s.sync();
            let stage = stage_of(d, unit);
            if axis >= stage.axes() {
                return bench::error(format!(
                    "{unit:?} stage axis {axis} does not exist (0..{})",
                    stage.axes()
                ));
            }
            r(stage.move_to(axis, position).map(|()| json!(null)))
        }
        Request::StagePosition { unit, axis } => {
            let _c = s.sync();
            let stage = stage_of(d, unit);
            if axis >= stage.axes() {
                return bench::error(format!("{unit:?} stage axis {axis} does not exist"));
            }
            r(stage.position(axis).map(|p| json!(p)))
        }
        Request::StageBusy { unit } => {
            let _c = s.sync();
            r(stage_of(d, unit).is_busy().map(|b| json!(b)))
        }
        Request::StageTravel { unit, axis } => {
            let stage = stage_of(d, unit);
            if axis >= stage.axes() {
                return bench::error(format!("{unit:?} stage axis {axis} does not exist"));
            }
            let (lo, hi) = stage.travel(axis);
            bench::ok(json!([lo, hi]))
        }
        Request::StageAxes { unit } => bench::ok(json!(stage_of(d, unit).axes())),
        Request::Pulse { pressure, duration } => {
            let res = {
                let _c = s.sync();
                d.injector.pulse(pressure, duration)
            };
            if res.is_ok() {
                let end = s.ctl.lock().unwrap_or_else(|e| e.into_inner()).time();
                s.sleep_until(end);
            }
            r(res.map(|()| json!(null)))
        }
        Request::MaxPressure => bench::ok(json!(d.injector.max_pressure())),
        Request::Zoom => bench::ok(json!(d.optics.zoom())),
        Request::SetZoom { zoom } => {
            let _c = s.sync();
            r(d.optics.set_zoom(zoom).map(|()| json!(null)))
        }
        Request::ZoomRange => {
            let (a, b) = d.optics.zoom_range();
            bench::ok(json!([a, b]))
        }
        Request::Time => bench::ok(json!(s.wall())),
    }
}
