//! # cellinject-control
//!
//! The control laws that position the end-effector, behind one [`Controller`] trait:
//!
//! | kind | law | measures | bandwidth here |
//! |---|---|---|---|
//! | [`Open`] | `V = e / g`, the nominal linear gain (the naive baseline) | nothing | the amplifier's (2 kHz) |
//! | [`Feedforward`] | inverse hysteresis model (Preisach or Prandtl-Ishlinskii) of the desired extension, with logarithmic creep compensation while a position is held | nothing | the amplifier's |
//! | [`SensorLoop`] | PI on each stack's position sensor, sampled at 1 kHz, around the feedforward | the stacks | ~60 Hz (see [`SensorGains`]) |
//! | [`Cascade`] | the sensor loop inside; outside, an integrator on the end-effector position the cameras measure by DIC (30 fps), mapped to stack corrections through the calibrated Jacobian | stacks + cameras | ~3 Hz (see [`Cascade`]) |
//!
//! A controller is given, each step, the reference (the stacks' desired extensions from
//! rest, m) and what was measured (stack extensions, and a camera measurement of the
//! tip when a frame's correlation has just finished), and returns the voltages for A1
//! and A2. Whatever the caller actually applies after the safety wrapper (which may
//! refuse or shorten a command) it reports back through [`Controller::applied`]; the
//! integrators use it for anti-windup (back-calculation), and the hysteresis models'
//! memories follow the applied voltage, not the wished one.
//!
//! A frame that was lost or whose correlation was rejected ([`Vision::Rejected`]) leaves
//! the outer loop's correction where it was: the command is held, never driven by a
//! measurement that is not there.
//!
//! **Architecture invariant:** pure computation: no IO, no clock of its own (time is
//! an argument), no device. A step allocates nothing (a test counts allocations).

use cellinject_hysteresis::{AnyModel, LogCreep, Model, inverse_step};
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// The four controllers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// [`Open`].
    Open,
    /// [`Feedforward`].
    Feedforward,
    /// [`SensorLoop`].
    Sensor,
    /// [`Cascade`].
    Closed,
}

impl Kind {
    /// All, from the naive baseline to the cascade.
    pub const ALL: [Kind; 4] = [Kind::Open, Kind::Feedforward, Kind::Sensor, Kind::Closed];

    /// The name used on the command line and in files.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Open => "open",
            Kind::Feedforward => "feedforward",
            Kind::Sensor => "sensor",
            Kind::Closed => "closed",
        }
    }

    /// Whether the controller reads the stack sensors.
    pub fn uses_sensors(self) -> bool {
        matches!(self, Kind::Sensor | Kind::Closed)
    }

    /// Whether the controller acts on camera measurements.
    pub fn uses_vision(self) -> bool {
        self == Kind::Closed
    }
}

/// What the camera loop delivered this step.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Vision {
    /// No new frame result.
    #[default]
    Nothing,
    /// The end-effector's displacement from rest (x, y), m, measured on a frame.
    Tip([f64; 2]),
    /// A frame was lost or its correlation rejected: no measurement.
    Rejected,
}

/// What was measured for one step.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Measurement {
    /// Stack extensions of A1 and A2 from rest, m, when the sensors were read.
    pub stacks: Option<[f64; 2]>,
    /// The camera loop's news.
    pub vision: Vision,
    /// The stack references in effect while the frame behind [`Measurement::vision`]
    /// was exposed (m): the tip it shows is compared with where it should have been
    /// then, not now (a moving reference would otherwise read as an error of its speed
    /// times the camera's latency). `None`: the current reference.
    pub frame_reference: Option<[f64; 2]>,
}

/// How a stack's command was limited in the last step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Saturation {
    /// Not limited.
    #[default]
    Free,
    /// Held up: at 0 V, at the model's lowest reach, or raised by the safety wrapper.
    Low,
    /// Held down: at `v_max`, at the model's highest reach, or shortened by the safety
    /// wrapper.
    High,
}

