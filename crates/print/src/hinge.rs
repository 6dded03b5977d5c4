//! One flexure hinge's figures as text (`cellinject hinge`, `hinge-table`).

use cellinject_core::hinge::{HingeReport, Method, ProfileKind, TableRow};
use cellinject_fem::hinge2d::Plane;
use cellinject_flexure::Hinge;

use crate::table::Table;

/// `cellinject hinge`'s text: the hinge and the method, then its stiffnesses, stress
/// concentration, stress per radian and rotation at yield (and the FEM's convergence,
/// and the stress at a given angle, when computed).
pub fn hinge_text(kind: ProfileKind, hinge: &Hinge, method: Method, r: &HingeReport) -> String {
    let mut t = Table::new(&["quantity", "value", "unit"], &[false, true, false]);
    let mut row = |q: &str, v: String, u: &str| t.row(vec![q.into(), v, u.into()]);
    row(
        "compliant bending stiffness k_bend",
        format!("{:.4}", r.k_bend),
        "N·m/rad",
    );
    row(
        "off-axis bending stiffness",
        format!("{:.4}", r.k_bend_off),
        "N·m/rad",
    );
    row(
        "torsional stiffness",
        format!("{:.4}", r.k_torsion),
        "N·m/rad",
    );
    row("axial stiffness", format!("{:.4e}", r.k_axial), "N/m");
    row(
        "stress concentration K_t",
        format!("{:.4}", r.stress_concentration),
        "",
    );
    row(
        "throat stress per radian",
        format!("{:.2}", r.max_stress_per_rad * 1e-6),
        "MPa/rad",
    );
    row(
        "rotation at yield",
        format!("{:.4}", r.max_rotation * 1e3),
        "mrad",
    );
    if let Some(c) = &r.fem {
        let levels: Vec<String> = c.k_bend_levels.iter().map(|k| format!("{k:.4}")).collect();
        row("FEM k_bend at levels 1, 2, 4", levels.join(", "), "N·m/rad");
        row(
            "FEM mesh error (last refinement)",
            format!("{:.2e}", c.mesh_error),
            "",
        );
        row(
            "FEM unknowns (finest)",
            format!("{}", c.unknowns.last().copied().unwrap_or(0)),
            "",
        );
        row("beam / FEM", format!("{:.4}", c.beam_over_fem), "");
    }
    if let (Some(th), Some(s)) = (r.angle, r.stress) {
        row(
            "stress at --angle",
            format!("{:.2} at {:.3} mrad", s * 1e-6, th * 1e3),
            "MPa",
        );
        row(
            "safety factor against yield",
            r.safety_factor
                .map_or("unloaded".into(), |sf| format!("{sf:.2}")),
            "",
        );
    }
    format!(
        "{kind:?} hinge, t = {} mm, b = {} mm, L = {} mm ({})\n{}",
        hinge.thickness * 1e3,
        hinge.width * 1e3,
        r.length * 1e3,
        match method {
            Method::Beam => "beam integral",
            Method::PwSimple => "simplified Paros-Weisbord",
            Method::Fem(_) => "2-D FEM for k_bend, beam integrals for the rest",
        },
        t.text()
    )
}

/// `cellinject hinge-table`'s text: circular notches of radius `radius` from thin to
/// thick, the beam integral, simplified Paros-Weisbord and the FEM side by side.
pub fn table_text(radius: f64, width: f64, youngs: f64, plane: Plane, rows: &[TableRow]) -> String {
    let head = format!(
        "Circular notch, R = {} mm, b = {} mm, E = {} GPa, plane {}: compliant stiffness, N·m/rad\n",
        radius * 1e3,
        width * 1e3,
        youngs * 1e-9,
        match plane {
            Plane::Stress => "stress",
            Plane::Strain => "strain",
        }
    );
    let mut t = Table::new(
        &[
            "t/R",
            "beam integral",
            "PW simplified",
            "FEM",
            "beam/FEM",
            "PW/FEM",
            "FEM mesh error",
        ],
        &[true; 7],
    );
    for r in rows {
        t.row(vec![
            format!("{}", r.t_over_r),
            format!("{:.4}", r.k_beam),
            format!("{:.4}", r.k_pw_simple),
            format!("{:.4}", r.k_fem),
            format!("{:.4}", r.beam_over_fem),
            format!("{:.4}", r.pw_over_fem),
            format!("{:.1e}", r.fem_mesh_error),
        ]);
    }
    head + &t.text()
}
