//! `reproduce`: every figure of the paper's Sec. 3.2 (eqs. 37-58), computed and
//! compared with the published value.

use cellinject_model::{Design, Mechanism, ModelError};
use cellinject_paper as paper;
use serde::Serialize;
use thiserror::Error;

use crate::model::{LinearisationReport, linearisation_report, linearisations};
use crate::tension::{TensionReport, report};

/// Why the reproduction could not be made.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ReproduceError {
    /// The model failed.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// A published figure has no computed counterpart.
    #[error("{0}")]
    Missing(String),
}

/// One published figure beside its computed value.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `eq` | | equation number |
/// | `approach` | | 1 or 2 |
/// | `key` | | quantity (as in `tension`) |
/// | `unit` | | SI unit of `paper` and `computed` |
/// | `paper` | `unit` | the published value (corrected where misprinted) |
/// | `printed` | `unit` | the value as printed, where it was misprinted |
/// | `computed` | `unit` | this design's value |
/// | `rel_diff` | 1 | largest relative difference over the components |
/// | `status` | | `input`, `ok`, `ok (truncated)` or `DIFFERS` |
/// | `note` | | on misprints and truncation |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FigureRow {
    /// Equation number.
    pub eq: u32,
    /// 1 or 2.
    pub approach: u8,
    /// Quantity key.
    pub key: String,
    /// SI unit.
    pub unit: String,
    /// Published value.
    pub paper: Vec<f64>,
    /// As printed, if misprinted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub printed: Option<Vec<f64>>,
    /// Computed value.
    pub computed: Vec<f64>,
    /// Relative difference.
    pub rel_diff: f64,
    /// Status.
    pub status: &'static str,
    /// Note.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// The result of `cellinject reproduce`.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `design` | | the description's name |
/// | `is_prototype` | | whether it is the paper's prototype (else differences are expected) |
/// | `tolerance` | 1 | relative tolerance of the paper's rounding |
/// | `computed` | | number of computed (not input) figures |
/// | `agree` | | of which agree |
/// | `figures` | | [`FigureRow`] per figure, in equation order |
/// | `tension` | | the `tension` report of each approach |
/// | `linearisation` | | the large-deflection check of each approach (as in `model`) |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReproduceReport {
    /// Name.
    pub design: String,
    /// The paper's prototype.
    pub is_prototype: bool,
    /// Relative tolerance.
    pub tolerance: f64,
    /// Computed figures.
    pub computed: usize,
    /// Agreeing figures.
    pub agree: usize,
    /// Every figure.
    pub figures: Vec<FigureRow>,
    /// Both approaches' analyses.
    pub tension: Vec<TensionReport>,
    /// Both approaches' large-deflection checks.
    pub linearisation: Vec<LinearisationReport>,
}

/// `cellinject reproduce`.
pub fn reproduce(name: &str, design: &Design) -> Result<ReproduceReport, ReproduceError> {
    let m = Mechanism::new(design)?;
    let all = linearisations(&m)?;
    let rows = paper::compare(|a, k| {
        all.iter()
            .find(|(t, _)| t.approach.number() == a)
            .and_then(|(t, _)| t.quantity(k))
    })
    .map_err(ReproduceError::Missing)?;
    let (computed, agree) = paper::summary(&rows);
    let figures = rows
        .iter()
        .map(|r| {
            let f = &r.figure;
            FigureRow {
                eq: f.eq,
                approach: f.approach,
                key: f.key.clone(),
                unit: f.unit.clone(),
                paper: f.value.clone(),
                printed: f.printed.clone(),
                computed: r.computed.clone(),
                rel_diff: r.rel_diff,
                status: paper::status(r),
                note: f.note.clone(),
            }
        })
        .collect();
    Ok(ReproduceReport {
        design: name.to_string(),
        is_prototype: *design == cellinject_model::prototype(),
        tolerance: paper::tolerance(),
        computed,
        agree,
        figures,
        tension: all.iter().map(|(t, _)| report(name, design, t)).collect(),
        linearisation: all
            .iter()
            .map(|(t, l)| linearisation_report(t, l))
            .collect(),
    })
}
