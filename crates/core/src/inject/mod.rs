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
pub mod machine;
mod setup;
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
pub use machine::{Event, State, Transition};

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

/// Settings of a run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Options {
    /// Magnification (a plate larger than the view is served field by field).
    pub zoom: f64,
    /// Injected volume aimed at, fraction of the cell's volume.
    pub target_fraction: f64,
    /// Pa, injection pressure.
    pub pressure: f64,
    /// m, tip-to-membrane gap before the approach.
    pub gap: f64,
    /// m, how high the stage lifts the pipette over the cells between wells (above the
    /// focal plane: the tip cannot touch a cell lower than its radius).
    pub lift: f64,
    /// m, stage height (optical axis) at which the tip is in focus.
    pub focus: f64,
    /// m/s, A3's approach speed.
    pub approach_speed: f64,
    /// Deepest the tip may be driven past the cell's centre, fraction of its radius.
    pub depth_limit: f64,
    /// m, lateral tip-to-axis error accepted before the approach.
    pub align_tolerance: f64,
    /// s, longest a stage move may take.
    pub stage_deadline: f64,
    /// Excitation samples (1 ms apart) of the hysteresis identification.
    pub hysteresis_samples: usize,
    /// Farthest the aim may move off the cell's centre across the pipette's axis
    /// (sideways or up), fraction of its radius, for the glass to pass a neighbour
    /// that blocks the centred approach; keep it below the membrane's tear limit with
    /// room for the tip error.
    pub max_off_centre: f64,
    /// s of device time between two re-checks of the background and the
    /// image-to-stage map (the bench drifts with temperature); 0: only after a fault.
    /// A fault on a cell always brings a re-check before the next one.
    pub recheck_every: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            zoom: 2.5,
            target_fraction: 0.05,
            pressure: 2.0e4,
            gap: 6e-6,
            lift: 30e-6,
            focus: 0.0,
            approach_speed: 60e-6,
            depth_limit: 0.25,
            align_tolerance: 0.15e-6,
            stage_deadline: 2.0,
            hysteresis_samples: crate::calibrate::HYSTERESIS_SAMPLES,
            max_off_centre: 0.3,
            recheck_every: 300.0,
        }
    }
}

impl Options {
    /// Refuses settings out of their domain, naming the option.
    pub fn check(&self, rig: &RigParams) -> Result<(), WorkflowError> {
        let bad = |arg: &'static str, value: f64, reason: &str| {
            Err(WorkflowError::Invalid {
                arg,
                value,
                reason: reason.into(),
            })
        };
        let (z0, z1) = (rig.optics.zoom_range[0], rig.optics.zoom_range[1]);
        if !(self.zoom.is_finite() && self.zoom >= z0 && self.zoom <= z1) {
            return bad("--zoom", self.zoom, "must lie in the zoom range");
        }
        if !(self.target_fraction.is_finite()
            && self.target_fraction > 0.0
            && self.target_fraction <= 0.1)
        {
            return bad(
                "--dose",
                self.target_fraction,
                "must lie in (0, 0.1] of the cell's volume",
            );
        }
        if !(self.pressure.is_finite()
            && self.pressure > 0.0
            && self.pressure <= rig.injector_max_pressure)
        {
            return bad(
                "--pressure",
                self.pressure,
                "must be positive and within the injector's limit",
            );
        }
        if !(self.lift.is_finite() && self.lift >= 16e-6 && self.lift <= 1e-3) {
            return bad(
                "--lift",
                self.lift,
                "must lie in [16 um, 1 mm] (above the largest cell's radius)",
            );
        }
        if !(self.recheck_every.is_finite() && self.recheck_every >= 0.0) {
            return bad(
                "--recheck-every",
                self.recheck_every,
                "must be a finite number of seconds, 0 or more (0: re-check only after a fault)",
            );
        }
        if !(self.max_off_centre.is_finite() && (0.0..=0.6).contains(&self.max_off_centre)) {
            return bad(
                "--max-off-centre",
                self.max_off_centre,
                "must lie in [0, 0.6] of the cell's radius",
            );
        }
        if !(self.stage_deadline.is_finite() && self.stage_deadline > 0.0) {
            return bad("--stage-deadline", self.stage_deadline, "must be positive");
        }
        for (arg, v) in [
            ("gap", self.gap),
            ("approach speed", self.approach_speed),
            ("depth limit", self.depth_limit),
            ("align tolerance", self.align_tolerance),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(arg, v, "must be positive");
            }
        }
        if !self.focus.is_finite() {
            return bad("focus", self.focus, "must be finite");
        }
        Ok(())
    }
}

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
        "the wells' pitch ({pitch_um:.0} um) leaves fewer than two walls along {axis} in a field of {field_um:.0} um at zoom {zoom}: use a lower zoom"
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

/// A cell found in the survey.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Target {
    /// Order in the survey.
    pub index: usize,
    /// [row, column].
    pub well: [u32; 2],
    /// m, plate coordinates of its centre (as measured).
    pub x_m: f64,
    /// m.
    pub y_m: f64,
    /// m, as measured.
    pub diameter_m: f64,
    /// m, the measured diameter's standard error (from the membrane's four quarters;
    /// null where fewer than three show it): how well the size, and so the dose, is
    /// known.
    pub diameter_se_m: Option<f64>,
    /// m, stage (x, z) that puts the resting tip on its centre.
    #[serde(skip)]
    pub stage_m: [f64; 2],
}

/// How an attempt ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Injected with its dose, looks alive.
    Injected,
    /// Touched but not injected as intended (no give, dose off, the cell died).
    Failed,
    /// Not touched (unreachable, lost, a fault before contact).
    Skipped,
    /// The process was killed after contact.
    Interrupted,
}

impl Outcome {
    /// The name used in records and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Outcome::Injected => "injected",
            Outcome::Failed => "failed",
            Outcome::Skipped => "skipped",
            Outcome::Interrupted => "interrupted",
        }
    }
}

/// What the backend's truth says about an attempt (the twin only).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Default)]
pub struct Truth {
    /// m, tip to the cell's true centre in the focal plane when the pulse started.
    pub tip_error_m: Option<f64>,
    /// Injected volume over the cell's volume.
    pub dose_fraction: Option<f64>,
    /// The cell is alive.
    pub alive: Option<bool>,
    /// Other cells the pipette's glass (not its tip) ran into during the attempt.
    pub grazed: Option<u32>,
}

/// One cell attempt.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Attempt {
    /// The cell.
    pub target: Target,
    /// How it ended.
    pub outcome: Outcome,
    /// Why (for anything but a clean injection).
    pub reason: String,
    /// The pipette touched the cell.
    pub contact: bool,
    /// m, tip to the cell's centre as vision and the A3 sensor saw it at injection.
    pub measured_tip_error_m: Option<f64>,
    /// m, how far the tip went into the cell past its membrane (A3's sensor).
    pub depth_m: Option<f64>,
    /// Pa and s of the pulse.
    pub pulse: Option<[f64; 2]>,
    /// Dose fraction the dye's darkening shows.
    pub measured_dose_fraction: Option<f64>,
    /// The backend's truth.
    pub truth: Truth,
    /// s, start and end (device time).
    pub t: [f64; 2],
    /// The transitions of this attempt.
    pub transitions: Vec<Transition>,
}

/// Where the run's records and the backend's truth go.
pub trait Observer {
    /// A transition happened.
    fn transition(&mut self, _t: &Transition) {}
    /// The feeder brought field `index` of `of` under the objective; `rect` is the
    /// plate's rectangle in view, `[x_lo, y_lo, x_hi, y_hi]`, m in plate coordinates,
    /// and `feeder` the feeder's position (a plate point `p` is at stage `p + feeder`).
    fn field(&mut self, _index: usize, _of: usize, _rect: [f64; 4], _feeder: [f64; 2]) {}
    /// The survey found these cells.
    fn surveyed(&mut self, _targets: &[Target]) -> Result<(), String> {
        Ok(())
    }
    /// Whether this cell was already attempted (a resumed run).
    fn done(&self, _target: &Target) -> bool {
        false
    }
    /// An attempt starts (nothing touched yet).
    fn started(&mut self, _a: &Attempt) -> Result<(), String> {
        Ok(())
    }
    /// The pipette touched the cell: from now on, the cell is never attempted again.
    fn contact(&mut self, _a: &Attempt) -> Result<(), String> {
        Ok(())
    }
    /// An attempt ended.
    fn finished(&mut self, _a: &Attempt) -> Result<(), String> {
        Ok(())
    }
    /// Asked before each cell, the pipette out of every cell: block here to hold the
    /// run (a pause), or answer `Err(why)` to end it (an abort: the pipette parks and
    /// the run reports `why` as why it stopped).
    fn proceed(&mut self) -> Result<(), String> {
        Ok(())
    }
    /// The image is mapped to the stage (before the survey, and again when a re-check
    /// finds the map off): where things are in the microscope's frames.
    fn mapped(&mut self, _map: &ImageMap) {}
    /// A transition of the run outside its cells (calibrated, surveyed, a re-check and
    /// its verdict, the end), after [`Observer::transition`]: to be recorded (an
    /// `Err` stops the run: the records failed).
    fn logged(&mut self, _t: &Transition) -> Result<(), String> {
        Ok(())
    }
    /// The tip's true distance to the cell (the twin), when the pulse starts.
    fn tip_error(&mut self, _target: &Target) -> Option<f64> {
        None
    }
    /// The cell's true dose and life (the twin), after the attempt.
    fn cell_truth(&mut self, _target: &Target) -> Option<(f64, bool)> {
        None
    }
    /// How many cells the pipette's glass behind its tip has run into so far (the
    /// twin): a planner that clears every neighbour keeps it still.
    fn grazed(&mut self) -> Option<u32> {
        None
    }
}

/// A cell seen in a field: its plate point (m), diameter (m) and the diameter's
/// standard error (m, where measured).
type Seen = ([f64; 2], f64, Option<f64>);

/// m: a diameter whose standard error exceeds this is uncertain ([`dose_diameter`]):
/// more than twice a round cell's alone (under 0.1 um), reached by small cells cut by
/// a touching partner.
const SIZE_SE_UNCERTAIN: f64 = 0.25e-6;

/// m, the standard error taken for a cell whose membrane fewer than three quarters
/// show: the detector's worst error on a doublet's 10 um partner (0.5 um).
const SIZE_SE_UNKNOWN: f64 = 0.5e-6;

/// The diameter a cell's dose is computed from, and whether its size was uncertain.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Dosed {
    /// m.
    diameter: f64,
    /// The measured diameter and its standard error (m) when the size was uncertain.
    uncertain: Option<[f64; 2]>,
}

impl Dosed {
    /// For the pulse's log line: empty when the size was known.
    fn note(&self) -> String {
        match self.uncertain {
            Some([d, se]) => format!(
                "; size uncertain ({:.1} +- {:.1} um): dosed for {:.1} um, its measured size",
                d * 1e6,
                se * 1e6,
                self.diameter * 1e6
            ),
            None => String::new(),
        }
    }
}

