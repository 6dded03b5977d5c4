//! DIC on real photographs (not speckle) shifted by known sub-pixel amounts.
//!
//! The photographs are 256x256 8-bit crops in `tests/data/photos` (see its README for
//! sources and licences). Each current image is made here from the committed original
//! by an exact band-limited shift, independent of the code under test and of its
//! interpolant: the image is extended mirror-symmetrically to a 512x512 period (so the
//! period has no jump at its edges), shifted in the Fourier domain, cropped, and rounded
//! to 8 bits like a camera's frame; optionally both images get Gaussian noise first.
//!
//! Two kinds of pair ([`Pair`]): the photograph itself as the reference (its pixels are
//! then the truth, with no rounding of their own), and both frames exposed from the
//! band-limited scene, the reference shifted by (0.31, 0.47) px and the current by that
//! plus the shift, each rounded, as two frames of one camera are.
//!
//! "Textured" is defined here, independently of the DIC: a grid point is textured when
//! the noise limit of Pan et al. (2008), `√2·σ/√Σ(∇f − mean ∇f)²` over its subset with
//! central differences of the original and σ the noise the test adds (rounding
//! included), is at most 0.01 px in x and in y. The mean gradient is removed because
//! ZNSSD's offset and gain make a linear ramp of grey levels carry no information.
//! A grid point whose subset, moved by the known shift, comes within 2 px of the edge
//! of the current image (the cubic spline's support and its margin) is not counted:
//! whatever its texture, its match is not in the image.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use cellinject_dic::Image;
use cellinject_dic::field::{FieldOptions, field};
use cellinject_dic::synth::fourier_shift;
use cellinject_numeric::Rng;

const PHOTOS: [&str; 6] = [
    "camera_sky_coat",
    "camera_field",
    "astronaut",
    "brick",
    "grass",
    "gravel",
];

fn load(name: &str) -> Image {
    let path = format!(
        "{}/tests/data/photos/{name}.png",
        env!("CARGO_MANIFEST_DIR")
    );
    let img = image::open(&path).unwrap().into_luma8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    Image::new(w, h, img.into_raw().into_iter().map(f64::from).collect()).unwrap()
}

/// Adds Gaussian noise and rounds to 8 bits, as a camera would.
fn expose(values: &[f64], w: usize, h: usize, noise: f64, rng: &mut Rng) -> Image {
    let data = values
        .iter()
        .map(|v| (v + noise * rng.gaussian_exact()).round().clamp(0.0, 255.0))
        .collect();
    Image::new(w, h, data).unwrap()
}

/// Gradient energy of the subset minus its best plane (central differences).
fn texture(img: &Image, x: usize, y: usize, m: usize) -> (f64, f64) {
    let (mut gx, mut gy) = (Vec::new(), Vec::new());
    for j in y - m..=y + m {
        for i in x - m..=x + m {
            gx.push(0.5 * (img.at(i + 1, j) - img.at(i - 1, j)));
            gy.push(0.5 * (img.at(i, j + 1) - img.at(i, j - 1)));
        }
    }
    let var = |g: &[f64]| {
        let mean = g.iter().sum::<f64>() / g.len() as f64;
        g.iter().map(|v| (v - mean).powi(2)).sum::<f64>()
    };
    (var(&gx), var(&gy))
}

/// How the reference frame is made.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Pair {
    /// The photograph itself (with the noise, if any, added and rounded).
    Photo,
    /// Exposed like the current frame from the band-limited scene, at an offset of
    /// [`EXPOSED_AT`] px: both frames carry their own rounding.
    Exposed,
}

/// Where the scene lies under the reference frame of an [`Pair::Exposed`] pair, px.
const EXPOSED_AT: (f64, f64) = (0.31, 0.47);

/// One photograph, one shift, one noise level: the field and what it says.
struct Run {
    name: &'static str,
    pair: Pair,
    shift: (f64, f64),
    noise: f64,
    /// Grid points, textured ones, textured ones kept.
    points: usize,
    textured: usize,
    textured_kept: usize,
    /// Kept points, and the largest error among them, px.
    kept: usize,
    worst: f64,
    /// Kept points more than 0.1 px off.
    wrong: usize,
    /// Dropped by the acceptance rule.
    dropped: usize,
    /// RMS error over the kept points' u and v, and RMS predicted σ, px.
    rms_error: f64,
    rms_sigma: f64,
    /// RMS over the kept points' u and v of the error in units of its own σ (1 for a
    /// σ that is right point by point), and the share of them more than 3 σ off.
    rms_z: f64,
    over_3_sigma: f64,
}

