//! # cellinject-config
//!
//! The manipulator description file (TOML, SI units): parsing and validation.
//! The paper's prototype ships as `configs/prototype.toml` and is embedded here as
//! [`PROTOTYPE_TOML`]. Every error names the key at fault, in dotted form
//! (`geometry.b1`, `actuators.A2.travel`, `tension.preload[1]`).
//!
//! **Architecture invariant:** this crate parses text it is given; it never opens a
//! file. The binary reads files and adds the file name to the error.

use cellinject_model::{Actuator, Design, Flexures, Geometry, Mechanism, ModelError, TensionSpec};
use cellinject_rig::RigParams;
use cellinject_rig::params::AmplifierRange;
use cellinject_simparams::{SimParams, StackParams};
use cellinject_structure::StructureParams;
use thiserror::Error;

pub mod overrides;
pub mod plate;
pub mod rigfile;
mod section;
mod structure;
mod twin;

use section::Section;

/// The embedded description of the paper's prototype (`configs/prototype.toml`).
pub const PROTOTYPE_TOML: &str = include_str!("../../../configs/prototype.toml");

/// What is wrong with a description file.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ConfigError {
    /// The text is not valid TOML.
    #[error("not valid TOML:\n{message}")]
    Syntax {
        /// The parser's message over several lines: line and column, the line itself
        /// with a caret under the fault, and what is wrong.
        message: String,
    },
    /// A required key is absent.
    #[error("key `{key}` is missing")]
    Missing {
        /// Dotted key.
        key: String,
    },
    /// A key that the format does not know.
    #[error("unknown key `{key}` (expected one of: {expected})")]
    Unknown {
        /// Dotted key.
        key: String,
        /// The keys allowed at that place.
        expected: String,
    },
    /// A value of the wrong type or shape.
    #[error("key `{key}` must be {expected}, found {found}")]
    Type {
        /// Dotted key.
        key: String,
        /// What was expected.
        expected: String,
        /// What was found.
        found: String,
    },
    /// A value outside its valid domain, or a design the model refuses.
    #[error("key `{key}`: {reason}")]
    Invalid {
        /// Dotted key.
        key: String,
        /// What is wrong.
        reason: String,
    },
}

impl ConfigError {
    /// The dotted key the error is about, if any.
    pub fn key(&self) -> Option<&str> {
        match self {
            ConfigError::Syntax { .. } => None,
            ConfigError::Missing { key }
            | ConfigError::Unknown { key, .. }
            | ConfigError::Type { key, .. }
            | ConfigError::Invalid { key, .. } => Some(key),
        }
    }
}

/// A parsed and validated manipulator description.
#[derive(Debug, Clone, PartialEq)]
pub struct Description {
    /// Human-readable name of the manipulator.
    pub name: String,
    /// The mechanism parameters.
    pub design: Design,
    /// The physical bench: approach, amplifier ranges, safety margins, travels,
    /// injector limit, zoom (shared by the twin and real hardware).
    pub rig: RigParams,
    /// What only the digital twin needs: noise, hysteresis, creep, dynamics, stick-slip,
    /// camera sensor, scene.
    pub sim: SimParams,
    /// The whole-manipulator structural model's parameters (`[structure]`).
    pub structure: StructureParams,
    /// Whether the file sets `[structure]` itself (else the prototype's joints are
    /// assumed, and `[flexures]` is not checked against them).
    pub structure_given: bool,
}

impl Description {
    /// The mechanism model of this description (cannot fail: validated at parse time).
    pub fn mechanism(&self) -> Mechanism {
        // Validation in `parse` ran `Mechanism::new` on this very design.
        Mechanism::new(&self.design)
            .unwrap_or_else(|e| unreachable!("validated design refused: {e}"))
    }
}

