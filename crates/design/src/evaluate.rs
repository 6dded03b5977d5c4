//! One design evaluated: the figures `cellinject design evaluate` prints.
//!
//! Both fidelities run the same chain, and differ only in where the joints come from:
//!
//! 1. **Joint bending stiffness** from `[structure]`'s dimensions: each of the double
//!    notch's two notches is a corner-filleted leaf (throat Δ, fillet `joint_radius`,
//!    flat `joint_flat`, width `joint_side`) in closed form (Lobontiu 2003:
//!    [`cellinject_flexure::Hinge::k_bend`]) at `beam` fidelity, or the 3-D FEM joint
//!    ([`cellinject_fea::FeaModel`]) at `fea` fidelity. These replace the
//!    description's `[flexures]`, so that a throat moves the range and the modes.
//! 2. **Range and margins** from the pseudo-rigid-body model on those stiffnesses
//!    (eqs. 19-44: `tension`): the working range χ of x and y, the stacks' force
//!    range against their push capacity and compression, J1/J2's torque against the
//!    stacks' limit, and the stacks' travel against the working shift.
//! 3. **Load cases**: the stack forces at the four corners of the working range
//!    (each stack at rest or at its working shift), applied to the whole-manipulator
//!    structural model ([`cellinject_structure`]): the cross-axis coupling is the
//!    largest motion of one axis when the other stack alone crosses its range.
//! 4. **Stresses**: at `fea` fidelity the FEM joints' peak von Mises stress at each
//!    corner (the numbers `cellinject fea --forces` gives); at `beam` fidelity the
//!    throat's bending stress `K_t·6M/(b Δ²)` plus the axial `F/(b Δ)` of each notch
//!    from the pseudo-rigid-body joint torques and stack forces at the corners. The
//!    safety factor of a joint is the yield strength over its worst stress.
//! 5. **Natural modes** of the structure pre-tensioned at the design preload with the
//!    sliders locked (`cellinject fea modes`), its bodies' masses from their shapes
//!    ([`cellinject_structure::BodyShape`]).
//! 6. **Stiffness** at the end-effector: the pseudo-rigid-body tilt stiffness
//!    `K = Kq + Wᵀ Kw W + Lᵀ Kl L` seen through J: `1 / (J K⁻¹ Jᵀ)_ii`, N/m.

use cellinject_config::Description;
use cellinject_fea::{FeaModel, FeaOptions, JointStore, SolvedCase};
use cellinject_flexure::{Hinge, Material, Profile};
use cellinject_model::{Approach, Design, Mechanism};
use cellinject_structure::{JointModel, Preload, Structure, StructureParams, StructureSpec, skew};
use nalgebra::{Matrix2, Matrix3, Matrix6, Vector3};
use serde::{Deserialize, Serialize};

use crate::DesignError;

/// How the joints are modelled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Fidelity {
    /// Closed-form notch formulas: about a millisecond per design.
    Beam,
    /// The joints' 3-D FEM at a mesh level (about a second per new joint geometry at
    /// level 1; repeated geometries come from the joint cache).
    Fea,
}

impl Fidelity {
    /// `beam` or `fea`.
    pub fn name(self) -> &'static str {
        match self {
            Fidelity::Beam => "beam",
            Fidelity::Fea => "fea",
        }
    }

    /// From `beam` or `fea`.
    pub fn from_name(s: &str) -> Option<Self> {
        match s {
            "beam" => Some(Fidelity::Beam),
            "fea" => Some(Fidelity::Fea),
            _ => None,
        }
    }
}

/// What an evaluation is asked for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalOptions {
    /// Pre-tensioning approach (`None`: the description's `twin.approach`).
    pub approach: Option<Approach>,
    /// Joint model.
    pub fidelity: Fidelity,
    /// The joints' FEM mesh level (1 or 2) at `fea` fidelity.
    pub level: usize,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            approach: None,
            fidelity: Fidelity::Beam,
            level: 1,
        }
    }
}

