//! `cellinject run`, `runs` and `report`: the unattended injection workflow on the twin
//! (or any backend), its run records and their report.

use std::path::{Path, PathBuf};

use anyhow::{Result, anyhow};
use cellinject_config::Description;
use cellinject_core::calibrate::HysteresisCalibration;
use cellinject_core::inject::{Attempt, ImageMap, Observer, Options, Target, Transition, Workflow};
use cellinject_plate::{GenerateOptions, Plate, generate};
use cellinject_records::{AttemptRow, EventRow, Records, RecordsError, RunRow};
use cellinject_twin::{Fault, FaultAt, SharedTwin};
use clap::{Args, Subcommand};
use serde::Serialize;

use crate::output::print_json;
use crate::{Format, InputError};

/// `cellinject run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// The plate (TOML; default: a generated 8 x 12 plate centred in the field of
    /// view, from the seed).
    #[arg(long)]
    plate: Option<PathBuf>,
    /// Seed of the twin (and of the default plate); default: the description's.
    #[arg(long)]
    seed: Option<u64>,
    /// The run database.
    #[arg(long, default_value = "runs.sqlite")]
    db: PathBuf,
    /// Continue the database's latest run where it was killed.
    #[arg(long)]
    resume: bool,
    /// A hysteresis calibration to use (JSON from `cellinject calibrate hysteresis`);
    /// checked, and redone if it fails its check.
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// Injected volume, fraction of each cell's volume.
    #[arg(long, default_value_t = 0.05, allow_negative_numbers = true)]
    dose: f64,
    /// Farthest the aim may move off a cell's centre across the pipette's axis (sideways
    /// or up), fraction of its radius, for the glass to pass a neighbour in its way
    /// (the twin's membrane tears past 0.6).
    #[arg(long, default_value_t = 0.3, allow_negative_numbers = true)]
    max_off_centre: f64,
    /// Seconds of device time between two re-checks of the background and the
    /// image-to-stage map (the bench drifts with temperature; the image is mapped again
    /// when the resting tip is more than 1.5 µm from where the map puts it); 0: only
    /// after a fault on a cell, which always brings one.
    #[arg(long, default_value_t = 300.0, value_name = "SECONDS")]
    recheck_every: f64,
    /// Inject a fault into the twin: KIND@ROW,COL (the cell in well [ROW, COL], from 0
    /// as in the plate file) or KIND@ROW,COL,K (the K-th cell of that well, top first,
    /// from 0); KIND one of clog, hard-clog, break, move, dark, stall (repeatable).
    #[arg(long, value_name = "KIND@ROW,COL[,K]")]
    fault: Vec<String>,
    #[command(flatten)]
    backend: crate::backend::BackendArgs,
    /// What to print.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
}

/// `cellinject runs`.
#[derive(Debug, Subcommand)]
pub enum RunsCommand {
    /// One line per run.
    #[command(
        after_help = "Examples:\n  cellinject runs list\n  cellinject runs list --db runs.sqlite --format json"
    )]
    List {
        /// The run database.
        #[arg(long, default_value = "runs.sqlite")]
        db: PathBuf,
        /// What to print.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// A run and its attempts as JSON (the latest, or `--run ID`).
    #[command(
        after_help = "Examples:\n  cellinject runs show\n  cellinject runs show --db runs.sqlite --run 2"
    )]
    Show {
        /// The run database.
        #[arg(long, default_value = "runs.sqlite")]
        db: PathBuf,
        /// Run id.
        #[arg(long)]
        run: Option<i64>,
    },
    /// A run's attempts as CSV or JSON on standard output.
    #[command(
        after_help = "Examples:\n  cellinject runs export > attempts.csv\n  cellinject runs export --run 2 --format json"
    )]
    Export {
        /// The run database.
        #[arg(long, default_value = "runs.sqlite")]
        db: PathBuf,
        /// Run id (default: the latest).
        #[arg(long)]
        run: Option<i64>,
        /// csv or json.
        #[arg(long, default_value = "csv")]
        format: String,
    },
}

/// Reads `--fault KIND@ROW,COL[,K]`; exit 2 naming the option and what is wrong.
pub(crate) fn parse_fault(s: &str) -> Result<FaultAt> {
    s.parse::<FaultAt>()
        .map_err(|e| InputError(format!("--fault {e}")).into())
}

/// The faults on `plate`'s cells; exit 2 naming the fault whose well or cell the plate
/// does not have.
pub(crate) fn resolve_faults(
    specs: &[String],
    faults: &[FaultAt],
    plate: &Plate,
) -> Result<Vec<Fault>> {
    specs
        .iter()
        .zip(faults)
        .map(|(s, f)| {
            f.resolve(plate).map_err(|e| {
                InputError(format!(
                    "--fault `{s}`: {}",
                    e.to_string().trim_start_matches("key `fault`: ")
                ))
                .into()
            })
        })
        .collect()
}

/// The default plate: 8 x 12 wells of 150 um centred in the 2.5x field of view.
pub fn default_plate(seed: u64) -> Result<Plate> {
    let (rows, cols, pitch) = (8u32, 12u32, 150e-6);
    generate(&GenerateOptions {
        rows,
        cols,
        pitch,
        origin: [
            -0.5 * (cols - 1) as f64 * pitch,
            -0.5 * (rows - 1) as f64 * pitch + 30e-6,
        ],
        seed,
        ..GenerateOptions::default()
    })
    .map_err(|e| anyhow!("default plate: {e}"))
}

/// A records failure as the user's error: the file's own faults name `--db`, the only
/// way a database reaches a command.
pub(crate) fn records_error(e: RecordsError) -> anyhow::Error {
    match e {
        RecordsError::Sql(_) => anyhow!("{e}"),
        RecordsError::Foreign { .. }
        | RecordsError::Newer { .. }
        | RecordsError::Unreadable { .. } => InputError(format!("--db {e}")).into(),
        other => InputError(other.to_string()).into(),
    }
}

