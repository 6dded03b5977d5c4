//! Three-dimensional FEM of the paper's double-notched two-axis joint (Fig. 3, Sec. 3.1).
//!
//! **Geometry.** A square rod of side `b` along z. Two circular notches of radius `R`
//! are cut into it, each by two cylinders on opposite faces, leaving a throat of
//! thickness `Δ` (the paper's "width Δ of the most bending-loaded area"):
//!
//! * notch A, centred at z = 0, thins the rod in x (thickness
//!   `h(z) = min(b, Δ + 2R − 2√(R² − z²))`): it is compliant in bending about **y**;
//! * notch B, centred at z = `2·z_e + gap`, thins it in y: compliant about **x**.
//!
//! `z_e = √(R² − (R − d)²)` with `d = (b − Δ)/2` is where a notch's cut meets the
//! rod's faces (`z_e = R` when the cut is a full half-circle, `b ≥ Δ + 2R`); the notch's
//! end sections lie at `±z_e` from its centre. `gap` is the full-section length between
//! the two notches.
//!
//! **Set-up**, following the rotational-stiffness definition used for every hinge in
//! this workspace: a block as long as the rod is wide (`b`) below notch A, clamped on its
//! bottom face; a block of the same length above notch B, loaded on its top face by a
//! force (uniform traction) or a moment (linear traction, or the torsional shear flow
//! `τ ∝ (−y, x)`). The joint's deformation is the relative rigid motion of its two end
//! sections (the bottom of notch A and the top of notch B), each fitted to the section's
//! nodal displacements by least squares; for a bending moment this is the least-squares
//! slope of the axial displacements. Six load cases give the joint's full 6x6 compliance
//! at the centre of its top end section.
//!
//! **Elements.** 27-node triquadratic hexahedra on a structured mesh that follows the
//! notch profiles (nodes in each cross-section spread over the local thickness, notch
//! layers spaced uniformly in the notch angle and graded towards the throat), 3x3x3
//! Gauss quadrature, isotropic linear elasticity. The stiffness matrix's lower triangle
//! is assembled straight into compressed columns and factorised by faer's supernodal
//! sparse Cholesky; the solution is refined and its backward error checked.
//!
//! **Stresses.** The stress tensor is evaluated at every element node for each unit
//! load, so that the von Mises stress of any combination of loads is exact
//! superposition ([`JointSolution::max_von_mises`]).

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky;
use faer::sparse::{SparseColMat, SymbolicSparseColMat};
use faer::{Conj, Mat, Side};
use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};
use rayon::prelude::*;

use cellinject_flexure::Material;
use cellinject_numeric::{Newton2Error, Newton2Options, newton2};

use crate::FemError;
use crate::lagrange::{G3, quad};

mod encoding;
mod fit;
mod grid;
pub use encoding::SOLUTION_ENCODING_VERSION;
use fit::*;
pub use fit::{FitStep, PairFit, fit_pair, fit_pair_observed};
use grid::*;

/// The double-notched joint's dimensions (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DoubleNotch {
    /// Side of the square rod, m.
    pub side: f64,
    /// Notch (fillet) radius, m.
    pub radius: f64,
    /// Length of the straight throat between the two fillets of a notch, m (0: a
    /// circular notch; > 0: a corner-filleted beam segment).
    pub flat: f64,
    /// Throat thickness Δ, m.
    pub throat: f64,
    /// Full-section length between the two notches, m.
    pub gap: f64,
}

/// z-coordinates of the joint's regions, from the clamped face up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Layout {
    /// Clamped bottom face.
    pub bottom: f64,
    /// Bottom end section (start of notch A).
    pub lower_end: f64,
    /// Centre of notch A.
    pub notch_a: f64,
    /// End of notch A.
    pub a_end: f64,
    /// Start of notch B.
    pub b_start: f64,
    /// Centre of notch B.
    pub notch_b: f64,
    /// Top end section (end of notch B).
    pub upper_end: f64,
    /// Loaded top face.
    pub top: f64,
}

impl DoubleNotch {
    /// Checks the dimensions.
    pub fn validate(&self) -> Result<(), FemError> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        if !ok(self.side) || !ok(self.radius) || !ok(self.throat) {
            return Err(FemError::Invalid(format!(
                "side {:e} m, radius {:e} m and throat {:e} m must be positive",
                self.side, self.radius, self.throat
            )));
        }
        for (name, v) in [("gap", self.gap), ("flat", self.flat)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(FemError::Invalid(format!(
                    "{name} {v:e} m must be zero or positive"
                )));
            }
        }
        if self.throat >= self.side {
            return Err(FemError::Invalid(format!(
                "throat {:e} m must be thinner than the rod side {:e} m",
                self.throat, self.side
            )));
        }
        Ok(())
    }

    /// Depth of each cut, `(b − Δ)/2`.
    pub fn depth(&self) -> f64 {
        0.5 * (self.side - self.throat)
    }

    /// Half-length of one rounded end of a notch (the fillet), along the rod.
    pub fn fillet_length(&self) -> f64 {
        let d = self.depth().min(self.radius);
        let r = self.radius;
        (r * r - (r - d) * (r - d)).max(0.0).sqrt()
    }

    /// Half-length of a notch along the rod, `z_e` (flat part and one fillet).
    pub fn half_length(&self) -> f64 {
        0.5 * self.flat + self.fillet_length()
    }

    /// The region boundaries.
    pub fn layout(&self) -> Layout {
        let ze = self.half_length();
        let b = self.side;
        Layout {
            bottom: -ze - b,
            lower_end: -ze,
            notch_a: 0.0,
            a_end: ze,
            b_start: ze + self.gap,
            notch_b: 2.0 * ze + self.gap,
            upper_end: 3.0 * ze + self.gap,
            top: 3.0 * ze + self.gap + b,
        }
    }

    /// Thickness of one notch at distance `s` from its centre.
    fn notch_thickness(&self, s: f64) -> f64 {
        let r = self.radius;
        let a = (s.abs() - 0.5 * self.flat).max(0.0);
        if a >= r {
            return self.side;
        }
        (self.throat + 2.0 * r - 2.0 * (r * r - a * a).sqrt()).min(self.side)
    }

    /// Cross-section `(extent in x, extent in y)` at height z.
    pub fn section(&self, z: f64) -> (f64, f64) {
        let l = self.layout();
        let hx = if z > l.lower_end && z < l.a_end {
            self.notch_thickness(z - l.notch_a)
        } else {
            self.side
        };
        let hy = if z > l.b_start && z < l.upper_end {
            self.notch_thickness(z - l.notch_b)
        } else {
            self.side
        };
        (hx, hy)
    }
}

