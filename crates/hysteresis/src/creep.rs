//! Logarithmic creep of a piezo stack after a step, ΔL(t) = ΔL(t₀)·(1 + γ·log₁₀(t/t₀))
//! (Jung & Gweon 2000; PI's P-8xx data sheets quote γ = 0.01-0.02), and its
//! compensation while a position is held: command the hysteresis inverse of
//! target / (1 + γ·log₁₀(t/t₀)).

use serde::{Deserialize, Serialize};

use crate::HysteresisError;

/// Logarithmic creep per decade of time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LogCreep {
    /// Creep per decade, as a fraction of the displacement.
    pub gamma: f64,
    /// s, the time after a step at which the hysteresis model's value is reached.
    pub t0: f64,
}

impl LogCreep {
    /// A creep law, checked.
    pub fn new(gamma: f64, t0: f64) -> Result<Self, HysteresisError> {
        if !(gamma.is_finite() && (0.0..0.2).contains(&gamma) && t0.is_finite() && t0 > 0.0) {
            return Err(HysteresisError::Invalid {
                what: "creep",
                reason: format!("γ = {gamma} must lie in [0, 0.2) and t0 = {t0} s be positive"),
            });
        }
        Ok(LogCreep { gamma, t0 })
    }

    /// The growth factor `t` seconds after a step (1 before t₀).
    pub fn factor(&self, t: f64) -> f64 {
        1.0 + self.gamma * (t.max(self.t0) / self.t0).log10()
    }

    /// The displacement to ask of the hysteresis inverse, `t` seconds into a hold, so
    /// that the crept displacement is `target`.
    pub fn compensate(&self, target: f64, t: f64) -> f64 {
        target / self.factor(t)
    }

    /// Fits γ to a hold: displacements `y` at times `t` after a step (t > 0), by least
    /// squares of y = y₀(1 + γ log₁₀(t/t₀)) in (y₀, y₀γ).
    pub fn identify(t: &[f64], y: &[f64], t0: f64) -> Result<Self, HysteresisError> {
        let pts: Vec<(f64, f64)> = t
            .iter()
            .zip(y)
            .filter(|(t, y)| **t >= t0 && t.is_finite() && y.is_finite())
            .map(|(t, y)| ((t / t0).log10(), *y))
            .collect();
        if pts.len() < 3 {
            return Err(HysteresisError::Invalid {
                what: "creep data",
                reason: format!("{} samples after t0 = {t0} s: give at least 3", pts.len()),
            });
        }
        let n = pts.len() as f64;
        let (sx, sy) = pts.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
        let (mx, my) = (sx / n, sy / n);
        let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
        let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        if sxx <= 0.0 {
            return Err(HysteresisError::Invalid {
                what: "creep data",
                reason: "the samples span no time".into(),
            });
        }
        let slope = sxy / sxx;
        let y0 = my - slope * mx;
        LogCreep::new(slope / y0, t0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fitted_creep_law_compensates_a_hold() {
        let truth = LogCreep::new(0.015, 0.01).unwrap();
        let t: Vec<f64> = (1..=400).map(|k| 0.01 * 1.02f64.powi(k)).collect();
        let y: Vec<f64> = t.iter().map(|t| 10e-6 * truth.factor(*t)).collect();
        let fit = LogCreep::identify(&t, &y, 0.01).unwrap();
        assert!((fit.gamma - 0.015).abs() < 1e-12, "{}", fit.gamma);
        // Asking for target/factor gives the target once crept.
        for &ti in &[0.01, 1.0, 100.0] {
            let asked = fit.compensate(5e-6, ti);
            assert!((asked * truth.factor(ti) - 5e-6).abs() < 1e-18);
        }
        assert!(LogCreep::new(f64::NAN, 1.0).is_err());
    }
}