/// Per axis x and y of the end-effector.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Axes {
    /// Along x (A1's axis).
    pub x: f64,
    /// Along y (A2's axis).
    pub y: f64,
}

/// Yield safety factor of each joint.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct JointFactors {
    /// J1 (A1's base flexure).
    #[serde(rename = "J1")]
    pub j1: f64,
    /// J2 (A2's base flexure).
    #[serde(rename = "J2")]
    pub j2: f64,
    /// J3 (body 1's universal flexure).
    #[serde(rename = "J3")]
    pub j3: f64,
}

impl JointFactors {
    fn min(&self) -> f64 {
        self.j1.min(self.j2).min(self.j3)
    }
}

/// Margins of the stacks A1, A2 over the working range (positive: within the limit).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StackMargins {
    /// N, push capacity minus the largest compressive force.
    pub push_capacity_n: [f64; 2],
    /// N, how far the force stays from zero (positive: always compressed, no backlash).
    pub compression_n: [f64; 2],
    /// m, travel minus the working shift's size.
    pub travel_m: [f64; 2],
    /// N·m, the stacks' torque limit minus the largest torque J1 (J2) passes on.
    pub torque_nm: [f64; 2],
}

/// Every figure of one design (`cellinject design evaluate --format json`; SI units).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Figures {
    /// `beam` or `fea`.
    pub fidelity: Fidelity,
    /// The joints' FEM mesh level (`fea` fidelity), else null.
    pub level: Option<usize>,
    /// Pre-tensioning approach, 1 or 2.
    pub approach: u8,
    /// m, working range of each axis (χ, eq. 44).
    pub range_m: Axes,
    /// m, the smaller of the two.
    pub range_min_m: f64,
    /// N/m, stiffness of the end-effector along each axis.
    pub stiffness_n_per_m: Axes,
    /// Hz, the lowest natural frequency.
    pub first_mode_hz: f64,
    /// Hz, the two lowest natural frequencies.
    pub modes_hz: [f64; 2],
    /// Yield safety factor of each joint over the working range.
    pub safety_factors: JointFactors,
    /// The smallest of them.
    pub min_safety_factor: f64,
    /// The stacks' margins.
    pub stack_margins: StackMargins,
    /// m, largest motion of one axis when the other stack alone crosses its range.
    pub coupling_m: f64,
    /// N·m/rad, the joints' bending stiffness used ([about x, about y]).
    pub joint_k_bend: JointBend,
    /// kg, body 1 (from its shape).
    pub body_mass_kg: f64,
    /// N, the stack forces (A1, A2) of the load cases: the working range's corners.
    pub load_cases_n: Vec<[f64; 2]>,
    /// Whether every margin of the safety envelope holds.
    pub feasible: bool,
    /// The margins that do not hold, by name (`A1.push_capacity`, `A2.compression`,
    /// `A1.travel`, `J1.torque`, `J3.yield`, ...).
    pub violations: Vec<String>,
}

/// Bending stiffness of the joints, N·m/rad.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct JointBend {
    /// J1 and J2 (about their local x, y).
    #[serde(rename = "J1_J2")]
    pub j1_j2: [f64; 2],
    /// J3 (about its local x, y).
    #[serde(rename = "J3")]
    pub j3: [f64; 2],
}

/// Names of every figure a space file may use as an objective or a constraint, and
/// whether larger is better.
pub const FIGURES: &[(&str, bool)] = &[
    ("range_min_m", true),
    ("range_m.x", true),
    ("range_m.y", true),
    ("stiffness_n_per_m.x", true),
    ("stiffness_n_per_m.y", true),
    ("first_mode_hz", true),
    ("min_safety_factor", true),
    ("safety_factors.J1", true),
    ("safety_factors.J2", true),
    ("safety_factors.J3", true),
    ("coupling_m", false),
    ("body_mass_kg", false),
    ("stack_margins.push_capacity_n", true),
    ("stack_margins.compression_n", true),
    ("stack_margins.travel_m", true),
    ("stack_margins.torque_nm", true),
];

