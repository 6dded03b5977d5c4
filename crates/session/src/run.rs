//! A run's lifecycle, the same for every front end (`cellinject run`, the dashboard's
//! runs, Python's `cellinject.twin.run`): [`run`] opens the run database, creates the
//! run's record or checks a resume against the recorded one (its plate, seed and
//! bench), puts the plate under the twin's microscope, executes the workflow
//! ([`cellinject_run_sim::execute`]), discards a new run whose input the workflow
//! refused, and sums the run up ([`cellinject_run_sim::summary`]). Front ends read
//! their arguments, call [`run`], and print what it returns.
//!
//! **Architecture invariant:** no front end creates, resumes or discards a run
//! record itself; the rules of [`Begin::Resume`] live here only.

use std::path::Path;

use cellinject_config::Description;
use cellinject_config::rigfile::RigFile;
use cellinject_core::calibrate::HysteresisCalibration;
use cellinject_core::inject::{Observer, Options, Session};
use cellinject_plate::Plate;
use cellinject_records::{Records, RecordsError};
use cellinject_run_sim::{Outcome, RunError, RunProgress, Summary};
use cellinject_twin::{Fault, FaultAt};
use thiserror::Error;

use crate::{Opened, SessionError, TwinOptions};

/// How a run begins.
#[derive(Debug, Clone)]
pub enum Begin {
    /// A new run record.
    New {
        /// The plate under the microscope.
        plate: Plate,
        /// Its text, as the record keeps it.
        text: String,
        /// The twin's seed (not recorded for another bench).
        seed: u64,
        /// Faults on the twin's cells (checked against `plate` by the caller).
        faults: Vec<Fault>,
        /// What the record's settings say of the run (options, faults as written,
        /// the front end).
        settings: serde_json::Value,
    },
    /// The database's latest run, continued where it stopped. What the caller was
    /// given is checked against the record: a resume takes its plate, seed and bench
    /// from the database and refuses others.
    Resume {
        /// The plate's text, if one was given.
        plate: Option<String>,
        /// The seed, if one was given.
        seed: Option<u64>,
        /// Faults as written (`KIND@ROW,COL[,K]`) and parsed, resolved on the run's
        /// own plate.
        faults: Vec<(String, FaultAt)>,
    },
}

/// The bench a run drives.
pub enum Bench<'a> {
    /// The twin, built when the run begins for its seed (a resume's from the record):
    /// by the function given (a front end showing progress while J3's check runs),
    /// else by [`crate::open`] on the description's twin.
    Twin(Option<&'a dyn Fn(u64) -> Result<Opened, SessionError>>),
    /// A bench already open: a controller opened before the database (one that
    /// cannot be reached leaves no run behind), or the dashboard's, kept from run to
    /// run. Its twin, if it has one, gets the run's plate.
    Opened(&'a mut Opened),
}

/// One run: what [`run`] needs besides the bench.
pub struct Request<'a> {
    /// The description (design and bench).
    pub d: &'a Description,
    /// The run database (created when missing; a new one is removed again when the
    /// run's input is refused).
    pub db: &'a Path,
    /// The workflow's options (checked by the caller against the description).
    pub options: Options,
    /// A hysteresis calibration to use (else the stacks are identified).
    pub hysteresis: Option<HysteresisCalibration>,
    /// What an earlier run of the same session found of the resting tip.
    pub session: Option<Session>,
    /// New or resumed.
    pub begin: Begin,
    /// Say every transition and each cell's truth on standard error.
    pub debug: bool,
}

/// Whether `CELLINJECT_DEBUG` is set: the switch for [`Request::debug`] the
/// command line and the dashboard honour (every transition and each cell's truth on
/// standard error).
pub fn debug_requested() -> bool {
    std::env::var_os("CELLINJECT_DEBUG").is_some()
}

/// What a front end sees of a run besides its records.
pub struct Hooks<'a> {
    /// Told how many cells the survey left, and of each attempt's end.
    pub progress: Option<&'a mut dyn RunProgress>,
    /// A second observer of the workflow (the dashboard).
    pub watch: Option<&'a mut dyn Observer>,
    /// Asked between steps whether the operator stopped the run.
    pub aborted: &'a dyn Fn() -> bool,
    /// Called once the twin holds the run's plate (the dashboard renews its view).
    pub plate_loaded: Option<&'a dyn Fn()>,
    /// Called when a resume retries or closes unfinished attempts: (run, retried,
    /// recorded interrupted).
    pub resumed: Option<&'a dyn Fn(i64, usize, usize)>,
}

impl Default for Hooks<'_> {
    fn default() -> Self {
        Hooks {
            progress: None,
            watch: None,
            aborted: &|| false,
            plate_loaded: None,
            resumed: None,
        }
    }
}

