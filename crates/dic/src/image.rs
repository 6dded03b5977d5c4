//! Greyscale images as the DIC sees them: `f64` grey levels in the source's own units
//! (0-255 for 8-bit, 0-65535 for 16-bit), row-major.

use crate::DicError;

/// A greyscale image.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    width: usize,
    height: usize,
    data: Vec<f64>,
}

impl Image {
    /// An image from row-major grey levels.
    pub fn new(width: usize, height: usize, data: Vec<f64>) -> Result<Self, DicError> {
        if width == 0 || height == 0 || data.len() != width * height {
            return Err(DicError::BadImage {
                reason: format!(
                    "{width}x{height} needs {} values, got {}",
                    width * height,
                    data.len()
                ),
            });
        }
        if data.iter().any(|v| !v.is_finite()) {
            return Err(DicError::BadImage {
                reason: "contains a value that is not finite".into(),
            });
        }
        Ok(Image {
            width,
            height,
            data,
        })
    }

    /// An image from 16-bit pixels.
    pub fn from_u16(width: usize, height: usize, px: &[u16]) -> Result<Self, DicError> {
        Image::new(width, height, px.iter().map(|&v| v as f64).collect())
    }

    /// A camera frame as an image in the frame's own grey levels (0 to 2^bit_depth − 1):
    /// the one conversion from the hardware layer's [`cellinject_hw::Frame`].
    pub fn from_frame(frame: &cellinject_hw::Frame) -> Result<Self, DicError> {
        Image::from_u16(frame.width as usize, frame.height as usize, &frame.pixels)
    }

    /// Columns.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Rows.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Row-major grey levels.
    pub fn data(&self) -> &[f64] {
        &self.data
    }

    /// Grey level at column `x`, row `y`.
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> f64 {
        self.data[y * self.width + x]
    }

    /// A copy of the rectangle `[x0, x0 + w) x [y0, y0 + h)`, clamped to the image.
    pub fn crop(&self, x0: usize, y0: usize, w: usize, h: usize) -> Image {
        let x1 = (x0 + w).min(self.width);
        let y1 = (y0 + h).min(self.height);
        let (x0, y0) = (x0.min(x1), y0.min(y1));
        let mut data = Vec::with_capacity((x1 - x0) * (y1 - y0));
        for y in y0..y1 {
            data.extend_from_slice(&self.data[y * self.width + x0..y * self.width + x1]);
        }
        Image {
            width: x1 - x0,
            height: y1 - y0,
            data,
        }
    }

    /// Half-resolution image by 2x2 averaging (for coarse-to-fine search).
    pub fn downsample(&self) -> Image {
        let (w, h) = (self.width / 2, self.height / 2);
        let mut data = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let s = self.at(2 * x, 2 * y)
                    + self.at(2 * x + 1, 2 * y)
                    + self.at(2 * x, 2 * y + 1)
                    + self.at(2 * x + 1, 2 * y + 1);
                data.push(0.25 * s);
            }
        }
        Image {
            width: w.max(1),
            height: h.max(1),
            data: if data.is_empty() { vec![0.0] } else { data },
        }
    }

    /// Separable Gaussian low-pass (optional prefilter against aliasing), sigma in
    /// pixels, kernel truncated at 3σ and normalised, mirror boundaries.
    pub fn gaussian_blur(&self, sigma: f64) -> Image {
        if sigma <= 0.0 {
            return self.clone();
        }
        let r = (3.0 * sigma).ceil() as isize;
        let k: Vec<f64> = (-r..=r)
            .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
            .collect();
        let s: f64 = k.iter().sum();
        let k: Vec<f64> = k.iter().map(|v| v / s).collect();
        let (w, h) = (self.width as isize, self.height as isize);
        let mirror = |i: isize, n: isize| -> usize {
            let m = if i < 0 {
                -i
            } else if i >= n {
                2 * n - 2 - i
            } else {
                i
            };
            m.clamp(0, n - 1) as usize
        };
        let mut tmp = vec![0.0; self.data.len()];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for (j, kv) in k.iter().enumerate() {
                    acc += kv * self.data[y as usize * self.width + mirror(x + j as isize - r, w)];
                }
                tmp[y as usize * self.width + x as usize] = acc;
            }
        }
        let mut out = vec![0.0; self.data.len()];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                for (j, kv) in k.iter().enumerate() {
                    acc += kv * tmp[mirror(y + j as isize - r, h) * self.width + x as usize];
                }
                out[y as usize * self.width + x as usize] = acc;
            }
        }
        Image {
            width: self.width,
            height: self.height,
            data: out,
        }
    }
}

