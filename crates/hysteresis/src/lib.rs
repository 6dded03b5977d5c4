//! # cellinject-hysteresis
//!
//! Rate-independent hysteresis models of piezo actuators, their identification from
//! measured (voltage, displacement) data and their inversion for feedforward
//! compensation: the discrete Preisach model ([`preisach`], the default) and the
//! Prandtl-Ishlinskii model with its closed-form inverse and an asymmetric variant
//! ([`pi`]); logarithmic creep compensation ([`creep`]).
//!
//! Every model is a [`Model`]: it keeps its own memory, can [`Model::peek`] the output an
//! input would give without committing it, and is inverted sample by sample by
//! [`inverse`] (bisection on the input, exact to the model's precision because each
//! model's output is continuous and non-decreasing in the input from any state).
//! Identification takes recordings as benches make them ([`data`]: dwells, a quantised
//! or noisy input) and reports its fit error ([`Fit`]); inversion reports its residual and
//! refuses a target outside the model's reach ([`HysteresisError::OutOfReach`]).
//!
//! **Architecture invariant:** pure computation on numbers: no IO, no time, no devices;
//! a model's step allocates nothing.

pub mod creep;
pub mod data;
pub mod pi;
pub mod preisach;

use serde::{Deserialize, Serialize};
use thiserror::Error;

pub use creep::LogCreep;
pub use data::{DataSummary, Prepared, prepare};
pub use pi::PrandtlIshlinskii;
pub use preisach::Preisach;

/// Why a model could not be built, identified or inverted.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum HysteresisError {
    /// A parameter or data set out of its domain.
    #[error("{what}: {reason}")]
    Invalid {
        /// What.
        what: &'static str,
        /// Why.
        reason: String,
    },
    /// Inputs and outputs of different lengths.
    #[error("identification data: {inputs} inputs but {outputs} outputs")]
    LengthMismatch {
        /// Inputs.
        inputs: usize,
        /// Outputs.
        outputs: usize,
    },
    /// Too few samples (after merging repeated inputs) to identify a model.
    #[error("{}", too_few(*rows, *samples, *min))]
    TooFewSamples {
        /// Samples given.
        rows: usize,
        /// Distinct samples left after merging repeated inputs.
        samples: usize,
        /// Fewest accepted.
        min: usize,
    },
    /// A sample that is not a finite number.
    #[error("identification data: sample {index}: the {which} is not a finite number")]
    NotFinite {
        /// Sample index (from 0).
        index: usize,
        /// `input` or `output`.
        which: &'static str,
    },
    /// The input never moves by more than its noise.
    #[error(
        "the input stays within [{min}, {max}] over {samples} samples, never moving by more than {} times its noise level {noise:.3e}: hysteresis needs it to move",
        data::REVERSAL_FACTOR
    )]
    ConstantInput {
        /// Lowest input.
        min: f64,
        /// Highest input.
        max: f64,
        /// The input's noise or quantisation level.
        noise: f64,
        /// Samples.
        samples: usize,
    },
    /// Fewer than two reversals of the input larger than its noise.
    #[error(
        "{reversals} reversals of the input (changes of direction larger than {threshold:.3e}, {} times its noise level {noise:.3e}) over [{min}, {max}]: hysteresis needs rising and falling branches",
        data::REVERSAL_FACTOR
    )]
    TooFewReversals {
        /// Reversals found.
        reversals: usize,
        /// Smallest change of direction counted.
        threshold: f64,
        /// The input's noise or quantisation level.
        noise: f64,
        /// Lowest input.
        min: f64,
        /// Highest input.
        max: f64,
    },
    /// The least-squares solver failed.
    #[error("identification: {0}")]
    Solver(String),
    /// The target output cannot be reached within the input range.
    #[error(
        "sample {index}: the target {:.4} µm lies outside the model's reach [{:.4}, {:.4}] µm from its state",
        target * 1e6,
        min * 1e6,
        max * 1e6
    )]
    OutOfReach {
        /// Sample index.
        index: usize,
        /// The target.
        target: f64,
        /// Lowest output reachable.
        min: f64,
        /// Highest output reachable.
        max: f64,
    },
}

fn too_few(rows: usize, samples: usize, min: usize) -> String {
    if rows == samples {
        format!("{rows} samples: give at least {min}, with reversals (a few thousand are enough)")
    } else {
        format!(
            "{samples} distinct samples ({rows} given, {} repeating the input before them): give at least {min}, with reversals (a few thousand are enough)",
            rows - samples
        )
    }
}

