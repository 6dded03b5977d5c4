//! # cellinject-design
//!
//! Design studies of the micromanipulator: [`evaluate()`] turns one description into
//! the figures a designer trades off (working range, end-effector stiffness, first
//! natural frequencies, every margin of the safety envelope, cross-axis coupling,
//! feasibility) at `beam` or `fea` fidelity; [`space::Space`] names the free
//! description keys, objectives and constraints of a study; [`nsga2::Search`] is a
//! seeded ask/tell NSGA-II whose generations any engine may evaluate;
//! [`study`] joins them (a point's description, its member for the search, the front);
//! [`batch`] splits a batch of designs into shards and joins the results.
//!
//! **Architecture invariant:** pure computation: no files, no terminal, no clock. The
//! descriptions come in as text, the joint cache as a [`cellinject_fea::JointStore`];
//! front ends (the binary, the Python package) read, write and report.

pub mod batch;
pub mod evaluate;
pub mod nsga2;
pub mod space;
pub mod study;

pub use evaluate::{EvalOptions, FIGURES, Fidelity, Figures, evaluate};
pub use space::Space;

use thiserror::Error;

/// What a design study can fail at.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum DesignError {
    /// A bad input: a space file's key, a batch line, a description value.
    #[error("{key}: {reason}")]
    Input {
        /// The key, file or line at fault.
        key: String,
        /// What is wrong.
        reason: String,
    },
    /// The description was refused.
    #[error(transparent)]
    Config(#[from] cellinject_config::ConfigError),
    /// The pseudo-rigid-body model failed.
    #[error("the model: {0}")]
    Model(cellinject_model::ModelError),
    /// The structural model failed.
    #[error("the structural model: {0}")]
    Structure(cellinject_structure::StructureError),
    /// The FEA pipeline failed.
    #[error("the FEA: {0}")]
    Fea(cellinject_fea::FeaError),
    /// A matrix that must be invertible was not.
    #[error("the {what} is singular")]
    Singular {
        /// Which.
        what: &'static str,
    },
}

impl DesignError {
    /// Whether the input is at fault (exit 2), rather than the computation (exit 1).
    pub fn is_input(&self) -> bool {
        match self {
            DesignError::Input { .. } | DesignError::Config(_) => true,
            DesignError::Fea(e) => e.is_input(),
            _ => false,
        }
    }
}
