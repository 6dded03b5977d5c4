//! The current image's rounding to grey levels, carried into a match: simulated at
//! four sub-pixel phases and taken through one Gauss-Newton step ([`rounding_error`]).

use super::*;

/// Sub-pixel phases at which [`rounding_error`] simulates the rounding: the
/// solution's translation moved by each of them in x and in y, a quarter of a pixel
/// apart. The image's tables ([`crate::correction::Corrections`]) take them as
/// absolute phases instead, the same for every subset: phase 0 is then the reference
/// itself, whose rounding is already done (no error).
pub const ROUNDING_PHASES: [f64; 4] = [0.0, 0.25, 0.5, 0.75];

/// The size of the error the current image's rounding to `opts.quantisation_step`
/// makes in the match `res` of the prepared subset (added to a grown subset's σ by
/// [`crate::accept::measure`]), u and v, pixels: the RMS over the sub-pixel phases
/// [`ROUNDING_PHASES`] of [`rounding_errors`]. At each phase a current image is
/// simulated, the reference's own spline warped by the solution's deformation with
/// its translation moved by the phase, onto the pixels the warped subset covers; its
/// rounding residual (rounded minus unrounded) is interpolated at the warped subset
/// and taken through one Gauss-Newton step of the subset's normal equations, which is
/// the change rounding makes in the converged match to first order. Re-matching the
/// rounded and the unrounded image instead gave the same summary on
/// `tests/real_images.rs` (points over 0.1 px, median and lowest share of textured
/// points kept, range of RMS error / σ; every run's share within 0.5 %, measured
/// with the term on every subset) and took 1.5 times as long.
///
/// The residual floor ([`IcgnOptions::residual_floor`]) counts rounding as white
/// noise, which it is where the grey levels change by several steps per pixel. Where
/// they change by less (a smooth sky, a dark coat, a faint gradient), the rounding
/// moves whole runs of pixels to the same contour and its error keeps its sign over
/// the subset: it does not average out over more pixels, and the white-noise σ
/// underestimates it by far (a larger subset lowers the σ, not the error). The error
/// is a function of the sub-pixel position, a sawtooth that pulls the match towards
/// whole pixels, so one simulation at the solution, which the pull has already
/// brought near a whole pixel, sees little of it: on the sky of
/// `tests/real_images.rs` (61 px subsets at shift (0.05, −0.80), noise 0, errors of
/// −0.10 to −0.15 px in v) one simulation gave 0.01-0.02 px, eight phases from
/// −0.11 to +0.11 px (RMS 0.02-0.08 px); the RMS over the phases is the size of the
/// error at an unknown sub-pixel position. The reference's own rounding, unknown, is
/// not counted.
pub fn rounding_error(
    reference: &Reference,
    prepared: &Prepared,
    res: &PointResult,
    opts: &IcgnOptions,
) -> Option<(f64, f64)> {
    let offsets = ROUNDING_PHASES.map(|d| (d, d));
    let e = rounding_errors(reference, prepared, res, opts, &offsets)?;
    let n = e.len() as f64;
    let (su, sv) = e
        .iter()
        .fold((0.0, 0.0), |(a, b), (u, v)| (a + u * u, b + v * v));
    Some(((su / n).sqrt(), (sv / n).sqrt()))
}

