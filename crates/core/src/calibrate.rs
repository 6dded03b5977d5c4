//! `calibrate pixels | jacobian | hysteresis`: the three calibrations a bench needs
//! before it can position the end-effector in metres, each checked before it is used.
//!
//! - **pixels**: the macro stage moves the whole manipulator by known amounts (its
//!   encoders read 0.1 µm); each camera tracks the marker and a least-squares fit gives
//!   its pixel-to-metre map, rotation and shear ([`cellinject_dic::calib::Calibration`]).
//! - **jacobian**: each tilt stack steps while the other rests; the stack sensors give
//!   the extension and the cameras the tip's motion: the 2x2 map from stack extension
//!   to tip position, compared with the mechanism model's.
//! - **hysteresis**: each tilt stack runs a rich excitation read by its sensor, fitted
//!   by the discrete Preisach model; then a held step gives its creep per decade.

use cellinject_dic::calib::Calibration;
use cellinject_hw::{Camera, Clock, Pacer, PiezoChannel, PositionSensor, Stage};
use cellinject_hysteresis::{AnyModel, LogCreep, Model, Range, excitation};
use cellinject_model::{ACTUATOR_NAMES, Approach, Design, Mechanism};
use cellinject_rig::{Backend, Rig, RigParams};
use nalgebra::Vector2;
use serde::{Deserialize, Serialize};

use crate::bench::{Bench, BenchError, Timing, dev};
use crate::vision::{Acquisition, PixelMap, Which};

/// Both cameras' pixel maps (`pixels.json`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PixelCalibration {
    /// Top camera, then side camera.
    pub maps: [PixelMap; 2],
    /// m, the stage steps used.
    pub step: f64,
}

impl PixelCalibration {
    /// What is wrong with it for a rig at `zoom`, if anything.
    pub fn problem(&self, zoom: f64) -> Option<String> {
        for (m, which) in self.maps.iter().zip(Which::BOTH) {
            if m.camera != which {
                return Some(format!(
                    "map {} is of the {} camera",
                    which as usize,
                    m.camera.name()
                ));
            }
            if (m.zoom / zoom - 1.0).abs() > 1e-9 {
                return Some(format!("made at zoom {} but the lens is at {zoom}", m.zoom));
            }
            if let Some(p) = m.problem() {
                return Some(p);
            }
        }
        None
    }
}

/// Calibrates both cameras' pixels from stage moves of `step` (m) along each axis,
/// with the marker at `marker` (m from the view's centre).
pub fn pixels<B: Backend>(
    rig: &mut Rig<B>,
    marker: [f64; 2],
    step: f64,
) -> Result<PixelCalibration, BenchError> {
    if !(step.is_finite() && (0.5e-6..=10e-6).contains(&step)) {
        return Err(BenchError::Invalid {
            arg: "--step",
            value: step,
            reason: "must lie in [0.5e-6, 10e-6] m (the tracking follows 10 µm per move)".into(),
        });
    }
    let zoom = cellinject_hw::Optics::zoom(&rig.optics);
    let identity = [
        PixelMap::identity(Which::Top, zoom),
        PixelMap::identity(Which::Side, zoom),
    ];
    let mut bench = Bench::new(
        rig,
        Acquisition::Marker,
        marker,
        identity,
        None,
        Timing::default(),
    )?;
    let nominal = [
        bench_pixel(&bench, Which::Top),
        bench_pixel(&bench, Which::Side),
    ];
    let origin = bench.stage_to([0.0; 3], [0.0; 3])?;
    // A lost marker is looked for afresh at the origin and the moves made again with
    // half the step, twice at most (no smaller than 0.5 µm).
    let mut step = step;
    let mut tried = Vec::new();
    let (stage, px) = loop {
        match pixel_moves(&mut bench, origin, step)? {
            Some(data) => break data,
            None => {
                tried.push(format!("{:.2} µm", step * 1e6));
                bench.stage_to(origin, [0.0; 3])?;
                bench.refind()?;
                if tried.len() == 3 || step / 2.0 < 0.5e-6 {
                    let tried = format!(
                        "stage steps of {}, the marker looked for afresh at the origin after each",
                        tried.join(", ")
                    );
                    return Err(bench.lost("the pixel calibration", &tried));
                }
                step /= 2.0;
            }
        }
    };
    bench.stage_to(origin, [0.0; 3])?;
    let mut maps = identity;
    for which in Which::BOTH {
        let c = which as usize;
        let cal = Calibration::fit(&stage[c], &px[c]).map_err(|e| BenchError::Calibration {
            what: "pixel",
            reason: e.to_string(),
        })?;
        maps[c] = PixelMap {
            camera: which,
            zoom,
            pixels_per_metre: [
                [cal.a[(0, 0)], cal.a[(0, 1)]],
                [cal.a[(1, 0)], cal.a[(1, 1)]],
            ],
            metres_per_pixel: cal.scale,
            nominal_pixel: nominal[c],
            rotation: cal.rotation,
            skew: cal.skew,
            rms_px: cal.rms,
            moves: stage[c].len(),
        };
    }
    let cal = PixelCalibration { maps, step };
    if let Some(reason) = cal.problem(zoom) {
        return Err(BenchError::Calibration {
            what: "pixel",
            reason,
        });
    }
    Ok(cal)
}

