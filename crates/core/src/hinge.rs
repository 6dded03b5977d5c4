//! `hinge` and `hinge-table`: one flexure hinge's stiffnesses, compliance and stress,
//! and circular notches from thin to thick by three methods.

use cellinject_fem::FemError;
use cellinject_fem::hinge2d::{self, Convergence, MeshDensity, Plane};
use cellinject_flexure::{FlexureError, Hinge, Material, Profile, paros_weisbord_simplified};
use serde::Serialize;
use thiserror::Error;

/// Why a hinge could not be evaluated.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum HingeError {
    /// A dimension or material constant out of its domain (names the flag).
    #[error(transparent)]
    Flexure(#[from] FlexureError),
    /// The FEM failed.
    #[error("hinge FEM: {0}")]
    Fem(#[from] FemError),
    /// A dimension the profile needs was not given (names the argument: `radius`,
    /// `length`).
    #[error("`{name}` is required for {article} {profile} hinge")]
    Missing {
        /// The argument.
        name: &'static str,
        /// "a" or "an".
        article: &'static str,
        /// The profile's long name (`circular`, `corner-filleted`, ...).
        profile: &'static str,
    },
    /// A profile name that is none of `circular`, `corner`, `elliptic`, `leaf`.
    #[error("profile must be circular, corner, elliptic or leaf, got `{0}`")]
    UnknownProfile(String),
    /// A result is not a finite number: the dimensions or constants are out of all
    /// physical scale (they are metres and pascals).
    #[error(
        "{quantity} is not a finite number for these dimensions and material: check their units (m, Pa)"
    )]
    NotFinite {
        /// Which result.
        quantity: &'static str,
    },
}

/// Refuses a non-finite result, naming it.
fn finite(quantity: &'static str, v: f64) -> Result<f64, HingeError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(HingeError::NotFinite { quantity })
    }
}

/// How the compliant bending stiffness is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Exact beam integral of the profile.
    Beam,
    /// Simplified Paros-Weisbord, circular notches only.
    PwSimple,
    /// 2-D finite elements at three refinements.
    Fem(Plane),
}

impl Method {
    /// The name used on the command line and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            Method::Beam => "beam",
            Method::PwSimple => "pw-simple",
            Method::Fem(_) => "fem",
        }
    }
}

/// The name of a profile on the command line and in JSON.
pub fn profile_name(p: &Profile) -> &'static str {
    match p {
        Profile::Circular { .. } => "circular",
        Profile::CornerFilleted { .. } => "corner",
        Profile::Elliptic { .. } => "elliptic",
        Profile::Leaf { .. } => "leaf",
    }
}

/// The four notch profiles by their command-line names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProfileKind {
    /// `circular`: radius R, length 2R.
    Circular,
    /// `corner`: fillet radius R, total length L.
    Corner,
    /// `elliptic`: depth R across, total length L along.
    Elliptic,
    /// `leaf`: length L.
    Leaf,
}

impl ProfileKind {
    /// The kind a command-line name (`circular`, `corner`, `elliptic`, `leaf`) names.
    pub fn from_name(name: &str) -> Result<Self, HingeError> {
        Ok(match name {
            "circular" => ProfileKind::Circular,
            "corner" => ProfileKind::Corner,
            "elliptic" => ProfileKind::Elliptic,
            "leaf" => ProfileKind::Leaf,
            other => return Err(HingeError::UnknownProfile(other.to_string())),
        })
    }

