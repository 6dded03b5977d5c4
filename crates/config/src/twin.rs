//! The bench's sections of the description file, split as they are read into the rig
//! (what a real bench has: approach, amplifier ranges, margins, travels, limits, zoom)
//! and the simulation (everything else). Every key is optional and defaults to the
//! prototype's value (`RigParams::default()`, `SimParams::default()`); present keys are
//! validated.

use cellinject_model::Approach;
use cellinject_rig::RigParams;
use cellinject_rig::params::{AmplifierRange, OpticsSetup, SafetyMargins};
use cellinject_simparams::{
    AmplifierParams, CreepParams, HysteresisParams, LensParams, SimParams, StackParams,
};

use crate::ConfigError;
use crate::section::{Check, Section};

/// Reads a section if present and applies `f` to it, then refuses unknown keys.
pub(crate) fn with<'a, T>(
    parent: &mut Section<'a>,
    name: &str,
    default: T,
    f: impl FnOnce(&mut Section<'a>, T) -> Result<T, ConfigError>,
) -> Result<T, ConfigError> {
    match parent.opt_table(name)? {
        None => Ok(default),
        Some(mut s) => {
            let out = f(&mut s, default)?;
            s.finish()?;
            Ok(out)
        }
    }
}

/// A stage's motion (`[stage]`, `[feeder_stage]`): speed, acceleration, encoder,
/// settling.
fn stage_motion(
    s: &mut Section<'_>,
    d: cellinject_simparams::StageParams,
) -> Result<cellinject_simparams::StageParams, ConfigError> {
    Ok(cellinject_simparams::StageParams {
        max_speed: s.num("max_speed", d.max_speed, Check::Positive)?,
        max_accel: s.num("max_accel", d.max_accel, Check::Positive)?,
        encoder_resolution: s.num("encoder_resolution", d.encoder_resolution, Check::Positive)?,
        settling_time: s.num("settling_time", d.settling_time, Check::Positive)?,
        settling_amplitude: s.num(
            "settling_amplitude",
            d.settling_amplitude,
            Check::NonNegative,
        )?,
    })
}

/// `[actuators.Ax.amplifier|hysteresis|creep]`: the amplifier's range (rig) and the
/// stack's simulation.
pub(crate) fn stack(a: &mut Section<'_>) -> Result<(AmplifierRange, StackParams), ConfigError> {
    let d = StackParams::default();
    let mut range = AmplifierRange::default();
    let amplifier = with(a, "amplifier", d.amplifier, |s, d| {
        range.v_max = s.num("v_max", range.v_max, Check::Positive)?;
        Ok(AmplifierParams {
            dac_bits: s.int("dac_bits", d.dac_bits as u64, 8, 24)? as u32,
            slew_rate: s.num("slew_rate", d.slew_rate, Check::Positive)?,
            bandwidth: s.num("bandwidth", d.bandwidth, Check::Positive)?,
            noise: s.num("noise", d.noise, Check::NonNegative)?,
        })
    })?;
    let hysteresis = with(a, "hysteresis", d.hysteresis, |s, d| {
        Ok(HysteresisParams {
            fraction: s.num("fraction", d.fraction, Check::Between(0.0, 1.0))?,
            skew: s.num("skew", d.skew, Check::Between(-0.99, 0.99))?,
        })
    })?;
    let creep = with(a, "creep", d.creep, |s, d| {
        let tau_min = s.num("tau_min", d.tau_min, Check::Positive)?;
        Ok(CreepParams {
            gamma: s.num("gamma", d.gamma, Check::Between(0.0, 0.1))?,
            tau_min,
            tau_max: s.num("tau_max", d.tau_max, Check::Between(tau_min, 1e9))?,
        })
    })?;
    Ok((
        range,
        StackParams {
            amplifier,
            hysteresis,
            creep,
        },
    ))
}

/// `[dynamics]`: the mechanism's inertia or tilt frequencies, A3's mass and stiffness, damping and the simulation rate.
fn dynamics(
    s: &mut Section<'_>,
    d: cellinject_simparams::DynamicsParams,
) -> Result<cellinject_simparams::DynamicsParams, ConfigError> {
    let inertia = s.opt_arr("inertia", Check::Positive)?;
    let freqs = s.opt_arr("tilt_frequencies", Check::Positive)?;
    let tilt_frequencies = match (inertia, freqs) {
        (Some(_), Some(_)) => {
            return Err(ConfigError::Invalid {
                key: s.key("tilt_frequencies"),
                reason: "give either tilt_frequencies or inertia, not both".into(),
            });
        }
        (Some(_), None) => None,
        (None, f) => f.or(d.tilt_frequencies),
    };
    Ok(cellinject_simparams::DynamicsParams {
        inertia: inertia.unwrap_or(d.inertia),
        tilt_frequencies,
        a3_mass: s.num("a3_mass", d.a3_mass, Check::Positive)?,
        a3_stiffness: s.num("a3_stiffness", d.a3_stiffness, Check::Positive)?,
        damping_ratio: s.num("damping_ratio", d.damping_ratio, Check::Between(1e-4, 0.99))?,
        rate: s.num("rate", d.rate, Check::Between(20e3, 1e7))?,
    })
}

