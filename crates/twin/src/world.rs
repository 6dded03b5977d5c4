//! The simulated world: three stacks, the mechanism's dynamics, the spherical joints'
//! stick-slip, the macro stage and the injector, advanced together at a fixed step on a
//! simulated clock.

use cellinject_model::{Approach, Assembly, Mechanism, ModelError};
use nalgebra::{Matrix2, Matrix4, Matrix4x2, Vector2, Vector3, Vector4};
use thiserror::Error;

use crate::dynamics::{Oscillator, TiltDynamics};
use crate::piezo::Stack;
use crate::stage::StageSim;
use cellinject_numeric::Rng;
use cellinject_rig::RigParams;
use cellinject_simparams::SimParams;

/// Random streams, one per process, so that adding one never changes another.
pub(crate) mod stream {
    pub const AMPLIFIER: u64 = 1;
    pub const JOINTS: u64 = 2;
    pub const CAMERA: u64 = 3;
    pub const SCENE: u64 = 4;
    /// A1's sensor; A2's and A3's follow.
    pub const SENSOR: u64 = 5;
    /// The side camera's noise (after A3's sensor, 7).
    pub const SIDE_CAMERA: u64 = 8;
    /// The side view's background and marker.
    pub const SIDE_SCENE: u64 = 9;
    /// The top view's scene when it comes from a plate file.
    pub const PLATE_SCENE: u64 = 10;
    /// The plate's cells' puncture thresholds.
    pub const BIOLOGY: u64 = 11;
    /// The injector's pulse-to-pulse scatter.
    pub const PULSES: u64 = 12;
    /// A live display's copy of the microscope ([`crate::Twin::view_camera`]).
    pub const VIEW: u64 = 13;
    /// A loaded plate's floor (its tilt and bow).
    pub const SURFACE: u64 = 14;
}

/// Why a twin could not be built.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum TwinError {
    /// The mechanism model refused the design.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// A twin parameter is out of its domain.
    #[error("key `{key}`: {reason}")]
    Invalid {
        /// Description-file key.
        key: String,
        /// What is wrong.
        reason: String,
    },
}

/// Everything observable about the mechanism at one instant (SI units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Snapshot {
    /// s, simulated time.
    pub time: f64,
    /// V, amplifier outputs (noise-free) of A1, A2, A3.
    pub voltage: [f64; 3],
    /// m, free extensions of the stacks.
    pub extension: [f64; 3],
    /// rad, J3 angles q1, q2; m, A3 position q3.
    pub q: Vector3<f64>,
    /// rad/s and m/s.
    pub q_dot: Vector3<f64>,
    /// m, end-effector displacement from its home (untensioned) position.
    pub x: Vector3<f64>,
    /// N, stack forces of A1, A2 (compression negative).
    pub force: Vector2<f64>,
    /// N·m, torques in J3 (eq. 18).
    pub fq: Vector2<f64>,
    /// N·m, torques in J1, J2 (eq. 17).
    pub fw: Vector4<f64>,
    /// m, drive displacement imposed on A1, A2 (l_r of the dynamics).
    pub imposed: Vector2<f64>,
    /// m, effective displacement along the drives δl = L q.
    pub dl: Vector2<f64>,
    /// m, the stick-slip error currently in each drive.
    pub joint_error: [f64; 2],
}

#[derive(Debug, Clone, Copy, Default)]
struct Joint {
    /// Re-stick angle, rad.
    phi: f64,
    /// Body 1's static pose when the joint last stuck, rad.
    stuck_at: Vector2<f64>,
}

impl From<&Snapshot> for cellinject_model::Statics {
    /// The model's view of a snapshot (`cellinject_model::statics`): A3 carries no
    /// preload, so its force and J3's third torque are 0.
    fn from(s: &Snapshot) -> Self {
        cellinject_model::Statics {
            force: Vector3::new(s.force[0], s.force[1], 0.0),
            fq: Vector3::new(s.fq[0], s.fq[1], 0.0),
            fw: s.fw,
            dx: s.x,
        }
    }
}

/// A pressure pulse applied by the injector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pulse {
    /// s, start.
    pub time: f64,
    /// Pa.
    pub pressure: f64,
    /// s.
    pub duration: f64,
    /// m³, volume delivered.
    pub volume: f64,
}

/// Everything the twin needs besides the mechanism design: the bench as built (the
/// rig's description, shared with real hardware) and what only a simulation has.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TwinParams {
    /// The physical bench: approach, amplifier ranges, margins, travels, limits, zoom.
    pub rig: RigParams,
    /// Noise, hysteresis, creep, dynamics, stick-slip, camera sensor, scene.
    pub sim: SimParams,
}

