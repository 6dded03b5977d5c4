//! # cellinject-hw
//!
//! The small traits through which cellinject talks to hardware, after openrr's `arci`:
//! a piezo amplifier channel, a stack position sensor, a camera, a translational stage,
//! an injector and a clock.
//! a zoom lens. The digital twin implements every trait (crate `cellinject-twin`), real
//! drivers will too, and the controllers see only the traits. Safety limits are
//! wrappers around any implementation (crate `cellinject-rig`): an unsafe command is
//! refused with a typed [`SafetyError`] before it reaches the device.
//!
//! All traits are object-safe and `Send` (devices live on a control thread); all
//! quantities are SI (s, V, m, Pa).
//!
//! **Architecture invariant:** this crate defines contracts and vocabulary types
//! ([`Frame`], [`Roi`], the errors); it does no IO, knows no particular device and
//! depends on nothing but `thiserror`.
//!
//! **Architecture invariant:** errors of an accepted command path carry static names
//! (`&'static str`), so that checking a command allocates nothing.

use thiserror::Error;

/// Why a safety wrapper refused a command.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum SafetyError {
    /// Voltage outside the amplifier channel's range (the stack's travel).
    #[error("{channel}: {volts} V is outside [{min}, {max}] V (the stack's travel)")]
    Voltage {
        /// Channel name.
        channel: &'static str,
        /// Requested voltage.
        volts: f64,
        /// Lowest allowed.
        min: f64,
        /// Highest allowed.
        max: f64,
    },
    /// A stack would be pushed beyond its push capacity.
    #[error("{actuator} force could reach {force:.3} N, beyond its push capacity {capacity} N")]
    Force {
        /// Actuator name.
        actuator: &'static str,
        /// Worst-case force, N (compression negative).
        force: f64,
        /// Push capacity, N.
        capacity: f64,
    },
    /// A stack would lose its compression (backlash, tensile load on the ceramic).
    #[error("{actuator} force could reach {force:.3} N: the stack would no longer be compressed")]
    Compression {
        /// Actuator name.
        actuator: &'static str,
        /// Worst-case force, N.
        force: f64,
    },
    /// A flexure would bend its stack beyond the stack's torque limit.
    #[error(
        "{flexure} bending torque could reach {torque:.4} N*m, beyond the torque limit {limit} N*m of {actuator}"
    )]
    Torque {
        /// Flexure name (J1, J2).
        flexure: &'static str,
        /// Actuator it loads.
        actuator: &'static str,
        /// Worst-case torque, N·m.
        torque: f64,
        /// Limit, N·m.
        limit: f64,
    },
    /// A flexure would be stressed past its yield strength.
    #[error(
        "{joint} could reach {:.1} MPa von Mises, beyond the {:.1} MPa allowed (its yield strength less the stress map's error)",
        .stress / 1e6,
        .limit / 1e6
    )]
    Yield {
        /// Flexure name (J3).
        joint: &'static str,
        /// Worst-case peak von Mises stress, Pa.
        stress: f64,
        /// The stress allowed, Pa.
        limit: f64,
    },
    /// A stage move beyond the axis travel.
    #[error("stage axis {axis}: {position} m is outside its travel [{min}, {max}] m")]
    StageTravel {
        /// Axis index.
        axis: usize,
        /// Requested position.
        position: f64,
        /// Lower limit.
        min: f64,
        /// Upper limit.
        max: f64,
    },
    /// An injection pressure beyond the limit.
    #[error("pressure {pressure} Pa exceeds the limit {max} Pa")]
    Pressure {
        /// Requested pressure.
        pressure: f64,
        /// Limit.
        max: f64,
    },
    /// A magnification outside the zoom range.
    #[error("zoom {zoom} is outside the zoom range [{min}, {max}]")]
    Zoom {
        /// Requested magnification.
        zoom: f64,
        /// Smallest allowed.
        min: f64,
        /// Largest allowed.
        max: f64,
    },
    /// The model could not evaluate the command.
    #[error("the mechanism model failed: {0}")]
    Model(String),
}