/// What `run` prints as JSON.
#[derive(Debug, Serialize)]
struct Summary {
    run: i64,
    status: String,
    /// `twin` or the controller's address (`gcs://...`).
    backend: String,
    cells_found: i64,
    injected: usize,
    failed: usize,
    skipped: usize,
    interrupted: usize,
    sim_time_s: f64,
    cell_time_s: f64,
    cells_per_min: f64,
    stopped: Option<String>,
    attempts: Vec<AttemptRow>,
    /// The run's own transitions: calibration, survey, re-checks, the end.
    events: Vec<EventRow>,
    /// Other cells the pipette's glass ran into during this command's attempts (the
    /// twin's truth; absent on hardware and from `runs show`).
    #[serde(skip_serializing_if = "Option::is_none")]
    grazed: Option<u32>,
    /// The fields' planes of best focus this command measured (absent from `runs
    /// show`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    focus: Vec<FocusRow>,
}

/// A field's focus as measured, and on the twin how far it is from the truth.
#[derive(Debug, Serialize)]
struct FocusRow {
    #[serde(flatten)]
    focus: cellinject_core::inject::FieldFocus,
    /// m, the twin's truth: the largest distance over the field's cells between the
    /// floor's height the plane puts under them and its true height.
    #[serde(skip_serializing_if = "Option::is_none")]
    true_error_m: Option<f64>,
}

fn summary(run: &RunRow, attempts: Vec<AttemptRow>, events: Vec<EventRow>) -> Summary {
    let n = |o: &str| attempts.iter().filter(|a| a.outcome == o).count();
    Summary {
        run: run.id,
        status: run.status.clone(),
        backend: run.backend.clone(),
        cells_found: run.cells_found,
        injected: n("injected"),
        failed: n("failed"),
        skipped: n("skipped"),
        interrupted: n("interrupted"),
        sim_time_s: run.sim_time_s,
        cell_time_s: run.cell_time_s,
        cells_per_min: if run.cell_time_s > 0.0 {
            attempts.len() as f64 / run.cell_time_s * 60.0
        } else {
            0.0
        },
        stopped: run.stopped.clone(),
        attempts,
        events,
        grazed: None,
        focus: Vec::new(),
    }
}

/// The twin's truth and the run records, as the workflow's observer.
struct Recorder<'a> {
    /// The twin, when it is the backend (else no truth).
    twin: Option<SharedTwin>,
    plate: Plate,
    db: &'a mut Records,
    run: i64,
    current: Option<i64>,
    previous: Vec<AttemptRow>,
    bar: Option<crate::progress::Progress>,
    /// Show a progress bar.
    progress: bool,
}

impl Recorder<'_> {
    fn row(&self, a: &Attempt, outcome: &str) -> AttemptRow {
        AttemptRow {
            id: 0,
            cell: a.target.index as i64,
            well: a.target.well,
            x_m: a.target.x_m,
            y_m: a.target.y_m,
            diameter_m: a.target.diameter_m,
            tip_error_m: a.truth.tip_error_m,
            measured_tip_error_m: a.measured_tip_error_m,
            depth_m: a.depth_m,
            dose_fraction: a.truth.dose_fraction.or(a.measured_dose_fraction),
            measured_dose_fraction: a.measured_dose_fraction,
            alive: a.truth.alive,
            outcome: outcome.into(),
            reason: a.reason.clone(),
            t_start: a.t[0],
            t_end: (a.t[1] > 0.0).then_some(a.t[1]),
            transitions: serde_json::to_value(&a.transitions).unwrap_or_default(),
        }
    }

    /// The twin's cell nearest to a target (plate coordinates).
    fn nearest(&self, t: &Target) -> Option<cellinject_twin::CellState> {
        let p = [t.x_m + self.plate.origin[0], t.y_m + self.plate.origin[1]];
        nearest_cell(self.twin.as_ref()?, p)
    }
}

