//! The subcommands: load inputs, call the library crates, present the results.

use std::path::Path;

use anyhow::{Context, Result};
use cellinject_config::Description;
use cellinject_core::model::{LinearisationReport, ModelReport};
use cellinject_core::reproduce::ReproduceReport;
use cellinject_core::tension::{TILT_ACTUATORS, TensionReport, approach_title};
use cellinject_model::Approach;

use crate::{Format, InputError};
use cellinject_print::table::{Table, display_unit, number, vector};

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
        Format::Text => {
            outln!("Pre-tension, approach {approach}: {}", approach_title(a));
            outln!("Design: {}\n", d.name);
            let mut table = Table::new(
                &["quantity", "eq.", "meaning", "unit", "value"],
                &[false, false, false, false, false],
            );
            for q in &r.quantities {
                table.row(vec![
                    q.key.to_string(),
                    q.eq.map(|e| format!("({e})")).unwrap_or_default(),
                    q.meaning.to_string(),
                    display_unit(q.unit).0.to_string(),
                    vector(&q.value, q.unit),
                ]);
            }
            out!("{}", table.text());
            outln!("\nMargins over the working range:");
            out!("{}", margins_text(&r));
            if r.warnings.is_empty() {
                outln!("\nAll margins hold.");
            } else {
                outln!();
                for w in &r.warnings {
                    outln!("warning: {w}");
                }
            }
        }
    }
    Ok(())
}

fn margins_text(r: &TensionReport) -> String {
    let g = &r.margins;
    let mut table = Table::new(
        &[
            "actuator",
            "force range [N]",
            "compression margin [N]",
            "capacity margin [N]",
            "flexure torque [mN·m]",
            "limit [mN·m]",
            "torque margin [mN·m]",
        ],
        &[false, true, true, true, true, true, true],
    );
    for i in 0..2 {
        table.row(vec![
            TILT_ACTUATORS[i].to_string(),
            format!(
                "{} .. {}",
                number(g.force_range[i][0], "N"),
                number(g.force_range[i][1], "N")
            ),
            number(g.compression_margin[i], "N"),
            number(g.capacity_margin[i], "N"),
            number(g.torque_max[i], "N*m"),
            number(g.torque_limit[i], "N*m"),
            number(g.torque_margin[i], "N*m"),
        ]);
    }
    format!(
        "{}End-effector offset after tensioning, length |δX|: {} µm\n",
        table.text(),
        number(g.offset, "m")
    )
}

fn matrix_text(name: &str, rows: &[Vec<f64>], unit: &str) -> String {
    let mut out = format!("{name} [{unit}]\n");
    for r in rows {
        // Entries below the printed precision (rounding of the implicit differentiation)
        // are shown as 0 rather than -0.000000.
        let cells: Vec<String> = r
            .iter()
            .map(|x| if x.abs() < 5e-7 { 0.0 } else { *x })
            .map(|x| format!("{x:>12.6}"))
            .collect();
        out.push_str(&format!("  [{} ]\n", cells.join(" ")));
    }
    out
}

fn linearisation_table(all: &[LinearisationReport]) -> Table {
    let mut table = Table::new(
        &[
            "approach",
            "quantity",
            "unit",
            "constant Jacobians",
            "nonlinear",
            "abs. difference",
            "relative",
        ],
        &[false, false, false, false, false, true, true],
    );
    for lin in all {
        for (key, unit, c) in lin.rows() {
            table.row(vec![
                lin.approach.to_string(),
                key.to_string(),
                display_unit(unit).0.to_string(),
                vector(&c.linear, unit),
                vector(&c.nonlinear, unit),
                number(c.absolute, unit),
                format!("{:.2e}", c.relative),
            ]);
        }
    }
    table
}

