//! Integer-pixel search by zero-normalised cross-correlation (ZNCC), computed for every
//! candidate shift at once through the FFT, with the local means and energies of the
//! search region from integral images (Lewis, "Fast normalized cross-correlation", 1995);
//! where the candidates are few (a refinement within ±2 px, a small template at a
//! pyramid's top) the cross-correlation is summed directly, which costs less than the
//! three transforms. Coarse-to-fine over an image pyramid for large jumps.

use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

use crate::image::Image;
use crate::lanes::dot;

/// Best integer shift of a subset and its ZNCC.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IntegerMatch {
    /// Shift along x (columns), pixels.
    pub u: i64,
    /// Shift along y (rows), pixels.
    pub v: i64,
    /// ZNCC at the shift (−1..1).
    pub zncc: f64,
}

thread_local! {
    /// Each thread's FFT plans, kept from one search to the next.
    static PLANNER: std::cell::RefCell<FftPlanner<f64>> = std::cell::RefCell::new(FftPlanner::new());
}

fn fft2(planner: &mut FftPlanner<f64>, data: &mut [Complex<f64>], n: usize, inverse: bool) {
    let fft = if inverse {
        planner.plan_fft_inverse(n)
    } else {
        planner.plan_fft_forward(n)
    };
    for row in data.chunks_mut(n) {
        fft.process(row);
    }
    let mut col = vec![Complex::new(0.0, 0.0); n];
    for x in 0..n {
        for y in 0..n {
            col[y] = data[y * n + x];
        }
        fft.process(&mut col);
        for y in 0..n {
            data[y * n + x] = col[y];
        }
    }
}

/// Searches the shift of the `(2m+1)²` subset of `reference` centred at integer (x, y)
/// within `±radius` pixels of the predicted shift `(pu, pv)` in `current`.
/// Returns `None` when the subset or the search region does not fit in the images.
#[allow(clippy::too_many_arguments)]
pub fn search(
    reference: &Image,
    current: &Image,
    x: i64,
    y: i64,
    m: i64,
    radius: i64,
    pu: i64,
    pv: i64,
) -> Option<IntegerMatch> {
    let n = 2 * m + 1;
    let (rw, rh) = (reference.width() as i64, reference.height() as i64);
    let (cw, ch) = (current.width() as i64, current.height() as i64);
    if x - m < 0 || y - m < 0 || x + m >= rw || y + m >= rh {
        return None;
    }
    // Search region in the current image, clipped to it.
    let x0 = (x + pu - m - radius).max(0);
    let y0 = (y + pv - m - radius).max(0);
    let x1 = (x + pu + m + radius).min(cw - 1);
    let y1 = (y + pv + m + radius).min(ch - 1);
    let (sw, sh) = (x1 - x0 + 1, y1 - y0 + 1);
    if sw < n || sh < n {
        return None;
    }
    let size = (sw.max(sh) as usize).next_power_of_two();
    // Zero-mean template.
    let mut t = Vec::with_capacity((n * n) as usize);
    for j in 0..n {
        for i in 0..n {
            t.push(reference.at((x - m + i) as usize, (y - m + j) as usize));
        }
    }
    let tm = t.iter().sum::<f64>() / t.len() as f64;
    let tz: Vec<f64> = t.iter().map(|v| v - tm).collect();
    let t_energy = tz.iter().map(|v| v * v).sum::<f64>().sqrt();
    if t_energy == 0.0 {
        return None;
    }
    // The cross-correlation of the zero-mean template with the region at every
    // candidate offset (i, j), row-major with `stride`: summed directly where that
    // costs less than three transforms of `size`², else through the FFT.
    let region = Region { x0, y0, sw, sh };
    let candidates = ((sw - n + 1) * (sh - n + 1)) as usize;
    let nn = n as usize;
    let transforms = 3 * size * size * (2 * size.trailing_zeros() as usize).max(1) * 2;
    let (cross, stride) = if candidates * nn * nn <= transforms {
        cross_direct(current, &tz, nn, region)
    } else {
        cross_fft(current, &tz, nn, region, size)
    };
    // Integral images of the region and its square.
    let w1 = (sw + 1) as usize;
    let mut s1 = vec![0.0; w1 * (sh + 1) as usize];
    let mut s2 = s1.clone();
    for j in 0..sh as usize {
        for i in 0..sw as usize {
            let v = current.at(x0 as usize + i, y0 as usize + j);
            let k = (j + 1) * w1 + i + 1;
            s1[k] = v + s1[k - 1] + s1[k - w1] - s1[k - w1 - 1];
            s2[k] = v * v + s2[k - 1] + s2[k - w1] - s2[k - w1 - 1];
        }
    }
    let box_sum = |s: &[f64], i: usize, j: usize| {
        let (i1, j1) = (i + n as usize, j + n as usize);
        s[j1 * w1 + i1] - s[j * w1 + i1] - s[j1 * w1 + i] + s[j * w1 + i]
    };
    let area = (n * n) as f64;
    let mut best = IntegerMatch {
        u: 0,
        v: 0,
        zncc: f64::NEG_INFINITY,
    };
    for j in 0..=(sh - n) as usize {
        for i in 0..=(sw - n) as usize {
            let sum = box_sum(&s1, i, j);
            let var = box_sum(&s2, i, j) - sum * sum / area;
            if var <= 0.0 {
                continue;
            }
            let num = cross[j * stride + i];
            let zncc = num / (t_energy * var.sqrt());
            if zncc > best.zncc {
                best = IntegerMatch {
                    u: x0 + i as i64 + m - x,
                    v: y0 + j as i64 + m - y,
                    zncc,
                };
            }
        }
    }
    best.zncc.is_finite().then_some(best)
}

