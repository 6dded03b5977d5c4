//! The interpolation error of a match: the spline against a band-limited (Kaiser-windowed
//! sinc) interpolation of the same samples ([`interpolation_mismatch`]).

use super::*;

/// Half-width of the windowed-sinc kernel [`interpolation_mismatch`] resamples with,
/// taps.
pub(crate) const SINC_HALF: isize = 16;

/// Kaiser window's shape parameter for that kernel.
pub(super) const SINC_BETA: f64 = 10.0;

/// The modified Bessel function I₀ (power series; converges for every x in use here).
pub(super) fn bessel_i0(x: f64) -> f64 {
    let (mut sum, mut term) = (1.0, 1.0);
    let q = 0.25 * x * x;
    for k in 1..50 {
        term *= q / (k * k) as f64;
        sum += term;
        if term < 1e-17 * sum {
            break;
        }
    }
    sum
}

/// Weights of the Kaiser-windowed sinc that resamples node m's lattice at m − t, t ∈
/// [0, 1): weight i belongs to the node m − d, d = i − SINC_HALF + 1 (from −SINC_HALF + 1
/// to SINC_HALF), which lies t − d from the point; normalised to unit sum.
pub(crate) fn sinc_weights(t: f64) -> [f64; 2 * SINC_HALF as usize] {
    let norm = bessel_i0(SINC_BETA);
    let mut w: [f64; 2 * SINC_HALF as usize] = std::array::from_fn(|i| {
        let d = t - (i as isize - SINC_HALF + 1) as f64;
        let r = d / SINC_HALF as f64;
        let window = if r.abs() < 1.0 {
            bessel_i0(SINC_BETA * (1.0 - r * r).sqrt()) / norm
        } else {
            0.0
        };
        let x = std::f64::consts::PI * d;
        let sinc = if x.abs() < 1e-12 { 1.0 } else { x.sin() / x };
        window * sinc
    });
    let s: f64 = w.iter().sum();
    for v in &mut w {
        *v /= s;
    }
    w
}

/// The spline's interpolation error at each pixel of the subset translated by the
/// solution's (u, v): interpolated minus band-limited value, grey levels, in the
/// subset's pixel order ([`corrected`] takes it out of a match).
///
/// A current image is simulated from the reference by band-limited resampling (a
/// Kaiser-windowed sinc of 2·`SINC_HALF` (32) taps, mirrored at the borders) at the
/// solution's translation; its spline of the current image's degree, interpolated
/// back at the translated subset, is compared with the reference's pixels. Unlike the
/// per-axis spectral model ([`spline_response`] weighted by the subset's spectrum, in
/// the σ of [`refine_prepared`]), it sees the subset in two dimensions: on a
/// diagonal edge the spline's phase errors along x and along y add in the edge's
/// normal and couple u and v through the normal equations. The shape's gradients are
/// left out of the simulation: the error depends on the sub-pixel phase, which they
/// change by little over a subset.
pub fn interpolation_mismatch(
    reference: &Reference,
    prepared: &Prepared,
    res: &PointResult,
    current: Degree,
) -> Option<Vec<f64>> {
    let img = reference.image();
    let (iw, ih) = (img.width() as isize, img.height() as isize);
    let (xc, yc) = (prepared.x as isize, prepared.y as isize);
    let (hw, hh) = (
        prepared.subset.half_w as isize,
        prepared.subset.half_h as isize,
    );
    // Current pixel n shows the reference at n − u = (n − U) − t, U = ⌊u⌋.
    let (uf, vf) = (res.u.floor(), res.v.floor());
    let (tu, tv) = (res.u - uf, res.v - vf);
    let (wu, wv) = (sinc_weights(tu), sinc_weights(tv));
    // The simulated current image over the translated subset with the spline's margin,
    // in reference-lattice coordinates m = n − U: pixel m holds f(m − t).
    let pad = 8isize;
    let (x0, y0) = (xc - hw - pad, yc - hh - pad);
    let (w, h) = (
        (2 * hw + 2 * pad + 1) as usize,
        (2 * hh + 2 * pad + 1) as usize,
    );
    let mirror = |i: isize, n: isize| -> usize {
        let m = i.rem_euclid(2 * n);
        (if m < n { m } else { 2 * n - 1 - m }) as usize
    };
    // Rows first: each needed reference row resampled along x.
    let rows = h + 2 * SINC_HALF as usize;
    let ry0 = y0 - SINC_HALF;
    let mut along_x = vec![0.0; rows * w];
    for r in 0..rows {
        let yy = mirror(ry0 + r as isize, ih);
        for i in 0..w {
            let m = x0 + i as isize;
            let mut acc = 0.0;
            for (k, wk) in wu.iter().enumerate() {
                // The node m − d, d = k − SINC_HALF + 1.
                let xx = mirror(m - (k as isize - SINC_HALF + 1), iw);
                acc += wk * img.at(xx, yy);
            }
            along_x[r * w + i] = acc;
        }
    }
    let mut sim = vec![0.0; w * h];
    for j in 0..h {
        for i in 0..w {
            let mut acc = 0.0;
            for (k, wk) in wv.iter().enumerate() {
                let r = (j as isize + SINC_HALF) - (k as isize - SINC_HALF + 1);
                acc += wk * along_x[r as usize * w + i];
            }
            sim[j * w + i] = acc;
        }
    }
    let s = BSpline::with_degree(&Image::new(w, h, sim).ok()?, current);
    let rs = &prepared.rs;
    let n = rs.f.len();
    let mean_f = {
        let mut sum = 0.0;
        for j in -hh..=hh {
            for i in -hw..=hw {
                sum += img.at((xc + i) as usize, (yc + j) as usize);
            }
        }
        sum / n as f64
    };
    // The subset pixel (dx, dy) is at m = (xc + dx, yc + dy) + t in the simulated
    // lattice, which shows f there: the reference pixel (xc + dx, yc + dy).
    let ek: Vec<f64> = (0..n)
        .map(|k| {
            let (dx, dy) = (rs.dx[k], rs.dy[k]);
            let sx = (xc - x0) as f64 + dx + tu;
            let sy = (yc - y0) as f64 + dy + tv;
            s.value(sx, sy) - (rs.f[k] + mean_f)
        })
        .collect();
    Some(ek)
}
