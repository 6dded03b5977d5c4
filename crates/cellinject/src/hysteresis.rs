//! `cellinject hysteresis identify | fit | invert | validate`: identification data from
//! the twin, models fitted to any (voltage, displacement) CSV, the voltages that make an
//! actuator follow a trajectory, and a model's prediction of a second recording; each
//! plots what it did.

use std::path::{Path, PathBuf};

use anyhow::Result;
use cellinject_config::Description;
use cellinject_core::hysteresis::{self as core, Kind};
use cellinject_hysteresis::{AnyModel, HysteresisError, Model};
use cellinject_print::hysteresis as print;
use clap::{Subcommand, ValueEnum};

use cellinject_core::table::Table;
use serde::Serialize;

use crate::output::print_json;
use crate::{Format, InputError};
use cellinject_files::{Kind as FileKind, Plan, write_with_plots, wrote};

/// Model classes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ModelArg {
    /// Discrete Preisach (the default): relay density on a grid, with a reversible part.
    Preisach,
    /// Classical Prandtl-Ishlinskii (play operators).
    Pi,
    /// Prandtl-Ishlinskii with a quadratic input term (asymmetric loops).
    PiAsym,
}

impl ModelArg {
    /// The class as text says it.
    fn name(self) -> &'static str {
        match self {
            ModelArg::Preisach => "Preisach",
            ModelArg::Pi => "PI (Prandtl-Ishlinskii)",
            ModelArg::PiAsym => "asymmetric PI (Prandtl-Ishlinskii)",
        }
    }
}

/// `hysteresis` subcommands.
#[derive(Debug, Subcommand)]
pub enum HysteresisCommand {
    /// Drive one stack of the twin through a rich excitation (reversals of every size)
    /// and record time, voltage and displacement for `hysteresis fit`.
    #[command(
        after_help = "Examples:\n  cellinject hysteresis identify --actuator A1 --out ident.csv\n  cellinject hysteresis identify --actuator A2 --samples 6000 --approach 1 --out a2.csv"
    )]
    Identify {
        /// Actuator: A1, A2 or A3.
        #[arg(long, default_value = "A1")]
        actuator: String,
        /// Samples of the excitation (one per millisecond).
        #[arg(long, default_value_t = 4000, value_parser = clap::value_parser!(u64).range(200..=200_000))]
        samples: u64,
        /// CSV output (`time_s,voltage_v,displacement_m`); its plot beside it (SVG, PNG).
        #[arg(long, default_value = "ident.csv")]
        out: PathBuf,
        #[command(flatten)]
        twin: crate::sim::TwinArgs,
    },
    /// Fit a hysteresis model to `time_s,voltage_v,displacement_m` data (from
    /// `identify` or a real actuator), starting relaxed at 0 V. Columns are found by
    /// name in any order, others ignored; dwells and a quantised voltage are welcome
    /// (repeated voltages merge; a reversal must exceed 10 times the voltage's noise).
    #[command(
        after_help = "Examples:\n  cellinject hysteresis fit --data ident.csv --out model.json\n  cellinject hysteresis fit --data ident.csv --model pi-asym --size 16 --out pi.json"
    )]
    Fit {
        /// The data (CSV with a header naming `voltage_v`, `displacement_m` and
        /// optionally `time_s`).
        #[arg(long, value_name = "FILE.csv")]
        data: PathBuf,
        /// Model class.
        #[arg(long, value_enum, default_value_t = ModelArg::Preisach)]
        model: ModelArg,
        /// Grid cells per axis (Preisach) or plays (PI).
        #[arg(long, default_value_t = core::DEFAULT_SIZE as u64, value_parser = clap::value_parser!(u64).range(2..=60))]
        size: u64,
        /// Highest input voltage of the model's range (default: the data's highest).
        #[arg(long)]
        v_max: Option<f64>,
        /// Model output (JSON); the measured and modelled loops are plotted beside it.
        #[arg(long, value_name = "FILE.json")]
        out: PathBuf,
        /// Output format of the summary.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// The voltages that make a modelled actuator, relaxed at 0 V, follow a trajectory.
    #[command(
        after_help = "Examples:\n  cellinject hysteresis invert --model model.json --trajectory desired.csv --out command.csv\n  cellinject hysteresis invert --model model.json --trajectory desired.csv --clip --out command.csv"
    )]
    Invert {
        /// A model from `hysteresis fit`.
        #[arg(long, value_name = "FILE.json")]
        model: PathBuf,
        /// The desired trajectory: CSV `time_s,displacement_m` with a header.
        #[arg(long, value_name = "FILE.csv")]
        trajectory: PathBuf,
        /// Output: CSV `time_s,voltage_v` (one row per input row); the desired and
        /// predicted trajectories are plotted beside it.
        #[arg(long, value_name = "FILE.csv")]
        out: PathBuf,
        /// Take a target outside the model's reach as the nearest displacement it
        /// reaches (a warning says how many and how far), instead of refusing the
        /// trajectory.
        #[arg(long)]
        clip: bool,
        /// Output format of the summary.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// Check a fitted model on a second recording of the same actuator (one it was not
    /// fitted on): the model, relaxed at 0 V, predicts the recording from its voltages,
    /// and the RMS and worst error are printed in µm and in % of the recording's
    /// stroke. The recording starts relaxed at 0 V, with the fit data's zero.
    #[command(
        after_help = "Examples:\n  cellinject hysteresis validate --model model.json --recording second.csv --out check.csv\n  cellinject hysteresis validate --model pi.json --recording second.csv --out check.csv --format json"
    )]
    Validate {
        /// A model from `hysteresis fit`.
        #[arg(long, value_name = "FILE.json")]
        model: PathBuf,
        /// The second recording: CSV with a header naming `voltage_v`, `displacement_m`
        /// and optionally `time_s` (as `hysteresis fit` reads).
        #[arg(long, value_name = "FILE.csv")]
        recording: PathBuf,
        /// Output: CSV `time_s,voltage_v,measured_m,predicted_m,error_m`, one row per
        /// recording row; measured and predicted are plotted beside it (over time and
        /// as loops over voltage).
        #[arg(long, value_name = "FILE.csv")]
        out: PathBuf,
        /// Output format of the summary.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
}

