//! Focusing a plate: how sharp each part of a frame is, where a through-focus sweep
//! peaks, and the plane of best focus over a field.
//!
//! A sweep moves the plate along the optical axis in equal steps and takes a frame at
//! each. Each frame is cut into tiles; a tile's sharpness is Brenner's gradient
//! (the mean squared difference of pixels two apart, along rows and columns) divided
//! by its squared mean level, so that a dimmer corner of the field counts as much.
//! Defocus spreads every edge, and the sharpness falls on both sides of focus. A
//! tile's best focus is the midpoint of the two half-height crossings of its curve
//! (linearly interpolated): exact for any curve symmetric about its peak, whatever its
//! shape (the cusp of a |defocus| blur included), where a parabola through the top
//! three samples is pulled towards the highest sample. The plane through the tiles'
//! best foci (least squares, the worst tile dropped while it lies more than 1.5 µm off)
//! gives the field's tilt: the focus at each cell of the field.
//!
//! Pure computation: frames in, numbers out.

use thiserror::Error;

/// Why a focus could not be found.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum FocusError {
    /// The curve's half-height is not crossed on one side within the sweep: the best
    /// focus lies beyond that end (or there is nothing to focus on).
    #[error(
        "the sharpness does not fall to half its height {side} the sweep (highest at {peak:.3e} m, sweep {from:.3e} to {to:.3e} m)"
    )]
    OutOfRange {
        /// "below" or "above".
        side: &'static str,
        /// m, the sample with the highest sharpness.
        peak: f64,
        /// m, the sweep's first position.
        from: f64,
        /// m, its last.
        to: f64,
    },
    /// The curve is flat: highest and lowest sharpness within `ratio` of each other.
    #[error("nothing in view to focus on: the sharpness varies only {:.1} % over the sweep", 100.0 * (ratio - 1.0))]
    Flat {
        /// Highest over lowest sharpness.
        ratio: f64,
    },
    /// Too few samples, or positions and sharpness of different lengths or not
    /// increasing.
    #[error(
        "a focus sweep needs at least 5 increasing positions with one sharpness each ({positions} positions, {values} values)"
    )]
    Samples {
        /// Positions given.
        positions: usize,
        /// Sharpness values given.
        values: usize,
    },
    /// Fewer than three usable tiles, or all on a line: no plane.
    #[error("{usable} tiles with a focus, not enough (or all on a line) for a plane")]
    Plane {
        /// Tiles with a focus.
        usable: usize,
    },
    /// The plane through the tiles slopes more steeply than a plate's floor lies
    /// ([`MAX_FLOOR_SLOPE`]): it rests on noise peaks.
    #[error(
        "the plane through {points} tiles slopes {:.1} µm/mm, steeper than a plate's floor lies ({:.0} µm/mm at most): their foci are noise",
        slope * 1e3,
        MAX_FLOOR_SLOPE * 1e3
    )]
    Steep {
        /// m/m, the plane's slope (its magnitude).
        slope: f64,
        /// Tiles it rests on.
        points: usize,
    },
}

/// Least contrast of a tile's focus curve (highest over lowest sharpness) for its
/// peak to be trusted. The camera's noise adds a floor to the sharpness that does not
/// depend on focus (most of a sparse plate's frame is bare medium: a 2 x 16 plate's
/// whole frame varies by 4 % through focus) and scatters it by about √2/√n of its
/// value from frame to frame over n pixels: 0.2 % in a ninth of a 5-megapixel frame;
/// 2 % is ten times that.
pub const TILE_CONTRAST: f64 = 1.02;

/// Least contrast of a whole frame's focus curve: its noise is a third of a tile's
/// (0.06 %), and a frame with only a few particles in view varies by 1.6 %.
pub const FRAME_CONTRAST: f64 = 1.005;

