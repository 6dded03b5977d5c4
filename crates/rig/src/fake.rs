//! A recording fake backend: devices that accept every command within their own
//! ranges and log it. For tests of controllers and guards without a twin: what the log
//! holds is exactly what reached "the hardware".

use std::sync::{Arc, Mutex, MutexGuard};

use cellinject_hw::{
    Camera, CameraSettings, Clock, Frame, HwError, Injector, Optics, PiezoChannel, PositionSensor,
    Roi, Stage, check_range,
};
use cellinject_model::ACTUATOR_NAMES;

use crate::params::RigParams;
use crate::rig::{Backend, Devices};

/// One command that reached a fake device.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Record {
    /// `set_voltage(volts)` on channel `channel`.
    Voltage {
        /// 0 = A1.
        channel: usize,
        /// V.
        volts: f64,
    },
    /// `move_to(axis, position)`.
    Stage {
        /// Axis.
        axis: usize,
        /// m.
        position: f64,
    },
    /// The feeder stage's `move_to(axis, position)`.
    Feeder {
        /// Axis.
        axis: usize,
        /// m.
        position: f64,
    },
    /// `pulse(pressure, duration)`.
    Pulse {
        /// Pa.
        pressure: f64,
        /// s.
        duration: f64,
    },
    /// `set_zoom(zoom)`.
    Zoom {
        /// Magnification.
        zoom: f64,
    },
    /// `sleep(seconds)`.
    Sleep {
        /// s.
        seconds: f64,
    },
}

/// The log shared by a fake's devices.
pub type Log = Arc<Mutex<Vec<Record>>>;

fn push(log: &Log, r: Record) {
    log.lock().unwrap_or_else(|e| e.into_inner()).push(r);
}

/// Reads a log.
pub fn records(log: &Log) -> MutexGuard<'_, Vec<Record>> {
    log.lock().unwrap_or_else(|e| e.into_inner())
}

/// The fake backend's device types.
#[derive(Debug, Clone, Copy)]
pub struct FakeBackend;

impl Backend for FakeBackend {
    type Piezo = FakePiezo;
    type Sensor = FakeSensor;
    type Camera = FakeCamera;
    type Stage = FakeStage;
    type Injector = FakeInjector;
    type Optics = FakeOptics;
    type Clock = FakeClock;
}

/// An amplifier channel that logs accepted voltages and outputs them at once.
#[derive(Debug)]
pub struct FakePiezo {
    log: Log,
    channel: usize,
    v_max: f64,
    volts: f64,
}

impl PiezoChannel for FakePiezo {
    fn name(&self) -> &str {
        ACTUATOR_NAMES[self.channel]
    }
    fn voltage_range(&self) -> (f64, f64) {
        (0.0, self.v_max)
    }
    fn set_voltage(&mut self, volts: f64) -> Result<(), HwError> {
        check_range(
            ["A1 voltage", "A2 voltage", "A3 voltage"][self.channel],
            volts,
            0.0,
            self.v_max,
        )?;
        push(
            &self.log,
            Record::Voltage {
                channel: self.channel,
                volts,
            },
        );
        self.volts = volts;
        Ok(())
    }
    fn commanded_voltage(&self) -> f64 {
        self.volts
    }
    fn read_voltage(&mut self) -> Result<f64, HwError> {
        Ok(self.volts)
    }
}

/// A sensor that reads a linear, noise-free stack: 0.3 µm per volt of its channel's
/// last accepted command (a stand-in for tests; it knows nothing of physics).
#[derive(Debug)]
pub struct FakeSensor {
    log: Log,
    channel: usize,
}

impl PositionSensor for FakeSensor {
    fn name(&self) -> &str {
        ACTUATOR_NAMES[self.channel]
    }
    fn read(&mut self) -> Result<f64, HwError> {
        let volts = records(&self.log)
            .iter()
            .rev()
            .find_map(|r| match r {
                Record::Voltage { channel, volts } if *channel == self.channel => Some(*volts),
                _ => None,
            })
            .unwrap_or(0.0);
        Ok(0.3e-6 * volts)
    }
    fn noise(&self) -> f64 {
        0.0
    }
}

/// A camera that returns blank frames.
#[derive(Debug)]
pub struct FakeCamera {
    settings: CameraSettings,
    index: u64,
}

impl Camera for FakeCamera {
    fn sensor_size(&self) -> (u32, u32) {
        (640, 480)
    }
    fn settings(&self) -> CameraSettings {
        self.settings
    }
    fn configure(&mut self, settings: CameraSettings) -> Result<(), HwError> {
        self.settings = settings;
        Ok(())
    }
    fn frame_rate(&self) -> f64 {
        30.0
    }
    fn grab_into(&mut self, frame: &mut Frame) -> Result<(), HwError> {
        let r = self.settings.roi;
        frame.width = r.width / self.settings.binning;
        frame.height = r.height / self.settings.binning;
        frame.bit_depth = self.settings.bit_depth;
        frame.pixels.clear();
        frame
            .pixels
            .resize(frame.width as usize * frame.height as usize, 0);
        frame.index = self.index;
        frame.exposure = self.settings.exposure;
        self.index += 1;
        Ok(())
    }
}

