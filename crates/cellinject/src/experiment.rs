//! `cellinject calibrate ...` and `cellinject experiment ...`: the calibrations of the
//! bench and the paper's experiments (Sec. 4) on the twin, through its two cameras;
//! this file loads and saves calibration files and writes CSV, JSON and plots.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Result;
use cellinject_config::Description;
use cellinject_control::Kind;
use cellinject_core::bench::{Bench, BenchError, FrameRecord, Timing};
use cellinject_core::calibrate::{HysteresisCalibration, PixelCalibration};
use cellinject_core::experiment::{
    self, Calibrations, RangeReport, RepeatabilityOptions, RepeatabilityReport, TrackingOptions,
    TrackingReport,
};
use cellinject_core::vision::Acquisition;
use cellinject_hw::Optics as _;
use cellinject_plot::{Chart, Series, Style};
use cellinject_rig::{DynBackend, Rig};
use cellinject_twin::SharedTwin;

use crate::backend::BackendArgs;
use cellinject_session::calibration::{self, Made, RunBench, description_digest, utc_now};
use clap::{Args, Subcommand, ValueEnum};
use serde::Serialize;

use crate::files::Staged;
use crate::output::print_json;
use crate::sim::TwinArgs;
use crate::{Format, InputError};

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
    let (seed, zoom) = match &o.twin {
        Some(twin) => {
            let t = twin.lock().unwrap_or_else(|e| e.into_inner());
            (Some(t.world.params().sim.seed), t.camera.zoom())
        }
        None => (None, o.rig.optics.zoom()),
    };
    let mut description = d.clone();
    description.rig.approach = o.approach;
    Ok(Setup {
        twin: o.twin,
        rig: o.rig,
        made: Made {
            created_utc: utc_now(),
            backend: o.name,
            design: d.name.clone(),
            approach: o.approach.number(),
            seed,
            zoom,
            description_digest: Some(description_digest(d)),
        },
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

/// A calibration step said on the terminal: a spinner while one is made, a note when
/// a file is not used.
fn show_step(spinner: &mut Option<crate::progress::Progress>, step: calibration::Step) {
    match step {
        calibration::Step::Making(what) => *spinner = Some(crate::progress::spinner(what)),
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

/// Creates `dir` (and its parents) or says why not.
/// Refuses an output directory that cannot be made (a file in the way, or no existing
/// directory above it); nothing is created yet, so a command that fails leaves nothing.
pub(crate) fn check_dir(arg: &str, dir: &Path) -> Result<()> {
    let mut p = Some(dir);
    while let Some(d) = p {
        if d.as_os_str().is_empty() || d.is_dir() {
            return Ok(());
        }
        if d.exists() {
            return Err(InputError(format!(
                "{arg} `{}`: `{}` is a file, not a directory",
                dir.display(),
                d.display()
            ))
            .into());
        }
        p = d.parent();
    }
    Ok(())
}

/// Creates an output directory (when the outputs are ready to be written).
fn make_dir(arg: &str, dir: &Path) -> Result<()> {
    check_dir(arg, dir)?;
    std::fs::create_dir_all(dir).map_err(|e| {
        InputError(format!(
            "{arg}: cannot create the directory `{}`: {e}",
            dir.display()
        ))
        .into()
    })
}

/// The files of one experiment, written together: the made calibrations under
/// OUT/calibration, then CSV, JSON, SVG and PNG.
pub(crate) struct Outputs {
    staged: Staged,
    written: Vec<PathBuf>,
}

impl Outputs {
    pub(crate) fn new() -> Self {
        Outputs {
            staged: Staged::new(),
            written: Vec::new(),
        }
    }

    pub(crate) fn add(&mut self, path: PathBuf, bytes: &[u8]) -> Result<()> {
        if let Some(dir) = path.parent() {
            make_dir("--out", dir)?;
        }
        self.staged.add(&path, bytes)?;
        self.written.push(path);
        Ok(())
    }

    fn calibrations(&mut self, out: &Path, made: calibration::MadeFiles) -> Result<()> {
        if made.is_empty() {
            return Ok(());
        }
        let dir = out.join("calibration");
        make_dir("--out", &dir)?;
        for (name, bytes) in made {
            self.add(dir.join(format!("{name}.json")), &bytes)?;
        }
        Ok(())
    }

    fn plots(&mut self, stem: &Path, charts: &[Chart], columns: usize) -> Result<()> {
        let size = (720, 480);
        let svg = cellinject_plot::svg(charts, columns, size)
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        let rgb = cellinject_plot::rgb(charts, columns, size)
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        let png_path = stem.with_extension("png");
        let png = crate::files::encode_rgb(rgb, &png_path)?;
        self.add(stem.with_extension("svg"), svg.as_bytes())?;
        self.add(png_path, &png)
    }

    pub(crate) fn commit(self) -> Result<Vec<PathBuf>> {
        self.staged.commit()?;
        Ok(self.written)
    }
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
    check_dir("--out", &bench.out)
}

fn um(x: f64) -> String {
    format!("{:.3} µm", x * 1e6)
}

fn nm(x: f64) -> String {
    format!("{:.1} nm", x * 1e9)
}

fn opt<T: Copy>(v: Option<T>, f: impl Fn(T) -> String) -> String {
    v.map(f).unwrap_or_else(|| "never".into())
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
        let _p = crate::progress::spinner("sweeping A1, then A2");
        let mut bench = Bench::new(
            &mut s.rig,
            Acquisition::Wide,
            marker,
            pixels.maps,
            truth(&s.twin),
            timing(args),
        )
        .map_err(bench_error)?;
        experiment::range(&mut bench, &s.description.design, &s.description.rig, sweep)
            .map_err(bench_error)?
    };
    let stem = args.out.join(format!("range-approach{}", r.approach));
    let mut out = Outputs::new();
    out.calibrations(&args.out, made)?;
    out.add(stem.with_extension("csv"), range_csv(&r).as_bytes())?;
    out.add(stem.with_extension("json"), &json_bytes(&r)?)?;
    out.plots(&stem, &range_charts(&r), 2)?;
    let files = out.commit()?;
    if args.twin.format() == Format::Json {
        let f: Vec<&Path> = files.iter().map(|p| p.as_path()).collect();
        return print_json(&r, &f);
    }
    outln!(
        "Range of motion, approach {} (A1 swept for x, A2 for y; through the cameras):",
        r.approach
    );
    for (i, (axis, m, model, full)) in [
        ("x", r.range_m.x, r.model_range_m.x, r.full_stroke_range_m.x),
        ("y", r.range_m.y, r.model_range_m.y, r.full_stroke_range_m.y),
    ]
    .into_iter()
    .enumerate()
    {
        let truth = r
            .true_range_m
            .map(|t| format!(", true {}", um(if i == 0 { t.x } else { t.y })))
            .unwrap_or_default();
        outln!(
            "  {axis}: {} measured{truth}; model {} for 0-{:.1} V ({:+.2} %), full stroke {}",
            um(m),
            um(model),
            r.v_max[i],
            (m / model - 1.0) * 100.0,
            um(full)
        );
        if let Some(why) = &r.limited_by[i] {
            outln!(
                "     the safety envelope stops A{} at {:.1} V: {why}",
                i + 1,
                r.v_max[i]
            );
        }
    }
    outln!("{}", crate::files::wrote(&files));
    Ok(())
}

fn range_csv(r: &RangeReport) -> String {
    let mut csv = String::from("actuator,voltage_v,axis,displacement_m,true_displacement_m\n");
    for (i, sweep) in r.sweeps.iter().enumerate() {
        for p in sweep {
            let _ = writeln!(
                csv,
                "A{},{:.4},{},{:.6e},{:.6e}",
                i + 1,
                p.volts,
                ["x", "y"][i],
                p.measured.unwrap_or(f64::NAN),
                p.truth.unwrap_or(f64::NAN)
            );
        }
    }
    csv
}

fn range_charts(r: &RangeReport) -> Vec<Chart> {
    (0..2)
        .map(|i| {
            let axis = ["x", "y"][i];
            let camera = ["top camera", "side camera"][i];
            let mut series = vec![Series {
                name: format!("{axis}, {camera}"),
                points: r.sweeps[i]
                    .iter()
                    .filter_map(|p| p.measured.map(|m| (p.volts, m * 1e6)))
                    .collect(),
                style: Style::Line,
            }];
            if r.sweeps[i].iter().all(|p| p.truth.is_some()) {
                series.push(Series {
                    name: format!("{axis}, twin's truth"),
                    points: r.sweeps[i]
                        .iter()
                        .step_by(4)
                        .filter_map(|p| p.truth.map(|t| (p.volts, t * 1e6)))
                        .collect(),
                    style: Style::Dots,
                });
            }
            Chart {
                title: format!(
                    "A{} swept, approach {}: range {:.1} µm",
                    i + 1,
                    r.approach,
                    [r.range_m.x, r.range_m.y][i] * 1e6
                ),
                x_label: format!("A{} voltage [V]", i + 1),
                y_label: format!("end-effector {axis} [µm]"),
                series,
            }
        })
        .collect()
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
    let stacks = experiment::stacks(&s.description.design, &s.description.rig, &cal.hysteresis);
    let mut controller = experiment::controller(kind, stacks, &cal)
        .map_err(|e| anyhow::anyhow!("cannot build the {} controller: {e}", kind.name()))?;
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
    let stem = args.out.join(format!(
        "repeatability-approach{}-{}",
        r.approach,
        kind.name()
    ));
    let mut out = Outputs::new();
    out.calibrations(&args.out, made)?;
    out.add(stem.with_extension("csv"), repeatability_csv(&r).as_bytes())?;
    out.add(stem.with_extension("json"), &json_bytes(&r)?)?;
    out.plots(&stem, &[repeatability_chart(&r)], 1)?;
    let files = out.commit()?;
    if args.twin.format() == Format::Json {
        let f: Vec<&Path> = files.iter().map(|p| p.as_path()).collect();
        return print_json(&r, &f);
    }
    outln!(
        "Repeatability, approach {}, {} control: {} runs of a {} shift of A1 and A2",
        r.approach,
        kind.name(),
        r.runs,
        um(r.shift_m)
    );
    outln!(
        "  cameras:      max error x {}, y {}, distance {};  RMS x {}, y {}",
        nm(r.max_error_m[0]),
        nm(r.max_error_m[1]),
        nm(r.max_distance_m),
        nm(r.rms_error_m[0]),
        nm(r.rms_error_m[1])
    );
    if let (Some(m), Some(rms), Some(d)) = (
        r.true_max_error_m,
        r.true_rms_error_m,
        r.true_max_distance_m,
    ) {
        outln!(
            "  twin's truth: max error x {}, y {}, distance {};  RMS x {}, y {}",
            nm(m[0]),
            nm(m[1]),
            nm(d),
            nm(rms[0]),
            nm(rms[1])
        );
    }
    if let Some(a) = r.camera_vs_truth_m {
        outln!("  the cameras agree with the truth to {}", nm(a));
    }
    outln!(
        "  settling (within {} of the run's position): median {} frames, worst {}{}",
        nm(r.tolerance_m),
        opt(r.settling_median_frames, |f| f.to_string()),
        opt(r.settling_max_frames, |f| format!("{f} frames")),
        if r.unsettled_runs > 0 {
            format!(" ({} runs never settled)", r.unsettled_runs)
        } else {
            String::new()
        }
    );
    let shortest = r
        .run_list
        .iter()
        .map(|run| run.hold_s)
        .fold(f64::INFINITY, f64::min);
    if r.longest_hold_s > shortest + 1e-9 {
        outln!(
            "  held {:.2} to {:.2} s (the closed loop holds until in position)",
            shortest,
            r.longest_hold_s
        );
    }
    outln!("{}", crate::files::wrote(&files));
    Ok(())
}

fn repeatability_csv(r: &RepeatabilityReport) -> String {
    let mut csv =
        String::from("run,x_m,y_m,true_x_m,true_y_m,settling_frames,a1_voltage_v,a2_voltage_v\n");
    for run in &r.run_list {
        let t = run.truth.unwrap_or([f64::NAN; 2]);
        let _ = writeln!(
            csv,
            "{},{:.6e},{:.6e},{:.6e},{:.6e},{},{:.5},{:.5}",
            run.run,
            run.measured[0],
            run.measured[1],
            t[0],
            t[1],
            run.settling_frames
                .map(|f| f.to_string())
                .unwrap_or_default(),
            run.volts[0],
            run.volts[1]
        );
    }
    csv
}

fn repeatability_chart(r: &RepeatabilityReport) -> Chart {
    let unit = if r.max_error_m[0].max(r.max_error_m[1]) > 2e-6 {
        ("µm", 1e6)
    } else {
        ("nm", 1e9)
    };
    let mean = r.mean_m;
    let mut series = vec![Series {
        name: "cameras".into(),
        points: r
            .run_list
            .iter()
            .map(|p| {
                (
                    (p.measured[0] - mean[0]) * unit.1,
                    (p.measured[1] - mean[1]) * unit.1,
                )
            })
            .collect(),
        style: Style::Dots,
    }];
    let truth: Option<Vec<[f64; 2]>> = r.run_list.iter().map(|p| p.truth).collect();
    if let Some(t) = truth {
        let n = t.len().max(1) as f64;
        let tm = [0, 1].map(|a| t.iter().map(|p| p[a]).sum::<f64>() / n);
        series.push(Series {
            name: "twin's truth".into(),
            points: t
                .iter()
                .map(|p| ((p[0] - tm[0]) * unit.1, (p[1] - tm[1]) * unit.1))
                .collect(),
            style: Style::Dots,
        });
    }
    Chart {
        title: format!(
            "{} runs, approach {}, {} control: max error {:.3} / {:.3} µm",
            r.runs,
            r.approach,
            r.control.name(),
            r.max_error_m[0] * 1e6,
            r.max_error_m[1] * 1e6
        ),
        x_label: format!("x from the mean [{}]", unit.0),
        y_label: format!("y from the mean [{}]", unit.0),
        series,
    }
}

fn tracking(d: &Description, kind: Kind, opts: TrackingOptions, args: &BenchArgs) -> Result<()> {
    opts.check().map_err(bench_error)?;
    check_out(args)?;
    let mut s = setup(d, &args.twin, &args.backend)?;
    let (pixels, cal, made) = calibrations(&mut s, args.calibration.as_deref())?;
    let stacks = experiment::stacks(&s.description.design, &s.description.rig, &cal.hysteresis);
    let mut controller = experiment::controller(kind, stacks, &cal)
        .map_err(|e| anyhow::anyhow!("cannot build the {} controller: {e}", kind.name()))?;
    let marker = s.description.rig.optics.marker;
    let approach = s.description.rig.approach;
    let r = {
        let _p = crate::progress::spinner(format!("tracking with the {} controller", kind.name()));
        let mut bench = Bench::new(
            &mut s.rig,
            Acquisition::Marker,
            marker,
            pixels.maps,
            truth(&s.twin),
            timing(args),
        )
        .map_err(bench_error)?;
        experiment::tracking(
            &mut bench,
            controller.as_mut(),
            approach,
            cal.jacobian.jacobian,
            opts,
        )
        .map_err(bench_error)?
    };
    let stem = args
        .out
        .join(format!("tracking-approach{}-{}", r.approach, kind.name()));
    let mut out = Outputs::new();
    out.calibrations(&args.out, made)?;
    out.add(stem.with_extension("csv"), tracking_csv(&r).as_bytes())?;
    out.add(stem.with_extension("json"), &json_bytes(&r)?)?;
    out.plots(&stem, &tracking_charts(&r), 2)?;
    let files = out.commit()?;
    if args.twin.format() == Format::Json {
        let f: Vec<&Path> = files.iter().map(|p| p.as_path()).collect();
        return print_json(&r, &f);
    }
    outln!(
        "Tracking, approach {}, {} control, stacks at {} µm plus steps of {} µm and a circle of {} µm (errors against J·r, through the cameras):",
        r.approach,
        kind.name(),
        r.bias_m * 1e6,
        r.step_m * 1e6,
        r.amplitude_m * 1e6
    );
    for (name, p) in [("steps", &r.steps), ("circle", &r.sine)] {
        outln!(
            "  {name:6}: RMS x {}, y {};  max x {}, y {}",
            nm(p.rms_error_m[0]),
            nm(p.rms_error_m[1]),
            nm(p.max_error_m[0]),
            nm(p.max_error_m[1])
        );
    }
    let settle: Vec<String> = r
        .steps
        .settling_frames
        .iter()
        .map(|s| opt(*s, |f| f.to_string()))
        .collect();
    outln!(
        "  settling of the four steps within {}: {} frames",
        nm(r.tolerance_m),
        settle.join(", ")
    );
    outln!("{}", crate::files::wrote(&files));
    Ok(())
}

fn tracking_csv(r: &TrackingReport) -> String {
    let mut csv = String::from(
        "time_s,a1_reference_m,a2_reference_m,desired_x_m,desired_y_m,x_m,y_m,z_m,true_x_m,true_y_m,true_z_m,a1_voltage_v,a2_voltage_v\n",
    );
    for (f, d) in r.frames.iter().zip(&r.desired) {
        let m = f.measured.unwrap_or([f64::NAN; 3]);
        let t = f.truth.unwrap_or([f64::NAN; 3]);
        let _ = writeln!(
            csv,
            "{:.5},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.5},{:.5}",
            f.t,
            f.reference[0],
            f.reference[1],
            d[0],
            d[1],
            m[0],
            m[1],
            m[2],
            t[0],
            t[1],
            t[2],
            f.volts[0],
            f.volts[1]
        );
    }
    csv
}

fn tracking_charts(r: &TrackingReport) -> Vec<Chart> {
    (0..2)
        .map(|i| {
            let axis = ["x", "y"][i];
            let pick = |f: &FrameRecord, d: &[f64; 2]| (f.t, d[i] * 1e6);
            Chart {
                title: format!("{axis}: {} control", r.control.name()),
                x_label: "time [s]".into(),
                y_label: format!("end-effector {axis} [µm]"),
                series: vec![
                    Series {
                        name: "desired".into(),
                        points: r
                            .frames
                            .iter()
                            .zip(&r.desired)
                            .map(|(f, d)| pick(f, d))
                            .collect(),
                        style: Style::Line,
                    },
                    Series {
                        name: "cameras".into(),
                        points: r
                            .frames
                            .iter()
                            .filter_map(|f| f.measured.map(|m| (f.t, m[i] * 1e6)))
                            .collect(),
                        style: Style::Dots,
                    },
                ],
            }
        })
        .collect()
}
