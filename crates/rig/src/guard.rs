//! Safety limits as wrappers around any device implementation.
//!
//! A [`PiezoEnvelope`] knows the mechanism (its pre-tension and Jacobians) and the
//! stacks' limits. Before a voltage reaches an amplifier, [`GuardedPiezo`] asks it
//! whether the three commanded voltages together keep every stack compressed, below its
//! push capacity, and every J1/J2 bending torque below the stack's torque limit, for
//! every extension the stacks may actually reach at those voltages (hysteresis and creep
//! move the extension within a band around the nominal `travel · V / V_max`; a dynamic
//! margin covers overshoot while the structure rings). All these quantities are affine
//! in the two drive shifts (eqs. 24-26, 32-33), so their extremes over the band lie at
//! its four corners, which are checked.
//!
//! [`GuardedStage`], [`GuardedInjector`] and [`GuardedOptics`] refuse stage moves
//! outside the travel, pressures above the injector's limit and magnifications outside
//! the zoom range.
//!
//! An accepted command allocates nothing: the refusals carry static names and build
//! their message only when displayed.

use std::sync::{Arc, Mutex, MutexGuard};

use cellinject_hw::{HwError, Injector, Optics, PiezoChannel, SafetyError, Stage, check_range};
use cellinject_model::{ACTUATOR_NAMES, Approach, Assembly, Mechanism, ModelError};
use nalgebra::Vector2;

/// Critical points a [`YieldCheck`] holds.
pub const YIELD_POINTS: usize = 16;

/// The stress tensor at one point of a flexure, affine in the two stack forces: `σ =
/// at_zero + per_newton[0]·F₁ + per_newton[1]·F₂` (Pa; xx, yy, zz, yz, xz, xy).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StressPoint {
    /// Pa at zero stack force.
    pub at_zero: [f64; 6],
    /// Pa per newton of F₁, of F₂.
    pub per_newton: [[f64; 6]; 2],
}

impl StressPoint {
    /// Von Mises stress at stack forces `f` (N), Pa.
    #[inline]
    pub fn von_mises(&self, f: [f64; 2]) -> f64 {
        let mut s = self.at_zero;
        for c in 0..6 {
            s[c] += self.per_newton[0][c] * f[0] + self.per_newton[1][c] * f[1];
        }
        let d = (s[0] - s[1]).powi(2) + (s[1] - s[2]).powi(2) + (s[2] - s[0]).powi(2);
        (0.5 * d + 3.0 * (s[3] * s[3] + s[4] * s[4] + s[5] * s[5])).sqrt()
    }
}

/// A flexure's yield check as numbers (no FEM at run time): its most stressed points
/// as affine functions of the stack forces (from the structural model and the joint
/// FEM: `cellinject-fea`'s `FeaModel::j3_yield_map`) and its yield strength. Von Mises
/// stress is convex in the forces, which are affine in the stacks' extensions: its
/// largest value over an extension band lies at one of the band's corners, which the
/// envelope checks. Fixed-size, so that a check allocates nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct YieldCheck {
    /// Flexure name.
    pub joint: &'static str,
    /// Pa.
    pub yield_strength: f64,
    /// The points (the first `count` are used).
    pub points: [StressPoint; YIELD_POINTS],
    /// Points in use.
    pub count: usize,
    /// Pa: how far the affine map may be from the full model (checked against
    /// `yield_strength − fit_error`).
    pub fit_error: f64,
}

impl YieldCheck {
    /// A check of `joint` from its most stressed points (the first [`YIELD_POINTS`]
    /// are kept), its yield strength and the points' fit error (Pa).
    pub fn new(
        joint: &'static str,
        yield_strength: f64,
        fit_error: f64,
        points: impl IntoIterator<Item = StressPoint>,
    ) -> Self {
        let mut out = [StressPoint::default(); YIELD_POINTS];
        let mut count = 0;
        for (o, p) in out.iter_mut().zip(points) {
            *o = p;
            count += 1;
        }
        YieldCheck {
            joint,
            yield_strength,
            points: out,
            count,
            fit_error,
        }
    }

    /// Peak von Mises stress at stack forces `f` (N), Pa.
    #[inline]
    pub fn von_mises(&self, f: [f64; 2]) -> f64 {
        self.points[..self.count.min(YIELD_POINTS)]
            .iter()
            .map(|p| p.von_mises(f))
            .fold(0.0, f64::max)
    }

