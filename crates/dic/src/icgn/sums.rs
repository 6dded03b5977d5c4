//! The reference-only sums a subset is prepared with ([`super::prepare_in`]), for every
//! point of a grid at once: rows first, then columns.
//!
//! A subset's Hessian and the sums that eliminate offset and gain are moments of
//! products of the reference's grey levels and gradients: `Σ q·dxᵃ·dyᵇ` over the
//! subset, q one of f, gx, gy, gx·f, gy·f, gx², gx·gy, gy². Summed pixel by pixel
//! that is 31 sums over 1,089 pixels for each point of a 33 x 33 field, where
//! neighbouring subsets share all but a few columns. Here each row's window sums
//! `Σ_x q·dxᵃ` are made once for each of the grid's columns, and each point's sums
//! are its 33 rows' window sums weighted by `dyᵇ`: at step 2 a twentieth of the
//! work, at step 10 a quarter. The sums are the same to rounding (a few parts in
//! 1e14; the test compares them with the pixel-by-pixel pass).

use super::Reference;
use crate::lanes::lane_sums;

/// Window sums of one row at one grid column: Σ over the window's pixels of f,
/// gx, gx·dx, gy, gy·dx, gx·f, gx·f·dx, gy·f, gy·f·dx, and of gx², gx·gy and gy²
/// each times 1, dx and dx².
const ROW: usize = 18;

/// The window sums of every row from `y_lo` at each grid column `xs` (see [`ROW`]),
/// the window `offsets.len()` pixels wide: a vector of the window's pixels at a
/// time, on the machine's vector units.
struct RowSums<'a> {
    /// The reference's grey levels and gradients (x, y), row-major.
    images: [&'a [f64]; 3],
    width: usize,
    xs: &'a [usize],
    y_lo: usize,
    /// Each window pixel's dx from its centre.
    offsets: &'a [f64],
    rows: &'a mut [[f64; ROW]],
}

impl pulp::WithSimd for RowSums<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> Self::Output {
        let RowSums {
            images: [f, gx, gy],
            width,
            xs,
            y_lo,
            offsets,
            rows,
        } = self;
        let n = offsets.len();
        let half = n / 2;
        for (r, out) in rows.chunks_exact_mut(xs.len()).enumerate() {
            let line = (y_lo + r) * width;
            for (o, &cx) in out.iter_mut().zip(xs) {
                let at = line + cx - half;
                let (f, gx, gy) = (&f[at..at + n], &gx[at..at + n], &gy[at..at + n]);
                *o = lane_sums!(n, |a| {
                    let (f, gx, gy, dx) = (a.of(f), a.of(gx), a.of(gy), a.of(offsets));
                    let (hx, hy) = (gx * f, gy * f);
                    let (xx, xy, yy) = (gx * gx, gx * gy, gy * gy);
                    let (xx1, xy1, yy1) = (xx * dx, xy * dx, yy * dx);
                    [
                        f,
                        gx,
                        gx * dx,
                        gy,
                        gy * dx,
                        hx,
                        hx * dx,
                        hy,
                        hy * dx,
                        xx,
                        xx1,
                        xx1 * dx,
                        xy,
                        xy1,
                        xy1 * dx,
                        yy,
                        yy1,
                        yy1 * dx,
                    ]
                });
            }
        }
    }
}

/// A subset's reference-only sums, as [`super::prepare_in`] makes them: `first` is
/// Σf and Σ of J and of J·f for J = [gx, gx·dx, gx·dy, gy, gy·dx, gy·dy]; `second`
/// is, for gx², gx·gy and gy² in turn, Σ of it times 1, dx, dy, dx², dx·dy and dy².
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SubsetSums {
    pub(crate) first: [f64; 13],
    pub(crate) second: [f64; 18],
}

/// [`SubsetSums`] of the square subsets of half side `half` centred at every point
/// `(x0 + i·step, y0 + j·step)`, i < nx, j < ny, of a grid.
#[derive(Debug, Clone)]
pub(crate) struct GridSums {
    origin: (usize, usize),
    step: usize,
    count: (usize, usize),
    half: usize,
    sums: Vec<SubsetSums>,
}