/// `[camera]`: the sensor, its noise, frame rates and exposures.
fn camera(
    s: &mut Section<'_>,
    d: cellinject_simparams::CameraParams,
) -> Result<cellinject_simparams::CameraParams, ConfigError> {
    let bits = s.int("bit_depth", d.bit_depth as u64, 8, 12)?;
    if bits != 8 && bits != 12 {
        return Err(ConfigError::Invalid {
            key: s.key("bit_depth"),
            reason: format!("{bits} must be 8 or 12"),
        });
    }
    let fps_full = s.num("fps_full", d.fps_full, Check::Positive)?;
    let fps_vga = s.num("fps_vga", d.fps_vga, Check::Positive)?;
    Ok(cellinject_simparams::CameraParams {
        width: s.int("width", d.width as u64, 640, 16384)? as u32,
        height: s.int("height", d.height as u64, 480, 16384)? as u32,
        pixel_size: s.num("pixel_size", d.pixel_size, Check::Positive)?,
        bit_depth: bits as u8,
        full_well: s.num("full_well", d.full_well, Check::Positive)?,
        read_noise: s.num("read_noise", d.read_noise, Check::NonNegative)?,
        fps_full,
        fps_vga,
        exposure: s.num(
            "exposure",
            d.exposure,
            Check::Between(1e-6, 1.0 / fps_vga.max(fps_full)),
        )?,
        reference_exposure: s.num("reference_exposure", d.reference_exposure, Check::Positive)?,
        background_level: s.num(
            "background_level",
            d.background_level,
            Check::Between(0.0, 1.0),
        )?,
    })
}

/// `[feeder]`: the twin's default plate of cells and its floor.
fn feeder(
    s: &mut Section<'_>,
    d: cellinject_simparams::FeederParams,
) -> Result<cellinject_simparams::FeederParams, ConfigError> {
    let cell_diameter = s.arr("cell_diameter", d.cell_diameter, Check::Positive)?;
    if cell_diameter[0] > cell_diameter[1] {
        return Err(ConfigError::Invalid {
            key: s.key("cell_diameter"),
            reason: "the smallest diameter exceeds the largest".into(),
        });
    }
    Ok(cellinject_simparams::FeederParams {
        rows: s.int("rows", d.rows as u64, 0, 1000)? as u32,
        cols: s.int("cols", d.cols as u64, 0, 1000)? as u32,
        pitch: s.num("pitch", d.pitch, Check::Positive)?,
        cell_diameter,
        offset: s.arr("offset", d.offset, Check::Between(-0.1, 0.1))?,
        empty_fraction: s.num("empty_fraction", d.empty_fraction, Check::Between(0.0, 1.0))?,
        debris_density: s.num("debris_density", d.debris_density, Check::Between(0.0, 1e5))?,
        surface_tilt: s.num("surface_tilt", d.surface_tilt, Check::Between(0.0, 0.02))?,
        surface_curvature: s.num(
            "surface_curvature",
            d.surface_curvature,
            Check::Between(0.0, 10.0),
        )?,
    })
}

/// `[injector]`: the injector's largest pressure and the pipette (into
/// `max_pressure` and `pipette`), and the injector's errors.
fn injector(
    s: &mut Section<'_>,
    d: cellinject_simparams::InjectorParams,
    max_pressure: &mut f64,
    pipette: &mut cellinject_rig::PipetteParams,
) -> Result<cellinject_simparams::InjectorParams, ConfigError> {
    *max_pressure = s.num("max_pressure", *max_pressure, Check::Positive)?;
    let angle = s.num(
        "pipette_angle",
        pipette.angle,
        // 10-75°: the glass must rise from the plate behind the tip, and the
        // microscope must still see the tip come along the plate.
        Check::Angle(0.17, 1.31),
    )?;
    let tip_outer_radius = s.num(
        "tip_outer_radius",
        pipette.tip_outer_radius,
        Check::Between(0.05e-6, 5e-6),
    )?;
    let outer_taper = s.num(
        "outer_taper",
        pipette.outer_taper,
        Check::Between(0.01, 1.0),
    )?;
    let shank_radius = s.num(
        "shank_radius",
        pipette.shank_radius,
        Check::Between(tip_outer_radius, 1e-3),
    )?;
    *pipette = cellinject_rig::PipetteParams {
        angle,
        tip_outer_radius,
        outer_taper,
        shank_radius,
        inner_diameter: s.num(
            "tip_inner_diameter",
            pipette.inner_diameter,
            Check::Between(1e-8, 1e-5),
        )?,
        cone_half_angle: s.num(
            "cone_half_angle",
            pipette.cone_half_angle,
            Check::Between(1e-3, 0.5),
        )?,
        viscosity: s.num("viscosity", pipette.viscosity, Check::Between(1e-4, 1.0))?,
        dye_contrast: s.num(
            "dye_contrast",
            pipette.dye_contrast,
            Check::Between(0.0, 10.0),
        )?,
    };
    Ok(cellinject_simparams::InjectorParams {
        conductance_error: s.num(
            "conductance_error",
            d.conductance_error,
            Check::Between(-0.9, 10.0),
        )?,
        pulse_noise: s.num("pulse_noise", d.pulse_noise, Check::Between(0.0, 0.5))?,
    })
}

