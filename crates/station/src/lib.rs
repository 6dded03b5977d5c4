//! # cellinject-station
//!
//! The bench a dashboard serves (`cellinject serve`): a session's bench
//! ([`cellinject_session::Opened`], the twin or real devices) as the dashboard's
//! [`Station`], whose runs go through the same lifecycle as `cellinject run`'s
//! ([`cellinject_session::run::run`]); the twin's scene as its [`Viewer`] (a binned copy
//! of its microscope), or the frames the runs grab on a real bench; the run database as
//! its [`Archive`], with each run's report ([`cellinject_session::report::html`]).
//!
//! **Architecture invariant:** the dashboard knows nothing of the twin, a driver or the
//! records: this crate is where they meet its traits, so that the binary only parses
//! `serve`'s arguments and the dashboard stays a web page.

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use cellinject_config::Description;
use cellinject_core::calibrate::HysteresisCalibration;
use cellinject_core::inject::{Observer, Options, WorkflowError};
use cellinject_dashboard::{
    Archive, GrabbedView, PlateView, RunEnd, Station, Telemetry, ViewFrame, Viewer,
};
use cellinject_hw::Frame;
use cellinject_plate::Plate;
use cellinject_records::Records;
use cellinject_rig::{DynBackend, Rig, RigError};
use cellinject_session::Opened;
use cellinject_session::run::{self as session_run, Begin, Ended};
use cellinject_twin::{Microscope, SharedTwin};

/// What a dashboard's bench is made of.
pub struct Bench {
    /// The manipulator's description.
    pub d: Description,
    /// The bench, opened for the session (its twin kept from run to run).
    pub opened: Opened,
    /// The plate every run injects, and its file's text (recorded with each run).
    pub plate: Plate,
    /// The plate file's text.
    pub plate_text: String,
    /// The twin's seed.
    pub seed: u64,
    /// The run database.
    pub db: PathBuf,
    /// The workflow's options.
    pub options: Options,
}

/// Whether the feeder can present `plate` with `options` on the bench (the fields over
/// it planned), before anything is served: the outer error if the twin's copy cannot
/// be built, the inner one the plan's. On the twin a copy is asked: the check grabs a
/// frame, which would move the twin's clock, and the first run would not start where
/// `cellinject run` does.
pub fn check_plate(
    d: &Description,
    opened: &mut Opened,
    plate: &Plate,
    options: Options,
) -> Result<Result<(), WorkflowError>, RigError> {
    let check = |rig: &mut Rig<DynBackend>| {
        cellinject_core::inject::Workflow::new(rig, &d.design, &d.rig, plate, options)
            .and_then(|mut w| w.fields())
            .map(|_| ())
    };
    Ok(match &opened.twin {
        Some(twin) => {
            let copy = twin
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .clone()
                .into_shared();
            let mut rig = cellinject_twin::guarded(&copy, cellinject_twin::devices(&copy).boxed())?;
            check(&mut rig)
        }
        None => check(&mut opened.rig),
    })
}

/// The dashboard's station, viewer and archive for `bench`: on the twin, its plate
/// loaded and the pipette lifted above it, the view a binned copy of its microscope;
/// on a real bench, the view the frames its runs grab (`telemetry`).
pub fn station(
    bench: Bench,
    telemetry: &Arc<Telemetry>,
) -> (Box<dyn Station>, Box<dyn Viewer>, Arc<dyn Archive>) {
    let generation = Arc::new(AtomicU64::new(0));
    if let Some(twin) = &bench.opened.twin {
        let mut t = twin.lock().unwrap_or_else(|e| e.into_inner());
        t.load_plate(&bench.plate);
        t.world
            .stage
            .place(1, bench.options.focus + bench.options.lift);
    }
    let viewer: Box<dyn Viewer> = match &bench.opened.twin {
        Some(twin) => Box::new(TwinViewer {
            twin: twin.clone(),
            cam: None,
            generation: generation.clone(),
            seen: 0,
            frame: Frame::default(),
        }),
        None => Box::new(GrabbedView::new(telemetry.clone())),
    };
    let archive = Arc::new(DbArchive {
        path: bench.db.clone(),
        db: Mutex::new(None),
    });
    let station = BenchStation {
        b: bench,
        generation,
        session: None,
    };
    (Box::new(station), viewer, archive)
}

/// The bench as the dashboard drives it.
struct BenchStation {
    b: Bench,
    /// Bumped when the twin gets a fresh plate (the viewer renews its camera).
    generation: Arc<AtomicU64>,
    /// What the session's first run found of the resting tip (the side camera's
    /// reference of its height, the stacks' readings at rest): every later run of
    /// the dashboard's session refers its focus to it.
    session: Option<cellinject_core::inject::Session>,
}

