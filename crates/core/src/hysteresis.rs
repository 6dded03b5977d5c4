//! `hysteresis identify | fit | invert | validate`: hysteresis models from a rig's measurements or
//! any (voltage, displacement) data, and the voltages that make an actuator follow a
//! trajectory.

use cellinject_hw::{Clock, PiezoChannel};
use cellinject_hysteresis::{
    AnyModel, DataSummary, HysteresisError, Model, PrandtlIshlinskii, Preisach, Range, excitation,
    inverse,
};
use cellinject_model::ACTUATOR_NAMES;
use cellinject_rig::{Backend, Rig};
use serde::Serialize;

use crate::sim::SimError;

/// Which model to fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Discrete Preisach on `size` x `size` cells.
    Preisach,
    /// Classical Prandtl-Ishlinskii with `size` plays.
    Pi,
    /// Prandtl-Ishlinskii with a quadratic input term.
    PiAsymmetric,
}

impl Kind {
    /// The kind a command-line name (`preisach`, `pi`, `pi-asym`) names.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "preisach" => Some(Kind::Preisach),
            "pi" => Some(Kind::Pi),
            "pi-asym" => Some(Kind::PiAsymmetric),
            _ => None,
        }
    }
}

/// Why the data cannot set a model's input range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RangeError {
    /// No voltage above 0 V and no `v_max` given (or `v_max` not positive).
    #[error("no voltage above 0 V (and no v_max)")]
    NoPositiveVoltage,
    /// A voltage outside `[0, top]`, at sample `index` (0-based).
    #[error("sample {index}: {value} V lies outside the model's range [0, {top}] V (v_max)")]
    Outside {
        /// 0-based sample.
        index: usize,
        /// The voltage, V.
        value: f64,
        /// The range's top, V.
        top: f64,
    },
}

/// The input range `hysteresis fit` gives a model: `[0, v_max]`, `v_max` by default
/// the data's highest voltage; refuses data outside it (1e-9 V of slack).
pub fn fit_range(volts: &[f64], v_max: Option<f64>) -> Result<Range, RangeError> {
    let top = v_max.unwrap_or_else(|| volts.iter().copied().fold(0.0, f64::max));
    if !(top.is_finite() && top > 0.0) {
        return Err(RangeError::NoPositiveVoltage);
    }
    if let Some(index) = volts.iter().position(|v| *v < -1e-9 || *v > top + 1e-9) {
        return Err(RangeError::Outside {
            index,
            value: volts[index],
            top,
        });
    }
    Ok(Range { min: 0.0, max: top })
}

/// The identification run of `hysteresis identify`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct IdentifyReport {
    /// A1, A2 or A3.
    pub actuator: &'static str,
    /// V, the highest voltage of the excitation (the safety envelope's limit if lower
    /// than the amplifier's).
    pub v_max: f64,
    /// (s, V, m) per sample.
    pub samples: Vec<[f64; 3]>,
}

/// Drives channel `ch` through the rich excitation of `n` samples, `dt` apart, up to
/// the highest voltage the safety envelope allows, measuring with `measure`.
pub fn identify<B: Backend>(
    rig: &mut Rig<B>,
    ch: usize,
    n: usize,
    dt: f64,
    mut measure: impl FnMut() -> f64,
) -> Result<IdentifyReport, SimError> {
    let name = ACTUATOR_NAMES[ch];
    let v_max = rig.max_safe_voltage(ch).unwrap_or(0.0);
    if v_max <= 0.0 {
        return Err(SimError::Invalid {
            arg: "--actuator",
            value: ch as f64,
            reason: format!("{name} has no safe voltage above 0 V in this assembly"),
        });
    }
    let volts = excitation(
        Range {
            min: 0.0,
            max: v_max,
        },
        n,
    );
    let start = measure();
    let mut samples = Vec::with_capacity(n);
    for v in volts {
        let dev = |source| SimError::Device {
            what: "identification",
            source,
        };
        rig.piezo[ch].set_voltage(v).map_err(dev)?;
        rig.clock.sleep(dt).map_err(dev)?;
        samples.push([rig.clock.now(), v, measure() - start]);
    }
    Ok(IdentifyReport {
        actuator: name,
        v_max,
        samples,
    })
}

/// The default size of `hysteresis fit`'s model: cells per axis of the Preisach grid.
pub const DEFAULT_SIZE: usize = 20;

