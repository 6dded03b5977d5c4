//! Sensapex devices behind cellinject's hardware traits: a uMp or uMs as a
//! [`Stage`] ([`Positioner`]: positions in m, relative to an origin in the device's
//! own coordinates), a uMv / uMc pressure channel as an [`Injector`]
//! ([`PressureChannel`]: Pa, the valve open for the pulse's duration), a uMs's lens
//! changer as the [`Optics`] ([`LensChanger`]: one magnification per lens position).

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use cellinject_hw::{HwError, Injector, Optics, Stage, check_range};

use crate::link::{Link, SensapexError};
use crate::protocol::{ARG_UNDEF, cmd, opt, param};

/// A link shared by the devices on it.
pub type SharedLink = Arc<Mutex<Link>>;

fn lock(l: &SharedLink) -> MutexGuard<'_, Link> {
    l.lock().unwrap_or_else(|e| e.into_inner())
}

/// A Sensapex error as a device error (a timeout stays a timeout).
pub fn hw_error(e: SensapexError) -> HwError {
    match e {
        SensapexError::Timeout {
            device,
            address,
            seconds,
            ..
        } => HwError::Timeout {
            device: format!("Sensapex device {device} at {address}"),
            // Shown as written: milliseconds are enough.
            seconds: (seconds * 1e3).round() / 1e3,
        },
        SensapexError::Refused {
            device, address, ..
        } => HwError::Device {
            device: format!("Sensapex device {device} at {address}"),
            message: e.to_string(),
        },
        other => HwError::Device {
            device: "Sensapex".into(),
            message: other.to_string(),
        },
    }
}

/// What a positioner is: its axes' travel in the device's coordinates, nm.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Model {
    /// A uMp micromanipulator: 0..20 mm on each axis.
    Manipulator,
    /// A uMs stage: X and Y 0..50 mm, focus 0..25 mm.
    Stage,
}

impl Model {
    /// Travel of axis `k`, nm.
    pub fn travel(self, k: usize) -> (i64, i64) {
        match (self, k) {
            (Model::Stage, 2) => (0, 25_000_000),
            (Model::Stage, _) => (0, 50_000_000),
            (Model::Manipulator, _) => (0, 20_000_000),
        }
    }
}

/// A move under way: each axis's target (nm, `None`: not commanded) and the last
/// completion the device had notified before it was sent.
#[derive(Debug, Clone)]
struct Pending {
    targets: Vec<Option<i32>>,
    before: Option<(u16, i32)>,
    sent: Instant,
}

/// A uMp or uMs as a stage: axis k at stage position p (m) is the device at
/// `origin[k] + p`, nm on the wire. Moves go at `speed`; a move commanded while
/// another is under way carries the other axes' targets along.
pub struct Positioner {
    link: SharedLink,
    device: u16,
    axes: usize,
    model: Model,
    origin: Vec<f64>,
    speed: f64,
    pending: Option<Pending>,
}

impl Positioner {
    /// The device `device` on `link`: its axis count is read (parameter 0x105);
    /// `origin` (m, the device's coordinates of stage position 0, one per axis;
    /// empty: the middle of each axis's travel) and `speed` (m/s).
    pub fn open(
        link: &SharedLink,
        device: u16,
        model: Model,
        origin: &[f64],
        speed: f64,
    ) -> Result<Positioner, SensapexError> {
        let r = lock(link).request(
            device,
            cmd::GET_PARAMETER,
            &[param::AXIS_COUNT as i32],
            true,
        )?;
        let axes = match r.as_slice() {
            [p, n, ..] if *p == param::AXIS_COUNT as i32 && (1..=4).contains(n) => *n as usize,
            _ => {
                return Err(SensapexError::BadReply {
                    device,
                    command: "GET_PARAMETER",
                    reason: format!("{r:?} for the axis count"),
                });
            }
        };
        let origin = (0..axes)
            .map(|k| {
                origin.get(k).copied().unwrap_or_else(|| {
                    let (lo, hi) = model.travel(k);
                    0.5 * (lo + hi) as f64 * 1e-9
                })
            })
            .collect();
        Ok(Positioner {
            link: link.clone(),
            device,
            axes,
            model,
            origin,
            speed,
            pending: None,
        })
    }

