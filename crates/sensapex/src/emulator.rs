//! An SMCP1 device emulator: uMp manipulators, uMs stages and uMv pressure
//! controllers on one UDP socket, answering what Sensapex's client library (libum,
//! v1.504) sends, so that Sensapex's own SDK, the driver of this crate and any other
//! SMCP1 client can be exercised without hardware.
//!
//! What it speaks (`inc/smcp1.h`; every request is acknowledged when it asks for an
//! ACK, a retransmission of the same command is acknowledged again and not executed
//! twice, a retransmitted query is answered again):
//!
//! - `PING` (0), to a device or to every device (0xff): ACK (and the request echoed
//!   when a response is asked for): what discovery needs;
//! - `STOP` (1): every axis decelerates to rest;
//! - `GET_POSITIONS` (14): X, Y, Z (and D on a 4-axis uMp), nm;
//! - `GET_PARAMETER` (16) / `SET_PARAMETER` (15): the axis count (0x105), the device
//!   id (3), the memory speed (2), the serial number (0x102); others read 0;
//! - `GET_VERSION` (23): the emulator's firmware version, five INT32 parts;
//! - `GOTO_POS` (33): targets in nm (`0x7fffffff`: axis not moved), speed µm/s
//!   (negative: nm/s), mode (0 axis by axis in X, Y, Z, D order, 1 simultaneous),
//!   acceleration µm/s² (0: the device's default), per-axis speeds in a second
//!   sub-block. Each axis moves on a trapezoidal profile in wall-clock time and
//!   ends exactly on its target; a target outside the travel stops at the limit and
//!   the move fails (sticky error state, status ERROR);
//! - `TAKE_STEP` (34): relative steps, nm, at per-axis speeds, µm/s;
//! - `READ_ERROR_STATE` (41) / `CLEAR_ERROR_STATE` (42);
//! - uMs `UMS_GET_LENS_POSITION` (63) / `UMS_SET_LENS_POSITION` (64): lens 0, 1 or 2;
//! - uMv `UMV_SET_PRESSURE` (88), `UMV_GET_PRESSURE` (89), `UMV_SET_VALVE` (92),
//!   `UMV_GET_VALVE` (93), `UMV_MEASURE_PRESSURE` (94): channels 0..7 on the wire,
//!   Pa, within ±100 kPa; the measured pressure follows the set point with a 20 ms
//!   time constant.
//!
//! While a device moves it notifies the client that commanded it: `STATUS_CHANGED`
//! (busy and the moving axes' bits) at the start, `POSITION_CHANGED` every
//! [`NOTIFY_EVERY`], and at the end the exact final position, `STATUS_CHANGED` 0 and
//! `GOTO_POS_COMPLETED` (0, or 8 when the move failed or was stopped), in that order,
//! which is what libum's drive status reads. Anything else is answered with the
//! ERROR option. A device [`Running::mute`]d, or in one of its
//! [`Running::silence`]s, answers nothing (a cable pulled).

use std::collections::HashMap;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::protocol::{ALL_DEVICES, ARG_UNDEF, Frame, MAX_DATAGRAM, SubBlock, cmd, opt, param};

/// How often a moving device notifies its position.
pub const NOTIFY_EVERY: Duration = Duration::from_millis(20);
/// Firmware version the emulated devices report (`GET_VERSION`).
pub const FIRMWARE: [i32; 5] = [1, 504, 0, 0, 0];
/// Default speed of a goto without one, µm/s.
pub const DEFAULT_SPEED: f64 = 1000.0;
/// Default acceleration, µm/s².
pub const DEFAULT_ACCELERATION: f64 = 50_000.0;
/// Largest pressure magnitude a uMv channel accepts, Pa.
pub const MAX_PRESSURE: i32 = 100_000;
/// Pressure channels of a uMv.
pub const CHANNELS: usize = 8;
/// Time constant of a channel's pressure regulation, s.
pub const PRESSURE_TAU: f64 = 0.02;

/// What kind of Sensapex device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A uMp micromanipulator, 3 or 4 axes (the fourth, D, along the pipette),
    /// 0..20 mm each.
    Manipulator {
        /// 3 or 4.
        axes: usize,
    },
    /// A uMs stage: X and Y 0..50 mm, focus Z 0..25 mm, and a lens changer.
    Stage,
    /// A uMv / uMc pressure controller, [`CHANNELS`] channels.
    Pressure,
}

impl Kind {
    /// Travel of each axis, nm.
    pub fn travel(self) -> Vec<(i64, i64)> {
        match self {
            Kind::Manipulator { axes } => vec![(0, 20_000_000); axes],
            Kind::Stage => vec![(0, 50_000_000), (0, 50_000_000), (0, 25_000_000)],
            Kind::Pressure => Vec::new(),
        }
    }

