//! Pre-tensioning of the parallel structure with the constant-Jacobian
//! pseudo-rigid-body model (paper Sec. 2.1, eqs. 14-26, and Sec. 2.2, eqs. 27-33).
//!
//! The paper writes its stiffness matrices as `diag(k, k, 0)`: the third axis is the
//! serial injection axis A3, which has neither a flexure nor a preload. Those matrices
//! are singular, so the equations are evaluated on the two tilt axes (q1, q2 and
//! actuators A1, A2), after checking that A3 is kinematically decoupled from them; A3
//! carries no force and its coordinate passes straight through (`l3 = q3 = X3`).

use nalgebra::{Matrix2, Matrix4, Matrix4x2, Vector2, Vector3, Vector4};

use crate::design::{ACTUATOR_NAMES, Design};
use crate::error::ModelError;
use crate::kinematics::{Jacobians, Kinematics, rcond};

/// The two ways of pre-tensioning the stacks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Approach {
    /// Assembly translation Δl0 along the drive axes (Sec. 2.1).
    DriveTranslation,
    /// Assembly deflection Δq0 of the main-chain flexure J3 (Sec. 2.2).
    JointDeflection,
}

impl Approach {
    /// The paper's number for the approach (1 or 2).
    pub fn number(self) -> u8 {
        match self {
            Approach::DriveTranslation => 1,
            Approach::JointDeflection => 2,
        }
    }

    /// The approach with the paper's number, if any.
    pub fn from_number(n: u8) -> Option<Self> {
        match n {
            1 => Some(Approach::DriveTranslation),
            2 => Some(Approach::JointDeflection),
            _ => None,
        }
    }
}

/// The static state of the structure for one set of actuator shifts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct State {
    /// N, actuator forces F_l (eq. 16); compression is negative.
    pub force: Vector3<f64>,
    /// m, elastic deformation of the actuators Δl1 (eq. 21).
    pub dl1: Vector3<f64>,
    /// m, resultant displacement along the drive axes δl (eqs. 15, 27).
    pub dl: Vector3<f64>,
    /// rad, deflection of the main-chain joints from their unstressed angle
    /// (δq for approach 1, Δq0 + δq for approach 2, eqs. 11, 28).
    pub dq_spring: Vector3<f64>,
    /// rad, passive-joint deflections δw (eq. 13).
    pub dw: Vector4<f64>,
    /// m, end-effector displacement δX from its home position (eqs. 12, 25, 33).
    pub dx: Vector3<f64>,
    /// N·m, torques in the flexure J3 (eqs. 18, 29).
    pub fq: Vector3<f64>,
    /// N·m, torques in the flexures J1 and J2 (eq. 17).
    pub fw: Vector4<f64>,
}

/// Safety margins of a pre-tension over the whole working range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Margins {
    /// N, per actuator A1, A2: the least and the most compressive force over the range.
    pub force_range: [[f64; 2]; 2],
    /// N, per actuator: how far the force stays from zero (positive = always compressed).
    pub compression_margin: [f64; 2],
    /// N, per actuator: push capacity minus the largest compressive force.
    pub capacity_margin: [f64; 2],
    /// N·m, per flexure J1, J2: the largest bending torque passed to its actuator.
    pub torque_max: [f64; 2],
    /// N·m, per actuator: torque limit minus `torque_max`.
    pub torque_margin: [f64; 2],
    /// m, length of the end-effector's offset from home after tensioning.
    pub offset: f64,
}

