//! # cellinject-structure
//!
//! The whole manipulator as rigid bodies joined by elastic elements (matrix structural
//! analysis in the manner of Klimchik and Pashkevich; the compliance-matrix method of
//! Koseki and of Pham and Chen is its serial/parallel special case), solved with large
//! displacements: the paper's pre-tension moves the end-effector by 1.5 mm and tilts
//! body 1 by 8 mrad, which is what makes the two approaches differ in their cross-axis
//! coupling (Sec. 3.3).
//!
//! **Bodies and elements.**
//! * Body 1 (with A3 and the pipette) hangs on the double-notched joint J3 from the
//!   base; J3 is a 6x6 compliance between the base and body 1 (from the 3-D FEM or from
//!   beam formulas: the crate takes it as input).
//! * Each drive chain i = 1, 2: a slider (the FEA's "linear joint" at the end of the
//!   motor loop, loaded by the force F1i along the drive axis), the double-notched joint
//!   J_i (6x6 compliance) between the slider and the stack, the stack as a rigid body
//!   with an axial spring (27 N/µm), and a spherical joint on body 1 (transmits force,
//!   no moment).
//! * The notch of J3 compliant about y (A1's axis) lies below the one compliant about
//!   x; A1 meets body 1 at `b1` above the first, A2 at `b1` above the second, and the
//!   end-effector lies at `b2` above the joint's middle. J_i's middle lies at
//!   `a_i1 + a_i2` behind the spherical joint, as in the pseudo-rigid-body model.
//!
//! **Equations.** The total potential `Π(q) = Σ ½ δ_eᵀ K_e δ_e + ½ Σ k_a e_i² + Σ F1i s_i`
//! over 16 coordinates q (body 1: 3 translations, 3 rotations; each chain: the stack's
//! 3 rotations, its compression e_i and the slider travel s_i) is minimised by Newton's
//! method. Each joint's deformation δ_e is the relative pose of its end sections in the
//! joint's frame (translation, rotation vector), so rigid rotations of any size cost
//! nothing (a corotational formulation); the spherical joints are exact constraints.
//! Approach 2's pre-deflection of J3 is the joint's rest pose rotated by −Δq0 about
//! its two notches (eq. 28). Natural modes come from the Hessian of Π at the
//! equilibrium (pre-stress included) and the bodies' mass matrices, with the sliders
//! locked as in the assembled manipulator.
//!
//! **Architecture invariant:** pure computation: no IO, no time, no devices; joint
//! compliances come in as numbers, so this crate does not depend on the FEM.

use cellinject_model::{Design, Geometry};
use cellinject_numeric::{Newton2Error, Newton2Options, newton2};
use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, Rotation3, SMatrix, SVector, Vector3, Vector6};
use thiserror::Error;

mod params;
pub use params::*;

/// Number of generalised coordinates.
pub const DOFS: usize = 16;
/// Scale of the coordinates: micrometres and microradians.
const SCALE: f64 = 1e-6;
/// Elastic measures: three joints (6 each) and two stack springs.
const NSTRAIN: usize = 20;
/// Newton iterations allowed.
const MAX_ITER: usize = 30;
/// Newton iterations allowed for approach 2's pre-deflection: each evaluation is an
/// equilibrium solved to [`TOLERANCE`], whose rounding makes the last digits of the
/// slider travel noisy.
const DEFLECTION_MAX_ITER: usize = 60;
/// Largest gradient component, relative to the load, accepted at equilibrium.
const TOLERANCE: f64 = 1e-7;

type Strains = SVector<f64, NSTRAIN>;

type Vec16 = SVector<f64, DOFS>;
type Mat16 = SMatrix<f64, DOFS, DOFS>;

/// What the structural model can fail at.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum StructureError {
    /// A parameter is unusable.
    #[error("{key}: {reason}")]
    Invalid {
        /// The description-file key.
        key: String,
        /// What is wrong.
        reason: String,
    },
    /// Newton's method did not reach equilibrium.
    #[error("equilibrium not reached after {iterations} iterations (gradient {residual:.3e})")]
    NotConverged {
        /// Iterations made.
        iterations: usize,
        /// Largest scaled gradient component left.
        residual: f64,
    },
    /// The tangent stiffness is singular or not positive definite (a mechanism).
    #[error("the tangent stiffness is not positive definite (smallest pivot {pivot:.3e})")]
    Unstable {
        /// Smallest eigenvalue found.
        pivot: f64,
    },
}

/// One drive chain's fixed geometry.
#[derive(Debug, Clone, Copy)]
struct Chain {
    /// Drive direction (towards body 1).
    d: Vector3<f64>,
    /// Joint frame of J_i: columns (local x, local y, d).
    frame: Matrix3<f64>,
    /// Spherical joint on body 1, relative to body 1's reference point.
    attach_local: Vector3<f64>,
    /// Rest position of the bottom end section's centre (on the slider).
    bottom: Vector3<f64>,
    /// Length between J_i's end sections.
    joint_length: f64,
    /// Stack length from J_i's top end section to the spherical joint.
    stack_length: f64,
    /// Axial stiffness of the stack, N/m.
    k_axial: f64,
    /// J_i's stiffness in its frame.
    k: Matrix6<f64>,
}

/// The assembled structural model of one design.
#[derive(Debug, Clone)]
pub struct Structure {
    spec: StructureSpec,
    /// Body 1's reference point at rest: J3's top end section centre (global).
    ref_point: Vector3<f64>,
    /// End-effector relative to the reference point.
    tip_local: Vector3<f64>,
    /// Body 1's centre of mass relative to the reference point.
    com_local: Vector3<f64>,
    /// J3's stiffness.
    k3: Matrix6<f64>,
    /// J3's compliance (for its assembly deflection).
    c3: Matrix6<f64>,
    chains: [Chain; 2],
}

