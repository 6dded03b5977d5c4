//! The rows of [`BSpline::warped_block`](crate::bspline::BSpline::warped_block) on the
//! vector units, in double precision or, where the iteration's tolerance allows
//! ([`SINGLE_PRECISION_TOLERANCE`]), in single precision with twice the lanes.

use crate::bspline::{Degree, TAPS};

/// The smallest IC-GN tolerance (px of corner motion) at which the warp runs in single
/// precision. Its values are within `5e-6·max|c|` of double precision's (see
/// `warped_block_agrees_with_value`); on the faintest texture the tests know, an
/// iteration stopped at this tolerance ends as close to the fixed point in either
/// precision, the two stops 5e-6 to 8e-6 px apart
/// (`a_weak_texture_converges_to_one_solution_from_either_side`). Fields and points
/// stop at `icgn::MEASUREMENT_TOLERANCE` (5e-4 px), where it saves some 7 % of a field
/// point's time on AVX-512; the default [`IcgnOptions`](crate::icgn::IcgnOptions)
/// (1e-5 px) stays in double precision.
pub const SINGLE_PRECISION_TOLERANCE: f64 = 1e-4;

/// Most lanes of a vector unit [`Rows`] may meet (pulp's widest has 16 of f32).
const MAX_LANES: usize = 64;

/// The floating-point type [`Rows`] runs in, with its vector operations.
pub(crate) trait Lane: Copy + Into<f64> + 'static {
    /// A vector of `Self`.
    type V<S: pulp::Simd>: Copy;
    /// Lanes of a vector.
    fn lanes<S: pulp::Simd>() -> usize;
    /// `v` in this precision.
    fn of(v: f64) -> Self;
    /// Every lane `v`.
    fn splat<S: pulp::Simd>(s: S, v: f64) -> Self::V<S>;
    /// `a·b`.
    fn mul<S: pulp::Simd>(s: S, a: Self::V<S>, b: Self::V<S>) -> Self::V<S>;
    /// `a + b`.
    fn add<S: pulp::Simd>(s: S, a: Self::V<S>, b: Self::V<S>) -> Self::V<S>;
    /// `a − b`.
    fn sub<S: pulp::Simd>(s: S, a: Self::V<S>, b: Self::V<S>) -> Self::V<S>;
    /// `a·b + c`, fused.
    fn mul_add<S: pulp::Simd>(s: S, a: Self::V<S>, b: Self::V<S>, c: Self::V<S>) -> Self::V<S>;
    /// The first [`Lane::lanes`] values of `t`.
    fn load<S: pulp::Simd>(t: &[Self]) -> Self::V<S>;
    /// `v` into the first [`Lane::lanes`] values of `out`.
    fn store<S: pulp::Simd>(v: Self::V<S>, out: &mut [Self]);
    /// 0, 1, 2, ... in this precision, the pixel counter of a run.
    fn iota() -> &'static [Self; IOTA_LEN];
}

/// Length of the pixel counters [`Lane::iota`].
const IOTA_LEN: usize = 1024;

macro_rules! lane {
    ($t:ty, $v:ident, $lanes:ident, $splat:ident, $mul:ident, $add:ident, $sub:ident,
     $fma:ident, $as:ident, $as_mut:ident, $iota:ident) => {
        static $iota: [$t; IOTA_LEN] = {
            let mut a = [0.0; IOTA_LEN];
            let mut i = 0;
            while i < IOTA_LEN {
                a[i] = i as $t;
                i += 1;
            }
            a
        };
        impl Lane for $t {
            type V<S: pulp::Simd> = S::$v;
            #[inline(always)]
            fn lanes<S: pulp::Simd>() -> usize {
                S::$lanes
            }
            #[inline(always)]
            fn of(v: f64) -> Self {
                v as $t
            }
            #[inline(always)]
            fn splat<S: pulp::Simd>(s: S, v: f64) -> S::$v {
                s.$splat(v as $t)
            }
            #[inline(always)]
            fn mul<S: pulp::Simd>(s: S, a: S::$v, b: S::$v) -> S::$v {
                s.$mul(a, b)
            }
            #[inline(always)]
            fn add<S: pulp::Simd>(s: S, a: S::$v, b: S::$v) -> S::$v {
                s.$add(a, b)
            }
            #[inline(always)]
            fn sub<S: pulp::Simd>(s: S, a: S::$v, b: S::$v) -> S::$v {
                s.$sub(a, b)
            }
            #[inline(always)]
            fn mul_add<S: pulp::Simd>(s: S, a: S::$v, b: S::$v, c: S::$v) -> S::$v {
                s.$fma(a, b, c)
            }
            #[inline(always)]
            fn load<S: pulp::Simd>(t: &[Self]) -> S::$v {
                S::$as(&t[..S::$lanes]).0[0]
            }
            #[inline(always)]
            fn store<S: pulp::Simd>(v: S::$v, out: &mut [Self]) {
                S::$as_mut(&mut out[..S::$lanes]).0[0] = v;
            }
            #[inline(always)]
            fn iota() -> &'static [Self; IOTA_LEN] {
                &$iota
            }
        }
    };
}
lane!(
    f64,
    f64s,
    F64_LANES,
    splat_f64s,
    mul_f64s,
    add_f64s,
    sub_f64s,
    mul_add_e_f64s,
    as_simd_f64s,
    as_mut_simd_f64s,
    IOTA_F64
);
lane!(
    f32,
    f32s,
    F32_LANES,
    splat_f32s,
    mul_f32s,
    add_f32s,
    sub_f32s,
    mul_add_e_f32s,
    as_simd_f32s,
    as_mut_simd_f32s,
    IOTA_F32
);

