//! # cellinject-fea
//!
//! The FEA pipeline behind `cellinject fea`: the two double-notched joint geometries of
//! a description (J1/J2 and J3, `[structure]`) solved by the 3-D FEM
//! ([`cellinject_fem::joint3d`]) or read from the joint [`cache`]; their 6x6
//! compliances joined into the whole-manipulator model ([`cellinject_structure`]);
//! then, as typed reports ([`report`]): one load case with the joints' stresses and
//! safety factors ([`FeaModel::solve`]), the paper's Tables 1 and 2 recomputed
//! ([`FeaModel::tables`]), the natural modes ([`FeaModel::modes`]), and the joints'
//! mesh convergence against the paper's stiffness ([`joints`]).
//!
//! ```no_run
//! use cellinject_fea::{Approach, DirCache, FeaModel, FeaOptions, NoCache, StructureParams};
//!
//! let design = cellinject_model::prototype();
//! let params = StructureParams::default();
//! let cache = DirCache::default_location().map(DirCache::new);
//! let store: &dyn cellinject_fea::JointStore = match &cache {
//!     Some(c) => c,
//!     None => &NoCache,
//! };
//! let model = FeaModel::build(&design, &params, FeaOptions::default(), store)?;
//! let case = model.solve(Approach::DriveTranslation, [-100.0, -100.0])?;
//! println!("δx = {} m, J3 safety {:?}", case.dx, case.joints[0].safety_factor);
//! # Ok::<(), cellinject_fea::FeaError>(())
//! ```
//!
//! The material (E, ν, yield strength) comes from the description's `[structure]`
//! keys, never from a constant. Inputs are validated with typed errors that carry the
//! numbers and the description keys ([`FeaError`], [`FeaError::is_input`]).
//!
//! **Architecture invariant:** the [`cache`] module is the only place in this crate that
//! touches files; everything else is pure computation on numbers. Formatting text,
//! drawing and choosing the cache directory belong to the caller (the binary).

pub mod cache;
pub mod cost;
pub mod report;

use cellinject_fem::FemError;
use cellinject_fem::joint3d::{DoubleNotch, JointMesh, JointSolution, JointWorkspace};
use cellinject_flexure::Material;
use cellinject_model::{Design, Mechanism, ModelError};
use cellinject_paper as paper;
use cellinject_structure::{JointModel, Preload, StructureError, StructureSpec};
use nalgebra::Vector6;
use serde::Serialize;
use thiserror::Error;

pub use cache::{CacheStatus, DirCache, JointKey, JointStore, NoCache, default_store};
pub use cellinject_model::Approach;
pub use cellinject_structure::{Equilibrium, Member, Structure, StructureParams};
pub use report::{
    JointConvergence, JointFem, JointGeometry, JointKBend, JointLevel, JointRow, JointStress,
    JointsReport, MaterialReport, ModeReport, ModesReport, PaperDisplacement, SolveReport,
    TableCase, TableReport, TablesReport,
};

use cache::{CacheUse, solve_cached_in};

/// The stress tensor at one point of a joint, affine in the two stack forces.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AffineStress {
    /// Pa (xx, yy, zz, yz, xz, xy) at zero stack force.
    pub at_zero: [f64; 6],
    /// Pa per newton of F11, of F12.
    pub per_newton: [[f64; 6]; 2],
}

impl AffineStress {
    /// Von Mises stress at stack forces `f` (N), Pa.
    pub fn von_mises(&self, f: [f64; 2]) -> f64 {
        let mut s = self.at_zero;
        for c in 0..6 {
            s[c] += self.per_newton[0][c] * f[0] + self.per_newton[1][c] * f[1];
        }
        cellinject_fem::joint3d::von_mises(&s)
    }
}

/// A joint's critical points with their affine stresses ([`FeaModel::j3_yield_map`]).
#[derive(Debug, Clone, PartialEq)]
pub struct YieldMap {
    /// Pa.
    pub yield_strength: f64,
    /// The points, most stressed first.
    pub points: Vec<AffineStress>,
    /// Pa: the largest difference between this map's peak von Mises stress and the
    /// full model's over the check grid.
    pub fit_error: f64,
}

