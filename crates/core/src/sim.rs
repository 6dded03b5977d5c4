//! `sim loop`, `sim step`, `sim frame`: programs run on any guarded rig (the twin by
//! default). How to measure the stack is the caller's: a closure that reads the
//! twin's truth, a strain-gauge sensor or a camera.

use cellinject_hw::{Camera, Clock, Frame, HwError, Optics, PiezoChannel, vga_settings};
use cellinject_model::{ACTUATOR_NAMES, Approach};
use cellinject_rig::programs::{self, LoopPlan, ProgramError, StepPlan};
use cellinject_rig::{Backend, Rig};
use serde::Serialize;
use thiserror::Error;

/// Why a program could not run.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum SimError {
    /// An argument out of its domain.
    #[error("{arg} {reason}, got {value}")]
    Invalid {
        /// The argument (`--amplitude`, `--actuator`, ...).
        arg: &'static str,
        /// Its value.
        value: f64,
        /// What is wrong.
        reason: String,
    },
    /// The requested stroke is beyond the safety envelope.
    #[error(
        "--amplitude {volts} V is beyond the safety envelope of {actuator} under approach {approach} ({why}); at most {max:.1} V is allowed"
    )]
    Unsafe {
        /// Requested amplitude, V.
        volts: f64,
        /// Actuator.
        actuator: &'static str,
        /// Pre-tensioning approach.
        approach: u8,
        /// The envelope's reason.
        why: String,
        /// The highest safe voltage, V.
        max: f64,
    },
    /// A device refused or failed during the program.
    #[error(transparent)]
    Program(#[from] ProgramError),
    /// A device refused or failed outside a program.
    #[error("{what}: {source}")]
    Device {
        /// What was being done.
        what: &'static str,
        /// The device's error.
        source: HwError,
    },
}

/// The channel of an actuator name (A1, A2, A3, any case).
pub fn channel(name: &str) -> Option<usize> {
    ACTUATOR_NAMES
        .iter()
        .position(|a| a.eq_ignore_ascii_case(name))
}

/// The result of `sim loop`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LoopReport {
    /// A1, A2 or A3.
    pub actuator: &'static str,
    /// V, the loop's largest voltage.
    pub amplitude: f64,
    /// (s, V amplifier output, m displacement from the start) every millisecond.
    pub samples: Vec<[f64; 3]>,
    /// m, the largest displacement reached.
    pub stroke: f64,
}

/// `sim loop`: a full hysteresis loop and nested minor loops on channel `ch`, up to
/// `amplitude` volts (default: the amplifier's full range), refused beyond the safety
/// envelope. `measure()` returns the stack's displacement, m.
pub fn hysteresis_loop<B: Backend>(
    rig: &mut Rig<B>,
    ch: usize,
    amplitude: Option<f64>,
    approach: Approach,
    mut measure: impl FnMut() -> f64,
) -> Result<LoopReport, SimError> {
    let v_max = rig.piezo[ch].voltage_range().1;
    let amp = amplitude.unwrap_or(v_max);
    if !(amp > 0.0 && amp <= v_max) {
        return Err(SimError::Invalid {
            arg: "--amplitude",
            value: amp,
            reason: format!("must lie in (0, {v_max}] V"),
        });
    }
    let safe = rig.max_safe_voltage(ch).unwrap_or(0.0);
    if amp > safe {
        let why = {
            let g = cellinject_rig::guard::lock(&rig.guard);
            let mut volts = g.commanded();
            volts[ch] = amp;
            g.envelope()
                .check(volts)
                .err()
                .map(|e| e.to_string())
                .unwrap_or_default()
        };
        return Err(SimError::Unsafe {
            volts: amp,
            actuator: ACTUATOR_NAMES[ch],
            approach: approach.number(),
            why,
            max: safe,
        });
    }
    let start = measure();
    let name = ACTUATOR_NAMES[ch];
    let samples = programs::hysteresis_loop(
        &mut rig.piezo[ch],
        name,
        &mut rig.clock,
        &LoopPlan::nested(amp),
        || measure() - start,
    )?;
    let samples: Vec<[f64; 3]> = samples
        .iter()
        .map(|s| [s.time, s.voltage, s.value])
        .collect();
    let stroke = samples
        .iter()
        .map(|s| s[2])
        .fold(f64::NEG_INFINITY, f64::max);
    Ok(LoopReport {
        actuator: name,
        amplitude: amp,
        samples,
        stroke,
    })
}

