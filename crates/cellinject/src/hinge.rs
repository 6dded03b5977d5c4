//! `cellinject hinge`: stiffness and stress of one flexure hinge.

use anyhow::Result;
use cellinject_fem::hinge2d::{MeshDensity, Plane, converge};
use cellinject_flexure::{FlexureError, Hinge, Material, Profile, paros_weisbord_simplified};
use clap::{Args, ValueEnum};
use serde_json::json;

use crate::output::Table;
use crate::{Format, InputError};

/// Notch profiles.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ProfileArg {
    /// Circular notch (radius R, length 2R).
    Circular,
    /// Corner-filleted leaf (fillet radius R, total length L).
    Corner,
    /// Elliptic notch (depth R across, total length L along).
    Elliptic,
    /// Straight leaf (length L).
    Leaf,
}

/// How the compliant stiffness is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    /// Exact beam integral of the profile (equal to the full Paros-Weisbord and Wu-Zhou forms).
    Beam,
    /// Simplified Paros-Weisbord formula 2·E·b·t^2.5 / (9π√R), circular notches only.
    PwSimple,
    /// 2-D finite elements (9-node quadrilaterals, three refinements, sparse Cholesky).
    Fem,
}

/// In-plane assumption of the FEM.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PlaneArg {
    /// Plane stress (thin hinge).
    Stress,
    /// Plane strain (thick hinge).
    Strain,
}

/// `cellinject hinge` arguments.
#[derive(Debug, Args)]
pub struct HingeArgs {
    /// Notch profile.
    #[arg(long, value_enum)]
    profile: ProfileArg,
    /// Thickness at the throat, m.
    #[arg(long)]
    thickness: f64,
    /// Notch radius (circular), fillet radius (corner) or notch depth (elliptic), m.
    #[arg(long)]
    radius: Option<f64>,
    /// Width of the hinge (out of the bending plane), m.
    #[arg(long)]
    width: f64,
    /// Total length, m (corner, elliptic, leaf).
    #[arg(long)]
    length: Option<f64>,
    /// Young's modulus, Pa (default: X2CrNi18-9, 190 GPa).
    #[arg(long, default_value_t = 190e9)]
    youngs: f64,
    /// Poisson's ratio.
    #[arg(long, default_value_t = 0.3)]
    poisson: f64,
    /// Yield strength, Pa (default: X2CrNi18-9, 465 MPa).
    #[arg(long = "yield", default_value_t = 465e6)]
    yield_strength: f64,
    /// Method for the compliant bending stiffness.
    #[arg(long, value_enum, default_value_t = MethodArg::Beam)]
    method: MethodArg,
    /// In-plane assumption for `--method fem`.
    #[arg(long, value_enum, default_value_t = PlaneArg::Stress)]
    plane: PlaneArg,
    /// With `--method fem`: write the finest mesh (nodes, 9-node elements, sections)
    /// with this solve's stiffness and time as JSON, for peer solvers
    /// (bench/fem_peers.sh).
    #[arg(long, value_name = "FILE.json")]
    export_mesh: Option<std::path::PathBuf>,
    /// A working rotation, rad: report its stress and safety factor.
    #[arg(long, allow_negative_numbers = true)]
    angle: Option<f64>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
}

fn need(v: Option<f64>, flag: &str, profile: &str) -> Result<f64> {
    v.ok_or_else(|| InputError(format!("--{flag} is required for a {profile} hinge")).into())
}

fn flex_error(e: FlexureError) -> anyhow::Error {
    match e {
        FlexureError::Invalid {
            name,
            value,
            reason,
        } => InputError(format!("--{name} {value}: {reason}")).into(),
        other => InputError(format!("--method: {other}")).into(),
    }
}

/// Writes the finest mesh of `converge` (level 4) and its solve for peer solvers.
fn export_mesh(hinge: &Hinge, m: &Material, plane: Plane, path: &std::path::Path) -> Result<()> {
    let density = MeshDensity::default();
    let level = 4;
    let t = std::time::Instant::now();
    let sol = cellinject_fem::hinge2d::solve(hinge, m, plane, &density, level)
        .map_err(|e| anyhow::anyhow!("hinge FEM: {e}"))?;
    let seconds = t.elapsed().as_secs_f64();
    let mesh = cellinject_fem::hinge2d::mesh(hinge, &density, level);
    let v = json!({
        "level": level,
        "plane": match plane { Plane::Stress => "stress", Plane::Strain => "strain" },
        "youngs": m.youngs,
        "poisson": m.poisson,
        "width": hinge.width,
        "moment": sol.moment,
        "cols": mesh.cols,
        "rows": mesh.rows,
        "coords": mesh.coords.iter().map(|p| [p.0, p.1]).collect::<Vec<_>>(),
        "elements": mesh.elements(),
        "element_order": "9 nodes, x fastest then y: (i, j) = (k % 3, k / 3)",
        "section_columns": mesh.section_columns(),
        "clamped_column": 0,
        "loaded_column": mesh.cols - 1,
        "k_bend": sol.k_bend,
        "unknowns": sol.dofs,
        "solve_seconds": seconds,
    });
    crate::output::write_atomic(path, &serde_json::to_string(&v)?)
        .map_err(|e| InputError(format!("--export-mesh `{}`: {e}", path.display())))?;
    Ok(())
}