/// Stage positions and marker pixels per camera.
type PixelData = [Vec<[f64; 2]>; 2];

/// The stage moves of the pixel calibration (0, ±1, ±2 steps along each axis from
/// `origin`), each camera's view after each; `None` as soon as a camera loses the marker.
fn pixel_moves<B: Backend>(
    bench: &mut Bench<'_, B>,
    origin: [f64; 3],
    step: f64,
) -> Result<Option<(PixelData, PixelData)>, BenchError> {
    let mut stage: PixelData = [Vec::new(), Vec::new()];
    let mut px: PixelData = [Vec::new(), Vec::new()];
    for axis in 0..3 {
        for k in [0.0, 1.0, 2.0, 1.0, 0.0, -1.0, -2.0, -1.0, 0.0] {
            let mut d = [0.0; 3];
            d[axis] = k * step;
            let at = bench.stage_to(origin, d)?;
            let moved = [at[0] - origin[0], at[1] - origin[1], at[2] - origin[2]];
            let views = bench.measure_views(2)?;
            for which in Which::BOTH {
                let c = which as usize;
                let axes = which.stage_axes();
                if !axes.contains(&axis) && axis != 2 {
                    continue;
                }
                let Some(p) = views[c] else {
                    return Ok(None);
                };
                stage[c].push([moved[axes[0]], moved[axes[1]]]);
                px[c].push(p);
            }
        }
    }
    Ok(Some((stage, px)))
}

fn bench_pixel<B: Backend>(bench: &Bench<'_, B>, which: Which) -> f64 {
    let cam: &dyn Camera = match which {
        Which::Top => &bench.rig.camera,
        Which::Side => &bench.rig.side_camera,
    };
    bench.view_frame(which).pixel_size / cam.settings().binning as f64
}

/// The map from the tilt stacks' extensions to the tip's position (`jacobian.json`).
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `jacobian` | m/m | `[[∂x/∂e₁, ∂x/∂e₂], [∂y/∂e₁, ∂y/∂e₂]]` as measured |
/// | `model` | m/m | the same from the mechanism model (eqs. 24-26) |
/// | `deviation` | 1 | largest entry difference over the model's largest entry |
/// | `spread` | 1 | largest relative standard deviation of a column over the repeats |
/// | `step_volts` | V | the step asked for |
/// | `volts` | V | the step each stack made (A1, A2): smaller than `step_volts` where the marker was lost and the steps made again at half the voltage |
/// | `repeats` | | steps per stack |
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct JacobianCalibration {
    /// m/m.
    pub jacobian: [[f64; 2]; 2],
    /// m/m.
    pub model: [[f64; 2]; 2],
    /// 1.
    pub deviation: f64,
    /// 1.
    pub spread: f64,
    /// V.
    pub step_volts: f64,
    /// V, per stack (0 in files written before it was recorded).
    #[serde(default)]
    pub volts: [f64; 2],
    /// Steps per stack.
    pub repeats: usize,
}