/// How [`run`] ended, the workflow having run or not.
pub enum Ended {
    /// The workflow ran (to its end, or stopped, or aborted: `stopped` says why).
    Ran {
        /// The run's record.
        run_id: i64,
        /// The run as `cellinject run --format json` prints it.
        summary: Summary,
        /// What the workflow returned (boxed: a run's report is large).
        outcome: Box<Outcome>,
        /// Why the run stopped, if it did.
        stopped: Option<String>,
    },
    /// A resume of a run that had finished: nothing ran.
    AlreadyFinished {
        /// The run's record.
        run_id: i64,
        /// The run as recorded.
        summary: Summary,
    },
}

/// Why a run could not be started or recorded. Every variant but `Records` with an
/// SQL failure and `Bench` with a device failure is the caller's input.
#[derive(Debug, Error)]
pub enum RunFailure {
    /// The workflow refused its input (the plate's plan, the options): a new run
    /// leaves no record.
    #[error("{0}")]
    Input(String),
    /// The plate given to a resume is not the run's.
    #[error("the plate given is not the plate of run {run} (resume takes it from the database)")]
    ResumePlate {
        /// The run.
        run: i64,
    },
    /// The seed given to a resume is not the run's.
    #[error(
        "seed {given} is not run {run}'s seed {recorded:?} (resume takes it from the database)"
    )]
    ResumeSeed {
        /// Given.
        given: u64,
        /// The run.
        run: i64,
        /// The run's (none on a bench without a twin).
        recorded: Option<u64>,
    },
    /// A resume on another bench.
    #[error("this bench ({bench}) is not run {run}'s ({recorded}): resume on the same hardware")]
    ResumeBench {
        /// This bench's name.
        bench: String,
        /// The run.
        run: i64,
        /// The run's bench.
        recorded: String,
    },
    /// A fault names a well or cell the plate does not have, or the twin refused it.
    #[error("fault `{spec}`: {reason}")]
    Fault {
        /// The fault as written.
        spec: String,
        /// Why.
        reason: String,
    },
    /// The twin refused the run's faults.
    #[error("fault: {0}")]
    TwinFault(String),
    /// The recorded plate no longer parses or checks.
    #[error("the run's plate: {0}")]
    RecordedPlate(String),
    /// The twin could not be built.
    #[error(transparent)]
    Bench(SessionError),
    /// The run database failed (or is not one).
    #[error(transparent)]
    Records(RecordsError),
}

impl From<RecordsError> for RunFailure {
    fn from(e: RecordsError) -> Self {
        RunFailure::Records(e)
    }
}

impl From<RunError> for RunFailure {
    fn from(e: RunError) -> Self {
        match e {
            RunError::Input(s) => RunFailure::Input(s),
            RunError::Fault(s) => RunFailure::TwinFault(s),
            RunError::Records(e) => RunFailure::Records(e),
        }
    }
}

/// The record [`run`] works on, once created or checked.
struct Record {
    run_id: i64,
    /// The plate: the caller's for a new run, the recorded one, parsed and checked,
    /// for a resume.
    plate: Plate,
    seed: u64,
    previous: Vec<cellinject_records::AttemptRow>,
    base: (f64, f64),
    faults: Vec<Fault>,
    new: bool,
}

/// The resume rules: the database's latest run, given `plate`, `seed` and faults
/// checked against it on bench `bench`; `Err(Ok(summary))` when it has finished.
fn resume(
    d: &Description,
    db: &mut Records,
    bench: &str,
    plate: Option<&str>,
    seed: Option<u64>,
    faults: &[(String, FaultAt)],
    resumed: Option<&dyn Fn(i64, usize, usize)>,
) -> Result<Result<Record, (i64, Summary)>, RunFailure> {
    let r = db.run(None)?;
    if plate.is_some_and(|text| text != r.plate) {
        return Err(RunFailure::ResumePlate { run: r.id });
    }
    if let Some(s) = seed
        && Some(s) != r.seed
    {
        return Err(RunFailure::ResumeSeed {
            given: s,
            run: r.id,
            recorded: r.seed,
        });
    }
    if r.backend != bench {
        return Err(RunFailure::ResumeBench {
            bench: bench.to_string(),
            run: r.id,
            recorded: r.backend.clone(),
        });
    }
    if r.status == "finished" {
        let attempts = db.attempts(r.id)?;
        let events = db.events(r.id)?;
        return Ok(Err((
            r.id,
            cellinject_run_sim::summary(&r, attempts, events),
        )));
    }
    // The faults act on the run's own plate (checked before the records change).
    let resolved = match cellinject_config::plate::parse(&r.plate) {
        Ok(p) => resolve_faults(faults, &p)?,
        Err(_) => Vec::new(), // refused below, naming the run's plate
    };
    let (dropped, interrupted) = db.prepare_resume(r.id)?;
    if dropped + interrupted > 0
        && let Some(f) = resumed
    {
        f(r.id, dropped, interrupted);
    }
    let previous = db.attempts(r.id)?;
    let recorded = |e: &dyn std::fmt::Display| RunFailure::RecordedPlate(e.to_string());
    let plate = cellinject_config::plate::parse(&r.plate).map_err(|e| recorded(&e))?;
    plate.check().map_err(|e| recorded(&e))?;
    Ok(Ok(Record {
        run_id: r.id,
        plate,
        seed: r.seed.unwrap_or(d.sim.seed),
        previous,
        base: (r.sim_time_s, r.cell_time_s),
        faults: resolved,
        new: false,
    }))
}

