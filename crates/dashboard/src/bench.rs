//! The bench behind the dashboard: what a front end provides ([`Station`], [`Viewer`],
//! [`Archive`]), the one control thread that owns the devices and takes commands by
//! message, and the board it writes what it does on, which the web side reads.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender, channel};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use cellinject_core::calibrate::{self, HysteresisCalibration};
use cellinject_core::inject::{Attempt, Event, ImageMap, Observer, State, Target, Transition};
use cellinject_hw::{CameraSettings, Frame, PiezoChannel, Stage};
use cellinject_rig::{DynBackend, Rig};
use serde::Serialize;

use crate::watch::{Control, Telemetry, lock};

/// How a run under the dashboard ended, as recorded.
#[derive(Debug, Clone, PartialEq)]
pub struct RunEnd {
    /// The run's record.
    pub id: i64,
    /// `finished`, `stopped` or `aborted`, as recorded.
    pub status: String,
    /// Why it stopped, if it did.
    pub stopped: Option<String>,
    /// Attempts per minute of device time, first cell to last.
    pub cells_per_min: f64,
    /// The stacks' calibration the run used (the next run loads it).
    pub calibration: Option<HysteresisCalibration>,
}

/// The grid of the plate on the bench, to draw its map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PlateView {
    /// Rows of wells.
    pub rows: u32,
    /// Columns.
    pub cols: u32,
    /// m between wells.
    pub pitch_m: f64,
    /// m, stage coordinates of well [0, 0].
    pub origin_m: [f64; 2],
}

/// One bench, as the front end sets it up: its guarded devices (already wrapped by
/// [`crate::instrument`]) and how a run is started, recorded and ended.
pub trait Station: Send + 'static {
    /// The backend's name (`twin`, `gcs://...`).
    fn backend(&self) -> String;
    /// The plate a run injects.
    fn plate(&self) -> PlateView;
    /// The guarded devices.
    fn rig(&mut self) -> &mut Rig<DynBackend>;
    /// m, how far the stacks' hysteresis sweep can lower the pipette's tip: the
    /// calibration raises the pipette as much first
    /// ([`cellinject_core::calibrate::sweep_drop`] of the bench's description), or
    /// why the description's model gives none.
    fn sweep_drop(&self) -> Result<f64, String>;
    /// Runs the plate to its end, recording it. Every call of the workflow's
    /// observer also goes to `watch` (which pauses and aborts through
    /// [`Observer::proceed`]); `aborted` tells whether the operator aborted, for the
    /// record. `Err`: the run could not start or its records failed.
    fn run(
        &mut self,
        watch: &mut dyn Observer,
        hysteresis: Option<HysteresisCalibration>,
        aborted: &dyn Fn() -> bool,
    ) -> Result<RunEnd, String>;
}

/// A frame for the live view, with where its pixels lie.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewFrame {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// 8-bit grey, row-major.
    pub pixels: Vec<u8>,
    /// m, object-plane (stage) x and z of pixel (0, 0)'s outer corner, when known.
    pub origin_m: Option<[f64; 2]>,
    /// m per pixel.
    pub pitch_m: f64,
    /// Where stage coordinates fall in this frame, when known and not as simple as
    /// `origin_m` and `pitch_m` say: the affine map from stage (x, z) in m to the
    /// frame's pixel coordinates (0 at the outer edge of the first pixel),
    /// `column = a[0][0] x + a[0][1] z + a[0][2]`, `row = a[1][0] x + a[1][1] z + a[1][2]`
    /// (a real bench: from the workflow's image-to-stage map).
    pub to_view: Option<[[f64; 3]; 2]>,
    /// m, the tip (x, y, z) when the backend knows it.
    pub tip_m: Option<[f64; 3]>,
    /// m, the microscope's region of interest (x0, z0, x1, z1): where the program
    /// looks (the tracking window), when known.
    pub roi_m: Option<[f64; 4]>,
    /// s, device time.
    pub time_s: f64,
}

/// Renders the live view (the twin renders the scene as it is; a real bench shows
/// the frames the program grabs). Called from the view thread.
pub trait Viewer: Send + 'static {
    /// The newest view, or None if there is nothing new.
    fn frame(&mut self) -> Option<ViewFrame>;
}

/// The frames the program grabbed, downscaled: the view of a backend that cannot
/// render one of its own.
pub struct GrabbedView {
    t: Arc<Telemetry>,
    seen: u64,
}