/// The rows of a warped block, the part that runs on the vector units (see
/// [`Rows::rows`]), with the spline's coefficients in the precision `T`.
pub(crate) struct Rows<'a, T: Lane> {
    /// The coefficients.
    pub(crate) c: &'a [T],
    pub(crate) width: usize,
    pub(crate) degree: Degree,
    /// Position of the first pixel of the row dy = 0, in the coefficients' frame.
    pub(crate) origin: (f64, f64),
    /// Change of the position per pixel along a row (x, y).
    pub(crate) step_x: (f64, f64),
    /// Change per row.
    pub(crate) step_y: (f64, f64),
    pub(crate) first_row: f64,
    pub(crate) nw: usize,
    pub(crate) out: &'a mut [f64],
}

impl<T: Lane> pulp::WithSimd for Rows<'_, T> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) -> Self::Output {
        match self.degree {
            Degree::Quintic => self.rows::<S, true>(simd),
            Degree::Cubic => self.rows::<S, false>(simd),
        }
    }
}

impl<T: Lane> Rows<'_, T> {
    /// Each row cut into runs where the floor of the position moves by one pixel per
    /// pixel (x) and not at all (y): over a run the taps of consecutive pixels are
    /// consecutive coefficients, read as contiguous vectors, and only the weights
    /// differ from lane to lane. A small deformation leaves a run or two per row.
    ///
    /// The lanes are pixels: a vector of consecutive pixels gets its weights in one
    /// pass of the polynomial and its 36 taps as 36 fused multiply-adds of
    /// unaligned loads (the taps along a row summed first, then the rows); a tail of
    /// the run shorter than a vector is computed whole and only its own lanes stored.
    /// In single precision the run's start is exact (double precision) and the
    /// position along it off by a few `f32::EPSILON` of a pixel.
    /// `warped_block_agrees_with_value` checks every pixel against
    /// [`BSpline::value`](crate::bspline::BSpline::value), in both precisions.
    #[inline(always)]
    fn rows<S: pulp::Simd, const QUINTIC: bool>(self, simd: S) {
        let lanes = T::lanes::<S>();
        assert!(lanes <= MAX_LANES, "{lanes} lanes");
        let w = self.width;
        let nw = self.nw;
        let mut buf = [T::of(0.0); MAX_LANES];
        for (j, row) in self.out.chunks_exact_mut(nw).enumerate() {
            let dy = self.first_row + j as f64;
            // Position of pixel i: (x0 + i + sx·i, y0 + sy·i).
            let x0 = self.origin.0 + self.step_y.0 * dy;
            let y0 = self.origin.1 + self.step_y.1 * dy;
            let (sx, sy) = (self.step_x.0 - 1.0, self.step_x.1);
            let (vsx, vsy) = (T::splat(simd, sx), T::splat(simd, sy));
            let mut i0 = 0;
            while i0 < nw {
                // Inside (x, y ≥ 2): truncation is the floor.
                let ox = (x0 + sx * i0 as f64) as usize;
                let oy = (y0 + sy * i0 as f64) as usize;
                // Fractional offsets at the run's first pixel; the run lasts while
                // both stay in [0, 1).
                let (tx0, ty0) = (
                    x0 + sx * i0 as f64 - ox as f64,
                    y0 + sy * i0 as f64 - oy as f64,
                );
                let len = run_length(tx0, sx)
                    .min(run_length(ty0, sy))
                    .min(nw - i0)
                    .min(IOTA_LEN - MAX_LANES);
                let i1 = i0 + len;
                let base = (oy - 2) * w + ox + i0 - 2;
                // Whole vectors, read up to a vector past the run's last tap: the
                // extra lanes are computed and not stored. (A masked load is a call
                // through a table of masks, and a 33-pixel row's 33rd pixel cost as
                // much as the other 32: the field ran some 15 % slower so.) The reads
                // stay in the coefficients: with the corners inside (x < w − 4,
                // y < h − 4) the last tap is at column w − 2 at most of a row h − 2 at
                // most, and a vector read from it runs at most `lanes − 2` values
                // into the next row, which holds w of them: w ≥ 7 for any block inside
                // (6 for double precision's 8 lanes), and the caller runs single
                // precision (16 lanes: 14) only on images 16 pixels wide or more.
                let reach = len + TAPS - 1 + lanes;
                let taps: [&[T]; TAPS] = std::array::from_fn(|k| {
                    let from = base + k * w;
                    &self.c[from..from + reach]
                });
                let (vtx0, vty0) = (T::splat(simd, tx0), T::splat(simd, ty0));
                let out = &mut row[i0..i1];
                let mut i = 0;
                while i < len {
                    let m = lanes.min(len - i);
                    let n = T::load::<S>(&T::iota()[i..]);
                    let (tx, ty) = (
                        T::mul_add(simd, vsx, n, vtx0),
                        T::mul_add(simd, vsy, n, vty0),
                    );
                    // A generic function, not a closure: a call through `Fn` is not
                    // inlined, and outside the vector context each lane operation
                    // becomes a call (four times slower in all).
                    let (wx, wy) = if QUINTIC {
                        (
                            quintic_weights::<S, T>(simd, tx),
                            quintic_weights::<S, T>(simd, ty),
                        )
                    } else {
                        (
                            cubic_weights::<S, T>(simd, tx),
                            cubic_weights::<S, T>(simd, ty),
                        )
                    };
                    let mut acc = T::splat(simd, 0.0);
                    for (wyk, t) in wy.iter().zip(&taps) {
                        let mut d = T::mul(simd, wx[0], T::load::<S>(&t[i..]));
                        for (q, wxq) in wx.iter().enumerate().skip(1) {
                            d = T::mul_add(simd, *wxq, T::load::<S>(&t[i + q..]), d);
                        }
                        acc = T::mul_add(simd, *wyk, d, acc);
                    }
                    T::store::<S>(acc, &mut buf);
                    for (o, b) in out[i..i + m].iter_mut().zip(&buf[..m]) {
                        *o = (*b).into();
                    }
                    i += m;
                }
                i0 = i1;
            }
        }
    }
}

