//! The typed results of the pipeline. Serialized (serde, e.g. to JSON), each is the
//! documented output schema of one `cellinject fea` command; all quantities are SI.

use serde::Serialize;

use crate::PreloadKind;
use crate::cache::CacheStatus;

/// Peak stress of one joint at one equilibrium.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `name` | – | `"J3"`, `"J1"` or `"J2"` |
/// | `max_von_mises` | Pa | largest von Mises stress between the joint's end sections |
/// | `safety_factor` | – | yield strength / `max_von_mises`; `null` when the joint is unloaded (stress below 1e-9 of the yield strength) |
/// | `at` | m | where the peak lies, in the joint's frame (`[x, y, z]`) |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JointStress {
    /// `"J3"`, `"J1"` or `"J2"`.
    pub name: &'static str,
    /// Pa, largest von Mises stress.
    pub max_von_mises: f64,
    /// Yield strength over the peak stress.
    pub safety_factor: Option<f64>,
    /// m, where the peak lies (joint frame).
    pub at: [f64; 3],
}

/// The FEM joints' bending stiffness, N·m/rad, about local x and about local y.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `J1_J2` | N·m/rad | J1 and J2 (throat `structure.throat_J12`): `[about x, about y]` |
/// | `J3` | N·m/rad | J3 (throat `structure.throat_J3`): `[about x, about y]` |
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct JointKBend {
    /// N·m/rad, J1 and J2.
    #[serde(rename = "J1_J2")]
    pub j1_j2: [f64; 2],
    /// N·m/rad, J3.
    #[serde(rename = "J3")]
    pub j3: [f64; 2],
}

/// How one joint's 3-D FEM was obtained and how well it is converged.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `dofs` | – | unknowns of the FEM |
/// | `elements` | – | 27-node hexahedra |
/// | `residual` | – | backward error of the worst load case (accepted below 1e-13) |
/// | `asymmetry` | – | relative antisymmetric part of the fitted compliance |
/// | `cache` | – | `"hit"`, `"miss"`, `"recomputed (corrupt entry)"`, `"off"` or `"unwritable"` |
/// | `cache_detail` | – | only when an entry was refused or could not be written: file and reason |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JointFem {
    /// Unknowns.
    pub dofs: usize,
    /// Elements.
    pub elements: usize,
    /// Backward error of the worst load case.
    pub residual: f64,
    /// Relative antisymmetric part of the compliance before symmetrisation.
    pub asymmetry: f64,
    /// How the cache served the joint.
    pub cache: CacheStatus,
    /// Why an entry was refused or not written.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cache_detail: Option<String>,
}

/// Both joints' FEM convergence and cache use.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `J1_J2` | – | [`JointFem`] of J1 and J2 |
/// | `J3` | – | [`JointFem`] of J3 |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JointConvergence {
    /// J1 and J2.
    #[serde(rename = "J1_J2")]
    pub j1_j2: JointFem,
    /// J3.
    #[serde(rename = "J3")]
    pub j3: JointFem,
}

/// One static load case: `cellinject fea --approach A --forces F11,F12`.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `approach` | – | pre-tensioning approach, 1 or 2 |
/// | `forces` | N | `[F11, F12]` on the motor loops' ends (negative: compressive) |
/// | `dx`, `dy`, `dz` | m | end-effector displacement from home |
/// | `body_rotation` | rad | rotation vector of body 1 from home |
/// | `stack_force` | N | axial force of A1, A2 (negative: compression) |
/// | `slider` | m | slider travel of each chain (positive towards body 1) |
/// | `joints` | – | [`JointStress`] of J3, J1, J2 |
/// | `yield_strength` | Pa | the material's (`structure.yield_strength`) |
/// | `joint_k_bend` | N·m/rad | [`JointKBend`] |
/// | `mesh_level` | – | refinement level of the joints' FEM |
/// | `iterations` | – | Newton iterations of the equilibrium |
/// | `residual` | – | largest gradient component left, relative to the load |
/// | `joint_convergence` | – | [`JointConvergence`] |
/// | `warnings` | – | [`crate::FeaModel::consistency_warnings`] |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SolveReport {
    /// Pre-tensioning approach.
    pub approach: u8,
    /// N, F11 and F12.
    pub forces: [f64; 2],
    /// m, end-effector displacement along x.
    pub dx: f64,
    /// m, along y.
    pub dy: f64,
    /// m, along z.
    pub dz: f64,
    /// rad, body 1's rotation vector.
    pub body_rotation: [f64; 3],
    /// N, axial forces of A1 and A2.
    pub stack_force: [f64; 2],
    /// m, slider travels.
    pub slider: [f64; 2],
    /// J3, J1, J2.
    pub joints: Vec<JointStress>,
    /// Pa, yield strength.
    pub yield_strength: f64,
    /// N·m/rad, the joints' bending stiffness.
    pub joint_k_bend: JointKBend,
    /// Mesh level of the joints.
    pub mesh_level: usize,
    /// Newton iterations.
    pub iterations: usize,
    /// Relative gradient left at the equilibrium.
    pub residual: f64,
    /// The joints' FEM convergence and cache use.
    pub joint_convergence: JointConvergence,
    /// Disagreements between `[flexures]` and the `[structure]` joints.
    pub warnings: Vec<String>,
}