/// The sharpness of each of `tiles[0]` x `tiles[1]` tiles (columns x rows) of a frame
/// `width` pixels wide, row by row: Brenner's gradient over its mean level squared.
/// Returns an empty vector for a frame smaller than 4 pixels per tile.
pub fn tile_sharpness(pixels: &[u16], width: usize, tiles: [usize; 2]) -> Vec<f64> {
    let height = pixels.len().checked_div(width).unwrap_or(0);
    let (tx, ty) = (tiles[0].max(1), tiles[1].max(1));
    if width < 4 * tx || height < 4 * ty {
        return Vec::new();
    }
    let mut grad = vec![0.0f64; tx * ty];
    let mut sum = vec![0.0f64; tx * ty];
    let mut count = vec![0usize; tx * ty];
    for j in 0..height - 2 {
        let tj = j * ty / height;
        let row = &pixels[j * width..(j + 1) * width];
        let below = &pixels[(j + 2) * width..(j + 3) * width];
        for i in 0..width - 2 {
            let t = tj * tx + i * tx / width;
            let v = row[i] as f64;
            let dx = row[i + 2] as f64 - v;
            let dy = below[i] as f64 - v;
            grad[t] += dx * dx + dy * dy;
            sum[t] += v;
            count[t] += 1;
        }
    }
    (0..tx * ty)
        .map(|t| {
            let n = count[t].max(1) as f64;
            let mean = sum[t] / n;
            if mean > 0.0 {
                grad[t] / n / (mean * mean)
            } else {
                0.0
            }
        })
        .collect()
}

/// Where each tile's sharpness comes from (same tiles as [`tile_sharpness`]): the
/// pixel centroid (column, row) of the squared gradients above the tile's mean
/// squared gradient, so that the camera's noise over bare medium does not pull it to
/// the tile's centre. A tile with nothing above its mean gives its centre.
pub fn tile_centroids(pixels: &[u16], width: usize, tiles: [usize; 2]) -> Vec<[f64; 2]> {
    let height = pixels.len().checked_div(width).unwrap_or(0);
    let (tx, ty) = (tiles[0].max(1), tiles[1].max(1));
    if width < 4 * tx || height < 4 * ty {
        return Vec::new();
    }
    let grad = |i: usize, j: usize| {
        let v = pixels[j * width + i] as f64;
        let dx = pixels[j * width + i + 2] as f64 - v;
        let dy = pixels[(j + 2) * width + i] as f64 - v;
        dx * dx + dy * dy
    };
    let tile = |i: usize, j: usize| (j * ty / height) * tx + i * tx / width;
    let mut mean = vec![0.0f64; tx * ty];
    let mut count = vec![0usize; tx * ty];
    for j in 0..height - 2 {
        for i in 0..width - 2 {
            let t = tile(i, j);
            mean[t] += grad(i, j);
            count[t] += 1;
        }
    }
    for (m, &n) in mean.iter_mut().zip(&count) {
        *m /= n.max(1) as f64;
    }
    let mut acc = vec![[0.0f64; 3]; tx * ty];
    for j in 0..height - 2 {
        for i in 0..width - 2 {
            let t = tile(i, j);
            let w = grad(i, j) - mean[t];
            if w > 0.0 {
                acc[t][0] += w * i as f64;
                acc[t][1] += w * j as f64;
                acc[t][2] += w;
            }
        }
    }
    (0..tx * ty)
        .map(|t| {
            let a = acc[t];
            if a[2] > 0.0 {
                [a[0] / a[2], a[1] / a[2]]
            } else {
                let (i, j) = (t % tx, t / tx);
                [
                    (i as f64 + 0.5) * width as f64 / tx as f64,
                    (j as f64 + 0.5) * height as f64 / ty as f64,
                ]
            }
        })
        .collect()
}

/// The best focus of a sweep: positions `z` (m, increasing), `sharpness` at each.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Peak {
    /// m, the midpoint of the half-height crossings.
    pub z: f64,
    /// m, the distance between them (the curve's full width at half height).
    pub width: f64,
    /// Highest over lowest sharpness.
    pub contrast: f64,
}

