//! `experiment range | repeatability | tracking`: the paper's bench experiments
//! (Sec. 4, Figs. 7 and 8) and a tracking test, on any rig, through the cameras, with
//! any of the four controllers.

use cellinject_control::{
    Cascade, ControlError, Controller, Feedforward, Kind, Open, SensorGains, SensorLoop, Stacks,
};
use cellinject_hw::SafetyError;
use cellinject_model::{Approach, Design, Mechanism};
use cellinject_rig::{Backend, RigParams};
use nalgebra::Vector2;
use serde::Serialize;

use crate::bench::{Bench, BenchError, FrameRecord};
use crate::calibrate::{HysteresisCalibration, JacobianCalibration};

/// The calibrations a controller is built from.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibrations {
    /// Stack extension to tip position.
    pub jacobian: JacobianCalibration,
    /// The stacks' hysteresis and creep.
    pub hysteresis: HysteresisCalibration,
}

/// The cascade's outer gain per frame (see [`Cascade`]).
pub const OUTER_GAIN: f64 = 0.6;
/// The largest correction the cascade may add to a stack reference, m.
pub const CORRECTION_LIMIT: f64 = 3e-6;

/// The stacks as the controllers see them: nominal gain (travel over the amplifier's
/// range) and the highest voltage the hysteresis models were identified to.
pub fn stacks(design: &Design, rig: &RigParams, cal: &HysteresisCalibration) -> Stacks {
    Stacks {
        gain: [0, 1].map(|i| design.actuators[i].travel / rig.amplifiers[i].v_max),
        v_max: cal.v_max,
    }
}

/// Builds a controller of `kind` from the calibrations.
pub fn controller(
    kind: Kind,
    stacks: Stacks,
    cal: &Calibrations,
) -> Result<Box<dyn Controller>, ControlError> {
    let ff = || {
        Feedforward::new(
            stacks,
            cal.hysteresis.models.clone(),
            cal.hysteresis.creep.map(Some),
        )
    };
    Ok(match kind {
        Kind::Open => Box::new(Open::new(stacks)?),
        Kind::Feedforward => Box::new(ff()?),
        Kind::Sensor => Box::new(SensorLoop::new(ff()?, SensorGains::default())?),
        Kind::Closed => Box::new(Cascade::new(
            SensorLoop::new(ff()?, SensorGains::default())?,
            cal.jacobian.jacobian,
            OUTER_GAIN,
            CORRECTION_LIMIT,
        )?),
    })
}

/// A pair of numbers per axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Axes {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
}

/// One point of a range sweep.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SweepPoint {
    /// V on the swept stack.
    pub volts: f64,
    /// m, the swept axis (x for A1, y for A2) as its camera measured it (absent if it
    /// rejected the frame).
    pub measured: Option<f64>,
    /// m, the twin's truth of that axis.
    pub truth: Option<f64>,
}

/// The result of `experiment range` (Fig. 7).
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `range_m` | m | motion range per axis measured through the cameras (x: A1 swept, top camera; y: A2 swept, side camera) |
/// | `true_range_m` | m | the same from the twin's truth |
/// | `model_range_m` | m | what the mechanism model predicts for the same sweeps |
/// | `full_stroke_range_m` | m | the model's range for the stacks' full travel (eqs. 49/58: 177.4 µm) |
/// | `v_max` | V | the highest voltage the safety envelope allowed each stack |
/// | `limited_by` | | per stack, why the envelope stopped the sweep below the amplifier's range (absent if it did not) |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RangeReport {
    /// 1 or 2.
    pub approach: u8,
    /// m.
    pub range_m: Axes,
    /// m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub true_range_m: Option<Axes>,
    /// m.
    pub model_range_m: Axes,
    /// m.
    pub full_stroke_range_m: Axes,
    /// V.
    pub v_max: [f64; 2],
    /// Reasons, per stack.
    pub limited_by: [Option<String>; 2],
    /// The sweeps of A1 and A2.
    #[serde(skip)]
    pub sweeps: [Vec<SweepPoint>; 2],
}