    /// The short name used in `--devices` (`ump`, `ump4`, `ums`, `umv`).
    pub fn name(self) -> &'static str {
        match self {
            Kind::Manipulator { axes: 4 } => "ump4",
            Kind::Manipulator { .. } => "ump",
            Kind::Stage => "ums",
            Kind::Pressure => "umv",
        }
    }
}

/// One emulated device: its id and kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceSpec {
    /// SMCP1 device id (1..254).
    pub id: u16,
    /// Kind.
    pub kind: Kind,
}

/// Parses `ump:1,ums:21,umv:31` (`ump4` for a 4-axis uMp).
pub fn parse_devices(s: &str) -> Result<Vec<DeviceSpec>, String> {
    let mut out: Vec<DeviceSpec> = Vec::new();
    for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (kind, id) = part
            .split_once(':')
            .ok_or_else(|| format!("`{part}`: a device is KIND:ID, e.g. ump:1, ums:21, umv:31"))?;
        let kind = match kind.trim() {
            "ump" => Kind::Manipulator { axes: 3 },
            "ump4" => Kind::Manipulator { axes: 4 },
            "ums" => Kind::Stage,
            "umv" | "umc" => Kind::Pressure,
            k => {
                return Err(format!(
                    "`{part}`: unknown device kind `{k}` (ump, ump4, ums, umv)"
                ));
            }
        };
        let id: u16 = id
            .trim()
            .parse()
            .ok()
            .filter(|i| (1..=254).contains(i))
            .ok_or_else(|| format!("`{part}`: the device id must be a whole number 1..254"))?;
        if out.iter().any(|d| d.id == id) {
            return Err(format!("`{part}`: device id {id} is given twice"));
        }
        out.push(DeviceSpec { id, kind });
    }
    if out.is_empty() {
        return Err("no device given (e.g. ump:1,ums:21,umv:31)".into());
    }
    Ok(out)
}

/// Parses a fault switch `ID@START[..END]`: device ID silent from START to END s
/// after the emulator starts (for good without END).
pub fn parse_silence(s: &str) -> Result<(u16, f64, Option<f64>), String> {
    let bad = || format!("`{s}`: a silence is ID@START[..END], seconds, e.g. 1@60..75");
    let (id, window) = s.split_once('@').ok_or_else(bad)?;
    let id: u16 = id.trim().parse().map_err(|_| bad())?;
    let (from, until) = match window.split_once("..") {
        Some((a, b)) => (a, Some(b)),
        None => (window, None),
    };
    let num = |v: &str| -> Result<f64, String> {
        v.trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite() && *x >= 0.0)
            .ok_or_else(bad)
    };
    let from = num(from)?;
    let until = until.map(num).transpose()?;
    if until.is_some_and(|u| u <= from) {
        return Err(format!("`{s}`: the silence must end after it starts"));
    }
    Ok((id, from, until))
}

/// One axis's trapezoidal move, nm and s.
#[derive(Debug, Clone, Copy)]
struct Segment {
    from: f64,
    to: f64,
    speed: f64,
    accel: f64,
    start: f64,
}

impl Segment {
    /// Duration of the accelerating part, the cruise and the whole move.
    fn timing(&self) -> (f64, f64, f64) {
        let d = (self.to - self.from).abs();
        let ta = self.speed / self.accel;
        if self.accel * ta * ta >= d {
            // Triangular: never reaches the speed.
            let ta = (d / self.accel).sqrt();
            (ta, 0.0, 2.0 * ta)
        } else {
            let cruise = (d - self.accel * ta * ta) / self.speed;
            (ta, cruise, 2.0 * ta + cruise)
        }
    }

    fn end(&self) -> f64 {
        self.start + self.timing().2
    }

    /// Position at time `t`.
    fn at(&self, t: f64) -> f64 {
        let (ta, cruise, total) = self.timing();
        let s = (t - self.start).clamp(0.0, total);
        let d = (self.to - self.from).abs();
        let vmax = self.accel * ta;
        let done = if s < ta {
            0.5 * self.accel * s * s
        } else if s < ta + cruise {
            0.5 * self.accel * ta * ta + vmax * (s - ta)
        } else {
            let r = total - s;
            d - 0.5 * self.accel * r * r
        };
        if s >= total {
            self.to
        } else {
            self.from + (self.to - self.from).signum() * done.min(d)
        }
    }