/// An input range (e.g. an amplifier's 0-100 V), normalised to [0, 1] by the models.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Range {
    /// Lowest input.
    pub min: f64,
    /// Highest input.
    pub max: f64,
}

impl Range {
    /// (u − min) / (max − min).
    pub fn normalise(&self, u: f64) -> f64 {
        (u - self.min) / (self.max - self.min)
    }

    /// The inverse of [`Range::normalise`].
    pub fn denormalise(&self, x: f64) -> f64 {
        self.min + x * (self.max - self.min)
    }
}

/// A hysteresis operator with memory.
pub trait Model {
    /// Back to the relaxed state at the bottom of the range.
    fn reset(&mut self);
    /// The input range.
    fn range(&self) -> Range;
    /// Moves the input to `u` and returns the output.
    fn apply(&mut self, u: f64) -> f64;
    /// The output `u` would give from the current state, without changing it.
    fn peek(&self, u: f64) -> f64;
    /// The output now.
    fn output(&self) -> f64;
    /// The input now.
    fn input(&self) -> f64;
}

/// A fitted model and how well it fits the data it was fitted on.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Fit<M> {
    /// The model, reset to its relaxed state.
    pub model: M,
    /// RMS of model − data, output units.
    pub rms: f64,
    /// Largest |model − data|.
    pub max: f64,
    /// The data's span of outputs (max − min), for relative figures.
    pub span: f64,
    /// Samples fitted (after merging repeated inputs).
    pub samples: usize,
    /// What the data preparation did (merged dwells, flattened noise, reversals).
    pub data: DataSummary,
}

impl<M: Model + Clone> Fit<M> {
    /// Replays prepared data through `model` from its relaxed state and measures the
    /// error.
    pub fn measure(mut model: M, data: &Prepared) -> Result<Self, HysteresisError> {
        let (inputs, outputs) = (&data.inputs, &data.outputs);
        model.reset();
        let (mut s2, mut max) = (0.0, 0.0f64);
        for (&u, &y) in inputs.iter().zip(outputs) {
            let e = model.apply(u) - y;
            s2 += e * e;
            max = max.max(e.abs());
        }
        model.reset();
        let lo = outputs.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = outputs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Ok(Fit {
            model,
            rms: (s2 / inputs.len() as f64).sqrt(),
            max,
            span: hi - lo,
            samples: inputs.len(),
            data: data.summary,
        })
    }
}

/// Inverse of a model, sample by sample: the inputs that make `model` (from its current
/// state) follow `targets`, each found by bisection on the input range to `tolerance`
/// (relative to the reachable span); the model's state follows. Returns the inputs and
/// the largest residual |output − target|. A target outside what the input range can
/// reach from the state is refused, not clipped.
pub fn inverse<M: Model>(
    model: &mut M,
    targets: &[f64],
    out: &mut Vec<f64>,
) -> Result<f64, HysteresisError> {
    out.clear();
    let r = model.range();
    let mut worst = 0.0f64;
    for (index, &yd) in targets.iter().enumerate() {
        let u = inverse_step(model, yd, r).map_err(|(min, max)| HysteresisError::OutOfReach {
            index,
            target: yd,
            min,
            max,
        })?;
        let y = model.apply(u);
        worst = worst.max((y - yd).abs());
        out.push(u);
    }
    Ok(worst)
}

/// The recording's rest, the output relaxed at the bottom of the range, for a
/// recording that starts relaxed (as the fits ask): its first sample's output when
/// that sample lies at the bottom (within the input's reversal threshold); when the
/// recording's first rise starts a little above it (within 5 % of the range, as a
/// logger that starts with the ramp does), the line through the first rise's samples
/// in that band (at most 10), extended to the bottom. `None` otherwise: the offset is
/// then fitted with the rest.
pub(crate) fn rest_of(data: &Prepared, range: &Range) -> Option<f64> {
    let (u0, y0) = (*data.inputs.first()?, *data.outputs.first()?);
    let span = range.max - range.min;
    let tol = data.summary.reversal_threshold.max(1e-9 * span);
    if !y0.is_finite() {
        return None;
    }
    if u0 - range.min <= tol {
        return Some(y0);
    }
    // The first rise, within 5 % of the range above the bottom.
    let mut pts = Vec::with_capacity(10);
    let mut last = range.min;
    for (&u, &y) in data.inputs.iter().zip(&data.outputs) {
        if u <= last || u - range.min > 0.05 * span || pts.len() == 10 || !y.is_finite() {
            break;
        }
        pts.push((u - range.min, y));
        last = u;
    }
    if pts.len() < 2 {
        return None;
    }
    let n = pts.len() as f64;
    let (mu, my) = pts
        .iter()
        .fold((0.0, 0.0), |a, p| (a.0 + p.0 / n, a.1 + p.1 / n));
    let (sxy, sxx) = pts.iter().fold((0.0, 0.0), |a, p| {
        (a.0 + (p.0 - mu) * (p.1 - my), a.1 + (p.0 - mu) * (p.0 - mu))
    });
    (sxx > 0.0).then(|| my - sxy / sxx * mu)
}