/// [`Degree::weights`] of the quintic for every lane of `t`, the same operations in
/// the same order (in double precision, the same values).
#[inline(always)]
fn quintic_weights<S: pulp::Simd, T: Lane>(s: S, t: T::V<S>) -> [T::V<S>; TAPS] {
    let c = |v: f64| T::splat(s, v);
    let (mul, add, sub) = (T::mul::<S>, T::add::<S>, T::sub::<S>);
    let mut w = t;
    let mut w2 = mul(s, w, w);
    let w5 = mul(s, mul(s, mul(s, c(1.0 / 120.0), w), w2), w2);
    w2 = sub(s, w2, w);
    let w4 = mul(s, w2, w2);
    w = sub(s, w, c(0.5));
    let tt = mul(s, w2, sub(s, w2, c(3.0)));
    let w0 = sub(
        s,
        mul(s, c(1.0 / 24.0), add(s, add(s, c(1.0 / 5.0), w2), w4)),
        w5,
    );
    let t0 = mul(
        s,
        c(1.0 / 24.0),
        add(s, mul(s, w2, sub(s, w2, c(5.0))), c(46.0 / 5.0)),
    );
    let t1 = mul(s, mul(s, c(-1.0 / 12.0), w), add(s, tt, c(4.0)));
    let (w2_, w3_) = (add(s, t0, t1), sub(s, t0, t1));
    let t0 = mul(s, c(1.0 / 16.0), sub(s, c(9.0 / 5.0), tt));
    let t1 = mul(s, mul(s, c(1.0 / 24.0), w), sub(s, sub(s, w4, w2), c(5.0)));
    [w0, add(s, t0, t1), w2_, w3_, sub(s, t0, t1), w5]
}

/// [`Degree::weights`] of the cubic for every lane of `t`, as the scalar.
#[inline(always)]
fn cubic_weights<S: pulp::Simd, T: Lane>(s: S, t: T::V<S>) -> [T::V<S>; TAPS] {
    let c = |v: f64| T::splat(s, v);
    let (mul, add, sub) = (T::mul::<S>, T::add::<S>, T::sub::<S>);
    let sixth = 1.0 / 6.0;
    let t2 = mul(s, t, t);
    let t3 = mul(s, t2, t);
    let u = sub(s, c(1.0), t);
    let w0 = mul(s, mul(s, mul(s, u, u), u), c(sixth));
    let w3 = mul(s, t3, c(sixth));
    let w1 = add(s, sub(s, mul(s, c(0.5), t3), t2), c(4.0 * sixth));
    let w2 = sub(s, sub(s, sub(s, c(1.0), w0), w1), w3);
    [c(0.0), w0, w1, w2, w3, c(0.0)]
}

/// How many pixels k = 0, 1, ... keep `t0 + s·k` in [0, 1) (at least one: `t0` is).
#[inline(always)]
fn run_length(t0: f64, s: f64) -> usize {
    let n = if s > 0.0 {
        ((1.0 - t0) / s).ceil()
    } else if s < 0.0 {
        (t0 / -s).floor() + 1.0
    } else {
        f64::INFINITY
    };
    // Saturating: a very long run is cut by the row's end.
    (n as usize).max(1)
}