    /// Velocity at time `t` (signed, nm/s).
    fn velocity(&self, t: f64) -> f64 {
        let (ta, cruise, total) = self.timing();
        let s = (t - self.start).clamp(0.0, total);
        let sign = (self.to - self.from).signum();
        let v = if s < ta {
            self.accel * s
        } else if s < ta + cruise {
            self.accel * ta
        } else {
            self.accel * (total - s)
        };
        sign * v
    }
}

/// The client a device notifies: its address and SMCP1 id.
#[derive(Debug, Clone, Copy)]
struct Listener {
    addr: SocketAddr,
    id: u16,
}

/// Another model's device an emulated one stands for (the twin's stage or
/// injector in `emulate gcs --sensapex`): its positions and moves, nm in the
/// emulated device's coordinates, and the pulses its valves make.
pub trait Backing: Send {
    /// Every axis's position now, nm (none: a pressure controller's).
    fn positions(&mut self) -> Vec<f64> {
        Vec::new()
    }
    /// Starts moves to `targets` (nm; `None`: not moved); false when the device
    /// refused them (a pressure controller refuses every move).
    fn start(&mut self, _targets: &[Option<f64>]) -> bool {
        false
    }
    /// Stops every axis.
    fn stop(&mut self) {}
    /// Whether it is still moving.
    fn busy(&mut self) -> bool {
        false
    }
    /// A valve was open for `duration` s at `pressure` Pa (just closed).
    fn pulse(&mut self, _pressure: f64, _duration: f64) {}
    /// A uMs's lens changer moved to `position` (1 or 2; 0 the empty centre).
    fn lens(&mut self, _position: i32) {}
}

/// A device to emulate, with what moves it (its own simulated axes when `None`).
pub type Emulated = (DeviceSpec, Option<Box<dyn Backing>>);

/// One device's state.
struct Device {
    spec: DeviceSpec,
    /// Position of each axis at rest, nm.
    rest: Vec<f64>,
    /// Each axis's move (None at rest).
    moves: Vec<Option<Segment>>,
    /// The move's outcome when it ends: 0 completed, 8 failed.
    outcome: i32,
    moving: bool,
    error_state: u32,
    lens: i32,
    params: HashMap<i32, i32>,
    set_point: [f64; CHANNELS],
    pressure: [f64; CHANNELS],
    valve: [i32; CHANNELS],
    listener: Option<Listener>,
    last_notify: f64,
    /// Last (sender, message id) executed: a retransmission is only acknowledged.
    last_request: Option<(u16, u16, u16)>,
    muted: bool,
    /// Windows of the emulator's clock (s) in which it answers nothing.
    silences: Vec<(f64, f64)>,
    /// What moves it, when not its own simulated axes.
    backing: Option<Box<dyn Backing>>,
    /// Axes of the move under way (status bits).
    commanded: u32,
    /// When each valve opened.
    opened: [Option<f64>; CHANNELS],
}

impl Device {
    fn new(spec: DeviceSpec, backing: Option<Box<dyn Backing>>) -> Self {
        let travel = spec.kind.travel();
        Device {
            spec,
            rest: travel
                .iter()
                .map(|&(lo, hi)| 0.5 * (lo + hi) as f64)
                .collect(),
            moves: vec![None; travel.len()],
            outcome: 0,
            moving: false,
            error_state: 0,
            lens: 1,
            params: HashMap::new(),
            set_point: [0.0; CHANNELS],
            pressure: [0.0; CHANNELS],
            valve: [0; CHANNELS],
            listener: None,
            last_notify: 0.0,
            last_request: None,
            muted: false,
            silences: Vec::new(),
            backing,
            commanded: 0,
            opened: [None; CHANNELS],
        }
    }

    /// Whether it answers nothing at `t` (muted, or in a silence).
    fn silent(&self, t: f64) -> bool {
        self.muted || self.silences.iter().any(|&(a, b)| t >= a && t < b)
    }

    fn position(&mut self, t: f64) -> Vec<f64> {
        if let Some(b) = self.backing.as_mut() {
            return b.positions();
        }
        self.moves
            .iter()
            .zip(&self.rest)
            .map(|(m, r)| m.map_or(*r, |s| s.at(t)))
            .collect()
    }

    fn positions_nm(&mut self, t: f64) -> Vec<i32> {
        self.position(t).iter().map(|p| p.round() as i32).collect()
    }

    fn status(&self, t: f64) -> i32 {
        let mut s = 0u32;
        if self.moving {
            s |= crate::protocol::status::BUSY;
            if self.backing.is_some() {
                s |= self.commanded;
            }
            for (k, m) in self.moves.iter().enumerate() {
                if m.is_some_and(|m| t >= m.start && t < m.end()) {
                    s |= crate::protocol::status::X_MOVING << k;
                }
            }
        }
        if self.error_state != 0 {
            s |= crate::protocol::status::ERROR;
        }
        s as i32
    }