    /// The stress the check allows, Pa: the yield strength less the map's error.
    pub fn allowed(&self) -> f64 {
        self.yield_strength - self.fit_error
    }
}

/// Parameters of the envelope besides the mechanism.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnvelopeLimits {
    /// Output range of each amplifier channel, V.
    pub voltage_range: [(f64, f64); 3],
    /// Largest deviation of a stack's extension from `travel · V / V_max`, as a fraction
    /// of travel (hysteresis plus creep).
    pub hysteresis_bound: f64,
    /// Extra extension, as a fraction of travel, for dynamic overshoot.
    pub dynamic_margin: f64,
    /// J3's yield check, when the structural model was available.
    pub j3: Option<YieldCheck>,
}

/// The safe operating region of the three stacks of one assembled mechanism.
#[derive(Debug, Clone)]
pub struct PiezoEnvelope {
    mechanism: Mechanism,
    assembly: Assembly,
    limits: EnvelopeLimits,
}

/// The worst case found over the extension band of a command.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorstCase {
    /// N, per actuator: the most compressive and the least compressive force.
    pub force: [[f64; 2]; 2],
    /// N·m, per flexure J1, J2: the largest bending torque.
    pub torque: [f64; 2],
    /// Pa, J3's largest von Mises stress (0 without a yield check).
    pub j3_stress: f64,
}

impl PiezoEnvelope {
    /// The envelope of a mechanism assembled with `approach`.
    pub fn new(
        mechanism: Mechanism,
        approach: Approach,
        limits: EnvelopeLimits,
    ) -> Result<Self, ModelError> {
        let assembly = mechanism.assembly(approach)?;
        Ok(PiezoEnvelope {
            mechanism,
            assembly,
            limits,
        })
    }

    /// The limits.
    pub fn limits(&self) -> &EnvelopeLimits {
        &self.limits
    }

    /// The range of extensions (m) stack `ch` may reach at `volts`, dynamic margin
    /// included: `travel · (u ± (h + d))` with `u = V / V_max`, never below `−d·travel`
    /// (a relaxed stack does not pull). A stack reaches its rated travel at full voltage
    /// and creeps beyond it over hours: the upper edge is not capped at the travel.
    pub fn extension_band(&self, ch: usize, volts: f64) -> (f64, f64) {
        let (lo, hi) = self.limits.voltage_range[ch];
        let travel = self.mechanism.design().actuators[ch].travel;
        let u = ((volts - lo) / (hi - lo)).clamp(0.0, 1.0);
        let h = self.limits.hysteresis_bound;
        let d = self.limits.dynamic_margin;
        (travel * (u - h - d).max(-d), travel * (u + h + d))
    }

    /// Checks three voltages together; returns the worst case when they are safe.
    pub fn check(&self, volts: [f64; 3]) -> Result<WorstCase, SafetyError> {
        for (ch, v) in volts.iter().enumerate() {
            let (min, max) = self.limits.voltage_range[ch];
            if !v.is_finite() || *v < min || *v > max {
                return Err(SafetyError::Voltage {
                    channel: ACTUATOR_NAMES[ch],
                    volts: *v,
                    min,
                    max,
                });
            }
        }
        let b1 = self.extension_band(0, volts[0]);
        let b2 = self.extension_band(1, volts[1]);
        let mut worst = WorstCase {
            force: [[f64::INFINITY, f64::NEG_INFINITY]; 2],
            torque: [0.0; 2],
            j3_stress: 0.0,
        };
        for e1 in [b1.0, b1.1] {
            for e2 in [b2.0, b2.1] {
                // A stack's extension pushes the drive: Δl2 = −e (the paper's eq. 44 sign).
                let s = self
                    .mechanism
                    .state_at(&self.assembly, Vector2::new(-e1, -e2))
                    .map_err(|e| SafetyError::Model(e.to_string()))?;
                for i in 0..2 {
                    worst.force[i][0] = worst.force[i][0].min(s.force[i]);
                    worst.force[i][1] = worst.force[i][1].max(s.force[i]);
                    let t = s.fw[2 * i].hypot(s.fw[2 * i + 1]);
                    worst.torque[i] = worst.torque[i].max(t);
                }
                if let Some(y) = &self.limits.j3 {
                    worst.j3_stress = worst.j3_stress.max(y.von_mises([s.force[0], s.force[1]]));
                }
            }
        }
        let design = self.mechanism.design();
        for i in 0..2 {
            let a = &design.actuators[i];
            let name = ACTUATOR_NAMES[i];
            if -worst.force[i][0] > a.push_capacity {
                return Err(SafetyError::Force {
                    actuator: name,
                    force: worst.force[i][0],
                    capacity: a.push_capacity,
                });
            }
            if worst.force[i][1] >= 0.0 {
                return Err(SafetyError::Compression {
                    actuator: name,
                    force: worst.force[i][1],
                });
            }
            if worst.torque[i] > a.torque_limit {
                return Err(SafetyError::Torque {
                    flexure: ["J1", "J2"][i],
                    actuator: name,
                    torque: worst.torque[i],
                    limit: a.torque_limit,
                });
            }
        }
        if let Some(y) = &self.limits.j3
            && (worst.j3_stress.is_nan() || worst.j3_stress > y.allowed())
        {
            return Err(SafetyError::Yield {
                joint: y.joint,
                stress: worst.j3_stress,
                limit: y.allowed(),
            });
        }
        Ok(worst)
    }