impl Saturation {
    /// Whether a change of `d` (positive: more extension) would push further into the
    /// limit.
    pub fn blocks(self, d: f64) -> bool {
        match self {
            Saturation::Free => false,
            Saturation::Low => d < 0.0,
            Saturation::High => d > 0.0,
        }
    }

    /// The limit a command `asked` met if `got` is what came out.
    fn of(asked: f64, got: f64) -> Saturation {
        if got < asked {
            Saturation::High
        } else if got > asked {
            Saturation::Low
        } else {
            Saturation::Free
        }
    }

    /// The first limit of the two that is one.
    fn or(self, other: Saturation) -> Saturation {
        if self == Saturation::Free {
            other
        } else {
            self
        }
    }
}

/// A control law for the two tilt stacks A1 and A2.
pub trait Controller: Send {
    /// Which law.
    fn kind(&self) -> Kind;
    /// Forgets integrators and hysteresis memory: the stacks are relaxed at 0 V.
    fn reset(&mut self);
    /// One step at time `t` (s) towards `reference` (desired stack extensions from
    /// rest, m): the voltages to command on A1 and A2, within `[0, v_max]`.
    fn step(&mut self, t: f64, reference: [f64; 2], measured: &Measurement) -> [f64; 2];
    /// The voltages the caller actually applied after the safety wrapper.
    fn applied(&mut self, volts: [f64; 2]);
    /// Per stack, whether the last step had to clip its command (to `[0, v_max]` or
    /// the model's reach) or the safety wrapper changed it, and which way.
    fn saturation(&self) -> [Saturation; 2];
    /// Whether either stack is limited ([`Controller::saturation`]).
    fn saturated(&self) -> bool {
        self.saturation().iter().any(|s| *s != Saturation::Free)
    }
}

/// Why a controller could not be built.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ControlError {
    /// A parameter outside its domain.
    #[error("{what} = {value} {reason}")]
    Invalid {
        /// Which parameter.
        what: &'static str,
        /// Its value.
        value: f64,
        /// What is wrong.
        reason: &'static str,
    },
    /// The Jacobian cannot be inverted.
    #[error(
        "the actuator-to-tip Jacobian [[{0:e}, {1:e}], [{2:e}, {3:e}]] is singular: the stacks do not move the tip in two directions"
    )]
    SingularJacobian(f64, f64, f64, f64),
}

fn positive(what: &'static str, value: f64) -> Result<f64, ControlError> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(ControlError::Invalid {
            what,
            value,
            reason: "must be a positive number",
        })
    }
}

/// The two stacks as the controllers see them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stacks {
    /// m/V, nominal extension per volt (travel over the amplifier's range).
    pub gain: [f64; 2],
    /// V, the highest voltage each channel may be asked for.
    pub v_max: [f64; 2],
}

impl Stacks {
    fn check(&self) -> Result<(), ControlError> {
        for i in 0..2 {
            positive("stack gain", self.gain[i])?;
            positive("v_max", self.v_max[i])?;
        }
        Ok(())
    }

    fn clip(&self, v: [f64; 2]) -> ([f64; 2], [Saturation; 2]) {
        let mut out = v;
        let mut sat = [Saturation::Free; 2];
        for i in 0..2 {
            let c = if v[i].is_nan() {
                0.0
            } else {
                v[i].clamp(0.0, self.v_max[i])
            };
            sat[i] = if v[i].is_nan() {
                Saturation::Low
            } else {
                Saturation::of(v[i], c)
            };
            out[i] = c;
        }
        (out, sat)
    }
}

/// The naive baseline: `V = e / g` with the nominal gain.
#[derive(Debug, Clone)]
pub struct Open {
    stacks: Stacks,
    saturated: [Saturation; 2],
    last: [f64; 2],
}

impl Open {
    /// An open-loop controller of `stacks`.
    pub fn new(stacks: Stacks) -> Result<Self, ControlError> {
        stacks.check()?;
        Ok(Open {
            stacks,
            saturated: [Saturation::Free; 2],
            last: [0.0; 2],
        })
    }
}

