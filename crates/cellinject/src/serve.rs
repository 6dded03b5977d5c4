//! `cellinject serve`: the live web dashboard of one bench (the twin by default).

use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use anyhow::Result;
use cellinject_config::Description;
use cellinject_core::calibrate::HysteresisCalibration;
use cellinject_core::inject::{Observer, Options};
use cellinject_dashboard::{
    Access, Archive, Control, DashboardError, GrabbedView, Lifetime, PlateView, RunEnd, Setup,
    Station, Telemetry, ViewFrame, Viewer,
};
use cellinject_hw::Frame;
use cellinject_plate::Plate;
use cellinject_records::Records;
use cellinject_rig::{DynBackend, Rig};
use cellinject_twin::{Microscope, SharedTwin};
use clap::Args;

use crate::InputError;
use crate::run::{default_plate_text, records_error};
use cellinject_session::Opened;
use cellinject_session::run::{self as session_run, Begin, Ended};

/// `cellinject serve`.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Address to listen on (loopback by default; any other needs --allow-remote;
    /// port 0 picks a free one).
    #[arg(long, default_value = "127.0.0.1:8080", value_name = "HOST:PORT")]
    bind: String,
    /// Listen beyond loopback: prints a random access token (`access token: TOKEN` on
    /// standard error) that every request must then carry.
    #[arg(long)]
    allow_remote: bool,
    /// With --allow-remote: the page, the status, the live view and the records
    /// without the token (control still needs it).
    #[arg(long)]
    public_view: bool,
    /// A further name the page may be reached by (e.g. bench.lab.example), checked
    /// against the Host header (repeatable).
    #[arg(long, value_name = "NAME")]
    allowed_host: Vec<String>,
    /// The plate a run injects (TOML; default: `run`'s generated 8 x 12 plate from
    /// the seed).
    #[arg(long, value_name = "FILE.toml")]
    plate: Option<PathBuf>,
    /// Seed of the twin (and of the default plate); default: the description's.
    #[arg(long)]
    seed: Option<u64>,
    /// The run database (as `cellinject run`'s).
    #[arg(long, default_value = "runs.sqlite")]
    db: PathBuf,
    /// Injected volume, fraction of each cell's volume.
    #[arg(long, default_value_t = 0.05, allow_negative_numbers = true)]
    dose: f64,
    /// The twin flat out instead of paced to wall time (the live view then shows
    /// moments of a faster world).
    #[arg(long)]
    fast: bool,
    #[command(flatten)]
    backend: crate::backend::BackendArgs,
    /// Stop serving after this many seconds (default: until Ctrl-C or SIGTERM, which
    /// also end it earlier); whatever is going is aborted and recorded first.
    #[arg(long, value_name = "SECONDS", allow_negative_numbers = true)]
    serve_for: Option<f64>,
}

/// The bench as the dashboard drives it.
struct BenchStation {
    d: Description,
    /// The bench, its twin kept from run to run.
    opened: Opened,
    plate: Plate,
    plate_text: String,
    seed: u64,
    db: PathBuf,
    options: Options,
    /// Bumped when the twin gets a fresh plate (the viewer renews its camera).
    generation: Arc<AtomicU64>,
    /// What the session's first run found of the resting tip (the side camera's
    /// reference of its height, the stacks' readings at rest): every later run of
    /// the dashboard's session refers its focus to it.
    session: Option<cellinject_core::inject::Session>,
}