/// The result of `hysteresis fit`: the model and how well it fits.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `model` | | the fitted model (`"model": "preisach"` or `"pi"`), its input range in V |
/// | `rms`, `max` | m | fit error over the data |
/// | `rms_relative` | 1 | `rms` over the data's span |
/// | `samples` | | samples fitted (rows after merging held inputs) |
/// | `data` | | what the data preparation did ([`DataSummary`]: rows, samples merged and flattened, reversals, the voltage's noise level and reversal threshold in V) |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FitReport {
    /// The model.
    pub model: AnyModel,
    /// m.
    pub rms: f64,
    /// m.
    pub max: f64,
    /// 1.
    pub rms_relative: f64,
    /// Samples fitted.
    pub samples: usize,
    /// What the preparation of the data did.
    pub data: DataSummary,
}

/// Fits a model of `kind` and `size` (cells or plays) to (V, m) samples in time order,
/// starting relaxed at 0 V, on the input range `range`. Real recordings are welcome:
/// held voltages (dwells at the turning points, a DAC slower than the logger) merge
/// into one sample, the voltage's wiggles within its measured noise or quantisation
/// are holds, not reversals ([`cellinject_hysteresis::prepare`]).
pub fn fit(
    kind: Kind,
    size: usize,
    range: Range,
    volts: &[f64],
    disp: &[f64],
) -> Result<FitReport, HysteresisError> {
    let lambda = 1e-7;
    let (model, rms, max, span, samples, data) = match kind {
        Kind::Preisach => {
            let f = Preisach::identify(range, size, volts, disp, lambda)?;
            (
                AnyModel::Preisach(f.model),
                f.rms,
                f.max,
                f.span,
                f.samples,
                f.data,
            )
        }
        Kind::Pi | Kind::PiAsymmetric => {
            let f = PrandtlIshlinskii::identify(
                range,
                size,
                kind == Kind::PiAsymmetric,
                volts,
                disp,
                lambda,
            )?;
            (
                AnyModel::Pi(f.model),
                f.rms,
                f.max,
                f.span,
                f.samples,
                f.data,
            )
        }
    };
    Ok(FitReport {
        model,
        rms,
        max,
        rms_relative: rms / span.max(1e-300),
        samples,
        data,
    })
}

/// The result of `hysteresis invert`.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `samples` | | rows |
/// | `voltage_range` | V | lowest and highest command |
/// | `residual` | m | largest |model output − target| |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct InvertReport {
    /// Rows.
    pub samples: usize,
    /// V.
    pub voltage_range: [f64; 2],
    /// m.
    pub residual: f64,
    /// The commands, V, one per target.
    #[serde(skip)]
    pub volts: Vec<f64>,
    /// What the model predicts for them, m.
    #[serde(skip)]
    pub predicted: Vec<f64>,
    /// Targets outside the model's reach taken as the nearest it reaches (only with
    /// `clip`).
    pub clipped: usize,
    /// m, the largest distance between such a target and what was reached (0 when
    /// none was clipped).
    pub largest_clip: f64,
    /// The sample of that largest clip, if any.
    pub largest_clip_sample: Option<usize>,
}

/// The voltages that make `model`, relaxed at 0 V, follow `targets` (m). A target
/// outside the model's reach from its state is refused
/// ([`HysteresisError::OutOfReach`]), or with `clip` taken as the nearest output the
/// model reaches, and counted.
pub fn invert(
    model: &AnyModel,
    targets: &[f64],
    clip: bool,
) -> Result<InvertReport, HysteresisError> {
    let mut m = model.clone();
    m.reset();
    let mut volts = Vec::with_capacity(targets.len());
    let mut clipped = Vec::new();
    let residual = if clip {
        cellinject_hysteresis::inverse_clipped(&mut m, targets, &mut volts, &mut clipped)
    } else {
        inverse(&mut m, targets, &mut volts)?
    };
    let largest = clipped
        .iter()
        .max_by(|a, b| a.miss().total_cmp(&b.miss()))
        .copied();
    let mut replay = model.clone();
    replay.reset();
    let predicted = volts.iter().map(|v| replay.apply(*v)).collect();
    let lo = volts.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = volts.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    Ok(InvertReport {
        samples: volts.len(),
        voltage_range: [lo, hi],
        residual,
        volts,
        predicted,
        clipped: clipped.len(),
        largest_clip: largest.map_or(0.0, |c| c.miss()),
        largest_clip_sample: largest.map(|c| c.index),
    })
}