/// The diameter to dose a cell for, and whether its size is uncertain (standard error
/// `se` above [`SIZE_SE_UNCERTAIN`], or [`SIZE_SE_UNKNOWN`] taken where the detector
/// could not tell). Either way its measured diameter `d`: the estimate that errs as
/// little to one side as to the other, where the verification accepts 0.5 to 2 times
/// the target (a diameter 26 % off either way) and the twin lyses a cell at 3 times.
/// Dosing an uncertain cell one standard error smaller was tried: a 10 um cell
/// measured 10.0 +- 0.9 um got 59 % of its dose, which the dye's darkening (it reads
/// small cells about a third low) put at 50 %, and it failed its verification; no
/// size error of the detector (1 um at worst) comes near the lytic dose.
fn dose_diameter(d: f64, se: Option<f64>) -> Dosed {
    let se = se.filter(|s| s.is_finite()).unwrap_or(SIZE_SE_UNKNOWN);
    Dosed {
        diameter: d,
        uncertain: (se > SIZE_SE_UNCERTAIN).then_some([d, se]),
    }
}

/// An attempt's outcome and reason when the run stops in its cell for `reason`
/// (`by_operator`: an abort). Untouched, it stays skipped; touched and not yet judged, it
/// is interrupted (an abort) or failed (a fault); judged already (the dose measured,
/// the pipette withdrawing), it keeps its outcome. The reason is the stop's, or the
/// cell's own verdict followed by the abort.
fn verdict_on_stop(a: &mut Attempt, reason: String, by_operator: bool) {
    if a.outcome == Outcome::Skipped && a.contact {
        a.outcome = if by_operator {
            Outcome::Interrupted
        } else {
            Outcome::Failed
        };
    }
    if a.reason.is_empty() {
        a.reason = reason;
    } else if by_operator {
        a.reason = format!("{}; then {reason}", a.reason);
    }
}

/// The image-to-stage map and the actuators' directions in the image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ImageMap {
    /// Full-frame pixel of the tip with the stage at `stage0` (A1, A2, A3 at rest).
    pub pixel0: [f64; 2],
    /// m, stage (x, z) of `pixel0`.
    pub stage0: [f64; 2],
    /// Pixels per metre of stage motion: columns and rows by stage x and z.
    pub b: [[f64; 2]; 2],
    /// RMS residual of the four-point fit, pixels.
    pub residual_px: f64,
    /// Pixels per metre of A1's extension (its sensor).
    pub a1: [f64; 2],
    /// Pixels per metre of A3's extension: the tip's motion down the pipette's axis as
    /// the microscope sees it (foreshortened by the mount angle).
    pub a3: [f64; 2],
    /// m per pixel of the frames.
    pub pixel_size: f64,
}

impl ImageMap {
    /// The stage motion (m) that moves the tip by `d` pixels.
    fn stage_delta(&self, d: [f64; 2]) -> [f64; 2] {
        let [[a, b], [c, e]] = self.b;
        let det = a * e - b * c;
        [(e * d[0] - b * d[1]) / det, (-c * d[0] + a * d[1]) / det]
    }

    /// The stage position (m) that puts the resting tip at full-frame pixel `px`.
    pub fn stage_of(&self, px: [f64; 2]) -> [f64; 2] {
        let d = self.stage_delta([px[0] - self.pixel0[0], px[1] - self.pixel0[1]]);
        [self.stage0[0] + d[0], self.stage0[1] + d[1]]
    }

    /// The full-frame pixel of the resting tip with the stage at `s` (m) (also where
    /// a cell whose `stage_m` is `s` appears).
    pub fn pixel_of(&self, s: [f64; 2]) -> [f64; 2] {
        let (u, v) = (s[0] - self.stage0[0], s[1] - self.stage0[1]);
        [
            self.pixel0[0] + self.b[0][0] * u + self.b[0][1] * v,
            self.pixel0[1] + self.b[1][0] * u + self.b[1][1] * v,
        ]
    }

    /// The two shortest stage moves (m, stage x and z, the shorter first) that take
    /// the pipette wholly out of a `frame` (columns, rows) from stage position `stage`:
    /// sideways across the image, to the left or to the right, until every column the
    /// glass covers in view (from the tip back along the pipette's axis, `-a3`, to the
    /// frame's edge) stands `margin` (m) beyond the frame, and more by
    /// [`OUT_OF_VIEW_SPREAD`] of the glass's height there above focus (its defocused
    /// shadow). `None` when the tip is not in
    /// the frame or the map has no axis.
    pub fn out_of_view(
        &self,
        stage: [f64; 2],
        frame: [f64; 2],
        margin: f64,
    ) -> Option<[[f64; 2]; 2]> {
        let t = self.pixel_of(stage);
        let n = self.a3[0].hypot(self.a3[1]);
        let inside =
            |p: [f64; 2]| (0.0..=frame[0]).contains(&p[0]) && (0.0..=frame[1]).contains(&p[1]);
        if !(n > 0.0 && n.is_finite() && inside(t) && self.pixel_size > 0.0) {
            return None;
        }
        let s = [-self.a3[0] / n, -self.a3[1] / n];
        // Where the shank leaves the frame.
        let exit = |p: f64, d: f64, hi: f64| {
            if d > 0.0 {
                (hi - p) / d
            } else if d < 0.0 {
                -p / d
            } else {
                f64::INFINITY
            }
        };
        let l = exit(t[0], s[0], frame[0]).min(exit(t[1], s[1], frame[1]));
        let end = t[0] + l * s[0];
        // The glass rises out of focus behind the tip (the image sees its length
        // foreshortened by f = cos of its angle): at the frame's edge it stands `high`
        // above the tip (and the focus sweeps lift it up to 0.2 mm more), and its
        // defocused shadow spreads with that height.
        let f = (n * self.pixel_size).clamp(1e-3, 1.0);
        let high = l * self.pixel_size * (1.0 - f * f).sqrt() / f + 0.2e-3;
        let m = (margin + OUT_OF_VIEW_SPREAD * high) / self.pixel_size;
        let left = -(t[0].max(end) + m);
        let right = frame[0] - t[0].min(end) + m;
        let to = |dc: f64| {
            let d = self.stage_delta([dc, 0.0]);
            [stage[0] + d[0], stage[1] + d[1]]
        };
        Some(if -left <= right {
            [to(left), to(right)]
        } else {
            [to(right), to(left)]
        })
    }
}

/// What a session's first run found of the resting tip, for the session's later
/// runs ([`Workflow::with_session`]).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Session {
    /// m, A1's and A2's sensor readings at which the option's focus puts the tip in
    /// focus (used when the side camera cannot measure the tip's height).
    pub rest_m: [f64; 2],
    /// The side camera's reference of the tip's height, taken with the stacks at
    /// rest as the session's first run started.
    pub side: Option<SideReference>,
}

/// The run's summary.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunReport {
    /// Cells the survey found.
    pub cells_found: usize,
    /// m, A1's and A2's sensor readings the stack sensors' fallback refers the focus
    /// to (the session's rest, carried in [`RunReport::session`]).
    pub rest_m: [f64; 2],
    /// A loaded hysteresis calibration checked against the stacks (null when none was
    /// loaded, or it failed its own check): [`crate::calibrate::ResponseCheck`].
    pub hysteresis_check: Option<crate::calibrate::ResponseCheck>,
    /// m, the stage height that put the tip in focus with the stacks at their zero
    /// as last measured (after the image map, or at the last re-check): the option's
    /// focus less [`RunReport::tip_above_m`].
    pub focus_m: f64,
    /// What measured the tip's height: `"side camera"` (the marker tab against the
    /// session's side reference) or `"stack sensors"` (their readings against the
    /// session's rest, through the model's Jacobian).
    pub focus_by: &'static str,
    /// m, how much higher the resting tip stood than where the session's first run
    /// found it (negative: lower), as last measured.
    pub tip_above_m: f64,
    /// Pixels (of the full frames), the blur of the tip's end in focus that every
    /// tip location used ([`Workflow::learn_blur`]; NaN, null in the records, if never
    /// learnt).
    pub tip_blur_px: f64,
    /// What the session's next run refers its focus to (not in the records: it holds
    /// the side reference's frame).
    #[serde(skip)]
    pub session: Session,
    /// Fields of view the plate was served in.
    pub fields: usize,
    /// Attempts by outcome.
    pub injected: usize,
    /// Failed.
    pub failed: usize,
    /// Skipped.
    pub skipped: usize,
    /// s, device time of the whole run (calibration included).
    pub sim_time_s: f64,
    /// s, device time from the first cell to the last.
    pub cell_time_s: f64,
    /// Attempts per minute of `cell_time_s`.
    pub cells_per_min: f64,
    /// Why the run stopped early, if it did.
    pub stopped: Option<String>,
    /// The map and directions in use.
    pub map: Option<ImageMap>,
    /// This run's attempts (a resumed run: only the new ones).
    pub attempts: Vec<Attempt>,
    /// The transitions outside attempts (calibration, survey, the end).
    pub transitions: Vec<Transition>,
    /// The fields' planes of best focus, in the order they were measured.
    pub focus: Vec<FieldFocus>,
}

/// The closed loops that hold the stacks: A1/A2 in the control crate's sensor loop
/// (inverse hysteresis model plus PI on the strain gauges), A3 by feedforward plus an
/// integrator on its gauge. Stepped at 1 kHz whenever time passes.
struct Servo {
    ctl: SensorLoop,
    refs: [f64; 2],
    a3_ref: f64,
    a3_int: f64,
    a3_gain: f64,
    a3_vmax: f64,
    zero: [f64; 3],
    t: f64,
}

const DT: f64 = 1e-3;

impl Servo {
    fn step<B: Backend>(&mut self, rig: &mut Rig<B>) -> Result<(), WorkflowError> {
        let mut e = [0.0; 3];
        for (k, e) in e.iter_mut().enumerate() {
            *e = rig.sensors[k].read().map_err(dev("stack sensor"))? - self.zero[k];
        }
        let m = Measurement {
            stacks: Some([e[0], e[1]]),
            ..Measurement::default()
        };
        let v = self.ctl.step(self.t, self.refs, &m);
        let applied = rig.command_tilt(v).map_err(dev("A1/A2"))?;
        self.ctl.applied(applied);
        let err = self.a3_ref - e[2];
        self.a3_int = (self.a3_int + 0.05 * err / self.a3_gain)
            .clamp(-0.3 * self.a3_vmax, 0.3 * self.a3_vmax);
        let v3 = (self.a3_ref / self.a3_gain + self.a3_int).clamp(0.0, self.a3_vmax);
        rig.piezo[2].set_voltage(v3).map_err(dev("A3"))?;
        Ok(())
    }