    /// The notch of this kind from the arguments `radius` and `length` (m), refusing
    /// a missing one ([`HingeError::Missing`]); an elliptic notch's `length` is its
    /// total length (twice the semi-axis).
    pub fn profile(self, radius: Option<f64>, length: Option<f64>) -> Result<Profile, HingeError> {
        let need = |v: Option<f64>, name: &'static str, profile: &'static str| {
            let article = if profile.starts_with(['a', 'e', 'i', 'o', 'u']) {
                "an"
            } else {
                "a"
            };
            v.ok_or(HingeError::Missing {
                name,
                article,
                profile,
            })
        };
        Ok(match self {
            ProfileKind::Circular => Profile::Circular {
                radius: need(radius, "radius", "circular")?,
            },
            ProfileKind::Corner => Profile::CornerFilleted {
                radius: need(radius, "radius", "corner-filleted")?,
                length: need(length, "length", "corner-filleted")?,
            },
            ProfileKind::Elliptic => Profile::Elliptic {
                half_length: 0.5 * need(length, "length", "elliptic")?,
                depth: need(radius, "radius", "elliptic")?,
            },
            ProfileKind::Leaf => Profile::Leaf {
                length: need(length, "length", "leaf")?,
            },
        })
    }

    /// An argument given that this kind does not use, and why (said, not silently
    /// dropped): a circular notch's length is 2R, a leaf has no radius.
    pub fn unused(
        self,
        radius: Option<f64>,
        length: Option<f64>,
    ) -> Option<(&'static str, &'static str)> {
        match self {
            ProfileKind::Circular => length.map(|_| ("length", "its length is 2R")),
            ProfileKind::Leaf => radius.map(|_| ("radius", "a straight leaf has no notch radius")),
            _ => None,
        }
    }
}

/// The FEM's convergence, with `--method fem`.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `k_bend_levels` | N·m/rad | stiffness at mesh levels 1, 2, 4 |
/// | `unknowns` | | unknowns at each level |
/// | `backward_error` | 1 | of each solve |
/// | `mesh_error` | 1 | relative change of the last refinement |
/// | `beam_over_fem` | 1 | beam integral over the FEM |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FemReport {
    /// N·m/rad.
    pub k_bend_levels: Vec<f64>,
    /// Unknowns.
    pub unknowns: Vec<usize>,
    /// Backward errors.
    pub backward_error: Vec<f64>,
    /// Mesh error estimate.
    pub mesh_error: f64,
    /// Beam integral over FEM.
    pub beam_over_fem: f64,
}

/// The result of `cellinject hinge`.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `profile`, `method` | | as given |
/// | `thickness`, `width`, `length` | m | throat, width, notch length |
/// | `k_bend` | N·m/rad | compliant bending stiffness (by `method`) |
/// | `k_bend_off` | N·m/rad | off-axis bending |
/// | `k_axial` | N/m | axial |
/// | `k_torsion` | N·m/rad | torsional |
/// | `stress_concentration` | 1 | K_t at the throat |
/// | `max_stress_per_rad` | Pa/rad | throat stress per radian of bending |
/// | `max_rotation` | rad | rotation at yield |
/// | `yield_strength` | Pa | the material's |
/// | `compliance` | m/N, rad/(N·m) | 6x6, order `compliance_order` |
/// | `fem` | | [`FemReport`], with `--method fem` |
/// | `angle`, `stress`, `safety_factor` | rad, Pa, 1 | with `--angle` |
/// | `warnings` | | where the hinge lies outside the range its formulas were checked over |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HingeReport {
    /// Profile name.
    pub profile: &'static str,
    /// Method name.
    pub method: &'static str,
    /// m.
    pub thickness: f64,
    /// m.
    pub width: f64,
    /// m.
    pub length: f64,
    /// N·m/rad.
    pub k_bend: f64,
    /// N·m/rad.
    pub k_bend_off: f64,
    /// N/m.
    pub k_axial: f64,
    /// N·m/rad.
    pub k_torsion: f64,
    /// K_t.
    pub stress_concentration: f64,
    /// Pa/rad.
    pub max_stress_per_rad: f64,
    /// rad.
    pub max_rotation: f64,
    /// Pa.
    pub yield_strength: f64,
    /// 6x6 rows.
    pub compliance: Vec<Vec<f64>>,
    /// Order of the compliance's rows and columns.
    pub compliance_order: [&'static str; 6],
    /// FEM convergence.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fem: Option<FemReport>,
    /// rad.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub angle: Option<f64>,
    /// Pa.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stress: Option<f64>,
    /// Yield over stress.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub safety_factor: Option<f64>,
    /// Where the hinge lies outside the range its formulas were checked over.
    pub warnings: Vec<String>,
}

