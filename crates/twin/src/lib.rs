//! # cellinject-twin
//!
//! The digital twin of the micromanipulator: the default backend of every cellinject
//! command. It simulates the three piezo stacks (amplifier, hysteresis, creep), the
//! mechanism's dynamics built on the pseudo-rigid-body model of `cellinject-model`, the
//! spherical joints' stick-slip, the macro stage, the injector and the microscope
//! camera, on a simulated clock, deterministically for a given seed.
//!
//! **Architecture invariant:** the twin is pure simulation. Its only notion of time is
//! the simulated clock; it opens no files and talks to no device. It is reached by
//! controllers only through the traits of `cellinject-hw`, as a backend of
//! `cellinject-rig` ([`TwinBackend`]).

pub mod biology;
pub mod camera;
pub mod devices;
pub mod dynamics;
pub mod piezo;
pub mod scene;
pub mod stage;
pub mod surface;
pub mod world;

/// The twin's random generator (crate `cellinject-numeric`).
pub use cellinject_numeric::rng;
/// The twin's simulation-only parameters (crate `cellinject-simparams`).
pub use cellinject_simparams as params;

pub use biology::{Biology, CellState, Death, Fault, FaultAt, FaultKind, FaultSpecError};
pub use camera::{CellLook, Grid, Microscope, PipetteView, TipPose};
pub use devices::{
    SharedTwin, Twin, TwinBackend, TwinCamera, TwinParams, View, devices, dyn_rig, guarded, rig,
};
pub use surface::PlateSurface;
pub use world::{Snapshot, TwinError, World};
