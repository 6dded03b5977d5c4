//! The workflow's options ([`Options`]) and their check against the rig.

use super::*;

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
                "must lie in [16 µm, 1 mm] (above the largest cell's radius)",
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