impl Margins {
    /// Human-readable warnings for every margin that is violated.
    pub fn warnings(&self, design: &Design) -> Vec<String> {
        let mut out = Vec::new();
        for i in 0..2 {
            let name = ACTUATOR_NAMES[i];
            if self.compression_margin[i] <= 0.0 {
                out.push(format!(
                    "{name} loses compression in the working range (force reaches {:.3} N): backlash returns",
                    self.force_range[i][1]
                ));
            }
            if self.capacity_margin[i] < 0.0 {
                out.push(format!(
                    "{name} force {:.3} N exceeds its push capacity {} N",
                    self.force_range[i][0], design.actuators[i].push_capacity
                ));
            }
            if self.torque_margin[i] < 0.0 {
                out.push(format!(
                    "J{} bending torque {:.4} N*m exceeds the torque limit {} N*m of {name}",
                    i + 1,
                    self.torque_max[i],
                    design.actuators[i].torque_limit
                ));
            }
        }
        out
    }
}

/// Result of a pre-tension analysis: every quantity of Sec. 3.2.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tension {
    /// Which approach.
    pub approach: Approach,
    /// m, assembly translation Δl0 along the drive axes (approach 1, eq. 22 at Δl2 = 0).
    pub dl0: Option<Vector3<f64>>,
    /// rad, assembly deflection Δq0 of J3 (approach 2, eq. 31 at Δl2 = 0).
    pub dq0: Option<Vector3<f64>>,
    /// m, working shifts Δl2 (eq. 44).
    pub dl2: Vector3<f64>,
    /// m, Δl = Δl0 + Δl2 at the working shift (approach 1, eq. 14).
    pub dl_total: Option<Vector3<f64>>,
    /// State after tensioning, actuators inactive.
    pub tensioned: State,
    /// State at the working shift.
    pub work: State,
    /// m, working range χ: |δX − δX_work| on the tilt axes, A3's travel on axis 3.
    pub chi: Vector3<f64>,
    /// Margins over the working range.
    pub margins: Margins,
}

impl Tension {
    /// Every quantity by its name in the paper's notation (and in the `tension` JSON
    /// output), SI units, vectors of 3 (axis 3 = A3) except `Fw`/`Fw_work` (4: J1 axis 1,
    /// J1 axis 2, J2 axis 1, J2 axis 2). `dl0` and `dl_total` exist for approach 1 only,
    /// `dq0` for approach 2 only.
    pub fn quantities(&self) -> Vec<(&'static str, Vec<f64>)> {
        let v = |x: &Vector3<f64>| x.as_slice().to_vec();
        let w = |x: &Vector4<f64>| x.as_slice().to_vec();
        let mut out = vec![("F10", v(&self.tensioned.force))];
        if let Some(dl0) = &self.dl0 {
            out.push(("dl0", v(dl0)));
        }
        if let Some(dq0) = &self.dq0 {
            out.push(("dq0", v(dq0)));
        }
        out.extend([
            ("dl1", v(&self.tensioned.dl1)),
            ("dl", v(&self.tensioned.dl)),
            ("dX", v(&self.tensioned.dx)),
            ("Fq", v(&self.tensioned.fq)),
            ("Fw", w(&self.tensioned.fw)),
            ("dl2", v(&self.dl2)),
        ]);
        if let Some(t) = &self.dl_total {
            out.push(("dl_total", v(t)));
        }
        out.extend([
            ("F_work", v(&self.work.force)),
            ("dl1_work", v(&self.work.dl1)),
            ("dl_work", v(&self.work.dl)),
            ("dX_work", v(&self.work.dx)),
            ("Fq_work", v(&self.work.fq)),
            ("Fw_work", w(&self.work.fw)),
            ("chi", v(&self.chi)),
        ]);
        out
    }

    /// One quantity of [`Tension::quantities`] by name.
    pub fn quantity(&self, key: &str) -> Option<Vec<f64>> {
        self.quantities()
            .into_iter()
            .find(|(k, _)| *k == key)
            .map(|(_, v)| v)
    }
}

/// How the structure was assembled: the offset that pre-tensions it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Assembly {
    /// Which approach.
    pub approach: Approach,
    /// m, assembly translation Δl0 of A1, A2 (zero for approach 2).
    pub dl0: Vector2<f64>,
    /// rad, assembly deflection Δq0 of J3 (zero for approach 1).
    pub dq0: Vector2<f64>,
}