/// Reads a model file of `hysteresis fit`.
fn read_model(model: &Path) -> Result<AnyModel> {
    let text = std::fs::read_to_string(model)
        .map_err(|e| InputError(format!("--model `{}`: cannot read: {e}", model.display())))?;
    Ok(serde_json::from_str(&text).map_err(|e| {
        InputError(format!(
            "--model `{}`: not a model from `hysteresis fit`: {e}",
            model.display()
        ))
    })?)
}

/// Reads a numeric CSV by its header (`needed` columns in any order, `optional` ones if
/// present, others ignored), naming the file, line and column of anything wrong.
fn read_table(
    path: &Path,
    arg: &str,
    needed: &[&'static str],
    optional: &[&'static str],
) -> Result<Table> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| InputError(format!("{arg} `{}`: cannot read: {e}", path.display())))?;
    let t = Table::parse(&text, needed, optional)
        .and_then(|t| t.non_decreasing("time_s").map(|()| t))
        .map_err(|e| InputError(format!("{arg} `{}`: {e}", path.display())))?;
    if let Some(note) = t.ignored_note(needed, optional) {
        eprintln!("warning: {arg} `{}`: {note}", path.display());
    }
    Ok(t)
}

/// A column of a table read with it as needed.
fn column<'a>(t: &'a Table, name: &str) -> &'a [f64] {
    t.column(name).unwrap_or(&[])
}

/// `hysteresis fit`'s JSON: the report and the columns of the data it ignored.
#[derive(Serialize)]
struct FitOutput<'a> {
    #[serde(flatten)]
    report: &'a core::FitReport,
    ignored_columns: &'a [String],
}

/// A library error as the front end's: a solver failure exits 1, bad data 2, with the
/// file (`--data` and the voltage column for what is wrong with the voltages).
fn hysteresis_error(arg: &str, path: &Path, e: HysteresisError) -> anyhow::Error {
    match e {
        HysteresisError::Solver(_) => anyhow::anyhow!("{e}"),
        HysteresisError::ConstantInput { .. } | HysteresisError::TooFewReversals { .. } => {
            InputError(format!(
                "{arg} `{}`, column `voltage_v`: {e}",
                path.display()
            ))
            .into()
        }
        e => InputError(format!("{arg} `{}`: {e}", path.display())).into(),
    }
}

/// Runs `hysteresis`.
pub fn run(d: impl FnOnce() -> Result<Description>, cmd: &HysteresisCommand) -> Result<()> {
    match cmd {
        HysteresisCommand::Identify {
            actuator,
            samples,
            out,
            twin,
        } => identify(d, actuator, *samples, out, twin),
        HysteresisCommand::Fit {
            data,
            model,
            size,
            v_max,
            out,
            format,
        } => fit(data, *model, *size, *v_max, out, *format),
        HysteresisCommand::Invert {
            model,
            trajectory,
            out,
            clip,
            format,
        } => invert(model, trajectory, out, *clip, *format),
        HysteresisCommand::Validate {
            model,
            recording,
            out,
            format,
        } => validate(model, recording, out, *format),
    }
}

