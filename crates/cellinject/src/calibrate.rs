//! `cellinject calibrate`: the cameras' pixels, the stacks-to-tip Jacobian and the
//! stacks' hysteresis, each written as a calibration file with what it was made on
//! (`cellinject_session::calibration`), or all three into one directory.

use std::path::{Path, PathBuf};

use anyhow::Result;
use cellinject_config::Description;
use cellinject_core::bench::{Bench, Timing};
use cellinject_core::calibrate;
use cellinject_core::vision::Acquisition;
use cellinject_print::calibrate as print;
use cellinject_session::calibration;
use clap::Subcommand;

use crate::backend::BackendArgs;
use crate::experiment::{bench_error, calibrations, file_bytes, given_pixels, setup};
use crate::output::print_json;
use crate::sim::TwinArgs;
use crate::{Format, InputError};

/// The calibrations.
#[derive(Debug, Subcommand)]
pub enum CalibrateCommand {
    /// Both cameras' pixel size, rotation and shear from stage moves.
    #[command(after_help = "Examples:\n  cellinject calibrate pixels --out pixels.json")]
    Pixels {
        /// Stage step, m (moves of ±1 and ±2 steps along each axis).
        #[arg(long, default_value_t = 4e-6, allow_negative_numbers = true)]
        step: f64,
        /// The calibration file (JSON).
        #[arg(long, default_value = "pixels.json")]
        out: PathBuf,
        #[command(flatten)]
        twin: TwinArgs,
        #[command(flatten)]
        backend: BackendArgs,
    },
    /// How each tilt stack moves the tip: the 2x2 Jacobian, checked against the model.
    #[command(
        after_help = "Examples:\n  cellinject calibrate jacobian --pixels pixels.json --out jacobian.json"
    )]
    Jacobian {
        /// The cameras' pixel calibration (default: made first).
        #[arg(long, value_name = "FILE.json")]
        pixels: Option<PathBuf>,
        /// Step of each stack, V.
        #[arg(long, default_value_t = 15.0, allow_negative_numbers = true)]
        volts: f64,
        /// Steps per stack.
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u64).range(1..=50))]
        repeats: u64,
        /// The calibration file (JSON).
        #[arg(long, default_value = "jacobian.json")]
        out: PathBuf,
        #[command(flatten)]
        twin: TwinArgs,
        #[command(flatten)]
        backend: BackendArgs,
    },
    /// The tilt stacks' hysteresis (Preisach) and creep from their position sensors.
    ///
    /// The macro stage first raises the pipette by as much as the sweep can lower its
    /// tip (clear of a plate under it), and brings it back after.
    #[command(after_help = "Examples:\n  cellinject calibrate hysteresis --out hysteresis.json")]
    Hysteresis {
        /// Excitation samples per stack, 1 ms apart (by default a run's own number).
        #[arg(long, default_value_t = cellinject_session::calibration::HYSTERESIS_SAMPLES as u64, value_parser = clap::value_parser!(u64).range(2000..=200_000))]
        samples: u64,
        /// Preisach cells per axis.
        #[arg(long, default_value_t = cellinject_session::calibration::HYSTERESIS_SIZE as u64, value_parser = clap::value_parser!(u64).range(2..=60))]
        size: u64,
        /// The calibration file (JSON).
        #[arg(long, default_value = "hysteresis.json")]
        out: PathBuf,
        #[command(flatten)]
        twin: TwinArgs,
        #[command(flatten)]
        backend: BackendArgs,
    },
    /// All three, into one directory (what `experiment --calibration DIR` reads).
    #[command(after_help = "Examples:\n  cellinject calibrate all --out calibration")]
    All {
        /// Directory (created if needed).
        #[arg(long, value_name = "DIR", default_value = "calibration")]
        out: PathBuf,
        #[command(flatten)]
        twin: TwinArgs,
        #[command(flatten)]
        backend: BackendArgs,
    },
}