/// [`rounding_error`] for the translation of the match alone (its gradients left
/// out, as in the image's tables), simulated separably on a window of the subset:
/// the current image the reference's spline makes at each phase, rounded, and its
/// residual's spline read at the subset. The same RMS over the phases relative to
/// the match, at a tenth of the cost; the field and point modes' way where the
/// rounding is coherent ([`crate::accept::COHERENT_ROUNDING`]). `scratch` holds the
/// subset's [`influence`].
#[inline(always)]
pub(crate) fn rounding_error_translated(
    reference: &Reference,
    prepared: &Prepared,
    res: &PointResult,
    opts: &IcgnOptions,
    scratch: &mut Scratch,
) -> Option<(f64, f64)> {
    let q = opts.quantisation_step;
    let (hw, hh) = (prepared.subset.half_w, prepared.subset.half_h);
    let pad = match prepared.degree {
        Degree::Cubic => 4,
        Degree::Quintic => 8,
    };
    let (xc, yc) = (prepared.x as f64, prepared.y as f64);
    let d = prepared.degree;
    let (mut su, mut sv) = (0.0, 0.0);
    for a in ROUNDING_PHASES {
        let (u, v) = (res.u + a, res.v + a);
        let (tu, tv) = (u - u.floor(), v - v.floor());
        // Window pixel j (from −(hw + pad)) shows the reference at xc + j − tu:
        // node xc − 1 + j at fraction 1 − tu (node xc + j at 0 when tu is 0).
        let node = |c: f64, t: f64| {
            if t > 0.0 {
                (c - 1.0, 1.0 - t)
            } else {
                (c, 0.0)
            }
        };
        let ((fx, ax), (fy, ay)) = (node(xc, tu), node(yc, tv));
        let mut exact = std::mem::take(&mut scratch.g);
        reference.spline.translated_block(
            fx,
            fy,
            hw + pad,
            hh + pad,
            &d.weights(ax),
            &d.weights(ay),
            &mut scratch.tmp,
            &mut exact,
        );
        for v in exact.iter_mut() {
            *v = (*v / q).round() * q - *v;
        }
        // Finite: a NaN or an infinity makes the (vectorised) sum of v·0 one.
        let [check] = lane_sums!(exact.len(), |a| [a.of(&exact) * 0.0]);
        let (ww, wh) = (2 * (hw + pad) + 1, 2 * (hh + pad) + 1);
        if exact.len() != ww * wh || check != 0.0 {
            return None;
        }
        let residual = BSpline::from_values_in(ww, wh, exact, d, &mut scratch.tmp);
        // Subset pixel dx lies at window position hw + pad + dx + tu.
        let mut e = std::mem::take(&mut scratch.mismatch);
        residual.translated_block(
            (hw + pad) as f64,
            (hh + pad) as f64,
            hw,
            hh,
            &d.weights(tu),
            &d.weights(tv),
            &mut scratch.tmp,
            &mut e,
        );
        let (du, dv) = scratch.first_order(&e);
        scratch.mismatch = e;
        scratch.g = residual.into_coefficients();
        su += du * du;
        sv += dv * dv;
    }
    let phases = ROUNDING_PHASES.len() as f64;
    Some(((su / phases).sqrt(), (sv / phases).sqrt()))
}

/// The signed errors (u, v) the current image's rounding makes in the match, one per
/// offset (du, dv) of the simulated translation from the solution's (see
/// [`rounding_error`]).
pub fn rounding_errors(
    reference: &Reference,
    prepared: &Prepared,
    res: &PointResult,
    opts: &IcgnOptions,
    offsets: &[(f64, f64)],
) -> Option<Vec<(f64, f64)>> {
    offsets
        .iter()
        .map(|&(du, dv)| rounding_error_at(reference, prepared, res, opts, du, dv))
        .collect()
}

