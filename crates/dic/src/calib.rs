//! Image-space calibration (paper Sec. 4: the stage's 0.1 µm encoders calibrate the image
//! space): from frames taken at known stage moves, fit the linear map from stage
//! displacement (m) to image displacement (pixels), `p = A s`, by least squares, and
//! decompose it into scale, rotation and skew with standard errors.

use nalgebra::{Matrix2, Vector2};

use crate::DicError;

/// A fitted pixel-to-metre mapping.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// Pixels per metre of stage motion: `pixels = A · metres`.
    pub a: Matrix2<f64>,
    /// Standard errors of the entries of `A`.
    pub a_std: Matrix2<f64>,
    /// Metres per pixel along the image x and y axes (columns of `A⁻¹`'s norms).
    pub scale: [f64; 2],
    /// Relative standard error of the scale.
    pub scale_rel_std: [f64; 2],
    /// Rotation of the stage axes in the image, rad.
    pub rotation: f64,
    /// Shear between the axes, rad (0 for perpendicular axes).
    pub skew: f64,
    /// RMS residual of the fit, pixels.
    pub rms: f64,
}

impl Calibration {
    /// Fits the map from pairs of stage moves (m) and measured image displacements (px).
    pub fn fit(stage: &[[f64; 2]], pixels: &[[f64; 2]]) -> Result<Self, DicError> {
        let n = stage.len();
        if n != pixels.len() || n < 3 {
            return Err(DicError::Calibration {
                reason: format!(
                    "needs at least 3 pairs of moves and displacements, got {n} and {}",
                    pixels.len()
                ),
            });
        }
        let mut sts = Matrix2::zeros();
        for s in stage {
            let v = Vector2::from(*s);
            sts += v * v.transpose();
        }
        let inv = sts
            .try_inverse()
            .filter(|m| m.iter().all(|v| v.is_finite()))
            .ok_or_else(|| DicError::Calibration {
                reason: "the stage moves do not span two directions".into(),
            })?;
        let mut a = Matrix2::zeros();
        for row in 0..2 {
            let mut stp = Vector2::zeros();
            for (s, p) in stage.iter().zip(pixels) {
                stp += Vector2::from(*s) * p[row];
            }
            let coef = inv * stp;
            a[(row, 0)] = coef[0];
            a[(row, 1)] = coef[1];
        }
        let mut ss = 0.0;
        for (s, p) in stage.iter().zip(pixels) {
            let r = Vector2::from(*p) - a * Vector2::from(*s);
            ss += r.norm_squared();
        }
        let dof = (2 * n - 4).max(1) as f64;
        let var = ss / dof;
        let a_std = Matrix2::new(
            (var * inv[(0, 0)]).sqrt(),
            (var * inv[(1, 1)]).sqrt(),
            (var * inv[(0, 0)]).sqrt(),
            (var * inv[(1, 1)]).sqrt(),
        );
        // A = R(θ) · [[kx, kx·tan(skew)], [0, ky]] (QR with positive diagonal).
        let c0 = Vector2::new(a[(0, 0)], a[(1, 0)]);
        let kx = c0.norm();
        let rotation = c0[1].atan2(c0[0]);
        let (sn, cs) = rotation.sin_cos();
        let r_t = Matrix2::new(cs, sn, -sn, cs);
        let upper = r_t * a;
        let ky = upper[(1, 1)];
        let skew = (upper[(0, 1)] / ky).atan();
        Ok(Calibration {
            a,
            a_std,
            scale: [1.0 / kx, 1.0 / ky.abs()],
            scale_rel_std: [a_std[(0, 0)] / kx, a_std[(1, 1)] / ky.abs()],
            rotation,
            skew,
            rms: (ss / n as f64).sqrt(),
        })
    }

    /// Converts an image displacement (px) into a stage-frame displacement (m).
    pub fn to_metres(&self, pixels: [f64; 2]) -> Option<[f64; 2]> {
        let m = self.a.try_inverse()? * Vector2::from(pixels);
        Some([m[0], m[1]])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_scale_rotation_and_skew_from_noisy_moves() {
        // 0.22 µm/px, 1.5° rotation, 0.2° skew, 0.01 px noise on the displacements.
        let (kx, ky, th, sk): (f64, f64, f64, f64) = (
            1.0 / 0.22e-6,
            1.0 / 0.221e-6,
            1.5f64.to_radians(),
            0.2f64.to_radians(),
        );
        let (sn, cs) = th.sin_cos();
        let a = Matrix2::new(cs, -sn, sn, cs) * Matrix2::new(kx, kx * sk.tan(), 0.0, ky);
        let mut stage = Vec::new();
        let mut px = Vec::new();
        let mut k = 0u64;
        for i in -3i32..=3 {
            for j in -3i32..=3 {
                let s = [i as f64 * 5e-6, j as f64 * 5e-6];
                let p = a * Vector2::from(s);
                k = k
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let e1 = ((k >> 33) as f64 / (1u64 << 31) as f64 - 0.5) * 0.02;
                let e2 = ((k >> 11 & 0xFFFF) as f64 / 65536.0 - 0.5) * 0.02;
                stage.push(s);
                px.push([p[0] + e1, p[1] + e2]);
            }
        }
        let c = Calibration::fit(&stage, &px).unwrap();
        assert!((c.scale[0] / 0.22e-6 - 1.0).abs() < 1e-3, "{:?}", c.scale);
        assert!((c.scale[1] / 0.221e-6 - 1.0).abs() < 1e-3);
        assert!((c.rotation - th).abs() < 1e-3);
        assert!((c.skew - sk).abs() < 1e-3);
        assert!(c.rms < 0.02 && c.scale_rel_std[0] < 1e-3);
        let back = c.to_metres([kx * 1e-6, 0.0]).unwrap();
        assert!(back[0] > 0.0);
        assert!(Calibration::fit(&stage[..2], &px[..2]).is_err());
        let colinear: Vec<[f64; 2]> = (0..5).map(|i| [i as f64 * 1e-6, 0.0]).collect();
        assert!(Calibration::fit(&colinear, &px[..5]).is_err());
    }
}
