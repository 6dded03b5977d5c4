//! `cellinject.model`: the mechanism model (`tension`, `model`, `reproduce`).

use std::path::PathBuf;

use cellinject_model::ModelError;
use pyo3::prelude::*;

use crate::{Kind, approach, description, err, input, to_py};

fn model_error(e: ModelError) -> PyErr {
    match e {
        ModelError::NotConverged { .. } => err(Kind::NotConverged, e.to_string()),
        other => input(format!("config: {other}")),
    }
}

/// The pre-tension analysis of one approach: the fields of
/// ``cellinject tension --approach N --format json`` (docs/json.md), SI units.
///
/// Args:
///     approach: 1 (assembly translation along the drives, Sec. 2.1) or 2 (assembly
///         deflection of J3, Sec. 2.2).
///     config: a description file (TOML); None: the embedded prototype.
///
/// Returns:
///     dict: ``F10`` (N), ``dX`` (m), ``margins``, ``warnings``, ...
///
/// Raises:
///     InputError: an approach other than 1 or 2, or a bad description file.
///     NotConverged: the mechanism's equilibrium did not converge.
///
/// Example:
///     >>> from cellinject import model
///     >>> r = model.tension(1)
///     >>> r["approach"], len(r["F10"])
///     (1, 3)
#[pyfunction]
#[pyo3(signature = (approach, config=None))]
fn model_tension(py: Python<'_>, approach: i64, config: Option<PathBuf>) -> PyResult<Py<PyAny>> {
    let a = crate::approach("approach", approach)?;
    let d = description(config.as_deref())?;
    let r = py
        .detach(|| cellinject_core::tension::tension(&d.name, &d.design, a))
        .map_err(model_error)?;
    to_py(py, &r)
}

/// The Jacobians J, L, W, the compliance B_l and the large-deflection check: the
/// fields of ``cellinject model --format json``.
///
/// Args:
///     config: a description file (TOML); None: the embedded prototype.
///
/// Returns:
///     dict: ``J``, ``L``, ``W`` (rows), ``B_l`` (m/N), ``linearisation``.
///
/// Raises:
///     InputError: a bad description file.
///
/// Example:
///     >>> from cellinject import model
///     >>> len(model.model()["J"])
///     3
#[pyfunction]
#[pyo3(signature = (config=None))]
fn model_model(py: Python<'_>, config: Option<PathBuf>) -> PyResult<Py<PyAny>> {
    let d = description(config.as_deref())?;
    let r = py
        .detach(|| cellinject_core::model::model(&d.name, &d.mechanism()))
        .map_err(model_error)?;
    to_py(py, &r)
}

/// Eqs. 37-58 of the paper recomputed beside the published values: the fields of
/// ``cellinject reproduce --format json``.
///
/// Args:
///     config: a description file (TOML); None: the embedded prototype.
///
/// Returns:
///     dict: ``figures`` (``eq``, ``paper``, ``computed``, ``rel_diff``, ``status``),
///     ``agree``, ``computed``, ...
///
/// Example:
///     >>> from cellinject import model
///     >>> r = model.reproduce()
///     >>> r["agree"] == r["computed"]
///     True
#[pyfunction]
#[pyo3(signature = (config=None))]
fn model_reproduce(py: Python<'_>, config: Option<PathBuf>) -> PyResult<Py<PyAny>> {
    let d = description(config.as_deref())?;
    let r = py
        .detach(|| cellinject_core::reproduce::reproduce(&d.name, &d.design))
        .map_err(|e| input(format!("config: {e}")))?;
    to_py(py, &r)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let _ = approach;
    m.add_function(wrap_pyfunction!(model_tension, m)?)?;
    m.add_function(wrap_pyfunction!(model_model, m)?)?;
    m.add_function(wrap_pyfunction!(model_reproduce, m)?)
}
