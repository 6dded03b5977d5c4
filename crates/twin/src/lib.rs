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
//! controllers only through the traits of `cellinject-hw`.

pub mod camera;
pub mod devices;
pub mod dynamics;
pub mod params;
pub mod piezo;
pub mod rng;
pub mod scene;
pub mod stage;
pub mod world;

pub use camera::{Microscope, TipPose};
pub use devices::{Devices, GuardedDevices, SharedTwin, Twin, devices, guarded_devices};
pub use params::TwinParams;
pub use world::{Snapshot, TwinError, World};
