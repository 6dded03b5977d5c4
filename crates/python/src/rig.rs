//! `cellinject.rig`: a bench opened from a rig file (docs/rig.md), its devices asked
//! whether they answer, and the injection workflow run on it: the same library calls
//! as `cellinject rig check` and `cellinject run --rig`.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use cellinject_config::Description;
use cellinject_config::rigfile::RigFile;
use cellinject_core::inject::{Options, Session};
use cellinject_session::run::{self as session_run, Begin, Ended, RunFailure};
use cellinject_session::{Opened, SessionError, TwinOptions};
use pyo3::prelude::*;

use crate::{Kind, description, err, input};

/// A refused rig (bad input: the file and the dotted key named) or a device that
/// failed.
fn session_err(e: SessionError) -> PyErr {
    if e.is_refusal() {
        input(e.to_string())
    } else {
        err(Kind::Other, e.to_string())
    }
}

/// The rig file at `path`, or the twin's when `None`.
fn load(path: Option<&Path>) -> PyResult<RigFile> {
    match path {
        Some(p) => cellinject_session::load_rig(p).map_err(session_err),
        None => Ok(RigFile::twin()),
    }
}

struct Inner {
    opened: Opened,
    /// What the bench's first run found of the resting tip (later runs refer their
    /// focus to it, as the dashboard's do).
    session: Option<Session>,
}

/// A bench opened from a rig file (``cellinject.rig.open``): its devices behind the
/// safety envelope, kept open from run to run.
#[pyclass(module = "cellinject.rig", name = "Bench", frozen)]
pub(crate) struct PyBench {
    d: Description,
    seed: u64,
    inner: Mutex<Inner>,
}

/// Opens the bench a rig file names (docs/rig.md): each device through its driver,
/// the safety envelope round them, the stacks brought to 0 V. A rig file with an
/// unknown driver, a missing key, an unknown section or a device of the wrong kind
/// raises InputError naming the file and the dotted key, before anything is opened.
///
/// Args:
///     path: the rig file (TOML); None: the twin.
///     seed: the twin's seed (None: the description's ``twin.seed``); refused for a
///         rig without the twin.
///     config: a description file; None: the prototype.
///
/// Returns: a ``Bench``.
///
/// Example:
///     >>> from cellinject import rig
///     >>> b = rig.open(seed=2)
///     >>> b.backend
///     'twin'
#[pyfunction]
#[pyo3(signature = (path=None, seed=None, config=None))]
fn rig_open(
    py: Python<'_>,
    path: Option<PathBuf>,
    seed: Option<u64>,
    config: Option<PathBuf>,
) -> PyResult<PyBench> {
    let d = description(config.as_deref())?;
    let rig = load(path.as_deref())?;
    if seed.is_some() && !rig.is_twin() {
        return Err(input(format!(
            "seed seeds the twin: the rig's bench is {} (seed the emulator instead)",
            rig.backend()
        )));
    }
    let seed = seed.unwrap_or(d.sim.seed);
    let opts = TwinOptions {
        approach: None,
        seed: Some(seed),
    };
    let opened = py
        .detach(|| cellinject_session::open(&d, &rig, opts))
        .map_err(session_err)?;
    Ok(PyBench {
        d,
        seed,
        inner: Mutex::new(Inner {
            opened,
            session: None,
        }),
    })
}

/// Asks each device of a rig whether it answers (``cellinject rig check --format
/// json``): one harmless question each, nothing moves.
///
/// Args:
///     path: the rig file (TOML); None: the twin.
///     config: a description file; None: the prototype.
///
/// Returns: a dict: ``name``, ``backend`` and ``devices`` (each ``section``,
/// ``driver``, ``answers``, ``detail``).
///
/// Example:
///     >>> from cellinject import rig
///     >>> all(d["answers"] for d in rig.check()["devices"])
///     True
#[pyfunction]
#[pyo3(signature = (path=None, config=None))]
fn rig_check(
    py: Python<'_>,
    path: Option<PathBuf>,
    config: Option<PathBuf>,
) -> PyResult<Py<PyAny>> {
    let d = description(config.as_deref())?;
    let rig = load(path.as_deref())?;
    let answers = py
        .detach(|| cellinject_session::check(&d, &rig))
        .map_err(session_err)?;
    crate::to_py(py, &cellinject_session::CheckReport::new(&rig, &answers))
}