/// Largest deviation from the model a Jacobian may have, as a fraction of the model's
/// largest entry (the joints' stick-slip moves the tip by up to ~10 % of a step).
pub const JACOBIAN_TOLERANCE: f64 = 0.25;

impl JacobianCalibration {
    /// What is wrong with it, if anything.
    pub fn problem(&self) -> Option<String> {
        let j = self.jacobian;
        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        if !(det.is_finite() && det.abs() > 1e-6) {
            return Some(format!("singular (determinant {det:.3e})"));
        }
        if !(self.deviation.is_finite() && self.deviation <= JACOBIAN_TOLERANCE) {
            return Some(format!(
                "{:.1} % from the mechanism model (at most {:.0} % expected)",
                self.deviation * 100.0,
                JACOBIAN_TOLERANCE * 100.0
            ));
        }
        None
    }
}

/// The model's Jacobian from stack extension (m) to tip displacement (x, y, m), by
/// central differences of 1 µm around rest.
pub fn model_jacobian(design: &Design, approach: Approach) -> Result<[[f64; 2]; 2], BenchError> {
    let err = |e: cellinject_model::ModelError| BenchError::Calibration {
        what: "jacobian",
        reason: format!("the mechanism model: {e}"),
    };
    let m = Mechanism::new(design).map_err(err)?;
    let a = m.assembly(approach).map_err(err)?;
    let h = 1e-6;
    let mut j = [[0.0; 2]; 2];
    for i in 0..2 {
        let mut e = Vector2::zeros();
        e[i] = h;
        // A stack's extension shortens the drive: Δl2 = −e (eq. 44's sign).
        let p = m.state_at(&a, -e).map_err(err)?;
        let q = m.state_at(&a, e).map_err(err)?;
        j[0][i] = (p.dx[0] - q.dx[0]) / (2.0 * h);
        j[1][i] = (p.dx[1] - q.dx[1]) / (2.0 * h);
    }
    Ok(j)
}

/// Each camera's motion (x, y) per metre of stack `i`'s extension over `repeats` steps
/// of `volts` (ramped up and back); `None` as soon as a camera loses the marker.
fn jacobian_steps<B: Backend>(
    bench: &mut Bench<'_, B>,
    i: usize,
    volts: f64,
    repeats: usize,
) -> Result<Option<[Vec<f64>; 2]>, BenchError> {
    let mut cols = [Vec::new(), Vec::new()];
    let mut scratch = Vec::new();
    for _ in 0..repeats {
        let mut pos = [[0.0; 2]; 2];
        let mut ext = [0.0; 2];
        for (k, v) in [volts, 0.0].into_iter().enumerate() {
            let mut target = [0.0; 2];
            target[i] = v;
            bench.ramp_volts(target, 0.5, &mut scratch)?;
            bench.hold_volts(target, 0.3, &mut scratch)?;
            ext[k] = bench.read_stacks(20)?[i];
            let views = bench.measure_views(3)?;
            let (Some(top), Some(side)) = (views[0], views[1]) else {
                return Ok(None);
            };
            pos[k] = [top[0], side[0]];
        }
        let de = ext[0] - ext[1];
        if de.abs() < 1e-9 {
            return Err(BenchError::Calibration {
                what: "jacobian",
                reason: format!(
                    "{} moved {:.1} nm for {volts} V: is its sensor connected?",
                    ACTUATOR_NAMES[i],
                    de * 1e9
                ),
            });
        }
        for r in 0..2 {
            cols[r].push((pos[0][r] - pos[1][r]) / de);
        }
    }
    Ok(Some(cols))
}

