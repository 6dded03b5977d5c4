//! `cellinject.design`: one design's figures, and the pieces of a design study that
//! `cellinject.design.optimise` drives with any `map` (the builtin, or a Dask
//! client's).

use std::path::PathBuf;

use cellinject_design::study::{Record, Settings, Study, Task};
use cellinject_design::{DesignError, EvalOptions, Fidelity, Space};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::{Kind, err, input, to_py};

fn design_error(e: DesignError) -> PyErr {
    if e.is_input() {
        input(e.to_string())
    } else {
        err(Kind::NotConverged, e.to_string())
    }
}

fn base_text(config: Option<&std::path::Path>) -> PyResult<String> {
    let Some(path) = config else {
        return Ok(cellinject_config::PROTOTYPE_TOML.to_string());
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
    })?;
    Ok(text)
}

fn parse_fidelity(name: &str) -> PyResult<Fidelity> {
    Fidelity::from_name(name).ok_or_else(|| {
        input(format!(
            "fidelity must be \"beam\" or \"fea\", got {name:?}"
        ))
    })
}

fn parse_level(n: i64) -> PyResult<usize> {
    match n {
        1 | 2 => Ok(n as usize),
        _ => Err(input(format!("level must be 1 or 2, got {n}"))),
    }
}

fn approach_opt(a: Option<i64>) -> PyResult<Option<u8>> {
    a.map(|n| crate::approach("approach", n).map(|a| a.number()))
        .transpose()
}

fn from_py<T: serde::de::DeserializeOwned>(
    py: Python<'_>,
    name: &str,
    v: &Bound<'_, PyAny>,
) -> PyResult<T> {
    let json = py.import("json")?;
    let text: String = json.call_method1("dumps", (v,))?.extract()?;
    serde_json::from_str(&text).map_err(|e| input(format!("{name}: {e}")))
}

/// One design's figures: the fields of ``cellinject design evaluate --format json``
/// (docs/json.md), SI units.
///
/// Args:
///     variables: description keys to override, e.g. ``{"geometry.b2": 0.2}``
///         (``section.key``; ``key[i]`` for one element of an array key); None: none.
///     config: a description file (TOML); None: the embedded prototype.
///     approach: 1 or 2; None: the description's ``twin.approach``.
///     fidelity: ``"beam"`` (closed-form joints, about a millisecond) or ``"fea"``
///         (the joints' 3-D FEM, about a second per new joint geometry; cached).
///     level: the FEM mesh level at ``"fea"`` fidelity (1 or 2).
///
/// Returns:
///     dict: ``range_m`` (``x``, ``y``), ``range_min_m``, ``first_mode_hz``,
///     ``safety_factors`` (``J1``, ``J2``, ``J3``), ``min_safety_factor``,
///     ``stack_margins``, ``coupling_m``, ``feasible``, ``violations``, ...
///
/// Raises:
///     InputError: an unknown key, a value out of its domain, a bad argument.
///     NotConverged: the model's equilibrium did not converge.
///
/// Example:
///     >>> from cellinject import design
///     >>> f = design.evaluate({"geometry.b2": 0.2})
///     >>> round(f["range_min_m"] * 1e6)
///     197
#[pyfunction]
#[pyo3(signature = (variables=None, config=None, approach=None, fidelity="beam", level=1))]
fn design_evaluate(
    py: Python<'_>,
    variables: Option<&Bound<'_, PyDict>>,
    config: Option<PathBuf>,
    approach: Option<i64>,
    fidelity: &str,
    level: i64,
) -> PyResult<Py<PyAny>> {
    let base = base_text(config.as_deref())?;
    let mut overrides = Vec::new();
    if let Some(vars) = variables {
        for (k, v) in vars.iter() {
            let key: String = k
                .extract()
                .map_err(|_| input("variables: keys must be strings like \"geometry.b2\""))?;
            let value: f64 = v
                .extract()
                .map_err(|_| input(format!("variables[{key:?}] must be a number")))?;
            let value = crate::finite(&format!("variables[{key:?}]"), value)?;
            overrides.push(cellinject_config::overrides::Override { key, value });
        }
    }
    let text = cellinject_config::overrides::apply(&base, &overrides)
        .map_err(|e| input(format!("variables: {e}")))?;
    let desc = cellinject_config::parse(&text).map_err(|e| input(e.to_string()))?;
    let options = EvalOptions {
        approach: approach_opt(approach)?.and_then(cellinject_model::Approach::from_number),
        fidelity: parse_fidelity(fidelity)?,
        level: parse_level(level)?,
    };
    let store = cellinject_fea::default_store(true);
    let f = py
        .detach(|| cellinject_design::evaluate(&desc, &options, store.as_ref()))
        .map_err(design_error)?;
    to_py(py, &f)
}

