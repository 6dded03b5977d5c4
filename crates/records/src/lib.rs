//! # cellinject-records
//!
//! The injection workflow's run records in an embedded SQLite database (rusqlite with
//! its bundled SQLite): a `runs` table (plate, seed, settings, calibration, status), an
//! `attempts` table, one row per cell attempt, and an `events` table, one row per
//! transition of the run outside the cells (calibrated, surveyed, each re-check of the
//! calibrations and its verdict, the end). Every write is its own transaction
//! in WAL mode with `synchronous = FULL`, so a killed process loses at most the attempt
//! in progress; an attempt is first written `started`, marked `contact` when the
//! pipette may touch the cell, and completed with its outcome. On resume, `started`
//! rows are dropped (the cell is retried) and `contact` rows become `interrupted`
//! (never injected again).
//!
//! The database identifies itself by SQLite's `application_id` and carries its schema
//! version in `user_version`: a database from another program, or from a newer
//! cellinject, is refused and never written.
//!
//! **Architecture invariant:** the only crate that touches SQLite; it stores what it is
//! given (JSON text for nested values) and computes nothing.

use std::path::Path;

use rusqlite::{Connection, OptionalExtension, params};
use serde::Serialize;
use thiserror::Error;

/// `application_id` of a cellinject database: "CIJR".
pub const APPLICATION_ID: i32 = 0x4349_4A52;
/// Schema version written by this build (2 added `events`; a version-1 database is
/// upgraded in place when opened).
pub const SCHEMA_VERSION: i32 = 2;

/// Why the records failed.
#[derive(Debug, Error)]
pub enum RecordsError {
    /// The file is an SQLite database of another program.
    #[error(
        "{path}: not a cellinject run database (application id {found:#x}, tables {tables}): refusing to touch it"
    )]
    Foreign {
        /// File.
        path: String,
        /// Its application id.
        found: i32,
        /// Its tables.
        tables: String,
    },
    /// Written by a newer cellinject.
    #[error(
        "{path}: schema version {found} is newer than this cellinject's {SCHEMA_VERSION}: upgrade cellinject to read it"
    )]
    Newer {
        /// File.
        path: String,
        /// Its version.
        found: i32,
    },
    /// The file is not a database at all, or is damaged.
    #[error("{path}: {message}")]
    Unreadable {
        /// File.
        path: String,
        /// SQLite's message.
        message: String,
    },
    /// The database to read does not exist ([`Records::open_existing`]).
    #[error("{path}: no such file")]
    Missing {
        /// File.
        path: String,
    },
    /// No such run.
    #[error("no run {0} in the database")]
    NoRun(i64),
    /// The database holds no run.
    #[error("the database holds no run yet")]
    Empty,
    /// A run that touched cells cannot be discarded.
    #[error(
        "run {run} has {attempts} attempts: only a run that never touched a cell can be discarded"
    )]
    NotDiscardable {
        /// Run id.
        run: i64,
        /// Its attempts.
        attempts: usize,
    },
    /// Any other SQLite failure.
    #[error("run database: {0}")]
    Sql(#[from] rusqlite::Error),
}

/// A run's row.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunRow {
    /// Run id.
    pub id: i64,
    /// Seconds since the Unix epoch when it was created.
    pub created: i64,
    /// `running`, `finished`, `stopped` (on a fault) or `aborted` (by the operator).
    pub status: String,
    /// The plate file's text.
    #[serde(skip)]
    pub plate: String,
    /// Seed of the twin.
    pub seed: Option<u64>,
    /// Backend name.
    pub backend: String,
    /// Settings, JSON.
    pub settings: serde_json::Value,
    /// Calibration in force, JSON.
    pub calibration: serde_json::Value,
    /// s of device time so far (all segments).
    pub sim_time_s: f64,
    /// s of device time on cells.
    pub cell_time_s: f64,
    /// Cells the survey found.
    pub cells_found: i64,
    /// Why it stopped, if it did.
    pub stopped: Option<String>,
    /// Times it was resumed.
    pub resumed: i64,
}