impl Controller for Open {
    fn kind(&self) -> Kind {
        Kind::Open
    }
    fn reset(&mut self) {
        self.saturated = [Saturation::Free; 2];
    }
    fn step(&mut self, _t: f64, reference: [f64; 2], _m: &Measurement) -> [f64; 2] {
        let v = [0, 1].map(|i| reference[i] / self.stacks.gain[i]);
        let (v, sat) = self.stacks.clip(v);
        self.saturated = sat;
        self.last = v;
        v
    }
    fn applied(&mut self, volts: [f64; 2]) {
        for i in 0..2 {
            self.saturated[i] = self.saturated[i].or(Saturation::of(self.last[i], volts[i]));
        }
    }
    fn saturation(&self) -> [Saturation; 2] {
        self.saturated
    }
}

/// Inverse hysteresis feedforward with creep compensation.
///
/// Each stack's model maps voltage to extension from the state its memory holds; the
/// command for a desired extension `e` held since `t₀` is the model's inverse of
/// `e / (1 + γ·log₁₀((t − t₀)/τ))` ([`LogCreep::compensate`]): the stack creeps
/// towards `e` instead of past it.
#[derive(Debug, Clone)]
pub struct Feedforward {
    stacks: Stacks,
    models: [AnyModel; 2],
    creep: [Option<LogCreep>; 2],
    held: [f64; 2],
    since: [f64; 2],
    saturated: [Saturation; 2],
    last: [f64; 2],
}

impl Feedforward {
    /// A feedforward from identified models (input V, output m, relaxed at 0 V) and
    /// creep laws of A1 and A2.
    pub fn new(
        stacks: Stacks,
        models: [AnyModel; 2],
        creep: [Option<LogCreep>; 2],
    ) -> Result<Self, ControlError> {
        stacks.check()?;
        let mut f = Feedforward {
            stacks,
            models,
            creep,
            held: [0.0; 2],
            since: [0.0; 2],
            saturated: [Saturation::Free; 2],
            last: [0.0; 2],
        };
        f.reset();
        Ok(f)
    }

    /// The models (their memories follow the applied voltages).
    pub fn models(&self) -> &[AnyModel; 2] {
        &self.models
    }

    fn volts(&mut self, t: f64, reference: [f64; 2]) -> ([f64; 2], [Saturation; 2]) {
        let mut out = [0.0; 2];
        let mut reach = [Saturation::Free; 2];
        for i in 0..2 {
            if reference[i] != self.held[i] {
                self.held[i] = reference[i];
                self.since[i] = t;
            }
            let target = match self.creep[i] {
                Some(c) => c.compensate(reference[i], t - self.since[i]),
                None => reference[i],
            };
            let model = &self.models[i];
            let range = model.range();
            let v = match inverse_step(model, target, range) {
                Ok(v) => v,
                Err((lo, _)) => {
                    if target.is_nan() || target < lo {
                        reach[i] = Saturation::Low;
                        range.min
                    } else {
                        reach[i] = Saturation::High;
                        range.max
                    }
                }
            };
            out[i] = v;
        }
        let (v, c) = self.stacks.clip(out);
        (v, [0, 1].map(|i| reach[i].or(c[i])))
    }
}

impl Controller for Feedforward {
    fn kind(&self) -> Kind {
        Kind::Feedforward
    }
    fn reset(&mut self) {
        for m in &mut self.models {
            m.reset();
        }
        self.held = [0.0; 2];
        self.since = [0.0; 2];
        self.saturated = [Saturation::Free; 2];
        self.last = [0.0; 2];
    }
    fn step(&mut self, t: f64, reference: [f64; 2], _m: &Measurement) -> [f64; 2] {
        let (v, sat) = self.volts(t, reference);
        self.saturated = sat;
        self.last = v;
        v
    }
    fn applied(&mut self, volts: [f64; 2]) {
        for i in 0..2 {
            self.models[i].apply(volts[i]);
            self.saturated[i] = self.saturated[i].or(Saturation::of(self.last[i], volts[i]));
        }
    }
    fn saturation(&self) -> [Saturation; 2] {
        self.saturated
    }
}

