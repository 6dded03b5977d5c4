//! `cellinject.flexure`: one flexure hinge (`cellinject hinge`).

use cellinject_core::hinge::{self as core, HingeError, Method, ProfileKind};
use cellinject_fem::hinge2d::Plane;
use cellinject_flexure::{FlexureError, Hinge, Material};
use pyo3::prelude::*;

use crate::{Kind, err, input, to_py};

fn hinge_error(e: HingeError) -> PyErr {
    match e {
        HingeError::Flexure(FlexureError::Invalid {
            name,
            value,
            reason,
        }) => {
            // The CLI's `--yield` is Python's `yield_strength` (`yield` is a keyword).
            let name = if name == "yield" {
                "yield_strength"
            } else {
                name
            };
            input(format!("{name} {value}: {reason}"))
        }
        HingeError::Flexure(other) => input(format!("method: {other}")),
        HingeError::Fem(e) => err(Kind::NotConverged, format!("hinge FEM: {e}")),
        e => input(e.to_string()),
    }
}

/// One flexure hinge from its beam integrals (or its 2-D FEM for the compliant
/// stiffness): the fields of ``cellinject hinge --format json`` (docs/json.md), SI
/// units.
///
/// Args:
///     profile: ``"circular"``, ``"corner"``, ``"elliptic"`` or ``"leaf"``.
///     thickness: throat thickness t, m.
///     width: width b out of the bending plane, m.
///     radius: notch radius (circular), fillet radius (corner) or depth (elliptic), m.
///     length: total length (corner, elliptic, leaf), m.
///     youngs: Young's modulus, Pa (X2CrNi18-9 by default).
///     poisson: Poisson's ratio.
///     yield_strength: Pa.
///     method: ``"beam"``, ``"pw-simple"`` or ``"fem"``.
///     plane: ``"stress"`` or ``"strain"`` (FEM only).
///     angle: a working rotation, rad: adds ``stress`` and ``safety_factor``.
///
/// Returns:
///     dict: ``k_bend`` (N·m/rad), ``k_axial`` (N/m), ``compliance`` (6x6), ...
///
/// Raises:
///     InputError: a dimension missing, NaN, negative or zero (named).
///
/// Example:
///     >>> from cellinject import flexure
///     >>> r = flexure.hinge("circular", thickness=0.5e-3, width=5e-3, radius=2e-3)
///     >>> round(r["k_bend"], 2)
///     8.68
#[pyfunction]
#[pyo3(signature = (profile, thickness, width, radius=None, length=None, youngs=None,
    poisson=None, yield_strength=None, method="beam", plane="stress", angle=None))]
#[allow(clippy::too_many_arguments)]
fn flexure_hinge(
    py: Python<'_>,
    profile: &str,
    thickness: f64,
    width: f64,
    radius: Option<f64>,
    length: Option<f64>,
    youngs: Option<f64>,
    poisson: Option<f64>,
    yield_strength: Option<f64>,
    method: &str,
    plane: &str,
    angle: Option<f64>,
) -> PyResult<Py<PyAny>> {
    let kind = ProfileKind::from_name(profile).map_err(|e| input(format!("profile: {e}")))?;
    let profile = kind.profile(radius, length).map_err(hinge_error)?;
    let d = Material::x2crni18_9();
    let m = Material {
        youngs: youngs.unwrap_or(d.youngs),
        poisson: poisson.unwrap_or(d.poisson),
        yield_strength: yield_strength.unwrap_or(d.yield_strength),
    };
    let plane = match plane {
        "stress" => Plane::Stress,
        "strain" => Plane::Strain,
        other => {
            return Err(input(format!(
                "plane must be stress or strain, got `{other}`"
            )));
        }
    };
    let method = match method {
        "beam" => Method::Beam,
        "pw-simple" => Method::PwSimple,
        "fem" => Method::Fem(plane),
        other => {
            return Err(input(format!(
                "method must be beam, pw-simple or fem, got `{other}`"
            )));
        }
    };
    let hinge = Hinge {
        profile,
        thickness,
        width,
    };
    let r = py
        .detach(|| core::hinge(&hinge, &m, method, angle))
        .map_err(hinge_error)?;
    to_py(py, &r)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(flexure_hinge, m)?)
}