/// Measures the Jacobian on `bench`: each stack ramps to `step_volts` and back
/// `repeats` times. A stack whose steps lose the marker (out of the field, too far out
/// of focus) is brought back to rest, the marker looked for afresh, and its steps made
/// again at half the voltage, twice at most.
pub fn jacobian<B: Backend>(
    bench: &mut Bench<'_, B>,
    design: &Design,
    approach: Approach,
    step_volts: f64,
    repeats: usize,
) -> Result<JacobianCalibration, BenchError> {
    let model = model_jacobian(design, approach)?;
    let mut cols = [[Vec::new(), Vec::new()], [Vec::new(), Vec::new()]];
    let mut used = [step_volts; 2];
    for i in 0..2 {
        // A lost marker: the stacks back to rest, the marker looked for afresh, and the
        // steps made again at half the voltage, twice at most.
        let mut volts = step_volts;
        let mut tried = Vec::new();
        loop {
            match jacobian_steps(bench, i, volts, repeats.max(1))? {
                Some(c) => {
                    for r in 0..2 {
                        cols[r][i] = c[r].clone();
                    }
                    used[i] = volts;
                    break;
                }
                None => {
                    tried.push(format!("{volts:.2} V"));
                    bench.rest([0.0, 0.0], 0.5)?;
                    bench.refind()?;
                    if tried.len() == 3 {
                        let tried = format!(
                            "{} steps of {}, the marker looked for afresh at rest after each",
                            ACTUATOR_NAMES[i],
                            tried.join(", ")
                        );
                        return Err(bench.lost("the Jacobian calibration", &tried));
                    }
                    volts /= 2.0;
                }
            }
        }
    }
    let mean = |v: &Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
    let mut j = [[0.0; 2]; 2];
    let mut spread = 0.0f64;
    for r in 0..2 {
        for i in 0..2 {
            j[r][i] = mean(&cols[r][i]);
        }
    }
    for i in 0..2 {
        let norm = j[0][i].hypot(j[1][i]);
        let n = cols[0][i].len();
        if n > 1 {
            let var: f64 = (0..n)
                .map(|k| (cols[0][i][k] - j[0][i]).powi(2) + (cols[1][i][k] - j[1][i]).powi(2))
                .sum::<f64>()
                / (n - 1) as f64;
            spread = spread.max(var.sqrt() / norm);
        }
    }
    let scale = model.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
    let deviation = (0..4)
        .map(|k| (j[k / 2][k % 2] - model[k / 2][k % 2]).abs())
        .fold(0.0f64, f64::max)
        / scale;
    let cal = JacobianCalibration {
        jacobian: j,
        model,
        deviation,
        spread,
        step_volts,
        volts: used,
        repeats: repeats.max(1),
    };
    if let Some(reason) = cal.problem() {
        return Err(BenchError::Calibration {
            what: "jacobian",
            reason,
        });
    }
    Ok(cal)
}

/// Hysteresis and creep of the tilt stacks (`hysteresis.json`).
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `models` | | A1's and A2's Preisach models (input V, output m of extension) |
/// | `creep` | | their logarithmic creep laws |
/// | `fit_rms` | m | RMS fit error over the identification data |
/// | `fit_rms_relative` | 1 | the same over the data's span |
/// | `v_max` | V | the identification's highest voltage (the safety envelope's limit) |
/// | `samples` | | samples per stack, 1 ms apart |
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HysteresisCalibration {
    /// A1, A2.
    pub models: [AnyModel; 2],
    /// A1, A2.
    pub creep: [LogCreep; 2],
    /// m.
    pub fit_rms: [f64; 2],
    /// 1.
    pub fit_rms_relative: [f64; 2],
    /// V.
    pub v_max: [f64; 2],
    /// Per stack.
    pub samples: usize,
}

/// Largest relative RMS error of a usable hysteresis fit.
pub const HYSTERESIS_TOLERANCE: f64 = 0.02;

impl HysteresisCalibration {
    /// What is wrong with it, if anything.
    pub fn problem(&self) -> Option<String> {
        for i in 0..2 {
            let r = self.fit_rms_relative[i];
            if !(r.is_finite() && r <= HYSTERESIS_TOLERANCE) {
                return Some(format!(
                    "{}'s model misses the data by {:.2} % RMS of its span (at most {:.0} % expected)",
                    ACTUATOR_NAMES[i],
                    r * 100.0,
                    HYSTERESIS_TOLERANCE * 100.0
                ));
            }
            if self.models[i].range().max > self.v_max[i] + 1e-9 {
                return Some(format!(
                    "{}'s model reaches {} V, beyond the {} V it was identified to",
                    ACTUATOR_NAMES[i],
                    self.models[i].range().max,
                    self.v_max[i]
                ));
            }
        }
        None
    }
}

