//! `cellinject.hysteresis`: hysteresis models fitted to (voltage, displacement) data,
//! applied and inverted (`cellinject hysteresis fit | invert`).

use cellinject_core::hysteresis::{self as core, Kind as ModelKind, RangeError};
use cellinject_hysteresis::{AnyModel, HysteresisError, Model as _};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::{out, vector};
use crate::{Kind, err, input, to_py};

fn hysteresis_error(name: &str, e: HysteresisError) -> PyErr {
    match e {
        HysteresisError::Solver(_) => err(Kind::NotConverged, e.to_string()),
        HysteresisError::ConstantInput { .. } | HysteresisError::TooFewReversals { .. } => {
            input(format!("voltage: {e}"))
        }
        e => input(format!("{name}: {e}")),
    }
}

/// A fitted hysteresis model (Preisach or Prandtl-Ishlinskii): input in V, output in m.
///
/// Made by :func:`fit` or :meth:`from_json`; its JSON is the CLI's model file
/// (``hysteresis fit --out model.json``, read by ``hysteresis invert --model``).
#[pyclass(module = "cellinject.hysteresis", name = "Model", frozen)]
pub(crate) struct PyModel {
    model: AnyModel,
    report: Option<core::FitReport>,
}

#[pymethods]
impl PyModel {
    /// The model's output (m) for ``voltages`` (V) applied in order from relaxed at 0 V.
    ///
    /// Args:
    ///     voltages: a 1-D array (any real dtype) or sequence, V.
    ///
    /// Returns:
    ///     numpy.ndarray: float64 displacements, m.
    ///
    /// Raises:
    ///     InputError: a NaN or infinite voltage (named with its index), not 1-D.
    ///
    /// Example:
    ///     >>> y = m.apply([0.0, 50.0, 100.0, 50.0])
    fn apply(&self, py: Python<'_>, voltages: &Bound<'_, PyAny>) -> PyResult<Py<PyAny>> {
        let v = vector("voltages", voltages)?;
        let mut m = self.model.clone();
        m.reset();
        let y: Vec<f64> = py.detach(|| v.iter().map(|x| m.apply(*x)).collect());
        Ok(out(py, y))
    }

    /// The voltages that make the modelled actuator, relaxed at 0 V, follow
    /// ``displacements`` (m): ``cellinject hysteresis invert``.
    ///
    /// Args:
    ///     displacements: a 1-D array or sequence of target displacements, m.
    ///
    /// Returns:
    ///     dict: ``voltage`` (NumPy array, V), ``predicted`` (NumPy array, m: the model's
    ///     output for them), and the fields of ``hysteresis invert --format json``:
    ///     ``samples``, ``voltage_range`` (V), ``residual`` (m).
    ///
    /// Raises:
    ///     InputError: a target out of the model's reach, a NaN (named).
    ///
    /// Example:
    ///     >>> cmd = m.invert([1e-6, 2e-6, 4e-6])["voltage"]
    fn invert(&self, py: Python<'_>, displacements: &Bound<'_, PyAny>) -> PyResult<Py<PyAny>> {
        let t = vector("displacements", displacements)?;
        if t.is_empty() {
            return Err(input("displacements must hold at least one target"));
        }
        let r = py
            .detach(|| core::invert(&self.model, &t, false))
            .map_err(|e| hysteresis_error("displacements", e))?;
        let d = to_py(py, &r)?;
        let d = d.bind(py).cast::<PyDict>()?;
        d.set_item("voltage", out(py, r.volts))?;
        d.set_item("predicted", out(py, r.predicted))?;
        Ok(d.clone().into_any().unbind())
    }

    /// The model file's JSON text, as ``hysteresis fit --out model.json`` writes it.
    fn to_json(&self) -> PyResult<String> {
        serde_json::to_string_pretty(&self.model).map_err(|e| err(Kind::Other, e.to_string()))
    }

    /// A model from the JSON text of a model file (``hysteresis fit --out``).
    ///
    /// Raises:
    ///     InputError: not a model file (what is wrong, with the line).
    #[staticmethod]
    fn from_json(text: &str) -> PyResult<PyModel> {
        let model: AnyModel = serde_json::from_str(text)
            .map_err(|e| input(format!("text: not a model from `hysteresis fit`: {e}")))?;
        Ok(PyModel {
            model,
            report: None,
        })
    }