    /// The farthest safe command from `from` towards `to` (three voltages each): `to`
    /// itself when it is safe, else the point where the straight path from `from`
    /// leaves the envelope (bisection to 1e-6 of the path). A channel whose target is
    /// not a number stays where it is. If `from` itself is unsafe, `from` is returned
    /// (the guard will refuse it). Allocates nothing.
    pub fn limit_towards(&self, from: [f64; 3], to: [f64; 3]) -> [f64; 3] {
        let mut to = to;
        for ch in 0..3 {
            if to[ch].is_nan() {
                to[ch] = from[ch];
            } else {
                let (lo, hi) = self.limits.voltage_range[ch];
                to[ch] = to[ch].clamp(lo, hi);
            }
        }
        if self.check(to).is_ok() {
            return to;
        }
        let at = |l: f64| [0, 1, 2].map(|i| from[i] + l * (to[i] - from[i]));
        if self.check(from).is_err() {
            return from;
        }
        let (mut a, mut b) = (0.0, 1.0);
        while b - a > 1e-6 {
            let m = 0.5 * (a + b);
            if self.check(at(m)).is_ok() {
                a = m
            } else {
                b = m
            }
        }
        at(a)
    }

    /// The highest voltage channel `ch` may take while the others stay at `volts`
    /// (bisection to 1 mV), or `None` if even the lowest voltage is unsafe.
    pub fn max_safe_voltage(&self, ch: usize, volts: [f64; 3]) -> Option<f64> {
        let (lo, hi) = self.limits.voltage_range[ch];
        let with = |v: f64| {
            let mut c = volts;
            c[ch] = v;
            self.check(c).is_ok()
        };
        if !with(lo) {
            return None;
        }
        if with(hi) {
            return Some(hi);
        }
        let (mut a, mut b) = (lo, hi);
        while b - a > 1e-3 {
            let m = 0.5 * (a + b);
            if with(m) { a = m } else { b = m }
        }
        Some(a)
    }
}

/// The envelope and the voltages last accepted on each channel, shared by the guards
/// of one manipulator.
#[derive(Debug)]
pub struct GuardState {
    envelope: PiezoEnvelope,
    commanded: [f64; 3],
}

impl GuardState {
    /// The envelope.
    pub fn envelope(&self) -> &PiezoEnvelope {
        &self.envelope
    }

    /// The voltages last accepted on A1, A2, A3.
    pub fn commanded(&self) -> [f64; 3] {
        self.commanded
    }
}

/// A shared [`GuardState`].
pub type SharedGuard = Arc<Mutex<GuardState>>;

/// Creates the shared state for three guarded channels starting at `commanded` volts.
pub fn shared_guard(envelope: PiezoEnvelope, commanded: [f64; 3]) -> SharedGuard {
    Arc::new(Mutex::new(GuardState {
        envelope,
        commanded,
    }))
}

/// Locks a shared guard (a poisoned lock still holds consistent state: every update is
/// one assignment).
pub fn lock(g: &SharedGuard) -> MutexGuard<'_, GuardState> {
    g.lock().unwrap_or_else(|e| e.into_inner())
}