/// Which pre-tensioning the structure is assembled with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Preload {
    /// Approach 1: J3 straight; the tension comes from the slider forces alone.
    Translation,
    /// Approach 2: J3 assembled pre-deflected by Δq0 (rad, about y then x; eq. 31).
    Deflection {
        /// Δq0 of the pseudo-rigid-body model.
        dq0: [f64; 2],
    },
    /// Approach 2 as the paper's CAD FEA sets it up (Sec. 3.3.2): J3 straight, and
    /// constant torques (eq. 53) on body 1 near J3 instead of the pre-deflection.
    Torque {
        /// N·m, about y (q1) and about x (q2), as Fq of eq. (53).
        moment: [f64; 2],
    },
}

/// The constant loads of one solve.
#[derive(Debug, Clone, Copy)]
struct Loads {
    forces: [f64; 2],
    /// N·m, constant moment on body 1 (global frame).
    torque: Vector3<f64>,
}

impl Loads {
    fn new(forces: [f64; 2], preload: Preload) -> Self {
        let torque = match preload {
            Preload::Torque { moment } => Vector3::new(moment[1], moment[0], 0.0),
            _ => Vector3::zeros(),
        };
        Loads { forces, torque }
    }
}

/// A static equilibrium.
#[derive(Debug, Clone, PartialEq)]
pub struct Equilibrium {
    /// m, end-effector displacement from its home position.
    pub tip: Vector3<f64>,
    /// rad, rotation vector of body 1 from home.
    pub body_rotation: Vector3<f64>,
    /// Deformation (m, rad) of J3, J1, J2 between their end sections, joint frames.
    pub joint_deformation: [Vector6<f64>; 3],
    /// Wrench (N, N·m) each joint carries at its top end section, joint frames.
    pub joint_wrench: [Vector6<f64>; 3],
    /// N, axial force of A1, A2 (negative: compression).
    pub stack_force: [f64; 2],
    /// N, the applied slider forces.
    pub applied: [f64; 2],
    /// m, slider travel (positive towards body 1).
    pub slider: [f64; 2],
    /// Newton iterations.
    pub iterations: usize,
    /// Largest gradient component at the solution relative to the load scale.
    pub residual: f64,
    /// Coordinates (µm, µrad), for modes.
    coords: Vec16,
    preload: Preload,
}

/// One natural mode.
#[derive(Debug, Clone, PartialEq)]
pub struct Mode {
    /// Hz.
    pub frequency: f64,
    /// End-effector motion (m) of the mode scaled so that its largest coordinate (a
    /// translation or a rotation of body 1 or a stack) is 1 µm or 1 µrad.
    pub tip_shape: Vector3<f64>,
    /// What moves most: "body 1 tilt about x", "A1 axial", ...
    pub description: String,
}

/// The cross-product matrix: `skew(a) b = a × b`.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    v.cross_matrix()
}

fn exp_rot(v: &Vector3<f64>) -> Matrix3<f64> {
    Rotation3::new(*v).into_inner()
}

/// Rotation vector of a rotation matrix, accurate for tiny angles (the axis from the
/// antisymmetric part, the angle from atan2, never from acos near 1).
fn log_rot(r: &Matrix3<f64>) -> Vector3<f64> {
    let v = 0.5
        * Vector3::new(
            r[(2, 1)] - r[(1, 2)],
            r[(0, 2)] - r[(2, 0)],
            r[(1, 0)] - r[(0, 1)],
        );
    let s = v.norm();
    let c = 0.5 * (r.trace() - 1.0);
    if s == 0.0 {
        return Vector3::zeros();
    }
    v * (s.atan2(c) / s)
}

impl Structure {
    /// Assembles the model of a design with the given joints and masses.
    pub fn new(design: &Design, spec: &StructureSpec) -> Result<Self, StructureError> {
        let bad = |key: &str, reason: String| StructureError::Invalid {
            key: key.into(),
            reason,
        };
        let k3 = spec.j3.stiffness;
        let spd = |k: &Matrix6<f64>| k.cholesky().is_some();
        if !spd(&k3) {
            return Err(bad(
                "structure.J3",
                "stiffness is not positive definite".into(),
            ));
        }
        let g = &design.geometry;
        let m3 = spec.j3.middle();
        // Global z of J3's sections (its middle at the origin).
        let z_top = spec.j3.upper_end - m3;
        let za = spec.j3.lower_notch - m3;
        let zb = spec.j3.upper_notch - m3;
        let ref_point = Vector3::new(0.0, 0.0, z_top);
        let heights = [za + g.b1, zb + g.b1];
        let kl = design.drive_stiffness();
        let mut chains = Vec::with_capacity(2);
        for i in 0..2 {
            let j = &spec.j12[i];
            let k = j.stiffness;
            if !spd(&k) {
                return Err(bad(
                    &format!("structure.J{}", i + 1),
                    "stiffness is not positive definite".into(),
                ));
            }
            let phi = g.actuator_azimuth[i];
            // The stack pushes along d, from the side that makes a compressive force
            // move M towards −x (A1) and −y (A2), as the paper's Tables 1-2 report;
            // this mirrors the pseudo-rigid-body figure, whose relations it leaves
            // unchanged.
            let d = -Vector3::new(phi.cos(), phi.sin(), 0.0);
            let ey = Vector3::z().cross(&d);
            let ex = ey.cross(&d);
            let frame = Matrix3::from_columns(&[ex, ey, d]);
            let attach = Vector3::new(0.0, 0.0, heights[i]);
            let reach = g.reach(i);
            let middle = attach - reach * d;
            let m = j.middle();
            let top = middle + (j.upper_end - m) * d;
            let bottom = middle - (m - j.lower_end) * d;
            let stack_length = (attach - top).norm();
            if stack_length.is_nan() || stack_length <= 0.0 || (attach - top).dot(&d) <= 0.0 {
                return Err(bad(
                    &format!("geometry.a{}1", i + 1),
                    format!(
                        "joint J{} ({:.1} mm between its middle and top section) does not fit in the reach {:.1} mm",
                        i + 1,
                        (j.upper_end - m) * 1e3,
                        reach * 1e3
                    ),
                ));
            }
            if !(kl[i].is_finite() && kl[i] > 0.0) {
                return Err(bad(
                    &format!("actuators.A{}.stiffness", i + 1),
                    "the structural model needs the stack's axial stiffness".into(),
                ));
            }
            chains.push(Chain {
                d,
                frame,
                attach_local: attach - ref_point,
                bottom,
                joint_length: j.upper_end - j.lower_end,
                stack_length,
                k_axial: kl[i],
                k,
            });
        }
        let m = &spec.mass;
        for (key, v) in [
            ("body 1's mass", m.body_mass),
            ("A1's mass", m.stack_mass[0]),
            ("A2's mass", m.stack_mass[1]),
            ("body 1's inertia", m.body_inertia[0]),
            ("body 1's inertia", m.body_inertia[1]),
            ("body 1's inertia", m.body_inertia[2]),
        ] {
            if !(v.is_finite() && v > 0.0) {
                let from = if key.starts_with("body") {
                    "structure.body_side, body_density, tool_mass and geometry.b2"
                } else {
                    "structure.stack_side, stack_density and geometry.a12/a22"
                };
                return Err(bad(
                    from,
                    format!("{key} must be positive and finite, got {v}"),
                ));
            }
        }
        Ok(Structure {
            spec: *spec,
            ref_point,
            tip_local: Vector3::new(0.0, 0.0, g.b2) - ref_point,
            com_local: Vector3::new(0.0, 0.0, m.body_com) - ref_point,
            k3,
            c3: k3
                .cholesky()
                .map(|ch| ch.inverse())
                .unwrap_or_else(Matrix6::zeros),
            chains: [chains[0], chains[1]],
        })
    }

