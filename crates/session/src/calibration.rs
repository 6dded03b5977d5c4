//! The calibration files of a bench: their format (the calibration with what it was
//! made on), reading one back with its kind checked, and telling a calibration made on
//! another bench (approach, backend, the twin's seed, the description) from one made
//! on this. Every front end reads and writes calibrations through this module.
//!
//! A file is JSON: `{"kind": "pixels" | "jacobian" | "hysteresis", "made": {...},
//! "calibration": {...}}` (docs/json.md).

use std::path::{Path, PathBuf};

use cellinject_config::Description;
use cellinject_core::bench::{Bench, BenchError, Timing};
use cellinject_core::calibrate::{
    self, HysteresisCalibration, JacobianCalibration, PixelCalibration,
};
use cellinject_core::experiment::Calibrations;
use cellinject_core::vision::Acquisition;
use cellinject_rig::{Backend, Rig};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// What a calibration file holds besides the calibration: what it was made on, when.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Made {
    /// UTC, ISO 8601.
    pub created_utc: String,
    /// `twin` or a driver's name.
    pub backend: String,
    /// The description's name.
    pub design: String,
    /// 1 or 2.
    pub approach: u8,
    /// The twin's seed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// The lens's magnification.
    pub zoom: f64,
    /// FNV-1a digest of the description the calibration was made with (files made
    /// before 0.1 of this field have none: their design's name alone is checked).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description_digest: Option<String>,
}

/// A calibration file.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CalibrationFile<T> {
    /// `pixels`, `jacobian` or `hysteresis`.
    pub kind: String,
    /// What it was made on.
    pub made: Made,
    /// The calibration.
    pub calibration: T,
}

/// Why a calibration file cannot be used at all (bad input: the caller names the
/// option that gave it).
#[derive(Debug, Error)]
pub enum CalibrationError {
    /// The file cannot be read.
    #[error("cannot read `{}`: {reason}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The system's reason.
        reason: String,
    },
    /// It is not a calibration file of the kind asked for.
    #[error("`{}` is not a {kind} calibration file: {reason}", path.display())]
    NotOne {
        /// The file.
        path: PathBuf,
        /// The kind asked for.
        kind: String,
        /// The parser's reason.
        reason: String,
    },
    /// It holds another kind of calibration.
    #[error("`{}` holds a {found} calibration, not a {kind} one", path.display())]
    OtherKind {
        /// The file.
        path: PathBuf,
        /// The kind it holds.
        found: String,
        /// The kind asked for.
        kind: String,
    },
}

impl Made {
    /// What a calibration made now on the bench `o` records, and the description as
    /// that bench runs it (`d` with the approach the bench was assembled with): the
    /// twin's seed and zoom on the twin, the lens's zoom on hardware.
    pub fn of(d: &Description, o: &crate::Opened) -> (Made, Description) {
        use cellinject_hw::Optics as _;
        let (seed, zoom) = match &o.twin {
            Some(twin) => {
                let t = twin.lock().unwrap_or_else(|e| e.into_inner());
                (Some(t.world.params().sim.seed), t.camera.zoom())
            }
            None => (None, o.rig.optics.zoom()),
        };
        let mut description = d.clone();
        description.rig.approach = o.approach;
        let made = Made {
            created_utc: utc_now(),
            backend: o.name.clone(),
            design: d.name.clone(),
            approach: o.approach.number(),
            seed,
            zoom,
            description_digest: Some(description_digest(d)),
        };
        (made, description)
    }
}

/// A digest of description `d`, every value it holds (not its file's text: comments
/// and the order of keys do not change it): FNV-1a, 64 bits, of its debug form, as 16
/// hex digits. It tells a calibration made on another description (a stack's travel,
/// a lever's length) from one made on this, whatever their names.
pub fn description_digest(d: &Description) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in format!("{d:?}").bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// The bench a run loads a calibration for: what its file must have been made on.
pub struct RunBench<'a> {
    /// The description the run uses.
    pub d: &'a Description,
    /// `twin` or the controller's address.
    pub backend: &'a str,
    /// The twin's seed (None on hardware).
    pub seed: Option<u64>,
}