/// A piezo channel whose commands pass the envelope first.
pub struct GuardedPiezo<C> {
    inner: C,
    channel: usize,
    guard: SharedGuard,
}

impl<C: PiezoChannel> GuardedPiezo<C> {
    /// Guards `inner`, which drives stack `channel` (0 = A1).
    pub fn new(inner: C, channel: usize, guard: SharedGuard) -> Self {
        GuardedPiezo {
            inner,
            channel,
            guard,
        }
    }

    /// The wrapped channel.
    pub fn inner(&self) -> &C {
        &self.inner
    }
}

impl<C: PiezoChannel> PiezoChannel for GuardedPiezo<C> {
    fn name(&self) -> &str {
        self.inner.name()
    }
    fn voltage_range(&self) -> (f64, f64) {
        lock(&self.guard).envelope.limits.voltage_range[self.channel]
    }
    fn set_voltage(&mut self, volts: f64) -> Result<(), HwError> {
        let mut g = lock(&self.guard);
        let mut candidate = g.commanded;
        candidate[self.channel] = volts;
        g.envelope.check(candidate)?;
        self.inner.set_voltage(volts)?;
        g.commanded = candidate;
        Ok(())
    }
    fn commanded_voltage(&self) -> f64 {
        self.inner.commanded_voltage()
    }
    fn read_voltage(&mut self) -> Result<f64, HwError> {
        self.inner.read_voltage()
    }
}

/// A stage whose moves stay within per-axis limits.
pub struct GuardedStage<S> {
    inner: S,
    limits: Vec<(f64, f64)>,
}

impl<S: Stage> GuardedStage<S> {
    /// Guards `inner` with its own travel limits, narrowed to `limits` where given.
    pub fn new(inner: S, limits: Option<Vec<(f64, f64)>>) -> Self {
        let limits = (0..inner.axes())
            .map(|a| {
                let own = inner.travel(a);
                match limits.as_ref().and_then(|l| l.get(a)) {
                    Some(&(lo, hi)) => (lo.max(own.0), hi.min(own.1)),
                    None => own,
                }
            })
            .collect();
        GuardedStage { inner, limits }
    }
}

impl<S: Stage> Stage for GuardedStage<S> {
    fn axes(&self) -> usize {
        self.inner.axes()
    }
    fn travel(&self, axis: usize) -> (f64, f64) {
        self.limits.get(axis).copied().unwrap_or((0.0, 0.0))
    }
    fn move_to(&mut self, axis: usize, position: f64) -> Result<(), HwError> {
        let (min, max) = self.travel(axis);
        if axis >= self.limits.len() || !position.is_finite() || position < min || position > max {
            return Err(SafetyError::StageTravel {
                axis,
                position,
                min,
                max,
            }
            .into());
        }
        self.inner.move_to(axis, position)
    }
    fn position(&mut self, axis: usize) -> Result<f64, HwError> {
        self.inner.position(axis)
    }
    fn is_busy(&mut self) -> Result<bool, HwError> {
        self.inner.is_busy()
    }
}

/// An injector whose pulses stay below a pressure limit.
pub struct GuardedInjector<I> {
    inner: I,
    max: f64,
}

impl<I: Injector> GuardedInjector<I> {
    /// Guards `inner` with the smaller of its own limit and `max`.
    pub fn new(inner: I, max: f64) -> Self {
        let max = max.min(inner.max_pressure());
        GuardedInjector { inner, max }
    }
}

impl<I: Injector> Injector for GuardedInjector<I> {
    fn max_pressure(&self) -> f64 {
        self.max
    }
    fn pulse(&mut self, pressure: f64, duration: f64) -> Result<(), HwError> {
        if !pressure.is_finite() || pressure > self.max || pressure < 0.0 {
            return Err(SafetyError::Pressure {
                pressure,
                max: self.max,
            }
            .into());
        }
        check_range("pulse duration", duration, 0.0, 10.0)?;
        self.inner.pulse(pressure, duration)
    }
}

/// A zoom lens kept within a magnification range.
pub struct GuardedOptics<O> {
    inner: O,
    range: (f64, f64),
}

impl<O: Optics> GuardedOptics<O> {
    /// Guards `inner` with the narrower of its own range and `range`.
    pub fn new(inner: O, range: (f64, f64)) -> Self {
        let own = inner.zoom_range();
        GuardedOptics {
            inner,
            range: (range.0.max(own.0), range.1.min(own.1)),
        }
    }
}

