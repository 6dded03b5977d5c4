//! Exact synthetic images for tests and benchmarks: a sum of Gaussian speckles
//! integrated over each pixel (through the error function), moved by moving their
//! centres (never by interpolating an image), then Gaussian noise and quantisation;
//! and the band-limited (Fourier) shift of a real photograph ([`fourier_shift`]).

use cellinject_numeric::Rng;
use rustfft::FftPlanner;
use rustfft::num_complex::Complex;

use crate::image::Image;
use crate::search::fft2;

/// How the speckle pattern looks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpeckleParams {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Speckles per pixel of image area.
    pub density: f64,
    /// Gaussian sigma of a speckle, pixels (range).
    pub sigma: [f64; 2],
    /// Peak grey level of a speckle (range).
    pub amplitude: [f64; 2],
    /// Background grey level.
    pub background: f64,
    /// Noise sigma, grey levels.
    pub noise: f64,
    /// Bits of the output (8 or 16); 0 keeps the exact, unquantised values.
    pub bits: u32,
}

impl SpeckleParams {
    /// A well-conditioned 8-bit pattern with 2 grey levels of noise.
    pub fn default_for(width: usize, height: usize) -> Self {
        SpeckleParams {
            width,
            height,
            density: 0.04,
            sigma: [1.6, 2.4],
            amplitude: [50.0, 90.0],
            background: 40.0,
            noise: 2.0,
            bits: 8,
        }
    }
}

/// One speckle pattern.
#[derive(Debug, Clone)]
pub struct Speckle {
    params: SpeckleParams,
    /// (x, y, sigma, amplitude), in pixel coordinates of the reference image.
    dots: Vec<[f64; 4]>,
}

/// ∫ exp(−(s − c)²/2σ²) ds over [a, b].
fn gauss_integral(a: f64, b: f64, c: f64, sigma: f64) -> f64 {
    let k = sigma * std::f64::consts::FRAC_PI_2.sqrt();
    let r = std::f64::consts::SQRT_2 * sigma;
    k * (cellinject_numeric::erf((b - c) / r) - cellinject_numeric::erf((a - c) / r))
}

impl Speckle {
    /// A random pattern (speckles scattered a little beyond the borders).
    pub fn new(p: &SpeckleParams, seed: u64) -> Self {
        let mut g = Rng::new(seed, 0x005E_ED0F_5BEC);
        let margin = 40.0;
        let area = (p.width as f64 + 2.0 * margin) * (p.height as f64 + 2.0 * margin);
        let n = (p.density * area).round() as usize;
        let dots = (0..n)
            .map(|_| {
                [
                    -margin + g.uniform() * (p.width as f64 + 2.0 * margin),
                    -margin + g.uniform() * (p.height as f64 + 2.0 * margin),
                    p.sigma[0] + g.uniform() * (p.sigma[1] - p.sigma[0]),
                    p.amplitude[0] + g.uniform() * (p.amplitude[1] - p.amplitude[0]),
                ]
            })
            .collect();
        Speckle { params: *p, dots }
    }

    /// The same pattern seen out of focus: convolved with a Gaussian of `blur` pixels
    /// (σ), exactly (each speckle's σ² grows by `blur²` and its peak falls so that its
    /// integral stays the same).
    pub fn defocused(&self, blur: f64) -> Speckle {
        let dots = self
            .dots
            .iter()
            .map(|&[x, y, s, a]| {
                let s2 = s * s + blur * blur;
                [x, y, s2.sqrt(), a * s * s / s2]
            })
            .collect();
        Speckle {
            params: self.params,
            dots,
        }
    }

    /// Renders the pattern with every speckle centre moved by `map` (reference pixel
    /// coordinates to current ones), exactly integrated over the pixels.
    pub fn render_mapped(&self, map: impl Fn(f64, f64) -> (f64, f64), noise_seed: u64) -> Image {
        let p = &self.params;
        let (w, h) = (p.width, p.height);
        let mut data = vec![p.background; w * h];
        let mut gx = Vec::new();
        for d in &self.dots {
            let (cx, cy) = map(d[0], d[1]);
            let (s, a) = (d[2], d[3]);
            let reach = 5.0 * s;
            let i0 = ((cx - reach).floor().max(0.0)) as usize;
            let i1 = ((cx + reach).ceil().min(w as f64 - 1.0)).max(0.0) as usize;
            let j0 = ((cy - reach).floor().max(0.0)) as usize;
            let j1 = ((cy + reach).ceil().min(h as f64 - 1.0)).max(0.0) as usize;
            if cx + reach < 0.0 || cy + reach < 0.0 || i0 > i1 || j0 > j1 {
                continue;
            }
            gx.clear();
            for i in i0..=i1 {
                gx.push(gauss_integral(i as f64 - 0.5, i as f64 + 0.5, cx, s));
            }
            for j in j0..=j1 {
                let gy = a * gauss_integral(j as f64 - 0.5, j as f64 + 0.5, cy, s);
                let row = &mut data[j * w + i0..=j * w + i1];
                for (px, g) in row.iter_mut().zip(&gx) {
                    *px += gy * g;
                }
            }
        }
        let mut g = Rng::new(noise_seed, 0xA5A5);
        let max = if p.bits == 0 {
            f64::INFINITY
        } else {
            ((1u64 << p.bits) - 1) as f64
        };
        for v in &mut data {
            if p.noise > 0.0 {
                *v += p.noise * g.gaussian_exact();
            }
            if p.bits > 0 {
                *v = v.round().clamp(0.0, max);
            }
        }
        Image::new(w, h, data).unwrap_or_else(|e| unreachable!("synthetic image: {e}"))
    }

