//! # cellinject-flexure
//!
//! Flexure hinges in closed form: the compliances of a notch hinge from the beam
//! integrals of its thickness profile (Euler-Bernoulli bending with Timoshenko shear,
//! Saint-Venant torsion), after Lobontiu, *Compliant Mechanisms: Design of Flexure
//! Hinges* (CRC, 2003), ch. 2; the simplified Paros-Weisbord formula; the stress at the
//! throat with a stress-concentration factor, against the material's yield strength.
//!
//! A hinge lies along x over its length `L`, its in-plane thickness `h(x)` (along y,
//! the compliant direction, smallest `t` at the throat) and its width `b` (along z).
//! Bending about z is the compliant rotation; about y the stiff one.
//!
//! **Architecture invariant:** pure computation: geometry and material in, compliances
//! and stresses out (SI units).

use nalgebra::Matrix6;
use thiserror::Error;

/// Notch profiles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Profile {
    /// Circular notch of radius `radius` (both sides): `h(x) = t + 2R − 2√(R² − x²)`,
    /// `L = 2R`. Valid (as a beam) for roughly `t/R` ≤ 1; Paros & Weisbord (1965).
    Circular {
        /// m, notch radius.
        radius: f64,
    },
    /// Elliptic notch, semi-axis `half_length` along the hinge and `depth` across:
    /// `h(x) = t + 2·depth·(1 − √(1 − (x/a)²))`; Smith et al. (1997), Lobontiu (2003).
    Elliptic {
        /// m, semi-axis along the hinge (a).
        half_length: f64,
        /// m, semi-axis across the hinge (the notch depth).
        depth: f64,
    },
    /// Corner-filleted leaf: a flat of thickness `t` between two fillets of radius
    /// `radius`, total length `length`; Lobontiu et al. (2001).
    CornerFilleted {
        /// m, fillet radius.
        radius: f64,
        /// m, total length (≥ 2·radius).
        length: f64,
    },
    /// Straight leaf of constant thickness.
    Leaf {
        /// m, length.
        length: f64,
    },
}

/// An elastic material.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Pa, Young's modulus.
    pub youngs: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// Pa, yield strength.
    pub yield_strength: f64,
}

impl Material {
    /// The paper's X2CrNi18-9 stainless steel: E = 190 GPa, yield 465 MPa (Sec. 3.1);
    /// ν = 0.3 (typical for austenitic steel, not given by the paper).
    pub fn x2crni18_9() -> Self {
        Material {
            youngs: 190e9,
            poisson: 0.3,
            yield_strength: 465e6,
        }
    }

    /// Shear modulus `E / 2(1 + ν)`.
    pub fn shear(&self) -> f64 {
        self.youngs / (2.0 * (1.0 + self.poisson))
    }
}

/// A hinge: profile, throat thickness, width.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hinge {
    /// Notch profile.
    pub profile: Profile,
    /// m, thickness at the throat.
    pub thickness: f64,
    /// m, width (out of the bending plane).
    pub width: f64,
}

/// What the flexure library refuses.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum FlexureError {
    /// A dimension or material constant out of its domain.
    #[error("{name} = {value}: {reason}")]
    Invalid {
        /// Parameter name (CLI flag or field).
        name: &'static str,
        /// Its value.
        value: f64,
        /// What is wrong.
        reason: String,
    },
    /// The formula does not apply to this profile.
    #[error("{formula} applies to {applies_to} only")]
    NotApplicable {
        /// Formula name.
        formula: &'static str,
        /// Where it applies.
        applies_to: &'static str,
    },
}

fn check(name: &'static str, value: f64) -> Result<(), FlexureError> {
    if !(value.is_finite() && value > 0.0) {
        return Err(FlexureError::Invalid {
            name,
            value,
            reason: "must be a positive number".into(),
        });
    }
    Ok(())
}