/// The two levels of a stack's range, as fractions, at which a loaded hysteresis
/// calibration is checked against the stack ([`check_response`]).
pub const RESPONSE_LEVELS: [f64; 2] = [0.3, 0.6];

/// Largest miss, as a fraction of a stack's modelled stroke, at which a loaded
/// hysteresis calibration still holds ([`check_response`]): the fit's own RMS is
/// 0.3 % of the span on the twin, its worst error about 1 %, and a 0.3 s ramp adds a
/// little creep; a stack whose gain moved by 5 % misses by about 3 %.
pub const RESPONSE_TOLERANCE: f64 = 0.02;

/// A loaded hysteresis calibration checked against the stacks ([`check_response`]).
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `volts` | V | per stack, the two levels ramped to from rest |
/// | `measured`, `predicted` | m | per stack, the sensor's extension there from its reading at rest, and the model's |
/// | `stroke` | m | per stack, the model's output at its top voltage over its output at rest |
/// | `worst` | 1 | the largest \|measured − predicted\| over its stack's stroke |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ResponseCheck {
    /// V, per stack.
    pub volts: [[f64; 2]; 2],
    /// m, per stack.
    pub measured: [[f64; 2]; 2],
    /// m, per stack.
    pub predicted: [[f64; 2]; 2],
    /// m, per stack.
    pub stroke: [f64; 2],
    /// 1.
    pub worst: f64,
}

impl ResponseCheck {
    /// Whether the calibration still holds ([`RESPONSE_TOLERANCE`]).
    pub fn holds(&self) -> bool {
        self.worst.is_finite() && self.worst <= RESPONSE_TOLERANCE
    }

    /// One line for a log: each stack's miss in um and % of its stroke.
    pub fn summary(&self) -> String {
        let per = |k: usize| {
            let miss = (0..2)
                .map(|i| (self.measured[k][i] - self.predicted[k][i]).abs())
                .fold(0.0, f64::max);
            format!(
                "{} {:.3} µm ({:.2} %)",
                ACTUATOR_NAMES[k],
                miss * 1e6,
                100.0 * miss / self.stroke[k].abs().max(1e-12)
            )
        };
        format!(
            "ramped to {:.0} % and {:.0} % of their range, the stacks miss the calibration by {}, {}",
            100.0 * RESPONSE_LEVELS[0],
            100.0 * RESPONSE_LEVELS[1],
            per(0),
            per(1)
        )
    }
}

/// Checks a loaded hysteresis calibration against the stacks, cheaply (0.3 s a
/// stack): from rest (0 V, the sensor read 10 times), each tilt stack in turn is
/// ramped in 1 ms steps of its range's 0.4 % to [`RESPONSE_LEVELS`] of its
/// calibrated range and its sensor read there; its model, relaxed, driven through
/// the same voltages, predicts the extensions. The stack is back at 0 V after.
pub fn check_response<B: Backend>(
    rig: &mut Rig<B>,
    cal: &HysteresisCalibration,
) -> Result<ResponseCheck, BenchError> {
    let mut c = ResponseCheck {
        volts: [[0.0; 2]; 2],
        measured: [[0.0; 2]; 2],
        predicted: [[0.0; 2]; 2],
        stroke: [0.0; 2],
        worst: 0.0,
    };
    for ch in 0..2 {
        let top = cal.models[ch]
            .range()
            .max
            .min(rig.max_safe_voltage(ch).unwrap_or(0.0));
        if top <= 0.0 {
            return Err(BenchError::Calibration {
                what: "hysteresis check",
                reason: format!("{} has no safe voltage above 0 V", ACTUATOR_NAMES[ch]),
            });
        }
        rig.piezo[ch].set_voltage(0.0).map_err(dev("rest"))?;
        rig.clock.sleep(0.05).map_err(dev("clock"))?;
        let mut zero = 0.0;
        for _ in 0..10 {
            zero += rig.sensors[ch].read().map_err(dev("stack sensor"))? / 10.0;
        }
        let mut m = cal.models[ch].clone();
        m.reset();
        let rest = m.output();
        c.stroke[ch] = m.peek(top) - rest;
        let step = 0.004 * top;
        let mut v = 0.0;
        for (i, level) in RESPONSE_LEVELS.iter().enumerate() {
            let to = level * top;
            while v < to - 1e-12 {
                v = (v + step).min(to);
                rig.piezo[ch]
                    .set_voltage(v)
                    .map_err(dev("response check"))?;
                rig.clock.sleep(1e-3).map_err(dev("clock"))?;
                m.apply(v);
            }
            let mut read = 0.0;
            for _ in 0..5 {
                read += rig.sensors[ch].read().map_err(dev("stack sensor"))? / 5.0;
            }
            c.volts[ch][i] = to;
            c.measured[ch][i] = read - zero;
            c.predicted[ch][i] = m.output() - rest;
            let miss =
                (c.measured[ch][i] - c.predicted[ch][i]).abs() / c.stroke[ch].abs().max(1e-12);
            c.worst = c.worst.max(miss);
        }
        rig.piezo[ch].set_voltage(0.0).map_err(dev("rest"))?;
    }
    rig.clock.sleep(0.1).map_err(dev("clock"))?;
    Ok(c)
}