/// Every bench section except the per-actuator ones.
pub(crate) fn bench(
    top: &mut Section<'_>,
    amplifiers: [AmplifierRange; 3],
    stacks: [StackParams; 3],
) -> Result<(RigParams, SimParams), ConfigError> {
    let d = SimParams::default();
    let r = RigParams::default();
    let (approach, seed) = with(top, "twin", (r.approach, d.seed), |s, (a, seed)| {
        let n = s.int("approach", a.number() as u64, 1, 2)?;
        let approach = Approach::from_number(n as u8).unwrap_or(a);
        Ok((approach, s.int("seed", seed, 0, u64::MAX)?))
    })?;
    let dynamics = with(top, "dynamics", d.dynamics, dynamics)?;
    let joints = with(top, "joints", d.joints, |s, d| {
        Ok(cellinject_simparams::JointParams {
            stick_slip_angle: s.num("stick_slip_angle", d.stick_slip_angle, Check::NonNegative)?,
            slip_rotation: s.num("slip_rotation", d.slip_rotation, Check::Positive)?,
            ball_radius: s.num("ball_radius", d.ball_radius, Check::Positive)?,
        })
    })?;
    let thermal = with(top, "thermal", d.thermal, |s, d| {
        Ok(cellinject_simparams::ThermalParams {
            drift_rate: s.num("drift_rate", d.drift_rate, Check::Between(-1.0, 1.0))?,
            expansion: s.num("expansion", d.expansion, Check::Between(-1e-5, 1e-5))?,
            magnification: s.num(
                "magnification",
                d.magnification,
                Check::Between(-1e-2, 1e-2),
            )?,
        })
    })?;
    let sensors = with(top, "sensor", d.sensors, |s, d| {
        Ok(cellinject_simparams::SensorParams {
            noise: s.num("noise", d.noise, Check::NonNegative)?,
            thermal_drift: s.num(
                "thermal_drift",
                d.thermal_drift,
                Check::Between(-1e-6, 1e-6),
            )?,
        })
    })?;
    let mut stage_travel = r.stage_travel;
    let stage = with(top, "stage", d.stage, |s, d| {
        stage_travel = s.num("travel", stage_travel, Check::Positive)?;
        stage_motion(s, d)
    })?;
    let mut feeder_travel = r.feeder_travel;
    let feeder_stage = with(top, "feeder_stage", d.feeder_stage, |s, d| {
        feeder_travel = s.num("travel", feeder_travel, Check::Between(1e-3, 1.0))?;
        stage_motion(s, d)
    })?;
    let camera = with(top, "camera", d.camera, camera)?;
    let mut optics = r.optics;
    let lens = with(top, "optics", d.lens, |s, d| {
        let zoom_range = s.arr("zoom_range", optics.zoom_range, Check::Positive)?;
        if zoom_range[0] > zoom_range[1] {
            return Err(ConfigError::Invalid {
                key: s.key("zoom_range"),
                reason: "the smallest magnification exceeds the largest".into(),
            });
        }
        optics = OpticsSetup {
            zoom: s.num(
                "zoom",
                optics.zoom,
                Check::Between(zoom_range[0], zoom_range[1]),
            )?,
            zoom_range,
            marker: s.arr("marker", optics.marker, Check::Between(-1e-3, 1e-3))?,
        };
        Ok(LensParams {
            focus_blur: s.num("focus_blur", d.focus_blur, Check::NonNegative)?,
            defocus_rate: s.num("defocus_rate", d.defocus_rate, Check::NonNegative)?,
        })
    })?;
    let feeder = with(top, "feeder", d.feeder, feeder)?;
    let mut injector_max_pressure = r.injector_max_pressure;
    let mut pipette = r.pipette;
    let injector = with(top, "injector", d.injector, |s, d| {
        injector(s, d, &mut injector_max_pressure, &mut pipette)
    })?;
    let safety = with(top, "safety", r.safety, |s, d| {
        Ok(SafetyMargins {
            hysteresis_bound: s.num(
                "hysteresis_bound",
                d.hysteresis_bound,
                Check::Between(0.0, 1.0),
            )?,
            dynamic_margin: s.num("dynamic_margin", d.dynamic_margin, Check::Between(0.0, 1.0))?,
        })
    })?;
    let rig = RigParams {
        approach,
        amplifiers,
        safety,
        stage_travel,
        feeder_travel,
        injector_max_pressure,
        pipette,
        optics,
        // Computed by the front end from the structural model (not a description key).
        j3_yield: None,
    };
    let sim = SimParams {
        seed,
        stacks,
        dynamics,
        joints,
        thermal,
        sensors,
        stage,
        feeder_stage,
        camera,
        lens,
        feeder,
        injector,
        biology: d.biology,
    };
    Ok((rig, sim))
}
