//! `cellinject hinge`: stiffness and stress of one flexure hinge.

use anyhow::Result;
use cellinject_core::hinge::{self as core, HingeError, Method, ProfileKind};
use cellinject_fem::hinge2d::Plane;
use cellinject_flexure::{FlexureError, Hinge, Material};
use clap::{Args, ValueEnum};

use crate::{Format, InputError};
use cellinject_files::{Kind, Plan, write_one};
use cellinject_print::hinge as print;

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
    #[arg(long, default_value_t = Material::x2crni18_9().youngs)]
    youngs: f64,
    /// Poisson's ratio.
    #[arg(long, default_value_t = Material::x2crni18_9().poisson)]
    poisson: f64,
    /// Yield strength, Pa (default: X2CrNi18-9, 465 MPa).
    #[arg(long = "yield", default_value_t = Material::x2crni18_9().yield_strength)]
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

fn hinge_error(e: HingeError) -> anyhow::Error {
    match e {
        HingeError::Flexure(FlexureError::Invalid {
            name,
            value,
            reason,
        }) => InputError(format!("--{name} {value}: {reason}")).into(),
        HingeError::Flexure(other) => InputError(format!("--method: {other}")).into(),
        HingeError::Fem(e) => anyhow::anyhow!("hinge FEM: {e}"),
        HingeError::Missing {
            name,
            article,
            profile,
        } => InputError(format!(
            "--{name} is required for {article} {profile} hinge"
        ))
        .into(),
        e @ (HingeError::NotFinite { .. } | HingeError::UnknownProfile(_)) => {
            InputError(e.to_string()).into()
        }
    }
}

fn plane(p: PlaneArg) -> Plane {
    match p {
        PlaneArg::Stress => Plane::Stress,
        PlaneArg::Strain => Plane::Strain,
    }
}

/// Writes the finest mesh of the FEM and its solve for peer solvers.
fn export_mesh(hinge: &Hinge, m: &Material, plane: Plane, path: &std::path::Path) -> Result<()> {
    let t = std::time::Instant::now();
    let mut export = core::mesh_export(hinge, m, plane).map_err(hinge_error)?;
    export.solve_seconds = t.elapsed().as_secs_f64();
    write_one(path, serde_json::to_string(&export)?.as_bytes())?;
    Ok(())
}

/// Runs `cellinject hinge`.
pub fn run(a: &HingeArgs) -> Result<()> {
    let kind = match a.profile {
        ProfileArg::Circular => ProfileKind::Circular,
        ProfileArg::Corner => ProfileKind::Corner,
        ProfileArg::Elliptic => ProfileKind::Elliptic,
        ProfileArg::Leaf => ProfileKind::Leaf,
    };
    let profile = kind.profile(a.radius, a.length).map_err(hinge_error)?;
    // An option the profile does not use is said, not silently dropped.
    if let Some((flag, why)) = kind.unused(a.radius, a.length) {
        eprintln!(
            "warning: --{flag} is not used by a {:?} hinge: {why}",
            a.profile
        );
    }
    let hinge = Hinge {
        profile,
        thickness: a.thickness,
        width: a.width,
    };
    let m = Material {
        youngs: a.youngs,
        poisson: a.poisson,
        yield_strength: a.yield_strength,
    };
    let method = match a.method {
        MethodArg::Beam => Method::Beam,
        MethodArg::PwSimple => Method::PwSimple,
        MethodArg::Fem => Method::Fem(plane(a.plane)),
    };
    if let Some(path) = &a.export_mesh {
        if a.method != MethodArg::Fem {
            return Err(InputError(
                "--export-mesh writes the FEM's mesh: it needs --method fem".into(),
            )
            .into());
        }
        let mut plan = Plan::new();
        plan.output("--export-mesh", path, &[Kind::Json])?;
        plan.check()?;
    }
    let r = {
        let _p = (a.method == MethodArg::Fem)
            .then(|| crate::progress::spinner("hinge FEM at levels 1, 2 and 4"));
        core::hinge(&hinge, &m, method, a.angle).map_err(hinge_error)?
    };
    if let (Method::Fem(p), Some(path)) = (method, &a.export_mesh) {
        export_mesh(&hinge, &m, p, path)?;
    }
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
    match a.format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&r)?),
        Format::Text => out!("{}", print::hinge_text(kind, &hinge, method, &r)),
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
    #[arg(long, default_value_t = Material::x2crni18_9().youngs)]
    youngs: f64,
    /// Poisson's ratio.
    #[arg(long, default_value_t = Material::x2crni18_9().poisson)]
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
    if !(a.radius > 0.0 && a.width > 0.0) {
        return Err(InputError(format!(
            "--radius and --width must be positive, got {} and {}",
            a.radius, a.width
        ))
        .into());
    }
    let m = Material {
        youngs: a.youngs,
        poisson: a.poisson,
        ..Material::x2crni18_9()
    };
    let rows = {
        let _p = crate::progress::spinner("seven notches by beam integral and FEM");
        core::table(a.radius, a.width, &m, plane(a.plane)).map_err(hinge_error)?
    };
    match a.format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&rows)?),
        Format::Text => out!(
            "{}",
            print::table_text(a.radius, a.width, a.youngs, plane(a.plane), &rows)
        ),
    }
    Ok(())
}
