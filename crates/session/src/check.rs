//! Whether each device of a rig answers (`cellinject rig check`): each opened
//! through its driver and asked one harmless question (a voltage, a frame, a
//! position, a limit, the zoom). Nothing moves.

use cellinject_config::Description;
use cellinject_config::rigfile::{CameraDriver, DeviceDriver, PiezoDriver, RigFile};
use cellinject_gcs_emulator::bench::ViewName;
use cellinject_hw::{Camera, Injector, Optics, PiezoChannel, Stage};

use crate::drivers::{Drivers, SharedOptics, StageRole};
use crate::{SessionError, TwinOptions};

/// One device's answer.
#[derive(Debug, Clone, PartialEq)]
pub struct Answer {
    /// The rig file's section (`piezo`, `camera.top`, ...).
    pub section: &'static str,
    /// Its driver, as the rig names it.
    pub driver: String,
    /// What it answered (`Ok`: a reading, in SI units), or why it did not.
    pub result: Result<String, String>,
}

/// The sections, in the rig file's order.
const SECTIONS: [&str; 7] = [
    "piezo",
    "camera.top",
    "camera.side",
    "stage.macro",
    "stage.feeder",
    "injector",
    "optics",
];

fn driver_text(rig: &RigFile, section: &str) -> String {
    let cam = |c: &CameraDriver| match c {
        CameraDriver::Twin => "twin".to_string(),
        CameraDriver::Bench(a) => format!("bench://{a}"),
        CameraDriver::Aravis(id) => format!("aravis:{id}"),
        CameraDriver::Dir { path, fps } => format!("dir:{path} ({fps} fps)"),
    };
    let dev = |d: &DeviceDriver| match d {
        DeviceDriver::Twin => "twin".to_string(),
        DeviceDriver::Bench(a) => format!("bench://{a}"),
        DeviceDriver::Sensapex(s) => s.url(),
    };
    match section {
        "piezo" => match &rig.piezo {
            PiezoDriver::Twin => "twin".into(),
            PiezoDriver::Gcs { url, axes } => format!("{url} (axes {})", axes.join(", ")),
        },
        "camera.top" => cam(&rig.camera_top),
        "camera.side" => cam(&rig.camera_side),
        "stage.macro" => dev(&rig.stage_macro),
        "stage.feeder" => dev(&rig.stage_feeder),
        "injector" => dev(&rig.injector),
        _ => dev(&rig.optics),
    }
}

fn voltages(piezo: &mut [&mut dyn PiezoChannel]) -> Result<String, String> {
    let mut out = Vec::new();
    for p in piezo.iter_mut() {
        let v = p.read_voltage().map_err(|e| e.to_string())?;
        out.push(format!("{} {v:.2} V", p.name()));
    }
    Ok(out.join(", "))
}

fn frame(c: &mut dyn Camera) -> Result<String, String> {
    let f = c.grab().map_err(|e| e.to_string())?;
    Ok(format!(
        "a {}x{} frame, {}-bit, {:.3} µm per pixel",
        f.width,
        f.height,
        f.bit_depth,
        f.pixel_size * 1e6
    ))
}

fn position(s: &mut dyn Stage) -> Result<String, String> {
    let mut out = Vec::new();
    for axis in 0..s.axes() {
        let x = s.position(axis).map_err(|e| e.to_string())?;
        out.push(format!("{:.1}", x * 1e6));
    }
    Ok(format!("at ({}) µm", out.join(", ")))
}

fn pressure(i: &dyn Injector) -> Result<String, String> {
    Ok(format!("up to {:.0} kPa", i.max_pressure() / 1e3))
}

fn zoom(o: &dyn Optics) -> Result<String, String> {
    let (lo, hi) = o.zoom_range();
    let z = o.zoom();
    // A lens changer at its empty centre has no zoom until a lens is turned in.
    let now = if z.is_finite() {
        format!("zoom {z:.2}x")
    } else {
        "no lens in place".to_string()
    };
    Ok(format!("{now} (range {lo}x to {hi}x)"))
}

/// Asks each device of `rig` whether it answers, in the rig file's order. A rig
/// that is not valid is refused whole ([`crate::validate`]); a device that does not
/// answer is reported and the others are still asked.
pub fn check(d: &Description, rig: &RigFile) -> Result<Vec<Answer>, SessionError> {
    crate::validate(rig)
        .map_err(|(key, reason)| crate::refused(format!("the rig's `{key}`"), reason))?;
    let results = if rig.is_twin() {
        twin(d, rig)?
    } else {
        real(d, rig)
    };
    Ok(SECTIONS
        .iter()
        .zip(results)
        .map(|(&section, result)| Answer {
            section,
            driver: driver_text(rig, section),
            result,
        })
        .collect())
}

/// `cellinject rig check`'s lines: each device's section, driver and answer (`ok` or
/// `NO` and why), aligned.
pub fn text(answers: &[Answer]) -> String {
    let width = answers.iter().map(|x| x.driver.len()).max().unwrap_or(0);
    answers
        .iter()
        .map(|x| {
            let (mark, detail) = match &x.result {
                Ok(s) => ("ok ", s.as_str()),
                Err(s) => ("NO ", s.as_str()),
            };
            format!(
                "  {mark} {:<12} {:<width$}  {detail}\n",
                x.section, x.driver
            )
        })
        .collect()
}

