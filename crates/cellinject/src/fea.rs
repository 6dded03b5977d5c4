//! `cellinject fea`: the whole-manipulator structural model with joints from the 3-D FEM.

use std::path::PathBuf;

use anyhow::{Context, Result};
use cellinject_config::Description;
use cellinject_fem::joint3d::{self, DoubleNotch, JointMesh, JointSolution};
use cellinject_flexure::Material;
use cellinject_model::Approach;
use cellinject_paper as paper;
use cellinject_plot::contour::{Member as PlotMember, StructurePanel, structure_svg};
use cellinject_structure::{
    Equilibrium, JointModel, Preload, Structure, StructureParams, StructureSpec,
};
use clap::{Args, Subcommand};
use nalgebra::Vector6;
use serde_json::{Value, json};

use crate::output::{Table, write_atomic};
use crate::{Format, InputError};

/// `cellinject fea`: one load case, or a subcommand.
#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct FeaArgs {
    #[command(subcommand)]
    command: Option<FeaCommand>,
    #[command(flatten)]
    solve: SolveArgs,
}

/// How the structural model is built: the joints' mesh level and approach 2's preload.
#[derive(Debug, Clone, Copy, Args)]
pub struct MeshArgs {
    /// Refinement level of the joints' 3-D FEM (1: 25k unknowns per joint, under a
    /// second; 2: 184k, about ten seconds, 1-2 % stiffer results converged).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=3))]
    level: u8,
    /// Approach 2's pre-tension of J3 in the model.
    #[arg(long, value_enum, default_value_t = PreloadArg::Deflection)]
    preload: PreloadArg,
}

/// One static load case.
#[derive(Debug, Args)]
pub struct SolveArgs {
    /// Pre-tensioning approach: 1 (assembly translation, the forces alone) or 2 (J3
    /// assembled pre-deflected by the model's Δq0).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
    approach: Option<u8>,
    /// Forces on the ends of the motor loops A1-J1 and A2-J2, N (negative: compressive),
    /// as the paper's F11,F12.
    #[arg(long, value_name = "F11,F12", value_parser = parse_forces, allow_hyphen_values = true)]
    forces: Option<[f64; 2]>,
    /// Also draw the deformed structure coloured by displacement (SVG), like Fig. 4.
    #[arg(long, value_name = "FILE.svg")]
    plot: Option<PathBuf>,
    #[command(flatten)]
    mesh: MeshArgs,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
}

