//! Identification data as real recordings give it: the input held at the turning points
//! (the amplifier dwells while the logger keeps sampling), a quantised input (a DAC's
//! steps, slower than the logger), noise on a measured input. [`prepare`] turns such a
//! recording into what a rate-independent model can be fitted to:
//!
//! 1. the input's noise or quantisation level is measured from the data
//!    ([`input_noise`]): the larger of its smallest non-zero step and a robust standard
//!    deviation of its noise (the median absolute third difference, which a smooth
//!    signal barely feeds, over 0.6745·√20);
//! 2. a reversal is a change of direction larger than [`REVERSAL_FACTOR`] times that
//!    level ([`turning_points`]): wiggles within it are noise, not reversals;
//! 3. between two turning points the input is taken as monotone (a rising branch is
//!    its running maximum, a falling one its running minimum), so a sub-threshold
//!    wiggle is a hold: the Preisach memory and the plays do not change;
//! 4. consecutive samples with the same input are one state of a rate-independent
//!    model (a dwell: only creep and noise change the output), merged into one sample
//!    whose output is their mean, so that a hold weighs in the least squares like any
//!    other state and not by how long it lasted;
//! 5. each sample is weighted by the input path it stands for (half the way from the
//!    sample before, half the way to the sample after, [`Prepared::weights`]), so that
//!    a branch weighs in the least squares by the span of input it covers, not by how
//!    many samples the logger took of it: a ramp slower than the DAC gives one sample
//!    per DAC level, 6 to 20 times as many per volt as a fast one (unweighted, the
//!    slow twentieth of a recording's branches gave a quarter of its samples).
//!
//! The data that cannot identify a loop are refused with the numbers: too few samples,
//! an input that never moves beyond its noise, fewer than two reversals.

use serde::Serialize;

use crate::{HysteresisError, Range};

/// Fewest distinct samples an identification accepts.
pub const MIN_SAMPLES: usize = 100;

/// A reversal is a change of direction larger than this many times the input's noise
/// level: a held input's noise (Gaussian or flickering between DAC levels) ranges over
/// fewer than 8 standard deviations even over 10⁴ samples.
pub const REVERSAL_FACTOR: f64 = 10.0;

/// What [`prepare`] did to a recording.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `rows` | | samples given |
/// | `samples` | | samples fitted, after merging |
/// | `merged` | | samples merged into the one before them (same input: dwells, DAC steps slower than the logger) |
/// | `flattened` | | samples whose input was moved to the branch's running extremum (wiggles within the noise, taken as holds) |
/// | `reversals` | | changes of direction larger than `reversal_threshold` |
/// | `input_noise` | input units | the input's noise or quantisation level, measured from the data |
/// | `reversal_threshold` | input units | the smallest change of direction counted as a reversal |
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Default)]
pub struct DataSummary {
    /// Samples given.
    pub rows: usize,
    /// Samples fitted.
    pub samples: usize,
    /// Samples merged into the one before them.
    pub merged: usize,
    /// Samples whose input was flattened.
    pub flattened: usize,
    /// Reversals.
    pub reversals: usize,
    /// Input units.
    pub input_noise: f64,
    /// Input units.
    pub reversal_threshold: f64,
}

/// A recording ready for identification.
#[derive(Debug, Clone, PartialEq)]
pub struct Prepared {
    /// Inputs, monotone between turning points, no two consecutive equal.
    pub inputs: Vec<f64>,
    /// Outputs (the mean over each merged run).
    pub outputs: Vec<f64>,
    /// Each sample's weight in a least-squares fit: the input path it stands for (half
    /// the step from the sample before plus half the step to the sample after) over the
    /// mean of that path, so the weights' mean is 1.
    pub weights: Vec<f64>,
    /// What was done.
    pub summary: DataSummary,
}

/// The median of `v` (reordered); 0 for an empty slice.
fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}

/// The input's noise or quantisation level, measured from the data: the larger of its
/// resolution (the smallest non-zero gap between two of its values: a DAC's step;
/// gaps below 10⁻⁹ of the values' scale are rounding) and the robust standard
/// deviation of its noise from the median absolute third difference (σ·√20 for white
/// noise; a smoothly varying signal's third differences are far smaller). 0 for a
/// constant input.
pub fn input_noise(inputs: &[f64]) -> f64 {
    let scale = inputs.iter().fold(0.0f64, |a, u| a.max(u.abs()));
    let tiny = 1e-9 * scale;
    let mut sorted = inputs.to_vec();
    sorted.sort_unstable_by(f64::total_cmp);
    let step = sorted
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > tiny)
        .fold(f64::INFINITY, f64::min);
    let step = if step.is_finite() { step } else { 0.0 };
    let mut d3: Vec<f64> = inputs
        .windows(4)
        .map(|w| (w[3] - 3.0 * w[2] + 3.0 * w[1] - w[0]).abs())
        .collect();
    let sigma = median(&mut d3) / (0.674_489_750_196 * 20f64.sqrt());
    step.max(sigma)
}

