//! The injection workflow run and recorded, the same for every front end (the CLI's
//! `run` and `serve`, Python's `cellinject.twin.run`): [`execute`] runs a
//! [`cellinject_core::inject::Workflow`] on a rig and records every attempt and
//! transition in the run database, with the twin's truth (tip
//! error, dose, grazed cells) when the backend is the twin; [`summary`] is the run's
//! JSON (`cellinject run --format json`, docs/json.md); [`default_plate`] the plate a
//! run injects when given none.
//!
//! Its name says it simulates: it reads the twin's truth, so by ARCHITECTURE.md's
//! dependency rule it may depend on `cellinject-twin` (and nothing but front ends
//! depends on it).

use cellinject_config::Description;
use cellinject_core::calibrate::HysteresisCalibration;
use cellinject_core::inject::{Attempt, ImageMap, Observer, Options, Target, Transition, Workflow};
use cellinject_plate::{GenerateOptions, Plate, PlateError, generate};
use cellinject_records::{AttemptRow, EventRow, Records, RecordsError, RunRow};
use cellinject_twin::{Fault, SharedTwin};
use serde::Serialize;
use std::fmt::Write as _;

/// Why a run could not be executed (before or after the workflow: the workflow's own
/// failures are in its [`Outcome`]).
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The workflow refused its inputs (plate, options) before anything moved.
    #[error("{0}")]
    Input(String),
    /// The run database failed.
    #[error(transparent)]
    Records(RecordsError),
    /// The twin refused the run's faults.
    #[error("fault: {0}")]
    Fault(String),
}

/// What a front end shows of a run in progress (a progress bar).
pub trait RunProgress {
    /// The survey is done: `left` cells to attempt.
    fn surveyed(&mut self, left: u64);
    /// An attempt ended.
    fn attempt_done(&mut self);
}

/// Puts `plate` under the twin's microscope with `faults` on its cells, and lifts the
/// pipette above it (the macro stage's start of a run).
pub fn prepare_twin(
    twin: &SharedTwin,
    plate: &Plate,
    faults: &[Fault],
    options: &Options,
) -> Result<(), RunError> {
    let mut t = twin.lock().unwrap_or_else(|e| e.into_inner());
    t.load_plate(plate);
    t.set_faults(faults)
        .map_err(|e| RunError::Fault(e.to_string()))?;
    // The macro stage starts with the pipette lifted above the plate.
    t.world.stage.place(1, options.focus + options.lift);
    Ok(())
}

/// Whether a workflow's failure is the user's input (the plate's plan, a pitch larger
/// than the view): then a new run leaves no record ([`discard`]).
pub fn refused_input(e: &cellinject_core::inject::WorkflowError) -> bool {
    matches!(
        e,
        cellinject_core::inject::WorkflowError::Plan(_)
            | cellinject_core::inject::WorkflowError::PitchTooLarge { .. }
    )
}

/// Bad input leaves no record: the new run `run_id` refused before any cell goes is
/// discarded, and so is the database file at `path` if this command created it
/// (`existed` false).
pub fn discard(
    mut db: Records,
    run_id: i64,
    path: &std::path::Path,
    existed: bool,
) -> Result<(), RecordsError> {
    db.discard_run(run_id)?;
    if !existed {
        drop(db);
        for suffix in ["", "-wal", "-shm"] {
            let mut p = path.to_path_buf().into_os_string();
            p.push(suffix);
            let _ = std::fs::remove_file(p);
        }
    }
    Ok(())
}

/// The run's summary with what only this command saw: the cells the glass grazed and
/// the fields' planes of focus (with the twin's truth of them when `twin` is given).
pub fn with_report(
    mut s: Summary,
    report: &cellinject_core::inject::RunReport,
    twin: Option<&SharedTwin>,
    plate: &Plate,
) -> Summary {
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
            true_error_m: twin.map(|t| focus_error(t, plate, f)),
        })
        .collect();
    s
}

/// The default plate: 8 x 12 wells of 150 um centred in the 2.5x field of view.
pub fn default_plate(seed: u64) -> Result<Plate, PlateError> {
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
}