/// The paper's displacement for one load case.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `dx`, `dy` | m | end-effector displacement the paper's CAD FEA gives |
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PaperDisplacement {
    /// m, along x.
    pub dx: f64,
    /// m, along y.
    pub dy: f64,
}

/// One load case of a table.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `F11`, `F12` | N | the case's forces |
/// | `paper` | m | [`PaperDisplacement`] |
/// | `dx`, `dy`, `dz` | m | the model's end-effector displacement |
/// | `stack_force` | N | axial force of A1, A2 |
/// | `joints` | – | [`JointStress`] of J3, J1, J2 |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TableCase {
    /// N, F11.
    #[serde(rename = "F11")]
    pub f11: f64,
    /// N, F12.
    #[serde(rename = "F12")]
    pub f12: f64,
    /// The paper's displacement.
    pub paper: PaperDisplacement,
    /// m, along x.
    pub dx: f64,
    /// m, along y.
    pub dy: f64,
    /// m, along z.
    pub dz: f64,
    /// N, axial forces of A1 and A2.
    pub stack_force: [f64; 2],
    /// J3, J1, J2.
    pub joints: Vec<JointStress>,
}

impl TableCase {
    /// The joint with the smallest safety factor.
    pub fn weakest(&self) -> Option<&JointStress> {
        self.joints
            .iter()
            .filter(|j| j.safety_factor.is_some())
            .min_by(|a, b| {
                let f = |j: &JointStress| j.safety_factor.unwrap_or(f64::INFINITY);
                f(a).total_cmp(&f(b))
            })
    }
}

/// One of the paper's Tables 1 and 2, recomputed.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `table` | – | 1 or 2 |
/// | `approach` | – | its pre-tensioning approach |
/// | `largest_paper_displacement` | m | largest `|dx|`, `|dy|` of the paper's cases |
/// | `worst_difference` | m | largest model − paper difference of `dx`, `dy` |
/// | `worst_relative_to_largest` | – | the two above divided (the paper accepts 3 %) |
/// | `coupling_x` | m | `dx` of case 3 minus case 1 (raising F12 alone) |
/// | `paper_coupling_x` | m | the paper's |
/// | `cases` | – | [`TableCase`] |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TableReport {
    /// Table number.
    pub table: u8,
    /// Pre-tensioning approach.
    pub approach: u8,
    /// m, largest displacement of the paper's cases.
    pub largest_paper_displacement: f64,
    /// m, largest difference.
    pub worst_difference: f64,
    /// Largest difference over largest displacement.
    pub worst_relative_to_largest: f64,
    /// m, cross-axis coupling of the model.
    pub coupling_x: f64,
    /// m, the paper's.
    pub paper_coupling_x: f64,
    /// The load cases.
    pub cases: Vec<TableCase>,
}

/// `cellinject fea tables`: Tables 1 and 2 recomputed.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `mesh_level` | – | refinement level of the joints' FEM |
/// | `approach2_preload` | – | `"deflection"` or `"torque"` |
/// | `joint_k_bend` | N·m/rad | [`JointKBend`] |
/// | `yield_strength` | Pa | the material's |
/// | `tables` | – | [`TableReport`] of Tables 1 and 2 |
/// | `joint_convergence` | – | [`JointConvergence`] |
/// | `warnings` | – | [`crate::FeaModel::consistency_warnings`] |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TablesReport {
    /// Mesh level of the joints.
    pub mesh_level: usize,
    /// How approach 2's preload enters.
    pub approach2_preload: PreloadKind,
    /// N·m/rad, the joints' bending stiffness.
    pub joint_k_bend: JointKBend,
    /// Pa, yield strength.
    pub yield_strength: f64,
    /// Tables 1 and 2.
    pub tables: Vec<TableReport>,
    /// The joints' FEM convergence and cache use.
    pub joint_convergence: JointConvergence,
    /// Disagreements between `[flexures]` and the `[structure]` joints.
    pub warnings: Vec<String>,
}

