//! A control step allocates nothing: the controller's law, its hysteresis inverse and
//! the rig's safety projection (`Rig::command_tilt`), for every controller, through
//! camera measurements, rejected frames and saturation.
//!
//! The counting allocator is global, so this binary runs without libtest's harness
//! (`harness = false` in Cargo.toml): libtest's own threads allocate while a test runs,
//! which once counted 4 stray allocations against the first controller in CI.

#![allow(clippy::unwrap_used)]

use std::alloc::System;

use cellinject_control::{
    Cascade, Controller, Feedforward, Measurement, Open, SensorGains, SensorLoop, Stacks, Vision,
};
use cellinject_hysteresis::{AnyModel, LogCreep, Preisach, Range};
use cellinject_model::{Approach, prototype};
use cellinject_rig::{Rig, RigParams, fake};
use stats_alloc::{INSTRUMENTED_SYSTEM, Region, StatsAlloc};

#[global_allocator]
static GLOBAL: &StatsAlloc<System> = &INSTRUMENTED_SYSTEM;

fn preisach() -> AnyModel {
    let n = 12;
    let w: Vec<f64> = (0..n * (n + 1) / 2)
        .map(|k| 8e-8 * (1 + k % 3) as f64)
        .collect();
    let range = Range {
        min: 0.0,
        max: 100.0,
    };
    AnyModel::Preisach(Preisach::new(range, n, 0.0, [20e-6, 0.0], w).unwrap())
}

fn main() {
    control_steps_allocate_nothing();
    println!("control_steps_allocate_nothing: ok");
}

fn control_steps_allocate_nothing() {
    let stacks = Stacks {
        gain: [0.3e-6; 2],
        v_max: [100.0; 2],
    };
    let creep = LogCreep::new(0.015, 1e-3).unwrap();
    let ff = || Feedforward::new(stacks, [preisach(), preisach()], [Some(creep); 2]).unwrap();
    let mut controllers: Vec<Box<dyn Controller>> = vec![
        Box::new(Open::new(stacks).unwrap()),
        Box::new(ff()),
        Box::new(SensorLoop::new(ff(), SensorGains::default()).unwrap()),
        Box::new(
            Cascade::new(
                SensorLoop::new(ff(), SensorGains::default()).unwrap(),
                [[-5.9, 0.0], [0.0, -5.9]],
                0.6,
                3e-6,
            )
            .unwrap(),
        ),
    ];
    let p = RigParams {
        approach: Approach::DriveTranslation,
        ..RigParams::default()
    };
    let (devices, log) = fake::devices(&p);
    let mut rig = Rig::new(devices, &prototype(), &p).unwrap();
    fake::records(&log).reserve(100_000);
    for c in &mut controllers {
        let region = Region::new(GLOBAL);
        for k in 0..2000 {
            let t = k as f64 * 1e-3;
            // Steps, a ramp past the envelope (saturation), frames and lost frames.
            let r = if k < 1000 {
                1e-6
            } else {
                1e-6 + 30e-9 * (k - 1000) as f64
            };
            let vision = match k % 33 {
                0 => Vision::Tip([-5.8e-6, -6.1e-6]),
                16 => Vision::Rejected,
                _ => Vision::Nothing,
            };
            let m = Measurement {
                frame_reference: None,
                stacks: Some([0.97 * r, 1.02 * r]),
                vision,
            };
            let v = c.step(t, [r, r], &m);
            let applied = rig.command_tilt(v).unwrap();
            c.applied(applied);
        }
        let stats = region.change();
        assert_eq!(
            (stats.allocations, stats.reallocations),
            (0, 0),
            "{:?}: {stats:?}",
            c.kind()
        );
    }
}
