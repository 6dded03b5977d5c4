//! The `[structure]` section: dimensions of the double-notched joints and the masses of
//! the whole-manipulator model. Every key is optional and defaults to the prototype's
//! value (`StructureParams::default()`).

use cellinject_structure::{JointDimensions, MassSpec, StructureParams};

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
            mass: MassSpec {
                body_mass: s.num("body_mass", d.mass.body_mass, Check::Positive)?,
                body_com: s.num("body_com", d.mass.body_com, Check::NonNegative)?,
                body_inertia: s.arr("body_inertia", d.mass.body_inertia, Check::Positive)?,
                stack_mass: s.num("stack_mass", d.mass.stack_mass, Check::Positive)?,
            },
        })
    })?;
    Ok(p)
}
