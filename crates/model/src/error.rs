//! Typed errors of the mechanism model.

use thiserror::Error;

/// Everything the model can refuse or fail at. Each variant carries the numbers
/// needed to diagnose the problem.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ModelError {
    /// A parameter of the description is out of its valid domain.
    #[error("key `{key}` = {value}: {reason}")]
    InvalidParameter {
        /// Description-file key, e.g. `geometry.b1`.
        key: String,
        /// The offending value (NaN when the value is absent).
        value: f64,
        /// What is wrong with it.
        reason: String,
    },
    /// A Jacobian of the structure is singular at the pose where it is needed.
    #[error(
        "the Jacobian {matrix} is singular at the home pose (reciprocal condition number {rcond:.3e}); \
         check `geometry` (for instance two actuators along the same direction)"
    )]
    SingularJacobian {
        /// "J", "L" or "W".
        matrix: &'static str,
        /// Reciprocal condition number estimate (smallest/largest singular value).
        rcond: f64,
    },
    /// The injection axis A3 is kinematically coupled to the tilt axes; the model
    /// assumes it is a pure serial axis.
    #[error(
        "the injection axis A3 is coupled to the tilt axes (largest coupling term {coupling:.3e})"
    )]
    CoupledInjectionAxis {
        /// Largest off-block Jacobian entry.
        coupling: f64,
    },
    /// A linear system of the pre-tension equations is singular.
    #[error("the {what} of eq. ({equation}) is singular (reciprocal condition number {rcond:.3e})")]
    SingularSystem {
        /// Which matrix.
        what: &'static str,
        /// Paper equation number.
        equation: u32,
        /// Reciprocal condition number estimate.
        rcond: f64,
    },
    /// A Newton iteration did not converge.
    #[error("{what} did not converge: {iterations} iterations, residual {residual:.3e}")]
    NotConverged {
        /// Which solve.
        what: &'static str,
        /// Iterations performed.
        iterations: usize,
        /// Final residual norm.
        residual: f64,
    },
}

impl ModelError {
    pub(crate) fn invalid(key: &str, value: f64, reason: &str) -> Self {
        ModelError::InvalidParameter {
            key: key.to_string(),
            value,
            reason: reason.to_string(),
        }
    }
}