/// Errors a device can report.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum HwError {
    /// The command was refused by a safety wrapper.
    #[error("refused: {0}")]
    Refused(#[from] SafetyError),
    /// A parameter outside the device's own range.
    #[error("{what} = {value} is outside the device range [{min}, {max}]")]
    OutOfRange {
        /// Which parameter.
        what: &'static str,
        /// Requested value.
        value: f64,
        /// Smallest accepted value.
        min: f64,
        /// Largest accepted value.
        max: f64,
    },
    /// A parameter that is not a finite number.
    #[error("{what} must be a finite number, got {value}")]
    NotFinite {
        /// Which parameter.
        what: &'static str,
        /// Requested value.
        value: f64,
    },
    /// The device did not answer in time.
    #[error("{device} timed out after {seconds} s")]
    Timeout {
        /// Which device.
        device: String,
        /// How long we waited.
        seconds: f64,
    },
    /// The operator interrupted what was going on (an abort): nothing is wrong with
    /// the device, but the program must stop and make the bench safe.
    #[error("interrupted: {reason}")]
    Interrupted {
        /// Which device noticed.
        device: String,
        /// Why, in words.
        reason: String,
    },
    /// Any other device failure.
    #[error("{device}: {message}")]
    Device {
        /// Which device.
        device: String,
        /// What it said.
        message: String,
    },
}

/// Checks that `value` is finite and in `[min, max]`.
pub fn check_range(what: &'static str, value: f64, min: f64, max: f64) -> Result<(), HwError> {
    if !value.is_finite() {
        return Err(HwError::NotFinite { what, value });
    }
    if value < min || value > max {
        return Err(HwError::OutOfRange {
            what,
            value,
            min,
            max,
        });
    }
    Ok(())
}

/// Time. The twin's clock is simulated: `sleep` advances the simulation, so a run is
/// as fast as the computer allows while reporting the time the real device would take.
pub trait Clock: Send {
    /// Seconds since the clock's epoch.
    fn now(&self) -> f64;
    /// Lets `seconds` pass (the twin integrates its dynamics over them).
    fn sleep(&mut self, seconds: f64) -> Result<(), HwError>;
}

/// Paces a sampled program at a fixed interval on a [`Clock`]: each [`Pacer::wait`]
/// lets what is left of `dt` pass since the previous one ended, counting the time the
/// caller's own device calls took in between. Over a link (a controller on TCP, two
/// round trips a sample) the samples then stay `dt` apart where the link allows,
/// instead of `dt` plus the round trips; on a clock that moves only when slept (the
/// twin) every wait sleeps exactly `dt`, so a twin's run is unchanged.
#[derive(Debug, Clone, Copy)]
pub struct Pacer {
    dt: f64,
    mark: f64,
}

impl Pacer {
    /// A pacer of interval `dt` (s), counting from `clock`'s now.
    pub fn start<C: Clock + ?Sized>(clock: &C, dt: f64) -> Self {
        Pacer {
            dt,
            mark: clock.now(),
        }
    }

    /// Sleeps `dt` less the time spent since the previous wait ended (nothing when the
    /// calls took longer than `dt`).
    pub fn wait<C: Clock + ?Sized>(&mut self, clock: &mut C) -> Result<(), HwError> {
        let spent = clock.now() - self.mark;
        clock.sleep((self.dt - spent).max(0.0))?;
        self.mark = clock.now();
        Ok(())
    }
}

/// One channel of a piezo amplifier driving one stack.
///
/// Contract: `set_voltage` returns once the command is accepted (not once the stack has
/// moved); the amplifier then follows it with its own slew rate and bandwidth.
/// `read_voltage` is the amplifier's output monitor.
pub trait PiezoChannel: Send {
    /// Channel name (A1, A2, A3).
    fn name(&self) -> &str;
    /// Output range of the amplifier, volts.
    fn voltage_range(&self) -> (f64, f64);
    /// Commands an output voltage.
    fn set_voltage(&mut self, volts: f64) -> Result<(), HwError>;
    /// The last accepted command.
    fn commanded_voltage(&self) -> f64;
    /// The output voltage now.
    fn read_voltage(&mut self) -> Result<f64, HwError>;
}

/// A region of the sensor, in sensor pixels (before binning).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Roi {
    /// First column.
    pub x: u32,
    /// First row.
    pub y: u32,
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
}

/// Acquisition settings of a camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraSettings {
    /// Region of interest on the sensor.
    pub roi: Roi,
    /// Binning factor (1, 2, 4): `binning x binning` sensor pixels make one output pixel.
    pub binning: u32,
    /// Exposure time, s.
    pub exposure: f64,
    /// Output bit depth (8 or 12).
    pub bit_depth: u8,
}