/// A three-axis stage that logs moves and arrives at once.
#[derive(Debug)]
pub struct FakeStage {
    log: Log,
    travel: (f64, f64),
    position: [f64; 3],
    /// The feeder stage (logged as [`Record::Feeder`]).
    feeder: bool,
    /// Looks at it that find it still moving before it stops (0: it arrives at once;
    /// `usize::MAX`: it never stops). Set before the rig wraps it.
    pub busy_polls: usize,
}

impl Stage for FakeStage {
    fn axes(&self) -> usize {
        3
    }
    fn travel(&self, _axis: usize) -> (f64, f64) {
        self.travel
    }
    fn move_to(&mut self, axis: usize, position: f64) -> Result<(), HwError> {
        check_range("stage axis", axis as f64, 0.0, (self.axes() - 1) as f64)?;
        check_range("stage position", position, self.travel.0, self.travel.1)?;
        push(
            &self.log,
            if self.feeder {
                Record::Feeder { axis, position }
            } else {
                Record::Stage { axis, position }
            },
        );
        self.position[axis] = position;
        Ok(())
    }
    fn position(&mut self, axis: usize) -> Result<f64, HwError> {
        check_range("stage axis", axis as f64, 0.0, (self.axes() - 1) as f64)?;
        Ok(self.position[axis])
    }
    fn is_busy(&mut self) -> Result<bool, HwError> {
        let busy = self.busy_polls > 0;
        if busy && self.busy_polls != usize::MAX {
            self.busy_polls -= 1;
        }
        Ok(busy)
    }
}

/// An injector that logs pulses.
#[derive(Debug)]
pub struct FakeInjector {
    log: Log,
    max: f64,
}

impl Injector for FakeInjector {
    fn max_pressure(&self) -> f64 {
        self.max
    }
    fn pulse(&mut self, pressure: f64, duration: f64) -> Result<(), HwError> {
        check_range("pressure", pressure, 0.0, self.max)?;
        check_range("pulse duration", duration, 0.0, 10.0)?;
        push(&self.log, Record::Pulse { pressure, duration });
        Ok(())
    }
}

/// A zoom lens that logs changes.
#[derive(Debug)]
pub struct FakeOptics {
    log: Log,
    zoom: f64,
    range: (f64, f64),
}

impl Optics for FakeOptics {
    fn zoom(&self) -> f64 {
        self.zoom
    }
    fn zoom_range(&self) -> (f64, f64) {
        self.range
    }
    fn set_zoom(&mut self, zoom: f64) -> Result<(), HwError> {
        check_range("zoom", zoom, self.range.0, self.range.1)?;
        push(&self.log, Record::Zoom { zoom });
        self.zoom = zoom;
        Ok(())
    }
}

/// A clock that only counts.
#[derive(Debug)]
pub struct FakeClock {
    log: Log,
    now: f64,
}

impl Clock for FakeClock {
    fn now(&self) -> f64 {
        self.now
    }
    fn sleep(&mut self, seconds: f64) -> Result<(), HwError> {
        check_range("sleep", seconds, 0.0, 1.0e6)?;
        push(&self.log, Record::Sleep { seconds });
        self.now += seconds;
        Ok(())
    }
}

/// Fake devices whose own ranges are `rig`'s (a device with wider ranges would be
/// narrowed by the guards anyway), and the log they write to.
pub fn devices(rig: &RigParams) -> (Devices<FakeBackend>, Log) {
    let log: Log = Arc::default();
    let piezo = [0, 1, 2].map(|channel| FakePiezo {
        log: log.clone(),
        channel,
        v_max: rig.amplifiers[channel].v_max,
        volts: 0.0,
    });
    let devices = Devices {
        piezo,
        sensors: [0, 1, 2].map(|channel| FakeSensor {
            log: log.clone(),
            channel,
        }),
        camera: FakeCamera {
            settings: CameraSettings {
                roi: Roi {
                    x: 0,
                    y: 0,
                    width: 640,
                    height: 480,
                },
                binning: 1,
                exposure: 5e-3,
                bit_depth: 8,
            },
            index: 0,
        },
        side_camera: FakeCamera {
            settings: CameraSettings {
                roi: Roi {
                    x: 0,
                    y: 0,
                    width: 640,
                    height: 480,
                },
                binning: 1,
                exposure: 5e-3,
                bit_depth: 8,
            },
            index: 0,
        },
        stage: FakeStage {
            log: log.clone(),
            travel: rig.stage_limits(),
            position: [0.0; 3],
            feeder: false,
            busy_polls: 0,
        },
        feeder: FakeStage {
            log: log.clone(),
            travel: rig.feeder_limits(),
            position: [0.0; 3],
            feeder: true,
            busy_polls: 0,
        },
        injector: FakeInjector {
            log: log.clone(),
            max: rig.injector_max_pressure,
        },
        optics: FakeOptics {
            log: log.clone(),
            zoom: rig.optics.zoom,
            range: (rig.optics.zoom_range[0], rig.optics.zoom_range[1]),
        },
        clock: FakeClock {
            log: log.clone(),
            now: 0.0,
        },
    };
    (devices, log)
}