    /// The inputs.
    pub fn spec(&self) -> &StructureSpec {
        &self.spec
    }

    /// J3's rest pose of its top section for a preload.
    fn j3_rest(&self, preload: Preload) -> (Vector3<f64>, Matrix3<f64>) {
        match preload {
            Preload::Translation | Preload::Torque { .. } => (self.ref_point, Matrix3::identity()),
            Preload::Deflection { dq0 } => {
                // Rest angles q_r = −Δq0 (eq. 28): the joint as an assembly moment
                // bends it, so its rest pose is C·w for the pure moment w that turns the
                // top section by q_r (about y for q1, about x for q2) — the translation
                // that comes with the rotation is the joint's own.
                let c = self.c3;
                let crr = nalgebra::Matrix2::new(c[(3, 3)], c[(3, 4)], c[(4, 3)], c[(4, 4)]);
                let target = nalgebra::Vector2::new(-dq0[1], -dq0[0]);
                let m = crr
                    .lu()
                    .solve(&target)
                    .unwrap_or_else(nalgebra::Vector2::zeros);
                let w = Vector6::new(0.0, 0.0, 0.0, m[0], m[1], 0.0);
                let d = c * w;
                let p = self.ref_point + Vector3::new(d[0], d[1], d[2]);
                let r = exp_rot(&Vector3::new(0.0, -dq0[0], 0.0))
                    * exp_rot(&Vector3::new(-dq0[1], 0.0, 0.0));
                (p, r)
            }
        }
    }

    /// Body 1's pose and each chain's state for coordinates q.
    fn kinematics(&self, q: &Vec16) -> Kin {
        let x1 = self.ref_point + SCALE * Vector3::new(q[0], q[1], q[2]);
        let r1 = exp_rot(&(SCALE * Vector3::new(q[3], q[4], q[5])));
        let mut chains = [ChainKin::default(); 2];
        for (i, c) in self.chains.iter().enumerate() {
            let o = 6 + 5 * i;
            let rp = exp_rot(&(SCALE * Vector3::new(q[o], q[o + 1], q[o + 2]))) * c.frame;
            let e = SCALE * q[o + 3];
            let s = SCALE * q[o + 4];
            let attach = x1 + r1 * c.attach_local;
            let axis = rp.column(2).into_owned();
            let top = attach - (c.stack_length - e) * axis;
            let bottom = c.bottom + s * c.d;
            let dx = c.frame.transpose() * (top - bottom) - Vector3::new(0.0, 0.0, c.joint_length);
            let dth = log_rot(&(c.frame.transpose() * rp));
            chains[i] = ChainKin {
                deformation: Vector6::new(dx[0], dx[1], dx[2], dth[0], dth[1], dth[2]),
                e,
                s,
                attach,
                top,
                rp,
            };
        }
        Kin { x1, r1, chains }
    }

    fn j3_deformation(&self, k: &Kin, rest: &(Vector3<f64>, Matrix3<f64>)) -> Vector6<f64> {
        let dx = rest.1.transpose() * (k.x1 - rest.0);
        let dth = log_rot(&(rest.1.transpose() * k.r1));
        Vector6::new(dx[0], dx[1], dx[2], dth[0], dth[1], dth[2])
    }

    /// The elastic measures at q: J3's, J1's and J2's deformations (18), the stacks'
    /// compressions (2).
    fn strains(&self, q: &Vec16, rest: &(Vector3<f64>, Matrix3<f64>)) -> Strains {
        let k = self.kinematics(q);
        let d3 = self.j3_deformation(&k, rest);
        let mut e = Strains::zeros();
        e.fixed_rows_mut::<6>(0).copy_from(&d3);
        e.fixed_rows_mut::<6>(6).copy_from(&k.chains[0].deformation);
        e.fixed_rows_mut::<6>(12)
            .copy_from(&k.chains[1].deformation);
        e[18] = k.chains[0].e;
        e[19] = k.chains[1].e;
        e
    }

    /// Block-diagonal stiffness of the elastic measures.
    fn strain_stiffness(&self) -> SMatrix<f64, NSTRAIN, NSTRAIN> {
        let mut k = SMatrix::<f64, NSTRAIN, NSTRAIN>::zeros();
        k.fixed_view_mut::<6, 6>(0, 0).copy_from(&self.k3);
        k.fixed_view_mut::<6, 6>(6, 6).copy_from(&self.chains[0].k);
        k.fixed_view_mut::<6, 6>(12, 12)
            .copy_from(&self.chains[1].k);
        k[(18, 18)] = self.chains[0].k_axial;
        k[(19, 19)] = self.chains[1].k_axial;
        k
    }