/// Solves a fit's normal equations (`g x = h`, every unknown but the first, the
/// offset, non-negative) with the offset pinned to `rest` when given: the model's
/// relaxed output is then the recording's rest, not whatever offset trades best
/// against the weights (a free offset put a Bouc-Wen stack's relaxed output at
/// 3.24 um, and the twin's at 0.15 um against a fit RMS of 0.08 um: no trajectory
/// starting at rest could be inverted).
pub(crate) fn solve_pinned(
    g: &nalgebra::DMatrix<f64>,
    h: &nalgebra::DVector<f64>,
    rest: Option<f64>,
) -> Result<nalgebra::DVector<f64>, HysteresisError> {
    let solver = |e: cellinject_numeric::NnlsError| HysteresisError::Solver(e.to_string());
    let Some(r) = rest else {
        return cellinject_numeric::nnls_gram(g, h, &[0]).map_err(solver);
    };
    let k = h.len();
    let g1 = g.view((1, 1), (k - 1, k - 1)).into_owned();
    let h1 = nalgebra::DVector::from_iterator(k - 1, (1..k).map(|a| h[a] - g[(a, 0)] * r));
    let x1 = cellinject_numeric::nnls_gram(&g1, &h1, &[]).map_err(solver)?;
    let mut x = nalgebra::DVector::zeros(k);
    x[0] = r;
    x.rows_mut(1, k - 1).copy_from(&x1);
    Ok(x)
}

/// A target the inversion could not reach and took as near as the model goes
/// ([`inverse_clipped`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Clipped {
    /// Sample index.
    pub index: usize,
    /// The target, m (or the model's output unit).
    pub target: f64,
    /// What the model reaches instead: the nearer end of its reach from its state.
    pub reached: f64,
}

impl Clipped {
    /// How far what was reached lies from the target (infinite for a NaN target).
    pub fn miss(&self) -> f64 {
        let d = (self.target - self.reached).abs();
        if d.is_nan() { f64::INFINITY } else { d }
    }
}

/// As [`inverse`], but a target outside the model's reach from its state is taken
/// as the nearer end of that reach instead of refused; each such sample is listed.
/// Returns the largest residual over the samples that were reachable.
pub fn inverse_clipped<M: Model>(
    model: &mut M,
    targets: &[f64],
    out: &mut Vec<f64>,
    clipped: &mut Vec<Clipped>,
) -> f64 {
    out.clear();
    clipped.clear();
    let r = model.range();
    let mut worst = 0.0f64;
    for (index, &yd) in targets.iter().enumerate() {
        let u = match inverse_step(model, yd, r) {
            Ok(u) => u,
            Err((min, max)) => {
                // NaN and a target below the reach go to its low end.
                let (u, reached) = if yd > max { (r.max, max) } else { (r.min, min) };
                clipped.push(Clipped {
                    index,
                    target: yd,
                    reached,
                });
                out.push(u);
                model.apply(u);
                continue;
            }
        };
        let y = model.apply(u);
        worst = worst.max((y - yd).abs());
        out.push(u);
    }
    worst
}

/// A target this far past either end of a model's reach (as a fraction of the
/// reach's span) counts as that end: 3 nm on a 30 um stack, below any stack's noise.
/// A trajectory that starts at rest asks for 0 m where the model's relaxed output is
/// the recording's rest, read with its sensor's noise (0.12 nm on the twin's).
pub const REACH_SLACK: f64 = 1e-4;

/// One inverse step without allocation: the input in `range` whose output from the
/// current state is `target`, or the reachable (min, max) if none is.
pub fn inverse_step<M: Model + ?Sized>(
    model: &M,
    target: f64,
    range: Range,
) -> Result<f64, (f64, f64)> {
    let (mut lo, mut hi) = (range.min, range.max);
    let (ylo, yhi) = (model.peek(lo), model.peek(hi));
    let slack = REACH_SLACK * (yhi - ylo).abs().max(1e-300);
    if !target.is_finite() || target < ylo - slack || target > yhi + slack {
        return Err((ylo, yhi));
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if model.peek(mid) < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(0.5 * (lo + hi))
}

/// Any of the models, as saved in a model file (`"model": "preisach" | "pi"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum AnyModel {
    /// Discrete Preisach.
    Preisach(Preisach),
    /// Prandtl-Ishlinskii (classical or asymmetric).
    Pi(PrandtlIshlinskii),
}

