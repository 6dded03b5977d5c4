//! The manipulator description as plain data: geometry, joint stiffnesses,
//! actuator limits and the pre-tension specification. All values are SI.

use crate::error::ModelError;

/// Geometry of the serial-parallel structure (paper Sec. 3.1, Fig. 1), metres and radians.
///
/// Frame and conventions (the paper's Fig. 1 is not in the text; this is our reading):
/// - origin at the centre of the universal flexure J3, body 1 hangs along +z;
/// - the end-effector M sits on the body axis at distance `b2` from J3;
/// - the actuators A1 and A2 lie in the plane z = `b1`, perpendicular to body 1,
///   along the unit directions `d_i = (cos φ_i, sin φ_i, 0)`, φ = `actuator_azimuth`
///   (default 0 and π/2: A1 along x, A2 along y);
/// - actuator i is pinned to the base by its 2-DOF flexure at `(0, 0, b1) − (a_i1 + a_i2)·d_i`
///   and reaches body 1 through a spherical joint at `(0, 0, b1)`;
/// - A3 extends the pipette along the body axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geometry {
    /// m, flexure J1 to the start of actuator A1.
    pub a11: f64,
    /// m, length of actuator A1 (J1 to the spherical joint is `a11 + a12`).
    pub a12: f64,
    /// m, flexure J2 to the start of actuator A2.
    pub a21: f64,
    /// m, length of actuator A2.
    pub a22: f64,
    /// m, J3 to the actuators' attachment on body 1.
    pub b1: f64,
    /// m, J3 to the end-effector M.
    pub b2: f64,
    /// rad, direction of A1 and A2 in the plane perpendicular to body 1.
    pub actuator_azimuth: [f64; 2],
}

impl Geometry {
    /// Distance from flexure J_i to the spherical joint on body 1 (`a_i1 + a_i2`), i = 0 for A1.
    pub fn reach(&self, i: usize) -> f64 {
        if i == 0 {
            self.a11 + self.a12
        } else {
            self.a21 + self.a22
        }
    }
}

/// Rotational stiffnesses of the 2-DOF flexures, N·m/rad, [first axis, second axis].
///
/// Axis conventions (chosen so that the paper's signs of eqs. 42-43 come out):
/// - J3: axis 1 is the base y axis (q1 tilts M towards +x), axis 2 is body 1's x axis
///   (q2 tilts M towards −y);
/// - J1, J2: axis 1 is −z (swings the actuator within the plane z = b1), axis 2 is
///   `ẑ × d_i` (tilts the actuator out of that plane).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Flexures {
    /// J3, the universal joint of the main serial chain (matrix Kq, eq. 34).
    pub j3: [f64; 2],
    /// J1, the base flexure of actuator A1 (first half of Kw, eq. 35).
    pub j1: [f64; 2],
    /// J2, the base flexure of actuator A2 (second half of Kw, eq. 35).
    pub j2: [f64; 2],
}

/// One piezo stack actuator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Actuator {
    /// N/m, axial stiffness (matrix Kl, eq. 36). `None` for A3, which is not pre-tensioned.
    pub stiffness: Option<f64>,
    /// m, nominal travel (stroke).
    pub travel: f64,
    /// N, largest compressive force the stack may carry.
    pub push_capacity: f64,
    /// N·m, largest bending torque the stack may carry.
    pub torque_limit: f64,
}

/// What the pre-tension must achieve (paper eqs. 37 and 44).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TensionSpec {
    /// N, desired actuator forces F10 of A1 and A2 (compression is negative).
    pub preload: [f64; 2],
    /// m, working shifts Δl2 of A1 and A2 that define the working range.
    pub work_shift: [f64; 2],
}

/// A complete manipulator description.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Design {
    /// Lengths and directions.
    pub geometry: Geometry,
    /// Flexure stiffnesses.
    pub flexures: Flexures,
    /// A1, A2, A3.
    pub actuators: [Actuator; 3],
    /// Preload and working shift.
    pub tension: TensionSpec,
}