fn model_dx(m: &Mechanism, approach: Approach, e: [f64; 2]) -> Result<[f64; 2], BenchError> {
    let err = |e: cellinject_model::ModelError| BenchError::Calibration {
        what: "model",
        reason: e.to_string(),
    };
    let a = m.assembly(approach).map_err(err)?;
    let s = m.state_at(&a, Vector2::new(-e[0], -e[1])).map_err(err)?;
    Ok([s.dx[0], s.dx[1]])
}

/// Device time [`range`] takes with sweeps of `seconds` each way, s: for each stack,
/// 0.2 s at rest, the sweep up, 0.3 s held, the sweep down, 0.3 s held.
pub fn range_seconds(seconds: f64) -> f64 {
    2.0 * (RANGE_REST + 2.0 * seconds + 2.0 * RANGE_HOLD)
}

/// s at rest before a stack's sweep ([`range`]).
const RANGE_REST: f64 = 0.2;
/// s held at each end of a stack's sweep ([`range`]).
const RANGE_HOLD: f64 = 0.3;

/// Sweeps A1 (then A2) from rest up to the highest voltage the safety envelope allows
/// and back, `seconds` each way, measuring x (then y) through the cameras.
pub fn range<B: Backend>(
    bench: &mut Bench<'_, B>,
    design: &Design,
    rig: &RigParams,
    seconds: f64,
) -> Result<RangeReport, BenchError> {
    if !(seconds.is_finite() && (0.5..=600.0).contains(&seconds)) {
        return Err(BenchError::Invalid {
            arg: "--sweep",
            value: seconds,
            reason: "must lie in [0.5, 600] s".into(),
        });
    }
    let mech = Mechanism::new(design).map_err(|e| BenchError::Calibration {
        what: "model",
        reason: e.to_string(),
    })?;
    let mut sweeps: [Vec<SweepPoint>; 2] = [Vec::new(), Vec::new()];
    let mut v_max = [0.0; 2];
    let mut limited_by: [Option<String>; 2] = [None, None];
    let mut range = [0.0; 2];
    let mut true_range = [0.0; 2];
    let mut has_truth = true;
    let mut model_range = [0.0; 2];
    let mut full = [0.0; 2];
    for i in 0..2 {
        bench.command([0.0, 0.0])?;
        let top = bench.rig.max_safe_voltage(i).unwrap_or(0.0);
        v_max[i] = top;
        let amp = rig.amplifiers[i].v_max;
        if top < amp - 1e-3 {
            let mut probe = [0.0; 3];
            probe[i] = (top + 0.01).min(amp);
            let g = cellinject_rig::guard::lock(&bench.rig.guard);
            limited_by[i] = g
                .envelope()
                .check(probe)
                .err()
                .map(|e: SafetyError| e.to_string());
        }
        let mut target = [0.0; 2];
        target[i] = top;
        let mut rec: Vec<FrameRecord> = Vec::new();
        bench.hold_volts([0.0, 0.0], RANGE_REST, &mut rec)?;
        bench.ramp_volts(target, seconds, &mut rec)?;
        bench.hold_volts(target, RANGE_HOLD, &mut rec)?;
        bench.ramp_volts([0.0, 0.0], seconds, &mut rec)?;
        bench.hold_volts([0.0, 0.0], RANGE_HOLD, &mut rec)?;
        // A1 moves x, seen by the top camera; A2 moves y, seen by the side camera (the
        // other camera then loses focus: its measurement is not used).
        let view = |r: &FrameRecord| r.views[i].map(|v| v[0]);
        let lost = rec.iter().filter(|r| view(r).is_none()).count();
        if lost * 10 > rec.len() {
            return Err(bench.lost("the range sweep", ""));
        }
        let span = |f: &dyn Fn(&FrameRecord) -> Option<f64>| {
            let v: Vec<f64> = rec.iter().filter_map(f).collect();
            let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            (hi - lo).max(0.0)
        };
        range[i] = span(&view);
        if rec.iter().all(|r| r.truth.is_some()) {
            true_range[i] = span(&|r| r.truth.map(|p| p[i]));
        } else {
            has_truth = false;
        }
        sweeps[i] = rec
            .iter()
            .map(|r| SweepPoint {
                volts: r.volts[i],
                measured: view(r),
                truth: r.truth.map(|t| t[i]),
            })
            .collect();
        let travel = design.actuators[i].travel;
        let mut e = [0.0; 2];
        let rest = model_dx(&mech, rig.approach, e)?;
        e[i] = travel * top / amp;
        model_range[i] = (model_dx(&mech, rig.approach, e)?[i] - rest[i]).abs();
        e[i] = travel;
        full[i] = (model_dx(&mech, rig.approach, e)?[i] - rest[i]).abs();
    }
    let axes = |a: [f64; 2]| Axes { x: a[0], y: a[1] };
    Ok(RangeReport {
        approach: rig.approach.number(),
        range_m: axes(range),
        true_range_m: has_truth.then(|| axes(true_range)),
        model_range_m: axes(model_range),
        full_stroke_range_m: axes(full),
        v_max,
        limited_by,
        sweeps,
    })
}

