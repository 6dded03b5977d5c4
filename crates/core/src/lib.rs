//! # cellinject-core
//!
//! The library core behind every cellinject front end (the command line today; the
//! injection workflow, the PI driver's tools and the web dashboard next). Each command
//! is one function here that takes plain inputs (a design, images already decoded,
//! a guarded [`cellinject_rig::Rig`] over any backend) and returns a typed report that
//! derives `serde::Serialize`: that serialisation *is* the command's JSON, documented
//! field by field (with units) on each report type and in `docs/json.md`.
//!
//! | command | function | report |
//! |---|---|---|
//! | `tension` | [`tension::tension`] | [`tension::TensionReport`] |
//! | `model` | [`model::model`] | [`model::ModelReport`] |
//! | `reproduce` | [`reproduce::reproduce`] | [`reproduce::ReproduceReport`] |
//! | `hinge` | [`hinge::hinge`] | [`hinge::HingeReport`] |
//! | `hinge-table` | [`hinge::table`] | [`hinge::TableRow`] (a list) |
//! | `dic` | [`dic::points`] | [`dic::PointReport`] (a list) |
//! | `dic field` | [`dic::field_report`] | [`dic::FieldReport`] |
//! | `sim loop` | [`sim::hysteresis_loop`] | [`sim::LoopReport`] |
//! | `sim step` | [`sim::step_response`] | [`sim::StepReport`] |
//! | `hysteresis identify / fit / invert` | [`hysteresis::identify`], [`hysteresis::fit`], [`hysteresis::invert`] | [`hysteresis::IdentifyReport`], [`hysteresis::FitReport`], [`hysteresis::InvertReport`] |
//! | `calibrate pixels / jacobian / hysteresis` | [`calibrate::pixels`], [`calibrate::jacobian`], [`calibrate::hysteresis`] | [`calibrate::PixelCalibration`], [`calibrate::JacobianCalibration`], [`calibrate::HysteresisCalibration`] |
//! | `experiment range` | [`experiment::range`] | [`experiment::RangeReport`] |
//! | `experiment repeatability` | [`experiment::repeatability`] | [`experiment::RepeatabilityReport`] |
//! | `experiment tracking` | [`experiment::tracking`] | [`experiment::TrackingReport`] |
//! | `plate detect` | [`cells::detect_and_score`] | [`cells::DetectionReport`] |
//! | `fea ...` | crate `cellinject-fea` | its reports |
//!
//! **Architecture invariant:** no IO: no files, no terminal, no environment. Front ends
//! read and write; this crate computes and validates, and its errors name the argument
//! or key at fault.

pub mod bench;
pub mod calibrate;
pub mod cells;
pub mod dic;
pub mod experiment;
pub mod hinge;
pub mod hysteresis;
pub mod inject;
pub mod model;
pub mod reproduce;
pub mod sim;
pub mod table;
pub mod tension;
pub mod vision;
