//! # cellinject-simparams
//!
//! The simulation-only parameters of a bench description, with the prototype's
//! defaults: how the digital twin renders noise, hysteresis density, creep, dynamics,
//! stick-slip, the camera sensor and the scene. What a real bench has too (the
//! pre-tensioning approach, amplifier ranges, safety margins, travels, the injector's
//! limit, the zoom) is the rig's (`cellinject-rig::RigParams`).
//!
//! The description file's `[twin] seed`, `[actuators.*.amplifier|hysteresis|creep]`
//! (all but `v_max`), `[dynamics]`, `[joints]`, `[thermal]`, `[stage]` (all but
//! `travel`), `[camera]`, `[optics]` (`focus_blur`, `defocus_rate`), `[feeder]` and
//! `[injector] conductance_error`, `pulse_noise` fill these structures (crate `cellinject-config`).
//!
//! **Architecture invariant:** plain data with defaults; no behaviour, no dependencies.

/// Piezo amplifier channel: how it follows its command (its output range is the rig's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AmplifierParams {
    /// Resolution of the DAC, bits.
    pub dac_bits: u32,
    /// V/s, largest output slew rate (current limit into the stack's capacitance).
    pub slew_rate: f64,
    /// Hz, small-signal bandwidth (first-order).
    pub bandwidth: f64,
    /// V rms, output noise.
    pub noise: f64,
}

impl Default for AmplifierParams {
    fn default() -> Self {
        AmplifierParams {
            dac_bits: 16,
            slew_rate: 1.0e4,
            bandwidth: 2.0e3,
            noise: 1.0e-3,
        }
    }
}

/// Rate-independent hysteresis of a stack: a Preisach operator with the continuous
/// density `μ(α, β) = 2·(1 + skew·(α + β − 1))` on the normalised input triangle
/// `0 ≤ β ≤ α ≤ 1`, mixed with a reversible part: `y = (1 − fraction)·u + fraction·P[u]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HysteresisParams {
    /// Share of the stroke that is hysteretic (0..1). A full loop is about
    /// `fraction / 2` of the stroke wide at mid-input.
    pub fraction: f64,
    /// Asymmetry of the density (−1..1): positive puts more switching at high voltages.
    pub skew: f64,
}

impl Default for HysteresisParams {
    fn default() -> Self {
        HysteresisParams {
            fraction: 0.25,
            skew: 0.3,
        }
    }
}

/// Logarithmic creep, `ΔL(t) ≈ ΔL(t0)·[1 + γ·log10(t/t0)]`, realised by first-order
/// lags with time constants spaced two per decade from `tau_min` to `tau_max`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CreepParams {
    /// Creep per decade of time, as a fraction of the extension (0.01-0.02 typical).
    pub gamma: f64,
    /// s, shortest time constant.
    pub tau_min: f64,
    /// s, longest time constant.
    pub tau_max: f64,
}

impl Default for CreepParams {
    fn default() -> Self {
        CreepParams {
            gamma: 0.015,
            tau_min: 0.01,
            tau_max: 1.0e4,
        }
    }
}

/// One piezo stack with its amplifier.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StackParams {
    /// Amplifier.
    pub amplifier: AmplifierParams,
    /// Hysteresis.
    pub hysteresis: HysteresisParams,
    /// Creep.
    pub creep: CreepParams,
}

/// Rigid-body dynamics of body 1 with the pipette on its flexures.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DynamicsParams {
    /// kg·m², moments of inertia of body 1 (with A3 and the pipette) about J3's two axes;
    /// used when `tilt_frequencies` is `None`.
    pub inertia: [f64; 2],
    /// Hz, the tilt modes about J3's axes q1 (base y) and q2 (body x), as the structural
    /// model finds them (`cellinject fea modes`: J1's axial and J3's lateral compliance
    /// and the stacks' mass, which the pseudo-rigid-body model lacks); the inertias are
    /// then set so that each axis rings at its frequency.
    pub tilt_frequencies: Option<[f64; 2]>,
    /// kg, moving mass of the injection axis (pipette holder and pipette) on A3.
    pub a3_mass: f64,
    /// N/m, axial stiffness of A3 (used by the dynamics only).
    pub a3_stiffness: f64,
    /// Modal damping ratio.
    pub damping_ratio: f64,
    /// Hz, integration rate (at least 20 kHz).
    pub rate: f64,
}

