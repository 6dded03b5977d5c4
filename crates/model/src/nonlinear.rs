//! Large-deflection check: the pre-tension equilibrium solved with the full nonlinear
//! kinematics instead of the constant Jacobians.
//!
//! The equilibrium (19), `Fq + Wᵀ Fw = Lᵀ F_l`, is the stationarity condition of the
//! elastic energy
//!
//! ```text
//! U(q) = ½ (q − q_r)ᵀ Kq (q − q_r) + ½ w(q)ᵀ Kw w(q) + ½ (l_r − l(q))ᵀ Kl (l_r − l(q)),
//! ```
//!
//! whose gradient is `Fq + W(q)ᵀ Fw − L(q)ᵀ F_l` with `Fq = Kq (q − q_r)`,
//! `Fw = Kw w(q)`, `F_l = Kl (l_r − l(q))` (eqs. 16-18). Here `w(q)` and `l(q)` come from
//! the loop closures, `W(q)` and `L(q)` are the Jacobians at the current pose, and the
//! rest positions encode the approach: approach 1 has `q_r = 0` and `l_r = Δl0 + Δl2`
//! (eq. 14); approach 2 has `q_r = −Δq0` (eq. 28) and `l_r = Δl2`. With constant
//! Jacobians this reduces exactly to eqs. (22)-(26) and (29)-(33).

use nalgebra::{Matrix2, Vector2, Vector3, Vector4};

use crate::error::ModelError;
use crate::tension::{Approach, Mechanism, Tension};

/// A nonlinear equilibrium of the pre-tensioned structure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NonlinearState {
    /// Pose of the main chain (rad, rad, m).
    pub q: Vector3<f64>,
    /// rad, passive-joint angles w.
    pub w: Vector4<f64>,
    /// m, actuator coordinates l.
    pub l: Vector3<f64>,
    /// N, actuator forces.
    pub force: Vector3<f64>,
    /// N·m, J3 torques.
    pub fq: Vector3<f64>,
    /// N·m, J1/J2 torques.
    pub fw: Vector4<f64>,
    /// m, end-effector displacement from home.
    pub dx: Vector3<f64>,
    /// Newton iterations used.
    pub iterations: usize,
    /// Relative residual of eq. (19) at the solution.
    pub residual: f64,
    /// Relative residual that rounding alone leaves at this state: the actuator
    /// extensions come from loop closures solved to `8ε·reach`, so each actuator force
    /// carries `Kl·8ε·reach` of noise, and eq. (19) `‖Lᵀ·δF‖` of it. A light preload on
    /// a stiff stack makes this larger than [`ACCEPT`]; the solver accepts it then.
    pub floor: f64,
}

/// Relative residual at which the Newton iteration stops early.
const TOLERANCE: f64 = 1e-12;
/// Relative residual accepted once the iteration has reached its rounding floor (the
/// actuator force is `Kl·(l_r − l)`, a difference of lengths of order `a11 + a12`), or
/// four times the state's own [`NonlinearState::floor`] where that is larger.
pub const ACCEPT: f64 = 1e-9;
const MAX_ITER: usize = 60;

impl Mechanism {
    /// Generalised forces of the energy at pose `q` on the tilt axes, and the state there.
    fn energy_gradient(
        &self,
        q: &Vector3<f64>,
        q_rest: &Vector2<f64>,
        l_rest: &Vector2<f64>,
    ) -> Result<(Vector2<f64>, f64, NonlinearState), ModelError> {
        let kin = self.kinematics();
        let (w, l) = kin.inverse(q)?;
        let jac = kin.jacobians_at(q)?;
        let f = &self.design().flexures;
        let kl = self.design().drive_stiffness();
        let w = Vector4::from(w);
        let fw = Vector4::new(
            f.j1[0] * w[0],
            f.j1[1] * w[1],
            f.j2[0] * w[2],
            f.j2[1] * w[3],
        );
        let fq = Vector3::new(
            f.j3[0] * (q[0] - q_rest[0]),
            f.j3[1] * (q[1] - q_rest[1]),
            0.0,
        );
        let force = Vector3::new(kl[0] * (l_rest[0] - l[0]), kl[1] * (l_rest[1] - l[1]), 0.0);
        let a = fq;
        let b = jac.w.transpose() * fw;
        let c = jac.l.transpose() * force;
        let g = a + b - c;
        let scale = a.norm() + b.norm() + c.norm();
        let noise = Vector3::new(
            kl[0] * kin.rounding_floor(0),
            kl[1] * kin.rounding_floor(1),
            0.0,
        );
        let floor = if scale > 0.0 {
            (jac.l.transpose().abs() * noise).norm() / scale
        } else {
            0.0
        };
        let state = NonlinearState {
            q: *q,
            w,
            l,
            force,
            fq,
            fw,
            dx: kin.end_effector(q),
            iterations: 0,
            residual: 0.0,
            floor,
        };
        Ok((Vector2::new(g[0], g[1]), scale, state))
    }

