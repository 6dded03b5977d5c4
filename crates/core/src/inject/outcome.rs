//! What a run finds and does: the targets, each attempt and its outcome (with the
//! twin's truth where there is one), the [`Observer`] told of each step, the dose's
//! verdict, and the run's report and session.

use super::*;

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

/// m: a diameter whose standard error exceeds this is uncertain ([`dose_diameter`]):
/// more than twice a round cell's alone (under 0.1 um), reached by small cells cut by
/// a touching partner.
pub(super) const SIZE_SE_UNCERTAIN: f64 = 0.25e-6;

/// m, the standard error taken for a cell whose membrane fewer than three quarters
/// show: the detector's worst error on a doublet's 10 um partner (0.5 um).
pub(super) const SIZE_SE_UNKNOWN: f64 = 0.5e-6;

/// The diameter a cell's dose is computed from, and whether its size was uncertain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Dosed {
    /// m.
    pub(super) diameter: f64,
    /// The measured diameter and its standard error (m) when the size was uncertain.
    pub(super) uncertain: Option<[f64; 2]>,
}

impl Dosed {
    /// For the pulse's log line: empty when the size was known.
    pub(super) fn note(&self) -> String {
        match self.uncertain {
            Some([d, se]) => format!(
                "; size uncertain ({:.1} +- {:.1} µm): dosed for {:.1} µm, its measured size",
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
pub(super) fn dose_diameter(d: f64, se: Option<f64>) -> Dosed {
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
pub(super) fn verdict_on_stop(a: &mut Attempt, reason: String, by_operator: bool) {
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
