//! # cellinject-paper
//!
//! The source paper's published figures (Sec. 3.2, eqs. 37-58), kept in the project's
//! own `figures.toml` with their equation numbers, and the comparison of computed values
//! against them.
//!
//! **Architecture invariant:** the figures here are only ever compared with; no model
//! code reads them to compute anything.

use std::sync::OnceLock;

use serde::Deserialize;

/// The figures file, embedded.
pub const FIGURES_TOML: &str = include_str!("../figures.toml");

/// One published figure.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Figure {
    /// Equation number in the paper.
    pub eq: u32,
    /// Pre-tensioning approach, 1 or 2.
    pub approach: u8,
    /// Quantity name, as in the `tension` JSON output.
    pub key: String,
    /// `"input"` for values the paper sets rather than computes.
    #[serde(default)]
    pub kind: Option<String>,
    /// SI unit.
    pub unit: String,
    /// The value (corrected where the paper misprints, see `printed`).
    pub value: Vec<f64>,
    /// The value as printed, where it differs from `value`.
    #[serde(default)]
    pub printed: Option<Vec<f64>>,
    /// Set when the paper truncates the figure to this many decimals (SI unit).
    #[serde(default)]
    pub truncated_decimals: Option<i32>,
    /// What the quantity is.
    pub what: String,
    /// Remarks on how the paper prints it.
    #[serde(default)]
    pub note: Option<String>,
}

impl Figure {
    /// Whether the paper sets this value rather than computing it.
    pub fn is_input(&self) -> bool {
        self.kind.as_deref() == Some("input")
    }
}

/// One load case of the paper's whole-manipulator FEA (Tables 1 and 2).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeaCase {
    /// N, force on the end of A1's motor loop.
    #[serde(rename = "F11")]
    pub f11: f64,
    /// N, force on the end of A2's motor loop.
    #[serde(rename = "F12")]
    pub f12: f64,
    /// m, end-effector displacement along x.
    pub dx: f64,
    /// m, end-effector displacement along y.
    pub dy: f64,
}

/// One of the paper's FEA tables (Sec. 3.3).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeaTable {
    /// Table number (1 or 2).
    pub table: u8,
    /// Pre-tensioning approach.
    pub approach: u8,
    /// m, dx change from raising F12 alone (case 3 against case 1).
    pub coupling_x: f64,
    /// The load cases.
    pub cases: Vec<FeaCase>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    tolerance: f64,
    figure: Vec<Figure>,
    fea_table: Vec<FeaTable>,
}

fn file() -> &'static File {
    static FILE: OnceLock<File> = OnceLock::new();
    FILE.get_or_init(|| {
        toml::from_str(FIGURES_TOML)
            .unwrap_or_else(|e| unreachable!("embedded figures.toml is invalid: {e}"))
    })
}

/// Every figure, in equation order.
pub fn figures() -> &'static [Figure] {
    &file().figure
}

/// The paper's Tables 1 and 2.
pub fn fea_tables() -> &'static [FeaTable] {
    &file().fea_table
}

/// The relative tolerance the paper's rounding allows (0.1 %).
pub fn tolerance() -> f64 {
    file().tolerance
}

/// A figure with its computed counterpart.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// The published figure.
    pub figure: Figure,
    /// The computed value, same length and units.
    pub computed: Vec<f64>,
    /// Largest relative difference over the components; a component the paper prints as
    /// zero is measured against the vector's largest magnitude.
    pub rel_diff: f64,
}

impl Row {
    /// Whether the computed value agrees with the figure: within the relative tolerance,
    /// or, for a truncated figure, equal to it once truncated the same way.
    pub fn pass(&self) -> bool {
        self.rel_diff <= tolerance() || self.matches_truncated()
    }

