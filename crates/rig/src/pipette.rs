//! The injection pipette as the bench knows it: the orifice the puller made, the
//! solution's viscosity and the dye, and the flow they give (pressure, tip, time →
//! volume).

/// The mounted pipette and the injected solution (`[injector]` keys
/// `tip_inner_diameter`, `cone_half_angle`, `viscosity`, `dye_contrast`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PipetteParams {
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
