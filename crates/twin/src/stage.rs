//! The macro stage M1-M3: trapezoidal moves within speed and acceleration limits, a
//! decaying residual vibration while it settles, 0.1 µm encoders.

use crate::params::StageParams;

/// One planned move of one axis.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Move {
    t0: f64,
    from: f64,
    to: f64,
    /// Duration of the acceleration phase.
    t_acc: f64,
    /// Duration at constant speed.
    t_flat: f64,
    peak: f64,
}

impl Move {
    fn plan(t0: f64, from: f64, to: f64, v: f64, a: f64) -> Self {
        let d = (to - from).abs();
        let (t_acc, t_flat, peak) = if d <= v * v / a {
            let ta = (d / a).sqrt();
            (ta, 0.0, a * ta)
        } else {
            (v / a, d / v - v / a, v)
        };
        Move {
            t0,
            from,
            to,
            t_acc,
            t_flat,
            peak,
        }
    }

    fn duration(&self) -> f64 {
        2.0 * self.t_acc + self.t_flat
    }

    /// Distance travelled after `t` seconds (0 ≤ t ≤ duration).
    fn travelled(&self, t: f64) -> f64 {
        let a = if self.t_acc > 0.0 {
            self.peak / self.t_acc
        } else {
            0.0
        };
        let d_acc = 0.5 * self.peak * self.t_acc;
        if t <= self.t_acc {
            0.5 * a * t * t
        } else if t <= self.t_acc + self.t_flat {
            d_acc + self.peak * (t - self.t_acc)
        } else {
            let td = (t - self.t_acc - self.t_flat).min(self.t_acc);
            d_acc + self.peak * self.t_flat + self.peak * td - 0.5 * a * td * td
        }
    }

    fn position(&self, t: f64) -> f64 {
        let s = (t - self.t0).clamp(0.0, self.duration());
        let dir = if self.to >= self.from { 1.0 } else { -1.0 };
        if s >= self.duration() {
            self.to
        } else {
            self.from + dir * self.travelled(s)
        }
    }
}

/// The simulated stage.
#[derive(Debug, Clone)]
pub struct StageSim {
    p: StageParams,
    travel: f64,
    moves: [Move; 3],
    time: f64,
    stalled: bool,
}

impl StageSim {
    /// A stage at rest at the origin, `travel` metres per axis (the rig's), centred on 0.
    pub fn new(p: StageParams, travel: f64) -> Self {
        StageSim {
            p,
            travel,
            moves: [Move::plan(0.0, 0.0, 0.0, 1.0, 1.0); 3],
            time: 0.0,
            stalled: false,
        }
    }

    /// Parameters.
    pub fn params(&self) -> &StageParams {
        &self.p
    }

    /// Travel limits of each axis.
    pub fn travel(&self) -> (f64, f64) {
        (-0.5 * self.travel, 0.5 * self.travel)
    }

    /// Moves the clock.
    pub fn advance_to(&mut self, t: f64) {
        self.time = t;
    }

    /// True position of an axis now, residual vibration included.
    pub fn true_position(&self, axis: usize) -> f64 {
        let m = &self.moves[axis];
        let end = m.t0 + m.duration();
        let mut x = m.position(self.time);
        if self.time > end && m.from != m.to {
            let s = self.time - end;
            let tau = self.p.settling_time / 4.0;
            let f = 4.0 / self.p.settling_time;
            x += self.p.settling_amplitude
                * (-s / tau).exp()
                * (2.0 * std::f64::consts::PI * f * s).sin();
        }
        x
    }

    /// Encoder reading of an axis (quantised to the encoder resolution).
    pub fn encoder(&self, axis: usize) -> f64 {
        let r = self.p.encoder_resolution;
        (self.true_position(axis) / r).round() * r
    }

    /// Starts a move (the caller checks the travel).
    pub fn move_to(&mut self, axis: usize, position: f64) {
        if self.stalled {
            return;
        }
        let from = self.true_position(axis);
        self.moves[axis] = Move::plan(
            self.time,
            from,
            position,
            self.p.max_speed,
            self.p.max_accel,
        );
    }

    /// Whether any axis is moving or settling.
    pub fn busy(&self) -> bool {
        self.stalled
            || self
                .moves
                .iter()
                .any(|m| m.from != m.to && self.time < m.t0 + m.duration() + self.p.settling_time)
    }

    /// Puts an axis at `position` at once, at rest (the bench's initial condition).
    pub fn place(&mut self, axis: usize, position: f64) {
        self.moves[axis] = Move::plan(self.time, position, position, 1.0, 1.0);
    }

    /// Jams the stage (a fault of the twin): it accepts moves but never starts them and
    /// stays busy.
    pub fn stall(&mut self) {
        self.stalled = true;
    }

    /// When the last axis will have settled.
    pub fn settled_at(&self) -> f64 {
        self.moves
            .iter()
            .map(|m| {
                m.t0 + m.duration()
                    + if m.from != m.to {
                        self.p.settling_time
                    } else {
                        0.0
                    }
            })
            .fold(self.time, f64::max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trapezoidal_move_respects_limits_and_arrives() {
        let p = StageParams::default();
        let mut s = StageSim::new(p, 0.025);
        s.move_to(0, 5e-3);
        // 5 mm at 2 mm/s with 20 mm/s²: 2.5 s + 0.1 s.
        let m = s.moves[0];
        assert!((m.duration() - (5e-3 / p.max_speed + p.max_speed / p.max_accel)).abs() < 1e-12);
        let mut last = 0.0;
        let dt = 1e-3;
        let mut t = 0.0;
        while t < m.duration() {
            t += dt;
            s.advance_to(t);
            let x = m.position(t);
            assert!((x - last) / dt <= p.max_speed * (1.0 + 1e-9));
            last = x;
        }
        assert!(s.busy());
        s.advance_to(t + p.settling_time + 1e-3);
        assert!(!s.busy());
        assert!((s.encoder(0) - 5e-3).abs() <= 0.5 * p.encoder_resolution + 1e-15);
        // Encoder steps of 0.1 µm.
        let e = s.encoder(0) / p.encoder_resolution;
        assert!((e - e.round()).abs() < 1e-6);
    }

    #[test]
    fn short_moves_are_triangular() {
        let m = Move::plan(0.0, 0.0, 1e-6, 2e-3, 2e-2);
        assert_eq!(m.t_flat, 0.0);
        assert!((m.position(m.duration()) - 1e-6).abs() < 1e-18);
        assert!((m.position(0.5 * m.duration()) - 0.5e-6).abs() < 1e-15);
    }
}