impl Figures {
    /// A figure by its name in [`FIGURES`] (a margin pair gives its smaller element).
    pub fn get(&self, name: &str) -> Option<f64> {
        let m = &self.stack_margins;
        let min2 = |a: [f64; 2]| a[0].min(a[1]);
        Some(match name {
            "range_min_m" => self.range_min_m,
            "range_m.x" => self.range_m.x,
            "range_m.y" => self.range_m.y,
            "stiffness_n_per_m.x" => self.stiffness_n_per_m.x,
            "stiffness_n_per_m.y" => self.stiffness_n_per_m.y,
            "first_mode_hz" => self.first_mode_hz,
            "min_safety_factor" => self.min_safety_factor,
            "safety_factors.J1" => self.safety_factors.j1,
            "safety_factors.J2" => self.safety_factors.j2,
            "safety_factors.J3" => self.safety_factors.j3,
            "coupling_m" => self.coupling_m,
            "body_mass_kg" => self.body_mass_kg,
            "stack_margins.push_capacity_n" => min2(m.push_capacity_n),
            "stack_margins.compression_n" => min2(m.compression_n),
            "stack_margins.travel_m" => min2(m.travel_m),
            "stack_margins.torque_nm" => min2(m.torque_nm),
            _ => return None,
        })
    }
}

/// The notch of a double-notched joint with throat `throat` as a closed-form hinge.
pub fn notch(params: &StructureParams, throat: f64) -> Hinge {
    let j = &params.joint;
    Hinge {
        profile: Profile::CornerFilleted {
            radius: j.radius,
            length: j.flat + 2.0 * j.radius,
        },
        thickness: throat,
        width: j.side,
    }
}

fn material(p: &StructureParams) -> Material {
    Material {
        youngs: p.youngs,
        poisson: p.poisson,
        yield_strength: p.yield_strength,
    }
}

/// The joints' bending stiffness at `beam` fidelity: each notch in closed form.
pub fn beam_k_bend(params: &StructureParams) -> Result<JointBend, DesignError> {
    let m = material(params);
    let k = |throat: f64, key: &'static str| -> Result<f64, DesignError> {
        let h = notch(params, throat);
        h.validate().map_err(|e| DesignError::Input {
            key: key.into(),
            reason: e.to_string(),
        })?;
        Ok(h.k_bend(&m))
    };
    let k12 = k(params.throat_j12, "structure.throat_J12")?;
    let k3 = k(params.throat_j3, "structure.throat_J3")?;
    Ok(JointBend {
        j1_j2: [k12, k12],
        j3: [k3, k3],
    })
}

/// A double-notched joint in closed form, as the structure sees it: the two notches
/// (lower: bending about local y, upper: about local x) act through the joint's middle
/// (the pseudo-rigid-body reading), torsion, axial and shear springs are the two
/// notches' in series (Lobontiu's integrals: [`Hinge::k_torsion`], [`Hinge::k_axial`],
/// shear `G / (6/5 ∫ dx/(b h))`), and the top section sits half the joint's length
/// above the middle.
pub fn beam_joint(params: &StructureParams, throat: f64) -> JointModel {
    let m = material(params);
    let h = notch(params, throat);
    let j = &params.joint;
    let length = 2.0 * (j.flat + 2.0 * j.radius) + j.gap;
    let kb = h.k_bend(&m);
    let torsion = 0.5 * h.k_torsion(&m);
    let axial = 0.5 * h.k_axial(&m);
    let area_integral = h.compliance(&m)[(0, 0)] * m.youngs;
    let shear = 0.5 * m.shear() / (1.2 * area_integral);
    let arm = Vector3::new(0.0, 0.0, 0.5 * length);
    let kt = Matrix3::from_diagonal(&Vector3::new(shear, shear, axial));
    let kr = Matrix3::from_diagonal(&Vector3::new(kb, kb, torsion));
    // The top section moves by u and turns by θ; the springs at the middle see
    // u − θ × arm = u + skew(arm) θ.
    let sa = skew(&arm);
    let mut k = Matrix6::zeros();
    k.fixed_view_mut::<3, 3>(0, 0).copy_from(&kt);
    k.fixed_view_mut::<3, 3>(0, 3).copy_from(&(kt * sa));
    k.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(sa.transpose() * kt));
    k.fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&(kr + sa.transpose() * kt * sa));
    JointModel {
        stiffness: k,
        lower_end: -0.5 * length,
        lower_notch: 0.0,
        upper_notch: 0.0,
        upper_end: 0.5 * length,
    }
}