/// Excitation samples per stack of the hysteresis identification (1 ms apart): the
/// one value every front end uses (a run identifying its stacks, `cellinject
/// calibrate`, the experiments, the dashboard's calibration), so that a calibration
/// file made once is the one a run would have made.
pub const HYSTERESIS_SAMPLES: usize = 20_000;

/// Relays per axis of the Preisach plane of the hysteresis identification.
pub const HYSTERESIS_SIZE: usize = 20;

/// Identifies the tilt stacks' hysteresis (Preisach on `size` cells, `samples`
/// excitation samples 1 ms apart, read by the stack sensors) and creep.
pub fn hysteresis<B: Backend>(
    rig: &mut Rig<B>,
    samples: usize,
    size: usize,
) -> Result<HysteresisCalibration, BenchError> {
    if !(2000..=200_000).contains(&samples) {
        return Err(BenchError::Invalid {
            arg: "--samples",
            value: samples as f64,
            reason: "must lie in [2000, 200000] (1 ms apart; fewer outrun the amplifier)".into(),
        });
    }
    let dt = 1e-3;
    rig.command_tilt([0.0, 0.0]).map_err(dev("rest"))?;
    rig.clock.sleep(0.5).map_err(dev("clock"))?;
    let mut models = Vec::new();
    let mut creep = Vec::new();
    let mut fit_rms = [0.0; 2];
    let mut rel = [0.0; 2];
    let mut v_max = [0.0; 2];
    for ch in 0..2 {
        let top = rig.max_safe_voltage(ch).unwrap_or(0.0);
        if top <= 0.0 {
            return Err(BenchError::Calibration {
                what: "hysteresis",
                reason: format!("{} has no safe voltage above 0 V", ACTUATOR_NAMES[ch]),
            });
        }
        let range = Range { min: 0.0, max: top };
        let read = |rig: &mut Rig<B>| rig.sensors[ch].read().map_err(dev("stack sensor"));
        let zero = (0..20).map(|_| read(rig)).sum::<Result<f64, _>>()? / 20.0;
        let volts = excitation(range, samples);
        let mut disp = Vec::with_capacity(samples);
        // Samples dt apart, the link's round trips included (see `Pacer`).
        let mut pace = Pacer::start(&rig.clock, dt);
        for v in &volts {
            rig.piezo[ch].set_voltage(*v).map_err(dev("excitation"))?;
            pace.wait(&mut rig.clock).map_err(dev("clock"))?;
            disp.push(read(rig)? - zero);
        }
        let fit = crate::hysteresis::fit(
            crate::hysteresis::Kind::Preisach,
            size,
            range,
            &volts,
            &disp,
        )
        .map_err(|e| BenchError::Calibration {
            what: "hysteresis",
            reason: format!("{}: {e}", ACTUATOR_NAMES[ch]),
        })?;
        // Creep: relax, then hold half the range and read the sensor on a log scale.
        rig.piezo[ch].set_voltage(0.0).map_err(dev("rest"))?;
        rig.clock.sleep(1.0).map_err(dev("clock"))?;
        let zero = read(rig)?;
        rig.piezo[ch]
            .set_voltage(0.5 * top)
            .map_err(dev("creep step"))?;
        let t_step = rig.clock.now();
        let (mut ts, mut ys) = (Vec::new(), Vec::new());
        for k in 0..=30 {
            let t = 0.005 * 10f64.powf(k as f64 / 12.0);
            let now = rig.clock.now() - t_step;
            rig.clock.sleep((t - now).max(0.0)).map_err(dev("clock"))?;
            let y = (0..5).map(|_| read(rig)).sum::<Result<f64, _>>()? / 5.0;
            ts.push(rig.clock.now() - t_step);
            ys.push(y - zero);
        }
        rig.piezo[ch].set_voltage(0.0).map_err(dev("rest"))?;
        rig.clock.sleep(0.5).map_err(dev("clock"))?;
        let c = LogCreep::identify(&ts, &ys, dt).map_err(|e| BenchError::Calibration {
            what: "hysteresis",
            reason: format!("{} creep: {e}", ACTUATOR_NAMES[ch]),
        })?;
        fit_rms[ch] = fit.rms;
        rel[ch] = fit.rms_relative;
        v_max[ch] = top;
        models.push(fit.model);
        creep.push(c);
    }
    let [m1, m2]: [AnyModel; 2] = models.try_into().map_err(|_| BenchError::Calibration {
        what: "hysteresis",
        reason: "two models expected".into(),
    })?;
    let cal = HysteresisCalibration {
        models: [m1, m2],
        creep: [creep[0], creep[1]],
        fit_rms,
        fit_rms_relative: rel,
        v_max,
        samples,
    };
    if let Some(reason) = cal.problem() {
        return Err(BenchError::Calibration {
            what: "hysteresis",
            reason,
        });
    }
    Ok(cal)
}

