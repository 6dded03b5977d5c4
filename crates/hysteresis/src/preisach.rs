//! The discrete Preisach model: a density of relays (hysterons) on the Preisach
//! triangle β ≤ α of the normalised input, piecewise constant on an n x n grid of cells
//! (weights μ ≥ 0), so that the output is exactly
//!
//! y(t) = y₀ + a₁·x(t) + a₂·x(t)² + Σ_cells μ_c · area(c ∩ S⁺(t))
//!
//! with a reversible part a₁x + a₂x² (a₁, a₂ ≥ 0: relays of a finite grid cannot be
//! reversible, and real stacks have a large reversible share)
//! where S⁺ is the set of relays that are up (Mayergoyz, *Mathematical Models of
//! Hysteresis*, 1991, ch. 1). S⁺ follows from the memory of alternating dominant extrema
//! M₁ > M₂ > … and m₁ < m₂ < … (wiping-out: a new extremum erases the smaller ones):
//! S⁺ = ∪ₖ {α ≤ Mₖ, β < mₖ}, mₖ the extremum after Mₖ (+∞ for the running maximum).
//! The output is continuous in the input (areas, not relay counts), so the inverse is
//! found by bisection to machine precision. The weights are identified from any rich
//! excitation by non-negative least squares (Lawson-Hanson) with a ridge and a
//! smoothness penalty on neighbouring cells ([`SMOOTHNESS`]).

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::{HysteresisError, Model, Range};

/// Largest number of remembered extrema; beyond it the innermost (smallest) loop is
/// merged away, an approximation below the grid's resolution.
pub const MEMORY: usize = 64;

/// Weight of the smoothness penalty of [`Preisach::identify`], relative to the data's
/// scale (the mean diagonal of the normal equations, like the ridge): the squared
/// difference of every two neighbouring cells' weights is added to the least squares
/// with this factor.
///
/// Without it the weights are ill-determined (a cell's weight trades off against its
/// neighbours' on every branch that crosses both) and come out spiky, many 0 next to
/// large ones; the fit to the data hardly tells, but a trajectory whose staircase
/// cuts the cells differently from the data's (nested loops about one level, as a
/// decaying oscillation makes) sums the spikes into a bias. On a Bouc-Wen actuator
/// (not of the Preisach class) recorded with 200 random reversals (`cellinject-core`'s
/// `hysteresis_recording` test), that bias made the feedforward's tracking RMS range
/// from 0.47 % to 1.36 % of the stroke over 50 recordings, and its ratio to a linear
/// inverse's from 0.12 to 0.42; smoothed (with [`crate::Prepared::weights`]), 0.43 %
/// to 0.72 % and 0.12 to 0.22, for a fit about 12 % worse on the data. The worst
/// ratio is 0.24, 0.22 and 0.22 for 3e-4, 1e-3 and 3e-3.
pub const SMOOTHNESS: f64 = 1e-3;

/// The memory of alternating dominant extrema on the normalised input [0, 1].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Memory {
    /// Alternating M₁, m₁, M₂, m₂, … (starting with a maximum).
    ext: [f64; MEMORY],
    len: usize,
    /// The current input, continuing the sequence: a maximum in progress when `len` is
    /// even, a minimum in progress when it is odd.
    x: f64,
}

impl Default for Memory {
    fn default() -> Self {
        // Negative saturation: every relay down, the input at the bottom of its range.
        Memory {
            ext: [0.0; MEMORY],
            len: 0,
            x: 0.0,
        }
    }
}

impl Memory {
    /// The current (normalised) input.
    pub fn input(&self) -> f64 {
        self.x
    }

    /// The remembered extrema, oldest first.
    pub fn extrema(&self) -> &[f64] {
        &self.ext[..self.len]
    }

    /// Moves the input to `u` (clamped to [0, 1]), updating the memory.
    pub fn apply(&mut self, u: f64) {
        let u = u.clamp(0.0, 1.0);
        let rising = self.len % 2 == 0;
        if rising {
            if u >= self.x {
                self.x = u;
            } else {
                self.push(self.x);
                self.x = u;
            }
        } else if u <= self.x {
            self.x = u;
        } else {
            self.push(self.x);
            self.x = u;
        }
        self.wipe();
    }

