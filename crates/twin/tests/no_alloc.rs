//! A voltage command accepted by the guard and applied to the twin allocates nothing.
//!
//! The counting allocator is global, so this binary runs without libtest's harness
//! (`harness = false` in Cargo.toml): libtest's own threads would be counted too.

#![allow(clippy::unwrap_used)]

use std::alloc::System;

use cellinject_hw::PiezoChannel;
use cellinject_model::prototype;
use cellinject_twin::{Twin, TwinParams};
use stats_alloc::{INSTRUMENTED_SYSTEM, Region, StatsAlloc};

#[global_allocator]
static GLOBAL: &StatsAlloc<System> = &INSTRUMENTED_SYSTEM;

fn main() {
    guarded_voltage_commands_on_the_twin_allocate_nothing();
    println!("guarded_voltage_commands_on_the_twin_allocate_nothing: ok");
}

fn guarded_voltage_commands_on_the_twin_allocate_nothing() {
    let twin = Twin::new(&prototype(), TwinParams::default())
        .unwrap()
        .into_shared();
    let mut rig = cellinject_twin::rig(&twin).unwrap();
    let region = Region::new(GLOBAL);
    for k in 0..300 {
        rig.piezo[k % 3].set_voltage(0.3 * k as f64).unwrap();
        let _ = rig.piezo[k % 3].read_voltage().unwrap();
    }
    let stats = region.change();
    assert_eq!(
        (stats.allocations, stats.reallocations),
        (0, 0),
        "{stats:?}"
    );
}