/// A validated design with its kinematics and constant Jacobians.
#[derive(Debug, Clone)]
pub struct Mechanism {
    design: Design,
    kinematics: Kinematics,
    jacobians: Jacobians,
}

fn embed2(v: &Vector2<f64>) -> Vector3<f64> {
    Vector3::new(v[0], v[1], 0.0)
}

impl Mechanism {
    /// Validates the design and derives its Jacobians from the nonlinear kinematics.
    pub fn new(design: &Design) -> Result<Self, ModelError> {
        design.validate()?;
        let kinematics = Kinematics::new(&design.geometry);
        let jacobians = kinematics.jacobians()?;
        let m = Mechanism {
            design: *design,
            kinematics,
            jacobians,
        };
        let coupling = [
            jacobians.l[(0, 2)].abs() / design.geometry.b1,
            jacobians.l[(1, 2)].abs() / design.geometry.b1,
            jacobians.l[(2, 0)].abs() / design.geometry.b1,
            jacobians.l[(2, 1)].abs() / design.geometry.b1,
            jacobians.w.column(2).amax() * design.geometry.b1,
        ]
        .into_iter()
        .fold(0.0, f64::max);
        if coupling > 1e-12 {
            return Err(ModelError::CoupledInjectionAxis { coupling });
        }
        let rl = rcond(&m.lp());
        if rl < 1e-9 {
            return Err(ModelError::SingularJacobian {
                matrix: "L",
                rcond: rl,
            });
        }
        let rj = rcond(&m.jp());
        if rj < 1e-9 {
            return Err(ModelError::SingularJacobian {
                matrix: "J",
                rcond: rj,
            });
        }
        Ok(m)
    }

    /// The design.
    pub fn design(&self) -> &Design {
        &self.design
    }

    /// The nonlinear kinematics.
    pub fn kinematics(&self) -> &Kinematics {
        &self.kinematics
    }

    /// The constant Jacobians J, L, W (eqs. 5-7) at the home pose.
    pub fn jacobians(&self) -> &Jacobians {
        &self.jacobians
    }

    /// Tilt block of J.
    pub fn jp(&self) -> Matrix2<f64> {
        self.jacobians.j.fixed_view::<2, 2>(0, 0).into_owned()
    }
    /// Tilt block of L.
    pub fn lp(&self) -> Matrix2<f64> {
        self.jacobians.l.fixed_view::<2, 2>(0, 0).into_owned()
    }
    /// Tilt columns of W.
    pub fn wp(&self) -> Matrix4x2<f64> {
        self.jacobians.w.fixed_view::<4, 2>(0, 0).into_owned()
    }
    /// Kq restricted to the tilt axes (eq. 34).
    pub fn kq(&self) -> Matrix2<f64> {
        Matrix2::from_diagonal(&Vector2::from(self.design.flexures.j3))
    }
    /// Kw (eq. 35).
    pub fn kw(&self) -> Matrix4<f64> {
        let f = &self.design.flexures;
        Matrix4::from_diagonal(&Vector4::new(f.j1[0], f.j1[1], f.j2[0], f.j2[1]))
    }
    /// Kl restricted to A1, A2 (eq. 36).
    pub fn kl(&self) -> Matrix2<f64> {
        Matrix2::from_diagonal(&Vector2::from(self.design.drive_stiffness()))
    }

    fn inv(m: Matrix2<f64>, what: &'static str, equation: u32) -> Result<Matrix2<f64>, ModelError> {
        let r = rcond(&m);
        if r < 1e-13 {
            return Err(ModelError::SingularSystem {
                what,
                equation,
                rcond: r,
            });
        }
        m.try_inverse().ok_or(ModelError::SingularSystem {
            what,
            equation,
            rcond: r,
        })
    }

