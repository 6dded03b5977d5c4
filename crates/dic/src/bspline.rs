//! Cubic B-spline interpolation with the recursive prefilter (Unser, Aldroubi & Eden,
//! IEEE TSP 1993; Unser, IEEE SP Mag. 1999): the coefficients `c` are computed so that
//! the spline `Σ c_k β³(x − k)` passes through every pixel exactly; values and
//! gradients anywhere come from the same spline. Mirror-symmetric boundaries.

use crate::image::Image;

/// The pole of the cubic B-spline prefilter, `√3 − 2`.
const POLE: f64 = -0.267_949_192_431_122_7;

/// Spline coefficients of an image (same size; mirror boundary conditions).
#[derive(Debug, Clone)]
pub struct BSpline {
    width: usize,
    height: usize,
    c: Vec<f64>,
    /// Offset of the image origin inside a larger image (for local windows).
    origin: (f64, f64),
}

/// In-place causal/anticausal recursion along a line of `n` samples with stride `s`.
fn prefilter_line(d: &mut [f64], start: usize, n: usize, s: usize) {
    if n < 2 {
        return;
    }
    let z = POLE;
    let gain = (1.0 - z) * (1.0 - 1.0 / z);
    for k in 0..n {
        d[start + k * s] *= gain;
    }
    // Causal initialisation (mirror boundary): a sum truncated at machine precision when
    // the line is long enough, the exact mirrored sum otherwise (Unser 1999).
    let horizon = (f64::EPSILON.ln() / z.abs().ln()).ceil() as usize;
    if horizon < n {
        let mut zn = z;
        let mut sum = d[start];
        for k in 1..horizon {
            sum += zn * d[start + k * s];
            zn *= z;
        }
        d[start] = sum;
    } else {
        let iz = 1.0 / z;
        let mut zn = z;
        let mut z2n = z.powi(n as i32 - 1);
        let mut sum = d[start] + z2n * d[start + (n - 1) * s];
        z2n = z2n * z2n * iz;
        for k in 1..n - 1 {
            sum += (zn + z2n) * d[start + k * s];
            zn *= z;
            z2n *= iz;
        }
        d[start] = sum / (1.0 - zn * zn);
    }
    for k in 1..n {
        d[start + k * s] += z * d[start + (k - 1) * s];
    }
    // Anticausal initialisation.
    let last = start + (n - 1) * s;
    d[last] = (z / (z * z - 1.0)) * (z * d[start + (n - 2) * s] + d[last]);
    for k in (0..n - 1).rev() {
        d[start + k * s] = z * (d[start + (k + 1) * s] - d[start + k * s]);
    }
}

const SIXTH: f64 = 1.0 / 6.0;

/// Cubic B-spline weights for fractional offset `t` ∈ [0, 1): taps at −1, 0, +1, +2.
#[inline]
pub fn weights(t: f64) -> [f64; 4] {
    let t2 = t * t;
    let t3 = t2 * t;
    let u = 1.0 - t;
    let w0 = u * u * u * SIXTH;
    let w3 = t3 * SIXTH;
    let w1 = 0.5 * t3 - t2 + 4.0 * SIXTH;
    [w0, w1, 1.0 - w0 - w1 - w3, w3]
}

/// `floor` without a library call (baseline x86-64 has no rounding instruction).
#[inline]
fn fast_floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}

/// Derivatives of [`weights`] with respect to `t`.
#[inline]
pub fn weights_derivative(t: f64) -> [f64; 4] {
    let t2 = t * t;
    let u = 1.0 - t;
    [
        -0.5 * u * u,
        1.5 * t2 - 2.0 * t,
        -1.5 * t2 + t + 0.5,
        0.5 * t2,
    ]
}

#[inline]
fn mirror(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n == 1 {
        return 0;
    }
    let period = 2 * n - 2;
    let mut m = i.rem_euclid(period);
    if m >= n {
        m = period - m;
    }
    m as usize
}

impl BSpline {
    /// Coefficients of a whole image.
    pub fn new(img: &Image) -> Self {
        let (w, h) = (img.width(), img.height());
        let mut c = img.data().to_vec();
        for y in 0..h {
            prefilter_line(&mut c, y * w, w, 1);
        }
        for x in 0..w {
            prefilter_line(&mut c, x, h, w);
        }
        BSpline {
            width: w,
            height: h,
            c,
            origin: (0.0, 0.0),
        }
    }

    /// Coefficients of the window `[x0, x0 + w) x [y0, y0 + h)` of `img`, addressed in
    /// the coordinates of the whole image (for tracking a region without filtering the
    /// whole frame).
    pub fn window(img: &Image, x0: usize, y0: usize, w: usize, h: usize) -> Self {
        let crop = img.crop(x0, y0, w, h);
        let mut s = BSpline::new(&crop);
        s.origin = (x0 as f64, y0 as f64);
        s
    }

    /// Moves the coordinate origin by (dx, dy): the spline is then addressed in a frame
    /// whose origin sits at (−dx, −dy) of the current one.
    pub fn shift_origin(&mut self, dx: f64, dy: f64) {
        self.origin.0 += dx;
        self.origin.1 += dy;
    }