/// Element counts at refinement level 1 (each level multiplies every count).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointMesh {
    /// Elements across the rod, in x and in y.
    pub across: usize,
    /// Elements along each notch.
    pub notch: usize,
    /// Elements along each end block.
    pub block: usize,
    /// Elements along the gap between the notches (none if the gap is zero).
    pub gap: usize,
    /// Grading of the notch layers towards the throat (1 = uniform in angle).
    pub grading: f64,
}

impl Default for JointMesh {
    fn default() -> Self {
        JointMesh {
            across: 4,
            notch: 12,
            block: 3,
            gap: 2,
            grading: 1.4,
        }
    }
}

impl JointMesh {
    /// Unknowns of the mesh at `level` for a joint (clamped layer and cut-away
    /// shoulders removed).
    pub fn unknowns(&self, joint: &DoubleNotch, level: usize) -> usize {
        build_grid(joint, self, level).n_dof
    }

    fn counts(&self, joint: &DoubleNotch, level: usize) -> (usize, usize, usize, usize) {
        let l = level.max(1);
        let gap = if joint.gap > 0.0 {
            (self.gap * l).max(1)
        } else {
            0
        };
        (
            (self.across * l).max(1),
            (self.notch * l).max(4),
            (self.block * l).max(1),
            gap,
        )
    }
}

/// Index of the six generalised components: translations x, y, z, rotations x, y, z.
pub const COMPONENTS: [&str; 6] = ["ux", "uy", "uz", "rx", "ry", "rz"];

/// The joint's solution.
#[derive(Debug, Clone)]
pub struct JointSolution {
    /// 6x6 compliance at the centre of the top end section: relative motion (m, rad)
    /// of the top end section against the bottom one, per unit wrench (N, N·m) applied
    /// at that point. Symmetric to rounding.
    pub compliance: Matrix6<f64>,
    /// 6x6 compliance between sections in the middle of the two blocks (local z in
    /// `block_sections`), referred to the upper one's centre: the notches' section
    /// warping has died out there, so this is the compliance to join rigid bodies with.
    pub block_compliance: Matrix6<f64>,
    /// Local z of the block sections of `block_compliance` (lower, upper), m.
    pub block_sections: [f64; 2],
    /// Largest `|C_ij − C_ji| / √(C_ii C_jj)` before symmetrisation: how far the fitted
    /// section motions are from work-conjugate (section warping).
    pub asymmetry: f64,
    /// Bending stiffness about x (notch B) and about y (notch A) for a pure moment,
    /// N·m/rad: the stiffness definition of the crate.
    pub k_bend: [f64; 2],
    /// Axial stiffness between the end sections, N/m.
    pub k_axial: f64,
    /// Torsional stiffness, N·m/rad.
    pub k_torsion: f64,
    /// Region boundaries.
    pub layout: Layout,
    /// Unknowns.
    pub dofs: usize,
    /// Elements.
    pub elements: usize,
    /// Backward error of the worst load case after refinement.
    pub residual: f64,
    /// Stress tensors (xx, yy, zz, yz, xz, xy; Pa) at every element node between the
    /// end sections for a unit wrench component at the top end section.
    stress_basis: Vec<[[f64; 6]; 6]>,
    /// Where each entry of the stress basis lies (m).
    stress_points: Vec<[f64; 3]>,
}

impl JointSolution {
    /// Stiffness matrix (inverse of the compliance).
    pub fn stiffness(&self) -> Option<Matrix6<f64>> {
        self.compliance.try_inverse()
    }

    /// Largest von Mises stress (Pa) in the joint under a wrench (N, N·m) at the top end
    /// section, by superposition of the unit load cases.
    pub fn max_von_mises(&self, wrench: &Vector6<f64>) -> f64 {
        self.peak_von_mises(wrench).0
    }

    /// A wrench given at the upper block section moved to the top end section:
    /// `M_end = M + (c_block − c_end) × F`.
    fn block_to_end(&self, wrench: &Vector6<f64>) -> Vector6<f64> {
        let arm = Vector3::new(0.0, 0.0, self.block_sections[1] - self.layout.upper_end);
        let f = Vector3::new(wrench[0], wrench[1], wrench[2]);
        let m = Vector3::new(wrench[3], wrench[4], wrench[5]) + arm.cross(&f);
        Vector6::new(f[0], f[1], f[2], m[0], m[1], m[2])
    }