impl Default for DynamicsParams {
    fn default() -> Self {
        DynamicsParams {
            inertia: [1.2e-3, 1.2e-3],
            // `cellinject fea modes --approach 2` on the prototype (joints at level 1).
            tilt_frequencies: Some([552.7, 617.8]),
            a3_mass: 0.02,
            a3_stiffness: 20.0e6,
            damping_ratio: 0.02,
            rate: 20.0e3,
        }
    }
}

/// Stick-slip of the spherical joints between the stacks and body 1: the imperfection
/// that explains the paper's open-loop repeatability (Sec. 4).
///
/// The bending torque that flexure J_i passes to its stack (eq. 43) seats the stack's
/// ball eccentrically in its socket, at `ε = |Fw_i| / |F_i|` from the axis (torque over
/// axial force, capped at the ball radius). Whenever body 1 moves, the ball slips in its
/// socket; it re-sticks at an angle that varies from one slip to the next within
/// `±stick_slip_angle` (surface roughness). With the eccentric seat, that angle changes
/// the effective drive length by `ε·φ`: up to 3.2 mm × 0.14 mrad ≈ 0.45 µm under
/// approach 1 (0.316 N·m / 100 N), about 5 nm under approach 2 (0.005 N·m / 100 N).
/// The lever b2/b1 = 6 turns that into the 3-5 µm and under-1 µm end-effector scatter of
/// the paper's 200 open-loop runs (Sec. 4, Fig. 8).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointParams {
    /// rad, half-width of the re-stick angle.
    pub stick_slip_angle: f64,
    /// rad, net relative rotation of a joint from where it last stuck that breaks it
    /// free (smaller motions are taken elastically: a 1 µm stack step turns body 1 by
    /// ~14 µrad, amplifier noise by nanoradians).
    pub slip_rotation: f64,
    /// m, radius of the ball (caps the eccentricity).
    pub ball_radius: f64,
}

impl Default for JointParams {
    fn default() -> Self {
        JointParams {
            stick_slip_angle: 1.4e-4,
            slip_rotation: 2.0e-5,
            ball_radius: 4.0e-3,
        }
    }
}

/// Temperature drift: by default the prototype's lab, warming by 1 K an hour (see
/// `configs/prototype.toml`); `drift_rate = 0` turns it off.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThermalParams {
    /// K/s, rate of change of the ambient temperature.
    pub drift_rate: f64,
    /// m/K, change of each drive's length per kelvin (stack and frame together).
    pub expansion: f64,
    /// 1/K, relative change of the microscope's magnification per kelvin (the zoom
    /// lens and the tube): the object-plane size of a pixel changes by
    /// `−magnification · ΔT` of itself, while the frames still report the nominal
    /// pixel size.
    pub magnification: f64,
}

impl Default for ThermalParams {
    fn default() -> Self {
        ThermalParams {
            drift_rate: 2.78e-4,
            expansion: 3.0e-7,
            magnification: 1.0e-3,
        }
    }
}

impl ThermalParams {
    /// K, the ambient temperature's change since the start (time 0) at `t` s:
    /// `drift_rate · t`.
    pub fn delta_t(&self, t: f64) -> f64 {
        self.drift_rate * t
    }
}

/// The stacks' strain-gauge position sensors (PI's P-8xx stacks: a few nm of noise).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorParams {
    /// m rms, noise of one reading.
    pub noise: f64,
    /// m/K, the reading's drift with the ambient temperature (see [`ThermalParams`]).
    pub thermal_drift: f64,
}

impl Default for SensorParams {
    fn default() -> Self {
        SensorParams {
            noise: 3.0e-9,
            thermal_drift: 5.0e-9,
        }
    }
}