fn run(
    name: &'static str,
    img: &Image,
    pair: Pair,
    shift: (f64, f64),
    noise: f64,
    seed: u64,
    step: usize,
) -> Run {
    let (w, h) = (img.width(), img.height());
    let mut rng = Rng::new(seed, 1);
    let base = match pair {
        Pair::Photo => (0.0, 0.0),
        Pair::Exposed => EXPOSED_AT,
    };
    let r = match pair {
        Pair::Photo if noise == 0.0 => img.clone(),
        Pair::Photo => expose(img.data(), w, h, noise, &mut rng),
        Pair::Exposed => expose(&fourier_shift(img, base.0, base.1), w, h, noise, &mut rng),
    };
    let c = expose(
        &fourier_shift(img, shift.0 + base.0, shift.1 + base.1),
        w,
        h,
        noise,
        &mut rng,
    );
    let opts = FieldOptions {
        step,
        prefilter: std::env::var("DIC_PREFILTER").map_or(0.0, |v| v.parse().unwrap()),
        ..FieldOptions::default()
    };
    let f = field(&r, &c, &opts).unwrap();
    // The current image's rounding, and the added noise in both images.
    let sigma = (noise * noise + 1.0 / 12.0).sqrt();
    let m = opts.subset / 2;
    let (mut textured, mut textured_kept, mut kept, mut wrong) = (0, 0, 0, 0);
    let (mut worst, mut se, mut ss, mut sz, mut z3) = (0.0f64, 0.0, 0.0, 0.0, 0);
    for (k, p) in f.points.iter().enumerate() {
        let (x, y) = (f.x0 + (k % f.nx) * f.step, f.y0 + (k / f.nx) * f.step);
        let (tx, ty) = texture(img, x, y, m);
        let limit = std::f64::consts::SQRT_2 * sigma / tx.min(ty).sqrt();
        let inside = |c: usize, d: f64, n: usize| {
            let (lo, hi) = (c as f64 - m as f64 + d, (c + m) as f64 + d);
            lo >= 2.0 && hi <= n as f64 - 3.0
        };
        if limit <= 0.01 && inside(x, shift.0, w) && inside(y, shift.1, h) {
            textured += 1;
            textured_kept += usize::from(p.is_some());
        }
        if let Some(p) = p {
            let (eu, ev) = (p.u - shift.0, p.v - shift.1);
            let e = eu.hypot(ev);
            kept += 1;
            worst = worst.max(e);
            wrong += usize::from(e > 0.1);
            se += eu * eu + ev * ev;
            ss += p.sigma_u * p.sigma_u + p.sigma_v * p.sigma_v;
            let (zu, zv) = (eu / p.sigma_u, ev / p.sigma_v);
            sz += zu * zu + zv * zv;
            z3 += usize::from(zu.abs() > 3.0) + usize::from(zv.abs() > 3.0);
        }
    }
    let n = (2 * kept.max(1)) as f64;
    Run {
        name,
        pair,
        shift,
        noise,
        points: f.points.len(),
        textured,
        textured_kept,
        kept,
        worst,
        wrong,
        dropped: f.dropped.total(),
        rms_error: (se / n).sqrt(),
        rms_sigma: (ss / n).sqrt(),
        rms_z: (sz / n).sqrt(),
        over_3_sigma: z3 as f64 / n,
    }
}