    /// Largest von Mises stress (Pa) and where, for a wrench given at the upper block
    /// section of [`JointSolution::block_compliance`].
    pub fn peak_von_mises_block(&self, wrench: &Vector6<f64>) -> (f64, [f64; 3]) {
        self.peak_von_mises(&self.block_to_end(wrench))
    }

    /// The stress tensor (xx, yy, zz, yz, xz, xy; Pa) at every stress point, for a
    /// wrench given at the upper block section (superposition of the unit load cases).
    pub fn stresses_block(&self, wrench: &Vector6<f64>) -> Vec<[f64; 6]> {
        let w = self.block_to_end(wrench);
        self.stress_basis
            .iter()
            .map(|b| {
                let mut s = [0.0; 6];
                for c in 0..6 {
                    for j in 0..6 {
                        s[c] += b[c][j] * w[j];
                    }
                }
                s
            })
            .collect()
    }

    /// Largest von Mises stress (Pa) under a wrench and where it occurs (m, joint frame).
    pub fn peak_von_mises(&self, wrench: &Vector6<f64>) -> (f64, [f64; 3]) {
        let mut best = (0.0, [0.0; 3]);
        for (b, p) in self.stress_basis.iter().zip(&self.stress_points) {
            let mut s = [0.0; 6];
            for c in 0..6 {
                for j in 0..6 {
                    s[c] += b[c][j] * wrench[j];
                }
            }
            let v = von_mises(&s);
            if v > best.0 {
                best = (v, *p);
            }
        }
        best
    }

    /// Largest von Mises stress for a relative motion of the end sections (m, rad).
    pub fn max_von_mises_for_motion(&self, motion: &Vector6<f64>) -> Option<f64> {
        self.stiffness().map(|k| self.max_von_mises(&(k * motion)))
    }

    /// Largest von Mises stress per radian of pure bending about x and about y, Pa/rad.
    pub fn max_stress_per_rad(&self) -> [f64; 2] {
        let mut out = [0.0; 2];
        for (a, o) in out.iter_mut().enumerate() {
            let mut w = Vector6::zeros();
            w[3 + a] = self.k_bend[a];
            *o = self.max_von_mises(&w);
        }
        out
    }
}

/// Von Mises equivalent stress of (xx, yy, zz, yz, xz, xy).
pub fn von_mises(s: &[f64; 6]) -> f64 {
    let d = (s[0] - s[1]).powi(2) + (s[1] - s[2]).powi(2) + (s[2] - s[0]).powi(2);
    (0.5 * d + 3.0 * (s[3] * s[3] + s[4] * s[4] + s[5] * s[5])).sqrt()
}

/// Shape-function derivatives (natural coordinates) of the 27 nodes at one point.
fn natural_gradients(xi: f64, eta: f64, zeta: f64) -> [[f64; 3]; 27] {
    let (nx, dx) = quad(xi);
    let (ny, dy) = quad(eta);
    let (nz, dz) = quad(zeta);
    let mut g = [[0.0; 3]; 27];
    for c in 0..3 {
        for b in 0..3 {
            for a in 0..3 {
                g[(c * 3 + b) * 3 + a] = [
                    dx[a] * ny[b] * nz[c],
                    nx[a] * dy[b] * nz[c],
                    nx[a] * ny[b] * dz[c],
                ];
            }
        }
    }
    g
}

/// Physical gradients of the 27 shape functions and the Jacobian determinant.
fn physical_gradients(nat: &[[f64; 3]; 27], xyz: &[[f64; 3]; 27]) -> Option<([[f64; 3]; 27], f64)> {
    let mut j = Matrix3::zeros();
    for k in 0..27 {
        for r in 0..3 {
            for c in 0..3 {
                j[(r, c)] += nat[k][r] * xyz[k][c];
            }
        }
    }
    let det = j.determinant();
    let inv = j.try_inverse()?;
    let mut g = [[0.0; 3]; 27];
    for k in 0..27 {
        for r in 0..3 {
            g[k][r] = inv[(r, 0)] * nat[k][0] + inv[(r, 1)] * nat[k][1] + inv[(r, 2)] * nat[k][2];
        }
    }
    Some((g, det))
}

/// The 27x27 node-pair blocks (3x3 each) of one element's stiffness.
type ElementMatrix = Box<[[[f64; 9]; 27]; 27]>;

/// Element matrix's lower node-pair blocks: `ke[a][b]` for the 27 local nodes.
fn element_matrix(
    xyz: &[[f64; 3]; 27],
    gauss: &[([[f64; 3]; 27], f64)],
    lambda: f64,
    mu: f64,
) -> Result<ElementMatrix, f64> {
    let mut ke = Box::new([[[0.0; 9]; 27]; 27]);
    for (nat, w) in gauss {
        let Some((g, det)) = physical_gradients(nat, xyz) else {
            return Err(0.0);
        };
        if det <= 0.0 {
            return Err(det);
        }
        let f = w * det;
        for a in 0..27 {
            let ga = g[a];
            for b in 0..=a {
                let gb = g[b];
                let dot = mu * (ga[0] * gb[0] + ga[1] * gb[1] + ga[2] * gb[2]);
                let blk = &mut ke[a][b];
                for r in 0..3 {
                    for c in 0..3 {
                        blk[r * 3 + c] += f * (lambda * ga[r] * gb[c] + mu * ga[c] * gb[r]);
                    }
                    blk[r * 3 + r] += f * dot;
                }
            }
        }
    }
    Ok(ke)
}