/// The design with `[flexures]` replaced by the joints' stiffness (J3[0] is q1, about
/// the joint's local y; J1/J2 axis 1 is local x).
fn with_joints(design: &Design, k: &JointBend) -> Design {
    let mut d = *design;
    d.flexures.j3 = [k.j3[1], k.j3[0]];
    d.flexures.j1 = k.j1_j2;
    d.flexures.j2 = k.j1_j2;
    d
}

/// The structure with the closed-form joints as ideal universal joints, and its
/// preload: approach 2's J3 deflection found from the model's `dq0`.
fn beam_structure_of(
    params: &StructureParams,
    design: &Design,
    approach: Approach,
    dq0: [f64; 2],
) -> Result<(Structure, Preload), DesignError> {
    let j12 = beam_joint(params, params.throat_j12);
    let spec = StructureSpec {
        j3: beam_joint(params, params.throat_j3),
        j12: [j12, j12],
        mass: params.masses(&design.geometry),
    };
    let structure = Structure::new(design, &spec).map_err(DesignError::Structure)?;
    let preload = match approach {
        Approach::DriveTranslation => Preload::Translation,
        Approach::JointDeflection => {
            // Closed-form joints leave the slider travel noisy at a few 1e-11 m:
            // straight to 1e-10 m, where `deflection_for` would spend its iterations
            // at 1e-11 first.
            let dq0 = structure
                .deflection_to(design.tension.preload, dq0, 1e-10)
                .map_err(DesignError::Structure)?;
            Preload::Deflection { dq0 }
        }
    };
    Ok((structure, preload))
}

/// The joints' safety factors against yield by the beam formulas: the largest stress of
/// each over the working range's corners `states`.
fn beam_factors(
    params: &StructureParams,
    states: &[cellinject_model::tension::State],
) -> JointFactors {
    let m = material(params);
    let h12 = notch(params, params.throat_j12);
    let h3 = notch(params, params.throat_j3);
    let mut worst = [0.0f64; 3];
    for s in states {
        worst[2] = worst[2].max(beam_stress(&h3, &m, [s.fq[0], s.fq[1]], 0.0));
        worst[0] = worst[0].max(beam_stress(&h12, &m, [s.fw[0], s.fw[1]], s.force[0]));
        worst[1] = worst[1].max(beam_stress(&h12, &m, [s.fw[2], s.fw[3]], s.force[1]));
    }
    let yield_strength = params.yield_strength;
    JointFactors {
        j1: yield_strength / worst[0],
        j2: yield_strength / worst[1],
        j3: yield_strength / worst[2],
    }
}

/// The cross-axis coupling: as one stack alone crosses its range (the corner `loads`),
/// the largest motion of the other axis.
fn coupling(
    structure: &Structure,
    loads: &[[f64; 2]],
    preload: Preload,
) -> Result<f64, DesignError> {
    let mut tips = Vec::with_capacity(4);
    for f in loads {
        let eq = structure
            .solve(*f, preload)
            .map_err(DesignError::Structure)?;
        tips.push(eq.tip);
    }
    Ok([
        (tips[1][1] - tips[0][1]).abs(),
        (tips[3][1] - tips[2][1]).abs(),
        (tips[2][0] - tips[0][0]).abs(),
        (tips[3][0] - tips[1][0]).abs(),
    ]
    .into_iter()
    .fold(0.0f64, f64::max))
}