/// Checks a material's constants, naming the flags.
pub fn check_material(m: &Material) -> Result<(), FlexureError> {
    for (name, value, ok, reason) in [
        ("youngs", m.youngs, m.youngs > 0.0, "must be positive"),
        (
            "poisson",
            m.poisson,
            m.poisson > -1.0 && m.poisson < 0.5,
            "must lie in (-1, 0.5)",
        ),
        (
            "yield",
            m.yield_strength,
            m.yield_strength > 0.0,
            "must be positive",
        ),
    ] {
        if !(value.is_finite() && ok) {
            return Err(FlexureError::Invalid {
                name,
                value,
                reason: reason.into(),
            });
        }
    }
    Ok(())
}

/// `cellinject hinge`: `angle` (rad), if given, is a working rotation whose stress and
/// safety factor are reported.
pub fn hinge(
    hinge: &Hinge,
    m: &Material,
    method: Method,
    angle: Option<f64>,
) -> Result<HingeReport, HingeError> {
    hinge.validate()?;
    check_material(m)?;
    if let Some(th) = angle
        && !th.is_finite()
    {
        return Err(FlexureError::Invalid {
            name: "angle",
            value: th,
            reason: "must be a finite number of radians".into(),
        }
        .into());
    }
    let mut fem: Option<Convergence> = None;
    let k_bend = match method {
        Method::Beam => hinge.k_bend(m),
        Method::PwSimple => paros_weisbord_simplified(hinge, m)?,
        Method::Fem(plane) => {
            let c = hinge2d::converge(hinge, m, plane, &MeshDensity::default())?;
            let k = c.k_bend;
            fem = Some(c);
            k
        }
    };
    let kt = hinge.stress_concentration();
    let stress_per_rad = kt * 6.0 * k_bend / (hinge.width * hinge.thickness.powi(2));
    let c = hinge.compliance(m);
    finite("k_bend", k_bend)?;
    finite("the throat stress per radian", stress_per_rad)?;
    finite("the rotation at yield", m.yield_strength / stress_per_rad)?;
    for (q, v) in [
        ("k_bend_off", hinge.k_bend_off(m)),
        ("k_axial", hinge.k_axial(m)),
        ("k_torsion", hinge.k_torsion(m)),
    ] {
        finite(q, v)?;
    }
    if (0..6).any(|r| (0..6).any(|k| !c[(r, k)].is_finite())) {
        return Err(HingeError::NotFinite {
            quantity: "the compliance",
        });
    }
    // At a rotation that stresses the throat by less than 1e-9 of the yield strength
    // there is no safety factor to report (it would be rounding over rounding).
    let at = angle.map(|th| {
        let s = stress_per_rad * th.abs();
        let sf = (s >= 1e-9 * m.yield_strength).then(|| m.yield_strength / s);
        (th, s, sf)
    });
    if let Some((_, s, _)) = at {
        finite("the stress at --angle", s)?;
    }
    Ok(HingeReport {
        profile: profile_name(&hinge.profile),
        method: method.name(),
        thickness: hinge.thickness,
        width: hinge.width,
        length: hinge.length(),
        k_bend,
        k_bend_off: hinge.k_bend_off(m),
        k_axial: hinge.k_axial(m),
        k_torsion: hinge.k_torsion(m),
        stress_concentration: kt,
        max_stress_per_rad: stress_per_rad,
        max_rotation: m.yield_strength / stress_per_rad,
        yield_strength: m.yield_strength,
        compliance: (0..6)
            .map(|r| (0..6).map(|k| c[(r, k)]).collect())
            .collect(),
        compliance_order: ["ux", "uy", "uz", "rx", "ry", "rz"],
        fem: fem.map(|c| FemReport {
            k_bend_levels: c.levels.iter().map(|l| l.k_bend).collect(),
            unknowns: c.levels.iter().map(|l| l.dofs).collect(),
            backward_error: c.levels.iter().map(|l| l.residual).collect(),
            mesh_error: c.error_estimate,
            beam_over_fem: hinge.k_bend(m) / c.k_bend,
        }),
        angle: at.map(|a| a.0),
        stress: at.map(|a| a.1),
        safety_factor: at.and_then(|a| a.2),
        warnings: validity_warnings(hinge, method),
    })
}