    /// Solves the nonlinear equilibrium for rest positions `q_rest` (J3) and `l_rest`
    /// (A1, A2), with A3 at extension `a3`, by Newton's method started at `q_start`.
    pub fn solve_nonlinear(
        &self,
        q_rest: Vector2<f64>,
        l_rest: Vector2<f64>,
        a3: f64,
        q_start: Vector2<f64>,
    ) -> Result<NonlinearState, ModelError> {
        let mut q = Vector3::new(q_start[0], q_start[1], a3);
        let h = 1e-7;
        let mut last = f64::INFINITY;
        let mut stalled = 0;
        for it in 0..MAX_ITER {
            let (g, scale, mut state) = self.energy_gradient(&q, &q_rest, &l_rest)?;
            let rel = if scale > 0.0 { g.norm() / scale } else { 0.0 };
            stalled = if rel < 0.5 * last { 0 } else { stalled + 1 };
            last = last.min(rel);
            if rel <= TOLERANCE || (stalled >= 3 && rel <= ACCEPT.max(4.0 * state.floor)) {
                state.iterations = it;
                state.residual = rel;
                return Ok(state);
            }
            // Newton step with a central-difference Hessian of the energy.
            let mut hess = Matrix2::zeros();
            for c in 0..2 {
                let mut qp = q;
                let mut qm = q;
                qp[c] += h;
                qm[c] -= h;
                let (gp, _, _) = self.energy_gradient(&qp, &q_rest, &l_rest)?;
                let (gm, _, _) = self.energy_gradient(&qm, &q_rest, &l_rest)?;
                hess.set_column(c, &((gp - gm) / (2.0 * h)));
            }
            let Some(step) = hess.lu().solve(&(-g)) else {
                break;
            };
            q[0] += step[0];
            q[1] += step[1];
        }
        Err(ModelError::NotConverged {
            what: "nonlinear equilibrium",
            iterations: MAX_ITER,
            residual: last,
        })
    }

    /// Linear and nonlinear answers side by side for one approach (item 5 of the model).
    pub fn linearisation(&self, approach: Approach) -> Result<Linearisation, ModelError> {
        let t = self.tension(approach)?;
        let zero = Vector2::zeros();
        let (q_rest, l_tension, l_work) = match approach {
            Approach::DriveTranslation => {
                let dl0 = t.dl0.unwrap_or_default();
                let dlt = t.dl_total.unwrap_or_default();
                (
                    zero,
                    Vector2::new(dl0[0], dl0[1]),
                    Vector2::new(dlt[0], dlt[1]),
                )
            }
            Approach::JointDeflection => {
                let dq0 = t.dq0.unwrap_or_default();
                (
                    Vector2::new(-dq0[0], -dq0[1]),
                    zero,
                    Vector2::new(t.dl2[0], t.dl2[1]),
                )
            }
        };
        let l_inv = self.jacobians().l.try_inverse().unwrap_or_default();
        let start = |s: &crate::tension::State| {
            let q = l_inv * s.dl;
            Vector2::new(q[0], q[1])
        };
        let tension = self.solve_nonlinear(q_rest, l_tension, 0.0, start(&t.tensioned))?;
        let work = self.solve_nonlinear(q_rest, l_work, 0.0, start(&t.work))?;
        Ok(Linearisation::new(&t, tension, work))
    }
}

/// How a linear quantity compares with its nonlinear counterpart.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Deviation {
    /// Norm of the difference (SI units of the quantity).
    pub absolute: f64,
    /// `absolute` divided by the norm of the nonlinear value.
    pub relative: f64,
}

impl Deviation {
    fn of(linear: &Vector3<f64>, nonlinear: &Vector3<f64>) -> Self {
        let absolute = (linear - nonlinear).norm();
        let n = nonlinear.norm();
        Deviation {
            absolute,
            relative: if n > 0.0 { absolute / n } else { absolute },
        }
    }
}

/// The constant-Jacobian answer against the nonlinear equilibrium.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Linearisation {
    /// The approach.
    pub approach: Approach,
    /// Nonlinear state after tensioning.
    pub tensioned: NonlinearState,
    /// Nonlinear state at the working shift.
    pub work: NonlinearState,
    /// End-effector displacement after tensioning: linear vs nonlinear.
    pub dx_tensioned: Deviation,
    /// End-effector displacement at the working shift.
    pub dx_work: Deviation,
    /// Actuator forces after tensioning.
    pub force_tensioned: Deviation,
    /// Actuator forces at the working shift.
    pub force_work: Deviation,
    /// m, working range from the nonlinear model (axes 1-2; axis 3 is A3's travel).
    pub chi_nonlinear: Vector3<f64>,
    /// Working range.
    pub chi: Deviation,
    /// m, cross-axis coupling: the nonlinear end-effector displacement off the
    /// commanded axes that the linear model does not have (out-of-plane z drop).
    pub dz_tensioned: f64,
}

impl Linearisation {
    fn new(t: &Tension, tensioned: NonlinearState, work: NonlinearState) -> Self {
        let chi_nonlinear = Vector3::new(
            (tensioned.dx[0] - work.dx[0]).abs(),
            (tensioned.dx[1] - work.dx[1]).abs(),
            t.chi[2],
        );
        let planar = |v: &Vector3<f64>| Vector3::new(v[0], v[1], 0.0);
        Linearisation {
            approach: t.approach,
            dx_tensioned: Deviation::of(&t.tensioned.dx, &planar(&tensioned.dx)),
            dx_work: Deviation::of(&t.work.dx, &planar(&work.dx)),
            force_tensioned: Deviation::of(&t.tensioned.force, &tensioned.force),
            force_work: Deviation::of(&t.work.force, &work.force),
            chi: Deviation::of(&t.chi, &chi_nonlinear),
            chi_nonlinear,
            dz_tensioned: tensioned.dx[2],
            tensioned,
            work,
        }
    }
}
