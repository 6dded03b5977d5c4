//! One-dimensional quadratic Lagrange shape functions and 3-point Gauss quadrature,
//! shared by the 2-D (9-node) and 3-D (27-node) elements as tensor products.

/// Lagrange quadratic shape functions on [−1, 1] (nodes −1, 0, 1) and their derivatives.
#[inline]
pub(crate) fn quad(x: f64) -> ([f64; 3], [f64; 3]) {
    (
        [0.5 * x * (x - 1.0), 1.0 - x * x, 0.5 * x * (x + 1.0)],
        [x - 0.5, -2.0 * x, x + 0.5],
    )
}

/// Gauss-Legendre points and weights, 3 points on [−1, 1] (exact to degree 5).
pub(crate) const G3: [(f64, f64); 3] = [
    (-0.774_596_669_241_483_4, 5.0 / 9.0),
    (0.0, 8.0 / 9.0),
    (0.774_596_669_241_483_4, 5.0 / 9.0),
];
