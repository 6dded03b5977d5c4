//! Integer-pixel search by zero-normalised cross-correlation (ZNCC), computed for every
//! candidate shift at once through the FFT, with the local means and energies of the
//! search region from integral images (Lewis, "Fast normalized cross-correlation", 1995);
//! where the candidates are few (a refinement within ±2 px, a small template at a
//! pyramid's top) the cross-correlation is summed directly, which costs less than the
//! three transforms. Coarse-to-fine over an image pyramid for large jumps.

use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

use crate::image::Image;
use crate::lanes::LANES;

/// Best integer shift of a subset and its ZNCC.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IntegerMatch {
    /// Shift along x (columns), pixels.
    pub u: i64,
    /// Shift along y (rows), pixels.
    pub v: i64,
    /// ZNCC at the shift (−1..1).
    pub zncc: f64,
    /// Where the correlation peaks within the pixel along x and y, pixels in
    /// [−0.5, 0.5]: the vertex of the parabola through the ZNCC at the shift and at
    /// its two neighbours along each axis (0 where a neighbour lies outside the
    /// search or the three do not bend down). A start for sub-pixel refinement
    /// within about a tenth of a pixel on speckle, where the whole shift is still
    /// a step or two of IC-GN away.
    pub sub: (f64, f64),
}

impl IntegerMatch {
    /// The shift with its sub-pixel peak: (u + sub.0, v + sub.1), pixels.
    pub fn refined(&self) -> (f64, f64) {
        (self.u as f64 + self.sub.0, self.v as f64 + self.sub.1)
    }
}

/// The vertex of the parabola through (−1, a), (0, b), (1, c), in [−0.5, 0.5]; 0
/// unless the three bend down about b.
fn parabola_vertex(a: f64, b: f64, c: f64) -> f64 {
    let bend = a - 2.0 * b + c;
    if bend < 0.0 && a <= b && c <= b {
        (0.5 * (a - c) / bend).clamp(-0.5, 0.5)
    } else {
        0.0
    }
}

thread_local! {
    /// Each thread's FFT plans, kept from one search to the next.
    static PLANNER: std::cell::RefCell<FftPlanner<f64>> = std::cell::RefCell::new(FftPlanner::new());
}