    /// `Kq + Wᵀ Kw W`, the joint-space stiffness of the flexures on the tilt axes.
    pub fn joint_stiffness(&self) -> Matrix2<f64> {
        self.kq() + self.wp().transpose() * self.kw() * self.wp()
    }

    /// The compliance of the system reduced to the actuator axes A1, A2,
    /// `B_l = L [Kq + Wᵀ Kw W]⁻¹ Lᵀ + Kl⁻¹` (eq. 23). A3 has no stiffness, hence no entry.
    pub fn compliance(&self) -> Result<Matrix2<f64>, ModelError> {
        let k = Self::inv(self.joint_stiffness(), "joint stiffness Kq + WᵀKwW", 23)?;
        let lp = self.lp();
        Ok(lp * k * lp.transpose() + Self::inv(self.kl(), "actuator stiffness Kl", 21)?)
    }

    /// The static state for a drive displacement `dl_drive` (Δl), actuator force `f` and
    /// assembly deflection of J3 `dq0` (zero for approach 1).
    fn state(
        &self,
        dl_drive: Vector2<f64>,
        f: Vector2<f64>,
        dq0: Vector2<f64>,
    ) -> Result<State, ModelError> {
        let kl_inv = Self::inv(self.kl(), "actuator stiffness Kl", 21)?;
        let l_inv = Self::inv(self.lp(), "Jacobian L", 11)?;
        let dl1 = kl_inv * f; // (21)
        let dl = dl_drive - dl1; // (15), (27)
        let dq = l_inv * dl; // (11)
        let dx = self.jp() * dq; // (12)
        let spring = dq0 + dq; // (28)
        let fq = self.kq() * spring; // (18), (29)
        let dw = self.wp() * dq; // (13)
        let fw = self.kw() * dw; // (17)
        Ok(State {
            force: embed2(&f),
            dl1: embed2(&dl1),
            dl: embed2(&dl),
            dq_spring: embed2(&spring),
            dw,
            dx: embed2(&dx),
            fq: embed2(&fq),
            fw,
        })
    }

    /// Relative residual of the static equilibrium `Fq + Wᵀ Fw = Lᵀ F_l` (eq. 19) in a state.
    pub fn equilibrium_residual(&self, s: &State) -> f64 {
        self.equilibrium_residual_of(&s.fq, &s.fw, &s.force)
    }

    /// Relative residual of eq. (19), `|Fq + Wᵀ Fw − Lᵀ F| / (|Fq| + |Wᵀ Fw| + |Lᵀ F|)`,
    /// for any torques and forces (J3 torques, J1/J2 torques, actuator forces).
    pub fn equilibrium_residual_of(
        &self,
        fq: &Vector3<f64>,
        fw: &Vector4<f64>,
        force: &Vector3<f64>,
    ) -> f64 {
        let b = self.jacobians.w.transpose() * fw;
        let c = self.jacobians.l.transpose() * force;
        let scale = fq.norm() + b.norm() + c.norm();
        if scale == 0.0 {
            0.0
        } else {
            (fq + b - c).norm() / scale
        }
    }

    /// The assembly offset that gives the design's preload F10 with the actuators
    /// inactive: Δl0 by eq. (22) for approach 1, Δq0 by eq. (31) for approach 2.
    pub fn assembly(&self, approach: Approach) -> Result<Assembly, ModelError> {
        let f10 = Vector2::from(self.design.tension.preload);
        let zero = Vector2::zeros();
        Ok(match approach {
            Approach::DriveTranslation => Assembly {
                approach,
                dl0: self.compliance()? * f10, // (22) with Δl2 = 0
                dq0: zero,
            },
            Approach::JointDeflection => {
                let kq_inv = Self::inv(self.kq(), "J3 stiffness Kq", 31)?;
                let l_inv = Self::inv(self.lp(), "Jacobian L", 31)?;
                let kl_inv = Self::inv(self.kl(), "actuator stiffness Kl", 21)?;
                let wkw = self.wp().transpose() * self.kw() * self.wp();
                let lt = self.lp().transpose();
                // (31) with Δl2 = 0 and F_l = F10.
                let u = zero - kl_inv * f10;
                let dq0 = -kq_inv * (wkw * l_inv * u - lt * f10) - l_inv * u;
                Assembly {
                    approach,
                    dl0: zero,
                    dq0,
                }
            }
        })
    }