    /// Jacobian of the elastic measures by central differences (the measures are smooth
    /// functions of the coordinates, of order 1e-3; the step is 1 nm / 1 nrad).
    fn strain_jacobian(
        &self,
        q: &Vec16,
        rest: &(Vector3<f64>, Matrix3<f64>),
    ) -> SMatrix<f64, NSTRAIN, DOFS> {
        let h = 1e-3;
        let mut j = SMatrix::<f64, NSTRAIN, DOFS>::zeros();
        for c in 0..DOFS {
            let mut qp = *q;
            let mut qm = *q;
            qp[c] += h;
            qm[c] -= h;
            j.set_column(
                c,
                &((self.strains(&qp, rest) - self.strains(&qm, rest)) / (2.0 * h)),
            );
        }
        j
    }

    /// Total potential: elastic energy plus the slider loads' potential, J.
    fn potential(&self, q: &Vec16, rest: &(Vector3<f64>, Matrix3<f64>), loads: &Loads) -> f64 {
        let e = self.strains(q, rest);
        0.5 * e.dot(&(self.strain_stiffness() * e)) + Self::load_gradient(loads).dot(q)
    }

    /// Load term of the gradient: d(F·s − τ·θ)/dq (the slider forces' and the constant
    /// moment's potential, linear in the coordinates).
    fn load_gradient(loads: &Loads) -> Vec16 {
        let mut g = Vec16::zeros();
        g[10] = SCALE * loads.forces[0];
        g[15] = SCALE * loads.forces[1];
        for i in 0..3 {
            g[3 + i] = -SCALE * loads.torque[i];
        }
        g
    }

    /// Gradient of the potential, `Jᵀ K ε + F`, and the tangent stiffness
    /// `Jᵀ K J + Σ (Kε)_k ∇²ε_k` (the second term, the pre-stress, by differences of
    /// `Jᵀ w` with the measures' forces `w = Kε` held fixed).
    fn gradient_and_tangent(
        &self,
        q: &Vec16,
        rest: &(Vector3<f64>, Matrix3<f64>),
        loads: &Loads,
    ) -> (Vec16, Mat16) {
        let ks = self.strain_stiffness();
        let eps = self.strains(q, rest);
        let w = ks * eps;
        let j = self.strain_jacobian(q, rest);
        let g = j.transpose() * w + Self::load_gradient(loads);
        let mut t = j.transpose() * ks * j;
        let h = 1.0;
        for c in 0..DOFS {
            let mut qp = *q;
            let mut qm = *q;
            qp[c] += h;
            qm[c] -= h;
            let gp = self.strain_jacobian(&qp, rest).transpose() * w;
            let gm = self.strain_jacobian(&qm, rest).transpose() * w;
            let col = (gp - gm) / (2.0 * h);
            for r in 0..DOFS {
                t[(r, c)] += col[r];
            }
        }
        (g, 0.5 * (t + t.transpose()))
    }

    /// Static equilibrium under slider forces `forces` (N, negative = compressive, as
    /// F11 and F12 of the paper's Tables 1 and 2) with the given preload.
    pub fn solve(&self, forces: [f64; 2], preload: Preload) -> Result<Equilibrium, StructureError> {
        for (i, f) in forces.iter().enumerate() {
            if !f.is_finite() {
                return Err(StructureError::Invalid {
                    key: format!("F1{}", i + 1),
                    reason: format!("force must be finite, got {f}"),
                });
            }
        }
        let rest = self.j3_rest(preload);
        let loads = Loads::new(forces, preload);
        let mut q = Vec16::zeros();
        // Load scale for the convergence test: the applied forces (and J3's preload).
        let scale = SCALE * (forces[0].abs() + forces[1].abs() + 1.0);
        let mut last = f64::INFINITY;
        for it in 0..MAX_ITER {
            let (g, t) = self.gradient_and_tangent(&q, &rest, &loads);
            let res = g.amax() / scale;
            last = res;
            if res < TOLERANCE {
                return Ok(self.equilibrium(&q, preload, forces, it, res));
            }
            // Newton step; where the tangent is indefinite away from the solution (the
            // linear first step violates stiff directions at second order), shift it.
            let step = match t.cholesky() {
                Some(chol) => chol.solve(&(-g)),
                None => {
                    let low = t.symmetric_eigenvalues().min();
                    let shift = 2.0 * low.abs() + 1e-12 * t.diagonal().amax();
                    let shifted = t + Mat16::identity() * shift;
                    let Some(chol) = shifted.cholesky() else {
                        return Err(StructureError::Unstable { pivot: low });
                    };
                    chol.solve(&(-g))
                }
            };
            // Backtracking on the potential energy.
            let p0 = self.potential(&q, &rest, &loads);
            let mut a = 1.0;
            while a > 1e-6 && self.potential(&(q + a * step), &rest, &loads) > p0 {
                a *= 0.5;
            }
            q += a * step;
            // At the rounding floor of the gradient the step vanishes first: 1e-5 µm
            // (10 pm) or 10 prad is converged.
            if (a * step).amax() < 1e-5 && res < 1e-4 {
                let (g, _) = self.gradient_and_tangent(&q, &rest, &loads);
                let res = g.amax() / scale;
                return Ok(self.equilibrium(&q, preload, forces, it + 1, res));
            }
        }
        Err(StructureError::NotConverged {
            iterations: MAX_ITER,
            residual: last,
        })
    }

    /// Approach 2's design rule applied to this model: the pre-deflection Δq0 of J3
    /// for which the stacks carry `preload` (N) with the drives at their home length
    /// (sliders at zero travel), found by Newton's method from `start` (the
    /// pseudo-rigid-body model's Δq0, eq. 31).
    pub fn deflection_for(
        &self,
        preload: [f64; 2],
        start: [f64; 2],
    ) -> Result<[f64; 2], StructureError> {
        // To 1e-11 m of slider travel; where the equilibria's own rounding keeps the
        // travel noisy above that (some joint geometries of a design study), to
        // 1e-10 m: 3 mN on a 27 N/µm stack, 3e-5 of the paper's 100 N.
        match self.deflection_to(preload, start, 1e-11) {
            Err(StructureError::NotConverged { .. }) => self.deflection_to(preload, start, 1e-10),
            other => other,
        }
    }

