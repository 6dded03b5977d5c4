//! Full-field DIC on a regular grid with reliability-guided propagation (Pan, Appl. Opt.
//! 48, 2009): from a seed found by the FFT search, the most reliable computed point
//! (highest ZNCC) hands its deformation to its uncomputed neighbours as their initial
//! guess, so IC-GN converges in a few iterations and no point needs its own search. The
//! grid is cut into tiles, each grown from its own seed, in parallel with rayon; the
//! tiling does not depend on the number of threads, so results are reproducible.
//!
//! Every point is computed by [`measure`](crate::accept::measure), as in the point
//! mode: a point whose predicted σ is too large for the rule is tried again with larger
//! subsets (the self-adaptive subset, [`FieldOptions::adaptive_subset`]; each result
//! records its subset size).
//! Every computed point goes through [`judge`], the rule of the point mode: a point it
//! rejects is not reported, and is counted in [`Field::dropped`]; one that did not
//! converge or has a low ZNCC is not used as a starting guess either. (A neighbour's guess lets IC-GN converge where the point mode's
//! own search would not, so without the rule the field reported points the point mode
//! refused.)
//!
//! A tile is seeded near its centre, then over a lattice spread across it, so that a
//! centre on a featureless patch does not leave the whole tile unmeasured. Once every
//! tile is done, a kept point that its grid neighbours contradict, or that no kept
//! neighbour confirms, is dropped too ([`Dropped::inconsistent`]): the normalised
//! median test of PIV on the pairs of neighbours facing each other across it, with the
//! noise level taken from the predicted σ.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use rayon::prelude::*;

use crate::accept::{Acceptance, Dropped, Rejection, judge, measure_on_grid};
use crate::correction::Corrections;
use crate::icgn::{GridSums, IcgnOptions, PointResult, Scratch, Shape};
use crate::search;
use crate::{Degree, DicError, Image, check_subset};

/// Options of a full-field run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldOptions {
    /// Grid step, pixels.
    pub step: usize,
    /// Odd subset size, pixels.
    pub subset: usize,
    /// Self-adaptive subset: a point whose result the acceptance rule rejects only for
    /// its predicted σ is tried again with larger subsets, up to twice the size
    /// ([`crate::accept::measure`]; each result says which size it used).
    pub adaptive_subset: bool,
    /// Shape function.
    pub shape: Shape,
    /// Largest displacement the seeds search for, pixels.
    pub search_radius: usize,
    /// What makes a point a measurement (the point mode's rule); the others are
    /// dropped.
    pub acceptance: Acceptance,
    /// Most grid points per tile side (each tile grows from its own seed). The grid
    /// is cut into as few tiles along each axis as this allows, all of one size (the
    /// last a little smaller where the grid does not divide evenly), and never fewer
    /// than [`MIN_TILES_PER_SIDE`] where the grid has points enough: tiles of equal
    /// work keep every thread busy to the end, whichever their number.
    pub tile: usize,
    /// Sigma of an optional Gaussian prefilter of both images, pixels (0 = none).
    pub prefilter: f64,
    /// Degree of the B-spline interpolant of both images (quintic by default here; cubic
    /// for comparison: [`crate::bspline::Degree`]).
    pub spline: Degree,
    /// Iteration control.
    pub icgn: IcgnOptions,
    /// Threads to correlate on (0: rayon's pool, all the cores by default). The tiling
    /// does not depend on it, so neither does the result.
    pub threads: usize,
}

impl Default for FieldOptions {
    fn default() -> Self {
        FieldOptions {
            step: 5,
            subset: 31,
            adaptive_subset: true,
            shape: Shape::Affine,
            search_radius: 64,
            acceptance: Acceptance::default(),
            tile: 32,
            prefilter: 0.0,
            spline: Degree::Quintic,
            icgn: IcgnOptions {
                tolerance: crate::icgn::MEASUREMENT_TOLERANCE,
                ..IcgnOptions::default()
            },
            threads: 0,
        }
    }
}