impl Station for BenchStation {
    fn backend(&self) -> String {
        self.b.opened.name.clone()
    }
    fn plate(&self) -> PlateView {
        PlateView {
            rows: self.b.plate.rows,
            cols: self.b.plate.cols,
            pitch_m: self.b.plate.pitch,
            origin_m: self.b.plate.origin,
        }
    }
    fn rig(&mut self) -> &mut Rig<DynBackend> {
        &mut self.b.opened.rig
    }
    fn sweep_drop(&self) -> Result<f64, String> {
        cellinject_core::calibrate::sweep_drop(&self.b.d.design, &self.b.d.rig)
            .map_err(|e| e.to_string())
    }
    fn run(
        &mut self,
        watch: &mut dyn Observer,
        hysteresis: Option<HysteresisCalibration>,
        aborted: &dyn Fn() -> bool,
    ) -> Result<RunEnd, String> {
        // The same lifecycle as `cellinject run`'s (cellinject-session): a fresh
        // plate under the microscope, the pipette lifted above it.
        let generation = self.generation.clone();
        let renew = move || {
            generation.fetch_add(1, Ordering::SeqCst);
        };
        let request = session_run::Request {
            d: &self.b.d,
            db: &self.b.db,
            options: self.b.options,
            hysteresis,
            session: self.session.clone(),
            begin: Begin::New {
                plate: self.b.plate.clone(),
                text: self.b.plate_text.clone(),
                seed: self.b.seed,
                faults: Vec::new(),
                settings: serde_json::json!({
                    "options": self.b.options,
                    "faults": [],
                    "front_end": "dashboard",
                }),
            },
            debug: session_run::debug_requested(),
        };
        let hooks = session_run::Hooks {
            watch: Some(watch),
            aborted,
            plate_loaded: Some(&renew),
            ..session_run::Hooks::default()
        };
        let ended = session_run::run(
            request,
            session_run::Bench::Opened(&mut self.b.opened),
            hooks,
        )
        .map_err(|e| e.to_string())?;
        let Ended::Ran {
            run_id,
            summary,
            outcome,
            stopped,
        } = ended
        else {
            return Err("a new run cannot be finished before it starts".into());
        };
        let (cells_per_min, calibration) = match *outcome {
            Ok((report, cal)) => {
                self.session.get_or_insert(report.session);
                (report.cells_per_min, Some(cal))
            }
            Err(_) => (0.0, None),
        };
        Ok(RunEnd {
            id: run_id,
            status: summary.status,
            stopped,
            cells_per_min,
            calibration,
        })
    }
}

/// The twin's scene as it is, through a binned copy of its microscope.
struct TwinViewer {
    twin: SharedTwin,
    cam: Option<Microscope>,
    generation: Arc<AtomicU64>,
    seen: u64,
    frame: Frame,
}

impl Viewer for TwinViewer {
    fn frame(&mut self) -> Option<ViewFrame> {
        let mut t = self.twin.lock().unwrap_or_else(|e| e.into_inner());
        let g = self.generation.load(Ordering::SeqCst);
        if self.cam.is_none() || g != self.seen {
            self.cam = Some(t.view_camera());
            self.seen = g;
        }
        let cam = self.cam.as_mut()?;
        let grid = t.peek(cam, &mut self.frame);
        let tip = t.tip();
        let roi = t.camera.grid();
        let time = t.world.time();
        drop(t);
        let half = |g: &cellinject_twin::Grid| 0.5 * g.pitch;
        Some(ViewFrame {
            width: self.frame.width,
            height: self.frame.height,
            pixels: self
                .frame
                .pixels
                .iter()
                .map(|&v| v.min(255) as u8)
                .collect(),
            origin_m: Some([grid.x0 - half(&grid), grid.z0 - half(&grid)]),
            pitch_m: grid.pitch,
            to_view: None,
            tip_m: Some([tip.x, tip.depth, tip.z]),
            roi_m: Some([
                roi.x0 - half(&roi),
                roi.z0 - half(&roi),
                roi.x0 - half(&roi) + roi.width as f64 * roi.pitch,
                roi.z0 - half(&roi) + roi.height as f64 * roi.pitch,
            ]),
            time_s: time,
        })
    }
}

/// The run database, read on request.
struct DbArchive {
    path: PathBuf,
    /// One connection for reads (the control thread writes through its own).
    db: Mutex<Option<Records>>,
}

impl DbArchive {
    fn with<R>(
        &self,
        f: impl FnOnce(&Records) -> Result<R, cellinject_records::RecordsError>,
    ) -> Result<R, String> {
        let mut g = self.db.lock().unwrap_or_else(|e| e.into_inner());
        if g.is_none() {
            *g = Some(Records::open_existing(&self.path).map_err(|e| match e {
                cellinject_records::RecordsError::Missing { .. } => format!(
                    "--db {e} (a run creates it: cellinject run --db {})",
                    self.path.display()
                ),
                e => format!("--db {e}"),
            })?);
        }
        let db = g.as_ref().ok_or("no database")?;
        f(db).map_err(|e| e.to_string())
    }
}

impl Archive for DbArchive {
    fn runs(&self) -> Result<serde_json::Value, String> {
        self.with(|db| {
            let mut out = Vec::new();
            for r in db.runs()? {
                let a = db.attempts(r.id)?;
                let n = |o: &str| a.iter().filter(|x| x.outcome == o).count();
                out.push(serde_json::json!({
                    "id": r.id,
                    "created": r.created,
                    "status": r.status,
                    "backend": r.backend,
                    "seed": r.seed,
                    "cells_found": r.cells_found,
                    "attempts": a.len(),
                    "injected": n("injected"),
                    "failed": n("failed"),
                    "skipped": n("skipped"),
                    "sim_time_s": r.sim_time_s,
                    "cell_time_s": r.cell_time_s,
                    "stopped": r.stopped,
                }));
            }
            out.reverse();
            Ok(serde_json::Value::Array(out))
        })
    }
    fn report(&self, id: i64) -> Result<Option<String>, String> {
        let found = self.with(|db| match db.run(Some(id)) {
            Err(cellinject_records::RecordsError::NoRun(_)) => Ok(None),
            r => Ok(Some((r?, db.attempts(id)?))),
        })?;
        match found {
            None => Ok(None),
            Some((r, a)) => cellinject_session::report::html(&r, &a)
                .map(Some)
                .map_err(|e| e.to_string()),
        }
    }
}