/// How the repeatability experiment runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RepeatabilityOptions {
    /// Runs.
    pub runs: usize,
    /// m, the working shift of A1 and A2 from rest.
    pub shift: f64,
    /// s at rest (0 V) before each run.
    pub rest: f64,
    /// s the controller holds the shift; the last frame is the run's position.
    pub hold: f64,
    /// m, the band a position must stay in to count as settled.
    pub tolerance: f64,
    /// Frames at the end of the hold whose mean is the run's position (the truth is
    /// averaged over the same frames).
    pub average: usize,
}

impl Default for RepeatabilityOptions {
    fn default() -> Self {
        RepeatabilityOptions {
            runs: 200,
            shift: 1e-6,
            rest: 0.1,
            hold: 0.8,
            tolerance: 100e-9,
            average: 3,
        }
    }
}

/// One run of the repeatability experiment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Run {
    /// Index from 0.
    pub run: usize,
    /// m, x and y the cameras measured at the end of the hold (mean of the last
    /// frames).
    pub measured: [f64; 2],
    /// m, the twin's truth over the same frames.
    pub truth: Option<[f64; 2]>,
    /// Frames from the start of the hold until the measurement stayed within the
    /// tolerance of the run's position (`None`: never).
    pub settling_frames: Option<usize>,
    /// s, how long the stacks were held (the closed loop holds until in position).
    pub hold_s: f64,
    /// V, A1 and A2 at the end.
    pub volts: [f64; 2],
}

/// The result of `experiment repeatability` (Fig. 8).
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `max_error_m`, `rms_error_m` | m | per axis (x, y), the largest and RMS deviation of a run's camera measurement from the mean of all runs |
/// | `max_distance_m` | m | the largest distance of a run's (x, y) from the mean (the radius of Fig. 8's scatter) |
/// | `true_max_error_m`, `true_rms_error_m`, `true_max_distance_m` | m | the same from the twin's truth |
/// | `camera_vs_truth_m` | m | largest difference between a run's measured and true deviation from their means (both axes) |
/// | `settling_frames` | frames | per run, the settling time (every later frame's measurement within `tolerance_m` of the run's position, per axis; `null`: never) |
/// | `settling_median_frames`, `settling_max_frames` | frames | their median and largest (`null`: some run never settled) |
/// | `unsettled_runs` | | runs that never settled |
/// | `longest_hold_s` | s | the longest hold: the closed loop holds until in position, up to `IN_POSITION_EXTRA` more than `--hold` |
/// | `mean_m` | m | mean measured position (x, y) |
/// | `rejected_frames` | | frames a camera rejected (top, side) |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RepeatabilityReport {
    /// 1 or 2.
    pub approach: u8,
    /// Controller.
    pub control: Kind,
    /// Runs.
    pub runs: usize,
    /// m.
    pub shift_m: f64,
    /// m.
    pub max_error_m: [f64; 2],
    /// m.
    pub rms_error_m: [f64; 2],
    /// m, the largest distance of a run's (x, y) from the mean.
    pub max_distance_m: f64,
    /// m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub true_max_error_m: Option<[f64; 2]>,
    /// m, the same from the twin's truth.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub true_max_distance_m: Option<f64>,
    /// m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub true_rms_error_m: Option<[f64; 2]>,
    /// m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera_vs_truth_m: Option<f64>,
    /// Frames, per run (`null`: that run never settled).
    pub settling_frames: Vec<Option<usize>>,
    /// Frames, the median over the runs (`null`: over half never settled).
    pub settling_median_frames: Option<usize>,
    /// Frames, the largest (`null`: some run never settled).
    pub settling_max_frames: Option<usize>,
    /// Runs that never settled.
    pub unsettled_runs: usize,
    /// s, the longest hold (the closed loop holds until in position).
    pub longest_hold_s: f64,
    /// m.
    pub tolerance_m: f64,
    /// m.
    pub mean_m: [f64; 2],
    /// Top, side.
    pub rejected_frames: [u64; 2],
    /// Each run.
    #[serde(skip)]
    pub run_list: Vec<Run>,
}