/// Memory one joint's solve can hand to the next: the Cholesky factor's values
/// (1.5 GB at level 2). A caller solving several joints in turn passes the same
/// workspace to each ([`solve_in`]): the factor's pages are then written again instead
/// of mapped afresh, each page a fault (`fea joints --levels 1,2` on a 2-core VM, four
/// runs alternated with and without: kernel time 5.4-9.9 s against 7.4-13.8 s, wall
/// time 8 % less at the median; the same numbers to the bit). Dropping the workspace
/// frees the memory.
#[derive(Debug, Default)]
pub struct JointWorkspace {
    factor: Vec<f64>,
}

/// Solves the joint at a refinement level: six load cases, one factorisation.
pub fn solve(
    joint: &DoubleNotch,
    m: &Material,
    mesh: &JointMesh,
    level: usize,
) -> Result<JointSolution, FemError> {
    solve_in(joint, m, mesh, level, &mut JointWorkspace::default())
}

/// [`solve`], the factor's memory taken from (and left in) `workspace`.
pub fn solve_in(
    joint: &DoubleNotch,
    m: &Material,
    mesh: &JointMesh,
    level: usize,
    workspace: &mut JointWorkspace,
) -> Result<JointSolution, FemError> {
    joint.validate()?;
    if !(m.youngs > 0.0 && m.poisson > -1.0 && m.poisson < 0.5) {
        return Err(FemError::Invalid(format!(
            "material E = {:e} Pa, ν = {} is not a valid isotropic solid",
            m.youngs, m.poisson
        )));
    }
    let g = build_grid(joint, mesh, level);
    let lame = Lame {
        lambda: m.youngs * m.poisson / ((1.0 + m.poisson) * (1.0 - 2.0 * m.poisson)),
        mu: m.shear(),
    };
    let mut gauss = Vec::with_capacity(27);
    for &(c, wc) in &G3 {
        for &(b, wb) in &G3 {
            for &(a, wa) in &G3 {
                gauss.push((natural_gradients(a, b, c), wa * wb * wc));
            }
        }
    }
    let pat = pattern(&g);
    let values = assemble(&g, &pat, &gauss, lame)?;
    let rhs = top_face_loads(&g);
    let (u, residual) = factor_and_solve(&g, &pat, values, &rhs, &mut workspace.factor)?;
    let Sections {
        compliance,
        asymmetry,
        block_compliance,
        block_sections,
    } = sections(&g, &u)?;
    let (stress_points, stress_basis) = stresses(&g, &u, &gauss, lame)?;
    let k_bend = [1.0 / compliance[(3, 3)], 1.0 / compliance[(4, 4)]];
    Ok(JointSolution {
        k_bend,
        k_axial: 1.0 / compliance[(2, 2)],
        k_torsion: 1.0 / compliance[(5, 5)],
        compliance,
        asymmetry,
        block_compliance,
        block_sections,
        layout: joint.layout(),
        dofs: g.n_dof,
        elements: g.active.len(),
        residual,
        stress_basis,
        stress_points,
    })
}

/// The material's Lamé constants, Pa.
#[derive(Debug, Clone, Copy)]
struct Lame {
    lambda: f64,
    mu: f64,
}

/// The Gauss points of an element: the shape functions' natural gradients and the
/// weight.
type Gauss = [([[f64; 3]; 27], f64)];

/// The stiffness matrix's lower triangle in the pattern's order: the element matrices
/// in parallel, a chunk at a time, scattered serially.
fn assemble(g: &Grid, pat: &Pattern, gauss: &Gauss, lame: Lame) -> Result<Vec<f64>, FemError> {
    let Lame { lambda, mu } = lame;
    let n_el = g.active.len();
    let element_nodes = |e: usize| g.element_nodes(g.active[e]);
    let mut values = vec![0.0f64; pat.row_idx.len()];
    const CHUNK: usize = 256;
    for start in (0..n_el).step_by(CHUNK) {
        let end = (start + CHUNK).min(n_el);
        let mats: Vec<Result<ElementMatrix, (usize, f64)>> = (start..end)
            .into_par_iter()
            .map(|e| {
                let ids = element_nodes(e);
                let xyz: [[f64; 3]; 27] = std::array::from_fn(|k| g.coords[ids[k]]);
                element_matrix(&xyz, gauss, lambda, mu).map_err(|d| (e, d))
            })
            .collect();
        for (off, res) in mats.into_iter().enumerate() {
            let ke =
                res.map_err(|(element, jacobian)| FemError::InvertedElement { element, jacobian })?;
            let ids = element_nodes(start + off);
            for a in 0..27 {
                for b in 0..27 {
                    // Lower triangle: global id of the row node ≥ the column node's.
                    let (ra, cb_node) = (ids[a], ids[b]);
                    let dcb = g.dof[cb_node];
                    if ra < cb_node || dcb == usize::MAX {
                        continue;
                    }
                    let blk = if a >= b { &ke[a][b] } else { &ke[b][a] };
                    let transpose = a < b;
                    let list = &pat.neighbours[dcb / 3];
                    let Ok(pos) = list.binary_search(&ra) else {
                        continue;
                    };
                    for cb in 0..3 {
                        let col = dcb + cb;
                        for ca in 0..3 {
                            if ra == cb_node && ca < cb {
                                continue;
                            }
                            let v = if transpose {
                                blk[cb * 3 + ca]
                            } else {
                                blk[ca * 3 + cb]
                            };
                            values[pat.col_ptr[col] + 3 * pos + ca - cb] += v;
                        }
                    }
                }
            }
        }
    }
    Ok(values)
}