/// The 2-D FFT of the `w x h` row-major `data`, in place (forward, or inverse without
/// the `1/(w·h)`): the rows, then the columns.
pub(crate) fn fft2(
    planner: &mut FftPlanner<f64>,
    data: &mut [Complex<f64>],
    (w, h): (usize, usize),
    inverse: bool,
) {
    let (fr, fc) = if inverse {
        (planner.plan_fft_inverse(w), planner.plan_fft_inverse(h))
    } else {
        (planner.plan_fft_forward(w), planner.plan_fft_forward(h))
    };
    for row in data.chunks_mut(w) {
        fr.process(row);
    }
    let mut col = vec![Complex::new(0.0, 0.0); h];
    for x in 0..w {
        for y in 0..h {
            col[y] = data[y * w + x];
        }
        fc.process(&mut col);
        for y in 0..h {
            data[y * w + x] = col[y];
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
    BUFFERS.with(|b| {
        pulp::Arch::new().dispatch(SearchIn {
            reference,
            current,
            at: (x, y, m),
            r: Region { x0, y0, sw, sh },
            size,
            b: &mut b.borrow_mut(),
        })
    })
}

/// A search's buffers, kept per thread: point mode searches at every point, and
/// nothing is allocated per point (the FFT path, for wide searches, aside).
#[derive(Default)]
struct Buffers {
    /// The zero-mean template, row-major.
    tz: Vec<f64>,
    /// The cross-correlation at every candidate offset.
    cross: Vec<f64>,
    /// The search region with padded rows.
    region: Vec<f64>,
    /// The region's and its square's column sums over one row of candidates.
    s1: Vec<f64>,
    s2: Vec<f64>,
    /// The region's variance over each candidate window, row-major (0: flat).
    var: Vec<f64>,
}

thread_local! {
    static BUFFERS: std::cell::RefCell<Buffers> = std::cell::RefCell::new(Buffers::default());
}

/// [`search`] of the `n x n` template centred at (x, y) (`at` = (x, y, m), n = 2m + 1)
/// over the region `r` of `current`, in `b`'s buffers, compiled for the machine's
/// vector units.
struct SearchIn<'a> {
    reference: &'a Image,
    current: &'a Image,
    at: (i64, i64, i64),
    r: Region,
    size: usize,
    b: &'a mut Buffers,
}

impl pulp::WithSimd for SearchIn<'_> {
    type Output = Option<IntegerMatch>;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> Self::Output {
        let SearchIn {
            reference,
            current,
            at: (x, y, m),
            r,
            size,
            b,
        } = self;
        let Region { x0, y0, sw, sh } = r;
        let n = 2 * m + 1;
        // Zero-mean template.
        let nn = n as usize;
        let tz = &mut b.tz;
        tz.clear();
        let (rd, rw) = (reference.data(), reference.width());
        for j in 0..nn {
            let start = (y - m) as usize * rw + j * rw + (x - m) as usize;
            tz.extend_from_slice(&rd[start..start + nn]);
        }
        let tm = tz.iter().sum::<f64>() / tz.len() as f64;
        for v in tz.iter_mut() {
            *v -= tm;
        }
        let t_energy = tz.iter().map(|v| v * v).sum::<f64>().sqrt();
        if t_energy == 0.0 {
            return None;
        }
        // The cross-correlation of the zero-mean template with the region at every
        // candidate offset (i, j), row-major with `stride`: summed directly where that
        // costs less than three transforms of `size`², else through the FFT.
        let candidates = ((sw - n + 1) * (sh - n + 1)) as usize;
        let transforms = 3 * size * size * (2 * size.trailing_zeros() as usize).max(1) * 2;
        let stride = if candidates * nn * nn <= transforms {
            cross_direct(current, tz, nn, r, &mut b.cross, &mut b.region)
        } else {
            let (c, stride) = cross_fft(current, tz, nn, r, size);
            b.cross = c;
            stride
        };
        let cross = &b.cross;
        // The region's and its square's sums over every candidate window: for each row
        // of candidates, the columns' sums over the window's n rows (side by side on the
        // vector units), then n of those. Summed from the pixels, without the rounding of
        // differences of running sums.
        let (cols, rows) = ((sw - n + 1) as usize, (sh - n + 1) as usize);
        let swu = sw as usize;
        let (data, cw) = (current.data(), current.width());
        let (c1, c2) = (&mut b.s1, &mut b.s2);
        let area = (n * n) as f64;
        // The best candidate so far, by ZNCC = num / (|t|·√var), compared as num·|num|
        // / var (the same order, without a root or a division per candidate): its
        // offset, num and var.
        let mut best: Option<(usize, usize, f64, f64)> = None;
        b.var.clear();
        b.var.resize(rows * cols, 0.0);
        for j in 0..rows {
            for c in [&mut *c1, &mut *c2] {
                c.clear();
                c.resize(swu, 0.0);
            }
            for jj in 0..nn {
                let start = (y0 as usize + j + jj) * cw + x0 as usize;
                let row = &data[start..start + swu];
                for ((a, a2), &v) in c1.iter_mut().zip(c2.iter_mut()).zip(row) {
                    *a += v;
                    *a2 += v * v;
                }
            }
            for i in 0..cols {
                let sum: f64 = c1[i..i + nn].iter().sum();
                let sum2: f64 = c2[i..i + nn].iter().sum();
                let var = sum2 - sum * sum / area;
                if var <= 0.0 {
                    continue;
                }
                b.var[j * cols + i] = var;
                let num = cross[j * stride + i];
                let better = match best {
                    None => true,
                    Some((_, _, bn, bv)) => num * num.abs() * bv > bn * bn.abs() * var,
                };
                if better {
                    best = Some((i, j, num, var));
                }
            }
        }
        let (i, j, num, var) = best?;
        let zncc = num / (t_energy * var.sqrt());
        // The ZNCC at candidate (i + di, j + dj), None outside the search or flat.
        let at = |di: isize, dj: isize| {
            let (ii, jj) = (i.checked_add_signed(di)?, j.checked_add_signed(dj)?);
            if ii >= cols || jj >= rows {
                return None;
            }
            let var = b.var[jj * cols + ii];
            (var > 0.0).then(|| cross[jj * stride + ii] / (t_energy * var.sqrt()))
        };
        let vertex = |a: Option<f64>, c: Option<f64>| match (a, c) {
            (Some(a), Some(c)) => parabola_vertex(a, zncc, c),
            _ => 0.0,
        };
        let sub = (vertex(at(-1, 0), at(1, 0)), vertex(at(0, -1), at(0, 1)));
        zncc.is_finite().then_some(IntegerMatch {
            u: x0 + i as i64 + m - x,
            v: y0 + j as i64 + m - y,
            zncc,
            sub,
        })
    }
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
/// `current` at every candidate offset (i, j), into `out` (row-major; returns the
/// stride, the number of columns), summed directly (inlined into [`SearchIn`], so on
/// the machine's vector units): lanes over [`LANES`] neighbouring candidates of a
/// row, four such groups at a time (each sum in order over the template). The region is first copied with its rows
/// padded to whole vectors (`region`, a buffer), so that every load is a whole
/// vector and the sums keep no index to check.
#[inline(always)]
fn cross_direct(
    current: &Image,
    tz: &[f64],
    n: usize,
    r: Region,
    out: &mut Vec<f64>,
    region: &mut Vec<f64>,
) -> usize {
    let (cols, rows) = (r.sw as usize + 1 - n, r.sh as usize + 1 - n);
    let (data, cw) = (current.data(), current.width());
    out.clear();
    out.resize(cols * rows, 0.0);
    // The region's rows, each padded with zeros to whole vectors of candidates.
    let chunks = cols.div_ceil(LANES);
    let stride = chunks * LANES + n - 1;
    let sw = cols + n - 1;
    region.clear();
    region.resize(stride * (rows + n - 1), 0.0);
    let region = &mut region[..];
    for (y, dst) in region.chunks_exact_mut(stride).enumerate() {
        let start = (r.y0 as usize + y) * cw + r.x0 as usize;
        dst[..sw].copy_from_slice(&data[start..start + sw]);
    }
    // A unit is LANES candidates of one row (lanes over the candidates); BLOCK
    // units are summed side by side, each template value times the region's
    // pixels from its tap, so that BLOCK independent sums keep the vector units
    // busy (one alone waits on each addition). A last, partial block repeats its
    // last unit; lanes past a row's end are not kept.
    const BLOCK: usize = 4;
    let units = rows * chunks;
    let origin = |u: usize| (u / chunks) * stride + (u % chunks) * LANES;
    for u0 in (0..units).step_by(BLOCK) {
        let base: [usize; BLOCK] = std::array::from_fn(|b| origin((u0 + b).min(units - 1)));
        let mut acc = [[0.0; LANES]; BLOCK];
        for (jj, trow) in tz.chunks_exact(n).enumerate() {
            let line = |b: usize| {
                let start = base[b] + jj * stride;
                region[start..start + n + LANES - 1].windows(LANES)
            };
            let taps = trow
                .iter()
                .zip(line(0))
                .zip(line(1))
                .zip(line(2))
                .zip(line(3));
            for ((((&t, v0), v1), v2), v3) in taps {
                for (b, v) in [v0, v1, v2, v3].into_iter().enumerate() {
                    for l in 0..LANES {
                        acc[b][l] += t * v[l];
                    }
                }
            }
        }
        for (b, sums) in acc.iter().enumerate().take(units - u0) {
            let u = u0 + b;
            let (q, c) = (u / chunks, (u % chunks) * LANES);
            let w = (cols - c).min(LANES);
            out[q * cols + c..q * cols + c + w].copy_from_slice(&sums[..w]);
        }
    }
    cols
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
        fft2(&mut planner, &mut a, (size, size), false);
        fft2(&mut planner, &mut b, (size, size), false);
        for (p, q) in a.iter_mut().zip(&b) {
            *p *= q.conj();
        }
        fft2(&mut planner, &mut a, (size, size), true);
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
            // Fewer candidates in a row than a vector holds.
            Region {
                x0: 50,
                y0: 30,
                sw: 14,
                sh: 13,
            },
        ] {
            let size = (r.sw.max(r.sh) as usize).next_power_of_two();
            let mut d = Vec::new();
            let ds = cross_direct(&c, &tz, n, r, &mut d, &mut Vec::new());
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

    /// The parabola's vertex: exact on a parabola, 0 where the three do not bend
    /// down about the middle, never beyond half a pixel.
    #[test]
    fn the_parabola_vertex_is_exact_on_a_parabola_and_bounded() {
        for x0 in [-0.4, -0.1, 0.0, 0.25, 0.45] {
            let f = |x: f64| 0.9 - 0.3 * (x - x0) * (x - x0);
            assert!((parabola_vertex(f(-1.0), f(0.0), f(1.0)) - x0).abs() < 1e-12);
        }
        assert_eq!(parabola_vertex(0.5, 0.4, 0.3), 0.0);
        assert_eq!(parabola_vertex(0.1, 0.5, 0.1), 0.0);
        assert_eq!(parabola_vertex(0.3, 0.4, 0.5), 0.0);
        // Two equal highest: the vertex midway between them.
        assert_eq!(parabola_vertex(0.4, 0.4, -0.5), -0.5);
    }

    /// The sub-pixel peak of the search brings the start within a fifth of a pixel of
    /// a sub-pixel shift the integer search leaves up to half a pixel off, over a
    /// sweep of shifts and places (the worst case printed).
    #[test]
    fn the_sub_pixel_peak_starts_nearer_the_shift_than_the_whole_pixel() {
        let s = Speckle::new(&SpeckleParams::default_for(160, 160), 9);
        let r = s.render_shifted(0.0, 0.0, 0.0, 1);
        let (mut worst, mut whole) = (0.0f64, 0.0f64);
        for (k, (u, v)) in [
            (0.3, -0.2),
            (1.45, 0.1),
            (-2.6, 3.35),
            (0.5, -0.5),
            (4.1, -0.9),
        ]
        .into_iter()
        .enumerate()
        {
            let c = s.render_shifted(u, v, 0.0, 2 + k as u64);
            for (x, y) in [(50, 50), (80, 90), (110, 70)] {
                let hit = search(&r, &c, x, y, 15, 6, 0, 0).unwrap();
                let (ru, rv) = hit.refined();
                worst = worst.max((ru - u).abs()).max((rv - v).abs());
                whole = whole
                    .max((hit.u as f64 - u).abs())
                    .max((hit.v as f64 - v).abs());
                assert!(hit.sub.0.abs() <= 0.5 && hit.sub.1.abs() <= 0.5);
            }
        }
        println!("worst start error: {worst:.3} px from the peak, {whole:.3} px whole pixels");
        assert!(worst < 0.2, "{worst}");
        assert!(worst < whole, "{worst} against {whole}");
    }
}