    /// The device's id.
    pub fn device(&self) -> u16 {
        self.device
    }

    /// Every axis's position, m (stage coordinates).
    pub fn positions(&mut self) -> Result<Vec<f64>, SensapexError> {
        let r = lock(&self.link).request(self.device, cmd::GET_POSITIONS, &[], true)?;
        if r.len() < self.axes {
            return Err(SensapexError::BadReply {
                device: self.device,
                command: "GET_POSITIONS",
                reason: format!("{} positions for {} axes", r.len(), self.axes),
            });
        }
        Ok((0..self.axes)
            .map(|k| f64::from(r[k]) * 1e-9 - self.origin[k])
            .collect())
    }

    /// Stops every axis.
    pub fn stop(&mut self) -> Result<(), SensapexError> {
        self.pending = None;
        lock(&self.link).request(self.device, cmd::STOP, &[], false)?;
        Ok(())
    }

    fn name(&self) -> &'static str {
        match self.model {
            Model::Manipulator => "Sensapex manipulator",
            Model::Stage => "Sensapex stage",
        }
    }
}

impl Stage for Positioner {
    fn axes(&self) -> usize {
        self.axes
    }

    fn travel(&self, axis: usize) -> (f64, f64) {
        let (lo, hi) = self.model.travel(axis.min(self.axes.saturating_sub(1)));
        let o = self.origin.get(axis).copied().unwrap_or(0.0);
        (lo as f64 * 1e-9 - o, hi as f64 * 1e-9 - o)
    }

    fn move_to(&mut self, axis: usize, position: f64) -> Result<(), HwError> {
        check_range(self.name(), axis as f64, 0.0, (self.axes - 1) as f64)?;
        let (lo, hi) = self.travel(axis);
        check_range(self.name(), position, lo, hi)?;
        let nm = ((position + self.origin[axis]) * 1e9).round() as i32;
        let mut link = lock(&self.link);
        link.poll().map_err(hw_error)?;
        let before = link.notes(self.device).completed;
        let mut targets = match &self.pending {
            Some(p) => p.targets.clone(),
            None => vec![None; self.axes],
        };
        targets[axis] = Some(nm);
        let speed = (self.speed * 1e6).round().max(1.0) as i32;
        let mut first: Vec<i32> = targets.iter().map(|t| t.unwrap_or(ARG_UNDEF)).collect();
        first.resize(4, ARG_UNDEF);
        first.extend([speed, 1]);
        let speeds = vec![speed; self.axes];
        link.exchange(
            self.device,
            cmd::GOTO_POS,
            &[&first, &speeds],
            opt::REQ_ACK | opt::REQ_NOTIFY,
        )
        .map_err(hw_error)?;
        self.pending = Some(Pending {
            targets,
            before,
            sent: Instant::now(),
        });
        Ok(())
    }

    fn position(&mut self, axis: usize) -> Result<f64, HwError> {
        check_range(self.name(), axis as f64, 0.0, (self.axes - 1) as f64)?;
        Ok(self.positions().map_err(hw_error)?[axis])
    }