/// The six unit load cases on the top face (forces and moments at its centre), as
/// consistent nodal loads: one column per case.
fn top_face_loads(g: &Grid) -> Mat<f64> {
    let [ex, ey, _] = g.ne;
    let top_k = g.nk - 1;
    let (mut area, mut ixx, mut iyy) = (0.0, 0.0, 0.0);
    let face_points = |visit: &mut dyn FnMut([usize; 9], [f64; 9], f64, f64, f64)| {
        for fj in 0..ey {
            for fi in 0..ex {
                let ids: [usize; 9] =
                    std::array::from_fn(|q| g.id(2 * fi + q % 3, 2 * fj + q / 3, top_k));
                for &(eta, wy) in &G3 {
                    for &(xi, wx) in &G3 {
                        let (nx, dx) = quad(xi);
                        let (ny, dy) = quad(eta);
                        let n: [f64; 9] = std::array::from_fn(|q| nx[q % 3] * ny[q / 3]);
                        let (mut x, mut y) = (0.0, 0.0);
                        let mut jac = [[0.0; 2]; 2];
                        for q in 0..9 {
                            let p = g.coords[ids[q]];
                            x += n[q] * p[0];
                            y += n[q] * p[1];
                            let (dxi, deta) = (dx[q % 3] * ny[q / 3], nx[q % 3] * dy[q / 3]);
                            jac[0][0] += dxi * p[0];
                            jac[0][1] += dxi * p[1];
                            jac[1][0] += deta * p[0];
                            jac[1][1] += deta * p[1];
                        }
                        let det = jac[0][0] * jac[1][1] - jac[0][1] * jac[1][0];
                        visit(ids, n, x, y, wx * wy * det);
                    }
                }
            }
        }
    };
    face_points(&mut |_, _, x, y, w| {
        area += w;
        ixx += w * y * y;
        iyy += w * x * x;
    });
    let jp = ixx + iyy;
    let mut rhs = Mat::<f64>::zeros(g.n_dof, 6);
    face_points(&mut |ids, n, x, y, w| {
        // Tractions of the six unit cases.
        let t: [[f64; 3]; 6] = [
            [1.0 / area, 0.0, 0.0],
            [0.0, 1.0 / area, 0.0],
            [0.0, 0.0, 1.0 / area],
            [0.0, 0.0, y / ixx],
            [0.0, 0.0, -x / iyy],
            [-y / jp, x / jp, 0.0],
        ];
        for q in 0..9 {
            let d = g.dof[ids[q]];
            for (case, tc) in t.iter().enumerate() {
                for c in 0..3 {
                    rhs[(d + c, case)] += w * n[q] * tc[c];
                }
            }
        }
    });
    rhs
}

/// The displacements of the six load cases: the matrix factorised once (Cholesky,
/// geometric nested dissection) and the solutions refined; with the refinement's
/// residual. The factor's values are kept in `factor` (resized; its memory reused).
fn factor_and_solve(
    g: &Grid,
    pat: &Pattern,
    values: Vec<f64>,
    rhs: &Mat<f64>,
    factor: &mut Vec<f64>,
) -> Result<(Mat<f64>, f64), FemError> {
    let n_dof = g.n_dof;
    let symbolic = SymbolicSparseColMat::<usize>::new_checked(
        n_dof,
        n_dof,
        pat.col_ptr.clone(),
        None,
        pat.row_idx.clone(),
    );
    let k = SparseColMat::<usize, f64>::new(symbolic, values);
    // Geometric nested dissection of the structured grid (separators are node planes
    // on element boundaries): far less fill than AMD on this slender solid.
    let order = nested_dissection(g);
    let mut inverse = vec![0usize; n_dof];
    for (new, &old) in order.iter().enumerate() {
        inverse[old] = new;
    }
    let perm = faer::perm::PermRef::new_checked(&order, &inverse, n_dof);
    let not_pd = |reason: String| FemError::NotPositiveDefinite {
        dofs: n_dof,
        reason,
    };
    let symbolic = cholesky::factorize_symbolic_cholesky(
        k.symbolic(),
        Side::Lower,
        cholesky::SymmetricOrdering::Custom(perm),
        Default::default(),
    )
    .map_err(|e| not_pd(format!("{e:?}")))?;
    let par = faer::get_global_parallelism();
    // Only the length is set (faer fills the factor with zeros itself): a reused
    // buffer keeps its pages.
    factor.resize(symbolic.len_val(), 0.0);
    let mut buf =
        MemBuffer::new(symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()));
    let llt = symbolic
        .factorize_numeric_llt(
            factor,
            k.as_ref(),
            Side::Lower,
            Default::default(),
            par,
            MemStack::new(&mut buf),
            Default::default(),
        )
        .map_err(|e| not_pd(format!("{e:?}")))?;
    let mut solve_buf = MemBuffer::new(symbolic.solve_in_place_scratch::<f64>(6, par));
    let mut solve = |b: &Mat<f64>| {
        let mut x = b.clone();
        llt.solve_in_place_with_conj(Conj::No, x.as_mut(), par, MemStack::new(&mut solve_buf));
        x
    };
    let mut u = solve(rhs);
    let residual = refine(&k, &mut solve, rhs, &mut u, n_dof)?;
    Ok((u, residual))
}

/// The compliances [`sections`] measures.
struct Sections {
    compliance: Matrix6<f64>,
    asymmetry: f64,
    block_compliance: Matrix6<f64>,
    block_sections: [f64; 2],
}

