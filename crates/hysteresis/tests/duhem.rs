//! Feedforward compensation of an actuator whose hysteresis belongs to another class
//! than the models: an asymmetric Duhem (Coleman-Hodgdon) operator with about 12 %
//! loop width, identified from noisy data (5 nm sensor noise), then asked to track a
//! two-sine trajectory. The acceptance: RMS error at most 1.2 % of the stroke
//! and at most a quarter of a linear inverse's.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use cellinject_hysteresis::{PrandtlIshlinskii, Preisach, Range, inverse};
use cellinject_numeric::Rng;

/// m, the actuator's nominal stroke.
const STROKE: f64 = 30e-6;

/// The test actuator: dy = α|dx|(f(x) − y) + g·dx on x = V/100, with an asymmetric
/// anhysteretic curve f(x) = a·(x + c·x²)/(1 + c).
#[derive(Clone)]
struct Duhem {
    x: f64,
    y: f64,
}

impl Duhem {
    const ALPHA: f64 = 6.0;
    const G: f64 = 0.7 * STROKE;
    const A: f64 = 1.1 * STROKE;
    const C: f64 = 0.5;

    fn new() -> Self {
        Duhem { x: 0.0, y: 0.0 }
    }

    fn f(x: f64) -> f64 {
        Self::A * (x + Self::C * x * x) / (1.0 + Self::C)
    }

    /// Moves the voltage to `v` (integrated in steps of 1e-4 of the range).
    fn apply(&mut self, v: f64) -> f64 {
        let target = (v / 100.0).clamp(0.0, 1.0);
        let n = ((target - self.x).abs() / 1e-4).ceil().max(1.0) as usize;
        let dx = (target - self.x) / n as f64;
        for _ in 0..n {
            let xm = self.x + 0.5 * dx;
            self.y += Self::ALPHA * dx.abs() * (Self::f(xm) - self.y) + Self::G * dx;
            self.x += dx;
        }
        self.y
    }
}

/// A rich excitation: a full rise, then oscillations of varying amplitude and centre
/// (first-order reversals of every size), 4000 samples, inside 0-100 V.
fn excitation() -> Vec<f64> {
    let n = 4000;
    (0..n)
        .map(|k| {
            let t = k as f64 / n as f64;
            if t < 0.05 {
                100.0 * t / 0.05
            } else {
                let s = (t - 0.05) / 0.95;
                let centre = 50.0 + 25.0 * (2.0 * std::f64::consts::PI * 1.3 * s).sin();
                let amp = 48.0
                    * (1.0 - 0.85 * s)
                    * (0.5 + 0.5 * (2.0 * std::f64::consts::PI * 2.1 * s).cos());
                let v = centre + amp * (2.0 * std::f64::consts::PI * 23.0 * s).cos();
                v.clamp(0.0, 100.0)
            }
        })
        .collect()
}

/// The two-sine trajectory, starting near the relaxed state.
fn trajectory() -> Vec<f64> {
    let n = 2000;
    (0..n)
        .map(|k| {
            let t = k as f64 / n as f64;
            let tau = 2.0 * std::f64::consts::PI;
            STROKE * (0.5 - 0.25 * (tau * 2.0 * t).cos() - 0.15 * (tau * 7.0 * t).cos())
        })
        .collect()
}

