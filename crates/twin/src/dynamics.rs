//! Rigid-body dynamics of body 1 on its flexures and of the injection axis, integrated
//! exactly (zero-order hold) at a fixed step.
//!
//! Tilt axes: `M q̈ + C q̇ + K q = f(t)` with `M = diag(I1, I2)` about J3,
//! `K = Kq + Wᵀ Kw W + Lᵀ Kl L` (the flexures and the stacks in series with the
//! mechanism) and `f = Kq q_r + Lᵀ Kl l_r(t)`, where `q_r` is J3's unstressed angle
//! (−Δq0 under approach 2) and `l_r` the drives' imposed displacement (Δl0 + Δl2 under
//! approach 1, Δl2 under approach 2). At rest, `K q = f` is exactly the equilibrium (19)
//! with `Fq = Kq (q − q_r)`, `Fw = Kw W q`, `F = Kl (l_r − L q)`: the quasi-static model of
//! the mechanism crate. The system is decoupled into modes (`K φ = ω² M φ`) with modal
//! damping ratio ζ; each mode is advanced by its exact transition matrix, so the step
//! size affects only how often the input is sampled, never stability.

use nalgebra::{Matrix2, SymmetricEigen, Vector2};

/// A damped oscillator `ẍ + 2ζω ẋ + ω² x = g`, advanced exactly for `g` held over a step.
#[derive(Debug, Clone, Copy)]
pub struct Oscillator {
    phi: [[f64; 2]; 2],
    omega2: f64,
    /// Position.
    pub x: f64,
    /// Velocity.
    pub v: f64,
}

impl Oscillator {
    /// An oscillator of angular frequency `omega` and damping ratio `zeta` (< 1), at rest at 0.
    pub fn new(omega: f64, zeta: f64, dt: f64) -> Self {
        let sigma = zeta * omega;
        let wd = omega * (1.0 - zeta * zeta).sqrt();
        let e = (-sigma * dt).exp();
        let (s, c) = (wd * dt).sin_cos();
        Oscillator {
            phi: [
                [e * (c + sigma / wd * s), e * s / wd],
                [-e * omega * omega / wd * s, e * (c - sigma / wd * s)],
            ],
            omega2: omega * omega,
            x: 0.0,
            v: 0.0,
        }
    }

    /// Advances one step under the generalised force `g`.
    #[inline]
    pub fn step(&mut self, g: f64) {
        let eq = g / self.omega2;
        let xi = self.x - eq;
        let x = self.phi[0][0] * xi + self.phi[0][1] * self.v;
        let v = self.phi[1][0] * xi + self.phi[1][1] * self.v;
        self.x = x + eq;
        self.v = v;
    }

    /// Places the oscillator at its equilibrium under `g`, at rest.
    pub fn settle(&mut self, g: f64) {
        self.x = g / self.omega2;
        self.v = 0.0;
    }
}

/// The two tilt modes of body 1.
#[derive(Debug, Clone)]
pub struct TiltDynamics {
    /// Natural angular frequencies of the modes, rad/s.
    pub omega: [f64; 2],
    modes: [Oscillator; 2],
    /// q = shape · η.
    shape: Matrix2<f64>,
    /// g = load · f.
    load: Matrix2<f64>,
}

impl TiltDynamics {
    /// Modes of `M = diag(inertia)` and stiffness `k` (symmetric positive definite).
    pub fn new(inertia: [f64; 2], k: &Matrix2<f64>, zeta: f64, dt: f64) -> Self {
        let m_inv_sqrt = Matrix2::from_diagonal(&Vector2::new(
            1.0 / inertia[0].sqrt(),
            1.0 / inertia[1].sqrt(),
        ));
        let a = m_inv_sqrt * k * m_inv_sqrt;
        let a = 0.5 * (a + a.transpose());
        let eig = SymmetricEigen::new(a);
        let omega = [eig.eigenvalues[0].sqrt(), eig.eigenvalues[1].sqrt()];
        let v = eig.eigenvectors;
        TiltDynamics {
            omega,
            modes: [
                Oscillator::new(omega[0], zeta, dt),
                Oscillator::new(omega[1], zeta, dt),
            ],
            shape: m_inv_sqrt * v,
            load: v.transpose() * m_inv_sqrt,
        }
    }

    /// Advances one step under the generalised forces `f` (N·m).
    #[inline]
    pub fn step(&mut self, f: &Vector2<f64>) {
        let g = self.load * f;
        self.modes[0].step(g[0]);
        self.modes[1].step(g[1]);
    }

    /// Puts the body at rest in equilibrium under `f`.
    pub fn settle(&mut self, f: &Vector2<f64>) {
        let g = self.load * f;
        self.modes[0].settle(g[0]);
        self.modes[1].settle(g[1]);
    }

    /// Joint angles q1, q2.
    #[inline]
    pub fn q(&self) -> Vector2<f64> {
        self.shape * Vector2::new(self.modes[0].x, self.modes[1].x)
    }

    /// Joint rates q̇1, q̇2.
    #[inline]
    pub fn q_dot(&self) -> Vector2<f64> {
        self.shape * Vector2::new(self.modes[0].v, self.modes[1].v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn oscillator_matches_the_closed_form_step_response() {
        // Unit step from rest: x(t) = 1 − e^{−σt}(cos ω_d t + σ/ω_d sin ω_d t).
        let (w, z, dt) = (2.0 * std::f64::consts::PI * 700.0, 0.02, 5e-5);
        let mut o = Oscillator::new(w, z, dt);
        let g = w * w;
        let sigma = z * w;
        let wd = w * (1.0 - z * z).sqrt();
        for n in 1..=400 {
            o.step(g);
            let t = n as f64 * dt;
            let x = 1.0 - (-sigma * t).exp() * ((wd * t).cos() + sigma / wd * (wd * t).sin());
            assert!((o.x - x).abs() < 1e-12, "step {n}: {} vs {x}", o.x);
        }
    }

    #[test]
    fn tilt_modes_are_the_generalised_eigenvalues() {
        let k = Matrix2::new(25_000.0, 300.0, 300.0, 18_000.0);
        let d = TiltDynamics::new([1.0e-3, 2.0e-3], &k, 0.02, 5e-5);
        // det(K − ω² M) = 0, solved independently as a quadratic in λ = ω².
        let (m1, m2) = (1.0e-3, 2.0e-3);
        let a = m1 * m2;
        let b = -(k[(0, 0)] * m2 + k[(1, 1)] * m1);
        let c = k[(0, 0)] * k[(1, 1)] - k[(0, 1)] * k[(1, 0)];
        let disc = (b * b - 4.0 * a * c).sqrt();
        let mut l = [(-b - disc) / (2.0 * a), (-b + disc) / (2.0 * a)];
        l.sort_by(f64::total_cmp);
        let mut got = [d.omega[0].powi(2), d.omega[1].powi(2)];
        got.sort_by(f64::total_cmp);
        for i in 0..2 {
            assert!((got[i] / l[i] - 1.0).abs() < 1e-12);
        }
        // A settled body satisfies K q = f.
        let mut d = d;
        let f = Vector2::new(1.5, -0.7);
        d.settle(&f);
        assert!((k * d.q() - f).norm() < 1e-12 * f.norm());
    }
}