/// Names of the actuators, in order.
pub const ACTUATOR_NAMES: [&str; 3] = ["A1", "A2", "A3"];

fn positive(key: &str, value: f64) -> Result<(), ModelError> {
    if !value.is_finite() {
        return Err(ModelError::invalid(key, value, "must be a finite number"));
    }
    if value <= 0.0 {
        return Err(ModelError::invalid(key, value, "must be positive"));
    }
    Ok(())
}

impl Design {
    /// The stiffness of A1 and A2 (validated designs always have it).
    pub fn drive_stiffness(&self) -> [f64; 2] {
        [
            self.actuators[0].stiffness.unwrap_or(f64::NAN),
            self.actuators[1].stiffness.unwrap_or(f64::NAN),
        ]
    }

    /// Checks every value for sign, finiteness and consistency. Keys in the error are
    /// those of the description file (`geometry.b1`, `actuators.A2.travel`, ...).
    pub fn validate(&self) -> Result<(), ModelError> {
        let g = &self.geometry;
        for (key, v) in [
            ("geometry.a11", g.a11),
            ("geometry.a12", g.a12),
            ("geometry.a21", g.a21),
            ("geometry.a22", g.a22),
            ("geometry.b1", g.b1),
            ("geometry.b2", g.b2),
        ] {
            positive(key, v)?;
        }
        for (i, v) in g.actuator_azimuth.iter().enumerate() {
            if !v.is_finite() {
                return Err(ModelError::invalid(
                    &format!("geometry.actuator_azimuth[{i}]"),
                    *v,
                    "must be a finite number",
                ));
            }
        }
        if g.b1 >= g.b2 {
            return Err(ModelError::invalid(
                "geometry.b1",
                g.b1,
                &format!(
                    "must be smaller than geometry.b2 = {} (the actuators act between J3 and the end-effector)",
                    g.b2
                ),
            ));
        }
        let f = &self.flexures;
        for (name, k) in [("J3", f.j3), ("J1", f.j1), ("J2", f.j2)] {
            for (i, v) in k.iter().enumerate() {
                positive(&format!("flexures.{name}[{i}]"), *v)?;
            }
        }
        for (i, a) in self.actuators.iter().enumerate() {
            let name = ACTUATOR_NAMES[i];
            match a.stiffness {
                Some(k) => positive(&format!("actuators.{name}.stiffness"), k)?,
                None if i < 2 => {
                    return Err(ModelError::invalid(
                        &format!("actuators.{name}.stiffness"),
                        f64::NAN,
                        "is required: A1 and A2 are pre-tensioned",
                    ));
                }
                None => {}
            }
            positive(&format!("actuators.{name}.travel"), a.travel)?;
            positive(&format!("actuators.{name}.push_capacity"), a.push_capacity)?;
            positive(&format!("actuators.{name}.torque_limit"), a.torque_limit)?;
        }
        for i in 0..2 {
            let p = self.tension.preload[i];
            let key = format!("tension.preload[{i}]");
            if !p.is_finite() {
                return Err(ModelError::invalid(&key, p, "must be a finite number"));
            }
            if p >= 0.0 {
                return Err(ModelError::invalid(
                    &key,
                    p,
                    "must be negative: the stacks are pre-tensioned in compression",
                ));
            }
            let cap = self.actuators[i].push_capacity;
            if -p > cap {
                return Err(ModelError::invalid(
                    &key,
                    p,
                    &format!(
                        "exceeds the push capacity of {} ({cap} N)",
                        ACTUATOR_NAMES[i]
                    ),
                ));
            }
            let s = self.tension.work_shift[i];
            let key = format!("tension.work_shift[{i}]");
            if !s.is_finite() {
                return Err(ModelError::invalid(&key, s, "must be a finite number"));
            }
            let travel = self.actuators[i].travel;
            if s.abs() > travel {
                return Err(ModelError::invalid(
                    &key,
                    s,
                    &format!("exceeds the travel of {} ({travel} m)", ACTUATOR_NAMES[i]),
                ));
            }
        }
        Ok(())
    }
}
