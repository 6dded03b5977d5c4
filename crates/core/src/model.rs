//! `model`: the Jacobians (eqs. 5-7), the compliance B_l (eq. 23) and the
//! large-deflection check of both approaches.

use cellinject_model::{Approach, Deviation, Linearisation, Mechanism, ModelError, Tension};
use nalgebra::{SMatrix, Vector3};
use serde::Serialize;

/// One quantity of the large-deflection check.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `linear` | quantity's | constant-Jacobian answer |
/// | `nonlinear` | quantity's | nonlinear equilibrium |
/// | `absolute` | quantity's | norm of the difference |
/// | `relative` | 1 | `absolute` over the norm of `nonlinear` |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Comparison {
    /// Constant Jacobians.
    pub linear: Vec<f64>,
    /// Nonlinear kinematics.
    pub nonlinear: Vec<f64>,
    /// Norm of the difference.
    pub absolute: f64,
    /// Relative to the nonlinear norm.
    pub relative: f64,
}

/// The large-deflection check of one approach.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `approach` | | 1 or 2 |
/// | `dX`, `dX_work` | m | end-effector after tensioning, at the working shift |
/// | `F10`, `F_work` | N | stack forces after tensioning, at the working shift |
/// | `chi` | m | working range |
/// | `dz_tensioned` | m | out-of-plane drop of M after tensioning (nonlinear only) |
/// | `equilibrium_residual` | 1 | of the two nonlinear solves |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LinearisationReport {
    /// 1 or 2.
    pub approach: u8,
    /// End-effector after tensioning, m.
    #[serde(rename = "dX")]
    pub dx: Comparison,
    /// End-effector at the working shift, m.
    #[serde(rename = "dX_work")]
    pub dx_work: Comparison,
    /// Stack forces after tensioning, N.
    #[serde(rename = "F10")]
    pub f10: Comparison,
    /// Stack forces at the working shift, N.
    #[serde(rename = "F_work")]
    pub f_work: Comparison,
    /// Working range, m.
    pub chi: Comparison,
    /// Out-of-plane drop of M after tensioning, m.
    pub dz_tensioned: f64,
    /// Residuals of the tensioned and working equilibria.
    pub equilibrium_residual: [f64; 2],
}

impl LinearisationReport {
    /// (key, SI unit, comparison) in display order.
    pub fn rows(&self) -> [(&'static str, &'static str, &Comparison); 5] {
        [
            ("dX", "m", &self.dx),
            ("dX_work", "m", &self.dx_work),
            ("F10", "N", &self.f10),
            ("F_work", "N", &self.f_work),
            ("chi", "m", &self.chi),
        ]
    }
}

fn comparison(a: &Vector3<f64>, b: &Vector3<f64>, d: Deviation) -> Comparison {
    Comparison {
        linear: a.as_slice().to_vec(),
        nonlinear: b.as_slice().to_vec(),
        absolute: d.absolute,
        relative: d.relative,
    }
}

/// The report of one approach's check.
pub fn linearisation_report(t: &Tension, lin: &Linearisation) -> LinearisationReport {
    LinearisationReport {
        approach: t.approach.number(),
        dx: comparison(&t.tensioned.dx, &lin.tensioned.dx, lin.dx_tensioned),
        dx_work: comparison(&t.work.dx, &lin.work.dx, lin.dx_work),
        f10: comparison(
            &t.tensioned.force,
            &lin.tensioned.force,
            lin.force_tensioned,
        ),
        f_work: comparison(&t.work.force, &lin.work.force, lin.force_work),
        chi: comparison(&t.chi, &lin.chi_nonlinear, lin.chi),
        dz_tensioned: lin.dz_tensioned,
        equilibrium_residual: [lin.tensioned.residual, lin.work.residual],
    }
}

/// Both approaches' analyses and their large-deflection checks.
pub fn linearisations(m: &Mechanism) -> Result<Vec<(Tension, Linearisation)>, ModelError> {
    [Approach::DriveTranslation, Approach::JointDeflection]
        .into_iter()
        .map(|a| Ok((m.tension(a)?, m.linearisation(a)?)))
        .collect()
}

/// The result of `cellinject model`.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `design` | | the description's name |
/// | `J` | m/rad (column 3: m/m) | end-effector Jacobian dX/dq at home (eq. 5) |
/// | `L` | m/rad (column 3: m/m) | drive Jacobian dl/dq (eq. 6) |
/// | `W` | rad/rad | flexure Jacobian dw/dq (eq. 7) |
/// | `B_l` | m/N | compliance on the actuator axes A1, A2 (eq. 23) |
/// | `B_l_axes` | | `["A1", "A2"]` |
/// | `linearisation` | | [`LinearisationReport`] per approach |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModelReport {
    /// The description's name.
    pub design: String,
    /// Rows of J.
    #[serde(rename = "J")]
    pub j: Vec<Vec<f64>>,
    /// Rows of L.
    #[serde(rename = "L")]
    pub l: Vec<Vec<f64>>,
    /// Rows of W.
    #[serde(rename = "W")]
    pub w: Vec<Vec<f64>>,
    /// Rows of B_l.
    #[serde(rename = "B_l")]
    pub b_l: Vec<Vec<f64>>,
    /// Axes of B_l.
    #[serde(rename = "B_l_axes")]
    pub b_l_axes: [&'static str; 2],
    /// Both approaches.
    pub linearisation: Vec<LinearisationReport>,
}

/// Rows of a small matrix.
pub fn matrix_rows<const R: usize, const C: usize>(m: &SMatrix<f64, R, C>) -> Vec<Vec<f64>> {
    (0..R)
        .map(|r| (0..C).map(|c| m[(r, c)]).collect())
        .collect()
}

/// `cellinject model`.
pub fn model(name: &str, m: &Mechanism) -> Result<ModelReport, ModelError> {
    let jac = m.jacobians();
    let b = m.compliance()?;
    let all = linearisations(m)?;
    Ok(ModelReport {
        design: name.to_string(),
        j: matrix_rows(&jac.j),
        l: matrix_rows(&jac.l),
        w: matrix_rows(&jac.w),
        b_l: matrix_rows(&b),
        b_l_axes: ["A1", "A2"],
        linearisation: all
            .iter()
            .map(|(t, l)| linearisation_report(t, l))
            .collect(),
    })
}