/// What makes a calibration made on `m` unfit for `bench`, if anything.
pub fn made_elsewhere(m: &Made, bench: &RunBench<'_>) -> Option<String> {
    let approach = bench.d.rig.approach.number();
    if m.approach != approach {
        return Some(format!(
            "was made under approach {}, the bench is assembled with approach {approach}",
            m.approach
        ));
    }
    if m.backend != bench.backend {
        return Some(format!(
            "was made on backend {}, the run is on {}",
            m.backend, bench.backend
        ));
    }
    if let (Some(made), Some(now)) = (m.seed, bench.seed)
        && made != now
    {
        return Some(format!(
            "was made on the twin of seed {made}, the run's twin has seed {now}"
        ));
    }
    if m.design != bench.d.name {
        return Some(format!(
            "was made for the description `{}`, the run uses `{}`",
            m.design, bench.d.name
        ));
    }
    let digest = description_digest(bench.d);
    if let Some(made) = &m.description_digest
        && *made != digest
    {
        return Some(format!(
            "was made with another description of `{}` (digest {made}, this one's {digest}: a value differs)",
            m.design
        ));
    }
    None
}

/// Now as `YYYY-MM-DDTHH:MM:SSZ`.
pub fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0);
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem / 60 % 60,
        rem % 60
    )
}