impl Station for BenchStation {
    fn backend(&self) -> String {
        self.opened.name.clone()
    }
    fn plate(&self) -> PlateView {
        PlateView {
            rows: self.plate.rows,
            cols: self.plate.cols,
            pitch_m: self.plate.pitch,
            origin_m: self.plate.origin,
        }
    }
    fn rig(&mut self) -> &mut Rig<DynBackend> {
        &mut self.opened.rig
    }
    fn run(
        &mut self,
        watch: &mut dyn Observer,
        hysteresis: Option<HysteresisCalibration>,
        aborted: &dyn Fn() -> bool,
    ) -> std::result::Result<RunEnd, String> {
        // The same lifecycle as `cellinject run`'s (cellinject-session): a fresh
        // plate under the microscope, the pipette lifted above it.
        let generation = self.generation.clone();
        let renew = move || {
            generation.fetch_add(1, Ordering::SeqCst);
        };
        let request = session_run::Request {
            d: &self.d,
            db: &self.db,
            options: self.options,
            hysteresis,
            session: self.session.clone(),
            begin: Begin::New {
                plate: self.plate.clone(),
                text: self.plate_text.clone(),
                seed: self.seed,
                faults: Vec::new(),
                settings: serde_json::json!({
                    "options": self.options,
                    "faults": [],
                    "front_end": "dashboard",
                }),
            },
            debug: crate::run::debug(),
        };
        let hooks = session_run::Hooks {
            watch: Some(watch),
            aborted,
            plate_loaded: Some(&renew),
            ..session_run::Hooks::default()
        };
        let ended = session_run::run(request, session_run::Bench::Opened(&mut self.opened), hooks)
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
        f: impl FnOnce(&Records) -> std::result::Result<R, cellinject_records::RecordsError>,
    ) -> std::result::Result<R, String> {
        let mut g = self.db.lock().unwrap_or_else(|e| e.into_inner());
        if g.is_none() {
            *g = Some(crate::run::open_existing(&self.path).map_err(|e| e.to_string())?);
        }
        let db = g.as_ref().ok_or("no database")?;
        f(db).map_err(|e| e.to_string())
    }
}