    /// The fit's report, the fields of ``hysteresis fit --format json`` (``model``,
    /// ``rms``, ``max`` in m, ``rms_relative``, ``samples``, ``data``); None for a model
    /// read with :meth:`from_json`.
    #[getter]
    fn report(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        match &self.report {
            Some(r) => to_py(py, r),
            None => Ok(py.None()),
        }
    }

    /// ``"preisach"`` or ``"pi"``.
    #[getter]
    fn kind(&self) -> &'static str {
        match self.model {
            AnyModel::Preisach(_) => "preisach",
            AnyModel::Pi(_) => "pi",
        }
    }

    fn __repr__(&self) -> String {
        format!("<cellinject.hysteresis.Model {}>", self.kind())
    }
}

/// Fits a hysteresis model by non-negative least squares to a recording in time
/// order that starts relaxed at 0 V: ``cellinject hysteresis fit``.
///
/// Held voltages (dwells, DAC steps) merge into one sample; a reversal must exceed 10
/// times the voltage's noise, measured from the data.
///
/// Args:
///     voltage: 1-D array (any real dtype) or sequence, V.
///     displacement: the same length, m.
///     model: ``"preisach"``, ``"pi"`` or ``"pi-asym"``.
///     size: grid cells per axis (Preisach) or plays (PI), 2 to 60.
///     v_max: the top of the model's input range, V (default: the data's highest).
///
/// Returns:
///     Model: with ``apply``, ``invert``, ``to_json`` and the fit's ``report``.
///
/// Raises:
///     InputError: lengths differ, a NaN, too few reversals, a voltage out of range.
///     NotConverged: the least-squares solve failed.
///
/// Example:
///     >>> import numpy as np
///     >>> from cellinject import hysteresis
///     >>> v = np.concatenate([np.linspace(0, 100, 50), np.linspace(100, 20, 40),
///     ...                     np.linspace(20, 80, 30), np.linspace(80, 0, 40)])
///     >>> d = 1e-7 * v + 2e-10 * v * (100 - v) * np.sign(np.gradient(v))
///     >>> m = hysteresis.fit(v, d, size=8)
///     >>> m.report["rms_relative"] < 0.05
///     True
#[pyfunction]
#[pyo3(signature = (voltage, displacement, model="preisach", size=core::DEFAULT_SIZE as i64, v_max=None))]
fn hysteresis_fit(
    py: Python<'_>,
    voltage: &Bound<'_, PyAny>,
    displacement: &Bound<'_, PyAny>,
    model: &str,
    size: i64,
    v_max: Option<f64>,
) -> PyResult<PyModel> {
    let kind = ModelKind::from_name(model).ok_or_else(|| {
        input(format!(
            "model must be preisach, pi or pi-asym, got `{model}`"
        ))
    })?;
    if !(2..=60).contains(&size) {
        return Err(input(format!("size must lie in 2..=60, got {size}")));
    }
    let volts = vector("voltage", voltage)?;
    let disp = vector("displacement", displacement)?;
    if volts.len() != disp.len() {
        return Err(input(format!(
            "voltage and displacement differ in length: {} and {}",
            volts.len(),
            disp.len()
        )));
    }
    if volts.is_empty() {
        return Err(input("voltage: no samples"));
    }
    if let Some(v) = v_max {
        crate::positive("v_max", v)?;
    }
    let range = core::fit_range(&volts, v_max).map_err(|e| match e {
        RangeError::NoPositiveVoltage => input("voltage: no voltage above 0 V (and no v_max)"),
        e @ RangeError::Outside { .. } => input(format!("voltage: {e}")),
    })?;
    let r = py
        .detach(|| core::fit(kind, size as usize, range, &volts, &disp))
        .map_err(|e| hysteresis_error("voltage", e))?;
    Ok(PyModel {
        model: r.model.clone(),
        report: Some(r),
    })
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyModel>()?;
    m.add_function(wrap_pyfunction!(hysteresis_fit, m)?)
}
