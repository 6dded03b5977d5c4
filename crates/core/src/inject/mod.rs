//! The unattended injection workflow (Sec. 3.1 of the paper and its next step): the
//! macro stage brings the lifted pipette over each cell of the matrix feeder, A1 under
//! closed-loop control puts the tip on the cell's axis, A3 advances it until the
//! membrane gives and on to the cell's centre, a pressure pulse injects the dose, A3
//! withdraws, and the cell is looked at again.
//!
//! The sequence is the state machine of [`machine`]; this module acts in each state
//! over any backend's guarded [`Rig`] and reports an event. It does no IO: what is
//! recorded, and the twin's truth, go through an [`Observer`].
//!
//! What the workflow knows comes from its own measurements: the cells from one image
//! of the plate (the pipette out of view), the tip from each image
//! (`cellinject_cells::tip`), the map between image and stage from four stage moves,
//! the stacks' hysteresis from their sensors, the membrane's give from the cell being
//! pushed ahead of the tip and snapping back, the dose from the dye's darkening. The
//! plate file's cells are never read (only its grid).

pub mod approach;
mod attempt;
mod height;
mod imaging;
pub mod machine;
mod motion;
mod options;
mod outcome;
mod setup;
mod survey;
pub mod window;

use cellinject_cells::tip::Tip;
use cellinject_cells::{Kind as BlobKind, Options as DetectOptions};
use cellinject_control::{Controller, Feedforward, Measurement, SensorGains, SensorLoop, Stacks};
use cellinject_hw::{Camera, CameraSettings, Clock, HwError, Optics, PiezoChannel};
use cellinject_hw::{PositionSensor, Roi, Stage};
use cellinject_model::Design;
use cellinject_plate::Plate;
use cellinject_plate::fields::{self, Field, FieldPlan, PlanError, Travel};

use cellinject_rig::{Backend, Rig, RigParams};
use serde::Serialize;
use thiserror::Error;

use crate::calibrate::{HYSTERESIS_SIZE, HysteresisCalibration};
pub use height::{Height, SideReference};
pub use imaging::ImageMap;
use imaging::*;
pub use machine::{Event, State, Transition};
use motion::*;
pub use options::Options;
pub use outcome::*;

/// s, the longest a withdrawal of A3 may take before the run stops on a fault.
const RETRACT_TIMEOUT: f64 = 2.0;

/// m, A3's extension while the image map measures its direction. The direction's error
/// is the tip detector's noise over this length, and every cell is approached along
/// it: over the 15-25 µm from the aligned tip to a cell's centre, a probe of 5 µm left a
/// lateral bias of 0.3-0.6 µm that varied from run to run (seeds 1 and 22); 20 µm along
/// the line between two wells stays clear of every cell (they lie within their wells).
const A3_PROBE: f64 = 20e-6;

/// m, half the range of the first field's focus sweep: a plate's floor may lie this
/// far from the focal plane where it is loaded.
const FOCUS_RANGE: f64 = 40e-6;

/// m, how close a field's centre must lie to one focused before for that field's
/// plane to serve it, extended (the plan made on the measured image map moves the
/// first field by some micrometres from the one the calibration focused).
const FOCUS_REUSE: f64 = 0.25e-3;

/// Binning of the focus frames (2 x 2: 1.76 um pixels at the lowest zoom).
const FOCUS_BINNING: u32 = 2;

/// Tiles (columns, rows) of a focus frame: each gives the floor's focus at its centre.
const FOCUS_TILES: [usize; 2] = [3, 3];

/// s, waited after each step of the feeder's height before a focus frame (its
/// residual vibration).
const FOCUS_SETTLE: f64 = 0.05;

/// Mean |frame / background - 1| over a cell's disc below which it has not moved
/// since the background was taken (the sensor's noise gives 0.015; a move of 1.5 um
/// leaves rims several times that).
const STILL_RESIDUAL: f64 = 0.035;

/// m, farthest the resting tip may be from where the image map puts it (in the object
/// plane, at either of the re-check's two stage positions) before the image is mapped
/// again. The map only brings the tip to the start of the approach; the cell is found
/// again in the image and a cell more than 1.5 um from where the map puts it is
/// followed (the same bound). The check's own noise is 0.2-0.6 um (the tip detector's
/// 0.2-0.4 px), and mapping again costs some 15 s and scatters the map by about as
/// much over the plate, so a smaller bound would map again for nothing.
const RECHECK_TOLERANCE: f64 = 1.5e-6;

/// Frames whose tips are combined (by their median) wherever one position of the tip
/// decides a step: a single frame's tip stands 2-4 px behind the true one along the
/// pipette about once in 50 frames.
const TIP_FRAMES: usize = 5;

/// m of the top of the image the window leaves to the pipette: the tip finder needs
/// that much of the pipette in view above the cells (it comes in from the top).
const TOP_BAND: f64 = 200e-6;

/// m kept clear of the image's left, right and bottom edges by the window: a cell at
/// the window's edge is whole in the frame with its blur.
const WINDOW_MARGIN: f64 = 5e-6;

