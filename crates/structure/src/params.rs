//! The structural model's parameters: each joint's model and dimensions, body 1's
//! shape and masses, and what a structure is built from.

use super::*;

/// A double-notched joint as the structure sees it: its 6x6 compliance between the
/// end sections and where its notches lie along its axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointModel {
    /// Stiffness at the centre of the top end section, joint frame (local z along the
    /// joint; the lower notch is compliant about local y, the upper about local x):
    /// wrench (N, N·m) per relative motion (m, rad) of the end sections.
    pub stiffness: Matrix6<f64>,
    /// Local z of the bottom end section, m.
    pub lower_end: f64,
    /// Local z of the lower notch's centre, m.
    pub lower_notch: f64,
    /// Local z of the upper notch's centre, m.
    pub upper_notch: f64,
    /// Local z of the top end section, m.
    pub upper_end: f64,
}

impl JointModel {
    /// Middle between the notch centres (local z).
    pub fn middle(&self) -> f64 {
        0.5 * (self.lower_notch + self.upper_notch)
    }

    /// Stiffness from a compliance, inverted after symmetric equilibration
    /// (`S C S` with `S = diag(1/√C_ii)`), so that compliances of very different
    /// sizes (m/N against rad/(N·m)) do not cost accuracy.
    pub fn stiffness_of(compliance: &Matrix6<f64>) -> Option<Matrix6<f64>> {
        let mut d = Vector6::zeros();
        for i in 0..6 {
            let c = compliance[(i, i)];
            if !(c.is_finite() && c > 0.0) {
                return None;
            }
            d[i] = 1.0 / c.sqrt();
        }
        let sm = Matrix6::from_diagonal(&d);
        let inner = (sm * compliance * sm).cholesky()?.inverse();
        let k = sm * inner * sm;
        Some(0.5 * (k + k.transpose()))
    }
}

/// Dimensions shared by the double-notched joints J1-J3 (Fig. 3 of the paper is
/// missing; these are our reading, fitted to its stiffnesses: see `configs/prototype.toml`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointDimensions {
    /// m, side of the square rod.
    pub side: f64,
    /// m, fillet radius at the ends of each slot.
    pub radius: f64,
    /// m, length of each notch's straight throat.
    pub flat: f64,
    /// m, full section between the two notches.
    pub gap: f64,
}

/// The description's `[structure]` section: joint dimensions, throats, the bodies'
/// shapes and densities, the joints' material.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StructureParams {
    /// Joint dimensions common to J1-J3.
    pub joint: JointDimensions,
    /// m, throat Δ1 = Δ2 of J1 and J2 (paper: 1.2 mm).
    pub throat_j12: f64,
    /// m, throat Δ3 of J3 (paper: 2.0 mm).
    pub throat_j3: f64,
    /// Shapes and densities the masses follow from ([`StructureParams::masses`]).
    pub shape: BodyShape,
    /// Pa, Young's modulus of the joints' material (X2CrNi18-9: 190 GPa, Sec. 3.1).
    pub youngs: f64,
    /// Poisson's ratio of the joints' material (0.3; not in the paper).
    pub poisson: f64,
    /// Pa, yield strength the joints' stresses are compared with (X2CrNi18-9: 465 MPa,
    /// Sec. 3.1).
    pub yield_strength: f64,
}

impl Default for StructureParams {
    /// The prototype: a 13.99 mm square rod, slots with 2 mm fillets and 2.31 mm
    /// straight throats, 2 mm between the notches (fitted by the 3-D FEM to 91.3 and
    /// 340.3 N·m/rad at Δ = 1.2 and 2.0 mm; the fillet is the smallest that keeps J3
    /// below yield over both approaches' working ranges); the bodies of
    /// [`BodyShape::default`]; X2CrNi18-9 (E = 190 GPa, ν = 0.3, yield 465 MPa).
    fn default() -> Self {
        StructureParams {
            joint: JointDimensions {
                side: 13.99e-3,
                radius: 2.0e-3,
                flat: 2.31e-3,
                gap: 2.0e-3,
            },
            throat_j12: 1.2e-3,
            throat_j3: 2.0e-3,
            shape: BodyShape::default(),
            youngs: 190e9,
            poisson: 0.3,
            yield_strength: 465e6,
        }
    }
}