    /// Lets `seconds` pass, stepping the loops; `ramp` moves A3's reference towards
    /// `(target, speed)` meanwhile.
    fn wait<B: Backend>(
        &mut self,
        rig: &mut Rig<B>,
        seconds: f64,
        ramp: Option<(f64, f64)>,
    ) -> Result<(), WorkflowError> {
        let end = rig.clock.now() + seconds;
        // The ramp moves with the time that passed since the last step (at least one
        // step's DT): a bench whose clock is the wall clock (a GCS controller on a
        // loaded host) steps less often than every DT, and a ramp counted in steps
        // fell behind there (A3 left 6 um out after a withdrawal of 0.08 s).
        let mut last = rig.clock.now() - DT;
        loop {
            let now = rig.clock.now();
            if now >= end - 1e-9 {
                return Ok(());
            }
            if let Some((target, speed)) = ramp {
                let step = speed * (now - last).max(DT);
                self.a3_ref += (target - self.a3_ref).clamp(-step, step);
            }
            last = now;
            self.step(rig)?;
            let dt = DT.min(end - now);
            rig.clock.sleep(dt).map_err(dev("clock"))?;
            self.t += dt;
        }
    }

    fn a3(&mut self, rig: &mut Rig<impl Backend>) -> Result<f64, WorkflowError> {
        Ok(rig.sensors[2].read().map_err(dev("A3 sensor"))? - self.zero[2])
    }
}

/// A frame and where its pixel (0, 0) is on the full sensor.
struct Shot {
    frame: cellinject_hw::Frame,
    origin: [f64; 2],
    /// The glass's outer taper as the microscope sees it (foreshortened).
    taper: f64,
}

impl Shot {
    fn full(&self, p: [f64; 2]) -> [f64; 2] {
        [p[0] + self.origin[0], p[1] + self.origin[1]]
    }
    fn local(&self, p: [f64; 2]) -> [f64; 2] {
        [p[0] - self.origin[0], p[1] - self.origin[1]]
    }
    /// This frame divided by the background (the same view with the pipette out of
    /// it: the feeder's walls and the cells divide out, the pipette stays), scaled to
    /// 2000; `None` for a frame far darker or brighter than the background (the light
    /// off, a bubble, a flash), which shows nothing to trust.
    fn normalised(&self, background: &Background) -> Option<Vec<u16>> {
        let f = &self.frame;
        let (w, h) = (f.width as usize, f.height as usize);
        let (ox, oy) = (self.origin[0] as usize, self.origin[1] as usize);
        let mut norm = Vec::with_capacity(w * h);
        for (j, row) in f.pixels.chunks_exact(w).take(h).enumerate() {
            let start = (oy + j) * background.width + ox;
            let bg = &background.pixels[start..start + w];
            norm.extend(row.iter().zip(bg).map(|(&p, &b)| {
                let v = p as f64 / b.max(1) as f64 * 2000.0;
                v.clamp(0.0, 65535.0) as u16
            }));
        }
        let mean = norm.iter().map(|&v| v as f64).sum::<f64>() / norm.len().max(1) as f64;
        (1000.0..4000.0).contains(&mean).then_some(norm)
    }

    /// The tip in `norm` (this frame [`Shot::normalised`]), in full-frame pixels;
    /// `blur`: the tip's blur (pixels) if known, else it is fitted too.
    fn locate(&self, norm: &[u16], blur: Option<f64>) -> Option<Tip> {
        let f = &self.frame;
        let (w, h) = (f.width as usize, f.height as usize);
        cellinject_cells::tip::locate_tapered(norm, w, h, f.pixel_size, blur, self.taper)
            .ok()
            .map(|t| {
                let [x, y] = self.full([t.x, t.y]);
                Tip { x, y, ..t }
            })
    }

    /// The tip, found in this frame divided by the background, with the tip's blur
    /// (pixels) if known.
    fn tip(&self, background: &Background, blur: Option<f64>) -> Option<[f64; 2]> {
        let norm = self.normalised(background)?;
        self.locate(&norm, blur).map(|t| [t.x, t.y])
    }
    /// Mean intensity of pixel (column, row) rounded, or None outside.
    fn at(&self, c: f64, r: f64) -> Option<f64> {
        let (w, h) = (self.frame.width as i64, self.frame.height as i64);
        let (i, j) = (c.round() as i64, r.round() as i64);
        (i >= 0 && j >= 0 && i < w && j < h).then(|| self.frame.pixels[(j * w + i) as usize] as f64)
    }
}