    fn push(&mut self, e: f64) {
        if self.len == MEMORY {
            // Merge the innermost loop: drop the last pair.
            self.len -= 2;
        }
        self.ext[self.len] = e;
        self.len += 1;
    }

    /// Wiping-out: the running extremum erases every stored pair it exceeds.
    fn wipe(&mut self) {
        loop {
            let rising = self.len % 2 == 0;
            let exceeds = if rising {
                // A rising input past the last stored maximum wipes (M, m) out.
                self.len >= 2 && self.x >= self.ext[self.len - 2]
            } else {
                // A falling input past the last stored minimum wipes (m, M) out.
                self.len >= 3 && self.x <= self.ext[self.len - 2]
            };
            if !exceeds {
                break;
            }
            self.len -= 2;
        }
        // The first maximum falls with the input only to its own level: a fall below 0
        // is clamped, so an odd memory whose running minimum is 0 erases everything.
        if self.len == 1 && self.x <= 0.0 {
            self.len = 0;
        }
    }

    /// A(β): the largest α whose relays at β are up, for the staircase S⁺; the pairs
    /// (Mₖ, mₖ) with mₖ increasing and Mₖ decreasing.
    fn pairs(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        let n = self.len;
        (0..n.div_ceil(2) + usize::from(n % 2 == 0)).filter_map(move |k| {
            let i = 2 * k;
            let m_max = if i < n {
                self.ext[i]
            } else if i == n {
                self.x
            } else {
                return None;
            };
            let m_min = if i + 1 < n {
                self.ext[i + 1]
            } else if i + 1 == n {
                self.x
            } else {
                f64::INFINITY
            };
            Some((m_max, m_min))
        })
    }
}

/// Area of the cell [a0, a1] x [b0, b1] (α x β) inside β ≤ α and inside the up-region
/// of `memory`.
fn up_area(memory: &Memory, a0: f64, a1: f64, b0: f64, b1: f64) -> f64 {
    // Over β, the up-region spans α ∈ [β, A(β)], A(β) = max{Mₖ : mₖ > β}. With mₖ
    // increasing and Mₖ decreasing, A is a decreasing step function.
    let mut area = 0.0;
    let mut lo = b0;
    for (m_max, m_min) in memory.pairs() {
        if lo >= b1 {
            break;
        }
        let hi = m_min.min(b1);
        if hi > lo {
            // On β ∈ [lo, hi], A = m_max: integrate max(0, min(a1, A) − max(a0, β)).
            let top = a1.min(m_max);
            area += integrate_strip(a0, top, lo, hi);
        }
        lo = lo.max(m_min);
    }
    area
}

/// ∫_{lo}^{hi} max(0, top − max(a0, β)) dβ.
fn integrate_strip(a0: f64, top: f64, lo: f64, hi: f64) -> f64 {
    let mut s = 0.0;
    // β ≤ a0: the height is top − a0.
    let p1 = hi.min(a0);
    if p1 > lo && top > a0 {
        s += (top - a0) * (p1 - lo);
    }
    // β > a0: the height is top − β, positive below top.
    let q0 = lo.max(a0);
    let q1 = hi.min(top);
    if q1 > q0 {
        s += (top - q0) * (q1 - q0) - 0.5 * (q1 - q0) * (q1 - q0);
    }
    s
}

/// A discrete Preisach model on `n` x `n` cells of the input range.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Preisach {
    /// The input range the grid spans.
    pub range: Range,
    /// Cells along each axis.
    pub n: usize,
    /// Output at negative saturation (every relay down), in output units.
    pub offset: f64,
    /// Reversible part: coefficients of x and x² (x the normalised input), ≥ 0.
    pub reversible: [f64; 2],
    /// Weights of the cells (i, j), j ≤ i, row by row: α cell i, β cell j.
    pub weights: Vec<f64>,
    #[serde(skip)]
    memory: Memory,
}

/// The cells (i, j), j ≤ i, in weight order, with their α and β ranges (normalised).
fn cells(n: usize) -> impl Iterator<Item = (f64, f64, f64, f64)> {
    let h = 1.0 / n as f64;
    (0..n).flat_map(move |i| {
        (0..=i).map(move |j| {
            (
                i as f64 * h,
                (i + 1) as f64 * h,
                j as f64 * h,
                (j + 1) as f64 * h,
            )
        })
    })
}