/// The calibration file of `kind` at `path`.
pub fn read_file<T: DeserializeOwned>(
    path: &Path,
    kind: &str,
) -> Result<CalibrationFile<T>, CalibrationError> {
    let text = std::fs::read_to_string(path).map_err(|e| CalibrationError::Read {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    let f: CalibrationFile<T> =
        serde_json::from_str(&text).map_err(|e| CalibrationError::NotOne {
            path: path.to_path_buf(),
            kind: kind.to_string(),
            reason: e.to_string(),
        })?;
    if f.kind != kind {
        return Err(CalibrationError::OtherKind {
            path: path.to_path_buf(),
            found: f.kind,
            kind: kind.to_string(),
        });
    }
    Ok(f)
}

/// A hysteresis calibration file for a run, checked against the bench it is to be
/// used on: its kind (an error when it is not one), then what it was made on (the
/// approach, the backend, the twin's seed, the description's name and digest).
/// `Ok((None, Some(why)))` when it was made on another bench: the run identifies the
/// stacks again and records why; never used silently.
pub fn read_hysteresis_for_run(
    path: &Path,
    bench: &RunBench<'_>,
) -> Result<(Option<HysteresisCalibration>, Option<String>), CalibrationError> {
    let f = read_file::<HysteresisCalibration>(path, "hysteresis")?;
    Ok(match made_elsewhere(&f.made, bench) {
        None => (Some(f.calibration), None),
        Some(w) => (None, Some(format!("`{}` {w}", path.display()))),
    })
}

/// The file of calibration `c` of `kind` made on `made`: pretty JSON, a final newline.
pub fn file_bytes<T: Serialize + Clone>(
    kind: &str,
    made: &Made,
    c: &T,
) -> Result<Vec<u8>, serde_json::Error> {
    let mut s = serde_json::to_string_pretty(&CalibrationFile {
        kind: kind.into(),
        made: made.clone(),
        calibration: c.clone(),
    })?;
    s.push('\n');
    Ok(s.into_bytes())
}

/// What [`load_or_make`] is doing, for a front end to show.
#[derive(Debug, Clone, PartialEq)]
pub enum Step {
    /// Calibration `k` of the three (1: the cameras' pixels, 2: the stacks' hysteresis,
    /// 3: the Jacobian) is being made: what, for a spinner, and `k`.
    Making(&'static str, usize),
    /// A file was not used and the calibration is made again (why, for a note).
    Redo(String),
}

/// Calibration files made by [`load_or_make`]: (kind, the file's bytes).
pub type MadeFiles = Vec<(String, Vec<u8>)>;

/// Why [`load_or_make`] failed.
#[derive(Debug, Error)]
pub enum LoadError {
    /// A file given is not a calibration of its kind (bad input).
    #[error(transparent)]
    File(#[from] CalibrationError),
    /// A calibration could not be made.
    #[error(transparent)]
    Bench(#[from] BenchError),
    /// A calibration could not be written as JSON.
    #[error("cannot write a calibration as JSON: {0}")]
    Json(#[from] serde_json::Error),
}

/// The stage step of the pixel calibration, m.
pub const PIXEL_STEP: f64 = 4e-6;
/// The hysteresis identification's excitation and Preisach plane: the run's own
/// (`cellinject_core::calibrate`), one set for every front end.
pub use cellinject_core::calibrate::{HYSTERESIS_SAMPLES, HYSTERESIS_SIZE};
/// The Jacobian calibration's voltage step, V.
pub const JACOBIAN_STEP: f64 = 15.0;
/// The Jacobian calibration's repeats of each step.
pub const JACOBIAN_REPEATS: usize = 3;

/// The calibration of `kind` from `path`, or `None` (said through `step`) when it was
/// made under another approach: the caller makes it again. Pixels do not depend on the
/// approach.
pub fn load<T: DeserializeOwned>(
    path: &Path,
    kind: &str,
    approach: u8,
    step: &mut dyn FnMut(Step),
) -> Result<Option<T>, CalibrationError> {
    let f = read_file::<T>(path, kind)?;
    if kind != "pixels" && f.made.approach != approach {
        step(Step::Redo(format!(
            "`{}` was made under approach {}, the bench is assembled with approach {approach}: calibrating again",
            path.display(),
            f.made.approach
        )));
        return Ok(None);
    }
    Ok(Some(f.calibration))
}

/// [`load`], then the calibration's own check (`problem`): a failing one is said and
/// dropped (to be made again), never used.
pub fn load_checked<T: DeserializeOwned>(
    path: Option<&Path>,
    kind: &str,
    approach: u8,
    problem: impl Fn(&T) -> Option<String>,
    step: &mut dyn FnMut(Step),
) -> Result<Option<T>, CalibrationError> {
    let Some(p) = path else {
        return Ok(None);
    };
    let Some(c) = load::<T>(p, kind, approach, step)? else {
        return Ok(None);
    };
    Ok(match problem(&c) {
        None => Some(c),
        Some(why) => {
            step(Step::Redo(format!(
                "`{}` fails its check ({why}): calibrating again",
                p.display()
            )));
            None
        }
    })
}

/// The calibrations an experiment needs on `rig` (made on `made`, for `description`):
/// each loaded from `dir` (`pixels.json`, `hysteresis.json`, `jacobian.json`) where it
/// is there, of this approach and passes its check, made otherwise with this module's
/// parameters; the ones made are returned as files for saving.
pub fn load_or_make<B: Backend>(
    rig: &mut Rig<B>,
    made: &Made,
    description: &Description,
    dir: Option<&Path>,
    step: &mut dyn FnMut(Step),
) -> Result<(PixelCalibration, Calibrations, MadeFiles), LoadError> {
    let mut files = Vec::new();
    let marker = description.rig.optics.marker;
    let file = |name: &str| dir.map(|d| d.join(format!("{name}.json")));
    let pixels = load_checked(
        file("pixels").as_deref(),
        "pixels",
        made.approach,
        |c: &PixelCalibration| c.problem(made.zoom),
        step,
    )?;
    let pixels = match pixels {
        Some(p) => p,
        None => {
            step(Step::Making(
                "calibrating the cameras' pixels (stage moves)",
                1,
            ));
            let c = calibrate::pixels(rig, marker, PIXEL_STEP)?;
            files.push(("pixels".into(), file_bytes("pixels", made, &c)?));
            c
        }
    };
    let hysteresis = load_checked(
        file("hysteresis").as_deref(),
        "hysteresis",
        made.approach,
        |c: &HysteresisCalibration| c.problem(),
        step,
    )?;
    let hysteresis = match hysteresis {
        Some(h) => h,
        None => {
            step(Step::Making(
                "identifying the stacks' hysteresis and creep",
                2,
            ));
            let drop = calibrate::sweep_drop(&description.design, &description.rig)?;
            let c = calibrate::hysteresis_clear(rig, drop, HYSTERESIS_SAMPLES, HYSTERESIS_SIZE)?;
            files.push(("hysteresis".into(), file_bytes("hysteresis", made, &c)?));
            c
        }
    };
    let jacobian = load_checked(
        file("jacobian").as_deref(),
        "jacobian",
        made.approach,
        |c: &JacobianCalibration| c.problem(),
        step,
    )?;
    let jacobian = match jacobian {
        Some(j) => j,
        None => {
            step(Step::Making("measuring the stacks-to-tip Jacobian", 3));
            let mut bench = Bench::new(
                rig,
                Acquisition::Marker,
                marker,
                pixels.maps,
                None,
                Timing::default(),
            )?;
            let c = calibrate::jacobian(
                &mut bench,
                &description.design,
                description.rig.approach,
                JACOBIAN_STEP,
                JACOBIAN_REPEATS,
            )?;
            files.push(("jacobian".into(), file_bytes("jacobian", made, &c)?));
            c
        }
    };
    Ok((
        pixels,
        Calibrations {
            jacobian,
            hysteresis,
        },
        files,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn made(d: &Description, seed: Option<u64>) -> Made {
        Made {
            created_utc: "2026-12-05T00:00:00Z".into(),
            backend: "twin".into(),
            design: d.name.clone(),
            approach: d.rig.approach.number(),
            seed,
            zoom: 2.5,
            description_digest: Some(description_digest(d)),
        }
    }

    #[test]
    fn a_calibration_from_another_bench_is_told_apart() {
        let d = cellinject_config::prototype();
        let bench = RunBench {
            d: &d,
            backend: "twin",
            seed: Some(1),
        };
        assert_eq!(made_elsewhere(&made(&d, Some(1)), &bench), None);
        let why = made_elsewhere(&made(&d, Some(2)), &bench).expect("another seed");
        assert!(why.contains("seed 2") && why.contains("seed 1"), "{why}");
        let gcs = RunBench {
            backend: "gcs://127.0.0.1:50000",
            seed: None,
            ..bench
        };
        let why = made_elsewhere(&made(&d, Some(1)), &gcs).expect("another backend");
        assert!(why.contains("backend twin"), "{why}");
        // Same name, one value changed: the digest tells.
        let mut other = d.clone();
        other.sim.stage.settling_time *= 1.2;
        let why = made_elsewhere(&made(&other, Some(1)), &bench).expect("another description");
        assert!(why.contains("digest"), "{why}");
        // A file from before the digest: the name alone is checked.
        let mut old = made(&other, Some(1));
        old.description_digest = None;
        assert_eq!(made_elsewhere(&old, &bench), None);
        let mut renamed = made(&d, Some(1));
        renamed.design = "My bench".into();
        let why = made_elsewhere(&renamed, &bench).expect("another name");
        assert!(why.contains("My bench"), "{why}");
    }

    #[test]
    fn a_file_reads_back_as_written_and_another_kind_is_refused() {
        let d = cellinject_config::prototype();
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("x.json");
        let m = made(&d, Some(1));
        std::fs::write(&p, file_bytes("pixels", &m, &[1.5f64, 2.0]).expect("json")).expect("write");
        let f: CalibrationFile<[f64; 2]> = read_file(&p, "pixels").expect("reads");
        assert_eq!((f.made, f.calibration), (m, [1.5, 2.0]));
        let e = read_file::<[f64; 2]>(&p, "jacobian").expect_err("another kind");
        assert!(matches!(e, CalibrationError::OtherKind { .. }), "{e}");
        let e = read_file::<[f64; 3]>(&p, "pixels").expect_err("not one");
        assert!(
            e.to_string().contains("is not a pixels calibration file"),
            "{e}"
        );
        let e =
            read_file::<[f64; 2]>(&dir.path().join("none.json"), "pixels").expect_err("no file");
        assert!(e.to_string().contains("cannot read"), "{e}");
    }

    /// The stacks' sweep on a bench with a plate under the pipette, as `emulate gcs
    /// --plate` serves it and a run starts (the pipette 30 µm above focus): swept where
    /// the pipette stands, the tilt of body 1 drives the tip into the floor; raised by
    /// [`calibrate::sweep_drop`] first ([`calibrate::hysteresis_clear`], what the
    /// calibration commands and the dashboard run), the tip meets neither the floor nor
    /// a cell, and the pipette ends where it stood; a sweep that fails leaves it raised.
    #[test]
    fn the_stacks_sweep_clears_a_plate_under_the_pipette() {
        use cellinject_hw::Stage;
        use cellinject_plate::{Object, Plate};
        use cellinject_twin::{Twin, TwinParams, rig};
        let d = cellinject_config::prototype();
        let plate = |diameter: f64| {
            let cell = |row, col| Object {
                well: [row, col],
                offset: [0.0, 0.0],
                diameter,
            };
            Plate {
                rows: 2,
                cols: 2,
                pitch: 150e-6,
                origin: [-75e-6, -45e-6],
                cells: vec![cell(0, 0), cell(0, 1), cell(1, 0), cell(1, 1)],
                debris: vec![],
            }
        };
        let start = cellinject_core::inject::Options::default();
        let loaded_with = |seed: u64, diameter: f64| {
            let mut params = TwinParams {
                rig: d.rig,
                ..TwinParams::default()
            };
            params.sim.seed = seed;
            let plate = plate(diameter);
            let t = Twin::new(&d.design, params).unwrap().into_shared();
            let mut w = t.lock().unwrap();
            w.load_plate(&plate);
            w.world.stage.place(1, start.focus + start.lift);
            drop(w);
            t
        };
        // (floor strikes, m of tip lost, cells touched, punctures) after the sweep.
        let harm = |t: &cellinject_twin::SharedTwin| {
            let w = t.lock().unwrap();
            let b = w.biology.as_ref().unwrap();
            let touched = b.cells.iter().filter(|c| c.touched || c.grazed).count();
            let punctures: u32 = b.cells.iter().map(|c| c.punctures).sum();
            (b.floor_strikes, b.tip_loss, touched, punctures)
        };
        let drop = calibrate::sweep_drop(&d.design, &d.rig).unwrap();
        // A bare sweep strikes and a clear one touches nothing, comes back to its
        // height and fits: the default seed with 20 µm cells, then over seeds (the
        // stacks' noise, creep and stick-slip) and the smallest and largest cells the
        // workflow takes. The twin and rig of the last clear sweep are returned.
        let sweeps = |seed: u64, diameter: f64| {
            let bare = loaded_with(seed, diameter);
            calibrate::hysteresis(&mut rig(&bare).unwrap(), 2000, 12).unwrap();
            assert!(
                harm(&bare).0 > 0,
                "seed {seed}, {diameter} m: bare {:?}",
                harm(&bare)
            );
            let clear = loaded_with(seed, diameter);
            let mut r = rig(&clear).unwrap();
            let y0 = r.stage.position(1).unwrap();
            let c = calibrate::hysteresis_clear(&mut r, drop, 2000, 12).unwrap();
            assert_eq!(harm(&clear), (0, 0.0, 0, 0), "seed {seed}, {diameter} m");
            assert!((r.stage.position(1).unwrap() - y0).abs() < 0.1e-6);
            assert_eq!(c.problem(), None, "seed {seed}, {diameter} m");
            (clear, r, y0)
        };
        for seed in 1..=6 {
            for diameter in [10e-6, 30e-6] {
                sweeps(seed, diameter);
            }
        }
        let (clear, mut r, y0) = sweeps(TwinParams::default().sim.seed, 20e-6);
        // A clearance that is not a length is refused before anything moves.
        let e = calibrate::hysteresis_clear(&mut r, f64::NAN, 2000, 12).unwrap_err();
        assert!(e.to_string().contains("clearance"), "{e}");
        assert!((r.stage.position(1).unwrap() - y0).abs() < 0.1e-6);
        // A sweep that fails leaves the pipette raised (the safe side).
        assert!(calibrate::hysteresis_clear(&mut r, drop, 100, 12).is_err());
        assert!((r.stage.position(1).unwrap() - (y0 + drop)).abs() < 0.1e-6);
        assert_eq!(harm(&clear), (0, 0.0, 0, 0));
    }
}