    /// Starts moves to `targets` (nm, None: not moved) at `speeds` (nm/s).
    fn start(
        &mut self,
        t: f64,
        targets: &[Option<f64>],
        speeds: &[f64],
        accel: f64,
        together: bool,
    ) {
        self.commanded = targets
            .iter()
            .enumerate()
            .filter(|(_, t)| t.is_some())
            .fold(0, |m, (k, _)| m | (crate::protocol::status::X_MOVING << k));
        if let Some(b) = self.backing.as_mut() {
            let travel = self.spec.kind.travel();
            let clamped: Vec<Option<f64>> = targets
                .iter()
                .zip(&travel)
                .map(|(t, &(lo, hi))| t.map(|t| t.clamp(lo as f64, hi as f64)))
                .collect();
            let failed = clamped != targets[..clamped.len()] || !b.start(&clamped);
            if failed {
                self.error_state |= 0x4;
            }
            self.outcome = if failed { 8 } else { 0 };
            self.moving = true;
            return;
        }
        let travel = self.spec.kind.travel();
        let now = self.position(t);
        let mut start = t;
        let mut failed = false;
        for k in 0..self.rest.len() {
            self.rest[k] = now[k];
            self.moves[k] = None;
            let Some(target) = targets.get(k).copied().flatten() else {
                continue;
            };
            let (lo, hi) = (travel[k].0 as f64, travel[k].1 as f64);
            let to = target.clamp(lo, hi);
            failed |= to != target;
            if (to - now[k]).abs() < 0.5 {
                self.rest[k] = to;
                continue;
            }
            let seg = Segment {
                from: now[k],
                to,
                speed: speeds
                    .get(k)
                    .copied()
                    .unwrap_or(DEFAULT_SPEED * 1e3)
                    .max(1.0),
                accel,
                start,
            };
            if !together {
                start = seg.end();
            }
            self.moves[k] = Some(seg);
        }
        if failed {
            self.error_state |= 0x4;
        }
        self.outcome = if failed { 8 } else { 0 };
        self.moving = true;
    }

    /// Decelerates every axis to rest as fast as its acceleration allows.
    fn stop(&mut self, t: f64) {
        if let Some(b) = self.backing.as_mut() {
            b.stop();
            if self.moving {
                self.outcome = 8;
            }
            return;
        }
        for k in 0..self.rest.len() {
            if let Some(m) = self.moves[k] {
                let (p, v) = (m.at(t), m.velocity(t));
                let brake = v * v / (2.0 * m.accel);
                self.rest[k] = p;
                self.moves[k] = if t < m.start || v == 0.0 {
                    None
                } else {
                    Some(Segment {
                        from: p,
                        to: p + v.signum() * brake,
                        speed: v.abs(),
                        accel: m.accel,
                        start: t,
                    })
                };
                if let Some(s) = self.moves[k] {
                    // From full speed: a triangular profile would accelerate
                    // first; start it at its peak instead.
                    let ta = s.speed / s.accel;
                    self.moves[k] = Some(Segment {
                        from: p - v.signum() * 0.5 * s.accel * ta * ta,
                        start: t - ta,
                        ..s
                    });
                }
            }
        }
        if self.moving {
            self.outcome = 8;
        }
    }

    /// The move has ended: every axis at rest where it is.
    fn finish(&mut self, t: f64) {
        if self.backing.is_some() {
            self.moving = false;
            return;
        }
        self.rest = self.position(t);
        self.moves.iter_mut().for_each(|m| *m = None);
        self.moving = false;
    }

    fn settle_pressure(&mut self, dt: f64) {
        let k = 1.0 - (-dt / PRESSURE_TAU).exp();
        for c in 0..CHANNELS {
            self.pressure[c] += k * (self.set_point[c] - self.pressure[c]);
        }
    }
}

/// Where a [`Running`] emulator logs the datagrams it sends and receives (`--verbose`).
pub type Log = Option<Box<dyn FnMut(&str) + Send>>;

/// The emulator's world: its devices and the wall clock's origin.
struct World {
    devices: Vec<Device>,
    origin: Instant,
    last_tick: f64,
    notify_id: u16,
    /// Datagrams received.
    received: u64,
}

impl World {
    fn now(&self) -> f64 {
        self.origin.elapsed().as_secs_f64()
    }

    fn next_id(&mut self) -> u16 {
        self.notify_id = self.notify_id.wrapping_add(1).max(1);
        self.notify_id
    }
}

/// A running emulator; dropped or [`Running::stop`]ped, it closes its socket.
pub struct Running {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    world: Arc<Mutex<World>>,
    handle: Option<JoinHandle<()>>,
}

