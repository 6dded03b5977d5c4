//! Identification from a real recording (issue 20, point 3): an actuator of another
//! class than the models (a Bouc-Wen operator with an asymmetric quadratic term),
//! recorded as a bench logger would: the amplifier holds each turning point for 5 to 50
//! samples, the voltage is a 12-bit DAC's (steps of 100/4096 V, some ramps slower than
//! the logger), 5 nm of Gaussian noise on the displacement, irregular time stamps, and
//! extra columns in another order than the documented one. The CSV text goes through
//! the same reader and fit as `cellinject hysteresis fit` (default model and size), the
//! fitted model is inverted for a decaying sinusoid, and the true actuator is driven
//! with the result. The acceptance: tracking RMS at most 1.2 % of the stroke
//! and at most a quarter of a linear inverse's, worst case over a sweep of recording
//! seeds ([`SEEDS`]: 1 to 5 and the four worst of 1 to 50 before the fit was
//! smoothed).
//!
//! The Bouc-Wen operator is not of the Preisach class (its minor loops do not close),
//! so the default 20 x 20 Preisach model misfits it by about 250-320 nm RMS whatever
//! the data's defects (the same recordings without dwells, quantisation or noise fit
//! no better). The tracking error is that misfit along the trajectory (the inversion
//! is exact to the model): with the weights identified by least squares with a ridge
//! only, they came out spiky (many 0 next to large ones) and the decaying oscillation's nested
//! loops summed the spikes into a bias of up to 400 nm, so that the tracking RMS
//! ranged from 0.47 % to 1.36 % of the stroke and the ratio to the linear inverse from
//! 0.12 to 0.42 over seeds 1 to 50 (median 0.18; seeds 6, 17, 21, 25, 28, 41 and 46
//! above 0.25). With the smoothness penalty and the path-length weights of the fit
//! (`cellinject_hysteresis::preisach::SMOOTHNESS`, `Prepared::weights`): 0.43 % to
//! 0.72 % of the stroke, ratio median 0.16 and worst 0.22 (seed 17) over the same 50
//! (`over_fifty_seeds`, ignored).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::fmt::Write as _;

use cellinject_core::hysteresis::{DEFAULT_SIZE, Kind, fit, invert};
use cellinject_core::table::Table;
use cellinject_hysteresis::Range;
use cellinject_numeric::Rng;

/// The DAC's step, V.
const LSB: f64 = 100.0 / 4096.0;

/// Reversals in a recording.
const REVERSALS: usize = 200;

/// A rate-independent Bouc-Wen actuator on x = V/100:
/// y = d·x + c·x² − h, dh = a·d·dx − β|dx|·h − γ·dx·|h|.
/// The quadratic term and β ≠ γ make the loop asymmetric.
#[derive(Clone)]
struct BoucWen {
    x: f64,
    h: f64,
}

impl BoucWen {
    const D: f64 = 30e-6;
    const C: f64 = 0.35 * 30e-6;
    const A: f64 = 0.5;
    const BETA: f64 = 4.0;
    const GAMMA: f64 = 1.5;

    fn new() -> Self {
        BoucWen { x: 0.0, h: 0.0 }
    }

    /// Moves the voltage to `v` (integrated in steps of 1e-4 of the range).
    fn apply(&mut self, v: f64) -> f64 {
        let target = (v / 100.0).clamp(0.0, 1.0);
        let n = ((target - self.x).abs() / 1e-4).ceil().max(1.0) as usize;
        let dx = (target - self.x) / n as f64;
        for _ in 0..n {
            self.h += Self::A * Self::D * dx
                - Self::BETA * dx.abs() * self.h
                - Self::GAMMA * dx * self.h.abs();
            self.x += dx;
        }
        Self::D * self.x + Self::C * self.x * self.x - self.h
    }
}

/// What went into a recording.
struct Recording {
    csv: String,
    rows: usize,
    dwell_rows: usize,
}

