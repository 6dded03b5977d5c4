//! Non-negative least squares, min ‖A x − b‖² subject to x ≥ 0, by the active-set
//! method of Lawson & Hanson (*Solving Least Squares Problems*, 1974, ch. 23), on the
//! normal equations G = AᵀA, h = Aᵀb (the identification problems here have a few
//! hundred unknowns and many thousands of rows: the Gram matrix is the small object).
//! Variables listed as free may take either sign.

use nalgebra::{DMatrix, DVector};
use thiserror::Error;

/// Why the solve failed.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum NnlsError {
    /// The Gram matrix and right-hand side do not match.
    #[error("the Gram matrix is {rows}x{cols} but the right-hand side has {len} entries")]
    Shape {
        /// Rows.
        rows: usize,
        /// Columns.
        cols: usize,
        /// Right-hand side length.
        len: usize,
    },
    /// The active set did not settle.
    #[error("no convergence in {iterations} active-set iterations")]
    NotConverged {
        /// Iterations.
        iterations: usize,
    },
}

/// Solves min xᵀGx − 2hᵀx with x_i ≥ 0 except for `free` indices; `G` must be symmetric
/// positive semi-definite (add a ridge for uniqueness).
pub fn nnls_gram(
    g: &DMatrix<f64>,
    h: &DVector<f64>,
    free: &[usize],
) -> Result<DVector<f64>, NnlsError> {
    let n = h.len();
    if g.nrows() != n || g.ncols() != n {
        return Err(NnlsError::Shape {
            rows: g.nrows(),
            cols: g.ncols(),
            len: n,
        });
    }
    let is_free = |i: usize| free.contains(&i);
    // Passive set P (variables allowed to be non-zero); free variables always in it.
    let mut passive: Vec<bool> = (0..n).map(is_free).collect();
    let mut x = DVector::zeros(n);
    let solve_passive = |passive: &[bool]| -> DVector<f64> {
        let idx: Vec<usize> = (0..n).filter(|&i| passive[i]).collect();
        let mut z = DVector::zeros(n);
        if idx.is_empty() {
            return z;
        }
        let gp = DMatrix::from_fn(idx.len(), idx.len(), |r, c| g[(idx[r], idx[c])]);
        let hp = DVector::from_fn(idx.len(), |r, _| h[idx[r]]);
        let sol = gp
            .clone()
            .cholesky()
            .map(|c| c.solve(&hp))
            .or_else(|| gp.lu().solve(&hp))
            .unwrap_or_else(|| DVector::zeros(idx.len()));
        for (k, &i) in idx.iter().enumerate() {
            z[i] = sol[k];
        }
        z
    };
    if free.iter().any(|&i| i < n) {
        x = solve_passive(&passive);
    }
    let tol = 1e-12 * (1.0 + h.amax());
    let max_iter = 30 * n + 100;
    for _ in 0..max_iter {
        // Gradient of the objective (halved, negated): w = h − G x.
        let w = h - g * &x;
        let candidate = (0..n)
            .filter(|&i| !passive[i])
            .max_by(|&a, &b| w[a].total_cmp(&w[b]));
        let Some(t) = candidate.filter(|&t| w[t] > tol) else {
            return Ok(x);
        };
        passive[t] = true;
        loop {
            let z = solve_passive(&passive);
            let bad: Vec<usize> = (0..n)
                .filter(|&i| passive[i] && !is_free(i) && z[i] <= 0.0)
                .collect();
            if bad.is_empty() {
                x = z;
                break;
            }
            // Step from x towards z as far as feasibility allows.
            let alpha = bad
                .iter()
                .map(|&i| x[i] / (x[i] - z[i]))
                .fold(f64::INFINITY, f64::min);
            x = &x + (&z - &x) * alpha;
            for i in 0..n {
                if passive[i] && !is_free(i) && x[i] <= 1e-15 * (1.0 + x.amax()) {
                    passive[i] = false;
                    x[i] = 0.0;
                }
            }
        }
    }
    Err(NnlsError::NotConverged {
        iterations: max_iter,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_negative_unconstrained_solution_is_clipped_and_the_kkt_conditions_hold() {
        // A = I, b = (1, −2, 3): x = (1, 0, 3).
        let a = DMatrix::<f64>::identity(3, 3);
        let b = DVector::from_vec(vec![1.0, -2.0, 3.0]);
        let x = nnls_gram(&(a.transpose() * &a), &(a.transpose() * &b), &[]).unwrap();
        assert!((x - DVector::from_vec(vec![1.0, 0.0, 3.0])).amax() < 1e-12);
        // A free variable keeps its sign.
        let x = nnls_gram(&(a.transpose() * &a), &(a.transpose() * &b), &[1]).unwrap();
        assert!((x[1] + 2.0).abs() < 1e-12);
        // Random overdetermined problem: KKT — gradient zero on the support, pointing
        // into the constraint off it.
        let mut r = crate::Rng::new(5, 1);
        let a = DMatrix::from_fn(40, 6, |_, _| r.gaussian_exact());
        let b = DVector::from_fn(40, |_, _| r.gaussian_exact());
        let g = a.transpose() * &a;
        let h = a.transpose() * &b;
        let x = nnls_gram(&g, &h, &[]).unwrap();
        let w = &h - &g * &x;
        for i in 0..6 {
            assert!(x[i] >= 0.0);
            if x[i] > 0.0 {
                assert!(w[i].abs() < 1e-9, "{i}: {}", w[i]);
            } else {
                assert!(w[i] <= 1e-9, "{i}: {}", w[i]);
            }
        }
    }
}
