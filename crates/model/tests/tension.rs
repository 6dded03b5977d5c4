//! Pre-tension of designs other than the prototype, checked against an independent
//! direct matrix evaluation of the paper's equations, and property tests of the
//! invariants the paper states.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use approx::assert_relative_eq;
use cellinject_model::{Approach, Design, Mechanism, NONLINEAR_ACCEPT, prototype};
use nalgebra::{Matrix3, Matrix4, Matrix4x3, Vector3, Vector4};
use proptest::prelude::*;

/// The paper's 3x3 matrices for an orthogonal design, written from the closed forms of
/// our reading (J = diag(b2, −b2, 1), L = diag(b1, −b1, 1), W with w_i = b1/(a_i1 + a_i2)),
/// independently of the kinematics code.
struct Direct {
    j: Matrix3<f64>,
    l: Matrix3<f64>,
    w: Matrix4x3<f64>,
    kq: Matrix3<f64>,
    kw: Matrix4<f64>,
    kl: Matrix3<f64>,
}

impl Direct {
    fn new(d: &Design) -> Self {
        let g = &d.geometry;
        let mut w = Matrix4x3::zeros();
        w[(0, 1)] = g.b1 / (g.a11 + g.a12);
        w[(2, 0)] = g.b1 / (g.a21 + g.a22);
        let f = &d.flexures;
        Direct {
            j: Matrix3::from_diagonal(&Vector3::new(g.b2, -g.b2, 1.0)),
            l: Matrix3::from_diagonal(&Vector3::new(g.b1, -g.b1, 1.0)),
            w,
            kq: Matrix3::from_diagonal(&Vector3::new(f.j3[0], f.j3[1], 0.0)),
            kw: Matrix4::from_diagonal(&Vector4::new(f.j1[0], f.j1[1], f.j2[0], f.j2[1])),
            kl: Matrix3::from_diagonal(&Vector3::new(
                d.actuators[0].stiffness.unwrap(),
                d.actuators[1].stiffness.unwrap(),
                0.0,
            )),
        }
    }

    /// The paper's singular diag(.., .., 0) matrices are inverted on the tilt block only:
    /// A3 carries no force. `pinv` inverts the upper-left 2x2 block.
    fn pinv(m: &Matrix3<f64>) -> Matrix3<f64> {
        let b = m
            .fixed_view::<2, 2>(0, 0)
            .into_owned()
            .try_inverse()
            .unwrap();
        let mut out = Matrix3::zeros();
        out.fixed_view_mut::<2, 2>(0, 0).copy_from(&b);
        out
    }
}

fn v3(a: [f64; 2]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], 0.0)
}

fn other_designs() -> Vec<Design> {
    let mut a = prototype();
    // Asymmetric: different actuator reaches, flexures and stack stiffnesses.
    a.geometry.a21 = 0.010;
    a.geometry.a22 = 0.050;
    a.flexures.j3 = [250.0, 410.0];
    a.flexures.j1 = [60.0, 120.0];
    a.flexures.j2 = [140.0, 75.0];
    a.actuators[0].stiffness = Some(20e6);
    a.actuators[1].stiffness = Some(35e6);
    a.tension.preload = [-150.0, -80.0];
    a.tension.work_shift = [-20e-6, 12e-6];
    let mut b = prototype();
    // Another size: longer lever, heavier preload, positive shifts.
    b.geometry.b1 = 0.045;
    b.geometry.b2 = 0.120;
    b.geometry.a11 = 0.012;
    b.geometry.a12 = 0.080;
    b.geometry.a21 = 0.012;
    b.geometry.a22 = 0.080;
    b.tension.preload = [-300.0, -300.0];
    b.tension.work_shift = [25e-6, 25e-6];
    vec![a, b]
}