/// What `run` prints as JSON.
#[derive(Debug, Serialize)]
pub struct Summary {
    /// Run id in the database.
    pub run: i64,
    /// `finished`, `stopped` (a fault) or `aborted` (the operator).
    pub status: String,
    /// `twin` or the controller's address (`gcs://...`).
    pub backend: String,
    /// Cells the survey found.
    pub cells_found: i64,
    /// Attempts injected.
    pub injected: usize,
    /// Attempts failed.
    pub failed: usize,
    /// Cells skipped.
    pub skipped: usize,
    /// Attempts interrupted.
    pub interrupted: usize,
    /// s of device time, calibration included, all segments.
    pub sim_time_s: f64,
    /// s of device time from the first cell to the last.
    pub cell_time_s: f64,
    /// Attempts per minute of `cell_time_s`.
    pub cells_per_min: f64,
    /// Why the run stopped (None: it finished).
    pub stopped: Option<String>,
    /// One per cell attempt, in order.
    pub attempts: Vec<AttemptRow>,
    /// The run's own transitions: calibration, survey, re-checks, the end.
    pub events: Vec<EventRow>,
    /// Other cells the pipette's glass ran into during this command's attempts (the
    /// twin's truth; absent on hardware and from `runs show`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub grazed: Option<u32>,
    /// The fields' planes of best focus this command measured (absent from `runs
    /// show`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub focus: Vec<FocusRow>,
}