    /// Whether (x, y), in image coordinates, lies where the spline is defined away from
    /// the mirrored border by `margin` pixels.
    #[inline]
    pub fn contains(&self, x: f64, y: f64, margin: f64) -> bool {
        let (x, y) = (x - self.origin.0, y - self.origin.1);
        x >= margin
            && y >= margin
            && x <= self.width as f64 - 1.0 - margin
            && y <= self.height as f64 - 1.0 - margin
    }

    #[inline]
    fn coef(&self, x: isize, y: isize) -> f64 {
        self.c[mirror(y, self.height) * self.width + mirror(x, self.width)]
    }

    #[inline]
    fn split(&self, x: f64, y: f64) -> (isize, isize, f64, f64) {
        let (x, y) = (x - self.origin.0, y - self.origin.1);
        let (fx, fy) = (fast_floor(x), fast_floor(y));
        (fx as isize, fy as isize, x - fx, y - fy)
    }

    /// The interpolated value at (x, y).
    #[inline(always)]
    pub fn value(&self, x: f64, y: f64) -> f64 {
        let (ix, iy, tx, ty) = self.split(x, y);
        self.combine(ix, iy, &weights(tx), &weights(ty))
    }

    /// The value at the integer node (fx, fy), image coordinates, plus a fractional
    /// offset whose weights `wx`, `wy` the caller computed once (translation warps).
    #[inline]
    pub fn value_with(&self, fx: f64, fy: f64, wx: &[f64; 4], wy: &[f64; 4]) -> f64 {
        let ix = (fx - self.origin.0) as isize;
        let iy = (fy - self.origin.1) as isize;
        self.combine(ix, iy, wx, wy)
    }

    /// The values at `(fx + dx, fy + dy)` for `dy` in `−hh..=hh` (outer) and `dx` in
    /// `−hw..=hw` (inner), for one fractional offset whose weights are `wx`, `wy`
    /// (a translated subset), written into `out`. Separable: two passes of four taps
    /// instead of sixteen products per value; `tmp` is scratch.
    #[allow(clippy::too_many_arguments)]
    pub fn translated_block(
        &self,
        fx: f64,
        fy: f64,
        hw: usize,
        hh: usize,
        wx: &[f64; 4],
        wy: &[f64; 4],
        tmp: &mut Vec<f64>,
        out: &mut Vec<f64>,
    ) {
        let (nw, nh) = (2 * hw + 1, 2 * hh + 1);
        let ix0 = (fx - self.origin.0) as isize - hw as isize;
        let iy0 = (fy - self.origin.1) as isize - hh as isize;
        out.clear();
        let inner = ix0 >= 1
            && iy0 >= 1
            && ix0 + nw as isize + 1 < self.width as isize
            && iy0 + nh as isize + 1 < self.height as isize;
        if !inner {
            for j in 0..nh as isize {
                for i in 0..nw as isize {
                    out.push(self.combine(ix0 + i, iy0 + j, wx, wy));
                }
            }
            return;
        }
        tmp.clear();
        tmp.resize((nh + 3) * nw, 0.0);
        for r in 0..nh + 3 {
            let base = (iy0 as usize - 1 + r) * self.width + ix0 as usize - 1;
            let src = &self.c[base..base + nw + 3];
            let dst = &mut tmp[r * nw..(r + 1) * nw];
            for (i, d) in dst.iter_mut().enumerate() {
                *d = wx[0] * src[i] + wx[1] * src[i + 1] + wx[2] * src[i + 2] + wx[3] * src[i + 3];
            }
        }
        for j in 0..nh {
            let (a, b, c, d) = (
                &tmp[j * nw..(j + 1) * nw],
                &tmp[(j + 1) * nw..(j + 2) * nw],
                &tmp[(j + 2) * nw..(j + 3) * nw],
                &tmp[(j + 3) * nw..(j + 4) * nw],
            );
            for i in 0..nw {
                out.push(wy[0] * a[i] + wy[1] * b[i] + wy[2] * c[i] + wy[3] * d[i]);
            }
        }
    }

    #[inline(always)]
    fn combine(&self, ix: isize, iy: isize, wx: &[f64; 4], wy: &[f64; 4]) -> f64 {
        let inner =
            ix >= 1 && iy >= 1 && ix + 2 < self.width as isize && iy + 2 < self.height as isize;
        let mut acc = 0.0;
        if inner {
            let base = (iy - 1) as usize * self.width + (ix - 1) as usize;
            for (j, wyj) in wy.iter().enumerate() {
                let row = &self.c[base + j * self.width..base + j * self.width + 4];
                acc += wyj * (wx[0] * row[0] + wx[1] * row[1] + wx[2] * row[2] + wx[3] * row[3]);
            }
        } else {
            for (j, wyj) in wy.iter().enumerate() {
                let mut r = 0.0;
                for (i, wxi) in wx.iter().enumerate() {
                    r += wxi * self.coef(ix - 1 + i as isize, iy - 1 + j as isize);
                }
                acc += wyj * r;
            }
        }
        acc
    }

