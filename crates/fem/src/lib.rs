//! # cellinject-fem
//!
//! Linear-elastic finite elements for flexure hinges, where beam formulas stop being
//! accurate (thick notches, t/R → 1).
//!
//! [`hinge2d`]: a notch hinge in plane stress or plane strain, meshed with 9-node
//! quadratic quadrilaterals on a structured mesh that follows the notch profile and is
//! graded towards the throat, assembled into a sparse matrix and solved by faer's sparse
//! Cholesky factorisation, the residual `|K u − f| / |f|` checked. The rotational
//! stiffness follows one definition so that methods compare: a block of the hinge's
//! full height, as long as it is high, on each side; the far end of one block clamped,
//! a pure moment (linear traction) on the far end of the other; the rotation is the
//! relative rotation of the notch's end sections, each the least-squares slope of its
//! axial displacements.
//!
//! [`joint3d`]: the paper's double-notched two-axis joint in 3-D (27-node hexahedra),
//! its full 6x6 compliance between the end sections and its stresses by superposition.
//!
//! **Architecture invariant:** pure computation; faer is used only here.

pub mod hinge2d;
pub mod joint3d;
mod lagrange;

use thiserror::Error;

/// What a finite-element solve can fail at.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum FemError {
    /// The stiffness matrix is not positive definite (a mechanism, or a bad mesh).
    #[error("the stiffness matrix ({dofs} unknowns) is not positive definite: {reason}")]
    NotPositiveDefinite {
        /// Unknowns.
        dofs: usize,
        /// faer's message.
        reason: String,
    },
    /// The solution does not satisfy the equations to the required accuracy.
    #[error("backward error {residual:.3e} above {tolerance:.1e} ({dofs} unknowns)")]
    Residual {
        /// |f − K u|∞ / (|K|∞ |u|∞ + |f|∞).
        residual: f64,
        /// Accepted.
        tolerance: f64,
        /// Unknowns.
        dofs: usize,
    },
    /// An element with a non-positive Jacobian (the mesh folded).
    #[error("element {element} is inverted (Jacobian {jacobian:.3e})")]
    InvertedElement {
        /// Element index.
        element: usize,
        /// Its smallest Jacobian determinant.
        jacobian: f64,
    },
    /// A bad parameter.
    #[error("{0}")]
    Invalid(String),
}