/// `hysteresis identify`.
fn identify(
    d: impl FnOnce() -> Result<Description>,
    actuator: &str,
    samples: u64,
    out: &Path,
    twin: &crate::sim::TwinArgs,
) -> Result<()> {
    let mut plan = Plan::new();
    let files = plan.companions("--out", out, &[FileKind::Csv, FileKind::Svg, FileKind::Png])?;
    plan.check()?;
    let d = d()?;
    let ch = cellinject_core::sim::channel(actuator)
        .ok_or_else(|| InputError(format!("--actuator must be A1, A2 or A3, got `{actuator}`")))?;
    let (tw, mut rig) = crate::sim::build(&d, twin)?;
    let progress = crate::progress::spinner("the twin runs the excitation");
    let r = core::identify(&mut rig, ch, samples as usize, 1e-3, || {
        tw.lock()
            .unwrap_or_else(|e| e.into_inner())
            .actuator_displacement(ch)
    })
    .map_err(|e| InputError(e.to_string()))?;
    drop(progress);
    let csv = print::voltage_displacement_csv(&r.samples);
    let chart = print::identify_chart(&r);
    write_with_plots(&files, csv.as_bytes(), &[chart], 1)?;
    outln!(
        "{}: {} samples up to {:.1} V (the safety envelope's limit), 1 ms apart",
        r.actuator,
        r.samples.len(),
        r.v_max
    );
    outln!("{}", wrote(&files));
    Ok(())
}

/// `hysteresis fit`.
fn fit(
    data: &Path,
    model: ModelArg,
    size: u64,
    v_max: Option<f64>,
    out: &Path,
    format: Format,
) -> Result<()> {
    let mut plan = Plan::new();
    plan.input("--data", data);
    let files = plan.companions(
        "--out",
        out,
        &[FileKind::Json, FileKind::Svg, FileKind::Png],
    )?;
    plan.check()?;
    let t = read_table(
        data,
        "--data",
        &["voltage_v", "displacement_m"],
        &["time_s"],
    )?;
    if t.is_empty() {
        return Err(InputError(format!(
            "--data `{}`: no rows under the header",
            data.display()
        ))
        .into());
    }
    let volts = column(&t, "voltage_v").to_vec();
    let disp = column(&t, "displacement_m").to_vec();
    let range = core::fit_range(&volts, v_max).map_err(|e| match e {
        core::RangeError::NoPositiveVoltage => InputError(format!(
            "--data `{}`, column `voltage_v`: no voltage above 0 V (and no --v-max)",
            data.display()
        )),
        core::RangeError::Outside { index, value, top } => InputError(format!(
            "--data `{}`, line {}, column `voltage_v`: {value} V lies outside the model's range [0, {top}] V (--v-max)",
            data.display(),
            t.line(index),
        )),
    })?;
    let kind = match model {
        ModelArg::Preisach => Kind::Preisach,
        ModelArg::Pi => Kind::Pi,
        ModelArg::PiAsym => Kind::PiAsymmetric,
    };
    let r = {
        let _p = crate::progress::spinner("fitting");
        core::fit(kind, size as usize, range, &volts, &disp)
            .map_err(|e| hysteresis_error("--data", data, e))?
    };
    let d = &r.data;
    if d.merged > 0 {
        eprintln!(
            "warning: --data `{}`: {} of {} rows repeat the voltage before them (dwells at the turning points, DAC steps slower than the logger): each held voltage fitted once, at its mean displacement",
            data.display(),
            d.merged,
            d.rows
        );
    }
    if d.flattened > 0 {
        eprintln!(
            "warning: --data `{}`: {} voltages turned back by less than {:.4} V ({} times the voltage's noise level {:.4} V): taken as holds, not reversals",
            data.display(),
            d.flattened,
            d.reversal_threshold,
            cellinject_hysteresis::data::REVERSAL_FACTOR,
            d.input_noise
        );
    }
    let chart = print::fit_chart(&format!("{model:?}"), &r, &volts, &disp);
    let json = serde_json::to_string_pretty(&r.model)?;
    write_with_plots(&files, json.as_bytes(), &[chart], 1)?;
    if format == Format::Json {
        let o = FitOutput {
            report: &r,
            ignored_columns: &t.ignored,
        };
        return print_json(&o, &[&files[0], &files[1], &files[2]]);
    }
    outln!(
        "{} model fitted to {} samples ({} reversals): RMS {:.2} nm ({:.3} % of the data's span), max {:.2} nm",
        model.name(),
        r.samples,
        r.data.reversals,
        r.rms * 1e9,
        100.0 * r.rms_relative,
        r.max * 1e9
    );
    outln!("{}", wrote(&files));
    Ok(())
}

