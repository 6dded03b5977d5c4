//! The Python bindings of cellinject: the extension module `cellinject._cellinject`,
//! which the pure-Python package in `python/cellinject` wraps into the modules `dic`,
//! `model`, `flexure`, `fea`, `hysteresis`, `twin` and `runs`.
//!
//! A front end like the binary: every function converts its arguments, checks them
//! (naming the argument in a `cellinject.InputError`), calls one library function and
//! converts the result. Reports go through `serde_json`, so that a result's dict has
//! exactly the CLI's JSON field names, nesting and SI units (docs/json.md). Long work
//! (DIC, FEA, the twin) runs with the GIL released ([`Python::detach`]). No logic of
//! its own: what the CLI and Python share lives in the library crates.
//!
//! The workspace's `unsafe_code = "forbid"` holds here too: PyO3 0.30's macros expand
//! to no `unsafe` in this crate (the FFI lives in pyo3 itself).

use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyList, PyType};

mod arrays;
mod design;
mod dic;
mod fea;
mod flexure;
mod hysteresis;
mod model;
mod rig;
mod runs;
mod twin;
mod vision;

/// The exception classes of `cellinject._errors`, looked up once.
struct Classes {
    error: Py<PyType>,
    input: Py<PyType>,
    not_converged: Py<PyType>,
}

static CLASSES: PyOnceLock<Classes> = PyOnceLock::new();

fn classes(py: Python<'_>) -> PyResult<&Classes> {
    CLASSES.get_or_try_init(py, || {
        let m = py.import("cellinject._errors")?;
        let get = |name: &str| -> PyResult<Py<PyType>> {
            Ok(m.getattr(name)?.cast_into::<PyType>()?.unbind())
        };
        Ok(Classes {
            error: get("Error")?,
            input: get("InputError")?,
            not_converged: get("NotConverged")?,
        })
    })
}

/// Which of the package's exceptions an error is.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Kind {
    /// `cellinject.InputError` (also a `ValueError`): a bad argument, named.
    Input,
    /// `cellinject.NotConverged` (also a `RuntimeError`): the computation ran but gave
    /// nothing usable.
    NotConverged,
    /// `cellinject.Error`: anything else (a file that cannot be written, a device).
    Other,
}

/// An exception of the package's hierarchy with `msg`.
pub(crate) fn err(kind: Kind, msg: impl Into<String>) -> PyErr {
    let msg = msg.into();
    Python::attach(|py| match classes(py) {
        Ok(c) => {
            let t = match kind {
                Kind::Input => &c.input,
                Kind::NotConverged => &c.not_converged,
                Kind::Other => &c.error,
            };
            PyErr::from_type(t.bind(py).clone(), msg)
        }
        Err(e) => e,
    })
}

/// `cellinject.InputError(msg)`.
pub(crate) fn input(msg: impl Into<String>) -> PyErr {
    err(Kind::Input, msg)
}

/// Refuses a NaN or an infinity, naming the argument.
pub(crate) fn finite(name: &str, v: f64) -> PyResult<f64> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(input(format!("{name} must be a finite number, got {v}")))
    }
}

/// Refuses a NaN, an infinity or a value not above 0, naming the argument.
pub(crate) fn positive(name: &str, v: f64) -> PyResult<f64> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(input(format!("{name} must be a positive number, got {v}")))
    }
}

/// The description file at `path` (`config`), parsed and validated, or the embedded
/// prototype; errors name the file and the key.
pub(crate) fn description(
    path: Option<&std::path::Path>,
) -> PyResult<cellinject_config::Description> {
    let Some(path) = path else {
        return Ok(cellinject_config::prototype());
    };
    let text = std::fs::read_to_string(path).map_err(|e| {
        input(format!(
            "config: cannot read description file `{}`: {e}",
            path.display()
        ))
    })?;
    cellinject_config::parse(&text).map_err(|e| {
        input(format!(
            "config: description file `{}`: {e}",
            path.display()
        ))
    })
}

/// The pre-tensioning approach numbered `n` (1 or 2).
pub(crate) fn approach(name: &str, n: i64) -> PyResult<cellinject_model::Approach> {
    u8::try_from(n)
        .ok()
        .and_then(cellinject_model::Approach::from_number)
        .ok_or_else(|| input(format!("{name} must be 1 or 2, got {n}")))
}

/// A serialisable report as Python objects: dicts with the JSON's field names (in its
/// order), lists, floats, ints, bools, str, None: exactly what `json.loads` of the
/// CLI's `--format json` gives.
pub(crate) fn to_py<T: serde::Serialize>(py: Python<'_>, v: &T) -> PyResult<Py<PyAny>> {
    let v = serde_json::to_value(v).map_err(|e| err(Kind::Other, e.to_string()))?;
    value(py, &v)
}

fn value(py: Python<'_>, v: &serde_json::Value) -> PyResult<Py<PyAny>> {
    use serde_json::Value;
    Ok(match v {
        Value::Null => py.None(),
        Value::Bool(b) => b.into_pyobject(py)?.to_owned().into_any().unbind(),
        Value::Number(n) => {
            if let Some(i) = n.as_i64() {
                i.into_pyobject(py)?.into_any().unbind()
            } else if let Some(u) = n.as_u64() {
                u.into_pyobject(py)?.into_any().unbind()
            } else {
                n.as_f64()
                    .unwrap_or(f64::NAN)
                    .into_pyobject(py)?
                    .into_any()
                    .unbind()
            }
        }
        Value::String(s) => s.into_pyobject(py)?.into_any().unbind(),
        Value::Array(a) => {
            let l = PyList::empty(py);
            for x in a {
                l.append(value(py, x)?)?;
            }
            l.into_any().unbind()
        }
        Value::Object(o) => {
            let d = PyDict::new(py);
            for (k, x) in o {
                d.set_item(k, value(py, x)?)?;
            }
            d.into_any().unbind()
        }
    })
}

/// The extension module: every function of the package, registered flat under the
/// module-qualified names the Python modules re-export.
#[pymodule]
fn _cellinject(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    design::register(m)?;
    dic::register(m)?;
    model::register(m)?;
    flexure::register(m)?;
    fea::register(m)?;
    hysteresis::register(m)?;
    twin::register(m)?;
    runs::register(m)?;
    rig::register(m)?;
    vision::register(m)?;
    Ok(())
}
