//! Sums over a subset's pixels on the vector units: [`sums`] (several sums of
//! per-pixel terms at once) in [`LANES`] interleaved partial sums,
//! and [`V`], the lane-wise operand of [`sums`]' terms.
//!
//! **Compiled where they are called.** Everything here is `#[inline(always)]`, and
//! the closures given to [`sums`] must be too (call it through [`lane_sums!`]): the
//! callers run inside a `pulp` dispatch (AVX2/FMA or AVX-512, chosen at run time),
//! and a closure or function compiled apart from it is built for the baseline
//! instruction set and called once per vector through memory (the field ran 25 %
//! slower so).

/// Lanes of [`sums`]: as many as the widest vector unit holds (AVX-512, f64).
pub(crate) const LANES: usize = 8;

/// `Σ_k f(k)` over `k < n`, each of the `M` sums kept in [`LANES`] interleaved
/// partial sums. A floating-point sum taken in order cannot be vectorised (the
/// compiler may not reassociate it); interleaved partial sums can, and are as
/// accurate. Used by every reduction over a subset's pixels.
///
/// `f` sees [`LANES`] pixels at once ([`At`]: `at.of(slice)` is their values, a
/// [`V`]), so its products are vector products, not lane-by-lane work the compiler
/// would have to gather; a tail shorter than a vector is read zero-padded and only
/// its own lanes are added, in order, after the partial sums (the same sums, in the
/// same order, as one pixel at a time).
#[inline(always)]
pub(crate) fn sums<const M: usize>(n: usize, f: impl Fn(At) -> [V; M]) -> [f64; M] {
    let mut acc = [V::splat(0.0); M];
    let full = n / LANES * LANES;
    for k in (0..full).step_by(LANES) {
        let v = f(At { k, len: LANES });
        for m in 0..M {
            acc[m] = acc[m] + v[m];
        }
    }
    let mut out = [0.0; M];
    for m in 0..M {
        out[m] = acc[m].0.iter().sum();
    }
    if full < n {
        let v = f(At {
            k: full,
            len: n - full,
        });
        for l in 0..n - full {
            for m in 0..M {
                out[m] += v[m].0[l];
            }
        }
    }
    out
}

/// [`sums`] with its closure `#[inline(always)]`, as every call must have it (see
/// the module's doc): `lane_sums!(n, |a| [a.of(g), a.of(g) * a.of(g)])`.
macro_rules! lane_sums {
    ($n:expr, |$a:ident| $body:expr $(,)?) => {
        $crate::lanes::sums(
            $n,
            #[inline(always)]
            |$a| $body,
        )
    };
}
pub(crate) use lane_sums;

/// [`LANES`] consecutive pixels' values, the operand of [`sums`]' terms: plain
/// lane-by-lane arithmetic the compiler keeps in vector registers.
#[derive(Debug, Clone, Copy)]
pub(crate) struct V(pub(crate) [f64; LANES]);

impl V {
    /// Every lane `x`.
    #[inline(always)]
    pub(crate) fn splat(x: f64) -> V {
        V([x; LANES])
    }
}

macro_rules! lanewise {
    ($trait:ident, $method:ident, $op:tt) => {
        impl std::ops::$trait for V {
            type Output = V;
            #[inline(always)]
            fn $method(self, o: V) -> V {
                V(std::array::from_fn(|l| self.0[l] $op o.0[l]))
            }
        }
        impl std::ops::$trait<f64> for V {
            type Output = V;
            #[inline(always)]
            fn $method(self, o: f64) -> V {
                V(std::array::from_fn(|l| self.0[l] $op o))
            }
        }
    };
}
lanewise!(Add, add, +);
lanewise!(Sub, sub, -);
lanewise!(Mul, mul, *);

/// Which pixels a term of [`sums`] reads: `len` (at most [`LANES`]) from `k`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct At {
    k: usize,
    len: usize,
}

impl At {
    /// `s[k..k + len]` as a vector, zero-padded.
    #[inline(always)]
    pub(crate) fn of(self, s: &[f64]) -> V {
        if self.len == LANES {
            V(s[self.k..self.k + LANES].try_into().expect("LANES values"))
        } else {
            let mut v = [0.0; LANES];
            v[..self.len].copy_from_slice(&s[self.k..self.k + self.len]);
            V(v)
        }
    }
}
