//! One view of the mechanism's static state, shared by its three producers.
//!
//! Three types describe the mechanism at an instant, each with what its solver knows:
//!
//! | type | crate | solver | extra |
//! |---|---|---|---|
//! | [`crate::State`] | model | constant Jacobians, eqs. 14-33 | δl, Δl1, δq, δw |
//! | [`crate::NonlinearState`] | model | eq. (19) with pose-dependent Jacobians | pose q, w, l; residual |
//! | `Snapshot` | twin | modal dynamics on the simulated clock | time, voltages, velocities, stick-slip |
//!
//! [`Statics`] is what they share (forces, joint torques, end-effector) in one layout:
//! three actuator forces, three J3 torques, four J1/J2 torques, three end-effector
//! displacements. Each type converts into it (`Statics::from(&state)`); the twin's
//! `Snapshot` has no A3 force or third J3 torque (the injection axis carries no preload)
//! and fills them with 0. At rest, the twin's statics equal the model's
//! `state_at` for the stacks' extensions (twin test
//! `at_rest_the_forces_satisfy_the_statics_of_the_mechanism_model`).

use nalgebra::{Vector3, Vector4};

use crate::{NonlinearState, State};

/// Forces, torques and end-effector displacement of the mechanism at equilibrium.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Statics {
    /// N, actuator forces A1, A2, A3 (compression negative).
    pub force: Vector3<f64>,
    /// N·m, torques in J3 about its axes (eq. 18).
    pub fq: Vector3<f64>,
    /// N·m, torques in J1, J2 (axes 11, 12, 21, 22; eq. 17).
    pub fw: Vector4<f64>,
    /// m, end-effector displacement from home.
    pub dx: Vector3<f64>,
}

impl Statics {
    /// The largest difference from `other` in each quantity: (N, N·m, N·m, m).
    pub fn max_difference(&self, other: &Statics) -> [f64; 4] {
        [
            (self.force - other.force).amax(),
            (self.fq - other.fq).amax(),
            (self.fw - other.fw).amax(),
            (self.dx - other.dx).amax(),
        ]
    }
}

impl From<&State> for Statics {
    fn from(s: &State) -> Self {
        Statics {
            force: s.force,
            fq: s.fq,
            fw: s.fw,
            dx: s.dx,
        }
    }
}

impl From<&NonlinearState> for Statics {
    fn from(s: &NonlinearState) -> Self {
        Statics {
            force: s.force,
            fq: s.fq,
            fw: s.fw,
            dx: s.dx,
        }
    }
}