/// `cellinject model`.
pub fn model(d: &Description, format: Format) -> Result<()> {
    let r: ModelReport =
        cellinject_core::model::model(&d.name, &d.mechanism()).context("mechanism model")?;
    match format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&r)?),
        Format::Text => {
            outln!("Mechanism model of {}\n", d.name);
            outln!(
                "Jacobians at the home pose (eqs. 5-7), obtained by differentiating the nonlinear kinematics:"
            );
            out!("{}", matrix_text("J = dX/dq", &r.j, "m/rad; column 3: m/m"));
            out!("{}", matrix_text("L = dl/dq", &r.l, "m/rad; column 3: m/m"));
            out!("{}", matrix_text("W = dw/dq", &r.w, "rad/rad"));
            let b_um: Vec<Vec<f64>> = r
                .b_l
                .iter()
                .map(|row| row.iter().map(|x| x * 1e6).collect())
                .collect();
            out!(
                "{}",
                matrix_text(
                    "B_l, compliance on the actuator axes A1, A2 (eq. 23)",
                    &b_um,
                    "µm/N"
                )
            );
            outln!(
                "  (A3 is a serial axis with neither flexure nor preload: no compliance entry)\n"
            );
            outln!("Large-deflection check: constant Jacobians vs the nonlinear equilibrium");
            out!("{}", linearisation_table(&r.linearisation).text());
            for l in &r.linearisation {
                outln!(
                    "approach {}: out-of-plane drop of M after tensioning {} µm; equilibrium residuals {:.1e}, {:.1e}",
                    l.approach,
                    number(l.dz_tensioned, "m"),
                    l.equilibrium_residual[0],
                    l.equilibrium_residual[1]
                );
            }
        }
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
    let mut plan = crate::files::Plan::new();
    plan.output("--out", &path, &[crate::files::Kind::Markdown])?;
    plan.check()?;
    let r: ReproduceReport = cellinject_core::reproduce::reproduce(&d.name, &d.design)
        .context("reproduction of the paper's figures")?;
    let mut table = Table::new(
        &[
            "eq.",
            "appr.",
            "quantity",
            "unit",
            "paper",
            "computed",
            "rel. diff",
            "status",
        ],
        &[false, false, false, false, true, true, true, false],
    );
    for f in &r.figures {
        table.row(vec![
            format!("({})", f.eq),
            f.approach.to_string(),
            f.key.clone(),
            display_unit(&f.unit).0.to_string(),
            vector(&f.paper, &f.unit),
            vector(&f.computed, &f.unit),
            format!("{:.2e}", f.rel_diff),
            f.status.to_string(),
        ]);
    }
    let (n, ok) = (r.computed, r.agree);
    let caveat = if r.is_prototype {
        String::new()
    } else {
        format!(
            "Note: the design `{}` is not the paper's prototype; differences from the paper's figures are expected.\n",
            d.name
        )
    };
    let mut md = String::new();
    md.push_str("# Reproduction of Sec. 3.2 (eqs. 37-58)\n\n");
    md.push_str(&format!(
        "Design: **{}**. Source: Chakarov, Kostadinov et al., *Development of a Piezo-actuated \
         Robot for Cell Injection*, ICINCO 2012. The paper rounds its figures and truncates some; \
         a figure agrees when the relative difference is at most {:.1} % (measured against the \
         largest component where the paper prints 0), or, for a truncated figure, when the \
         computed value truncates to it.\n\n",
        d.name,
        r.tolerance * 100.0
    ));
    md.push_str(&caveat);
    md.push_str(&format!("**{ok} of {n}** computed figures agree.\n\n"));
    md.push_str(&table.markdown());
    md.push_str("\n## Notes on the printed figures\n\n");
    for f in r.figures.iter().filter(|f| f.note.is_some()) {
        let printed = f
            .printed
            .as_ref()
            .map(|p| format!(" (printed {})", vector(p, &f.unit)))
            .unwrap_or_default();
        md.push_str(&format!(
            "- eq. ({}) `{}`{}: {}.\n",
            f.eq,
            f.key,
            printed,
            f.note.as_deref().unwrap_or_default()
        ));
    }
    md.push_str("\n## Margins over the working range\n\n");
    for t in &r.tension {
        md.push_str(&format!(
            "Approach {}: {}.\n\n```\n{}```\n\n",
            t.approach.number(),
            approach_title(t.approach),
            margins_text(t)
        ));
        for w in &t.warnings {
            md.push_str(&format!("- warning: {w}\n"));
        }
        md.push('\n');
    }
    md.push_str("## Large-deflection check\n\n");
    md.push_str(
        "The same equilibrium (eq. 19) solved with the nonlinear kinematics instead of the \
         constant Jacobians; the paper assumes the difference is negligible. Differences of \
         the end-effector are taken on axes 1-2; the nonlinear column also shows the \
         out-of-plane displacement of M, which the constant-Jacobian model does not have.\n\n",
    );
    md.push_str(&linearisation_table(&r.linearisation).markdown());

    crate::files::write_one(&path, md.as_bytes())?;
    match format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&r)?),
        Format::Text => {
            outln!(
                "Reproduction of Sec. 3.2 (eqs. 37-58), design: {}\n",
                d.name
            );
            out!("{}", table.text());
            outln!(
                "\n{ok} of {n} computed figures agree with the paper (tolerance {:.1} %).",
                r.tolerance * 100.0
            );
            out!("{caveat}");
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
