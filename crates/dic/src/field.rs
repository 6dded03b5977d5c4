//! Full-field DIC on a regular grid with reliability-guided propagation (Pan, Appl. Opt.
//! 48, 2009): from a seed found by the FFT search, the most reliable computed point
//! (highest ZNCC) hands its deformation to its uncomputed neighbours as their initial
//! guess, so IC-GN converges in a few iterations and no point needs its own search. The
//! grid is cut into tiles, each grown from its own seed, in parallel with rayon; the
//! tiling does not depend on the number of threads, so results are reproducible.
//!
//! Every point is computed by [`measure`], as in the point mode: a point whose predicted
//! σ is too large for the rule is tried again with larger subsets (the self-adaptive
//! subset, [`FieldOptions::adaptive_subset`]; each result records its subset size).
//! Every computed point goes through [`judge`], the rule of the point mode: a point it
//! rejects is not reported, and is counted in [`Field::dropped`]; one that did not
//! converge or has a low ZNCC is not used as a starting guess either. (A neighbour's guess lets IC-GN converge where the point mode's
//! own search would not, so without the rule the field reported points the point mode
//! refused.)

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use rayon::prelude::*;

use crate::accept::{Acceptance, Dropped, Rejection, judge, measure};
use crate::icgn::{IcgnOptions, PointResult, Shape};
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
    /// Grid points per tile side (each tile grows from its own seed).
    pub tile: usize,
    /// Sigma of an optional Gaussian prefilter of both images, pixels (0 = none).
    pub prefilter: f64,
    /// Degree of the B-spline interpolant of both images (quintic by default here; cubic
    /// for comparison: [`crate::bspline::Degree`]).
    pub spline: Degree,
    /// Iteration control.
    pub icgn: IcgnOptions,
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
            // Neighbours start close to their solution, and the iteration contracts
            // fast: stopping at a 5e-4 px update leaves the result unchanged to 1e-5 px
            // (measured against 1e-4) and saves a third of the iterations.
            icgn: IcgnOptions {
                tolerance: 5e-4,
                ..IcgnOptions::default()
            },
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

/// Computes the displacement field between two images.
pub fn field(reference: &Image, current: &Image, opts: &FieldOptions) -> Result<Field, DicError> {
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
    } = crate::Prepared::new(
        reference,
        current,
        opts.search_radius,
        opts.prefilter,
        opts.spline,
    );
    let icgn_opts = IcgnOptions {
        residual_floor: opts.icgn.residual_floor.max(floor),
        quantisation_step: opts.icgn.quantisation_step.max(q),
        ..opts.icgn
    };
    let refine = |px: usize, py: usize, init: [f64; 6]| {
        measure(
            &r,
            &s,
            px,
            py,
            opts.subset,
            opts.adaptive_subset,
            opts.shape,
            init,
            &icgn_opts,
            &opts.acceptance,
        )
    };
    let tile = opts.tile.max(4);
    let tiles: Vec<(usize, usize)> = (0..ny.div_ceil(tile))
        .flat_map(|ty| (0..nx.div_ceil(tile)).map(move |tx| (tx, ty)))
        .collect();
    let grid = |gx: usize, gy: usize| (x0 + gx * step, y0 + gy * step);
    // Per tile: (grid index, measurement) pairs and the tile's dropped points.
    type TileResult = (Vec<(usize, Option<PointResult>)>, Dropped);
    let results: Vec<TileResult> = tiles
        .par_iter()
        .map(|&(tx, ty)| {
            let (gx0, gy0) = (tx * tile, ty * tile);
            let (gx1, gy1) = ((gx0 + tile).min(nx), (gy0 + tile).min(ny));
            let (tw, th) = (gx1 - gx0, gy1 - gy0);
            let mut work = Tile::new(tw * th);
            let mut done = vec![false; tw * th];
            // Seed: the tile centre, then spiralling candidates until one the rule
            // accepts. A match rejected only for its σ hands its guess on to its
            // neighbours, but as a seed it may be anywhere: on a featureless patch
            // (sky) a wrong integer peak converges to a ZNCC of 0.999 with an infinite
            // σ, and the whole tile follows it. Such a seed is used only when none of
            // the candidates is accepted; the others are left for the propagation.
            let centre = (tw / 2, th / 2);
            let mut order: Vec<(usize, usize)> =
                (0..th).flat_map(|j| (0..tw).map(move |i| (i, j))).collect();
            order.sort_by_key(|&(i, j)| {
                (i as i64 - centre.0 as i64).abs() + (j as i64 - centre.1 as i64).abs()
            });
            let mut fallback = None;
            let mut seeded = false;
            for &(i, j) in order.iter().take(8) {
                let (px, py) = grid(gx0 + i, gy0 + j);
                let hit = search::search_pyramid(
                    &pr,
                    &pc,
                    px as i64,
                    py as i64,
                    m as i64,
                    opts.search_radius as i64,
                );
                let Some(hit) = hit else { continue };
                let init = [hit.u as f64, 0.0, 0.0, hit.v as f64, 0.0, 0.0];
                let k = j * tw + i;
                match refine(px, py, init) {
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
                    let (px, py) = grid(gx0 + ni as usize, gy0 + nj as usize);
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
                    if let Some(p) = refine(px, py, init) {
                        work.keep(k, p, &opts.acceptance);
                    }
                }
            }
            let points = (0..tw * th)
                .map(|k| {
                    let (i, j) = (k % tw, k / tw);
                    ((gy0 + j) * nx + gx0 + i, work.out[k])
                })
                .collect();
            (points, work.dropped)
        })
        .collect();
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