/// The joint's compliance between its end sections, and the blocks' between their
/// middles, from rigid fits of the sections' displacements.
fn sections(g: &Grid, u: &Mat<f64>) -> Result<Sections, FemError> {
    let top_k = g.nk - 1;
    // Rigid fits of the end sections.
    let section = |kk: usize, case: usize| -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        let pts: Vec<(Vector3<f64>, Vector3<f64>)> = (0..g.nj)
            .flat_map(|j| (0..g.ni).map(move |i| (i, j)))
            .filter_map(|(i, j)| {
                let id = g.id(i, j, kk);
                let p = Vector3::from(g.coords[id]);
                let d = g.dof[id];
                (d != usize::MAX).then(|| {
                    (
                        p,
                        Vector3::new(u[(d, case)], u[(d + 1, case)], u[(d + 2, case)]),
                    )
                })
            })
            .collect();
        rigid_fit(&pts)
    };
    // Compliance between two node layers, referred to the upper one's centre.
    let between = |k_lo: usize, k_up: usize| -> Result<(Matrix6<f64>, f64), FemError> {
        let mut motion = Matrix6::zeros();
        let c_up = Vector3::new(0.0, 0.0, g.zs[k_up]);
        for case in 0..6 {
            let (cl, u_lo, th_lo) = section(k_lo, case);
            let (cu, u_up, th_up) = section(k_up, case);
            let u_lo_at = u_lo + th_lo.cross(&(c_up - cl));
            let u_up_at = u_up + th_up.cross(&(c_up - cu));
            let du = u_up_at - u_lo_at;
            let dth = th_up - th_lo;
            for r in 0..3 {
                motion[(r, case)] = du[r];
                motion[(3 + r, case)] = dth[r];
            }
        }
        let w_inv = face_to_section(g.zs[top_k] - g.zs[k_up])?;
        let raw = motion * w_inv;
        // Maxwell-Betti makes the compliance symmetric for work-conjugate measures; a
        // least-squares rigid fit of a warping section is only nearly so. The symmetric
        // part is kept and the relative size of the antisymmetric part reported.
        let mut asymmetry: f64 = 0.0;
        for r in 0..6 {
            for q in 0..6 {
                let scale = (raw[(r, r)] * raw[(q, q)]).abs().sqrt();
                if scale > 0.0 {
                    asymmetry = asymmetry.max((raw[(r, q)] - raw[(q, r)]).abs() / scale);
                }
            }
        }
        Ok((0.5 * (raw + raw.transpose()), asymmetry))
    };
    let (compliance, asymmetry) = between(g.lower_k, g.upper_k)?;
    // Sections in the middle of the blocks, where the notches' warping has died out:
    // the compliance a structural model should join rigid bodies with.
    let (k_blo, k_bup) = (g.lower_k / 2, (g.upper_k + g.nk - 1) / 2);
    let (block_compliance, _) = between(k_blo, k_bup)?;
    let block_sections = [g.zs[k_blo], g.zs[k_bup]];
    Ok(Sections {
        compliance,
        asymmetry,
        block_compliance,
        block_sections,
    })
}

/// Stresses at the element nodes between the end sections, per unit section wrench:
/// the points and, for each, the six stress components of the six unit wrenches.
#[allow(clippy::type_complexity)]
fn stresses(
    g: &Grid,
    u: &Mat<f64>,
    gauss: &Gauss,
    lame: Lame,
) -> Result<(Vec<[f64; 3]>, Vec<[[f64; 6]; 6]>), FemError> {
    let Lame { lambda, mu } = lame;
    let [ex, ey, _] = g.ne;
    let n_el = g.active.len();
    let top_k = g.nk - 1;
    let element_nodes = |e: usize| g.element_nodes(g.active[e]);
    // Face cases as unit wrenches at the top end section, for the stresses.
    let w_inv = face_to_section(g.zs[top_k] - g.zs[g.upper_k])?;
    // Stresses at the Gauss points, extrapolated to the element nodes by the quadratic
    // through the Gauss points (as finite-element codes report nodal stresses): robust
    // where the mapped fillet elements are skewed, exact for a quadratic stress field.
    let a = G3[2].0;
    let lagrange = |x: f64| {
        [
            x * (x - a) / (2.0 * a * a),
            1.0 - x * x / (a * a),
            x * (x + a) / (2.0 * a * a),
        ]
    };
    let ext: [[f64; 3]; 3] = [lagrange(-1.0), lagrange(0.0), lagrange(1.0)];
    // Stresses between the end sections only: the clamped and loaded faces' edges of the
    // blocks are singular in linear elasticity and are not part of the joint.
    let layer_of = |e: usize| 2 * (g.active[e] / (ex * ey));
    let stressed: Vec<([f64; 3], [[f64; 6]; 6])> = (0..n_el)
        .into_par_iter()
        .filter(|&e| layer_of(e) >= g.lower_k && layer_of(e) < g.upper_k)
        .flat_map_iter(|e| {
            let ids = element_nodes(e);
            let xyz: [[f64; 3]; 27] = std::array::from_fn(|k| g.coords[ids[k]]);
            let mut at_gauss = [[[0.0f64; 6]; 6]; 27];
            for (q, (nat, _)) in gauss.iter().enumerate() {
                let Some((gr, _)) = physical_gradients(nat, &xyz) else {
                    continue;
                };
                let s_cases = &mut at_gauss[q];
                for case in 0..6 {
                    let mut eps = [0.0f64; 6];
                    for k in 0..27 {
                        let d = g.dof[ids[k]];
                        if d == usize::MAX {
                            continue;
                        }
                        let (ux, uy, uz) = (u[(d, case)], u[(d + 1, case)], u[(d + 2, case)]);
                        let gk = gr[k];
                        eps[0] += gk[0] * ux;
                        eps[1] += gk[1] * uy;
                        eps[2] += gk[2] * uz;
                        eps[3] += gk[2] * uy + gk[1] * uz;
                        eps[4] += gk[2] * ux + gk[0] * uz;
                        eps[5] += gk[1] * ux + gk[0] * uy;
                    }
                    let tr = eps[0] + eps[1] + eps[2];
                    for c in 0..3 {
                        s_cases[case][c] = lambda * tr + 2.0 * mu * eps[c];
                        s_cases[case][3 + c] = mu * eps[3 + c];
                    }
                }
            }
            let mut out = Vec::with_capacity(27);
            for q in 0..27 {
                let (na, nb, nc) = (q % 3, (q / 3) % 3, q / 9);
                let mut s_cases = [[0.0f64; 6]; 6];
                for gq in 0..27 {
                    let (ga, gb, gc) = (gq % 3, (gq / 3) % 3, gq / 9);
                    let w = ext[na][ga] * ext[nb][gb] * ext[nc][gc];
                    for i in 0..6 {
                        for c in 0..6 {
                            s_cases[i][c] += w * at_gauss[gq][i][c];
                        }
                    }
                }
                // Convert face cases to unit section wrenches.
                let mut b = [[0.0f64; 6]; 6];
                for c in 0..6 {
                    for j in 0..6 {
                        b[c][j] = (0..6).map(|i| s_cases[i][c] * w_inv[(i, j)]).sum();
                    }
                }
                out.push((xyz[q], b));
            }
            out
        })
        .collect();
    Ok(stressed.into_iter().unzip())
}