impl Running {
    /// The address it listens on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Mutes or unmutes device `id` (it answers nothing while muted, as if its
    /// cable were pulled); false when there is no such device.
    pub fn mute(&self, id: u16, muted: bool) -> bool {
        let mut w = self.world.lock().unwrap_or_else(|e| e.into_inner());
        match w.devices.iter_mut().find(|d| d.spec.id == id) {
            Some(d) => {
                d.muted = muted;
                true
            }
            None => false,
        }
    }

    /// Device `id` answers nothing from `from` to `until` (s after the emulator
    /// started; `None`: for good), as if its cable were pulled then; false when there
    /// is no such device.
    pub fn silence(&self, id: u16, from: f64, until: Option<f64>) -> bool {
        let mut w = self.world.lock().unwrap_or_else(|e| e.into_inner());
        match w.devices.iter_mut().find(|d| d.spec.id == id) {
            Some(d) => {
                d.silences.push((from, until.unwrap_or(f64::INFINITY)));
                true
            }
            None => false,
        }
    }

    /// Device `id`'s positions now, nm (empty for a pressure controller).
    pub fn positions(&self, id: u16) -> Option<Vec<f64>> {
        let mut w = self.world.lock().unwrap_or_else(|e| e.into_inner());
        let t = w.now();
        w.devices
            .iter_mut()
            .find(|d| d.spec.id == id)
            .map(|d| d.position(t))
    }

    /// Datagrams received so far.
    pub fn received(&self) -> u64 {
        self.world
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .received
    }

    /// A pressure controller's channel (0..7): its set point (Pa) and valve.
    pub fn channel(&self, id: u16, channel: usize) -> Option<(f64, i32)> {
        let w = self.world.lock().unwrap_or_else(|e| e.into_inner());
        let d = w.devices.iter().find(|d| d.spec.id == id)?;
        Some((*d.set_point.get(channel)?, d.valve[channel]))
    }

    /// Stops the emulator and waits for its thread.
    pub fn stop(mut self) {
        self.shutdown();
    }

    /// Serves until the process ends.
    pub fn wait(mut self) {
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }

