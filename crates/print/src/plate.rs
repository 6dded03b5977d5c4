//! The plate commands' text (`cellinject plate generate|check|detect`).

use std::fmt::Write as _;

use cellinject_core::cells::DetectionReport;
use cellinject_plate::Summary;

/// `n` and the noun, singular or plural.
fn count(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

/// `cellinject plate generate|check`'s line: wells, cells and their sizes, doublets,
/// empty wells, debris.
pub fn summary_text(s: &Summary) -> String {
    let sizes = s
        .cell_diameter_m
        .map(|d| {
            if (d[1] - d[0]).abs() < 0.05e-6 {
                format!(" of {:.1} µm", d[0] * 1e6)
            } else {
                format!(" of {:.1}-{:.1} µm", d[0] * 1e6, d[1] * 1e6)
            }
        })
        .unwrap_or_default();
    format!(
        "{}x{} wells at {:.1} µm: {}{sizes}, {}, {}, {}",
        s.rows,
        s.cols,
        s.pitch_m * 1e6,
        count(s.cells, "cell", "cells"),
        count(s.doublets, "doublet", "doublets"),
        count(s.empty_wells, "empty well", "empty wells"),
        count(s.debris, "piece of debris", "pieces of debris")
    )
}

/// `cellinject plate detect`'s text: the frame, what was in view, what was found and
/// how well it matches the plate's truth.
pub fn detect_text(r: &DetectionReport, zoom: f64, size: (u32, u32), pitch: f64) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}x{} frame at {zoom}x ({:.3} µm per pixel): {} of the plate's cells and {} pieces of debris in view",
        size.0,
        size.1,
        pitch * 1e6,
        r.true_cells,
        r.true_debris
    );
    let _ = writeln!(
        out,
        "found {} cells ({} split from a touching neighbour) and {} debris; {} match a true cell, {} do not ({} of them debris), {} cells missed",
        r.found_cells,
        r.cells.iter().filter(|c| c.split).count(),
        r.found_debris,
        r.true_positives,
        r.false_positives,
        r.debris_called_cells,
        r.false_negatives
    );
    let ratio = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.3}"));
    let um = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{:.3} µm", v * 1e6));
    let _ = writeln!(
        out,
        "precision {}, recall {}; centre error median {}, 95th percentile {}; diameter error median {}",
        ratio(r.precision),
        ratio(r.recall),
        um(r.centre_error_m.map(|c| c[0])),
        um(r.centre_error_m.map(|c| c[1])),
        um(r.diameter_error_m)
    );
    out.pop();
    out
}