/// One image from a camera.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Frame {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Significant bits of each pixel value (8 or 12).
    pub bit_depth: u8,
    /// Row-major pixel values.
    pub pixels: Vec<u16>,
    /// Start of the exposure, s (on the device's clock).
    pub timestamp: f64,
    /// Exposure time, s.
    pub exposure: f64,
    /// Size of one output pixel in the object plane, m.
    pub pixel_size: f64,
    /// Frame counter since the camera started.
    pub index: u64,
}

/// A camera.
pub trait Camera: Send {
    /// Sensor size in pixels (columns, rows).
    fn sensor_size(&self) -> (u32, u32);
    /// Current acquisition settings.
    fn settings(&self) -> CameraSettings;
    /// Changes the acquisition settings (validated by the device).
    fn configure(&mut self, settings: CameraSettings) -> Result<(), HwError>;
    /// Frames per second with the current settings.
    fn frame_rate(&self) -> f64;
    /// Waits for the next frame and writes it into `frame`, reusing its buffer.
    fn grab_into(&mut self, frame: &mut Frame) -> Result<(), HwError>;
    /// Waits for the next frame.
    fn grab(&mut self) -> Result<Frame, HwError> {
        let mut f = Frame::default();
        self.grab_into(&mut f)?;
        Ok(f)
    }
}

/// A motorised translational stage with position encoders.
pub trait Stage: Send {
    /// Number of axes.
    fn axes(&self) -> usize;
    /// Travel limits of an axis, m.
    fn travel(&self, axis: usize) -> (f64, f64);
    /// Starts a move of one axis to an absolute position (returns at once).
    fn move_to(&mut self, axis: usize, position: f64) -> Result<(), HwError>;
    /// Encoder reading of an axis, m.
    fn position(&mut self, axis: usize) -> Result<f64, HwError>;
    /// Whether any axis is still moving or settling.
    fn is_busy(&mut self) -> Result<bool, HwError>;
}

/// A pressure injector connected to the pipette.
pub trait Injector: Send {
    /// Largest pressure the injector may apply, Pa.
    fn max_pressure(&self) -> f64;
    /// Applies a pressure pulse (gauge pressure in Pa, duration in s).
    fn pulse(&mut self, pressure: f64, duration: f64) -> Result<(), HwError>;
}

/// A position sensor on one stack (strain gauges, as on PI's P-8xx stacks): it reads
/// the stack's extension, not the end-effector's position, so it cannot see what
/// happens after the stack (the joints' stick-slip, the lever).
pub trait PositionSensor: Send {
    /// Sensor name (the stack's: A1, A2, A3).
    fn name(&self) -> &str;
    /// The stack's extension now, m (noise and drift included).
    fn read(&mut self) -> Result<f64, HwError>;
    /// Rms noise of one reading, m, as the device states it.
    fn noise(&self) -> f64;
}

/// A zoom lens.
pub trait Optics: Send {
    /// Magnification now.
    fn zoom(&self) -> f64;
    /// Smallest and largest magnification.
    fn zoom_range(&self) -> (f64, f64);
    /// Changes the magnification.
    fn set_zoom(&mut self, zoom: f64) -> Result<(), HwError>;
}

/// The centred 640x480 acquisition a camera of `sensor` pixels offers for fast
/// tracking: `binned` takes 4x4-binned pixels of a 2560x1920 centre region, otherwise
/// the centre region at full resolution; exposure and bit depth are kept from `current`.
pub fn vga_settings(sensor: (u32, u32), current: &CameraSettings, binned: bool) -> CameraSettings {
    let (w, h) = (640u32, 480u32);
    let b = if binned { 4 } else { 1 };
    let sw = (w * b).min(sensor.0);
    let sh = (h * b).min(sensor.1);
    CameraSettings {
        roi: Roi {
            x: (sensor.0 - sw) / 2,
            y: (sensor.1 - sh) / 2,
            width: sw,
            height: sh,
        },
        binning: b,
        ..*current
    }
}

// Boxed devices are devices: a front end picks its backend at run time
// (`cellinject_rig::DynBackend`).

impl<T: Clock + ?Sized> Clock for Box<T> {
    fn now(&self) -> f64 {
        (**self).now()
    }
    fn sleep(&mut self, seconds: f64) -> Result<(), HwError> {
        (**self).sleep(seconds)
    }
}