/// m, how far the tilt stacks swept over their travel (the hysteresis identification,
/// the check of a loaded calibration) and A3 over its stroke can lower the pipette's
/// tip from where it stands with all three at rest: A1 and A2 through the vertical
/// row of the model's Jacobian, A3 down the pipette's axis. The run's workflow raises
/// the pipette as much before either; [`hysteresis_clear`] does for the calibration
/// commands.
pub fn sweep_drop(design: &Design, params: &RigParams) -> Result<f64, BenchError> {
    let j = model_jacobian(design, params.approach)?;
    Ok(drop_over_travel(
        design.actuators[2].travel,
        params.pipette.angle,
        j[1],
        [design.actuators[0].travel, design.actuators[1].travel],
    ))
}

/// m, the drop of [`sweep_drop`] from its parts, the one formula of every caller: A3's
/// full stroke `a3_stroke` (m) down the pipette's axis at `angle` (rad) from the
/// horizontal, and the tilt stacks' travels `travel` (m) through `vertical`, the
/// vertical row of a Jacobian (tip height per stack extension, either sign). The
/// model's parts for the calibration commands; the workflow's own (A3's identified
/// gain times its voltage range, its measured Jacobian) on a bench.
pub fn drop_over_travel(a3_stroke: f64, angle: f64, vertical: [f64; 2], travel: [f64; 2]) -> f64 {
    a3_stroke * angle.sin() + vertical[0].abs() * travel[0] + vertical[1].abs() * travel[1]
}

/// [`hysteresis`] with the pipette first raised `drop` m ([`sweep_drop`]) above where
/// it stands (the macro stage's axis 1), and brought back once the stacks are at rest
/// again: what the calibration commands and the dashboard's calibration run, on a
/// bench where a plate may lie under the pipette. A sweep that fails (a device, the
/// operator) leaves the pipette raised: the stacks may not be at rest, and lowering
/// it then could drive the tip down. Swept without it from a run's start
/// height (30 µm above focus) over a loaded plate, the twin's tip struck the floor 8
/// times and lost 16 µm of its length, and the next run's injections found no flow. A
/// stage that cannot rise that far refuses the move, and nothing is swept.
pub fn hysteresis_clear<B: Backend>(
    rig: &mut Rig<B>,
    drop: f64,
    samples: usize,
    size: usize,
) -> Result<HysteresisCalibration, BenchError> {
    if !(drop.is_finite() && drop >= 0.0) {
        return Err(BenchError::Invalid {
            arg: "drop",
            value: drop,
            reason: "the pipette's clearance must be a finite length of at least 0 m".into(),
        });
    }
    let y0 = rig.stage.position(1).map_err(dev("stage"))?;
    stage_height(rig, y0 + drop)?;
    let made = hysteresis(rig, samples, size)?;
    stage_height(rig, y0)?;
    Ok(made)
}

