//! The noise's share of a match's uncertainty: the image noise's covariance through the
//! spline and the gradients, line by line ([`corrected`]).

use super::*;

/// The noise part of a match's covariance (u, v), from the residuals at the solution,
/// and the residual variance used (at least the floor). See [`PointResult::sigma_u`].
#[inline(always)]
pub(super) fn noise_covariance(
    prepared: &Prepared,
    residuals: &[f64],
    residual2: f64,
    opts: &IcgnOptions,
    gain: f64,
    scratch: &mut Sandwich,
) -> ((f64, f64), f64) {
    let Prepared {
        rs,
        subset,
        shape,
        info,
        degree,
        ..
    } = prepared;
    // Noise from the residual: it holds the noise of both images, 2σ². Degrees of
    // freedom: the shape parameters, offset and gain.
    let n = rs.f.len();
    let params = match shape {
        Shape::Affine => 8.0,
        Shape::Rigid => 4.0,
    };
    let dof = (n as f64 - params).max(1.0);
    let var = (residual2 / dof / gain).max(opts.residual_floor);
    // The reference's noise (half the residual's variance) in its gradients.
    let nu = 0.5 * var * degree.derivative_noise_gain();
    let nw = 2 * subset.half_w + 1;
    let Sandwich { scores_u, scores_v } = scratch;
    // The sandwich `A_s⁻¹ B A_s⁻¹` at u and v: the scores of its projections, then
    // the meat (see [`meat`]), scaled so that the residuals' mean square is
    // `var`; without residual, the white-noise `var·A`.
    let scale = n as f64 * var / residual2;
    let [f, gx, gy, dx, dy] = rs.slices();
    let residuals = &residuals[..n];
    let nh = n / nw;
    let stride = padded_scores(scores_u, nw, nh);
    padded_scores(scores_v, nw, nh);
    let (su, sv) = (&mut scores_u[..], &mut scores_v[..]);
    let white = match info {
        Information::Affine(a) => {
            // Σ wwᵀ over a centred subset, w = (1, dx, dy): diagonal.
            let mut noise = SMatrix::<f64, 8, 8>::zeros();
            for (i, m) in rs.moments.iter().enumerate() {
                noise[(i, i)] = nu * m;
                noise[(3 + i, 3 + i)] = nu * m;
            }
            let Some((zu, zv)) = projections(a, &noise, 3) else {
                return ((f64::INFINITY, f64::INFINITY), var);
            };
            fill_padded(
                (su, sv),
                (nw, nh, stride),
                #[inline(always)]
                |k| {
                    let (gx, gy, dx, dy, f, r) = (gx[k], gy[k], dx[k], dy[k], f[k], residuals[k]);
                    let score = |z: &[f64; 8]| {
                        r * (gx * (z[0] + z[1] * dx + z[2] * dy)
                            + gy * (z[3] + z[4] * dx + z[5] * dy)
                            + z[6]
                            + z[7] * f)
                    };
                    (score(&zu), score(&zv))
                },
            );
            let white = |z: &[f64; 8]| {
                let z = SVector::<f64, 8>::from(*z);
                var * (z.transpose() * a * z)[(0, 0)]
            };
            (white(&zu), white(&zv))
        }
        Information::Rigid(a) => {
            let mut noise = SMatrix::<f64, 4, 4>::zeros();
            noise[(0, 0)] = nu * rs.moments[0];
            noise[(1, 1)] = nu * rs.moments[0];
            let Some((zu, zv)) = projections(a, &noise, 1) else {
                return ((f64::INFINITY, f64::INFINITY), var);
            };
            fill_padded(
                (su, sv),
                (nw, nh, stride),
                #[inline(always)]
                |k| {
                    let (gx, gy, f, r) = (gx[k], gy[k], f[k], residuals[k]);
                    let score = |z: &[f64; 4]| r * (gx * z[0] + gy * z[1] + z[2] + z[3] * f);
                    (score(&zu), score(&zv))
                },
            );
            let white = |z: &[f64; 4]| {
                let z = SVector::<f64, 4>::from(*z);
                var * (z.transpose() * a * z)[(0, 0)]
            };
            (white(&zu), white(&zv))
        }
    };
    let cov = if residual2 <= 0.0 {
        white
    } else {
        let (mu, mv) = meat(su, sv, nw, nh);
        (scale * mu, scale * mv)
    };
    (cov, var)
}

