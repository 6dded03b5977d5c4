//! Integer-pixel search by zero-normalised cross-correlation (ZNCC), computed for every
//! candidate shift at once through the FFT, with the local means and energies of the
//! search region from integral images (Lewis, "Fast normalized cross-correlation", 1995).
//! Coarse-to-fine over an image pyramid for large jumps.

use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

use crate::image::Image;

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
    let t_energy = t.iter().map(|v| (v - tm).powi(2)).sum::<f64>().sqrt();
    if t_energy == 0.0 {
        return None;
    }
    let zero = Complex::new(0.0, 0.0);
    let mut a = vec![zero; size * size];
    let mut b = vec![zero; size * size];
    for j in 0..sh {
        for i in 0..sw {
            a[j as usize * size + i as usize].re = current.at((x0 + i) as usize, (y0 + j) as usize);
        }
    }
    for j in 0..n {
        for i in 0..n {
            b[j as usize * size + i as usize].re = t[(j * n + i) as usize] - tm;
        }
    }
    let mut planner = FftPlanner::new();
    fft2(&mut planner, &mut a, size, false);
    fft2(&mut planner, &mut b, size, false);
    for (p, q) in a.iter_mut().zip(&b) {
        *p *= q.conj();
    }
    fft2(&mut planner, &mut a, size, true);
    let scale = 1.0 / (size * size) as f64;
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
            let num = a[j * size + i].re * scale;
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