    /// Whether the figure is truncated and the computed value truncates to it.
    pub fn matches_truncated(&self) -> bool {
        let Some(d) = self.figure.truncated_decimals else {
            return false;
        };
        let scale = 10f64.powi(d);
        self.figure.value.len() == self.computed.len()
            && self
                .figure
                .value
                .iter()
                .zip(&self.computed)
                .all(|(p, c)| ((c * scale).trunc() - p * scale).abs() < 1e-6)
    }
}

/// The relative difference used by [`Row::rel_diff`].
pub fn relative_difference(paper: &[f64], computed: &[f64]) -> f64 {
    if paper.len() != computed.len() {
        return f64::INFINITY;
    }
    let scale = paper.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    paper
        .iter()
        .zip(computed)
        .map(|(p, c)| {
            let d = (c - p).abs();
            if *p != 0.0 {
                d / p.abs()
            } else if scale > 0.0 {
                d / scale
            } else {
                d
            }
        })
        .fold(0.0, f64::max)
}

/// Compares every figure with `lookup(approach, key)`. A figure with no computed
/// counterpart is returned in the error.
pub fn compare<F>(lookup: F) -> Result<Vec<Row>, String>
where
    F: Fn(u8, &str) -> Option<Vec<f64>>,
{
    figures()
        .iter()
        .map(|f| {
            let computed = lookup(f.approach, &f.key)
                .ok_or_else(|| format!("eq. ({}): no computed value for `{}`", f.eq, f.key))?;
            Ok(Row {
                rel_diff: relative_difference(&f.value, &computed),
                figure: f.clone(),
                computed,
            })
        })
        .collect()
}

/// Short status of a row: `input`, `ok`, `ok (truncated)` or `DIFFERS`.
pub fn status(row: &Row) -> &'static str {
    if row.figure.is_input() {
        "input"
    } else if row.rel_diff <= tolerance() {
        "ok"
    } else if row.matches_truncated() {
        "ok (truncated)"
    } else {
        "DIFFERS"
    }
}

/// Summary counts: (computed figures, of which agree).
pub fn summary(rows: &[Row]) -> (usize, usize) {
    let computed: Vec<&Row> = rows.iter().filter(|r| !r.figure.is_input()).collect();
    (computed.len(), computed.iter().filter(|r| r.pass()).count())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn figures_cover_eqs_37_to_58_in_order() {
        let eqs: Vec<u32> = figures().iter().map(|f| f.eq).collect();
        let expected: Vec<u32> = (37..=58).collect();
        assert_eq!(eqs, expected);
        assert!(figures().iter().all(|f| f.approach == 1 || f.approach == 2));
        assert_eq!(tolerance(), 1e-3);
    }

    #[test]
    fn relative_difference_measures_zero_components_against_the_largest() {
        assert_eq!(relative_difference(&[2.0, 0.0], &[2.0, 0.0]), 0.0);
        assert!((relative_difference(&[2.0, 0.0], &[2.002, 0.0]) - 1e-3).abs() < 1e-12);
        assert!((relative_difference(&[2.0, 0.0], &[2.0, 0.01]) - 5e-3).abs() < 1e-12);
        assert_eq!(relative_difference(&[1.0], &[1.0, 2.0]), f64::INFINITY);
    }

    #[test]
    fn truncated_figures_match_only_values_that_truncate_to_them() {
        let f = figures().iter().find(|f| f.eq == 43).unwrap().clone();
        let row = |c: f64| Row {
            rel_diff: relative_difference(&f.value, &[c, 0.0, -c, 0.0]),
            computed: vec![c, 0.0, -c, 0.0],
            figure: f.clone(),
        };
        assert!(row(0.3169).pass());
        assert!(!row(0.3171).pass());
        assert!(!row(0.3155).pass());
    }

    #[test]
    fn a_missing_quantity_is_an_error() {
        let e = compare(|_, k| (k != "chi").then(|| vec![0.0; 3])).unwrap_err();
        assert!(e.contains("chi"), "{e}");
    }
}