/// What [`corrected`] needs of the noise along one axis at fractional offset `t`,
/// from impulse responses on a line.
pub(super) struct LineResponses {
    /// The noise gain of the corrected residual: the mean of the spline interpolant's
    /// (the current image's noise, interpolated at `t`) and of the simulated
    /// mismatch's path (the reference's noise, resampled by the sinc and interpolated
    /// back: the mismatch carries the reference's noise through it, and adding the
    /// mismatch to the residual replaces the reference's noise by that), each `Σ h²`
    /// over its impulse response h. The residual's variance divided by the product
    /// over x and y is the 2σ² of white noise in both images.
    pub(super) gain: f64,
    /// What the reference's own white noise puts, on average, in the first-order
    /// change: the mismatch carries the reference's noise `n` as `S n − n` (S:
    /// resampled by the sinc at the shift, interpolated back by the current image's
    /// spline) and the reference's gradients carry it as `D n` (D: the reference
    /// spline's derivative at the pixels), so their product has the mean
    /// `σ²·Σᵢ D(i)·S(i)` per pixel (D(0) = 0), an errors-in-variables term that is
    /// not interpolation error. This is `Σᵢ D(i)·S(i)`.
    pub(super) mismatch_noise: f64,
    /// `S(0)`: the other axis's factor of `mismatch_noise` (the derivative along x is
    /// the identity along y).
    pub(super) centre: f64,
}

impl LineResponses {
    pub(super) fn new(current: Degree, reference: Degree, t: f64) -> Self {
        let (delta, shifted) = impulses(t);
        let range = 8..N_LINE - 9;
        // The spline of an impulse at C, interpolated at k + t.
        let p = line_spline(&delta, current);
        let gp: f64 = range
            .clone()
            .map(|k| p.value(k as f64 + t, 2.0).powi(2))
            .sum();
        // The impulse resampled at m − t by the sinc, then interpolated back at m + t.
        let s = line_spline(&shifted, current);
        let gs: f64 = range
            .clone()
            .map(|k| s.value(k as f64 + t, 2.0).powi(2))
            .sum();
        let d = if reference == current {
            p
        } else {
            line_spline(&delta, reference)
        };
        // Pixel k sees the impulse at C through D(k − C) and S(k − C).
        let mismatch_noise = range
            .map(|k| d.value_gradient(k as f64, 2.0).1 * s.value(k as f64 + t, 2.0))
            .sum();
        LineResponses {
            gain: 0.5 * (gp + gs),
            mismatch_noise,
            centre: s.value(C_LINE as f64 + t, 2.0),
        }
    }
}

/// A spline of one line of `N_LINE` samples (a 5-row image of the same row: the
/// mirrored rows keep it one line), for the impulse responses below.
pub(super) fn line_spline(values: &[f64], degree: Degree) -> BSpline {
    let data: Vec<f64> = (0..5).flat_map(|_| values.iter().copied()).collect();
    BSpline::with_degree(
        &Image::new(values.len(), 5, data).expect("a line of 5 rows"),
        degree,
    )
}

/// Length of the lines of the impulse responses, and the impulse's position.
pub(super) const N_LINE: usize = 97;
pub(super) const C_LINE: usize = N_LINE / 2;

/// An impulse at `C_LINE`, and the same impulse resampled at m − t by the sinc.
pub(super) fn impulses(t: f64) -> (Vec<f64>, Vec<f64>) {
    let mut delta = vec![0.0; N_LINE];
    delta[C_LINE] = 1.0;
    let w = sinc_weights(t);
    let shifted: Vec<f64> = (0..N_LINE)
        .map(|m| {
            w.iter()
                .enumerate()
                .map(|(i, wi)| {
                    let node = m as isize - (i as isize - SINC_HALF + 1);
                    if node == C_LINE as isize { *wi } else { 0.0 }
                })
                .sum()
        })
        .collect();
    (delta, shifted)
}