/// Parses and validates a description file's text.
pub fn parse(text: &str) -> Result<Description, ConfigError> {
    let root = toml_table(text)?;
    let mut top = Section::root(&root);
    let name = top.string("name")?;
    let mut g = top.table("geometry")?;
    let a11 = g.number("a11")?;
    let a12 = g.number("a12")?;
    let geometry = Geometry {
        a11,
        a12,
        a21: g.opt_number("a21")?.unwrap_or(a11),
        a22: g.opt_number("a22")?.unwrap_or(a12),
        b1: g.number("b1")?,
        b2: g.number("b2")?,
        actuator_azimuth: g
            .opt_array::<2>("actuator_azimuth")?
            .unwrap_or([0.0, std::f64::consts::FRAC_PI_2]),
    };
    g.finish()?;
    let mut f = top.table("flexures")?;
    let flexures = Flexures {
        j3: f.array::<2>("J3")?,
        j1: f.array::<2>("J1")?,
        j2: f.array::<2>("J2")?,
    };
    f.finish()?;
    let mut acts = top.table("actuators")?;
    let mut actuator =
        |name: &str| -> Result<(Actuator, AmplifierRange, StackParams), ConfigError> {
            let mut a = acts.table(name)?;
            let out = Actuator {
                stiffness: a.opt_number("stiffness")?,
                travel: a.number("travel")?,
                push_capacity: a.number("push_capacity")?,
                torque_limit: a.number("torque_limit")?,
            };
            let (range, stack) = twin::stack(&mut a)?;
            a.finish()?;
            Ok((out, range, stack))
        };
    let (a1, r1, s1) = actuator("A1")?;
    let (a2, r2, s2) = actuator("A2")?;
    let (a3, r3, s3) = actuator("A3")?;
    let actuators = [a1, a2, a3];
    acts.finish()?;
    let mut t = top.table("tension")?;
    let tension = TensionSpec {
        preload: t.array::<2>("preload")?,
        work_shift: t.array::<2>("work_shift")?,
    };
    t.finish()?;
    let (rig, sim) = twin::bench(&mut top, [r1, r2, r3], [s1, s2, s3])?;
    let structure_given = root.contains_key("structure");
    let structure = structure::structure(&mut top)?;
    top.finish()?;
    let design = Design {
        geometry,
        flexures,
        actuators,
        tension,
    };
    Mechanism::new(&design).map_err(|e| match e {
        ModelError::InvalidParameter { key, reason, value } => ConfigError::Invalid {
            key,
            reason: if value.is_nan() {
                reason
            } else {
                format!("{value} {reason}")
            },
        },
        other => ConfigError::Invalid {
            key: "geometry".into(),
            reason: other.to_string(),
        },
    })?;
    Ok(Description {
        name,
        design,
        rig,
        sim,
        structure,
        structure_given,
    })
}

/// The text as a TOML table, or the parser's message.
pub(crate) fn toml_table(text: &str) -> Result<toml::Table, ConfigError> {
    text.parse()
        .map_err(|e: toml::de::Error| ConfigError::Syntax {
            message: e.to_string().trim_end().to_string(),
        })
}