/// An attempt's row.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AttemptRow {
    /// Attempt id.
    #[serde(skip)]
    pub id: i64,
    /// Survey index of the cell.
    pub cell: i64,
    /// [row, col].
    pub well: [u32; 2],
    /// m.
    pub x_m: f64,
    /// m.
    pub y_m: f64,
    /// m.
    pub diameter_m: f64,
    /// m (the twin's truth; null on hardware).
    pub tip_error_m: Option<f64>,
    /// m, as vision saw it.
    pub measured_tip_error_m: Option<f64>,
    /// m past the membrane.
    pub depth_m: Option<f64>,
    /// Dose fraction (truth where known, else measured).
    pub dose_fraction: Option<f64>,
    /// Dose fraction the dye showed.
    pub measured_dose_fraction: Option<f64>,
    /// The cell lives (truth).
    pub alive: Option<bool>,
    /// `injected`, `failed`, `skipped`, `interrupted`; `started` or `contact` while in
    /// progress.
    pub outcome: String,
    /// Why.
    pub reason: String,
    /// s, device time.
    pub t_start: f64,
    /// s.
    pub t_end: Option<f64>,
    /// The attempt's transitions, JSON.
    #[serde(skip)]
    pub transitions: serde_json::Value,
}

/// A transition of the run outside its cells (calibration, survey, a re-check, the
/// end): when, from which state by which event to which, and why.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EventRow {
    /// s, device time.
    pub t: f64,
    /// State before.
    pub from: String,
    /// Event.
    pub event: String,
    /// State after.
    pub to: String,
    /// Why, in words with the numbers.
    pub reason: String,
}

/// An open run database.
pub struct Records {
    conn: Connection,
}

