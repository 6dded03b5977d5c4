//! The structural model's reports as text (`cellinject fea`, `fea modes`, `fea tables`,
//! `fea joints`) and the drawing of a solved structure.

use std::fmt::Write as _;
use std::path::Path;

use cellinject_fea::{Approach, JointsReport, Member, ModesReport, SolveReport, TablesReport};
use cellinject_plot::contour::{Member as PlotMember, StructurePanel};

use crate::table::Table;

/// `cellinject fea`'s text for one load case: the end-effector's displacement, the
/// stack forces, each joint's stress against yield, and where the drawing went.
pub fn case_text(r: &SolveReport, plot: Option<&Path>) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Structural model, approach {}: F11 = {} N, F12 = {} N (joints: 3-D FEM level {}, J1/J2 {:.1} N·m/rad, J3 {:.1} N·m/rad)",
        r.approach,
        r.forces[0],
        r.forces[1],
        r.mesh_level,
        r.joint_k_bend.j1_j2[1],
        r.joint_k_bend.j3[1]
    );
    let _ = writeln!(
        out,
        "end-effector  δx {:9.2} µm   δy {:9.2} µm   δz {:9.3} µm",
        r.dx * 1e6,
        r.dy * 1e6,
        r.dz * 1e6
    );
    let _ = writeln!(
        out,
        "stack forces  A1 {:8.3} N   A2 {:8.3} N",
        r.stack_force[0], r.stack_force[1]
    );
    let mut t = Table::new(
        &[
            "joint",
            "max von Mises [MPa]",
            "yield [MPa]",
            "safety factor",
        ],
        &[false, true, true, true],
    );
    for j in &r.joints {
        t.row(vec![
            j.name.to_string(),
            format!("{:.1}", j.max_von_mises * 1e-6),
            format!("{:.0}", r.yield_strength * 1e-6),
            j.safety_factor
                .map_or("unloaded".to_string(), |f| format!("{f:.2}")),
        ]);
    }
    out.push_str(&t.text());
    for j in &r.joints {
        if let Some(sf) = j.safety_factor.filter(|f| *f < 1.0) {
            let _ = writeln!(
                out,
                "warning: {} is past its yield strength here (safety factor {:.2}, at ({:.2}, {:.2}, {:.2}) mm in the joint)",
                j.name,
                sf,
                j.at[0] * 1e3,
                j.at[1] * 1e3,
                j.at[2] * 1e3
            );
        }
    }
    out.push_str(&warnings_text(&r.warnings));
    if let Some(p) = plot {
        let _ = writeln!(out, "plot: {}", p.display());
    }
    out
}

/// `cellinject fea modes`: each natural mode's frequency, what moves and the tip's
/// motion.
pub fn modes_text(r: &ModesReport) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Natural modes, approach {} pre-tensioned at F10 = {:?} N (sliders locked, joints from the 3-D FEM level {})",
        r.approach, r.preload, r.mesh_level
    );
    let mut t = Table::new(
        &[
            "mode",
            "frequency [Hz]",
            "mostly",
            "tip motion [µm] per 1 µm or µrad of it",
        ],
        &[true, true, false, false],
    );
    for (i, mode) in r.modes.iter().enumerate() {
        t.row(vec![
            (i + 1).to_string(),
            format!("{:.1}", mode.frequency),
            mode.description.clone(),
            format!(
                "({:+.4}, {:+.4}, {:+.4})",
                mode.tip_shape[0] * 1e6,
                mode.tip_shape[1] * 1e6,
                mode.tip_shape[2] * 1e6
            ),
        ]);
    }
    out.push_str(&t.text());
    out.push_str(&warnings_text(&r.warnings));
    out
}

