//! NumPy arrays in and out: images (2-D, uint8, uint16 or float) and vectors, checked
//! and named in the errors.

use cellinject_dic::Image;
use numpy::{
    Element, IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use crate::input;

/// The grey levels of a 2-D array of element type `T` as f64, row-major.
fn grey<T: Element + Copy + Into<f64>>(a: &Bound<'_, PyAny>) -> Option<(usize, usize, Vec<f64>)> {
    let a = a.cast::<PyArray2<T>>().ok()?.readonly();
    let v = a.as_array();
    let (h, w) = v.dim();
    Some((w, h, v.iter().map(|x| (*x).into()).collect()))
}

/// An image argument: a 2-D NumPy array (rows, columns) of uint8, uint16, float32 or
/// float64 grey levels, finite, at least 1x1.
pub(crate) fn image(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Image> {
    let Ok(u) = obj.cast::<PyUntypedArray>() else {
        return Err(input(format!(
            "{name} must be a 2-D NumPy array of grey levels (uint8, uint16 or float), got {}",
            obj.get_type().name()?
        )));
    };
    if u.ndim() != 2 {
        return Err(input(format!(
            "{name} must be a 2-D array (rows, columns), got {} dimension(s) of shape {:?}",
            u.ndim(),
            u.shape()
        )));
    }
    let got = grey::<u8>(obj)
        .or_else(|| grey::<u16>(obj))
        .or_else(|| grey::<f32>(obj))
        .or_else(|| grey::<f64>(obj));
    let Some((w, h, data)) = got else {
        return Err(input(format!(
            "{name} must hold uint8, uint16, float32 or float64 grey levels, got dtype {}",
            u.dtype().str()?
        )));
    };
    if w == 0 || h == 0 {
        return Err(input(format!("{name} is empty ({h}x{w})")));
    }
    if let Some(k) = data.iter().position(|v| !v.is_finite()) {
        return Err(input(format!(
            "{name} holds a non-finite value at row {}, column {}",
            k / w,
            k % w
        )));
    }
    Image::new(w, h, data).map_err(|e| input(format!("{name}: {e}")))
}

fn floats<T: Element + Copy + Into<f64>>(a: &Bound<'_, PyAny>) -> Option<Vec<f64>> {
    let a = a.cast::<PyArray1<T>>().ok()?.readonly();
    Some(a.as_array().iter().map(|x| (*x).into()).collect())
}

/// A vector argument: a 1-D NumPy array of any real dtype or a sequence of numbers,
/// every value finite.
pub(crate) fn vector(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Vec<f64>> {
    let v = if let Ok(u) = obj.cast::<PyUntypedArray>() {
        if u.ndim() != 1 {
            return Err(input(format!(
                "{name} must be a 1-D array, got {} dimension(s) of shape {:?}",
                u.ndim(),
                u.shape()
            )));
        }
        floats::<f64>(obj)
            .or_else(|| floats::<f32>(obj))
            .or_else(|| floats::<i32>(obj))
            .or_else(|| floats::<u8>(obj))
            .or_else(|| floats::<u16>(obj))
            .or_else(|| floats::<i16>(obj))
            .or_else(|| floats::<u32>(obj))
            .or_else(|| {
                // int64: exact below 2^53, which any voltage or displacement is.
                let a = obj.cast::<PyArray1<i64>>().ok()?.readonly();
                Some(a.as_array().iter().map(|x| *x as f64).collect())
            })
            .ok_or_else(|| {
                input(format!(
                    "{name} must hold real numbers, got dtype {}",
                    u.dtype().str().map(|s| s.to_string()).unwrap_or_default()
                ))
            })?
    } else {
        obj.extract::<Vec<f64>>().map_err(|_| {
            input(format!(
                "{name} must be a 1-D array or a sequence of numbers"
            ))
        })?
    };
    if let Some(k) = v.iter().position(|x| !x.is_finite()) {
        return Err(input(format!(
            "{name}[{k}] = {} is not a finite number",
            v[k]
        )));
    }
    Ok(v)
}

/// A list of `(x, y)` pairs: a sequence of pairs or an `(n, 2)` array of any real
/// dtype, every value finite.
pub(crate) fn pairs(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Vec<(f64, f64)>> {
    let py = obj.py();
    let bad = || {
        input(format!(
            "{name} must be a sequence of (x, y) pairs or an (n, 2) array"
        ))
    };
    let a = py
        .import("numpy")?
        .call_method1("asarray", (obj, "float64"))
        .map_err(|_| bad())?;
    let a = a.cast::<PyArray2<f64>>().map_err(|_| bad())?.readonly();
    let v = a.as_array();
    if v.ncols() != 2 {
        return Err(bad());
    }
    let out: Vec<(f64, f64)> = v.rows().into_iter().map(|r| (r[0], r[1])).collect();
    if let Some(k) = out
        .iter()
        .position(|(x, y)| !(x.is_finite() && y.is_finite()))
    {
        return Err(input(format!(
            "{name}[{k}] = ({}, {}) is not a pair of finite numbers",
            out[k].0, out[k].1
        )));
    }
    Ok(out)
}

/// A vector as a new NumPy array (moved, not copied).
pub(crate) fn out<T: Element>(py: Python<'_>, v: Vec<T>) -> Py<PyAny> {
    v.into_pyarray(py).into_any().unbind()
}

/// An image as a 2-D float64 NumPy array (rows, columns).
pub(crate) fn out_image(py: Python<'_>, img: &Image) -> PyResult<Py<PyAny>> {
    let a = img.data().to_vec().into_pyarray(py);
    Ok(a.reshape([img.height(), img.width()])?.into_any().unbind())
}