impl Observer for Recorder<'_> {
    fn transition(&mut self, t: &Transition) {
        if std::env::var_os("CELLINJECT_DEBUG").is_some() {
            let Some(twin) = &self.twin else {
                eprintln!("{:?} -> {:?}: {}", t.from, t.to, t.reason);
                return;
            };
            let twin = twin.lock().unwrap_or_else(|e| e.into_inner());
            let tip = twin.tip();
            let (strikes, lost, grazed) = twin.biology.as_ref().map_or((0, 0.0, 0), |b| {
                (
                    b.floor_strikes,
                    b.tip_loss,
                    b.cells.iter().filter(|c| c.grazed).count(),
                )
            });
            eprintln!(
                "{:?} -> {:?}: {} [true tip {:.2}, {:.2} um, depth {:.2} um; floor strikes {strikes}, tip lost {:.1} um, grazed {grazed}]",
                t.from,
                t.to,
                t.reason,
                tip.x * 1e6,
                tip.z * 1e6,
                tip.depth * 1e6,
                lost * 1e6
            );
        }
    }
    fn logged(&mut self, t: &Transition) -> Result<(), String> {
        let name = |v: serde_json::Value| v.as_str().unwrap_or_default().to_string();
        let row = EventRow {
            t: t.t,
            from: name(serde_json::to_value(t.from).unwrap_or_default()),
            event: name(serde_json::to_value(t.event).unwrap_or_default()),
            to: name(serde_json::to_value(t.to).unwrap_or_default()),
            reason: t.reason.clone(),
        };
        self.db
            .write_event(self.run, &row)
            .map_err(|e| e.to_string())
    }
    fn surveyed(&mut self, targets: &[Target]) -> Result<(), String> {
        if self.progress {
            let left = targets.iter().filter(|t| !self.done(t)).count();
            self.bar = Some(crate::progress::rate_bar(left as u64, "cells"));
        }
        Ok(())
    }
    fn done(&self, t: &Target) -> bool {
        self.previous
            .iter()
            .any(|a| a.well == t.well && (a.x_m - t.x_m).hypot(a.y_m - t.y_m) < 3e-6)
    }
    fn started(&mut self, a: &Attempt) -> Result<(), String> {
        let row = self.row(a, "started");
        self.current = Some(
            self.db
                .write_attempt(self.run, None, &row)
                .map_err(|e| e.to_string())?,
        );
        Ok(())
    }
    fn contact(&mut self, a: &Attempt) -> Result<(), String> {
        let row = self.row(a, "contact");
        self.db
            .write_attempt(self.run, self.current, &row)
            .map_err(|e| e.to_string())?;
        Ok(())
    }
    fn finished(&mut self, a: &Attempt) -> Result<(), String> {
        let row = self.row(a, a.outcome.name());
        self.db
            .write_attempt(self.run, self.current.take(), &row)
            .map_err(|e| e.to_string())?;
        if let Some(b) = &self.bar {
            b.inc();
        }
        Ok(())
    }
    fn tip_error(&mut self, t: &Target) -> Option<f64> {
        let c = self.nearest(t)?;
        // The tip in the plate's frame: the cells lie where the feeder has moved it.
        let (mut tip, o) = {
            let twin = self
                .twin
                .as_ref()?
                .lock()
                .unwrap_or_else(|e| e.into_inner());
            (twin.tip(), twin.plate_offset())
        };
        tip.x -= o[0];
        tip.z -= o[1];
        if std::env::var_os("CELLINJECT_DEBUG").is_some() {
            eprintln!(
                "tip - cell: ({:.2}, {:.2}) um; target ({:.2}, {:.2}) um vs true ({:.2}, {:.2})",
                (tip.x - c.centre[0]) * 1e6,
                (tip.z - c.centre[1]) * 1e6,
                (t.x_m + self.plate.origin[0]) * 1e6,
                (t.y_m + self.plate.origin[1]) * 1e6,
                c.centre[0] * 1e6,
                c.centre[1] * 1e6
            );
        }
        Some((tip.x - c.centre[0]).hypot(tip.z - c.centre[1]))
    }
    fn cell_truth(&mut self, t: &Target) -> Option<(f64, bool)> {
        let c = self.nearest(t)?;
        if std::env::var_os("CELLINJECT_DEBUG").is_some() {
            eprintln!(
                "cell {}: punctures {}, max depth {:.2} um of r {:.2}, inside x {:.2} um, dead {:?}",
                t.index,
                c.punctures,
                c.max_depth * 1e6,
                c.radius * 1e6,
                (c.inside_x[1] - c.inside_x[0]) * 1e6,
                c.dead
            );
        }
        Some((c.dose_fraction(), c.dead.is_none()))
    }
    fn grazed(&mut self) -> Option<u32> {
        let twin = self
            .twin
            .as_ref()?
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        let b = twin.biology.as_ref()?;
        Some(b.cells.iter().filter(|c| c.grazed).count() as u32)
    }
}

/// One run on an opened bench: what [`execute`] needs.
pub(crate) struct Job<'a> {
    pub d: &'a Description,
    pub options: Options,
    pub hysteresis: Option<HysteresisCalibration>,
    /// The twin, when it is the backend (its truth goes into the records).
    pub twin: Option<SharedTwin>,
    pub plate: Plate,
    /// The run's record.
    pub run_id: i64,
    /// Attempts already recorded (a resumed run).
    pub previous: Vec<AttemptRow>,
    /// Device time of earlier segments (a resumed run): whole run, cells.
    pub base: (f64, f64),
    /// A progress bar on standard error.
    pub progress: bool,
}

/// The twin's cell whose true centre is nearest to stage point `p` (m).
fn nearest_cell(twin: &SharedTwin, p: [f64; 2]) -> Option<cellinject_twin::CellState> {
    let twin = twin.lock().unwrap_or_else(|e| e.into_inner());
    let b = twin.biology.as_ref()?;
    b.cells
        .iter()
        .min_by(|a, c| {
            let da = (a.centre[0] - p[0]).hypot(a.centre[1] - p[1]);
            let dc = (c.centre[0] - p[0]).hypot(c.centre[1] - p[1]);
            da.total_cmp(&dc)
        })
        .copied()
}

/// The workflow's observer calls go to the records and, if given, to a second
/// observer (the dashboard); the records answer the questions.
struct Tee<'a, 'b> {
    rec: Recorder<'a>,
    extra: Option<&'b mut dyn Observer>,
}

impl Observer for Tee<'_, '_> {
    fn transition(&mut self, t: &Transition) {
        self.rec.transition(t);
        if let Some(x) = self.extra.as_mut() {
            x.transition(t);
        }
    }
    fn logged(&mut self, t: &Transition) -> Result<(), String> {
        self.rec.logged(t)?;
        self.extra.as_mut().map_or(Ok(()), |x| x.logged(t))
    }
    fn field(&mut self, index: usize, of: usize, rect: [f64; 4], feeder: [f64; 2]) {
        self.rec.field(index, of, rect, feeder);
        if let Some(x) = self.extra.as_mut() {
            x.field(index, of, rect, feeder);
        }
    }
    fn surveyed(&mut self, targets: &[Target]) -> Result<(), String> {
        self.rec.surveyed(targets)?;
        self.extra.as_mut().map_or(Ok(()), |x| x.surveyed(targets))
    }
    fn done(&self, t: &Target) -> bool {
        self.rec.done(t)
    }
    fn started(&mut self, a: &Attempt) -> Result<(), String> {
        self.rec.started(a)?;
        self.extra.as_mut().map_or(Ok(()), |x| x.started(a))
    }
    fn contact(&mut self, a: &Attempt) -> Result<(), String> {
        self.rec.contact(a)?;
        self.extra.as_mut().map_or(Ok(()), |x| x.contact(a))
    }
    fn finished(&mut self, a: &Attempt) -> Result<(), String> {
        self.rec.finished(a)?;
        self.extra.as_mut().map_or(Ok(()), |x| x.finished(a))
    }
    fn proceed(&mut self) -> Result<(), String> {
        self.extra.as_mut().map_or(Ok(()), |x| x.proceed())
    }
    fn mapped(&mut self, map: &ImageMap) {
        if let Some(x) = self.extra.as_mut() {
            x.mapped(map);
        }
    }
    fn tip_error(&mut self, t: &Target) -> Option<f64> {
        self.rec.tip_error(t)
    }
    fn cell_truth(&mut self, t: &Target) -> Option<(f64, bool)> {
        self.rec.cell_truth(t)
    }
    fn grazed(&mut self) -> Option<u32> {
        self.rec.grazed()
    }
}