/// The reference noise's mean share in the first-order change of the mismatch,
/// (u, v): `load` (pixels times the reference's noise variance) times
/// [`LineResponses::mismatch_noise`] along each axis.
#[inline(always)]
pub(super) fn noise_share(
    prepared: &Prepared,
    lx: &LineResponses,
    ly: &LineResponses,
    load: f64,
) -> Option<(f64, f64)> {
    let b = SVector::<f64, 6>::new(
        load * lx.mismatch_noise * ly.centre,
        0.0,
        0.0,
        load * ly.mismatch_noise * lx.centre,
        0.0,
        0.0,
    );
    translation_step(prepared, &b)
}

/// The match `res` of the prepared subset with the spline's interpolation error taken
/// out ([`interpolation_mismatch`]): the translation corrected by its first-order
/// effect (less the reference noise's mean share in it, `LineResponses::mismatch_noise`), and the residual, ZNCC and noise σ recomputed at the corrected solution
/// from the current image's interpolated values less the mismatch, so that the
/// interpolation's own error is not counted again as noise. `kappa` of the correction
/// stays in σ (in quadrature) for what the band-limited model of the image misses.
/// `None` when the mismatch cannot be simulated or the corrected warp leaves the image.
pub fn corrected(
    reference: &Reference,
    prepared: &Prepared,
    current: &BSpline,
    res: &PointResult,
    opts: &IcgnOptions,
    kappa: f64,
) -> Option<PointResult> {
    let e = interpolation_mismatch(reference, prepared, res, current.degree())?;
    let (bu, bv) = first_order_change(prepared, &e)?;
    // The reference noise's mean share of it (`LineResponses::mismatch_noise`),
    // taken back.
    let (tu, tv) = (res.u - res.u.floor(), res.v - res.v.floor());
    let lx = LineResponses::new(current.degree(), prepared.degree, tu);
    let ly = LineResponses::new(current.degree(), prepared.degree, tv);
    let load = prepared.rs.f.len() as f64 * res.sigma_noise * res.sigma_noise;
    let (nu, nv) = noise_share(prepared, &lx, &ly, load)?;
    let (bu, bv) = (bu - nu, bv - nv);
    let (u, v) = (res.u - bu, res.v - bv);
    let [ux, uy, vx, vy] = res.gradients;
    let rs = &prepared.rs;
    let n = rs.f.len();
    let (xc, yc) = (prepared.x as f64, prepared.y as f64);
    let mut g = Vec::with_capacity(n);
    for k in 0..n {
        let (dx, dy) = (rs.dx[k], rs.dy[k]);
        let wx = xc + dx + u + ux * dx + uy * dy;
        let wy = yc + dy + v + vx * dx + vy * dy;
        if !current.contains(wx, wy, 2.0) {
            return None;
        }
        g.push(current.value(wx, wy) - e[k]);
    }
    let gm = g.iter().sum::<f64>() / n as f64;
    let dg = g.iter().map(|x| (x - gm) * (x - gm)).sum::<f64>().sqrt();
    if dg == 0.0 {
        return None;
    }
    let ratio = rs.df / dg;
    let residuals: Vec<f64> = (0..n).map(|k| rs.f[k] - ratio * (g[k] - gm)).collect();
    let residual2: f64 = residuals.iter().map(|r| r * r).sum();
    let gain = lx.gain * ly.gain;
    let mut sandwich = Sandwich::default();
    let (cov, var) = noise_covariance(prepared, &residuals, residual2, opts, gain, &mut sandwich);
    Some(PointResult {
        u,
        v,
        zncc: 1.0 - 0.5 * residual2 / (rs.df * rs.df),
        sigma_u: (cov.0 + (kappa * bu).powi(2)).sqrt(),
        sigma_v: (cov.1 + (kappa * bv).powi(2)).sqrt(),
        sigma_noise: (0.5 * var).sqrt(),
        ..*res
    })
}
