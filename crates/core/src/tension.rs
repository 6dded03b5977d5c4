//! `tension`: the pre-tension analysis of one approach (Sec. 2.1, 2.2; eqs. 14-33).

use cellinject_model::{ACTUATOR_NAMES, Approach, Design, Mechanism, ModelError, Tension};
use serde::Serialize;
use serde::ser::SerializeMap;

/// One quantity of the analysis.
#[derive(Debug, Clone, PartialEq)]
pub struct Quantity {
    /// Key, as in the paper's notation (`dl0`, `dX`, `Fw`, ...).
    pub key: &'static str,
    /// Equation number in the paper where it is published, if it is.
    pub eq: Option<u32>,
    /// What it is.
    pub meaning: &'static str,
    /// SI unit (`m`, `rad`, `N`, `N*m`).
    pub unit: &'static str,
    /// Components (3 per axis, 4 for the J1/J2 torques).
    pub value: Vec<f64>,
}

/// Margins over the working range.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `force_range` | N | per actuator A1, A2: least and most compressive force |
/// | `compression_margin` | N | how far the force stays from zero |
/// | `capacity_margin` | N | push capacity minus the largest compressive force |
/// | `torque_max` | N·m | largest J1/J2 bending torque passed to the stack |
/// | `torque_limit` | N·m | the stacks' torque limits |
/// | `torque_margin` | N·m | limit minus `torque_max` |
/// | `offset` | m | end-effector offset from home after tensioning |
/// | `ok` | bool | every margin holds |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MarginsReport {
    /// N.
    pub force_range: [[f64; 2]; 2],
    /// N.
    pub compression_margin: [f64; 2],
    /// N.
    pub capacity_margin: [f64; 2],
    /// N·m.
    pub torque_max: [f64; 2],
    /// N·m.
    pub torque_limit: [f64; 2],
    /// N·m.
    pub torque_margin: [f64; 2],
    /// m.
    pub offset: f64,
    /// Every margin holds.
    pub ok: bool,
}

/// The result of `cellinject tension`.
///
/// JSON: `design` (name), `approach` (1 or 2), then one key per quantity with its
/// components in SI units (`F10` N, `dl0` m (approach 1), `dq0` rad (approach 2),
/// `dl1`, `dl`, `dX` m, `Fq` N·m, `Fw` N·m (axes 11, 12, 21, 22), `dl2`, `dl_total` m,
/// `F_work` N, `dl1_work`, `dl_work`, `dX_work` m, `Fq_work`, `Fw_work` N·m, `chi` m),
/// `margins` ([`MarginsReport`]) and `warnings` (strings).
#[derive(Debug, Clone, PartialEq)]
pub struct TensionReport {
    /// The description's name.
    pub design: String,
    /// Which approach.
    pub approach: Approach,
    /// Every quantity, in the paper's order.
    pub quantities: Vec<Quantity>,
    /// Margins over the working range.
    pub margins: MarginsReport,
    /// A line per violated margin.
    pub warnings: Vec<String>,
}

impl Serialize for TensionReport {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(Some(self.quantities.len() + 4))?;
        m.serialize_entry("design", &self.design)?;
        m.serialize_entry("approach", &self.approach.number())?;
        for q in &self.quantities {
            m.serialize_entry(q.key, &q.value)?;
        }
        m.serialize_entry("margins", &self.margins)?;
        m.serialize_entry("warnings", &self.warnings)?;
        m.end()
    }
}

