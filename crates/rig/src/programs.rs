//! Stimulus programs over any amplifier channel and clock: the hysteresis loop with
//! nested minor loops and the step response of `cellinject sim`, reused by hysteresis
//! identification. The caller says how to measure (the twin's truth, a strain-gauge
//! sensor, a camera) through a closure.

use cellinject_hw::{Clock, HwError, Pacer, PiezoChannel};
use thiserror::Error;

/// Why a program stopped.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ProgramError {
    /// A parameter of the program is out of its domain.
    #[error("{what} = {value}: {reason}")]
    Invalid {
        /// Which parameter.
        what: &'static str,
        /// Its value.
        value: f64,
        /// What is wrong.
        reason: &'static str,
    },
    /// A device refused or failed, at this commanded voltage.
    #[error("{channel} at {volts:.3} V: {source}")]
    Device {
        /// Channel name.
        channel: &'static str,
        /// Voltage being commanded.
        volts: f64,
        /// The device's error.
        source: HwError,
    },
}

/// A triangular hysteresis loop: from 0 V through each turning point in turn, at a
/// constant ramp rate, sampling every `dt`.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopPlan {
    /// Largest voltage, V.
    pub amplitude: f64,
    /// Turning points as fractions of the amplitude, in order.
    pub turning: Vec<f64>,
    /// Ramp rate, V/s.
    pub ramp: f64,
    /// Sampling interval, s.
    pub dt: f64,
}

impl LoopPlan {
    /// A full loop 0 → A → 0, then minor loops closing towards the middle (0.8/0.2,
    /// 0.7/0.3, 0.6/0.4), then back to 0 V; one second per full leg, 1 ms samples.
    pub fn nested(amplitude: f64) -> Self {
        LoopPlan {
            amplitude,
            turning: vec![1.0, 0.0, 0.8, 0.2, 0.7, 0.3, 0.6, 0.4, 0.0],
            ramp: amplitude,
            dt: 1e-3,
        }
    }

    fn check(&self) -> Result<(), ProgramError> {
        let pos = |what, value: f64| {
            if value.is_finite() && value > 0.0 {
                Ok(())
            } else {
                Err(ProgramError::Invalid {
                    what,
                    value,
                    reason: "must be a positive number",
                })
            }
        };
        pos("amplitude", self.amplitude)?;
        pos("ramp", self.ramp)?;
        pos("dt", self.dt)?;
        for &t in &self.turning {
            if !(0.0..=1.0).contains(&t) {
                return Err(ProgramError::Invalid {
                    what: "turning point",
                    value: t,
                    reason: "must lie in [0, 1] (fraction of the amplitude)",
                });
            }
        }
        Ok(())
    }
}

/// One sample of a loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopSample {
    /// s, on the device's clock.
    pub time: f64,
    /// V, the amplifier's output monitor.
    pub voltage: f64,
    /// What the measurement closure returned.
    pub value: f64,
}

fn device(channel: &'static str, volts: f64) -> impl FnOnce(HwError) -> ProgramError {
    move |source| ProgramError::Device {
        channel,
        volts,
        source,
    }
}

/// Runs `plan` on `piezo` (named `channel`), sampling `measure()` after every step.
pub fn hysteresis_loop<P: PiezoChannel + ?Sized, C: Clock + ?Sized>(
    piezo: &mut P,
    channel: &'static str,
    clock: &mut C,
    plan: &LoopPlan,
    mut measure: impl FnMut() -> f64,
) -> Result<Vec<LoopSample>, ProgramError> {
    plan.check()?;
    let mut out = Vec::new();
    let mut v = 0.0;
    // Samples `dt` apart, the device calls' own time included (see `Pacer`).
    let mut pace = Pacer::start(clock, plan.dt);
    for &target in &plan.turning {
        let target = target * plan.amplitude;
        let n = ((target - v).abs() / (plan.ramp * plan.dt)).ceil().max(1.0) as usize;
        let from = v;
        for k in 1..=n {
            v = from + (target - from) * k as f64 / n as f64;
            piezo.set_voltage(v).map_err(device(channel, v))?;
            pace.wait(clock).map_err(device(channel, v))?;
            let voltage = piezo.read_voltage().map_err(device(channel, v))?;
            out.push(LoopSample {
                time: clock.now(),
                voltage,
                value: measure(),
            });
        }
    }
    Ok(out)
}

/// When a step response is sampled: every integration step within `fast` seconds of
/// the step (the ringing), then every `slow_period` (the creep).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepPlan {
    /// V, the step.
    pub voltage: f64,
    /// s, how long to record.
    pub duration: f64,
    /// s, the clock step.
    pub dt: f64,
    /// s, the window sampled at every step.
    pub fast: f64,
    /// s, the sampling period after it.
    pub slow_period: f64,
}

impl StepPlan {
    fn check(&self) -> Result<(), ProgramError> {
        if !(self.duration > 0.0 && self.duration <= 3600.0) {
            return Err(ProgramError::Invalid {
                what: "duration",
                value: self.duration,
                reason: "must lie in (0, 3600] s",
            });
        }
        for (what, value) in [("dt", self.dt), ("slow_period", self.slow_period)] {
            if !(value.is_finite() && value > 0.0) {
                return Err(ProgramError::Invalid {
                    what,
                    value,
                    reason: "must be a positive number",
                });
            }
        }
        Ok(())
    }
}

/// Steps `piezo` to `plan.voltage` and records `sample(t)` (t since the step) on
/// `plan`'s schedule.
pub fn step_response<P: PiezoChannel + ?Sized, C: Clock + ?Sized, S>(
    piezo: &mut P,
    channel: &'static str,
    clock: &mut C,
    plan: &StepPlan,
    mut sample: impl FnMut(f64) -> S,
) -> Result<Vec<S>, ProgramError> {
    plan.check()?;
    let v = plan.voltage;
    piezo.set_voltage(v).map_err(device(channel, v))?;
    let t0 = clock.now();
    let mut next_slow = 0.0;
    let mut out = Vec::new();
    loop {
        let t = clock.now() - t0;
        if t > plan.duration + 0.5 * plan.dt {
            break;
        }
        if t <= plan.fast || t >= next_slow {
            out.push(sample(t));
            if t >= next_slow {
                next_slow += plan.slow_period;
            }
        }
        clock.sleep(plan.dt).map_err(device(channel, v))?;
    }
    Ok(out)
}