/// Number of weights of an n x n grid.
pub fn weight_count(n: usize) -> usize {
    n * (n + 1) / 2
}

impl Preisach {
    /// A model with the given weights, at negative saturation.
    pub fn new(
        range: Range,
        n: usize,
        offset: f64,
        reversible: [f64; 2],
        weights: Vec<f64>,
    ) -> Result<Self, HysteresisError> {
        if weights.len() != weight_count(n) {
            return Err(HysteresisError::Invalid {
                what: "weights",
                reason: format!(
                    "{} weights for a {n}x{n} grid (needs {})",
                    weights.len(),
                    weight_count(n)
                ),
            });
        }
        if weights
            .iter()
            .chain(&reversible)
            .any(|w| !w.is_finite() || *w < 0.0)
        {
            return Err(HysteresisError::Invalid {
                what: "weights",
                reason: "weights must be finite and non-negative".into(),
            });
        }
        Ok(Preisach {
            range,
            n,
            offset,
            reversible,
            weights,
            memory: Memory::default(),
        })
    }

    /// The regressors of the output at a memory state: area of each cell that is up.
    fn regressors(n: usize, memory: &Memory, out: &mut [f64]) {
        for (o, (a0, a1, b0, b1)) in out.iter_mut().zip(cells(n)) {
            *o = up_area(memory, a0, a1, b0, b1);
        }
    }

    fn output_at(&self, memory: &Memory) -> f64 {
        let x = memory.input();
        self.offset
            + self.reversible[0] * x
            + self.reversible[1] * x * x
            + cells(self.n)
                .zip(&self.weights)
                .map(|((a0, a1, b0, b1), w)| {
                    if *w == 0.0 {
                        0.0
                    } else {
                        w * up_area(memory, a0, a1, b0, b1)
                    }
                })
                .sum::<f64>()
    }

    /// The memory (for tests and inspection).
    pub fn memory(&self) -> &Memory {
        &self.memory
    }

    /// Identifies the weights from samples of (input, output) in time order, starting
    /// from the relaxed state at the bottom of `range`, on an `n` x `n` grid, with a ridge
    /// `lambda` (relative to the data's scale) that keeps weights the data cannot see
    /// small and a smoothness penalty ([`SMOOTHNESS`]) that keeps neighbouring cells
    /// alike. The data go through [`crate::prepare`] first: held inputs (dwells) merge
    /// into one sample, wiggles within the input's noise are holds, each sample weighs
    /// by the input path it stands for ([`crate::Prepared::weights`]), and data without
    /// two reversals larger than the noise are refused.
    pub fn identify(
        range: Range,
        n: usize,
        inputs: &[f64],
        outputs: &[f64],
        lambda: f64,
    ) -> Result<crate::Fit<Preisach>, HysteresisError> {
        let data = crate::prepare(inputs, outputs, &range)?;
        if !(2..=60).contains(&n) {
            return Err(HysteresisError::Invalid {
                what: "cells",
                reason: format!("{n}: use 2 to 60"),
            });
        }
        let k = weight_count(n) + 3; // offset, x, x², weights
        let mut g = DMatrix::<f64>::zeros(k, k);
        let mut h = DVector::<f64>::zeros(k);
        let mut memory = Memory::default();
        let mut row = vec![0.0; k];
        // The regressors that are not 0 (cells down are), and the lower triangle of the
        // symmetric normal equations only, mirrored after.
        let mut up = Vec::with_capacity(k);
        for ((&u, &y), &w) in data.inputs.iter().zip(&data.outputs).zip(&data.weights) {
            memory.apply(range.normalise(u));
            let x = memory.input();
            Self::regressors(n, &memory, &mut row[3..]);
            row[0] = 1.0;
            row[1] = x;
            row[2] = x * x;
            up.clear();
            up.extend((0..k).filter(|&a| row[a] != 0.0));
            for (i, &a) in up.iter().enumerate() {
                let wa = w * row[a];
                h[a] += wa * y;
                for &b in &up[i..] {
                    g[(b, a)] += wa * row[b];
                }
            }
        }
        for a in 0..k {
            for b in a + 1..k {
                g[(a, b)] = g[(b, a)];
            }
        }
        // The ridge scales with the weights' own regressors (not the offset's column,
        // which is orders of magnitude larger).
        let scale = ((1..k).map(|a| g[(a, a)]).sum::<f64>() / (k - 1) as f64).max(1e-300);
        for a in 1..k {
            g[(a, a)] += lambda * scale;
        }
        // Smoothness: SMOOTHNESS·scale·(wₚ − w_q)² for every two cells p, q sharing a
        // side (α or β neighbours inside the triangle).
        let s = SMOOTHNESS * scale;
        let index = |i: usize, j: usize| 3 + i * (i + 1) / 2 + j;
        for i in 0..n {
            for j in 0..=i {
                let p = index(i, j);
                let next = [
                    (i + 1 < n).then(|| index(i + 1, j)),
                    (j < i).then(|| index(i, j + 1)),
                ];
                for q in next.into_iter().flatten() {
                    g[(p, p)] += s;
                    g[(q, q)] += s;
                    g[(p, q)] -= s;
                    g[(q, p)] -= s;
                }
            }
        }
        let x = crate::solve_pinned(&g, &h, crate::rest_of(&data, &range))?;
        let model = Preisach::new(range, n, x[0], [x[1], x[2]], x.as_slice()[3..].to_vec())?;
        crate::Fit::measure(model, &data)
    }
}

