//! `cellinject.fea`: the whole manipulator on FEM joints (`cellinject fea`), with the
//! same joint cache as the CLI.

use std::path::PathBuf;

use cellinject_config::Description;
use cellinject_fea::{FeaError, FeaModel, FeaOptions, PreloadKind};
use pyo3::prelude::*;

use crate::{Kind, description, err, input, to_py};

fn fea_error(e: FeaError) -> PyErr {
    match e {
        FeaError::PullingForce { .. } | FeaError::PushCapacity { .. } => {
            input(format!("forces: {e}"))
        }
        FeaError::NonFinite { ref key, .. } if key.starts_with("F1") => {
            input(format!("forces: {e}"))
        }
        FeaError::Level { .. } => input(format!("level: {e}")),
        e if e.is_input() => input(e.to_string()),
        e => err(Kind::NotConverged, e.to_string()),
    }
}

/// The model's options from the arguments, checked.
fn options(level: i64, preload: &str) -> PyResult<FeaOptions> {
    let level = usize::try_from(level)
        .ok()
        .filter(|l| cellinject_fea::LEVELS.contains(l))
        .ok_or_else(|| input(format!("level must be 1, 2 or 3, got {level}")))?;
    let preload = match preload {
        "deflection" => PreloadKind::Deflection,
        "torque" => PreloadKind::Torque,
        other => {
            return Err(input(format!(
                "preload must be deflection or torque, got `{other}`"
            )));
        }
    };
    Ok(FeaOptions { level, preload })
}

/// The structural model of `d` on its FEM joints (from the cache when `cache`).
fn build(d: &Description, o: FeaOptions, cache: bool) -> Result<FeaModel, FeaError> {
    let store = cellinject_fea::default_store(cache);
    FeaModel::build(&d.design, &d.structure, o, store.as_ref())
}

/// The consistency warnings between `[flexures]` and `[structure]`: only when the
/// description sets `[structure]` itself (as the CLI).
fn warnings(d: &Description, all: Vec<String>) -> Vec<String> {
    if d.structure_given { all } else { Vec::new() }
}

/// One static load case of the whole manipulator: the fields of
/// ``cellinject fea --approach N --forces F11,F12 --format json`` (docs/json.md).
///
/// The joints' 3-D FEM is solved (or read from the joint cache the CLI shares,
/// ``$XDG_CACHE_HOME/cellinject``) with the GIL released.
///
/// Args:
///     approach: 1 or 2.
///     forces: ``(F11, F12)``, N, on the motor loops (negative: compressive).
///     level: the joints' mesh level, 1 to 3 (1: under a second per joint).
///     preload: approach 2's pre-tension of J3, ``"deflection"`` or ``"torque"``.
///     config: a description file; None: the prototype.
///     cache: read and write the joint cache (False: solve afresh).
///
/// Returns:
///     dict: ``dx``, ``dy``, ``dz`` (m), ``stack_force`` (N), ``joints`` (von Mises, Pa;
///     safety factors), ...
///
/// Raises:
///     InputError: a pulling force, one beyond the push capacity, NaN, a bad level.
///     NotConverged: the equilibrium was not found.
///
/// Example:
///     >>> from cellinject import fea
///     >>> r = fea.run(1, (-100.0, -100.0))
///     >>> r["dx"] != 0.0
///     True
#[pyfunction]
#[pyo3(signature = (approach, forces, level=1, preload="deflection", config=None, cache=true))]
fn fea_run(
    py: Python<'_>,
    approach: i64,
    forces: &Bound<'_, PyAny>,
    level: i64,
    preload: &str,
    config: Option<PathBuf>,
    cache: bool,
) -> PyResult<Py<PyAny>> {
    let a = crate::approach("approach", approach)?;
    let o = options(level, preload)?;
    let d = description(config.as_deref())?;
    let forces = match crate::arrays::vector("forces", forces)?[..] {
        [a, b] => [a, b],
        ref other => {
            return Err(input(format!(
                "forces takes (F11, F12), got {} numbers",
                other.len()
            )));
        }
    };
    cellinject_fea::check_forces(&d.design, forces).map_err(fea_error)?;
    let mut r = py
        .detach(|| build(&d, o, cache)?.solve(a, forces))
        .map_err(fea_error)?;
    r.warnings = warnings(&d, r.warnings);
    to_py(py, &r)
}

/// The paper's Tables 1 and 2 recomputed beside the published values: the fields of
/// ``cellinject fea tables --format json``.
///
/// Args:
///     level: the joints' mesh level, 1 to 3.
///     preload: ``"deflection"`` or ``"torque"``.
///     config: a description file; None: the prototype.
///     cache: read and write the joint cache.
///
/// Returns:
///     dict: ``tables`` (``cases`` with ``paper`` and model ``dx``, ``dy``, m), ...
///
/// Example:
///     >>> from cellinject import fea
///     >>> [t["table"] for t in fea.tables()["tables"]]
///     [1, 2]
#[pyfunction]
#[pyo3(signature = (level=1, preload="deflection", config=None, cache=true))]
fn fea_tables(
    py: Python<'_>,
    level: i64,
    preload: &str,
    config: Option<PathBuf>,
    cache: bool,
) -> PyResult<Py<PyAny>> {
    let o = options(level, preload)?;
    let d = description(config.as_deref())?;
    let mut r = py
        .detach(|| build(&d, o, cache)?.tables())
        .map_err(fea_error)?;
    r.warnings = warnings(&d, r.warnings);
    to_py(py, &r)
}

/// Natural frequencies and mode shapes of the assembled, pre-tensioned manipulator:
/// the fields of ``cellinject fea modes --format json``.
///
/// Args:
///     approach: 1 or 2; None: the description's ``twin.approach``.
///     count: modes to list, 1 to 16.
///     level: the joints' mesh level, 1 to 3.
///     preload: ``"deflection"`` or ``"torque"``.
///     config: a description file; None: the prototype.
///     cache: read and write the joint cache.
///
/// Returns:
///     dict: ``modes`` (``frequency``, Hz; ``description``; ``tip_shape``, m), ...
///
/// Example:
///     >>> from cellinject import fea
///     >>> len(fea.modes(count=3)["modes"])
///     3
#[pyfunction]
#[pyo3(signature = (approach=None, count=8, level=1, preload="deflection", config=None, cache=true))]
fn fea_modes(
    py: Python<'_>,
    approach: Option<i64>,
    count: i64,
    level: i64,
    preload: &str,
    config: Option<PathBuf>,
    cache: bool,
) -> PyResult<Py<PyAny>> {
    let o = options(level, preload)?;
    let count = usize::try_from(count)
        .ok()
        .filter(|c| (1..=16).contains(c))
        .ok_or_else(|| input(format!("count must lie in 1..=16, got {count}")))?;
    let d = description(config.as_deref())?;
    let a = match approach {
        Some(n) => crate::approach("approach", n)?,
        None => d.rig.approach,
    };
    let mut r = py
        .detach(|| build(&d, o, cache)?.modes(a, count))
        .map_err(fea_error)?;
    r.warnings = warnings(&d, r.warnings);
    to_py(py, &r)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(fea_run, m)?)?;
    m.add_function(wrap_pyfunction!(fea_tables, m)?)?;
    m.add_function(wrap_pyfunction!(fea_modes, m)?)
}
