//! A model's step and an inverse step allocate nothing (they run inside control loops).
//!
//! The counting allocator is global, so this binary runs without libtest's harness
//! (`harness = false` in Cargo.toml): libtest's own threads would be counted too.

#![allow(clippy::unwrap_used)]

use std::alloc::System;

use cellinject_hysteresis::{Model, PrandtlIshlinskii, Preisach, Range, inverse_step};
use stats_alloc::{INSTRUMENTED_SYSTEM, Region, StatsAlloc};

#[global_allocator]
static GLOBAL: &StatsAlloc<System> = &INSTRUMENTED_SYSTEM;

fn main() {
    steps_and_inverse_steps_allocate_nothing();
    println!("steps_and_inverse_steps_allocate_nothing: ok");
}

fn steps_and_inverse_steps_allocate_nothing() {
    let range = Range {
        min: 0.0,
        max: 100.0,
    };
    let n = 12;
    let w: Vec<f64> = (0..n * (n + 1) / 2)
        .map(|k| 1e-7 * (1 + k % 3) as f64)
        .collect();
    let mut p = Preisach::new(range, n, 0.0, [1e-6, 0.0], w).unwrap();
    let mut pi = PrandtlIshlinskii::new(
        range,
        0.0,
        PrandtlIshlinskii::even_thresholds(8),
        vec![1e-6; 8],
        2e-7,
    )
    .unwrap();
    let region = Region::new(GLOBAL);
    for k in 0..500 {
        let v = 50.0 + 45.0 * (0.07 * k as f64).sin() * (0.01 * k as f64).cos();
        let y = p.apply(v);
        let u = inverse_step(&p, y * 0.99, range).unwrap_or(0.0);
        p.apply(u);
        let y2 = pi.apply(v);
        let _ = inverse_step(&pi, y2, range);
    }
    let stats = region.change();
    assert_eq!(
        (stats.allocations, stats.reallocations),
        (0, 0),
        "{stats:?}"
    );
}