/// Mean, largest and RMS deviation per axis, and the largest distance from the mean.
fn stats(v: &[[f64; 2]]) -> ([f64; 2], [f64; 2], [f64; 2], f64) {
    let n = v.len().max(1) as f64;
    let mean = [0, 1].map(|a| v.iter().map(|p| p[a]).sum::<f64>() / n);
    let max = [0, 1].map(|a| v.iter().map(|p| (p[a] - mean[a]).abs()).fold(0.0, f64::max));
    let rms = [0, 1].map(|a| (v.iter().map(|p| (p[a] - mean[a]).powi(2)).sum::<f64>() / n).sqrt());
    let dist = v
        .iter()
        .map(|p| (p[0] - mean[0]).hypot(p[1] - mean[1]))
        .fold(0.0, f64::max);
    (mean, max, rms, dist)
}

/// The closed loop is in position when its last `average + IN_POSITION_FRAMES` camera
/// measurements all lie within the tolerance of the mean of the last `average`.
pub const IN_POSITION_FRAMES: usize = 3;

/// s, the most a closed-loop run's hold is extended to wait until in position.
pub const IN_POSITION_EXTRA: f64 = 2.0;

/// Whether the measurements `points` (x, y) have come to rest: see
/// [`IN_POSITION_FRAMES`].
fn in_position_now(points: &[[f64; 2]], average: usize, tol: f64) -> bool {
    let n = average.max(1);
    let window = n + IN_POSITION_FRAMES;
    if points.len() < window {
        return false;
    }
    let tail = &points[points.len() - n..];
    let end = [0, 1].map(|a| tail.iter().map(|p| p[a]).sum::<f64>() / n as f64);
    points[points.len() - window..]
        .iter()
        .all(|p| (p[0] - end[0]).abs() <= tol && (p[1] - end[1]).abs() <= tol)
}

/// Frames until the (x, y) positions stay within `tol` of `end` (per axis), or `None`
/// if the last frame is not within it.
fn settling(points: &[[f64; 2]], end: [f64; 2], tol: f64) -> Option<usize> {
    let mut k = points.len();
    while k > 0 {
        let p = points[k - 1];
        if (p[0] - end[0]).abs() > tol || (p[1] - end[1]).abs() > tol {
            break;
        }
        k -= 1;
    }
    (k < points.len()).then_some(k)
}

/// `Ok` if `v` is finite and within `[lo, hi]`, else the error naming `arg`.
fn in_range(arg: &'static str, v: f64, lo: f64, hi: f64) -> Result<(), BenchError> {
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(BenchError::Invalid {
            arg,
            value: v,
            reason: format!("must lie in [{lo}, {hi}]"),
        })
    }
}