impl Hinge {
    /// Validates the dimensions.
    pub fn validate(&self) -> Result<(), FlexureError> {
        check("thickness", self.thickness)?;
        check("width", self.width)?;
        match self.profile {
            Profile::Circular { radius } => check("radius", radius),
            Profile::Elliptic { half_length, depth } => {
                check("length", half_length)?;
                check("radius", depth)
            }
            Profile::CornerFilleted { radius, length } => {
                check("radius", radius)?;
                check("length", length)?;
                if length < 2.0 * radius {
                    return Err(FlexureError::Invalid {
                        name: "length",
                        value: length,
                        reason: format!(
                            "must be at least twice the fillet radius ({})",
                            2.0 * radius
                        ),
                    });
                }
                Ok(())
            }
            Profile::Leaf { length } => check("length", length),
        }
    }

    /// Length of the hinge along x, m.
    pub fn length(&self) -> f64 {
        match self.profile {
            Profile::Circular { radius } => 2.0 * radius,
            Profile::Elliptic { half_length, .. } => 2.0 * half_length,
            Profile::CornerFilleted { length, .. } | Profile::Leaf { length } => length,
        }
    }

    /// In-plane thickness at `x` ∈ [−L/2, L/2].
    pub fn thickness_at(&self, x: f64) -> f64 {
        let t = self.thickness;
        match self.profile {
            Profile::Circular { radius: r } => t + 2.0 * (r - (r * r - x * x).max(0.0).sqrt()),
            Profile::Elliptic {
                half_length: a,
                depth: d,
            } => t + 2.0 * d * (1.0 - (1.0 - (x / a).powi(2)).max(0.0).sqrt()),
            Profile::CornerFilleted { radius: r, length } => {
                let s = x.abs() - (0.5 * length - r);
                if s <= 0.0 {
                    t
                } else {
                    t + 2.0 * (r - (r * r - s * s).max(0.0).sqrt())
                }
            }
            Profile::Leaf { .. } => t,
        }
    }

    /// ∫ f(x, h(x)) dx over the hinge by composite 8-point Gauss-Legendre quadrature
    /// (256 panels per piece), with every curved piece parametrised by its angle
    /// (x = x_c + R·sin φ) so that the integrand is smooth: relative error below 1e-12.
    fn integrate(&self, f: impl Fn(f64, f64) -> f64) -> f64 {
        use std::f64::consts::FRAC_PI_2;
        // Pieces: (angle-parametrised?, centre, radius-or-half-length, φ or u range).
        let mut pieces: Vec<(bool, f64, f64, f64, f64)> = Vec::new();
        match self.profile {
            Profile::Circular { radius } => pieces.push((true, 0.0, radius, -FRAC_PI_2, FRAC_PI_2)),
            Profile::Elliptic { half_length, .. } => {
                pieces.push((true, 0.0, half_length, -FRAC_PI_2, FRAC_PI_2))
            }
            Profile::CornerFilleted { radius, length } => {
                let c = 0.5 * length - radius;
                pieces.push((true, -c, radius, -FRAC_PI_2, 0.0));
                if c > 0.0 {
                    pieces.push((false, 0.0, c, -1.0, 1.0));
                }
                pieces.push((true, c, radius, 0.0, FRAC_PI_2));
            }
            Profile::Leaf { length } => pieces.push((false, 0.0, 0.5 * length, -1.0, 1.0)),
        }
        let mut total = 0.0;
        for (angular, centre, scale, lo, hi) in pieces {
            let g = |u: f64| {
                let (x, dx) = if angular {
                    (centre + scale * u.sin(), scale * u.cos())
                } else {
                    (centre + scale * u, scale)
                };
                f(x, self.thickness_at(x)) * dx
            };
            total += gauss_legendre(&g, lo, hi, 256);
        }
        total
    }

    /// Compliant bending stiffness about z, `k = 1 / (12/E ∫ dx / (b h³))`, N·m/rad.
    pub fn k_bend(&self, m: &Material) -> f64 {
        let b = self.width;
        1.0 / (12.0 / m.youngs * self.integrate(|_, h| 1.0 / (b * h * h * h)))
    }