/// m by which the first field's window is narrowed on every side before the image is
/// mapped (the window then comes from the rig's set-up, which puts the resting tip
/// near the image's centre with the stage at its origin, not from a measurement): the
/// prototype's views are centred 30 µm off the tip.
const BOOTSTRAP_MARGIN: f64 = 60e-6;

/// Frames of the resting tip whose fitted blurs measure the tip's blur before any
/// position is taken ([`Workflow::blur`]).
const BLUR_MIN: usize = 15;

/// Sub-pixel steps per axis of the stage pattern over which the run first learns the
/// tip's blur ([`Workflow::learn_blur`]): 4 x 4 positions a quarter pixel apart.
const BLUR_PHASES: usize = 4;

/// m the glass stands beyond the frame's edge for a background (its shank's width and
/// its marker tab, 0.14 mm beside the tip, with room; [`ImageMap::out_of_view`]).
const OUT_OF_VIEW_MARGIN: f64 = 0.3e-3;

/// How far a glass's defocused shadow reaches beside it per metre of its height above
/// focus ([`ImageMap::out_of_view`]): half, where a 2.5x objective's geometric blur
/// (its NA, about 0.08) is a sixth of that and the twin's shadow (four σ of its
/// defocus) 0.2.
const OUT_OF_VIEW_SPREAD: f64 = 0.5;

/// m, farthest the stage moves the tip (in focus, across the plate) to find plain
/// floor on which to learn its blur ([`Workflow::learn_blur`]).
const BLUR_REACH: f64 = 40e-6;

/// m, how far ahead of the tip's end the floor under the tip locator's strip must be
/// plain when the blur is learnt ([`plainest`]).
const PLAIN_AHEAD: f64 = 10e-6;

/// m, how far behind the tip's end, along the glass (the locator reads the tube's
/// darkness up to 50 um behind the end).
const PLAIN_BEHIND: f64 = 55e-6;

/// m, how far either side of the glass's axis.
const PLAIN_ACROSS: f64 = 12e-6;

/// The most frames of the resting tip whose fitted blurs make the tip's blur.
const BLUR_FRAMES: usize = 60;

/// Why a run could not start or had to stop.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum WorkflowError {
    /// A setting out of its domain.
    #[error("{arg} {reason}, got {value}")]
    Invalid {
        /// The option.
        arg: &'static str,
        /// Its value.
        value: f64,
        /// What is wrong.
        reason: String,
    },
    /// The plate cannot be served: wells beyond the feeder's reach, or a view too
    /// small for a well. Nothing has moved when this is returned before the
    /// calibrations (always, unless the measured view differs from the set-up's).
    #[error("the plate cannot be served: {0}")]
    Plan(PlanError),
    /// The wells are too wide for the view: a field must show two walls along each
    /// axis (the image map's points lie on them).
    #[error(
        "the wells' pitch ({pitch_um:.0} µm) leaves fewer than two walls along {axis} in a field of {field_um:.0} µm at zoom {zoom}: use a lower zoom"
    )]
    PitchTooLarge {
        /// um.
        pitch_um: f64,
        /// um, the field's size along the axis.
        field_um: f64,
        /// "x" or "y".
        axis: &'static str,
        /// Zoom.
        zoom: f64,
    },
    /// A calibration failed its check twice.
    #[error("the {what} calibration failed its check: {reason}")]
    Calibration {
        /// Which.
        what: &'static str,
        /// Why, with numbers.
        reason: String,
    },
    /// A device failed where the run cannot go on.
    #[error("{what}: {source}")]
    Device {
        /// Doing what.
        what: &'static str,
        /// The device's error.
        source: HwError,
    },
    /// The observer (the run records) failed.
    #[error("recording the run failed: {0}")]
    Record(String),
    /// The workflow met an event its state does not expect (a bug).
    #[error("the workflow got {event:?} in state {state:?}")]
    Illegal {
        /// State.
        state: State,
        /// Event.
        event: Event,
    },
}

fn dev(what: &'static str) -> impl Fn(HwError) -> WorkflowError {
    move |source| WorkflowError::Device { what, source }
}

/// A cell seen in a field: its plate point (m), diameter (m) and the diameter's
/// standard error (m, where measured).
type Seen = ([f64; 2], f64, Option<f64>);

const DT: f64 = 1e-3;