impl StructureParams {
    /// The masses of a design with lever arms `geometry`: [`BodyShape::masses`].
    pub fn masses(&self, geometry: &Geometry) -> MassSpec {
        self.shape.masses(geometry)
    }
}

/// The shapes the bodies' masses follow from, so that a design's mass and inertia move
/// with its dimensions (a design study changes `b2` or the stacks' length, and the first
/// natural frequency follows).
///
/// * Body 1 is a uniform square rod of side `body_side` and density `body_density`
///   from J3 (z = 0) to the end-effector (z = `b2`), carrying the tool (A3, the pipette
///   holder and the pipette) as a point mass `tool_mass` at the end-effector.
/// * A1 and A2 are uniform square rods of side `stack_side` and density
///   `stack_density` over their length `a_i2`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyShape {
    /// m, side of body 1's square section.
    pub body_side: f64,
    /// kg/m³, body 1's density (steel: 7900).
    pub body_density: f64,
    /// kg, A3 with the pipette holder and the pipette, at the end-effector.
    pub tool_mass: f64,
    /// m, side of the stacks' square section.
    pub stack_side: f64,
    /// kg/m³, the stacks' density (PZT: 7800).
    pub stack_density: f64,
}

impl Default for BodyShape {
    /// The prototype: a 6 mm steel rod (7900 kg/m³) with a 20 g tool (the twin's
    /// `dynamics.a3_mass`), which gives body 1 the twin's 1.2e-3 kg·m² about J3 at
    /// b2 = 180 mm; stacks of 10 x 10 mm PZT (7800 kg/m³): 51 g at 66 mm.
    fn default() -> Self {
        BodyShape {
            body_side: 6.0e-3,
            body_density: 7900.0,
            tool_mass: 0.02,
            stack_side: 10.0e-3,
            stack_density: 7800.0,
        }
    }
}

impl BodyShape {
    /// Mass, centre of mass and inertia of body 1 and the stacks' masses for the lever
    /// arms of `geometry` (rod: `m = ρ s² b2`, `I = m (b2² + s²)/12` about its centre,
    /// `m s²/6` about its axis; parallel axes to the joint centre of mass).
    pub fn masses(&self, geometry: &Geometry) -> MassSpec {
        let b2 = geometry.b2;
        let rod = self.body_density * self.body_side.powi(2) * b2;
        let tool = self.tool_mass;
        let mass = rod + tool;
        let com = (rod * 0.5 * b2 + tool * b2) / mass;
        let transverse = rod * (b2 * b2 + self.body_side.powi(2)) / 12.0
            + rod * (0.5 * b2 - com).powi(2)
            + tool * (b2 - com).powi(2);
        let axial = rod * self.body_side.powi(2) / 6.0;
        let stack = |len: f64| self.stack_density * self.stack_side.powi(2) * len;
        MassSpec {
            body_mass: mass,
            body_com: com,
            body_inertia: [transverse, transverse, axial],
            stack_mass: [stack(geometry.a12), stack(geometry.a22)],
        }
    }
}

/// Masses for the natural modes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MassSpec {
    /// kg, body 1 with A3, the pipette holder and the pipette.
    pub body_mass: f64,
    /// m, height of body 1's centre of mass above J3's middle.
    pub body_com: f64,
    /// kg·m², body 1's principal moments of inertia about its centre of mass (x, y, z).
    pub body_inertia: [f64; 3],
    /// kg, A1 and A2 (each a uniform rod between J_i and the spherical joint).
    pub stack_mass: [f64; 2],
}

/// The model's inputs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StructureSpec {
    /// J3.
    pub j3: JointModel,
    /// J1 and J2.
    pub j12: [JointModel; 2],
    /// Masses.
    pub mass: MassSpec,
}
