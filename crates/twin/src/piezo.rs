//! Piezo stack and amplifier: DAC, slew and bandwidth; rate-independent hysteresis
//! (Preisach operator with a continuous density); logarithmic creep.
//!
//! The stack's free extension (no load) is
//!
//! ```text
//! e = S · (y + c),   y = (1 − p)·u + p·P[u],   u = V / V_max,
//! ```
//!
//! with `P` the Preisach operator of [`Preisach`], `c` the creep of [`Creep`], and the
//! scale `S = travel / (1 + c(1 s))` chosen so that the stack reaches its rated travel
//! at full voltage one second after a step from rest (as data sheets quote nominal
//! travel, quasi-statically); held for hours it creeps a few per cent further
//! (`Σ a_j − c(1 s)`: 6 % with the default creep), which the safety envelope's
//! hysteresis bound covers. The load it works against is the mechanism's business
//! (the stack stiffness enters the structure's stiffness, eqs. 21 and 26).

use crate::params::{AmplifierParams, CreepParams, HysteresisParams, StackParams};

/// A piezo amplifier channel: quantised command, first-order bandwidth, slew limit.
#[derive(Debug, Clone)]
pub struct Amplifier {
    p: AmplifierParams,
    v_max: f64,
    command: f64,
    quantised: f64,
    output: f64,
    alpha: f64,
    max_step: f64,
}

impl Amplifier {
    /// An amplifier with the output range 0..`v_max` volts (the rig's), stepped every
    /// `dt` seconds, starting at 0 V.
    pub fn new(p: AmplifierParams, v_max: f64, dt: f64) -> Self {
        Amplifier {
            p,
            v_max,
            command: 0.0,
            quantised: 0.0,
            output: 0.0,
            alpha: 1.0 - (-2.0 * std::f64::consts::PI * p.bandwidth * dt).exp(),
            max_step: p.slew_rate * dt,
        }
    }

    /// The DAC value nearest to `volts` (16 bits over 0..V_max by default).
    pub fn quantise(&self, volts: f64) -> f64 {
        let levels = ((1u64 << self.p.dac_bits) - 1) as f64;
        let v = volts.clamp(0.0, self.v_max);
        (v / self.v_max * levels).round() / levels * self.v_max
    }

    /// Sets the command (clamped to the output range: range checks belong to the caller).
    pub fn set(&mut self, volts: f64) {
        self.command = volts;
        self.quantised = self.quantise(volts);
    }

    /// The last command.
    pub fn command(&self) -> f64 {
        self.command
    }

    /// The noise-free output.
    pub fn output(&self) -> f64 {
        self.output
    }

    /// Parameters.
    pub fn params(&self) -> &AmplifierParams {
        &self.p
    }

    /// Highest output, V.
    pub fn v_max(&self) -> f64 {
        self.v_max
    }

    /// Advances one step and returns the noise-free output. The output snaps to the
    /// command once within 1 nV of it, so that a settled amplifier costs nothing downstream.
    #[inline]
    pub fn step(&mut self) -> f64 {
        let diff = self.quantised - self.output;
        if diff.abs() < 1e-9 {
            self.output = self.quantised;
        } else {
            self.output += (diff * self.alpha).clamp(-self.max_step, self.max_step);
        }
        self.output
    }

    /// Output noise for a standard normal sample, V.
    #[inline]
    pub fn noise(&self, sample: f64) -> f64 {
        self.p.noise * sample
    }
}

/// Everett function of the density `μ(α, β) = c0 + c1·α + c2·β` over the triangle
/// `{β ≤ β' ≤ α' ≤ α}`: `E(a, b) = ∫_b^a ∫_{β'}^a μ(α', β') dα' dβ'`.
#[inline]
fn everett(c: &[f64; 3], a: f64, b: f64) -> f64 {
    let d = a - b;
    let a2 = a * a;
    let cube = (a2 * a - b * b * b) / 3.0;
    c[0] * d * d * 0.5 + c[1] * 0.5 * (a2 * d - cube) + c[2] * (a * (a2 - b * b) * 0.5 - cube)
}

