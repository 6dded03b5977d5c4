//! # cellinject-dashboard
//!
//! A live web page for one bench, safe to leave open beside the microscope: the
//! camera view with the tip, the target, the cells found and the tracking window
//! drawn over it; the actuators', sensors' and stage's readouts; the tracking error,
//! the hysteresis loop being traced and the throughput as live plots; the plate map
//! filling up; jog, calibrate, start, pause, resume and a big abort; the run records
//! and each run's report. The page uses a small JSON API (`docs/dashboard.md`).
//!
//! Three threads: the **control thread** owns the devices and does one command at a
//! time ([`bench::spawn`]); the **view thread** renders the live view at 15 frames a
//! second; the **web side** (axum on tokio) reads what they publish and sends them
//! commands by message. Abort is not a message: it flips a switch ([`Control`]) that
//! the control thread sees at its next clock tick, so it is never queued behind a
//! busy bench.
//!
//! **Architecture invariant:** this is the only crate that uses tokio and axum; it
//! knows nothing of the twin or of a driver (the front end hands it a [`Station`],
//! a [`Viewer`] and an [`Archive`]).
//!
//! **Architecture invariant:** nothing is listened for beyond loopback unless asked
//! (`--allow-remote`), and then every request needs the access token; Host and
//! Origin are checked on every request.

pub mod bench;
pub mod server;
pub mod watch;

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

pub use bench::{
    Archive, BenchState, Board, Command, GrabbedView, Jog, JogAxis, PlateView, RunEnd, Shared,
    Station, ViewFrame, Viewer, view_geometry,
};
pub use server::{Access, App, DashboardError, router};
pub use watch::{Control, Telemetry, instrument};

/// Longest the server waits, when it stops, for the bench to reach its safe state.
pub const SHUTDOWN_WAIT: Duration = Duration::from_secs(20);

/// Frames per second of the live view.
pub const VIEW_FPS: f64 = 15.0;

/// The state shared by the threads, for `station`'s bench.
pub fn shared(
    station: &dyn Station,
    control: Arc<Control>,
    telemetry: Arc<Telemetry>,
) -> Arc<Shared> {
    Arc::new(Shared {
        control,
        telemetry,
        board: Mutex::new(Board {
            state: BenchState::Idle,
            task: None,
            stopping: false,
            message: None,
            run: None,
            calibrated: false,
            log: Vec::new(),
        }),
        busy: AtomicBool::new(false),
        quit: AtomicBool::new(false),
        plate: station.plate(),
        backend: station.backend(),
    })
}

/// Starts the view thread: `viewer`'s frames, encoded, at [`VIEW_FPS`] until `stop`.
pub fn spawn_viewer(
    mut viewer: Box<dyn Viewer>,
    stop: Arc<AtomicBool>,
) -> (
    tokio::sync::watch::Receiver<Option<Arc<server::FrameMsg>>>,
    std::thread::JoinHandle<()>,
) {
    let (tx, rx) = tokio::sync::watch::channel(None);
    let h = std::thread::Builder::new()
        .name("cellinject-view".into())
        .spawn(move || {
            let period = Duration::from_secs_f64(1.0 / VIEW_FPS);
            let mut n = 0u64;
            while !stop.load(Ordering::SeqCst) {
                let t0 = Instant::now();
                if let Some(f) = viewer.frame() {
                    n += 1;
                    let _ = tx.send(Some(Arc::new(server::frame_msg(f, n))));
                }
                if let Some(rest) = period.checked_sub(t0.elapsed()) {
                    std::thread::sleep(rest);
                }
            }
        })
        .expect("a thread can be spawned");
    (rx, h)
}

/// How long the server runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Lifetime {
    /// Until Ctrl-C (or SIGTERM).
    UntilSignal,
    /// For this many seconds (tests, demos), or until a signal if that comes first.
    For(f64),
}

/// Ctrl-C, and SIGTERM on Unix (a service manager's stop), listened for from the
/// moment this is made (inside the runtime), so that a stop that comes as soon as the
/// address is printed ends the server like any other.
struct Signals {
    #[cfg(unix)]
    int: Option<tokio::signal::unix::Signal>,
    #[cfg(unix)]
    term: Option<tokio::signal::unix::Signal>,
}

