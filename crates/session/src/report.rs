//! A run's report: its records as one self-contained HTML page (inline SVG, no
//! scripts, no external files): the plate map with each attempt's outcome and reason
//! on hover, histograms of the tip error and the dose, throughput over time, and the
//! run's settings and calibrations. `cellinject report` writes it to a file; the
//! dashboard serves it.

use cellinject_plot::{Chart, Series, Style, svg};
use cellinject_records::{AttemptRow, RunRow};
use thiserror::Error;

/// Why a report could not be drawn.
#[derive(Debug, Error)]
pub enum ReportError {
    /// The plots failed.
    #[error("plots: {0}")]
    Plots(String),
    /// The run's settings or calibrations could not be written out.
    #[error("the run's settings: {0}")]
    Json(#[from] serde_json::Error),
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Step-line histogram of `values` (display units) in `bins` bins.
fn histogram(values: &[f64], bins: usize) -> Vec<(f64, f64)> {
    if values.is_empty() {
        return vec![(0.0, 0.0), (1.0, 0.0)];
    }
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let (lo, hi) = if hi > lo {
        (lo, hi)
    } else {
        (lo - 0.5, hi + 0.5)
    };
    let w = (hi - lo) / bins as f64;
    let mut counts = vec![0usize; bins];
    for v in values {
        let k = (((v - lo) / w) as usize).min(bins - 1);
        counts[k] += 1;
    }
    let mut pts = vec![(lo, 0.0)];
    for (k, c) in counts.iter().enumerate() {
        let (a, b) = (lo + k as f64 * w, lo + (k + 1) as f64 * w);
        pts.push((a, *c as f64));
        pts.push((b, *c as f64));
    }
    pts.push((hi, 0.0));
    pts
}

fn plate_map(run: &RunRow, attempts: &[AttemptRow]) -> String {
    let plate = cellinject_config::plate::parse(&run.plate).ok();
    let (rows, cols, pitch) = plate
        .as_ref()
        .map_or((1, 1, 150e-6), |p| (p.rows, p.cols, p.pitch));
    let scale = 600.0 / (cols.max(rows) as f64 * pitch);
    let (w, h) = (cols as f64 * pitch * scale, rows as f64 * pitch * scale);
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{:.0}\" height=\"{:.0}\" viewBox=\"0 0 {w:.1} {h:.1}\">",
        w + 2.0,
        h + 2.0
    );
    for r in 0..rows {
        for c in 0..cols {
            s += &format!(
                "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"#f7f7f7\" stroke=\"#bbb\" stroke-width=\"0.5\"/>",
                c as f64 * pitch * scale,
                r as f64 * pitch * scale,
                pitch * scale,
                pitch * scale
            );
        }
    }
    for a in attempts {
        let colour = match a.outcome.as_str() {
            "injected" => "#2a9d3a",
            "failed" => "#d62828",
            "interrupted" => "#7b2cbf",
            _ => "#f4a261",
        };
        let x = (a.x_m + 0.5 * pitch) * scale;
        let y = (a.y_m + 0.5 * pitch) * scale;
        let tip = a
            .tip_error_m
            .map(|e| format!(", tip error {:.2} µm", e * 1e6))
            .unwrap_or_default();
        let dose = a
            .dose_fraction
            .map(|d| format!(", dose {:.1} %", d * 100.0))
            .unwrap_or_default();
        let title = format!(
            "cell {} well [{}, {}]: {}{}{}{}",
            a.cell,
            a.well[0],
            a.well[1],
            a.outcome,
            tip,
            dose,
            if a.reason.is_empty() {
                String::new()
            } else {
                format!(" — {}", a.reason)
            }
        );
        s += &format!(
            "<circle cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"{:.1}\" fill=\"{colour}\" fill-opacity=\"0.8\"><title>{}</title></circle>",
            (0.5 * a.diameter_m * scale).max(2.0),
            esc(&title)
        );
    }
    s + "</svg>"
}

/// A run's report: one self-contained HTML page.
pub fn html(run: &RunRow, attempts: &[AttemptRow]) -> Result<String, ReportError> {
    let tips: Vec<f64> = attempts
        .iter()
        .filter_map(|a| a.tip_error_m.map(|e| e * 1e6))
        .collect();
    let doses: Vec<f64> = attempts
        .iter()
        .filter(|a| a.outcome == "injected")
        .filter_map(|a| a.dose_fraction.map(|d| d * 100.0))
        .collect();
    let t0 = attempts.first().map_or(0.0, |a| a.t_start);
    let mut done = 0.0;
    let mut through = vec![(0.0, 0.0)];
    for a in attempts {
        if a.outcome == "injected" {
            done += 1.0;
        }
        through.push(((a.t_end.unwrap_or(a.t_start) - t0).max(0.0), done));
    }
    let chart = |title: &str, x: &str, y: &str, pts: Vec<(f64, f64)>| Chart {
        title: title.into(),
        x_label: x.into(),
        y_label: y.into(),
        // One series: no legend (an unnamed series gets none), the title says it.
        series: vec![Series {
            name: String::new(),
            points: pts,
            style: Style::Line,
        }],
    };
    let charts = svg(
        &[
            chart(
                "Tip error at injection",
                "µm",
                "cells",
                histogram(&tips, 20),
            ),
            chart(
                "Dose of the injected cells",
                "% of the cell's volume",
                "cells",
                histogram(&doses, 20),
            ),
            chart(
                "Throughput",
                "device time since the first cell, s",
                "cells injected",
                through,
            ),
        ],
        3,
        (420, 300),
    )
    .map_err(|e| ReportError::Plots(e.to_string()))?;
    let n = |o: &str| attempts.iter().filter(|a| a.outcome == o).count();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let settings = serde_json::to_string_pretty(&run.settings)?;
    let calibration = serde_json::to_string_pretty(&run.calibration)?;
    let html = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>cellinject run {id}</title>\
<style>body{{font-family:sans-serif;margin:2em;max-width:1400px}}td,th{{padding:2px 10px;text-align:left}}pre{{background:#f4f4f4;padding:1em;max-height:30em;overflow:auto}}svg{{max-width:100%;height:auto}}</style></head><body>\
<h1>cellinject run {id}: {status}</h1>\
<table><tr><th>cells found</th><td>{found}</td></tr><tr><th>injected</th><td>{inj}</td></tr><tr><th>failed</th><td>{fail}</td></tr>\
<tr><th>skipped</th><td>{skip}</td></tr><tr><th>interrupted</th><td>{intr}</td></tr>\
<tr><th>simulated time</th><td>{sim:.1} s ({cell:.1} s on cells)</td></tr><tr><th>mean tip error</th><td>{tip:.2} µm</td></tr>\
<tr><th>stopped</th><td>{stopped}</td></tr><tr><th>resumed</th><td>{resumed}</td></tr></table>\
<h2>Plate map</h2><p>green injected, red failed, orange skipped, purple interrupted; hover a cell for its record.</p>{map}\
<h2>Tip error, dose, throughput</h2>{charts}\
<h2>Settings</h2><pre>{settings}</pre><h2>Calibrations in force</h2><pre>{calibration}</pre></body></html>\n",
        id = run.id,
        status = esc(&run.status),
        found = run.cells_found,
        inj = n("injected"),
        fail = n("failed"),
        skip = n("skipped"),
        intr = n("interrupted"),
        sim = run.sim_time_s,
        cell = run.cell_time_s,
        tip = mean(&tips),
        stopped = esc(run.stopped.as_deref().unwrap_or("no")),
        resumed = match run.resumed {
            0 => "never".to_string(),
            1 => "once".to_string(),
            n => format!("{n} times"),
        },
        map = plate_map(run, attempts),
        settings = esc(&settings),
        calibration = esc(&calibration),
    );
    Ok(html)
}