/// The peak of a focus curve (see the module's description), trusted only if its
/// highest sharpness is at least `min_contrast` times its lowest ([`TILE_CONTRAST`],
/// [`FRAME_CONTRAST`]).
pub fn peak(z: &[f64], sharpness: &[f64], min_contrast: f64) -> Result<Peak, FocusError> {
    let n = z.len();
    if n < 5
        || sharpness.len() != n
        || z.windows(2)
            .any(|w| w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater))
    {
        return Err(FocusError::Samples {
            positions: n,
            values: sharpness.len(),
        });
    }
    let (mut k, mut hi, mut lo) = (0, f64::NEG_INFINITY, f64::INFINITY);
    for (i, &s) in sharpness.iter().enumerate() {
        if s > hi {
            (k, hi) = (i, s);
        }
        lo = lo.min(s);
    }
    let contrast = if lo > 0.0 { hi / lo } else { f64::INFINITY };
    if !(contrast.is_finite() && contrast >= min_contrast) {
        return Err(FocusError::Flat {
            ratio: if contrast.is_finite() { contrast } else { 1.0 },
        });
    }
    let half = 0.5 * (hi + lo);
    let cross = |a: usize, b: usize| {
        let (sa, sb) = (sharpness[a], sharpness[b]);
        z[a] + (half - sa) / (sb - sa) * (z[b] - z[a])
    };
    let out = |side| FocusError::OutOfRange {
        side,
        peak: z[k],
        from: z[0],
        to: z[n - 1],
    };
    // The first crossing on each side of the highest sample.
    let below = (0..k)
        .rev()
        .find(|&i| sharpness[i] < half)
        .ok_or(out("below"))?;
    let above = (k + 1..n)
        .find(|&i| sharpness[i] < half)
        .ok_or(out("above"))?;
    let (z0, z1) = (cross(below, below + 1), cross(above - 1, above));
    Ok(Peak {
        z: 0.5 * (z0 + z1),
        width: z1 - z0,
        contrast,
    })
}

/// A plane of best focus: `z(p) = z + slope · (p − centre)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// m, the point (x, y) it is written about.
    pub centre: [f64; 2],
    /// m, its height there.
    pub z: f64,
    /// m/m, its slope along x and y.
    pub slope: [f64; 2],
    /// m, the rms residual of the points it was fitted to.
    pub residual: f64,
    /// Points it rests on (after dropping outliers).
    pub points: usize,
}

impl Plane {
    /// m, its height at `p`.
    pub fn at(&self, p: [f64; 2]) -> f64 {
        self.z + self.slope[0] * (p[0] - self.centre[0]) + self.slope[1] * (p[1] - self.centre[1])
    }
}

/// Farthest a tile's focus may lie from the plane through the others, m.
pub const PLANE_OUTLIER: f64 = 1.5e-6;

/// m/m, how much steeper than another with as many points near a plane must be for
/// the consensus to prefer the other whatever their sums of distances (10 um/mm:
/// twice the steepest field of the prototype's plates; closer tilts are told apart
/// by the sum, as a plate truly tilted by 5 um/mm needs).
const TILT_EQUAL: f64 = 10e-3;

/// m/m, the steepest floor a plane of tile foci may describe (20 um/mm, 1.1°: four
/// times the steepest field of the prototype's plates, 5.6 um/mm, whose dishes lie
/// on a level holder). A steeper plane rests on noise: a field of nearly empty wells
/// gave four tiles with curves wide enough to pass, on a plane of 27.8 um/mm, and
/// the next field's focus, predicted from it 1.9 mm away, started its sweep 45 um off.
pub const MAX_FLOOR_SLOPE: f64 = 20e-3;

/// m, least rms spread of the points along a direction for the plane's slope along
/// it to be fitted: along a narrower direction (a plate a few wells wide, seen in one
/// row of tiles) the slope is left at 0 rather than fitted to noise.
pub const MIN_SPREAD: f64 = 0.15e-3;