/// A full frame of the plate with the pipette out of view.
struct Background {
    pixels: Vec<u16>,
    width: usize,
    /// m per pixel.
    pixel_size: f64,
}

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
                "{} cells found on the plate ({fields} field{} of view)",
                targets.len(),
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

    /// Retracts A3, relaxes A1/A2 and lifts the pipette: the safe state.
    fn park(&mut self) -> Result<(), WorkflowError> {
        if let Some(mut s) = self.servo.take() {
            // A3 out first (straight back along its axis), then A1/A2 relaxed: never
            // sideways inside a cell.
            let r = s.wait(self.rig, 0.15, Some((0.0, 500e-6))).and_then(|()| {
                s.refs = [0.0; 2];
                s.wait(self.rig, 0.05, None)
            });
            self.servo = Some(s);
            if let Err(e) = r {
                // The loops lost a device (a link that broke, a reply that never
                // came): straight commands, retried while the link comes back, A3
                // first.
                self.park_direct().map_err(|_| e)?;
            }
        } else {
            // No loops running (calibrating, or they were never started).
            self.park_direct()?;
        }
        let lift = self.home[1].max(self.options.focus + self.options.lift);
        self.rig.stage.move_to(1, lift).map_err(dev("stage lift"))?;
        Ok(())
    }

    /// The end of a run, however it ends: parked, and A3 at 0 V (the loop held the
    /// withdrawn tip with a small offset; the stack rests at 0 V, the same whether the
    /// loops or straight commands parked it).
    fn rest(&mut self) -> Result<(), WorkflowError> {
        self.park()?;
        if let Some(s) = self.servo.as_mut() {
            s.a3_ref = 0.0;
            s.a3_int = 0.0;
        }
        self.rig.piezo[2].set_voltage(0.0).map_err(dev("A3"))
    }

    /// A3 to 0 V, then A1/A2 to 0 V, each retried for up to a second.
    fn park_direct(&mut self) -> Result<(), WorkflowError> {
        let mut last = None;
        for step in 0..2 {
            for _ in 0..10 {
                let r = if step == 0 {
                    self.rig.piezo[2].set_voltage(0.0)
                } else {
                    self.rig.command_tilt([0.0, 0.0]).map(|_| ())
                };
                match r {
                    Ok(()) => {
                        last = None;
                        break;
                    }
                    Err(e) => {
                        last = Some(e);
                        let _ = self.rig.clock.sleep(0.1);
                    }
                }
            }
            if let Some(e) = last.take() {
                return Err(WorkflowError::Device {
                    what: if step == 0 {
                        "A3 (safe state)"
                    } else {
                        "A1/A2 (safe state)"
                    },
                    source: e,
                });
            }
        }
        Ok(())
    }

    /// Lets `seconds` pass with the loops running; `ramp`: A3's reference moves
    /// towards (target, speed) meanwhile.
    fn servo_wait(&mut self, seconds: f64, ramp: Option<(f64, f64)>) -> Result<(), WorkflowError> {
        let mut s = self.servo.take().expect("servo");
        let r = s.wait(self.rig, seconds, ramp);
        self.servo = Some(s);
        r
    }

    fn wait(&mut self, seconds: f64) -> Result<(), WorkflowError> {
        self.servo_wait(seconds, None)
    }

    fn ramp_a3(&mut self, target: f64, speed: f64, seconds: f64) -> Result<(), WorkflowError> {
        self.servo_wait(seconds, Some((target, speed)))
    }

    /// Moves the stage; the deadline is the option's for moves of up to 1 mm, plus
    /// 1 s per further mm (the calibration's long moves).
    /// Moves the stage's height to `y` before the servo runs (no stack is driven):
    /// waits until it is there.
    fn raise_to(&mut self, y: f64) -> Result<(), WorkflowError> {
        self.rig.stage.move_to(1, y).map_err(dev("stage lift"))?;
        let t0 = self.now();
        while self.rig.stage.is_busy().map_err(dev("stage"))? {
            if self.now() - t0 > self.options.stage_deadline {
                return Err(WorkflowError::Device {
                    what: "stage",
                    source: HwError::Timeout {
                        device: "stage (missed its deadline)".into(),
                        seconds: self.options.stage_deadline,
                    },
                });
            }
            self.rig.clock.sleep(0.005).map_err(dev("clock"))?;
        }
        Ok(())
    }

    fn stage_to(&mut self, p: [Option<f64>; 3]) -> Result<Result<(), String>, WorkflowError> {
        let far = match self.stage_start(p)? {
            Ok(far) => far,
            Err(e) => return Ok(Err(e)),
        };
        let deadline = self.options.stage_deadline + (far - 1e-3).max(0.0) * 1e3;
        let t0 = self.now();
        while self.rig.stage.is_busy().map_err(dev("stage"))? {
            if self.now() - t0 > deadline {
                return Err(WorkflowError::Device {
                    what: "stage",
                    source: HwError::Timeout {
                        device: "stage (missed its deadline)".into(),
                        seconds: deadline,
                    },
                });
            }
            self.wait(0.005)?;
        }
        Ok(Ok(()))
    }

    /// Starts the stage's move to `p` (per axis; `None` stays) without waiting; returns
    /// the longest distance an axis has to go (m).
    fn stage_start(&mut self, p: [Option<f64>; 3]) -> Result<Result<f64, String>, WorkflowError> {
        let mut far = 0.0f64;
        for (axis, v) in p.iter().enumerate() {
            if let Some(v) = v {
                let now = self.rig.stage.position(axis).map_err(dev("stage"))?;
                far = far.max((v - now).abs());
            }
        }
        for (axis, v) in p.iter().enumerate() {
            if let Some(v) = v
                && let Err(e) = self.rig.stage.move_to(axis, *v)
            {
                return Ok(Err(format!("stage move refused: {e}")));
            }
        }
        Ok(Ok(far))
    }

    /// The stage positions (lifted to `lift`) that take the pipette out of the
    /// camera's view for a background, the first tried first: for a field served again
    /// once the survey is done (its focus known), the two shortest ways sideways out of
    /// the frame that the image map gives ([`ImageMap::out_of_view`]); then, and in the
    /// survey, a whole view to the left of the field's left edge (with the shorter way
    /// in the survey, field 2 of a strip plate could not be focused: its sweep swung
    /// between two heights that each saw the peak at an end).
    fn ways_out(&mut self, lift: f64, pixel: f64) -> Result<Vec<[Option<f64>; 3]>, WorkflowError> {
        let full = self.settings_full.expect("full settings");
        let fov = full.roi.width as f64 * pixel;
        let x0 = self.field.expect("field").rect[0] + self.feeder_at[0];
        let mut ways = Vec::new();
        // Only for a field served again once the survey is done: the survey keeps the
        // way its focus and its backgrounds were measured with.
        if let Some(map) = self
            .map
            .filter(|_| self.field_focus.is_some() && !self.survey_cells.is_empty())
        {
            let now = [
                self.rig.stage.position(0).map_err(dev("stage"))?,
                self.rig.stage.position(2).map_err(dev("stage"))?,
            ];
            let frame = [full.roi.width as f64, full.roi.height as f64];
            if let Some(two) = map.out_of_view(now, frame, OUT_OF_VIEW_MARGIN) {
                ways.extend(two.map(|p| [Some(p[0]), Some(lift), Some(p[1])]));
            }
        }
        ways.push([Some(x0 - fov - OUT_OF_VIEW_MARGIN), Some(lift), None]);
        Ok(ways)
    }

    fn shoot(&mut self, roi: Option<[f64; 2]>) -> Result<Shot, WorkflowError> {
        let full = self.settings_full.expect("full settings");
        let s = match roi {
            None => full,
            Some(c) => {
                let (sw, sh) = self.rig.camera.sensor_size();
                let (w, h) = (640u32.min(sw), 480u32.min(sh));
                let x = (c[0] - 0.5 * w as f64).round().clamp(0.0, (sw - w) as f64) as u32;
                let y = (c[1] - 0.5 * h as f64).round().clamp(0.0, (sh - h) as f64) as u32;
                CameraSettings {
                    roi: Roi {
                        x,
                        y,
                        width: w,
                        height: h,
                    },
                    binning: 1,
                    ..full
                }
            }
        };
        self.shoot_with(s)
    }

    /// A frame taken with camera settings `s`.
    fn shoot_with(&mut self, s: CameraSettings) -> Result<Shot, WorkflowError> {
        if self.rig.camera.settings() != s {
            self.rig.camera.configure(s).map_err(dev("camera"))?;
        }
        // Keep the loops running until just before the next exposure.
        let period = 1.0 / self.rig.camera.frame_rate();
        let wait = (period - s.exposure - 2e-3).max(0.0);
        self.wait(wait)?;
        let frame = self.rig.camera.grab().map_err(dev("camera"))?;
        Ok(Shot {
            frame,
            origin: [s.roi.x as f64, s.roi.y as f64],
            taper: self.pipette.outer_taper / self.pipette.angle.cos(),
        })
    }

    /// The resting tip in full frames: the median of [`TIP_FRAMES`] frames' tips
    /// (`tries`: frames without a tip tolerated on top), each found with the tip's blur
    /// known ([`Workflow::blur`], learnt on plain floor by [`Workflow::learn_blur`];
    /// should that leave fewer than [`BLUR_MIN`] fits, the frames here add theirs
    /// until there are enough):
    /// with the blur free, a frame's tip stood up to 5 px behind the true one along the
    /// axis (the fit trades the end's blur against its position in the noise), and the
    /// image map extrapolates each of its points' errors over the plate: seed 15's map,
    /// two of its four points 2-3 px off, put the first row's cells 7-11 um off along
    /// the pipette.
    fn tip_full(&mut self, tries: usize) -> Result<Option<[f64; 2]>, WorkflowError> {
        self.tip_full_at(tries, true)
    }

    /// As [`Self::tip_full`]; a tip out of focus (`in_focus` false) is located by the
    /// free fit alone, and its blur is not learnt.
    fn tip_full_at(
        &mut self,
        tries: usize,
        in_focus: bool,
    ) -> Result<Option<[f64; 2]>, WorkflowError> {
        if in_focus && self.blur().is_none() {
            self.learn_blur()?;
        }
        let mut seen = Vec::with_capacity(TIP_FRAMES);
        let mut misses = 0;
        while seen.len() < TIP_FRAMES && misses < tries {
            let shot = self.shoot(None)?;
            let bg = self.background.as_ref().expect("background");
            let Some(free) = shot.normalised(bg).and_then(|n| {
                let free = shot.locate(&n, None)?;
                Some((n, free))
            }) else {
                misses += 1;
                continue;
            };
            let (norm, free) = free;
            if !in_focus {
                seen.push([free.x, free.y]);
                continue;
            }
            // The blur is learnt on plain floor ([`Workflow::learn_blur`]); a frame
            // elsewhere adds its free fit only while too few fits are known (the
            // image map's points lie at the walls' crossings, where free fits learn
            // twice the optics' blur: measured 0.8-1.05 px against 0.5 px on plain
            // floor, and the tip located with it stood 0.1-0.2 um further behind the
            // true one along the axis, differently in every run).
            if self.blur().is_none() {
                self.add_blurs([free.sigma]);
            }
            let Some(blur) = self.blur() else {
                // Still measuring the blur.
                continue;
            };
            match shot.locate(&norm, Some(blur)) {
                Some(t) => seen.push([t.x, t.y]),
                None => misses += 1,
            }
        }
        if seen.len() < TIP_FRAMES.div_ceil(2) {
            return Ok(None);
        }
        let xs: Vec<f64> = seen.iter().map(|t| t[0]).collect();
        let ys: Vec<f64> = seen.iter().map(|t| t[1]).collect();
        Ok(Some([median(xs), median(ys)]))
    }

    /// Learns the tip's blur in focus from free fits of the resting tip over clean
    /// floor, with the stage stepped over a [`BLUR_PHASES`]² pattern a quarter pixel
    /// apart (the stage back where it stood after).
    ///
    /// A free fit trades the end's blur against its position, and it does so worst
    /// where the background is not plain: the image map's points lie at the crossings
    /// of the plate's walls, and there (seed 1 from a saved calibration) 15 frames
    /// learnt 1.4 px of blur where the optics give about 0.4 px; the tip located ever
    /// after with that blur stood 0.2 um behind the true one along the axis, and every
    /// cell's tip error grew by as much, while on a first run the stacks' creep after
    /// the identification had moved the tip's end a pixel off the wall. So the tip is
    /// first moved (lifted over the cells, and down into focus there) to the plainest
    /// floor within [`BLUR_REACH`] (no wall, no cell under the strip the locator reads:
    /// [`plainest`]; with only the end's 31 x 31 px window plain and 18 um of reach, a
    /// run from a saved calibration learnt 1.1 px where the optics give 0.5 px), and
    /// the phases within a pixel, on which a fit's blur also depends, are sampled
    /// evenly there.
    fn learn_blur(&mut self) -> Result<(), WorkflowError> {
        let here = [
            self.rig.stage.position(0).map_err(dev("stage"))?,
            self.rig.stage.position(2).map_err(dev("stage"))?,
        ];
        let pixel = self.background.as_ref().expect("background").pixel_size;
        let shot = self.shoot(None)?;
        let bg = self.background.as_ref().expect("background");
        let start = shot.normalised(bg).and_then(|n| shot.locate(&n, None));
        let centre = match start {
            Some(t) => {
                let d = plainest(bg, [t.x, t.y], t.axis, pixel);
                [here[0] + d[0], here[1] + d[1]]
            }
            None => here,
        };
        // Over the cells at the lift, to the patch and back (the patch may be up to
        // BLUR_REACH away, beyond the 18 um the tip could cross at focus height).
        let height = self.rig.stage.position(1).map_err(dev("stage"))?;
        let over = height.max(self.options.focus + self.options.lift);
        self.lifted_to([centre[0], centre[1]], over, height)?;
        let step = pixel / BLUR_PHASES as f64;
        let mut fits = Vec::with_capacity(BLUR_PHASES * BLUR_PHASES);
        for k in 0..BLUR_PHASES * BLUR_PHASES {
            let (i, j) = ((k % BLUR_PHASES) as f64, (k / BLUR_PHASES) as f64);
            let at = [centre[0] + i * step, centre[1] + j * step];
            if self.stage_to([Some(at[0]), None, Some(at[1])])?.is_err() {
                continue;
            }
            let shot = self.shoot(None)?;
            let bg = self.background.as_ref().expect("background");
            if let Some(t) = shot.normalised(bg).and_then(|n| shot.locate(&n, None)) {
                fits.push(t.sigma);
            }
        }
        self.add_blurs(fits);
        self.lifted_to(here, over, height)?;
        Ok(())
    }

    /// The stage to `xz` (m) by way of height `over`, then down to `height`; a move
    /// the stage refuses leaves it where it got.
    fn lifted_to(&mut self, xz: [f64; 2], over: f64, height: f64) -> Result<(), WorkflowError> {
        for p in [
            [None, Some(over), None],
            [Some(xz[0]), None, Some(xz[1])],
            [None, Some(height), None],
        ] {
            if self.stage_to(p)?.is_err() {
                break;
            }
        }
        Ok(())
    }

    /// Adds free fits' blurs, keeping the latest [`BLUR_FRAMES`].
    fn add_blurs(&mut self, fits: impl IntoIterator<Item = f64>) {
        self.blurs.extend(fits);
        let extra = self.blurs.len().saturating_sub(BLUR_FRAMES);
        self.blurs.drain(..extra);
    }

    /// Pixels, the blur of the tip's end in focus: the lower quartile of the latest
    /// [`BLUR_FRAMES`] free fits of the resting tip, once there are [`BLUR_MIN`] of
    /// them. The optics' blur at the focus is the same in every frame taken there; a
    /// single frame's free fit scatters from 0.3 to 6 px around it, and whatever
    /// spoils a frame (the floor's texture under the glass, the tip moving in the
    /// exposure) widens the fit, never narrows it: so the lower quartile, not the
    /// median (on a dashboard's second run 16 fits on plain floor gave 0.3-3.6 px,
    /// median 2.45 px against 0.5 px in focus, and every tip located with it stood
    /// 0.8 um behind the true one along the axis; three cells died).
    fn blur(&self) -> Option<f64> {
        (self.blurs.len() >= BLUR_MIN).then(|| lower_quartile(self.blurs.clone()))
    }

    /// The background: a full frame of the plate with the pipette lifted out of view
    /// (the tip is found against it, and the survey reads it): one field width to the
    /// field's left in the survey, the shortest way sideways out of the frame for a
    /// field served again ([`Workflow::ways_out`]; 1.4-1.7 s for a field change on a
    /// 3 x 40 strip, against 3.4 s and 1.4 s more to come back). Taken again at every
    /// re-check: a bench that drifts moves the plate's image (a change of
    /// magnification of 1e-4 moves the walls at the edge of the field by 0.1 px), and
    /// the stale edges would pull the tip detector.
    fn take_background(&mut self) -> Result<Result<(), String>, WorkflowError> {
        let lift = self.home[1];
        // m per pixel of the full frames: the last background's (taken with them), or on
        // the first call a frame's at the current binning.
        let pixel = match &self.background {
            Some(b) => b.pixel_size,
            None => {
                self.rig.camera.grab().map_err(dev("camera"))?.pixel_size
                    / self.rig.camera.settings().binning as f64
            }
        };
        if let Err(e) = self.stage_to([None, Some(lift), None])? {
            return Ok(Err(format!("the pipette cannot be lifted: {e}")));
        }
        let mut refused = Vec::new();
        let mut ways = self.ways_out(lift, pixel)?;
        if let Some(way) = self.leaving.take() {
            ways.insert(0, way);
        }
        for way in ways {
            match self.stage_to(way)? {
                Ok(()) => {
                    refused.clear();
                    break;
                }
                Err(e) => refused.push(e),
            }
        }
        if !refused.is_empty() {
            return Ok(Err(format!(
                "the pipette cannot be moved out of view: {}",
                refused.join("; ")
            )));
        }
        if self.field_focus.is_none() {
            // The plate moves up and down through focus: the pipette goes as much
            // higher first.
            let half = if self.focused.is_empty() {
                FOCUS_RANGE
            } else {
                12e-6
            };
            // (a sweep moved three times goes 5.5 half-ranges from where it started).
            if let Err(e) = self.stage_to([None, Some(lift + 6.0 * half), None])? {
                return Ok(Err(format!("the pipette cannot be lifted: {e}")));
            }
            match self.focus_field()? {
                Ok(f) => {
                    self.field_focus = Some(f);
                    self.focused.push(f);
                }
                Err(e) => return Ok(Err(e)),
            }
            if let Err(e) = self.stage_to([None, Some(lift), None])? {
                return Ok(Err(format!("the pipette cannot be lowered: {e}")));
            }
        }
        let mean = |p: &[u16]| p.iter().map(|&v| v as f64).sum::<f64>() / p.len().max(1) as f64;
        // A background taken again must be lit like the first (a flicker of the lamp
        // would make every later tip a guess): up to 60 frames (20 s) of patience.
        let reference = self.background.as_ref().map(|b| mean(&b.pixels));
        let mut shot = self.shoot(None)?;
        if let Some(r) = reference {
            let mut tries = 0;
            while mean(&shot.frame.pixels) < 0.5 * r {
                tries += 1;
                if tries >= 60 {
                    return Ok(Err(format!(
                        "the image stayed dark for {tries} frames (mean level {:.0} against {r:.0} when the run started)",
                        mean(&shot.frame.pixels)
                    )));
                }
                shot = self.shoot(None)?;
            }
        }
        self.background = Some(Background {
            pixels: shot.frame.pixels,
            width: shot.frame.width as usize,
            pixel_size: shot.frame.pixel_size,
        });
        Ok(Ok(()))
    }

    /// The image map's stage positions: at corners between four wells of the current
    /// field, where the tip is surely in view and, in focus, touches no cell (a cell
    /// lies within its well, so its disc stays clear of the corner), as far apart as
    /// the field allows: along each axis the corners between the first two and the
    /// last two wells the field holds whole. The map is extrapolated no further than
    /// that: from four points 150 um apart at the plate's centre it was more than 5 um
    /// off at the corners of a 10 x 15 plate (it called such a plate with 5 um to spare
    /// too large on 4 seeds of 5); every field lies in the same window of the image,
    /// so points spread over one field serve them all. Along an axis where the field
    /// holds fewer than four whole wells: on a plate that small, a corner near its
    /// centre and one `d` (about 200 um, whole pitches) beyond it; in a field of a
    /// larger plate, the first and the last wall crossing in the field.
    fn map_points(&self) -> [[f64; 2]; 4] {
        let p = &self.plate;
        let f = self.field.expect("field");
        let q = 0.5 * p.pitch;
        let d = p.pitch.max(200e-6f64.min(2.0 * p.pitch));
        let d = (d / p.pitch).round() * p.pitch;
        let span = |a: usize| {
            let (o, all) = (p.origin[a], if a == 0 { p.cols } else { p.rows });
            let (lo, hi) = (f.rect[a], f.rect[a + 2]);
            let last = all.saturating_sub(1) as f64;
            let k0 = ((lo - o + q) / p.pitch - 1e-9).ceil().max(0.0);
            let k1 = ((hi - o - q) / p.pitch + 1e-9).floor().min(last);
            let n = if k1 >= k0 { (k1 - k0) as u32 + 1 } else { 0 };
            let (a0, a1) = if n >= 4 {
                (o + k0 * p.pitch + q, o + (k1 - 1.0) * p.pitch + q)
            } else if n == all {
                let c = o + (n / 2) as f64 * p.pitch - q;
                (c, c + d)
            } else {
                let wall = |k: f64| o - q + k * p.pitch;
                let w0 = ((lo - (o - q)) / p.pitch - 1e-9)
                    .ceil()
                    .clamp(0.0, all as f64);
                let w1 = ((hi - (o - q)) / p.pitch + 1e-9)
                    .floor()
                    .clamp(0.0, all as f64);
                (wall(w0), wall(w1.max(w0 + 1.0)))
            };
            (a0 + self.feeder_at[a], a1 + self.feeder_at[a])
        };
        let (x0, x1) = span(0);
        let (z0, z1) = span(1);
        [[x0, z0], [x1, z0], [x0, z1], [x1, z1]]
    }

    /// The tip's full-frame pixel with the stage at `s` (x, z) and the pipette in
    /// focus there (lowered from the lift height, lifted again after).
    fn tip_at(&mut self, s: [f64; 2]) -> Result<Result<[f64; 2], String>, WorkflowError> {
        let lift = self.home[1];
        for p in [
            [None, Some(lift), None],
            [Some(s[0]), None, Some(s[1])],
            [None, Some(self.focus), None],
        ] {
            if let Err(e) = self.stage_to(p)? {
                return Ok(Err(e));
            }
        }
        let Some(px) = self.tip_full(3)? else {
            return Ok(Err(format!(
                "the tip was not found in the image with the stage at ({:.0}, {:.0}) um",
                s[0] * 1e6,
                s[1] * 1e6
            )));
        };
        if let Err(e) = self.stage_to([None, Some(lift), None])? {
            return Ok(Err(e));
        }
        Ok(Ok(px))
    }

    /// Whether it is time to re-check the image map, and why.
    fn recheck_due(&mut self) -> Option<String> {
        if let Some(why) = self.check_due.take() {
            return Some(why);
        }
        let (every, since) = (self.options.recheck_every, self.now() - self.last_check);
        (every > 0.0 && since >= every).then(|| {
            format!("{since:.0} s after the image map was made or checked (every {every:.0} s)")
        })
    }

    /// Re-checks the calibrations between cells (`why`: what made it due): the
    /// background is taken again, and the resting tip is located at two of the map's
    /// stage positions (a diagonal apart) and compared with the map's prediction, in
    /// position and in scale. Within [`RECHECK_TOLERANCE`] the map is kept; else (or
    /// if the tip was not found) the image is mapped again, twice at most. Returns why
    /// the run must stop, if it must.
    fn recheck(
        &mut self,
        why: String,
        obs: &mut dyn Observer,
    ) -> Result<Option<String>, WorkflowError> {
        self.fire(Event::Recheck, format!("re-check {why}"), obs, None)?;
        let t0 = self.now();
        let stop = |w: &mut Self, r: String, obs: &mut dyn Observer| {
            w.fire(Event::Fatal, r.clone(), obs, None).map(|()| Some(r))
        };
        if let Err(e) = self.take_background()? {
            return stop(
                self,
                format!("the background could not be taken again: {e}"),
                obs,
            );
        }
        let map = self.map.expect("map");
        let pts = self.map_points();
        let (s0, s1) = (pts[0], pts[3]);
        let mut verdict = None;
        let mut measured = [[0.0; 2]; 2];
        for (k, s) in [s0, s1].into_iter().enumerate() {
            match self.tip_at(s)? {
                Ok(px) => measured[k] = px,
                Err(e) => {
                    verdict = Some(e);
                    break;
                }
            }
        }
        let verdict = match verdict {
            Some(e) => e,
            None => {
                let off =
                    |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]) * map.pixel_size;
                let worst =
                    off(measured[0], map.pixel_of(s0)).max(off(measured[1], map.pixel_of(s1)));
                let said = format!(
                    "background taken again; the resting tip is {:.2} um from where the map puts it (worst of two points {:.0} um apart)",
                    worst * 1e6,
                    (s1[0] - s0[0]).hypot(s1[1] - s0[1]) * 1e6,
                );
                if worst <= RECHECK_TOLERANCE {
                    let focus = match self.refocus()? {
                        Some(f) => format!("; {f}"),
                        None => String::new(),
                    };
                    self.last_check = self.now();
                    let r = format!(
                        "{said}: the map holds{focus} (re-check {:.1} s)",
                        self.now() - t0
                    );
                    self.fire(Event::Rechecked, r, obs, None)?;
                    return Ok(None);
                }
                format!("{said}, more than {:.1} um", RECHECK_TOLERANCE * 1e6)
            }
        };
        let mut last = String::new();
        for _ in 0..2 {
            match self.map_image()? {
                Ok(m) => {
                    self.map = Some(m);
                    obs.mapped(&m);
                    let focus = match self.refocus()? {
                        Some(f) => format!("; {f}"),
                        None => String::new(),
                    };
                    self.last_check = self.now();
                    let r = format!(
                        "{verdict}: image mapped to the stage again (4 points, rms {:.2} px{focus}; re-check {:.1} s)",
                        m.residual_px,
                        self.now() - t0
                    );
                    self.fire(Event::Rechecked, r, obs, None)?;
                    return Ok(None);
                }
                Err(reason) => last = reason,
            }
        }
        stop(
            self,
            format!("{verdict}; mapping the image again failed twice: {last}"),
            obs,
        )
    }

    /// Maps the image to the stage: the tip located (in focus, over the plate) at the
    /// four stage positions of [`Workflow::map_points`], and its motion under A1 and A3.
    fn map_image(&mut self) -> Result<Result<ImageMap, String>, WorkflowError> {
        let mut pts = Vec::new();
        for s in self.map_points() {
            match self.tip_at(s)? {
                Ok(px) => pts.push((s, px)),
                Err(e) => return Ok(Err(e)),
            }
        }
        let lift = self.home[1];
        // Affine least squares px = p0 + B (s - s0) with s0 the first point.
        let s0 = pts[0].0;
        let mut b = [[0.0; 2]; 2];
        let mut p0 = [0.0; 2];
        for c in 0..2 {
            // Unknowns p0, b_c0, b_c1 from 4 points: normal equations 3x3.
            let mut ata = nalgebra::Matrix3::<f64>::zeros();
            let mut atb = nalgebra::Vector3::<f64>::zeros();
            for (s, px) in &pts {
                let row = nalgebra::Vector3::new(1.0, s[0] - s0[0], s[1] - s0[1]);
                ata += row * row.transpose();
                atb += row * px[c];
            }
            let Some(x) = ata.lu().solve(&atb) else {
                return Ok(Err("the four stage positions are degenerate".into()));
            };
            p0[c] = x[0];
            b[c] = [x[1], x[2]];
        }
        let mut ss = 0.0;
        for (s, px) in &pts {
            for c in 0..2 {
                let pred = p0[c] + b[c][0] * (s[0] - s0[0]) + b[c][1] * (s[1] - s0[1]);
                ss += (pred - px[c]).powi(2);
            }
        }
        let residual = (ss / 8.0).sqrt();
        if residual > 0.5 {
            return Ok(Err(format!(
                "the four-point fit leaves {residual:.2} px rms (more than 0.5)"
            )));
        }
        let pixel = self.background.as_ref().expect("background").pixel_size;
        let scale = 1.0 / pixel;
        let sx = b[0][0].hypot(b[1][0]);
        if (sx / scale - 1.0).abs() > 0.05 {
            return Ok(Err(format!(
                "stage x moves the tip {:.4} px/um, the camera says {:.4}: more than 5 % apart",
                sx * 1e-6,
                scale * 1e-6
            )));
        }
        // A1 and A3 in the image: 1 um of A1 extension, A3_PROBE of A3, from rest; per metre
        // of extension as the stacks' own sensors read it.
        self.stage_to([Some(s0[0]), None, Some(s0[1])])?.ok();
        self.stage_to([None, Some(self.focus), None])?.ok();
        let mut dir = [[0.0; 2]; 2];
        for (k, (e, what)) in [(1e-6, "A1"), (A3_PROBE, "A3")].into_iter().enumerate() {
            let ch = if k == 0 { 0 } else { 2 };
            let extension = |w: &mut Self| -> Result<f64, WorkflowError> {
                let s = w.servo.as_mut().expect("servo");
                let mut sum = 0.0;
                for _ in 0..10 {
                    sum += w.rig.sensors[ch].read().map_err(dev("stack sensor"))? - s.zero[ch];
                }
                Ok(sum / 10.0)
            };
            // A3 drives the tip down its axis: the probe starts as high above the focus
            // as it will come down, and ends in focus (above the floor).
            let drop = if k == 1 {
                e * self.pipette.angle.sin()
            } else {
                0.0
            };
            if drop > 0.0 {
                self.stage_to([None, Some(self.focus + drop), None])?.ok();
            }
            let Some(p0) = self.tip_full_at(3, drop == 0.0)? else {
                return Ok(Err(format!("the tip was lost before {what} moved")));
            };
            let e0 = extension(self)?;
            let s = self.servo.as_mut().expect("servo");
            if k == 0 {
                s.refs = [e, 0.0];
            } else {
                s.a3_ref = e;
            }
            self.wait(0.3)?;
            let Some(p1) = self.tip_full_at(3, drop == 0.0)? else {
                return Ok(Err(format!("the tip was lost while {what} moved")));
            };
            let e1 = extension(self)?;
            let s = self.servo.as_mut().expect("servo");
            s.refs = [0.0; 2];
            s.a3_ref = 0.0;
            self.wait(0.3)?;
            let de = e1 - e0;
            if de.abs() < 0.3 * e {
                return Ok(Err(format!(
                    "{what} extended {:.2} um when asked for {:.2} um",
                    de * 1e6,
                    e * 1e6
                )));
            }
            dir[k] = [(p1[0] - p0[0]) / de, (p1[1] - p0[1]) / de];
        }
        self.stage_to([None, Some(lift), None])?.ok();
        // The microscope sees A3's motion foreshortened by the pipette's angle.
        let cos = self.pipette.angle.cos();
        let a3m = dir[1][0].hypot(dir[1][1]) / scale / cos;
        // A3 carries the pipette directly: the tip follows the stack's extension, less
        // what the structure in series with it gives (some 10-20 %).
        if !(0.5..1.5).contains(&a3m) {
            return Ok(Err(format!(
                "A3 moved the tip {a3m:.2} times its own extension along the pipette (it carries the pipette directly: expected about 1)"
            )));
        }
        if dir[0][0].hypot(dir[0][1]) / scale < 0.5 {
            return Ok(Err("A1 barely moves the tip in the image".into()));
        }
        Ok(Ok(ImageMap {
            pixel0: p0,
            stage0: s0,
            b,
            residual_px: residual,
            a1: dir[0],
            // A3 carries the pipette directly: its direction from the probe, its gain
            // one metre of tip per metre of extension (the probe's magnitude, from two
            // tip positions a few um apart, is only checked).
            a3: {
                let u = unit(dir[1]);
                [u[0] * scale * cos, u[1] * scale * cos]
            },
            pixel_size: pixel,
        }))
    }

    /// The fields over the plate for the view `map` gives, narrowed by `narrow` m on
    /// every side, with the feeder now at `at`.
    fn plan_for(
        &self,
        map: &ImageMap,
        narrow: f64,
        at: [f64; 2],
    ) -> Result<FieldPlan, WorkflowError> {
        let (sw, sh) = self.rig.camera.sensor_size();
        let too_small = || {
            WorkflowError::Plan(PlanError::WindowTooSmall {
                window: [0.0; 2],
                pitch: self.plate.pitch,
                overlap: fields::MIN_OVERLAP,
            })
        };
        let win = window::window(
            map,
            [sw as f64, sh as f64],
            TOP_BAND + narrow,
            WINDOW_MARGIN + narrow,
        )
        .ok_or_else(too_small)?;
        let plan = fields::plan_near(&self.plate, win, fields::MIN_OVERLAP, self.travel, Some(at))
            .map_err(WorkflowError::Plan)?;
        // The image map's points lie on wall crossings in the field: two walls along
        // each axis. A field of width L holds at least ⌊L / pitch⌋ walls of a larger
        // plate; a plate in one field holds all its own.
        for (a, axis) in [(0, "x"), (1, "y")] {
            let many = plan.grid[1 - a] > 1;
            if many && win.size[a] < 2.0 * self.plate.pitch {
                return Err(WorkflowError::PitchTooLarge {
                    pitch_um: self.plate.pitch * 1e6,
                    field_um: win.size[a] * 1e6,
                    axis,
                    zoom: self.options.zoom,
                });
            }
        }
        Ok(plan)
    }

    /// The fields for the view the rig's set-up gives, before the image is mapped: the
    /// stage's origin puts the resting tip near the image's centre and the image's
    /// columns and rows run along stage x and z, so the window is taken from a nominal
    /// map, narrowed by [`BOOTSTRAP_MARGIN`]. The image is mapped in its first field;
    /// the fields are planned again with the measured map.
    fn bootstrap_plan(&mut self) -> Result<FieldPlan, WorkflowError> {
        let frame = self.rig.camera.grab().map_err(dev("camera"))?;
        let pixel = frame.pixel_size / self.rig.camera.settings().binning as f64;
        let nominal = self.nominal_map(pixel);
        let at = self.feeder_position()?;
        self.plan_for(&nominal, BOOTSTRAP_MARGIN, at)
    }

    /// The image-to-stage map before it is measured: the frame's centre at the
    /// stage's origin, image columns and rows along stage x and z, `pixel` m each.
    fn nominal_map(&self, pixel: f64) -> ImageMap {
        let (sw, sh) = self.rig.camera.sensor_size();
        ImageMap {
            pixel0: [0.5 * (sw as f64 - 1.0), 0.5 * (sh as f64 - 1.0)],
            stage0: [0.0, 0.0],
            b: [[1.0 / pixel, 0.0], [0.0, 1.0 / pixel]],
            residual_px: 0.0,
            a1: [0.0; 2],
            a3: [0.0; 2],
            pixel_size: pixel,
        }
    }

    /// m, where the feeder is (x, y).
    fn feeder_position(&mut self) -> Result<[f64; 2], WorkflowError> {
        Ok([
            self.rig.feeder.position(0).map_err(dev("feeder stage"))?,
            self.rig.feeder.position(1).map_err(dev("feeder stage"))?,
        ])
    }

    /// Time passes: with the loops running if they are.
    fn idle(&mut self, seconds: f64) -> Result<(), WorkflowError> {
        if self.servo.is_some() {
            self.wait(seconds)
        } else {
            self.rig.clock.sleep(seconds).map_err(dev("clock"))
        }
    }

    /// Brings `field` under the objective: the pipette lifted first (the plate moves
    /// under it), then the feeder moved and waited for (its deadline: the run's stage
    /// deadline plus 1 s per mm). The feeder's position is read back: plate and stage
    /// coordinates differ by it until the next move.
    fn goto_field(&mut self, field: Field) -> Result<Result<(), String>, WorkflowError> {
        if let Err(e) = self.stage_to([None, Some(self.home[1]), None])? {
            return Ok(Err(format!("the pipette cannot be lifted: {e}")));
        }
        let now = self.feeder_position()?;
        let now_z = self.rig.feeder.position(2).map_err(dev("feeder stage"))?;
        // The field's height: measured if it (or a field centred within FOCUS_REUSE of
        // it, its plane extended) was focused, else predicted from the nearest field
        // focused, else where the feeder stands.
        let known = self
            .focused
            .iter()
            .map(|f| {
                (
                    f,
                    (f.centre_m[0] - field.centre[0]).hypot(f.centre_m[1] - field.centre[1]),
                )
            })
            .filter(|(_, d)| *d < FOCUS_REUSE)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(f, d)| {
                if d < 1e-6 {
                    *f
                } else {
                    FieldFocus {
                        centre_m: field.centre,
                        rect_m: field.rect,
                        feeder_z_m: f.feeder_z_at(field.centre),
                        frames: 0,
                        ..*f
                    }
                }
            });
        if let Some(k) = known
            && k.frames == 0
            && !self.focused.iter().any(|f| f.centre_m == k.centre_m)
        {
            self.focused.push(k);
        }
        let z = match known {
            Some(f) => f.feeder_z_m,
            None => self.predicted_focus(field.centre).unwrap_or(now_z),
        };
        self.field_focus = known;
        // A field served again: the pipette starts on its shortest way out of view
        // (for the background) while the feeder moves; the background waits for it
        // there, or tries the other ways if the stage refused this one.
        if known.is_some() && !self.survey_cells.is_empty() {
            // The background's pixel, as the background takes its ways with (a
            // fallback way computed with none would stop inside the view).
            let pixel = self
                .background
                .as_ref()
                .map_or_else(|| self.map.map_or(0.0, |m| m.pixel_size), |b| b.pixel_size);
            if let Some(&way) = self.ways_out(self.home[1], pixel)?.first() {
                // Refused (the stage's travel): the background tries the other ways.
                if self.stage_start(way)?.is_ok() {
                    self.leaving = Some(way);
                }
            }
        }
        let far = (field.feeder[0] - now[0])
            .abs()
            .max((field.feeder[1] - now[1]).abs())
            .max((z - now_z).abs());
        // Within the feeder's resolution: already there.
        if far > 0.05e-6 {
            for (a, v) in [field.feeder[0], field.feeder[1], z].iter().enumerate() {
                if let Err(e) = self.rig.feeder.move_to(a, *v) {
                    return Ok(Err(format!(
                        "the feeder stage refused the move to field {} ({:.3}, {:.3}) mm: {e}",
                        field.index,
                        field.feeder[0] * 1e3,
                        field.feeder[1] * 1e3
                    )));
                }
            }
            let deadline = self.options.stage_deadline + far * 1e3;
            let t0 = self.now();
            while self.rig.feeder.is_busy().map_err(dev("feeder stage"))? {
                if self.now() - t0 > deadline {
                    return Err(WorkflowError::Device {
                        what: "feeder stage",
                        source: HwError::Timeout {
                            device: "feeder stage (missed its deadline)".into(),
                            seconds: deadline,
                        },
                    });
                }
                self.idle(0.005)?;
            }
        }
        self.feeder_at = self.feeder_position()?;
        self.field = Some(field);
        Ok(Ok(()))
    }

    /// How the current field was focused, for the log.
    fn focus_note(&self) -> String {
        match self.field_focus {
            Some(f) => format!(
                ", height {:.1} um: the floor slopes {:.2} um/mm{}",
                f.feeder_z_m * 1e6,
                f.slope[0].hypot(f.slope[1]) * 1e3,
                if f.tiles > 0 {
                    format!(
                        " ({} tiles, {:.2} um rms, {} focus frames)",
                        f.tiles,
                        f.residual_m * 1e6,
                        f.frames
                    )
                } else {
                    format!(" (whole frame, {} focus frames)", f.frames)
                }
            ),
            None => String::new(),
        }
    }

    /// m, the feeder height predicted to focus plate point `p`: the plane of the
    /// nearest field focused, extended; `None` before any.
    fn predicted_focus(&self, p: [f64; 2]) -> Option<f64> {
        self.focused
            .iter()
            .min_by(|a, b| {
                let d = |f: &FieldFocus| (f.centre_m[0] - p[0]).hypot(f.centre_m[1] - p[1]);
                d(a).total_cmp(&d(b))
            })
            .map(|f| f.feeder_z_at(p))
    }

    /// m, how far above the focal plane the floor at plate point `p` stands in the
    /// current field (its measured tilt; 0 before it is measured).
    fn floor_at(&self, p: [f64; 2]) -> f64 {
        self.field_focus.map_or(0.0, |f| f.floor_at(p))
    }

    /// Moves the feeder's height to `z` and waits for it to settle.
    fn feeder_height(&mut self, z: f64) -> Result<Result<(), String>, WorkflowError> {
        if let Err(e) = self.rig.feeder.move_to(2, z) {
            return Ok(Err(format!(
                "the feeder stage refused the height {:.1} um: {e}",
                z * 1e6
            )));
        }
        let t0 = self.now();
        while self.rig.feeder.is_busy().map_err(dev("feeder stage"))? {
            if self.now() - t0 > self.options.stage_deadline {
                return Err(WorkflowError::Device {
                    what: "feeder stage",
                    source: HwError::Timeout {
                        device: "feeder stage (missed its deadline)".into(),
                        seconds: self.options.stage_deadline,
                    },
                });
            }
            self.idle(0.005)?;
        }
        self.idle(FOCUS_SETTLE)?;
        Ok(Ok(()))
    }

    /// One frame of a focus sweep: the feeder's height moved to `z`, a whole frame
    /// binned by `binning`, and its tiles' sharpness.
    fn focus_sample(
        &mut self,
        z: f64,
        binning: u32,
    ) -> Result<Result<(f64, Vec<f64>), String>, WorkflowError> {
        if let Err(e) = self.feeder_height(z)? {
            return Ok(Err(e));
        }
        let full = self.settings_full.expect("full settings");
        let shot = self.shoot_with(CameraSettings { binning, ..full })?;
        let f = shot.frame;
        let w = f.width as usize;
        let sharp = cellinject_cells::focus::tile_sharpness(&f.pixels, w, FOCUS_TILES);
        Ok(Ok((z, sharp)))
    }

    /// Focuses the current field (the pipette lifted out of view): the feeder's
    /// height swept through focus in equal steps, a full frame at each; the frame cut
    /// into 3 x 3 tiles, each tile's best focus the midpoint of its sharpness curve's
    /// half-height crossings, the plane through them the field's tilt
    /// (`cellinject_cells::focus`). The first field is swept over ±[`FOCUS_RANGE`] in
    /// 4 um steps, then again over ±8 um in 1.5 um steps about its peak; a later
    /// one over ±12 um in 1.5 um steps about the height its nearest focused
    /// neighbour's plane predicts. A peak beyond a sweep's end moves the sweep that way
    /// (three times at most). The feeder ends at the plane's height at the field's
    /// centre.
    fn focus_field(&mut self) -> Result<Result<FieldFocus, String>, WorkflowError> {
        use cellinject_cells::focus;
        let field = self.field.expect("field");
        let first = self.focused.is_empty();
        let now_z = self.rig.feeder.position(2).map_err(dev("feeder stage"))?;
        let mut centre = self.predicted_focus(field.centre).unwrap_or(now_z);
        let mut frames = 0;
        // (half range, step): every frame binned 2 x 2 (a quarter of the pixels to
        // move and read). Not 4 x 4: pixels of 3.5 um average the walls' and rings'
        // edges away, and such frames were sharpest far from focus.
        let passes: &[(f64, f64)] = if first {
            &[(FOCUS_RANGE, 4e-6), (8e-6, 1.5e-6)]
        } else {
            &[(12e-6, 1.5e-6)]
        };
        // The last pass's samples, by height: (z, each tile's sharpness).
        let mut samples: Vec<(f64, Vec<f64>)> = Vec::new();
        let mut whole = None;
        let mut step = 0.0;
        for &(half, dz) in passes {
            step = dz;
            let mut shifts = 0;
            loop {
                let n = (2.0 * half / step).round() as usize + 1;
                samples.clear();
                for k in 0..n {
                    match self.focus_sample(centre - half + k as f64 * step, FOCUS_BINNING)? {
                        Ok(s) => samples.push(s),
                        Err(e) => return Ok(Err(e)),
                    }
                    frames += 1;
                }
                let zs: Vec<f64> = samples.iter().map(|s| s.0).collect();
                let total: Vec<f64> = samples.iter().map(|s| s.1.iter().sum()).collect();
                match focus::peak(&zs, &total, focus::FRAME_CONTRAST) {
                    Ok(p) => {
                        centre = p.z;
                        whole = Some(p);
                        break;
                    }
                    Err(focus::FocusError::OutOfRange { side, .. }) if shifts < 3 => {
                        shifts += 1;
                        centre += if side == "above" { 1.5 } else { -1.5 } * half;
                    }
                    Err(e) => {
                        return Ok(Err(format!(
                            "field {} could not be focused: {e}",
                            field.index
                        )));
                    }
                }
            }
        }
        let whole = whole.expect("a pass found the peak");
        // A tile whose focus lies beyond an end (the floor tilted steeply across the
        // field) extends the sweep on that side, up to FOCUS_RANGE from the peak.
        let tiles = FOCUS_TILES[0] * FOCUS_TILES[1];
        let curve = |samples: &[(f64, Vec<f64>)], t: usize| {
            let zs: Vec<f64> = samples.iter().map(|s| s.0).collect();
            let c: Vec<f64> = samples
                .iter()
                .map(|s| s.1.get(t).copied().unwrap_or(0.0))
                .collect();
            focus::peak(&zs, &c, focus::TILE_CONTRAST)
        };
        loop {
            let (lo, hi) = (samples[0].0, samples[samples.len() - 1].0);
            let (mut below, mut above) = (false, false);
            for t in 0..tiles {
                if let Err(focus::FocusError::OutOfRange { side, .. }) = curve(&samples, t) {
                    below |= side == "below";
                    above |= side == "above";
                }
            }
            let below = below && whole.z - lo < FOCUS_RANGE;
            let above = above && hi - whole.z < FOCUS_RANGE;
            if !below && !above {
                break;
            }
            for k in 1..=3 {
                if below {
                    match self.focus_sample(lo - k as f64 * step, FOCUS_BINNING)? {
                        Ok(s) => samples.insert(0, s),
                        Err(e) => return Ok(Err(e)),
                    }
                    frames += 1;
                }
                if above {
                    match self.focus_sample(hi + k as f64 * step, FOCUS_BINNING)? {
                        Ok(s) => samples.push(s),
                        Err(e) => return Ok(Err(e)),
                    }
                    frames += 1;
                }
            }
        }
        // Each tile's focus where its sharpness comes from (read in a frame at the whole
        // frame's focus), at that point of the plate.
        if let Err(e) = self.feeder_height(whole.z)? {
            return Ok(Err(e));
        }
        let full = self.shoot(None)?.frame;
        frames += 1;
        let at = focus::tile_centroids(&full.pixels, full.width as usize, FOCUS_TILES);
        let map = self
            .map
            .unwrap_or_else(|| self.nominal_map(full.pixel_size));
        let mut points = Vec::new();
        for t in 0..tiles {
            // A real focus curve spans several steps; noise peaks in one.
            let Ok(p) = curve(&samples, t) else { continue };
            if p.width < 2.0 * step {
                continue;
            }
            let Some(&px) = at.get(t) else {
                continue;
            };
            let st = map.stage_of(px);
            points.push(([st[0] - self.feeder_at[0], st[1] - self.feeder_at[1]], p.z));
        }
        let result = match focus::fit_plane(&points, field.centre) {
            Ok(plane) => FieldFocus {
                centre_m: field.centre,
                rect_m: field.rect,
                feeder_z_m: plane.z,
                slope: plane.slope,
                tiles: plane.points,
                residual_m: plane.residual,
                frames,
            },
            Err(_) => FieldFocus {
                centre_m: field.centre,
                rect_m: field.rect,
                feeder_z_m: whole.z,
                slope: [0.0; 2],
                tiles: 0,
                residual_m: 0.0,
                frames,
            },
        };
        if let Err(e) = self.feeder_height(result.feeder_z_m)? {
            return Ok(Err(e));
        }
        Ok(Ok(result))
    }

    /// The cells in the current field's background frame (the pipette out of view):
    /// plate coordinates of their centres and their diameters, m. Only cells whole in
    /// the field.
    fn detect_field(&self) -> Result<Vec<Seen>, WorkflowError> {
        let map = self.map.expect("map");
        let field = self.field.expect("field");
        let bg = self.background.as_ref().expect("background");
        let (w, h) = (bg.width, bg.pixels.len() / bg.width);
        let o = DetectOptions::for_pixel_size(map.pixel_size);
        let blobs = cellinject_cells::detect(&bg.pixels, w, h, &[], &o).map_err(|e| {
            WorkflowError::Calibration {
                what: "survey",
                reason: e.to_string(),
            }
        })?;
        Ok(blobs
            .iter()
            .filter(|b| b.kind == BlobKind::Cell)
            .filter_map(|b| {
                let s = map.stage_of([b.x, b.y]);
                let p = [s[0] - self.feeder_at[0], s[1] - self.feeder_at[1]];
                field
                    .holds(p, 0.5 * b.diameter)
                    .then_some((p, b.diameter, b.diameter_se))
            })
            .collect())
    }

    /// The survey: the feeder brings every field under the objective in turn, and one
    /// frame of each (the background, the pipette out of view) shows where its cells
    /// are. A cell seen in two fields (in their overlap) is one cell: detections whose
    /// centres lie within a radius of each other are merged, and the cell is given to
    /// the field that owns its centre if that field holds it whole, else to the first
    /// that does. Cells are then numbered in the order they are injected: field by
    /// field in the reverse of the survey's order (the feeder is over the last field
    /// surveyed), row by row within a field in alternating direction, top cell first
    /// within a well.
    fn survey(&mut self, obs: &mut dyn Observer) -> Result<Vec<Target>, WorkflowError> {
        let plan = self.plan.clone().expect("plan");
        let n = plan.fields.len();
        // (plate point, diameter, field, the diameter's standard error) of every
        // detection.
        let mut seen: Vec<([f64; 2], f64, usize, Option<f64>)> = Vec::new();
        for field in &plan.fields {
            if let Err(reason) = self.goto_field(*field)? {
                return Err(WorkflowError::Calibration {
                    what: "survey",
                    reason,
                });
            }
            if let Err(reason) = self.take_background()? {
                return Err(WorkflowError::Calibration {
                    what: "survey",
                    reason: format!("field {}: {reason}", field.index),
                });
            }
            obs.field(field.index, n, field.rect, self.feeder_at);
            let found = self.detect_field()?;
            let r = format!(
                "field {} of {n} surveyed: plate x {:.3} to {:.3} mm, y {:.3} to {:.3} mm (feeder at {:.3}, {:.3} mm{}): {} cells whole in it",
                field.index,
                field.rect[0] * 1e3,
                field.rect[2] * 1e3,
                field.rect[1] * 1e3,
                field.rect[3] * 1e3,
                self.feeder_at[0] * 1e3,
                self.feeder_at[1] * 1e3,
                self.focus_note(),
                found.len()
            );
            self.fire(Event::FieldReached, r, obs, None)?;
            for (p, d, se) in found {
                seen.push((p, d, field.index, se));
            }
        }
        // One cell, one entry: detections within a radius of a cell's first.
        let mut cells: Vec<Vec<usize>> = Vec::new();
        for (k, (p, d, _, _)) in seen.iter().enumerate() {
            let same = cells.iter_mut().find(|c| {
                let (q, e, _, _) = seen[c[0]];
                (p[0] - q[0]).hypot(p[1] - q[1]) < 0.5 * d.min(e)
            });
            match same {
                Some(c) => c.push(k),
                None => cells.push(vec![k]),
            }
        }
        let pl = &self.plate;
        let half = 0.5 * pl.pitch;
        let mut targets: Vec<(Target, usize)> = Vec::new();
        for c in &cells {
            let m = c.len() as f64;
            let mean = [
                c.iter().map(|&k| seen[k].0[0]).sum::<f64>() / m,
                c.iter().map(|&k| seen[k].0[1]).sum::<f64>() / m,
            ];
            let owner = plan.owner(mean).index;
            let &k = c.iter().find(|&&k| seen[k].2 == owner).unwrap_or(&c[0]);
            let (p, d, field, se) = seen[k];
            let rel = [p[0] - pl.origin[0], p[1] - pl.origin[1]];
            let (col, row) = ((rel[0] / pl.pitch).round(), (rel[1] / pl.pitch).round());
            if col < 0.0 || row < 0.0 || col >= pl.cols as f64 || row >= pl.rows as f64 {
                continue;
            }
            let w = pl.well_centre([row as u32, col as u32]);
            if (p[0] - w[0]).abs() > half || (p[1] - w[1]).abs() > half {
                continue;
            }
            targets.push((
                Target {
                    index: 0,
                    well: [row as u32, col as u32],
                    x_m: rel[0],
                    y_m: rel[1],
                    diameter_m: d,
                    diameter_se_m: se,
                    stage_m: [p[0] + self.feeder_at[0], p[1] + self.feeder_at[1]],
                },
                field,
            ));
        }
        let key = |t: &Target, f: usize| {
            (
                n - 1 - f,
                t.well[0],
                if t.well[0] % 2 == 0 {
                    t.well[1]
                } else {
                    u32::MAX - t.well[1]
                },
            )
        };
        targets.sort_by(|(a, fa), (b, fb)| {
            key(a, *fa)
                .cmp(&key(b, *fb))
                .then(a.y_m.total_cmp(&b.y_m))
                .then(a.x_m.total_cmp(&b.x_m))
        });
        for (k, (t, _)) in targets.iter_mut().enumerate() {
            t.index = k;
        }
        self.target_field = targets.iter().map(|(_, f)| *f).collect();
        let targets: Vec<Target> = targets.into_iter().map(|(t, _)| t).collect();
        self.survey_cells = targets.clone();
        self.mean_diameter = if targets.is_empty() {
            0.0
        } else {
            targets.iter().map(|t| t.diameter_m).sum::<f64>() / targets.len() as f64
        };
        self.place_targets();
        Ok(targets)
    }

    /// The surveyed cells' stage positions for the feeder where it is now.
    fn place_targets(&mut self) {
        let (o, f) = (self.plate.origin, self.feeder_at);
        for t in &mut self.survey_cells {
            t.stage_m = [t.x_m + o[0] + f[0], t.y_m + o[1] + f[1]];
        }
    }
}

