//! The guarded device set of one bench, over any backend.

use cellinject_hw::{
    Camera, Clock, HwError, Injector, Optics, PiezoChannel, PositionSensor, Stage,
};
use cellinject_model::{Design, Mechanism, ModelError};
use thiserror::Error;

use crate::guard::{
    EnvelopeLimits, GuardedInjector, GuardedOptics, GuardedPiezo, GuardedStage, PiezoEnvelope,
    SharedGuard, lock, shared_guard,
};
use crate::params::RigParams;

/// A family of device types: the twin, a real controller, a recording fake. Every
/// device is `Send`, so a bench can live on a control thread.
pub trait Backend {
    /// One amplifier channel.
    type Piezo: PiezoChannel;
    /// One stack's position sensor.
    type Sensor: PositionSensor;
    /// A camera (the microscope's top view and the side view are of this type).
    type Camera: Camera;
    /// The macro stage.
    type Stage: Stage;
    /// The injector.
    type Injector: Injector;
    /// The zoom lens.
    type Optics: Optics;
    /// The clock.
    type Clock: Clock;
}

/// Every device of a backend, unguarded.
pub struct Devices<B: Backend> {
    /// A1, A2, A3.
    pub piezo: [B::Piezo; 3],
    /// The stacks' position sensors, A1, A2, A3.
    pub sensors: [B::Sensor; 3],
    /// The microscope camera, looking along y: sees x (columns) and z (rows).
    pub camera: B::Camera,
    /// The side camera, looking along x: sees y (columns) and z (rows).
    pub side_camera: B::Camera,
    /// Stage.
    pub stage: B::Stage,
    /// The feeder stage carrying the plate (axis 0: plate x, axis 1: plate y, axis 2:
    /// the plate's height along the optical axis, its focus).
    pub feeder: B::Stage,
    /// Injector.
    pub injector: B::Injector,
    /// Zoom lens.
    pub optics: B::Optics,
    /// Clock.
    pub clock: B::Clock,
}

/// A backend chosen at run time: every device boxed behind its trait.
#[derive(Debug, Clone, Copy)]
pub struct DynBackend;

impl Backend for DynBackend {
    type Piezo = Box<dyn PiezoChannel>;
    type Sensor = Box<dyn PositionSensor>;
    type Camera = Box<dyn Camera>;
    type Stage = Box<dyn Stage>;
    type Injector = Box<dyn Injector>;
    type Optics = Box<dyn Optics>;
    type Clock = Box<dyn Clock>;
}

impl<B: Backend> Devices<B>
where
    B::Piezo: 'static,
    B::Sensor: 'static,
    B::Camera: 'static,
    B::Stage: 'static,
    B::Injector: 'static,
    B::Optics: 'static,
    B::Clock: 'static,
{
    /// The same devices, boxed.
    pub fn boxed(self) -> Devices<DynBackend> {
        Devices {
            piezo: self.piezo.map(|p| Box::new(p) as Box<dyn PiezoChannel>),
            sensors: self.sensors.map(|s| Box::new(s) as Box<dyn PositionSensor>),
            camera: Box::new(self.camera),
            side_camera: Box::new(self.side_camera),
            stage: Box::new(self.stage),
            feeder: Box::new(self.feeder),
            injector: Box::new(self.injector),
            optics: Box::new(self.optics),
            clock: Box::new(self.clock),
        }
    }
}

/// Why a bench could not be set up.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RigError {
    /// The mechanism model refused the design or its assembly.
    #[error("the mechanism model: {0}")]
    Model(#[from] ModelError),
    /// An amplifier's range in the rig description differs from the device's own.
    #[error(
        "{channel}: the description's amplifier range 0..{described} V differs from the device's {device_min}..{device_max} V (actuators.{channel}.amplifier.v_max)"
    )]
    AmplifierRange {
        /// Channel name.
        channel: &'static str,
        /// The description's highest voltage.
        described: f64,
        /// The device's lowest voltage.
        device_min: f64,
        /// The device's highest voltage.
        device_max: f64,
    },
}

/// The devices of one bench behind the safety wrappers, as every controller, program
/// and front end should see them.
pub struct Rig<B: Backend> {
    /// A1, A2, A3 behind the shared piezo envelope.
    pub piezo: [GuardedPiezo<B::Piezo>; 3],
    /// The envelope's shared state.
    pub guard: SharedGuard,
    /// The stacks' position sensors (read-only: nothing to guard).
    pub sensors: [B::Sensor; 3],
    /// The microscope camera, looking along y: x in its columns, z in its rows
    /// (nothing to guard).
    pub camera: B::Camera,
    /// The side camera, looking along x: y in its columns, z in its rows.
    pub side_camera: B::Camera,
    /// Stage within the rig's travel.
    pub stage: GuardedStage<B::Stage>,
    /// The feeder stage within the rig's feeder travel.
    pub feeder: GuardedStage<B::Stage>,
    /// Injector below the rig's pressure limit.
    pub injector: GuardedInjector<B::Injector>,
    /// Zoom within the rig's range.
    pub optics: GuardedOptics<B::Optics>,
    /// Clock.
    pub clock: B::Clock,
}

/// The safety envelope of a design assembled and wired as `rig` describes.
pub fn envelope(design: &Design, rig: &RigParams) -> Result<PiezoEnvelope, ModelError> {
    let limits = EnvelopeLimits {
        voltage_range: rig.amplifiers.map(|a| (0.0, a.v_max)),
        hysteresis_bound: rig.safety.hysteresis_bound,
        dynamic_margin: rig.safety.dynamic_margin,
        j3: rig.j3_yield,
    };
    PiezoEnvelope::new(Mechanism::new(design)?, rig.approach, limits)
}