/// What a run's workflow returned.
pub(crate) type Outcome = Result<
    (cellinject_core::inject::RunReport, HysteresisCalibration),
    cellinject_core::inject::WorkflowError,
>;

/// Runs `job` on `rig`, recording every attempt in `db` and the run's end: `finished`,
/// `stopped`, or `aborted` when `aborted()` says the operator stopped it. Returns the
/// workflow's result and why the run stopped, if it did.
pub(crate) fn execute(
    job: Job<'_>,
    db: &mut Records,
    rig: &mut cellinject_rig::Rig<cellinject_rig::DynBackend>,
    extra: Option<&mut dyn Observer>,
    aborted: &dyn Fn() -> bool,
) -> Result<(Outcome, Option<String>)> {
    let Job {
        d,
        options,
        hysteresis,
        twin,
        plate,
        run_id,
        previous,
        base,
        progress,
    } = job;
    let mut tee = Tee {
        rec: Recorder {
            twin,
            plate: plate.clone(),
            db,
            run: run_id,
            current: None,
            previous,
            bar: None,
            progress,
        },
        extra,
    };
    let wf = Workflow::new(rig, &d.design, &d.rig, &plate, options)
        .map_err(|e| InputError(e.to_string()))?;
    let result = wf.run(hysteresis, &mut tee);
    let rec = tee.rec;
    let (status, stopped, sim, cell, found) = match &result {
        Ok((r, cal)) => {
            rec.db
                .set_calibration(
                    run_id,
                    &serde_json::json!({ "hysteresis": cal, "map": r.map }),
                )
                .map_err(records_error)?;
            (
                if r.stopped.is_some() {
                    "stopped"
                } else {
                    "finished"
                },
                r.stopped.clone(),
                r.sim_time_s,
                r.cell_time_s,
                r.cells_found as i64,
            )
        }
        Err(e) => ("stopped", Some(e.to_string()), 0.0, 0.0, 0),
    };
    let status = if aborted() { "aborted" } else { status };
    rec.db
        .update_run(
            run_id,
            status,
            base.0 + sim,
            base.1 + cell,
            found,
            stopped.as_deref(),
        )
        .map_err(records_error)?;
    Ok((result, stopped))
}