/// One natural mode.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `frequency` | Hz | natural frequency |
/// | `description` | – | what moves most (`"body 1 tilt about x"`, `"A1 axial"`, ...) |
/// | `tip_shape` | m | end-effector motion with the mode's largest coordinate at 1 µm or 1 µrad |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModeReport {
    /// Hz.
    pub frequency: f64,
    /// What moves most.
    pub description: String,
    /// m, end-effector motion of the scaled mode.
    pub tip_shape: [f64; 3],
}

/// `cellinject fea modes`: natural modes of the pre-tensioned manipulator.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `approach` | – | pre-tensioning approach |
/// | `preload` | N | the forces F10 it is pre-tensioned with (`tension.preload`) |
/// | `modes` | – | [`ModeReport`], lowest first |
/// | `mesh_level` | – | refinement level of the joints' FEM |
/// | `joint_convergence` | – | [`JointConvergence`] |
/// | `warnings` | – | [`crate::FeaModel::consistency_warnings`] |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModesReport {
    /// Pre-tensioning approach.
    pub approach: u8,
    /// N, F10.
    pub preload: [f64; 2],
    /// The modes, lowest first.
    pub modes: Vec<ModeReport>,
    /// Mesh level of the joints.
    pub mesh_level: usize,
    /// The joints' FEM convergence and cache use.
    pub joint_convergence: JointConvergence,
    /// Disagreements between `[flexures]` and the `[structure]` joints.
    pub warnings: Vec<String>,
}

/// The joints' common dimensions.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `side` | m | square rod |
/// | `radius` | m | slot fillet radius |
/// | `flat` | m | straight throat length of each notch |
/// | `gap` | m | full section between the notches |
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct JointGeometry {
    /// m, rod side.
    pub side: f64,
    /// m, fillet radius.
    pub radius: f64,
    /// m, straight throat length.
    pub flat: f64,
    /// m, gap between the notches.
    pub gap: f64,
}

/// The material of the joints.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `youngs` | Pa | Young's modulus |
/// | `poisson` | – | Poisson's ratio |
/// | `yield_strength` | Pa | yield strength |
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MaterialReport {
    /// Pa.
    pub youngs: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// Pa.
    pub yield_strength: f64,
}

/// One joint at one mesh level.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `level` | – | mesh level |
/// | `k_bend` | N·m/rad | bending stiffness about x, about y |
/// | `k_axial` | N/m | axial stiffness |
/// | `k_torsion` | N·m/rad | torsional stiffness |
/// | `max_stress_per_rad` | Pa/rad | peak von Mises stress per radian of bending about x, y |
/// | `dofs` | – | unknowns |
/// | `residual` | – | backward error of the worst load case |
/// | `cache` | – | as in [`JointFem`] |
/// | `cache_detail` | – | as in [`JointFem`] |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JointLevel {
    /// Mesh level.
    pub level: usize,
    /// N·m/rad, about x and y.
    pub k_bend: [f64; 2],
    /// N/m.
    pub k_axial: f64,
    /// N·m/rad.
    pub k_torsion: f64,
    /// Pa/rad, about x and y.
    pub max_stress_per_rad: [f64; 2],
    /// Unknowns.
    pub dofs: usize,
    /// Backward error.
    pub residual: f64,
    /// How the cache served it.
    pub cache: CacheStatus,
    /// Why an entry was refused or not written.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cache_detail: Option<String>,
}

/// One joint over the mesh levels, against the paper.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `joint` | – | `"J1, J2"` or `"J3"` |
/// | `throat` | m | its throat Δ |
/// | `paper_k_bend` | N·m/rad | the paper's stiffness (91.3, 340.3) |
/// | `levels` | – | [`JointLevel`], coarse to fine |
/// | `k_bend` | N·m/rad | the finest level's, about x and y |
/// | `relative_to_paper` | – | `k_bend / paper_k_bend − 1` |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JointRow {
    /// Which joint.
    pub joint: &'static str,
    /// m, throat.
    pub throat: f64,
    /// N·m/rad, the paper's.
    pub paper_k_bend: f64,
    /// Per level.
    pub levels: Vec<JointLevel>,
    /// N·m/rad, finest level.
    pub k_bend: [f64; 2],
    /// Finest level against the paper.
    pub relative_to_paper: [f64; 2],
}

/// `cellinject fea joints`: the joints by 3-D FEM with mesh convergence.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `geometry` | m | [`JointGeometry`] |
/// | `material` | – | [`MaterialReport`] |
/// | `joints` | – | [`JointRow`] of J1/J2 and J3 |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JointsReport {
    /// Common dimensions.
    pub geometry: JointGeometry,
    /// The material.
    pub material: MaterialReport,
    /// J1/J2 and J3.
    pub joints: Vec<JointRow>,
}

impl std::fmt::Display for PreloadKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            PreloadKind::Deflection => "deflection",
            PreloadKind::Torque => "torque",
        })
    }
}
