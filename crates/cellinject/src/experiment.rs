//! `cellinject calibrate ...` and `cellinject experiment ...`: the calibrations of the
//! bench and the paper's experiments (Sec. 4) on the twin, through its two cameras;
//! this file loads and saves calibration files and writes CSV, JSON and plots.

use std::path::{Path, PathBuf};

use anyhow::Result;
use cellinject_config::Description;
use cellinject_control::Kind;
use cellinject_core::bench::{Bench, BenchError, Timing};
use cellinject_core::calibrate::{HysteresisCalibration, PixelCalibration};
use cellinject_core::experiment::{self, Calibrations, RepeatabilityOptions, TrackingOptions};
use cellinject_core::vision::Acquisition;
use cellinject_plot::Chart;
use cellinject_print::experiment as print;
use cellinject_rig::{DynBackend, Rig};
use cellinject_twin::SharedTwin;

use crate::backend::BackendArgs;
use cellinject_session::calibration::{self, Made, RunBench};
use clap::{Args, Subcommand, ValueEnum};
use serde::Serialize;

use crate::output::print_json;
use crate::sim::TwinArgs;
use crate::{Format, InputError};
use cellinject_files::{Outputs, check_dir};

/// The controllers on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ControlArg {
    /// Linear gain, no measurement (the naive baseline).
    Open,
    /// Inverse hysteresis model and creep compensation, no measurement.
    Feedforward,
    /// PI on the stacks' position sensors at 1 kHz around the inverse model.
    Sensor,
    /// The sensor loop inside a visual servo on both cameras (30 fps).
    Closed,
}

impl From<ControlArg> for Kind {
    fn from(c: ControlArg) -> Kind {
        match c {
            ControlArg::Open => Kind::Open,
            ControlArg::Feedforward => Kind::Feedforward,
            ControlArg::Sensor => Kind::Sensor,
            ControlArg::Closed => Kind::Closed,
        }
    }
}

/// Options of every experiment.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// Directory of calibration files (`pixels.json`, `jacobian.json`,
    /// `hysteresis.json` from `cellinject calibrate all`); without it the experiment
    /// calibrates itself and saves them under OUT/calibration. A file whose check
    /// fails is reported and made again.
    #[arg(long, value_name = "DIR")]
    calibration: Option<PathBuf>,
    /// Directory for the CSV, JSON and plots (created if needed).
    #[arg(long, value_name = "DIR", default_value = "experiments")]
    out: PathBuf,
    /// Seconds from the end of a frame's exposure until its measurement reaches the
    /// controller (readout and correlation).
    #[arg(long, default_value_t = 0.015, allow_negative_numbers = true)]
    latency: f64,
    #[command(flatten)]
    twin: TwinArgs,
    #[command(flatten)]
    backend: BackendArgs,
}

/// The experiments.
#[derive(Debug, Subcommand)]
pub enum ExperimentCommand {
    /// Range of motion per axis through the cameras (the paper's Fig. 7).
    #[command(
        after_help = "Examples:\n  cellinject experiment range --approach 2\n  cellinject experiment range --approach 1 --format json"
    )]
    Range {
        /// Seconds of each sweep up (and again down); the cameras follow at 30 fps.
        #[arg(long, default_value_t = 3.0, allow_negative_numbers = true)]
        sweep: f64,
        #[command(flatten)]
        bench: BenchArgs,
    },
    /// The same working shift set N times, measured through the cameras (Fig. 8).
    #[command(
        after_help = "Examples:\n  cellinject experiment repeatability --approach 1 --control open\n  cellinject experiment repeatability --approach 2 --control closed --runs 200 --shift 1e-6 --format json"
    )]
    Repeatability {
        /// The controller.
        #[arg(long, value_enum, default_value_t = ControlArg::Open)]
        control: ControlArg,
        /// Runs.
        #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u64).range(2..=100_000))]
        runs: u64,
        /// Working shift of A1 and A2 from their pre-tensioned state, m.
        #[arg(long, default_value_t = 1e-6, allow_negative_numbers = true)]
        shift: f64,
        /// Seconds the controller holds the shift before the position is measured.
        #[arg(long, default_value_t = 0.8, allow_negative_numbers = true)]
        hold: f64,
        /// Seconds at rest (0 V) before each run.
        #[arg(long, default_value_t = 0.1, allow_negative_numbers = true)]
        rest: f64,
        /// Band a position must stay in to count as settled, m.
        #[arg(long, default_value_t = 100e-9, allow_negative_numbers = true)]
        tolerance: f64,
        #[command(flatten)]
        bench: BenchArgs,
    },
    /// Steps and a circle of the stack references: tracking error and settling.
    #[command(
        after_help = "Examples:\n  cellinject experiment tracking --control closed\n  cellinject experiment tracking --control feedforward --frequency 2 --format json"
    )]
    Tracking {
        /// The controller.
        #[arg(long, value_enum, default_value_t = ControlArg::Closed)]
        control: ControlArg,
        /// The stacks' operating point, m of extension from rest: the steps and the
        /// circle run above it, so every controller can correct both ways.
        #[arg(long, default_value_t = 1e-6, allow_negative_numbers = true)]
        bias: f64,
        /// Stack step, m (the tip moves about six times as far).
        #[arg(long, default_value_t = 1e-6, allow_negative_numbers = true)]
        step: f64,
        /// Seconds per step.
        #[arg(long, default_value_t = 0.5, allow_negative_numbers = true)]
        dwell: f64,
        /// Stack amplitude of the circle, m.
        #[arg(long, default_value_t = 0.5e-6, allow_negative_numbers = true)]
        amplitude: f64,
        /// Frequency of the circle, Hz.
        #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
        frequency: f64,
        /// Seconds of circling.
        #[arg(long, default_value_t = 3.0, allow_negative_numbers = true)]
        duration: f64,
        /// Band around the target a step must stay in to count as settled, m.
        #[arg(long, default_value_t = 100e-9, allow_negative_numbers = true)]
        tolerance: f64,
        #[command(flatten)]
        bench: BenchArgs,
    },
}