/// The recording of seed `seed`: a first rise to the DAC's top, then 200 turning
/// points at random levels (reversals of every size, the largest first), ramps of
/// random speed (every 20th slower than a DAC step per sample, so levels repeat), a
/// dwell of 5-50 samples at each extreme.
fn record(seed: u64) -> Recording {
    let mut rng = Rng::new(seed, 20);
    let mut act = BoucWen::new();
    let mut volts: Vec<f64> = Vec::new();
    let mut dwell_rows = 0;
    let top = 4095.0 * LSB;
    let mut turns = vec![top];
    let mut up = false;
    for k in 0..REVERSALS {
        let span = 100.0 * (1.0 - 0.8 * k as f64 / REVERSALS as f64);
        let last = *turns.last().unwrap();
        let step = rng.range(0.05, 1.0) * span;
        turns.push(if up {
            (last + step).min(top)
        } else {
            (last - step).max(0.0)
        });
        up = !up;
    }
    let mut at = 0.0f64;
    for (k, &to) in turns.iter().enumerate() {
        // V per sample.
        let speed = if k % 20 == 19 {
            (0.5 * LSB).max((to - at).abs() / 800.0)
        } else {
            10f64.powf(rng.range(-0.8, -0.3))
        };
        let n = ((to - at).abs() / speed).ceil().max(1.0) as usize;
        for i in 1..=n {
            let v = at + (to - at) * i as f64 / n as f64;
            volts.push((v / LSB).round() * LSB);
        }
        at = to;
        let hold = 5 + (rng.uniform() * 46.0) as usize;
        let v = *volts.last().unwrap();
        volts.extend(std::iter::repeat_n(v, hold));
        dwell_rows += hold;
    }
    // The logger: columns in another order than the documented one, two extra ones.
    let mut csv = String::from("displacement_m,temperature_c,voltage_v,status,time_s\n");
    let mut t = 0.0;
    for v in &volts {
        let y = act.apply(*v) + 5e-9 * rng.gaussian_exact();
        t += 1e-3 * rng.range(0.6, 1.4);
        let temp = 21.0 + 0.1 * rng.gaussian();
        let _ = writeln!(csv, "{y:.12e},{temp:.3},{v:.6},ok,{t:.6}");
    }
    Recording {
        csv,
        rows: volts.len(),
        dwell_rows,
    }
}

/// The desired trajectory: a decaying sinusoid about mid-stroke, from near rest.
fn trajectory(stroke: f64) -> Vec<f64> {
    (0..3000)
        .map(|k| {
            let t = k as f64 * 1e-3;
            let tau = 2.0 * std::f64::consts::PI;
            stroke * (0.5 - 0.42 * (-t / 1.0).exp() * (tau * 4.0 * t).cos())
        })
        .collect()
}

fn rms(e: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for x in e {
        s += x * x;
        n += 1;
    }
    (s / n as f64).sqrt()
}

/// The tracking errors of the true actuator driven with `volts`.
fn errors(volts: &[f64], desired: &[f64]) -> Vec<f64> {
    let mut a = BoucWen::new();
    volts
        .iter()
        .zip(desired)
        .map(|(v, yd)| a.apply(*v) - yd)
        .collect()
}

/// The RMS tracking error of the true actuator driven with `volts`.
fn tracking(volts: &[f64], desired: &[f64]) -> f64 {
    rms(errors(volts, desired).into_iter())
}

