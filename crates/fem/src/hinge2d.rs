//! Two-dimensional FEM of a notch hinge (see the crate documentation for the set-up).

use cellinject_flexure::{Hinge, Material, Profile};
use faer::linalg::solvers::Solve;
use faer::sparse::{SparseColMat, Triplet};
use faer::{Mat, Side};

use crate::FemError;
use crate::lagrange::{G3, quad};

/// In-plane assumption.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Plane {
    /// Thin plate (σ_zz = 0): the usual choice for a hinge narrower than it is long.
    Stress,
    /// Thick plate (ε_zz = 0).
    Strain,
}

/// Mesh density at refinement level 1 (each level multiplies every count).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshDensity {
    /// Elements along the notch.
    pub along: usize,
    /// Elements through the thickness.
    pub across: usize,
    /// Elements along each end block.
    pub block: usize,
    /// Grading exponent: nodes at x = (L/2)·|s|^g·sign(s) for uniform s (1 = uniform).
    pub grading: f64,
}

impl Default for MeshDensity {
    fn default() -> Self {
        MeshDensity {
            along: 16,
            across: 4,
            block: 4,
            grading: 1.8,
        }
    }
}

/// One solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HingeSolution {
    /// Rotational stiffness about the compliant axis, N·m/rad.
    pub k_bend: f64,
    /// Applied moment, N·m.
    pub moment: f64,
    /// Relative rotation of the notch's end sections, rad.
    pub rotation: f64,
    /// Unknowns after the clamped nodes are removed.
    pub dofs: usize,
    /// Elements.
    pub elements: usize,
    /// Backward error `|f − K u|∞ / (|K|∞ |u|∞ + |f|∞)` after iterative refinement.
    pub residual: f64,
}

/// Stiffness from successive refinements.
#[derive(Debug, Clone, PartialEq)]
pub struct Convergence {
    /// Solutions at levels 1, 2, 4.
    pub levels: Vec<HingeSolution>,
    /// The finest solve's stiffness, N·m/rad.
    pub k_bend: f64,
    /// Relative change of the stiffness between the two finest levels: a conservative
    /// error indicator (the thickest notches converge more slowly than h⁴, where the
    /// profile meets the blocks with a vertical tangent, so no Richardson extrapolation
    /// is applied).
    pub error_estimate: f64,
}

/// The structured mesh of a hinge: node grid, 9-node elements, section columns.
#[derive(Debug, Clone, PartialEq)]
pub struct HingeMesh {
    /// Node coordinates (x along the hinge, y across), row-major: node (i, j) is
    /// `j·cols + i`.
    pub coords: Vec<(f64, f64)>,
    /// Node columns.
    pub cols: usize,
    /// Node rows.
    pub rows: usize,
    /// Elements along each block.
    pub nb: usize,
    /// Elements along the notch.
    pub nh: usize,
    /// Elements along the whole mesh.
    pub nx: usize,
    /// Elements across.
    pub ny: usize,
    /// Height of the blocks (the notch's thickness at its ends), m.
    pub height: f64,
}

impl HingeMesh {
    /// Node ids of each 9-node element, lexicographic (x fastest, then y).
    pub fn elements(&self) -> Vec<[usize; 9]> {
        let mut out = Vec::with_capacity(self.nx * self.ny);
        for ey in 0..self.ny {
            for ex in 0..self.nx {
                out.push(std::array::from_fn(|k| {
                    (2 * ey + k / 3) * self.cols + 2 * ex + k % 3
                }));
            }
        }
        out
    }

    /// Node columns of the notch's end sections (x = −L/2 and x = +L/2).
    pub fn section_columns(&self) -> [usize; 2] {
        [2 * self.nb, 2 * (self.nb + self.nh)]
    }
}

