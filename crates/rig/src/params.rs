//! The description of a physical bench: what a real rig has as much as the twin.

use cellinject_model::Approach;

/// One amplifier channel's output range: 0 V to `v_max`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AmplifierRange {
    /// V, highest output (`actuators.Ax.amplifier.v_max`); the lowest is 0 V.
    pub v_max: f64,
}

impl Default for AmplifierRange {
    fn default() -> Self {
        AmplifierRange { v_max: 100.0 }
    }
}

/// Margins of the piezo safety envelope (`[safety]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SafetyMargins {
    /// Fraction of travel by which hysteresis and creep may move a stack's extension
    /// away from `travel · V / V_max`.
    pub hysteresis_bound: f64,
    /// Fraction of travel allowed for dynamic overshoot.
    pub dynamic_margin: f64,
}

impl Default for SafetyMargins {
    fn default() -> Self {
        SafetyMargins {
            hysteresis_bound: 0.2,
            dynamic_margin: 0.03,
        }
    }
}

/// The zoom lens's magnification and where the speckled marker tabs sit (`[optics]
/// zoom`, `zoom_range`, `marker`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OpticsSetup {
    /// Magnification at start.
    pub zoom: f64,
    /// Smallest and largest magnification.
    pub zoom_range: [f64; 2],
    /// m, where the centre of the speckled marker tab appears relative to the centre
    /// of each camera's view with the stacks at rest (along the image columns, rows):
    /// the region the cameras track. The prototype's tabs are glued 95 µm beside and
    /// 125 µm above the tip, and the views are centred 30 µm below it.
    pub marker: [f64; 2],
}

impl Default for OpticsSetup {
    fn default() -> Self {
        OpticsSetup {
            zoom: 10.0,
            zoom_range: [2.5, 10.0],
            marker: [95e-6, -155e-6],
        }
    }
}

/// The physical bench besides the mechanism design: how it was assembled and the
/// limits its devices must respect. The same on the twin and on real hardware.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigParams {
    /// How the structure was pre-tensioned (`twin.approach`).
    pub approach: Approach,
    /// A1, A2, A3 amplifier ranges.
    pub amplifiers: [AmplifierRange; 3],
    /// Safety envelope margins.
    pub safety: SafetyMargins,
    /// m, travel of each macro-stage axis, centred on 0 (`stage.travel`).
    pub stage_travel: f64,
    /// m, travel of each of the feeder stage's two axes (plate x and y), centred on 0
    /// (`feeder_stage.travel`).
    pub feeder_travel: f64,
    /// Pa, largest gauge pressure of the injector (`injector.max_pressure`).
    pub injector_max_pressure: f64,
    /// The mounted pipette and the injected solution (`[injector]`).
    pub pipette: crate::pipette::PipetteParams,
    /// The zoom lens.
    pub optics: OpticsSetup,
    /// J3's yield check for the envelope: numbers from the structural model and the
    /// joint FEM of this design and approach (the front end computes them from the FEA
    /// cache); `None` leaves J3's stress unchecked, which a front end must not do
    /// silently.
    pub j3_yield: Option<crate::guard::YieldCheck>,
}

impl Default for RigParams {
    fn default() -> Self {
        RigParams {
            approach: Approach::JointDeflection,
            amplifiers: [AmplifierRange::default(); 3],
            safety: SafetyMargins::default(),
            stage_travel: 0.025,
            feeder_travel: 0.05,
            injector_max_pressure: 2.0e5,
            pipette: crate::pipette::PipetteParams::default(),
            optics: OpticsSetup::default(),
            j3_yield: None,
        }
    }
}

impl RigParams {
    /// The stage's limits of every axis, m.
    pub fn stage_limits(&self) -> (f64, f64) {
        (-0.5 * self.stage_travel, 0.5 * self.stage_travel)
    }

    /// The feeder stage's limits of each axis, m.
    pub fn feeder_limits(&self) -> (f64, f64) {
        (-0.5 * self.feeder_travel, 0.5 * self.feeder_travel)
    }
}