impl Summary {
    /// `cellinject run`'s summary: what became of the cells, the time and rate, the tip's
    /// error at injection (the twin's truth, else as the camera measured it), the focus
    /// over the fields, the rechecks, each cell not injected and why, and why the run
    /// stopped.
    pub fn text(&self) -> String {
        let s = self;
        let mut out = String::new();
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
        let _ = writeln!(
            out,
            "run {} {}: {} cell{} found, {} injected, {} failed, {} skipped, {} interrupted",
            s.run,
            s.status,
            s.cells_found,
            if s.cells_found == 1 { "" } else { "s" },
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
        let _ = writeln!(
            out,
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
                let _ = writeln!(out, "the pipette's glass touched no cell but its targets");
            } else {
                let _ = writeln!(out, "the pipette's glass ran into {g} other cells");
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
            let _ = writeln!(
                out,
                "{} focused ({} focus frames), the floor sloping {slope} µm/mm{}",
                if swept.len() == 1 {
                    "1 field".to_string()
                } else {
                    format!("{} fields", swept.len())
                },
                swept.iter().map(|f| f.focus.frames).sum::<usize>(),
                worst.map_or(String::new(), |w| format!(
                    "; the floor under the cells at most {:.2} µm from where the focus put it",
                    w * 1e6
                ))
            );
        }
        for e in s
            .events
            .iter()
            .filter(|e| e.event == "recheck" || e.event == "rechecked")
        {
            let _ = writeln!(out, "  {:.0} s: {}", e.t, e.reason);
        }
        for a in s.attempts.iter().filter(|a| a.outcome != "injected") {
            let _ = writeln!(
                out,
                "  cell {} well [{}, {}]: {}: {}",
                a.cell, a.well[0], a.well[1], a.outcome, a.reason
            );
        }
        if let Some(w) = &s.stopped {
            let _ = writeln!(out, "stopped: {w}");
        }
        out.pop();
        out
    }
}

/// A field's focus as measured, and on the twin how far it is from the truth.
#[derive(Debug, Serialize)]
pub struct FocusRow {
    /// The plane as measured.
    #[serde(flatten)]
    pub focus: cellinject_core::inject::FieldFocus,
    /// m, the twin's truth: the largest distance over the field's cells between the
    /// floor's height the plane puts under them and its true height.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub true_error_m: Option<f64>,
}

/// The summary of a run as recorded (`run --format json`; `grazed` and `focus` empty:
/// [`with_report`] adds them).
pub fn summary(run: &RunRow, attempts: Vec<AttemptRow>, events: Vec<EventRow>) -> Summary {
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
struct Recorder<'a, 'p> {
    /// The twin, when it is the backend (else no truth).
    twin: Option<SharedTwin>,
    plate: Plate,
    db: &'a mut Records,
    run: i64,
    current: Option<i64>,
    previous: Vec<AttemptRow>,
    progress: Option<&'p mut dyn RunProgress>,
    debug: bool,
}

impl Recorder<'_, '_> {
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

impl Observer for Recorder<'_, '_> {
    fn transition(&mut self, t: &Transition) {
        if self.debug {
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
                "{:?} -> {:?}: {} [true tip {:.2}, {:.2} µm, depth {:.2} µm; floor strikes {strikes}, tip lost {:.1} µm, grazed {grazed}]",
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
        let left = targets.iter().filter(|t| !self.done(t)).count();
        if let Some(p) = self.progress.as_mut() {
            p.surveyed(left as u64);
        }
        // Live counts for readers of the records (the dashboard's list of runs).
        self.db
            .set_progress(self.run, Some(targets.len() as i64), None)
            .map_err(|e| e.to_string())
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
        self.db
            .set_progress(self.run, None, Some(row.t_end.unwrap_or(row.t_start)))
            .map_err(|e| e.to_string())?;
        if let Some(p) = self.progress.as_mut() {
            p.attempt_done();
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
        if self.debug {
            eprintln!(
                "tip - cell: ({:.2}, {:.2}) µm; target ({:.2}, {:.2}) µm vs true ({:.2}, {:.2})",
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
        if self.debug {
            eprintln!(
                "cell {}: punctures {}, max depth {:.2} µm of r {:.2}, inside x {:.2} µm, dead {:?}",
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
pub struct Job<'a> {
    /// The description (the design and the bench).
    pub d: &'a Description,
    /// The workflow's options.
    pub options: Options,
    /// A hysteresis calibration to use (else the stacks are identified).
    pub hysteresis: Option<HysteresisCalibration>,
    /// What the session's first run found of the resting tip (its
    /// [`cellinject_core::inject::RunReport::session`]): a later run of the same
    /// session refers its focus to it. `None`: the run's own start.
    pub session: Option<cellinject_core::inject::Session>,
    /// The twin, when it is the backend (its truth goes into the records).
    pub twin: Option<SharedTwin>,
    /// The plate.
    pub plate: Plate,
    /// The run's record.
    pub run_id: i64,
    /// Attempts already recorded (a resumed run).
    pub previous: Vec<AttemptRow>,
    /// Device time of earlier segments (a resumed run): whole run, cells.
    pub base: (f64, f64),
    /// Told how many cells the survey left and of each attempt's end (a progress
    /// bar).
    pub progress: Option<&'a mut dyn RunProgress>,
    /// Say every transition and each cell's truth on standard error (the command line
    /// and the dashboard set it from `CELLINJECT_DEBUG`:
    /// `cellinject_session::run::debug_requested`).
    pub debug: bool,
}

/// The twin's cell whose true centre is nearest to stage point `p` (m).
pub fn nearest_cell(twin: &SharedTwin, p: [f64; 2]) -> Option<cellinject_twin::CellState> {
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
struct Tee<'a, 'p, 'b> {
    rec: Recorder<'a, 'p>,
    extra: Option<&'b mut dyn Observer>,
}

impl Observer for Tee<'_, '_, '_> {
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
pub type Outcome = Result<
    (cellinject_core::inject::RunReport, HysteresisCalibration),
    cellinject_core::inject::WorkflowError,
>;

/// Runs `job` on `rig`, recording every attempt in `db` and the run's end: `finished`,
/// `stopped`, or `aborted` when `aborted()` says the operator stopped it. Returns the
/// workflow's result and why the run stopped, if it did.
pub fn execute(
    job: Job<'_>,
    db: &mut Records,
    rig: &mut cellinject_rig::Rig<cellinject_rig::DynBackend>,
    extra: Option<&mut dyn Observer>,
    aborted: &dyn Fn() -> bool,
) -> Result<(Outcome, Option<String>), RunError> {
    let Job {
        d,
        options,
        hysteresis,
        session,
        twin,
        plate,
        run_id,
        previous,
        base,
        progress,
        debug,
    } = job;
    let mut tee = Tee {
        rec: Recorder {
            twin,
            plate: plate.clone(),
            db,
            run: run_id,
            current: None,
            previous,
            progress,
            debug,
        },
        extra,
    };
    let wf = Workflow::new(rig, &d.design, &d.rig, &plate, options)
        .map_err(|e| RunError::Input(e.to_string()))?
        .with_session(session);
    let result = wf.run(hysteresis, &mut tee);
    let rec = tee.rec;
    let (status, stopped, sim, cell, found) = match &result {
        Ok((r, cal)) => {
            rec.db
                .set_calibration(
                    run_id,
                    &serde_json::json!({
                        "hysteresis": cal,
                        "map": r.map,
                        "rest_m": r.rest_m,
                        "focus_by": r.focus_by,
                        "tip_above_m": r.tip_above_m,
                        "tip_blur_px": r.tip_blur_px,
                        "focus_m": r.focus_m,
                        "hysteresis_check": r.hysteresis_check,
                    }),
                )
                .map_err(RunError::Records)?;
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
        .map_err(RunError::Records)?;
    Ok((result, stopped))
}

/// `run`'s default plate for `seed` and its text as the run records keep it.
pub fn default_plate_text(seed: u64) -> Result<(Plate, String), PlateError> {
    let plate = default_plate(seed)?;
    let text = cellinject_config::plate::to_toml(
        &plate,
        &format!("cellinject run's default plate: 8 x 12 wells, seed {seed}"),
    );
    Ok((plate, text))
}

/// A new run record for `plate_text`, created now.
pub fn new_run(
    db: &mut Records,
    plate_text: &str,
    seed: Option<u64>,
    backend: &str,
    settings: &serde_json::Value,
) -> Result<i64, RecordsError> {
    let created = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0);
    db.create_run(plate_text, seed, backend, settings, created)
}

/// m, the largest distance over the cells of field `f` (the plate's true cells in
/// its rectangle; its centre if it holds none) between the floor's height its plane of
/// focus gives and the twin's truth, the feeder at the plane's height.
pub fn focus_error(
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