    /// The static state of an assembled structure for actuator shifts Δl2 of A1, A2:
    /// eqs. (24)-(26) for approach 1, (32)-(33) for approach 2.
    pub fn state_at(&self, asm: &Assembly, dl2: Vector2<f64>) -> Result<State, ModelError> {
        match asm.approach {
            Approach::DriveTranslation => {
                let b_inv = Self::inv(self.compliance()?, "compliance B_l", 24)?;
                let dl = asm.dl0 + dl2; // (14)
                self.state(dl, b_inv * dl, Vector2::zeros()) // (24), (25), (26)
            }
            Approach::JointDeflection => {
                let l_inv = Self::inv(self.lp(), "Jacobian L", 32)?;
                let kl_inv = Self::inv(self.kl(), "actuator stiffness Kl", 21)?;
                let k = self.joint_stiffness();
                let lhs = k * l_inv * kl_inv + self.lp().transpose();
                let m = Self::inv(lhs, "force matrix", 32)?;
                let f = m * (self.kq() * asm.dq0 + k * l_inv * dl2); // (32)
                self.state(dl2, f, asm.dq0) // (27), (33)
            }
        }
    }

    /// Pre-tension analysis with the design's preload and working shift.
    pub fn tension(&self, approach: Approach) -> Result<Tension, ModelError> {
        let dl2 = Vector2::from(self.design.tension.work_shift);
        let asm = self.assembly(approach)?;
        let tensioned = self.state_at(&asm, Vector2::zeros())?;
        let work = self.state_at(&asm, dl2)?;
        let chi = Vector3::new(
            (tensioned.dx[0] - work.dx[0]).abs(),
            (tensioned.dx[1] - work.dx[1]).abs(),
            self.design.actuators[2].travel,
        );
        let margins = self.margins(&tensioned, &work);
        let (dl0, dq0, dl_total) = match approach {
            Approach::DriveTranslation => {
                (Some(embed2(&asm.dl0)), None, Some(embed2(&(asm.dl0 + dl2))))
            }
            Approach::JointDeflection => (None, Some(embed2(&asm.dq0)), None),
        };
        Ok(Tension {
            approach,
            dl0,
            dq0,
            dl2: embed2(&dl2),
            dl_total,
            tensioned,
            work,
            chi,
            margins,
        })
    }

    /// Margins over the working range. Every quantity is affine in the working shift,
    /// so its extremes over the range lie at the two end states.
    fn margins(&self, a: &State, b: &State) -> Margins {
        let mut m = Margins {
            force_range: [[0.0; 2]; 2],
            compression_margin: [0.0; 2],
            capacity_margin: [0.0; 2],
            torque_max: [0.0; 2],
            torque_margin: [0.0; 2],
            offset: a.dx.norm(),
        };
        for i in 0..2 {
            let lo = a.force[i].min(b.force[i]);
            let hi = a.force[i].max(b.force[i]);
            m.force_range[i] = [lo, hi];
            m.compression_margin[i] = -hi;
            m.capacity_margin[i] = self.design.actuators[i].push_capacity + lo;
            let t = [a.fw, b.fw]
                .iter()
                .map(|fw| fw[2 * i].hypot(fw[2 * i + 1]))
                .fold(0.0, f64::max);
            m.torque_max[i] = t;
            m.torque_margin[i] = self.design.actuators[i].torque_limit - t;
        }
        m
    }
}