    fn is_busy(&mut self) -> Result<bool, HwError> {
        let Some(p) = self.pending.clone() else {
            return Ok(false);
        };
        let notes = {
            let mut link = lock(&self.link);
            link.poll().map_err(hw_error)?;
            link.notes(self.device)
        };
        if let Some(done) = notes.completed
            && Some(done) != p.before
        {
            self.pending = None;
            return match done.1 {
                0 | 2 => Ok(false),
                code => Err(HwError::Device {
                    device: format!("{} {}", self.name(), self.device),
                    message: format!("the move ended without reaching its target (code {code})"),
                }),
            };
        }
        // A lost notification: after a while, the position says.
        if p.sent.elapsed() > Duration::from_millis(500) && notes.status & 0xfff1 == 0 {
            let now = lock(&self.link)
                .request(self.device, cmd::GET_POSITIONS, &[], true)
                .map_err(hw_error)?;
            let arrived = p
                .targets
                .iter()
                .zip(&now)
                .all(|(t, n)| t.is_none_or(|t| (i64::from(t) - i64::from(*n)).abs() <= 1));
            if arrived {
                self.pending = None;
                return Ok(false);
            }
        }
        Ok(true)
    }
}

/// The largest pressure a uMv / uMc channel sets, Pa (±100 kPa in Sensapex's SDK).
pub const MAX_PRESSURE: f64 = 100e3;

/// One pressure channel of a uMv / uMc as the injector: a pulse sets the channel's
/// pressure, opens its valve for the pulse's duration, closes it, then sets 0.
pub struct PressureChannel {
    link: SharedLink,
    device: u16,
    channel: u8,
    max_pressure: f64,
}

impl PressureChannel {
    /// Channel `channel` (1..8, as Sensapex numbers them) of `device`, refusing
    /// pressures above `max_pressure` (Pa, the injector's limit from the rig's
    /// description, and at most the controller's own [`MAX_PRESSURE`]) before
    /// anything is sent. The device is asked for the
    /// channel's valve state, so a device that does not answer is found now.
    pub fn open(
        link: &SharedLink,
        device: u16,
        channel: u8,
        max_pressure: f64,
    ) -> Result<PressureChannel, SensapexError> {
        let c = PressureChannel {
            link: link.clone(),
            device,
            channel,
            max_pressure: max_pressure.min(MAX_PRESSURE),
        };
        lock(link).request(device, cmd::UMV_GET_VALVE, &[c.wire()], true)?;
        Ok(c)
    }

    fn wire(&self) -> i32 {
        i32::from(self.channel) - 1
    }

    /// The pressure the channel's sensor measures, Pa.
    pub fn measure(&mut self) -> Result<f64, SensapexError> {
        let r = lock(&self.link).request(
            self.device,
            cmd::UMV_MEASURE_PRESSURE,
            &[self.wire()],
            true,
        )?;
        match r.as_slice() {
            [c, p] if *c == self.wire() => Ok(f64::from(*p)),
            _ => Err(SensapexError::BadReply {
                device: self.device,
                command: "UMV_MEASURE_PRESSURE",
                reason: format!("{r:?}"),
            }),
        }
    }

    /// Opens the valve at `pressure` (the set point first), or closes it and sets
    /// `pressure` (the valve first: nothing is pushed at the falling set point).
    fn set(&mut self, pressure: i32, open: bool) -> Result<(), SensapexError> {
        let mut link = lock(&self.link);
        let (c, dev) = (self.wire(), self.device);
        if open {
            link.request(dev, cmd::UMV_SET_PRESSURE, &[c, pressure], false)?;
            link.request(dev, cmd::UMV_SET_VALVE, &[c, 1], false)?;
        } else {
            link.request(dev, cmd::UMV_SET_VALVE, &[c, 0], false)?;
            link.request(dev, cmd::UMV_SET_PRESSURE, &[c, pressure], false)?;
        }
        Ok(())
    }
}

impl Injector for PressureChannel {
    fn max_pressure(&self) -> f64 {
        self.max_pressure
    }

    fn pulse(&mut self, pressure: f64, duration: f64) -> Result<(), HwError> {
        check_range("pressure", pressure, 0.0, self.max_pressure)?;
        check_range("pulse duration", duration, 0.0, 10.0)?;
        self.set(pressure.round() as i32, true).map_err(hw_error)?;
        std::thread::sleep(Duration::from_secs_f64(duration));
        let closed = self.set(0, false);
        if closed.is_err() {
            // Once more: a valve left open keeps pushing.
            let _ =
                lock(&self.link).request(self.device, cmd::UMV_SET_VALVE, &[self.wire(), 0], false);
        }
        closed.map_err(hw_error)
    }
}