/// The bench a command runs on.
pub(crate) struct Setup {
    /// The twin, when it is the backend (its truth).
    pub(crate) twin: Option<SharedTwin>,
    pub(crate) rig: Rig<DynBackend>,
    pub(crate) made: Made,
    pub(crate) description: Description,
}

pub(crate) fn setup(d: &Description, args: &TwinArgs, backend: &BackendArgs) -> Result<Setup> {
    let o = crate::backend::open(d, args, &backend.rig()?)?;
    let (made, description) = Made::of(d, &o);
    Ok(Setup {
        twin: o.twin,
        rig: o.rig,
        made,
        description,
    })
}

/// The twin's truth of the tip position, when the backend is the twin.
fn truth(twin: &Option<SharedTwin>) -> Option<Box<dyn FnMut() -> [f64; 3] + '_>> {
    let twin = twin.as_ref()?;
    Some(Box::new(move || {
        let p = twin.lock().unwrap_or_else(|e| e.into_inner()).tip();
        [p.x, p.depth, p.z]
    }))
}

/// Bench errors are the user's to fix (arguments, refusals) or the bench's (a check
/// failed, the marker was lost): exit code 2 for the first, 1 for the second.
pub(crate) fn bench_error(e: BenchError) -> anyhow::Error {
    match e {
        BenchError::Invalid { .. } | BenchError::Device { .. } => InputError(e.to_string()).into(),
        other => anyhow::anyhow!("{other}"),
    }
}

fn json_bytes<T: Serialize>(v: &T) -> Result<Vec<u8>> {
    let mut s = serde_json::to_string_pretty(v)?;
    s.push('\n');
    Ok(s.into_bytes())
}

/// A calibration file that cannot be used: bad input, naming the option.
fn calibration_error(e: calibration::CalibrationError) -> InputError {
    InputError(format!("--calibration: {e}"))
}

/// [`calibration::read_hysteresis_for_run`], its refusals exit 2.
pub(crate) fn read_hysteresis_for_run(
    path: &Path,
    bench: &RunBench<'_>,
) -> Result<(Option<HysteresisCalibration>, Option<String>)> {
    calibration::read_hysteresis_for_run(path, bench).map_err(|e| calibration_error(e).into())
}

/// A calibration step said on the terminal: a spinner while one is made, counted
/// among the three (`2 of 3: identifying the stacks' hysteresis and
/// creep`), a note when a file is not used.
fn show_step(spinner: &mut Option<crate::progress::Progress>, step: calibration::Step) {
    match step {
        calibration::Step::Making(what, k) => {
            // The last one's spinner goes first: one line at a time.
            *spinner = None;
            *spinner = Some(crate::progress::spinner(format!("{k} of 3: {what}")));
        }
        calibration::Step::Redo(note) => eprintln!("note: {note}"),
    }
}