#[pymethods]
impl PyBench {
    /// The bench as the run records name it: ``twin`` or the controller's address.
    #[getter]
    fn backend(&self) -> String {
        self.lock().opened.name.clone()
    }

    /// Runs the injection workflow on this bench and records it in ``db``: the same
    /// lifecycle as ``cellinject run`` (a plate whose plan the workflow refuses leaves
    /// no record). A later run on the same bench refers its focus to the first's
    /// resting tip, as the dashboard's runs do.
    ///
    /// Args:
    ///     plate: the plate file; None: the twin's default plate for its seed
    ///         (required for a bench without the twin: the plate under its microscope).
    ///     db: the run database (created if missing).
    ///
    /// Returns: the run as ``cellinject run --format json`` prints it.
    #[pyo3(signature = (plate=None, db=PathBuf::from("runs.sqlite")))]
    fn run(&self, py: Python<'_>, plate: Option<PathBuf>, db: PathBuf) -> PyResult<Py<PyAny>> {
        let options = Options::default();
        options
            .check(&self.d.rig)
            .map_err(|e| input(e.to_string()))?;
        let twin = self.lock().opened.twin.is_some();
        let (plate, text) = match (&plate, twin) {
            (Some(p), _) => crate::runs::read_plate(p)?,
            (None, true) => cellinject_run_sim::default_plate_text(self.seed)
                .map_err(|e| err(Kind::Other, format!("default plate: {e}")))?,
            (None, false) => {
                return Err(input(
                    "plate is required on a bench without the twin: the plate file under its microscope",
                ));
            }
        };
        let summary = py.detach(|| {
            let mut g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
            let inner = &mut *g;
            let request = session_run::Request {
                d: &self.d,
                db: &db,
                options,
                hysteresis: None,
                session: inner.session.clone(),
                begin: Begin::New {
                    plate,
                    text,
                    seed: self.seed,
                    faults: Vec::new(),
                    settings: serde_json::json!({
                        "options": options,
                        "faults": Vec::<String>::new(),
                        "front_end": "python",
                    }),
                },
                debug: false,
            };
            let ended = session_run::run(
                request,
                session_run::Bench::Opened(&mut inner.opened),
                session_run::Hooks::default(),
            )?;
            Ok(match ended {
                Ended::Ran {
                    summary, outcome, ..
                } => {
                    if let Ok((report, _)) = *outcome {
                        inner.session.get_or_insert(report.session);
                    }
                    summary
                }
                Ended::AlreadyFinished { summary, .. } => summary,
            })
        });
        let summary = summary.map_err(run_failure)?;
        crate::to_py(py, &summary)
    }

    fn __repr__(&self) -> String {
        format!("<cellinject.rig.Bench {}>", self.lock().opened.name)
    }
}

impl PyBench {
    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// A run that could not start or be recorded, as Python's error.
pub(crate) fn run_failure(e: RunFailure) -> PyErr {
    match e {
        RunFailure::Records(e) => crate::runs::records_error(e),
        // Only a twin built for the run can fail here: its J3 check.
        RunFailure::Bench(e) if !e.is_refusal() => {
            err(Kind::NotConverged, format!("the twin: {e}"))
        }
        RunFailure::Bench(e) => input(e.to_string()),
        RunFailure::Input(e) => input(format!("plate: {e}")),
        e => input(e.to_string()),
    }
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyBench>()?;
    m.add_function(wrap_pyfunction!(rig_open, m)?)?;
    m.add_function(wrap_pyfunction!(rig_check, m)?)
}