/// How long a lens change may take before it is an error, s (the uMs lifts the
/// objective, turns the changer and dips back: seconds).
pub const LENS_CHANGE_TIMEOUT: f64 = 30.0;

/// A uMs's lens changer as the microscope's optics: lens position k (1 or 2; 0 is the
/// empty centre) has magnification `lenses[k - 1]`. A zoom is set by moving to the
/// lens of that magnification (within 0.1 %); any other zoom is refused, naming the
/// lenses.
pub struct LensChanger {
    link: SharedLink,
    device: u16,
    lenses: Vec<f64>,
    /// The lens position now (0: the centre, no lens).
    position: i32,
}

impl LensChanger {
    /// The lens changer of uMs `device` on `link`, whose positions 1, 2, ... carry
    /// lenses of magnification `lenses`; its position is read now, so a device that
    /// does not answer is found before anything moves.
    pub fn open(
        link: &SharedLink,
        device: u16,
        lenses: &[f64],
    ) -> Result<LensChanger, SensapexError> {
        let mut l = LensChanger {
            link: link.clone(),
            device,
            lenses: lenses.to_vec(),
            position: 0,
        };
        l.position = l.read()?;
        Ok(l)
    }

    /// The lens position the device reports (0: the centre or unknown).
    pub fn read(&mut self) -> Result<i32, SensapexError> {
        let r = lock(&self.link).request(self.device, cmd::UMS_GET_LENS_POSITION, &[], true)?;
        match r.first() {
            Some(&p) if (-1..=9).contains(&p) => Ok(p.max(0)),
            _ => Err(SensapexError::BadReply {
                device: self.device,
                command: "UMS_GET_LENS_POSITION",
                reason: format!("{r:?}"),
            }),
        }
    }

    fn lens_list(&self) -> String {
        self.lenses
            .iter()
            .enumerate()
            .map(|(k, m)| format!("lens {} = {m}x", k + 1))
            .collect::<Vec<_>>()
            .join(", ")
    }

    fn name(&self) -> String {
        format!("Sensapex stage {} lens changer", self.device)
    }
}

impl Optics for LensChanger {
    fn zoom(&self) -> f64 {
        usize::try_from(self.position - 1)
            .ok()
            .and_then(|k| self.lenses.get(k).copied())
            .unwrap_or(f64::NAN)
    }

    fn zoom_range(&self) -> (f64, f64) {
        let lo = self.lenses.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = self
            .lenses
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        (lo, hi)
    }

    fn set_zoom(&mut self, zoom: f64) -> Result<(), HwError> {
        let (lo, hi) = self.zoom_range();
        check_range("zoom", zoom, lo, hi)?;
        let Some(k) = self
            .lenses
            .iter()
            .position(|m| (m - zoom).abs() <= 1e-3 * m)
        else {
            return Err(HwError::Device {
                device: self.name(),
                message: format!("no lens of magnification {zoom}x ({})", self.lens_list()),
            });
        };
        let target = k as i32 + 1;
        if self.position == target {
            return Ok(());
        }
        lock(&self.link)
            .request(self.device, cmd::UMS_SET_LENS_POSITION, &[target], false)
            .map_err(hw_error)?;
        let start = Instant::now();
        loop {
            self.position = self.read().map_err(hw_error)?;
            if self.position == target {
                return Ok(());
            }
            if start.elapsed().as_secs_f64() > LENS_CHANGE_TIMEOUT {
                return Err(HwError::Timeout {
                    device: format!("{} (to lens {target})", self.name()),
                    seconds: LENS_CHANGE_TIMEOUT,
                });
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}