/// How the macro stage M1-M3 moves (its travel is the rig's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StageParams {
    /// m/s, top speed.
    pub max_speed: f64,
    /// m/s², acceleration.
    pub max_accel: f64,
    /// m, encoder resolution.
    pub encoder_resolution: f64,
    /// s, settling time after a move.
    pub settling_time: f64,
    /// m, amplitude of the residual vibration at the end of a move.
    pub settling_amplitude: f64,
}

impl StageParams {
    /// The feeder stage's: a motorised XY microscope stage carrying the plate (5 mm/s,
    /// 50 mm/s², 0.1 µm encoders, 0.1 s to settle within 0.3 µm).
    pub fn feeder() -> Self {
        StageParams {
            max_speed: 5.0e-3,
            max_accel: 5.0e-2,
            encoder_resolution: 0.1e-6,
            settling_time: 0.1,
            settling_amplitude: 0.3e-6,
        }
    }
}

impl Default for StageParams {
    fn default() -> Self {
        StageParams {
            max_speed: 2.0e-3,
            max_accel: 2.0e-2,
            encoder_resolution: 0.1e-6,
            settling_time: 0.05,
            settling_amplitude: 0.2e-6,
        }
    }
}

/// The microscope camera's sensor (paper Sec. 4).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraParams {
    /// Sensor columns.
    pub width: u32,
    /// Sensor rows.
    pub height: u32,
    /// m, pixel pitch on the sensor.
    pub pixel_size: f64,
    /// Output bits (8 or 12).
    pub bit_depth: u8,
    /// Electrons at saturation.
    pub full_well: f64,
    /// Electrons rms.
    pub read_noise: f64,
    /// Frames per second at full resolution.
    pub fps_full: f64,
    /// Frames per second at VGA.
    pub fps_vga: f64,
    /// s, default exposure.
    pub exposure: f64,
    /// s, exposure at which the background reaches `background_level` of full well.
    pub reference_exposure: f64,
    /// Background brightness at the reference exposure, fraction of full well.
    pub background_level: f64,
}

impl Default for CameraParams {
    fn default() -> Self {
        CameraParams {
            width: 2592,
            height: 1944,
            pixel_size: 2.2e-6,
            bit_depth: 8,
            full_well: 10_000.0,
            read_noise: 8.0,
            fps_full: 3.0,
            fps_vga: 30.0,
            exposure: 5.0e-3,
            reference_exposure: 5.0e-3,
            background_level: 0.7,
        }
    }
}

/// How the zoom lens blurs (its magnification is the rig's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LensParams {
    /// m, blur (Gaussian sigma, object plane) at best focus.
    pub focus_blur: f64,
    /// Blur sigma added per metre of distance from the focal plane (m/m).
    pub defocus_rate: f64,
}

impl Default for LensParams {
    fn default() -> Self {
        LensParams {
            focus_blur: 0.35e-6,
            defocus_rate: 0.05,
        }
    }
}

/// The matrix feeder holding the cells, and the scene around the pipette.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeederParams {
    /// Rows of wells.
    pub rows: u32,
    /// Columns of wells.
    pub cols: u32,
    /// m, well pitch.
    pub pitch: f64,
    /// m, smallest and largest cell diameter.
    pub cell_diameter: [f64; 2],
    /// m, position of the first well relative to the pipette tip at home (x, z).
    pub offset: [f64; 2],
    /// Probability that a well is empty.
    pub empty_fraction: f64,
    /// Debris particles per square millimetre.
    pub debris_density: f64,
    /// m/m, how steeply a loaded plate's floor is tilted (the twin draws a direction
    /// and 0.5-1 times this magnitude from its seed): the focus differs across the
    /// plate by this much per metre.
    pub surface_tilt: f64,
    /// 1/m, how much a loaded plate's floor is bowed (the twin draws a sign and 0.5-1
    /// times this curvature from its seed): the floor rises or sags by half of it
    /// times the squared distance from the plate's centre.
    pub surface_curvature: f64,
}