/// The workflow over one rig.
pub struct Workflow<'r, B: Backend> {
    rig: &'r mut Rig<B>,
    plate: Plate,
    options: Options,
    stacks: Stacks,
    gain_a3: f64,
    dye_contrast: f64,
    conductance: f64,
    /// The pipette's glass and its mount angle.
    pipette: cellinject_rig::PipetteParams,
    /// m of tip motion (x, height) per metre of A1 and A2 extension: the mechanism
    /// model's Jacobian at rest ([`crate::calibrate::model_jacobian`]).
    jacobian: [[f64; 2]; 2],
    /// m, A1's and A2's travels.
    travel_a12: [f64; 2],
    /// m, the stage height that puts the tip in the focal plane with the stacks held
    /// at their zero: the option's focus, less the tip's height above where the
    /// session's first run found it (the side camera's [`SideReference`], else the
    /// stacks' sensors against `rest` through the mechanism's Jacobian).
    focus: f64,
    /// What measured the tip's height ([`RunReport::focus_by`]).
    focus_by: &'static str,
    /// m, A1's and A2's sensor readings at which the option's focus puts the tip in
    /// focus: the stacks as the session's first run found them (a later run of the
    /// session is given them, [`Workflow::with_session`]), else as this run finds them.
    rest: Option<[f64; 2]>,
    /// The session's side reference of the tip's height ([`SideReference`]): given
    /// by the session, or taken as this run starts; `None` when the side camera could
    /// not take one.
    side: Option<SideReference>,
    /// m, the surveyed cells' mean diameter: the plate is focused on their equators,
    /// so a cell of diameter d has its centre (d - mean) / 2 above the focal plane.
    mean_diameter: f64,
    state: State,
    log: Vec<Transition>,
    servo: Option<Servo>,
    map: Option<ImageMap>,
    settings_full: Option<CameraSettings>,
    home: [f64; 3],
    consecutive_faults: usize,
    low_doses: usize,
    dead_in_row: usize,
    survey_cells: Vec<Target>,
    background: Option<Background>,
    /// Pixels, the blur of the resting tip's end in each of the latest [`BLUR_FRAMES`]
    /// full frames of it (fitted with its position).
    blurs: Vec<f64>,
    /// The check of a loaded hysteresis calibration against the stacks, if one was
    /// loaded and passed its own check.
    response_check: Option<crate::calibrate::ResponseCheck>,
    /// s, device time at which the image map was last made or checked.
    last_check: f64,
    /// Why a re-check is due before the next cell (a fault), if one is.
    check_due: Option<String>,
    /// The feeder stage's reach.
    travel: Travel,
    /// The fields over the plate, once planned.
    plan: Option<FieldPlan>,
    /// The field the feeder has brought under the objective.
    field: Option<Field>,
    /// m, the feeder's position read after it brought the current field (a plate
    /// point `p` is then at stage `p + feeder_at`).
    feeder_at: [f64; 2],
    /// The field each surveyed cell is injected in, by the cell's index.
    target_field: Vec<usize>,
    /// The planes of best focus measured so far, one per field focused (plate
    /// coordinates; `z` the feeder height that focuses the field's centre).
    focused: Vec<FieldFocus>,
    /// The current field's plane of best focus, once measured.
    field_focus: Option<FieldFocus>,
    /// Where the pipette was sent out of view while the feeder moved (the next
    /// background's first way, [`Workflow::ways_out`]).
    leaving: Option<[Option<f64>; 3]>,
}

/// A field's plane of best focus, from a through-focus sweep of the feeder's height
/// (see `cellinject_cells::focus`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FieldFocus {
    /// m, plate point (x, y) of the field's centre.
    pub centre_m: [f64; 2],
    /// m, the plate rectangle in view, `[x_lo, y_lo, x_hi, y_hi]`.
    pub rect_m: [f64; 4],
    /// m, the feeder height that brings the floor at the centre into focus.
    pub feeder_z_m: f64,
    /// m/m, how much higher the feeder must go per metre along plate x and y to focus
    /// the floor there (the floor falls by as much).
    pub slope: [f64; 2],
    /// Tiles of the frame whose focus the plane rests on (0: the whole frame's focus,
    /// no tilt measured).
    pub tiles: usize,
    /// m, rms distance of those tiles' foci from the plane.
    pub residual_m: f64,
    /// Frames the sweep took (0: the plane of a field focused before, centred within
    /// 0.25 mm of this one, extended to it).
    pub frames: usize,
}

impl FieldFocus {
    /// m, the feeder height that focuses plate point `p`.
    pub fn feeder_z_at(&self, p: [f64; 2]) -> f64 {
        self.feeder_z_m
            + self.slope[0] * (p[0] - self.centre_m[0])
            + self.slope[1] * (p[1] - self.centre_m[1])
    }

    /// m, how far above the focal plane the floor at plate point `p` stands with
    /// the feeder at this field's height.
    pub fn floor_at(&self, p: [f64; 2]) -> f64 {
        self.feeder_z_m - self.feeder_z_at(p)
    }
}

/// Why an attempt was skipped (the cell not touched), for what follows it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Skip {
    /// A neighbour blocks the approach even off-centre: nothing was off, so no re-check
    /// follows.
    Blocked,
    /// A fault before contact (the tip or the cell lost, a stage move refused, ...): the
    /// calibrations are re-checked before the next cell.
    Fault,
}

/// How a cell's procedure ended early.
enum Fail {
    /// A fault on this cell; the run goes on.
    Cell(String),
    /// The approach to this cell is blocked by a neighbour (the cell is skipped); the
    /// run goes on.
    Blocked(String),
    /// A fault the run stops on.
    Fatal(String),
    /// The operator stopped the run (an abort): the run stops; a touched cell is
    /// recorded interrupted, not failed.
    Interrupted(String),
    /// The records failed.
    Error(WorkflowError),
}