/// Why a recording cannot be predicted by a model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ValidateError {
    /// Fewer than two rows, or voltage and displacement of different lengths.
    #[error(
        "{rows} rows: a validation needs at least 2 (voltage and displacement of equal length)"
    )]
    TooShort {
        /// Rows given.
        rows: usize,
    },
    /// A voltage or displacement that is not a finite number, at sample `index`.
    #[error("sample {index}: the {which} is not a finite number")]
    NotFinite {
        /// 0-based sample.
        index: usize,
        /// `voltage` or `displacement`.
        which: &'static str,
    },
    /// A voltage outside the model's input range, at sample `index`.
    #[error("sample {index}: {value} V lies outside the model's range [{min}, {max}] V")]
    Outside {
        /// 0-based sample.
        index: usize,
        /// The voltage, V.
        value: f64,
        /// The range's bottom, V.
        min: f64,
        /// The range's top, V.
        max: f64,
    },
    /// The recording's displacement does not move: no stroke to relate errors to.
    #[error(
        "the displacement never changes ({value:e} m throughout): no stroke to validate against"
    )]
    NoStroke {
        /// The constant displacement, m.
        value: f64,
    },
}

/// What `hysteresis validate` measured: a model's prediction of a recording it was not
/// fitted on, from its relaxed state, against the recording.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `samples` | | rows predicted |
/// | `stroke` | m | the recording's span of displacement (max − min) |
/// | `rms`, `max` | m | RMS and largest \|predicted − measured\| |
/// | `rms_percent`, `max_percent` | % | the same over `stroke` |
/// | `worst_sample` | | the 0-based row of `max` |
/// | `rest_measured`, `rest_predicted` | m | the first row's displacement and the model's output at that row |
/// | `starts_relaxed` | | whether the recording starts at the model's lowest input (the prediction assumes it does) |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ValidateReport {
    /// Rows.
    pub samples: usize,
    /// m.
    pub stroke: f64,
    /// m.
    pub rms: f64,
    /// m.
    pub max: f64,
    /// %.
    pub rms_percent: f64,
    /// %.
    pub max_percent: f64,
    /// 0-based row.
    pub worst_sample: usize,
    /// m.
    pub rest_measured: f64,
    /// m.
    pub rest_predicted: f64,
    /// The first voltage is the model's lowest input (within 1 % of its range).
    pub starts_relaxed: bool,
    /// The prediction, m, one per row.
    #[serde(skip)]
    pub predicted: Vec<f64>,
}