impl Model for AnyModel {
    fn reset(&mut self) {
        match self {
            AnyModel::Preisach(m) => m.reset(),
            AnyModel::Pi(m) => m.reset(),
        }
    }
    fn range(&self) -> Range {
        match self {
            AnyModel::Preisach(m) => m.range(),
            AnyModel::Pi(m) => m.range(),
        }
    }
    fn apply(&mut self, u: f64) -> f64 {
        match self {
            AnyModel::Preisach(m) => m.apply(u),
            AnyModel::Pi(m) => m.apply(u),
        }
    }
    fn peek(&self, u: f64) -> f64 {
        match self {
            AnyModel::Preisach(m) => m.peek(u),
            AnyModel::Pi(m) => m.peek(u),
        }
    }
    fn output(&self) -> f64 {
        match self {
            AnyModel::Preisach(m) => m.output(),
            AnyModel::Pi(m) => m.output(),
        }
    }
    fn input(&self) -> f64 {
        match self {
            AnyModel::Preisach(m) => m.input(),
            AnyModel::Pi(m) => m.input(),
        }
    }
}

/// A rich identification excitation of `n` samples on `range`: a full rise, then
/// oscillations whose amplitude and centre vary, so that reversals of every size and
/// at every level occur (first-order reversal curves and nested minor loops).
pub fn excitation(range: Range, n: usize) -> Vec<f64> {
    let tau = 2.0 * std::f64::consts::PI;
    (0..n)
        .map(|k| {
            let t = k as f64 / n.max(1) as f64;
            let x = if t < 0.05 {
                t / 0.05
            } else {
                let s = (t - 0.05) / 0.95;
                let centre = 0.5 + 0.25 * (tau * 1.3 * s).sin();
                let amp = 0.48 * (1.0 - 0.85 * s) * (0.5 + 0.5 * (tau * 2.1 * s).cos());
                centre + amp * (tau * 23.0 * s).cos()
            };
            range.denormalise(x.clamp(0.0, 1.0))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A PI model with a linear part only: output 1 µm per volt from rest over 0-10 V
    /// (plays of threshold 0 pass the input), offset 0.5 µm.
    fn line() -> PrandtlIshlinskii {
        let r = Range {
            min: 0.0,
            max: 10.0,
        };
        PrandtlIshlinskii::new(r, 0.5e-6, vec![0.0], vec![10e-6], 0.0).unwrap()
    }

    #[test]
    fn targets_past_the_reach_are_refused_or_clipped_and_listed() {
        // Reach from rest: [0.5, 10.5] µm.
        let targets = [0.5e-6, 3.5e-6, 12e-6, 0.1e-6, f64::NAN, 0.5e-6 - 0.5e-10];
        let mut m = line();
        let mut out = Vec::new();
        assert!(matches!(
            inverse(&mut m, &targets, &mut out),
            Err(HysteresisError::OutOfReach { index: 2, .. })
        ));
        let mut m = line();
        let mut clipped = Vec::new();
        let worst = inverse_clipped(&mut m, &targets, &mut out, &mut clipped);
        assert_eq!(out.len(), targets.len());
        // The residual: the last target's 0.05 nm, no more than the slack allows.
        assert!(
            (worst - 0.5e-10).abs() < 1e-15 && worst <= REACH_SLACK * 10e-6,
            "{worst}"
        );
        assert!((out[1] - 3.0).abs() < 1e-9, "{}", out[1]);
        // Above the reach: the top; below it and NaN: the bottom. The last target,
        // 0.05 nm under the reach (within REACH_SLACK of its 10 µm span), is reached.
        let idx: Vec<usize> = clipped.iter().map(|c| c.index).collect();
        assert_eq!(idx, vec![2, 3, 4]);
        assert_eq!(out[2], 10.0);
        assert!((clipped[0].reached - 10.5e-6).abs() < 1e-15);
        assert_eq!(out[3], 0.0);
        assert!((clipped[1].reached - 0.5e-6).abs() < 1e-15);
        assert!(out[5] < 1e-12, "{}", out[5]);
    }
}