    /// [`Structure::deflection_for`] to a slider travel of `tolerance` (m).
    pub fn deflection_to(
        &self,
        preload: [f64; 2],
        start: [f64; 2],
        tolerance: f64,
    ) -> Result<[f64; 2], StructureError> {
        let travel = |dq0: [f64; 2]| -> Result<[f64; 2], StructureError> {
            Ok(self.solve(preload, Preload::Deflection { dq0 })?.slider)
        };
        let options = Newton2Options {
            fd_step: 1e-6,
            tolerance,
            max_iterations: DEFLECTION_MAX_ITER,
            max_step: f64::INFINITY,
        };
        newton2(travel, start, &options, |_, _, _| {})
            .map(|r| r.x)
            .map_err(|e| match e {
                Newton2Error::Eval(e) => e,
                Newton2Error::Singular { .. } => StructureError::Unstable { pivot: 0.0 },
                Newton2Error::NotConverged {
                    iterations,
                    residual,
                } => StructureError::NotConverged {
                    iterations,
                    residual: residual / SCALE,
                },
            })
    }

    fn equilibrium(
        &self,
        q: &Vec16,
        preload: Preload,
        forces: [f64; 2],
        iterations: usize,
        residual: f64,
    ) -> Equilibrium {
        let rest = self.j3_rest(preload);
        let k = self.kinematics(q);
        let tip0 = self.ref_point + self.tip_local;
        let tip = k.x1 + k.r1 * self.tip_local - tip0;
        let d3 = self.j3_deformation(&k, &rest);
        let d1 = k.chains[0].deformation;
        let d2 = k.chains[1].deformation;
        Equilibrium {
            tip,
            body_rotation: log_rot(&k.r1),
            joint_deformation: [d3, d1, d2],
            joint_wrench: [self.k3 * d3, self.chains[0].k * d1, self.chains[1].k * d2],
            stack_force: [
                -self.chains[0].k_axial * k.chains[0].e,
                -self.chains[1].k_axial * k.chains[1].e,
            ],
            applied: forces,
            slider: [k.chains[0].s, k.chains[1].s],
            iterations,
            residual,
            coords: *q,
            preload,
        }
    }

    /// Mass matrix (in the coordinates) at q: body 1 and both stacks.
    fn mass_matrix(&self, q: &Vec16) -> Mat16 {
        let m = &self.spec.mass;
        let h = 1e-2;
        // Velocity Jacobians of each body's centre of mass and rotation by differences.
        let bodies = |q: &Vec16| -> [(Vector3<f64>, Matrix3<f64>); 3] {
            let k = self.kinematics(q);
            [
                (k.x1 + k.r1 * self.com_local, k.r1),
                (0.5 * (k.chains[0].attach + k.chains[0].top), k.chains[0].rp),
                (0.5 * (k.chains[1].attach + k.chains[1].top), k.chains[1].rp),
            ]
        };
        let base = bodies(q);
        let mut jv = [SMatrix::<f64, 3, DOFS>::zeros(); 3];
        let mut jw = [SMatrix::<f64, 3, DOFS>::zeros(); 3];
        for j in 0..DOFS {
            let mut qp = *q;
            let mut qm = *q;
            qp[j] += h;
            qm[j] -= h;
            let (bp, bm) = (bodies(&qp), bodies(&qm));
            for b in 0..3 {
                jv[b].set_column(j, &((bp[b].0 - bm[b].0) / (2.0 * h)));
                let w = log_rot(&(bp[b].1 * bm[b].1.transpose())) / (2.0 * h);
                jw[b].set_column(j, &w);
            }
        }
        let mut mm = Mat16::zeros();
        // Body 1: principal inertia in its own frame.
        let ib = base[0].1
            * Matrix3::from_diagonal(&Vector3::from(m.body_inertia))
            * base[0].1.transpose();
        mm += m.body_mass * jv[0].transpose() * jv[0] + jw[0].transpose() * ib * jw[0];
        for (b, c) in self.chains.iter().enumerate() {
            let l = c.stack_length;
            let it = m.stack_mass[b] * l * l / 12.0;
            let axis = base[b + 1].1.column(2).into_owned();
            // Uniform rod: no inertia about its own axis beyond a thin-rod estimate.
            let ir = it * (Matrix3::identity() - axis * axis.transpose())
                + 1e-3 * it * axis * axis.transpose();
            mm += m.stack_mass[b] * jv[b + 1].transpose() * jv[b + 1]
                + jw[b + 1].transpose() * ir * jw[b + 1];
        }
        0.5 * (mm + mm.transpose())
    }

