//! `cellinject report`: a run's records as one self-contained HTML page (inline SVG,
//! no scripts, no external files): the plate map with each attempt's outcome and reason
//! on hover, histograms of the tip error and the dose, throughput over time, and the
//! run's settings and calibrations.

use std::path::{Path, PathBuf};

use anyhow::Result;
use cellinject_records::{AttemptRow, RunRow};

use cellinject_files::{Kind, Plan, write_one};

/// Writes the report of run `id` (or the latest) of `db` to `out`: that file if it
/// ends in `.html` (or `.htm`), else `out/report.html` (the directory made).
pub fn report(db: &Path, id: Option<i64>, out: &Path) -> Result<PathBuf> {
    let records = crate::run::open_existing(db)?;
    let run = records.run(id).map_err(crate::run::records_error)?;
    let attempts = records
        .attempts(run.id)
        .map_err(crate::run::records_error)?;
    let file = if Kind::of(out) == Some(Kind::Html) {
        out.to_path_buf()
    } else {
        // A file in the way is refused naming it (not a directory of that name).
        cellinject_files::make_dir("--out", out)?;
        out.join("report.html")
    };
    let mut plan = Plan::new();
    plan.input("--db", db);
    plan.output("--out", &file, &[Kind::Html])?;
    plan.check()?;
    let html = html(&run, &attempts)?;
    write_one(&file, html.as_bytes())?;
    Ok(file)
}

/// A run's report: one self-contained HTML page (`cellinject_session::report`).
pub fn html(run: &RunRow, attempts: &[AttemptRow]) -> Result<String> {
    cellinject_session::report::html(run, attempts).map_err(|e| anyhow::anyhow!("{e}"))
}