impl RepeatabilityOptions {
    /// Refuses options outside what the experiment supports, naming the option (a
    /// front end can check before it calibrates anything).
    pub fn check(&self) -> Result<(), BenchError> {
        in_range("--runs", self.runs as f64, 2.0, 100_000.0)?;
        in_range("--shift", self.shift, 1e-9, 5e-6)?;
        in_range("--hold", self.hold, 0.1, 60.0)?;
        in_range("--rest", self.rest, 0.0, 60.0)?;
        in_range("--tolerance", self.tolerance, 1e-9, 1e-5)?;
        in_range("--average", self.average as f64, 1.0, 100.0)
    }
}

impl TrackingOptions {
    /// Device time [`tracking`] takes, s: 0.2 s at rest, the ramp to the operating
    /// point and a dwell there, the four steps, a dwell to the circle's start, the
    /// circle.
    pub fn seconds(&self) -> f64 {
        TRACKING_REST + APPROACH_RAMP + self.dwell + 4.0 * self.dwell + self.dwell + self.duration
    }

    /// Refuses options outside what the experiment supports, naming the option.
    pub fn check(&self) -> Result<(), BenchError> {
        in_range("--bias", self.bias, 0.0, 10e-6)?;
        in_range("--step", self.step, 1e-9, 1.5e-6)?;
        in_range("--dwell", self.dwell, 0.1, 60.0)?;
        in_range("--amplitude", self.amplitude, 1e-9, 0.75e-6)?;
        in_range("--frequency", self.frequency, 0.01, 10.0)?;
        in_range("--duration", self.duration, 0.1, 600.0)?;
        in_range("--tolerance", self.tolerance, 1e-9, 1e-5)
    }
}

/// Sets the stacks `runs` times to the same working shift with `controller`, from rest
/// each time, and measures where the end-effector lands (Fig. 8).
pub fn repeatability<B: Backend>(
    bench: &mut Bench<'_, B>,
    controller: &mut dyn Controller,
    approach: Approach,
    opts: RepeatabilityOptions,
    mut progress: impl FnMut(usize),
) -> Result<RepeatabilityReport, BenchError> {
    opts.check()?;
    let mut runs = Vec::with_capacity(opts.runs);
    let mut rec = Vec::new();
    let in_position = controller.kind() == Kind::Closed;
    let step = 4.0 * bench.frame_period();
    for run in 0..opts.runs {
        controller.reset();
        rec.clear();
        bench.rest([0.0, 0.0], opts.rest)?;
        let shift = opts.shift;
        bench.run(controller, opts.hold, |_| [shift, shift], &mut rec)?;
        let mut held = opts.hold;
        let measured = |rec: &[FrameRecord]| -> Vec<[f64; 2]> {
            rec.iter()
                .filter_map(|r| r.measured.map(|p| [p[0], p[1]]))
                .collect()
        };
        // The closed loop holds until it is in position (see `IN_POSITION_FRAMES`): a
        // joint that slips near the end of the hold is corrected before the run's
        // position is read, as a positioning controller waits for on-target.
        while in_position
            && held < opts.hold + IN_POSITION_EXTRA
            && !in_position_now(&measured(&rec), opts.average, opts.tolerance)
        {
            bench.run_on(controller, held, step, |_| [shift, shift], &mut rec)?;
            held += step;
        }
        let measured = measured(&rec);
        let tail: Vec<&FrameRecord> = rec
            .iter()
            .rev()
            .filter(|r| r.measured.is_some())
            .take(opts.average)
            .collect();
        let Some(last) = tail.first() else {
            return Err(bench.lost("a repeatability run", ""));
        };
        let k = tail.len() as f64;
        let mean_of = |f: &dyn Fn(&FrameRecord) -> Option<[f64; 3]>| -> Option<[f64; 2]> {
            let mut s = [0.0; 2];
            for r in &tail {
                let p = f(r)?;
                s[0] += p[0] / k;
                s[1] += p[1] / k;
            }
            Some(s)
        };
        let end = mean_of(&|r| r.measured).unwrap_or([f64::NAN; 2]);
        runs.push(Run {
            run,
            measured: end,
            truth: mean_of(&|r| r.truth),
            settling_frames: settling(&measured, end, opts.tolerance),
            hold_s: held,
            volts: last.volts,
        });
        progress(run + 1);
    }
    bench.command([0.0, 0.0])?;
    let meas: Vec<[f64; 2]> = runs.iter().map(|r| r.measured).collect();
    let (mean, max, rms, dist) = stats(&meas);
    let truth: Option<Vec<[f64; 2]>> = runs.iter().map(|r| r.truth).collect();
    let (true_max, true_rms, true_dist, agree) = match &truth {
        Some(t) => {
            let (tm, tmax, trms, tdist) = stats(t);
            let agree = meas
                .iter()
                .zip(t)
                .map(|(m, t)| {
                    let dx = (m[0] - mean[0]) - (t[0] - tm[0]);
                    let dy = (m[1] - mean[1]) - (t[1] - tm[1]);
                    dx.abs().max(dy.abs())
                })
                .fold(0.0, f64::max);
            (Some(tmax), Some(trms), Some(tdist), Some(agree))
        }
        None => (None, None, None, None),
    };
    let settling_frames: Vec<Option<usize>> = runs.iter().map(|r| r.settling_frames).collect();
    let mut settle = settling_frames.clone();
    settle.sort_by_key(|s| s.unwrap_or(usize::MAX));
    let median = settle[settle.len() / 2];
    let worst = settle.last().copied().flatten();
    let unsettled = settle.iter().filter(|s| s.is_none()).count();
    Ok(RepeatabilityReport {
        approach: approach.number(),
        control: controller.kind(),
        runs: opts.runs,
        shift_m: opts.shift,
        max_error_m: max,
        rms_error_m: rms,
        max_distance_m: dist,
        true_max_error_m: true_max,
        true_max_distance_m: true_dist,
        true_rms_error_m: true_rms,
        camera_vs_truth_m: agree,
        settling_frames,
        settling_median_frames: median,
        settling_max_frames: if unsettled > 0 { None } else { worst },
        unsettled_runs: unsettled,
        longest_hold_s: runs.iter().map(|r| r.hold_s).fold(0.0, f64::max),
        tolerance_m: opts.tolerance,
        mean_m: mean,
        rejected_frames: bench.rejected(),
        run_list: runs,
    })
}