/// The result on the grid.
#[derive(Debug, Clone)]
pub struct Field {
    /// Grid columns.
    pub nx: usize,
    /// Grid rows.
    pub ny: usize,
    /// Column of the first grid point.
    pub x0: usize,
    /// Row of the first grid point.
    pub y0: usize,
    /// Grid step.
    pub step: usize,
    /// Row-major measurements (`None`: not reached, no match, or dropped).
    pub points: Vec<Option<PointResult>>,
    /// Points computed but rejected by the acceptance rule, by reason.
    pub dropped: Dropped,
}

#[derive(PartialEq)]
struct Candidate {
    zncc: f64,
    index: usize,
}

impl Eq for Candidate {}

impl PartialOrd for Candidate {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Candidate {
    fn cmp(&self, other: &Self) -> Ordering {
        self.zncc
            .total_cmp(&other.zncc)
            .then_with(|| other.index.cmp(&self.index))
    }
}

/// Whether a computed point hands its deformation to its neighbours as their starting
/// guess: when it converged at a ZNCC the rule accepts. A point dropped only for its
/// predicted σ still does (it is likely close, and each neighbour is judged on its
/// own), or a band of weak texture would cut the rest of its tile off.
fn propagates(verdict: Result<(), Rejection>) -> bool {
    matches!(verdict, Ok(()) | Err(Rejection::Uncertain))
}

/// Fewest tiles along each axis of a grid with at least [`MIN_TILE`] points per tile
/// there: 16 tiles of equal size share out evenly over 1, 2, 4, 8 or 16 threads, and
/// over 3 to within one tile.
pub const MIN_TILES_PER_SIDE: usize = 4;

/// Fewest grid points along a tile's side from the cut into [`MIN_TILES_PER_SIDE`]
/// (each tile pays for a seed's search).
pub const MIN_TILE: usize = 8;

/// The tiles' side along an axis of `n` grid points, at most `most`
/// ([`FieldOptions::tile`]): `n` cut into equal parts.
fn tile_side(n: usize, most: usize) -> usize {
    let most = most.max(1);
    let parts = n
        .div_ceil(most)
        .max(MIN_TILES_PER_SIDE.min(n / MIN_TILE))
        .max(1);
    n.div_ceil(parts)
}

/// Candidates nearest the centre tried as a tile's seed before [`seed_candidates`]
/// spreads out over the tile.
const SEEDS_AT_CENTRE: usize = 8;

/// Side of the lattice of further seed candidates spread over a tile.
const SEED_LATTICE: usize = 4;

/// The grid points of a `tw` x `th` tile tried in turn as its seed: the
/// [`SEEDS_AT_CENTRE`] nearest its centre, then a [`SEED_LATTICE`]² lattice spread over
/// the tile, nearest the centre first. A tile whose centre falls on a featureless
/// patch (a sky, a dark coat without noise to texture it) is seeded where it has
/// texture; with the centre's neighbours alone the whole tile was left unmeasured
/// (camera_sky_coat with both frames exposed at (−1.13, 2.5) px: 1095 of 2025 grid
/// points, a 32 x 32-point tile, never reached).
fn seed_candidates(tw: usize, th: usize) -> Vec<(usize, usize)> {
    let centre = (tw / 2, th / 2);
    let distance = |&(i, j): &(usize, usize)| i.abs_diff(centre.0) + j.abs_diff(centre.1);
    let mut near: Vec<(usize, usize)> =
        (0..th).flat_map(|j| (0..tw).map(move |i| (i, j))).collect();
    near.sort_by_key(distance);
    near.truncate(SEEDS_AT_CENTRE);
    let lattice = |n: usize| -> Vec<usize> {
        (0..SEED_LATTICE)
            .map(|k| ((2 * k + 1) * n / (2 * SEED_LATTICE)).min(n - 1))
            .collect()
    };
    let (xs, ys) = (lattice(tw), lattice(th));
    let mut spread: Vec<(usize, usize)> = Vec::new();
    for p in ys.iter().flat_map(|&j| xs.iter().map(move |&i| (i, j))) {
        if !near.contains(&p) && !spread.contains(&p) {
            spread.push(p);
        }
    }
    spread.sort_by_key(distance);
    near.extend(spread);
    near
}

/// Threshold of the normalised median test ([`inconsistent`]), Westerweel & Scarano's.
const MEDIAN_TEST_THRESHOLD: f64 = 2.0;

/// The kept points of a field that their neighbours contradict: the normalised median
/// test of PIV (Westerweel & Scarano, "Universal outlier detection for PIV data",
/// Exp. Fluids 39, 2005) on the 8 grid neighbours, taken as the 4 pairs facing each
/// other across the point (left and right, above and below, the two diagonals), each
/// pair's mean the value it predicts at the point: exact in any linear field, also at
/// the field's edges, where the median of one-sided neighbours is off by a step's
/// strain. Neighbours are not carried to the point by their own gradients: on a smooth
/// sky the affine shape's gradients are noise (0.03 over a 5 px step is 0.15 px) that
/// hid an outlier 0.10 px off. The noise level ε is taken from the predicted σ of the
/// point and of the pairs' points (`√(σ² + median σₙ²)`, per axis) rather than a fixed
/// 0.1 px. A point is an outlier when `|u − median pᵢ| / (median |pᵢ − median pᵢ| +
/// ε)` exceeds [`MEDIAN_TEST_THRESHOLD`] in u or v, pᵢ the pairs' predictions; or when
/// no neighbour was kept to confirm it. A point with kept neighbours but no complete
/// pair, or the one point of a 1 x 1 grid, is kept (nothing to test it against). Neighbouring subsets overlap, so their
/// errors are correlated and the test is lenient. The rule of each point ([`judge`])
/// cannot see these: with both frames rounded and little or no noise, where a smooth
/// sky meets an edge, a match can settle 0.1-0.26 px off with a σ of 0.02 px
/// (camera_sky_coat, `tests/real_images.rs`): each was alone, or 3 of its ε from its
/// pairs.
fn inconsistent(points: &[Option<PointResult>], nx: usize, ny: usize) -> Vec<usize> {
    use cellinject_numeric::median;
    let at = |gx: usize, gy: usize, di: i64, dj: i64| -> Option<PointResult> {
        let (i, j) = (gx as i64 + di, gy as i64 + dj);
        if i < 0 || j < 0 || i >= nx as i64 || j >= ny as i64 {
            return None;
        }
        points[j as usize * nx + i as usize]
    };
    const PAIRS: [(i64, i64); 4] = [(1, 0), (0, 1), (1, 1), (1, -1)];
    // Each point on its own (in parallel, in grid order).
    let outlier = |k: usize| -> bool {
        let Some(p) = points[k] else { return false };
        let (gx, gy) = (k % nx, k / nx);
        // In the grid at all, and none of them kept (a grid of one point has no
        // neighbour to ask).
        let (mut in_grid, mut kept) = (0, 0);
        for dj in -1..=1 {
            for di in -1..=1 {
                let (i, j) = (gx as i64 + di, gy as i64 + dj);
                if (di, dj) != (0, 0) && i >= 0 && j >= 0 && i < nx as i64 && j < ny as i64 {
                    in_grid += 1;
                    kept += usize::from(at(gx, gy, di, dj).is_some());
                }
            }
        }
        if in_grid > 0 && kept == 0 {
            return true;
        }
        // The pairs' means and both members' σ, in fixed arrays (no allocation per
        // point): `n` pairs complete.
        let (mut us, mut vs, mut sus, mut svs) = ([0.0; 4], [0.0; 4], [0.0; 8], [0.0; 8]);
        let mut n = 0;
        for (di, dj) in PAIRS {
            if let (Some(a), Some(b)) = (at(gx, gy, di, dj), at(gx, gy, -di, -dj)) {
                us[n] = 0.5 * (a.u + b.u);
                vs[n] = 0.5 * (a.v + b.v);
                [sus[2 * n], sus[2 * n + 1]] = [a.sigma_u, b.sigma_u];
                [svs[2 * n], svs[2 * n + 1]] = [a.sigma_v, b.sigma_v];
                n += 1;
            }
        }
        if n == 0 {
            return false;
        }
        let test = |own: f64, sigma: f64, values: &mut [f64], sigmas: &mut [f64]| {
            let m = median(values);
            let mut spread = [0.0; 4];
            for (s, x) in spread.iter_mut().zip(values.iter()) {
                *s = (x - m).abs();
            }
            let r = median(&mut spread[..values.len()]);
            let eps = sigma.hypot(median(sigmas));
            (own - m).abs() > MEDIAN_TEST_THRESHOLD * (r + eps)
        };
        test(p.u, p.sigma_u, &mut us[..n], &mut sus[..2 * n])
            || test(p.v, p.sigma_v, &mut vs[..n], &mut svs[..2 * n])
    };
    (0..points.len())
        .into_par_iter()
        .filter(|&k| outlier(k))
        .collect()
}

/// One tile's propagation: what is kept, the starting guesses, what was dropped and
/// the points waiting to hand on their guess.
struct Tile {
    out: Vec<Option<PointResult>>,
    /// Every converged result, kept or not: the starting guesses.
    guess: Vec<Option<PointResult>>,
    dropped: Dropped,
    heap: BinaryHeap<Candidate>,
}

impl Tile {
    fn new(n: usize) -> Self {
        Tile {
            out: vec![None; n],
            guess: vec![None; n],
            dropped: Dropped::default(),
            heap: BinaryHeap::new(),
        }
    }