impl<O: Optics> Optics for GuardedOptics<O> {
    fn zoom(&self) -> f64 {
        self.inner.zoom()
    }
    fn zoom_range(&self) -> (f64, f64) {
        self.range
    }
    fn set_zoom(&mut self, zoom: f64) -> Result<(), HwError> {
        let (min, max) = self.range;
        if !zoom.is_finite() || zoom < min || zoom > max {
            return Err(SafetyError::Zoom { zoom, min, max }.into());
        }
        self.inner.set_zoom(zoom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cellinject_model::prototype;

    fn envelope(approach: Approach) -> PiezoEnvelope {
        PiezoEnvelope::new(
            Mechanism::new(&prototype()).unwrap(),
            approach,
            EnvelopeLimits {
                voltage_range: [(0.0, 100.0); 3],
                hysteresis_bound: 0.0,
                dynamic_margin: 0.0,
                j3: None,
            },
        )
        .unwrap()
    }

    #[test]
    fn approach_1_full_stroke_exceeds_the_torque_limit_and_is_refused() {
        // Without any margin the band is the nominal extension: 30 µm at 100 V gives
        // the torque of the paper's working point, 0.3534 N*m > 0.35 N*m.
        let e = envelope(Approach::DriveTranslation);
        let err = e.check([100.0, 100.0, 0.0]).unwrap_err();
        assert!(
            matches!(err, SafetyError::Torque { flexure, torque, .. } if flexure == "J1" && (torque - 0.3534).abs() < 1e-3),
            "{err}"
        );
        assert!(e.check([0.0, 0.0, 0.0]).is_ok());
        // The limit lies where the torque, affine in the extension, reaches 0.35 N*m.
        let t0 = 0.316434; // N*m at 0 µm (eq. 43)
        let t30 = 0.353413; // N*m at 30 µm
        let v_lim = 100.0 * (0.35 - t0) / (t30 - t0);
        let v = e.max_safe_voltage(0, [0.0, 0.0, 0.0]).unwrap();
        assert!((v - v_lim).abs() < 0.05, "{v} vs {v_lim}");
    }

    #[test]
    fn a_command_past_the_envelope_is_shortened_to_its_edge() {
        let e = envelope(Approach::DriveTranslation);
        let v = e.limit_towards([0.0; 3], [100.0, 100.0, 0.0]);
        assert!(e.check(v).is_ok());
        assert!(
            (v[0] - v[1]).abs() < 1e-9 && v[0] > 50.0 && v[0] < 100.0,
            "{v:?}"
        );
        // Just past the edge along the same path is refused.
        assert!(e.check([v[0] + 0.01, v[1] + 0.01, 0.0]).is_err());
        // Out-of-range and NaN targets.
        let w = e.limit_towards([10.0, 10.0, 0.0], [f64::NAN, -5.0, 500.0]);
        assert_eq!(w, [10.0, 0.0, 100.0]);
    }

    #[test]
    fn approach_2_allows_the_full_stroke() {
        let e = envelope(Approach::JointDeflection);
        assert!(e.check([100.0, 100.0, 100.0]).is_ok());
        assert!(matches!(
            e.check([100.1, 0.0, 0.0]),
            Err(SafetyError::Voltage { .. })
        ));
        assert!(matches!(
            e.check([f64::NAN, 0.0, 0.0]),
            Err(SafetyError::Voltage { .. })
        ));
    }

    #[test]
    fn a_lower_push_capacity_is_enforced() {
        let mut d = prototype();
        d.actuators[0].push_capacity = 105.0;
        let e = PiezoEnvelope::new(
            Mechanism::new(&d).unwrap(),
            Approach::JointDeflection,
            EnvelopeLimits {
                voltage_range: [(0.0, 100.0); 3],
                hysteresis_bound: 0.0,
                dynamic_margin: 0.0,
                j3: None,
            },
        )
        .unwrap();
        // 100 N at 0 V, 111.7 N at 100 V: the limit is crossed near 43 V.
        assert!(e.check([30.0, 0.0, 0.0]).is_ok());
        assert!(matches!(
            e.check([60.0, 0.0, 0.0]),
            Err(SafetyError::Force { .. })
        ));
    }
}