/// Where stage (x, z) falls in a frame grabbed with `settings` (`pixel_size`: its
/// output pixel, binning included) and binned `k` x `k` for the view, as the affine
/// map of [`ViewFrame::to_view`]: the image-to-stage map's [`ImageMap::pixel_of`] `p`
/// (full-frame sensor pixels, a pixel's centre at its index), less the region of
/// interest's corner, plus half a sensor pixel (the view's coordinates start at a
/// pixel's outer edge), over the camera's binning times `k`:
/// `(p - roi + 0.5) / (binning k)`. None when the frame is not at the map's scale
/// (another zoom).
pub fn view_geometry(
    map: &ImageMap,
    settings: &CameraSettings,
    pixel_size: f64,
    k: u32,
) -> Option<[[f64; 3]; 2]> {
    let bin = settings.binning.max(1) as f64;
    let same_scale = (pixel_size - map.pixel_size * bin).abs() <= 1e-6 * pixel_size;
    if !same_scale {
        return None;
    }
    let s = bin * k.max(1) as f64;
    let roi = [settings.roi.x as f64, settings.roi.y as f64];
    let row = |r: usize| {
        let [bx, bz] = map.b[r];
        let c = map.pixel0[r] - bx * map.stage0[0] - bz * map.stage0[1] - roi[r];
        // Sensor pixel i spans [i - 0.5, i + 0.5) in the map's coordinates and
        // [i, i + 1) in the view's.
        [bx / s, bz / s, (c + 0.5) / s]
    };
    Some([row(0), row(1)])
}

impl GrabbedView {
    /// A view of the frames that reach `t`.
    pub fn new(t: Arc<Telemetry>) -> Self {
        GrabbedView { t, seen: 0 }
    }
}

impl Viewer for GrabbedView {
    fn frame(&mut self) -> Option<ViewFrame> {
        let (f, settings, n) = self.t.grabbed_since(self.seen)?;
        self.seen = n;
        let mut v = downscale(&f, 640);
        if let Some(map) = self.t.map() {
            // The view's binning (downscale's own factor).
            let k = (v.pitch_m / f.pixel_size).round().max(1.0) as u32;
            v.to_view = view_geometry(&map, &settings, f.pixel_size, k);
        }
        Some(v)
    }
}

/// `f` as 8-bit grey, binned down to at most `max_width` columns.
pub fn downscale(f: &Frame, max_width: u32) -> ViewFrame {
    let b = f.width.div_ceil(max_width.max(1)).max(1) as usize;
    let (w, h) = (f.width as usize / b, f.height as usize / b);
    let shift = f.bit_depth.saturating_sub(8) as u32;
    let mut pixels = Vec::with_capacity(w * h);
    for j in 0..h {
        for i in 0..w {
            let mut s = 0u32;
            for dj in 0..b {
                let row = (j * b + dj) * f.width as usize;
                for di in 0..b {
                    s += f.pixels.get(row + i * b + di).copied().unwrap_or(0) as u32;
                }
            }
            pixels.push(((s / (b * b) as u32) >> shift).min(255) as u8);
        }
    }
    ViewFrame {
        width: w as u32,
        height: h as u32,
        pixels,
        origin_m: None,
        pitch_m: f.pixel_size * b as f64,
        to_view: None,
        tip_m: None,
        roi_m: None,
        time_s: f.timestamp,
    }
}

/// The run records, read by the web side at any time (the control thread writes
/// them).
pub trait Archive: Send + Sync + 'static {
    /// Every run, newest first, as JSON (an array of objects with at least `id` and
    /// `status`).
    fn runs(&self) -> Result<serde_json::Value, String>;
    /// A run's report as a complete HTML page, or None if there is no such run.
    fn report(&self, id: i64) -> Result<Option<String>, String>;
}

/// The bench's state, as `GET /api/status` reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BenchState {
    /// Nothing started yet.
    Idle,
    /// A run (or a calibration) is going.
    Running,
    /// The run holds before its next cell.
    Paused,
    /// The last run was aborted by the operator.
    Aborted,
    /// The last run went through the plate.
    Finished,
    /// The last run or task stopped on a fault.
    Fault,
}

