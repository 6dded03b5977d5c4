//! # cellinject-model
//!
//! The pseudo-rigid-body model of the cellinject micromanipulator (Chakarov et al.,
//! ICINCO 2012, Sec. 2): a 3-DOF serial-parallel structure in which body 1 hangs from
//! the universal flexure J3, piezo stacks A1 and A2 tilt it through the flexures J1 and
//! J2, and A3 drives the pipette along the body axis.
//!
//! - [`kinematics`]: nonlinear kinematics, loop closures and the Jacobians J, L, W
//!   (eqs. 5-7) obtained by differentiation at the home pose;
//! - [`tension`]: both pre-tensioning approaches with constant Jacobians (eqs. 14-33)
//!   and the margins they leave;
//! - [`nonlinear`]: the same equilibrium with the nonlinear kinematics, to measure the
//!   linearisation error.
//!
//! **Architecture invariant:** this crate is pure computation. It knows nothing of
//! files, time, devices or formats; every quantity is SI.
//!
//! ```
//! use cellinject_model::{Approach, Mechanism, prototype};
//! let m = Mechanism::new(&prototype()).unwrap();
//! let t = m.tension(Approach::DriveTranslation).unwrap();
//! assert!(t.tensioned.force[0] < 0.0); // the stacks are compressed
//! ```

pub mod design;
pub mod error;
pub mod kinematics;
pub mod nonlinear;
pub mod statics;
pub mod tension;

pub use design::{ACTUATOR_NAMES, Actuator, Design, Flexures, Geometry, TensionSpec};
pub use error::ModelError;
pub use kinematics::{ChainState, Jacobians, Kinematics, Pose};
pub use nonlinear::{ACCEPT as NONLINEAR_ACCEPT, Deviation, Linearisation, NonlinearState};
pub use statics::Statics;
pub use tension::{Approach, Assembly, Margins, Mechanism, State, Tension};

/// The parameters of the paper's prototype (Sec. 3.1 and eqs. 34-37, 44), for examples
/// and tests. Applications load `configs/prototype.toml` instead, which holds the same
/// values.
pub fn prototype() -> Design {
    let drive = Actuator {
        stiffness: Some(27e6),
        travel: 30e-6,
        push_capacity: 1000.0,
        torque_limit: 0.35,
    };
    Design {
        geometry: Geometry {
            a11: 0.007,
            a12: 0.066,
            a21: 0.007,
            a22: 0.066,
            b1: 0.030,
            b2: 0.180,
            actuator_azimuth: [0.0, std::f64::consts::FRAC_PI_2],
        },
        flexures: Flexures {
            j3: [340.3, 340.3],
            j1: [91.3, 91.3],
            j2: [91.3, 91.3],
        },
        actuators: [
            drive,
            drive,
            Actuator {
                stiffness: None,
                travel: 60e-6,
                ..drive
            },
        ],
        tension: TensionSpec {
            preload: [-100.0, -100.0],
            work_shift: [-30e-6, -30e-6],
        },
    }
}