impl GridSums {
    /// The sums of the grid of `count` points (x, y) from `origin`, `step` apart, of
    /// `reference`, subsets of half side `half`; `None` when a subset leaves the
    /// image, the grid is empty or the step is 0.
    pub(crate) fn new(
        reference: &Reference,
        origin: (usize, usize),
        step: usize,
        count: (usize, usize),
        half: usize,
    ) -> Option<Self> {
        let (w, h) = (reference.image.width(), reference.image.height());
        if step == 0 || count.0 == 0 || count.1 == 0 {
            return None;
        }
        let xs: Vec<usize> = (0..count.0).map(|i| origin.0 + i * step).collect();
        let ys = (0..count.1).map(|j| origin.1 + j * step);
        let (x_first, x_last) = (origin.0, origin.0 + (count.0 - 1) * step);
        let (y_first, y_last) = (origin.1, origin.1 + (count.1 - 1) * step);
        if x_first < half || y_first < half || x_last + half >= w || y_last + half >= h {
            return None;
        }
        let (y_lo, y_hi) = (y_first - half, y_last + half);
        let (f, gx, gy) = (reference.image.data(), &reference.gx, &reference.gy);
        // Each row's window sums at each grid column.
        let mut rows = vec![[0.0; ROW]; (y_hi - y_lo + 1) * xs.len()];
        let offsets: Vec<f64> = (0..=2 * half).map(|i| i as f64 - half as f64).collect();
        pulp::Arch::new().dispatch(RowSums {
            images: [f, gx, gy],
            width: w,
            xs: &xs,
            y_lo,
            offsets: &offsets,
            rows: &mut rows,
        });
        // Each point's rows, weighted by dy and dy².
        let mut sums = Vec::with_capacity(count.0 * count.1);
        for cy in ys {
            for i in 0..xs.len() {
                let mut first = [0.0; 13];
                let mut second = [0.0; 18];
                for y in cy - half..=cy + half {
                    let r = &rows[(y - y_lo) * xs.len() + i];
                    let dy = y as f64 - cy as f64;
                    first[0] += r[0];
                    // gx, gy, gx·f, gy·f: times 1, dx, dy.
                    for (q, at) in [(0, 1), (1, 3), (2, 5), (3, 7)] {
                        first[1 + 3 * q] += r[at];
                        first[2 + 3 * q] += r[at + 1];
                        first[3 + 3 * q] += r[at] * dy;
                    }
                    // gx², gx·gy, gy²: times 1, dx, dy, dx², dx·dy, dy².
                    for (q, at) in [(0, 9), (1, 12), (2, 15)] {
                        let (one, x1, x2) = (r[at], r[at + 1], r[at + 2]);
                        let s = &mut second[6 * q..6 * q + 6];
                        s[0] += one;
                        s[1] += x1;
                        s[2] += one * dy;
                        s[3] += x2;
                        s[4] += x1 * dy;
                        s[5] += one * dy * dy;
                    }
                }
                sums.push(SubsetSums { first, second });
            }
        }
        Some(GridSums {
            origin,
            step,
            count,
            half,
            sums,
        })
    }

    /// The sums of the subset of half side `half` centred at (x, y), if it is one of
    /// the grid's.
    pub(crate) fn at(&self, x: usize, y: usize, half: usize) -> Option<&SubsetSums> {
        let (dx, dy) = (x.checked_sub(self.origin.0)?, y.checked_sub(self.origin.1)?);
        let (i, j) = (dx / self.step, dy / self.step);
        let on_grid = dx % self.step == 0 && dy % self.step == 0;
        (half == self.half && on_grid && i < self.count.0 && j < self.count.1)
            .then(|| &self.sums[j * self.count.0 + i])
    }
}

#[cfg(test)]
mod tests {
    use super::super::{RefSubset, Subset, subset_sums};
    use super::*;
    use crate::Degree;
    use crate::synth::{Speckle, SpeckleParams};

    /// Every point of grids of steps 1, 2, 3 and 10 and two subset sizes: the sums
    /// made rows first agree with the pixel-by-pixel pass to 1e-12 of the subset's
    /// largest sum (the two add the same products in other orders).
    #[test]
    fn grid_sums_are_the_subsets_own_sums() {
        let sp = Speckle::new(&SpeckleParams::default_for(120, 100), 5);
        let r = Reference::with_degree(sp.render_shifted(0.0, 0.0, 0.0, 1), Degree::Quintic);
        for (half, step) in [(16, 1), (16, 2), (10, 3), (16, 10), (5, 2)] {
            let xs: Vec<usize> = (half + 1..120 - half - 1).step_by(step).collect();
            let ys: Vec<usize> = (half + 2..100 - half - 1).step_by(step).collect();
            let grid = GridSums::new(&r, (xs[0], ys[0]), step, (xs.len(), ys.len()), half).unwrap();
            for &y in &ys {
                for &x in &xs {
                    let rs = RefSubset::new(&r, x, y, Subset::square(2 * half + 1), None);
                    let (first, second) = subset_sums(&rs);
                    let got = grid.at(x, y, half).unwrap();
                    let scale = first
                        .iter()
                        .chain(&second)
                        .fold(0.0f64, |m, v| m.max(v.abs()));
                    for (a, b) in got
                        .first
                        .iter()
                        .zip(&first)
                        .chain(got.second.iter().zip(&second))
                    {
                        assert!(
                            (a - b).abs() <= 1e-12 * scale,
                            "({x}, {y}) half {half}: {a} against {b}"
                        );
                    }
                }
            }
            // Off the grid, another size, outside: none.
            assert!(grid.at(xs[0] + 1, ys[0], half).is_none() || step == 1);
            assert!(grid.at(xs[0], ys[0], half + 1).is_none());
            assert!(grid.at(xs[0] - 1, ys[0], half).is_none());
        }
        // A subset that leaves the image: no grid.
        assert!(GridSums::new(&r, (10, 50), 1, (1, 1), 16).is_none());
        assert!(GridSums::new(&r, (30, 50), 1, (0, 1), 16).is_none());
    }
}