/// Moves the macro stage's axis 1 (the pipette's height) to `y` and waits until it has
/// settled (at most 10 s of the bench's clock).
fn stage_height<B: Backend>(rig: &mut Rig<B>, y: f64) -> Result<(), BenchError> {
    rig.stage.move_to(1, y).map_err(dev("stage lift"))?;
    rig.wait_stage(10.0, 0.01, "stage (lifting the pipette clear)")
        .map_err(dev("stage"))
}

#[cfg(test)]
mod response_tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use cellinject_hysteresis::PrandtlIshlinskii;
    use cellinject_model::prototype;
    use cellinject_rig::{RigParams, fake};

    /// A3's 100 µm down a pipette at 30° is 50 µm of height; stacks of 20 and 40 µm
    /// through a vertical row (0.5, −0.25) add 10 + 10 µm, whatever the signs; and
    /// the prototype's drop is the model's parts put through the same formula.
    #[test]
    fn the_drop_over_travel_adds_each_axis_worst_case() {
        let d = drop_over_travel(
            100e-6,
            std::f64::consts::FRAC_PI_6,
            [0.5, -0.25],
            [20e-6, 40e-6],
        );
        assert!((d - 70e-6).abs() < 1e-15, "{d}");
        let (design, params) = (prototype(), RigParams::default());
        let j = model_jacobian(&design, params.approach).unwrap();
        let by_hand = design.actuators[2].travel * params.pipette.angle.sin()
            + j[1][0].abs() * design.actuators[0].travel
            + j[1][1].abs() * design.actuators[1].travel;
        assert_eq!(sweep_drop(&design, &params).unwrap(), by_hand);
    }

    /// A calibration of two linear stacks of `um_per_volt`, on 0-100 V.
    fn linear(um_per_volt: f64) -> HysteresisCalibration {
        let range = Range {
            min: 0.0,
            max: 100.0,
        };
        let m = AnyModel::Pi(
            PrandtlIshlinskii::new(range, 0.0, vec![0.0], vec![um_per_volt * 1e-6 * 100.0], 0.0)
                .unwrap(),
        );
        HysteresisCalibration {
            models: [m.clone(), m],
            creep: [LogCreep::new(0.01, 0.1).unwrap(); 2],
            fit_rms: [1e-9; 2],
            fit_rms_relative: [1e-4; 2],
            v_max: [100.0; 2],
            samples: 2000,
        }
    }

    /// The fake's stacks answer 0.3 um/V. A calibration that says so holds; one that
    /// says 0.33 um/V misses at 60 % of the safe range (about 68 V for A1 with
    /// approach 1) by 0.03 um/V x 0.6 x top over a stroke of 0.33 um/V x top:
    /// 5.45 %, and does not hold.
    #[test]
    fn a_calibration_is_checked_against_the_stacks_at_two_levels() {
        let p = RigParams {
            approach: cellinject_model::Approach::DriveTranslation,
            ..RigParams::default()
        };
        let (devices, _) = fake::devices(&p);
        let mut rig = Rig::new(devices, &prototype(), &p).unwrap();
        let right = check_response(&mut rig, &linear(0.3)).unwrap();
        assert!(right.worst < 1e-9 && right.holds(), "{right:?}");
        let top = rig.max_safe_voltage(0).unwrap().min(100.0);
        assert!((right.volts[0][1] - 0.6 * top).abs() < 1e-9);
        assert!((right.measured[0][1] - 0.3e-6 * 0.6 * top).abs() < 1e-15);
        let off = check_response(&mut rig, &linear(0.33)).unwrap();
        assert!(
            (off.worst - 0.03 * 0.6 / 0.33).abs() < 1e-9,
            "{}",
            off.worst
        );
        assert!(!off.holds());
        assert!(off.summary().contains("A1") && off.summary().contains("%"));
    }
}
