//! DIC on real photographs (not speckle) shifted by known sub-pixel amounts.
//!
//! The photographs are 256x256 8-bit crops in `tests/data/photos` (see its README for
//! sources and licences). Each current image is made here from the committed original
//! by an exact band-limited shift, independent of the code under test and of its
//! interpolant: the image is extended mirror-symmetrically to a 512x512 period (so the
//! period has no jump at its edges), shifted in the Fourier domain, cropped, and rounded
//! to 8 bits like a camera's frame; optionally both images get Gaussian noise first.
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
use cellinject_numeric::Rng;
use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

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

/// The band-limited shift of `img`'s mirror-symmetric periodic extension: the result at
/// pixel (x, y) is the trigonometric interpolant of the extension at (x − u, y − v).
fn fourier_shift(img: &Image, u: f64, v: f64) -> Vec<f64> {
    let (w, h) = (img.width(), img.height());
    let (ew, eh) = (2 * w, 2 * h);
    let mirror = |i: usize, n: usize| if i < n { i } else { 2 * n - 1 - i };
    let mut e: Vec<Complex<f64>> = (0..eh)
        .flat_map(|y| (0..ew).map(move |x| (x, y)))
        .map(|(x, y)| Complex::new(img.at(mirror(x, w), mirror(y, h)), 0.0))
        .collect();
    let mut planner = FftPlanner::new();
    let fft2 = |data: &mut [Complex<f64>], inverse: bool, planner: &mut FftPlanner<f64>| {
        let (fr, fc) = if inverse {
            (planner.plan_fft_inverse(ew), planner.plan_fft_inverse(eh))
        } else {
            (planner.plan_fft_forward(ew), planner.plan_fft_forward(eh))
        };
        for row in data.chunks_mut(ew) {
            fr.process(row);
        }
        let mut col = vec![Complex::new(0.0, 0.0); eh];
        for x in 0..ew {
            for y in 0..eh {
                col[y] = data[y * ew + x];
            }
            fc.process(&mut col);
            for y in 0..eh {
                data[y * ew + x] = col[y];
            }
        }
    };
    fft2(&mut e, false, &mut planner);
    let freq = |k: usize, n: usize| {
        if 2 * k < n {
            k as f64 / n as f64
        } else {
            k as f64 / n as f64 - 1.0
        }
    };
    for ky in 0..eh {
        for kx in 0..ew {
            let phase = -2.0 * std::f64::consts::PI * (freq(kx, ew) * u + freq(ky, eh) * v);
            e[ky * ew + kx] *= Complex::from_polar(1.0, phase);
        }
    }
    fft2(&mut e, true, &mut planner);
    let scale = 1.0 / (ew * eh) as f64;
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| e[y * ew + x].re * scale)
        .collect()
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

/// One photograph, one shift, one noise level: the field and what it says.
struct Run {
    name: &'static str,
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
}

fn run(
    name: &'static str,
    img: &Image,
    shift: (f64, f64),
    noise: f64,
    seed: u64,
    step: usize,
) -> Run {
    let (w, h) = (img.width(), img.height());
    let mut rng = Rng::new(seed, 1);
    let r = if noise > 0.0 {
        expose(img.data(), w, h, noise, &mut rng)
    } else {
        img.clone()
    };
    let c = expose(&fourier_shift(img, shift.0, shift.1), w, h, noise, &mut rng);
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
    let (mut worst, mut se, mut ss) = (0.0f64, 0.0, 0.0);
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
        }
    }
    let n = (2 * kept.max(1)) as f64;
    Run {
        name,
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
    }
}

