//! The Prandtl-Ishlinskii model: a weighted sum of play (backlash) operators of
//! thresholds r₀ = 0 < r₁ < … < r_{n−1} on the normalised input,
//!
//! y(t) = y₀ + Σᵢ wᵢ · F_{rᵢ}[x](t),   F_r[x](t) = max(x − r, min(x + r, F_r[x](t⁻))),
//!
//! with wᵢ ≥ 0 (Krasnosel'skii & Pokrovskii 1989; Kuhnen & Janocha 2001). Its inverse
//! is again a PI operator, in closed form (Kuhnen, *Modeling, identification and
//! compensation of complex hysteretic nonlinearities*, 2003):
//!
//! ŵ₀ = 1/w₀,  ŵᵢ = −wᵢ / ((w₀ + … + wᵢ)(w₀ + … + w_{i−1})),
//! r̂ᵢ = Σ_{j<i} wⱼ (rᵢ − rⱼ),
//!
//! exact for plays started at zero. The asymmetric variant adds a monotone quadratic
//! input term c·x², c ≥ 0 (real stacks stiffen or soften along their stroke); it is
//! inverted numerically, like every model here ([`crate::inverse`]).

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::{Fit, HysteresisError, Model, Range};

/// Most plays in a model.
pub const MAX_PLAYS: usize = 64;

/// A Prandtl-Ishlinskii model (with an optional quadratic input term).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PrandtlIshlinskii {
    /// The input range (normalised to [0, 1] before the plays).
    pub range: Range,
    /// Output at zero input with relaxed plays.
    pub offset: f64,
    /// Thresholds rᵢ on the normalised input, increasing, r₀ = 0.
    pub thresholds: Vec<f64>,
    /// Weights wᵢ ≥ 0 (w₀ > 0 for an invertible model), output units.
    pub weights: Vec<f64>,
    /// Coefficient of x² (asymmetric variant; 0 for the classical model).
    pub quadratic: f64,
    #[serde(skip, default = "relaxed")]
    state: [f64; MAX_PLAYS],
    #[serde(skip)]
    x: f64,
}

fn relaxed() -> [f64; MAX_PLAYS] {
    [0.0; MAX_PLAYS]
}

fn play(r: f64, x: f64, last: f64) -> f64 {
    (x - r).max((x + r).min(last))
}

impl PrandtlIshlinskii {
    /// A model at zero input with relaxed plays.
    pub fn new(
        range: Range,
        offset: f64,
        thresholds: Vec<f64>,
        weights: Vec<f64>,
        quadratic: f64,
    ) -> Result<Self, HysteresisError> {
        let bad = |reason: String| HysteresisError::Invalid {
            what: "Prandtl-Ishlinskii model",
            reason,
        };
        if thresholds.len() != weights.len()
            || thresholds.is_empty()
            || thresholds.len() > MAX_PLAYS
        {
            return Err(bad(format!(
                "{} thresholds and {} weights (1 to {MAX_PLAYS} plays)",
                thresholds.len(),
                weights.len()
            )));
        }
        if thresholds.windows(2).any(|w| w[1] <= w[0]) || thresholds[0] != 0.0 {
            return Err(bad("thresholds must increase from 0".into()));
        }
        if weights
            .iter()
            .chain([&quadratic, &offset])
            .any(|w| !w.is_finite())
        {
            return Err(bad("weights must be finite".into()));
        }
        Ok(PrandtlIshlinskii {
            range,
            offset,
            thresholds,
            weights,
            quadratic,
            state: [0.0; MAX_PLAYS],
            x: 0.0,
        })
    }

    /// Evenly spaced thresholds i/n, i = 0..n.
    pub fn even_thresholds(n: usize) -> Vec<f64> {
        (0..n).map(|i| i as f64 / n as f64).collect()
    }

    fn eval(&self, x: f64, state: &mut [f64]) -> f64 {
        let mut y = self.offset + self.quadratic * x * x;
        for ((r, w), s) in self
            .thresholds
            .iter()
            .zip(&self.weights)
            .zip(state.iter_mut())
        {
            *s = play(*r, x, *s);
            y += w * *s;
        }
        y
    }

