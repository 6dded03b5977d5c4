//! `cellinject.vision`: cells and the pipette's tip in a lab's own micrograph, a NumPy
//! image in, the dict of `cellinject vision cells` (`tip`) `--format json` out.

use cellinject_cells::CellsError;
use cellinject_cells::tip::find_tip_in;
use cellinject_cells::vision::{Arg, Contrast, Request, find_cells};
use cellinject_print::vision::{CellsReport, VisionTip};
use pyo3::prelude::*;

use crate::{Kind, err, input, to_py};

/// The cells (and the debris apart) in ``image``, a 2-D array of grey levels (uint8,
/// uint16 or float; rows x columns): each with ``x_px``, ``y_px`` (x along the
/// columns, y along the rows, from the centre of the top-left pixel), ``diameter_px``,
/// ``diameter_m`` (None without ``pixel_size``), ``confidence`` (0-1) and
/// ``contrast`` (``"bright"`` or ``"dark"``); ``pixel_size_m``. ``pixel_size``: m per
/// pixel; ``diameter``: (min, max) in m, needs ``pixel_size`` (default 9.5-30 µm with
/// one, 8 px to half the shorter side without); ``contrast``: ``"auto"``, ``"dark"`` or
/// ``"bright"``. What ``cellinject vision cells --format json`` prints (docs/vision.md).
///
/// Example: a bright disc of 50 px on a grey field.
///
/// >>> y, x = np.mgrid[0:120, 0:140]
/// >>> disc = np.where(np.hypot(x - 70.3, y - 60.0) < 25.0, 200.0, 70.0)
/// >>> found = cellinject.vision.cells(disc, pixel_size=0.4e-6)
/// >>> [(round(c["x_px"]), round(c["y_px"]), round(c["diameter_px"]), c["contrast"]) for c in found["cells"]]
/// [(70, 60, 50, 'bright')]
#[pyfunction]
#[pyo3(signature = (image, pixel_size=None, diameter=None, contrast="auto"))]
fn vision_cells(
    py: Python<'_>,
    image: &Bound<'_, PyAny>,
    pixel_size: Option<f64>,
    diameter: Option<(f64, f64)>,
    contrast: &str,
) -> PyResult<Py<PyAny>> {
    let contrast = match contrast {
        "auto" => Contrast::Auto,
        "dark" => Contrast::Dark,
        "bright" => Contrast::Bright,
        other => {
            return Err(input(format!(
                "contrast must be auto, dark or bright, got `{other}`"
            )));
        }
    };
    let request = Request {
        pixel_size,
        diameter: diameter.map(|(lo, hi)| [lo, hi]),
        contrast,
    };
    let img = crate::arrays::image("image", image)?;
    let options = request.options(img.width(), img.height()).map_err(|e| {
        let arg = match e.arg() {
            Arg::PixelSize => "pixel_size",
            Arg::Diameter => "diameter",
        };
        input(format!("{arg} {e}"))
    })?;
    let census = py
        .detach(|| find_cells(img.data(), img.width(), img.height(), &options))
        .map_err(|e| input(format!("image: {e}")))?;
    to_py(py, &CellsReport::new(&census, pixel_size))
}

/// The pipette's tip in ``image``, a 2-D array of grey levels (uint8, uint16 or float,
/// none negative; rows x columns), the pipette entering from any edge: ``tip_px``
/// (``[x, y]``, x along the columns, y along the rows, from the centre of the top-left
/// pixel), ``axis_rad`` (from the tip towards the shank, ``atan2(dy, dx)``),
/// ``width_px`` (5 µm behind the tip), ``width_m`` (None without ``pixel_size``),
/// ``confidence`` (0-1) and ``pixel_size_m``. ``pixel_size``: m per pixel (default:
/// the image's shorter side taken as 240 µm). No pipette in view raises
/// ``cellinject.NotConverged`` (a ``RuntimeError``); bad input
/// ``cellinject.InputError`` (a ``ValueError``). What ``cellinject vision tip --format
/// json`` prints (docs/vision.md).
///
/// Example: a dark tube entering from the left, its tip at column 80, row 60.
///
/// >>> y, x = np.mgrid[0:120, 0:160].astype(float)
/// >>> r = 1.5 + 0.12 * np.maximum(80.0 - x, 0.0)
/// >>> dark = 0.4 / (1 + np.exp((np.abs(y - 60.0) - r) / 0.6)) / (1 + np.exp((x - 80.0) / 0.6))
/// >>> tip = cellinject.vision.tip(1000.0 * (1.0 - dark), pixel_size=0.5e-6)
/// >>> [round(v) for v in tip["tip_px"]], abs(round(np.degrees(tip["axis_rad"])))
/// ([80, 60], 180)
#[pyfunction]
#[pyo3(signature = (image, pixel_size=None))]
fn vision_tip(
    py: Python<'_>,
    image: &Bound<'_, PyAny>,
    pixel_size: Option<f64>,
) -> PyResult<Py<PyAny>> {
    let img = crate::arrays::image("image", image)?;
    let found = py.detach(|| find_tip_in(img.data(), img.width(), img.height(), pixel_size));
    let tip = match found {
        Ok(t) => t,
        Err(CellsError::NoPipette) => {
            return Err(err(Kind::NotConverged, CellsError::NoPipette.to_string()));
        }
        Err(CellsError::Invalid {
            what: "pixel_size", ..
        }) => {
            return Err(input(format!(
                "pixel_size {pixel_size:?}: must be a positive length in m"
            )));
        }
        Err(e) => return Err(input(format!("image: {e}"))),
    };
    to_py(py, &VisionTip::new(&tip, pixel_size))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(vision_cells, m)?)?;
    m.add_function(wrap_pyfunction!(vision_tip, m)?)
}
