//! `cellinject.dic`: digital image correlation on NumPy images (`cellinject dic`,
//! `dic field`, `dic track`, `dic synth`).

use cellinject_core::dic::{self as core, ArgError, PointReport};
use cellinject_dic::field::FieldOptions;
use cellinject_dic::track::{Roi, Status, Tracker};
use cellinject_dic::{DicError, PointOptions, Shape};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::arrays::{image, out, out_image};
use crate::{Kind, err, input};

/// A checked setting's error with the Python argument's name (`min_zncc`).
fn arg(e: ArgError) -> PyErr {
    input(format!(
        "{} {}, got {}",
        e.name.replace('-', "_"),
        e.rule,
        e.value
    ))
}

fn dic_error(name: &str, e: DicError) -> PyErr {
    input(format!("{name}: {e}"))
}

fn shape(s: &str) -> PyResult<Shape> {
    match s {
        "affine" => Ok(Shape::Affine),
        "rigid" => Ok(Shape::Rigid),
        other => Err(input(format!(
            "shape must be affine or rigid, got `{other}`"
        ))),
    }
}

/// A size argument (pixels) that must be at least `min`.
fn size(name: &str, v: i64, min: i64) -> PyResult<usize> {
    if v < min {
        return Err(input(format!("{name} must be at least {min}, got {v}")));
    }
    usize::try_from(v).map_err(|_| input(format!("{name} is too large: {v}")))
}

fn same_size(r: &cellinject_dic::Image, c: &cellinject_dic::Image) -> PyResult<()> {
    if (r.width(), r.height()) != (c.width(), c.height()) {
        return Err(input(format!(
            "reference is {}x{} but current is {}x{} (columns x rows): the images must have the same size",
            r.width(),
            r.height(),
            c.width(),
            c.height()
        )));
    }
    Ok(())
}

/// Correlates chosen points of ``reference`` into ``current`` (FFT-ZNCC search, then
/// IC-GN with ZNSSD on cubic B-splines): ``cellinject dic --format json`` as arrays.
///
/// Args:
///     reference, current: 2-D arrays (rows, columns) of grey levels, uint8, uint16 or
///         float, the same shape.
///     at: ``(x, y)`` pixel pairs in the reference (x along columns, y along rows,
///         origin at the centre of the top-left pixel).
///     subset: odd subset side, px.
///     shape: ``"affine"`` or ``"rigid"``.
///     search: largest displacement searched for, px.
///     prefilter: sigma of a Gaussian prefilter, px (0: none).
///     min_zncc: the acceptance rule's smallest ZNCC.
///     max_sigma: the acceptance rule's largest predicted sigma, px.
///
/// Returns:
///     dict of NumPy arrays of ``len(at)``: ``x``, ``y``, ``u``, ``v`` (px; NaN without
///     a match), ``du_dx``, ``du_dy``, ``dv_dx``, ``dv_dy``, ``zncc``, ``sigma_u``,
///     ``sigma_v`` (px), ``sigma_noise`` (grey levels), ``iterations``, ``subset``,
///     ``converged`` (bool: a match the acceptance rule accepted), and ``error`` (a
///     list: None, or why a point has no match).
///
/// Raises:
///     InputError: an image not 2-D or of another dtype, a subset leaving the image,
///         a bad setting (named).
///     NotConverged: no point matched.
///
/// Example:
///     >>> from cellinject import dic
///     >>> ref, cur = dic.synth(size=(128, 128), shift=(0.25, 0.0), noise=0.0)
///     >>> r = dic.points(ref, cur, [(64, 64)])
///     >>> bool(abs(r["u"][0] - 0.25) < 0.01)
///     True
#[pyfunction]
#[pyo3(signature = (reference, current, at, subset=31, shape="affine", search=64,
    prefilter=0.0, min_zncc=0.8, max_sigma=cellinject_dic::accept::DEFAULT_MAX_SIGMA))]