    /// Natural modes about an equilibrium, sliders locked (the assembled manipulator),
    /// lowest first.
    pub fn modes(&self, eq: &Equilibrium) -> Result<Vec<Mode>, StructureError> {
        let rest = self.j3_rest(eq.preload);
        let (_, h) =
            self.gradient_and_tangent(&eq.coords, &rest, &Loads::new(eq.applied, eq.preload));
        let m = self.mass_matrix(&eq.coords);
        // Remove the slider coordinates (10 and 15).
        let keep: Vec<usize> = (0..DOFS).filter(|&i| i != 10 && i != 15).collect();
        let n = keep.len();
        let kk = DMatrix::from_fn(n, n, |r, c| h[(keep[r], keep[c])]);
        let mk = DMatrix::from_fn(n, n, |r, c| m[(keep[r], keep[c])]);
        let chol = mk
            .clone()
            .cholesky()
            .ok_or(StructureError::Unstable { pivot: 0.0 })?;
        let l_inv = chol
            .l()
            .try_inverse()
            .ok_or(StructureError::Unstable { pivot: 0.0 })?;
        let a = &l_inv * &kk * l_inv.transpose();
        let a = 0.5 * (&a + a.transpose());
        let eig = a.symmetric_eigen();
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
        let names = [
            "body 1 along x",
            "body 1 along y",
            "body 1 along z",
            "body 1 tilt about x",
            "body 1 tilt about y",
            "body 1 twist about z",
            "A1 swing (1)",
            "A1 swing (2)",
            "A1 twist",
            "A1 axial",
            "A2 swing (1)",
            "A2 swing (2)",
            "A2 twist",
            "A2 axial",
        ];
        let mut modes = Vec::with_capacity(n);
        for &i in &order {
            let lam = eig.eigenvalues[i];
            if lam <= 0.0 {
                return Err(StructureError::Unstable { pivot: lam });
            }
            // Back to coordinates: φ = L⁻ᵀ y.
            let y = eig.eigenvectors.column(i).into_owned();
            let phi: DVector<f64> = l_inv.transpose() * y;
            let mut full = Vec16::zeros();
            for (r, &kidx) in keep.iter().enumerate() {
                full[kidx] = phi[r];
            }
            // Tip motion by differences of the kinematics.
            let eps = 1e-3 / full.amax().max(1e-30);
            let kp = self.kinematics(&(eq.coords + eps * full));
            let km = self.kinematics(&(eq.coords - eps * full));
            let tp = kp.x1 + kp.r1 * self.tip_local;
            let tm = km.x1 + km.r1 * self.tip_local;
            // Scaled so that the mode's largest coordinate is 1 µm or 1 µrad.
            let tip = (tp - tm) / (2.0 * eps) / full.amax();
            // Dominant coordinate by modal kinetic energy share.
            let mut share = vec![0.0f64; n];
            for r in 0..n {
                share[r] = (phi[r] * (&mk * &phi)[r]).abs();
            }
            let dom = (0..n)
                .max_by(|&a, &b| share[a].total_cmp(&share[b]))
                .unwrap_or(0);
            modes.push(Mode {
                frequency: lam.sqrt() / (2.0 * std::f64::consts::PI),
                tip_shape: tip,
                description: names[dom].to_string(),
            });
        }
        Ok(modes)
    }
}

/// A member of the structure's line drawing: its points at rest and displaced.
#[derive(Debug, Clone, PartialEq)]
pub struct Member {
    /// "J3", "body 1", "J1", "A1", ...
    pub name: &'static str,
    /// Points at rest (m, global frame).
    pub rest: Vec<Vector3<f64>>,
    /// The same points at the equilibrium.
    pub displaced: Vec<Vector3<f64>>,
}

impl Structure {
    /// The structure as line members (for plots like the paper's Fig. 4), each sampled
    /// at `n` points along its length.
    pub fn skeleton(&self, eq: &Equilibrium, n: usize) -> Vec<Member> {
        let n = n.max(2);
        let k = self.kinematics(&eq.coords);
        let lerp = |a: Vector3<f64>, b: Vector3<f64>, t: f64| a + (b - a) * t;
        let ts: Vec<f64> = (0..n).map(|i| i as f64 / (n - 1) as f64).collect();
        let mut out = Vec::new();
        // J3: from its bottom section (fixed) to body 1's reference point, interpolated.
        let bottom = Vector3::new(0.0, 0.0, self.spec.j3.lower_end - self.spec.j3.middle());
        out.push(Member {
            name: "J3",
            rest: ts
                .iter()
                .map(|&t| lerp(bottom, self.ref_point, t))
                .collect(),
            displaced: ts.iter().map(|&t| lerp(bottom, k.x1, t)).collect(),
        });
        // Body 1: rigid, from the reference point to the end-effector.
        let tip = self.ref_point + self.tip_local;
        let rest: Vec<_> = ts.iter().map(|&t| lerp(self.ref_point, tip, t)).collect();
        let displaced = rest
            .iter()
            .map(|p| k.x1 + k.r1 * (p - self.ref_point))
            .collect();
        out.push(Member {
            name: "body 1",
            rest,
            displaced,
        });
        for (i, (c, ck)) in self.chains.iter().zip(&k.chains).enumerate() {
            let attach0 = self.ref_point + c.attach_local;
            let top0 = c.bottom + c.joint_length * c.d;
            out.push(Member {
                name: ["J1", "J2"][i],
                rest: ts.iter().map(|&t| lerp(c.bottom, top0, t)).collect(),
                displaced: ts
                    .iter()
                    .map(|&t| lerp(c.bottom + ck.s * c.d, ck.top, t))
                    .collect(),
            });
            out.push(Member {
                name: ["A1", "A2"][i],
                rest: ts.iter().map(|&t| lerp(top0, attach0, t)).collect(),
                displaced: ts.iter().map(|&t| lerp(ck.top, ck.attach, t)).collect(),
            });
        }
        out
    }
}

#[derive(Debug, Clone, Copy, Default)]
struct ChainKin {
    deformation: Vector6<f64>,
    e: f64,
    s: f64,
    attach: Vector3<f64>,
    top: Vector3<f64>,
    rp: Matrix3<f64>,
}

struct Kin {
    x1: Vector3<f64>,
    r1: Matrix3<f64>,
    chains: [ChainKin; 2],
}