    /// The interpolated value and gradient (∂/∂x, ∂/∂y) at (x, y).
    pub fn value_gradient(&self, x: f64, y: f64) -> (f64, f64, f64) {
        let (ix, iy, tx, ty) = self.split(x, y);
        let (wx, wy) = (weights(tx), weights(ty));
        let (dx, dy) = (weights_derivative(tx), weights_derivative(ty));
        let (mut v, mut gx, mut gy) = (0.0, 0.0, 0.0);
        for j in 0..4 {
            for i in 0..4 {
                let c = self.coef(ix - 1 + i as isize, iy - 1 + j as isize);
                v += wx[i] * wy[j] * c;
                gx += dx[i] * wy[j] * c;
                gy += wx[i] * dy[j] * c;
            }
        }
        (v, gx, gy)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn test_image() -> Image {
        let (w, h) = (23, 17);
        let data = (0..w * h)
            .map(|k| {
                let (x, y) = ((k % w) as f64, (k / w) as f64);
                100.0 + 40.0 * (0.7 * x).sin() * (0.45 * y).cos() + 3.0 * x
            })
            .collect();
        Image::new(w, h, data).unwrap()
    }

    #[test]
    fn spline_interpolates_every_pixel_exactly() {
        let img = test_image();
        let s = BSpline::new(&img);
        for y in 0..img.height() {
            for x in 0..img.width() {
                let v = s.value(x as f64, y as f64);
                assert!(
                    (v - img.at(x, y)).abs() < 1e-9,
                    "({x},{y}): {v} vs {}",
                    img.at(x, y)
                );
            }
        }
    }

    #[test]
    fn gradient_is_the_derivative_of_the_value() {
        let s = BSpline::new(&test_image());
        let h = 1e-6;
        for &(x, y) in &[(5.3, 7.7), (10.0, 3.25), (1.5, 14.9)] {
            let (_, gx, gy) = s.value_gradient(x, y);
            let nx = (s.value(x + h, y) - s.value(x - h, y)) / (2.0 * h);
            let ny = (s.value(x, y + h) - s.value(x, y - h)) / (2.0 * h);
            assert!((gx - nx).abs() < 1e-5 && (gy - ny).abs() < 1e-5);
            let (v, _, _) = s.value_gradient(x, y);
            assert!((v - s.value(x, y)).abs() < 1e-10);
        }
    }

    #[test]
    fn cubic_polynomials_are_reproduced() {
        // A cubic spline reproduces polynomials of degree ≤ 3 away from the borders.
        let (w, h) = (40, 30);
        let f = |x: f64, y: f64| 0.01 * x * x * x - 0.2 * x * y + 0.5 * y * y + 3.0;
        let data = (0..w * h)
            .map(|k| f((k % w) as f64, (k / w) as f64))
            .collect();
        let s = BSpline::new(&Image::new(w, h, data).unwrap());
        for &(x, y) in &[(15.3, 12.7), (20.5, 14.25)] {
            assert!(
                (s.value(x, y) - f(x, y)).abs() < 1e-6,
                "{} vs {}",
                s.value(x, y),
                f(x, y)
            );
        }
    }

    #[test]
    fn windows_address_whole_image_coordinates() {
        let (w, h) = (60, 50);
        let data = (0..w * h)
            .map(|k| 100.0 + 40.0 * (0.7 * (k % w) as f64).sin() * (0.45 * (k / w) as f64).cos())
            .collect();
        let img = Image::new(w, h, data).unwrap();
        let whole = BSpline::new(&img);
        let win = BSpline::window(&img, 10, 10, 40, 30);
        // 14 px from the window's border the boundary's influence is |z|^14 ≈ 1e-8.
        let (x, y) = (30.4, 25.6);
        assert!((whole.value(x, y) - win.value(x, y)).abs() < 1e-5);
    }

    #[test]
    fn a_translated_block_equals_point_by_point_values() {
        let (w, h) = (60, 50);
        let data = (0..w * h)
            .map(|k| 100.0 + 40.0 * (0.7 * (k % w) as f64).sin() * (0.45 * (k / w) as f64).cos())
            .collect();
        let s = BSpline::new(&Image::new(w, h, data).unwrap());
        let (wx, wy) = (weights(0.3), weights(0.8));
        let (mut tmp, mut out) = (Vec::new(), Vec::new());
        // Inside (separable path) and touching the border (point-by-point path).
        for (fx, fy) in [(30.0, 25.0), (4.0, 3.0)] {
            s.translated_block(fx, fy, 5, 3, &wx, &wy, &mut tmp, &mut out);
            assert_eq!(out.len(), 11 * 7);
            let mut k = 0;
            for dy in -3..=3 {
                for dx in -5..=5 {
                    let v = s.value_with(fx + dx as f64, fy + dy as f64, &wx, &wy);
                    assert!((out[k] - v).abs() < 1e-9, "{fx} {fy} {dx} {dy}");
                    k += 1;
                }
            }
        }
    }
}