impl LoopReport {
    /// What `sim loop` reports besides its CSV.
    pub fn summary(&self) -> LoopSummary {
        LoopSummary {
            actuator: self.actuator,
            amplitude: self.amplitude,
            stroke: self.stroke,
            samples: self.samples.len(),
        }
    }
}

/// The JSON summary of `sim loop` (the samples go to its CSV).
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `actuator` | | A1, A2 or A3 |
/// | `amplitude` | V | the loop's largest voltage |
/// | `stroke` | m | the largest displacement reached, under the mechanism's load |
/// | `samples` | | rows of the CSV (one per millisecond) |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LoopSummary {
    /// A1, A2 or A3.
    pub actuator: &'static str,
    /// V.
    pub amplitude: f64,
    /// m.
    pub stroke: f64,
    /// CSV rows.
    pub samples: usize,
}

/// One sample of a step response.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StepSample {
    /// s since the step.
    pub time: f64,
    /// V, the amplifier's output.
    pub voltage: f64,
    /// m, the stack's displacement from before the step.
    pub displacement: f64,
    /// m, the end-effector's displacement from before the step (x, y, z).
    pub end_effector: [f64; 3],
}

/// The result of `sim step`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StepReport {
    /// A1, A2 or A3.
    pub actuator: &'static str,
    /// V.
    pub voltage: f64,
    /// s.
    pub duration: f64,
    /// Every integration step for the first 50 ms (ringing), then every millisecond.
    pub samples: Vec<StepSample>,
}

impl StepReport {
    /// The displacement at the first sample at or after `t`, m.
    pub fn displacement_at(&self, t: f64) -> Option<f64> {
        self.samples
            .iter()
            .find(|s| s.time >= t)
            .map(|s| s.displacement)
    }
}

impl StepReport {
    /// What `sim step` reports besides its CSV; `frequencies` are the twin's tilt modes
    /// and A3 axis mode, Hz.
    pub fn summary(&self, frequencies: [f64; 3]) -> StepSummary {
        StepSummary {
            actuator: self.actuator,
            voltage: self.voltage,
            duration: self.duration,
            displacement_at_100ms: self.displacement_at(0.1),
            displacement_final: self.samples.last().map(|s| s.displacement),
            natural_frequencies: frequencies,
            samples: self.samples.len(),
        }
    }
}

/// The JSON summary of `sim step` (the samples go to its CSV).
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `actuator`, `voltage`, `duration` | –, V, s | the step |
/// | `displacement_at_100ms` | m | the stack's displacement 0.1 s after the step (null if shorter) |
/// | `displacement_final` | m | at the end |
/// | `natural_frequencies` | Hz | the tilt modes about the two axes and the A3 axis |
/// | `samples` | | rows of the CSV |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StepSummary {
    /// A1, A2 or A3.
    pub actuator: &'static str,
    /// V.
    pub voltage: f64,
    /// s.
    pub duration: f64,
    /// m.
    pub displacement_at_100ms: Option<f64>,
    /// m.
    pub displacement_final: Option<f64>,
    /// Hz.
    pub natural_frequencies: [f64; 3],
    /// CSV rows.
    pub samples: usize,
}

