//! # cellinject-sensapex
//!
//! Sensapex devices over SMCP1, Sensapex's micromanipulator control protocol (UDP,
//! port 55555 + group): the framing ([`protocol`]), the client link with libum's
//! retransmissions and timeouts ([`link`]), the devices behind the hardware traits
//! ([`devices`]) and a device emulator ([`emulator`]) that Sensapex's own client
//! library drives.
//!
//! **Architecture invariant:** this crate never depends on the twin: it knows SMCP1
//! and the hardware traits, nothing of the mechanism.

pub mod devices;
pub mod emulator;
pub mod link;
pub mod protocol;

pub use devices::{LensChanger, Model, Positioner, PressureChannel, SharedLink};
pub use link::{Link, SensapexError};
pub use protocol::{Frame, FrameError, SubBlock};