/// `cellinject fea tables`: the model against the paper's CAD FEA tables (Sec. 3.3),
/// with the largest difference and the cross-axis coupling.
pub fn tables_text(r: &TablesReport) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Whole-manipulator model against the paper's CAD FEA (Sec. 3.3); joints from the 3-D FEM level {} (J1/J2 {:.1}, J3 {:.1} N·m/rad)",
        r.mesh_level, r.joint_k_bend.j1_j2[1], r.joint_k_bend.j3[1]
    );
    for tr in &r.tables {
        let _ = writeln!(out, "\nTable {} (approach {}):", tr.table, tr.approach);
        let mut t = Table::new(
            &[
                "F11, F12 [N]",
                "δx paper [µm]",
                "δx model [µm]",
                "δy paper [µm]",
                "δy model [µm]",
                "δz model [µm]",
                "min safety (joint)",
            ],
            &[false, true, true, true, true, true, false],
        );
        for c in &tr.cases {
            let weakest = c
                .weakest()
                .and_then(|j| j.safety_factor.map(|f| (j.name, f)));
            t.row(vec![
                format!("{}, {}", c.f11, c.f12),
                format!("{:.1}", c.paper.dx * 1e6),
                format!("{:.1}", c.dx * 1e6),
                format!("{:.1}", c.paper.dy * 1e6),
                format!("{:.1}", c.dy * 1e6),
                format!("{:.2}", c.dz * 1e6),
                weakest.map_or("unloaded".to_string(), |(name, sf)| {
                    format!("{sf:.2} ({name})")
                }),
            ]);
        }
        out.push_str(&t.text());
        let _ = writeln!(
            out,
            "largest difference {:.2} µm = {:.2} % of the largest displacement {:.1} µm (acceptance 3 %)",
            tr.worst_difference * 1e6,
            100.0 * tr.worst_difference / tr.largest_paper_displacement,
            tr.largest_paper_displacement * 1e6
        );
        let _ = writeln!(
            out,
            "cross-axis coupling (δx from raising F12 alone): model {:+.3} µm, paper {:+.1} µm",
            tr.coupling_x * 1e6,
            tr.paper_coupling_x * 1e6
        );
    }
    out.push_str(&warnings_text(&r.warnings));
    out
}

/// `cellinject fea joints`: each joint's bending stiffness by level against the
/// paper's.
pub fn joints_text(r: &JointsReport) -> String {
    let mut out = String::new();
    let g = &r.geometry;
    let _ = writeln!(
        out,
        "Double-notched joints by 3-D FEM: rod {:.2} mm square, fillets {:.2} mm, throat length {:.2} mm, gap {:.2} mm",
        g.side * 1e3,
        g.radius * 1e3,
        g.flat * 1e3,
        g.gap * 1e3
    );
    let mut t = Table::new(
        &[
            "joint",
            "Δ [mm]",
            "level",
            "unknowns",
            "k about x",
            "k about y",
            "paper",
            "difference",
            "σ/θ [GPa/rad]",
        ],
        &[false, true, true, true, true, true, true, true, true],
    );
    for row in &r.joints {
        for l in &row.levels {
            t.row(vec![
                row.joint.to_string(),
                format!("{:.2}", row.throat * 1e3),
                l.level.to_string(),
                l.dofs.to_string(),
                format!("{:.2}", l.k_bend[0]),
                format!("{:.2}", l.k_bend[1]),
                format!("{:.1}", row.paper_k_bend),
                format!("{:+.2} %", 100.0 * (l.k_bend[1] / row.paper_k_bend - 1.0)),
                format!("{:.1}", l.max_stress_per_rad[1] * 1e-9),
            ]);
        }
    }
    out.push_str(&t.text());
    let _ = writeln!(
        out,
        "stiffness in N·m/rad; the paper's acceptance: within 3 %"
    );
    out
}

/// A line `warning: ...` for each warning.
pub fn warnings_text(w: &[String]) -> String {
    w.iter().map(|w| format!("warning: {w}\n")).collect()
}

/// The drawing of a solved structure: the effective displacements δx (x-z plane) and
/// δy (y-z plane), each member at rest and displaced, magnified so that the largest
/// displacement reads as 8 % of the body's length.
pub fn structure_panels(members: &[Member], approach: Approach) -> [StructurePanel; 2] {
    let big = members
        .iter()
        .flat_map(|m| m.rest.iter().zip(&m.displaced).map(|(r, d)| (d - r).norm()))
        .fold(0.0, f64::max);
    // Magnify so that the largest displacement reads as 8 % of the body's length.
    let gain = if big > 0.0 { 0.08 * 0.2 / big } else { 1.0 };
    let panel = |axis: usize, title: &str, label: &str| StructurePanel {
        title: format!(
            "{title} (approach {}, deformation ×{gain:.0})",
            approach.number()
        ),
        x_label: format!("{} [mm]", ["x", "y"][axis]),
        y_label: "z [mm]".into(),
        value_label: label.into(),
        members: members
            .iter()
            .map(|m| PlotMember {
                name: m.name.to_string(),
                rest: m.rest.iter().map(|p| (p[axis] * 1e3, p[2] * 1e3)).collect(),
                displaced: m
                    .rest
                    .iter()
                    .zip(&m.displaced)
                    .map(|(r, d)| {
                        let p = r + (d - r) * gain;
                        (p[axis] * 1e3, p[2] * 1e3)
                    })
                    .collect(),
                values: m
                    .rest
                    .iter()
                    .zip(&m.displaced)
                    .map(|(r, d)| (d - r)[axis] * 1e6)
                    .collect(),
                width: if m.name.starts_with('J') { 5 } else { 8 },
            })
            .collect(),
    };
    [
        panel(0, "effective displacement δx, x-z plane", "δx [µm]"),
        panel(1, "effective displacement δy, y-z plane", "δy [µm]"),
    ]
}