fn rms(e: &[f64]) -> f64 {
    (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt()
}

/// Runs `volts` through a fresh actuator and returns the tracking errors.
fn errors(volts: &[f64], desired: &[f64]) -> Vec<f64> {
    let mut a = Duhem::new();
    volts
        .iter()
        .zip(desired)
        .map(|(v, yd)| a.apply(*v) - yd)
        .collect()
}

#[test]
fn preisach_feedforward_tracks_a_duhem_actuator_to_a_fraction_of_a_linear_inverse() {
    // The actuator's character: stroke on the first rise, loop width at mid-range.
    let mut a = Duhem::new();
    let stroke = a.apply(100.0);
    let down_mid = a.apply(50.0);
    let mut b = Duhem::new();
    let up_mid = b.apply(50.0);
    let width = (down_mid - up_mid) / stroke;
    eprintln!(
        "Duhem actuator: stroke {:.3} µm, loop width at 50 V {:.1} %",
        stroke * 1e6,
        width * 100.0
    );
    assert!((0.09..=0.15).contains(&width), "loop width {width}");
    // Identification data with 5 nm of sensor noise.
    let volts = excitation();
    let mut a = Duhem::new();
    let mut rng = Rng::new(11, 3);
    let meas: Vec<f64> = volts
        .iter()
        .map(|v| a.apply(*v) + 5e-9 * rng.gaussian_exact())
        .collect();
    let range = Range {
        min: 0.0,
        max: 100.0,
    };
    let fit = Preisach::identify(range, 20, &volts, &meas, 1e-7).unwrap();
    eprintln!(
        "Preisach 20x20 fit: RMS {:.2} nm ({:.3} % of the data's span), max {:.1} nm",
        fit.rms * 1e9,
        100.0 * fit.rms / fit.span,
        fit.max * 1e9
    );
    // The linear inverse: least-squares slope through the origin.
    let k = volts.iter().zip(&meas).map(|(v, y)| v * y).sum::<f64>()
        / volts.iter().map(|v| v * v).sum::<f64>();
    let desired = trajectory();
    let linear: Vec<f64> = desired.iter().map(|y| (y / k).clamp(0.0, 100.0)).collect();
    let lin = rms(&errors(&linear, &desired));
    // The Preisach feedforward.
    let mut model = fit.model.clone();
    let mut cmd = Vec::new();
    let residual = inverse(&mut model, &desired, &mut cmd).unwrap();
    assert!(residual < 1e-12, "inversion residual {residual}");
    let ff = rms(&errors(&cmd, &desired));
    eprintln!(
        "two-sine tracking: feedforward RMS {:.2} nm = {:.3} % of stroke; linear inverse {:.2} nm = {:.2} %; ratio {:.3}",
        ff * 1e9,
        100.0 * ff / stroke,
        lin * 1e9,
        100.0 * lin / stroke,
        ff / lin
    );
    assert!(ff <= 0.012 * stroke, "{} % of stroke", 100.0 * ff / stroke);
    assert!(ff <= 0.25 * lin, "ratio {}", ff / lin);
    // The asymmetric Prandtl-Ishlinskii model on the same data, for comparison.
    let pi = PrandtlIshlinskii::identify(range, 16, true, &volts, &meas, 1e-7).unwrap();
    let mut pm = pi.model.clone();
    let mut pcmd = Vec::new();
    inverse(&mut pm, &desired, &mut pcmd).unwrap();
    let pf = rms(&errors(&pcmd, &desired));
    eprintln!(
        "asymmetric PI (16 plays): fit RMS {:.2} nm; tracking RMS {:.2} nm = {:.3} % of stroke",
        pi.rms * 1e9,
        pf * 1e9,
        100.0 * pf / stroke
    );
    assert!(pf < lin, "PI {pf} vs linear {lin}");
}

#[test]
fn a_target_out_of_reach_is_refused_and_bad_data_is_named() {
    let range = Range {
        min: 0.0,
        max: 100.0,
    };
    let volts = excitation();
    let mut a = Duhem::new();
    let meas: Vec<f64> = volts.iter().map(|v| a.apply(*v)).collect();
    let fit = Preisach::identify(range, 10, &volts, &meas, 1e-7).unwrap();
    let mut m = fit.model;
    let mut out = Vec::new();
    let e = inverse(&mut m, &[0.5 * STROKE, 2.0 * STROKE], &mut out).unwrap_err();
    assert!(
        matches!(
            e,
            cellinject_hysteresis::HysteresisError::OutOfReach { index: 1, .. }
        ),
        "{e}"
    );
    let short = Preisach::identify(range, 10, &volts[..50], &meas[..50], 1e-7).unwrap_err();
    assert!(short.to_string().contains("at least 100"), "{short}");
    let ramp: Vec<f64> = (0..500).map(|k| k as f64 / 5.0).collect();
    let e = Preisach::identify(range, 10, &ramp, &ramp, 1e-7).unwrap_err();
    assert!(e.to_string().contains("reversals"), "{e}");
}
