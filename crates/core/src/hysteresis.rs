//! `hysteresis identify | fit | invert`: hysteresis models from a rig's measurements or
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
}
