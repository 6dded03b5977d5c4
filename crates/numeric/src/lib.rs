//! # cellinject-numeric
//!
//! Numerical pieces that several cellinject crates need and that must be the same
//! everywhere: the seeded random generator ([`Rng`], bit-exact so that the twin's
//! digests hold), the error function ([`erf`], [`erfc`], [`normal_cdf`]) and a damped
//! Newton solve of two equations in two unknowns with a finite-difference Jacobian
//! ([`newton2`]), non-negative least squares ([`nnls_gram`], Lawson-Hanson) for
//! identifying hysteresis weights, and the [`median`].
//!
//! **Architecture invariant:** pure functions of their arguments; no IO, no global
//! state but lazily built constant tables.

mod newton;
pub mod nnls;
pub mod rng;

pub use newton::{Newton2, Newton2Error, Newton2Options, newton2};
pub use nnls::{NnlsError, nnls_gram};
pub use rng::Rng;

/// The error function erf(x) (libm's, correctly rounded to within 1 ulp).
#[inline]
pub fn erf(x: f64) -> f64 {
    libm::erf(x)
}

/// The complementary error function erfc(x) = 1 − erf(x), accurate also where erf(x)
/// is close to 1.
#[inline]
pub fn erfc(x: f64) -> f64 {
    libm::erfc(x)
}

/// The median of `v` (sorted in place): the middle value, the mean of the middle two
/// for an even count; NaN for an empty slice.
pub fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The standard normal cumulative distribution Φ(u) = erfc(−u/√2)/2.
#[inline]
pub fn normal_cdf(u: f64) -> f64 {
    0.5 * erfc(-u / std::f64::consts::SQRT_2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_is_the_middle_value_or_the_mean_of_the_middle_two() {
        assert_eq!(median(&mut [0.1, -3.0, 0.2, 0.0, 0.15]), 0.1);
        assert!((median(&mut [0.2, 0.1, -3.0, 0.3]) - 0.15).abs() < 1e-12);
        assert_eq!(median(&mut [2.0]), 2.0);
        assert!(median(&mut []).is_nan());
    }

    #[test]
    fn erf_matches_reference_values_and_symmetry() {
        // Abramowitz & Stegun Table 7.1.
        assert!((erf(0.5) - 0.520_499_877_813_047).abs() < 1e-15);
        assert!((erf(1.0) - 0.842_700_792_949_715).abs() < 1e-15);
        assert!((erfc(3.0) - 2.209_049_699_858_544e-5).abs() < 1e-19);
        for x in [0.1, 0.7, 2.3] {
            assert_eq!(erf(-x), -erf(x));
            assert!((erf(x) + erfc(x) - 1.0).abs() < 1e-15);
        }
        assert!((normal_cdf(1.959_963_984_540_054) - 0.975).abs() < 1e-12);
    }
}
