//! # cellinject-rig
//!
//! The physical bench, whatever drives it. [`RigParams`] describes it (how the
//! structure was pre-tensioned, amplifier ranges, safety margins, stage travel, the
//! injector's pressure limit, the zoom range); [`Rig`] wraps the devices of any
//! [`Backend`] (the digital twin, a real controller, a test fake) in the safety guards
//! of [`guard`], so that the same controller, program or front end runs on all of
//! them; [`programs`] are stimulus programs over any amplifier channel.
//!
//! **Architecture invariant:** this crate never depends on the twin or on a driver;
//! backends depend on it. It does no IO and keeps no time of its own.
//!
//! **Architecture invariant:** an accepted guarded command allocates nothing (a test
//! counts allocations).

pub mod fake;
pub mod guard;
pub mod params;
pub mod pipette;
pub mod programs;
mod rig;

pub use guard::{PiezoEnvelope, SharedGuard};
pub use params::RigParams;
pub use pipette::PipetteParams;
pub use rig::{Backend, Devices, DynBackend, Rig, RigError, envelope};