/// The six unit face loads (forces and moments at the loaded face's centre) seen as
/// wrenches at a section `arm` below the face (`M_sec = M + arm ẑ × F`), inverted:
/// column j holds the face-load amplitudes that make a unit wrench component j there.
fn face_to_section(arm: f64) -> Result<Matrix6<f64>, FemError> {
    let arm = Vector3::new(0.0, 0.0, arm);
    let mut wrench = Matrix6::identity();
    for c in 0..3 {
        let mut f = Vector3::zeros();
        f[c] = 1.0;
        let mom = arm.cross(&f);
        for r in 0..3 {
            wrench[(3 + r, c)] = mom[r];
        }
    }
    wrench.try_inverse().ok_or_else(|| {
        FemError::Invalid("singular load-case matrix (zero-length top block)".into())
    })
}

/// Iterative refinement with the lower-triangle matrix; returns the worst backward
/// error `|f − K u|∞ / (|K|∞ |u|∞ + |f|∞)` over the columns.
fn refine(
    k: &SparseColMat<usize, f64>,
    solve: &mut dyn FnMut(&Mat<f64>) -> Mat<f64>,
    rhs: &Mat<f64>,
    u: &mut Mat<f64>,
    n: usize,
) -> Result<f64, FemError> {
    let (sym, vals) = k.parts();
    let col_ptr = sym.col_ptr();
    let row_idx = sym.row_idx();
    let mut k_row = vec![0.0f64; n];
    for c in 0..n {
        for p in col_ptr[c]..col_ptr[c + 1] {
            let r = row_idx[p];
            k_row[r] += vals[p].abs();
            if r != c {
                k_row[c] += vals[p].abs();
            }
        }
    }
    let k_inf = k_row.iter().cloned().fold(0.0, f64::max);
    let cols = rhs.ncols();
    let mut worst = 0.0f64;
    for _ in 0..3 {
        let mut r = rhs.clone();
        for c in 0..n {
            for p in col_ptr[c]..col_ptr[c + 1] {
                let row = row_idx[p];
                let v = vals[p];
                for j in 0..cols {
                    r[(row, j)] -= v * u[(c, j)];
                    if row != c {
                        r[(c, j)] -= v * u[(row, j)];
                    }
                }
            }
        }
        worst = 0.0;
        for j in 0..cols {
            let ru = (0..n).map(|i| r[(i, j)].abs()).fold(0.0, f64::max);
            let uu = (0..n).map(|i| u[(i, j)].abs()).fold(0.0, f64::max);
            let ff = (0..n).map(|i| rhs[(i, j)].abs()).fold(0.0, f64::max);
            worst = worst.max(ru / (k_inf * uu + ff));
        }
        if worst < 1e-15 {
            break;
        }
        let du = solve(&r);
        *u += du;
    }
    if worst.is_nan() || worst >= 1e-13 {
        return Err(FemError::Residual {
            residual: worst,
            tolerance: 1e-13,
            dofs: n,
        });
    }
    Ok(worst)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn steel() -> Material {
        Material::x2crni18_9()
    }

    #[test]
    fn a_plain_rod_matches_beam_theory() {
        // A throat as thick as the rod leaves a plain square rod between the sections:
        // bending k = E I / L, axial E A / L, torsion G·0.1406 b⁴ / L (Saint-Venant,
        // square section), within the few per cent that end-section warping costs.
        let joint = DoubleNotch {
            side: 4e-3,
            radius: 3e-3,
            flat: 0.0,
            throat: 4e-3 * 0.999,
            gap: 10e-3,
        };
        let m = steel();
        let s = solve(&joint, &m, &JointMesh::default(), 1).unwrap();
        let len = s.layout.upper_end - s.layout.lower_end;
        let b: f64 = 4e-3;
        let i = b.powi(4) / 12.0;
        let kb = m.youngs * i / len;
        assert!(
            (s.k_bend[0] / kb - 1.0).abs() < 0.01,
            "{} {kb}",
            s.k_bend[0]
        );
        assert!((s.k_bend[1] / kb - 1.0).abs() < 0.01);
        let ka = m.youngs * b * b / len;
        assert!((s.k_axial / ka - 1.0).abs() < 0.01, "{} {ka}", s.k_axial);
        let kt = m.shear() * 0.1406 * b.powi(4) / len;
        assert!(
            (s.k_torsion / kt - 1.0).abs() < 0.03,
            "{} {kt}",
            s.k_torsion
        );
        assert!(s.residual < 1e-13);
    }

    #[test]
    fn compliance_is_symmetric_and_positive() {
        let joint = DoubleNotch {
            side: 6e-3,
            radius: 2.5e-3,
            flat: 0.0,
            throat: 1.2e-3,
            gap: 2e-3,
        };
        let s = solve(&joint, &steel(), &JointMesh::default(), 1).unwrap();
        let c = s.compliance;
        // Reciprocity, up to the warping of the fitted sections.
        assert!(s.asymmetry < 1e-3, "{}", s.asymmetry);
        assert!(c.symmetric_eigenvalues().iter().all(|&e| e > 0.0));
        // The two notches are alike: equal bending stiffness about x and y.
        assert!((s.k_bend[0] / s.k_bend[1] - 1.0).abs() < 0.02);
    }

    /// One workspace through a larger mesh, a smaller one (the factor's memory then
    /// holds the larger's values beyond the smaller's) and the larger again: each
    /// solution is the fresh solve's, to the bit.
    /// A joint with a flat and a coarse mesh of it: solved in a second, for the tests
    /// of what a solve is and keeps rather than of its accuracy.
    fn coarse_joint() -> (DoubleNotch, JointMesh) {
        let joint = DoubleNotch {
            side: 6e-3,
            radius: 2.5e-3,
            flat: 0.5e-3,
            throat: 1.2e-3,
            gap: 2e-3,
        };
        let mesh = JointMesh {
            across: 2,
            notch: 4,
            block: 1,
            gap: 1,
            grading: 1.0,
        };
        (joint, mesh)
    }

    #[test]
    fn a_reused_workspace_gives_the_fresh_solutions() {
        let (joint, coarse) = coarse_joint();
        let fine = JointMesh {
            across: 4,
            notch: 6,
            ..coarse
        };
        let mut ws = JointWorkspace::default();
        for mesh in [&fine, &coarse, &fine] {
            let fresh = solve(&joint, &steel(), mesh, 1).unwrap();
            let reused = solve_in(&joint, &steel(), mesh, 1, &mut ws).unwrap();
            assert_eq!(reused.to_bytes(), fresh.to_bytes(), "{mesh:?}");
        }
        assert!(ws.factor.capacity() > 0);
    }

    #[test]
    fn a_solution_survives_its_byte_encoding_bit_for_bit() {
        // A coarse mesh: only the encoding is under test.
        let (joint, mesh) = coarse_joint();
        let s = solve(&joint, &steel(), &mesh, 1).unwrap();
        let bytes = s.to_bytes();
        let back = JointSolution::from_bytes(&bytes).unwrap();
        assert_eq!(back.to_bytes(), bytes);
        assert_eq!(back.compliance, s.compliance);
        assert_eq!(back.block_compliance, s.block_compliance);
        assert_eq!(back.block_sections, s.block_sections);
        assert_eq!(back.layout, s.layout);
        assert_eq!(
            (back.dofs, back.elements, back.residual.to_bits()),
            (s.dofs, s.elements, s.residual.to_bits())
        );
        assert_eq!(back.k_bend, s.k_bend);
        assert_eq!(back.stress_basis, s.stress_basis);
        assert_eq!(back.stress_points, s.stress_points);
        assert!(!s.stress_points.is_empty());
        let w = Vector6::new(1.0, -2.0, 30.0, 0.4, -0.5, 0.06);
        assert_eq!(back.peak_von_mises_block(&w), s.peak_von_mises_block(&w));
        // Damaged bytes are refused, never decoded into a wrong solution.
        for cut in [0, 7, 16, bytes.len() / 2, bytes.len() - 1] {
            assert!(
                JointSolution::from_bytes(&bytes[..cut]).is_err(),
                "cut {cut}"
            );
        }
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(JointSolution::from_bytes(&longer).is_err());
        let mut version = bytes.clone();
        version[8] ^= 0x40;
        assert!(JointSolution::from_bytes(&version).is_err());
        // A stress-basis count far beyond the bytes left does not allocate.
        let count_at = 8 + 8 + 8 * (36 + 36 + 2 + 1 + 2 + 1 + 1 + 8 + 2 + 1);
        let mut count = bytes.clone();
        count[count_at..count_at + 8].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(JointSolution::from_bytes(&count).is_err());
    }

    #[test]
    fn bending_stress_matches_the_beam_estimate_at_a_thin_throat() {
        // Thin throat: σ_max ≈ 6 M / (b Δ²)·K_t with K_t → 1 + small; the FEM's
        // peak must lie between the nominal value and 1.2× it.
        let joint = DoubleNotch {
            side: 6e-3,
            radius: 3e-3,
            flat: 0.0,
            throat: 0.6e-3,
            gap: 2e-3,
        };
        let s = solve(&joint, &steel(), &JointMesh::default(), 2).unwrap();
        let mut w = Vector6::zeros();
        w[4] = 1.0;
        let sigma = s.max_von_mises(&w);
        let nominal = 6.0 / (6e-3 * 0.6e-3f64.powi(2));
        assert!(
            sigma > 0.97 * nominal && sigma < 1.25 * nominal,
            "{sigma:e} vs {nominal:e}"
        );
    }
}