/// Gains of the stack-sensor PI loop, relative to the stack's gain `g` (m/V).
///
/// Sampled at `rate`, the loop sees the amplifier (first order, 2 kHz) and one sample
/// of delay; with the proportional part `kp·g` and the integral part per sample
/// `ki·g/rate` both below ½ it is well damped, and the integral crossover
/// `ki·g / 2π` sets its bandwidth (defaults: 0.2, 0.4 per sample at 1 kHz: ~64 Hz).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorGains {
    /// Hz, sampling rate of the loop.
    pub rate: f64,
    /// Proportional gain times the stack's gain (1).
    pub proportional: f64,
    /// Integral gain per sample times the stack's gain (1).
    pub integral: f64,
}

impl Default for SensorGains {
    fn default() -> Self {
        SensorGains {
            rate: 1000.0,
            proportional: 0.2,
            integral: 0.4,
        }
    }
}

impl SensorGains {
    /// The loop's bandwidth, Hz (integral crossover).
    pub fn bandwidth(&self) -> f64 {
        self.integral * self.rate / (2.0 * std::f64::consts::PI)
    }
}

/// PI on each stack's position sensor with the inverse hysteresis model inside: the
/// model does most of the work, the PI removes what the model misses and the creep
/// (the feedforward's own creep compensation is off: its hold clock would restart at
/// every correction of the reference and kick the command). It sees the stacks only:
/// what the joints do after them (stick-slip) stays.
#[derive(Debug, Clone)]
pub struct SensorLoop {
    ff: Feedforward,
    gains: SensorGains,
    /// The reference the feedforward was last evaluated for, and its command.
    ff_for: Option<([f64; 2], [f64; 2], [Saturation; 2])>,
    /// V, the integral term.
    integral: [f64; 2],
    /// V, the last command.
    last: [f64; 2],
    saturated: [Saturation; 2],
}

impl SensorLoop {
    /// A sensor loop around `ff` (whose creep compensation it switches off).
    pub fn new(mut ff: Feedforward, gains: SensorGains) -> Result<Self, ControlError> {
        ff.creep = [None, None];
        positive("sensor loop rate", gains.rate)?;
        for (what, g) in [
            ("proportional gain", gains.proportional),
            ("integral gain", gains.integral),
        ] {
            if !(g.is_finite() && (0.0..1.0).contains(&g)) {
                return Err(ControlError::Invalid {
                    what,
                    value: g,
                    reason: "must lie in [0, 1) (per sample, times the stack's gain)",
                });
            }
        }
        Ok(SensorLoop {
            ff,
            gains,
            ff_for: None,
            integral: [0.0; 2],
            last: [0.0; 2],
            saturated: [Saturation::Free; 2],
        })
    }

    /// The gains.
    pub fn gains(&self) -> SensorGains {
        self.gains
    }
}