/// Builds the hinge's mesh at a refinement level (assumes a validated hinge).
pub fn mesh(hinge: &Hinge, density: &MeshDensity, level: usize) -> HingeMesh {
    let level = level.max(1);
    let nh = 2 * (density.along * level).div_ceil(2);
    let ny = density.across * level;
    let nb = density.block * level;
    let nx = nb + nh + nb;
    let half = 0.5 * hinge.length();
    let height = hinge.thickness_at(half).max(hinge.thickness_at(-half));
    // Node columns: 2·nx + 1 x-positions.
    let mut xs = Vec::with_capacity(2 * nx + 1);
    for k in 0..2 * nb {
        xs.push(-half - height + height * k as f64 / (2 * nb) as f64);
    }
    // A notch that curves up to the blocks (circular, elliptic) is spaced uniformly in
    // its angle (x = (L/2)·sin φ): fine where the profile steepens at the ends, and
    // graded towards the throat by the exponent.
    let angular = matches!(
        hinge.profile,
        Profile::Circular { .. } | Profile::Elliptic { .. }
    );
    for k in 0..=2 * nh {
        let s = -1.0 + 2.0 * k as f64 / (2 * nh) as f64;
        let g = s.signum() * s.abs().powf(density.grading);
        xs.push(if angular {
            half * (g * std::f64::consts::FRAC_PI_2).sin()
        } else {
            half * g
        });
    }
    for k in 1..=2 * nb {
        xs.push(half + height * k as f64 / (2 * nb) as f64);
    }
    let cols = 2 * nx + 1;
    let rows = 2 * ny + 1;
    let depth = |x: f64| {
        if x.abs() >= half {
            height
        } else {
            hinge.thickness_at(x)
        }
    };
    let coords: Vec<(f64, f64)> = (0..rows)
        .flat_map(|j| xs.iter().map(move |&x| (x, j)))
        .map(|(x, j)| {
            (
                x,
                (-1.0 + 2.0 * j as f64 / (rows - 1) as f64) * 0.5 * depth(x),
            )
        })
        .collect();
    HingeMesh {
        coords,
        cols,
        rows,
        nb,
        nh,
        nx,
        ny,
        height,
    }
}

/// Solves the hinge at a refinement level.
pub fn solve(
    hinge: &Hinge,
    m: &Material,
    plane: Plane,
    density: &MeshDensity,
    level: usize,
) -> Result<HingeSolution, FemError> {
    hinge
        .validate()
        .map_err(|e| FemError::Invalid(e.to_string()))?;
    let hm = mesh(hinge, density, level);
    let elements = hm.elements();
    let HingeMesh {
        coords,
        cols,
        rows,
        nb,
        nh,
        nx,
        ny,
        height,
    } = hm;
    let node = |i: usize, j: usize| j * cols + i;
    let d = elasticity(m, plane);
    let b = hinge.width;
    // DOF numbering without the clamped first column.
    let n_nodes = rows * cols;
    let mut dof = vec![usize::MAX; 2 * n_nodes];
    let mut n_dof = 0;
    for j in 0..rows {
        for i in 1..cols {
            let id = node(i, j);
            dof[2 * id] = n_dof;
            dof[2 * id + 1] = n_dof + 1;
            n_dof += 2;
        }
    }
    let mut triplets: Vec<Triplet<usize, usize, f64>> = Vec::with_capacity(nx * ny * 18 * 18);
    for (element, ids) in elements.iter().enumerate() {
        let ke = element_stiffness(&coords, ids, &d, b, element)?;
        for r in 0..18 {
            let gr = dof[2 * ids[r / 2] + r % 2];
            if gr == usize::MAX {
                continue;
            }
            for c in 0..18 {
                let gc = dof[2 * ids[c / 2] + c % 2];
                if gc != usize::MAX && ke[r][c] != 0.0 {
                    triplets.push(Triplet::new(gr, gc, ke[r][c]));
                }
            }
        }
    }
    // Pure moment on the far end: traction t_x = −M·y/I over the block's height.
    let moment = 1.0;
    let inertia = b * height.powi(3) / 12.0;
    let mut f = vec![0.0f64; n_dof];
    let last = cols - 1;
    for ey in 0..ny {
        let ids = [
            node(last, 2 * ey),
            node(last, 2 * ey + 1),
            node(last, 2 * ey + 2),
        ];
        for &(eta, w) in &G3 {
            let (n, dn) = quad(eta);
            let y: f64 = (0..3).map(|k| n[k] * coords[ids[k]].1).sum();
            let dy: f64 = (0..3).map(|k| dn[k] * coords[ids[k]].1).sum();
            let t = -moment * y / inertia;
            for k in 0..3 {
                f[dof[2 * ids[k]]] += w * n[k] * t * b * dy;
            }
        }
    }
    let k = SparseColMat::<usize, f64>::try_new_from_triplets(n_dof, n_dof, &triplets)
        .map_err(|e| FemError::Invalid(format!("assembly: {e:?}")))?;
    let llt = k
        .sp_cholesky(Side::Lower)
        .map_err(|e| FemError::NotPositiveDefinite {
            dofs: n_dof,
            reason: format!("{e:?}"),
        })?;
    let rhs = Mat::from_fn(n_dof, 1, |i, _| f[i]);
    let mut u = llt.solve(&rhs);
    // Residual from the triplets (duplicates sum, as in the assembly), with iterative
    // refinement. Thin throats make K ill-conditioned (~1e9), so the residual is judged
    // as a backward error, |f − K u|∞ / (|K|∞ |u|∞ + |f|∞), which rounding keeps near
    // 1e-16 whatever the conditioning; a wrong factorisation shows as a large one.
    let mut k_norm = vec![0.0f64; n_dof];
    for t in &triplets {
        k_norm[t.row] += t.val.abs();
    }
    let k_inf = k_norm.iter().cloned().fold(0.0, f64::max);
    let f_inf = f.iter().map(|v| v.abs()).fold(0.0, f64::max);
    let mut residual = f64::INFINITY;
    for _ in 0..3 {
        let mut r = f.clone();
        for t in &triplets {
            r[t.row] -= t.val * u[(t.col, 0)];
        }
        let u_inf = (0..n_dof).map(|i| u[(i, 0)].abs()).fold(0.0, f64::max);
        residual = r.iter().map(|v| v.abs()).fold(0.0, f64::max) / (k_inf * u_inf + f_inf);
        if residual < 1e-15 {
            break;
        }
        let du = llt.solve(Mat::from_fn(n_dof, 1, |i, _| r[i]));
        u += du;
    }
    if residual.is_nan() || residual >= 1e-13 {
        return Err(FemError::Residual {
            residual,
            tolerance: 1e-13,
            dofs: n_dof,
        });
    }
    // Section rotations at the notch's ends: least-squares slope of u_x over y.
    let rotation_at = |i: usize| {
        let pts: Vec<(f64, f64)> = (0..rows)
            .map(|j| {
                let id = node(i, j);
                (coords[id].1, u[(dof[2 * id], 0)])
            })
            .collect();
        let n = pts.len() as f64;
        let (sy, su) = pts.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
        let (my, mu) = (sy / n, su / n);
        let (num, den) = pts.iter().fold((0.0, 0.0), |a, p| {
            (a.0 + (p.0 - my) * (p.1 - mu), a.1 + (p.0 - my).powi(2))
        });
        -num / den
    };
    let rotation = rotation_at(2 * (nb + nh)) - rotation_at(2 * nb);
    Ok(HingeSolution {
        k_bend: moment / rotation,
        moment,
        rotation,
        dofs: n_dof,
        elements: nx * ny,
        residual,
    })
}