impl Model for Preisach {
    fn reset(&mut self) {
        self.memory = Memory::default();
    }

    fn range(&self) -> Range {
        self.range
    }

    fn apply(&mut self, u: f64) -> f64 {
        self.memory.apply(self.range.normalise(u));
        self.output()
    }

    fn peek(&self, u: f64) -> f64 {
        let mut m = self.memory;
        m.apply(self.range.normalise(u));
        self.output_at(&m)
    }

    fn output(&self) -> f64 {
        self.output_at(&self.memory)
    }

    fn input(&self) -> f64 {
        self.range.denormalise(self.memory.input())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(m: &Memory) -> f64 {
        up_area(m, 0.0, 1.0, 0.0, 1.0)
    }

    #[test]
    fn the_up_region_follows_the_staircase_and_wipes_out() {
        let mut m = Memory::default();
        m.apply(0.8);
        // Up: the triangle under α ≤ 0.8: area 0.32.
        assert!((area(&m) - 0.32).abs() < 1e-12);
        m.apply(0.3);
        // Up: α ≤ 0.8, β < 0.3: 0.32 − (triangle 0.3..0.8: 0.125) = 0.195.
        assert!((area(&m) - 0.195).abs() < 1e-12, "{}", area(&m));
        m.apply(0.6);
        // Plus α ≤ 0.6, 0.3 ≤ β: triangle of side 0.3: 0.045.
        assert!((area(&m) - 0.24).abs() < 1e-12, "{}", area(&m));
        assert_eq!(m.extrema(), &[0.8, 0.3]);
        // Rising past 0.8 wipes the (0.8, 0.3) pair out: the state of a plain rise.
        m.apply(0.9);
        assert!(m.extrema().is_empty());
        assert!((area(&m) - 0.405).abs() < 1e-12);
        // Back to 0: negative saturation again.
        m.apply(0.0);
        assert!(area(&m).abs() < 1e-15 && m.extrema().is_empty());
    }

    #[test]
    fn the_cell_areas_add_up_to_the_whole_up_region() {
        let mut m = Memory::default();
        for u in [0.7, 0.2, 0.55, 0.35, 0.5, 0.42] {
            m.apply(u);
            let n = 7;
            let total: f64 = cells(n)
                .map(|(a0, a1, b0, b1)| up_area(&m, a0, a1, b0, b1))
                .sum();
            assert!(
                (total - area(&m)).abs() < 1e-12,
                "{u}: {total} vs {}",
                area(&m)
            );
        }
    }

    #[test]
    fn minor_loops_close() {
        // Congruency and return-point memory: after a minor loop the output returns.
        let range = Range {
            min: 0.0,
            max: 100.0,
        };
        let w: Vec<f64> = (0..weight_count(8)).map(|k| 1.0 + (k % 5) as f64).collect();
        let mut p = Preisach::new(range, 8, 0.0, [1.0, 0.5], w).unwrap();
        p.apply(70.0);
        let y = p.apply(40.0);
        p.apply(60.0);
        p.apply(45.0);
        let back = p.apply(40.0);
        assert!((y - back).abs() < 1e-12, "{y} {back}");
    }
}