/// The margins the design violates, by name (`A1.travel`, `J3.yield`, ...).
fn violations(m: &StackMargins, factors: &JointFactors) -> Vec<String> {
    let mut out = Vec::new();
    for (i, name) in ["A1", "A2"].iter().enumerate() {
        if m.push_capacity_n[i] < 0.0 {
            out.push(format!("{name}.push_capacity"));
        }
        if m.compression_n[i] <= 0.0 {
            out.push(format!("{name}.compression"));
        }
        if m.travel_m[i] < 0.0 {
            out.push(format!("{name}.travel"));
        }
    }
    for (i, name) in ["J1", "J2"].iter().enumerate() {
        if m.torque_nm[i] < 0.0 {
            out.push(format!("{name}.torque"));
        }
    }
    for (name, sf) in [("J1", factors.j1), ("J2", factors.j2), ("J3", factors.j3)] {
        if sf < 1.0 {
            out.push(format!("{name}.yield"));
        }
    }
    out
}

/// The stacks' states at the working range's corners: (0, 0), (s1, 0), (0, s2),
/// (s1, s2), each stack at rest or at its working shift.
fn corners(
    design: &Design,
    approach: Approach,
) -> Result<Vec<cellinject_model::tension::State>, DesignError> {
    let s = design.tension.work_shift;
    let mut out = Vec::with_capacity(4);
    for (a, b) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
        let mut d = *design;
        d.tension.work_shift = [a * s[0], b * s[1]];
        let t = Mechanism::new(&d)
            .and_then(|m| m.tension(approach))
            .map_err(DesignError::Model)?;
        out.push(if a == 0.0 && b == 0.0 {
            t.tensioned
        } else {
            t.work
        });
    }
    Ok(out)
}

/// N/m, the end-effector's stiffness along x and y from the pseudo-rigid-body model.
fn tip_stiffness(m: &Mechanism, d: &Design) -> Result<Axes, DesignError> {
    let jac = m.kinematics().jacobians().map_err(DesignError::Model)?;
    let f = &d.flexures;
    let kq = Matrix3::from_diagonal(&nalgebra::Vector3::new(f.j3[0], f.j3[1], 0.0));
    let kw = nalgebra::Matrix4::from_diagonal(&nalgebra::Vector4::new(
        f.j1[0], f.j1[1], f.j2[0], f.j2[1],
    ));
    let kl = d.drive_stiffness();
    let kl = Matrix3::from_diagonal(&nalgebra::Vector3::new(kl[0], kl[1], 0.0));
    let k = kq + jac.w.transpose() * kw * jac.w + jac.l.transpose() * kl * jac.l;
    let kt: Matrix2<f64> = k.fixed_view::<2, 2>(0, 0).into_owned();
    let jt: Matrix2<f64> = jac.j.fixed_view::<2, 2>(0, 0).into_owned();
    let c = kt
        .try_inverse()
        .map(|ki| jt * ki * jt.transpose())
        .ok_or(DesignError::Singular {
            what: "tilt stiffness",
        })?;
    Ok(Axes {
        x: 1.0 / c[(0, 0)],
        y: 1.0 / c[(1, 1)],
    })
}

/// Beam-formula stress of a double-notched joint: each notch bends about one axis by
/// its torque and carries the axial force.
fn beam_stress(h: &Hinge, m: &Material, torques: [f64; 2], axial: f64) -> f64 {
    let per_torque = h.stress_concentration() * 6.0 / (h.width * h.thickness.powi(2));
    let area = h.width * h.thickness;
    torques
        .iter()
        .map(|t| per_torque * t.abs() + axial.abs() / area)
        .fold(0.0f64, f64::max)
        .max(f64::MIN_POSITIVE * m.yield_strength)
}