/// SI unit and meaning of each quantity of [`Tension::quantities`].
pub fn quantity_info(key: &str) -> (&'static str, &'static str) {
    match key {
        "F10" => ("N", "actuator force after tensioning F10"),
        "dl0" => ("m", "assembly translation along the drives Δl0"),
        "dq0" => ("rad", "assembly deflection of J3 Δq0"),
        "dl1" => ("m", "elastic deformation of the stacks Δl1"),
        "dl" => ("m", "effective drive displacement δl"),
        "dX" => ("m", "end-effector offset after tensioning δX"),
        "Fq" => ("N*m", "torques in J3 Fq"),
        "Fw" => ("N*m", "torques in J1, J2 Fw (axes 11, 12, 21, 22)"),
        "dl2" => ("m", "working shift Δl2"),
        "dl_total" => ("m", "Δl0 + Δl2"),
        "F_work" => ("N", "actuator force at the working shift"),
        "dl1_work" => ("m", "elastic deformation at the working shift"),
        "dl_work" => ("m", "effective drive displacement at the working shift"),
        "dX_work" => ("m", "end-effector at the working shift"),
        "Fq_work" => ("N*m", "torques in J3 at the working shift"),
        "Fw_work" => ("N*m", "torques in J1, J2 at the working shift"),
        "chi" => ("m", "working range χ (axis 3: A3 travel)"),
        _ => ("", ""),
    }
}

/// A short title of an approach.
pub fn approach_title(a: Approach) -> &'static str {
    match a {
        Approach::DriveTranslation => "assembly translation along the drive axes (Sec. 2.1)",
        Approach::JointDeflection => "assembly deflection of the J3 flexure (Sec. 2.2)",
    }
}

/// The margins of an analysis, with the design's torque limits.
pub fn margins(t: &Tension, design: &Design) -> MarginsReport {
    let g = &t.margins;
    MarginsReport {
        force_range: g.force_range,
        compression_margin: g.compression_margin,
        capacity_margin: g.capacity_margin,
        torque_max: g.torque_max,
        torque_limit: [
            design.actuators[0].torque_limit,
            design.actuators[1].torque_limit,
        ],
        torque_margin: g.torque_margin,
        offset: g.offset,
        ok: g.warnings(design).is_empty(),
    }
}

/// The report of an analysis already computed.
pub fn report(name: &str, design: &Design, t: &Tension) -> TensionReport {
    let approach = t.approach;
    let quantities = t
        .quantities()
        .into_iter()
        .map(|(key, value)| {
            let (unit, meaning) = quantity_info(key);
            let eq = cellinject_paper::figures()
                .iter()
                .find(|f| f.approach == approach.number() && f.key == key)
                .map(|f| f.eq);
            Quantity {
                key,
                eq,
                meaning,
                unit,
                value,
            }
        })
        .collect();
    TensionReport {
        design: name.to_string(),
        approach,
        quantities,
        margins: margins(t, design),
        warnings: t.margins.warnings(design),
    }
}

/// `cellinject tension`: the pre-tension analysis of `design` with `approach`.
pub fn tension(
    name: &str,
    design: &Design,
    approach: Approach,
) -> Result<TensionReport, ModelError> {
    let m = Mechanism::new(design)?;
    let t = m.tension(approach)?;
    Ok(report(name, design, &t))
}

/// Names of the two tilt actuators, for tables of margins.
pub const TILT_ACTUATORS: [&str; 2] = [ACTUATOR_NAMES[0], ACTUATOR_NAMES[1]];

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use cellinject_model::prototype;

    #[test]
    fn the_json_holds_every_quantity_once_with_its_paper_equation() {
        let d = prototype();
        let r = tension("p", &d, Approach::DriveTranslation).unwrap();
        let v: serde_json::Value = serde_json::to_value(&r).unwrap();
        let t = Mechanism::new(&d)
            .unwrap()
            .tension(Approach::DriveTranslation)
            .unwrap();
        for (k, value) in t.quantities() {
            assert_eq!(v[k], serde_json::json!(value), "{k}");
        }
        assert_eq!(v["approach"], 1);
        // Eq. (38) is approach 1's assembly translation (paper-values.toml).
        let dl0 = r.quantities.iter().find(|q| q.key == "dl0").unwrap();
        assert_eq!((dl0.eq, dl0.unit), (Some(38), "m"));
        assert!(v.get("dq0").is_none());
    }
}
