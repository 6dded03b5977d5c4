//! Nonlinear kinematics of the serial-parallel structure and its Jacobians
//! (paper Sec. 2, eqs. 1-7).
//!
//! Generalised coordinates (eqs. 1-3): `q = [q1, q2, q3]` are the two angles of the
//! universal flexure J3 and the extension of A3; `w = [w11, w12, w21, w22]` are the
//! angles of the flexures J1 and J2; `l = [l1, l2, l3]` are the actuator extensions.
//! The end-effector coordinates `X` (eq. 4) are the displacement of M from its home
//! position. The home pose is `q = w = l = 0`.
//!
//! The serial chain is evaluated in closed form (`X = Ψ(q)`), the two parallel loops
//! `Ψ_i(q, w, l) = 0` (three scalar equations each, six in all) are solved by Newton's
//! method, and the Jacobians `J = ∂X/∂q`, `W = ∂w/∂q`, `L = ∂l/∂q` (eqs. 5-7) are
//! obtained by differentiating these functions: `J` directly, `W` and `L` by implicit
//! differentiation of the loop-closure equations.

use nalgebra::{Matrix3, Matrix4x3, Rotation3, Unit, Vector3};

use crate::design::Geometry;
use crate::error::ModelError;

/// Pose of the main serial chain: `q = [q1, q2, q3]` (rad, rad, m).
pub type Pose = Vector3<f64>;

/// Solution of one parallel loop for a given pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChainState {
    /// Angles of the base flexure (rad), [axis 1, axis 2].
    pub w: [f64; 2],
    /// Extension of the actuator (m), positive when it lengthens.
    pub l: f64,
}

/// The constant Jacobians of eqs. (5)-(7), or their value at any pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Jacobians {
    /// `J = ∂X/∂q`, 3x3 (eq. 5).
    pub j: Matrix3<f64>,
    /// `L = ∂l/∂q`, 3x3 (eq. 7).
    pub l: Matrix3<f64>,
    /// `W = ∂w/∂q`, 4x3 (eq. 6), rows w11, w12, w21, w22.
    pub w: Matrix4x3<f64>,
}

#[derive(Debug, Clone, Copy)]
struct Chain {
    /// Position of the base flexure J_i.
    base: Vector3<f64>,
    /// Home direction of the actuator.
    dir: Vector3<f64>,
    /// First flexure axis (−z), fixed in the base.
    axis1: Unit<Vector3<f64>>,
    /// Second flexure axis (ẑ × d), carried by the first.
    axis2: Unit<Vector3<f64>>,
    /// Distance from J_i to the spherical joint at home (a_i1 + a_i2).
    reach: f64,
}

impl Chain {
    /// Unit direction of the actuator for flexure angles `w`, and its two partial derivatives.
    fn direction(&self, w: [f64; 2]) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        let r1 = Rotation3::from_axis_angle(&self.axis1, w[0]);
        let r2 = Rotation3::from_axis_angle(&self.axis2, w[1]);
        let r2d = r2 * self.dir;
        let u = r1 * r2d;
        let du1 = self.axis1.into_inner().cross(&u);
        let du2 = r1 * self.axis2.into_inner().cross(&r2d);
        (u, du1, du2)
    }
}

/// Maximum Newton iterations of the loop-closure and forward solves.
const MAX_ITER: usize = 50;

/// The kinematic model of one geometry.
#[derive(Debug, Clone, Copy)]
pub struct Kinematics {
    geometry: Geometry,
    chains: [Chain; 2],
}

/// Rotation of body 1 by the universal joint J3: `R(q) = R_y(q1) · R_x(q2)`.
fn body_rotation(q1: f64, q2: f64) -> Matrix3<f64> {
    let ry = Rotation3::from_axis_angle(&Vector3::y_axis(), q1);
    let rx = Rotation3::from_axis_angle(&Vector3::x_axis(), q2);
    (ry * rx).into_inner()
}

/// Partial derivatives of [`body_rotation`] with respect to q1 and q2.
fn body_rotation_derivatives(q1: f64, q2: f64) -> [Matrix3<f64>; 2] {
    let ry = Rotation3::from_axis_angle(&Vector3::y_axis(), q1).into_inner();
    let rx = Rotation3::from_axis_angle(&Vector3::x_axis(), q2).into_inner();
    let ey = Vector3::<f64>::y().cross_matrix();
    let ex = Vector3::<f64>::x().cross_matrix();
    [ey * ry * rx, ry * ex * rx]
}

impl Kinematics {
    /// Builds the kinematic model of a geometry (assumed validated).
    pub fn new(geometry: &Geometry) -> Self {
        let attach = Vector3::new(0.0, 0.0, geometry.b1);
        let chain = |i: usize| {
            let phi = geometry.actuator_azimuth[i];
            let dir = Vector3::new(phi.cos(), phi.sin(), 0.0);
            let reach = geometry.reach(i);
            Chain {
                base: attach - reach * dir,
                dir,
                axis1: Unit::new_normalize(-Vector3::z()),
                axis2: Unit::new_normalize(Vector3::z().cross(&dir)),
                reach,
            }
        };
        Kinematics {
            geometry: *geometry,
            chains: [chain(0), chain(1)],
        }
    }