impl From<WorkflowError> for Fail {
    fn from(e: WorkflowError) -> Self {
        match e {
            WorkflowError::Device {
                source: HwError::Refused(r),
                what,
            } => Fail::Cell(format!("{what}: refused by the safety envelope: {r}")),
            WorkflowError::Record(_) | WorkflowError::Illegal { .. } => Fail::Error(e),
            WorkflowError::Device {
                source: HwError::Interrupted { .. },
                ..
            } => Fail::Interrupted(e.to_string()),
            other => Fail::Fatal(other.to_string()),
        }
    }
}

impl<'r, B: Backend> Workflow<'r, B> {
    /// A workflow on `rig` for `plate` (its grid only). The stacks are described by
    /// `design` and `params`.
    pub fn new(
        rig: &'r mut Rig<B>,
        design: &Design,
        params: &RigParams,
        plate: &Plate,
        options: Options,
    ) -> Result<Self, WorkflowError> {
        options.check(params)?;
        let stacks = Stacks {
            gain: [0, 1].map(|i| design.actuators[i].travel / params.amplifiers[i].v_max),
            v_max: [params.amplifiers[0].v_max, params.amplifiers[1].v_max],
        };
        Ok(Workflow {
            rig,
            plate: Plate {
                cells: Vec::new(),
                debris: Vec::new(),
                ..plate.clone()
            },
            options,
            stacks,
            gain_a3: design.actuators[2].travel / params.amplifiers[2].v_max,
            dye_contrast: params.pipette.dye_contrast,
            conductance: params.pipette.conductance(),
            pipette: params.pipette,
            jacobian: crate::calibrate::model_jacobian(design, params.approach).map_err(|e| {
                WorkflowError::Calibration {
                    what: "mechanism model",
                    reason: e.to_string(),
                }
            })?,
            travel_a12: [design.actuators[0].travel, design.actuators[1].travel],
            focus: options.focus,
            focus_by: "stack sensors",
            rest: None,
            side: None,
            mean_diameter: 0.0,
            state: State::Start,
            log: Vec::new(),
            servo: None,
            map: None,
            settings_full: None,
            home: [0.0; 3],
            consecutive_faults: 0,
            low_doses: 0,
            dead_in_row: 0,
            survey_cells: Vec::new(),
            background: None,
            blurs: Vec::new(),
            response_check: None,
            last_check: 0.0,
            check_due: None,
            travel: {
                let (lo, hi) = params.feeder_limits();
                Travel {
                    lo: [lo; 2],
                    hi: [hi; 2],
                }
            },
            plan: None,
            field: None,
            feeder_at: [0.0; 2],
            target_field: Vec::new(),
            focused: Vec::new(),
            field_focus: None,
            leaving: None,
        })
    }

    /// What the session's first run found ([`RunReport::session`]): a session's later
    /// runs refer the focus to it. Without it the run takes the bench as it finds it
    /// (right on a bench at rest since long, not after a run: the stacks then still
    /// creep back from it, and a second run of the dashboard that measured the tip's
    /// drop from that creeping start set its focus 1.4 um low).
    pub fn with_session(mut self, session: Option<Session>) -> Self {
        if let Some(s) = session {
            self.rest = Some(s.rest_m).filter(|r| r.iter().all(|v| v.is_finite()));
            self.side = s.side;
        }
        self
    }

    fn now(&self) -> f64 {
        self.rig.clock.now()
    }

    /// The fields of view the plate would be served in, from the view the rig's
    /// set-up gives at the run's zoom (the lens is set to it): a front end calls this
    /// at start to refuse a plate the feeder cannot present
    /// ([`WorkflowError::Plan`], [`WorkflowError::PitchTooLarge`]) before any run.
    /// Nothing else moves.
    pub fn fields(&mut self) -> Result<FieldPlan, WorkflowError> {
        self.rig
            .optics
            .set_zoom(self.options.zoom)
            .map_err(dev("zoom"))?;
        self.bootstrap_plan()
    }

    fn fire(
        &mut self,
        event: Event,
        reason: String,
        obs: &mut dyn Observer,
        into: Option<&mut Vec<Transition>>,
    ) -> Result<(), WorkflowError> {
        let to = machine::next(self.state, event).ok_or(WorkflowError::Illegal {
            state: self.state,
            event,
        })?;
        let t = Transition {
            t: self.now(),
            from: self.state,
            event,
            to,
            reason,
        };
        obs.transition(&t);
        match into {
            Some(v) => v.push(t),
            None => {
                obs.logged(&t).map_err(WorkflowError::Record)?;
                self.log.push(t)
            }
        }
        self.state = to;
        Ok(())
    }

    /// Runs the whole plate. `hysteresis`: a calibration to use if it passes its
    /// check (else the stacks are identified again). Cells the observer says are done
    /// are left alone.
    pub fn run(
        mut self,
        hysteresis: Option<HysteresisCalibration>,
        obs: &mut dyn Observer,
    ) -> Result<(RunReport, HysteresisCalibration), WorkflowError> {
        let r = self.run_inner(hysteresis, obs);
        if r.is_err() {
            // Whatever ended the run (a device lost in calibration, between cells),
            // the pipette leaves for the safe state; the cause is what the caller
            // records.
            let _ = self.rest();
        }
        r
    }