    /// Judges the computed point `k`: kept or counted as dropped, remembered as a guess,
    /// and queued to hand it on when it [`propagates`] (returned).
    fn keep(&mut self, k: usize, p: PointResult, acceptance: &crate::Acceptance) -> bool {
        let verdict = judge(&p, acceptance);
        self.guess[k] = Some(p);
        match verdict {
            Ok(()) => self.out[k] = Some(p),
            Err(why) => self.dropped.add(why),
        }
        let hands_on = propagates(verdict);
        if hands_on {
            self.heap.push(Candidate {
                zncc: p.zncc,
                index: k,
            });
        }
        hands_on
    }
}

/// Per tile: (grid index, measurement) pairs and the tile's dropped points.
type TileResult = (Vec<(usize, Option<PointResult>)>, Dropped);

/// What every tile of a field shares: the images' splines and pyramids, the grid,
/// the options, and the count of grid points done (for the progress callback).
struct TileJob<'a> {
    r: &'a crate::icgn::Reference,
    s: &'a crate::bspline::BSpline,
    pr: &'a [Image],
    pc: &'a [Image],
    /// Half the subset, pixels.
    m: usize,
    x0: usize,
    y0: usize,
    step: usize,
    nx: usize,
    ny: usize,
    /// Tile sides, grid points along x and y.
    tile: (usize, usize),
    opts: &'a FieldOptions,
    icgn: &'a IcgnOptions,
    corrections: &'a Corrections<'a>,
    finished: std::sync::atomic::AtomicUsize,
    progress: &'a (dyn Fn(usize, usize) + Sync),
}