    /// Bending stiffness about y (the stiff axis), `1 / (12/E ∫ dx / (h b³))`, N·m/rad.
    pub fn k_bend_off(&self, m: &Material) -> f64 {
        let b = self.width;
        1.0 / (12.0 / m.youngs * self.integrate(|_, h| 1.0 / (h * b * b * b)))
    }

    /// Axial stiffness `1 / (1/E ∫ dx / (b h))`, N/m.
    pub fn k_axial(&self, m: &Material) -> f64 {
        let b = self.width;
        1.0 / (self.integrate(|_, h| 1.0 / (b * h)) / m.youngs)
    }

    /// Torsional stiffness about x, `1 / ∫ dx / (G·J(x))` with the rectangle's torsion
    /// constant `J = c·s³·l`, `c = 1/3 − 0.21 (s/l)(1 − (s/l)⁴/12)` (Roark, table 10.7),
    /// s and l the short and long sides. N·m/rad.
    pub fn k_torsion(&self, m: &Material) -> f64 {
        let b = self.width;
        let g = m.shear();
        1.0 / self.integrate(|_, h| {
            let (s, l) = if h < b { (h, b) } else { (b, h) };
            let r = s / l;
            let c = 1.0 / 3.0 - 0.21 * r * (1.0 - r.powi(4) / 12.0);
            1.0 / (g * c * s * s * s * l)
        })
    }

    /// The 6x6 compliance of the hinge at its free end, the other end fixed, in the
    /// order (u_x, u_y, u_z, θ_x, θ_y, θ_z) against (F_x, F_y, F_z, M_x, M_y, M_z):
    /// axial, both shears with bending (Timoshenko, shear factor 6/5), torsion and both
    /// bendings, with the deflection-rotation couplings (Lobontiu 2003, eq. 2.6-2.20).
    pub fn compliance(&self, m: &Material) -> Matrix6<f64> {
        let (e, g, b) = (m.youngs, m.shear(), self.width);
        let half = 0.5 * self.length();
        // Lever from the section at x to the free end at +L/2.
        let lever = |x: f64| half - x;
        let alpha = 1.2;
        let iz0 = self.integrate(|_, h| 12.0 / (b * h * h * h));
        let iz1 = self.integrate(|x, h| 12.0 * lever(x) / (b * h * h * h));
        let iz2 = self.integrate(|x, h| 12.0 * lever(x).powi(2) / (b * h * h * h));
        let iy0 = self.integrate(|_, h| 12.0 / (h * b * b * b));
        let iy1 = self.integrate(|x, h| 12.0 * lever(x) / (h * b * b * b));
        let iy2 = self.integrate(|x, h| 12.0 * lever(x).powi(2) / (h * b * b * b));
        let area = self.integrate(|_, h| 1.0 / (b * h));
        let mut c = Matrix6::zeros();
        c[(0, 0)] = area / e;
        c[(1, 1)] = iz2 / e + alpha * area / g;
        c[(2, 2)] = iy2 / e + alpha * area / g;
        c[(3, 3)] = 1.0 / self.k_torsion(m);
        c[(4, 4)] = iy0 / e;
        c[(5, 5)] = iz0 / e;
        // u_y with M_z and θ_z with F_y: rotation about z by F_y at the lever.
        c[(1, 5)] = iz1 / e;
        c[(5, 1)] = iz1 / e;
        // u_z with M_y (opposite sign: a positive M_y tilts the end towards −z).
        c[(2, 4)] = -iy1 / e;
        c[(4, 2)] = -iy1 / e;
        c
    }

    /// Radius of curvature of the notch at the throat, m (infinite for a leaf).
    pub fn throat_radius(&self) -> f64 {
        match self.profile {
            Profile::Circular { radius } => radius,
            Profile::Elliptic {
                half_length: a,
                depth: d,
            } => a * a / d,
            Profile::CornerFilleted { radius, .. } => radius,
            Profile::Leaf { .. } => f64::INFINITY,
        }
    }