    fn run_inner(
        &mut self,
        hysteresis: Option<HysteresisCalibration>,
        obs: &mut dyn Observer,
    ) -> Result<(RunReport, HysteresisCalibration), WorkflowError> {
        let t_start = self.now();
        self.fire(Event::Begin, "run started".into(), obs, None)?;
        let (cal, why) = self.calibrate(hysteresis)?;
        if let Some(map) = &self.map {
            obs.mapped(map);
        }
        self.fire(Event::Calibrated, why, obs, None)?;
        // The fields again, in the measured view (the feeder stays where it is when
        // the plate is in view there).
        let planned = match self.map {
            Some(map) => self.plan_for(&map, 0.0, self.feeder_at),
            None => Err(WorkflowError::Calibration {
                what: "image-to-stage",
                reason: "no map".into(),
            }),
        };
        match planned {
            Ok(p) => self.plan = Some(p),
            Err(e) => {
                let _ = self.fire(Event::Fatal, e.to_string(), obs, None);
                return Err(e);
            }
        }
        let targets = match self.survey(obs) {
            Ok(t) => t,
            Err(e) => {
                let _ = self.fire(Event::Fatal, e.to_string(), obs, None);
                return Err(e);
            }
        };
        obs.surveyed(&targets).map_err(WorkflowError::Record)?;
        let fields = self.plan.as_ref().map_or(1, |p| p.fields.len());
        self.fire(
            Event::Surveyed,
            format!(
                "{} cell{} found on the plate ({fields} field{} of view)",
                targets.len(),
                if targets.len() == 1 { "" } else { "s" },
                if fields == 1 { "" } else { "s" }
            ),
            obs,
            None,
        )?;
        let t_cells = self.now();
        let mut attempts = Vec::new();
        let mut stopped = None;
        for target in &targets {
            if let Err(why) = obs.proceed() {
                self.fire(Event::Fatal, why.clone(), obs, None)?;
                stopped = Some(why);
                break;
            }
            if let Some(why) = self.recheck_due()
                && let Some(fatal) = self.recheck(why, obs)?
            {
                stopped = Some(fatal);
                break;
            }
            if obs.done(target) {
                self.fire(
                    Event::CellSkipped,
                    format!(
                        "cell {} in well {:?} already attempted",
                        target.index, target.well
                    ),
                    obs,
                    None,
                )?;
                continue;
            }
            let k = self.target_field[target.index];
            if self.field.is_none_or(|f| f.index != k)
                && let Some(fatal) = self.enter_field(k, obs)?
            {
                stopped = Some(fatal);
                break;
            }
            match self.attempt(self.survey_cells[target.index], obs)? {
                (a, skip, None) => {
                    if a.outcome != Outcome::Injected && a.contact {
                        self.check_due = Some(format!(
                            "after a fault on cell {} ({})",
                            a.target.index, a.reason
                        ));
                    } else if skip == Some(Skip::Fault) {
                        self.check_due = Some(format!(
                            "after cell {} was skipped ({})",
                            a.target.index, a.reason
                        ));
                    }
                    attempts.push(a)
                }
                (a, _, Some(fatal)) => {
                    attempts.push(a);
                    stopped = Some(fatal);
                    break;
                }
            }
        }
        if stopped.is_none() {
            self.fire(Event::NoMoreCells, "every cell done".into(), obs, None)?;
        }
        self.rest()?;
        let end = self.now();
        let count = |o: Outcome| attempts.iter().filter(|a| a.outcome == o).count();
        let cell_time = end - t_cells;
        Ok((
            RunReport {
                cells_found: targets.len(),
                rest_m: self.rest.unwrap_or([0.0; 2]),
                focus_by: self.focus_by,
                tip_above_m: self.options.focus - self.focus,
                tip_blur_px: self.blur().unwrap_or(f64::NAN),
                session: Session {
                    rest_m: self.rest.unwrap_or([0.0; 2]),
                    side: self.side.clone(),
                },
                hysteresis_check: self.response_check.clone(),
                focus_m: self.focus,
                fields,
                injected: count(Outcome::Injected),
                failed: count(Outcome::Failed),
                skipped: count(Outcome::Skipped),
                sim_time_s: end - t_start,
                cell_time_s: cell_time,
                cells_per_min: if cell_time > 0.0 {
                    attempts.len() as f64 / cell_time * 60.0
                } else {
                    0.0
                },
                stopped,
                map: self.map,
                attempts,
                transitions: std::mem::take(&mut self.log),
                focus: self.focused.clone(),
            },
            cal,
        ))
    }