/// The signed rounding error (u, v) of a simulated current image: the reference's
/// spline warped by `res`'s deformation with its translation moved by (du, dv), and
/// the first-order change of the match when it is rounded to the step.
pub(super) fn rounding_error_at(
    reference: &Reference,
    prepared: &Prepared,
    res: &PointResult,
    opts: &IcgnOptions,
    du: f64,
    dv: f64,
) -> Option<(f64, f64)> {
    let q = opts.quantisation_step;
    let (u, v) = (res.u + du, res.v + dv);
    let (xc, yc) = (prepared.x as f64, prepared.y as f64);
    let [ux, uy, vx, vy] = res.gradients;
    let (hw, hh) = (prepared.subset.half_w as f64, prepared.subset.half_h as f64);
    // The current image's pixels under the warped subset, with the spline's margin
    // (wider for the quintic, whose mirrored border reaches further: |z₁|⁸ ≈ 1e-3).
    let pad = match prepared.degree {
        Degree::Cubic => 4.0,
        Degree::Quintic => 8.0,
    };
    let corners = [(-hw, -hh), (hw, -hh), (-hw, hh), (hw, hh)].map(|(dx, dy)| {
        (
            xc + dx + u + ux * dx + uy * dy,
            yc + dy + v + vx * dx + vy * dy,
        )
    });
    let lo = |f: fn(&(f64, f64)) -> f64| corners.iter().map(f).fold(f64::INFINITY, f64::min);
    let hi = |f: fn(&(f64, f64)) -> f64| corners.iter().map(f).fold(f64::NEG_INFINITY, f64::max);
    let x0 = lo(|c| c.0).floor() - pad;
    let x1 = hi(|c| c.0).ceil() + pad;
    let y0 = lo(|c| c.1).floor() - pad;
    let y1 = hi(|c| c.1).ceil() + pad;
    let (w, h) = ((x1 - x0) as usize + 1, (y1 - y0) as usize + 1);
    // Current pixel (px, py) ↦ reference point: the inverse of the affine warp.
    let det = (1.0 + ux) * (1.0 + vy) - uy * vx;
    if det.abs() < 1e-6 {
        return None;
    }
    let spline = &reference.spline;
    let mut exact = Vec::with_capacity(w * h);
    for j in 0..h {
        for i in 0..w {
            let (ex, ey) = (x0 + i as f64 - xc - u, y0 + j as f64 - yc - v);
            let dx = ((1.0 + vy) * ex - uy * ey) / det;
            let dy = (-vx * ex + (1.0 + ux) * ey) / det;
            // Outside the reference the mirrored spline continues it.
            exact.push(spline.value(xc + dx, yc + dy));
        }
    }
    // The rounding residual, interpolated at the warped subset, through one
    // Gauss-Newton step: the change of the converged solution to first order.
    let e: Vec<f64> = exact.iter().map(|v| (v / q).round() * q - v).collect();
    let mut s = BSpline::with_degree(&Image::new(w, h, e).ok()?, prepared.degree);
    s.shift_origin(x0, y0);
    let rs = &prepared.rs;
    let n = rs.f.len();
    let ek: Vec<f64> = (0..n)
        .map(|k| {
            let (dx, dy) = (rs.dx[k], rs.dy[k]);
            s.value(
                xc + dx + u + ux * dx + uy * dy,
                yc + dy + v + vx * dx + vy * dy,
            )
        })
        .collect();
    first_order_change(prepared, &ek)
}

/// The change of a converged match to first order when the current image, interpolated
/// at the warped subset, is off by `ek` (one value per subset pixel): one Gauss-Newton
/// step of the subset's normal equations, offset removed. (u, v), pixels.
pub(super) fn first_order_change(prepared: &Prepared, ek: &[f64]) -> Option<(f64, f64)> {
    let rs = &prepared.rs;
    let n = rs.f.len();
    let mean = ek.iter().sum::<f64>() / n as f64;
    let mut b = [0.0; 6];
    for k in 0..n {
        let (gx, gy, dx, dy) = (rs.gx[k], rs.gy[k], rs.dx[k], rs.dy[k]);
        let r = ek[k] - mean;
        let (ex, ey) = (gx * r, gy * r);
        b[0] += ex;
        b[1] += ex * dx;
        b[2] += ex * dy;
        b[3] += ey;
        b[4] += ey * dx;
        b[5] += ey * dy;
    }
    if prepared.shape == Shape::Rigid {
        b = [b[0], 0.0, 0.0, b[3], 0.0, 0.0];
    }
    translation_step(prepared, &SVector::from(b))
}

/// The Gauss-Newton step (u, v) of the subset's normal equations for the right-hand
/// side `b` over (u, ∂u/∂x, ∂u/∂y, v, ∂v/∂x, ∂v/∂y): `−H⁻¹ b` (the rigid shape uses
/// the translation entries alone).
#[inline(always)]
pub(super) fn translation_step(prepared: &Prepared, b: &SVector<f64, 6>) -> Option<(f64, f64)> {
    match prepared.shape {
        Shape::Affine => {
            let d = -(prepared.h6_inv?) * b;
            Some((d[0], d[3]))
        }
        Shape::Rigid => {
            let d = -(prepared.h2_inv?) * SVector::<f64, 2>::new(b[0], b[3]);
            Some((d[0], d[1]))
        }
    }
}
