//! The `cellinject` binary's integration tests, in one test binary: one link instead
//! of fifteen, and one pool of test threads, so the tests that wait on the wall clock
//! (the GCS emulator, pytest, the browser) overlap with the ones that keep a core busy.
//! A suite runs alone with its module's name: `cargo test -p cellinject --test it run::`.
//! (`camera.rs` beside this directory stays its own binary: CI builds it a second time
//! with the `genicam` feature.)

#[path = "../common/mod.rs"]
mod common;

mod architecture;
mod chain;
mod cli;
mod control;
mod dashboard;
mod design;
mod experiment;
mod files;
mod gcs;
mod golden;
mod hysteresis;
mod no_panic;
mod plate;
mod python;
mod run;
mod tidy;
mod vision;