/// One phase of the tracking experiment.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `rms_error_m`, `max_error_m` | m | per axis, the camera's measurement against the desired tip position `J·r` |
/// | `true_rms_error_m`, `true_max_error_m` | m | the twin's truth against it |
/// | `settling_frames` | frames | steps only: per step, frames until the measurement stays within the tolerance of the target (`null`: never) |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PhaseReport {
    /// m.
    pub rms_error_m: [f64; 2],
    /// m.
    pub max_error_m: [f64; 2],
    /// m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub true_rms_error_m: Option<[f64; 2]>,
    /// m.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub true_max_error_m: Option<[f64; 2]>,
    /// Frames per step.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub settling_frames: Vec<Option<usize>>,
}

/// The result of `experiment tracking`.
///
/// Steps: the stack references step through `[s, 0]`, `[s, s]`, `[0, s]`, `[0, 0]`
/// (`s` = `step_m`), `dwell_s` each; the errors are over each step's second half.
/// Sines: `[a(1 − cos ωt), a(1 − sin ωt)]`-like circle of amplitude `amplitude_m` at
/// `frequency_hz` for `duration_s`; errors over the whole circle after its first
/// quarter period.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrackingReport {
    /// 1 or 2.
    pub approach: u8,
    /// Controller.
    pub control: Kind,
    /// m, the stacks' operating point.
    pub bias_m: f64,
    /// m, stack step.
    pub step_m: f64,
    /// s.
    pub dwell_s: f64,
    /// m, stack amplitude of the sine.
    pub amplitude_m: f64,
    /// Hz.
    pub frequency_hz: f64,
    /// s.
    pub duration_s: f64,
    /// m.
    pub tolerance_m: f64,
    /// Steps.
    pub steps: PhaseReport,
    /// Sines.
    pub sine: PhaseReport,
    /// Every frame.
    #[serde(skip)]
    pub frames: Vec<FrameRecord>,
    /// The frames' desired tip positions (x, y), m.
    #[serde(skip)]
    pub desired: Vec<[f64; 2]>,
}