    /// Brings field `k` under the objective for its cells: the feeder moved, the
    /// background taken again there, the cells' stage positions updated. Returns why
    /// the run must stop, if it must.
    fn enter_field(
        &mut self,
        k: usize,
        obs: &mut dyn Observer,
    ) -> Result<Option<String>, WorkflowError> {
        let field = self.plan.as_ref().expect("plan").fields[k];
        let t0 = self.now();
        let why = match self.goto_field(field)? {
            Ok(()) => match self.take_background()? {
                Ok(()) => None,
                Err(e) => Some(format!(
                    "the background of field {k} could not be taken: {e}"
                )),
            },
            Err(e) => Some(e),
        };
        if let Some(why) = why {
            self.fire(Event::Fatal, why.clone(), obs, None)?;
            return Ok(Some(why));
        }
        self.place_targets();
        let of = self.plan.as_ref().map_or(1, |p| p.fields.len());
        obs.field(k, of, field.rect, self.feeder_at);
        let r = format!(
            "field {k} under the objective (feeder at {:.3}, {:.3} mm{}; {:.1} s)",
            self.feeder_at[0] * 1e3,
            self.feeder_at[1] * 1e3,
            self.focus_note(),
            self.now() - t0
        );
        self.fire(Event::FieldReached, r, obs, None)?;
        Ok(None)
    }
}

impl<B: Backend> Workflow<'_, B> {
    /// Renews the background from `shot` within `reach` pixels of `c` (full-frame
    /// pixels), except under the pipette's glass, whose tip `shot` shows at `tip`.
    fn refresh_background(&mut self, shot: &Shot, c: [f64; 2], reach: f64, tip: [f64; 2]) {
        let pix = shot.frame.pixel_size;
        let cos = self.pipette.angle.cos();
        let pipette = self.pipette;
        let blur = self.blur().unwrap_or(1.0);
        let Some(bg) = self.background.as_mut() else {
            return;
        };
        let (w, h) = (shot.frame.width as i64, shot.frame.height as i64);
        let l = shot.local(c);
        let t = shot.local(tip);
        let k = reach.ceil() as i64;
        for j in (l[1] as i64 - k)..=(l[1] as i64 + k) {
            for i in (l[0] as i64 - k)..=(l[0] as i64 + k) {
                let (dx, dy) = (i as f64 - l[0], j as f64 - l[1]);
                if i < 0 || j < 0 || i >= w || j >= h || dx.hypot(dy) > reach {
                    continue;
                }
                // Not where the glass lies (the image shows it foreshortened over the
                // cell): its pixels keep the old background. (No tip: no glass.)
                let behind = t[1] - j as f64;
                if behind > -4.0 * blur - 2.0
                    && (i as f64 - t[0]).abs()
                        < pipette.radius_at(behind.max(0.0) * pix / cos) / pix + 4.0 * blur + 3.0
                {
                    continue;
                }
                let (fi, fj) = (
                    (i + shot.origin[0] as i64) as usize,
                    (j + shot.origin[1] as i64) as usize,
                );
                bg.pixels[fj * bg.width + fi] = shot.frame.pixels[(j * w + i) as usize];
            }
        }
    }

    /// One cell: an attempt from the stage move to the verification. Returns the
    /// attempt, why it was skipped if it was (and the run goes on), and, if the run
    /// must stop, why.
    fn attempt(
        &mut self,
        target: Target,
        obs: &mut dyn Observer,
    ) -> Result<(Attempt, Option<Skip>, Option<String>), WorkflowError> {
        let mut a = Attempt {
            target,
            outcome: Outcome::Skipped,
            reason: String::new(),
            contact: false,
            measured_tip_error_m: None,
            depth_m: None,
            pulse: None,
            measured_dose_fraction: None,
            truth: Truth::default(),
            t: [self.now(), 0.0],
            transitions: Vec::new(),
        };
        obs.started(&a).map_err(WorkflowError::Record)?;
        let grazed0 = obs.grazed();
        let why = format!(
            "cell {} in well [{}, {}], {:.1} µm at ({:.1}, {:.1}) µm",
            target.index,
            target.well[0],
            target.well[1],
            target.diameter_m * 1e6,
            target.x_m * 1e6,
            target.y_m * 1e6
        );
        self.fire(Event::CellChosen, why, obs, Some(&mut a.transitions))?;
        let result = self.procedure(&mut a, obs);
        let mut fatal = None;
        let blocked = matches!(result, Err(Fail::Blocked(_)));
        match result {
            Ok(()) => self.consecutive_faults = 0,
            Err(Fail::Error(e)) => return Err(e),
            Err(Fail::Cell(reason) | Fail::Blocked(reason)) => {
                self.consecutive_faults += 1;
                self.fire(
                    Event::CellFault,
                    reason.clone(),
                    obs,
                    Some(&mut a.transitions),
                )?;
                a.outcome = if a.contact {
                    Outcome::Failed
                } else {
                    Outcome::Skipped
                };
                a.reason = reason;
                match self.park() {
                    Ok(()) if self.consecutive_faults < 3 => {
                        self.fire(
                            Event::Recovered,
                            "pipette retracted, stacks at rest, pipette lifted".into(),
                            obs,
                            Some(&mut a.transitions),
                        )?;
                    }
                    Ok(()) => {
                        let r = format!(
                            "{} cells in a row failed (last: {}): stopping",
                            self.consecutive_faults, a.reason
                        );
                        self.fire(Event::Fatal, r.clone(), obs, Some(&mut a.transitions))?;
                        fatal = Some(r);
                    }
                    Err(e) => {
                        let r = format!("the safe state could not be reached: {e}");
                        self.fire(Event::Fatal, r.clone(), obs, Some(&mut a.transitions))?;
                        fatal = Some(r);
                    }
                }
            }
            Err(Fail::Fatal(reason)) => {
                fatal = Some(self.stop_in_cell(&mut a, reason, false, obs)?)
            }
            Err(Fail::Interrupted(reason)) => {
                fatal = Some(self.stop_in_cell(&mut a, reason, true, obs)?)
            }
        }
        if a.contact
            && let Some((dose, alive)) = obs.cell_truth(&a.target)
        {
            a.truth.dose_fraction = Some(dose);
            a.truth.alive = Some(alive);
        }
        a.truth.grazed = obs.grazed().zip(grazed0).map(|(n, m)| n.saturating_sub(m));
        a.t[1] = self.now();
        obs.finished(&a).map_err(WorkflowError::Record)?;
        let skip = (fatal.is_none() && a.outcome == Outcome::Skipped).then_some(if blocked {
            Skip::Blocked
        } else {
            Skip::Fault
        });
        Ok((a, skip, fatal))
    }

    /// A cell's procedure ended in a fault the run stops on (`by_operator`: an
    /// abort): the safe state, the attempt's outcome (a touched cell is failed, or
    /// interrupted by the operator), the transition. Returns why the run stops.
    fn stop_in_cell(
        &mut self,
        a: &mut Attempt,
        reason: String,
        by_operator: bool,
        obs: &mut dyn Observer,
    ) -> Result<String, WorkflowError> {
        let parked = self.park();
        let r = match parked {
            Ok(()) => format!("{reason} (pipette retracted, stacks at rest)"),
            Err(e) => format!("{reason}; the safe state could not be reached either: {e}"),
        };
        verdict_on_stop(a, reason, by_operator);
        self.fire(Event::Fatal, r.clone(), obs, Some(&mut a.transitions))?;
        Ok(r)
    }
}
#[cfg(test)]
mod tests {
    /// The ways out of view, against the geometry worked by hand: a 2592 x 1944 frame
    /// at 0.88 um/px, the tip at column 300, row 1050, the glass straight up the image
    /// (A3 moves the tip down the rows, foreshortened to 0.57), 1 px per um of stage
    /// x along the columns. The glass at the frame's top edge stands 0.924 mm x
    /// sqrt(1 - 0.57^2) / 0.57 + 0.2 mm (lifts) = 1.52 mm above the tip: margin
    /// 0.3 mm + half that = 1.06 mm = 1205.6 px. Left: 300 + 1205.6 px; right:
    /// 2592 - 300 + 1205.6 px; the left is shorter and comes first.
    #[test]
    fn the_pipette_leaves_the_view_by_the_shorter_side() {
        let pix = 0.88e-6;
        let f = 0.57;
        let map = super::ImageMap {
            pixel0: [300.0, 1050.0],
            stage0: [0.0, 0.0],
            b: [[1.0 / pix, 0.0], [0.0, 1.0 / pix]],
            residual_px: 0.0,
            a1: [1.0 / pix, 0.0],
            a3: [0.0, f / pix],
            pixel_size: pix,
        };
        let frame = [2592.0, 1944.0];
        let [first, second] = map.out_of_view([0.0, 0.0], frame, 0.3e-3).unwrap();
        let high = 1050.0 * pix * (1.0f64 - f * f).sqrt() / f + 0.2e-3;
        let m = (0.3e-3 + 0.5 * high) / pix;
        let left = -(300.0 + m) * pix;
        let right = (2592.0 - 300.0 + m) * pix;
        assert!(
            (first[0] - left).abs() < 1e-12 && first[1].abs() < 1e-12,
            "{first:?}"
        );
        assert!((second[0] - right).abs() < 1e-12, "{second:?}");
        // The glass wholly beyond the frame from there: the tip's column and the
        // glass's column at the top edge (the same: it runs up the rows).
        assert!(map.pixel_of(first)[0] + m <= 1e-6);
        // A tip out of view, or no axis: no way from the map.
        assert!(map.out_of_view(first, frame, 0.3e-3).is_none());
        let flat = super::ImageMap {
            a3: [0.0; 2],
            ..map
        };
        assert!(flat.out_of_view([0.0, 0.0], frame, 0.3e-3).is_none());
    }