#[allow(clippy::too_many_arguments)]
fn dic_points(
    py: Python<'_>,
    reference: &Bound<'_, PyAny>,
    current: &Bound<'_, PyAny>,
    at: &Bound<'_, PyAny>,
    subset: i64,
    shape: &str,
    search: i64,
    prefilter: f64,
    min_zncc: f64,
    max_sigma: f64,
) -> PyResult<Py<PyAny>> {
    let at = crate::arrays::pairs("at", at)?;
    if at.is_empty() {
        return Err(input("at must hold at least one (x, y) point"));
    }
    let options = PointOptions {
        subset: size("subset", subset, 1)?,
        shape: self::shape(shape)?,
        search_radius: size("search", search, 0)?,
        prefilter,
        ..PointOptions::default()
    };
    core::check_prefilter(prefilter).map_err(arg)?;
    let acceptance = core::acceptance(min_zncc, max_sigma).map_err(arg)?;
    let r = image("reference", reference)?;
    let c = image("current", current)?;
    same_size(&r, &c)?;
    let res = py
        .detach(|| core::points(&r, &c, &at, &options, &acceptance))
        .map_err(|e| match e {
            DicError::SubsetSize { .. } => dic_error("subset", e),
            DicError::SubsetOutside { .. } => dic_error("at", e),
            other => dic_error("dic", other),
        })?;
    if res.iter().all(|p| matches!(p, PointReport::Missing { .. })) {
        return Err(err(
            Kind::NotConverged,
            format!(
                "no point matched reliably (converged, ZNCC at least {min_zncc}, predicted σ at most {max_sigma} px): nothing to measure"
            ),
        ));
    }
    let n = res.len();
    let mut cols: [Vec<f64>; 13] = Default::default();
    let mut iterations = Vec::with_capacity(n);
    let mut subsets = Vec::with_capacity(n);
    let mut converged = Vec::with_capacity(n);
    let errors = PyList::empty(py);
    for p in &res {
        let row = match *p {
            PointReport::Found {
                x,
                y,
                u,
                v,
                du_dx,
                du_dy,
                dv_dx,
                dv_dy,
                zncc,
                iterations: it,
                converged: _,
                sigma_u,
                sigma_v,
                sigma_noise,
                subset,
            } => {
                iterations.push(it as i64);
                subsets.push(subset as i64);
                converged.push(true);
                errors.append(py.None())?;
                [
                    x,
                    y,
                    u,
                    v,
                    du_dx,
                    du_dy,
                    dv_dx,
                    dv_dy,
                    zncc,
                    sigma_u,
                    sigma_v,
                    sigma_noise,
                    0.0,
                ]
            }
            PointReport::Missing { x, y, error, .. } => {
                iterations.push(0);
                subsets.push(0);
                converged.push(false);
                errors.append(error)?;
                let nan = f64::NAN;
                [x, y, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, 0.0]
            }
        };
        for (c, v) in cols.iter_mut().zip(row) {
            c.push(v);
        }
    }
    let d = PyDict::new(py);
    let names = [
        "x",
        "y",
        "u",
        "v",
        "du_dx",
        "du_dy",
        "dv_dx",
        "dv_dy",
        "zncc",
        "sigma_u",
        "sigma_v",
        "sigma_noise",
    ];
    for (name, c) in names.iter().zip(cols) {
        d.set_item(*name, out(py, c))?;
    }
    d.set_item("iterations", out(py, iterations))?;
    d.set_item("subset", out(py, subsets))?;
    d.set_item("converged", out(py, converged))?;
    d.set_item("error", errors)?;
    Ok(d.into_any().unbind())
}

/// The full displacement field on a grid, reliability-guided and parallel (the GIL
/// released): ``cellinject dic field`` as arrays.
///
/// Args:
///     reference, current: 2-D arrays of grey levels, uint8, uint16 or float.
///     step: grid step, px.
///     subset: odd subset side, px.
///     shape: ``"affine"`` or ``"rigid"``.
///     prefilter: Gaussian prefilter sigma, px.
///     min_zncc, max_sigma: the acceptance rule (as ``points``).
///
/// Returns:
///     dict: NumPy arrays over the ``nx * ny`` grid points, row by row: ``x``, ``y``
///     (px), ``u``, ``v`` (px; NaN where no accepted match), ``zncc``, ``sigma_u``,
///     ``sigma_v``, ``subset``, ``converged`` (bool: an accepted match); and the
///     summary of ``dic field --format json``: ``points``, ``found``, ``dropped``,
///     ``dropped_by``, ``min_zncc``, ``max_sigma``, ``nx``, ``ny``, ``step``,
///     ``u_range``, ``v_range``.
///
/// Raises:
///     InputError: bad images or settings (named). NotConverged: no grid point matched.
///
/// Example:
///     >>> from cellinject import dic
///     >>> ref, cur = dic.synth(size=(96, 96), shift=(0.5, -0.25), noise=0.0)
///     >>> f = dic.field(ref, cur, step=16)
///     >>> f["found"] > 0
///     True
#[pyfunction]
#[pyo3(signature = (reference, current, step=5, subset=31, shape="affine", prefilter=0.0,
    min_zncc=0.8, max_sigma=cellinject_dic::accept::DEFAULT_MAX_SIGMA))]