    /// The geometry this model was built from.
    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }

    /// Position of the spherical joints on body 1 (both actuators meet body 1 at one point).
    pub fn attachment(&self, q: &Pose) -> Vector3<f64> {
        body_rotation(q[0], q[1]) * Vector3::new(0.0, 0.0, self.geometry.b1)
    }

    /// Direct kinematics of the serial chain, `X = Ψ(q)`: displacement of M from home (m).
    pub fn end_effector(&self, q: &Pose) -> Vector3<f64> {
        body_rotation(q[0], q[1]) * Vector3::new(0.0, 0.0, self.geometry.b2 + q[2])
            - Vector3::new(0.0, 0.0, self.geometry.b2)
    }

    /// Residual of the loop-closure equations `Ψ_i(q, w_i, l_i)` of chain `i` (0 = A1/J1).
    pub fn loop_residual(&self, i: usize, q: &Pose, s: &ChainState) -> Vector3<f64> {
        let c = &self.chains[i];
        let (u, _, _) = c.direction(s.w);
        c.base + (c.reach + s.l) * u - self.attachment(q)
    }

    /// Jacobian of the loop-closure residual of chain `i` with respect to `(w_i1, w_i2, l_i)`.
    fn loop_matrix(&self, i: usize, s: &ChainState) -> Matrix3<f64> {
        let c = &self.chains[i];
        let (u, du1, du2) = c.direction(s.w);
        let r = c.reach + s.l;
        Matrix3::from_columns(&[r * du1, r * du2, u])
    }

    /// m, the loop-closure residual at which [`Self::solve_chain`] stops: `8ε` of the
    /// chain's reach, the rounding floor of its actuator extension.
    pub fn rounding_floor(&self, i: usize) -> f64 {
        8.0 * f64::EPSILON * self.chains[i].reach
    }

    /// Solves the loop closure of chain `i` for its flexure angles and actuator extension
    /// at pose `q` (Newton's method, starting from the home state).
    pub fn solve_chain(&self, i: usize, q: &Pose) -> Result<ChainState, ModelError> {
        let mut s = ChainState {
            w: [0.0; 2],
            l: 0.0,
        };
        // Iterate to the rounding floor: stop once the residual no longer decreases.
        let floor = self.rounding_floor(i);
        let reach = self.chains[i].reach;
        let mut res = self.loop_residual(i, q, &s).norm();
        for _ in 0..MAX_ITER {
            if res <= floor {
                return Ok(s);
            }
            let a = self.loop_matrix(i, &s);
            let r = self.loop_residual(i, q, &s);
            let Some(dx) = a.lu().solve(&(-r)) else {
                break;
            };
            let trial = ChainState {
                w: [s.w[0] + dx[0], s.w[1] + dx[1]],
                l: s.l + dx[2],
            };
            let next = self.loop_residual(i, q, &trial).norm();
            if next >= res {
                break;
            }
            s = trial;
            res = next;
        }
        if res <= 1e-12 * reach {
            return Ok(s);
        }
        Err(ModelError::NotConverged {
            what: "loop closure",
            iterations: MAX_ITER,
            residual: res,
        })
    }

    /// Inverse kinematics of the whole structure: passive angles `w` and actuator
    /// extensions `l` at pose `q` (`l3 = q3`: A3 is the serial axis).
    pub fn inverse(&self, q: &Pose) -> Result<([f64; 4], Vector3<f64>), ModelError> {
        let s1 = self.solve_chain(0, q)?;
        let s2 = self.solve_chain(1, q)?;
        Ok((
            [s1.w[0], s1.w[1], s2.w[0], s2.w[1]],
            Vector3::new(s1.l, s2.l, q[2]),
        ))
    }

    /// Jacobians J, L, W at an arbitrary pose, by differentiating the serial chain and
    /// implicitly differentiating the loop closures: `∂(w_i, l_i)/∂q = A_i⁻¹ ∂P/∂q`.
    pub fn jacobians_at(&self, q: &Pose) -> Result<Jacobians, ModelError> {
        let [d1, d2] = body_rotation_derivatives(q[0], q[1]);
        let rot = body_rotation(q[0], q[1]);
        let ez = Vector3::z();
        let arm = self.geometry.b2 + q[2];
        let j = Matrix3::from_columns(&[d1 * ez * arm, d2 * ez * arm, rot * ez]);
        let dp = Matrix3::from_columns(&[
            d1 * ez * self.geometry.b1,
            d2 * ez * self.geometry.b1,
            Vector3::zeros(),
        ]);
        let mut l = Matrix3::zeros();
        let mut w = Matrix4x3::zeros();
        for i in 0..2 {
            let s = self.solve_chain(i, q)?;
            let a = self.loop_matrix(i, &s);
            let rows = a.lu().solve(&dp).ok_or(ModelError::SingularJacobian {
                matrix: "W",
                rcond: 0.0,
            })?;
            w.set_row(2 * i, &rows.row(0));
            w.set_row(2 * i + 1, &rows.row(1));
            l.set_row(i, &rows.row(2));
        }
        l[(2, 2)] = 1.0;
        Ok(Jacobians { j, l, w })
    }

    /// The constant Jacobians of the pseudo-rigid-body model: those at the home pose.
    pub fn jacobians(&self) -> Result<Jacobians, ModelError> {
        self.jacobians_at(&Pose::zeros())
    }

    /// Forward kinematics of the parallel structure: the pose reached for actuator
    /// extensions `l` (Newton's method on the loop closures).
    pub fn forward(&self, l: &Vector3<f64>) -> Result<Pose, ModelError> {
        let mut q = Pose::new(0.0, 0.0, l[2]);
        let tol = 1e-15 * self.geometry.b2;
        let mut last = f64::INFINITY;
        for _ in 0..MAX_ITER {
            let (_, lq) = self.inverse(&q)?;
            let r = lq - l;
            last = r.norm();
            if last <= tol {
                return Ok(q);
            }
            let jac = self.jacobians_at(&q)?;
            let dq = jac
                .l
                .lu()
                .solve(&(-r))
                .ok_or(ModelError::SingularJacobian {
                    matrix: "L",
                    rcond: 0.0,
                })?;
            q += dq;
        }
        if last <= 1e3 * tol {
            return Ok(q);
        }
        Err(ModelError::NotConverged {
            what: "forward kinematics",
            iterations: MAX_ITER,
            residual: last,
        })
    }
}

