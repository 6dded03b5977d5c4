//! Re-runs the fit behind `configs/prototype.toml`'s `[structure]` joint dimensions:
//! one double-notched geometry whose 3-D FEM bending stiffness is 91.3 N·m/rad at a
//! 1.2 mm throat and 340.3 N·m/rad at 2.0 mm (the paper's J1/J2 and J3, Sec. 3.1).
//! Fillet radius (1 mm) and gap (2 mm) are kept; rod side and throat length are fitted.
//!
//! `cargo run --release -p cellinject-fem --example joint_fit [LEVEL]` (level 2: about
//! a minute).

use cellinject_fem::joint3d::{DoubleNotch, JointMesh, fit_pair};
use cellinject_flexure::Material;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let level: usize = std::env::args()
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(2);
    let start = DoubleNotch {
        side: 13.2e-3,
        radius: 1e-3,
        flat: 2.6e-3,
        throat: 1.2e-3,
        gap: 2e-3,
    };
    let t = std::time::Instant::now();
    let f = fit_pair(
        &start,
        [1.2e-3, 2.0e-3],
        [91.3, 340.3],
        &Material::x2crni18_9(),
        &JointMesh::default(),
        level,
    )?;
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