impl YieldMap {
    /// The peak von Mises stress over the points at stack forces `f`, Pa.
    pub fn von_mises(&self, f: [f64; 2]) -> f64 {
        self.points
            .iter()
            .map(|p| p.von_mises(f))
            .fold(0.0, f64::max)
    }
}

/// A joint's peak stress below this fraction of the yield strength is numerical noise:
/// the joint is unloaded.
pub const UNLOADED: f64 = 1e-9;

/// The paper's bending stiffness of J1 and J2 (Sec. 3.1, eq. 35), N·m/rad: compared with
/// only.
pub const PAPER_K_J12: f64 = 91.3;
/// The paper's bending stiffness of J3 (Sec. 3.1, eq. 34), N·m/rad: compared with only.
pub const PAPER_K_J3: f64 = 340.3;
/// Relative difference between a `[flexures]` stiffness and the FEM joint's above which
/// [`FeaModel::consistency_warnings`] speaks.
pub const CONSISTENCY_TOLERANCE: f64 = 0.02;
/// Mesh levels the joint FEM is run at.
pub const LEVELS: std::ops::RangeInclusive<usize> = 1..=3;

/// How approach 2's pre-tension of J3 enters the structural model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PreloadKind {
    /// J3 assembled pre-deflected, by the approach's design rule (the stacks carry F10
    /// with the drives at their home length) applied to this model's stiffness.
    #[default]
    Deflection,
    /// The paper's CAD set-up (Sec. 3.3.2): J3 straight and the torques of eq. (53) on
    /// body 1 (ill-conditioned: a 0.1 % difference of 3 N·m terms).
    Torque,
}

/// How the model is built.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FeaOptions {
    /// Refinement level of the joints' 3-D FEM, 1..=3 (1: 25k unknowns per joint, under
    /// a second; 2: 184k, about ten seconds).
    pub level: usize,
    /// Approach 2's preload.
    pub preload: PreloadKind,
}

impl Default for FeaOptions {
    /// Level 1, approach 2 by deflection.
    fn default() -> Self {
        FeaOptions {
            level: 1,
            preload: PreloadKind::Deflection,
        }
    }
}

/// What the pipeline refuses or fails at.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum FeaError {
    /// A slider force that pulls: the stacks' spherical joints only push.
    #[error(
        "F1{index} = {force} N would pull on A{index}: its spherical joint only pushes (compression is negative)"
    )]
    PullingForce {
        /// 1 or 2.
        index: usize,
        /// N.
        force: f64,
    },
    /// A force beyond the stack's push capacity.
    #[error(
        "F1{index} = {force} N exceeds A{index}'s push capacity {capacity} N (actuators.A{index}.push_capacity)"
    )]
    PushCapacity {
        /// 1 or 2.
        index: usize,
        /// N.
        force: f64,
        /// N, `actuators.A{index}.push_capacity`.
        capacity: f64,
    },
    /// A mesh level outside 1..=3.
    #[error("mesh level {level} is outside 1..=3")]
    Level {
        /// The level asked for.
        level: usize,
    },
    /// No mesh level, or one outside 1..=3, in a convergence study.
    #[error("mesh levels {levels:?}: give levels between 1 and 3, e.g. 1,2")]
    Levels {
        /// The levels asked for.
        levels: Vec<usize>,
    },
    /// A number that must be finite is not.
    #[error("{key} = {value} is not a finite number")]
    NonFinite {
        /// What it is (`F11`, `structure.youngs`, ...).
        key: String,
        /// Its value.
        value: f64,
    },
    /// A parameter outside its domain.
    #[error("{key} = {value}: {reason}")]
    Invalid {
        /// The description key.
        key: String,
        /// Its value.
        value: f64,
        /// What is wrong.
        reason: String,
    },
    /// The joint FEM refused or failed on a joint.
    #[error("{key}: joint FEM failed: {source}")]
    JointFem {
        /// `structure.throat_J12` or `structure.throat_J3`.
        key: &'static str,
        /// The FEM's error.
        source: FemError,
    },
    /// A joint's compliance has no Cholesky factor.
    #[error("{key}: the joint's compliance is not positive definite (diagonal {diagonal:?})")]
    NotPositiveDefinite {
        /// `structure.throat_J12` or `structure.throat_J3`.
        key: &'static str,
        /// Its diagonal (m/N, rad/(N·m)).
        diagonal: [f64; 6],
    },
    /// The structural model refused its inputs.
    #[error("structure: {0}")]
    Structure(StructureError),
    /// The mechanism model failed (approach 2's pre-tension).
    #[error("mechanism model: {0}")]
    Model(ModelError),
    /// Approach 2's assembly deflection of J3 was not found.
    #[error("approach 2's assembly deflection of J3: {0}")]
    Deflection(StructureError),
    /// The structural equilibrium was not found.
    #[error("structural equilibrium: {0}")]
    Equilibrium(StructureError),
    /// The natural modes could not be computed.
    #[error("natural modes: {0}")]
    Modes(StructureError),
    /// The embedded paper tables hold an approach that does not exist.
    #[error("the paper's table {table} names approach {approach}")]
    PaperTable {
        /// Table number.
        table: u8,
        /// Its approach.
        approach: u8,
    },
}

