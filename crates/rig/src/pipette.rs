//! The injection pipette as the bench knows it: the orifice the puller made, the
//! solution's viscosity and the dye, and the flow they give (pressure, tip, time →
//! volume); the glass's outer shape and the angle it is mounted at, and the clearance
//! between that shape and a cell.
//!
//! Frame: the plate's. `x` and `z` lie in the plate's plane (the microscope's columns
//! and rows), `y` is height above the focal plane (up, towards the objective). The
//! pipette comes from `-z` and from above: A3 drives the tip along
//! [`PipetteParams::axis`], `(0, -sin a, cos a)` for the mount angle `a` to the plate.

/// The mounted pipette and the injected solution (`[injector]` keys
/// `tip_inner_diameter`, `cone_half_angle`, `viscosity`, `dye_contrast`,
/// `pipette_angle`, `tip_outer_radius`, `outer_taper`, `shank_radius`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PipetteParams {
    /// rad, the angle between the pipette's axis (A3's axis) and the plate's plane:
    /// 0 in the plate's plane, π/2 straight down the optical axis.
    pub angle: f64,
    /// m, the glass's outer radius at the tip.
    pub tip_outer_radius: f64,
    /// Growth of the outer radius per metre behind the tip (tan of the outer taper's
    /// half-angle).
    pub outer_taper: f64,
    /// m, outer radius of the shank (where the taper ends).
    pub shank_radius: f64,
    /// m, inner diameter of the orifice.
    pub inner_diameter: f64,
    /// rad, half-angle of the conical taper behind the orifice.
    pub cone_half_angle: f64,
    /// Pa·s, dynamic viscosity of the injected solution.
    pub viscosity: f64,
    /// Darkening of a cell's cytoplasm per unit injected volume fraction (the dye's
    /// absorbance in the cell: 0.8 makes a 5 % dose darken the cytoplasm by 0.04).
    pub dye_contrast: f64,
}

impl Default for PipetteParams {
    fn default() -> Self {
        PipetteParams {
            // 55°: between the 30-45° real injection rigs use and the paper's Z axis
            // (90°, where the microscope would look down the pipette and no longer see
            // the tip approach the cell). Steeper passes over more touching
            // neighbours: on a 20 x 30 doublet-rich plate (seed 2) 45° skipped 9 cells
            // a partner blocked, 52° 4, 56° 2, 60° none; but the tip lands less
            // precisely as the glass is seen more foreshortened (mean tip error 0.38,
            // 0.44, 0.45, 0.51 um).
            angle: 55.0 * std::f64::consts::PI / 180.0,
            tip_outer_radius: 0.5e-6,
            outer_taper: 0.12,
            shank_radius: 45e-6,
            inner_diameter: 0.2e-6,
            cone_half_angle: 0.05,
            viscosity: 1.0e-3,
            dye_contrast: 0.8,
        }
    }
}

impl PipetteParams {
    /// Hydraulic conductance of the tip, m³/(s·Pa): Poiseuille flow through a slender
    /// cone, dominated by its narrowest part, `G = 3π r³ tan θ / (8 μ)` with r the
    /// orifice's inner radius and θ the cone's half-angle (integrating
    /// `dP/dx = 8 μ Q / (π r(x)⁴)` along `r(x) = r + x tan θ`).
    pub fn conductance(&self) -> f64 {
        let r = 0.5 * self.inner_diameter;
        3.0 * std::f64::consts::PI * r.powi(3) * self.cone_half_angle.tan() / (8.0 * self.viscosity)
    }

    /// The pulse duration that delivers `volume` (m³) at gauge `pressure` (Pa), s.
    pub fn duration_for(&self, volume: f64, pressure: f64) -> f64 {
        volume / (self.conductance() * pressure)
    }

    /// Unit vector along which A3 drives the tip forward, in the plate's frame
    /// (x, y up, z): `(0, -sin a, cos a)`.
    pub fn axis(&self) -> [f64; 3] {
        [0.0, -self.angle.sin(), self.angle.cos()]
    }

