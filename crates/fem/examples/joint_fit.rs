//! Re-runs the fit behind `configs/prototype.toml`'s `[structure]` joint dimensions:
//! one double-notched geometry whose 3-D FEM bending stiffness is 91.3 N·m/rad at a
//! 1.2 mm throat and 340.3 N·m/rad at 2.0 mm (the paper's J1/J2 and J3, Sec. 3.1).
//! Fillet radius (1 mm) and gap (2 mm) are kept; rod side and throat length are fitted.
//!
//! `cargo run --release -p cellinject-fem --example joint_fit [LEVEL [FILLET_M [GAP_M]]]`
//! (level 2: about a minute).

use cellinject_fem::joint3d::{DoubleNotch, JointMesh, fit_pair_observed};
use cellinject_flexure::Material;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let level: usize = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(2);
    let radius: f64 = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(1e-3);
    let gap: f64 = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(2e-3);
    let start = DoubleNotch {
        side: 13.2e-3,
        radius,
        flat: 2.6e-3,
        throat: 1.2e-3,
        gap,
    };
    let t = std::time::Instant::now();
    let f = fit_pair_observed(
        &start,
        [1.2e-3, 2.0e-3],
        [91.3, 340.3],
        &Material::x2crni18_9(),
        &JointMesh::default(),
        level,
        |s| {
            eprintln!(
                "fit it {}: flat {:.4e} b {:.4e} k {:.2} {:.2}",
                s.iteration, s.flat, s.side, s.k[0], s.k[1]
            )
        },
    )?;
    let j3 = cellinject_fem::joint3d::solve(
        &DoubleNotch {
            throat: 2.0e-3,
            ..f.joint
        },
        &Material::x2crni18_9(),
        &JointMesh::default(),
        level,
    )?;
    println!(
        "J3 stress per radian {:.1} GPa/rad: 9 mrad gives {:.0} MPa",
        j3.max_stress_per_rad()[1] * 1e-9,
        j3.max_stress_per_rad()[1] * 9e-3 * 1e-6
    );
    println!(
        "level {level}: side {:.4} mm, throat length {:.4} mm (fillet {:.2} mm, gap {:.2} mm): k = {:.2} and {:.2} N·m/rad after {} Newton steps, {:.1} s",
        f.joint.side * 1e3,
        f.joint.flat * 1e3,
        f.joint.radius * 1e3,
        f.joint.gap * 1e3,
        f.k[0],
        f.k[1],
        f.iterations,
        t.elapsed().as_secs_f64()
    );
    Ok(())
}