/// The range of throat over notch radius over which the circular notch's beam integral
/// and FEM were compared (`hinge-table`, methods.md): outside it they are unchecked.
pub const CHECKED_T_OVER_R: (f64, f64) = (0.05, 1.0);

/// The simplified Paros-Weisbord formula is a thin-notch asymptote: beyond t/R = 0.2 it
/// is more than 10 % off the beam integral (`hinge-table`).
pub const PW_SIMPLE_T_OVER_R: f64 = 0.2;

/// Warnings for a hinge outside the range where its formulas hold (it is still
/// computed: nothing inside the range is refused, nothing outside it silently trusted).
pub fn validity_warnings(hinge: &Hinge, method: Method) -> Vec<String> {
    let mut out = Vec::new();
    if let Profile::Circular { radius } = hinge.profile {
        let tr = hinge.thickness / radius;
        let (lo, hi) = CHECKED_T_OVER_R;
        if !(lo..=hi).contains(&tr) {
            out.push(format!(
                "t/R = {tr:.3} lies outside {lo}-{hi}, the range over which the beam integral was checked against the FEM"
            ));
        }
        if method == Method::PwSimple && tr > PW_SIMPLE_T_OVER_R {
            out.push(format!(
                "t/R = {tr:.3} is above {PW_SIMPLE_T_OVER_R}: the simplified Paros-Weisbord formula is a thin-notch approximation (over 10 % off here; see hinge-table)"
            ));
        }
    }
    out
}

/// The finest mesh of the FEM and its solve, for peer solvers (`hinge --export-mesh`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MeshExport {
    /// Refinement level.
    pub level: usize,
    /// `stress` or `strain`.
    pub plane: &'static str,
    /// Pa.
    pub youngs: f64,
    /// 1.
    pub poisson: f64,
    /// m.
    pub width: f64,
    /// N·m, the applied moment.
    pub moment: f64,
    /// Node columns.
    pub cols: usize,
    /// Node rows.
    pub rows: usize,
    /// Node coordinates, m.
    pub coords: Vec<[f64; 2]>,
    /// 9-node elements.
    pub elements: Vec<[usize; 9]>,
    /// Node order within an element.
    pub element_order: &'static str,
    /// Columns of the two end sections.
    pub section_columns: [usize; 2],
    /// Clamped column.
    pub clamped_column: usize,
    /// Loaded column.
    pub loaded_column: usize,
    /// N·m/rad.
    pub k_bend: f64,
    /// Unknowns.
    pub unknowns: usize,
    /// s, the solve's wall time (filled in by the caller, which owns the clock).
    pub solve_seconds: f64,
}

/// Solves the finest (level 4) mesh of [`hinge`]'s FEM and returns it with its result.
pub fn mesh_export(hinge: &Hinge, m: &Material, plane: Plane) -> Result<MeshExport, HingeError> {
    let density = MeshDensity::default();
    let level = 4;
    let sol = hinge2d::solve(hinge, m, plane, &density, level)?;
    let mesh = hinge2d::mesh(hinge, &density, level);
    Ok(MeshExport {
        level,
        plane: match plane {
            Plane::Stress => "stress",
            Plane::Strain => "strain",
        },
        youngs: m.youngs,
        poisson: m.poisson,
        width: hinge.width,
        moment: sol.moment,
        cols: mesh.cols,
        rows: mesh.rows,
        coords: mesh.coords.iter().map(|p| [p.0, p.1]).collect(),
        elements: mesh.elements(),
        element_order: "9 nodes, x fastest then y: (i, j) = (k % 3, k / 3)",
        section_columns: mesh.section_columns(),
        clamped_column: 0,
        loaded_column: mesh.cols - 1,
        k_bend: sol.k_bend,
        unknowns: sol.dofs,
        solve_seconds: 0.0,
    })
}