/// What `cellinject rig check --format json` prints and Python's `rig.check`
/// returns: the rig's name and bench, and each device's answer.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct CheckReport {
    /// The rig file's `name`, if it has one.
    pub name: Option<String>,
    /// The bench as the run records name it (`twin`, `gcs://HOST:PORT`).
    pub backend: String,
    /// Each device, in the rig file's order.
    pub devices: Vec<DeviceReport>,
}

/// One device of a [`CheckReport`].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DeviceReport {
    /// The rig file's section.
    pub section: &'static str,
    /// Its driver.
    pub driver: String,
    /// Whether it answered.
    pub answers: bool,
    /// What it answered, or why it did not.
    pub detail: String,
}

impl CheckReport {
    /// The report of `answers` ([`check`]) on `rig`.
    pub fn new(rig: &RigFile, answers: &[Answer]) -> Self {
        CheckReport {
            name: rig.name.clone(),
            backend: rig.backend().to_string(),
            devices: answers
                .iter()
                .map(|x| DeviceReport {
                    section: x.section,
                    driver: x.driver.clone(),
                    answers: x.result.is_ok(),
                    detail: match &x.result {
                        Ok(s) | Err(s) => s.clone(),
                    },
                })
                .collect(),
        }
    }
}

fn twin(d: &Description, rig: &RigFile) -> Result<Vec<Result<String, String>>, SessionError> {
    let mut o = crate::open(d, rig, TwinOptions::default())?;
    let r = &mut o.rig;
    let [a, b, c] = &mut r.piezo;
    Ok(vec![
        voltages(&mut [a, b, c]),
        frame(&mut r.camera),
        frame(&mut r.side_camera),
        position(&mut r.stage),
        position(&mut r.feeder),
        pressure(&r.injector),
        zoom(&r.optics),
    ])
}

fn real(d: &Description, rig: &RigFile) -> Vec<Result<String, String>> {
    let piezo = match &rig.piezo {
        PiezoDriver::Gcs { url, axes } => crate::controller(url).and_then(|gcs| {
            let ranges = [0, 1, 2].map(|k| (0.0, d.rig.amplifiers[k].v_max));
            let axes = [axes[0].as_str(), axes[1].as_str(), axes[2].as_str()];
            cellinject_gcs::devices::stacks(
                &gcs,
                axes,
                cellinject_model::ACTUATOR_NAMES,
                ranges,
                [0.0; 3],
            )
            .map_err(|e| crate::device(url.clone(), e))
        }),
        PiezoDriver::Twin => Err(crate::refused("piezo", "the twin")),
    };
    let piezo = piezo.map_err(|e| e.to_string()).and_then(|(mut p, _)| {
        let [a, b, c] = &mut p;
        voltages(&mut [a, b, c])
    });
    let text = |e: SessionError| e.to_string();
    let mut drivers = Drivers::default();
    let main = drivers.first(rig).map_err(text);
    let optics = drivers.optics(&rig.optics).map(SharedOptics::new);
    let pitch = d.sim.camera.pixel_size;
    let mut camera = |key: &str, driver: &CameraDriver, view: ViewName| match driver {
        CameraDriver::Bench(a) => drivers
            .endpoint(a)
            .map_err(text)
            .and_then(|b| b.camera(view).map_err(|e| e.to_string()))
            .and_then(|mut c| frame(&mut c)),
        other => main.clone().and_then(|m| {
            // Without the optics, a pixel's size is unknown.
            let size = match &optics {
                Ok(o) => o.pixel_size(pitch),
                Err(_) => Box::new(|| f64::NAN),
            };
            crate::own_camera(key, other, &m, size)
                .map_err(text)
                .and_then(|mut c| frame(c.as_mut()))
        }),
    };
    let top = camera("camera.top", &rig.camera_top, ViewName::Top);
    let side = camera("camera.side", &rig.camera_side, ViewName::Side);
    let stage = drivers
        .stage(&rig.stage_macro, StageRole::Macro)
        .map_err(text)
        .and_then(|mut s| position(s.as_mut()));
    let feeder = drivers
        .stage(&rig.stage_feeder, StageRole::Feeder)
        .map_err(text)
        .and_then(|mut s| position(s.as_mut()));
    let injector = drivers
        .injector(&rig.injector, d.rig.injector_max_pressure)
        .map_err(text)
        .and_then(|i| pressure(i.as_ref()));
    let optics = optics.map_err(text).and_then(|o| zoom(&o));
    vec![piezo, top, side, stage, feeder, injector, optics]
}

#[cfg(test)]
mod tests {
    use cellinject_hw::{HwError, Optics};

    struct Lens(f64);

    impl Optics for Lens {
        fn zoom(&self) -> f64 {
            self.0
        }
        fn zoom_range(&self) -> (f64, f64) {
            (4.0, 10.0)
        }
        fn set_zoom(&mut self, _: f64) -> Result<(), HwError> {
            Ok(())
        }
    }

    /// The optics' line: the zoom in place, or none when a lens changer sits at its
    /// empty centre (its zoom is NaN), with the range either way.
    #[test]
    fn the_optics_line_says_the_zoom_or_that_no_lens_is_in_place() {
        assert_eq!(
            super::zoom(&Lens(4.0)).unwrap(),
            "zoom 4.00x (range 4x to 10x)"
        );
        assert_eq!(
            super::zoom(&Lens(f64::NAN)).unwrap(),
            "no lens in place (range 4x to 10x)"
        );
    }
}