impl TileJob<'_> {
    /// Grid point (gx, gy) in pixels.
    fn grid(&self, gx: usize, gy: usize) -> (usize, usize) {
        (self.x0 + gx * self.step, self.y0 + gy * self.step)
    }

    /// One point measured from `init` ([`measure_on_grid`], with the tile's `sums`).
    fn refine(
        &self,
        (px, py): (usize, usize),
        init: [f64; 6],
        scratch: &mut Scratch,
        sums: Option<&GridSums>,
    ) -> Option<PointResult> {
        let opts = self.opts;
        measure_on_grid(
            self.r,
            self.s,
            (px, py),
            (opts.subset, opts.adaptive_subset, opts.shape),
            init,
            (self.icgn, &opts.acceptance),
            self.corrections,
            scratch,
            sums,
        )
    }

    /// Tile (tx, ty): seeded, then grown from neighbour to neighbour.
    fn grow(&self, tx: usize, ty: usize) -> TileResult {
        let (nx, ny, (sx, sy)) = (self.nx, self.ny, self.tile);
        let opts = self.opts;
        let (gx0, gy0) = (tx * sx, ty * sy);
        let (gx1, gy1) = ((gx0 + sx).min(nx), (gy0 + sy).min(ny));
        let (tw, th) = (gx1 - gx0, gy1 - gy0);
        let mut work = Tile::new(tw * th);
        let mut scratch = Scratch::default();
        let mut done = vec![false; tw * th];
        // The reference-only sums of the tile's subsets, made together.
        let origin = self.grid(gx0, gy0);
        let sums = GridSums::new(self.r, origin, self.step, (tw, th), opts.subset / 2);
        let sums = sums.as_ref();
        // Seed: the tile centre, then spiralling candidates until one the rule
        // accepts. A match rejected only for its σ hands its guess on to its
        // neighbours, but as a seed it may be anywhere: on a featureless patch
        // (sky) a wrong integer peak converges to a ZNCC of 0.999 with an infinite
        // σ, and the whole tile follows it. Such a seed is used only when none of
        // the candidates is accepted; the others are left for the propagation.
        let order = seed_candidates(tw, th);
        let mut fallback = None;
        let mut seeded = false;
        for &(i, j) in &order {
            let (px, py) = self.grid(gx0 + i, gy0 + j);
            let hit = search::search_pyramid(
                self.pr,
                self.pc,
                px as i64,
                py as i64,
                self.m as i64,
                opts.search_radius as i64,
            );
            let Some(hit) = hit else { continue };
            let (u, v) = hit.refined();
            let init = [u, 0.0, 0.0, v, 0.0, 0.0];
            let k = j * tw + i;
            match self.refine((px, py), init, &mut scratch, sums) {
                Some(p) if judge(&p, &opts.acceptance).is_ok() => {
                    done[k] = true;
                    work.keep(k, p, &opts.acceptance);
                    seeded = true;
                    break;
                }
                Some(p) if fallback.is_none() && propagates(judge(&p, &opts.acceptance)) => {
                    fallback = Some((k, p));
                }
                _ => {}
            }
        }
        if !seeded && let Some((k, p)) = fallback {
            done[k] = true;
            work.keep(k, p, &opts.acceptance);
        }
        while let Some(Candidate { index, .. }) = work.heap.pop() {
            let Some(parent) = work.guess[index] else {
                continue;
            };
            let (i, j) = (index % tw, index / tw);
            let neighbours = [
                (i as i64 - 1, j as i64),
                (i as i64 + 1, j as i64),
                (i as i64, j as i64 - 1),
                (i as i64, j as i64 + 1),
            ];
            for (ni, nj) in neighbours {
                if ni < 0 || nj < 0 || ni >= tw as i64 || nj >= th as i64 {
                    continue;
                }
                let k = nj as usize * tw + ni as usize;
                if done[k] {
                    continue;
                }
                done[k] = true;
                let (px, py) = self.grid(gx0 + ni as usize, gy0 + nj as usize);
                let (dx, dy) = (px as f64 - parent.x, py as f64 - parent.y);
                let [ux, uy, vx, vy] = parent.gradients;
                let init = [
                    parent.u + ux * dx + uy * dy,
                    ux,
                    uy,
                    parent.v + vx * dx + vy * dy,
                    vx,
                    vy,
                ];
                if let Some(p) = self.refine((px, py), init, &mut scratch, sums) {
                    work.keep(k, p, &opts.acceptance);
                }
            }
        }
        let total = self
            .finished
            .fetch_add(tw * th, std::sync::atomic::Ordering::Relaxed)
            + tw * th;
        (self.progress)(total, nx * ny);
        let points = (0..tw * th)
            .map(|k| {
                let (i, j) = (k % tw, k / tw);
                ((gy0 + j) * nx + gx0 + i, work.out[k])
            })
            .collect();
        (points, work.dropped)
    }
}