#[test]
fn approach_1_equals_direct_evaluation_of_eqs_22_to_26() {
    for d in other_designs() {
        let x = Direct::new(&d);
        let m = Mechanism::new(&d).unwrap();
        let t = m.tension(Approach::DriveTranslation).unwrap();
        let f10 = v3(d.tension.preload);
        let dl2 = v3(d.tension.work_shift);
        // (23) B_l = L [Kq + Wᵀ Kw W]⁻¹ Lᵀ + Kl⁻¹
        let b = x.l * Direct::pinv(&(x.kq + x.w.transpose() * x.kw * x.w)) * x.l.transpose()
            + Direct::pinv(&x.kl);
        let dl0 = b * f10; // (22)
        let dl1 = Direct::pinv(&x.kl) * f10; // (21)
        let dl = dl0 - dl1; // (15)
        let dx = x.j * x.l.try_inverse().unwrap() * dl; // (12)
        let fq = x.kq * x.l.try_inverse().unwrap() * dl; // (11), (18)
        let fw = x.kw * x.w * x.l.try_inverse().unwrap() * dl; // (13), (17)
        let f_work = Direct::pinv(&b) * (dl0 + dl2); // (24)
        let dl1_work = Direct::pinv(&x.kl) * f_work; // (26)
        let dx_work = x.j * x.l.try_inverse().unwrap() * (dl0 + dl2 - dl1_work); // (25)
        let eps = 1e-12;
        assert_relative_eq!(t.dl0.unwrap(), dl0, max_relative = eps);
        assert_relative_eq!(t.tensioned.dl1, dl1, max_relative = eps);
        assert_relative_eq!(t.tensioned.dl, dl, max_relative = eps);
        assert_relative_eq!(t.tensioned.dx, dx, max_relative = eps);
        assert_relative_eq!(t.tensioned.fq, fq, max_relative = eps);
        assert_relative_eq!(t.tensioned.fw, fw, max_relative = eps);
        assert_relative_eq!(t.work.force, f_work, max_relative = eps);
        assert_relative_eq!(t.work.dl1, dl1_work, max_relative = eps);
        assert_relative_eq!(t.work.dx, dx_work, max_relative = eps);
        assert_relative_eq!(
            m.compliance().unwrap()[(0, 0)],
            b[(0, 0)],
            max_relative = eps
        );
        // These designs are not the paper's: the answer must differ from its figures.
        assert!((t.tensioned.dx[0] + 1518.006e-6).abs() > 1e-6);
    }
}

#[test]
fn approach_2_equals_direct_evaluation_of_eqs_27_to_33() {
    for d in other_designs() {
        let x = Direct::new(&d);
        let m = Mechanism::new(&d).unwrap();
        let t = m.tension(Approach::JointDeflection).unwrap();
        let f10 = v3(d.tension.preload);
        let dl2 = v3(d.tension.work_shift);
        let li = x.l.try_inverse().unwrap();
        let kli = Direct::pinv(&x.kl);
        let wkw = x.w.transpose() * x.kw * x.w;
        // (31) at Δl2 = 0
        let u = -kli * f10;
        let dq0 = -Direct::pinv(&x.kq) * (wkw * li * u - x.l.transpose() * f10) - li * u;
        let dl = -kli * f10; // (27), (21)
        let dx = x.j * li * dl; // (33)
        let fq = x.kq * (dq0 + li * dl); // (29)
        // (32)
        let k = x.kq + wkw;
        let lhs = k * li * kli + x.l.transpose();
        let f_work = Direct::pinv(&lhs) * (x.kq * dq0 + k * li * dl2);
        let dl_work = dl2 - kli * f_work;
        let dx_work = x.j * li * dl_work;
        let eps = 1e-12;
        assert_relative_eq!(t.dq0.unwrap(), dq0, max_relative = eps);
        assert_relative_eq!(t.tensioned.dl, dl, max_relative = eps);
        assert_relative_eq!(t.tensioned.dx, dx, max_relative = eps);
        assert_relative_eq!(t.tensioned.fq, fq, max_relative = eps);
        assert_relative_eq!(t.work.force, f_work, max_relative = eps);
        assert_relative_eq!(t.work.dl, dl_work, max_relative = eps);
        assert_relative_eq!(t.work.dx, dx_work, max_relative = eps);
    }
}