/// The pixel calibration of `--pixels`, if given, of this bench and passing its check.
pub(crate) fn given_pixels(path: Option<&Path>, s: &Setup) -> Result<Option<PixelCalibration>> {
    let mut spinner = None;
    let zoom = s.made.zoom;
    calibration::load_checked(
        path,
        "pixels",
        s.made.approach,
        |c: &PixelCalibration| c.problem(zoom),
        &mut |step| show_step(&mut spinner, step),
    )
    .map_err(|e| calibration_error(e).into())
}

/// The calibrations an experiment needs: loaded from `dir` where valid, made otherwise;
/// the ones made are returned for saving ([`calibration::load_or_make`]).
pub(crate) fn calibrations(
    setup: &mut Setup,
    dir: Option<&Path>,
) -> Result<(PixelCalibration, Calibrations, calibration::MadeFiles)> {
    let mut spinner = None;
    calibration::load_or_make(
        &mut setup.rig,
        &setup.made,
        &setup.description,
        dir,
        &mut |s| show_step(&mut spinner, s),
    )
    .map_err(|e| match e {
        calibration::LoadError::File(e) => calibration_error(e).into(),
        calibration::LoadError::Bench(e) => bench_error(e),
        e @ calibration::LoadError::Json(_) => anyhow::anyhow!("{e}"),
    })
}

pub(crate) fn file_bytes<T: Serialize + Clone>(kind: &str, made: &Made, c: &T) -> Result<Vec<u8>> {
    Ok(calibration::file_bytes(kind, made, c)?)
}

/// The files an experiment writes beside its JSON: `stem`.csv and its charts (in so
/// many columns) as `stem`.svg and `stem`.png.
struct Written {
    stem: String,
    csv: String,
    charts: (Vec<Chart>, usize),
}

/// Writes an experiment's files under `--out` (the calibrations made for it first),
/// then prints its JSON or its summary `text` and the files written.
fn finish<T: Serialize>(
    args: &BenchArgs,
    made: calibration::MadeFiles,
    report: &T,
    written: Written,
    text: impl FnOnce() -> String,
) -> Result<()> {
    let stem = args.out.join(&written.stem);
    let mut out = Outputs::new("--out");
    out.add_named(&args.out.join("calibration"), made, "json")?;
    out.add(stem.with_extension("csv"), written.csv.as_bytes())?;
    out.add(stem.with_extension("json"), &json_bytes(report)?)?;
    out.plots(&stem, &written.charts.0, written.charts.1)?;
    let files = out.commit()?;
    if args.twin.format() == Format::Json {
        let f: Vec<&Path> = files.iter().map(|p| p.as_path()).collect();
        return print_json(report, &f);
    }
    outln!("{}", text());
    outln!("{}", cellinject_files::wrote(&files));
    Ok(())
}

/// The `kind` controller of the stacks, over the calibrations `cal`.
fn controller(
    s: &Setup,
    kind: Kind,
    cal: &Calibrations,
) -> Result<Box<dyn cellinject_control::Controller>> {
    let stacks = experiment::stacks(&s.description.design, &s.description.rig, &cal.hysteresis);
    experiment::controller(kind, stacks, cal)
        .map_err(|e| anyhow::anyhow!("cannot build the {} controller: {e}", kind.name()))
}

fn check_out(bench: &BenchArgs) -> Result<()> {
    if let Some(c) = &bench.calibration
        && !c.is_dir()
    {
        return Err(InputError(format!(
            "--calibration `{}` is not a directory (give the directory `cellinject calibrate all --out DIR` wrote)",
            c.display()
        ))
        .into());
    }
    if !(bench.latency.is_finite() && (0.0..=1.0).contains(&bench.latency)) {
        return Err(InputError(format!(
            "--latency must lie in [0, 1] s, got {}",
            bench.latency
        ))
        .into());
    }
    Ok(check_dir("--out", &bench.out)?)
}

/// Runs an `experiment` command.
pub fn run(d: &Description, cmd: &ExperimentCommand) -> Result<()> {
    match cmd {
        ExperimentCommand::Range { sweep, bench } => range(d, *sweep, bench),
        ExperimentCommand::Repeatability {
            control,
            runs,
            shift,
            hold,
            rest,
            tolerance,
            bench,
        } => repeatability(
            d,
            (*control).into(),
            RepeatabilityOptions {
                runs: *runs as usize,
                shift: *shift,
                rest: *rest,
                hold: *hold,
                tolerance: *tolerance,
                ..RepeatabilityOptions::default()
            },
            bench,
        ),
        ExperimentCommand::Tracking {
            control,
            bias,
            step,
            dwell,
            amplitude,
            frequency,
            duration,
            tolerance,
            bench,
        } => tracking(
            d,
            (*control).into(),
            TrackingOptions {
                bias: *bias,
                step: *step,
                dwell: *dwell,
                amplitude: *amplitude,
                frequency: *frequency,
                duration: *duration,
                tolerance: *tolerance,
            },
            bench,
        ),
    }
}

