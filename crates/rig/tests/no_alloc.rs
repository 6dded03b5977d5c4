//! An accepted guarded command allocates nothing (the control loop will run at kHz
//! rates); a refused one may (it builds its message only then).
//!
//! The counting allocator is global, so this binary runs without libtest's harness
//! (`harness = false` in Cargo.toml): libtest's own threads would be counted too.

#![allow(clippy::unwrap_used)]

use std::alloc::System;

use cellinject_hw::{Injector, Optics, PiezoChannel, Stage};
use cellinject_model::{Approach, prototype};
use cellinject_rig::{Rig, RigParams, fake};
use stats_alloc::{INSTRUMENTED_SYSTEM, Region, StatsAlloc};

#[global_allocator]
static GLOBAL: &StatsAlloc<System> = &INSTRUMENTED_SYSTEM;

fn main() {
    accepted_commands_allocate_nothing();
    println!("accepted_commands_allocate_nothing: ok");
}

fn accepted_commands_allocate_nothing() {
    for approach in [Approach::DriveTranslation, Approach::JointDeflection] {
        let rig_params = RigParams {
            approach,
            ..RigParams::default()
        };
        let (devices, log) = fake::devices(&rig_params);
        let mut rig = Rig::new(devices, &prototype(), &rig_params).unwrap();
        // The fake logs into a Vec: give it room first so that only the guard is measured.
        fake::records(&log).reserve(1000);
        let region = Region::new(GLOBAL);
        for k in 0..200 {
            let v = 0.25 * k as f64;
            rig.piezo[k % 3].set_voltage(v).unwrap();
        }
        rig.stage.move_to(1, 1e-3).unwrap();
        rig.injector.pulse(1e5, 0.01).unwrap();
        rig.optics.set_zoom(5.0).unwrap();
        let stats = region.change();
        assert_eq!(
            (stats.allocations, stats.reallocations),
            (0, 0),
            "approach {}: {stats:?}",
            approach.number()
        );
        // A refusal is allowed to allocate its message, but is still refused.
        assert!(rig.piezo[0].set_voltage(1e3).is_err());
        assert_eq!(fake::records(&log).len(), 203);
    }
}
