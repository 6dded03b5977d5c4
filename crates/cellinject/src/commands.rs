//! The subcommands: load inputs, call the library crates, present the results.

use std::path::Path;

use anyhow::{Context, Result};
use cellinject_config::Description;
use cellinject_core::model::ModelReport;
use cellinject_core::reproduce::ReproduceReport;

use cellinject_model::Approach;

use crate::{Format, InputError};
use cellinject_print::model as print;

/// Reads and validates the description file, or returns the embedded prototype.
pub fn load_description(path: Option<&Path>) -> Result<Description> {
    let Some(path) = path else {
        return Ok(cellinject_config::prototype());
    };
    let text = std::fs::read_to_string(path).map_err(|e| {
        InputError(format!(
            "cannot read description file `{}`: {e}",
            path.display()
        ))
    })?;
    cellinject_config::parse(&text)
        .map_err(|e| InputError(format!("description file `{}`: {e}", path.display())).into())
}

fn approach_of(n: u8) -> Result<Approach> {
    Approach::from_number(n)
        .ok_or_else(|| InputError(format!("--approach must be 1 or 2, got {n}")).into())
}

/// `cellinject tension`.
pub fn tension(d: &Description, approach: u8, format: Format) -> Result<()> {
    let a = approach_of(approach)?;
    let r = cellinject_core::tension::tension(&d.name, &d.design, a)
        .context("pre-tension analysis failed")?;
    match format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&r)?),
        Format::Text => out!("{}", print::tension_text(&r)),
    }
    Ok(())
}

/// `cellinject model`.
pub fn model(d: &Description, format: Format) -> Result<()> {
    let r: ModelReport =
        cellinject_core::model::model(&d.name, &d.mechanism()).context("mechanism model")?;
    match format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&r)?),
        Format::Text => out!("{}", print::model_text(&d.name, &r)),
    }
    Ok(())
}

/// `cellinject reproduce`.
pub fn reproduce(d: &Description, out: &Path, format: Format) -> Result<()> {
    // The report's directory may be created; it must be writable before any work.
    std::fs::create_dir_all(out).map_err(|e| {
        InputError(format!(
            "--out `{}`: cannot create the report directory: {e}",
            out.display()
        ))
    })?;
    let path = out.join("reproduce.md");
    let mut plan = cellinject_files::Plan::new();
    plan.output("--out", &path, &[cellinject_files::Kind::Markdown])?;
    plan.check()?;
    let r: ReproduceReport = cellinject_core::reproduce::reproduce(&d.name, &d.design)
        .context("reproduction of the paper's figures")?;
    let table = print::reproduce_table(&r);
    let md = print::reproduce_markdown(&d.name, &r);
    cellinject_files::write_one(&path, md.as_bytes())?;
    match format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&r)?),
        Format::Text => {
            outln!(
                "Reproduction of Sec. 3.2 (eqs. 37-58), design: {}\n",
                d.name
            );
            out!("{}", table.text());
            outln!(
                "\n{} of {} computed figures agree with the paper (tolerance {:.1} %).",
                r.agree,
                r.computed,
                r.tolerance * 100.0
            );
            out!("{}", print::reproduce_caveat(&d.name, &r));
            outln!("Report written to {}", path.display());
        }
    }
    Ok(())
}

/// Parses a pair typed as one word, `A,B` (`expected` says what, in the message): two
/// finite numbers.
pub fn parse_pair(s: &str, expected: &str) -> Result<[f64; 2], String> {
    let bad = || format!("expected {expected} (two finite numbers), got `{s}`");
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != 2 {
        return Err(bad());
    }
    let mut out = [0.0f64; 2];
    for (o, p) in out.iter_mut().zip(&parts) {
        *o = p.trim().parse().map_err(|_| bad())?;
        if !o.is_finite() {
            return Err(bad());
        }
    }
    Ok(out)
}