impl FeaError {
    /// Whether the error is the user's input (a force, a level, a description value):
    /// the binary exits with code 2 on these, 1 on the others.
    pub fn is_input(&self) -> bool {
        match self {
            FeaError::PullingForce { .. }
            | FeaError::PushCapacity { .. }
            | FeaError::Level { .. }
            | FeaError::Levels { .. }
            | FeaError::NonFinite { .. }
            | FeaError::Invalid { .. }
            | FeaError::JointFem { .. }
            | FeaError::NotPositiveDefinite { .. } => true,
            FeaError::Structure(e) => matches!(e, StructureError::Invalid { .. }),
            FeaError::Model(e) => matches!(e, ModelError::InvalidParameter { .. }),
            FeaError::Deflection(_)
            | FeaError::Equilibrium(_)
            | FeaError::Modes(_)
            | FeaError::PaperTable { .. } => false,
        }
    }
}

/// The joints' material from the description's `[structure]` keys, checked: `youngs`
/// and `yield_strength` positive, `poisson` in (−1, 0.5), all finite.
pub fn material(params: &StructureParams) -> Result<Material, FeaError> {
    for (key, value) in [
        ("structure.youngs", params.youngs),
        ("structure.poisson", params.poisson),
        ("structure.yield_strength", params.yield_strength),
    ] {
        if !value.is_finite() {
            return Err(FeaError::NonFinite {
                key: key.into(),
                value,
            });
        }
    }
    let invalid = |key: &str, value: f64, reason: &str| FeaError::Invalid {
        key: key.into(),
        value,
        reason: reason.into(),
    };
    if params.youngs <= 0.0 {
        return Err(invalid(
            "structure.youngs",
            params.youngs,
            "must be positive",
        ));
    }
    if !(params.poisson > -1.0 && params.poisson < 0.5) {
        return Err(invalid(
            "structure.poisson",
            params.poisson,
            "must lie in the open interval (-1, 0.5)",
        ));
    }
    if params.yield_strength <= 0.0 {
        return Err(invalid(
            "structure.yield_strength",
            params.yield_strength,
            "must be positive",
        ));
    }
    Ok(Material {
        youngs: params.youngs,
        poisson: params.poisson,
        yield_strength: params.yield_strength,
    })
}

/// The double-notched joint of `[structure]` with throat `throat`.
pub fn joint_geometry(params: &StructureParams, throat: f64) -> DoubleNotch {
    DoubleNotch {
        side: params.joint.side,
        radius: params.joint.radius,
        flat: params.joint.flat,
        throat,
        gap: params.joint.gap,
    }
}

/// Checks slider forces against the design: finite, not pulling (the stacks' spherical
/// joints only push), within each stack's push capacity.
pub fn check_forces(design: &Design, forces: [f64; 2]) -> Result<(), FeaError> {
    for (i, &force) in forces.iter().enumerate() {
        let index = i + 1;
        if !force.is_finite() {
            return Err(FeaError::NonFinite {
                key: format!("F1{index}"),
                value: force,
            });
        }
        if force > 0.0 {
            return Err(FeaError::PullingForce { index, force });
        }
        let capacity = design.actuators[i].push_capacity;
        if force.abs() > capacity {
            return Err(FeaError::PushCapacity {
                index,
                force,
                capacity,
            });
        }
    }
    Ok(())
}