/// Preisach operator on `[0, 1]` with the continuous density
/// `μ(α, β) = 2·(1 + s·(α + β − 1))`, normalised so that a full sweep 0 → 1 gives 1.
///
/// Memory is the list of dominant alternating extrema (`m0 = 0, M1, m1, M2, …`), kept
/// by the wiping-out rule; the output is the sum of Everett differences along it.
#[derive(Debug, Clone)]
pub struct Preisach {
    c: [f64; 3],
    ext: Vec<f64>,
    /// `sums[i]`: the completed Everett terms of the extrema `ext[0..=i]`, so that the
    /// output costs at most three Everett evaluations whatever the memory depth.
    sums: Vec<f64>,
    u: f64,
    rising: bool,
    y: f64,
}

/// Longest memory kept; deeper (smaller) loops are merged.
const MAX_MEMORY: usize = 64;

impl Preisach {
    /// An operator with skew `s` (|s| < 1), starting at u = 0 from negative saturation.
    pub fn new(skew: f64) -> Self {
        let c = 2.0;
        Preisach {
            c: [c * (1.0 - skew), c * skew, c * skew],
            ext: vec![0.0],
            sums: vec![0.0],
            u: 0.0,
            rising: true,
            y: 0.0,
        }
    }

    /// The density at (α, β).
    pub fn density(&self, alpha: f64, beta: f64) -> f64 {
        self.c[0] + self.c[1] * alpha + self.c[2] * beta
    }

    /// Current output.
    pub fn output(&self) -> f64 {
        self.y
    }

    /// Current input.
    pub fn input(&self) -> f64 {
        self.u
    }

    /// Number of extrema in memory.
    pub fn memory_len(&self) -> usize {
        self.ext.len()
    }

    /// Applies input `u` (clamped to [0, 1]) and returns the output.
    pub fn apply(&mut self, u: f64) -> f64 {
        let u = u.clamp(0.0, 1.0);
        if u == self.u {
            return self.y;
        }
        let rising = u > self.u;
        if rising != self.rising {
            self.push(self.u);
            self.rising = rising;
        }
        // Wiping out: a new maximum removes every smaller earlier maximum with the
        // minimum that follows it, and symmetrically for minima.
        while self.ext.len() >= 3 {
            let n = self.ext.len();
            let wiped = if rising {
                u >= self.ext[n - 2]
            } else {
                u <= self.ext[n - 2]
            };
            if !wiped {
                break;
            }
            self.ext.truncate(n - 2);
            self.sums.truncate(n - 2);
        }
        if self.ext.len() > MAX_MEMORY {
            // Merge the innermost (smallest) loop: its contribution is negligible.
            let n = self.ext.len();
            let keep = self.ext[n - 1];
            self.ext.truncate(n - 3);
            self.sums.truncate(n - 3);
            self.push(keep);
        }
        self.u = u;
        self.y = self.evaluate();
        self.y
    }

    /// Appends an extremum and the Everett term it completes.
    fn push(&mut self, p: f64) {
        let i = self.ext.len();
        self.ext.push(p);
        let prev = self.sums[i - 1];
        // A point at an even index follows the maximum at i − 1, whose term it completes.
        let s = if i % 2 == 0 {
            let m = self.ext[i - 1];
            prev + everett(&self.c, m, self.ext[i - 2]) - everett(&self.c, m, p)
        } else {
            prev
        };
        self.sums.push(s);
    }

    fn evaluate(&self) -> f64 {
        // Points p0..p_{n-1} of the memory followed by the current input u at index n;
        // every odd index is a maximum between two minima.
        let n = self.ext.len();
        let done = self.sums[n - 1];
        if n % 2 == 1 {
            // u sits at a maximum position: its term is E(u, p_{n-1}).
            done + everett(&self.c, self.u, self.ext[n - 1])
        } else {
            let m = self.ext[n - 1];
            done + everett(&self.c, m, self.ext[n - 2]) - everett(&self.c, m, self.u)
        }
    }
}

/// Logarithmic creep by a bank of first-order lags, two per decade.
///
/// Lags much slower than the step are advanced every [`SLOW_EVERY`] steps with the
/// exact decay over that interval (the input is held over it: the error is of order
/// `SLOW_EVERY·dt/τ`, below 1 % for the slow lags), which keeps a step cheap.
#[derive(Debug, Clone)]
pub struct Creep {
    weight: Vec<f64>,
    decay: Vec<f64>,
    z: Vec<f64>,
    /// Lags `slow_from..` are slow.
    slow_from: usize,
    slow_sum: f64,
    counter: u32,
    total_weight: f64,
}

/// How many steps a slow creep lag waits between updates.
pub const SLOW_EVERY: u32 = 16;