/// The twin's physics.
#[derive(Debug, Clone)]
pub struct World {
    params: TwinParams,
    mechanism: Mechanism,
    assembly: Assembly,
    dt: f64,
    steps: u64,
    stacks: [Stack; 3],
    tilt: TiltDynamics,
    a3: Oscillator,
    kq: Matrix2<f64>,
    kw: Matrix4<f64>,
    kl: Matrix2<f64>,
    lp: Matrix2<f64>,
    wp: Matrix4x2<f64>,
    jp: Matrix2<f64>,
    kw_diag: [f64; 4],
    kl_diag: [f64; 2],
    /// Kq q_r, the generalised force of J3's assembly deflection.
    f_rest: Vector2<f64>,
    /// Static pose for zero drive displacement, and its gain: q_static = q0 + G·l.
    q_static0: Vector2<f64>,
    static_gain: Matrix2<f64>,
    a3_omega2: f64,
    q_rest: Vector2<f64>,
    l_base: Vector2<f64>,
    /// Lᵀ Kl, maps imposed drive displacements to generalised forces.
    lt_kl: Matrix2<f64>,
    joints: [Joint; 2],
    /// Stick-slip drive errors in use (see `step`).
    joint_cache: Vector2<f64>,
    /// s that passed with the bench idle beyond the simulated steps (the ambient
    /// temperature's clock runs on by them: [`World::let_time_pass`]).
    idle: f64,
    joint_pose: Vector2<f64>,
    joint_dirty: bool,
    q_static: Vector2<f64>,
    noise: Rng,
    joint_rng: Rng,
    /// The macro stage.
    pub stage: StageSim,
    /// The feeder stage carrying the plate: axis 0 moves it along plate x, axis 1
    /// along plate y, axis 2 along the optical axis (the plate's focus).
    pub feeder: StageSim,
    pulses: Vec<Pulse>,
}

