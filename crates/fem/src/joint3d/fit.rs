//! Rigid motions fitted to displaced points, and a pair of joints fitted to observed
//! stiffnesses ([`fit_pair`], [`fit_pair_observed`]).

use super::*;

/// Least-squares rigid motion `u ≈ u0 + θ × (p − c)` of a set of points: returns the
/// centroid `c`, `u0` and `θ`.
pub(super) fn rigid_fit(
    pts: &[(Vector3<f64>, Vector3<f64>)],
) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
    let n = pts.len() as f64;
    let c = pts.iter().fold(Vector3::zeros(), |a, p| a + p.0) / n;
    let mut a = Matrix6::<f64>::zeros();
    let mut b = Vector6::<f64>::zeros();
    for (p, v) in pts {
        let r = p - c;
        // u = u0 + θ × r = u0 − [r]× θ.
        let rx = -r.cross_matrix();
        let mut row = nalgebra::Matrix3x6::<f64>::zeros();
        row.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::identity());
        row.fixed_view_mut::<3, 3>(0, 3).copy_from(&rx);
        a += row.transpose() * row;
        b += row.transpose() * v;
    }
    let x = a
        .cholesky()
        .map(|ch| ch.solve(&b))
        .unwrap_or_else(Vector6::zeros);
    (
        c,
        Vector3::new(x[0], x[1], x[2]),
        Vector3::new(x[3], x[4], x[5]),
    )
}

/// A geometry fitted to two (throat, stiffness) pairs.
#[derive(Debug, Clone)]
pub struct PairFit {
    /// The fitted joint (its `throat` is the first pair's).
    pub joint: DoubleNotch,
    /// Bending stiffness reached for each pair, N·m/rad (mean of the two axes).
    pub k: [f64; 2],
    /// Newton iterations.
    pub iterations: usize,
}

/// One Newton iterate of [`fit_pair_observed`], for progress reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitStep {
    /// Newton step (0: the start).
    pub iteration: usize,
    /// m, straight throat length of the iterate.
    pub flat: f64,
    /// m, rod side of the iterate.
    pub side: f64,
    /// N·m/rad, bending stiffness reached at each throat (mean of the two axes).
    pub k: [f64; 2],
}

/// Fits the straight throat length and the rod side so that one geometry gives bending stiffness
/// `k[0]` at throat `throat[0]` and `k[1]` at `throat[1]` (the gap is kept), by
/// Newton's method on the logarithms with a finite-difference Jacobian, starting from
/// `start`.
pub fn fit_pair(
    start: &DoubleNotch,
    throat: [f64; 2],
    k: [f64; 2],
    m: &Material,
    mesh: &JointMesh,
    level: usize,
) -> Result<PairFit, FemError> {
    fit_pair_observed(start, throat, k, m, mesh, level, |_| {})
}

/// [`fit_pair`], showing every Newton iterate to `observe` (each costs two joint
/// solves, plus four for the Jacobian).
pub fn fit_pair_observed(
    start: &DoubleNotch,
    throat: [f64; 2],
    k: [f64; 2],
    m: &Material,
    mesh: &JointMesh,
    level: usize,
    mut observe: impl FnMut(&FitStep),
) -> Result<PairFit, FemError> {
    // The fillet radius is kept, capped at the cut depth of the thicker throat.
    let thickest = throat[0].max(throat[1]);
    let fillet_for = |side: f64| start.radius.min(0.5 * (side - thickest));
    let target = [k[0].ln(), k[1].ln()];
    // Residual: log-stiffness reached minus log-stiffness wanted, for x = (ln flat,
    // ln side).
    let residual = |x: [f64; 2]| -> Result<[f64; 2], FemError> {
        let mut out = [0.0; 2];
        for p in 0..2 {
            let j = DoubleNotch {
                flat: x[0].exp(),
                side: x[1].exp(),
                radius: fillet_for(x[1].exp()),
                throat: throat[p],
                gap: start.gap,
            };
            let s = solve(&j, m, mesh, level)?;
            out[p] = (0.5 * (s.k_bend[0] + s.k_bend[1])).ln() - target[p];
        }
        Ok(out)
    };
    let options = Newton2Options {
        fd_step: 1e-3,
        tolerance: 1e-4,
        max_iterations: 12,
        // Damped: at most 20 % change of a dimension per step.
        max_step: 0.2,
    };
    let x0 = [start.flat.max(1e-5).ln(), start.side.ln()];
    let fit = newton2(residual, x0, &options, |iteration, x, f| {
        observe(&FitStep {
            iteration,
            flat: x[0].exp(),
            side: x[1].exp(),
            k: [(f[0] + target[0]).exp(), (f[1] + target[1]).exp()],
        })
    })
    .map_err(|e| match e {
        Newton2Error::Eval(e) => e,
        Newton2Error::Singular { .. } => FemError::Invalid("singular fit Jacobian".into()),
        Newton2Error::NotConverged { residual, .. } => FemError::Invalid(format!(
            "joint fit did not converge: log-stiffness residual {residual:.2e}"
        )),
    })?;
    let x = fit.x;
    Ok(PairFit {
        joint: DoubleNotch {
            flat: x[0].exp(),
            side: x[1].exp(),
            radius: fillet_for(x[1].exp()),
            throat: throat[0],
            gap: start.gap,
        },
        k: [(fit.f[0] + target[0]).exp(), (fit.f[1] + target[1]).exp()],
        iterations: fit.iterations,
    })
}