    /// m, the glass's outer radius `s` metres behind the tip (along the axis).
    pub fn radius_at(&self, s: f64) -> f64 {
        (self.tip_outer_radius + self.outer_taper * s.max(0.0)).min(self.shank_radius)
    }

    /// m, clearance between the pipette with its tip at `tip` pointing forward along
    /// the unit vector `axis`, and the sphere at `centre` of `radius`: the distance from
    /// the sphere to the glass (a cone of radius [`Self::radius_at`] behind a flat tip,
    /// then the shank, endless behind), negative when they overlap. The solid is convex
    /// and of revolution, so the nearest point lies in the meridian half-plane through
    /// the centre: the distance is that of the point (s, ρ) to the profile polygon
    /// (s ≥ 0, ρ ≤ r0 + k s, ρ ≤ R).
    pub fn clearance(&self, tip: [f64; 3], axis: [f64; 3], centre: [f64; 3], radius: f64) -> f64 {
        let d = [centre[0] - tip[0], centre[1] - tip[1], centre[2] - tip[2]];
        // Behind the tip: positive s.
        let s = -(d[0] * axis[0] + d[1] * axis[1] + d[2] * axis[2]);
        let p = [d[0] + s * axis[0], d[1] + s * axis[1], d[2] + s * axis[2]];
        let rho = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        profile_distance(
            s,
            rho,
            self.tip_outer_radius,
            self.outer_taper,
            self.shank_radius,
        ) - radius
    }
}