/// Runs `cellinject hinge`.
pub fn run(a: &HingeArgs) -> Result<()> {
    let profile = match a.profile {
        ProfileArg::Circular => Profile::Circular {
            radius: need(a.radius, "radius", "circular")?,
        },
        ProfileArg::Corner => Profile::CornerFilleted {
            radius: need(a.radius, "radius", "corner-filleted")?,
            length: need(a.length, "length", "corner-filleted")?,
        },
        ProfileArg::Elliptic => Profile::Elliptic {
            half_length: 0.5 * need(a.length, "length", "elliptic")?,
            depth: need(a.radius, "radius", "elliptic")?,
        },
        ProfileArg::Leaf => Profile::Leaf {
            length: need(a.length, "length", "leaf")?,
        },
    };
    let hinge = Hinge {
        profile,
        thickness: a.thickness,
        width: a.width,
    };
    hinge.validate().map_err(flex_error)?;
    for (flag, v, ok) in [
        ("youngs", a.youngs, a.youngs > 0.0),
        ("poisson", a.poisson, a.poisson > -1.0 && a.poisson < 0.5),
        ("yield", a.yield_strength, a.yield_strength > 0.0),
    ] {
        if !(v.is_finite() && ok) {
            return Err(InputError(format!("--{flag} {v} is out of range")).into());
        }
    }
    let m = Material {
        youngs: a.youngs,
        poisson: a.poisson,
        yield_strength: a.yield_strength,
    };
    let mut fem_info = None;
    let k_bend = match a.method {
        MethodArg::Beam => hinge.k_bend(&m),
        MethodArg::PwSimple => paros_weisbord_simplified(&hinge, &m).map_err(flex_error)?,
        MethodArg::Fem => {
            let plane = match a.plane {
                PlaneArg::Stress => Plane::Stress,
                PlaneArg::Strain => Plane::Strain,
            };
            let c = converge(&hinge, &m, plane, &MeshDensity::default())
                .map_err(|e| anyhow::anyhow!("hinge FEM: {e}"))?;
            if let Some(path) = &a.export_mesh {
                export_mesh(&hinge, &m, plane, path)?;
            }
            fem_info = Some(c.clone());
            c.k_bend
        }
    };
    let kt = hinge.stress_concentration();
    let stress_per_rad = kt * 6.0 * k_bend / (hinge.width * hinge.thickness.powi(2));
    let max_rotation = m.yield_strength / stress_per_rad;
    let c = hinge.compliance(&m);
    let (k_off, k_axial, k_torsion) =
        (hinge.k_bend_off(&m), hinge.k_axial(&m), hinge.k_torsion(&m));
    let at_angle = a.angle.map(|th| {
        let s = stress_per_rad * th.abs();
        (th, s, m.yield_strength / s)
    });
    match a.format {
        Format::Json => {
            let rows: Vec<Vec<f64>> = (0..6)
                .map(|r| (0..6).map(|k| c[(r, k)]).collect())
                .collect();
            let mut v = json!({
                "profile": format!("{:?}", a.profile).to_lowercase(),
                "method": match a.method { MethodArg::Beam => "beam", MethodArg::PwSimple => "pw-simple", MethodArg::Fem => "fem" },
                "thickness": a.thickness, "width": a.width, "length": hinge.length(),
                "k_bend": k_bend, "k_bend_off": k_off, "k_axial": k_axial, "k_torsion": k_torsion,
                "stress_concentration": kt,
                "max_stress_per_rad": stress_per_rad,
                "max_rotation": max_rotation,
                "compliance": rows,
                "compliance_order": ["ux", "uy", "uz", "rx", "ry", "rz"],
            });
            if let Some(c) = &fem_info {
                v["fem"] = json!({
                    "k_bend_levels": c.levels.iter().map(|l| l.k_bend).collect::<Vec<_>>(),
                    "unknowns": c.levels.iter().map(|l| l.dofs).collect::<Vec<_>>(),
                    "backward_error": c.levels.iter().map(|l| l.residual).collect::<Vec<_>>(),
                    "mesh_error": c.error_estimate,
                    "beam_over_fem": hinge.k_bend(&m) / c.k_bend,
                });
            }
            if let Some((th, s, sf)) = at_angle {
                v["angle"] = json!(th);
                v["stress"] = json!(s);
                v["safety_factor"] = json!(sf);
            }
            println!("{}", serde_json::to_string_pretty(&v)?);
        }
        Format::Text => {
            let mut t = Table::new(&["quantity", "value", "unit"], &[false, true, false]);
            let mut row = |q: &str, v: String, u: &str| t.row(vec![q.into(), v, u.into()]);
            row(
                "compliant bending stiffness k_bend",
                format!("{k_bend:.4}"),
                "N·m/rad",
            );
            row(
                "off-axis bending stiffness",
                format!("{k_off:.4}"),
                "N·m/rad",
            );
            row("torsional stiffness", format!("{k_torsion:.4}"), "N·m/rad");
            row("axial stiffness", format!("{:.4e}", k_axial), "N/m");
            row("stress concentration K_t", format!("{kt:.4}"), "");
            row(
                "throat stress per radian",
                format!("{:.2}", stress_per_rad * 1e-6),
                "MPa/rad",
            );
            row(
                "rotation at yield",
                format!("{:.4}", max_rotation * 1e3),
                "mrad",
            );
            if let Some(c) = &fem_info {
                let levels: Vec<String> = c
                    .levels
                    .iter()
                    .map(|l| format!("{:.4}", l.k_bend))
                    .collect();
                row("FEM k_bend at levels 1, 2, 4", levels.join(", "), "N·m/rad");
                row(
                    "FEM mesh error (last refinement)",
                    format!("{:.2e}", c.error_estimate),
                    "",
                );
                row("FEM unknowns (finest)", format!("{}", c.levels[2].dofs), "");
                row(
                    "beam / FEM",
                    format!("{:.4}", hinge.k_bend(&m) / c.k_bend),
                    "",
                );
            }
            if let Some((th, s, sf)) = at_angle {
                row(
                    "stress at --angle",
                    format!("{:.2} at {:.3} mrad", s * 1e-6, th * 1e3),
                    "MPa",
                );
                row("safety factor against yield", format!("{sf:.2}"), "");
            }
            println!(
                "{:?} hinge, t = {} mm, b = {} mm, L = {} mm ({})",
                a.profile,
                a.thickness * 1e3,
                a.width * 1e3,
                hinge.length() * 1e3,
                match a.method {
                    MethodArg::Beam => "beam integral",
                    MethodArg::PwSimple => "simplified Paros-Weisbord",
                    MethodArg::Fem => "2-D FEM for k_bend, beam integrals for the rest",
                }
            );
            print!("{}", t.text());
        }
    }
    Ok(())
}

