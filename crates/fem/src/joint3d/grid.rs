//! The joint's mesh: the structured grid of 27-node hexahedra over the double notch,
//! its node ordering (nested dissection) and the sparsity pattern of its stiffness.

use super::*;

pub(super) struct Grid {
    pub(super) ni: usize,
    pub(super) nj: usize,
    pub(super) nk: usize,
    pub(super) coords: Vec<[f64; 3]>,
    pub(super) zs: Vec<f64>,
    /// Node layers of the bottom and top end sections.
    pub(super) lower_k: usize,
    pub(super) upper_k: usize,
    /// First DOF of each node (`usize::MAX`: clamped or outside the solid).
    pub(super) dof: Vec<usize>,
    /// Elements inside the solid.
    pub(super) active: Vec<usize>,
    /// Element counts per axis.
    pub(super) ne: [usize; 3],
    pub(super) n_dof: usize,
}

impl Grid {
    pub(super) fn id(&self, i: usize, j: usize, k: usize) -> usize {
        (k * self.nj + j) * self.ni + i
    }

    pub(super) fn element_nodes(&self, e: usize) -> [usize; 27] {
        let [ex, ey, _] = self.ne;
        let (i, rest) = (e % ex, e / ex);
        let (j, k) = (rest % ey, rest / ey);
        std::array::from_fn(|q| {
            let (a, b, c) = (q % 3, (q / 3) % 3, q / 9);
            self.id(2 * i + a, 2 * j + b, 2 * k + c)
        })
    }
}

/// Node coordinates across the rod along one axis: `2·ns` shoulder elements on each
/// side (only when the slot is narrower than the rod), `nc` core elements spread over
/// the core's half-width `core` at this height.
pub(super) fn across(idx: usize, ns: usize, nc: usize, half: f64, core_out: f64, core: f64) -> f64 {
    let n_core = 2 * nc;
    let s0 = 2 * ns;
    if idx < s0 {
        -half + (half - core_out) * idx as f64 / s0 as f64
    } else if idx > s0 + n_core {
        core_out + (half - core_out) * (idx - s0 - n_core) as f64 / s0 as f64
    } else {
        -core + 2.0 * core * (idx - s0) as f64 / n_core as f64
    }
}

pub(super) fn build_grid(joint: &DoubleNotch, mesh: &JointMesh, level: usize) -> Grid {
    let (ea, en, eb, eg) = mesh.counts(joint, level);
    let l = joint.layout();
    let zf = joint.fillet_length();
    let theta_e = (zf / joint.radius).clamp(-1.0, 1.0).asin();
    let half_flat = 0.5 * joint.flat;
    let mut zs: Vec<f64> = Vec::new();
    let push_uniform = |zs: &mut Vec<f64>, a: f64, b: f64, n: usize| {
        for k in 0..2 * n {
            zs.push(a + (b - a) * k as f64 / (2 * n) as f64);
        }
    };
    push_uniform(&mut zs, l.bottom, l.lower_end, eb);
    let lower_k = zs.len();
    let notch = |zs: &mut Vec<f64>, centre: f64| {
        if half_flat == 0.0 {
            // Uniform in the notch angle, graded towards the throat.
            for k in 0..2 * en {
                let s = -1.0 + 2.0 * k as f64 / (2 * en) as f64;
                let g = s.signum() * s.abs().powf(mesh.grading);
                zs.push(centre + joint.radius * (g * theta_e).sin());
            }
            return;
        }
        // Fillet (uniform in angle), straight throat (uniform), fillet.
        let nc = (en / 4).max(1);
        let nf = en - 2 * nc;
        for k in 0..2 * nc {
            let phi = theta_e * (1.0 - k as f64 / (2 * nc) as f64);
            zs.push(centre - half_flat - joint.radius * phi.sin());
        }
        for k in 0..2 * nf {
            zs.push(centre - half_flat + 2.0 * half_flat * k as f64 / (2 * nf) as f64);
        }
        for k in 0..2 * nc {
            let phi = theta_e * k as f64 / (2 * nc) as f64;
            zs.push(centre + half_flat + joint.radius * phi.sin());
        }
    };
    let a_start = zs.len();
    notch(&mut zs, l.notch_a);
    let a_stop = zs.len();
    push_uniform(&mut zs, l.a_end, l.b_start, eg);
    let b_start = zs.len();
    notch(&mut zs, l.notch_b);
    let upper_k = zs.len();
    push_uniform(&mut zs, l.upper_end, l.top, eb);
    zs.push(l.top);
    // A slot narrower than the rod (fillet radius below the cut depth) leaves
    // shoulders beside the core, which are cut away along the slot.
    let half = 0.5 * joint.side;
    let core_out = (0.5 * joint.throat + joint.radius).min(half);
    let ns = if core_out < half {
        (mesh.across * level.max(1)).div_ceil(4).max(1)
    } else {
        0
    };
    let ni = 2 * (2 * ns + ea) + 1;
    let nj = ni;
    let nk = zs.len();
    let core_at = |k: usize, lo: usize, hi: usize, centre: f64| {
        if k >= lo && k <= hi {
            (0.5 * joint.notch_thickness(zs[k] - centre)).min(core_out)
        } else {
            core_out
        }
    };
    let mut coords = Vec::with_capacity(ni * nj * nk);
    for k in 0..nk {
        let cx = core_at(k, a_start, a_stop, l.notch_a);
        let cy = core_at(k, b_start, upper_k, l.notch_b);
        let z = zs[k];
        for j in 0..nj {
            let y = across(j, ns, ea, half, core_out, cy);
            for i in 0..ni {
                coords.push([across(i, ns, ea, half, core_out, cx), y, z]);
            }
        }
    }
    let ne = [(ni - 1) / 2, (nj - 1) / 2, (nk - 1) / 2];
    let shoulder = |e: usize| ns > 0 && (e < ns || e >= ns + ea);
    let active: Vec<usize> = (0..ne[0] * ne[1] * ne[2])
        .filter(|&e| {
            let (i, rest) = (e % ne[0], e / ne[0]);
            let (j, k) = (rest % ne[1], rest / ne[1]);
            let in_a = 2 * k >= a_start && 2 * k < a_stop;
            let in_b = 2 * k >= b_start && 2 * k < upper_k;
            !((in_a && shoulder(i)) || (in_b && shoulder(j)))
        })
        .collect();
    let mut grid = Grid {
        ni,
        nj,
        nk,
        coords,
        zs,
        lower_k,
        upper_k,
        dof: Vec::new(),
        active,
        ne,
        n_dof: 0,
    };
    let mut used = vec![false; ni * nj * nk];
    for &e in &grid.active {
        for id in grid.element_nodes(e) {
            used[id] = true;
        }
    }
    let layer = ni * nj;
    let mut dof = vec![usize::MAX; ni * nj * nk];
    let mut n = 0;
    for id in layer..ni * nj * nk {
        if used[id] {
            dof[id] = n;
            n += 3;
        }
    }
    grid.dof = dof;
    grid.n_dof = n;
    grid
}