/// The field of view under the objective, as the plate map shows it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FieldView {
    /// Its number in the survey's order, from 0.
    pub index: usize,
    /// Fields over the plate.
    pub of: usize,
    /// m, the plate's rectangle in view: `[x_lo, y_lo, x_hi, y_hi]`, plate
    /// coordinates.
    pub rect_m: [f64; 4],
    /// m, the feeder's position: a plate point `p` is at stage `p + feeder_m`.
    pub feeder_m: [f64; 2],
}

/// A cell of the run, as the map and the overlay show it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CellView {
    /// Order in the survey.
    pub index: usize,
    /// [row, column].
    pub well: [u32; 2],
    /// m, stage coordinates of its centre (as measured).
    pub x_m: f64,
    /// m.
    pub y_m: f64,
    /// m.
    pub diameter_m: f64,
    /// `pending`, `current`, `injected`, `failed`, `skipped`, `interrupted`.
    pub status: &'static str,
}

/// A point of the tracking-error plot: the tip's distance to the cell's centre at the
/// pulse.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ErrorPoint {
    /// The cell.
    pub cell: usize,
    /// m, as vision and the sensors saw it.
    pub measured_m: Option<f64>,
    /// m, the backend's truth (the twin).
    pub true_m: Option<f64>,
}

/// The run in progress (or the last one).
#[derive(Debug, Clone, PartialEq, Serialize, Default)]
pub struct RunView {
    /// The record's id, once known.
    pub id: Option<i64>,
    /// The workflow's state.
    pub workflow: Option<State>,
    /// Cells the survey found.
    pub cells_found: usize,
    /// Attempts ended.
    pub done: usize,
    /// Injected.
    pub injected: usize,
    /// Failed.
    pub failed: usize,
    /// Skipped.
    pub skipped: usize,
    /// Touched, then stopped by an abort.
    pub interrupted: usize,
    /// The cells.
    pub cells: Vec<CellView>,
    /// The cell being worked on.
    pub current: Option<usize>,
    /// The field of view the feeder has brought under the objective.
    pub field: Option<FieldView>,
    /// Tracking error per attempt.
    pub errors: Vec<ErrorPoint>,
    /// (s of device time since the first cell, attempts ended).
    pub throughput: Vec<[f64; 2]>,
    /// Attempts per minute of device time.
    pub cells_per_min: f64,
    /// s, device time the run started.
    pub started_s: f64,
    /// s, device time of the first cell.
    pub cells_from_s: Option<f64>,
    /// Why it stopped, if it did.
    pub stopped: Option<String>,
}

/// A line of the log.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LogLine {
    /// s, device time.
    pub t: f64,
    /// What happened.
    pub text: String,
}

/// What the control thread writes and the web side reads.
#[derive(Debug, Clone, Serialize)]
pub struct Board {
    /// The bench's state.
    pub state: BenchState,
    /// What the control thread is doing: `run`, `calibrate`, `jog`, `safe` or none.
    pub task: Option<&'static str>,
    /// An abort was taken and the control thread is still bringing the bench to
    /// its safe state.
    pub stopping: bool,
    /// The last problem or refusal, in words.
    pub message: Option<String>,
    /// The run in progress, or the last one.
    pub run: Option<RunView>,
    /// A hysteresis calibration is at hand for the next run.
    pub calibrated: bool,
    /// The last lines of the workflow's log.
    pub log: Vec<LogLine>,
}

const LOG_LINES: usize = 40;

/// The state shared by the control thread, the view thread and the web side.
pub struct Shared {
    /// The run's switches.
    pub control: Arc<Control>,
    /// The devices' readings.
    pub telemetry: Arc<Telemetry>,
    /// The board.
    pub board: Mutex<Board>,
    /// A task is queued or going.
    pub busy: AtomicBool,
    /// The server is shutting down: the control thread ends after its task.
    pub quit: AtomicBool,
    /// The plate.
    pub plate: PlateView,
    /// The backend's name.
    pub backend: String,
}

impl Shared {
    /// Changes the board.
    pub fn update<R>(&self, f: impl FnOnce(&mut Board) -> R) -> R {
        f(&mut lock(&self.board))
    }
    /// A copy of the board.
    pub fn board(&self) -> Board {
        lock(&self.board).clone()
    }
}