fn check_level(level: usize) -> Result<(), FeaError> {
    if LEVELS.contains(&level) {
        Ok(())
    } else {
        Err(FeaError::Level { level })
    }
}

/// Solves (or reads) one joint, a solve made in `workspace` (shared by the joints
/// a command solves in turn).
fn joint(
    store: &dyn JointStore,
    joint: &DoubleNotch,
    material: &Material,
    level: usize,
    key: &'static str,
    workspace: &mut JointWorkspace,
) -> Result<(JointSolution, CacheUse), FeaError> {
    let k = JointKey::new(joint, material, &JointMesh::default(), level);
    solve_cached_in(store, &k, workspace).map_err(|source| FeaError::JointFem { key, source })
}

fn joint_fem(s: &JointSolution, used: CacheUse) -> JointFem {
    JointFem {
        dofs: s.dofs,
        elements: s.elements,
        residual: s.residual,
        asymmetry: s.asymmetry,
        cache: used.status,
        cache_detail: used.detail,
    }
}

/// The structure's view of a solved joint: its block stiffness and where its notches
/// lie.
fn joint_model(s: &JointSolution, key: &'static str) -> Result<JointModel, FeaError> {
    let stiffness = JointModel::stiffness_of(&s.block_compliance).ok_or_else(|| {
        let c = &s.block_compliance;
        FeaError::NotPositiveDefinite {
            key,
            diagonal: std::array::from_fn(|i| c[(i, i)]),
        }
    })?;
    let l = s.layout;
    Ok(JointModel {
        stiffness,
        lower_end: s.block_sections[0],
        lower_notch: l.notch_a,
        upper_notch: l.notch_b,
        upper_end: s.block_sections[1],
    })
}

/// The whole manipulator on its FEM joints, ready for load cases.
#[derive(Debug, Clone)]
pub struct FeaModel {
    design: Design,
    params: StructureParams,
    options: FeaOptions,
    material: Material,
    mechanism: Mechanism,
    j12: JointSolution,
    j3: JointSolution,
    convergence: JointConvergence,
    structure: Structure,
    warnings: Vec<String>,
}

/// A solved load case: the report and the equilibrium it came from (for drawings).
#[derive(Debug, Clone)]
pub struct SolvedCase {
    /// The report.
    pub report: SolveReport,
    /// The equilibrium ([`FeaModel::skeleton`] draws it).
    pub equilibrium: Equilibrium,
}

impl FeaModel {
    /// Builds the model of `design` with the joints and masses of `params`: both joint
    /// geometries are read from `cache` or solved by the 3-D FEM at `options.level` (and
    /// stored), then joined into the structural model.
    pub fn build(
        design: &Design,
        params: &StructureParams,
        options: FeaOptions,
        cache: &dyn JointStore,
    ) -> Result<FeaModel, FeaError> {
        check_level(options.level)?;
        let material = material(params)?;
        let mechanism = Mechanism::new(design).map_err(FeaError::Model)?;
        let level = options.level;
        let mut workspace = JointWorkspace::default();
        let (j12, u12) = joint(
            cache,
            &joint_geometry(params, params.throat_j12),
            &material,
            level,
            "structure.throat_J12",
            &mut workspace,
        )?;
        let (j3, u3) = joint(
            cache,
            &joint_geometry(params, params.throat_j3),
            &material,
            level,
            "structure.throat_J3",
            &mut workspace,
        )?;
        drop(workspace);
        let m12 = joint_model(&j12, "structure.throat_J12")?;
        let spec = StructureSpec {
            j3: joint_model(&j3, "structure.throat_J3")?,
            j12: [m12, m12],
            mass: params.masses(&design.geometry),
        };
        let structure = Structure::new(design, &spec).map_err(FeaError::Structure)?;
        let convergence = JointConvergence {
            j1_j2: joint_fem(&j12, u12),
            j3: joint_fem(&j3, u3),
        };
        let mut model = FeaModel {
            design: *design,
            params: *params,
            options,
            material,
            mechanism,
            j12,
            j3,
            convergence,
            structure,
            warnings: Vec::new(),
        };
        model.warnings = model.compute_warnings();
        Ok(model)
    }