/// The elasticity matrix of `m` in plane stress or plane strain, (σxx, σyy, τxy) from
/// (εxx, εyy, γxy).
fn elasticity(m: &Material, plane: Plane) -> [[f64; 3]; 3] {
    let (e, nu) = (m.youngs, m.poisson);
    match plane {
        Plane::Stress => {
            let c = e / (1.0 - nu * nu);
            [
                [c, c * nu, 0.0],
                [c * nu, c, 0.0],
                [0.0, 0.0, c * 0.5 * (1.0 - nu)],
            ]
        }
        Plane::Strain => {
            let c = e / ((1.0 + nu) * (1.0 - 2.0 * nu));
            [
                [c * (1.0 - nu), c * nu, 0.0],
                [c * nu, c * (1.0 - nu), 0.0],
                [0.0, 0.0, c * 0.5 * (1.0 - 2.0 * nu)],
            ]
        }
    }
}

/// The stiffness of the nine-node element `element` (its nodes `ids` at `coords`) of
/// thickness `b` and elasticity `d`, by 3 x 3 Gauss points; an element turned inside
/// out is refused.
fn element_stiffness(
    coords: &[(f64, f64)],
    ids: &[usize; 9],
    d: &[[f64; 3]; 3],
    b: f64,
    element: usize,
) -> Result<[[f64; 18]; 18], FemError> {
    let mut ke = [[0.0f64; 18]; 18];
    for &(xi, wx) in &G3 {
        for &(eta, wy) in &G3 {
            let (nxi, dxi) = quad(xi);
            let (neta, deta) = quad(eta);
            let mut dn = [(0.0, 0.0); 9];
            let mut jac = [[0.0; 2]; 2];
            for bj in 0..3 {
                for ai in 0..3 {
                    let k = bj * 3 + ai;
                    let (dxi_k, deta_k) = (dxi[ai] * neta[bj], nxi[ai] * deta[bj]);
                    dn[k] = (dxi_k, deta_k);
                    let (x, y) = coords[ids[k]];
                    jac[0][0] += dxi_k * x;
                    jac[0][1] += dxi_k * y;
                    jac[1][0] += deta_k * x;
                    jac[1][1] += deta_k * y;
                }
            }
            let det = jac[0][0] * jac[1][1] - jac[0][1] * jac[1][0];
            if det <= 0.0 {
                return Err(FemError::InvertedElement {
                    element,
                    jacobian: det,
                });
            }
            let inv = [
                [jac[1][1] / det, -jac[0][1] / det],
                [-jac[1][0] / det, jac[0][0] / det],
            ];
            // B: rows (εxx, εyy, γxy), columns (ux_k, uy_k).
            let mut bm = [[0.0f64; 18]; 3];
            for k in 0..9 {
                let gx = inv[0][0] * dn[k].0 + inv[0][1] * dn[k].1;
                let gy = inv[1][0] * dn[k].0 + inv[1][1] * dn[k].1;
                bm[0][2 * k] = gx;
                bm[1][2 * k + 1] = gy;
                bm[2][2 * k] = gy;
                bm[2][2 * k + 1] = gx;
            }
            let w = wx * wy * det * b;
            let mut db = [[0.0f64; 18]; 3];
            for r in 0..3 {
                for c in 0..18 {
                    db[r][c] = d[r][0] * bm[0][c] + d[r][1] * bm[1][c] + d[r][2] * bm[2][c];
                }
            }
            for r in 0..18 {
                for c in 0..18 {
                    ke[r][c] +=
                        w * (bm[0][r] * db[0][c] + bm[1][r] * db[1][c] + bm[2][r] * db[2][c]);
                }
            }
        }
    }
    Ok(ke)
}