/// The stage offset (m, x and z, at most [`BLUR_REACH`] along each) that puts the
/// tip's end, now at full-frame pixel `tip` with the glass along `axis` (unit, towards
/// the tip), over the plainest floor of `bg`: the strip the tip locator reads (from
/// [`PLAIN_AHEAD`] ahead of the end to [`PLAIN_BEHIND`] behind it along the glass,
/// [`PLAIN_ACROSS`] either side) with the least relative contrast (standard deviation
/// over mean), nearer offsets first among equals. Stage x and z move the image's x and
/// y by one pixel per `pixel` m (the rig's set-up; the image map is not yet measured
/// when the blur is learnt).
fn plainest(bg: &Background, tip: [f64; 2], axis: [f64; 2], pixel: f64) -> [f64; 2] {
    let h = (bg.pixels.len() / bg.width.max(1)) as i64;
    let w = bg.width as i64;
    let n = axis[0].hypot(axis[1]);
    let axis = if n > 0.0 && n.is_finite() {
        [axis[0] / n, axis[1] / n]
    } else {
        [0.0, 1.0]
    };
    let across = [-axis[1], axis[0]];
    let (ahead, behind, side) = (
        (PLAIN_AHEAD / pixel).ceil() as i64,
        (PLAIN_BEHIND / pixel).ceil() as i64,
        (PLAIN_ACROSS / pixel).ceil() as i64,
    );
    let contrast = |c: [f64; 2]| -> Option<f64> {
        let (mut s, mut s2, mut n) = (0.0, 0.0, 0.0);
        for a in -behind..=ahead {
            for b in -side..=side {
                let x = (c[0] + a as f64 * axis[0] + b as f64 * across[0]).round() as i64;
                let y = (c[1] + a as f64 * axis[1] + b as f64 * across[1]).round() as i64;
                if x < 0 || y < 0 || x >= w || y >= h {
                    return None;
                }
                let v = bg.pixels[(y * w + x) as usize] as f64;
                s += v;
                s2 += v * v;
                n += 1.0;
            }
        }
        let mean = s / n;
        (mean > 0.0).then(|| (s2 / n - mean * mean).max(0.0).sqrt() / mean)
    };
    let steps = (BLUR_REACH / 3e-6).round() as i64;
    let mut best = ([0.0, 0.0], f64::INFINITY);
    for i in -steps..=steps {
        for j in -steps..=steps {
            let d = [i as f64 * 3e-6, j as f64 * 3e-6];
            let at = [tip[0] + d[0] / pixel, tip[1] + d[1] / pixel];
            if let Some(c) = contrast(at) {
                // A thousandth of contrast per step of distance: nearer among equals.
                let score = c * (1.0 + 1e-3 * (i.abs() + j.abs()) as f64);
                if score < best.1 {
                    best = (d, score);
                }
            }
        }
    }
    best.0
}