    /// A size known or uncertain doses for the measured diameter; an uncertain one
    /// is said so in the pulse's line, with its standard error.
    #[test]
    fn an_uncertain_size_is_recorded_and_dosed_for_its_measure() {
        let known = super::dose_diameter(10e-6, Some(0.08e-6));
        assert_eq!((known.diameter, known.uncertain), (10e-6, None));
        assert_eq!(known.note(), "");
        let d = super::dose_diameter(10e-6, Some(0.6e-6));
        assert_eq!((d.diameter, d.uncertain), (10e-6, Some([10e-6, 0.6e-6])));
        assert!(
            d.note().contains("size uncertain (10.0 +- 0.6 µm)"),
            "{}",
            d.note()
        );
        // Not measured: the detector's worst error taken, and said.
        let none = super::dose_diameter(10e-6, None);
        assert_eq!(none.uncertain, Some([10e-6, 0.5e-6]));
        assert_eq!(
            super::dose_diameter(10e-6, Some(f64::NAN)).uncertain,
            Some([10e-6, 0.5e-6])
        );
    }

    use super::*;

    /// A background of plain floor at 150 with the plate's walls (dark lines every
    /// 170 px, 4 px wide, at 110) and one dark cell; `plainest` must carry the tip's
    /// end, put at a wall crossing, so far that the glass behind it too lies off every
    /// wall and away from the cell, within its reach.
    #[test]
    fn the_blur_is_learnt_on_plain_floor_off_the_walls() {
        let (w, h) = (400usize, 400usize);
        let pixel = 0.88e-6;
        let mut pixels = vec![150u16; w * h];
        for j in 0..h {
            for i in 0..w {
                let wall = |k: usize| (k % 170) < 4;
                let cell = (i as f64 - 200.0).hypot(j as f64 - 190.0) < 12.0;
                if wall(i) || wall(j) || cell {
                    pixels[j * w + i] = 110;
                }
            }
        }
        let bg = Background {
            pixels,
            width: w,
            pixel_size: pixel,
        };
        // The tip's end at the crossing of the walls at x = 171..175, y = 171..175.
        // The glass comes down the image (its axis towards the tip along +y).
        let tip = [172.0, 172.0];
        let d = plainest(&bg, tip, [0.0, 1.0], pixel);
        assert!(d[0].abs() <= BLUR_REACH + 1e-12 && d[1].abs() <= BLUR_REACH + 1e-12);
        let at = [tip[0] + d[0] / pixel, tip[1] + d[1] / pixel];
        // The strip the locator reads around the new end (10 um ahead, 55 um behind,
        // 12 um either side) touches no wall and not the cell.
        let px = |m: f64| (m / pixel).ceil() as usize;
        let (x0, x1) = (
            at[0].round() as usize - px(12e-6),
            at[0].round() as usize + px(12e-6),
        );
        let (y0, y1) = (
            at[1].round() as usize - px(55e-6),
            at[1].round() as usize + px(10e-6),
        );
        for j in y0..=y1 {
            for i in x0..=x1 {
                assert_eq!(bg.pixels[j * w + i], 150, "({i}, {j}) for offset {d:?}");
            }
        }
    }

