//! The `[structure]` section: dimensions and material of the double-notched joints and
//! the masses of the whole-manipulator model. Every key is optional and defaults to the
//! prototype's value (`StructureParams::default()`).

use cellinject_structure::{BodyShape, JointDimensions, StructureParams};

use crate::ConfigError;
use crate::section::{Check, Section};
use crate::twin::with;

pub(crate) fn structure(top: &mut Section<'_>) -> Result<StructureParams, ConfigError> {
    let d = StructureParams::default();
    let p = with(top, "structure", d, |s, d| {
        let side = s.num("joint_side", d.joint.side, Check::Positive)?;
        let joint = JointDimensions {
            side,
            radius: s.num("joint_radius", d.joint.radius, Check::Positive)?,
            flat: s.num("joint_flat", d.joint.flat, Check::NonNegative)?,
            gap: s.num("joint_gap", d.joint.gap, Check::NonNegative)?,
        };
        let below = |v: f64| Check::Between(1e-6, v * (1.0 - 1e-9));
        Ok(StructureParams {
            joint,
            throat_j12: s.num("throat_J12", d.throat_j12, below(side))?,
            throat_j3: s.num("throat_J3", d.throat_j3, below(side))?,
            shape: shape(s, &d.shape)?,
            youngs: s.num("youngs", d.youngs, Check::Positive)?,
            poisson: poisson(s, d.poisson)?,
            yield_strength: s.num("yield_strength", d.yield_strength, Check::Positive)?,
        })
    })?;
    Ok(p)
}

/// Keys of the fixed masses before they followed the dimensions.
const FIXED_MASS_KEYS: [&str; 4] = ["body_mass", "body_com", "body_inertia", "stack_mass"];

/// The bodies' shapes and densities; the fixed masses of earlier files are refused with
/// the keys that replace them.
fn shape(s: &mut Section<'_>, d: &BodyShape) -> Result<BodyShape, ConfigError> {
    for key in FIXED_MASS_KEYS {
        if s.has(key) {
            return Err(ConfigError::Invalid {
                key: s.key(key),
                reason: "the masses follow the dimensions now: set body_side, body_density, \
                         tool_mass, stack_side and stack_density instead (configs/prototype.toml \
                         documents the shapes)"
                    .into(),
            });
        }
    }
    Ok(BodyShape {
        body_side: s.num("body_side", d.body_side, Check::Positive)?,
        body_density: s.num("body_density", d.body_density, Check::Positive)?,
        tool_mass: s.num("tool_mass", d.tool_mass, Check::NonNegative)?,
        stack_side: s.num("stack_side", d.stack_side, Check::Positive)?,
        stack_density: s.num("stack_density", d.stack_density, Check::Positive)?,
    })
}

/// `structure.poisson`: within the open interval (−1, 0.5), where the elasticity
/// matrix is positive definite (0.5: incompressible; −1: no shear stiffness).
fn poisson(s: &mut Section<'_>, default: f64) -> Result<f64, ConfigError> {
    let nu = s.opt_number("poisson")?.unwrap_or(default);
    if !(nu > -1.0 && nu < 0.5) {
        return Err(ConfigError::Invalid {
            key: s.key("poisson"),
            reason: format!("{nu} must lie in the open interval (-1, 0.5)"),
        });
    }
    Ok(nu)
}

#[cfg(test)]
mod tests {
    use crate::{ConfigError, PROTOTYPE_TOML, parse};

    fn with_line(line: &str) -> Result<crate::Description, ConfigError> {
        let at = "stack_density = 7800.0";
        assert!(PROTOTYPE_TOML.contains(at));
        parse(&PROTOTYPE_TOML.replacen(at, &format!("{line}\n{at}"), 1))
    }

    #[test]
    fn the_fixed_masses_of_earlier_files_are_refused_with_the_keys_that_replace_them() {
        for line in [
            "body_mass = 0.2",
            "stack_mass = 0.05",
            "body_inertia = [1e-4, 1e-4, 1e-5]",
        ] {
            let e = with_line(line).unwrap_err().to_string();
            let key = line.split(' ').next().unwrap();
            assert!(e.contains(&format!("structure.{key}")), "{e}");
            assert!(e.contains("body_side") && e.contains("tool_mass"), "{e}");
        }
        let d =
            crate::parse(&PROTOTYPE_TOML.replace("tool_mass = 0.02", "tool_mass = 0.05")).unwrap();
        assert_eq!(d.structure.shape.tool_mass, 0.05);
    }

    #[test]
    fn the_material_keys_are_read_and_validated() {
        // The prototype sets them to the defaults; without them the defaults hold.
        let d = crate::prototype();
        assert_eq!(
            (
                d.structure.youngs,
                d.structure.poisson,
                d.structure.yield_strength
            ),
            (190e9, 0.3, 465e6)
        );
        let start = PROTOTYPE_TOML.find("youngs =").unwrap();
        let end = start
            + PROTOTYPE_TOML[start..]
                .find("\n[")
                .unwrap_or(PROTOTYPE_TOML.len() - start);
        let without = parse(&format!(
            "{}{}",
            &PROTOTYPE_TOML[..start],
            &PROTOTYPE_TOML[end..]
        ))
        .unwrap();
        assert_eq!(without.structure, d.structure);
        let text = PROTOTYPE_TOML
            .replacen("youngs = 190e9", "youngs = 200e9", 1)
            .replacen("poisson = 0.3 ", "poisson = 0.29", 1)
            .replacen("yield_strength = 465e6", "yield_strength = 5e8", 1);
        let d = parse(&text).unwrap();
        assert_eq!(
            (
                d.structure.youngs,
                d.structure.poisson,
                d.structure.yield_strength
            ),
            (200e9, 0.29, 5e8)
        );
        for (from, to, key) in [
            ("youngs = 190e9", "youngs = -1.0", "structure.youngs"),
            ("youngs = 190e9", "youngs = nan", "structure.youngs"),
            ("poisson = 0.3 ", "poisson = 0.5 ", "structure.poisson"),
            ("poisson = 0.3 ", "poisson = -1.0", "structure.poisson"),
            ("poisson = 0.3 ", "poisson = inf ", "structure.poisson"),
            (
                "yield_strength = 465e6",
                "yield_strength = 0",
                "structure.yield_strength",
            ),
        ] {
            assert!(PROTOTYPE_TOML.contains(from), "{from}");
            let e = parse(&PROTOTYPE_TOML.replacen(from, to, 1)).unwrap_err();
            assert_eq!(e.key(), Some(key), "{from} -> {to}: {e}");
        }
        let e = with_line("poisson_ratio = 0.3").unwrap_err();
        assert_eq!(e.key(), Some("structure.poisson_ratio"));
    }
}