/// One row of `hinge-table`.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `t_over_r` | 1 | throat over notch radius |
/// | `k_beam`, `k_pw_simple`, `k_fem` | N·m/rad | the three methods |
/// | `beam_over_fem`, `pw_over_fem` | 1 | ratios |
/// | `fem_mesh_error` | 1 | relative change of the last refinement |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TableRow {
    /// t/R.
    pub t_over_r: f64,
    /// Beam integral.
    pub k_beam: f64,
    /// Simplified Paros-Weisbord.
    pub k_pw_simple: f64,
    /// FEM.
    pub k_fem: f64,
    /// Ratio.
    pub beam_over_fem: f64,
    /// Ratio.
    pub pw_over_fem: f64,
    /// Mesh error.
    pub fem_mesh_error: f64,
}

/// The throat-to-radius ratios of `hinge-table`.
pub const TABLE_RATIOS: [f64; 7] = [0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0];

/// `cellinject hinge-table`: circular notches of `radius` and `width` at every ratio of
/// [`TABLE_RATIOS`]. The JSON is the list of rows.
pub fn table(
    radius: f64,
    width: f64,
    m: &Material,
    plane: Plane,
) -> Result<Vec<TableRow>, HingeError> {
    check_material(m)?;
    TABLE_RATIOS
        .iter()
        .map(|&tr| {
            let h = Hinge {
                profile: Profile::Circular { radius },
                thickness: tr * radius,
                width,
            };
            h.validate()?;
            let beam = h.k_bend(m);
            let pw = paros_weisbord_simplified(&h, m)?;
            let c = hinge2d::converge(&h, m, plane, &MeshDensity::default())?;
            for (q, v) in [
                ("k_beam", beam),
                ("k_pw_simple", pw),
                ("k_fem", c.k_bend),
                ("beam / FEM", beam / c.k_bend),
                ("PW / FEM", pw / c.k_bend),
            ] {
                finite(q, v)?;
            }
            Ok(TableRow {
                t_over_r: tr,
                k_beam: beam,
                k_pw_simple: pw,
                k_fem: c.k_bend,
                beam_over_fem: beam / c.k_bend,
                pw_over_fem: pw / c.k_bend,
                fem_mesh_error: c.error_estimate,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    #[test]
    fn non_finite_angles_and_bad_materials_name_their_flag() {
        let h = Hinge {
            profile: Profile::Circular { radius: 2e-3 },
            thickness: 1e-3,
            width: 5e-3,
        };
        let m = Material::x2crni18_9();
        let e = hinge(&h, &m, Method::Beam, Some(f64::NAN)).unwrap_err();
        assert!(matches!(
            e,
            HingeError::Flexure(FlexureError::Invalid { name: "angle", .. })
        ));
        let bad = Material { poisson: 0.7, ..m };
        let e = hinge(&h, &bad, Method::Beam, None).unwrap_err();
        assert!(matches!(
            e,
            HingeError::Flexure(FlexureError::Invalid {
                name: "poisson",
                ..
            })
        ));
        // Stress at an angle is linear in it, and the safety factor its inverse.
        let r = hinge(&h, &m, Method::Beam, Some(2e-3)).unwrap();
        let s = r.stress.unwrap();
        assert!((s - r.max_stress_per_rad * 2e-3).abs() <= 1e-9 * s);
        assert!((r.safety_factor.unwrap() - m.yield_strength / s).abs() < 1e-12);
    }
}