/// A joint that bends only about its two axes, both through its middle, and is nearly
/// rigid otherwise: the pseudo-rigid-body model's universal joint, for checks.
/// `k_bend` = [about local x, about local y].
///
/// The top section (at `arm` above the middle) moves by `u` and turns by `θ`; the
/// joint stores `½ θᵀ K_r θ + ½ k_t |u − θ × arm|²` with `K_r = diag(kx, ky, k_z)`,
/// `k_z` and `k_t` ten thousand times stiffer than the bending.
pub fn ideal_joint(k_bend: [f64; 2], length: f64) -> JointModel {
    let arm = Vector3::new(0.0, 0.0, 0.5 * length);
    let stiff = 1e4 * k_bend[0].max(k_bend[1]);
    let kt = stiff / (length * length);
    let kr = Matrix3::from_diagonal(&Vector3::new(k_bend[0], k_bend[1], stiff));
    // u − θ × arm = u + skew(arm) θ.
    let sa = skew(&arm);
    let mut k = Matrix6::zeros();
    k.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(kt * Matrix3::identity()));
    k.fixed_view_mut::<3, 3>(0, 3).copy_from(&(kt * sa));
    k.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(kt * sa.transpose()));
    k.fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&(kr + kt * sa.transpose() * sa));
    JointModel {
        stiffness: k,
        lower_end: -0.5 * length,
        lower_notch: 0.0,
        upper_notch: 0.0,
        upper_end: 0.5 * length,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cellinject_model::{Approach, Mechanism, prototype};

    fn ideal_spec(d: &Design) -> StructureSpec {
        let f = &d.flexures;
        StructureSpec {
            // J3: q1 is about y, q2 about x; J_i: axis 1 is local x, axis 2 local y.
            j3: ideal_joint([f.j3[1], f.j3[0]], 2e-3),
            j12: [
                ideal_joint([f.j1[0], f.j1[1]], 2e-3),
                ideal_joint([f.j2[0], f.j2[1]], 2e-3),
            ],
            mass: MassSpec {
                body_mass: 0.2,
                body_com: 0.06,
                body_inertia: [4.8e-4, 4.8e-4, 5e-5],
                stack_mass: [0.05, 0.05],
            },
        }
    }

    #[test]
    fn the_masses_follow_the_dimensions() {
        let shape = BodyShape::default();
        let mut g = prototype().geometry;
        let m = shape.masses(&g);
        // About J3: a rod of length b2 about its end, ρ s² b2³/3 (plus its section's
        // s²/12 share), and the tool at b2: the twin's 1.2e-3 kg·m² to 1 %.
        let about_j3 = m.body_inertia[0] + m.body_mass * m.body_com.powi(2);
        let rod = 7900.0 * 36e-6 * 0.18;
        let direct = rod * (0.18f64.powi(2) / 3.0 + 36e-6 / 12.0) + 0.02 * 0.18f64.powi(2);
        assert!(
            (about_j3 - direct).abs() < 1e-12 * direct,
            "{about_j3} vs {direct}"
        );
        assert!((about_j3 - 1.2e-3).abs() < 0.01 * 1.2e-3);
        assert!((m.stack_mass[0] - 7800.0 * 1e-4 * 0.066).abs() < 1e-12);
        // A longer lever is heavier, its centre of mass higher.
        g.b2 = 0.25;
        let longer = shape.masses(&g);
        assert!(longer.body_mass > m.body_mass && longer.body_com > m.body_com);
    }

    #[test]
    fn with_ideal_joints_small_loads_reproduce_the_linear_pseudo_rigid_body_model() {
        // Joints that bend only about their two axes through one point are the PRB
        // model's universal joints: at small loads both models are linear and must
        // agree (to the 1e-4 compliance left in the joints' rigid directions).
        let d = prototype();
        let s = Structure::new(&d, &ideal_spec(&d)).unwrap();
        let t = Mechanism::new(&d)
            .unwrap()
            .tension(Approach::DriveTranslation)
            .unwrap();
        let prb = t.tensioned.dx[0] / t.tensioned.force[0];
        let eq = s.solve([-1.0, -1.0], Preload::Translation).unwrap();
        for a in 0..2 {
            let mine = eq.tip[a] / eq.applied[a];
            assert!(
                (mine / prb - 1.0).abs() < 1e-4,
                "axis {a}: {mine:e} vs {prb:e}"
            );
        }
        // Approach 2: J3 pre-deflected by the PRB's Δq0 gives the PRB's tensioned state.
        let t2 = Mechanism::new(&d)
            .unwrap()
            .tension(Approach::JointDeflection)
            .unwrap();
        let dq0 = t2.dq0.unwrap();
        let eq2 = s
            .solve(
                [t2.tensioned.force[0], t2.tensioned.force[1]],
                Preload::Deflection {
                    dq0: [dq0[0], dq0[1]],
                },
            )
            .unwrap();
        for a in 0..2 {
            let (mine, prb) = (eq2.tip[a], t2.tensioned.dx[a]);
            assert!(
                (mine - prb).abs() < 0.02 * prb.abs(),
                "axis {a}: {mine:e} vs {prb:e}"
            );
        }
    }

    #[test]
    fn the_preload_softens_the_tilt_by_the_columns_geometric_stiffness() {
        // Under the 100 N compression of approach 1, a tilt θ swings the other stack by
        // b1 θ / reach and its force pushes the attachment on: the tilt stiffness drops
        // by P b1² / reach (a column's geometric stiffness). The nonlinear solution must
        // show exactly that.
        let d = prototype();
        let s = Structure::new(&d, &ideal_spec(&d)).unwrap();
        let lin = s.solve([-1.0, -1.0], Preload::Translation).unwrap();
        let k_lin = d.geometry.b1 * d.geometry.b2 / (lin.tip[0] / lin.applied[0]);
        let eq = s.solve([-100.0, -100.0], Preload::Translation).unwrap();
        let p = -eq.stack_force[1];
        let k_nl = k_lin - p * d.geometry.b1.powi(2) / d.geometry.reach(1);
        let expected = d.geometry.b1 * d.geometry.b2 / k_nl;
        let mine = eq.tip[0] / eq.stack_force[0];
        assert!(
            (mine / expected - 1.0).abs() < 3e-4,
            "{mine:e} vs {expected:e} (linear {:e})",
            d.geometry.b1 * d.geometry.b2 / k_lin
        );
        assert!(eq.residual < 1e-4);
    }

    #[test]
    fn cross_axis_coupling_comes_from_the_preload_geometry() {
        // Table 1/2's third case: raising F12 alone moves M along x only through the
        // pre-tensioned geometry. Under approach 1 each stack is swung by the other
        // axis' preload tilt (φ = b1 θ / reach), so A2's extra force has an x part
        // ΔF·φ; approach 2 leaves body 1 near home and the coupling near zero.
        let d = prototype();
        let s = Structure::new(&d, &ideal_spec(&d)).unwrap();
        let f = [-100.0, -111.686];
        let a = s.solve([-100.0, -100.0], Preload::Translation).unwrap();
        let b = s.solve(f, Preload::Translation).unwrap();
        let c1 = b.tip[0] - a.tip[0];
        // A2's swing at the preload: the tilt about x moved its attachment along y.
        let phi = (a.tip[1] / d.geometry.b2) * d.geometry.b1 / d.geometry.reach(1);
        let per_newton = a.tip[0] / a.stack_force[0];
        let expected = (f[1] - (-100.0)).abs() * phi.abs() * per_newton;
        assert!(
            (c1.abs() / expected - 1.0).abs() < 0.1,
            "coupling {c1:e} vs estimate {expected:e}"
        );
        let t2 = Mechanism::new(&d)
            .unwrap()
            .tension(Approach::JointDeflection)
            .unwrap();
        let dq0 = t2.dq0.unwrap();
        let pre = Preload::Deflection {
            dq0: [dq0[0], dq0[1]],
        };
        let a2 = s.solve([-100.0, -100.0], pre).unwrap();
        let b2 = s.solve(f, pre).unwrap();
        let c2 = b2.tip[0] - a2.tip[0];
        assert!(
            c1.abs() > 5.0 * c2.abs(),
            "approach 1 {c1:e}, approach 2 {c2:e}"
        );
    }

    #[test]
    fn the_tilt_mode_matches_its_hand_calculation() {
        // Sliders locked, the stacks hold body 1 like springs at b1: K = Kq + k_a b1²
        // + w² Kw (w = b1 / reach); the inertia is body 1's about J3 plus the stacks'
        // share (A1 compressing: m/4 b1², A2 swinging: m/3 b1²).
        let d = prototype();
        let spec = ideal_spec(&d);
        let s = Structure::new(&d, &spec).unwrap();
        let eq = s.solve([0.0, 0.0], Preload::Translation).unwrap();
        let modes = s.modes(&eq).unwrap();
        let g = &d.geometry;
        let w = g.b1 / g.reach(0);
        let k = d.flexures.j3[0] + d.drive_stiffness()[0] * g.b1 * g.b1 + w * w * d.flexures.j2[0];
        let m = &spec.mass;
        let inertia = m.body_inertia[1]
            + m.body_mass * m.body_com.powi(2)
            + g.b1 * g.b1 * (0.25 * m.stack_mass[0] + m.stack_mass[1] / 3.0);
        let f = (k / inertia).sqrt() / (2.0 * std::f64::consts::PI);
        for mode in &modes[..2] {
            assert!(
                (mode.frequency / f - 1.0).abs() < 0.01,
                "{} vs {f}",
                mode.frequency
            );
            assert!(
                mode.description.starts_with("body 1 tilt"),
                "{}",
                mode.description
            );
        }
        assert!(modes.windows(2).all(|p| p[0].frequency <= p[1].frequency));
    }

    proptest::proptest! {
        #![proptest_config(proptest::test_runner::Config::with_cases(24))]

        /// Small loads on the mirror-symmetric design: the response is linear in the
        /// forces (superposition) and each force moves M along its own axis only.
        #[test]
        fn small_loads_superpose_without_coupling(f1 in -5.0f64..-0.1, f2 in -5.0f64..-0.1) {
            let d = prototype();
            let s = Structure::new(&d, &ideal_spec(&d)).unwrap();
            let both = s.solve([f1, f2], Preload::Translation).unwrap();
            let one = s.solve([f1, 0.0], Preload::Translation).unwrap();
            let two = s.solve([0.0, f2], Preload::Translation).unwrap();
            let scale = both.tip.norm();
            // Superposition, up to the columns' geometric softening under the other
            // stack's force P: P b1² / (reach K) ≤ 1.7e-4 at 5 N.
            let sum = one.tip + two.tip;
            proptest::prop_assert!((both.tip - sum).norm() < 3e-4 * scale);
            // No cross-axis motion from a single force: mirror symmetry makes it zero.
            proptest::prop_assert!(one.tip[1].abs() < 1e-9 * one.tip[0].abs());
            proptest::prop_assert!(two.tip[0].abs() < 1e-9 * two.tip[1].abs());
            // The stacks carry the applied forces, less what the swing of the stacks
            // and the joints take (~1e-5 of the larger force).
            let big = f1.abs().max(f2.abs());
            proptest::prop_assert!((both.stack_force[0] - f1).abs() < 5e-5 * big);
            proptest::prop_assert!((both.stack_force[1] - f2).abs() < 5e-5 * big);
        }
    }

    #[test]
    fn the_papers_torque_setup_is_ill_conditioned() {
        // Sec. 3.3.2 replaces J3's pre-deflection by the torques of eq. (53) on body 1.
        // In the pseudo-rigid-body model itself (ideal joints) those torques, 3.002 N·m,
        // nearly cancel the stacks' F·b1 = 3.0 N·m: M moves by about 1 µm, not the
        // 22 µm of eq. (52) (Table 2: 23.2 µm). The pre-deflection's own moment
        // −Kq·Δq0 (3.04 N·m) gives eq. (52).
        let d = prototype();
        let s = Structure::new(&d, &ideal_spec(&d)).unwrap();
        let t = Mechanism::new(&d)
            .unwrap()
            .tension(Approach::JointDeflection)
            .unwrap();
        let (fq, dq0) = (t.tensioned.fq, t.dq0.unwrap());
        let paper = s
            .solve(
                [-100.0, -100.0],
                Preload::Torque {
                    moment: [-fq[0], -fq[1]],
                },
            )
            .unwrap();
        assert!(paper.tip[0].abs() < 2e-6, "{}", paper.tip[0]);
        let kq = d.flexures.j3;
        let own = s
            .solve(
                [-100.0, -100.0],
                Preload::Torque {
                    moment: [-kq[0] * dq0[0], -kq[1] * dq0[1]],
                },
            )
            .unwrap();
        for a in 0..2 {
            let prb = t.tensioned.dx[a];
            assert!(
                (own.tip[a] - prb).abs() < 0.01 * prb.abs(),
                "{} vs {prb}",
                own.tip[a]
            );
        }
    }
}