const SHIFTS: [(f64, f64); 4] = [(0.37, -0.62), (0.25, 0.1), (-1.13, 2.5), (0.05, -0.8)];

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Every photograph, shift and noise level on a grid of `step` pixels, one printed line
/// each and a summary.
fn all_runs(step: usize) -> Vec<Run> {
    let mut runs = Vec::new();
    for name in PHOTOS {
        let img = load(name);
        for (k, &shift) in SHIFTS.iter().enumerate() {
            for noise in [0.0, 2.0] {
                let r = run(name, &img, shift, noise, 7 + k as u64, step);
                println!(
                    "{:16} shift ({:5.2}, {:5.2}) noise {}: kept {:4} of {} ({:4} dropped), worst {:.3} px, {:3} over 0.1 px, textured {:4} kept {:5.1} %, rms error {:.4} px, rms σ {:.4} px, ratio {:.2}",
                    r.name,
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
                    r.rms_error / r.rms_sigma
                );
                runs.push(r);
            }
        }
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
    runs
}

fn assert_sigma_within_two(r: &Run) {
    let ratio = r.rms_error / r.rms_sigma;
    assert!(
        (0.5..=2.0).contains(&ratio),
        "{} {:?} noise {}: rms error / rms σ {ratio}",
        r.name,
        r.shift,
        r.noise
    );
}

/// Issue 20, point 6: on photographs shifted by known sub-pixel amounts, no point more
/// than 0.1 px off is reported, at least 90 % of the textured grid points are kept,
/// and the predicted σ is within a factor of two of the RMS error. Prints one line per
/// photograph, shift and noise (`cargo test -p cellinject-dic --release --test
/// real_images -- --include-ignored --nocapture`; `DIC_PREFILTER=0.7` in the
/// environment runs every field with that Gaussian prefilter).
///
/// Where it stands, on all 48 runs at step 5, with the self-adaptive subset (a point
/// whose σ exceeds `max_sigma` at 31 px is tried at 41, 51 and 61 px, and a grown
/// subset's σ includes its simulated rounding error: `accept::measure`): textured
/// kept median 96.1 %, lowest 41.5 % (was 78 % and 29 %), 14 runs under 90 % (was 33):
/// camera_field in 7 runs (41-85 %: the cubic spline's interpolation bias, which a
/// larger subset does not lower), camera_sky_coat in 4 (86-90 %), grass at
/// (0.05, −0.8) (85-86 %, bias), brick at (0.05, −0.8), noise 2 (88 %). RMS error / σ
/// 0.71-1.36 (was 0.71-1.34). Not met: 9 points in 5 runs are kept 0.103-0.171 px off
/// (was 4, up to 0.115): 4 in camera_sky_coat at (0.05, −0.8), noise 0, the worst at
/// (56, 76) on a 61 px subset of smooth sky whose rounding error the simulation puts
/// at 0.03 px against 0.165 px; the others at noise 2 on 41-61 px subsets of the
/// dark coat along the sky (errors of the same sign in u and v, 4-5 σ). The
/// test takes about 2 minutes in a release build (35 s without the growth).
///
/// Measured on the way: growth alone (no rounding term) keeps 30 points over 0.1 px
/// (worst 0.171, sky at noise 0); the rounding term on every subset, not only grown
/// ones, cuts that to 8 but overstates σ on brick at (0.05, −0.8), noise 0 (RMS error
/// / σ 0.42, and 0.48 in `the_predicted_sigma_holds_on_photographs`), as does taking
/// the larger of it and the white-noise σ (0.45, 15 points over 0.1 px); growth only
/// up to 51 px: median 94.7 %, 18 runs under 90 %, 6 points over 0.1 px. Growth with
/// the Gaussian prefilter (no rounding term, since the rounding is simulated on
/// unfiltered data only): 0.5 px, median 99.3 %, lowest 77.8 %, 67 points over 0.1 px;
/// 0.7 px, median 99.9 %, lowest 85.8 %, 36 points over 0.1 px.
///
/// Routes measured before the self-adaptive subset, and not taken:
///
/// - The Gaussian prefilter at 0.7 px (σ as now, white-noise derivative gain; the
///   previous measurement): textured kept median 99 %, lowest 65 % (camera_sky_coat at noise 2), 6 points in
///   5 runs kept over 0.1 px, RMS error / σ 0.77-2.03. With the blurred noise's
///   smaller derivative gain in σ (`∫|DH|²/∫|H|²` over the band, H the blur: about a
///   third of the white one at 0.7 px): median 99.6 %, lowest 69 %, 12 points kept
///   over 0.1 px (worst 0.115), ratio up to 2.14; at 0.5 px: median 94 %, lowest 60 %
///   (camera_field's bias at noise 0), 3 points over 0.1 px (worst 0.134), ratio up to
///   1.69. With the prefilter the σ of the noise-2 runs is 1.1-1.45 times too small,
///   and a longer residual correlation in the sandwich (2 → 6 px) does not change it.
/// - Subtracting the interpolation bias σ already predicts (the spectrum-weighted
///   spline phase error, with the sign as computed) cuts the RMS error 2-5 times where
///   the bias dominates (grass at shift (0.05, −0.8): 0.0148 → 0.0029 px; camera_field
///   0.0157 → 0.0093 px; gravel at noise 0 0.006-0.009 → 0.0015-0.0025 px), and with 0.3 of the bias left in σ
///   the textured kept median rises to 95 % (lowest 47 %, brick at noise 2), but the
///   σ test fails at both ends: RMS error / σ 2.14 on brick at (0.05, −0.8), noise 0
///   (3 points kept over 0.1 px, 6 in all), and 0.49 on gravel at noise 0 (the
///   rounding floor counts both images' rounding, and this test's reference is exact).
/// - Cause on brick at (0.05, −0.8), point (71, 31), IC-GN started at the truth: with
///   the exact (unrounded) shifted image the error in v is +0.020 px, the
///   interpolation bias (predicted +0.012 px per axis, +0.022 px when the predicted
///   per-pixel mismatch is mapped through the full normal equations); with the 8-bit
///   image it is −0.058 px (and a spurious ∂v/∂x of −0.006), rigid 31 px −0.001 px,
///   affine 41 px +0.007 px: the 8-bit rounding of this weakly textured patch, not
///   the interpolation, makes the error, through the affine subset's shear. σ does
///   not see it: the residual's lag-1 correlation there is small, so an automatic
///   Newey-West reach (Andrews 1991, AR(1) plug-in, at least 2 px) changes nothing on
///   any run. Until σ accounts for rounding on weak texture, subtracting the bias
///   only lets more such points through.
/// - Both together (tried, not landed): σ gains a rounding term (the reference moved
///   by half a pixel to first order, rounded to the step the residual floor implies,
///   the rounding error mapped through the normal equations, `A_s⁻¹ Σ J̃ q`: about
///   the noise term on strong texture, large on a weak gradient); the bias is
///   subtracted, with the noise's expected power taken out of the spectrum first
///   (else speckle under noise is over-corrected by 0.0015 px) and 0.2 of it left in
///   σ. On the 48 runs: textured kept median 93.9 %, lowest 47.1 % (19 runs under
///   90 %: brick, sky and astronaut at noise 2 are noise-limited), 3 points kept
///   0.100-0.106 px off (was 4, up to 0.115), RMS error / σ 0.50-1.95 (was
///   0.71-1.34: both ends at the limit). It also moves one edge point of
///   `field_mode_covers_the_grid_and_matches_the_shift` (speckle, (11, 99)) from
///   −0.049 to −0.052 px, past that test's 0.05 px.
#[test]
#[ignore = "issue 20 point 6 is not met yet: the σ holds (0.71-1.36), the self-adaptive subset keeps a median 96 % of the textured points, but 9 points in camera_sky_coat and astronaut are kept 0.103-0.171 px off, and 14 runs keep fewer than 90 % (lowest 41.5 %: the cubic spline's interpolation bias on camera_field and grass). See the notes above"]
fn photographs_shifted_by_known_amounts() {
    let runs = all_runs(5);
    for r in &runs {
        let at = format!("{} {:?} noise {}", r.name, r.shift, r.noise);
        assert_eq!(r.wrong, 0, "{at}: kept points over 0.1 px off");
        if r.textured > 0 {
            assert!(
                r.textured_kept as f64 >= 0.9 * r.textured as f64,
                "{at}: {} of {} textured points kept",
                r.textured_kept,
                r.textured
            );
        }
        assert_sigma_within_two(r);
    }
}

/// The part of point 6 that holds, on a coarse grid (fast in a debug build): the
/// predicted σ of the kept points is within a factor of two of their RMS error on
/// every photograph, shift and noise level, and with camera noise (σ = 2 grey levels)
/// no kept point is more than 0.1 px off.
#[test]
fn the_predicted_sigma_holds_on_photographs() {
    for r in &all_runs(20) {
        assert_sigma_within_two(r);
        if r.noise > 0.0 {
            assert_eq!(
                r.wrong, 0,
                "{} {:?} noise {}: kept points over 0.1 px off",
                r.name, r.shift, r.noise
            );
        }
    }
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