/// The turning points of `inputs`: the indices of the extrema where the input changed
/// direction by more than `threshold` (a reversal), and whether the input first moved
/// up (`None` if it never moved by more than `threshold`). An extremum held over
/// several samples is at its first.
pub fn turning_points(inputs: &[f64], threshold: f64) -> (Vec<usize>, Option<bool>) {
    let mut turns = Vec::new();
    let mut first = None;
    let mut rising = None;
    let (mut lo, mut hi, mut ext) = (0usize, 0usize, 0usize);
    for (i, &u) in inputs.iter().enumerate() {
        match rising {
            None => {
                if u > inputs[hi] {
                    hi = i;
                }
                if u < inputs[lo] {
                    lo = i;
                }
                if inputs[hi] - inputs[lo] > threshold {
                    // Heading for whichever extreme came last.
                    let up = hi > lo;
                    rising = Some(up);
                    first = Some(up);
                    ext = if up { hi } else { lo };
                }
            }
            Some(true) => {
                if u > inputs[ext] {
                    ext = i;
                } else if inputs[ext] - u > threshold {
                    turns.push(ext);
                    rising = Some(false);
                    // The lowest sample since the maximum.
                    ext = lowest(inputs, ext, i);
                }
            }
            Some(false) => {
                if u < inputs[ext] {
                    ext = i;
                } else if u - inputs[ext] > threshold {
                    turns.push(ext);
                    rising = Some(true);
                    ext = highest(inputs, ext, i);
                }
            }
        }
    }
    (turns, first)
}

/// The index of the first lowest sample in `inputs[from..=to]`.
fn lowest(inputs: &[f64], from: usize, to: usize) -> usize {
    (from..=to).fold(from, |b, k| if inputs[k] < inputs[b] { k } else { b })
}

/// The index of the first highest sample in `inputs[from..=to]`.
fn highest(inputs: &[f64], from: usize, to: usize) -> usize {
    (from..=to).fold(from, |b, k| if inputs[k] > inputs[b] { k } else { b })
}

/// The weight of each of `inputs` (a prepared sequence: no two consecutive equal): the
/// input path it stands for, half the step from the one before plus half the step to
/// the one after, over the mean of that path (1 each if the input never moves).
pub fn path_weights(inputs: &[f64]) -> Vec<f64> {
    let n = inputs.len();
    let step = |i: usize| (inputs[i + 1] - inputs[i]).abs();
    let mut w: Vec<f64> = (0..n)
        .map(|i| {
            let before = if i > 0 { step(i - 1) } else { 0.0 };
            let after = if i + 1 < n { step(i) } else { 0.0 };
            0.5 * (before + after)
        })
        .collect();
    let mean = w.iter().sum::<f64>() / n.max(1) as f64;
    if mean > 0.0 && mean.is_finite() {
        for x in &mut w {
            *x /= mean;
        }
    } else {
        w.fill(1.0);
    }
    w
}