impl<T: PiezoChannel + ?Sized> PiezoChannel for Box<T> {
    fn name(&self) -> &str {
        (**self).name()
    }
    fn voltage_range(&self) -> (f64, f64) {
        (**self).voltage_range()
    }
    fn set_voltage(&mut self, volts: f64) -> Result<(), HwError> {
        (**self).set_voltage(volts)
    }
    fn commanded_voltage(&self) -> f64 {
        (**self).commanded_voltage()
    }
    fn read_voltage(&mut self) -> Result<f64, HwError> {
        (**self).read_voltage()
    }
}

impl<T: Camera + ?Sized> Camera for Box<T> {
    fn sensor_size(&self) -> (u32, u32) {
        (**self).sensor_size()
    }
    fn settings(&self) -> CameraSettings {
        (**self).settings()
    }
    fn configure(&mut self, settings: CameraSettings) -> Result<(), HwError> {
        (**self).configure(settings)
    }
    fn frame_rate(&self) -> f64 {
        (**self).frame_rate()
    }
    fn grab_into(&mut self, frame: &mut Frame) -> Result<(), HwError> {
        (**self).grab_into(frame)
    }
}

impl<T: Stage + ?Sized> Stage for Box<T> {
    fn axes(&self) -> usize {
        (**self).axes()
    }
    fn travel(&self, axis: usize) -> (f64, f64) {
        (**self).travel(axis)
    }
    fn move_to(&mut self, axis: usize, position: f64) -> Result<(), HwError> {
        (**self).move_to(axis, position)
    }
    fn position(&mut self, axis: usize) -> Result<f64, HwError> {
        (**self).position(axis)
    }
    fn is_busy(&mut self) -> Result<bool, HwError> {
        (**self).is_busy()
    }
}

impl<T: Injector + ?Sized> Injector for Box<T> {
    fn max_pressure(&self) -> f64 {
        (**self).max_pressure()
    }
    fn pulse(&mut self, pressure: f64, duration: f64) -> Result<(), HwError> {
        (**self).pulse(pressure, duration)
    }
}

impl<T: PositionSensor + ?Sized> PositionSensor for Box<T> {
    fn name(&self) -> &str {
        (**self).name()
    }
    fn read(&mut self) -> Result<f64, HwError> {
        (**self).read()
    }
    fn noise(&self) -> f64 {
        (**self).noise()
    }
}

impl<T: Optics + ?Sized> Optics for Box<T> {
    fn zoom(&self) -> f64 {
        (**self).zoom()
    }
    fn zoom_range(&self) -> (f64, f64) {
        (**self).zoom_range()
    }
    fn set_zoom(&mut self, zoom: f64) -> Result<(), HwError> {
        (**self).set_zoom(zoom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A clock that moves when slept and, with `call`, by a device call's round trip.
    struct Link {
        t: f64,
        slept: Vec<f64>,
    }

    impl Clock for Link {
        fn now(&self) -> f64 {
            self.t
        }
        fn sleep(&mut self, seconds: f64) -> Result<(), HwError> {
            check_range("sleep", seconds, 0.0, 1.0e6)?;
            self.slept.push(seconds);
            self.t += seconds;
            Ok(())
        }
    }

    #[test]
    fn a_pacer_counts_the_calls_time_and_sleeps_exactly_dt_on_a_simulated_clock() {
        let dt = 1e-3;
        // Calls that take no time (the twin): every wait is exactly dt, bit for bit.
        let mut c = Link {
            t: 12.345,
            slept: Vec::new(),
        };
        let mut p = Pacer::start(&c, dt);
        for _ in 0..5 {
            p.wait(&mut c).unwrap();
        }
        assert!(c.slept.iter().all(|&s| s == dt), "{:?}", c.slept);
        // Calls of 0.4 ms between waits: samples stay dt apart (not dt + 0.4 ms).
        let mut c = Link {
            t: 0.0,
            slept: Vec::new(),
        };
        let mut p = Pacer::start(&c, dt);
        let mut marks = Vec::new();
        for _ in 0..5 {
            c.t += 4e-4;
            p.wait(&mut c).unwrap();
            marks.push(c.t);
        }
        for w in marks.windows(2) {
            assert!((w[1] - w[0] - dt).abs() < 1e-12, "{marks:?}");
        }
        // Calls slower than dt: no sleep at all, never a negative one.
        c.slept.clear();
        c.t += 5e-3;
        p.wait(&mut c).unwrap();
        assert_eq!(c.slept, vec![0.0]);
    }
}
