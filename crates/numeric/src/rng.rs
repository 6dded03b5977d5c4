//! Seeded randomness, bit-exact across platforms and crate versions: the one random
//! generator of cellinject (the twin's noise and scenes, synthetic DIC images).
//!
//! The twin's determinism test holds the digest of a fixed scenario, so the generator
//! and the Gaussian sampler are defined here rather than taken from a crate whose
//! algorithms may change between versions: xoshiro256++ (Blackman & Vigna 2019), seeded
//! through SplitMix64, and Gaussian samples by inverse-CDF lookup on 16-bit uniforms.

use std::sync::OnceLock;

/// xoshiro256++.
#[derive(Debug, Clone)]
pub struct Rng {
    s: [u64; 4],
}

fn splitmix(x: &mut u64) -> u64 {
    *x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *x;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Rng {
    /// A generator for `seed` and an independent `stream` (one per random process).
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut x = seed ^ stream.wrapping_mul(0xD1B5_4A32_D192_ED03);
        let s = [
            splitmix(&mut x),
            splitmix(&mut x),
            splitmix(&mut x),
            splitmix(&mut x),
        ];
        Rng { s }
    }

    /// Next 64 random bits.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let result = s[0].wrapping_add(s[3]).rotate_left(23).wrapping_add(s[0]);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        result
    }

    /// Uniform in [0, 1).
    #[inline]
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [a, b).
    #[inline]
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.uniform()
    }

    /// A standard normal sample.
    #[inline]
    pub fn gaussian(&mut self) -> f64 {
        gaussian_table()[(self.next_u64() >> 48) as usize] as f64
    }

    /// A standard normal sample by the Box-Muller transform of two uniforms: exact
    /// (unbounded, unquantised) where the table of [`Rng::gaussian`] is too coarse,
    /// e.g. the noise of synthetic test images.
    pub fn gaussian_exact(&mut self) -> f64 {
        let a = ((self.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
        let b = self.uniform();
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }

    /// Four standard normal samples from one draw (for per-pixel noise).
    #[inline]
    pub fn gaussian4(&mut self) -> [f32; 4] {
        let t = gaussian_table();
        let r = self.next_u64();
        [
            t[(r & 0xFFFF) as usize],
            t[((r >> 16) & 0xFFFF) as usize],
            t[((r >> 32) & 0xFFFF) as usize],
            t[(r >> 48) as usize],
        ]
    }
}

/// Inverse normal CDF by Acklam's rational approximation (relative error below 1.2e-9).
pub fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let plow = 0.02425;
    if p < plow {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - plow {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        let q = (-2.0 * (1.0 - p).ln()).sqrt();
        -(((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    }
}

/// 65536 equiprobable normal quantiles (midpoints of the bins), scaled so that the
/// table's variance is exactly 1.
fn gaussian_table() -> &'static [f32; 65536] {
    static TABLE: OnceLock<Box<[f32; 65536]>> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut v = vec![0.0f64; 65536];
        for (i, x) in v.iter_mut().enumerate() {
            *x = inverse_normal_cdf((i as f64 + 0.5) / 65536.0);
        }
        let var = v.iter().map(|x| x * x).sum::<f64>() / 65536.0;
        let s = 1.0 / var.sqrt();
        let mut t = Box::new([0.0f32; 65536]);
        for (o, x) in t.iter_mut().zip(&v) {
            *o = (x * s) as f32;
        }
        t
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xoshiro_is_reproducible_and_streams_differ() {
        let mut a = Rng::new(7, 0);
        let mut b = Rng::new(7, 0);
        let mut c = Rng::new(7, 1);
        let xa: Vec<u64> = (0..4).map(|_| a.next_u64()).collect();
        let xb: Vec<u64> = (0..4).map(|_| b.next_u64()).collect();
        let xc: Vec<u64> = (0..4).map(|_| c.next_u64()).collect();
        assert_eq!(xa, xb);
        assert_ne!(xa, xc);
    }

    #[test]
    fn gaussian_samples_have_unit_variance_and_zero_mean() {
        let mut r = Rng::new(3, 9);
        let n = 400_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..n / 4 {
            for g in r.gaussian4() {
                s += g as f64;
                s2 += (g * g) as f64;
            }
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        // Standard errors: 1/sqrt(n) = 0.0016 for the mean, sqrt(2/n) = 0.0022 for the variance.
        assert!(mean.abs() < 0.008, "{mean}");
        assert!((var - 1.0).abs() < 0.011, "{var}");
    }

    #[test]
    fn gaussian_samples_are_bounded_by_4_5_sigma() {
        // The stacks' travel margin relies on it (piezo::Stack::new).
        assert!(gaussian_table().iter().all(|g| g.abs() < 4.5));
    }

    #[test]
    fn inverse_cdf_matches_known_quantiles() {
        assert!(inverse_normal_cdf(0.5).abs() < 1e-12);
        assert!((inverse_normal_cdf(0.975) - 1.959_963_984_540_054).abs() < 1e-8);
        assert!((inverse_normal_cdf(0.001) + 3.090_232_306_167_814).abs() < 1e-8);
    }
}