/// Checks a recording (input, output) in time order and prepares it for
/// identification on `range` (see the module's documentation); refuses data that
/// cannot identify a hysteresis loop.
pub fn prepare(
    inputs: &[f64],
    outputs: &[f64],
    range: &Range,
) -> Result<Prepared, HysteresisError> {
    if inputs.len() != outputs.len() {
        return Err(HysteresisError::LengthMismatch {
            inputs: inputs.len(),
            outputs: outputs.len(),
        });
    }
    let rows = inputs.len();
    if rows < MIN_SAMPLES {
        return Err(HysteresisError::TooFewSamples {
            rows,
            samples: rows,
            min: MIN_SAMPLES,
        });
    }
    if !(range.max > range.min && range.min.is_finite() && range.max.is_finite()) {
        return Err(HysteresisError::Invalid {
            what: "identification data",
            reason: format!("input range [{}, {}]", range.min, range.max),
        });
    }
    for (which, v) in [("input", inputs), ("output", outputs)] {
        if let Some(index) = v.iter().position(|v| !v.is_finite()) {
            return Err(HysteresisError::NotFinite { index, which });
        }
    }
    let noise = input_noise(inputs);
    let threshold = REVERSAL_FACTOR * noise;
    let (turns, first) = turning_points(inputs, threshold);
    let lo = inputs.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = inputs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let Some(mut rising) = first else {
        return Err(HysteresisError::ConstantInput {
            min: lo,
            max: hi,
            noise,
            samples: rows,
        });
    };
    if turns.len() < 2 {
        return Err(HysteresisError::TooFewReversals {
            reversals: turns.len(),
            threshold,
            noise,
            min: lo,
            max: hi,
        });
    }
    // Monotone branches, then one sample per held input.
    let mut ins = Vec::with_capacity(rows);
    let mut outs = Vec::with_capacity(rows);
    let (mut flattened, mut run) = (0usize, 0usize);
    let mut next = turns.iter().copied().peekable();
    let mut level = inputs[0];
    for (i, (&u, &y)) in inputs.iter().zip(outputs).enumerate() {
        if next.peek() == Some(&i) {
            next.next();
            level = u;
            rising = !rising;
        } else if rising {
            level = level.max(u);
        } else {
            level = level.min(u);
        }
        if level != u {
            flattened += 1;
        }
        if ins.last() == Some(&level) {
            // The same state: accumulate the output's mean.
            run += 1;
            let last = outs.len() - 1;
            outs[last] += (y - outs[last]) / run as f64;
        } else {
            run = 1;
            ins.push(level);
            outs.push(y);
        }
    }
    let samples = ins.len();
    if samples < MIN_SAMPLES {
        return Err(HysteresisError::TooFewSamples {
            rows,
            samples,
            min: MIN_SAMPLES,
        });
    }
    let weights = path_weights(&ins);
    Ok(Prepared {
        inputs: ins,
        outputs: outs,
        weights,
        summary: DataSummary {
            rows,
            samples,
            merged: rows - samples,
            flattened,
            reversals: turns.len(),
            input_noise: noise,
            reversal_threshold: threshold,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use cellinject_numeric::Rng;

    const RANGE: Range = Range {
        min: 0.0,
        max: 100.0,
    };

    fn quantise(v: f64, q: f64) -> f64 {
        if q > 0.0 { (v / q).round() * q } else { v }
    }

    /// `branches` alternating ramps (rising first, from 5 V) of `per_branch` samples
    /// and shrinking amplitude, each followed by `dwell` repeats of the turning point,
    /// quantised to `q` (0: not).
    fn loops(branches: usize, per_branch: usize, dwell: usize, q: f64) -> Vec<f64> {
        let mut v = vec![quantise(5.0, q)];
        let mut at = 5.0;
        for b in 0..branches {
            let amp = 90.0 * (1.0 - 0.5 * b as f64 / branches as f64);
            let to = if b % 2 == 0 {
                5.0 + amp
            } else {
                5.0 + 90.0 - amp
            };
            for k in 1..=per_branch {
                v.push(quantise(at + (to - at) * k as f64 / per_branch as f64, q));
            }
            at = to;
            v.extend(std::iter::repeat_n(quantise(to, q), dwell));
        }
        v
    }

    #[test]
    fn noise_and_flicker_of_a_held_input_are_not_reversals() {
        let q = 100.0 / 4096.0;
        let mut rng = Rng::new(5, 1);
        // Gaussian noise of 20 mV on a held 40 V, 10⁴ samples.
        let held: Vec<f64> = (0..10_000)
            .map(|_| 40.0 + 0.02 * rng.gaussian_exact())
            .collect();
        let noise = input_noise(&held);
        assert!((noise / 0.02 - 1.0).abs() < 0.1, "noise {noise}");
        let (turns, first) = turning_points(&held, REVERSAL_FACTOR * noise);
        assert!(turns.is_empty() && first.is_none(), "{turns:?} {first:?}");
        let e = prepare(&held, &held, &RANGE).unwrap_err();
        assert!(matches!(e, HysteresisError::ConstantInput { .. }), "{e}");
        // A DAC level flickering by one step on a ramp's dwell: quantised, not reversals.
        let mut v = loops(1, 400, 0, q);
        let top = *v.last().unwrap();
        for k in 0..2000 {
            let flicker = if k % 7 == 0 { q } else { 0.0 };
            v.push(top - if rng.uniform() < 0.5 { q } else { 0.0 } + flicker);
        }
        let noise = input_noise(&v);
        assert!((noise - q).abs() < 1e-12, "{noise} vs {q}");
        let (turns, _) = turning_points(&v, REVERSAL_FACTOR * noise);
        assert!(turns.is_empty(), "{turns:?}");
        // A monotone ramp with dwells (0.01 V per sample, under a DAC step, held for 40
        // samples every 30) is refused, with its numbers; so is one rise and fall.
        let mut ramp = Vec::new();
        for k in 0..4000 {
            ramp.push(quantise(0.01 * k as f64, q));
            if k % 30 == 0 {
                let held = *ramp.last().unwrap();
                ramp.extend([held; 40]);
            }
        }
        let e = prepare(&ramp, &ramp, &RANGE).unwrap_err();
        match e {
            HysteresisError::TooFewReversals {
                reversals, noise, ..
            } => {
                assert_eq!(reversals, 0);
                assert!((noise - q).abs() < 1e-12, "{noise}");
            }
            ref e => panic!("{e}"),
        }
        assert!(e.to_string().starts_with("0 reversals"), "{e}");
        let once = loops(2, 300, 40, q);
        let e = prepare(&once, &once, &RANGE).unwrap_err();
        assert!(
            matches!(e, HysteresisError::TooFewReversals { reversals: 1, .. }),
            "{e}"
        );
    }

    #[test]
    fn dwells_merge_and_reversals_count_through_them() {
        let q = 100.0 / 4096.0;
        let mut rng = Rng::new(9, 2);
        // Six branches of 300 samples, 25 repeats at each extreme, 1 mV noise on the
        // logged voltage of a DAC's quantised levels.
        let clean = loops(6, 300, 25, q);
        let noisy: Vec<f64> = clean
            .iter()
            .map(|v| v + 1e-3 * rng.gaussian_exact())
            .collect();
        for (v, noisy) in [(&clean, false), (&noisy, true)] {
            // The old rule (a sign change of consecutive steps) saw no reversal in the
            // clean recording, and hundreds in the noisy one.
            let naive = v
                .windows(3)
                .filter(|w| (w[1] - w[0]) * (w[2] - w[1]) < 0.0)
                .count();
            let y: Vec<f64> = v.iter().map(|u| 1e-7 * u).collect();
            let p = prepare(v, &y, &RANGE).unwrap();
            assert_eq!(p.summary.reversals, 5, "noisy {noisy}: naive count {naive}");
            assert_eq!(p.summary.rows, v.len());
            assert_eq!(p.summary.samples + p.summary.merged, v.len());
            // Monotone between the turning points, no two consecutive inputs equal.
            assert!(p.inputs.windows(2).all(|w| w[0] != w[1]));
            let changes = p
                .inputs
                .windows(3)
                .filter(|w| (w[1] - w[0]) * (w[2] - w[1]) < 0.0)
                .count();
            assert_eq!(changes, 5, "noisy {noisy}");
            if !noisy {
                assert_eq!(naive, 0);
                // Each dwell and each repeated DAC level is one sample; no input moved.
                assert_eq!(p.summary.flattened, 0);
                let distinct = 1 + v.windows(2).filter(|w| w[0] != w[1]).count();
                assert_eq!(p.summary.samples, distinct);
                assert!(p.summary.merged >= 6 * 25);
            } else {
                assert!(naive > 100, "{naive}");
                // The flattened inputs moved by less than the threshold.
                assert!(p.summary.reversal_threshold < 0.5, "{:?}", p.summary);
            }
        }
    }

    #[test]
    fn a_dwell_merges_to_the_mean_of_its_outputs() {
        let mut v = loops(3, 200, 0, 0.0);
        let at = v.len() / 3;
        let hold = v[at];
        let tail = v.split_off(at + 1);
        v.extend([hold; 4]);
        v.extend(tail);
        let mut y: Vec<f64> = v.iter().map(|u| u * 1e-7).collect();
        for (k, e) in [1.0, 2.0, 3.0, 4.0].iter().enumerate() {
            y[at + 1 + k] += e * 1e-9;
        }
        let p = prepare(&v, &y, &RANGE).unwrap();
        assert_eq!(p.summary.merged, 4);
        let k = p.inputs.iter().position(|u| *u == hold).unwrap();
        let expected = (5.0 * hold * 1e-7 + 10e-9) / 5.0;
        assert!(
            (p.outputs[k] - expected).abs() < 1e-18,
            "{} vs {expected}",
            p.outputs[k]
        );
    }
}