impl Signals {
    fn new() -> Self {
        #[cfg(unix)]
        {
            use tokio::signal::unix::{SignalKind, signal};
            Signals {
                int: signal(SignalKind::interrupt()).ok(),
                term: signal(SignalKind::terminate()).ok(),
            }
        }
        #[cfg(not(unix))]
        Signals {}
    }

    /// The first of them (never, if none could be listened for).
    async fn first(mut self) {
        #[cfg(unix)]
        {
            async fn next(s: &mut Option<tokio::signal::unix::Signal>) {
                match s {
                    Some(s) => {
                        s.recv().await;
                    }
                    None => std::future::pending::<()>().await,
                }
            }
            tokio::select! {
                _ = next(&mut self.int) => {}
                _ = next(&mut self.term) => {}
            }
        }
        #[cfg(not(unix))]
        {
            if tokio::signal::ctrl_c().await.is_err() {
                std::future::pending::<()>().await;
            }
        }
    }
}

/// What the front end hands the dashboard: one bench and how to see it.
pub struct Setup {
    /// The bench (its devices already [`instrument`]ed with `control` and `telemetry`).
    pub station: Box<dyn Station>,
    /// The live view.
    pub viewer: Box<dyn Viewer>,
    /// The run records.
    pub archive: Arc<dyn Archive>,
    /// The switches the bench's clock obeys.
    pub control: Arc<Control>,
    /// The readings its devices report.
    pub telemetry: Arc<Telemetry>,
}

/// Serves the dashboard of `setup`'s bench until `lifetime` ends; then aborts
/// whatever is going and waits for the control thread to bring the bench to its safe
/// state and record the run. `on_ready` gets the address listened on (port 0
/// resolved).
pub fn serve(
    access: Access,
    setup: Setup,
    lifetime: Lifetime,
    on_ready: impl FnOnce(SocketAddr),
) -> Result<(), DashboardError> {
    let Setup {
        station,
        viewer,
        archive,
        control,
        telemetry,
    } = setup;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(DashboardError::Runtime)?;
    let listener = rt
        .block_on(tokio::net::TcpListener::bind(access.bind))
        .map_err(|source| DashboardError::Bind {
            addr: access.bind,
            source,
        })?;
    let addr = listener
        .local_addr()
        .map_err(|source| DashboardError::Bind {
            addr: access.bind,
            source,
        })?;
    let shared = shared(&*station, control, telemetry);
    let (cmd, control_thread) = bench::spawn(station, shared.clone());
    let stop = Arc::new(AtomicBool::new(false));
    let (frames, view_thread) = spawn_viewer(viewer, stop.clone());
    let app = App::new(shared.clone(), cmd, access, archive, frames);
    let signals = {
        let _rt = rt.enter();
        Signals::new()
    };
    on_ready(addr);
    let stop_view = stop.clone();
    let ended = async move {
        let limit = async {
            match lifetime {
                Lifetime::For(s) => tokio::time::sleep(Duration::from_secs_f64(s)).await,
                Lifetime::UntilSignal => std::future::pending::<()>().await,
            }
        };
        tokio::select! {
            _ = limit => {}
            _ = signals.first() => {}
        }
        // The live streams end with the view thread (their watch closes), so that
        // the graceful shutdown does not wait on them.
        stop_view.store(true, Ordering::SeqCst);
    };
    let served = rt.block_on(server::serve_on(listener, app.clone(), ended));
    // Whatever is going ends in the safe state and in the records.
    stop.store(true, Ordering::SeqCst);
    shared.control.abort();
    shared.quit.store(true, Ordering::SeqCst);
    drop(app);
    let _ = view_thread.join();
    // The control thread brings the bench to its safe state and records the run; a
    // device stuck in a blocking call must not hold the process forever.
    let t0 = Instant::now();
    while !control_thread.is_finished() && t0.elapsed() < SHUTDOWN_WAIT {
        std::thread::sleep(Duration::from_millis(20));
    }
    let finished = control_thread.is_finished();
    if finished {
        let _ = control_thread.join();
    }
    rt.shutdown_timeout(Duration::from_secs(1));
    served.map_err(|source| DashboardError::Bind { addr, source })?;
    if finished {
        Ok(())
    } else {
        Err(DashboardError::Stuck(SHUTDOWN_WAIT.as_secs_f64()))
    }
}