impl<B: Backend> Rig<B> {
    /// Wraps a backend's devices in the guards of `design` and `rig`. The amplifiers'
    /// own ranges must be the description's (else the envelope would be computed for
    /// other voltages than the device applies).
    pub fn new(devices: Devices<B>, design: &Design, rig: &RigParams) -> Result<Self, RigError> {
        for (ch, p) in devices.piezo.iter().enumerate() {
            let (lo, hi) = p.voltage_range();
            let described = rig.amplifiers[ch].v_max;
            if lo != 0.0 || hi != described {
                return Err(RigError::AmplifierRange {
                    channel: cellinject_model::ACTUATOR_NAMES[ch],
                    described,
                    device_min: lo,
                    device_max: hi,
                });
            }
        }
        let env = envelope(design, rig)?;
        let commanded = [0, 1, 2].map(|i| devices.piezo[i].commanded_voltage());
        let guard = shared_guard(env, commanded);
        let [a1, a2, a3] = devices.piezo;
        let limits = rig.stage_limits();
        let axes = devices.stage.axes();
        let feeder_limits = rig.feeder_limits();
        let feeder_axes = devices.feeder.axes();
        Ok(Rig {
            piezo: [
                GuardedPiezo::new(a1, 0, guard.clone()),
                GuardedPiezo::new(a2, 1, guard.clone()),
                GuardedPiezo::new(a3, 2, guard.clone()),
            ],
            guard,
            sensors: devices.sensors,
            camera: devices.camera,
            side_camera: devices.side_camera,
            stage: GuardedStage::new(devices.stage, Some(vec![limits; axes])),
            feeder: GuardedStage::new(devices.feeder, Some(vec![feeder_limits; feeder_axes])),
            injector: GuardedInjector::new(devices.injector, rig.injector_max_pressure),
            optics: GuardedOptics::new(
                devices.optics,
                (rig.optics.zoom_range[0], rig.optics.zoom_range[1]),
            ),
            clock: devices.clock,
        })
    }

    /// Commands A1 and A2 together (A3 stays): the farthest safe point towards `volts`
    /// ([`PiezoEnvelope::limit_towards`]), set channel by channel in an order the
    /// envelope accepts at every instant. Returns what was applied; allocates nothing
    /// when the command is accepted.
    pub fn command_tilt(&mut self, volts: [f64; 2]) -> Result<[f64; 2], HwError> {
        let (from, to) = {
            let g = lock(&self.guard);
            let from = g.commanded();
            (
                from,
                g.envelope()
                    .limit_towards(from, [volts[0], volts[1], from[2]]),
            )
        };
        if to == from {
            return Ok([from[0], from[1]]);
        }
        let [a1, a2, _] = &mut self.piezo;
        match a1.set_voltage(to[0]) {
            Ok(()) => a2.set_voltage(to[1])?,
            Err(_) => {
                // A1 first would leave the envelope for an instant: A2 first.
                a2.set_voltage(to[1])?;
                a1.set_voltage(to[0])?;
            }
        }
        Ok([to[0], to[1]])
    }

    /// The highest voltage channel `ch` may take with the other channels where they
    /// were last commanded, or `None` if none is safe.
    pub fn max_safe_voltage(&self, ch: usize) -> Option<f64> {
        let g = lock(&self.guard);
        g.envelope().max_safe_voltage(ch, g.commanded())
    }

    /// Waits on the rig's clock until the macro stage has stopped, looking every
    /// `poll` s; a timeout naming `what` (e.g. "stage (lifting the pipette clear)")
    /// once `deadline` s have passed with it still moving. The one wait of every
    /// plain stage move (a move that servos the stacks meanwhile waits its own way).
    pub fn wait_stage(&mut self, deadline: f64, poll: f64, what: &str) -> Result<(), HwError> {
        let t0 = self.clock.now();
        while self.stage.is_busy()? {
            let waited = self.clock.now() - t0;
            if waited > deadline {
                return Err(HwError::Timeout {
                    device: what.into(),
                    seconds: waited,
                });
            }
            self.clock.sleep(poll)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use crate::fake;

    fn rig(busy_polls: usize) -> Rig<fake::FakeBackend> {
        let params = RigParams::default();
        let (mut devices, _log) = fake::devices(&params);
        devices.stage.busy_polls = busy_polls;
        Rig::new(devices, &cellinject_model::prototype(), &params).unwrap()
    }

    /// A stage that stops after three looks is waited for three polls of the clock; one
    /// that never stops is a timeout naming what was waited for, after the deadline.
    #[test]
    fn the_stage_wait_ends_when_it_stops_or_at_the_deadline() {
        let mut r = rig(3);
        let t0 = r.clock.now();
        r.wait_stage(1.0, 0.01, "stage").unwrap();
        assert!((r.clock.now() - t0 - 0.03).abs() < 1e-12);
        let mut r = rig(usize::MAX);
        let t0 = r.clock.now();
        match r.wait_stage(0.5, 0.01, "stage (lifting the pipette clear)") {
            Err(HwError::Timeout { device, seconds }) => {
                assert_eq!(device, "stage (lifting the pipette clear)");
                assert!(seconds > 0.5 && seconds < 0.52, "{seconds}");
            }
            other => panic!("{other:?}"),
        }
        assert!(r.clock.now() - t0 < 0.52);
    }
}