/// The least-squares plane through `points` (x, y, z), written about `centre`, its
/// slope fitted only along directions in which the points spread by at least
/// [`MIN_SPREAD`] (rms). First the consensus: of the planes through every three
/// points, the one that the most points lie within [`PLANE_OUTLIER`] of (the smaller
/// sum of their distances between equals) keeps those points; then the point farthest
/// off is dropped while it lies more than [`PLANE_OUTLIER`] off and more than three
/// points remain. Dropping the farthest from the plane through all of them alone
/// failed where one wrong tile stood alone at the field's edge: the plane leant to it,
/// a right tile became the farthest, and a strip plate's floor was made to slope
/// 15 um/mm (the cells 11 um off their focus). A plane steeper than
/// [`MAX_FLOOR_SLOPE`] is refused ([`FocusError::Steep`]).
pub fn fit_plane(points: &[([f64; 2], f64)], centre: [f64; 2]) -> Result<Plane, FocusError> {
    let finite: Vec<([f64; 2], f64)> = points
        .iter()
        .copied()
        .filter(|(p, z)| p[0].is_finite() && p[1].is_finite() && z.is_finite())
        .collect();
    let mut kept = consensus(&finite, centre);
    loop {
        let plane = solve_plane(&kept, centre).ok_or(FocusError::Plane { usable: kept.len() })?;
        let (worst, off) = kept
            .iter()
            .enumerate()
            .map(|(i, (p, z))| (i, (z - plane.at(*p)).abs()))
            .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
        if off <= PLANE_OUTLIER || kept.len() <= 3 {
            let slope = plane.slope[0].hypot(plane.slope[1]);
            if slope > MAX_FLOOR_SLOPE {
                return Err(FocusError::Steep {
                    slope,
                    points: plane.points,
                });
            }
            return Ok(plane);
        }
        kept.remove(worst);
    }
}

/// The points within [`PLANE_OUTLIER`] of the plane through three of them that the
/// most points lie near (see [`fit_plane`]); all of them when there are four or fewer,
/// or when no three make a plane that three points lie near. Among planes with as many
/// points near, the smaller sum of distances wins, unless one is steeper than the
/// other by [`TILT_EQUAL`]: then the flatter. A plate lies nearly level on its holder
/// (the prototype's fields slope 1.5-5.6 um/mm), and points along one line fit any
/// tilt about it, so a noise peak beside them makes a plane that four points lie near
/// as well as the true one. A 1 x 16 strip plate's field had three right tiles on one
/// column: by the sum alone such a plane won (22.9 um/mm, the cells 13.6 um off their
/// focus); preferring the flatter at any difference lost a truly tilted plate's
/// slope (3.7 for 5 um/mm, the cells 2.1 um off).
fn consensus(points: &[([f64; 2], f64)], centre: [f64; 2]) -> Vec<([f64; 2], f64)> {
    let n = points.len();
    if n <= 4 {
        return points.to_vec();
    }
    // (points near, the plane's tilt, the sum of their distances, those points)
    type Best = (usize, f64, f64, Vec<([f64; 2], f64)>);
    let mut best: Option<Best> = None;
    for i in 0..n {
        for j in i + 1..n {
            for k in j + 1..n {
                let Some(plane) = solve_plane(&[points[i], points[j], points[k]], centre) else {
                    continue;
                };
                let near: Vec<([f64; 2], f64)> = points
                    .iter()
                    .copied()
                    .filter(|(p, z)| (z - plane.at(*p)).abs() <= PLANE_OUTLIER)
                    .collect();
                let cost: f64 = near.iter().map(|(p, z)| (z - plane.at(*p)).abs()).sum();
                let tilt = plane.slope[0].hypot(plane.slope[1]);
                let better = match &best {
                    None => true,
                    Some((count, t, c, _)) => {
                        near.len() > *count
                            || (near.len() == *count
                                && (tilt < t - TILT_EQUAL || (tilt <= t + TILT_EQUAL && cost < *c)))
                    }
                };
                if better {
                    best = Some((near.len(), tilt, cost, near));
                }
            }
        }
    }
    match best {
        Some((count, _, _, near)) if count >= 3 => near,
        _ => points.to_vec(),
    }
}