/// Ratio of the smallest to the largest singular value of a 2x2 matrix.
pub fn rcond(m: &nalgebra::Matrix2<f64>) -> f64 {
    let sv = m.singular_values();
    let max = sv.max();
    if max == 0.0 { 0.0 } else { sv.min() / max }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn prototype() -> Geometry {
        crate::prototype().geometry
    }

    #[test]
    fn home_jacobians_equal_the_closed_forms_of_our_reading() {
        let g = prototype();
        let k = Kinematics::new(&g);
        let jac = k.jacobians().unwrap();
        let w = g.b1 / (g.a11 + g.a12);
        let j = Matrix3::from_diagonal(&Vector3::new(g.b2, -g.b2, 1.0));
        let l = Matrix3::from_diagonal(&Vector3::new(g.b1, -g.b1, 1.0));
        let mut wm = Matrix4x3::zeros();
        wm[(0, 1)] = w; // q2 bends J1's first axis
        wm[(2, 0)] = w; // q1 bends J2's first axis
        assert_relative_eq!(jac.j, j, epsilon = 1e-15);
        assert_relative_eq!(jac.l, l, epsilon = 1e-15);
        assert_relative_eq!(jac.w, wm, epsilon = 1e-14);
    }

    #[test]
    fn jacobians_match_central_differences_of_the_nonlinear_maps() {
        let mut g = prototype();
        g.a21 = 0.011;
        g.actuator_azimuth[1] = 1.3;
        let k = Kinematics::new(&g);
        let q0 = Pose::new(3e-3, -2e-3, 1e-5);
        let jac = k.jacobians_at(&q0).unwrap();
        let h = 1e-6;
        for c in 0..3 {
            let mut qp = q0;
            let mut qm = q0;
            qp[c] += h;
            qm[c] -= h;
            let dx = (k.end_effector(&qp) - k.end_effector(&qm)) / (2.0 * h);
            let (wp, lp) = k.inverse(&qp).unwrap();
            let (wm, lm) = k.inverse(&qm).unwrap();
            let dl = (lp - lm) / (2.0 * h);
            for r in 0..3 {
                assert_relative_eq!(jac.j[(r, c)], dx[r], epsilon = 1e-7);
                assert_relative_eq!(jac.l[(r, c)], dl[r], epsilon = 1e-7);
            }
            for r in 0..4 {
                assert_relative_eq!(jac.w[(r, c)], (wp[r] - wm[r]) / (2.0 * h), epsilon = 1e-7);
            }
        }
    }

    #[test]
    fn loop_closure_residual_vanishes_and_forward_inverts_inverse() {
        let k = Kinematics::new(&prototype());
        let q = Pose::new(-8.4e-3, 8.4e-3, 2e-5);
        let (w, l) = k.inverse(&q).unwrap();
        for i in 0..2 {
            let s = ChainState {
                w: [w[2 * i], w[2 * i + 1]],
                l: l[i],
            };
            assert!(k.loop_residual(i, &q, &s).norm() < 1e-15);
            // The actuator extension is the change of the J_i-to-attachment distance.
            let c = &k.chains[i];
            let dist = (k.attachment(&q) - c.base).norm() - c.reach;
            assert_relative_eq!(l[i], dist, epsilon = 1e-16);
        }
        let back = k.forward(&l).unwrap();
        assert_relative_eq!(back, q, epsilon = 1e-13);
    }

    #[test]
    fn parallel_actuators_make_l_singular() {
        let mut g = prototype();
        g.actuator_azimuth = [0.0, 0.0];
        let jac = Kinematics::new(&g).jacobians().unwrap();
        let lp = jac.l.fixed_view::<2, 2>(0, 0).into_owned();
        assert!(rcond(&lp) < 1e-12);
    }
}