fn timing(b: &BenchArgs) -> Timing {
    Timing {
        latency: b.latency,
        ..Timing::default()
    }
}

fn range(d: &Description, sweep: f64, args: &BenchArgs) -> Result<()> {
    if !(sweep.is_finite() && (0.5..=600.0).contains(&sweep)) {
        return Err(InputError(format!("--sweep must lie in [0.5, 600] s, got {sweep}")).into());
    }
    check_out(args)?;
    let mut s = setup(d, &args.twin, &args.backend)?;
    let (pixels, _cal, made) = calibrations(&mut s, args.calibration.as_deref())?;
    let marker = s.description.rig.optics.marker;
    let r = {
        let bar = crate::progress::share_bar("sweeping A1, then A2");
        let total = experiment::range_seconds(sweep);
        let mut bench = Bench::new(
            &mut s.rig,
            Acquisition::Wide,
            marker,
            pixels.maps,
            truth(&s.twin),
            timing(args),
        )
        .map_err(bench_error)?;
        bench.watch(|t| bar.set_share(t / total));
        experiment::range(&mut bench, &s.description.design, &s.description.rig, sweep)
            .map_err(bench_error)?
    };
    let written = Written {
        stem: format!("range-approach{}", r.approach),
        csv: print::range_csv(&r),
        charts: (print::range_charts(&r), 2),
    };
    finish(args, made, &r, written, || print::range_text(&r))
}

fn repeatability(
    d: &Description,
    kind: Kind,
    opts: RepeatabilityOptions,
    args: &BenchArgs,
) -> Result<()> {
    opts.check().map_err(bench_error)?;
    check_out(args)?;
    let mut s = setup(d, &args.twin, &args.backend)?;
    let (pixels, cal, made) = calibrations(&mut s, args.calibration.as_deref())?;
    let mut controller = controller(&s, kind, &cal)?;
    let marker = s.description.rig.optics.marker;
    let approach = s.description.rig.approach;
    let r = {
        let bar = crate::progress::bar(opts.runs as u64, format!("{} runs", kind.name()));
        let mut bench = Bench::new(
            &mut s.rig,
            Acquisition::Marker,
            marker,
            pixels.maps,
            truth(&s.twin),
            timing(args),
        )
        .map_err(bench_error)?;
        experiment::repeatability(&mut bench, controller.as_mut(), approach, opts, |_| {
            bar.inc()
        })
        .map_err(bench_error)?
    };
    let written = Written {
        stem: format!("repeatability-approach{}-{}", r.approach, kind.name()),
        csv: print::repeatability_csv(&r),
        charts: (vec![print::repeatability_chart(&r)], 1),
    };
    finish(args, made, &r, written, || print::repeatability_text(&r))
}

fn tracking(d: &Description, kind: Kind, opts: TrackingOptions, args: &BenchArgs) -> Result<()> {
    opts.check().map_err(bench_error)?;
    check_out(args)?;
    let mut s = setup(d, &args.twin, &args.backend)?;
    let (pixels, cal, made) = calibrations(&mut s, args.calibration.as_deref())?;
    let mut controller = controller(&s, kind, &cal)?;
    let marker = s.description.rig.optics.marker;
    let approach = s.description.rig.approach;
    let r = {
        let bar =
            crate::progress::share_bar(format!("tracking with the {} controller", kind.name()));
        let total = opts.seconds();
        let mut bench = Bench::new(
            &mut s.rig,
            Acquisition::Marker,
            marker,
            pixels.maps,
            truth(&s.twin),
            timing(args),
        )
        .map_err(bench_error)?;
        bench.watch(|t| bar.set_share(t / total));
        experiment::tracking(
            &mut bench,
            controller.as_mut(),
            approach,
            cal.jacobian.jacobian,
            opts,
        )
        .map_err(bench_error)?
    };
    let written = Written {
        stem: format!("tracking-approach{}-{}", r.approach, kind.name()),
        csv: print::tracking_csv(&r),
        charts: (print::tracking_charts(&r), 2),
    };
    finish(args, made, &r, written, || print::tracking_text(&r))
}