impl Controller for SensorLoop {
    fn kind(&self) -> Kind {
        Kind::Sensor
    }
    fn reset(&mut self) {
        self.ff.reset();
        self.ff_for = None;
        self.integral = [0.0; 2];
        self.last = [0.0; 2];
        self.saturated = [Saturation::Free; 2];
    }
    fn step(&mut self, t: f64, reference: [f64; 2], m: &Measurement) -> [f64; 2] {
        // The inverse model gives the command for a new reference, from the state the
        // stack is in; while the reference holds, the PI alone acts (re-inverting from
        // the state its own corrections leave would fight them).
        let (ff, clipped) = match self.ff_for {
            Some((r, v, c)) if r == reference => (v, c),
            _ => {
                let (v, c) = self.ff.volts(t, reference);
                self.ff_for = Some((reference, v, c));
                (v, c)
            }
        };
        let mut u = ff;
        for i in 0..2 {
            let g = self.ff.stacks.gain[i];
            let e = match m.stacks {
                Some(s) if s[i].is_finite() => reference[i] - s[i],
                // No reading: hold the integral, no proportional action.
                _ => 0.0,
            };
            self.integral[i] += self.gains.integral / g * e;
            u[i] = ff[i] + self.gains.proportional / g * e + self.integral[i];
        }
        let (v, c) = self.ff.stacks.clip(u);
        self.saturated = [0, 1].map(|i| clipped[i].or(c[i]));
        self.last = v;
        // Back-calculation: the integral absorbs what the clip removed.
        for i in 0..2 {
            self.integral[i] += v[i] - u[i];
        }
        v
    }
    fn applied(&mut self, volts: [f64; 2]) {
        for i in 0..2 {
            let d = volts[i] - self.last[i];
            if d != 0.0 {
                // The safety wrapper changed the command: unwind by as much.
                self.integral[i] += d;
                self.saturated[i] = self.saturated[i].or(Saturation::of(self.last[i], volts[i]));
            }
        }
        self.ff.applied(volts);
    }
    fn saturation(&self) -> [Saturation; 2] {
        self.saturated
    }
}

/// The cascaded visual servo: the [`SensorLoop`] inside, and outside an integrator on
/// the tip position the cameras measure.
///
/// On each camera measurement `p` (x, y from rest, m) the correction of the stack
/// references grows by `k · J⁻¹ (J·r − p)`, where `r` is the reference and `J` the
/// calibrated actuator-to-tip Jacobian (m of tip per m of stack). A frame shows where
/// the tip was during its exposure and its measurement arrives after the correlation's
/// latency (15 ms of a 33 ms frame), so a correction is seen fully only a frame later:
/// with that one-frame delay the loop `c ← c + k·e` has the poles `z² − z + k = 0`,
/// stable for `k` < 1, without overshoot only for `k` ≤ ¼. The default 0.6 (in
/// `cellinject-core`) accepts a damped overshoot (poles at 0.77·e^(±0.87i), ζ ≈ 0.28) to settle an error within
/// 100 nm in about 6 frames; the bandwidth is about `k · fps / 2π` (0.6 at 30 fps:
/// ~3 Hz), set by the camera's frame rate and the correlation's latency, not by the
/// stacks. For
/// [`RING_HOLD_OFF`] after a step of the reference it waits for the structure to stop
/// ringing before it trusts a frame. Anti-windup:
/// a stack's correction does not integrate further in the direction the inner loop is
/// limited in (at 0 V, at `v_max`, or held back by the safety wrapper), while the other
/// stack's still does, and each stays within `±limit`. A lost or rejected frame leaves it where it is.
#[derive(Debug, Clone)]
pub struct Cascade {
    inner: SensorLoop,
    jacobian: [[f64; 2]; 2],
    inverse: [[f64; 2]; 2],
    gain: f64,
    limit: f64,
    correction: [f64; 2],
    frames: u64,
    last_reference: Option<[f64; 2]>,
    last_step: f64,
}

/// A change of a stack reference larger than this within one control step is a step
/// (m): the structure rings after it (see [`RING_HOLD_OFF`]).
pub const STEP_THRESHOLD: f64 = 100e-9;

/// s during which the cascade ignores camera measurements after a step of the
/// reference: the structure's tilt modes (553 and 618 Hz, 2 % damping) ring with a
/// time constant of 14 ms, and a frame exposed while they ring would be integrated as
/// a position error (and overshoot).
pub const RING_HOLD_OFF: f64 = 0.05;

fn inverse2(j: [[f64; 2]; 2]) -> Result<[[f64; 2]; 2], ControlError> {
    let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
    let scale = j.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
    if !(det.is_finite() && scale > 0.0 && det.abs() > 1e-6 * scale * scale) {
        return Err(ControlError::SingularJacobian(
            j[0][0], j[0][1], j[1][0], j[1][1],
        ));
    }
    Ok([
        [j[1][1] / det, -j[0][1] / det],
        [-j[1][0] / det, j[0][0] / det],
    ])
}