/// The embedded prototype description.
pub fn prototype() -> Description {
    parse(PROTOTYPE_TOML)
        .unwrap_or_else(|e| unreachable!("embedded prototype.toml is invalid: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_prototype_equals_the_models_prototype() {
        let d = prototype();
        assert_eq!(d.name, "ICINCO-2012 prototype");
        assert_eq!(d.design, cellinject_model::prototype());
        assert_eq!(d.rig, RigParams::default());
        assert_eq!(d.sim, SimParams::default());
        assert_eq!(d.structure, StructureParams::default());
    }

    fn replace(from: &str, to: &str) -> Result<Description, ConfigError> {
        assert!(PROTOTYPE_TOML.contains(from), "{from}");
        parse(&PROTOTYPE_TOML.replacen(from, to, 1))
    }

    #[test]
    fn missing_key_is_named() {
        let e = replace("b1 = 0.030", "").unwrap_err();
        assert_eq!(
            e,
            ConfigError::Missing {
                key: "geometry.b1".into()
            }
        );
        let e = replace("[tension]", "[tensio]").unwrap_err();
        assert_eq!(e.key(), Some("tension"));
    }

    #[test]
    fn unknown_key_is_named() {
        let e = replace("b2 = 0.180", "b2 = 0.180\nb3 = 1.0").unwrap_err();
        assert_eq!(e.key(), Some("geometry.b3"));
        assert!(e.to_string().contains("b1"), "{e}");
        let e = replace("name =", "colour = 3\nname =").unwrap_err();
        assert_eq!(e.key(), Some("colour"));
    }

    #[test]
    fn non_positive_and_non_finite_values_are_named() {
        for (from, to, key) in [
            ("b1 = 0.030", "b1 = 0.0", "geometry.b1"),
            ("a12 = 0.066", "a12 = -0.066", "geometry.a12"),
            ("b2 = 0.180", "b2 = nan", "geometry.b2"),
            (
                "stiffness = 27e6        #",
                "stiffness = inf #",
                "actuators.A1.stiffness",
            ),
            ("J1 = [91.3, 91.3]", "J1 = [91.3, 0]", "flexures.J1[1]"),
            (
                "preload = [-100.0, -100.0]",
                "preload = [-100.0, 5.0]",
                "tension.preload[1]",
            ),
            (
                "work_shift = [-30e-6, -30e-6]",
                "work_shift = [-31e-6, -30e-6]",
                "tension.work_shift[0]",
            ),
        ] {
            let e = replace(from, to).unwrap_err();
            assert_eq!(e.key(), Some(key), "{from} -> {to}: {e}");
        }
    }

    #[test]
    fn a_pipette_angle_typed_in_degrees_is_refused_with_its_radians() {
        let from = "pipette_angle = 0.9599310885968813";
        let e = replace(from, "pipette_angle = 45").unwrap_err();
        assert_eq!(e.key(), Some("injector.pipette_angle"), "{e}");
        let m = e.to_string();
        assert!(m.contains("45° would be 0.7854"), "{m}");
        // Out of range in radians: no degrees hint.
        let e = replace(from, "pipette_angle = 0.1").unwrap_err();
        assert!(!e.to_string().contains('°'), "{e}");
        assert!(replace(from, "pipette_angle = 0.7853981633974483").is_ok());
    }

    #[test]
    fn wrong_types_are_named() {
        let e = replace("b1 = 0.030", "b1 = \"thirty\"").unwrap_err();
        assert!(
            matches!(e, ConfigError::Type { ref key, .. } if key == "geometry.b1"),
            "{e}"
        );
        let e = replace("J3 = [340.3, 340.3]", "J3 = [340.3]").unwrap_err();
        assert_eq!(e.key(), Some("flexures.J3"));
    }

    #[test]
    fn singular_geometry_is_refused() {
        let e = replace(
            "actuator_azimuth = [0.0, 1.5707963267948966]",
            "actuator_azimuth = [0.0, 0.0]",
        )
        .unwrap_err();
        assert_eq!(e.key(), Some("geometry"));
        assert!(e.to_string().contains("singular"), "{e}");
    }

    #[test]
    fn twin_sections_are_validated_by_key() {
        for (from, to, key) in [
            (
                "slew_rate = 1.0e4",
                "slew_rate = -1.0",
                "actuators.A1.amplifier.slew_rate",
            ),
            (
                "fraction = 0.25",
                "fraction = 1.5",
                "actuators.A1.hysteresis.fraction",
            ),
            ("rate = 20000.0", "rate = 1000.0", "dynamics.rate"),
            ("bit_depth = 8", "bit_depth = 10", "camera.bit_depth"),
            ("zoom = 10.0", "zoom = 20.0", "optics.zoom"),
            ("approach = 2", "approach = 3", "twin.approach"),
            ("rows = 4", "rows = 4.5", "feeder.rows"),
            ("gamma = 0.015", "gama = 0.015", "actuators.A1.creep.gama"),
            ("noise = 3.0e-9", "noise = -3.0e-9", "sensor.noise"),
        ] {
            let e = replace(from, to).unwrap_err();
            assert_eq!(e.key(), Some(key), "{from} -> {to}: {e}");
        }
        // Sections are optional: a file without them gets the prototype's values.
        let start = PROTOTYPE_TOML.find("\n[twin]").unwrap();
        let d = parse(&PROTOTYPE_TOML[..start]).unwrap();
        assert_eq!(d.sim.dynamics, SimParams::default().dynamics);
        assert_eq!(d.rig, RigParams::default());
    }

    #[test]
    fn syntax_error_is_reported() {
        let e = parse("name = ").unwrap_err();
        assert!(matches!(e, ConfigError::Syntax { .. }));
    }
}
