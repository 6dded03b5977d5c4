//! `cellinject.runs`: the run database read back (`cellinject runs list | show |
//! export --format json`).

use std::path::{Path, PathBuf};

use cellinject_plate::Plate;
use cellinject_records::{Records, RecordsError};
use pyo3::prelude::*;

use crate::{Kind, err, input, to_py};

pub(crate) fn records_error(e: RecordsError) -> PyErr {
    match e {
        RecordsError::Sql(_) => err(Kind::Other, e.to_string()),
        RecordsError::Foreign { .. }
        | RecordsError::Newer { .. }
        | RecordsError::Missing { .. }
        | RecordsError::Unreadable { .. } => input(format!("db {e}")),
        other => input(other.to_string()),
    }
}

/// A run database that must exist (reading never creates one).
fn open_existing(p: &Path) -> PyResult<Records> {
    Records::open_existing(p).map_err(|e| match e {
        RecordsError::Missing { .. } => input(format!(
            "db {e} (a run creates it: cellinject.twin.run(db=...))"
        )),
        e => records_error(e),
    })
}

/// The plate file `p`, parsed and checked, and its text.
pub(crate) fn read_plate(p: &Path) -> PyResult<(Plate, String)> {
    let text = std::fs::read_to_string(p)
        .map_err(|e| input(format!("plate `{}`: cannot read: {e}", p.display())))?;
    let plate = cellinject_config::plate::parse(&text)
        .map_err(|e| input(format!("plate `{}`: {e}", p.display())))?;
    plate
        .check()
        .map_err(|e| input(format!("plate `{}`: {e}", p.display())))?;
    Ok((plate, text))
}

/// Every run of a database, one dict each: ``cellinject runs list --format json``.
///
/// Args:
///     db: the run database (``runs.sqlite``).
///
/// Returns:
///     list[dict]: ``id``, ``created`` (s since the epoch), ``status``, ``seed``,
///     ``backend``, ``settings``, ``calibration``, ``sim_time_s``, ``cell_time_s``,
///     ``cells_found``, ``stopped``, ``resumed``.
///
/// Raises:
///     InputError: no such file, or not a cellinject run database.
///
/// Example:
///     >>> from cellinject import runs
///     >>> [r["status"] for r in runs.list("runs.sqlite")]  # doctest: +SKIP
#[pyfunction]
fn runs_list(py: Python<'_>, db: PathBuf) -> PyResult<Py<PyAny>> {
    let db = open_existing(&db)?;
    to_py(py, &db.runs().map_err(records_error)?)
}

/// One run with its attempts and events: ``cellinject runs show``.
///
/// Args:
///     db: the run database.
///     run: the run's id; None: the latest.
///
/// Returns:
///     dict: ``run`` (as in :func:`list`), ``attempts`` (as in :func:`attempts`),
///     ``events`` (``t`` in s, ``from``, ``event``, ``to``, ``reason``).
///
/// Example:
///     >>> from cellinject import runs
///     >>> runs.show("runs.sqlite")["run"]["status"]  # doctest: +SKIP
///     'finished'
#[pyfunction]
#[pyo3(signature = (db, run=None))]
fn runs_show(py: Python<'_>, db: PathBuf, run: Option<i64>) -> PyResult<Py<PyAny>> {
    let db = open_existing(&db)?;
    let r = db.run(run).map_err(records_error)?;
    let a = db.attempts(r.id).map_err(records_error)?;
    let e = db.events(r.id).map_err(records_error)?;
    to_py(
        py,
        &serde_json::json!({ "run": r, "attempts": a, "events": e }),
    )
}

/// A run's attempts, one dict per cell attempt: ``cellinject runs export --format
/// json``.
///
/// Args:
///     db: the run database.
///     run: the run's id; None: the latest.
///
/// Returns:
///     list[dict]: ``cell``, ``well`` (``[row, col]``), ``x_m``, ``y_m``,
///     ``diameter_m``, ``tip_error_m`` (m; the twin's truth), ``measured_tip_error_m``,
///     ``depth_m``, ``dose_fraction``, ``alive``, ``outcome``, ``reason``, ``t_start``,
///     ``t_end`` (s), ``transitions``.
///
/// Example:
///     >>> from cellinject import runs
///     >>> [a["outcome"] for a in runs.attempts("runs.sqlite")]  # doctest: +SKIP
///     ['injected', 'injected']
#[pyfunction]
#[pyo3(signature = (db, run=None))]
fn runs_attempts(py: Python<'_>, db: PathBuf, run: Option<i64>) -> PyResult<Py<PyAny>> {
    let db = open_existing(&db)?;
    let r = db.run(run).map_err(records_error)?;
    to_py(py, &db.attempts(r.id).map_err(records_error)?)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(runs_list, m)?)?;
    m.add_function(wrap_pyfunction!(runs_show, m)?)?;
    m.add_function(wrap_pyfunction!(runs_attempts, m)?)
}