/// Solves at levels 1, 2 and 4 and reports the change between the two finest.
pub fn converge(
    hinge: &Hinge,
    m: &Material,
    plane: Plane,
    density: &MeshDensity,
) -> Result<Convergence, FemError> {
    let levels = [1, 2, 4]
        .iter()
        .map(|&l| solve(hinge, m, plane, density, l))
        .collect::<Result<Vec<_>, _>>()?;
    let (c, f) = (levels[1].k_bend, levels[2].k_bend);
    Ok(Convergence {
        error_estimate: ((f - c) / f).abs(),
        k_bend: f,
        levels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_thin_leaf_matches_beam_theory() {
        // A long thin leaf behaves as an Euler-Bernoulli beam: k = E b t³ / (12 L)
        // (plane stress; the blocks add a small root compliance).
        let m = Material::x2crni18_9();
        let h = Hinge {
            profile: Profile::Leaf { length: 20e-3 },
            thickness: 0.5e-3,
            width: 4e-3,
        };
        let s = solve(
            &h,
            &m,
            Plane::Stress,
            &MeshDensity {
                grading: 1.0,
                ..MeshDensity::default()
            },
            2,
        )
        .unwrap();
        let beam = m.youngs * 4e-3 * 0.5e-3f64.powi(3) / (12.0 * 20e-3);
        assert!(
            (s.k_bend / beam - 1.0).abs() < 0.01,
            "{} vs {beam}",
            s.k_bend
        );
        assert!(s.residual < 1e-13);
    }

    #[test]
    fn plane_strain_is_stiffer_by_about_one_over_one_minus_nu_squared() {
        let m = Material::x2crni18_9();
        let h = Hinge {
            profile: Profile::Leaf { length: 20e-3 },
            thickness: 0.5e-3,
            width: 4e-3,
        };
        let d = MeshDensity {
            grading: 1.0,
            ..MeshDensity::default()
        };
        let a = solve(&h, &m, Plane::Stress, &d, 1).unwrap().k_bend;
        let b = solve(&h, &m, Plane::Strain, &d, 1).unwrap().k_bend;
        let expected = 1.0 / (1.0 - m.poisson * m.poisson);
        assert!((b / a / expected - 1.0).abs() < 0.01, "{}", b / a);
    }
}
