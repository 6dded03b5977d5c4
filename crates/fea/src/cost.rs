//! What a joint FEM will cost before it runs: its unknowns (counted on the mesh, no
//! solve) and, from them, the time and peak memory on the reference machine, so that a
//! front end can say so, or refuse a solve that would not fit in memory.
//!
//! The model is a power law in the number of unknowns through two solves measured on
//! the 2-core reference machine (`cellinject fea joints --levels 1,2 --no-cache`, release
//! build, 2026-12-01): 25,272 unknowns in 0.48 s and 227 MB of peak memory, 183,600
//! unknowns in 7.4 s and 2.34 GB. Nested dissection on these slender 3-D meshes makes
//! the factor grow as n^1.18 in memory and n^1.38 in time here. For level 3
//! (about 590,000 unknowns) it predicts 9.2 GB, against 10.5 GB reported for such a run.

use cellinject_fem::joint3d::JointMesh;
use serde::Serialize;

use crate::cache::{JointKey, JointStore};
use crate::{FeaError, StructureParams, joint_geometry, material};

const N1: f64 = 25_272.0;
const N2: f64 = 183_600.0;
const BYTES: (f64, f64) = (227e6, 2.34e9);
const SECONDS: (f64, f64) = (0.48, 7.4);

fn power_law(n: f64, (y1, y2): (f64, f64)) -> f64 {
    let k = (y2 / y1).ln() / (N2 / N1).ln();
    y1 * (n / N1).powf(k)
}

/// The cost of the joint solves a command needs.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `solves` | | joint FEMs not in the cache |
/// | `unknowns` | | of the largest of them |
/// | `seconds` | s | all of them, on the reference machine |
/// | `peak_bytes` | B | the largest one's peak memory (they run one after another) |
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FemCost {
    /// Joint solves to run.
    pub solves: usize,
    /// Unknowns of the largest.
    pub unknowns: usize,
    /// s.
    pub seconds: f64,
    /// B.
    pub peak_bytes: f64,
}

/// Time and peak memory of one solve of `unknowns` unknowns on the reference machine.
pub fn solve_cost(unknowns: usize) -> (f64, f64) {
    let n = unknowns as f64;
    (power_law(n, SECONDS), power_law(n, BYTES))
}

/// The cost of solving the two joints (J1/J2 and J3) at each of `levels`, leaving out
/// those `store` already holds.
pub fn joints_cost(
    params: &StructureParams,
    levels: &[usize],
    store: &dyn JointStore,
) -> Result<FemCost, FeaError> {
    let m = material(params)?;
    let mesh = JointMesh::default();
    let mut cost = FemCost {
        solves: 0,
        unknowns: 0,
        seconds: 0.0,
        peak_bytes: 0.0,
    };
    for &level in levels {
        for throat in [params.throat_j12, params.throat_j3] {
            let joint = joint_geometry(params, throat);
            if store.has(&JointKey::new(&joint, &m, &mesh, level)) {
                continue;
            }
            let n = mesh.unknowns(&joint, level);
            let (t, b) = solve_cost(n);
            cost.solves += 1;
            cost.unknowns = cost.unknowns.max(n);
            cost.seconds += t;
            cost.peak_bytes = cost.peak_bytes.max(b);
        }
    }
    Ok(cost)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cache::NoCache;

    #[test]
    fn the_model_passes_through_its_measurements_and_grows_with_the_level() {
        let (t1, b1) = solve_cost(25_272);
        let (t2, b2) = solve_cost(183_600);
        assert!((t1 - 0.48).abs() < 1e-12 && (b1 - 227e6).abs() < 1e-3);
        assert!((t2 - 7.4).abs() < 1e-9 && (b2 - 2.34e9).abs() < 1.0);
        let p = StructureParams::default();
        let c1 = joints_cost(&p, &[1], &NoCache).unwrap();
        let c3 = joints_cost(&p, &[3], &NoCache).unwrap();
        // The prototype's level-1 joints are the measured 25,272 unknowns.
        assert_eq!((c1.solves, c1.unknowns), (2, 25_272));
        assert!(c3.unknowns > 500_000 && c3.peak_bytes > 8e9, "{c3:?}");
    }
}