    fn attempt(outcome: Outcome, contact: bool, reason: &str) -> Attempt {
        Attempt {
            target: Target {
                diameter_se_m: None,
                index: 0,
                well: [0, 0],
                x_m: 0.0,
                y_m: 0.0,
                diameter_m: 20e-6,
                stage_m: [0.0, 0.0],
            },
            outcome,
            reason: reason.into(),
            contact,
            measured_tip_error_m: None,
            depth_m: None,
            pulse: None,
            measured_dose_fraction: None,
            truth: Truth::default(),
            t: [0.0; 2],
            transitions: Vec::new(),
        }
    }

    #[test]
    fn the_median_ignores_one_frame_far_off() {
        assert_eq!(median(vec![0.1, -3.0, 0.2, 0.0, 0.15]), 0.1);
        assert!((median(vec![0.2, 0.1, -3.0, 0.3]) - 0.15).abs() < 1e-12);
        assert_eq!(median(vec![2.0]), 2.0);
        assert!(median(Vec::new()).is_nan());
    }

    #[test]
    fn a_stop_in_a_cell_keeps_a_judged_outcome_and_says_why() {
        let abort = "clock: interrupted: aborted by the operator";
        // Not touched: skipped, for the stop's reason.
        let mut a = attempt(Outcome::Skipped, false, "");
        verdict_on_stop(&mut a, abort.into(), true);
        assert_eq!((a.outcome, a.reason.as_str()), (Outcome::Skipped, abort));
        // Touched, not judged: interrupted by an abort, failed by a fault.
        let mut a = attempt(Outcome::Skipped, true, "");
        verdict_on_stop(&mut a, abort.into(), true);
        assert_eq!(a.outcome, Outcome::Interrupted);
        let mut a = attempt(Outcome::Skipped, true, "");
        verdict_on_stop(&mut a, "stage: stalled".into(), false);
        assert_eq!(
            (a.outcome, a.reason.as_str()),
            (Outcome::Failed, "stage: stalled")
        );
        // Judged: the outcome stays; a verdict of its own comes first, then the abort.
        let mut a = attempt(Outcome::Injected, true, "");
        verdict_on_stop(&mut a, abort.into(), true);
        assert_eq!((a.outcome, a.reason.as_str()), (Outcome::Injected, abort));
        let mut a = attempt(Outcome::Failed, true, "dose 40 % of the target");
        verdict_on_stop(&mut a, abort.into(), true);
        assert_eq!(a.outcome, Outcome::Failed);
        assert_eq!(a.reason, format!("dose 40 % of the target; then {abort}"));
        // A fault after a verdict leaves the verdict as it was (the fault is the run's
        // reason to stop).
        let mut a = attempt(Outcome::Failed, true, "dose 40 % of the target");
        verdict_on_stop(&mut a, "stage: stalled".into(), false);
        assert_eq!(a.reason, "dose 40 % of the target");
    }
}