/// The search region in the current image: its top-left pixel and size.
#[derive(Debug, Clone, Copy)]
struct Region {
    x0: i64,
    y0: i64,
    sw: i64,
    sh: i64,
}

/// `Σ tz_k c_{(i, j) + k}` of the zero-mean `n x n` template `tz` with the region of
/// `current` at every candidate offset (i, j) (row-major, as many columns as the
/// returned stride): summed directly, each row's products in interleaved partial
/// sums on the machine's vector units (an in-order sum is one long chain of
/// dependent additions).
fn cross_direct(current: &Image, tz: &[f64], n: usize, r: Region) -> (Vec<f64>, usize) {
    pulp::Arch::new().dispatch(CrossDirect { current, tz, n, r })
}

/// [`cross_direct`] compiled for the machine's vector units.
struct CrossDirect<'a> {
    current: &'a Image,
    tz: &'a [f64],
    n: usize,
    r: Region,
}

impl pulp::WithSimd for CrossDirect<'_> {
    type Output = (Vec<f64>, usize);

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> Self::Output {
        let CrossDirect { current, tz, n, r } = self;
        let (cols, rows) = (r.sw as usize + 1 - n, r.sh as usize + 1 - n);
        let (data, cw) = (current.data(), current.width());
        let mut out = vec![0.0; cols * rows];
        for (j, row) in out.chunks_exact_mut(cols).enumerate() {
            for (i, o) in row.iter_mut().enumerate() {
                let mut acc = 0.0;
                for (jj, trow) in tz.chunks_exact(n).enumerate() {
                    let start = (r.y0 as usize + j + jj) * cw + r.x0 as usize + i;
                    acc += dot(trow, &data[start..start + n]);
                }
                *o = acc;
            }
        }
        (out, cols)
    }
}

/// [`cross_direct`] through `size`² FFTs (the product of the transforms, transformed
/// back), row-major with stride `size`.
fn cross_fft(current: &Image, tz: &[f64], n: usize, r: Region, size: usize) -> (Vec<f64>, usize) {
    let zero = Complex::new(0.0, 0.0);
    let mut a = vec![zero; size * size];
    let mut b = vec![zero; size * size];
    for j in 0..r.sh as usize {
        for i in 0..r.sw as usize {
            a[j * size + i].re = current.at(r.x0 as usize + i, r.y0 as usize + j);
        }
    }
    for (j, trow) in tz.chunks_exact(n).enumerate() {
        for (i, v) in trow.iter().enumerate() {
            b[j * size + i].re = *v;
        }
    }
    PLANNER.with(|p| {
        let mut planner = p.borrow_mut();
        fft2(&mut planner, &mut a, size, false);
        fft2(&mut planner, &mut b, size, false);
        for (p, q) in a.iter_mut().zip(&b) {
            *p *= q.conj();
        }
        fft2(&mut planner, &mut a, size, true);
    });
    let scale = 1.0 / (size * size) as f64;
    (a.iter().map(|c| c.re * scale).collect(), size)
}