/// Predicts a recording (`volts`, V, and `disp`, m, in time order) with `model` from
/// its relaxed state and measures the prediction's error against the recording: the
/// check of a model on data it was not fitted on. Voltages must lie within the model's
/// range (1e-9 V of slack).
pub fn validate(
    model: &AnyModel,
    volts: &[f64],
    disp: &[f64],
) -> Result<ValidateReport, ValidateError> {
    let rows = volts.len();
    if rows < 2 || disp.len() != rows {
        return Err(ValidateError::TooShort { rows });
    }
    for (which, v) in [("voltage", volts), ("displacement", disp)] {
        if let Some(index) = v.iter().position(|v| !v.is_finite()) {
            return Err(ValidateError::NotFinite { index, which });
        }
    }
    let range = model.range();
    if let Some(index) = volts
        .iter()
        .position(|v| *v < range.min - 1e-9 || *v > range.max + 1e-9)
    {
        return Err(ValidateError::Outside {
            index,
            value: volts[index],
            min: range.min,
            max: range.max,
        });
    }
    let lo = disp.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = disp.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let stroke = hi - lo;
    if stroke <= 0.0 {
        return Err(ValidateError::NoStroke { value: lo });
    }
    let mut m = model.clone();
    m.reset();
    let predicted: Vec<f64> = volts.iter().map(|v| m.apply(*v)).collect();
    let (mut s2, mut max, mut worst) = (0.0, 0.0f64, 0);
    for (k, (p, y)) in predicted.iter().zip(disp).enumerate() {
        let e = (p - y).abs();
        s2 += e * e;
        if e > max {
            (max, worst) = (e, k);
        }
    }
    let rms = (s2 / rows as f64).sqrt();
    Ok(ValidateReport {
        samples: rows,
        stroke,
        rms,
        max,
        rms_percent: 100.0 * rms / stroke,
        max_percent: 100.0 * max / stroke,
        worst_sample: worst,
        rest_measured: disp[0],
        rest_predicted: predicted[0],
        starts_relaxed: (volts[0] - range.min).abs() <= 0.01 * (range.max - range.min),
        predicted,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use cellinject_model::prototype;
    use cellinject_rig::{RigParams, fake};

    #[test]
    fn an_identification_run_stays_inside_the_envelope_and_fits() {
        // The fake's "displacement" is a hysteresis-free 0.3 µm/V: a fitted model must
        // reproduce it closely and invert it to the same line.
        let p = RigParams {
            approach: cellinject_model::Approach::DriveTranslation,
            ..RigParams::default()
        };
        let (devices, _) = fake::devices(&p);
        let mut rig = Rig::new(devices, &prototype(), &p).unwrap();
        let guard = rig.guard.clone();
        let r = identify(&mut rig, 0, 1500, 1e-3, || {
            0.3e-6 * cellinject_rig::guard::lock(&guard).commanded()[0]
        })
        .unwrap();
        // Approach 1's torque limit caps A1 near 68 V.
        assert!(r.v_max > 60.0 && r.v_max < 75.0, "{}", r.v_max);
        assert!(r.samples.iter().all(|s| s[1] <= r.v_max + 1e-9));
        let v: Vec<f64> = r.samples.iter().map(|s| s[1]).collect();
        let y: Vec<f64> = r.samples.iter().map(|s| s[2]).collect();
        let f = fit(
            Kind::Preisach,
            16,
            Range {
                min: 0.0,
                max: r.v_max,
            },
            &v,
            &y,
        )
        .unwrap();
        assert!(f.rms_relative < 2e-3, "{}", f.rms_relative);
        let inv = invert(&f.model, &[3e-6, 6e-6, 4e-6], false).unwrap();
        for (u, yd) in inv.volts.iter().zip([3e-6, 6e-6, 4e-6]) {
            assert!((u * 0.3e-6 - yd).abs() < 0.02 * yd, "{u} V for {yd}");
        }
    }

    /// A linear model (one play of threshold 0: 20 µm over 0-100 V) against a
    /// recording that stands 0.1 µm above it on rows 10-19 of 100: RMS and worst error
    /// follow by hand (0.1 µm × √(10/100) and 0.1 µm, over the 20 µm stroke).
    #[test]
    fn a_validation_measures_the_error_against_an_independent_line() {
        let range = Range {
            min: 0.0,
            max: 100.0,
        };
        let m =
            AnyModel::Pi(PrandtlIshlinskii::new(range, 0.0, vec![0.0], vec![20e-6], 0.0).unwrap());
        let volts: Vec<f64> = (0..100).map(|k| 100.0 * k as f64 / 99.0).collect();
        let mut disp: Vec<f64> = volts.iter().map(|v| 0.2e-6 * v).collect();
        for y in &mut disp[10..20] {
            *y += 0.1e-6;
        }
        let r = validate(&m, &volts, &disp).unwrap();
        assert!((r.stroke - 20e-6).abs() < 1e-15, "{}", r.stroke);
        assert!((r.rms - 0.1e-6 * 0.1f64.sqrt()).abs() < 1e-15, "{}", r.rms);
        assert!((r.max - 0.1e-6).abs() < 1e-15 && (10..20).contains(&r.worst_sample));
        assert!((r.max_percent - 0.5).abs() < 1e-9, "{}", r.max_percent);
        assert!(r.starts_relaxed && r.rest_measured == 0.0 && r.rest_predicted.abs() < 1e-18);
        // Refusals name the sample.
        let mut bad = volts.clone();
        bad[7] = 120.0;
        assert!(matches!(
            validate(&m, &bad, &disp),
            Err(ValidateError::Outside { index: 7, .. })
        ));
        bad[7] = f64::NAN;
        assert!(matches!(
            validate(&m, &bad, &disp),
            Err(ValidateError::NotFinite {
                index: 7,
                which: "voltage"
            })
        ));
        assert!(matches!(
            validate(&m, &volts, &vec![1e-6; 100]),
            Err(ValidateError::NoStroke { .. })
        ));
        assert!(matches!(
            validate(&m, &volts[..1], &disp[..1]),
            Err(ValidateError::TooShort { rows: 1 })
        ));
    }
}