const SCHEMA: &str = "
CREATE TABLE runs (
    id INTEGER PRIMARY KEY,
    created INTEGER NOT NULL,
    status TEXT NOT NULL,
    plate TEXT NOT NULL,
    seed INTEGER,
    backend TEXT NOT NULL,
    settings TEXT NOT NULL,
    calibration TEXT NOT NULL,
    sim_time_s REAL NOT NULL DEFAULT 0,
    cell_time_s REAL NOT NULL DEFAULT 0,
    cells_found INTEGER NOT NULL DEFAULT 0,
    stopped TEXT,
    resumed INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE attempts (
    id INTEGER PRIMARY KEY,
    run INTEGER NOT NULL REFERENCES runs(id),
    cell INTEGER NOT NULL,
    well_row INTEGER NOT NULL,
    well_col INTEGER NOT NULL,
    x_m REAL NOT NULL,
    y_m REAL NOT NULL,
    diameter_m REAL NOT NULL,
    tip_error_m REAL,
    measured_tip_error_m REAL,
    depth_m REAL,
    dose_fraction REAL,
    measured_dose_fraction REAL,
    alive INTEGER,
    outcome TEXT NOT NULL,
    reason TEXT NOT NULL,
    t_start REAL NOT NULL,
    t_end REAL,
    transitions TEXT NOT NULL
);
CREATE INDEX attempts_run ON attempts(run);
";

/// Version 2: the run's own transitions.
const EVENTS: &str = "
CREATE TABLE events (
    id INTEGER PRIMARY KEY,
    run INTEGER NOT NULL REFERENCES runs(id),
    t REAL NOT NULL,
    from_state TEXT NOT NULL,
    event TEXT NOT NULL,
    to_state TEXT NOT NULL,
    reason TEXT NOT NULL
);
CREATE INDEX events_run ON events(run);
";

fn unreadable(path: &Path, e: rusqlite::Error) -> RecordsError {
    RecordsError::Unreadable {
        path: path.display().to_string(),
        message: e.to_string(),
    }
}

impl Records {
    /// Opens the database at `path` to read it: [`Records::open`] of a file that
    /// exists ([`RecordsError::Missing`] otherwise: reading never creates one).
    pub fn open_existing(path: &Path) -> Result<Self, RecordsError> {
        if !path.exists() {
            return Err(RecordsError::Missing {
                path: path.display().to_string(),
            });
        }
        Records::open(path)
    }

    /// Opens (creating if needed) the database at `path`, refusing a foreign or newer
    /// one without writing to it.
    pub fn open(path: &Path) -> Result<Self, RecordsError> {
        let conn = Connection::open(path).map_err(|e| unreadable(path, e))?;
        let app: i32 = conn
            .pragma_query_value(None, "application_id", |r| r.get(0))
            .map_err(|e| unreadable(path, e))?;
        let version: i32 = conn
            .pragma_query_value(None, "user_version", |r| r.get(0))
            .map_err(|e| unreadable(path, e))?;
        let tables: Vec<String> = {
            let mut st = conn
                .prepare("SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name")
                .map_err(|e| unreadable(path, e))?;
            st.query_map([], |r| r.get(0))
                .map_err(|e| unreadable(path, e))?
                .collect::<Result<_, _>>()
                .map_err(|e| unreadable(path, e))?
        };
        if app != APPLICATION_ID {
            if app != 0 || !tables.is_empty() {
                return Err(RecordsError::Foreign {
                    path: path.display().to_string(),
                    found: app,
                    tables: if tables.is_empty() {
                        "none".into()
                    } else {
                        tables.join(", ")
                    },
                });
            }
            conn.execute_batch("PRAGMA journal_mode = WAL;")?;
            conn.execute_batch(&format!(
                "BEGIN; {SCHEMA} {EVENTS} PRAGMA application_id = {APPLICATION_ID}; PRAGMA user_version = {SCHEMA_VERSION}; COMMIT;"
            ))?;
        } else if version > SCHEMA_VERSION {
            return Err(RecordsError::Newer {
                path: path.display().to_string(),
                found: version,
            });
        } else if version < 2 {
            // One transaction: a killed upgrade leaves the version-1 database as it was.
            conn.execute_batch(&format!(
                "BEGIN; {EVENTS} PRAGMA user_version = {SCHEMA_VERSION}; COMMIT;"
            ))?;
        }
        conn.execute_batch(
            "PRAGMA journal_mode = WAL; PRAGMA synchronous = FULL; PRAGMA foreign_keys = ON;",
        )?;
        Ok(Records { conn })
    }

    /// Starts a run; returns its id.
    pub fn create_run(
        &mut self,
        plate: &str,
        seed: Option<u64>,
        backend: &str,
        settings: &serde_json::Value,
        created: i64,
    ) -> Result<i64, RecordsError> {
        self.conn.execute(
            "INSERT INTO runs (created, status, plate, seed, backend, settings, calibration) VALUES (?1, 'running', ?2, ?3, ?4, ?5, '{}')",
            params![created, plate, seed.map(|s| s as i64), backend, settings.to_string()],
        )?;
        Ok(self.conn.last_insert_rowid())
    }

    /// The run with id `id`, or the latest if `None`.
    pub fn run(&self, id: Option<i64>) -> Result<RunRow, RecordsError> {
        let sql = "SELECT id, created, status, plate, seed, backend, settings, calibration, sim_time_s, cell_time_s, cells_found, stopped, resumed FROM runs";
        let row = |r: &rusqlite::Row| -> rusqlite::Result<RunRow> {
            let settings: String = r.get(6)?;
            let calibration: String = r.get(7)?;
            Ok(RunRow {
                id: r.get(0)?,
                created: r.get(1)?,
                status: r.get(2)?,
                plate: r.get(3)?,
                seed: r.get::<_, Option<i64>>(4)?.map(|s| s as u64),
                backend: r.get(5)?,
                settings: serde_json::from_str(&settings).unwrap_or(serde_json::Value::Null),
                calibration: serde_json::from_str(&calibration).unwrap_or(serde_json::Value::Null),
                sim_time_s: r.get(8)?,
                cell_time_s: r.get(9)?,
                cells_found: r.get(10)?,
                stopped: r.get(11)?,
                resumed: r.get(12)?,
            })
        };
        let found = match id {
            Some(id) => self
                .conn
                .query_row(&format!("{sql} WHERE id = ?1"), [id], row)
                .optional()?,
            None => self
                .conn
                .query_row(&format!("{sql} ORDER BY id DESC LIMIT 1"), [], row)
                .optional()?,
        };
        found.ok_or(match id {
            Some(id) => RecordsError::NoRun(id),
            None => RecordsError::Empty,
        })
    }

    /// Every run, oldest first.
    pub fn runs(&self) -> Result<Vec<RunRow>, RecordsError> {
        let ids: Vec<i64> = {
            let mut st = self.conn.prepare("SELECT id FROM runs ORDER BY id")?;
            st.query_map([], |r| r.get(0))?.collect::<Result<_, _>>()?
        };
        ids.into_iter().map(|i| self.run(Some(i))).collect()
    }

    /// Records the calibration in force.
    pub fn set_calibration(
        &mut self,
        run: i64,
        cal: &serde_json::Value,
    ) -> Result<(), RecordsError> {
        self.conn.execute(
            "UPDATE runs SET calibration = ?2 WHERE id = ?1",
            params![run, cal.to_string()],
        )?;
        Ok(())
    }

    /// Updates the run's totals and status.
    pub fn update_run(
        &mut self,
        run: i64,
        status: &str,
        sim_time_s: f64,
        cell_time_s: f64,
        cells_found: i64,
        stopped: Option<&str>,
    ) -> Result<(), RecordsError> {
        self.conn.execute(
            "UPDATE runs SET status = ?2, sim_time_s = ?3, cell_time_s = ?4, cells_found = ?5, stopped = ?6 WHERE id = ?1",
            params![run, status, sim_time_s, cell_time_s, cells_found, stopped],
        )?;
        Ok(())
    }

    /// A run in progress: the cells its survey found (when given) and the device time
    /// it has reached, s (when given; the larger of it and the time already written),
    /// so that a reader, such as the dashboard's list of runs, sees live counts before
    /// [`Records::update_run`] writes the run's end.
    pub fn set_progress(
        &mut self,
        run: i64,
        cells_found: Option<i64>,
        sim_time_s: Option<f64>,
    ) -> Result<(), RecordsError> {
        self.conn.execute(
            "UPDATE runs SET cells_found = COALESCE(?2, cells_found), sim_time_s = MAX(sim_time_s, COALESCE(?3, sim_time_s)) WHERE id = ?1",
            params![run, cells_found, sim_time_s],
        )?;
        Ok(())
    }

    /// Removes a run that was refused before it touched any cell (its events with it),
    /// in one transaction: bad input leaves no record. Refused for a run with attempts.
    pub fn discard_run(&mut self, run: i64) -> Result<(), RecordsError> {
        let tx = self.conn.transaction()?;
        let attempts: i64 =
            tx.query_row("SELECT COUNT(*) FROM attempts WHERE run = ?1", [run], |r| {
                r.get(0)
            })?;
        if attempts > 0 {
            return Err(RecordsError::NotDiscardable {
                run,
                attempts: attempts as usize,
            });
        }
        tx.execute("DELETE FROM events WHERE run = ?1", [run])?;
        if tx.execute("DELETE FROM runs WHERE id = ?1", [run])? == 0 {
            return Err(RecordsError::NoRun(run));
        }
        tx.commit()?;
        Ok(())
    }

    /// Prepares a killed run for resuming, in one transaction: attempts that never
    /// reached the cell are dropped (retried), those that may have touched it become
    /// `interrupted`; the run counts one more resume. Returns (dropped, interrupted).
    pub fn prepare_resume(&mut self, run: i64) -> Result<(usize, usize), RecordsError> {
        let tx = self.conn.transaction()?;
        let dropped = tx.execute(
            "DELETE FROM attempts WHERE run = ?1 AND outcome = 'started'",
            [run],
        )?;
        let interrupted = tx.execute(
            "UPDATE attempts SET outcome = 'interrupted', reason = 'the process stopped after the pipette reached the cell; never injected again' WHERE run = ?1 AND outcome = 'contact'",
            [run],
        )?;
        tx.execute(
            "UPDATE runs SET resumed = resumed + 1, status = 'running' WHERE id = ?1",
            [run],
        )?;
        tx.commit()?;
        Ok((dropped, interrupted))
    }

    /// Writes an attempt (insert when `id` is `None`), in its own transaction;
    /// returns its id.
    pub fn write_attempt(
        &mut self,
        run: i64,
        id: Option<i64>,
        a: &AttemptRow,
    ) -> Result<i64, RecordsError> {
        let tx = self.conn.transaction()?;
        let values = params![
            run,
            a.cell,
            a.well[0],
            a.well[1],
            a.x_m,
            a.y_m,
            a.diameter_m,
            a.tip_error_m,
            a.measured_tip_error_m,
            a.depth_m,
            a.dose_fraction,
            a.measured_dose_fraction,
            a.alive,
            a.outcome,
            a.reason,
            a.t_start,
            a.t_end,
            a.transitions.to_string(),
        ];
        let id = match id {
            None => {
                tx.execute(
                    "INSERT INTO attempts (run, cell, well_row, well_col, x_m, y_m, diameter_m, tip_error_m, measured_tip_error_m, depth_m, dose_fraction, measured_dose_fraction, alive, outcome, reason, t_start, t_end, transitions) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17, ?18)",
                    values,
                )?;
                tx.last_insert_rowid()
            }
            Some(id) => {
                tx.execute(
                    "UPDATE attempts SET run = ?1, cell = ?2, well_row = ?3, well_col = ?4, x_m = ?5, y_m = ?6, diameter_m = ?7, tip_error_m = ?8, measured_tip_error_m = ?9, depth_m = ?10, dose_fraction = ?11, measured_dose_fraction = ?12, alive = ?13, outcome = ?14, reason = ?15, t_start = ?16, t_end = ?17, transitions = ?18 WHERE id = ?19",
                    rusqlite::params_from_iter(
                        values.iter().copied().chain(std::iter::once(&id as &dyn rusqlite::ToSql)),
                    ),
                )?;
                id
            }
        };
        tx.commit()?;
        Ok(id)
    }

    /// Records a transition of the run outside its cells, in its own transaction.
    pub fn write_event(&mut self, run: i64, e: &EventRow) -> Result<(), RecordsError> {
        self.conn.execute(
            "INSERT INTO events (run, t, from_state, event, to_state, reason) VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
            params![run, e.t, e.from, e.event, e.to, e.reason],
        )?;
        Ok(())
    }

    /// A run's own transitions in order.
    pub fn events(&self, run: i64) -> Result<Vec<EventRow>, RecordsError> {
        let mut st = self.conn.prepare(
            "SELECT t, from_state, event, to_state, reason FROM events WHERE run = ?1 ORDER BY id",
        )?;
        let rows = st.query_map([run], |r| {
            Ok(EventRow {
                t: r.get(0)?,
                from: r.get(1)?,
                event: r.get(2)?,
                to: r.get(3)?,
                reason: r.get(4)?,
            })
        })?;
        Ok(rows.collect::<Result<_, _>>()?)
    }

    /// A run's attempts in order.
    pub fn attempts(&self, run: i64) -> Result<Vec<AttemptRow>, RecordsError> {
        let mut st = self.conn.prepare(
            "SELECT id, cell, well_row, well_col, x_m, y_m, diameter_m, tip_error_m, measured_tip_error_m, depth_m, dose_fraction, measured_dose_fraction, alive, outcome, reason, t_start, t_end, transitions FROM attempts WHERE run = ?1 ORDER BY id",
        )?;
        let rows = st.query_map([run], |r| {
            let tr: String = r.get(17)?;
            Ok(AttemptRow {
                id: r.get(0)?,
                cell: r.get(1)?,
                well: [r.get(2)?, r.get(3)?],
                x_m: r.get(4)?,
                y_m: r.get(5)?,
                diameter_m: r.get(6)?,
                tip_error_m: r.get(7)?,
                measured_tip_error_m: r.get(8)?,
                depth_m: r.get(9)?,
                dose_fraction: r.get(10)?,
                measured_dose_fraction: r.get(11)?,
                alive: r.get(12)?,
                outcome: r.get(13)?,
                reason: r.get(14)?,
                t_start: r.get(15)?,
                t_end: r.get(16)?,
                transitions: serde_json::from_str(&tr).unwrap_or(serde_json::Value::Null),
            })
        })?;
        Ok(rows.collect::<Result<_, _>>()?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str) -> std::path::PathBuf {
        let d =
            std::env::temp_dir().join(format!("cellinject-records-{}-{name}", std::process::id()));
        let _ = std::fs::remove_file(&d);
        d
    }

    #[test]
    fn reading_a_database_that_does_not_exist_creates_none() {
        let p = tmp("missing.db");
        match Records::open_existing(&p) {
            Err(RecordsError::Missing { path }) => assert_eq!(path, p.display().to_string()),
            other => panic!("{:?}", other.map(|_| ())),
        }
        assert!(!p.exists(), "{} was created", p.display());
        Records::open(&p).unwrap();
        assert!(Records::open_existing(&p).is_ok());
        let _ = std::fs::remove_file(&p);
    }

    fn attempt(outcome: &str) -> AttemptRow {
        AttemptRow {
            id: 0,
            cell: 3,
            well: [1, 2],
            x_m: 1e-4,
            y_m: 2e-4,
            diameter_m: 1.8e-5,
            tip_error_m: Some(2e-7),
            measured_tip_error_m: Some(1e-7),
            depth_m: Some(9e-6),
            dose_fraction: Some(0.05),
            measured_dose_fraction: Some(0.049),
            alive: Some(true),
            outcome: outcome.into(),
            reason: String::new(),
            t_start: 1.0,
            t_end: Some(2.0),
            transitions: serde_json::json!([]),
        }
    }

    /// Progress written while a run goes: the survey's count, then the device time,
    /// which only grows; the run's end overwrites both.
    #[test]
    fn a_run_in_progress_shows_its_counts() {
        let mut db = Records::open(&tmp("progress.sqlite")).unwrap();
        let id = db
            .create_run("[plate]", Some(1), "twin", &serde_json::json!({}), 0)
            .unwrap();
        db.set_progress(id, Some(41), None).unwrap();
        let r = db.run(Some(id)).unwrap();
        assert_eq!((r.cells_found, r.sim_time_s), (41, 0.0));
        db.set_progress(id, None, Some(12.5)).unwrap();
        db.set_progress(id, None, Some(3.0)).unwrap();
        let r = db.run(Some(id)).unwrap();
        assert_eq!((r.cells_found, r.sim_time_s), (41, 12.5));
        db.update_run(id, "finished", 80.0, 60.0, 40, None).unwrap();
        let r = db.run(Some(id)).unwrap();
        assert_eq!((r.cells_found, r.sim_time_s), (40, 80.0));
    }

    #[test]
    fn attempts_round_trip_and_resume_retries_or_interrupts() {
        let p = tmp("rt.sqlite");
        let mut r = Records::open(&p).unwrap();
        let run = r
            .create_run("[plate]", Some(7), "twin", &serde_json::json!({"a": 1}), 0)
            .unwrap();
        let done = r.write_attempt(run, None, &attempt("injected")).unwrap();
        r.write_attempt(run, None, &attempt("started")).unwrap();
        r.write_attempt(run, None, &attempt("contact")).unwrap();
        drop(r);
        let mut r = Records::open(&p).unwrap();
        assert_eq!(r.prepare_resume(run).unwrap(), (1, 1));
        let a = r.attempts(run).unwrap();
        assert_eq!(a.len(), 2);
        assert_eq!(a[0].id, done);
        assert_eq!(
            a[0],
            AttemptRow {
                id: done,
                ..attempt("injected")
            }
        );
        assert_eq!(a[1].outcome, "interrupted");
        assert_eq!(r.run(None).unwrap().resumed, 1);
        assert_eq!(r.run(None).unwrap().seed, Some(7));
    }

    #[test]
    fn only_a_run_that_touched_no_cell_is_discarded() {
        let p = tmp("discard.sqlite");
        let mut r = Records::open(&p).unwrap();
        let kept = r
            .create_run("[plate]", None, "twin", &serde_json::json!({}), 0)
            .unwrap();
        r.write_attempt(kept, None, &attempt("injected")).unwrap();
        let refused = r
            .create_run("[plate]", None, "twin", &serde_json::json!({}), 1)
            .unwrap();
        let e = r.discard_run(kept).unwrap_err();
        assert!(
            matches!(e, RecordsError::NotDiscardable { attempts: 1, .. }),
            "{e}"
        );
        r.discard_run(refused).unwrap();
        assert_eq!(r.runs().unwrap().len(), 1);
        assert_eq!(r.run(None).unwrap().id, kept);
        assert!(matches!(
            r.discard_run(refused),
            Err(RecordsError::NoRun(_))
        ));
    }

    #[test]
    fn foreign_and_newer_databases_are_refused_untouched() {
        let p = tmp("foreign.sqlite");
        {
            let c = Connection::open(&p).unwrap();
            c.execute_batch("CREATE TABLE notes (x TEXT); INSERT INTO notes VALUES ('keep');")
                .unwrap();
        }
        let before = std::fs::read(&p).unwrap();
        assert!(matches!(
            Records::open(&p),
            Err(RecordsError::Foreign { .. })
        ));
        assert_eq!(std::fs::read(&p).unwrap(), before);
        let p = tmp("newer.sqlite");
        drop(Records::open(&p).unwrap());
        {
            let c = Connection::open(&p).unwrap();
            c.execute_batch(&format!("PRAGMA user_version = {};", SCHEMA_VERSION + 1))
                .unwrap();
        }
        let e = Records::open(&p).err().expect("refused");
        assert!(e.to_string().contains("newer"), "{e}");
        let p = tmp("text.sqlite");
        std::fs::write(
            &p,
            "this is not a database, just text that is long enough to have a header",
        )
        .unwrap();
        assert!(Records::open(&p).is_err());
    }

    #[test]
    fn a_version_1_database_is_upgraded_keeping_its_runs_and_events_round_trip() {
        let p = tmp("v1.sqlite");
        {
            // A database as version 1 wrote it: its schema, no events table.
            let c = Connection::open(&p).unwrap();
            c.execute_batch(&format!(
                "{SCHEMA} PRAGMA application_id = {APPLICATION_ID}; PRAGMA user_version = 1;"
            ))
            .unwrap();
            c.execute(
                "INSERT INTO runs (created, status, plate, seed, backend, settings, calibration) VALUES (0, 'finished', '[plate]', 3, 'twin', '{}', '{}')",
                [],
            )
            .unwrap();
        }
        let mut r = Records::open(&p).unwrap();
        let version: i32 = r
            .conn
            .pragma_query_value(None, "user_version", |x| x.get(0))
            .unwrap();
        assert_eq!(version, SCHEMA_VERSION);
        let run = r.run(None).unwrap();
        assert_eq!((run.status.as_str(), run.seed), ("finished", Some(3)));
        assert!(r.events(run.id).unwrap().is_empty());
        let e = EventRow {
            t: 301.5,
            from: "next_cell".into(),
            event: "recheck".into(),
            to: "rechecking".into(),
            reason: "re-check 300 s after the image map was made".into(),
        };
        r.write_event(run.id, &e).unwrap();
        drop(r);
        let r = Records::open(&p).unwrap();
        assert_eq!(r.events(run.id).unwrap(), vec![e]);
    }
}