/// (feedforward RMS / stroke, feedforward RMS / linear inverse's RMS) for one seed.
fn run(seed: u64) -> (f64, f64) {
    let rec = record(seed);
    let table = Table::parse(&rec.csv, &["voltage_v", "displacement_m"], &["time_s"]).unwrap();
    table.non_decreasing("time_s").unwrap();
    assert_eq!(table.ignored, ["temperature_c", "status"]);
    let volts = table.column("voltage_v").unwrap();
    let disp = table.column("displacement_m").unwrap();
    assert_eq!(volts.len(), rec.rows);
    // The old rule (a sign change between consecutive steps) sees no reversal at all.
    let naive = volts
        .windows(3)
        .filter(|w| (w[1] - w[0]) * (w[2] - w[1]) < 0.0)
        .count();
    assert_eq!(naive, 0);
    // As `hysteresis fit` does by default: Preisach, its default size, on [0, the
    // data's highest voltage].
    let top = volts.iter().copied().fold(0.0, f64::max);
    let f = fit(
        Kind::Preisach,
        DEFAULT_SIZE,
        Range { min: 0.0, max: top },
        volts,
        disp,
    )
    .unwrap();
    assert_eq!(f.data.reversals, REVERSALS, "{:?}", f.data);
    assert!(f.data.merged >= rec.dwell_rows, "{:?}", f.data);
    assert_eq!(f.data.flattened, 0, "{:?}", f.data);
    assert!((f.data.input_noise - LSB).abs() < 1e-5, "{:?}", f.data);
    let stroke = BoucWen::new().apply(top);
    let desired = trajectory(stroke);
    let inv = invert(&f.model, &desired, false).unwrap();
    let e = errors(&inv.volts, &desired);
    let ff = rms(e.iter().copied());
    // The error's mean over the last second (small loops about mid-stroke): a bias
    // there is the model's, summed over the cells the nested loops cut.
    let late = e[2000..].iter().sum::<f64>() / 1000.0;
    // The linear inverse: the least-squares line of displacement against voltage.
    let n = volts.len() as f64;
    let (mv, my) = (volts.iter().sum::<f64>() / n, disp.iter().sum::<f64>() / n);
    let slope = volts
        .iter()
        .zip(disp)
        .map(|(v, y)| (v - mv) * (y - my))
        .sum::<f64>()
        / volts.iter().map(|v| (v - mv) * (v - mv)).sum::<f64>();
    let linear: Vec<f64> = desired
        .iter()
        .map(|y| (mv + (y - my) / slope).clamp(0.0, top))
        .collect();
    let lin = tracking(&linear, &desired);
    eprintln!(
        "seed {seed}: {} rows ({} in dwells), {} fitted, {} reversals; fit RMS {:.2} nm; tracking RMS {:.2} nm = {:.3} % of the {:.2} µm stroke, linear inverse {:.1} nm, ratio {:.3}; mean error over the last second {:.0} nm",
        rec.rows,
        rec.dwell_rows,
        f.samples,
        f.data.reversals,
        f.rms * 1e9,
        ff * 1e9,
        100.0 * ff / stroke,
        stroke * 1e6,
        lin * 1e9,
        ff / lin,
        late * 1e9
    );
    (ff / stroke, ff / lin)
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[s.len() / 2]
}

fn worst(v: &[f64]) -> f64 {
    v.iter().copied().fold(0.0, f64::max)
}

/// The recording seeds of the acceptance test: 1 to 5 (on which it was first tuned)
/// and the four worst of 1 to 50 before the fit was smoothed: 6, 17, 28 and 41, whose
/// ratio to the linear inverse was 0.31, 0.29, 0.40 and 0.42 (and tracking RMS 1.36 %
/// and 1.29 % of the stroke for 28 and 41). About 4.5 s a seed in a debug build.
const SEEDS: [u64; 9] = [1, 2, 3, 4, 5, 6, 17, 28, 41];

/// Runs `seeds` and prints the median and worst of both figures.
fn over(seeds: impl Iterator<Item = u64>) -> (Vec<f64>, Vec<f64>) {
    let (rel, ratio): (Vec<f64>, Vec<f64>) = seeds.map(run).unzip();
    let n = rel.len();
    eprintln!(
        "tracking RMS over {n} seeds: median {:.3} %, worst {:.3} % of stroke (at most 1.2 %); ratio to the linear inverse: median {:.3}, worst {:.3} (at most 0.25)",
        100.0 * median(&rel),
        100.0 * worst(&rel),
        median(&ratio),
        worst(&ratio)
    );
    (rel, ratio)
}

#[test]
fn a_real_recording_of_a_bouc_wen_actuator_is_fitted_and_inverted_to_a_fraction_of_a_linear_inverse()
 {
    // The actuator's character: loop width at mid-range.
    let mut a = BoucWen::new();
    let stroke = a.apply(100.0);
    let down = a.apply(50.0);
    let up = BoucWen::new().apply(50.0);
    let width = (down - up) / stroke;
    eprintln!(
        "Bouc-Wen actuator: stroke {:.2} µm, loop width at 50 V {:.1} %",
        stroke * 1e6,
        100.0 * width
    );
    assert!((0.09..=0.16).contains(&width), "{width}");
    let (rel, ratio) = over(SEEDS.into_iter());
    assert!(worst(&rel) <= 0.012, "{rel:?}");
    assert!(worst(&ratio) <= 0.25, "{ratio:?}");
}

/// The same over seeds 1 to 50, for the record (`cargo test --release -p
/// cellinject-core --test hysteresis_recording -- --ignored --nocapture`): no
/// assertion.
#[test]
#[ignore = "slow: the distribution over 50 seeds, printed"]
fn over_fifty_seeds() {
    over(1..=50);
}