impl Archive for DbArchive {
    fn runs(&self) -> std::result::Result<serde_json::Value, String> {
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
    fn report(&self, id: i64) -> std::result::Result<Option<String>, String> {
        let found = self.with(|db| match db.run(Some(id)) {
            Err(cellinject_records::RecordsError::NoRun(_)) => Ok(None),
            r => Ok(Some((r?, db.attempts(id)?))),
        })?;
        match found {
            None => Ok(None),
            Some((r, a)) => crate::report::html(&r, &a)
                .map(Some)
                .map_err(|e| e.to_string()),
        }
    }
}

fn dashboard_error(e: DashboardError) -> anyhow::Error {
    match e {
        DashboardError::RemoteNotAllowed(_)
        | DashboardError::BadHost(_)
        | DashboardError::Bind { .. } => InputError(e.to_string()).into(),
        other => anyhow::anyhow!("{other}"),
    }
}

/// `cellinject serve`.
pub fn serve(d: &Description, a: &ServeArgs) -> Result<()> {
    let lifetime = match a.serve_for {
        None => Lifetime::UntilSignal,
        Some(t) if t.is_finite() && t > 0.0 && t <= 1e7 => Lifetime::For(t),
        Some(t) => {
            return Err(InputError(format!("--serve-for must lie in (0, 1e7] s, got {t}")).into());
        }
    };
    let bind: SocketAddr = a.bind.parse().map_err(|_| {
        InputError(format!(
            "--bind `{}`: expected HOST:PORT with HOST an IP address (127.0.0.1:8080, [::1]:8080, 0.0.0.0:8080)",
            a.bind
        ))
    })?;
    if a.public_view && !a.allow_remote {
        return Err(InputError(
            "--public-view opens viewing to the network without the token: it needs --allow-remote (on loopback nothing needs a token)".into(),
        )
        .into());
    }
    let access = Access::new(bind, a.allow_remote, a.public_view, a.allowed_host.clone())
        .map_err(dashboard_error)?;
    let options = Options {
        target_fraction: a.dose,
        ..Options::default()
    };
    options
        .check(&d.rig)
        .map_err(|e| InputError(e.to_string()))?;
    let bench = a.backend.rig()?;
    let remote = !bench.is_twin();
    if remote {
        crate::run::gcs_run_checks(a.plate.is_some(), a.seed.is_some())?;
        if a.fast {
            return Err(InputError(
                "--fast runs the twin flat out: a GCS backend keeps wall-clock time".into(),
            )
            .into());
        }
    }
    let seed = a.seed.unwrap_or(d.sim.seed);
    let (plate, plate_text) = match &a.plate {
        Some(p) => crate::run::read_plate(p)?,
        None => default_plate_text(seed)?,
    };
    let control = Arc::new(Control::new(a.fast));
    let telemetry = Arc::new(Telemetry::default());
    let opened = crate::backend::open_with(
        d,
        &if remote {
            crate::sim::TwinArgs::new(None, None)
        } else {
            crate::sim::TwinArgs::with_seed(seed)
        },
        &bench,
        |devices| cellinject_dashboard::instrument(devices, &telemetry, &control, remote),
    )?;
    let mut opened = opened;
    // A plate the feeder cannot present is refused now, not at the first run. On the
    // twin, a copy of it is asked: the check grabs a frame, which would move the
    // twin's clock, and the first run would not start where `cellinject run` does.
    let check = |rig: &mut Rig<DynBackend>| {
        cellinject_core::inject::Workflow::new(rig, &d.design, &d.rig, &plate, options)
            .and_then(|mut w| w.fields())
    };
    let verdict = match &opened.twin {
        Some(twin) => {
            let copy = twin
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .clone()
                .into_shared();
            let mut rig = cellinject_twin::guarded(&copy, cellinject_twin::devices(&copy).boxed())
                .map_err(|e| anyhow::anyhow!("cannot build the twin: {e}"))?;
            check(&mut rig)
        }
        None => check(&mut opened.rig),
    };
    if let Err(e) = verdict {
        return Err(match e {
            cellinject_core::inject::WorkflowError::Plan(_)
            | cellinject_core::inject::WorkflowError::PitchTooLarge { .. }
            | cellinject_core::inject::WorkflowError::Invalid { .. } => {
                InputError(format!("--plate: {e}")).into()
            }
            e => anyhow::anyhow!("checking the plate: {e}"),
        });
    }
    // The database is opened (and refused if foreign) before anything is listened on,
    // and after the plate is checked (a refused plate leaves no file).
    drop(Records::open(&a.db).map_err(records_error)?);
    let generation = Arc::new(AtomicU64::new(0));
    if let Some(twin) = &opened.twin {
        let mut t = twin.lock().unwrap_or_else(|e| e.into_inner());
        t.load_plate(&plate);
        t.world.stage.place(1, options.focus + options.lift);
    }
    let viewer: Box<dyn Viewer> = match &opened.twin {
        Some(twin) => Box::new(TwinViewer {
            twin: twin.clone(),
            cam: None,
            generation: generation.clone(),
            seen: 0,
            frame: Frame::default(),
        }),
        None => Box::new(GrabbedView::new(telemetry.clone())),
    };
    let station = BenchStation {
        d: d.clone(),
        opened,
        plate,
        plate_text,
        seed,
        db: a.db.clone(),
        options,
        generation,
        session: None,
    };
    let archive = Arc::new(DbArchive {
        path: a.db.clone(),
        db: Mutex::new(None),
    });
    let token = access.token.clone();
    let setup = Setup {
        station: Box::new(station),
        viewer,
        archive,
        control,
        telemetry,
    };
    cellinject_dashboard::serve(access, setup, lifetime, |addr| {
        let shown = if addr.ip().is_unspecified() {
            format!("http://localhost:{}/", addr.port())
        } else {
            format!("http://{addr}/")
        };
        // Standard error may be a closed pipe (`2>&1 | head -1`): never a panic.
        let mut e = std::io::stderr();
        let _ = writeln!(e, "dashboard: {shown} (Ctrl-C to stop)");
        if let Some(t) = &token {
            let _ = writeln!(e, "access token: {t}");
            let _ = writeln!(
                e,
                "open {shown}?token={t} once in a browser: it keeps a session cookie"
            );
        }
    })
    .map_err(dashboard_error)
}