/// A move of one axis by a step, within the devices' limits (the safety envelope and
/// the stage's travel refuse anything past them).
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Jog {
    /// `A1`, `A2`, `A3` (a step in volts) or `x`, `y`, `z` (the stage, a step in m).
    pub axis: JogAxis,
    /// V for a stack, m for the stage.
    pub by: f64,
}

/// What a jog moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
pub enum JogAxis {
    /// Stack A1.
    A1,
    /// Stack A2.
    A2,
    /// Stack A3 (the pipette's own axis).
    A3,
    /// Stage x.
    #[serde(rename = "x")]
    X,
    /// Stage y (up, away from the plate).
    #[serde(rename = "y")]
    Y,
    /// Stage z.
    #[serde(rename = "z")]
    Z,
}

/// Largest stack step of one jog, V.
pub const JOG_MAX_VOLTS: f64 = 10.0;
/// Largest stage step of one jog, m.
pub const JOG_MAX_STAGE: f64 = 100e-6;

impl Jog {
    /// Refuses a step that is not a number or larger than a jog may be.
    pub fn check(&self) -> Result<(), String> {
        let (max, unit) = match self.axis {
            JogAxis::A1 | JogAxis::A2 | JogAxis::A3 => (JOG_MAX_VOLTS, "V"),
            _ => (JOG_MAX_STAGE, "m"),
        };
        if !self.by.is_finite() || self.by.abs() > max {
            return Err(format!(
                "`by` must be a finite step of at most {max} {unit} for {:?}, got {}",
                self.axis, self.by
            ));
        }
        Ok(())
    }
}

/// What the control thread is asked to do.
#[derive(Debug)]
pub enum Command {
    /// A run of the plate.
    Run,
    /// The stacks' hysteresis calibration (kept for the next runs).
    Calibrate,
    /// A jog, and where its outcome goes.
    Jog(
        Jog,
        Option<tokio::sync::oneshot::Sender<Result<(), String>>>,
    ),
    /// The safe state now: A3 to 0 V, then A1 and A2.
    Safe,
}

/// The workflow's observer on the board: the map, the plots, the log; pause and abort.
struct Watch<'a> {
    shared: &'a Shared,
}

impl Watch<'_> {
    fn run<R>(&self, f: impl FnOnce(&mut RunView) -> R) -> Option<R> {
        self.shared.update(|b| b.run.as_mut().map(f))
    }
}