impl World {
    /// Builds the twin of a design, assembled and at rest at 0 V.
    pub fn new(design: &cellinject_model::Design, params: TwinParams) -> Result<Self, TwinError> {
        let invalid = |key: &str, reason: &str| TwinError::Invalid {
            key: key.to_string(),
            reason: reason.to_string(),
        };
        let d = &params.sim.dynamics;
        if !(d.rate >= 20_000.0 && d.rate.is_finite()) {
            return Err(invalid("dynamics.rate", "must be at least 20000 Hz"));
        }
        if !(d.damping_ratio > 0.0 && d.damping_ratio < 1.0) {
            return Err(invalid("dynamics.damping_ratio", "must lie in (0, 1)"));
        }
        let mechanism = Mechanism::new(design)?;
        let assembly = mechanism.assembly(params.rig.approach)?;
        let dt = 1.0 / d.rate;
        let stacks = [0, 1, 2].map(|i| {
            Stack::new(
                &params.sim.stacks[i],
                params.rig.amplifiers[i].v_max,
                design.actuators[i].travel,
                dt,
            )
        });
        let (kq, kw, kl, lp, wp, jp) = (
            mechanism.kq(),
            mechanism.kw(),
            mechanism.kl(),
            mechanism.lp(),
            mechanism.wp(),
            mechanism.jp(),
        );
        let k = mechanism.joint_stiffness() + lp.transpose() * kl * lp;
        let k_inv = k
            .try_inverse()
            .ok_or_else(|| invalid("flexures", "the structure's stiffness matrix is singular"))?;
        let (q_rest, l_base) = match params.rig.approach {
            Approach::DriveTranslation => (Vector2::zeros(), assembly.dl0),
            Approach::JointDeflection => (-assembly.dq0, Vector2::zeros()),
        };
        let lt_kl = lp.transpose() * kl;
        let f0 = kq * q_rest + lt_kl * l_base;
        // The structural model's tilt frequencies, when given, set the inertias.
        let inertia = match d.tilt_frequencies {
            Some(f) => {
                if !f.iter().all(|f| f.is_finite() && *f > 0.0) {
                    return Err(invalid(
                        "dynamics.tilt_frequencies",
                        "must be positive frequencies",
                    ));
                }
                [0, 1].map(|i| k[(i, i)] / (2.0 * std::f64::consts::PI * f[i]).powi(2))
            }
            None => d.inertia,
        };
        let mut tilt = TiltDynamics::new(inertia, &k, d.damping_ratio, dt);
        tilt.settle(&f0);
        let a3_omega = (d.a3_stiffness / d.a3_mass).sqrt();
        let a3 = Oscillator::new(a3_omega, d.damping_ratio, dt);
        Ok(World {
            stage: StageSim::new(params.sim.stage, params.rig.stage_travel),
            feeder: StageSim::new(params.sim.feeder_stage, params.rig.feeder_travel),
            params,
            mechanism,
            assembly,
            dt,
            steps: 0,
            stacks,
            tilt,
            a3,
            kq,
            kw,
            kl,
            lp,
            wp,
            jp,
            kw_diag: [kw[(0, 0)], kw[(1, 1)], kw[(2, 2)], kw[(3, 3)]],
            kl_diag: [kl[(0, 0)], kl[(1, 1)]],
            f_rest: kq * q_rest,
            q_static0: k_inv * (kq * q_rest),
            static_gain: k_inv * lt_kl,
            a3_omega2: a3_omega * a3_omega,
            q_rest,
            l_base,
            lt_kl,
            joints: [Joint {
                phi: 0.0,
                stuck_at: k_inv * f0,
            }; 2],
            joint_cache: Vector2::zeros(),
            idle: 0.0,
            joint_pose: k_inv * f0,
            joint_dirty: false,
            q_static: k_inv * f0,
            noise: Rng::new(params.sim.seed, stream::AMPLIFIER),
            joint_rng: Rng::new(params.sim.seed, stream::JOINTS),
            pulses: Vec::new(),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &TwinParams {
        &self.params
    }

    /// The mechanism model the twin is built on.
    pub fn mechanism(&self) -> &Mechanism {
        &self.mechanism
    }

    /// How it was assembled.
    pub fn assembly(&self) -> &Assembly {
        &self.assembly
    }

    /// s, integration step.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// s, simulated time.
    pub fn time(&self) -> f64 {
        self.steps as f64 * self.dt
    }

    /// Natural frequencies of the tilt modes and of the injection axis, Hz.
    pub fn natural_frequencies(&self) -> [f64; 3] {
        let tau = 2.0 * std::f64::consts::PI;
        let d = &self.params.sim.dynamics;
        [
            self.tilt.omega[0] / tau,
            self.tilt.omega[1] / tau,
            (d.a3_stiffness / d.a3_mass).sqrt() / tau,
        ]
    }

    /// Commands an amplifier channel (no safety check here: see `cellinject_hw::safety`).
    pub fn set_voltage(&mut self, ch: usize, volts: f64) {
        self.stacks[ch].amplifier.set(volts);
    }

    /// The last command of a channel.
    pub fn commanded_voltage(&self, ch: usize) -> f64 {
        self.stacks[ch].amplifier.command()
    }

    /// A channel's amplifier output, V.
    pub fn output_voltage(&self, ch: usize) -> f64 {
        self.stacks[ch].amplifier.output()
    }

    /// The drive displacement imposed on A1, A2 by the assembly, the stacks and
    /// temperature (without the joints' stick-slip).
    #[inline]
    fn imposed_by_drives(&self) -> Vector2<f64> {
        let thermal = self.params.sim.thermal.expansion * self.delta_t(self.time());
        // A stack's extension pushes the drive: Δl2 = −e (the paper's eq. 44 sign).
        Vector2::new(
            self.l_base[0] - self.stacks[0].extension() - thermal,
            self.l_base[1] - self.stacks[1].extension() - thermal,
        )
    }

    /// The stick-slip error of each drive at the static pose `q`: the eccentricity of the ball's
    /// seat (bending torque over axial force, capped at the ball radius) times its
    /// re-stick angle.
    #[inline]
    fn joint_errors(&self, q: &Vector2<f64>, drives: &Vector2<f64>) -> Vector2<f64> {
        let mut out = Vector2::zeros();
        if self.joints[0].phi == 0.0 && self.joints[1].phi == 0.0 {
            return out;
        }
        let dl = self.lp * q;
        let w = self.wp * q;
        for i in 0..2 {
            let f = (self.kl_diag[i] * (drives[i] - dl[i])).abs();
            let (ta, tb) = (
                self.kw_diag[2 * i] * w[2 * i],
                self.kw_diag[2 * i + 1] * w[2 * i + 1],
            );
            let torque = (ta * ta + tb * tb).sqrt();
            let ball = self.params.sim.joints.ball_radius;
            let ecc = if f > 0.0 {
                (torque / f).min(ball)
            } else {
                ball
            };
            out[i] = ecc * self.joints[i].phi;
        }
        out
    }

    /// Advances one integration step.
    #[inline]
    pub fn step(&mut self) {
        let g = self.noise.gaussian4();
        for i in 0..3 {
            self.stacks[i].step(g[i] as f64);
        }
        self.steps += 1;
        let drives = self.imposed_by_drives();
        // Stick-slip: a joint breaks free when the commanded (static) pose has turned it
        // by `slip_rotation` away from where it last stuck (the net relative rotation of
        // its ball in the socket: the sum over body 1's two tilts and the flexure's two
        // bending angles), and re-sticks there at a new angle. Motion that stays
        // closer to the stick point (vibration, noise, a servo's small corrections) is
        // taken elastically by the contact (pre-sliding) and slips nothing.
        let q_static = self.q_static0 + self.static_gain * drives;
        if q_static != self.q_static {
            self.q_static = q_static;
            let jp = self.params.sim.joints;
            for i in 0..2 {
                let j = &mut self.joints[i];
                let dq = q_static - j.stuck_at;
                let dw = self.wp * dq;
                let turned = dq[0].abs() + dq[1].abs() + dw[2 * i].abs() + dw[2 * i + 1].abs();
                if turned >= jp.slip_rotation {
                    j.stuck_at = q_static;
                    j.phi = self
                        .joint_rng
                        .range(-jp.stick_slip_angle, jp.stick_slip_angle);
                    self.joint_dirty = true;
                }
            }
        }
        // The seat's eccentricity follows the quasi-static torque and force (not the
        // vibration): re-evaluated when a joint re-sticks or the static pose has moved
        // by more than 1e-7 rad since the last evaluation.
        let moved = (q_static - self.joint_pose).abs().max() > 1e-7;
        if self.joint_dirty || moved {
            self.joint_cache = self.joint_errors(&q_static, &drives);
            self.joint_pose = q_static;
            self.joint_dirty = false;
        }
        let imposed = drives + self.joint_cache;
        let f = self.f_rest + self.lt_kl * imposed;
        self.tilt.step(&f);
        self.a3.step(self.a3_omega2 * self.stacks[2].extension());
        self.stage.advance_to(self.time());
        self.feeder.advance_to(self.time());
    }

    /// Advances until simulated time `t` (to the nearest step).
    pub fn advance_to(&mut self, t: f64) {
        let target = (t / self.dt).round() as u64;
        while self.steps < target {
            self.step();
        }
    }

    /// Advances by `seconds`.
    pub fn advance(&mut self, seconds: f64) {
        self.advance_to(self.time() + seconds);
    }

    /// K, the ambient temperature's change since the start at simulated time `t`,
    /// counting the time let pass idle ([`World::let_time_pass`]).
    pub fn delta_t(&self, t: f64) -> f64 {
        self.params.sim.thermal.delta_t(t + self.idle)
    }

    /// Lets `seconds` pass with the bench idle (hours between two runs of a
    /// session): the ambient temperature runs on by all of it (the drives expand, the
    /// magnification and the stacks' sensors drift as after `seconds` of the lab's
    /// warming), and one minute of it is simulated (the clock, [`World::time`],
    /// advances by that minute; the stacks' creep goes on for that minute only).
    pub fn let_time_pass(&mut self, seconds: f64) {
        let settle = seconds.min(60.0);
        self.idle += seconds - settle;
        self.advance(settle);
    }

    /// The free extension of stack `ch`, m (what [`World::snapshot`] lists, without
    /// computing the rest).
    pub fn extension(&self, ch: usize) -> f64 {
        self.stacks[ch].extension()
    }

    /// The state now.
    pub fn snapshot(&self) -> Snapshot {
        let q2 = self.tilt.q();
        let qd2 = self.tilt.q_dot();
        let drives = self.imposed_by_drives();
        let joint = self.joint_cache;
        let imposed = drives + joint;
        let dl = self.lp * q2;
        let force = self.kl * (imposed - dl);
        let fq = self.kq * (q2 - self.q_rest);
        let fw = self.kw * (self.wp * q2);
        let x2 = self.jp * q2;
        Snapshot {
            time: self.time(),
            voltage: [0, 1, 2].map(|i| self.stacks[i].amplifier.output()),
            extension: [0, 1, 2].map(|i| self.stacks[i].extension()),
            q: Vector3::new(q2[0], q2[1], self.a3.x),
            q_dot: Vector3::new(qd2[0], qd2[1], self.a3.v),
            x: Vector3::new(x2[0], x2[1], self.a3.x),
            force,
            fq,
            fw,
            imposed,
            dl,
            joint_error: [joint[0], joint[1]],
        }
    }

    /// Relative residual of the equilibrium (19) in a snapshot (see
    /// [`Mechanism::equilibrium_residual_of`]).
    pub fn equilibrium_residual(&self, s: &Snapshot) -> f64 {
        let v3 = |v: &Vector2<f64>| Vector3::new(v[0], v[1], 0.0);
        self.mechanism
            .equilibrium_residual_of(&v3(&s.fq), &s.fw, &v3(&s.force))
    }

    /// Records an injector pulse that delivered `volume` m³ (the twin computes the
    /// flow; see `Twin::pulse`).
    pub fn record_pulse(&mut self, pressure: f64, duration: f64, volume: f64) {
        self.pulses.push(Pulse {
            time: self.time(),
            pressure,
            duration,
            volume,
        });
    }

    /// Pulses applied so far.
    pub fn pulses(&self) -> &[Pulse] {
        &self.pulses
    }
}