impl Cascade {
    /// A cascade around `inner` with the actuator-to-tip Jacobian `jacobian`
    /// (`[[∂x/∂e₁, ∂x/∂e₂], [∂y/∂e₁, ∂y/∂e₂]]`), the outer gain per frame `gain` in
    /// (0, 1] and the largest correction of a stack reference `limit` (m).
    pub fn new(
        inner: SensorLoop,
        jacobian: [[f64; 2]; 2],
        gain: f64,
        limit: f64,
    ) -> Result<Self, ControlError> {
        if !(gain.is_finite() && gain > 0.0 && gain <= 1.0) {
            return Err(ControlError::Invalid {
                what: "outer gain",
                value: gain,
                reason: "must lie in (0, 1]",
            });
        }
        positive("correction limit", limit)?;
        Ok(Cascade {
            inner,
            inverse: inverse2(jacobian)?,
            jacobian,
            gain,
            limit,
            correction: [0.0; 2],
            frames: 0,
            last_reference: None,
            last_step: f64::NEG_INFINITY,
        })
    }

    /// The correction of the stack references now, m.
    pub fn correction(&self) -> [f64; 2] {
        self.correction
    }

    /// Camera measurements acted on since the last reset.
    pub fn frames_used(&self) -> u64 {
        self.frames
    }
}