/// Variance of the rounding noise of an image's grey levels: `q²/12` for the step `q`
/// of its levels when they are whole numbers (8- or 16-bit data; `q` is the greatest
/// common divisor of their differences, 256 for 8-bit data stored in 16 bits), 0 for
/// other values (a synthetic or already filtered image) and for a uniform image.
pub fn quantisation_variance(img: &Image) -> f64 {
    let data = img.data();
    // One pass, a block at a time without an early exit inside it (so it runs on the
    // vector units): whole numbers within ±1e15, and their least. Whole is tested by
    // a round trip through an integer (a conversion every x86-64 has; `trunc` is a
    // call on the baseline instruction set); NaN comes back as 0, not itself.
    let mut lo = f64::INFINITY;
    for block in data.chunks(1024) {
        let (whole, least) = block.iter().fold((true, f64::INFINITY), |(ok, m), &v| {
            (ok & (v.abs() <= 1e15) & ((v as i64) as f64 == v), m.min(v))
        });
        if !whole {
            return 0.0;
        }
        lo = lo.min(least);
    }
    let gcd = |mut a: u64, mut b: u64| {
        while b != 0 {
            (a, b) = (b, a % b);
        }
        a
    };
    let mut q = 0u64;
    for v in data {
        q = gcd(q, (v - lo) as u64);
        if q == 1 {
            break;
        }
    }
    (q * q) as f64 / 12.0
}

/// Factor by which [`Image::gaussian_blur`] of `sigma` scales the variance of white noise.
pub fn blur_noise_gain(sigma: f64) -> f64 {
    if sigma <= 0.0 {
        return 1.0;
    }
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f64 = k.iter().sum();
    let g: f64 = k.iter().map(|v| (v / s).powi(2)).sum();
    g * g
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blur_keeps_constants_and_the_mean() {
        let flat = Image::new(20, 10, vec![7.0; 200]).unwrap();
        assert!(
            flat.gaussian_blur(1.5)
                .data()
                .iter()
                .all(|v| (v - 7.0).abs() < 1e-12)
        );
        let data: Vec<f64> = (0..400).map(|k| ((k * 37) % 11) as f64).collect();
        let img = Image::new(20, 20, data).unwrap();
        let b = img.gaussian_blur(1.0);
        // Smoother: the variance drops.
        let var = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            v.iter().map(|x| (x - m).powi(2)).sum::<f64>()
        };
        assert!(var(b.data()) < 0.5 * var(img.data()));
        assert_eq!(img.gaussian_blur(0.0), img);
    }

    #[test]
    fn rounding_noise_is_found_from_the_levels() {
        let eight = Image::new(3, 1, vec![0.0, 7.0, 255.0]).unwrap();
        assert!((quantisation_variance(&eight) - 1.0 / 12.0).abs() < 1e-15);
        // 8-bit data stored in 16 bits: steps of 256.
        let wide = Image::new(3, 1, vec![0.0, 256.0, 1024.0]).unwrap();
        assert!((quantisation_variance(&wide) - 256.0 * 256.0 / 12.0).abs() < 1e-9);
        let smooth = Image::new(3, 1, vec![0.5, 1.25, 2.0]).unwrap();
        assert_eq!(quantisation_variance(&smooth), 0.0);
        // The blur's variance gain: the sum of the squared weights, in two dimensions.
        let mut rng = cellinject_numeric::Rng::new(1, 1);
        let noise: Vec<f64> = (0..16384).map(|_| rng.gaussian_exact()).collect();
        let img = Image::new(128, 128, noise).unwrap();
        let var = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64;
        let ratio = var(img.gaussian_blur(1.0).data()) / var(img.data());
        assert!(
            (ratio / blur_noise_gain(1.0) - 1.0).abs() < 0.1,
            "{ratio} vs {}",
            blur_noise_gain(1.0)
        );
    }
}