/// `fea` subcommands.
#[derive(Debug, Subcommand)]
pub enum FeaCommand {
    /// Natural frequencies and mode shapes of the assembled manipulator.
    Modes {
        /// Pre-tensioning approach (default: the twin's).
        #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
        approach: Option<u8>,
        /// How many modes to list.
        #[arg(long, default_value_t = 8)]
        count: usize,
        #[command(flatten)]
        mesh: MeshArgs,
        /// Output format.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// The paper's Tables 1 and 2 recomputed, with the cross-axis coupling and the
    /// joints' stresses against the yield strength.
    Tables {
        #[command(flatten)]
        mesh: MeshArgs,
        /// Output format.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// The double-notched joints' stiffness from the 3-D FEM against the paper's.
    Joints {
        /// Mesh levels to solve (convergence).
        #[arg(long, value_delimiter = ',', default_values_t = [1u8, 2])]
        levels: Vec<u8>,
        /// Output format.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
}

fn parse_forces(s: &str) -> Result<[f64; 2], String> {
    let parts: Vec<&str> = s.split(',').collect();
    let bad = || format!("expected F11,F12 in newtons, got `{s}`");
    if parts.len() != 2 {
        return Err(bad());
    }
    let mut out = [0.0f64; 2];
    for (o, p) in out.iter_mut().zip(&parts) {
        *o = p.trim().parse().map_err(|_| bad())?;
        if !o.is_finite() {
            return Err(bad());
        }
    }
    Ok(out)
}

/// The joints of a description, solved by the 3-D FEM.
struct Joints {
    j12: JointSolution,
    j3: JointSolution,
    level: usize,
}

fn notch(p: &StructureParams, throat: f64) -> DoubleNotch {
    DoubleNotch {
        side: p.joint.side,
        radius: p.joint.radius,
        flat: p.joint.flat,
        throat,
        gap: p.joint.gap,
    }
}

fn material() -> Material {
    Material::x2crni18_9()
}

fn solve_joints(d: &Description, level: usize) -> Result<Joints> {
    let p = &d.structure;
    let m = material();
    let mesh = JointMesh::default();
    let solve = |t: f64, key: &str| {
        joint3d::solve(&notch(p, t), &m, &mesh, level)
            .map_err(|e| InputError(format!("structure.{key}: joint FEM failed: {e}")))
    };
    Ok(Joints {
        j12: solve(p.throat_j12, "throat_J12")?,
        j3: solve(p.throat_j3, "throat_J3")?,
        level,
    })
}

fn joint_model(s: &JointSolution, key: &str) -> Result<JointModel> {
    let stiffness = JointModel::stiffness_of(&s.block_compliance).ok_or_else(|| {
        InputError(format!(
            "structure.{key}: the joint's compliance is not positive definite"
        ))
    })?;
    let l = s.layout;
    Ok(JointModel {
        stiffness,
        lower_end: s.block_sections[0],
        lower_notch: l.notch_a,
        upper_notch: l.notch_b,
        upper_end: s.block_sections[1],
    })
}

fn structure(d: &Description, j: &Joints) -> Result<Structure> {
    let j12 = joint_model(&j.j12, "throat_J12")?;
    let spec = StructureSpec {
        j3: joint_model(&j.j3, "throat_J3")?,
        j12: [j12, j12],
        mass: d.structure.mass,
    };
    Structure::new(&d.design, &spec).map_err(|e| InputError(format!("structure: {e}")).into())
}

/// How approach 2's pre-tension of J3 enters the structural model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PreloadArg {
    /// J3 assembled pre-deflected, by the approach's design rule (the stacks carry F10
    /// with the drives at their home length) applied to this model's stiffness.
    Deflection,
    /// The paper's CAD set-up (Sec. 3.3.2): J3 straight and the torques of eq. (53) on
    /// body 1. The net moment on body 1 is then a 0.1 % difference of 3 N·m terms, so
    /// the offset of the first case is ill-conditioned.
    Torque,
}

/// The structure's preload for an approach. Approach 2: J3's assembly deflection by
/// the approach's design rule (the stacks carry F10 with the drives at home length),
/// applied to this model's own stiffness, from the pseudo-rigid-body Δq0 (eq. 31); or
/// the paper's torques (eq. 53).
fn preload(
    d: &Description,
    s: &Structure,
    approach: Approach,
    kind: PreloadArg,
) -> Result<Preload> {
    Ok(match approach {
        Approach::DriveTranslation => Preload::Translation,
        Approach::JointDeflection => {
            let t = d.mechanism().tension(approach)?;
            if kind == PreloadArg::Torque {
                let fq = t.tensioned.fq;
                return Ok(Preload::Torque {
                    moment: [-fq[0], -fq[1]],
                });
            }
            let dq0 = t.dq0.unwrap_or_default();
            let dq0 = s
                .deflection_for(d.design.tension.preload, [dq0[0], dq0[1]])
                .context("approach 2's assembly deflection of J3")?;
            Preload::Deflection { dq0 }
        }
    })
}

/// Stresses of the three joints at an equilibrium: (name, von Mises Pa, safety factor).
fn stresses(j: &Joints, eq: &Equilibrium) -> Vec<(&'static str, f64, f64, [f64; 3])> {
    let y = material().yield_strength;
    ["J3", "J1", "J2"]
        .iter()
        .enumerate()
        .map(|(i, &name)| {
            let sol = if i == 0 { &j.j3 } else { &j.j12 };
            let w: Vector6<f64> = eq.joint_wrench[i];
            let (s, at) = sol.peak_von_mises_block(&w);
            (name, s, y / s, at)
        })
        .collect()
}

fn approach_arg(n: Option<u8>, d: &Description) -> Approach {
    n.and_then(Approach::from_number).unwrap_or(d.twin.approach)
}

/// Runs `fea`.
pub fn run(d: &Description, a: &FeaArgs) -> Result<()> {
    match &a.command {
        Some(FeaCommand::Modes {
            approach,
            count,
            mesh,
            format,
        }) => modes(d, approach_arg(*approach, d), *count, mesh, *format),
        Some(FeaCommand::Tables { mesh, format }) => tables(d, mesh, *format),
        Some(FeaCommand::Joints { levels, format }) => joints(d, levels, *format),
        None => solve_case(d, &a.solve),
    }
}

fn solve_case(d: &Description, a: &SolveArgs) -> Result<()> {
    let approach = a
        .approach
        .and_then(Approach::from_number)
        .ok_or_else(|| InputError("fea: --approach 1|2 is required".into()))?;
    let forces = a.forces.ok_or_else(|| {
        InputError("fea: --forces F11,F12 is required (N, e.g. -100,-100)".into())
    })?;
    for (i, f) in forces.iter().enumerate() {
        if *f > 0.0 {
            return Err(InputError(format!(
                "--forces: F1{} = {f} N would pull on A{}: its spherical joint only pushes (compression is negative)",
                i + 1,
                i + 1
            ))
            .into());
        }
        let cap = d.design.actuators[i].push_capacity;
        if f.abs() > cap {
            return Err(InputError(format!(
                "--forces: F1{} = {f} N exceeds A{}'s push capacity {cap} N (actuators.A{}.push_capacity)",
                i + 1,
                i + 1,
                i + 1
            ))
            .into());
        }
    }
    let j = solve_joints(d, a.mesh.level as usize)?;
    let s = structure(d, &j)?;
    let eq = s
        .solve(forces, preload(d, &s, approach, a.mesh.preload)?)
        .context("structural equilibrium")?;
    let st = stresses(&j, &eq);
    if let Some(path) = &a.plot {
        plot(&s, &eq, approach, path)?;
    }
    match a.format {
        Format::Json => {
            let v = json!({
                "approach": approach.number(),
                "forces": forces,
                "dx": eq.tip[0], "dy": eq.tip[1], "dz": eq.tip[2],
                "body_rotation": eq.body_rotation.as_slice(),
                "stack_force": eq.stack_force,
                "slider": eq.slider,
                "joints": st.iter().map(|(n, s, f, at)| json!({
                    "name": n, "max_von_mises": s, "safety_factor": f, "at": at,
                })).collect::<Vec<_>>(),
                "yield_strength": material().yield_strength,
                "joint_k_bend": {"J1_J2": j.j12.k_bend, "J3": j.j3.k_bend},
                "mesh_level": j.level,
                "iterations": eq.iterations,
                "residual": eq.residual,
            });
            println!("{}", serde_json::to_string_pretty(&v)?);
        }
        Format::Text => {
            println!(
                "Structural model, approach {}: F11 = {} N, F12 = {} N (joints: 3-D FEM level {}, J1/J2 {:.1} N·m/rad, J3 {:.1} N·m/rad)",
                approach.number(),
                forces[0],
                forces[1],
                j.level,
                j.j12.k_bend[1],
                j.j3.k_bend[1]
            );
            println!(
                "end-effector  δx {:9.2} µm   δy {:9.2} µm   δz {:9.3} µm",
                eq.tip[0] * 1e6,
                eq.tip[1] * 1e6,
                eq.tip[2] * 1e6
            );
            println!(
                "stack forces  A1 {:8.3} N   A2 {:8.3} N",
                eq.stack_force[0], eq.stack_force[1]
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
            for (n, s, f, _) in &st {
                t.row(vec![
                    n.to_string(),
                    format!("{:.1}", s * 1e-6),
                    format!("{:.0}", material().yield_strength * 1e-6),
                    format!("{f:.2}"),
                ]);
            }
            print!("{}", t.text());
            for (n, _, f, at) in &st {
                if *f < 1.0 {
                    println!(
                        "warning: {n} is past its yield strength here (safety factor {f:.2}, at ({:.2}, {:.2}, {:.2}) mm in the joint)",
                        at[0] * 1e3,
                        at[1] * 1e3,
                        at[2] * 1e3
                    );
                }
            }
            if let Some(p) = &a.plot {
                println!("plot: {}", p.display());
            }
        }
    }
    Ok(())
}

fn plot(s: &Structure, eq: &Equilibrium, approach: Approach, path: &std::path::Path) -> Result<()> {
    if path.extension().and_then(|e| e.to_str()) != Some("svg") {
        return Err(InputError(format!(
            "--plot `{}`: the drawing is written as SVG; give a .svg file",
            path.display()
        ))
        .into());
    }
    let members = s.skeleton(eq, 24);
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
    let svg = structure_svg(
        &[
            panel(0, "effective displacement δx, x-z plane", "δx [µm]"),
            panel(1, "effective displacement δy, y-z plane", "δy [µm]"),
        ],
        (640, 560),
    )?;
    write_atomic(path, &svg).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

fn modes(
    d: &Description,
    approach: Approach,
    count: usize,
    mesh: &MeshArgs,
    format: Format,
) -> Result<()> {
    let level = mesh.level as usize;
    let j = solve_joints(d, level)?;
    let s = structure(d, &j)?;
    let f = d.design.tension.preload;
    let eq = s.solve(f, preload(d, &s, approach, mesh.preload)?)?;
    let modes = s.modes(&eq)?;
    let modes = &modes[..count.min(modes.len())];
    match format {
        Format::Json => {
            let v = json!({
                "approach": approach.number(),
                "preload": f,
                "modes": modes.iter().map(|m| json!({
                    "frequency": m.frequency,
                    "description": m.description,
                    "tip_shape": m.tip_shape.as_slice(),
                })).collect::<Vec<_>>(),
            });
            println!("{}", serde_json::to_string_pretty(&v)?);
        }
        Format::Text => {
            println!(
                "Natural modes, approach {} pre-tensioned at F10 = {:?} N (sliders locked, joints from the 3-D FEM level {level})",
                approach.number(),
                f
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
            for (i, m) in modes.iter().enumerate() {
                t.row(vec![
                    (i + 1).to_string(),
                    format!("{:.1}", m.frequency),
                    m.description.clone(),
                    format!(
                        "({:+.4}, {:+.4}, {:+.4})",
                        m.tip_shape[0] * 1e6,
                        m.tip_shape[1] * 1e6,
                        m.tip_shape[2] * 1e6
                    ),
                ]);
            }
            print!("{}", t.text());
        }
    }
    Ok(())
}

/// One recomputed table.
struct TableResult {
    table: &'static paper::FeaTable,
    computed: Vec<Equilibrium>,
    largest: f64,
    worst: f64,
    coupling: f64,
}

fn tables(d: &Description, mesh: &MeshArgs, format: Format) -> Result<()> {
    let kind = mesh.preload;
    let j = solve_joints(d, mesh.level as usize)?;
    let s = structure(d, &j)?;
    let mut results = Vec::new();
    for t in paper::fea_tables() {
        let approach = Approach::from_number(t.approach)
            .ok_or_else(|| anyhow::anyhow!("table {}: bad approach", t.table))?;
        let pre = preload(d, &s, approach, kind)?;
        let computed = t
            .cases
            .iter()
            .map(|c| s.solve([c.f11, c.f12], pre))
            .collect::<Result<Vec<_>, _>>()?;
        let largest = t
            .cases
            .iter()
            .flat_map(|c| [c.dx.abs(), c.dy.abs()])
            .fold(0.0, f64::max);
        let worst = t
            .cases
            .iter()
            .zip(&computed)
            .flat_map(|(c, e)| [(e.tip[0] - c.dx).abs(), (e.tip[1] - c.dy).abs()])
            .fold(0.0, f64::max);
        let coupling = computed[2].tip[0] - computed[0].tip[0];
        results.push(TableResult {
            table: t,
            computed,
            largest,
            worst,
            coupling,
        });
    }
    match format {
        Format::Json => {
            let v: Vec<Value> = results
                .iter()
                .map(|r| {
                    json!({
                        "table": r.table.table,
                        "approach": r.table.approach,
                        "largest_paper_displacement": r.largest,
                        "worst_difference": r.worst,
                        "worst_relative_to_largest": r.worst / r.largest,
                        "coupling_x": r.coupling,
                        "paper_coupling_x": r.table.coupling_x,
                        "cases": r.table.cases.iter().zip(&r.computed).map(|(c, e)| {
                            let st = stresses(&j, e);
                            json!({
                                "F11": c.f11, "F12": c.f12,
                                "paper": {"dx": c.dx, "dy": c.dy},
                                "dx": e.tip[0], "dy": e.tip[1], "dz": e.tip[2],
                                "stack_force": e.stack_force,
                                "joints": st.iter().map(|(n, s, f, _)| json!({
                                    "name": n, "max_von_mises": s, "safety_factor": f,
                                })).collect::<Vec<_>>(),
                            })
                        }).collect::<Vec<_>>(),
                    })
                })
                .collect();
            println!(
                "{}",
                serde_json::to_string_pretty(&json!({
                    "mesh_level": j.level,
                    "approach2_preload": format!("{kind:?}").to_lowercase(),
                    "joint_k_bend": {"J1_J2": j.j12.k_bend, "J3": j.j3.k_bend},
                    "yield_strength": material().yield_strength,
                    "tables": v,
                }))?
            );
        }
        Format::Text => {
            println!(
                "Whole-manipulator model against the paper's CAD FEA (Sec. 3.3); joints from the 3-D FEM level {} (J1/J2 {:.1}, J3 {:.1} N·m/rad)",
                j.level, j.j12.k_bend[1], j.j3.k_bend[1]
            );
            for r in &results {
                println!("\nTable {} (approach {}):", r.table.table, r.table.approach);
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
                for (c, e) in r.table.cases.iter().zip(&r.computed) {
                    let st = stresses(&j, e);
                    let (name, _, sf, _) = st
                        .iter()
                        .copied()
                        .min_by(|a, b| a.2.total_cmp(&b.2))
                        .unwrap_or(("-", 0.0, f64::NAN, [0.0; 3]));
                    t.row(vec![
                        format!("{}, {}", c.f11, c.f12),
                        format!("{:.1}", c.dx * 1e6),
                        format!("{:.1}", e.tip[0] * 1e6),
                        format!("{:.1}", c.dy * 1e6),
                        format!("{:.1}", e.tip[1] * 1e6),
                        format!("{:.2}", e.tip[2] * 1e6),
                        format!("{sf:.2} ({name})"),
                    ]);
                }
                print!("{}", t.text());
                println!(
                    "largest difference {:.2} µm = {:.2} % of the largest displacement {:.1} µm (acceptance 3 %)",
                    r.worst * 1e6,
                    100.0 * r.worst / r.largest,
                    r.largest * 1e6
                );
                println!(
                    "cross-axis coupling (δx from raising F12 alone): model {:.3} µm, paper {:.1} µm",
                    r.coupling * 1e6,
                    r.table.coupling_x * 1e6
                );
            }
        }
    }
    Ok(())
}

fn joints(d: &Description, levels: &[u8], format: Format) -> Result<()> {
    let p = &d.structure;
    let m = material();
    let mesh = JointMesh::default();
    let mut levels: Vec<usize> = levels.iter().map(|&l| l as usize).collect();
    levels.sort_unstable();
    levels.dedup();
    if levels.is_empty() || levels[0] == 0 || *levels.last().unwrap_or(&0) > 3 {
        return Err(InputError("--levels: give levels between 1 and 3, e.g. 1,2".into()).into());
    }
    let targets = [("J1, J2", p.throat_j12, 91.3), ("J3", p.throat_j3, 340.3)];
    let mut rows = Vec::new();
    for (name, throat, paper_k) in targets {
        let joint = notch(p, throat);
        let sols = levels
            .iter()
            .map(|&l| joint3d::solve(&joint, &m, &mesh, l))
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| InputError(format!("structure: joint FEM failed: {e}")))?;
        rows.push((name, throat, paper_k, sols));
    }
    match format {
        Format::Json => {
            let v: Vec<Value> = rows
                .iter()
                .map(|(name, throat, paper_k, sols)| {
                    let fine = &sols[sols.len() - 1];
                    json!({
                        "joint": name,
                        "throat": throat,
                        "paper_k_bend": paper_k,
                        "levels": sols.iter().zip(&levels).map(|(s, l)| json!({
                            "level": l,
                            "k_bend": s.k_bend,
                            "k_axial": s.k_axial,
                            "k_torsion": s.k_torsion,
                            "max_stress_per_rad": s.max_stress_per_rad(),
                            "dofs": s.dofs,
                            "residual": s.residual,
                        })).collect::<Vec<_>>(),
                        "k_bend": fine.k_bend,
                        "relative_to_paper": [fine.k_bend[0] / paper_k - 1.0, fine.k_bend[1] / paper_k - 1.0],
                    })
                })
                .collect();
            println!(
                "{}",
                serde_json::to_string_pretty(&json!({
                    "geometry": {
                        "side": p.joint.side, "radius": p.joint.radius,
                        "flat": p.joint.flat, "gap": p.joint.gap,
                    },
                    "joints": v,
                }))?
            );
        }
        Format::Text => {
            println!(
                "Double-notched joints by 3-D FEM: rod {:.2} mm square, fillets {:.2} mm, throat length {:.2} mm, gap {:.2} mm",
                p.joint.side * 1e3,
                p.joint.radius * 1e3,
                p.joint.flat * 1e3,
                p.joint.gap * 1e3
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
            for (name, throat, paper_k, sols) in &rows {
                for (s, l) in sols.iter().zip(&levels) {
                    t.row(vec![
                        name.to_string(),
                        format!("{:.2}", throat * 1e3),
                        l.to_string(),
                        s.dofs.to_string(),
                        format!("{:.2}", s.k_bend[0]),
                        format!("{:.2}", s.k_bend[1]),
                        format!("{paper_k:.1}"),
                        format!("{:+.2} %", 100.0 * (s.k_bend[1] / paper_k - 1.0)),
                        format!("{:.1}", s.max_stress_per_rad()[1] * 1e-9),
                    ]);
                }
            }
            print!("{}", t.text());
            println!("stiffness in N·m/rad; the paper's acceptance: within 3 %");
        }
    }
    Ok(())
}