/// How the tracking experiment runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackingOptions {
    /// m, the stacks' operating point: both are first brought to this extension from
    /// rest, and the steps and the circle run above it, so that every controller has
    /// room to correct both ways (a stack at 0 V cannot be pulled back further).
    pub bias: f64,
    /// m, stack step.
    pub step: f64,
    /// s per step.
    pub dwell: f64,
    /// m, stack amplitude of the sine.
    pub amplitude: f64,
    /// Hz.
    pub frequency: f64,
    /// s of sine.
    pub duration: f64,
    /// m.
    pub tolerance: f64,
}

impl Default for TrackingOptions {
    fn default() -> Self {
        TrackingOptions {
            bias: 1e-6,
            step: 1e-6,
            dwell: 0.5,
            amplitude: 0.5e-6,
            frequency: 1.0,
            duration: 3.0,
            tolerance: 100e-9,
        }
    }
}

fn phase(
    frames: &[FrameRecord],
    desired: &[[f64; 2]],
    keep: impl Fn(usize) -> bool,
) -> PhaseReport {
    let mut err = Vec::new();
    let mut terr = Vec::new();
    let mut all_truth = true;
    for (k, (f, d)) in frames.iter().zip(desired).enumerate() {
        if !keep(k) {
            continue;
        }
        if let Some(m) = f.measured {
            err.push([m[0] - d[0], m[1] - d[1]]);
        }
        match f.truth {
            Some(t) => terr.push([t[0] - d[0], t[1] - d[1]]),
            None => all_truth = false,
        }
    }
    let rms_max = |v: &[[f64; 2]]| {
        let n = v.len().max(1) as f64;
        (
            [0, 1].map(|a| (v.iter().map(|p| p[a] * p[a]).sum::<f64>() / n).sqrt()),
            [0, 1].map(|a| v.iter().map(|p| p[a].abs()).fold(0.0, f64::max)),
        )
    };
    let (rms, max) = rms_max(&err);
    let (trms, tmax) = rms_max(&terr);
    PhaseReport {
        rms_error_m: rms,
        max_error_m: max,
        true_rms_error_m: all_truth.then_some(trms),
        true_max_error_m: all_truth.then_some(tmax),
        settling_frames: Vec::new(),
    }
}

/// s over which the tracking experiment ramps the stacks to their operating point.
pub const APPROACH_RAMP: f64 = 0.3;

/// s at rest before [`tracking`] moves.
const TRACKING_REST: f64 = 0.2;

