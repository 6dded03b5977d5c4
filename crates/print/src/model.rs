//! The mechanism's reports as text (`cellinject tension`, `model`, `reproduce`): the
//! pre-tension quantities and margins, the Jacobians and compliance, the
//! large-deflection check, and the reproduction of the paper's figures as a table and a
//! Markdown report.

use cellinject_core::model::{LinearisationReport, ModelReport};
use cellinject_core::reproduce::ReproduceReport;
use cellinject_core::tension::{TILT_ACTUATORS, TensionReport, approach_title};

use crate::table::{Table, display_unit, number, vector};

/// `cellinject tension`'s text: every quantity with its equation, then the margins
/// over the working range and a warning per violated one.
pub fn tension_text(r: &TensionReport) -> String {
    let mut out = format!(
        "Pre-tension, approach {}: {}\nDesign: {}\n\n",
        r.approach.number(),
        approach_title(r.approach),
        r.design
    );
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
    out.push_str(&table.text());
    out.push_str("\nMargins over the working range:\n");
    out.push_str(&margins_text(r));
    if r.warnings.is_empty() {
        out.push_str("\nAll margins hold.\n");
    } else {
        out.push('\n');
        for w in &r.warnings {
            out.push_str(&format!("warning: {w}\n"));
        }
    }
    out
}

/// The margins of one approach over the working range, as a table, and the
/// end-effector's offset after tensioning.
pub fn margins_text(r: &TensionReport) -> String {
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

/// A matrix of `rows`, named, in `unit`; entries below the printed precision as 0.
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

/// The large-deflection check: each quantity with constant Jacobians and nonlinear.
pub fn linearisation_table(all: &[LinearisationReport]) -> Table {
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

/// `cellinject model`'s text: the Jacobians at the home pose, the compliance on the
/// actuator axes and the large-deflection check, for the design `name`.
pub fn model_text(name: &str, r: &ModelReport) -> String {
    let mut out = format!("Mechanism model of {name}\n\n");
    out.push_str(
        "Jacobians at the home pose (eqs. 5-7), obtained by differentiating the nonlinear kinematics:\n",
    );
    out.push_str(&matrix_text("J = dX/dq", &r.j, "m/rad; column 3: m/m"));
    out.push_str(&matrix_text("L = dl/dq", &r.l, "m/rad; column 3: m/m"));
    out.push_str(&matrix_text("W = dw/dq", &r.w, "rad/rad"));
    let b_um: Vec<Vec<f64>> = r
        .b_l
        .iter()
        .map(|row| row.iter().map(|x| x * 1e6).collect())
        .collect();
    out.push_str(&matrix_text(
        "B_l, compliance on the actuator axes A1, A2 (eq. 23)",
        &b_um,
        "µm/N",
    ));
    out.push_str(
        "  (A3 is a serial axis with neither flexure nor preload: no compliance entry)\n\n",
    );
    out.push_str("Large-deflection check: constant Jacobians vs the nonlinear equilibrium\n");
    out.push_str(&linearisation_table(&r.linearisation).text());
    for l in &r.linearisation {
        out.push_str(&format!(
            "approach {}: out-of-plane drop of M after tensioning {} µm; equilibrium residuals {:.1e}, {:.1e}\n",
            l.approach,
            number(l.dz_tensioned, "m"),
            l.equilibrium_residual[0],
            l.equilibrium_residual[1]
        ));
    }
    out
}

/// The reproduced figures: each with its equation, the paper's value, the computed one,
/// their relative difference and whether they agree.
pub fn reproduce_table(r: &ReproduceReport) -> Table {
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
    table
}

/// The note that a design other than the paper's prototype differs from its figures
/// (empty for the prototype).
pub fn reproduce_caveat(name: &str, r: &ReproduceReport) -> String {
    if r.is_prototype {
        String::new()
    } else {
        format!(
            "Note: the design `{name}` is not the paper's prototype; differences from the paper's figures are expected.\n"
        )
    }
}

/// `reproduce.md`: the reproduction of Sec. 3.2 for the design `name`, its notes on the
/// printed figures, the margins and the large-deflection check.
pub fn reproduce_markdown(name: &str, r: &ReproduceReport) -> String {
    let table = reproduce_table(r);
    let caveat = reproduce_caveat(name, r);
    let (n, ok) = (r.computed, r.agree);
    let mut md = String::new();
    md.push_str("# Reproduction of Sec. 3.2 (eqs. 37-58)\n\n");
    md.push_str(&format!(
        "Design: **{}**. Source: Chakarov, Kostadinov et al., *Development of a Piezo-actuated \
         Robot for Cell Injection*, ICINCO 2012. The paper rounds its figures and truncates some; \
         a figure agrees when the relative difference is at most {:.1} % (measured against the \
         largest component where the paper prints 0), or, for a truncated figure, when the \
         computed value truncates to it.\n\n",
        name,
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
    md
}