    /// Stress-concentration factor at the throat, `K_t = (1 + t/(2ρ))^(9/20)` with ρ the
    /// notch radius there (Smith, Badami, Dale & Xu, Rev. Sci. Instrum. 68, 1997; Pilkey,
    /// *Peterson's Stress Concentration Factors*). 1 for a leaf.
    pub fn stress_concentration(&self) -> f64 {
        let rho = self.throat_radius();
        if rho.is_infinite() {
            1.0
        } else {
            (1.0 + self.thickness / (2.0 * rho)).powf(0.45)
        }
    }

    /// Largest bending stress per radian of compliant rotation, Pa/rad:
    /// `K_t · 6·k_bend / (b t²)`.
    pub fn max_stress_per_rad(&self, m: &Material) -> f64 {
        self.stress_concentration() * 6.0 * self.k_bend(m) / (self.width * self.thickness.powi(2))
    }

    /// The largest rotation before yield, rad.
    pub fn max_rotation(&self, m: &Material) -> f64 {
        m.yield_strength / self.max_stress_per_rad(m)
    }
}

/// Simplified Paros-Weisbord stiffness of a circular notch, `2 E b t^(5/2) / (9π √R)`,
/// accurate for t ≪ R (Paros & Weisbord, Machine Design 37, 1965).
pub fn paros_weisbord_simplified(h: &Hinge, m: &Material) -> Result<f64, FlexureError> {
    match h.profile {
        Profile::Circular { radius } => Ok(2.0 * m.youngs * h.width * h.thickness.powf(2.5)
            / (9.0 * std::f64::consts::PI * radius.sqrt())),
        _ => Err(FlexureError::NotApplicable {
            formula: "the simplified Paros-Weisbord formula",
            applies_to: "circular notches",
        }),
    }
}

/// Composite 8-point Gauss-Legendre quadrature over `panels` equal panels.
fn gauss_legendre(f: &impl Fn(f64) -> f64, a: f64, b: f64, panels: usize) -> f64 {
    const X: [f64; 4] = [
        0.183_434_642_495_649_8,
        0.525_532_409_916_329,
        0.796_666_477_413_626_7,
        0.960_289_856_497_536_3,
    ];
    const W: [f64; 4] = [
        0.362_683_783_378_362,
        0.313_706_645_877_887_3,
        0.222_381_034_453_374_5,
        0.101_228_536_290_376_3,
    ];
    let h = (b - a) / panels as f64;
    let mut sum = 0.0;
    for p in 0..panels {
        let mid = a + (p as f64 + 0.5) * h;
        let half = 0.5 * h;
        for k in 0..4 {
            sum += W[k] * (f(mid - half * X[k]) + f(mid + half * X[k]));
        }
    }
    sum * 0.5 * h
}

#[cfg(test)]
mod tests {
    use super::*;

    fn circ(t: f64, r: f64) -> Hinge {
        Hinge {
            profile: Profile::Circular { radius: r },
            thickness: t,
            width: 5e-3,
        }
    }

    /// Independent check: composite Simpson in x (not in the angle) with a fine grid.
    fn plain_simpson(h: &Hinge, n: usize) -> f64 {
        let half = 0.5 * h.length();
        let dx = 2.0 * half / n as f64;
        let f = |x: f64| 1.0 / (h.width * h.thickness_at(x).powi(3));
        let mut s = f(-half) + f(half);
        for i in 1..n {
            let x = -half + i as f64 * dx;
            s += if i % 2 == 1 { 4.0 } else { 2.0 } * f(x);
        }
        s * dx / 3.0
    }

    #[test]
    fn beam_integral_matches_an_independent_quadrature_to_0_1_percent() {
        let m = Material::x2crni18_9();
        for t_over_r in [0.05, 0.1, 0.3, 0.5, 1.0] {
            let h = circ(t_over_r * 2e-3, 2e-3);
            let independent = 1.0 / (12.0 / m.youngs * plain_simpson(&h, 100_000));
            let k = h.k_bend(&m);
            assert!(
                (k / independent - 1.0).abs() < 1e-3,
                "t/R {t_over_r}: {k} vs {independent}"
            );
        }
    }