impl Default for FeederParams {
    fn default() -> Self {
        FeederParams {
            rows: 4,
            cols: 16,
            pitch: 40.0e-6,
            cell_diameter: [10.0e-6, 30.0e-6],
            offset: [-300.0e-6, 60.0e-6],
            empty_fraction: 0.1,
            debris_density: 150.0,
            surface_tilt: 3.0e-3,
            surface_curvature: 0.4,
        }
    }
}

/// The pressure injector's flow (its pressure limit is the rig's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InjectorParams {
    /// Relative deviation of this pipette's true conductance from what its nominal
    /// geometry gives (`[injector] tip_inner_diameter`, `cone_half_angle`,
    /// `viscosity`): the puller's spread.
    pub conductance_error: f64,
    /// Relative rms scatter of the volume from pulse to pulse.
    pub pulse_noise: f64,
}

impl Default for InjectorParams {
    fn default() -> Self {
        InjectorParams {
            conductance_error: 0.04,
            pulse_noise: 0.02,
        }
    }
}

/// How the twin's cells respond to the pipette (contact, puncture, dose, viability).
/// Not description keys yet: the defaults are the twin's cell line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellBiology {
    /// How far the cell is pushed ahead of the tip before its membrane gives, as a
    /// fraction of the tip's advance into the undeformed cell (the rest dimples the
    /// membrane).
    pub push_fraction: f64,
    /// Dimple depth at which the membrane gives, as a fraction of the cell's radius
    /// (drawn uniformly per cell between the two).
    pub puncture: [f64; 2],
    /// Largest lateral offset of the tip from the cell's centre at entry, as a
    /// fraction of the radius, that does not tear the membrane.
    pub tear_offset: f64,
    /// Largest sideways travel of the tip inside the cell, fraction of the radius.
    pub tear_travel: f64,
    /// Deepest the tip may go past the cell's centre, fraction of the radius, before
    /// it damages the nucleus and the cell dies.
    pub lethal_depth: f64,
    /// Injected volume, fraction of the cell's, beyond which the cell lyses.
    pub lethal_dose: f64,
}

impl Default for CellBiology {
    fn default() -> Self {
        CellBiology {
            push_fraction: 0.5,
            puncture: [0.18, 0.30],
            tear_offset: 0.6,
            tear_travel: 0.3,
            lethal_depth: 0.45,
            lethal_dose: 0.15,
        }
    }
}

/// Everything the twin simulates besides the mechanism design and the rig.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimParams {
    /// Seed of every random process (noise, stick-slip, scene).
    pub seed: u64,
    /// A1, A2, A3.
    pub stacks: [StackParams; 3],
    /// Rigid-body dynamics.
    pub dynamics: DynamicsParams,
    /// Spherical-joint stick-slip.
    pub joints: JointParams,
    /// Temperature drift.
    pub thermal: ThermalParams,
    /// Stack position sensors.
    pub sensors: SensorParams,
    /// Macro stage motion.
    pub stage: StageParams,
    /// The feeder stage that carries the plate under the objective (x, y).
    pub feeder_stage: StageParams,
    /// Camera sensor.
    pub camera: CameraParams,
    /// Zoom lens blur.
    pub lens: LensParams,
    /// Cells and scene.
    pub feeder: FeederParams,
    /// Injector flow.
    pub injector: InjectorParams,
    /// The cells' response to the pipette.
    pub biology: CellBiology,
}

impl Default for SimParams {
    fn default() -> Self {
        SimParams {
            seed: 1,
            stacks: [StackParams::default(); 3],
            dynamics: DynamicsParams::default(),
            joints: JointParams::default(),
            thermal: ThermalParams::default(),
            sensors: SensorParams::default(),
            stage: StageParams::default(),
            feeder_stage: StageParams::feeder(),
            camera: CameraParams::default(),
            lens: LensParams::default(),
            feeder: FeederParams::default(),
            injector: InjectorParams::default(),
            biology: CellBiology::default(),
        }
    }
}