/// `cellinject run`.
pub fn run(d: &Description, args: &RunArgs) -> Result<()> {
    let faults = args
        .fault
        .iter()
        .map(|f| parse_fault(f))
        .collect::<Result<Vec<_>>>()?;
    let options = Options {
        target_fraction: args.dose,
        max_off_centre: args.max_off_centre,
        recheck_every: args.recheck_every,
        ..Options::default()
    };
    options
        .check(&d.rig)
        .map_err(|e| InputError(e.to_string()))?;
    if args.backend.check()?.is_some() {
        if !faults.is_empty() {
            return Err(InputError(
                "--fault injects faults into the twin: with a GCS backend give them to the emulator (`cellinject emulate gcs --fault`)".into(),
            )
            .into());
        }
        gcs_run_checks(args.plate.is_some() || args.resume, args.seed.is_some())?;
    }
    let hysteresis = match &args.calibration {
        None => None,
        Some(p) => crate::experiment::read_hysteresis(p, d.rig.approach.number())?,
    };
    // The plate is read and checked before the database is touched.
    let given_plate = match &args.plate {
        None => None,
        Some(p) => Some(read_plate(p)?),
    };
    // So are the faults on a new run's plate: a fault naming a well or cell the plate
    // does not have leaves no run behind.
    let fresh = if args.resume {
        None
    } else {
        let seed = args.seed.unwrap_or(d.sim.seed);
        let (plate, text) = match &given_plate {
            Some(p) => p.clone(),
            None => default_plate_text(seed)?,
        };
        let resolved = resolve_faults(&args.fault, &faults, &plate)?;
        Some((plate, text, seed, resolved))
    };
    // A controller that cannot be reached leaves no run behind: it is opened before
    // the database.
    let mut wire = if args.backend.is_twin() {
        None
    } else {
        Some(crate::backend::open(
            d,
            &crate::sim::TwinArgs::new(None, None),
            &args.backend,
        )?)
    };
    let db_existed = args.db.exists();
    let mut db = Records::open(&args.db).map_err(records_error)?;
    let (run_id, plate_text, seed, previous, base, faults) = if args.resume {
        let r = db.run(None).map_err(records_error)?;
        if let (Some(p), Some((_, text))) = (&args.plate, &given_plate) {
            if *text != r.plate {
                return Err(InputError(format!(
                    "--plate `{}` is not the plate of run {} (resume takes the plate from the database: leave --plate out)",
                    p.display(),
                    r.id
                ))
                .into());
            }
        }
        if let Some(s) = args.seed
            && Some(s) != r.seed
        {
            return Err(InputError(format!(
                "--seed {s} is not run {}'s seed {} (resume takes it from the database: leave --seed out)",
                r.id,
                r.seed.map_or("(none)".to_string(), |s| s.to_string())
            ))
            .into());
        }
        if r.backend != args.backend.backend {
            return Err(InputError(format!(
                "--backend {} is not run {}'s backend {} (resume on the same hardware)",
                args.backend.backend, r.id, r.backend
            ))
            .into());
        }
        if r.status == "finished" {
            let attempts = db.attempts(r.id).map_err(records_error)?;
            if args.format == Format::Json {
                let events = db.events(r.id).map_err(records_error)?;
                return print_json(summary(&r, attempts, events), &[]);
            }
            outln!("run {} is finished: nothing to resume", r.id);
            return Ok(());
        }
        // The faults act on the run's own plate (checked before the records change).
        let resolved = match cellinject_config::plate::parse(&r.plate) {
            Ok(p) => resolve_faults(&args.fault, &faults, &p)?,
            Err(_) => Vec::new(), // refused below, naming the run's plate
        };
        let (dropped, interrupted) = db.prepare_resume(r.id).map_err(records_error)?;
        if dropped + interrupted > 0 {
            eprintln!(
                "resuming run {}: {dropped} attempt(s) that had not reached their cell will be retried, {interrupted} recorded interrupted",
                r.id
            );
        }
        let previous = db.attempts(r.id).map_err(records_error)?;
        (
            r.id,
            r.plate.clone(),
            r.seed.unwrap_or(d.sim.seed),
            previous,
            (r.sim_time_s, r.cell_time_s),
            resolved,
        )
    } else {
        let (_, text, seed, resolved) = fresh.expect("a new run's plate is read first");
        let settings = serde_json::json!({ "options": options, "faults": args.fault });
        let id = new_run(
            &mut db,
            &text,
            args.backend.is_twin().then_some(seed),
            &args.backend.backend,
            &settings,
        )?;
        (id, text, seed, Vec::new(), (0.0, 0.0), resolved)
    };
    let plate = cellinject_config::plate::parse(&plate_text).map_err(|e| {
        InputError(format!(
            "{}: {e}",
            args.plate
                .as_ref()
                .map_or("the run's plate".to_string(), |p| format!(
                    "--plate `{}`",
                    p.display()
                ))
        ))
    })?;
    plate
        .check()
        .map_err(|e| InputError(format!("plate: {e}")))?;
    let (twin, mut rig) = if args.backend.is_twin() {
        let o = crate::backend::open(d, &crate::sim::TwinArgs::with_seed(seed), &args.backend)?;
        let twin = o.twin.expect("the twin backend has a twin");
        {
            let mut t = twin.lock().unwrap_or_else(|e| e.into_inner());
            t.load_plate(&plate);
            t.set_faults(&faults)
                .map_err(|e| InputError(format!("--fault: {e}")))?;
            // The macro stage starts with the pipette lifted above the plate.
            t.world.stage.place(1, options.focus + options.lift);
        }
        (Some(twin), o.rig)
    } else {
        // The emulator (or the real bench) holds the plate and the stage's start.
        let o = wire.take().expect("opened before the database");
        (None, o.rig)
    };
    let truth = twin.clone();
    let job = Job {
        d,
        options,
        hysteresis,
        twin,
        plate: plate.clone(),
        run_id,
        previous,
        base,
        progress: true,
    };
    let (result, stopped) = execute(job, &mut db, &mut rig, None, &|| false)?;
    let r = db.run(Some(run_id)).map_err(records_error)?;
    let mut s = summary(
        &r,
        db.attempts(run_id).map_err(records_error)?,
        db.events(run_id).map_err(records_error)?,
    );
    if let Ok((report, _)) = &result {
        let g: Vec<u32> = report
            .attempts
            .iter()
            .filter_map(|a| a.truth.grazed)
            .collect();
        s.grazed = (!g.is_empty()).then(|| g.iter().sum());
        s.focus = report
            .focus
            .iter()
            .map(|f| FocusRow {
                focus: *f,
                true_error_m: truth.as_ref().map(|t| focus_error(t, &plate, f)),
            })
            .collect();
    }
    if let Err(e) = &result
        && matches!(
            e,
            cellinject_core::inject::WorkflowError::Plan(_)
                | cellinject_core::inject::WorkflowError::PitchTooLarge { .. }
        )
    {
        // Bad input leaves no record: a new run refused before any cell goes, and so
        // does the database file if this command created it.
        if !args.resume {
            db.discard_run(run_id).map_err(records_error)?;
            if !db_existed {
                drop(db);
                for suffix in ["", "-wal", "-shm"] {
                    let mut p = args.db.clone().into_os_string();
                    p.push(suffix);
                    let _ = std::fs::remove_file(p);
                }
            }
        }
        return Err(InputError(e.to_string()).into());
    }
    if args.format == Format::Json {
        print_json(&s, &[])?;
    } else {
        print_text(&s);
    }
    match (result, stopped) {
        (Err(e), _) => Err(anyhow!("run {run_id} stopped: {e}")),
        (Ok(_), Some(why)) => Err(anyhow!("run {run_id} stopped: {why}")),
        _ => Ok(()),
    }
}

fn print_text(s: &Summary) {
    // The twin's truth, else what the camera measured.
    let twin = s.backend == "twin";
    let errs: Vec<f64> = s
        .attempts
        .iter()
        .filter(|a| a.outcome == "injected")
        .filter_map(|a| {
            if twin {
                a.tip_error_m
            } else {
                a.measured_tip_error_m
            }
        })
        .collect();
    let mean = errs.iter().sum::<f64>() / errs.len().max(1) as f64;
    outln!(
        "run {} {}: {} cells found, {} injected, {} failed, {} skipped, {} interrupted",
        s.run,
        s.status,
        s.cells_found,
        s.injected,
        s.failed,
        s.skipped,
        s.interrupted
    );
    let tip = if errs.is_empty() {
        "no injection".to_string()
    } else {
        format!(
            "mean tip error at injection {:.2} µm{}",
            mean * 1e6,
            if twin {
                ""
            } else {
                " (as the camera measured it)"
            }
        )
    };
    outln!(
        "{:.1} s {} ({:.1} s on cells): {:.1} cells per minute; {tip}",
        s.sim_time_s,
        if twin {
            "simulated"
        } else {
            "on the bench's clock"
        },
        s.cell_time_s,
        s.cells_per_min
    );
    if let Some(g) = s.grazed {
        if g == 0 {
            outln!("the pipette's glass touched no cell but its targets");
        } else {
            outln!("the pipette's glass ran into {g} other cells");
        }
    }
    if !s.focus.is_empty() {
        let swept: Vec<&FocusRow> = s.focus.iter().filter(|f| f.focus.frames > 0).collect();
        let tilt = |f: &&FocusRow| f.focus.slope[0].hypot(f.focus.slope[1]) * 1e3;
        let (lo, hi) = swept
            .iter()
            .map(tilt)
            .fold((f64::INFINITY, 0.0f64), |(a, b), t| (a.min(t), b.max(t)));
        let worst = s
            .focus
            .iter()
            .filter_map(|f| f.true_error_m)
            .fold(None, |m: Option<f64>, e| Some(m.map_or(e, |m| m.max(e))));
        let slope = if format!("{lo:.1}") == format!("{hi:.1}") {
            format!("{hi:.1}")
        } else {
            format!("{lo:.1}-{hi:.1}")
        };
        outln!(
            "{} focused ({} focus frames), the floor sloping {slope} um/mm{}",
            if swept.len() == 1 {
                "1 field".to_string()
            } else {
                format!("{} fields", swept.len())
            },
            swept.iter().map(|f| f.focus.frames).sum::<usize>(),
            worst.map_or(String::new(), |w| format!(
                "; the floor under the cells at most {:.2} um from where the focus put it",
                w * 1e6
            ))
        );
    }
    for e in s
        .events
        .iter()
        .filter(|e| e.event == "recheck" || e.event == "rechecked")
    {
        outln!("  {:.0} s: {}", e.t, e.reason);
    }
    for a in s.attempts.iter().filter(|a| a.outcome != "injected") {
        outln!(
            "  cell {} well [{}, {}]: {}: {}",
            a.cell,
            a.well[0],
            a.well[1],
            a.outcome,
            a.reason
        );
    }
    if let Some(w) = &s.stopped {
        outln!("stopped: {w}");
    }
}