/// Coarse-to-fine search: a wide search on a pyramid level where the jump is small, then
/// ±2-pixel refinements down to full resolution. `levels` = 0 is a plain [`search`].
pub fn search_pyramid(
    reference: &[Image],
    current: &[Image],
    x: i64,
    y: i64,
    m: i64,
    radius: i64,
) -> Option<IntegerMatch> {
    let levels = reference.len().min(current.len()).saturating_sub(1);
    let mut pred = (0i64, 0i64);
    let mut last = None;
    for level in (0..=levels).rev() {
        let f = 1i64 << level;
        let ml = (m / f).max(4);
        let r = if level == levels { radius / f + 1 } else { 2 };
        let found = search(
            &reference[level],
            &current[level],
            x / f,
            y / f,
            ml,
            r,
            pred.0,
            pred.1,
        );
        match found {
            Some(hit) => {
                if level > 0 {
                    pred = (2 * hit.u, 2 * hit.v);
                } else {
                    last = Some(hit);
                }
            }
            None if level > 0 => pred = (2 * pred.0, 2 * pred.1),
            None => last = None,
        }
    }
    last
}

/// An image pyramid: level 0 is the image, each next level half its size.
pub fn pyramid(img: &Image, levels: usize) -> Vec<Image> {
    let mut out = vec![img.clone()];
    for _ in 0..levels {
        let next = out.last().map(Image::downsample);
        match next {
            Some(n) if n.width() >= 16 && n.height() >= 16 => out.push(n),
            _ => break,
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{Speckle, SpeckleParams};

    #[test]
    fn the_direct_and_the_fft_cross_correlations_agree() {
        let s = Speckle::new(&SpeckleParams::default_for(96, 80), 8);
        let c = s.render_shifted(1.3, -0.7, 0.0, 2);
        let n = 9;
        let tz: Vec<f64> = (0..n * n).map(|k| ((k * 37 % 11) as f64) - 5.0).collect();
        for r in [
            Region {
                x0: 10,
                y0: 12,
                sw: 27,
                sh: 27,
            },
            Region {
                x0: 0,
                y0: 0,
                sw: 40,
                sh: 23,
            },
        ] {
            let size = (r.sw.max(r.sh) as usize).next_power_of_two();
            let (d, ds) = cross_direct(&c, &tz, n, r);
            let (f, fs) = cross_fft(&c, &tz, n, r, size);
            for j in 0..=(r.sh as usize - n) {
                for i in 0..=(r.sw as usize - n) {
                    let (a, b) = (d[j * ds + i], f[j * fs + i]);
                    assert!(
                        (a - b).abs() <= 1e-9 * a.abs().max(1.0),
                        "({i}, {j}): {a} against {b}"
                    );
                }
            }
        }
    }

    #[test]
    fn finds_integer_and_large_shifts() {
        let p = SpeckleParams::default_for(160, 160);
        let s = Speckle::new(&p, 5);
        let r = s.render_shifted(0.0, 0.0, 0.0, 1);
        let c = s.render_shifted(7.0, -5.0, 0.0, 2);
        let hit = search(&r, &c, 80, 80, 15, 10, 0, 0).unwrap();
        assert_eq!((hit.u, hit.v), (7, -5));
        assert!(hit.zncc > 0.99);
        // 37 px away needs the pyramid.
        let c2 = s.render_shifted(37.0, 22.0, 0.0, 3);
        let hit = search_pyramid(&pyramid(&r, 3), &pyramid(&c2, 3), 70, 70, 15, 48).unwrap();
        assert_eq!((hit.u, hit.v), (37, 22));
    }
}