impl Observer for Watch<'_> {
    fn transition(&mut self, t: &Transition) {
        if t.event == Event::Begin {
            self.shared.telemetry.clear_map();
        }
        self.shared.update(|b| {
            if let Some(r) = b.run.as_mut() {
                r.workflow = Some(t.to);
            }
            if b.log.len() == LOG_LINES {
                b.log.remove(0);
            }
            b.log.push(LogLine {
                t: t.t,
                text: format!("{:?} -> {:?}: {}", t.from, t.to, t.reason),
            });
        });
    }
    fn mapped(&mut self, map: &ImageMap) {
        self.shared.telemetry.set_map(*map);
    }
    fn field(&mut self, index: usize, of: usize, rect: [f64; 4], feeder: [f64; 2]) {
        self.run(|r| {
            r.field = Some(FieldView {
                index,
                of,
                rect_m: rect,
                feeder_m: feeder,
            })
        });
    }
    fn surveyed(&mut self, targets: &[Target]) -> Result<(), String> {
        let p = self.shared.plate;
        self.run(|r| {
            r.cells_found = targets.len();
            r.cells = targets
                .iter()
                .map(|t| CellView {
                    index: t.index,
                    well: t.well,
                    x_m: t.x_m + p.origin_m[0],
                    y_m: t.y_m + p.origin_m[1],
                    diameter_m: t.diameter_m,
                    status: "pending",
                })
                .collect();
        });
        Ok(())
    }
    fn started(&mut self, a: &Attempt) -> Result<(), String> {
        self.run(|r| {
            r.cells_from_s.get_or_insert(a.t[0]);
            r.current = Some(a.target.index);
            if let Some(c) = r.cells.iter_mut().find(|c| c.index == a.target.index) {
                c.status = "current";
            }
        });
        Ok(())
    }
    fn finished(&mut self, a: &Attempt) -> Result<(), String> {
        self.run(|r| {
            if let Some(c) = r.cells.iter_mut().find(|c| c.index == a.target.index) {
                c.status = a.outcome.name();
            }
            r.current = None;
            r.done += 1;
            match a.outcome.name() {
                "injected" => r.injected += 1,
                "failed" => r.failed += 1,
                "interrupted" => r.interrupted += 1,
                _ => r.skipped += 1,
            }
            if a.contact {
                r.errors.push(ErrorPoint {
                    cell: a.target.index,
                    measured_m: a.measured_tip_error_m,
                    true_m: a.truth.tip_error_m,
                });
            }
            let from = r.cells_from_s.unwrap_or(a.t[0]);
            let dt = a.t[1] - from;
            r.throughput.push([dt, r.done as f64]);
            if dt > 0.0 {
                r.cells_per_min = r.done as f64 / dt * 60.0;
            }
        });
        Ok(())
    }
    fn proceed(&mut self) -> Result<(), String> {
        let c = &self.shared.control;
        let mut held = false;
        loop {
            if c.aborted() {
                return Err("aborted by the operator".into());
            }
            if !c.paused() {
                if held {
                    self.shared.update(|b| {
                        if !c.aborted() {
                            b.state = BenchState::Running;
                        }
                    });
                }
                return Ok(());
            }
            if !held {
                held = true;
                self.shared.update(|b| {
                    if !c.aborted() {
                        b.state = BenchState::Paused;
                    }
                });
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// Starts the control thread: it owns `station` and does one command at a time.
pub fn spawn(
    mut station: Box<dyn Station>,
    shared: Arc<Shared>,
) -> (Sender<Command>, std::thread::JoinHandle<()>) {
    let (tx, rx): (Sender<Command>, Receiver<Command>) = channel();
    let handle = std::thread::Builder::new()
        .name("cellinject-control".into())
        .spawn(move || {
            let mut calibration: Option<HysteresisCalibration> = None;
            loop {
                let cmd = match rx.recv_timeout(Duration::from_millis(100)) {
                    Ok(cmd) => cmd,
                    Err(RecvTimeoutError::Timeout) if !shared.quit.load(Ordering::SeqCst) => {
                        continue;
                    }
                    Err(_) => break,
                };
                execute(&mut *station, &shared, cmd, &mut calibration);
                // Free, all at once under the board's lock (a claim, a pause or an
                // abort sees either the task or nothing going).
                shared.update(|b| {
                    b.task = None;
                    b.stopping = false;
                    shared.control.pause(false);
                    shared.busy.store(false, Ordering::SeqCst);
                });
            }
        })
        .expect("a thread can be spawned");
    (tx, handle)
}

/// The stacks' hysteresis identified with the pipette raised clear of the plate first
/// ([`calibrate::hysteresis_clear`]), at a run's number of samples.
fn calibrate_clear(station: &mut dyn Station) -> Result<HysteresisCalibration, String> {
    let (n, size) = (calibrate::HYSTERESIS_SAMPLES, calibrate::HYSTERESIS_SIZE);
    let drop = station.sweep_drop()?;
    calibrate::hysteresis_clear(station.rig(), drop, n, size).map_err(|e| e.to_string())
}

fn execute(
    station: &mut dyn Station,
    shared: &Shared,
    cmd: Command,
    calibration: &mut Option<HysteresisCalibration>,
) {
    let control = &shared.control;
    match cmd {
        Command::Run => {
            shared.update(|b| {
                // An abort taken since the request stays what the status says.
                if !control.aborted() {
                    b.state = BenchState::Running;
                }
                b.task = Some("run");
                b.message = None;
                b.run = Some(RunView {
                    started_s: shared.telemetry.readings().time,
                    ..RunView::default()
                });
            });
            let mut watch = Watch { shared };
            let aborted = || control.aborted();
            let r = station.run(&mut watch, calibration.clone(), &aborted);
            // The workflow parked the pipette on its way out; after an abort the
            // stacks go all the way to 0 V too (A3 first).
            let safe = if control.aborted() {
                safe_state(station.rig()).err()
            } else {
                None
            };
            shared.update(|b| match r {
                Ok(end) => {
                    if let Some(c) = end.calibration.clone() {
                        *calibration = Some(c);
                    }
                    b.calibrated = calibration.is_some();
                    b.state = if control.aborted() || end.status == "aborted" {
                        BenchState::Aborted
                    } else if end.status == "finished" {
                        BenchState::Finished
                    } else {
                        BenchState::Fault
                    };
                    if let Some(run) = b.run.as_mut() {
                        run.id = Some(end.id);
                        run.stopped = end.stopped.clone();
                        run.current = None;
                        if end.cells_per_min > 0.0 {
                            run.cells_per_min = end.cells_per_min;
                        }
                    }
                    b.message = match safe {
                        None => end.stopped,
                        Some(e) => Some(format!(
                            "{}; the safe state could not be reached: {e}",
                            end.stopped.unwrap_or_default()
                        )),
                    };
                }
                Err(e) => {
                    b.state = if control.aborted() {
                        BenchState::Aborted
                    } else {
                        BenchState::Fault
                    };
                    b.message = Some(e);
                }
            });
        }
        Command::Calibrate => {
            let before = shared.board().state;
            shared.update(|b| {
                if !control.aborted() {
                    b.state = BenchState::Running;
                }
                b.task = Some("calibrate");
                b.message = None;
            });
            let r = calibrate_clear(station);
            let safe = safe_state(station.rig());
            shared.update(|b| match (r, safe) {
                (Ok(c), Ok(())) => {
                    b.state = before;
                    b.message = Some(match c.problem() {
                        None => format!(
                            "stacks calibrated: fit rms {:.2} / {:.2} %",
                            100.0 * c.fit_rms_relative[0],
                            100.0 * c.fit_rms_relative[1]
                        ),
                        Some(p) => format!("the calibration failed its check: {p}"),
                    });
                    if c.problem().is_none() {
                        *calibration = Some(c);
                    }
                    b.calibrated = calibration.is_some();
                }
                (r, safe) => {
                    b.state = if control.aborted() {
                        BenchState::Aborted
                    } else {
                        BenchState::Fault
                    };
                    b.message = Some(match (r, safe) {
                        (Err(e), _) => format!("calibration: {e}"),
                        (_, Err(e)) => format!("the safe state: {e}"),
                        _ => String::new(),
                    });
                }
            });
        }
        Command::Jog(j, reply) => {
            shared.update(|b| b.task = Some("jog"));
            let mut r =
                jog(station.rig(), j).map_err(|e| format!("jog {:?} by {}: {e}", j.axis, j.by));
            if control.aborted() {
                // Aborted meanwhile: the safe state, whatever the jog did.
                let safe = safe_state(station.rig());
                r = Err(match safe {
                    Ok(()) => "aborted: the stacks are at 0 V (A3 first)".to_string(),
                    Err(e) => format!("aborted, and the safe state could not be reached: {e}"),
                });
            }
            shared.update(|b| b.message = r.clone().err());
            if let Some(reply) = reply {
                let _ = reply.send(r);
            }
        }
        Command::Safe => {
            shared.update(|b| b.task = Some("safe"));
            let r = safe_state(station.rig());
            shared.update(|b| {
                b.message = Some(match r {
                    Ok(()) => "safe state: A3 and then A1, A2 at 0 V".into(),
                    Err(e) => format!("the safe state could not be reached: {e}"),
                })
            });
        }
    }
    // Read the stacks and the stage once more, so that the readouts are fresh.
    let rig = station.rig();
    for s in rig.sensors.iter_mut() {
        let _ = s.read();
    }
    for axis in 0..3 {
        let _ = rig.stage.position(axis);
    }
}

/// A3 to 0 V (the pipette out along its own axis), then A1 and A2.
pub fn safe_state(rig: &mut Rig<DynBackend>) -> Result<(), cellinject_hw::HwError> {
    rig.piezo[2].set_voltage(0.0)?;
    rig.command_tilt([0.0, 0.0])?;
    Ok(())
}

fn jog(rig: &mut Rig<DynBackend>, j: Jog) -> Result<(), cellinject_hw::HwError> {
    match j.axis {
        JogAxis::A1 | JogAxis::A2 | JogAxis::A3 => {
            let k = match j.axis {
                JogAxis::A1 => 0,
                JogAxis::A2 => 1,
                _ => 2,
            };
            let v = rig.piezo[k].commanded_voltage() + j.by;
            rig.piezo[k].set_voltage(v)
        }
        JogAxis::X | JogAxis::Y | JogAxis::Z => {
            let axis = match j.axis {
                JogAxis::X => 0,
                JogAxis::Y => 1,
                _ => 2,
            };
            let p = rig.stage.position(axis)? + j.by;
            rig.stage.move_to(axis, p)
        }
    }
}