/// `sim step`: steps channel `ch` to `voltage` and records `sample(t)` every clock
/// step `dt` for 50 ms, then every millisecond (every `duration`/100000 s for runs over
/// 100 s, so that no run records more than about 100,000 samples), for `duration`
/// seconds.
pub fn step_response<B: Backend>(
    rig: &mut Rig<B>,
    ch: usize,
    voltage: f64,
    duration: f64,
    dt: f64,
    sample: impl FnMut(f64) -> StepSample,
) -> Result<StepReport, SimError> {
    if !(duration > 0.0 && duration <= 3600.0) {
        return Err(SimError::Invalid {
            arg: "--duration",
            value: duration,
            reason: "must lie in (0, 3600] s".into(),
        });
    }
    if !voltage.is_finite() {
        return Err(SimError::Invalid {
            arg: "--voltage",
            value: voltage,
            reason: "must be a number of volts".into(),
        });
    }
    let name = ACTUATOR_NAMES[ch];
    let plan = StepPlan {
        voltage,
        duration,
        dt,
        fast: 0.05,
        // At most ~100,000 rows after the ringing, whatever the duration.
        slow_period: (duration / 1e5).max(1e-3),
    };
    let samples = programs::step_response(&mut rig.piezo[ch], name, &mut rig.clock, &plan, sample)?;
    Ok(StepReport {
        actuator: name,
        voltage,
        duration,
        samples,
    })
}

/// The JSON summary of `sim frame` (the pixels go to its image file).
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `width`, `height` | px | the frame |
/// | `bit_depth` | bits | significant bits of a pixel (8 or 12) |
/// | `zoom` | | magnification |
/// | `pixel_size` | m | one pixel in the object plane |
/// | `field_of_view` | m | width and height in the object plane |
/// | `exposure`, `timestamp` | s | exposure time and its start on the device's clock |
/// | `tip` | m | the pipette tip's true position (x, z) and distance from focus, where the backend knows it (the twin) |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameSummary {
    /// px.
    pub width: u32,
    /// px.
    pub height: u32,
    /// bits.
    pub bit_depth: u8,
    /// Magnification.
    pub zoom: f64,
    /// m.
    pub pixel_size: f64,
    /// m.
    pub field_of_view: [f64; 2],
    /// s.
    pub exposure: f64,
    /// s.
    pub timestamp: f64,
    /// m: x, z, depth from focus.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tip: Option<[f64; 3]>,
}

impl FrameSummary {
    /// The summary of `frame` taken at `zoom`, with the tip's truth if known.
    pub fn new(frame: &Frame, zoom: f64, tip: Option<[f64; 3]>) -> Self {
        FrameSummary {
            width: frame.width,
            height: frame.height,
            bit_depth: frame.bit_depth,
            zoom,
            pixel_size: frame.pixel_size,
            field_of_view: [
                frame.width as f64 * frame.pixel_size,
                frame.height as f64 * frame.pixel_size,
            ],
            exposure: frame.exposure,
            timestamp: frame.timestamp,
            tip,
        }
    }
}

/// How `sim frame` acquires.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Acquisition {
    /// The whole sensor.
    Full,
    /// 640x480 by 4x4 binning of the centre.
    VgaBinned,
    /// 640x480 cropped from the centre.
    VgaCropped,
}