/// Evaluates one description.
pub fn evaluate(
    desc: &Description,
    options: &EvalOptions,
    store: &dyn JointStore,
) -> Result<Figures, DesignError> {
    let approach = options.approach.unwrap_or(desc.rig.approach);
    let params = &desc.structure;
    let fea = match options.fidelity {
        Fidelity::Beam => None,
        Fidelity::Fea => Some(
            FeaModel::build(
                &desc.design,
                params,
                FeaOptions {
                    level: options.level,
                    ..FeaOptions::default()
                },
                store,
            )
            .map_err(DesignError::Fea)?,
        ),
    };
    let k = match &fea {
        None => beam_k_bend(params)?,
        Some(model) => {
            let kb = model.joint_k_bend();
            JointBend {
                j1_j2: kb.j1_j2,
                j3: kb.j3,
            }
        }
    };
    let design = with_joints(&desc.design, &k);
    let mech = Mechanism::new(&design).map_err(DesignError::Model)?;
    let t = mech.tension(approach).map_err(DesignError::Model)?;
    let corner_states = corners(&design, approach)?;
    let loads: Vec<[f64; 2]> = corner_states
        .iter()
        .map(|s| [s.force[0], s.force[1]])
        .collect();

    // The structure: FEM joints, or the closed-form joints as ideal universal joints.
    let beam_structure;
    let (structure, preload): (&Structure, Preload) = match &fea {
        Some(model) => (
            model.structure(),
            model.preload(approach).map_err(DesignError::Fea)?,
        ),
        None => {
            let dq0 = t.dq0.unwrap_or_default();
            let (built, preload) = beam_structure_of(params, &design, approach, [dq0[0], dq0[1]])?;
            beam_structure = built;
            (&beam_structure, preload)
        }
    };

    // Stresses at the corners.
    let factors = match &fea {
        Some(model) => {
            let mut worst = [f64::INFINITY; 3];
            for f in &loads {
                let case: SolvedCase = model.solve_case(approach, *f).map_err(DesignError::Fea)?;
                for (w, j) in worst.iter_mut().zip(&case.report.joints) {
                    if let Some(sf) = j.safety_factor {
                        *w = w.min(sf);
                    }
                }
            }
            // `stresses` lists J3, J1, J2.
            JointFactors {
                j3: worst[0],
                j1: worst[1],
                j2: worst[2],
            }
        }
        None => beam_factors(params, &corner_states),
    };

    let coupling = coupling(structure, &loads, preload)?;

    // Natural modes at the design preload.
    let modes = match &fea {
        Some(model) => model
            .modes(approach, 2)
            .map_err(DesignError::Fea)?
            .modes
            .iter()
            .map(|m| m.frequency)
            .collect::<Vec<_>>(),
        None => {
            let eq = structure
                .solve(design.tension.preload, preload)
                .map_err(DesignError::Structure)?;
            structure
                .modes(&eq)
                .map_err(DesignError::Structure)?
                .iter()
                .map(|m| m.frequency)
                .collect()
        }
    };
    let (f1, f2) = match modes.as_slice() {
        [a, b, ..] => (*a, *b),
        _ => {
            return Err(DesignError::Singular {
                what: "natural modes",
            });
        }
    };

    let g = &t.margins;
    let travel = [
        design.actuators[0].travel - design.tension.work_shift[0].abs(),
        design.actuators[1].travel - design.tension.work_shift[1].abs(),
    ];
    let stack_margins = StackMargins {
        push_capacity_n: g.capacity_margin,
        compression_n: g.compression_margin,
        travel_m: travel,
        torque_nm: g.torque_margin,
    };
    let violations = violations(&stack_margins, &factors);
    let range = Axes {
        x: t.chi[0],
        y: t.chi[1],
    };
    Ok(Figures {
        fidelity: options.fidelity,
        level: fea.as_ref().map(|_| options.level),
        approach: approach.number(),
        range_m: range,
        range_min_m: range.x.min(range.y),
        stiffness_n_per_m: tip_stiffness(&mech, &design)?,
        first_mode_hz: f1,
        modes_hz: [f1, f2],
        min_safety_factor: factors.min(),
        safety_factors: factors,
        stack_margins,
        coupling_m: coupling,
        joint_k_bend: k,
        body_mass_kg: params.masses(&design.geometry).body_mass,
        load_cases_n: loads,
        feasible: violations.is_empty(),
        violations,
    })
}