/// Steps and a circle of the stack references with `controller` about an operating
/// point, the tip measured by the cameras against `J·r`.
pub fn tracking<B: Backend>(
    bench: &mut Bench<'_, B>,
    controller: &mut dyn Controller,
    approach: Approach,
    jacobian: [[f64; 2]; 2],
    opts: TrackingOptions,
) -> Result<TrackingReport, BenchError> {
    opts.check()?;
    controller.reset();
    let mut rest = Vec::new();
    bench.hold_volts([0.0, 0.0], TRACKING_REST, &mut rest)?;
    let (s, o) = (opts.step, opts.bias);
    let dwell = opts.dwell;
    // To the operating point first, ramped so the cameras follow (a step of 2 µm of
    // stack moves the tip by 12 µm, farther than the correlation searches in a frame),
    // then settled there; not part of the record.
    let mut approach_frames = Vec::new();
    let ramp = APPROACH_RAMP;
    bench.run(
        controller,
        ramp + dwell,
        |t| {
            let k = (t / ramp).min(1.0);
            [k * o, k * o]
        },
        &mut approach_frames,
    )?;
    let targets = [[o + s, o], [o + s, o + s], [o, o + s], [o, o]];
    let mut frames = Vec::new();
    bench.run(
        controller,
        dwell * targets.len() as f64,
        |t| targets[((t / dwell) as usize).min(targets.len() - 1)],
        &mut frames,
    )?;
    let n_steps = frames.len();
    let (a, w) = (opts.amplitude, 2.0 * std::f64::consts::PI * opts.frequency);
    let circle = move |t: f64| [o + a * (1.0 - (w * t).cos()), o + a * (1.0 + (w * t).sin())];
    // Move to the circle's start first, then circle.
    let mut moving = Vec::new();
    bench.run(controller, dwell, |_| circle(0.0), &mut moving)?;
    let mut sine = Vec::new();
    bench.run(controller, opts.duration, circle, &mut sine)?;
    bench.command([0.0, 0.0])?;
    let lost = frames
        .iter()
        .chain(&sine)
        .filter(|f| f.measured.is_none())
        .count();
    if lost * 10 > frames.len() + sine.len() {
        return Err(bench.lost("the tracking experiment", ""));
    }
    // One time line: the steps, the move to the circle's start, the circle.
    for f in &mut moving {
        f.t += dwell * targets.len() as f64;
    }
    for f in &mut sine {
        f.t += dwell * (targets.len() + 1) as f64;
    }
    let n_moving = moving.len();
    frames.extend(moving);
    frames.extend(sine);
    let j = jacobian;
    let tip = |r: [f64; 2]| {
        [
            j[0][0] * r[0] + j[0][1] * r[1],
            j[1][0] * r[0] + j[1][1] * r[1],
        ]
    };
    let desired: Vec<[f64; 2]> = frames.iter().map(|f| tip(f.reference)).collect();
    let step_of = |t: f64| ((t / dwell) as usize).min(targets.len() - 1);
    let mut steps = phase(&frames[..n_steps], &desired[..n_steps], |k| {
        let t = frames[k].t;
        t - step_of(t) as f64 * dwell >= 0.5 * dwell
    });
    // Settling per step.
    for k in 0..targets.len() {
        let idx: Vec<usize> = (0..n_steps)
            .filter(|&i| step_of(frames[i].t) == k)
            .collect();
        let within = |i: usize| {
            frames[i].measured.is_some_and(|m| {
                (m[0] - desired[i][0]).abs() <= opts.tolerance
                    && (m[1] - desired[i][1]).abs() <= opts.tolerance
            })
        };
        let mut settled = None;
        for (pos, &i) in idx.iter().enumerate().rev() {
            if !within(i) {
                break;
            }
            settled = Some(pos);
        }
        steps.settling_frames.push(settled);
    }
    let period_quarter = 0.25 / opts.frequency;
    let first = n_steps + n_moving;
    let sine_report = phase(&frames[first..], &desired[first..], |k| {
        frames[first + k].t - frames[first].t >= period_quarter
    });
    Ok(TrackingReport {
        approach: approach.number(),
        control: controller.kind(),
        bias_m: opts.bias,
        step_m: opts.step,
        dwell_s: opts.dwell,
        amplitude_m: opts.amplitude,
        frequency_hz: opts.frequency,
        duration_s: opts.duration,
        tolerance_m: opts.tolerance,
        steps,
        sine: sine_report,
        frames,
        desired,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn in_position_needs_the_whole_window_inside_the_tolerance() {
        let tol = 100e-9;
        let at = |x: f64| [x, 0.0];
        // Settled for six frames: in position.
        let mut p: Vec<[f64; 2]> = vec![at(5e-6), at(1e-6)];
        p.extend((0..6).map(|k| at(1e-6 + 10e-9 * (k % 2) as f64)));
        assert!(in_position_now(&p, 3, tol));
        // A slip in the last frame (1.1 µm): not in position, whatever came before.
        p.push(at(2.1e-6));
        assert!(!in_position_now(&p, 3, tol));
        // Five frames back in the band are not yet enough; six are.
        p.extend((0..5).map(|_| at(1e-6)));
        assert!(!in_position_now(&p, 3, tol));
        p.push(at(1e-6));
        assert!(in_position_now(&p, 3, tol));
        // Too few frames to say.
        assert!(!in_position_now(&p[..4], 3, tol));
    }
}