    /// The options it was built with.
    pub fn options(&self) -> FeaOptions {
        self.options
    }

    /// The joints' material.
    pub fn material(&self) -> Material {
        self.material
    }

    /// The structural model.
    pub fn structure(&self) -> &Structure {
        &self.structure
    }

    /// J1's and J2's FEM solution.
    pub fn joint_j12(&self) -> &JointSolution {
        &self.j12
    }

    /// J3's FEM solution.
    pub fn joint_j3(&self) -> &JointSolution {
        &self.j3
    }

    /// The joints' bending stiffness.
    pub fn joint_k_bend(&self) -> JointKBend {
        JointKBend {
            j1_j2: self.j12.k_bend,
            j3: self.j3.k_bend,
        }
    }

    /// The joints' FEM convergence and how the cache served them.
    pub fn joint_convergence(&self) -> &JointConvergence {
        &self.convergence
    }

    /// Where the mechanism model's `[flexures]` stiffnesses and the `[structure]`
    /// joints' FEM bending stiffness differ by more than [`CONSISTENCY_TOLERANCE`], one
    /// message per joint and axis naming both keys. Axes: `flexures.J1[a]` and
    /// `flexures.J2[a]` are the FEM joint's bending about its local x (a = 0) and y
    /// (a = 1); `flexures.J3[0]` (q1) is about y, `flexures.J3[1]` (q2) about x.
    pub fn consistency_warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }

    fn compute_warnings(&self) -> Vec<String> {
        let f = &self.design.flexures;
        let p = &self.params;
        let k12 = self.j12.k_bend;
        let k3 = self.j3.k_bend;
        let checks = [
            ("J1", 0, f.j1[0], k12[0], "throat_J12", p.throat_j12),
            ("J1", 1, f.j1[1], k12[1], "throat_J12", p.throat_j12),
            ("J2", 0, f.j2[0], k12[0], "throat_J12", p.throat_j12),
            ("J2", 1, f.j2[1], k12[1], "throat_J12", p.throat_j12),
            ("J3", 0, f.j3[0], k3[1], "throat_J3", p.throat_j3),
            ("J3", 1, f.j3[1], k3[0], "throat_J3", p.throat_j3),
        ];
        checks
            .iter()
            .filter_map(|&(name, axis, given, fem, key, throat)| {
                let rel = fem / given - 1.0;
                (rel.abs() > CONSISTENCY_TOLERANCE).then(|| {
                    format!(
                        "flexures.{name}[{axis}] = {given} N·m/rad but the [structure] joint (structure.{key} = {throat} m) gives {fem:.1} N·m/rad at mesh level {} ({:+.1} %)",
                        self.options.level,
                        100.0 * rel
                    )
                })
            })
            .collect()
    }

    /// The structure's preload under `approach`. Approach 2: J3's assembly deflection by
    /// the approach's design rule (the stacks carry F10 with the drives at home length)
    /// on this model's own stiffness, from the pseudo-rigid-body Δq0 (eq. 31); or the
    /// paper's torques (eq. 53), by [`FeaOptions::preload`].
    pub fn preload(&self, approach: Approach) -> Result<Preload, FeaError> {
        Ok(match approach {
            Approach::DriveTranslation => Preload::Translation,
            Approach::JointDeflection => {
                let t = self.mechanism.tension(approach).map_err(FeaError::Model)?;
                if self.options.preload == PreloadKind::Torque {
                    let fq = t.tensioned.fq;
                    return Ok(Preload::Torque {
                        moment: [-fq[0], -fq[1]],
                    });
                }
                let dq0 = t.dq0.unwrap_or_default();
                let dq0 = self
                    .structure
                    .deflection_for(self.design.tension.preload, [dq0[0], dq0[1]])
                    .map_err(FeaError::Deflection)?;
                Preload::Deflection { dq0 }
            }
        })
    }

    fn equilibrium_with(
        &self,
        forces: [f64; 2],
        preload: Preload,
    ) -> Result<Equilibrium, FeaError> {
        self.structure
            .solve(forces, preload)
            .map_err(FeaError::Equilibrium)
    }

    /// J3's stress as an affine function of the two stack forces, for the piezo safety
    /// envelope to check at kilohertz rates without the FEM: the structural model gives
    /// J3's wrench at the stack forces `F` (eqs. 21-26 with the approach's preload), the
    /// joint FEM the stress tensor at each of its points per unit wrench; both are
    /// linearised at `F₀ = (−105, −105)` N by central differences of 5 N, and the
    /// `count` points that reach the highest von Mises stress anywhere on
    /// `F ∈ [−140, −70]²` N (the stacks' forces over both approaches' working ranges
    /// and the envelope's margins: −95 to −120 N) are kept. The map's worst error
    /// against the full model on that grid is reported ([`YieldMap::fit_error`]); the
    /// envelope subtracts it from the yield strength.
    pub fn j3_yield_map(&self, approach: Approach, count: usize) -> Result<YieldMap, FeaError> {
        let preload = self.preload(approach)?;
        let stress = |f: [f64; 2]| -> Result<Vec<[f64; 6]>, FeaError> {
            let eq = self.equilibrium_with(f, preload)?;
            Ok(self.j3.stresses_block(&eq.joint_wrench[0]))
        };
        let f0 = [-105.0, -105.0];
        let h = 5.0;
        let s0 = stress(f0)?;
        let mut per_newton = vec![[[0.0; 6]; 2]; s0.len()];
        for k in 0..2 {
            let (mut a, mut b) = (f0, f0);
            a[k] += h;
            b[k] -= h;
            let (sa, sb) = (stress(a)?, stress(b)?);
            for (p, (x, y)) in per_newton.iter_mut().zip(sa.iter().zip(&sb)) {
                for c in 0..6 {
                    p[k][c] = (x[c] - y[c]) / (2.0 * h);
                }
            }
        }
        let affine: Vec<AffineStress> = s0
            .iter()
            .zip(&per_newton)
            .map(|(s, d)| {
                let mut at_zero = *s;
                for c in 0..6 {
                    at_zero[c] -= d[0][c] * f0[0] + d[1][c] * f0[1];
                }
                AffineStress {
                    at_zero,
                    per_newton: *d,
                }
            })
            .collect();
        // Rank the points by the highest stress they reach over the grid.
        let grid: Vec<[f64; 2]> = (0..5)
            .flat_map(|i| (0..5).map(move |j| [-140.0 + 17.5 * i as f64, -140.0 + 17.5 * j as f64]))
            .collect();
        let mut reach: Vec<(f64, usize)> = affine
            .iter()
            .enumerate()
            .map(|(k, a)| {
                let m = grid.iter().map(|f| a.von_mises(*f)).fold(0.0f64, f64::max);
                (m, k)
            })
            .collect();
        reach.sort_by(|a, b| b.0.total_cmp(&a.0));
        let points: Vec<AffineStress> = reach
            .iter()
            .take(count.max(1))
            .map(|(_, k)| affine[*k])
            .collect();
        let map = YieldMap {
            yield_strength: self.material.yield_strength,
            points,
            fit_error: 0.0,
        };
        let mut worst = 0.0f64;
        for f in &grid {
            let exact = stress(*f)?
                .iter()
                .map(cellinject_fem::joint3d::von_mises)
                .fold(0.0f64, f64::max);
            worst = worst.max((map.von_mises(*f) - exact).abs());
        }
        Ok(YieldMap {
            fit_error: worst,
            ..map
        })
    }

    /// Peak stresses of J3, J1, J2 at an equilibrium. A joint whose peak stress is below
    /// [`UNLOADED`] times the yield strength is unloaded: its safety factor is `None`.
    pub fn stresses(&self, eq: &Equilibrium) -> Vec<JointStress> {
        let y = self.material.yield_strength;
        ["J3", "J1", "J2"]
            .iter()
            .enumerate()
            .map(|(i, &name)| {
                let sol = if i == 0 { &self.j3 } else { &self.j12 };
                let w: Vector6<f64> = eq.joint_wrench[i];
                let (s, at) = sol.peak_von_mises_block(&w);
                // Below 1e-9 of the yield strength a stress measures rounding, not load:
                // the joint is unloaded and has no safety factor.
                let unloaded = s < UNLOADED * y;
                JointStress {
                    name,
                    max_von_mises: s,
                    safety_factor: (!unloaded).then(|| y / s),
                    at,
                }
            })
            .collect()
    }

    /// One static load case: slider forces `forces` (N, negative: compressive, as the
    /// paper's F11, F12) on the structure pre-tensioned by `approach`. The forces are
    /// checked first ([`check_forces`]).
    pub fn solve(&self, approach: Approach, forces: [f64; 2]) -> Result<SolveReport, FeaError> {
        self.solve_case(approach, forces).map(|c| c.report)
    }

    /// [`FeaModel::solve`], keeping the equilibrium for a drawing.
    pub fn solve_case(&self, approach: Approach, forces: [f64; 2]) -> Result<SolvedCase, FeaError> {
        check_forces(&self.design, forces)?;
        let eq = self.equilibrium_with(forces, self.preload(approach)?)?;
        let report = SolveReport {
            approach: approach.number(),
            forces,
            dx: eq.tip[0],
            dy: eq.tip[1],
            dz: eq.tip[2],
            body_rotation: [
                eq.body_rotation[0],
                eq.body_rotation[1],
                eq.body_rotation[2],
            ],
            stack_force: eq.stack_force,
            slider: eq.slider,
            joints: self.stresses(&eq),
            yield_strength: self.material.yield_strength,
            joint_k_bend: self.joint_k_bend(),
            mesh_level: self.options.level,
            iterations: eq.iterations,
            residual: eq.residual,
            joint_convergence: self.convergence.clone(),
            warnings: self.warnings.clone(),
        };
        Ok(SolvedCase {
            report,
            equilibrium: eq,
        })
    }

    /// The structure as line members at rest and at `eq`, each sampled at `samples`
    /// points (for drawings like the paper's Fig. 4).
    pub fn skeleton(&self, eq: &Equilibrium, samples: usize) -> Vec<Member> {
        self.structure.skeleton(eq, samples)
    }

    /// The paper's Tables 1 and 2 recomputed on this model.
    pub fn tables(&self) -> Result<TablesReport, FeaError> {
        let mut tables = Vec::new();
        for t in paper::fea_tables() {
            let approach = Approach::from_number(t.approach).ok_or(FeaError::PaperTable {
                table: t.table,
                approach: t.approach,
            })?;
            let pre = self.preload(approach)?;
            let computed = t
                .cases
                .iter()
                .map(|c| self.equilibrium_with([c.f11, c.f12], pre))
                .collect::<Result<Vec<_>, _>>()?;
            let largest = t
                .cases
                .iter()
                .flat_map(|c| [c.dx.abs(), c.dy.abs()])
                .fold(0.0, f64::max);
            let worst = t
                .cases
                .iter()
                .zip(&computed)
                .flat_map(|(c, e)| [(e.tip[0] - c.dx).abs(), (e.tip[1] - c.dy).abs()])
                .fold(0.0, f64::max);
            let coupling = match (computed.first(), computed.get(2)) {
                (Some(a), Some(c)) => c.tip[0] - a.tip[0],
                _ => f64::NAN,
            };
            tables.push(TableReport {
                table: t.table,
                approach: t.approach,
                largest_paper_displacement: largest,
                worst_difference: worst,
                worst_relative_to_largest: worst / largest,
                coupling_x: coupling,
                paper_coupling_x: t.coupling_x,
                cases: t
                    .cases
                    .iter()
                    .zip(&computed)
                    .map(|(c, e)| TableCase {
                        f11: c.f11,
                        f12: c.f12,
                        paper: PaperDisplacement { dx: c.dx, dy: c.dy },
                        dx: e.tip[0],
                        dy: e.tip[1],
                        dz: e.tip[2],
                        stack_force: e.stack_force,
                        joints: self.stresses(e),
                    })
                    .collect(),
            });
        }
        Ok(TablesReport {
            mesh_level: self.options.level,
            approach2_preload: self.options.preload,
            joint_k_bend: self.joint_k_bend(),
            yield_strength: self.material.yield_strength,
            tables,
            joint_convergence: self.convergence.clone(),
            warnings: self.warnings.clone(),
        })
    }

    /// The lowest `count` natural modes of the manipulator pre-tensioned by `approach`
    /// at its design preload F10 (`tension.preload`), sliders locked.
    pub fn modes(&self, approach: Approach, count: usize) -> Result<ModesReport, FeaError> {
        let f = self.design.tension.preload;
        let eq = self.equilibrium_with(f, self.preload(approach)?)?;
        let modes = self.structure.modes(&eq).map_err(FeaError::Modes)?;
        Ok(ModesReport {
            approach: approach.number(),
            preload: f,
            modes: modes
                .iter()
                .take(count)
                .map(|m| ModeReport {
                    frequency: m.frequency,
                    description: m.description.clone(),
                    tip_shape: [m.tip_shape[0], m.tip_shape[1], m.tip_shape[2]],
                })
                .collect(),
            mesh_level: self.options.level,
            joint_convergence: self.convergence.clone(),
            warnings: self.warnings.clone(),
        })
    }
}