/// Runs a `calibrate` command.
pub fn calibrate(d: &Description, cmd: &CalibrateCommand) -> Result<()> {
    match cmd {
        CalibrateCommand::Pixels {
            step,
            out,
            twin,
            backend,
        } => {
            let path = plan_json(out, None)?;
            let mut s = setup(d, twin, backend)?;
            let marker = s.description.rig.optics.marker;
            let c = {
                let _p = crate::progress::spinner("calibrating the cameras' pixels");
                calibrate::pixels(&mut s.rig, marker, *step).map_err(bench_error)?
            };
            cellinject_files::write_one(&path, &file_bytes("pixels", &s.made, &c)?)?;
            if twin.format() == Format::Json {
                return print_json(c, &[&path]);
            }
            outln!("{}", print::pixels_text(&c));
            outln!("wrote {}", path.display());
            Ok(())
        }
        CalibrateCommand::Jacobian {
            pixels,
            volts,
            repeats,
            out,
            twin,
            backend,
        } => calibrate_jacobian(d, pixels.as_deref(), *volts, *repeats, out, twin, backend),
        CalibrateCommand::Hysteresis {
            samples,
            size,
            out,
            twin,
            backend,
        } => {
            let path = plan_json(out, None)?;
            let mut s = setup(d, twin, backend)?;
            let c = {
                let _p = crate::progress::spinner("exciting A1 and A2");
                calibrate::sweep_drop(&s.description.design, &s.description.rig)
                    .and_then(|drop| {
                        calibrate::hysteresis_clear(
                            &mut s.rig,
                            drop,
                            *samples as usize,
                            *size as usize,
                        )
                    })
                    .map_err(bench_error)?
            };
            cellinject_files::write_one(&path, &file_bytes("hysteresis", &s.made, &c)?)?;
            if twin.format() == Format::Json {
                return print_json(&c, &[&path]);
            }
            outln!("{}", print::hysteresis_text(&c));
            outln!("wrote {}", path.display());
            Ok(())
        }
        CalibrateCommand::All { out, twin, backend } => {
            cellinject_files::check_dir("--out", out)?;
            let mut s = setup(d, twin, backend)?;
            let (px, cal, made) = calibrations(&mut s, None)?;
            let mut o = cellinject_files::Outputs::new("--out");
            o.add_named(out, made, "json")?;
            let files = o.commit()?;
            if twin.format() == Format::Json {
                let f: Vec<&Path> = files.iter().map(|p| p.as_path()).collect();
                return print_json(
                    serde_json::json!({
                        "approach": s.made.approach,
                        "pixels": px,
                        "jacobian": cal.jacobian,
                        "hysteresis": cal.hysteresis,
                    }),
                    &f,
                );
            }
            // What was found, as each calibration's own command says it.
            outln!("{}", print::pixels_text(&px));
            outln!("{}", print::jacobian_text(&cal.jacobian));
            outln!("{}", print::hysteresis_text(&cal.hysteresis));
            outln!("{}", cellinject_files::wrote(&files));
            Ok(())
        }
    }
}

/// `calibrate jacobian`.
fn calibrate_jacobian(
    d: &Description,
    pixels: Option<&Path>,
    volts: f64,
    repeats: u64,
    out: &Path,
    twin: &TwinArgs,
    backend: &BackendArgs,
) -> Result<()> {
    if !(volts.is_finite() && volts > 0.0 && volts <= 30.0) {
        return Err(InputError(format!(
            "--volts must lie in (0, 30] V (the cameras follow ±30 µm of tip), got {volts}"
        ))
        .into());
    }
    let path = plan_json(out, pixels.map(|p| ("--pixels", p)))?;
    let mut s = setup(d, twin, backend)?;
    let px = given_pixels(pixels, &s)?;
    let marker = s.description.rig.optics.marker;
    let px = match px {
        Some(c) => c,
        None => {
            calibrate::pixels(&mut s.rig, marker, calibration::PIXEL_STEP).map_err(bench_error)?
        }
    };
    let c = {
        let _p = crate::progress::spinner("stepping A1 and A2");
        let mut bench = Bench::new(
            &mut s.rig,
            Acquisition::Marker,
            marker,
            px.maps,
            None,
            Timing::default(),
        )
        .map_err(bench_error)?;
        calibrate::jacobian(
            &mut bench,
            &s.description.design,
            s.description.rig.approach,
            volts,
            repeats as usize,
        )
        .map_err(bench_error)?
    };
    cellinject_files::write_one(&path, &file_bytes("jacobian", &s.made, &c)?)?;
    if twin.format() == Format::Json {
        return print_json(c, &[&path]);
    }
    outln!("{}", print::jacobian_text(&c));
    outln!("wrote {}", path.display());
    Ok(())
}

/// Checks a JSON output path (and that it is not the input) before the bench runs.
fn plan_json(out: &Path, input: Option<(&str, &Path)>) -> Result<PathBuf> {
    let mut plan = cellinject_files::Plan::new();
    if let Some((arg, p)) = input {
        plan.input(arg, p);
    }
    let p = plan.output("--out", out, &[cellinject_files::Kind::Json])?;
    plan.check()?;
    Ok(p)
}
