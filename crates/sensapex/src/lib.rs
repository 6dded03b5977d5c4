//! # cellinject-sensapex
//!
//! Sensapex devices over SMCP1, Sensapex's micromanipulator control protocol (UDP,
//! port 55555 + group): the framing ([`protocol`]) and a device emulator
//! ([`emulator`]) that Sensapex's own client library drives.
//!
//! **Architecture invariant:** this crate never depends on the twin: it knows SMCP1
//! and the hardware traits, nothing of the mechanism.

pub mod emulator;
pub mod protocol;

pub use protocol::{Frame, FrameError, SubBlock};