/// `cellinject hinge-table` arguments.
#[derive(Debug, Args)]
pub struct TableArgs {
    /// Notch radius, m.
    #[arg(long, default_value_t = 2e-3)]
    radius: f64,
    /// Width, m.
    #[arg(long, default_value_t = 5e-3)]
    width: f64,
    /// Young's modulus, Pa.
    #[arg(long, default_value_t = 190e9)]
    youngs: f64,
    /// Poisson's ratio.
    #[arg(long, default_value_t = 0.3)]
    poisson: f64,
    /// In-plane assumption of the FEM.
    #[arg(long, value_enum, default_value_t = PlaneArg::Stress)]
    plane: PlaneArg,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
}

/// `cellinject hinge-table`: circular notches from thin to thick, beam integral,
/// simplified Paros-Weisbord and FEM side by side.
pub fn table(a: &TableArgs) -> Result<()> {
    if !(a.radius > 0.0 && a.width > 0.0 && a.youngs > 0.0 && a.poisson > -1.0 && a.poisson < 0.5) {
        return Err(InputError(
            "--radius, --width and --youngs must be positive and --poisson in (-1, 0.5)".into(),
        )
        .into());
    }
    let m = Material {
        youngs: a.youngs,
        poisson: a.poisson,
        yield_strength: 465e6,
    };
    let plane = match a.plane {
        PlaneArg::Stress => Plane::Stress,
        PlaneArg::Strain => Plane::Strain,
    };
    let mut rows = Vec::new();
    for tr in [0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0] {
        let h = Hinge {
            profile: Profile::Circular { radius: a.radius },
            thickness: tr * a.radius,
            width: a.width,
        };
        let beam = h.k_bend(&m);
        let pw = paros_weisbord_simplified(&h, &m).map_err(flex_error)?;
        let c = converge(&h, &m, plane, &MeshDensity::default())
            .map_err(|e| anyhow::anyhow!("hinge FEM: {e}"))?;
        rows.push((tr, beam, pw, c.k_bend, c.error_estimate));
    }
    match a.format {
        Format::Json => {
            let v: Vec<serde_json::Value> = rows
                .iter()
                .map(|&(tr, beam, pw, fem, err)| {
                    json!({"t_over_r": tr, "k_beam": beam, "k_pw_simple": pw, "k_fem": fem,
                           "beam_over_fem": beam / fem, "pw_over_fem": pw / fem, "fem_mesh_error": err})
                })
                .collect();
            println!("{}", serde_json::to_string_pretty(&v)?);
        }
        Format::Text => {
            println!(
                "Circular notch, R = {} mm, b = {} mm, E = {} GPa, plane {:?}: compliant stiffness, N·m/rad",
                a.radius * 1e3,
                a.width * 1e3,
                a.youngs * 1e-9,
                a.plane
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
            for (tr, beam, pw, fem, err) in rows {
                t.row(vec![
                    format!("{tr}"),
                    format!("{beam:.4}"),
                    format!("{pw:.4}"),
                    format!("{fem:.4}"),
                    format!("{:.4}", beam / fem),
                    format!("{:.4}", pw / fem),
                    format!("{err:.1e}"),
                ]);
            }
            print!("{}", t.text());
        }
    }
    Ok(())
}