/// `faults` (as written, and parsed) on `plate`'s cells; a well or cell the plate
/// does not have is refused, naming the fault.
pub fn resolve_faults(
    faults: &[(String, FaultAt)],
    plate: &Plate,
) -> Result<Vec<Fault>, RunFailure> {
    faults
        .iter()
        .map(|(s, f)| {
            f.resolve(plate).map_err(|e| RunFailure::Fault {
                spec: s.clone(),
                reason: e
                    .to_string()
                    .trim_start_matches("key `fault`: ")
                    .to_string(),
            })
        })
        .collect()
}

/// Runs the injection workflow on `bench` as `req` says, recording it in `req.db`:
/// the one lifecycle of a run for every front end. A new run whose input the
/// workflow refuses leaves no record (nor the database file, if this call created
/// it); a resume follows the rules of [`Begin::Resume`].
pub fn run<'a>(req: Request<'a>, bench: Bench<'_>, hooks: Hooks<'a>) -> Result<Ended, RunFailure> {
    let Request {
        d,
        db: path,
        options,
        hysteresis,
        session,
        begin,
        debug,
    } = req;
    let Hooks {
        progress,
        watch,
        aborted,
        plate_loaded,
        resumed,
    } = hooks;
    let name = match &bench {
        Bench::Twin(_) => "twin".to_string(),
        Bench::Opened(o) => o.name.clone(),
    };
    let existed = path.exists();
    let mut db = Records::open(path)?;
    let record = match begin {
        Begin::Resume {
            plate,
            seed,
            faults,
        } => match resume(d, &mut db, &name, plate.as_deref(), seed, &faults, resumed)? {
            Ok(r) => r,
            Err((run_id, summary)) => return Ok(Ended::AlreadyFinished { run_id, summary }),
        },
        Begin::New {
            plate,
            text,
            seed,
            faults,
            settings,
        } => {
            let twin_seed = (name == "twin").then_some(seed);
            let run_id = cellinject_run_sim::new_run(&mut db, &text, twin_seed, &name, &settings)?;
            Record {
                run_id,
                plate,
                seed,
                previous: Vec::new(),
                base: (0.0, 0.0),
                faults,
                new: true,
            }
        }
    };
    let plate = record.plate.clone();
    let mut built;
    let opened: &mut Opened = match bench {
        Bench::Opened(o) => o,
        Bench::Twin(open) => {
            built = match open {
                Some(open) => open(record.seed),
                None => crate::open(
                    d,
                    &RigFile::twin(),
                    TwinOptions {
                        approach: None,
                        seed: Some(record.seed),
                    },
                ),
            }
            .map_err(RunFailure::Bench)?;
            &mut built
        }
    };
    if let Some(twin) = &opened.twin {
        cellinject_run_sim::prepare_twin(twin, &plate, &record.faults, &options)?;
        if let Some(f) = plate_loaded {
            f();
        }
    }
    let truth = opened.twin.clone();
    let job = cellinject_run_sim::Job {
        d,
        options,
        hysteresis,
        session,
        twin: opened.twin.clone(),
        plate: plate.clone(),
        run_id: record.run_id,
        previous: record.previous,
        base: record.base,
        progress,
        debug,
    };
    let (outcome, stopped) =
        cellinject_run_sim::execute(job, &mut db, &mut opened.rig, watch, aborted)?;
    let run_id = record.run_id;
    if let Err(e) = &outcome
        && cellinject_run_sim::refused_input(e)
    {
        // Bad input leaves no record: a new run refused before any cell goes, and
        // the database file if this call created it.
        if record.new {
            cellinject_run_sim::discard(db, run_id, path, existed)?;
        }
        return Err(RunFailure::Input(e.to_string()));
    }
    let r = db.run(Some(run_id))?;
    let mut summary = cellinject_run_sim::summary(&r, db.attempts(run_id)?, db.events(run_id)?);
    if let Ok((report, _)) = &outcome {
        summary = cellinject_run_sim::with_report(summary, report, truth.as_ref(), &plate);
    }
    Ok(Ended::Ran {
        run_id,
        summary,
        outcome: Box::new(outcome),
        stopped,
    })
}