impl Controller for Cascade {
    fn kind(&self) -> Kind {
        Kind::Closed
    }
    fn reset(&mut self) {
        self.inner.reset();
        self.correction = [0.0; 2];
        self.frames = 0;
        self.last_reference = None;
        self.last_step = f64::NEG_INFINITY;
    }
    fn step(&mut self, t: f64, reference: [f64; 2], m: &Measurement) -> [f64; 2] {
        let jump = match self.last_reference {
            Some(r) => (0..2).any(|i| (reference[i] - r[i]).abs() > STEP_THRESHOLD),
            None => true,
        };
        if jump {
            self.last_step = t;
        }
        self.last_reference = Some(reference);
        if let Vision::Tip(p) = m.vision
            && p[0].is_finite()
            && p[1].is_finite()
            && t - self.last_step >= RING_HOLD_OFF
        {
            let j = &self.jacobian;
            let at = m.frame_reference.unwrap_or(reference);
            let target = [
                j[0][0] * at[0] + j[0][1] * at[1],
                j[1][0] * at[0] + j[1][1] * at[1],
            ];
            let e = [target[0] - p[0], target[1] - p[1]];
            let k = &self.inverse;
            let sat = self.inner.saturation();
            for i in 0..2 {
                let d = k[i][0] * e[0] + k[i][1] * e[1];
                // Anti-windup per stack: no integration further into a limit.
                if !sat[i].blocks(d) {
                    self.correction[i] =
                        (self.correction[i] + self.gain * d).clamp(-self.limit, self.limit);
                }
            }
            self.frames += 1;
        }
        let r = [
            reference[0] + self.correction[0],
            reference[1] + self.correction[1],
        ];
        self.inner.step(t, r, m)
    }
    fn applied(&mut self, volts: [f64; 2]) {
        self.inner.applied(volts);
    }
    fn saturation(&self) -> [Saturation; 2] {
        self.inner.saturation()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use cellinject_hysteresis::{PrandtlIshlinskii, Range};

    fn stacks() -> Stacks {
        Stacks {
            gain: [0.3e-6; 2],
            v_max: [100.0; 2],
        }
    }

    /// A hysteresis-free "model": one play of zero width, 0.3 µm/V.
    fn linear() -> AnyModel {
        AnyModel::Pi(
            PrandtlIshlinskii::new(
                Range {
                    min: 0.0,
                    max: 100.0,
                },
                0.0,
                vec![0.0],
                // Weights act on the input normalised to [0, 1]: 30 µm over 100 V.
                vec![30e-6],
                0.0,
            )
            .unwrap(),
        )
    }

    fn ff() -> Feedforward {
        Feedforward::new(stacks(), [linear(), linear()], [None, None]).unwrap()
    }

    #[test]
    fn open_loop_is_the_nominal_gain_and_clips() {
        let mut c = Open::new(stacks()).unwrap();
        let v = c.step(0.0, [3e-6, 1e-6], &Measurement::default());
        assert!((v[0] - 10.0).abs() < 1e-9 && (v[1] - 10.0 / 3.0).abs() < 1e-9);
        assert!(!c.saturated());
        let v = c.step(0.0, [-1e-6, 1.0], &Measurement::default());
        assert_eq!(v, [0.0, 100.0]);
        assert!(c.saturated());
    }

    #[test]
    fn feedforward_inverts_its_model() {
        let mut c = ff();
        let v = c.step(0.0, [6e-6, 3e-6], &Measurement::default());
        assert!(
            (v[0] - 20.0).abs() < 1e-6 && (v[1] - 10.0).abs() < 1e-6,
            "{v:?}"
        );
    }

    #[test]
    fn creep_compensation_lowers_the_command_while_holding() {
        let creep = LogCreep::new(0.015, 0.01).unwrap();
        let mut c = Feedforward::new(stacks(), [linear(), linear()], [Some(creep); 2]).unwrap();
        let v0 = c.step(0.0, [6e-6, 6e-6], &Measurement::default());
        c.applied(v0);
        let v1 = c.step(1.0, [6e-6, 6e-6], &Measurement::default());
        // Two decades after 10 ms: 1 + 0.015·2 = 1.03.
        assert!((v0[0] / v1[0] - 1.03).abs() < 1e-6, "{v0:?} {v1:?}");
    }

    #[test]
    fn the_sensor_loop_removes_a_constant_model_error() {
        // The stack really moves 10 % less than the model says.
        let mut c = SensorLoop::new(ff(), SensorGains::default()).unwrap();
        let mut ext = [0.0; 2];
        for k in 0..200 {
            let m = Measurement {
                frame_reference: None,
                stacks: Some(ext),
                vision: Vision::Nothing,
            };
            let v = c.step(k as f64 * 1e-3, [6e-6, 3e-6], &m);
            c.applied(v);
            ext = [0.9 * 0.3e-6 * v[0], 0.9 * 0.3e-6 * v[1]];
        }
        assert!((ext[0] - 6e-6).abs() < 1e-12 && (ext[1] - 3e-6).abs() < 1e-12);
    }

    #[test]
    fn the_integral_does_not_wind_up_when_the_wrapper_shortens_commands() {
        let mut c = SensorLoop::new(ff(), SensorGains::default()).unwrap();
        // The wrapper allows at most 20 V: the reference asks for 40 V.
        for k in 0..1000 {
            let m = Measurement {
                frame_reference: None,
                stacks: Some([6e-6, 0.0]),
                vision: Vision::Nothing,
            };
            let v = c.step(k as f64 * 1e-3, [12e-6, 0.0], &m);
            c.applied([v[0].min(20.0), v[1]]);
        }
        assert!(c.saturated());
        // Once the reference comes back within reach, the command follows at once.
        let v = c.step(
            1.0,
            [3e-6, 0.0],
            &Measurement {
                frame_reference: None,
                stacks: Some([6e-6, 0.0]),
                vision: Vision::Nothing,
            },
        );
        assert!(v[0] < 20.0, "{v:?}");
    }

    fn cascade() -> Cascade {
        let inner = SensorLoop::new(ff(), SensorGains::default()).unwrap();
        Cascade::new(inner, [[6.0, 0.1], [0.2, 6.0]], 0.5, 5e-6).unwrap()
    }

    /// Runs `c` for `steps` ms towards `reference` on linear stacks (0.3 µm/V) behind
    /// joints that add `offset` to the tip, a frame every 33 ms: the last tip
    /// position and command.
    fn run_cascade(
        c: &mut Cascade,
        reference: [f64; 2],
        offset: [f64; 2],
        steps: usize,
    ) -> ([f64; 2], [f64; 2]) {
        let mut ext = [0.0; 2];
        let mut tip = [0.0; 2];
        let mut volts = [0.0; 2];
        for k in 0..steps {
            let vision = if k % 33 == 32 {
                Vision::Tip(tip)
            } else {
                Vision::Nothing
            };
            let m = Measurement {
                frame_reference: None,
                stacks: Some(ext),
                vision,
            };
            volts = c.step(k as f64 * 1e-3, reference, &m);
            c.applied(volts);
            ext = [0.3e-6 * volts[0], 0.3e-6 * volts[1]];
            tip = [
                6.0 * ext[0] + 0.1 * ext[1] + offset[0],
                0.2 * ext[0] + 6.0 * ext[1] + offset[1],
            ];
        }
        (tip, volts)
    }

    #[test]
    fn the_cascade_corrects_what_only_the_camera_sees() {
        // The joints add a constant tip offset the stacks cannot see.
        let mut c = cascade();
        let (tip, _) = run_cascade(&mut c, [1e-6, 1e-6], [0.4e-6, -0.3e-6], 2000);
        let target = [6.1e-6, 6.2e-6];
        assert!((tip[0] - target[0]).abs() < 1e-10 && (tip[1] - target[1]).abs() < 1e-10);
    }

    #[test]
    fn a_stack_held_at_0_v_stops_only_its_own_correction() {
        // The joints put the tip 0.5 µm above where y is wanted at A2's rest: A2 would
        // need less than 0 V. A2's correction must not wind up; A1's still corrects x.
        let mut c = cascade();
        let (tip, volts) = run_cascade(&mut c, [1e-6, 0.0], [0.4e-6, 0.5e-6], 3000);
        assert_eq!(volts[1], 0.0);
        assert_eq!(c.saturation()[1], Saturation::Low);
        // A2's correction stopped where it first reached 0 V, far from its limit.
        assert!(c.correction()[1] > -0.2e-6, "{:?}", c.correction());
        // x lands on its target up to the coupling the blocked stack leaves
        // (J⁻¹'s off-diagonal term times y's error: about 1.7 % of it).
        let target = [6e-6, 0.2e-6];
        let (ex, ey) = (tip[0] - target[0], tip[1] - target[1]);
        assert!(ey > 0.4e-6, "{ey}");
        assert!(ex.abs() < 0.02 * ey, "x error {ex}, y error {ey}");
    }

    #[test]
    fn a_rejected_frame_holds_the_command() {
        let mut c = cascade();
        let m = |v| Measurement {
            frame_reference: None,
            stacks: Some([1e-6, 1e-6]),
            vision: v,
        };
        // A frame within the ring hold-off after the step is not acted on.
        let v = c.step(0.0, [1e-6, 1e-6], &m(Vision::Tip([5e-6, 5e-6])));
        c.applied(v);
        assert_eq!(c.correction(), [0.0; 2]);
        let v0 = c.step(0.1, [1e-6, 1e-6], &m(Vision::Tip([5e-6, 5e-6])));
        c.applied(v0);
        let before = c.correction();
        assert!(before != [0.0; 2]);
        // A rejected frame acts exactly like no frame at all.
        let mut twin = c.clone();
        let v1 = c.step(0.101, [1e-6, 1e-6], &m(Vision::Rejected));
        let v2 = twin.step(0.101, [1e-6, 1e-6], &m(Vision::Nothing));
        assert_eq!(c.correction(), before);
        assert_eq!(v1, v2);
        // A NaN measurement is no measurement either.
        c.step(0.102, [1e-6, 1e-6], &m(Vision::Tip([f64::NAN, 0.0])));
        assert_eq!(c.correction(), before);
    }

    #[test]
    fn a_singular_jacobian_is_refused() {
        let inner = SensorLoop::new(ff(), SensorGains::default()).unwrap();
        assert!(matches!(
            Cascade::new(inner, [[1.0, 2.0], [2.0, 4.0]], 0.5, 1e-6),
            Err(ControlError::SingularJacobian(..))
        ));
    }
}