impl Creep {
    /// A creep bank for parameters `p`, stepped every `dt`.
    pub fn new(p: &CreepParams, dt: f64) -> Self {
        let decades = (p.tau_max / p.tau_min).log10().max(0.0);
        let n = (2.0 * decades).round() as usize + 1;
        let mut weight = Vec::with_capacity(n);
        let mut decay = Vec::with_capacity(n);
        let mut slow_from = n;
        for j in 0..n {
            let tau = p.tau_min * 10f64.powf(j as f64 / 2.0);
            // Each half-decade element contributes γ/2: γ per decade in all.
            weight.push(if p.gamma > 0.0 { p.gamma / 2.0 } else { 0.0 });
            let slow = tau >= 100.0 * SLOW_EVERY as f64 * dt;
            if slow && slow_from == n {
                slow_from = j;
            }
            let h = if slow { SLOW_EVERY as f64 * dt } else { dt };
            decay.push((-h / tau).exp());
        }
        let total_weight = weight.iter().sum();
        Creep {
            weight,
            decay,
            z: vec![0.0; n],
            slow_from,
            slow_sum: 0.0,
            counter: 0,
            total_weight,
        }
    }

    /// Σ a_j, the creep of a step held forever.
    pub fn total_weight(&self) -> f64 {
        self.total_weight
    }

    /// The creep `t` seconds after a unit step from rest: `Σ a_j (1 − e^(−t/τ_j))`.
    pub fn after(&self, t: f64, dt: f64) -> f64 {
        let h = |j: usize| {
            if j >= self.slow_from {
                SLOW_EVERY as f64 * dt
            } else {
                dt
            }
        };
        self.weight
            .iter()
            .zip(&self.decay)
            .enumerate()
            .map(|(j, (w, d))| {
                // decay = exp(−h/τ): the lag's time constant in steps of h.
                let tau_over_h = -1.0 / d.ln();
                w * (1.0 - (-t / (tau_over_h * h(j))).exp())
            })
            .sum()
    }

    /// Advances one step with input `y`; returns the creep `c`.
    #[inline]
    pub fn step(&mut self, y: f64) -> f64 {
        if self.total_weight == 0.0 {
            return 0.0;
        }
        let k = self.slow_from;
        let mut c = 0.0;
        for ((z, w), d) in self.z[..k]
            .iter_mut()
            .zip(&self.weight[..k])
            .zip(&self.decay[..k])
        {
            *z = w * y + (*z - w * y) * d;
            c += *z;
        }
        self.counter += 1;
        if self.counter == SLOW_EVERY {
            self.counter = 0;
            let mut s = 0.0;
            for ((z, w), d) in self.z[k..]
                .iter_mut()
                .zip(&self.weight[k..])
                .zip(&self.decay[k..])
            {
                *z = w * y + (*z - w * y) * d;
                s += *z;
            }
            self.slow_sum = s;
        }
        c + self.slow_sum
    }
}

/// One stack with its amplifier.
#[derive(Debug, Clone)]
pub struct Stack {
    /// The amplifier channel.
    pub amplifier: Amplifier,
    hysteresis: HysteresisParams,
    preisach: Preisach,
    creep: Creep,
    scale: f64,
    travel: f64,
    extension: f64,
}

impl Stack {
    /// A stack of rated `travel` (m) on an amplifier of 0..`v_max` volts, stepped
    /// every `dt`.
    pub fn new(p: &StackParams, v_max: f64, travel: f64, dt: f64) -> Self {
        let creep = Creep::new(&p.creep, dt);
        Stack {
            amplifier: Amplifier::new(p.amplifier, v_max, dt),
            hysteresis: p.hysteresis,
            preisach: Preisach::new(p.hysteresis.skew),
            // Rated travel at full voltage one second after a step from rest.
            scale: travel / (1.0 + creep.after(1.0, dt)),
            creep,
            travel,
            extension: 0.0,
        }
    }

    /// Rated travel, m.
    pub fn travel(&self) -> f64 {
        self.travel
    }

    /// `S`, the extension per unit of normalised hysteretic output, m.
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// Free extension now, m.
    pub fn extension(&self) -> f64 {
        self.extension
    }

    /// The rate-independent part for a normalised input `u` (no creep), for the current
    /// memory: `y = (1 − p)·u + p·P[u]`.
    fn hysteretic(&mut self, u: f64) -> f64 {
        let p = self.hysteresis.fraction;
        (1.0 - p) * u + p * self.preisach.apply(u)
    }