#[allow(clippy::too_many_arguments)]
fn dic_field(
    py: Python<'_>,
    reference: &Bound<'_, PyAny>,
    current: &Bound<'_, PyAny>,
    step: i64,
    subset: i64,
    shape: &str,
    prefilter: f64,
    min_zncc: f64,
    max_sigma: f64,
) -> PyResult<Py<PyAny>> {
    let step = size("step", step, 1)?;
    core::check_prefilter(prefilter).map_err(arg)?;
    let acceptance = core::acceptance(min_zncc, max_sigma).map_err(arg)?;
    let options = FieldOptions {
        step,
        subset: size("subset", subset, 1)?,
        shape: self::shape(shape)?,
        prefilter,
        acceptance,
        ..FieldOptions::default()
    };
    let r = image("reference", reference)?;
    let c = image("current", current)?;
    same_size(&r, &c)?;
    let report = py
        .detach(|| core::field_report(&r, &c, &options))
        .map_err(|e| match e {
            DicError::SubsetSize { .. } => dic_error("subset", e),
            other => dic_error("dic field", other),
        })?;
    let summary = report.summary();
    if report.found == 0 {
        return Err(err(
            Kind::NotConverged,
            format!(
                "no grid point matched ({} tried, {} dropped as unreliable): nothing to measure (no texture, or the images do not overlap)",
                summary.points, summary.dropped
            ),
        ));
    }
    let f = &report.field;
    let n = f.points.len();
    let (mut xs, mut ys) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut cols: [Vec<f64>; 5] = Default::default();
    let mut subsets = Vec::with_capacity(n);
    let mut converged = Vec::with_capacity(n);
    for (k, p) in f.points.iter().enumerate() {
        let (x, y) = report.position(k);
        xs.push(x as f64);
        ys.push(y as f64);
        let row = match p {
            Some(p) => [p.u, p.v, p.zncc, p.sigma_u, p.sigma_v],
            None => [f64::NAN; 5],
        };
        for (c, v) in cols.iter_mut().zip(row) {
            c.push(v);
        }
        subsets.push(p.as_ref().map_or(0, |p| p.subset as i64));
        converged.push(p.is_some());
    }
    let d = crate::to_py(py, &summary)?;
    let d = d.bind(py).cast::<PyDict>()?;
    d.set_item("x", out(py, xs))?;
    d.set_item("y", out(py, ys))?;
    for (name, c) in ["u", "v", "zncc", "sigma_u", "sigma_v"].iter().zip(cols) {
        d.set_item(*name, out(py, c))?;
    }
    d.set_item("subset", out(py, subsets))?;
    d.set_item("converged", out(py, converged))?;
    Ok(d.clone().into_any().unbind())
}