const SHIFTS: [(f64, f64); 4] = [(0.37, -0.62), (0.25, 0.1), (-1.13, 2.5), (0.05, -0.8)];

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Every photograph, kind of pair, shift and noise level on a grid of `step` pixels, one
/// printed line each and a summary. The photographs run on threads of their own.
fn all_runs(step: usize) -> Vec<Run> {
    let runs: Vec<Run> = std::thread::scope(|scope| {
        let handles: Vec<_> = PHOTOS
            .iter()
            .map(|&name| {
                scope.spawn(move || {
                    let img = load(name);
                    let mut out = Vec::new();
                    for pair in [Pair::Photo, Pair::Exposed] {
                        for (k, &shift) in SHIFTS.iter().enumerate() {
                            for noise in [0.0, 2.0] {
                                let seed = 7 + k as u64;
                                out.push(run(name, &img, pair, shift, noise, seed, step));
                            }
                        }
                    }
                    out
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap())
            .collect()
    });
    for r in &runs {
        println!(
            "{:16} {:7} shift ({:5.2}, {:5.2}) noise {}: kept {:4} of {} ({:4} dropped), worst {:.3} px, {:3} over 0.1 px, textured {:4} kept {:5.1} %, rms error {:.4} px, rms σ {:.4} px, ratio {:.2}, rms error/σ {:.2}, {:.1} % over 3 σ",
            r.name,
            format!("{:?}", r.pair),
            r.shift.0,
            r.shift.1,
            r.noise,
            r.kept,
            r.points,
            r.dropped,
            r.worst,
            r.wrong,
            r.textured,
            100.0 * r.textured_kept as f64 / r.textured.max(1) as f64,
            r.rms_error,
            r.rms_sigma,
            r.rms_error / r.rms_sigma,
            r.rms_z,
            100.0 * r.over_3_sigma
        );
    }
    let ratios: Vec<f64> = runs.iter().map(|r| r.rms_error / r.rms_sigma).collect();
    let kept: Vec<f64> = runs
        .iter()
        .filter(|r| r.textured > 0)
        .map(|r| r.textured_kept as f64 / r.textured as f64)
        .collect();
    let worst: Vec<f64> = runs.iter().map(|r| r.worst).collect();
    println!(
        "rms error / rms σ: median {:.2}, from {:.2} to {:.2}; textured kept: median {:.1} %, lowest {:.1} %; worst error: median {:.3} px, largest {:.3} px",
        median(ratios.clone()),
        ratios.iter().copied().fold(f64::INFINITY, f64::min),
        ratios.iter().copied().fold(0.0, f64::max),
        100.0 * median(kept.clone()),
        100.0 * kept.iter().copied().fold(f64::INFINITY, f64::min),
        median(worst.clone()),
        worst.iter().copied().fold(0.0, f64::max)
    );
    let range = |noisy: bool| {
        let z: Vec<f64> = runs
            .iter()
            .filter(|r| (r.noise > 0.0) == noisy)
            .map(|r| r.rms_z)
            .collect();
        (
            z.iter().copied().fold(f64::INFINITY, f64::min),
            z.iter().copied().fold(0.0, f64::max),
        )
    };
    let ((a0, b0), (a2, b2)) = (range(false), range(true));
    println!(
        "rms error/σ point by point: from {a0:.2} to {b0:.2} without noise, {a2:.2} to {b2:.2} with; over 3 σ: at most {:.1} % of a run's coordinates",
        100.0 * runs.iter().map(|r| r.over_3_sigma).fold(0.0, f64::max)
    );
    runs
}

/// Point 6 of issue 20 on every run: no kept point more than 0.1 px off, at least
/// 90 % of the textured grid points kept, and the predicted σ within a factor of two
/// of the error, read two ways:
///
/// - point by point: the RMS over the kept points of each error in units of its own σ
///   (`rms_z`) is in [0.5, 2] on every run. This is the reading that holds σ to
///   account where it is used, on each point: a grown subset on a sky with σ 0.02 px
///   and a point on grass with σ 0.002 px are each judged by their own σ.
/// - pooled: RMS error over RMS σ is in [0.5, 2] on every run with noise, and at most
///   2 (σ not over-confident) on every run without. Pooled, the few largest σ of a run
///   (its smooth regions) set the ratio. Without noise the current frame's rounding is
///   the only error besides the reference's; its size depends on the run's one
///   sub-pixel phase, which σ bounds by the RMS over four phases
///   (`icgn::rounding_error`), so that pooled σ may be up to 2.6 times the error
///   there: measured and printed, not asserted.
///
/// `pooled`: the share kept is checked over the four shifts of each photograph, kind
/// of pair and noise level together rather than run by run (a coarse grid's run has
/// about 90 textured points, whose share varies by ±2.5 % from one grid to another).
fn assert_point_6(runs: &[Run], pooled: bool) {
    let share = |rs: &[&Run], at: &str| {
        let (kept, all) = rs
            .iter()
            .fold((0, 0), |(k, a), r| (k + r.textured_kept, a + r.textured));
        assert!(
            kept as f64 >= 0.9 * all as f64,
            "{at}: {kept} of {all} textured points kept"
        );
    };
    if pooled {
        for name in PHOTOS {
            for pair in [Pair::Photo, Pair::Exposed] {
                for noise in [0.0, 2.0] {
                    let rs: Vec<&Run> = runs
                        .iter()
                        .filter(|r| r.name == name && r.pair == pair && r.noise == noise)
                        .collect();
                    share(&rs, &format!("{name} {pair:?} noise {noise}, all shifts"));
                }
            }
        }
    }
    for r in runs {
        let at = format!("{} {:?} {:?} noise {}", r.name, r.pair, r.shift, r.noise);
        assert_eq!(r.wrong, 0, "{at}: kept points over 0.1 px off");
        if !pooled {
            share(&[r], &at);
        }
        assert!(
            (0.5..=2.0).contains(&r.rms_z),
            "{at}: rms of error / σ point by point {}",
            r.rms_z
        );
        let ratio = r.rms_error / r.rms_sigma;
        let range = if r.noise > 0.0 { 0.5..=2.0 } else { 0.0..=2.0 };
        assert!(range.contains(&ratio), "{at}: rms error / rms σ {ratio}");
    }
}

/// Issue 20, point 6, on the full grid: 6 photographs, 2 kinds of pair, 4 sub-pixel
/// shifts, noise 0 and 2 grey levels, a grid point every 5 px (96 runs, 194 400
/// points). Prints one line per run and a summary (`cargo test -p cellinject-dic
/// --release --test real_images -- --include-ignored --nocapture`; `DIC_PREFILTER=0.7`
/// in the environment runs every field with that Gaussian prefilter).
///
/// Measured (release build, about 15 s on 2 cores, where this text said 370 s before
/// issue 37's work): 161 679 points kept, none more than 0.1 px off (worst 0.095 px);
/// textured points kept: median 100 %, lowest 91.6 % (camera_sky_coat, the
/// photograph as reference, (0.37, −0.62), noise 2); the RMS of error / σ point by point 0.54-1.13 in
/// every run, 1.4 % of a run's coordinates at most more than 3 σ off; RMS error / RMS
/// σ 0.77-1.10 on the 48 runs with noise, 0.37-1.21 on the 48 without (15 of them
/// under 0.5, σ conservative where the rounding sets it;
/// see [`assert_point_6`]). The history of this figure (cubic spline, spectral bias
/// model, square subsets: 4 points over 0.1 px, 81 % kept) is in the CHANGELOG and
/// `accept::measure`'s documentation.
#[test]
#[ignore = "about 15 s in a release build (minutes in a debug one); the CI runs the coarse grid below"]
fn photographs_shifted_by_known_amounts() {
    assert_point_6(&all_runs(5), false);
}

/// The same runs and checks on a grid point every 20 px (13 824 points), in the
/// test suite, with the share of textured points kept pooled over the shifts.
#[test]
fn photographs_shifted_by_known_amounts_on_a_coarse_grid() {
    assert_point_6(&all_runs(20), true);
}

/// The generator is exact: a whole-pixel shift is the mirrored image moved by whole
/// pixels.
#[test]
fn the_fourier_shift_is_exact() {
    let img = load("camera_field");
    let (w, h) = (img.width(), img.height());
    let moved = fourier_shift(&img, 3.0, -2.0);
    let mirror = |i: isize, n: usize| -> usize {
        let n = n as isize;
        let m = i.rem_euclid(2 * n);
        (if m < n { m } else { 2 * n - 1 - m }) as usize
    };
    let mut worst = 0.0f64;
    for y in 0..h {
        for x in 0..w {
            let want = img.at(mirror(x as isize - 3, w), mirror(y as isize + 2, h));
            worst = worst.max((moved[y * w + x] - want).abs());
        }
    }
    assert!(worst < 1e-9, "{worst}");
}