    /// Renders the pattern shifted by (u, v) and rotated by `theta` (rad) about the image centre.
    pub fn render_shifted(&self, u: f64, v: f64, theta: f64, noise_seed: u64) -> Image {
        let (cx, cy) = (
            0.5 * (self.params.width as f64 - 1.0),
            0.5 * (self.params.height as f64 - 1.0),
        );
        let (s, c) = theta.sin_cos();
        self.render_mapped(
            |x, y| {
                let (dx, dy) = (x - cx, y - cy);
                (cx + c * dx - s * dy + u, cy + s * dx + c * dy + v)
            },
            noise_seed,
        )
    }

    /// The exact derivatives (∂f/∂x, ∂f/∂y) of the noise-free, pixel-integrated pattern
    /// with respect to a shift of the pixel grid, from the Gaussians themselves
    /// (independent of any interpolation): for the error bounds of tests.
    pub fn gradient_exact(&self) -> (Image, Image) {
        let p = &self.params;
        let (w, h) = (p.width, p.height);
        let mut gx = vec![0.0; w * h];
        let mut gy = vec![0.0; w * h];
        for d in &self.dots {
            let (cx, cy, s, a) = (d[0], d[1], d[2], d[3]);
            let reach = 5.0 * s;
            if cx + reach < 0.0
                || cy + reach < 0.0
                || cx - reach > w as f64
                || cy - reach > h as f64
            {
                continue;
            }
            let i0 = (cx - reach).floor().max(0.0) as usize;
            let i1 = (cx + reach).ceil().clamp(0.0, w as f64 - 1.0) as usize;
            let j0 = (cy - reach).floor().max(0.0) as usize;
            let j1 = (cy + reach).ceil().clamp(0.0, h as f64 - 1.0) as usize;
            let e = |t: f64| (-t * t / (2.0 * s * s)).exp();
            for j in j0..=j1 {
                let yj = j as f64;
                let iy = gauss_integral(yj - 0.5, yj + 0.5, cy, s);
                let dy = e(yj + 0.5 - cy) - e(yj - 0.5 - cy);
                for i in i0..=i1 {
                    let xi = i as f64;
                    let ix = gauss_integral(xi - 0.5, xi + 0.5, cx, s);
                    let dx = e(xi + 0.5 - cx) - e(xi - 0.5 - cx);
                    gx[j * w + i] += a * dx * iy;
                    gy[j * w + i] += a * ix * dy;
                }
            }
        }
        let img = |v| Image::new(w, h, v).unwrap_or_else(|e| unreachable!("gradient image: {e}"));
        (img(gx), img(gy))
    }

    /// The noise-free pattern (for gradients in error bounds).
    pub fn render_exact(&self) -> Image {
        let p = SpeckleParams {
            noise: 0.0,
            bits: 0,
            ..self.params
        };
        Speckle {
            params: p,
            dots: self.dots.clone(),
        }
        .render_mapped(|x, y| (x, y), 0)
    }
}

/// The band-limited shift of `img` by (u, v) pixels, row-major values (not rounded):
/// pixel (x, y) holds the trigonometric interpolant of the image's mirror-symmetric
/// periodic extension at (x − u, y − v), what a camera would take of a band-limited
/// scene moved by (u, v). Exact for whole-pixel shifts (the mirrored image moved);
/// for any shift of a real photograph, the pair with a known sub-pixel motion that the
/// accuracy tests correlate (`tests/real_images.rs`; `bench/photo_pair.py` does the
/// same in NumPy).
pub fn fourier_shift(img: &Image, u: f64, v: f64) -> Vec<f64> {
    let (w, h) = (img.width(), img.height());
    let (ew, eh) = (2 * w, 2 * h);
    let mirror = |i: usize, n: usize| if i < n { i } else { 2 * n - 1 - i };
    let mut e: Vec<Complex<f64>> = (0..eh)
        .flat_map(|y| (0..ew).map(move |x| (x, y)))
        .map(|(x, y)| Complex::new(img.at(mirror(x, w), mirror(y, h)), 0.0))
        .collect();
    let mut planner = FftPlanner::new();
    fft2(&mut planner, &mut e, (ew, eh), false);
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
    fft2(&mut planner, &mut e, (ew, eh), true);
    let scale = 1.0 / (ew * eh) as f64;
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| e[y * ew + x].re * scale)
        .collect()
}