/// Solves `e = α u + β v` for (α, β).
fn decompose(e: [f64; 2], u: [f64; 2], v: [f64; 2]) -> [f64; 2] {
    let det = u[0] * v[1] - u[1] * v[0];
    [
        (e[0] * v[1] - e[1] * v[0]) / det,
        (u[0] * e[1] - u[1] * e[0]) / det,
    ]
}

/// The median of `v` (the mean of the middle two for an even count); NaN if empty.
fn median(mut v: Vec<f64>) -> f64 {
    cellinject_numeric::median(&mut v)
}

/// The lower quartile of `v` (not empty): the value a quarter of the way up the
/// sorted values, interpolated linearly between neighbours.
fn lower_quartile(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let at = 0.25 * (v.len() - 1) as f64;
    let (k, f) = (at.floor() as usize, at.fract());
    v[k] + f * (v[(k + 1).min(v.len() - 1)] - v[k])
}

fn unit(v: [f64; 2]) -> [f64; 2] {
    let n = v[0].hypot(v[1]);
    [v[0] / n, v[1] / n]
}

/// Darkness of a cell's interior against its local background: one minus the mean
/// intensity inside 0.7 radius over the mean of the ring 1.3-1.7 radii below the
/// pipette's side (pixels, full-frame coordinates).
fn cell_darkness(shot: &Shot, c: [f64; 2], r: f64) -> Option<f64> {
    let c = shot.local(c);
    let (mut inner, mut ni, mut outer, mut no) = (0.0, 0, 0.0, 0);
    let k = (1.8 * r).ceil() as i64;
    for j in -k..=k {
        for i in -k..=k {
            let rho = ((i * i + j * j) as f64).sqrt();
            let Some(v) = shot.at(c[0] + i as f64, c[1] + j as f64) else {
                continue;
            };
            if rho < 0.7 * r {
                inner += v;
                ni += 1;
            } else if rho > 1.3 * r && rho < 1.7 * r && j >= 0 {
                outer += v;
                no += 1;
            }
        }
    }
    (ni > 10 && no > 10).then(|| 1.0 - (inner / ni as f64) / (outer / no as f64))
}