    /// Advances one step (`noise` is a standard normal sample); returns the free extension.
    ///
    /// The amplifier's output noise (about a millivolt) is far below any loop the
    /// hysteresis could form, so it drives the stack through the small-signal, reversible
    /// response: it adds to the extension without entering the Preisach memory.
    #[inline]
    pub fn step(&mut self, noise: f64) -> f64 {
        let v_max = self.amplifier.v_max();
        let u = self.amplifier.step() / v_max;
        let y = self.hysteretic(u);
        let c = self.creep.step(y);
        // The amplifier is unipolar: its noisy output stays within 0..V_max.
        let n = (u + self.amplifier.noise(noise) / v_max).clamp(0.0, 1.0) - u;
        self.extension = self.scale * (y + c + n);
        self.extension
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Independent computation of the Preisach output: a grid of N x N relays with the
    /// density sampled at cell centres, switched one by one.
    struct Relays {
        n: usize,
        weight: Vec<f64>,
        up: Vec<bool>,
    }

    impl Relays {
        fn new(n: usize, skew: f64) -> Self {
            let h = 1.0 / n as f64;
            let mut weight = vec![0.0; n * n];
            for i in 0..n {
                for j in 0..n {
                    let alpha = (i as f64 + 0.5) * h;
                    let beta = (j as f64 + 0.5) * h;
                    weight[i * n + j] = if j < i {
                        2.0 * (1.0 + skew * (alpha + beta - 1.0)) * h * h
                    } else if i == j {
                        // Half of the diagonal cell lies in the triangle.
                        2.0 * (1.0 + skew * (alpha + beta - 1.0)) * h * h * 0.5
                    } else {
                        0.0
                    };
                }
            }
            Relays {
                n,
                weight,
                up: vec![false; n * n],
            }
        }
        fn apply(&mut self, u: f64) -> f64 {
            let h = 1.0 / self.n as f64;
            let mut y = 0.0;
            for i in 0..self.n {
                for j in 0..self.n {
                    let alpha = (i as f64 + 0.5) * h;
                    let beta = (j as f64 + 0.5) * h;
                    let k = i * self.n + j;
                    if u >= alpha {
                        self.up[k] = true;
                    } else if u <= beta {
                        self.up[k] = false;
                    }
                    if self.up[k] {
                        y += self.weight[k];
                    }
                }
            }
            y
        }
    }

    #[test]
    fn preisach_matches_an_independent_relay_grid_on_nested_loops() {
        let inputs = [
            0.0, 1.0, 0.2, 0.8, 0.4, 0.6, 0.5, 0.9, 0.1, 0.7, 0.3, 1.0, 0.0, 0.55,
        ];
        let mut p = Preisach::new(0.3);
        let mut r = Relays::new(400, 0.3);
        // Sweep in small increments so that both see the same history.
        let mut last = 0.0;
        for &target in &inputs {
            for k in 1..=50 {
                let u = last + (target - last) * k as f64 / 50.0;
                let a = p.apply(u);
                let b = r.apply(u);
                assert!((a - b).abs() < 4e-3, "u = {u}: operator {a}, relays {b}");
            }
            last = target;
        }
    }

    #[test]
    fn everett_full_triangle_is_one() {
        let p = Preisach::new(0.7);
        assert!((everett(&p.c, 1.0, 0.0) - 1.0).abs() < 1e-15);
    }

    #[test]
    fn amplifier_respects_slew_quantisation_and_bandwidth() {
        let dt = 5e-5;
        let p = AmplifierParams::default();
        let mut a = Amplifier::new(p, 100.0, dt);
        a.set(100.0);
        let v1 = a.step();
        // Slew-limited: one step moves at most slew · dt.
        assert!((v1 - p.slew_rate * dt).abs() < 1e-12);
        // A small step is bandwidth-limited: 63 % after one time constant 1/(2π f).
        let mut b = Amplifier::new(AmplifierParams { noise: 0.0, ..p }, 100.0, dt);
        b.set(0.01);
        let tau = 1.0 / (2.0 * std::f64::consts::PI * p.bandwidth);
        let steps = (tau / dt).round() as usize;
        let mut v = 0.0;
        for _ in 0..steps {
            v = b.step();
        }
        let expected = b.quantise(0.01) * (1.0 - (-(steps as f64) * dt / tau).exp());
        assert!((v - expected).abs() < 1e-9, "{v} vs {expected}");
        assert_eq!(a.quantise(50.0), (32767.5f64.round() / 65535.0) * 100.0);
    }
}
