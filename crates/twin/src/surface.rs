//! A loaded plate's floor: tilted and bowed by a few micrometres per millimetre, as a
//! real dish or slide lies on a feeder, so that the focus differs across the plate.
//!
//! The height is a plane plus a paraboloid about the plate's centre,
//! `h(p) = t · (p − c) + κ |p − c|² / 2`, drawn from the seed (direction and
//! magnitude of the tilt `t`, sign and magnitude of the curvature `κ`), over the
//! plate's extent: beyond its edges the floor keeps the height of the nearest edge
//! (the paraboloid extended tens of millimetres would stand hundreds of micrometres
//! high where the feeder holds no plate). Over a cell
//! (30 µm) a tilt of 3 µm/mm changes the height by 0.1 µm: the floor is flat at a
//! cell's scale, and a cell stands at the height of the floor under its centre.

use cellinject_numeric::Rng;
use cellinject_simparams::FeederParams;

/// The floor's height over the plate, relative to its centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlateSurface {
    /// m, the plate point (plate x, y) where the floor has its nominal height.
    pub centre: [f64; 2],
    /// m/m, the floor's slope along plate x and y.
    pub tilt: [f64; 2],
    /// 1/m, the floor's curvature (positive: it rises away from the centre).
    pub curvature: f64,
    /// m, the plate's extent `[x_lo, y_lo, x_hi, y_hi]`: a point beyond it takes the
    /// height of the nearest point within.
    pub extent: [f64; 4],
}

impl PlateSurface {
    /// A flat floor at the nominal height.
    pub const FLAT: PlateSurface = PlateSurface {
        centre: [0.0; 2],
        tilt: [0.0; 2],
        curvature: 0.0,
        extent: [
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::INFINITY,
        ],
    };

    /// A floor drawn from `rng` for `feeder`'s magnitudes over a plate spanning
    /// `extent` (`[x_lo, y_lo, x_hi, y_hi]`), centred on its centre: the tilt in a
    /// uniform direction with 0.5-1 times `surface_tilt`, the curvature of either sign
    /// with 0.5-1 times `surface_curvature`.
    pub fn draw(feeder: &FeederParams, extent: [f64; 4], rng: &mut Rng) -> Self {
        let centre = [0.5 * (extent[0] + extent[2]), 0.5 * (extent[1] + extent[3])];
        let dir = rng.range(0.0, std::f64::consts::TAU);
        let t = feeder.surface_tilt * rng.range(0.5, 1.0);
        let sign = if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
        let k = sign * feeder.surface_curvature * rng.range(0.5, 1.0);
        PlateSurface {
            centre,
            tilt: [t * dir.cos(), t * dir.sin()],
            curvature: k,
            extent,
        }
    }

    /// m, the floor's height at plate point `p` above its height at the centre.
    pub fn height(&self, p: [f64; 2]) -> f64 {
        let e = self.extent;
        let p = [p[0].clamp(e[0], e[2]), p[1].clamp(e[1], e[3])];
        let d = [p[0] - self.centre[0], p[1] - self.centre[1]];
        self.tilt[0] * d[0]
            + self.tilt[1] * d[1]
            + 0.5 * self.curvature * (d[0] * d[0] + d[1] * d[1])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_drawn_floor_has_the_magnitudes_asked_for_and_its_centre_at_zero() {
        let f = FeederParams::default();
        for seed in 0..50 {
            let s = PlateSurface::draw(&f, [-1e-3, -5e-3, 3e-3, 1e-3], &mut Rng::new(seed, 99));
            let t = s.tilt[0].hypot(s.tilt[1]);
            assert!(
                (0.5 * f.surface_tilt..=f.surface_tilt).contains(&t),
                "{s:?}"
            );
            assert!(
                (0.5 * f.surface_curvature..=f.surface_curvature).contains(&s.curvature.abs()),
                "{s:?}"
            );
            assert_eq!(s.height([1e-3, -2e-3]), 0.0);
            // Symmetric points: the tilt cancels, the bow doubles.
            let (a, b) = (s.height([2e-3, -2e-3]), s.height([0.0, -2e-3]));
            assert!((a + b - s.curvature * 1e-6).abs() < 1e-15, "{a} {b}");
            assert!((a - b - 2.0 * s.tilt[0] * 1e-3).abs() < 1e-15, "{a} {b}");
            // Beyond the plate: the nearest edge's height.
            assert_eq!(s.height([40e-3, -2e-3]), s.height([3e-3, -2e-3]));
            assert_eq!(s.height([-9e-3, -9e-3]), s.height([-1e-3, -5e-3]));
        }
    }
}