/// `cellinject runs`.
pub fn runs(cmd: &RunsCommand) -> Result<()> {
    match cmd {
        RunsCommand::List { db, format } => {
            let db = open_existing(db)?;
            let runs = db.runs().map_err(records_error)?;
            if *format == Format::Json {
                return json_out(&runs);
            }
            for r in runs {
                let a = db.attempts(r.id).map_err(records_error)?;
                let inj = a.iter().filter(|a| a.outcome == "injected").count();
                outln!(
                    "run {}: {}, {} cells found, {} attempts, {} injected, {:.1} s {}{}",
                    r.id,
                    r.status,
                    r.cells_found,
                    a.len(),
                    inj,
                    r.sim_time_s,
                    if r.backend == "twin" {
                        "simulated".to_string()
                    } else {
                        format!("on {}", r.backend)
                    },
                    r.stopped
                        .map(|s| format!(" (stopped: {s})"))
                        .unwrap_or_default()
                );
            }
            Ok(())
        }
        RunsCommand::Show { db, run } => {
            let db = open_existing(db)?;
            let r = db.run(*run).map_err(records_error)?;
            let a = db.attempts(r.id).map_err(records_error)?;
            let e = db.events(r.id).map_err(records_error)?;
            print_json(
                serde_json::json!({ "run": r, "attempts": a, "events": e }),
                &[],
            )
        }
        RunsCommand::Export { db, run, format } => {
            let db = open_existing(db)?;
            let r = db.run(*run).map_err(records_error)?;
            let a = db.attempts(r.id).map_err(records_error)?;
            match format.as_str() {
                "json" => json_out(&a),
                "csv" => {
                    let mut out = String::from(
                        "cell,well_row,well_col,x_m,y_m,diameter_m,tip_error_m,measured_tip_error_m,depth_m,dose_fraction,measured_dose_fraction,alive,outcome,reason,t_start_s,t_end_s\n",
                    );
                    let o = |v: Option<f64>| v.map(|v| format!("{v:e}")).unwrap_or_default();
                    for a in &a {
                        out.push_str(&format!(
                            "{},{},{},{:e},{:e},{:e},{},{},{},{},{},{},{},\"{}\",{},{}\n",
                            a.cell,
                            a.well[0],
                            a.well[1],
                            a.x_m,
                            a.y_m,
                            a.diameter_m,
                            o(a.tip_error_m),
                            o(a.measured_tip_error_m),
                            o(a.depth_m),
                            o(a.dose_fraction),
                            o(a.measured_dose_fraction),
                            a.alive.map(|b| b.to_string()).unwrap_or_default(),
                            a.outcome,
                            a.reason.replace('"', "\"\""),
                            a.t_start,
                            o(a.t_end)
                        ));
                    }
                    crate::output::print(format_args!("{out}"));
                    Ok(())
                }
                other => {
                    Err(InputError(format!("--format `{other}`: expected csv or json")).into())
                }
            }
        }
    }
}

fn json_out<T: Serialize>(v: &T) -> Result<()> {
    crate::output::print(format_args!("{}\n", serde_json::to_string_pretty(v)?));
    Ok(())
}

fn read_text(p: &Path) -> Result<String> {
    std::fs::read_to_string(p)
        .map_err(|e| InputError(format!("--plate `{}`: cannot read: {e}", p.display())).into())
}

/// `run`'s default plate for `seed` and its text as the run records keep it.
pub(crate) fn default_plate_text(seed: u64) -> Result<(Plate, String)> {
    let plate = default_plate(seed)?;
    let text = cellinject_config::plate::to_toml(
        &plate,
        &format!("cellinject run's default plate: 8 x 12 wells, seed {seed}"),
    );
    Ok((plate, text))
}

/// A new run record for `plate_text`, created now.
pub(crate) fn new_run(
    db: &mut Records,
    plate_text: &str,
    seed: Option<u64>,
    backend: &str,
    settings: &serde_json::Value,
) -> Result<i64> {
    let created = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0);
    db.create_run(plate_text, seed, backend, settings, created)
        .map_err(records_error)
}

/// The plate file `p` (`--plate`), parsed and checked, and its text.
pub(crate) fn read_plate(p: &Path) -> Result<(Plate, String)> {
    let text = read_text(p)?;
    let plate = cellinject_config::plate::parse(&text)
        .map_err(|e| InputError(format!("--plate `{}`: {e}", p.display())))?;
    plate
        .check()
        .map_err(|e| InputError(format!("--plate `{}`: {e}", p.display())))?;
    Ok((plate, text))
}