/// `hysteresis invert`.
fn invert(model: &Path, trajectory: &Path, out: &Path, clip: bool, format: Format) -> Result<()> {
    let mut plan = Plan::new();
    plan.input("--model", model)
        .input("--trajectory", trajectory);
    let files = plan.companions("--out", out, &[FileKind::Csv, FileKind::Svg, FileKind::Png])?;
    plan.check()?;
    let m = read_model(model)?;
    let tab = read_table(
        trajectory,
        "--trajectory",
        &["time_s", "displacement_m"],
        &[],
    )?;
    if tab.is_empty() {
        return Err(InputError(format!("--trajectory `{}`: no rows", trajectory.display())).into());
    }
    let targets = column(&tab, "displacement_m").to_vec();
    let r = core::invert(&m, &targets, clip).map_err(|e| match e {
        e @ cellinject_hysteresis::HysteresisError::OutOfReach { index, .. } => {
            InputError(format!(
                "--trajectory `{}`, line {}: {e} (--clip takes such targets as the nearest the model reaches)",
                trajectory.display(),
                tab.line(index)
            ))
            .into()
        }
        e => hysteresis_error("--trajectory", trajectory, e),
    })?;
    if let Some(k) = r.largest_clip_sample {
        eprintln!(
            "warning: --trajectory `{}`: {} of {} targets lie outside the model's reach and were clipped to it (the farthest {:.4} µm away, line {})",
            trajectory.display(),
            r.clipped,
            r.samples,
            r.largest_clip * 1e6,
            tab.line(k)
        );
    }
    let t = column(&tab, "time_s").to_vec();
    let csv = print::invert_csv(&t, &r);
    let charts = print::invert_charts(&t, &targets, &r);
    write_with_plots(&files, csv.as_bytes(), &charts, 2)?;
    if format == Format::Json {
        return print_json(&r, &[&files[0], &files[1], &files[2]]);
    }
    outln!(
        "{} samples: voltages from {:.3} to {:.3} V; largest model residual {:.2e} m",
        r.samples,
        r.voltage_range[0],
        r.voltage_range[1],
        r.residual
    );
    outln!("{}", wrote(&files));
    Ok(())
}

/// `hysteresis validate`.
fn validate(model: &Path, recording: &Path, out: &Path, format: Format) -> Result<()> {
    let mut plan = Plan::new();
    plan.input("--model", model).input("--recording", recording);
    let files = plan.companions("--out", out, &[FileKind::Csv, FileKind::Svg, FileKind::Png])?;
    plan.check()?;
    let m = read_model(model)?;
    let t = read_table(
        recording,
        "--recording",
        &["voltage_v", "displacement_m"],
        &["time_s"],
    )?;
    let volts = column(&t, "voltage_v");
    let disp = column(&t, "displacement_m");
    let r = core::validate(&m, volts, disp).map_err(|e| {
        let at = |index: usize, col: &str| {
            format!(
                "--recording `{}`, line {}, column `{col}`",
                recording.display(),
                t.line(index)
            )
        };
        InputError(match &e {
            core::ValidateError::Outside {
                index,
                value,
                min,
                max,
            } => format!(
                "{}: {value} V lies outside the range [{min}, {max}] V of the model `{}` (fit one on this voltage range)",
                at(*index, "voltage_v"),
                model.display()
            ),
            core::ValidateError::NotFinite { index, which } => format!(
                "{}: not a finite number",
                at(
                    *index,
                    if *which == "voltage" {
                        "voltage_v"
                    } else {
                        "displacement_m"
                    }
                )
            ),
            _ => format!("--recording `{}`: {e}", recording.display()),
        })
    })?;
    if !r.starts_relaxed {
        eprintln!(
            "warning: --recording `{}`: it starts at {:.3} V, not relaxed at {:.3} V; the model predicts it as if it had come there from rest",
            recording.display(),
            volts[0],
            m.range().min
        );
    }
    let time: Vec<f64> = match t.column("time_s") {
        Some(c) => c.to_vec(),
        None => (0..r.samples).map(|k| k as f64).collect(),
    };
    let has_time = t.column("time_s").is_some();
    let csv = print::validate_csv(&time, volts, disp, &r);
    let charts = print::validate_charts(&time, has_time, volts, disp, &r);
    write_with_plots(&files, csv.as_bytes(), &charts, 2)?;
    if format == Format::Json {
        return print_json(&r, &[&files[0], &files[1], &files[2]]);
    }
    outln!(
        "{} samples over a {:.3} µm stroke: RMS error {:.3} µm ({:.2} % of stroke), worst {:.3} µm ({:.2} %, line {})",
        r.samples,
        r.stroke * 1e6,
        r.rms * 1e6,
        r.rms_percent,
        r.max * 1e6,
        r.max_percent,
        t.line(r.worst_sample)
    );
    outln!(
        "rest: measured {:.3} µm, predicted {:.3} µm",
        r.rest_measured * 1e6,
        r.rest_predicted * 1e6
    );
    outln!("{}", wrote(&files));
    Ok(())
}