/// The far membrane's row (pixels, full frame): the darkest row of the cell's ring
/// beyond its centre, in two column bands either side of the pipette's axis, with
/// sub-pixel interpolation.
fn far_edge(shot: &Shot, c: [f64; 2], r: f64) -> Option<f64> {
    let c = shot.local(c);
    let rows: Vec<i64> =
        ((c[1] + 0.5 * r).floor() as i64..=(c[1] + 1.5 * r).ceil() as i64).collect();
    let mut means = Vec::with_capacity(rows.len());
    for &j in &rows {
        let (mut s, mut n) = (0.0, 0);
        let (a, b) = ((0.15 * r).ceil() as i64, (0.5 * r).floor() as i64);
        for i in (a..=b).flat_map(|i| [-i, i]) {
            if let Some(v) = shot.at(c[0] + i as f64, j as f64) {
                s += v;
                n += 1;
            }
        }
        if n == 0 {
            return None;
        }
        means.push(s / n as f64);
    }
    let k = (1..means.len().saturating_sub(1)).min_by(|&a, &b| means[a].total_cmp(&means[b]))?;
    let (l, m, h) = (means[k - 1], means[k], means[k + 1]);
    let den = l - 2.0 * m + h;
    let off = if den > 0.0 {
        (0.5 * (l - h) / den).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    Some(rows[k] as f64 + off + shot.origin[1])
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
            "cell {} in well [{}, {}], {:.1} um at ({:.1}, {:.1}) um",
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
            d.note().contains("size uncertain (10.0 +- 0.6 um)"),
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
