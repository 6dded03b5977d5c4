//! 3-D FEM speed. Target (issue 5): a 3-D hinge of about 100,000 unknowns solved in
//! under 5 s on this 2-core machine (assembly, nested-dissection sparse Cholesky,
//! six load cases, refinement, stresses).

#![allow(missing_docs, clippy::unwrap_used)]

use std::hint::black_box;

use cellinject_fem::joint3d::{DoubleNotch, JointMesh, solve};
use cellinject_flexure::Material;
use criterion::{Criterion, criterion_group, criterion_main};

/// The prototype's J1/J2 (configs/prototype.toml [structure]).
fn joint() -> DoubleNotch {
    DoubleNotch {
        side: 13.99e-3,
        radius: 2e-3,
        flat: 2.31e-3,
        throat: 1.2e-3,
        gap: 2e-3,
    }
}

/// A mesh of about 100,000 unknowns for that joint.
fn mesh_100k() -> JointMesh {
    JointMesh {
        across: 6,
        notch: 22,
        block: 4,
        gap: 3,
        grading: 1.4,
    }
}

fn hinge(c: &mut Criterion) {
    let m = Material::x2crni18_9();
    let (j, mesh) = (joint(), mesh_100k());
    let n = mesh.unknowns(&j, 1);
    let s = solve(&j, &m, &mesh, 1).unwrap();
    println!(
        "3-D double-notched joint: {n} unknowns, {} elements, k = {:.2} / {:.2} N·m/rad, backward error {:.1e}",
        s.elements, s.k_bend[0], s.k_bend[1], s.residual
    );
    let mut g = c.benchmark_group("joint3d");
    g.sample_size(10);
    g.bench_function(format!("solve, {n} unknowns"), |b| {
        b.iter(|| solve(black_box(&j), &m, &mesh, 1).unwrap())
    });
    let small = JointMesh::default();
    let n1 = small.unknowns(&j, 1);
    g.bench_function(
        format!("solve, default mesh level 1 ({n1} unknowns)"),
        |b| b.iter(|| solve(black_box(&j), &m, &small, 1).unwrap()),
    );
    g.finish();
}

criterion_group!(benches, hinge);
criterion_main!(benches);