fn design_strategy() -> impl Strategy<Value = Design> {
    (
        (0.003..0.02f64, 0.03..0.1f64, 0.003..0.02f64, 0.03..0.1f64),
        (0.01..0.06f64, 0.1..0.3f64, -0.3..0.3f64, 1.2..1.9f64),
        (
            prop::array::uniform2(100.0..600.0f64),
            prop::array::uniform4(30.0..200.0f64),
        ),
        (
            prop::array::uniform2(5e6..60e6f64),
            prop::array::uniform2(-400.0..-10.0f64),
        ),
        prop::array::uniform2(-1.0..1.0f64),
    )
        .prop_map(|(a, b, k, f, s)| {
            let mut d = prototype();
            d.geometry.a11 = a.0;
            d.geometry.a12 = a.1;
            d.geometry.a21 = a.2;
            d.geometry.a22 = a.3;
            d.geometry.b1 = b.0;
            d.geometry.b2 = b.1;
            d.geometry.actuator_azimuth = [b.2, b.2 + b.3];
            d.flexures.j3 = k.0;
            d.flexures.j1 = [k.1[0], k.1[1]];
            d.flexures.j2 = [k.1[2], k.1[3]];
            d.actuators[0].stiffness = Some(f.0[0]);
            d.actuators[1].stiffness = Some(f.0[1]);
            d.tension.preload = f.1;
            d.tension.work_shift = [s[0] * 30e-6, s[1] * 30e-6];
            d
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Eq. (19) holds in both states of both approaches.
    #[test]
    fn equilibrium_19_holds(d in design_strategy()) {
        let m = Mechanism::new(&d).unwrap();
        for a in [Approach::DriveTranslation, Approach::JointDeflection] {
            let t = m.tension(a).unwrap();
            prop_assert!(m.equilibrium_residual(&t.tensioned) < 1e-9);
            prop_assert!(m.equilibrium_residual(&t.work) < 1e-9);
            // The preload is what was asked for.
            prop_assert!((t.tensioned.force[0] - d.tension.preload[0]).abs() < 1e-9 * d.tension.preload[0].abs());
        }
    }

    /// Sec. 3.2: both approaches give the same working range.
    #[test]
    fn both_approaches_give_the_same_working_range(d in design_strategy()) {
        let m = Mechanism::new(&d).unwrap();
        let c1 = m.tension(Approach::DriveTranslation).unwrap().chi;
        let c2 = m.tension(Approach::JointDeflection).unwrap().chi;
        let scale = c1.norm();
        prop_assert!((c1 - c2).norm() <= 1e-9 * scale, "{c1} vs {c2}");
    }

    /// The nonlinear equilibrium converges to the linear one as preload and shift vanish.
    #[test]
    fn nonlinear_converges_to_linear(d in design_strategy()) {
        for a in [Approach::DriveTranslation, Approach::JointDeflection] {
            let mut errs = Vec::new();
            for s in [1.0, 0.1, 0.01] {
                let mut ds = d;
                ds.tension.preload = [d.tension.preload[0] * s, d.tension.preload[1] * s];
                ds.tension.work_shift = [d.tension.work_shift[0] * s, d.tension.work_shift[1] * s];
                let m = Mechanism::new(&ds).unwrap();
                let lin = m.linearisation(a).unwrap();
                // Converged to 1e-9, or to the rounding floor where a light preload
                // on a stiff stack puts that higher (the floor is computed, not tuned).
                for st in [&lin.tensioned, &lin.work] {
                    prop_assert!(st.residual < NONLINEAR_ACCEPT.max(4.0 * st.floor), "{st:?}");
                }
                errs.push(lin.dx_tensioned.relative.max(lin.dx_work.relative));
            }
            // Second-order terms: the relative error shrinks with the load.
            prop_assert!(errs[2] <= 0.2 * errs[0] + 1e-9, "{a:?}: {errs:?}");
            prop_assert!(errs[2] < 1e-3, "{a:?}: {errs:?}");
        }
    }
}

#[test]
fn prototype_linearisation_error_is_small_under_approach_2_and_visible_under_approach_1() {
    let m = Mechanism::new(&prototype()).unwrap();
    let l1 = m.linearisation(Approach::DriveTranslation).unwrap();
    let l2 = m.linearisation(Approach::JointDeflection).unwrap();
    // Approach 1 tilts body 1 by ~8.4 mrad; the second-order terms are of that order.
    assert!(l1.dx_tensioned.relative > 1e-4 && l1.dx_tensioned.relative < 1e-2);
    // Approach 2 leaves body 1 near home: far smaller.
    assert!(l2.dx_tensioned.relative < 0.1 * l1.dx_tensioned.relative);
}