/// `sim frame`: sets the zoom and acquisition, applies `volts` (A1, A2, A3) and lets
/// 0.1 s pass if given, then grabs one frame.
pub fn frame<B: Backend>(
    rig: &mut Rig<B>,
    zoom: f64,
    acquisition: Acquisition,
    volts: Option<[f64; 3]>,
) -> Result<Frame, SimError> {
    rig.optics
        .set_zoom(zoom)
        .map_err(|source| SimError::Device {
            what: "--zoom",
            source,
        })?;
    if acquisition != Acquisition::Full {
        let s = vga_settings(
            rig.camera.sensor_size(),
            &rig.camera.settings(),
            acquisition == Acquisition::VgaBinned,
        );
        rig.camera.configure(s).map_err(|source| SimError::Device {
            what: "camera",
            source,
        })?;
    }
    if let Some(v) = volts {
        for (ch, volts) in v.iter().enumerate() {
            rig.piezo[ch]
                .set_voltage(*volts)
                .map_err(|source| SimError::Device {
                    what: "--volts",
                    source,
                })?;
        }
        rig.clock.sleep(0.1).map_err(|source| SimError::Device {
            what: "clock",
            source,
        })?;
    }
    rig.camera.grab().map_err(|source| SimError::Device {
        what: "camera",
        source,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use cellinject_model::prototype;
    use cellinject_rig::{RigParams, fake};

    fn rig(approach: Approach) -> Rig<fake::FakeBackend> {
        let p = RigParams {
            approach,
            ..RigParams::default()
        };
        let (devices, _) = fake::devices(&p);
        Rig::new(devices, &prototype(), &p).unwrap()
    }

    #[test]
    fn the_loop_runs_on_any_backend_and_refuses_beyond_the_envelope() {
        // The fake outputs its command at once: the loop's samples trace the plan.
        let mut r = rig(Approach::JointDeflection);
        let mut volts = 0.0;
        let report = {
            let guard = r.guard.clone();
            hysteresis_loop(&mut r, 0, Some(50.0), Approach::JointDeflection, || {
                volts = cellinject_rig::guard::lock(&guard).commanded()[0];
                volts * 0.3e-6
            })
            .unwrap()
        };
        // 50 V up and down, then minor loops: 1000 + 1000 + 800 + 600 + 500 + 400 + 300
        // + 200 + 400 ms at 1 ms per sample.
        assert_eq!(report.samples.len(), 5200);
        let peak = report.samples.iter().map(|s| s[1]).fold(0.0, f64::max);
        assert!((peak - 50.0).abs() < 1e-12, "{peak}");
        assert!((report.stroke - 15e-6).abs() < 1e-15, "{}", report.stroke);
        // Approach 1 bends J1 past the stacks' torque limit above ~68 V: refused, with
        // the highest safe voltage.
        let mut r1 = rig(Approach::DriveTranslation);
        let e = hysteresis_loop(&mut r1, 0, None, Approach::DriveTranslation, || 0.0).unwrap_err();
        match e {
            SimError::Unsafe { max, approach, .. } => {
                assert_eq!(approach, 1);
                assert!((60.0..75.0).contains(&max), "{max}");
            }
            other => panic!("{other}"),
        }
        assert!(matches!(
            hysteresis_loop(
                &mut r1,
                0,
                Some(f64::NAN),
                Approach::DriveTranslation,
                || 0.0
            ),
            Err(SimError::Invalid {
                arg: "--amplitude",
                ..
            })
        ));
    }

    #[test]
    fn a_step_is_sampled_densely_then_every_millisecond() {
        let mut r = rig(Approach::JointDeflection);
        let rep = step_response(&mut r, 2, 10.0, 0.1, 1e-4, |t| StepSample {
            time: t,
            voltage: 10.0,
            displacement: 0.0,
            end_effector: [0.0; 3],
        })
        .unwrap();
        // 501 samples over the first 50 ms (every 0.1 ms), then every ms to 100 ms.
        let dense = rep.samples.iter().filter(|s| s.time <= 0.05 + 1e-9).count();
        assert_eq!(dense, 501);
        assert!((rep.samples.last().unwrap().time - 0.1).abs() < 1e-9);
        assert!(matches!(
            step_response(&mut r, 0, 10.0, -1.0, 1e-4, |_| unreachable!()),
            Err(SimError::Invalid {
                arg: "--duration",
                ..
            })
        ));
    }

    #[test]
    fn a_frame_is_refused_outside_the_zoom_range() {
        let mut r = rig(Approach::JointDeflection);
        let e = frame(&mut r, 20.0, Acquisition::Full, None).unwrap_err();
        assert!(
            matches!(
                e,
                SimError::Device {
                    what: "--zoom",
                    source: HwError::Refused(_)
                }
            ),
            "{e}"
        );
        let f = frame(&mut r, 5.0, Acquisition::VgaCropped, Some([1.0, 2.0, 3.0])).unwrap();
        assert_eq!((f.width, f.height), (640, 480));
    }
}