/// A run on a GCS backend: the plate is the bench's (give `--plate`), and there is no
/// twin to seed.
pub(crate) fn gcs_run_checks(plate_given: bool, seed_given: bool) -> Result<()> {
    if !plate_given {
        return Err(InputError(
            "with a GCS backend give --plate: the plate file under the microscope (`cellinject emulate gcs --plate` for the emulator)".into(),
        )
        .into());
    }
    if seed_given {
        return Err(InputError(
            "--seed seeds the twin: with a GCS backend seed the emulator (`cellinject emulate gcs --seed`)".into(),
        )
        .into());
    }
    Ok(())
}

pub(crate) fn open_existing(p: &Path) -> Result<Records> {
    if !p.exists() {
        return Err(InputError(format!(
            "--db `{}`: no such file (a run creates it: cellinject run --db {})",
            p.display(),
            p.display()
        ))
        .into());
    }
    Records::open(p).map_err(records_error)
}

/// m, the largest distance over the cells of field `f` (the plate's true cells in
/// its rectangle; its centre if it holds none) between the floor's height its plane of
/// focus gives and the twin's truth, the feeder at the plane's height.
fn focus_error(
    twin: &cellinject_twin::SharedTwin,
    plate: &cellinject_plate::Plate,
    f: &cellinject_core::inject::FieldFocus,
) -> f64 {
    let surface = twin.lock().unwrap_or_else(|e| e.into_inner()).surface();
    let r = f.rect_m;
    let mut at: Vec<[f64; 2]> = plate
        .cells
        .iter()
        .map(|c| plate.centre(c))
        .filter(|p| p[0] >= r[0] && p[0] <= r[2] && p[1] >= r[1] && p[1] <= r[3])
        .collect();
    if at.is_empty() {
        at.push(f.centre_m);
    }
    at.iter()
        .map(|&p| (f.feeder_z_m + surface.height(p) - f.floor_at(p)).abs())
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};

    use cellinject_core::inject::Event;
    use cellinject_hw::{Camera, CameraSettings, Clock, HwError, PiezoChannel, Roi};

    use super::*;
    use crate::backend::Opened;

    /// The device clock, failing its next sleep once `stop` is set (what the
    /// dashboard's clock does on an abort).
    struct Stopping {
        inner: Box<dyn Clock>,
        stop: Arc<AtomicBool>,
    }

    impl Clock for Stopping {
        fn now(&self) -> f64 {
            self.inner.now()
        }
        fn sleep(&mut self, seconds: f64) -> Result<(), HwError> {
            if self.stop.swap(false, Ordering::SeqCst) {
                return Err(HwError::Interrupted {
                    device: "clock".into(),
                    reason: "aborted by the test".into(),
                });
            }
            self.inner.sleep(seconds)
        }
    }

    /// What a test run on the twin left behind.
    struct Ran {
        opened: Opened,
        db: Records,
        run_id: i64,
        result: super::Outcome,
        stopped: Option<String>,
        dir: PathBuf,
    }

    impl Drop for Ran {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }

    /// A run of the default plate (seed 1) on the twin whose clock fails once `stop`
    /// is set (`obs` sets it), recorded in a fresh database.
    fn run_on_twin(name: &str, stop: Arc<AtomicBool>, obs: &mut dyn Observer) -> Ran {
        let d = cellinject_config::prototype();
        let backend = crate::backend::BackendArgs {
            backend: "twin".into(),
            bench: None,
            camera: None,
            camera_fps: None,
        };
        let mut opened = crate::backend::open_with(
            &d,
            &crate::sim::TwinArgs::with_seed(1),
            &backend,
            move |mut devices| {
                devices.clock = Box::new(Stopping {
                    inner: devices.clock,
                    stop,
                });
                devices
            },
        )
        .unwrap();
        let options = Options::default();
        let (plate, text) = default_plate_text(1).unwrap();
        let twin = opened.twin.clone().unwrap();
        {
            let mut t = twin.lock().unwrap();
            t.load_plate(&plate);
            t.world.stage.place(1, options.focus + options.lift);
        }
        let dir = std::env::temp_dir().join(format!("cellinject-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut db = Records::open(&dir.join("runs.sqlite")).unwrap();
        let run_id = new_run(&mut db, &text, Some(1), "twin", &serde_json::json!({})).unwrap();
        let job = Job {
            d: &d,
            options,
            hysteresis: None,
            twin: Some(twin),
            plate,
            run_id,
            previous: Vec::new(),
            base: (0.0, 0.0),
            progress: false,
        };
        let (result, stopped) =
            execute(job, &mut db, &mut opened.rig, Some(obs), &|| true).unwrap();
        Ran {
            opened,
            db,
            run_id,
            result,
            stopped,
            dir,
        }
    }

    /// Sets `stop` when the first cell's dose has been judged.
    struct AbortAfterDose(Arc<AtomicBool>);

    impl Observer for AbortAfterDose {
        fn transition(&mut self, t: &Transition) {
            if t.event == Event::DoseOk {
                self.0.store(true, Ordering::SeqCst);
            }
        }
    }

    /// An abort while the pipette withdraws from a cell it has injected: the cell keeps
    /// its judged outcome, its reason says the operator stopped the run, it is the last
    /// attempt, and the stacks end at rest with A3 at 0 V.
    #[test]
    fn an_abort_after_the_dose_keeps_the_cells_outcome_and_says_why() {
        let stop = Arc::new(AtomicBool::new(false));
        let mut obs = AbortAfterDose(stop.clone());
        let mut ran = run_on_twin("abort", stop, &mut obs);
        let report = ran.result.as_ref().unwrap().0.clone();
        assert!(
            ran.stopped
                .as_ref()
                .unwrap()
                .contains("aborted by the test")
        );
        let attempts = ran.db.attempts(ran.run_id).unwrap();
        assert_eq!(attempts.len(), 1, "{attempts:?}");
        let a = &attempts[0];
        assert!(a.outcome == "injected" || a.outcome == "failed", "{a:?}");
        assert!(a.measured_dose_fraction.is_some(), "{a:?}");
        assert!(a.reason.contains("aborted by the test"), "{a:?}");
        assert_eq!(ran.db.run(Some(ran.run_id)).unwrap().status, "aborted");
        assert!(report.stopped.is_some());
        assert_eq!(ran.opened.rig.piezo[2].read_voltage().unwrap(), 0.0);
    }

    /// Says stop before the third cell (what the dashboard's observer says when the
    /// operator aborts between two cells).
    struct AbortBetweenCells(usize);

    impl Observer for AbortBetweenCells {
        fn finished(&mut self, _: &Attempt) -> Result<(), String> {
            self.0 += 1;
            Ok(())
        }
        fn proceed(&mut self) -> Result<(), String> {
            if self.0 >= 2 {
                return Err("aborted by the test".into());
            }
            Ok(())
        }
    }

    /// An abort between two cells: no cell is in progress, so the attempts recorded are
    /// the two complete ones with their own outcomes and reasons; the run is recorded
    /// aborted with the abort as why it stopped, and A3 ends at 0 V.
    #[test]
    fn an_abort_between_cells_leaves_the_done_cells_as_they_were() {
        let stop = Arc::new(AtomicBool::new(false));
        let mut obs = AbortBetweenCells(0);
        let mut ran = run_on_twin("between", stop, &mut obs);
        assert!(
            ran.stopped
                .as_ref()
                .is_some_and(|s| s.contains("aborted by the test")),
            "{:?}",
            ran.stopped
        );
        let attempts = ran.db.attempts(ran.run_id).unwrap();
        assert_eq!(attempts.len(), 2, "{attempts:?}");
        for a in &attempts {
            assert_ne!(a.outcome, "interrupted", "{a:?}");
            assert!(a.t_end.is_some(), "{a:?}");
            assert!(!a.reason.contains("aborted"), "{a:?}");
        }
        let run = ran.db.run(Some(ran.run_id)).unwrap();
        assert_eq!(run.status, "aborted");
        assert!(
            run.stopped
                .as_ref()
                .is_some_and(|s| s.contains("aborted by the test")),
            "{run:?}"
        );
        assert_eq!(ran.opened.rig.piezo[2].read_voltage().unwrap(), 0.0);
    }

    /// Keeps the image map and the survey's cells, and stops the run there.
    struct StopAtSurvey(Arc<AtomicBool>, Option<ImageMap>, Vec<Target>);

    impl Observer for StopAtSurvey {
        fn mapped(&mut self, map: &ImageMap) {
            self.1 = Some(*map);
        }
        fn surveyed(&mut self, targets: &[Target]) -> Result<(), String> {
            self.2 = targets.to_vec();
            self.0.store(true, Ordering::SeqCst);
            Ok(())
        }
    }

    /// The live view of a bench without a renderer draws each cell the survey found
    /// where the workflow's image-to-stage map puts its stage position
    /// (`view_geometry`); on the twin, that is where the twin's camera truly images
    /// the cell's centre (its grid and the cell's true centre), to within a pixel, in a
    /// tracking window and in a binned full frame.
    #[test]
    fn the_view_geometry_from_the_image_map_puts_cells_on_the_twins_cells() {
        let stop = Arc::new(AtomicBool::new(false));
        let mut obs = StopAtSurvey(stop.clone(), None, Vec::new());
        let mut ran = run_on_twin("geometry", stop, &mut obs);
        let map = obs.1.expect("the workflow mapped the image");
        assert!(obs.2.len() > 80, "{} cells found", obs.2.len());
        let twin = ran.opened.twin.clone().unwrap();
        let truth: Vec<[f64; 2]> = obs
            .2
            .iter()
            .map(|c| nearest_cell(&twin, c.stage_m).unwrap().centre)
            .collect();
        let cam = &mut ran.opened.rig.camera;
        let (sw, sh) = cam.sensor_size();
        let full = cam.settings();
        // A tracking window as the workflow reads it, and the whole sensor binned 2 x 2
        // by the camera (and again for the view, as the dashboard's downscale does).
        for settings in [
            CameraSettings {
                roi: Roi {
                    x: 700,
                    y: 500,
                    width: 640,
                    height: 480,
                },
                binning: 1,
                ..full
            },
            CameraSettings {
                roi: Roi {
                    x: 0,
                    y: 0,
                    width: sw,
                    height: sh,
                },
                binning: 2,
                ..full
            },
        ] {
            cam.configure(settings).unwrap();
            let frame = cam.grab().unwrap();
            let k = frame.width.div_ceil(640);
            let g = twin.lock().unwrap().camera.grid();
            let a =
                cellinject_dashboard::view_geometry(&map, &settings, frame.pixel_size, k).unwrap();
            let view_pitch = g.pitch * k as f64;
            // In sensor pixels: the worst cell and the mean offset (a bias).
            let sensor = (settings.binning * k) as f64;
            let (mut worst, mut bias) = (0.0f64, [0.0; 2]);
            for (c, w) in obs.2.iter().zip(&truth) {
                let [x, z] = c.stage_m;
                let got = [
                    a[0][0] * x + a[0][1] * z + a[0][2],
                    a[1][0] * x + a[1][1] * z + a[1][2],
                ];
                // The true centre in the view: output pixel (0, 0)'s centre is at
                // (x0, z0), its outer edge half a pitch before.
                let want = [
                    (w[0] - g.x0 + 0.5 * g.pitch) / view_pitch,
                    (w[1] - g.z0 + 0.5 * g.pitch) / view_pitch,
                ];
                let d = [(got[0] - want[0]) * sensor, (got[1] - want[1]) * sensor];
                worst = worst.max(d[0].hypot(d[1]));
                bias = [bias[0] + d[0], bias[1] + d[1]];
            }
            let n = obs.2.len() as f64;
            let bias = (bias[0] / n).hypot(bias[1] / n);
            assert!(worst < 1.0, "{settings:?} / {k}: {worst:.2} sensor px off");
            assert!(
                bias < 0.25,
                "{settings:?} / {k}: mean offset {bias:.2} sensor px"
            );
        }
        // Another zoom: not the map's scale, no geometry.
        let settings = CameraSettings {
            binning: 1,
            ..cam.settings()
        };
        assert!(
            cellinject_dashboard::view_geometry(&map, &settings, 2.0 * map.pixel_size, 1).is_none()
        );
    }
}
