//! Newton's method for two equations in two unknowns, with a forward-difference
//! Jacobian and an optional step limit. Used where each evaluation is a whole model
//! solve (a joint FEM, a structural equilibrium), so the Jacobian costs two more.

use nalgebra::{Matrix2, Vector2};
use thiserror::Error;

/// Settings of [`newton2`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Newton2Options {
    /// Forward-difference step of each unknown.
    pub fd_step: f64,
    /// Converged once both residuals are at most this in magnitude.
    pub tolerance: f64,
    /// Largest number of Newton steps.
    pub max_iterations: usize,
    /// Largest change of an unknown in one step; longer steps are scaled down
    /// (`f64::INFINITY`: undamped).
    pub max_step: f64,
}

/// A converged solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Newton2 {
    /// The root.
    pub x: [f64; 2],
    /// The residuals there.
    pub f: [f64; 2],
    /// Newton steps taken.
    pub iterations: usize,
}

/// Why [`newton2`] stopped without a root.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum Newton2Error<E> {
    /// The function itself failed.
    #[error("{0}")]
    Eval(E),
    /// The finite-difference Jacobian is singular.
    #[error("singular Jacobian at step {iteration} (x = {x:?})")]
    Singular {
        /// Step at which it happened.
        iteration: usize,
        /// Where.
        x: [f64; 2],
    },
    /// No root within the allowed steps.
    #[error("no convergence in {iterations} Newton steps (largest residual {residual:e})")]
    NotConverged {
        /// Steps taken.
        iterations: usize,
        /// Largest residual magnitude at the last step.
        residual: f64,
    },
}

/// Solves `f(x) = 0` for `x` in R² from `x0`. `observe(iteration, x, f)` sees every
/// iterate (for progress reports).
pub fn newton2<E>(
    mut f: impl FnMut([f64; 2]) -> Result<[f64; 2], E>,
    x0: [f64; 2],
    options: &Newton2Options,
    mut observe: impl FnMut(usize, [f64; 2], [f64; 2]),
) -> Result<Newton2, Newton2Error<E>> {
    let mut x = x0;
    let mut fx = f(x).map_err(Newton2Error::Eval)?;
    let mut residual = f64::INFINITY;
    for it in 0..options.max_iterations {
        observe(it, x, fx);
        residual = fx[0].abs().max(fx[1].abs());
        if residual <= options.tolerance {
            return Ok(Newton2 {
                x,
                f: fx,
                iterations: it,
            });
        }
        let h = options.fd_step;
        let mut jac = Matrix2::zeros();
        for c in 0..2 {
            let mut xp = x;
            xp[c] += h;
            let fp = f(xp).map_err(Newton2Error::Eval)?;
            for r in 0..2 {
                jac[(r, c)] = (fp[r] - fx[r]) / h;
            }
        }
        let step = jac
            .lu()
            .solve(&Vector2::new(-fx[0], -fx[1]))
            .ok_or(Newton2Error::Singular { iteration: it, x })?;
        let scale = (options.max_step / step.amax()).min(1.0);
        x = [x[0] + scale * step[0], x[1] + scale * step[1]];
        fx = f(x).map_err(Newton2Error::Eval)?;
    }
    Err(Newton2Error::NotConverged {
        iterations: options.max_iterations,
        residual,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts() -> Newton2Options {
        Newton2Options {
            fd_step: 1e-7,
            tolerance: 1e-12,
            max_iterations: 50,
            max_step: f64::INFINITY,
        }
    }

    #[test]
    fn finds_the_intersection_of_a_circle_and_a_line() {
        // x² + y² = 4, x = y: root (√2, √2); residual checked, not a stored answer.
        let f = |x: [f64; 2]| -> Result<[f64; 2], ()> {
            Ok([x[0] * x[0] + x[1] * x[1] - 4.0, x[0] - x[1]])
        };
        let r = newton2(f, [1.0, 0.5], &opts(), |_, _, _| {}).unwrap();
        let res = f(r.x).unwrap();
        assert!(res[0].abs() < 1e-12 && res[1].abs() < 1e-12, "{res:?}");
        assert!((r.x[0] - 2f64.sqrt()).abs() < 1e-9);
    }

    #[test]
    fn a_step_limit_damps_and_failures_are_typed() {
        let f = |x: [f64; 2]| -> Result<[f64; 2], ()> { Ok([x[0].exp() - 10.0, x[1] - 1.0]) };
        let mut largest = 0.0f64;
        let mut last = [0.0; 2];
        let damped = Newton2Options {
            max_step: 0.2,
            ..opts()
        };
        let r = newton2(f, [0.0, 0.0], &damped, |it, x, _| {
            if it > 0 {
                largest = largest.max((x[0] - last[0]).abs());
            }
            last = x;
        })
        .unwrap();
        assert!(largest <= 0.2 + 1e-12, "{largest}");
        assert!((r.x[0] - 10f64.ln()).abs() < 1e-9);
        let flat = |_: [f64; 2]| -> Result<[f64; 2], ()> { Ok([1.0, 1.0]) };
        assert!(matches!(
            newton2(flat, [0.0, 0.0], &opts(), |_, _, _| {}),
            Err(Newton2Error::Singular { iteration: 0, .. })
        ));
        let never = |x: [f64; 2]| -> Result<[f64; 2], ()> { Ok([x[0] * x[0] + 1.0, x[1]]) };
        let few = Newton2Options {
            max_iterations: 5,
            ..opts()
        };
        assert!(matches!(
            newton2(never, [1.0, 0.0], &few, |_, _, _| {}),
            Err(Newton2Error::NotConverged { iterations: 5, .. })
        ));
        assert!(matches!(
            newton2(
                |_| Err::<[f64; 2], _>("boom"),
                [0.0, 0.0],
                &opts(),
                |_, _, _| {}
            ),
            Err(Newton2Error::Eval("boom"))
        ));
    }
}