/// Signed distance of the meridian point (s, ρ ≥ 0) to the region s ≥ 0,
/// ρ ≤ min(r0 + k s, big_r): negative inside.
fn profile_distance(s: f64, rho: f64, r0: f64, k: f64, big_r: f64) -> f64 {
    let s1 = ((big_r - r0) / k).max(0.0);
    let norm = (1.0 + k * k).sqrt();
    let inside = s >= 0.0 && rho <= (r0 + k * s).min(big_r);
    if inside {
        let to_cone = (r0 + k * s - rho) / norm;
        return -(s.min(to_cone).min(big_r - rho));
    }
    let seg = |a: [f64; 2], b: [f64; 2]| {
        let (vx, vy) = (b[0] - a[0], b[1] - a[1]);
        let l2 = vx * vx + vy * vy;
        let t = if l2 > 0.0 {
            (((s - a[0]) * vx + (rho - a[1]) * vy) / l2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (s - a[0] - t * vx).hypot(rho - a[1] - t * vy)
    };
    // The flat tip, the cone, the shank (a ray).
    let tip = seg([0.0, 0.0], [0.0, r0]);
    let cone = seg([0.0, r0], [s1, big_r]);
    let shank = if s >= s1 {
        (rho - big_r).abs()
    } else {
        (s - s1).hypot(rho - big_r)
    };
    tip.min(cone).min(shank)
}

/// Volume of a spherical cell of diameter `d`, m³.
pub fn cell_volume(d: f64) -> f64 {
    std::f64::consts::PI / 6.0 * d.powi(3)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conductance_is_the_integral_of_poiseuille_along_the_cone() {
        // Independent check: sum 8 μ dx / (π r(x)^4) numerically along a long cone.
        let p = PipetteParams::default();
        let (r0, t) = (0.5 * p.inner_diameter, p.cone_half_angle.tan());
        let mut resistance = 0.0;
        let n = 200_000;
        let length = 2e-3;
        for k in 0..n {
            // Geometric spacing: fine near the orifice where the resistance sits.
            let x0 = r0 / t * ((1.0 + length * t / r0).powf(k as f64 / n as f64) - 1.0);
            let x1 = r0 / t * ((1.0 + length * t / r0).powf((k + 1) as f64 / n as f64) - 1.0);
            let r = r0 + 0.5 * (x0 + x1) * t;
            resistance += 8.0 * p.viscosity * (x1 - x0) / (std::f64::consts::PI * r.powi(4));
        }
        let g = p.conductance();
        assert!(
            (g * resistance - 1.0).abs() < 1e-3,
            "{g:e} vs {:e}",
            1.0 / resistance
        );
    }

    /// Independent: the smallest distance from the sphere's centre to points sampled
    /// on the glass's surface (cone, shank and flat tip), minus the radius.
    fn sampled_clearance(
        p: &PipetteParams,
        tip: [f64; 3],
        axis: [f64; 3],
        c: [f64; 3],
        r: f64,
    ) -> f64 {
        // Two unit vectors across the axis.
        let e1 = {
            let t = if axis[0].abs() < 0.9 {
                [1.0, 0.0, 0.0]
            } else {
                [0.0, 1.0, 0.0]
            };
            let d = t[0] * axis[0] + t[1] * axis[1] + t[2] * axis[2];
            let v = [t[0] - d * axis[0], t[1] - d * axis[1], t[2] - d * axis[2]];
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            [v[0] / n, v[1] / n, v[2] / n]
        };
        let e2 = [
            axis[1] * e1[2] - axis[2] * e1[1],
            axis[2] * e1[0] - axis[0] * e1[2],
            axis[0] * e1[1] - axis[1] * e1[0],
        ];
        let mut best = f64::INFINITY;
        let mut at = |s: f64, rho: f64, phi: f64| {
            let (cs, sn) = (phi.cos(), phi.sin());
            let q = [0, 1, 2].map(|i| tip[i] - s * axis[i] + rho * (cs * e1[i] + sn * e2[i]));
            let d = ((q[0] - c[0]).powi(2) + (q[1] - c[1]).powi(2) + (q[2] - c[2]).powi(2)).sqrt();
            best = best.min(d);
        };
        let n_phi = 720;
        for j in 0..n_phi {
            let phi = j as f64 / n_phi as f64 * std::f64::consts::TAU;
            for k in 0..=4000 {
                let s = k as f64 * 0.05e-6;
                at(s, p.radius_at(s), phi);
            }
            for k in 0..=10 {
                at(0.0, p.tip_outer_radius * k as f64 / 10.0, phi);
            }
        }
        best - r
    }

    #[test]
    fn clearance_matches_distances_sampled_on_the_glass() {
        let p = PipetteParams {
            shank_radius: 5e-6,
            ..PipetteParams::default()
        };
        let axis = p.axis();
        let tip = [1e-6, 2e-6, -3e-6];
        // Spheres beside, behind (over the cone and the shank) and ahead of the tip.
        for (c, r) in [
            ([10e-6, 2e-6, -3e-6], 4e-6),
            ([0.0, 20e-6, -30e-6], 8e-6),
            ([3e-6, 40e-6, -60e-6], 6e-6),
            ([1e-6, -6e-6, 5e-6], 3e-6),
            ([-4e-6, 9e-6, -9e-6], 7e-6),
        ] {
            let closed = p.clearance(tip, axis, c, r);
            let sampled = sampled_clearance(&p, tip, axis, c, r);
            if sampled > 0.0 {
                assert!(
                    (closed - sampled).abs() < 0.03e-6,
                    "{c:?}: {closed:e} vs {sampled:e}"
                );
            } else {
                // Overlap: the sampled surface distance is the penetration's size.
                assert!(closed < 0.0, "{c:?}: {closed:e} vs {sampled:e}");
            }
        }
    }

    #[test]
    fn a_pulse_delivers_the_volume_asked_for() {
        let p = PipetteParams::default();
        let v = 0.05 * cell_volume(18e-6);
        let t = p.duration_for(v, 2e4);
        assert!((p.conductance() * 2e4 * t - v).abs() < 1e-12 * v);
        // Default pipette: a 5 % dose of an 18 um cell at 20 kPa takes 0.1-1 s.
        assert!((0.05..1.0).contains(&t), "{t}");
    }
}