    #[test]
    fn simplified_paros_weisbord_converges_to_the_beam_integral_for_thin_notches() {
        let m = Material::x2crni18_9();
        let ratio = |tr: f64| {
            let h = circ(tr * 2e-3, 2e-3);
            paros_weisbord_simplified(&h, &m).unwrap() / h.k_bend(&m)
        };
        assert!((ratio(0.002) - 1.0).abs() < 0.02, "{}", ratio(0.002));
        assert!((ratio(0.002) - 1.0).abs() < (ratio(0.5) - 1.0).abs());
    }

    #[test]
    fn leaf_and_composite_profiles_equal_their_closed_forms() {
        let m = Material::x2crni18_9();
        let (t, b, l, r) = (0.3e-3, 4e-3, 6e-3, 1e-3);
        let leaf = Hinge {
            profile: Profile::Leaf { length: l },
            thickness: t,
            width: b,
        };
        let exact = m.youngs * b * t.powi(3) / (12.0 * l);
        assert!((leaf.k_bend(&m) / exact - 1.0).abs() < 1e-10);
        assert!((leaf.k_axial(&m) / (m.youngs * b * t / l) - 1.0).abs() < 1e-10);
        // Corner-filleted: flat part in series with a circular notch of the fillet radius.
        let cf = Hinge {
            profile: Profile::CornerFilleted {
                radius: r,
                length: l,
            },
            thickness: t,
            width: b,
        };
        let c_circ = 1.0 / circ(t, r).with_width(b).k_bend(&m);
        let c_expected = 12.0 * (l - 2.0 * r) / (m.youngs * b * t.powi(3)) + c_circ;
        assert!((cf.k_bend(&m) * c_expected - 1.0).abs() < 1e-8);
        // Elliptic: a circular notch stretched by a/depth along x.
        let el = Hinge {
            profile: Profile::Elliptic {
                half_length: 3e-3,
                depth: 1e-3,
            },
            thickness: t,
            width: b,
        };
        let c_el = 3.0 / circ(t, 1e-3).with_width(b).k_bend(&m);
        assert!((el.k_bend(&m) * c_el - 1.0).abs() < 1e-8);
    }

    #[test]
    fn compliance_is_symmetric_positive_definite_and_consistent() {
        let m = Material::x2crni18_9();
        let h = circ(0.5e-3, 1.5e-3);
        let c = h.compliance(&m);
        assert!((c - c.transpose()).norm() < 1e-12 * c.norm());
        assert!(c.cholesky().is_some());
        assert!((1.0 / c[(5, 5)] / h.k_bend(&m) - 1.0).abs() < 1e-12);
        assert!((1.0 / c[(4, 4)] / h.k_bend_off(&m) - 1.0).abs() < 1e-12);
        // The throat is far thinner than the width: bending about z is the soft one.
        assert!(h.k_bend(&m) < 0.1 * h.k_bend_off(&m));
    }

    #[test]
    fn stress_and_yield() {
        let m = Material::x2crni18_9();
        let h = circ(0.5e-3, 1.5e-3);
        let kt = h.stress_concentration();
        assert!(kt > 1.0 && kt < 1.2);
        let s = h.max_stress_per_rad(&m);
        assert!((s * h.max_rotation(&m) - m.yield_strength).abs() < 1e-6 * m.yield_strength);
        assert!(h.validate().is_ok());
        let bad = Hinge {
            thickness: -1.0,
            ..h
        };
        assert!(bad.validate().is_err());
        let leaf = Hinge {
            profile: Profile::Leaf { length: 1e-3 },
            ..h
        };
        assert!(paros_weisbord_simplified(&leaf, &m).is_err());
    }

    impl Hinge {
        fn with_width(mut self, b: f64) -> Self {
            self.width = b;
            self
        }
    }
}