/// The double-notched joints of `[structure]` (J1/J2 and J3) by the 3-D FEM at each of
/// `levels` (1..=3; sorted, repeats dropped), against the paper's 91.3 and 340.3 N·m/rad:
/// `cellinject fea joints`. Solved joints are read from and kept in `cache`.
pub fn joints(
    params: &StructureParams,
    levels: &[usize],
    cache: &dyn JointStore,
) -> Result<JointsReport, FeaError> {
    let mut sorted = levels.to_vec();
    sorted.sort_unstable();
    sorted.dedup();
    if sorted.is_empty() || !sorted.iter().all(|l| LEVELS.contains(l)) {
        return Err(FeaError::Levels {
            levels: levels.to_vec(),
        });
    }
    let m = material(params)?;
    let targets = [
        (
            "J1, J2",
            params.throat_j12,
            PAPER_K_J12,
            "structure.throat_J12",
        ),
        ("J3", params.throat_j3, PAPER_K_J3, "structure.throat_J3"),
    ];
    let mut rows = Vec::new();
    let mut workspace = JointWorkspace::default();
    for (name, throat, paper_k, key) in targets {
        let geometry = joint_geometry(params, throat);
        let mut out = Vec::new();
        let mut finest = [f64::NAN; 2];
        for &level in &sorted {
            let (s, used) = joint(cache, &geometry, &m, level, key, &mut workspace)?;
            finest = s.k_bend;
            out.push(JointLevel {
                level,
                k_bend: s.k_bend,
                k_axial: s.k_axial,
                k_torsion: s.k_torsion,
                max_stress_per_rad: s.max_stress_per_rad(),
                dofs: s.dofs,
                residual: s.residual,
                cache: used.status,
                cache_detail: used.detail,
            });
        }
        rows.push(JointRow {
            joint: name,
            throat,
            paper_k_bend: paper_k,
            levels: out,
            k_bend: finest,
            relative_to_paper: [finest[0] / paper_k - 1.0, finest[1] / paper_k - 1.0],
        });
    }
    let g = &params.joint;
    Ok(JointsReport {
        geometry: JointGeometry {
            side: g.side,
            radius: g.radius,
            flat: g.flat,
            gap: g.gap,
        },
        material: MaterialReport {
            youngs: m.youngs,
            poisson: m.poisson,
            yield_strength: m.yield_strength,
        },
        joints: rows,
    })
}

/// J3's yield check for the safety envelope of a bench assembled with `approach`: the
/// structural model of `design` and `structure` on level-1 FEM joints (from `store`
/// when it holds them), reduced to numbers the envelope evaluates without the FEM
/// ([`cellinject_rig::guard::YieldCheck`]). Every front end that builds a twin or a
/// guarded rig calls this.
pub fn j3_yield_check(
    design: &Design,
    structure: &StructureParams,
    approach: Approach,
    store: &dyn JointStore,
) -> Result<cellinject_rig::guard::YieldCheck, FeaError> {
    use cellinject_rig::guard::{StressPoint, YIELD_POINTS, YieldCheck};
    let m = FeaModel::build(design, structure, FeaOptions::default(), store)?;
    let map = m.j3_yield_map(approach, YIELD_POINTS)?;
    Ok(YieldCheck::new(
        "J3",
        map.yield_strength,
        map.fit_error,
        map.points.iter().map(|a| StressPoint {
            at_zero: a.at_zero,
            per_newton: a.per_newton,
        }),
    ))
}