/// Follows a region through a sequence of frames (constant-velocity prediction, a
/// ladder of blurs for a region out of focus, rejection below ``min_zncc``):
/// ``cellinject dic track`` as arrays.
///
/// Args:
///     frames: a sequence of 2-D arrays, or a 3-D array (frame, row, column); the first
///         is the reference.
///     roi: ``(x, y, width, height)`` of the region in the first frame, px.
///     shape: ``"rigid"`` or ``"affine"``.
///     min_zncc: frames whose match falls below are rejected.
///
/// Returns:
///     dict: NumPy arrays per frame ``u``, ``v`` (px, NaN when rejected), ``zncc``,
///     ``iterations``, ``sigma_u`` (px), ``blur`` (px); ``status`` (a list of
///     ``"tracked"``, ``"recovered"``, ``"defocused"``, ``"rejected"``); and the summary
///     ``frames``, ``measured``, ``rejected``, ``min_zncc``.
///
/// Example:
///     >>> import numpy as np
///     >>> from cellinject import dic
///     >>> ref, cur = dic.synth(size=(96, 96), shift=(1.0, 0.0), noise=0.0)
///     >>> t = dic.track([ref, cur], roi=(32, 32, 32, 32))
///     >>> t["measured"]
///     2
#[pyfunction]
#[pyo3(signature = (frames, roi, shape="rigid", min_zncc=0.8))]
fn dic_track(
    py: Python<'_>,
    frames: &Bound<'_, PyAny>,
    roi: (i64, i64, i64, i64),
    shape: &str,
    min_zncc: f64,
) -> PyResult<Py<PyAny>> {
    let shape = self::shape(shape)?;
    if !(-1.0..=1.0).contains(&min_zncc) {
        return Err(input(format!(
            "min_zncc must lie in [-1, 1], got {min_zncc}"
        )));
    }
    let roi = {
        let c = |name: &str, v: i64| {
            u32::try_from(v).map_err(|_| {
                input(format!(
                    "roi: {name} must be a non-negative number of pixels, got {v}"
                ))
            })
        };
        Roi {
            x: c("x", roi.0)?,
            y: c("y", roi.1)?,
            width: c("width", roi.2)?,
            height: c("height", roi.3)?,
        }
    };
    let mut images = Vec::new();
    for (k, f) in frames.try_iter()?.enumerate() {
        images.push(image(&format!("frames[{k}]"), &f?)?);
    }
    if images.is_empty() {
        return Err(input("frames must hold at least one image"));
    }
    let points = py.detach(|| -> Result<Vec<_>, (usize, DicError)> {
        let mut t = Tracker::new(&images[0], roi, shape, min_zncc).map_err(|e| (0, e))?;
        images
            .iter()
            .enumerate()
            .map(|(k, img)| t.track(img).map_err(|e| (k, e)))
            .collect()
    });
    let points = points.map_err(|(k, e)| match e {
        e if k == 0 => dic_error("roi", e),
        e => dic_error(&format!("frames[{k}]"), e),
    })?;
    let status = PyList::empty(py);
    let mut rejected = 0;
    for p in &points {
        status.append(match p.status {
            Status::Tracked => "tracked",
            Status::Recovered => "recovered",
            Status::Defocused => "defocused",
            Status::Rejected => {
                rejected += 1;
                "rejected"
            }
        })?;
    }
    let summary = core::TrackSummary {
        frames: points.len(),
        measured: points.len() - rejected,
        rejected,
        min_zncc,
    };
    let d = crate::to_py(py, &summary)?;
    let d = d.bind(py).cast::<PyDict>()?;
    let col = |f: fn(&cellinject_dic::track::TrackPoint) -> f64| points.iter().map(f).collect();
    d.set_item("u", out::<f64>(py, col(|p| p.u)))?;
    d.set_item("v", out::<f64>(py, col(|p| p.v)))?;
    d.set_item("zncc", out::<f64>(py, col(|p| p.zncc)))?;
    d.set_item("sigma_u", out::<f64>(py, col(|p| p.sigma_u)))?;
    d.set_item("blur", out::<f64>(py, col(|p| p.blur)))?;
    d.set_item(
        "iterations",
        out(py, points.iter().map(|p| p.iterations as i64).collect()),
    )?;
    d.set_item("status", status)?;
    Ok(d.clone().into_any().unbind())
}

/// A pair of exact synthetic speckle images (erf-integrated Gaussians) with a known
/// motion, to check a setup: ``cellinject dic synth`` without the files.
///
/// Args:
///     size: ``(width, height)``, px, 16 to 20000 each.
///     shift: ``(u, v)`` of the current image, px.
///     rotation: about the image centre, degrees.
///     noise: Gaussian noise, grey levels rms.
///     seed: of the pattern and the noise.
///
/// Returns:
///     ``(reference, current)``: 2-D float64 arrays (rows, columns), grey levels 0-255
///     (not rounded; ``np.round(a).astype(np.uint8)`` gives the CLI's 8-bit files).
///
/// Example:
///     >>> from cellinject import dic
///     >>> ref, cur = dic.synth(size=(64, 48))
///     >>> ref.shape
///     (48, 64)
#[pyfunction]
#[pyo3(signature = (size=(512, 512), shift=(0.0, 0.0), rotation=0.0, noise=2.0, seed=1))]
fn dic_synth(
    py: Python<'_>,
    size: (i64, i64),
    shift: (f64, f64),
    rotation: f64,
    noise: f64,
    seed: u64,
) -> PyResult<(Py<PyAny>, Py<PyAny>)> {
    let w = usize::try_from(size.0)
        .map_err(|_| input(format!("size: width must be positive, got {}", size.0)))?;
    let h = usize::try_from(size.1)
        .map_err(|_| input(format!("size: height must be positive, got {}", size.1)))?;
    crate::finite("shift[0]", shift.0)?;
    crate::finite("shift[1]", shift.1)?;
    crate::finite("rotation", rotation)?;
    let (r, c) = py
        .detach(|| core::synth_pair((w, h), shift, rotation, noise, seed))
        .map_err(arg)?;
    Ok((out_image(py, &r)?, out_image(py, &c)?))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(dic_points, m)?)?;
    m.add_function(wrap_pyfunction!(dic_field, m)?)?;
    m.add_function(wrap_pyfunction!(dic_track, m)?)?;
    m.add_function(wrap_pyfunction!(dic_synth, m)?)
}