    /// The exact inverse of a classical model (no quadratic term, w₀ > 0, every
    /// partial sum of weights positive): a PI operator from output to normalised input,
    /// on the output range `output`.
    pub fn inverse(&self) -> Result<PrandtlIshlinskii, HysteresisError> {
        if self.quadratic != 0.0 {
            return Err(HysteresisError::Invalid {
                what: "inverse",
                reason: "the asymmetric model is inverted numerically (crate::inverse)".into(),
            });
        }
        let w = &self.weights;
        let r = &self.thresholds;
        if w[0] <= 0.0 {
            return Err(HysteresisError::Invalid {
                what: "inverse",
                reason: "the linear weight w0 must be positive".into(),
            });
        }
        let mut wi = Vec::with_capacity(w.len());
        let mut ri = Vec::with_capacity(w.len());
        let mut sum_prev = 0.0;
        let mut sum = 0.0;
        for i in 0..w.len() {
            sum += w[i];
            if i == 0 {
                wi.push(1.0 / w[0]);
                ri.push(0.0);
            } else {
                wi.push(-w[i] / (sum * sum_prev));
                ri.push((0..i).map(|j| w[j] * (r[i] - r[j])).sum());
            }
            sum_prev = sum;
        }
        // The inverse maps y − offset (output units) to the normalised input.
        Ok(PrandtlIshlinskii {
            range: Range { min: 0.0, max: 1.0 },
            offset: 0.0,
            thresholds: ri,
            weights: wi,
            quadratic: 0.0,
            state: [0.0; MAX_PLAYS],
            x: 0.0,
        })
    }

    /// Identifies offset, weights (≥ 0) and, if `asymmetric`, the quadratic term (≥ 0)
    /// for `n` evenly spaced plays, by non-negative least squares with a ridge, from
    /// data prepared by [`crate::prepare`] (dwells merged, noise wiggles held, each
    /// sample weighted by the input path it stands for).
    pub fn identify(
        range: Range,
        n: usize,
        asymmetric: bool,
        inputs: &[f64],
        outputs: &[f64],
        lambda: f64,
    ) -> Result<Fit<PrandtlIshlinskii>, HysteresisError> {
        let data = crate::prepare(inputs, outputs, &range)?;
        if !(1..=MAX_PLAYS).contains(&n) {
            return Err(HysteresisError::Invalid {
                what: "plays",
                reason: format!("{n}: use 1 to {MAX_PLAYS}"),
            });
        }
        let thresholds = Self::even_thresholds(n);
        let k = n + 2; // offset, quadratic, weights
        let mut g = DMatrix::<f64>::zeros(k, k);
        let mut h = DVector::<f64>::zeros(k);
        let mut state = vec![0.0; n];
        let mut row = vec![0.0; k];
        for ((&u, &y), &w) in data.inputs.iter().zip(&data.outputs).zip(&data.weights) {
            let x = range.normalise(u);
            row[0] = 1.0;
            row[1] = if asymmetric { x * x } else { 0.0 };
            for i in 0..n {
                state[i] = play(thresholds[i], x, state[i]);
                row[2 + i] = state[i];
            }
            for a in 0..k {
                let wa = w * row[a];
                h[a] += wa * y;
                for b in 0..k {
                    g[(a, b)] += wa * row[b];
                }
            }
        }
        // The ridge scales with the weights' own regressors (not the offset's column,
        // which is orders of magnitude larger).
        let scale = ((1..k).map(|a| g[(a, a)]).sum::<f64>() / (k - 1) as f64).max(1e-300);
        for a in 1..k {
            g[(a, a)] += lambda * scale;
        }
        let x = crate::solve_pinned(&g, &h, crate::rest_of(&data, &range))?;
        let model =
            PrandtlIshlinskii::new(range, x[0], thresholds, x.as_slice()[2..].to_vec(), x[1])?;
        Fit::measure(model, &data)
    }
}

impl Model for PrandtlIshlinskii {
    fn reset(&mut self) {
        self.state = [0.0; MAX_PLAYS];
        self.x = 0.0;
    }

    fn range(&self) -> Range {
        self.range
    }

    fn apply(&mut self, u: f64) -> f64 {
        let x = self.range.normalise(u);
        let mut state = self.state;
        let y = self.eval(x, &mut state);
        self.state = state;
        self.x = x;
        y
    }

    fn peek(&self, u: f64) -> f64 {
        let mut state = self.state;
        self.eval(self.range.normalise(u), &mut state)
    }

    fn output(&self) -> f64 {
        let mut state = self.state;
        self.eval(self.x, &mut state)
    }

    fn input(&self) -> f64 {
        self.range.denormalise(self.x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_closed_form_inverse_undoes_the_model() {
        let range = Range { min: 0.0, max: 1.0 };
        let w = vec![1.0, 0.3, 0.2, 0.15, 0.1, 0.05];
        let mut p =
            PrandtlIshlinskii::new(range, 0.0, PrandtlIshlinskii::even_thresholds(6), w, 0.0)
                .unwrap();
        let mut inv = p.inverse().unwrap();
        // Any trajectory of the output: the inverse's input, through the model, is it.
        for k in 0..400 {
            let t = k as f64 / 400.0;
            let yd = 1.0 * (0.5 - 0.45 * (7.0 * t).cos() + 0.2 * (23.0 * t).sin() * t);
            let x = inv.apply(yd);
            let y = p.apply(x);
            assert!((y - yd).abs() < 1e-12, "{k}: {y} vs {yd}");
        }
    }
}