/// Computes the displacement field between two images.
pub fn field(reference: &Image, current: &Image, opts: &FieldOptions) -> Result<Field, DicError> {
    field_with_progress(reference, current, opts, &|_, _| {})
}

/// [`field`], calling `progress(done, total)` with the grid points computed so far
/// each time a tile is done (from the worker threads, in any order of tiles; `done`
/// only grows).
pub fn field_with_progress(
    reference: &Image,
    current: &Image,
    opts: &FieldOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Field, DicError> {
    if opts.threads > 0 {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(opts.threads)
            .build()
            .map_err(|e| DicError::Threads {
                threads: opts.threads,
                reason: e.to_string(),
            })?;
        let single = FieldOptions {
            threads: 0,
            ..*opts
        };
        return pool.install(|| field_with_progress(reference, current, &single, progress));
    }
    check_subset(opts.subset)?;
    if (reference.width(), reference.height()) != (current.width(), current.height()) {
        return Err(DicError::SizeMismatch {
            a: (reference.width(), reference.height()),
            b: (current.width(), current.height()),
        });
    }
    let m = opts.subset / 2;
    let step = opts.step.max(1);
    let (w, h) = (reference.width(), reference.height());
    if w < opts.subset + 4 || h < opts.subset + 4 {
        return Err(DicError::SubsetOutside {
            x: 0.5 * w as f64,
            y: 0.5 * h as f64,
            size: opts.subset,
            width: w,
            height: h,
        });
    }
    // Keep one pixel more than the subset from the border for the spline.
    let x0 = m + 1;
    let y0 = m + 1;
    let nx = (w - 2 * m - 2 - 1) / step + 1;
    let ny = (h - 2 * m - 2 - 1) / step + 1;
    let crate::Prepared {
        r,
        s,
        pr,
        pc,
        floor,
        step: q,
        rounding,
    } = crate::Prepared::new(
        reference,
        current,
        opts.search_radius,
        opts.prefilter,
        opts.spline,
        opts.icgn.quantisation_step,
    );
    let icgn_opts = IcgnOptions {
        residual_floor: opts.icgn.residual_floor.max(floor),
        quantisation_step: q,
        ..opts.icgn
    };
    let corrections = Corrections::with_rounding(&r, opts.spline, rounding);
    let job = TileJob {
        r: &r,
        s: &s,
        pr: &pr,
        pc: &pc,
        m,
        x0,
        y0,
        step,
        nx,
        ny,
        tile: (
            tile_side(nx, opts.tile.max(4)),
            tile_side(ny, opts.tile.max(4)),
        ),
        opts,
        icgn: &icgn_opts,
        corrections: &corrections,
        finished: std::sync::atomic::AtomicUsize::new(0),
        progress,
    };
    let (sx, sy) = job.tile;
    let tiles: Vec<(usize, usize)> = (0..ny.div_ceil(sy))
        .flat_map(|ty| (0..nx.div_ceil(sx)).map(move |tx| (tx, ty)))
        .collect();
    let results: Vec<TileResult> = tiles.par_iter().map(|&(tx, ty)| job.grow(tx, ty)).collect();
    let mut points = vec![None; nx * ny];
    let mut dropped = Dropped::default();
    for (tile, d) in results {
        for (k, p) in tile {
            points[k] = p;
        }
        dropped.not_converged += d.not_converged;
        dropped.low_zncc += d.low_zncc;
        dropped.uncertain += d.uncertain;
    }
    let outliers = inconsistent(&points, nx, ny);
    dropped.inconsistent = outliers.len();
    for k in outliers {
        points[k] = None;
    }
    Ok(Field {
        nx,
        ny,
        x0,
        y0,
        step,
        points,
        dropped,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Over every grid of up to 300 points a side and every tile size: the tiles
    /// cover the grid, none is larger than asked, all but the last are of one size
    /// and the last is not much smaller (equal work), and a grid of 32 points or more
    /// has at least four tiles a side.
    #[test]
    fn tiles_cut_the_grid_into_equal_parts_of_at_most_the_size_asked() {
        for most in [1, 4, 8, 16, 32, 64] {
            for n in 1..=300 {
                let side = tile_side(n, most);
                let parts = n.div_ceil(side);
                assert!(
                    side >= 1 && side <= most.max(1),
                    "n {n} most {most}: {side}"
                );
                let last = n - (parts - 1) * side;
                assert!(last >= 1 && last <= side, "n {n} most {most}: last {last}");
                assert!(side - last < parts, "n {n} most {most}: {side} then {last}");
                if n >= MIN_TILES_PER_SIDE * MIN_TILE {
                    assert!(parts >= MIN_TILES_PER_SIDE, "n {n} most {most}: {parts}");
                }
            }
        }
        // The step-10 grid of a 512-pixel image: 48 points, 4 tiles of 12 (it was cut
        // 32 + 16, and one thread of two had twice the other's work).
        assert_eq!(tile_side(48, 32), 12);
    }

    #[test]
    fn seed_candidates_start_at_the_centre_then_spread_over_the_tile() {
        for (tw, th) in [(32, 32), (13, 32), (4, 4), (1, 7), (5, 2)] {
            let c = seed_candidates(tw, th);
            let mut seen = std::collections::BTreeSet::new();
            for &(i, j) in &c {
                assert!(i < tw && j < th, "{tw}x{th}: ({i}, {j}) outside");
                assert!(seen.insert((i, j)), "{tw}x{th}: ({i}, {j}) twice");
            }
            let d = |(i, j): (usize, usize)| i.abs_diff(tw / 2) + j.abs_diff(th / 2);
            let near = SEEDS_AT_CENTRE.min(tw * th);
            // The first ones are the nearest the centre: none left out is nearer.
            let reach = c[..near].iter().map(|&p| d(p)).max().unwrap();
            let all = (0..th).flat_map(|j| (0..tw).map(move |i| (i, j)));
            assert!(
                all.filter(|p| !c[..near].contains(p))
                    .all(|p| d(p) >= reach),
                "{tw}x{th}"
            );
        }
        // A 32 x 32 tile: the lattice reaches every quadrant, far from the centre.
        let c = seed_candidates(32, 32);
        for (qx, qy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            assert!(
                c.iter().any(|&(i, j)| i / 16 == qx
                    && j / 16 == qy
                    && i.abs_diff(16) + j.abs_diff(16) >= 16),
                "quadrant ({qx}, {qy}): {c:?}"
            );
        }
        assert_eq!(c.len(), SEEDS_AT_CENTRE + SEED_LATTICE * SEED_LATTICE);
    }

    fn point(u: f64, v: f64, sigma: f64) -> Option<PointResult> {
        Some(PointResult {
            x: 0.0,
            y: 0.0,
            u,
            v,
            gradients: [0.0; 4],
            zncc: 0.99,
            iterations: 3,
            converged: true,
            sigma_u: sigma,
            sigma_v: sigma,
            sigma_noise: 1.0,
            subset: 31,
        })
    }

    #[test]
    fn the_median_test_drops_what_the_neighbours_contradict_and_keeps_a_smooth_field() {
        let (nx, ny) = (40, 30);
        let sigma = 0.01;
        let linear = |k: usize| {
            let (i, j) = ((k % nx) as f64, (k / nx) as f64);
            // 1 % strain and 0.5 % shear over a 5 px step.
            (1.2 + 0.05 * i + 0.025 * j, -0.7 + 0.05 * j)
        };
        let field = |noise: &dyn Fn(usize) -> (f64, f64)| -> Vec<Option<PointResult>> {
            (0..nx * ny)
                .map(|k| {
                    let ((u, v), (a, b)) = (linear(k), noise(k));
                    point(u + a, v + b, sigma)
                })
                .collect()
        };
        // A linear field, edges and corners included: nothing dropped.
        let exact = field(&|_| (0.0, 0.0));
        assert_eq!(inconsistent(&exact, nx, ny), Vec::<usize>::new());
        // Errors of σ correlated over neighbours, as overlapping subsets make them (a
        // 3 x 3 moving average of white noise, scaled back to σ): hardly any dropped.
        let mut rng = cellinject_numeric::Rng::new(3, 1);
        let white: Vec<(f64, f64)> = (0..nx * ny)
            .map(|_| (rng.gaussian_exact(), rng.gaussian_exact()))
            .collect();
        let smooth = |k: usize| {
            let (i, j) = ((k % nx) as i64, (k / nx) as i64);
            let (mut a, mut b) = (0.0, 0.0);
            for dj in -1..=1 {
                for di in -1..=1 {
                    let (x, y) = (
                        (i + di).clamp(0, nx as i64 - 1),
                        (j + dj).clamp(0, ny as i64 - 1),
                    );
                    let w = white[y as usize * nx + x as usize];
                    a += w.0;
                    b += w.1;
                }
            }
            (sigma * a / 3.0, sigma * b / 3.0)
        };
        let correlated = field(&smooth);
        let rate =
            |f: &[Option<PointResult>]| inconsistent(f, nx, ny).len() as f64 / f.len() as f64;
        let r = rate(&correlated);
        println!("correlated errors: {:.2} % dropped", 100.0 * r);
        assert!(r <= 0.005, "{r}");
        // Independent errors of σ (subsets that do not overlap): a few dropped, at the
        // rate the threshold of 2 gives for a noise level ε of the predicted σ.
        let independent = field(&|k| (sigma * white[k].0, sigma * white[k].1));
        let r = rate(&independent);
        println!("independent errors: {:.2} % dropped", 100.0 * r);
        assert!(r < 0.05, "{r}");
        // One point 0.1 px off in v, ten of its σ: dropped, and only it.
        let mut bad = exact.clone();
        let k = 13 * nx + 17;
        bad[k] = bad[k].map(|p| PointResult { v: p.v - 0.1, ..p });
        assert_eq!(inconsistent(&bad, nx, ny), vec![k]);
        // The same offset where σ says 0.05 px: within the noise, kept.
        bad[k] = bad[k].map(|p| PointResult {
            sigma_u: 0.05,
            sigma_v: 0.05,
            ..p
        });
        assert_eq!(inconsistent(&bad, nx, ny), Vec::<usize>::new());
        // A point no kept neighbour confirms is dropped; two confirm each other.
        let mut alone = vec![None; nx * ny];
        alone[2 * nx + 2] = point(0.3, 0.3, sigma);
        alone[5 * nx + 6] = point(0.3, 0.3, sigma);
        alone[5 * nx + 7] = point(0.301, 0.3, sigma);
        assert_eq!(inconsistent(&alone, nx, ny), vec![2 * nx + 2]);
        // The one point of a 1 x 1 grid has no neighbour to ask: kept.
        assert_eq!(
            inconsistent(&[point(0.3, 0.3, sigma)], 1, 1),
            Vec::<usize>::new()
        );
    }
}