/// Least squares in the directions the points span: the mean height at their
/// centroid, and a slope along each principal direction of their scatter whose rms
/// spread reaches [`MIN_SPREAD`].
fn solve_plane(points: &[([f64; 2], f64)], c: [f64; 2]) -> Option<Plane> {
    let n = points.len();
    if n == 0 {
        return None;
    }
    let nf = n as f64;
    let (mut mx, mut my, mut mz) = (0.0, 0.0, 0.0);
    for (p, z) in points {
        mx += p[0] / nf;
        my += p[1] / nf;
        mz += z / nf;
    }
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for (p, _) in points {
        let (dx, dy) = (p[0] - mx, p[1] - my);
        sxx += dx * dx;
        sxy += dx * dy;
        syy += dy * dy;
    }
    // Principal directions of the scatter (symmetric 2 x 2).
    let half_diff = 0.5 * (sxx - syy);
    let root = half_diff.hypot(sxy);
    let mid = 0.5 * (sxx + syy);
    let theta = 0.5 * sxy.atan2(half_diff);
    let dirs = [
        ([theta.cos(), theta.sin()], mid + root),
        ([-theta.sin(), theta.cos()], mid - root),
    ];
    let mut slope = [0.0; 2];
    for (u, lambda) in dirs {
        if lambda / nf < MIN_SPREAD * MIN_SPREAD {
            continue;
        }
        let (mut num, mut den) = (0.0, 0.0);
        for (p, z) in points {
            let s = (p[0] - mx) * u[0] + (p[1] - my) * u[1];
            num += s * (z - mz);
            den += s * s;
        }
        let k = num / den;
        slope[0] += k * u[0];
        slope[1] += k * u[1];
    }
    if !(slope[0].is_finite() && slope[1].is_finite() && mz.is_finite()) {
        return None;
    }
    let plane = Plane {
        centre: c,
        z: mz + slope[0] * (c[0] - mx) + slope[1] * (c[1] - my),
        slope,
        residual: 0.0,
        points: n,
    };
    let ss: f64 = points.iter().map(|(p, z)| (z - plane.at(*p)).powi(2)).sum();
    Some(Plane {
        residual: (ss / nf).sqrt(),
        ..plane
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A symmetric cusp (the twin's |defocus| blur) sampled off its peak: the
    /// half-height midpoint finds it within 20 nm (the crossings' linear
    /// interpolation), where a parabola through the top three misses by more.
    #[test]
    fn the_peak_of_a_symmetric_cusp_is_found_between_samples() {
        for z0 in [-3.3e-6, -0.25e-6, 0.0, 0.7e-6, 2.1e-6] {
            let z: Vec<f64> = (0..21).map(|k| -10e-6 + k as f64 * 1e-6).collect();
            let s: Vec<f64> = z
                .iter()
                .map(|&z| 1.0 / (0.4e-6 + 0.05 * (z - z0).abs()).powi(2))
                .collect();
            let p = peak(&z, &s, TILE_CONTRAST).unwrap();
            assert!((p.z - z0).abs() < 0.02e-6, "{z0} {p:?}");
            // A parabola through the three highest samples.
            let k = (0..21).max_by(|&a, &b| s[a].total_cmp(&s[b])).unwrap();
            let (a, b, c) = (s[k - 1], s[k], s[k + 1]);
            let parabola = z[k] + 0.5e-6 * (a - c) / (a - 2.0 * b + c);
            if (z0 / 1e-6 - (z0 / 1e-6).round()).abs() > 0.2 {
                assert!((parabola - z0).abs() > 0.05e-6, "{z0} {parabola}");
            }
        }
    }

    #[test]
    fn a_sweep_that_misses_the_peak_or_sees_nothing_says_so() {
        let z: Vec<f64> = (0..9).map(|k| k as f64 * 1e-6).collect();
        let rising: Vec<f64> = z.iter().map(|z| 1.0 + z * 1e6).collect();
        assert!(matches!(
            peak(&z, &rising, TILE_CONTRAST),
            Err(FocusError::OutOfRange { side: "above", .. })
        ));
        let flat = vec![1.0; 9];
        assert!(matches!(
            peak(&z, &flat, TILE_CONTRAST),
            Err(FocusError::Flat { .. })
        ));
        assert!(matches!(
            peak(&z[..3], &flat[..3], TILE_CONTRAST),
            Err(FocusError::Samples { .. })
        ));
        let nan: Vec<f64> = z.iter().map(|_| f64::NAN).collect();
        assert!(peak(&z, &nan, TILE_CONTRAST).is_err());
    }

    /// Six tiles of a 1 x 16 plate's field as the twin gave them (mm, heights in um):
    /// four right ones, three of them on one column (x about -0.1 mm), and two noise
    /// peaks at 15.4 and 11.2 um. The plane through the column and the peak at
    /// x = 0.64 mm has four points near as well as the true one (and a smaller sum of
    /// distances); it slopes 22.8 um/mm. The flatter one wins.
    #[test]
    fn points_on_one_line_and_a_noise_peak_do_not_tilt_the_plane() {
        let tiles = [
            (-0.1020, -0.5563, -1.531),
            (0.6410, -0.5552, 15.382),
            (-0.8409, -0.0167, 11.180),
            (-0.0698, -0.0080, -0.075),
            (0.6140, -0.0126, 0.789),
            (-0.0983, 0.5559, 0.536),
        ];
        let pts: Vec<([f64; 2], f64)> = tiles
            .iter()
            .map(|&(x, y, z)| ([x * 1e-3, y * 1e-3], z * 1e-6))
            .collect();
        let plane = fit_plane(&pts, [0.0, 0.0]).unwrap();
        assert_eq!(plane.points, 4, "{plane:?}");
        assert!(plane.slope[0].hypot(plane.slope[1]) < 4e-3, "{plane:?}");
        for k in [1, 2] {
            assert!(
                (plane.at(pts[k].0) - pts[k].1).abs() > 5e-6,
                "{k}: {plane:?}"
            );
        }
    }

    /// Five tiles of a strip plate's field as the twin gave them (pixels of 0.88 um,
    /// heights in um): four agree on a floor within 1 um, the one alone at the left
    /// edge (a weak curve) says 11.3 um. The plane through all five leant to it, the
    /// farthest point was then a right one, and the floor came out sloping 15 um/mm;
    /// the consensus leaves the wrong tile out.
    #[test]
    fn a_lone_wrong_tile_at_the_edge_does_not_tilt_the_plane() {
        let px = 0.88e-6;
        let tiles = [
            (1290.0, 341.0, -0.24),
            (454.0, 953.0, 11.27),
            (1331.0, 963.0, -0.07),
            (2107.0, 958.0, 0.76),
            (1300.0, 1602.0, 0.20),
        ];
        let pts: Vec<([f64; 2], f64)> = tiles
            .iter()
            .map(|&(x, y, z)| ([x * px, y * px], z * 1e-6))
            .collect();
        let centre = [1296.0 * px, 972.0 * px];
        let plane = fit_plane(&pts, centre).unwrap();
        assert_eq!(plane.points, 4, "{plane:?}");
        assert!(
            plane.slope[0].abs() < 2e-3 && plane.slope[1].abs() < 2e-3,
            "{plane:?}"
        );
        assert!(plane.z.abs() < 0.5e-6, "{plane:?}");
        assert!((plane.at(pts[1].0) - pts[1].1).abs() > 5e-6);
    }

    /// Four tiles exactly on a plane: one of 19 um/mm is a floor; one of 21 um/mm
    /// (beyond [`MAX_FLOOR_SLOPE`]) is refused, its slope named, whichever way it
    /// leans.
    #[test]
    fn a_plane_steeper_than_a_floor_lies_is_refused() {
        let tiles = [
            [-0.7e-3, -0.5e-3],
            [0.7e-3, -0.5e-3],
            [-0.7e-3, 0.5e-3],
            [0.7e-3, 0.5e-3],
        ];
        for dir in [0.0, 1.0, 2.5, 4.0] {
            let on = |m: f64| -> Vec<([f64; 2], f64)> {
                let (tx, ty) = (m * f64::cos(dir), m * f64::sin(dir));
                tiles
                    .iter()
                    .map(|&p| (p, 3e-6 + tx * p[0] + ty * p[1]))
                    .collect()
            };
            let plane = fit_plane(&on(19e-3), [0.0, 0.0]).unwrap();
            assert!(
                (plane.slope[0].hypot(plane.slope[1]) - 19e-3).abs() < 1e-9,
                "{plane:?}"
            );
            match fit_plane(&on(21e-3), [0.0, 0.0]) {
                Err(FocusError::Steep { slope, points: 4 }) => {
                    assert!((slope - 21e-3).abs() < 1e-9, "{slope}")
                }
                other => panic!("{other:?}"),
            }
        }
    }

    #[test]
    fn the_plane_through_nine_tiles_recovers_the_tilt_and_drops_an_outlier() {
        let truth = |p: [f64; 2]| 4e-6 + 3e-3 * (p[0] - 1e-3) - 2e-3 * (p[1] + 2e-3);
        let mut pts: Vec<([f64; 2], f64)> = Vec::new();
        for j in 0..3 {
            for i in 0..3 {
                let p = [
                    1e-3 + (i as f64 - 1.0) * 0.7e-3,
                    -2e-3 + (j as f64 - 1.0) * 0.5e-3,
                ];
                pts.push((p, truth(p)));
            }
        }
        pts[4].1 += 5e-6;
        let plane = fit_plane(&pts, [1e-3, -2e-3]).unwrap();
        assert_eq!(plane.points, 8);
        assert!((plane.z - 4e-6).abs() < 1e-12, "{plane:?}");
        assert!((plane.slope[0] - 3e-3).abs() < 1e-9, "{plane:?}");
        assert!((plane.slope[1] + 2e-3).abs() < 1e-9, "{plane:?}");
        // On a line (a strip of wells in one row of tiles): the slope along it, none
        // across it, whatever the noise across.
        let line: Vec<([f64; 2], f64)> = (0..4)
            .map(|k| {
                let p = [k as f64 * 0.7e-3, 1e-6 * (k % 2) as f64];
                (p, truth(p) + 2e-9 * (k % 2) as f64)
            })
            .collect();
        let plane = fit_plane(&line, [1e-3, -2e-3]).unwrap();
        assert!((plane.slope[0] - 3e-3).abs() < 1e-5, "{plane:?}");
        assert!(plane.slope[1].abs() < 1e-5, "{plane:?}");
        assert!(matches!(
            fit_plane(&[], [0.0; 2]),
            Err(FocusError::Plane { usable: 0 })
        ));
    }

    #[test]
    fn a_sharp_tile_scores_higher_than_the_same_tile_blurred_whatever_its_level() {
        let (w, h) = (64usize, 48usize);
        let edge = |blur: f64, level: f64| -> Vec<u16> {
            (0..w * h)
                .map(|k| {
                    let x = (k % w) as f64 - 32.0;
                    (level * (1.0 - 0.3 / (1.0 + (-x / blur).exp()))) as u16
                })
                .collect()
        };
        let sharp = tile_sharpness(&edge(0.5, 1000.0), w, [1, 1]);
        let soft = tile_sharpness(&edge(2.0, 1000.0), w, [1, 1]);
        let dim = tile_sharpness(&edge(0.5, 500.0), w, [1, 1]);
        assert!(sharp[0] > 2.0 * soft[0], "{sharp:?} {soft:?}");
        assert!((sharp[0] / dim[0] - 1.0).abs() < 0.02, "{sharp:?} {dim:?}");
        assert!(tile_sharpness(&edge(0.5, 1000.0), w, [20, 20]).is_empty());
        // The edge at column 32: its tile's centroid lies on it, not at the centre
        // (16 of a 32-wide tile) of the tile it borders.
        let c = tile_centroids(&edge(0.5, 1000.0), w, [2, 1]);
        assert!(
            (c[0][0] - 31.0).abs() < 1.5 && (c[1][0] - 31.0).abs() < 1.5,
            "{c:?}"
        );
    }
}