    fn shutdown(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// Serves `devices` on `socket` (bound by the caller: 127.0.0.1:55555 + group for
/// Sensapex's client) until stopped; `log` sees every datagram, decoded.
pub fn serve(socket: UdpSocket, devices: &[DeviceSpec], log: Log) -> std::io::Result<Running> {
    serve_backed(socket, devices.iter().map(|&s| (s, None)).collect(), log)
}

/// [`serve`], each device moved by its [`Backing`] when it has one (else by its
/// own simulated axes).
pub fn serve_backed(
    socket: UdpSocket,
    devices: Vec<Emulated>,
    log: Log,
) -> std::io::Result<Running> {
    socket.set_read_timeout(Some(Duration::from_millis(2)))?;
    let addr = socket.local_addr()?;
    let world = Arc::new(Mutex::new(World {
        devices: devices
            .into_iter()
            .map(|(s, b)| Device::new(s, b))
            .collect(),
        origin: Instant::now(),
        last_tick: 0.0,
        notify_id: 0,
        received: 0,
    }));
    let stop = Arc::new(AtomicBool::new(false));
    let handle = {
        let (world, stop) = (world.clone(), stop.clone());
        std::thread::Builder::new()
            .name("sensapex-emulator".into())
            .spawn(move || run(socket, world, stop, log))?
    };
    Ok(Running {
        addr,
        stop,
        world,
        handle: Some(handle),
    })
}

fn run(socket: UdpSocket, world: Arc<Mutex<World>>, stop: Arc<AtomicBool>, mut log: Log) {
    let mut buf = [0u8; MAX_DATAGRAM];
    let mut out: Vec<(SocketAddr, Frame)> = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        if let Ok((n, from)) = socket.recv_from(&mut buf) {
            let mut w = world.lock().unwrap_or_else(|e| e.into_inner());
            w.received += 1;
            match Frame::decode(&buf[..n]) {
                Ok(f) => {
                    if let Some(l) = log.as_mut() {
                        l(&format!("<- {from} {}", describe(&f)));
                    }
                    handle(&mut w, &f, from, &mut out);
                }
                Err(e) => {
                    if let Some(l) = log.as_mut() {
                        l(&format!("<- {from} not SMCP1 ({e}), ignored"));
                    }
                }
            }
        }
        {
            let mut w = world.lock().unwrap_or_else(|e| e.into_inner());
            tick(&mut w, &mut out);
        }
        for (to, f) in out.drain(..) {
            if let Some(l) = log.as_mut() {
                l(&format!("-> {to} {}", describe(&f)));
            }
            let _ = socket.send_to(&f.encode(), to);
        }
    }
}

/// One line per frame for the log.
pub fn describe(f: &Frame) -> String {
    format!(
        "type {} from {} to {} msg {} options 0x{:x} args {:?}",
        f.kind,
        f.sender,
        f.receiver,
        f.message_id,
        f.options,
        f.blocks.iter().map(|b| &b.values).collect::<Vec<_>>()
    )
}

fn reply(to: &Frame, from: u16, options: u32, blocks: Vec<SubBlock>) -> Frame {
    Frame {
        extra: 0,
        receiver: to.sender,
        sender: from,
        message_id: to.message_id,
        options,
        kind: to.kind,
        blocks,
    }
}

/// Answers one request for every device it addresses.
fn handle(w: &mut World, f: &Frame, from: SocketAddr, out: &mut Vec<(SocketAddr, Frame)>) {
    if !f.is_request() {
        return;
    }
    let t = w.now();
    let broadcast = f.receiver == ALL_DEVICES || f.receiver == 0x7ff;
    for d in w.devices.iter_mut() {
        if d.silent(t) || !(broadcast || f.receiver == d.spec.id) {
            continue;
        }
        d.listener = Some(Listener {
            addr: from,
            id: f.sender,
        });
        let key = (f.sender, f.message_id, f.kind);
        let repeat = d.last_request == Some(key);
        d.last_request = Some(key);
        // A retransmission of a command is acknowledged, not executed again; a
        // query (it asks for a response) is answered again.
        let answer = if repeat && f.options & opt::REQ_RESP == 0 {
            Ok(None)
        } else {
            execute(d, f, t)
        };
        let id = d.spec.id;
        match answer {
            Ok(data) => {
                if f.options & opt::REQ_ACK != 0 {
                    out.push((from, reply(f, id, opt::ACK, Vec::new())));
                }
                if f.options & opt::REQ_RESP != 0 {
                    let blocks = match (data, f.kind) {
                        (Some(v), _) => vec![SubBlock::i32s(&v)],
                        (None, cmd::PING) => f.blocks.clone(),
                        (None, _) => Vec::new(),
                    };
                    if !blocks.is_empty() {
                        out.push((from, reply(f, id, 0, blocks)));
                    }
                }
                let started = matches!(f.kind, cmd::GOTO_POS | cmd::TAKE_STEP);
                if started && d.moving && !repeat {
                    // After the ACK: busy, and where it starts from.
                    let (status, pos) = (d.status(t), d.positions_nm(t));
                    if let Some(l) = d.listener {
                        w.notify_id = w.notify_id.wrapping_add(1).max(1);
                        let n1 = w.notify_id;
                        w.notify_id = w.notify_id.wrapping_add(1).max(1);
                        let n2 = w.notify_id;
                        let s = cmd::NOTIFY_STATUS_CHANGED;
                        out.push((l.addr, notify(id, l.id, n1, s, &[status])));
                        let p = cmd::NOTIFY_POSITION_CHANGED;
                        out.push((l.addr, notify(id, l.id, n2, p, &pos)));
                    }
                }
            }
            Err(()) => {
                let mut options = opt::ERROR;
                if f.options & opt::REQ_ACK != 0 {
                    options |= opt::ACK;
                }
                out.push((from, reply(f, id, options, Vec::new())));
            }
        }
    }
}

fn notify(from: u16, to: u16, id: u16, kind: u16, values: &[i32]) -> Frame {
    Frame {
        extra: 0,
        receiver: to,
        sender: from,
        message_id: id,
        options: opt::NOTIFY,
        kind,
        blocks: vec![SubBlock::i32s(values)],
    }
}

/// Executes one request on one device: `Ok(Some(data))` answers with data,
/// `Ok(None)` with an ACK only, `Err(())` with the ERROR option.
fn execute(d: &mut Device, f: &Frame, t: f64) -> Result<Option<Vec<i32>>, ()> {
    let args = f.all_ints();
    let axes = d.rest.len();
    let positional = axes > 0;
    match f.kind {
        cmd::PING => Ok(None),
        cmd::STOP => {
            d.stop(t);
            Ok(None)
        }
        cmd::GET_POSITIONS if positional => Ok(Some(d.positions_nm(t))),
        cmd::GET_PARAMETER => {
            let id = *args.first().ok_or(())?;
            let v = match id as u16 {
                param::AXIS_COUNT => axes as i32,
                param::DEV_ID => i32::from(d.spec.id),
                param::SN => 1_000_000 + i32::from(d.spec.id),
                _ => d.params.get(&id).copied().unwrap_or(0),
            };
            Ok(Some(vec![id, v]))
        }
        cmd::SET_PARAMETER => {
            let (&id, &v) = (args.first().ok_or(())?, args.get(1).ok_or(())?);
            d.params.insert(id, v);
            Ok(None)
        }
        cmd::GET_VERSION => Ok(Some(FIRMWARE.to_vec())),
        cmd::GOTO_POS if positional => {
            let first = f.ints(0);
            let per_axis = f.ints(1);
            let targets: Vec<Option<f64>> = (0..axes)
                .map(|k| {
                    first
                        .get(k)
                        .filter(|&&v| v != ARG_UNDEF)
                        .map(|&v| f64::from(v))
                })
                .collect();
            let speed_at = if first.len() > 4 { Some(4) } else { None };
            let wire_speed = |s: i32| {
                if s < 0 {
                    -f64::from(s)
                } else {
                    f64::from(s) * 1e3
                }
            };
            let common = speed_at
                .and_then(|k| first.get(k))
                .filter(|&&s| s != 0)
                .map(|&s| wire_speed(s))
                .unwrap_or(DEFAULT_SPEED * 1e3);
            let speeds: Vec<f64> = (0..axes)
                .map(|k| {
                    per_axis
                        .get(k)
                        .filter(|&&s| s != 0)
                        .map_or(common, |&s| wire_speed(s))
                })
                .collect();
            let mode = first.get(5).copied().unwrap_or(0);
            let accel = first
                .get(6)
                .filter(|&&a| a > 0)
                .map_or(DEFAULT_ACCELERATION, |&a| f64::from(a))
                * 1e3;
            d.start(t, &targets, &speeds, accel, mode != 0);
            Ok(None)
        }
        cmd::TAKE_STEP if positional => {
            let now = d.position(t);
            let targets: Vec<Option<f64>> = (0..axes)
                .map(|k| {
                    args.get(k)
                        .filter(|&&s| s != 0)
                        .map(|&s| now[k] + f64::from(s))
                })
                .collect();
            let speeds: Vec<f64> = (0..axes)
                .map(|k| {
                    args.get(4 + k)
                        .filter(|&&s| s > 0)
                        .map_or(DEFAULT_SPEED * 1e3, |&s| f64::from(s) * 1e3)
                })
                .collect();
            let accel = args
                .get(9)
                .filter(|&&a| a > 0)
                .map_or(DEFAULT_ACCELERATION, |&a| f64::from(a))
                * 1e3;
            d.start(t, &targets, &speeds, accel, true);
            Ok(None)
        }
        cmd::READ_ERROR_STATE => Ok(Some(vec![d.error_state as i32])),
        cmd::CLEAR_ERROR_STATE => {
            d.error_state = 0;
            Ok(None)
        }
        cmd::UMS_GET_LENS_POSITION if d.spec.kind == Kind::Stage => Ok(Some(vec![d.lens])),
        cmd::UMS_SET_LENS_POSITION if d.spec.kind == Kind::Stage => match args.first() {
            Some(&l) if (0..=2).contains(&l) => {
                d.lens = l;
                if let Some(b) = d.backing.as_mut() {
                    b.lens(l);
                }
                Ok(None)
            }
            _ => Err(()),
        },
        cmd::UMV_SET_PRESSURE..=cmd::UMV_MEASURE_PRESSURE if d.spec.kind == Kind::Pressure => {
            pressure(d, f.kind, &args, t)
        }
        _ => Err(()),
    }
}

/// A uMv's commands ([`execute`]'s): set points, valves and the measured pressure.
fn pressure(d: &mut Device, kind: u16, args: &[i32], t: f64) -> Result<Option<Vec<i32>>, ()> {
    let c = match args.first() {
        Some(&c) if (0..CHANNELS as i32).contains(&c) => c as usize,
        _ => return Err(()),
    };
    match kind {
        cmd::UMV_SET_PRESSURE => {
            let p = *args.get(1).ok_or(())?;
            if p.abs() > MAX_PRESSURE {
                return Err(());
            }
            d.set_point[c] = f64::from(p);
            Ok(None)
        }
        cmd::UMV_GET_PRESSURE => Ok(Some(vec![c as i32, d.set_point[c].round() as i32])),
        cmd::UMV_MEASURE_PRESSURE => Ok(Some(vec![c as i32, d.pressure[c].round() as i32])),
        cmd::UMV_SET_VALVE => match args.get(1) {
            Some(&v) if v == 0 || v == 1 => {
                d.valve[c] = v;
                match (v, d.opened[c]) {
                    (1, None) => d.opened[c] = Some(t),
                    (0, Some(t0)) => {
                        d.opened[c] = None;
                        let p = d.set_point[c];
                        if let Some(b) = d.backing.as_mut() {
                            b.pulse(p, t - t0);
                        }
                    }
                    _ => {}
                }
                Ok(None)
            }
            _ => Err(()),
        },
        cmd::UMV_GET_VALVE => Ok(Some(vec![c as i32, d.valve[c]])),
        _ => Err(()),
    }
}

/// Brings every device to the wall clock: pressures settle, moving devices notify
/// their positions, and a move that has ended is announced.
fn tick(w: &mut World, out: &mut Vec<(SocketAddr, Frame)>) {
    let t = w.now();
    let dt = t - w.last_tick;
    w.last_tick = t;
    let mut notes: Vec<(SocketAddr, u16, u16, u16, Vec<i32>)> = Vec::new();
    for d in w.devices.iter_mut() {
        d.settle_pressure(dt);
        if !d.moving {
            continue;
        }
        let done = match d.backing.as_mut() {
            Some(b) => !b.busy(),
            None => {
                t >= d
                    .moves
                    .iter()
                    .flatten()
                    .map(Segment::end)
                    .fold(0.0, f64::max)
            }
        };
        let Some(l) = d.listener.filter(|_| !d.silent(t)) else {
            if done {
                d.finish(t);
            }
            continue;
        };
        let id = d.spec.id;
        let mut note = |kind: u16, values: Vec<i32>| notes.push((l.addr, id, l.id, kind, values));
        if done {
            d.finish(t);
            note(cmd::NOTIFY_POSITION_CHANGED, d.positions_nm(t));
            note(cmd::NOTIFY_STATUS_CHANGED, vec![d.status(t)]);
            note(cmd::NOTIFY_GOTO_POS_COMPLETED, vec![d.outcome]);
        } else if t - d.last_notify >= NOTIFY_EVERY.as_secs_f64() {
            d.last_notify = t;
            note(cmd::NOTIFY_POSITION_CHANGED, d.positions_nm(t));
        }
    }
    for (addr, from, to, kind, values) in notes {
        let id = w.next_id();
        out.push((addr, notify(from, to, id, kind, &values)));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn device_lists_parse_and_bad_ones_name_the_part() {
        let d = parse_devices("ump:1, ums:21,umv:31,ump4:2").unwrap();
        assert_eq!(d.len(), 4);
        assert_eq!(d[3].kind, Kind::Manipulator { axes: 4 });
        for (bad, says) in [
            ("ump", "KIND:ID"),
            ("xyz:1", "unknown device kind `xyz`"),
            ("ump:0", "1..254"),
            ("ump:x", "1..254"),
            ("ump:1,ums:1", "twice"),
            ("", "no device"),
        ] {
            let e = parse_devices(bad).unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }

    #[test]
    fn silences_parse_and_bad_ones_say_the_form() {
        assert_eq!(parse_silence("1@60..75"), Ok((1, 60.0, Some(75.0))));
        assert_eq!(parse_silence("31@2.5"), Ok((31, 2.5, None)));
        for bad in [
            "1", "x@1", "1@", "1@-1", "1@nan", "1@5..5", "1@5..2", "1@1..x",
        ] {
            assert!(parse_silence(bad).is_err(), "{bad}");
        }
    }

    /// A trapezoidal move: continuous, monotone, at the speed in its middle and
    /// exactly on target at its end.
    #[test]
    fn a_move_is_a_trapezoid_that_ends_on_target() {
        let s = Segment {
            from: 1000.0,
            to: 101_000.0,
            speed: 100_000.0,
            accel: 1e6,
            start: 2.0,
        };
        let (ta, cruise, total) = s.timing();
        assert!((ta - 0.1).abs() < 1e-12 && (cruise - 0.9).abs() < 1e-9);
        assert!((total - 1.1).abs() < 1e-9);
        let mut last = s.at(2.0);
        assert_eq!(last, 1000.0);
        for k in 1..=220 {
            let p = s.at(2.0 + k as f64 * 0.005);
            assert!(p >= last - 1e-9, "monotone");
            assert!(
                p - last <= 100_000.0 * 0.005 + 1e-6,
                "never faster than the speed"
            );
            last = p;
        }
        assert_eq!(s.at(3.2), 101_000.0);
        assert!((s.velocity(2.5) - 100_000.0).abs() < 1e-6);
        // A short move never reaches the speed.
        let short = Segment { to: 1100.0, ..s };
        let (ta, cruise, _) = short.timing();
        assert_eq!(cruise, 0.0);
        assert!(short.accel * ta < short.speed);
    }
}