/// Evaluates one point of a study's task (the JSON of ``Study.task``): what a worker
/// of ``cellinject.design.optimise`` runs. Returns the point's record
/// (``variables`` and ``figures``, or ``error``).
///
/// Args:
///     task: the task's JSON text.
///     x: the point, one value per variable of the space.
///
/// Returns:
///     dict: ``variables`` and ``figures``, or ``variables`` and ``error``.
///
/// Raises:
///     InputError: a task that is not a study's, a point of the wrong length.
///
/// Example:
///     >>> from cellinject import design
///     >>> s = design.Study('[variables]\n"geometry.b2" = [0.1, 0.3]\n[objectives]\nmaximise = ["range_min_m"]\n')
///     >>> r = design.evaluate_point(s.task(False), [0.2])
///     >>> r["figures"]["feasible"]
///     True
#[pyfunction]
fn design_evaluate_point(py: Python<'_>, task: &str, x: Vec<f64>) -> PyResult<Py<PyAny>> {
    let t: Task = serde_json::from_str(task).map_err(|e| input(format!("task: {e}")))?;
    if x.len() != t.space.variables.len() {
        return Err(input(format!(
            "x has {} values; the space has {} variables",
            x.len(),
            t.space.variables.len()
        )));
    }
    let store = cellinject_fea::default_store(true);
    let r = py.detach(|| t.evaluate(&x, store.as_ref()));
    to_py(py, &r)
}

/// A design study: a space on a description, and a seeded NSGA-II search asked for
/// points and told their records generation by generation
/// (``cellinject.design.optimise`` drives it).
///
/// Args:
///     space: the space file's text (TOML: ``[variables]``, ``[objectives]``,
///         ``[constraints]``).
///     config: a description file (TOML); None: the embedded prototype.
///     approach: 1 or 2; None: the description's ``twin.approach``.
///     population: designs per generation (even, at least 4).
///     generations: generations to run.
///     seed: the search's seed.
///     fidelity: the front's fidelity, ``"beam"`` or ``"fea"``.
///     level: the FEM mesh level of the ``"fea"`` step.
///
/// Raises:
///     InputError: a bad space (named key), description or argument.
///
/// Example:
///     >>> from cellinject import design
///     >>> s = design.Study('[variables]\n"geometry.b2" = [0.1, 0.3]\n[objectives]\nmaximise = ["range_min_m"]\n', population=4)
///     >>> len(s.ask())
///     4
#[pyclass(name = "Study", module = "cellinject.design")]
pub struct PyStudy {
    study: Study,
}

#[pymethods]
impl PyStudy {
    #[new]
    #[pyo3(signature = (space, config=None, approach=None, population=40, generations=30, seed=1, fidelity="beam", level=1))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        space: &str,
        config: Option<PathBuf>,
        approach: Option<i64>,
        population: i64,
        generations: i64,
        seed: i64,
        fidelity: &str,
        level: i64,
    ) -> PyResult<Self> {
        let base = base_text(config.as_deref())?;
        let parsed = Space::parse(space, &base).map_err(|e| input(format!("space: {e}")))?;
        if population < 4 {
            return Err(input(format!(
                "population must be at least 4, got {population}"
            )));
        }
        if generations < 1 {
            return Err(input(format!(
                "generations must be at least 1, got {generations}"
            )));
        }
        let seed =
            u64::try_from(seed).map_err(|_| input(format!("seed must be >= 0, got {seed}")))?;
        let settings = Settings {
            approach: approach_opt(approach)?,
            fidelity: parse_fidelity(fidelity)?,
            level: parse_level(level)?,
            population: population as usize,
            generations: generations as usize,
            seed,
        };
        let study = Study::new(parsed, base, &settings).map_err(design_error)?;
        Ok(PyStudy { study })
    }

    /// Whether every generation has been told.
    #[getter]
    fn done(&self) -> bool {
        self.study.done()
    }

    /// Generations told so far.
    #[getter]
    fn generation(&self) -> usize {
        self.study.search.generation
    }

    /// Evaluations told so far.
    #[getter]
    fn evaluations(&self) -> usize {
        self.study.search.evaluations
    }

    /// The points of the next generation (lists of floats, one value per variable).
    fn ask(&self) -> Vec<Vec<f64>> {
        self.study.ask()
    }

    /// Hands back the records of the last ``ask``'s points, in order.
    fn tell(
        &mut self,
        py: Python<'_>,
        points: Vec<Vec<f64>>,
        records: &Bound<'_, PyAny>,
    ) -> PyResult<()> {
        let records: Vec<Record> = from_py(py, "records", records)?;
        self.study.tell(&points, records).map_err(design_error)
    }

    /// The JSON text of the task of the screening (``final=False``) or of the
    /// front's final evaluation (``final=True``), for ``evaluate_point``.
    #[pyo3(signature = (final_step=false))]
    fn task(&self, final_step: bool) -> PyResult<String> {
        serde_json::to_string(&self.study.task(final_step))
            .map_err(|e| err(Kind::Other, e.to_string()))
    }

    /// The search's front: a list of ``(point, record)``.
    fn screened_front(&self, py: Python<'_>) -> PyResult<Vec<(Vec<f64>, Py<PyAny>)>> {
        self.study
            .screened_front()
            .into_iter()
            .map(|(x, r)| Ok((x, to_py(py, &r)?)))
            .collect()
    }

    /// The final front from the front's points and their records at the final
    /// fidelity: a list of ``{"variables": ..., "figures": ...}`` (``front.json``).
    fn front(
        &self,
        py: Python<'_>,
        points: Vec<Vec<f64>>,
        records: &Bound<'_, PyAny>,
    ) -> PyResult<Py<PyAny>> {
        let records: Vec<Record> = from_py(py, "records", records)?;
        to_py(py, &self.study.front(&points, &records))
    }
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(design_evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(design_evaluate_point, m)?)?;
    m.add_class::<PyStudy>()?;
    Ok(())
}