/// Nested-dissection order of the free DOFs (new position → old index): each box of
/// nodes is split at an even node plane (an element boundary) across its longest
/// side, both halves ordered first and the separating plane last.
pub(super) fn nested_dissection(g: &Grid) -> Vec<usize> {
    let mut order = Vec::with_capacity(g.n_dof);
    // Boxes of inclusive node ranges [lo, hi] per axis (i, j, k).
    pub(super) fn split(g: &Grid, b: [[usize; 2]; 3], out: &mut Vec<usize>) {
        let len = |a: usize| b[a][1] + 1 - b[a][0];
        let axis = (0..3).max_by_key(|&a| len(a)).unwrap_or(2);
        let n = len(0) * len(1) * len(2);
        // An even plane strictly inside the box.
        let mid = (b[axis][0] + b[axis][1]) / 2;
        let plane = if mid % 2 == 0 { mid } else { mid + 1 };
        if n <= 96 || plane <= b[axis][0] || plane >= b[axis][1] {
            for k in b[2][0]..=b[2][1] {
                for j in b[1][0]..=b[1][1] {
                    for i in b[0][0]..=b[0][1] {
                        let d = g.dof[g.id(i, j, k)];
                        if d != usize::MAX {
                            out.extend([d, d + 1, d + 2]);
                        }
                    }
                }
            }
            return;
        }
        let mut lo = b;
        lo[axis][1] = plane - 1;
        let mut hi = b;
        hi[axis][0] = plane + 1;
        split(g, lo, out);
        split(g, hi, out);
        let mut sep = b;
        sep[axis] = [plane, plane];
        split(g, sep, out);
    }
    split(g, [[0, g.ni - 1], [0, g.nj - 1], [1, g.nk - 1]], &mut order);
    order
}

/// Lower-triangle compressed-column pattern, built from the active elements.
pub(super) struct Pattern {
    pub(super) col_ptr: Vec<usize>,
    pub(super) row_idx: Vec<usize>,
    /// Per node with DOFs (by DOF order): neighbour node ids at or after it.
    pub(super) neighbours: Vec<Vec<usize>>,
}

pub(super) fn pattern(g: &Grid) -> Pattern {
    let n_nodes = g.n_dof / 3;
    let mut neighbours: Vec<Vec<usize>> = vec![Vec::new(); n_nodes];
    for &e in &g.active {
        let ids = g.element_nodes(e);
        for &b in &ids {
            let db = g.dof[b];
            if db == usize::MAX {
                continue;
            }
            let list = &mut neighbours[db / 3];
            list.extend(ids.iter().copied().filter(|&a| a >= b));
        }
    }
    for list in &mut neighbours {
        list.sort_unstable();
        list.dedup();
    }
    let mut col_ptr = Vec::with_capacity(g.n_dof + 1);
    let mut row_idx = Vec::new();
    col_ptr.push(0);
    for (n, list) in neighbours.iter().enumerate() {
        for cb in 0..3 {
            for &a in list {
                let da = g.dof[a];
                let start = if da == 3 * n { cb } else { 0 };
                for ca in start..3 {
                    row_idx.push(da + ca);
                }
            }
            col_ptr.push(row_idx.len());
        }
    }
    Pattern {
        col_ptr,
        row_idx,
        neighbours,
    }
}
