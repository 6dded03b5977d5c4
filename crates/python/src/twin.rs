//! `cellinject.twin`: the digital twin of the bench, driven through its guarded rig
//! (the same safety envelope as every front end), and the injection workflow on it.

use std::path::PathBuf;
use std::sync::{Mutex, MutexGuard};

use cellinject_hw::{Camera as _, Clock as _, HwError, PiezoChannel as _, PositionSensor as _};
use cellinject_rig::Rig;
use cellinject_twin::{SharedTwin, TwinBackend};
use numpy::{IntoPyArray, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::{Kind, description, err, finite, input};

fn hw_error(name: &str, e: HwError) -> PyErr {
    match e {
        HwError::Refused(_) | HwError::OutOfRange { .. } | HwError::NotFinite { .. } => {
            input(format!("{name}: {e}"))
        }
        e => err(Kind::Other, format!("{name}: {e}")),
    }
}

struct Inner {
    twin: SharedTwin,
    rig: Rig<TwinBackend>,
}

/// The digital twin of the bench: three piezo stacks behind the safety envelope, their
/// position sensors, the microscope (``"top"``) and side cameras, the stages, on a
/// simulated clock that moves only when you advance it.
///
/// Args:
///     approach: the pre-tensioning approach it is assembled with, 1 or 2 (None: the
///         description's ``twin.approach``).
///     seed: of its random processes (None: the description's ``twin.seed``).
///     config: a description file; None: the prototype.
///
/// Building it evaluates J3's yield check with the structural model (joint FEM or the
/// joint cache the CLI shares), with the GIL released.
///
/// Example:
///     >>> from cellinject import twin
///     >>> t = twin.Twin(seed=1)
///     >>> t.set_voltages(20.0, 20.0, 0.0)
///     [20.0, 20.0, 0.0]
///     >>> t.advance(0.05)
///     >>> frame = t.grab("top")["image"]
#[pyclass(module = "cellinject.twin", name = "Twin", frozen)]
pub(crate) struct PyTwin {
    inner: Mutex<Inner>,
}

impl PyTwin {
    /// Runs `f` on the twin with the GIL released; the lock is taken and given back
    /// without the GIL, so two Python threads sharing a twin cannot deadlock.
    fn with<R: Send>(&self, py: Python<'_>, f: impl FnOnce(&mut Inner) -> R + Send) -> R {
        py.detach(|| {
            let mut g: MutexGuard<'_, Inner> = self.inner.lock().unwrap_or_else(|e| e.into_inner());
            f(&mut g)
        })
    }
}

/// The twin of a description, `approach` and `seed` overriding its own, with J3's
/// yield check from the structural model (as the CLI builds it).
pub(crate) fn build(
    py: Python<'_>,
    approach: Option<i64>,
    seed: Option<u64>,
    config: Option<&std::path::Path>,
) -> PyResult<SharedTwin> {
    let d = description(config)?;
    let opts = cellinject_session::TwinOptions {
        approach: approach
            .map(|a| crate::approach("approach", a))
            .transpose()?,
        seed,
    };
    py.detach(|| cellinject_session::twin(&d, opts))
        .map_err(|e| match e {
            e if e.is_refusal() => input(e.to_string()),
            e => err(Kind::NotConverged, e.to_string()),
        })
}

#[pymethods]
impl PyTwin {
    #[new]
    #[pyo3(signature = (approach=None, seed=None, config=None))]
    fn new(
        py: Python<'_>,
        approach: Option<i64>,
        seed: Option<u64>,
        config: Option<PathBuf>,
    ) -> PyResult<Self> {
        let twin = build(py, approach, seed, config.as_deref())?;
        let rig = cellinject_twin::rig(&twin)
            .map_err(|e| input(format!("cannot build the twin: {e}")))?;
        Ok(PyTwin {
            inner: Mutex::new(Inner { twin, rig }),
        })
    }

    /// Commands the stacks' amplifiers A1, A2, A3, V, each through the safety
    /// envelope (as `cellinject sim frame --volts` does): a voltage outside the
    /// amplifier's range, or one that would drive a stack, a flexure or a joint past
    /// its limit, is refused, and a refused call leaves every stack where it was.
    ///
    /// Returns:
    ///     list[float]: the voltages applied, V.
    ///
    /// Raises:
    ///     InputError: a NaN, or a refused voltage (the stack named).
    fn set_voltages(&self, py: Python<'_>, a1: f64, a2: f64, a3: f64) -> PyResult<Vec<f64>> {
        finite("a1", a1)?;
        finite("a2", a2)?;
        finite("a3", a3)?;
        self.with(py, |g| {
            // Each stack through the guard, as `sim frame --volts` does: a voltage
            // outside the amplifier's range, or one that would leave the safety
            // envelope, is refused, and a refused call leaves every stack where it was.
            let before: Vec<f64> = g.rig.piezo.iter().map(|p| p.commanded_voltage()).collect();
            let target = [a1, a2, a3];
            let names = ["a1", "a2", "a3"];
            let mut result = Ok(());
            for ch in 0..3 {
                if let Err(e) = g.rig.piezo[ch].set_voltage(target[ch]) {
                    result = Err((names[ch], e));
                    break;
                }
            }
            if let Err(e) = result {
                // Back in the reverse order, each to where it was (inside the envelope).
                for ch in (0..3).rev() {
                    let _ = g.rig.piezo[ch].set_voltage(before[ch]);
                }
                return Err(e);
            }
            Ok(g.rig.piezo.iter().map(|p| p.commanded_voltage()).collect())
        })
        .map_err(|(n, e)| hw_error(n, e))
    }

    /// The voltages commanded to A1, A2, A3, V.
    fn voltages(&self, py: Python<'_>) -> Vec<f64> {
        self.with(py, |g| {
            g.rig.piezo.iter().map(|p| p.commanded_voltage()).collect()
        })
    }

    /// The stacks' position sensors A1, A2, A3: extensions, m (with their noise).
    fn sensors(&self, py: Python<'_>) -> PyResult<Vec<f64>> {
        self.with(py, |g| {
            g.rig
                .sensors
                .iter_mut()
                .map(|s| s.read())
                .collect::<Result<Vec<f64>, HwError>>()
        })
        .map_err(|e| hw_error("sensors", e))
    }

    /// Advances the simulated clock by ``seconds`` (the structure rings, the stacks
    /// creep), with the GIL released.
    ///
    /// Raises:
    ///     InputError: a negative or non-finite duration.
    fn advance(&self, py: Python<'_>, seconds: f64) -> PyResult<()> {
        if !(seconds.is_finite() && seconds >= 0.0) {
            return Err(input(format!(
                "seconds must be a non-negative number, got {seconds}"
            )));
        }
        self.with(py, |g| g.rig.clock.sleep(seconds))
            .map_err(|e| hw_error("seconds", e))
    }

    /// The simulated clock, s.
    #[getter]
    fn time(&self, py: Python<'_>) -> f64 {
        self.with(py, |g| g.rig.clock.now())
    }

    /// One frame of a camera: ``"top"`` (the microscope, looking along y) or
    /// ``"side"``.
    ///
    /// Returns:
    ///     dict: ``image`` (2-D uint16 NumPy array, rows x columns), ``bit_depth``,
    ///     ``timestamp`` and ``exposure`` (s), ``pixel_size`` (m in the object plane),
    ///     ``index``.
    #[pyo3(signature = (camera="top"))]
    fn grab(&self, py: Python<'_>, camera: &str) -> PyResult<Py<PyAny>> {
        let f = self
            .with(py, |g| match camera {
                "top" => Ok(g.rig.camera.grab()),
                "side" => Ok(g.rig.side_camera.grab()),
                _ => Err(()),
            })
            .map_err(|()| input(format!("camera must be top or side, got `{camera}`")))?
            .map_err(|e| hw_error("camera", e))?;
        let d = PyDict::new(py);
        let image = f
            .pixels
            .into_pyarray(py)
            .reshape([f.height as usize, f.width as usize])?;
        d.set_item("image", image)?;
        d.set_item("bit_depth", f.bit_depth)?;
        d.set_item("timestamp", f.timestamp)?;
        d.set_item("exposure", f.exposure)?;
        d.set_item("pixel_size", f.pixel_size)?;
        d.set_item("index", f.index)?;
        Ok(d.into_any().unbind())
    }

    /// Puts a plate file's cells and debris under the microscope (``plate generate``
    /// writes one).
    ///
    /// Raises:
    ///     InputError: the file cannot be read, or what it holds cannot be (the key).
    fn load_plate(&self, py: Python<'_>, plate: PathBuf) -> PyResult<()> {
        let (p, _) = crate::runs::read_plate(&plate)?;
        self.with(py, |g| {
            g.twin
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .load_plate(&p)
        });
        Ok(())
    }

    /// The pipette tip's true pose (the twin's truth, never measured): ``x`` and ``z``
    /// (m, along the top camera's columns and rows), ``depth`` (m from the focal plane).
    fn tip(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let t = self.with(py, |g| {
            g.twin.lock().unwrap_or_else(|e| e.into_inner()).tip()
        });
        let d = PyDict::new(py);
        d.set_item("x", t.x)?;
        d.set_item("z", t.z)?;
        d.set_item("depth", t.depth)?;
        Ok(d.into_any().unbind())
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        format!("<cellinject.twin.Twin t={:.6} s>", self.time(py))
    }
}

/// The unattended injection workflow on a fresh twin (``cellinject run``): every cell
/// of the plate found, injected and checked, each attempt recorded in ``db``; the GIL
/// is released while it runs.
///
/// Args:
///     plate: a plate file (``plate generate`` writes one); None: the default 8 x 12
///         plate generated from ``seed``.
///     seed: of the twin and the default plate (None: the description's ``twin.seed``).
///     db: the run database, created if missing (``cellinject runs`` and
///         :mod:`cellinject.runs` read it).
///     config: a description file; None: the prototype.
///
/// Returns:
///     dict: the run summary of ``cellinject run --format json`` (docs/json.md):
///     ``run``, ``status``, ``injected``, ``failed``, ``attempts`` (``tip_error_m``,
///     ...), ``events``, ``focus``, ...; a run that stopped on a fault is returned too,
///     with ``status`` ``"stopped"`` and ``stopped`` saying why.
///
/// Raises:
///     InputError: a plate that cannot be read or served (nothing is recorded then).
///
/// Example:
///     >>> from cellinject import twin
///     >>> s = twin.run(plate="plate.toml", db="runs.sqlite")  # doctest: +SKIP
///     >>> s["injected"], s["status"]  # doctest: +SKIP
#[pyfunction]
#[pyo3(signature = (plate=None, seed=None, db=PathBuf::from("runs.sqlite"), config=None))]
fn twin_run(
    py: Python<'_>,
    plate: Option<PathBuf>,
    seed: Option<u64>,
    db: PathBuf,
    config: Option<PathBuf>,
) -> PyResult<Py<PyAny>> {
    use cellinject_session::run::{self as session_run, Begin, Ended};
    let d = description(config.as_deref())?;
    let options = cellinject_core::inject::Options::default();
    options.check(&d.rig).map_err(|e| input(e.to_string()))?;
    let seed = seed.unwrap_or(d.sim.seed);
    let (plate, text) = match &plate {
        Some(p) => crate::runs::read_plate(p)?,
        None => cellinject_run_sim::default_plate_text(seed)
            .map_err(|e| err(Kind::Other, format!("default plate: {e}")))?,
    };
    // The same lifecycle as `cellinject run`'s (cellinject-session).
    let request = session_run::Request {
        d: &d,
        db: &db,
        options,
        hysteresis: None,
        session: None,
        begin: Begin::New {
            plate,
            text,
            seed,
            faults: Vec::new(),
            settings: serde_json::json!({ "options": options, "faults": Vec::<String>::new() }),
        },
        debug: false,
    };
    let ended = py.detach(|| {
        session_run::run(
            request,
            session_run::Bench::Twin(None),
            session_run::Hooks::default(),
        )
    });
    let summary = match ended.map_err(crate::rig::run_failure)? {
        Ended::Ran { summary, .. } | Ended::AlreadyFinished { summary, .. } => summary,
    };
    crate::to_py(py, &summary)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyTwin>()?;
    m.add_function(wrap_pyfunction!(twin_run, m)?)
}
