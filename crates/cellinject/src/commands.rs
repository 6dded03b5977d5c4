//! The subcommands: load inputs, call the library crates, present the results.

use std::path::Path;

use anyhow::{Context, Result};
use cellinject_config::Description;
use cellinject_model::{ACTUATOR_NAMES, Approach, Deviation, Linearisation, Mechanism, Tension};
use cellinject_paper as paper;
use serde_json::{Value, json};

use crate::output::{Table, display_unit, number, vector, write_atomic};
use crate::{Format, InputError};

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

/// SI unit and a short meaning of each quantity of [`Tension::quantities`].
fn quantity_info(key: &str) -> (&'static str, &'static str) {
    match key {
        "F10" => ("N", "actuator force after tensioning F10"),
        "dl0" => ("m", "assembly translation along the drives Δl0"),
        "dq0" => ("rad", "assembly deflection of J3 Δq0"),
        "dl1" => ("m", "elastic deformation of the stacks Δl1"),
        "dl" => ("m", "effective drive displacement δl"),
        "dX" => ("m", "end-effector offset after tensioning δX"),
        "Fq" => ("N*m", "torques in J3 Fq"),
        "Fw" => ("N*m", "torques in J1, J2 Fw (axes 11, 12, 21, 22)"),
        "dl2" => ("m", "working shift Δl2"),
        "dl_total" => ("m", "Δl0 + Δl2"),
        "F_work" => ("N", "actuator force at the working shift"),
        "dl1_work" => ("m", "elastic deformation at the working shift"),
        "dl_work" => ("m", "effective drive displacement at the working shift"),
        "dX_work" => ("m", "end-effector at the working shift"),
        "Fq_work" => ("N*m", "torques in J3 at the working shift"),
        "Fw_work" => ("N*m", "torques in J1, J2 at the working shift"),
        "chi" => ("m", "working range χ (axis 3: A3 travel)"),
        _ => ("", ""),
    }
}

fn approach_of(n: u8) -> Result<Approach> {
    Approach::from_number(n)
        .ok_or_else(|| InputError(format!("--approach must be 1 or 2, got {n}")).into())
}

fn approach_title(a: Approach) -> &'static str {
    match a {
        Approach::DriveTranslation => "assembly translation along the drive axes (Sec. 2.1)",
        Approach::JointDeflection => "assembly deflection of the J3 flexure (Sec. 2.2)",
    }
}

fn margins_json(t: &Tension, m: &Mechanism) -> Value {
    let g = &t.margins;
    json!({
        "force_range": g.force_range,
        "compression_margin": g.compression_margin,
        "capacity_margin": g.capacity_margin,
        "torque_max": g.torque_max,
        "torque_limit": [m.design().actuators[0].torque_limit, m.design().actuators[1].torque_limit],
        "torque_margin": g.torque_margin,
        "offset": g.offset,
        "ok": g.warnings(m.design()).is_empty(),
    })
}

/// `cellinject tension`.
pub fn tension(d: &Description, approach: u8, format: Format) -> Result<()> {
    let m = d.mechanism();
    let a = approach_of(approach)?;
    let t = m.tension(a).context("pre-tension analysis failed")?;
    let warnings = t.margins.warnings(m.design());
    match format {
        Format::Json => {
            let mut obj = serde_json::Map::new();
            obj.insert("design".into(), json!(d.name));
            obj.insert("approach".into(), json!(approach));
            for (k, v) in t.quantities() {
                obj.insert(k.into(), json!(v));
            }
            obj.insert("margins".into(), margins_json(&t, &m));
            obj.insert("warnings".into(), json!(warnings));
            println!("{}", serde_json::to_string_pretty(&Value::Object(obj))?);
        }
        Format::Text => {
            println!("Pre-tension, approach {approach}: {}", approach_title(a));
            println!("Design: {}\n", d.name);
            let mut table = Table::new(
                &["quantity", "eq.", "meaning", "unit", "value"],
                &[false, false, false, false, false],
            );
            for (k, v) in t.quantities() {
                let (unit, what) = quantity_info(k);
                let eq = paper::figures()
                    .iter()
                    .find(|f| f.approach == approach && f.key == k)
                    .map(|f| format!("({})", f.eq))
                    .unwrap_or_default();
                table.row(vec![
                    k.to_string(),
                    eq,
                    what.to_string(),
                    display_unit(unit).0.to_string(),
                    vector(&v, unit),
                ]);
            }
            print!("{}", table.text());
            println!("\nMargins over the working range:");
            print!("{}", margins_text(&t, &m));
            if warnings.is_empty() {
                println!("\nAll margins hold.");
            } else {
                println!();
                for w in &warnings {
                    println!("warning: {w}");
                }
            }
        }
    }
    Ok(())
}

fn margins_text(t: &Tension, m: &Mechanism) -> String {
    let g = &t.margins;
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
            ACTUATOR_NAMES[i].to_string(),
            format!(
                "{} .. {}",
                number(g.force_range[i][0], "N"),
                number(g.force_range[i][1], "N")
            ),
            number(g.compression_margin[i], "N"),
            number(g.capacity_margin[i], "N"),
            number(g.torque_max[i], "N*m"),
            number(m.design().actuators[i].torque_limit, "N*m"),
            number(g.torque_margin[i], "N*m"),
        ]);
    }
    format!(
        "{}End-effector offset after tensioning: {} µm\n",
        table.text(),
        number(g.offset, "m")
    )
}

fn matrix_rows<const R: usize, const C: usize>(m: &nalgebra::SMatrix<f64, R, C>) -> Vec<Vec<f64>> {
    (0..R)
        .map(|r| (0..C).map(|c| m[(r, c)]).collect())
        .collect()
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

/// One quantity of the large-deflection check.
struct LinRow {
    key: &'static str,
    unit: &'static str,
    linear: Vec<f64>,
    nonlinear: Vec<f64>,
    deviation: Deviation,
}

fn linearisation_rows(lin: &Linearisation, t: &Tension) -> Vec<LinRow> {
    let v = |x: &nalgebra::Vector3<f64>| x.as_slice().to_vec();
    let row =
        |key, unit, a: &nalgebra::Vector3<f64>, b: &nalgebra::Vector3<f64>, deviation| LinRow {
            key,
            unit,
            linear: v(a),
            nonlinear: v(b),
            deviation,
        };
    vec![
        row(
            "dX",
            "m",
            &t.tensioned.dx,
            &lin.tensioned.dx,
            lin.dx_tensioned,
        ),
        row("dX_work", "m", &t.work.dx, &lin.work.dx, lin.dx_work),
        row(
            "F10",
            "N",
            &t.tensioned.force,
            &lin.tensioned.force,
            lin.force_tensioned,
        ),
        row(
            "F_work",
            "N",
            &t.work.force,
            &lin.work.force,
            lin.force_work,
        ),
        row("chi", "m", &t.chi, &lin.chi_nonlinear, lin.chi),
    ]
}

/// Linear and nonlinear answers of both approaches.
fn linearisations(m: &Mechanism) -> Result<Vec<(Tension, Linearisation)>> {
    [Approach::DriveTranslation, Approach::JointDeflection]
        .into_iter()
        .map(|a| {
            let t = m.tension(a).context("pre-tension analysis failed")?;
            let l = m
                .linearisation(a)
                .context("large-deflection equilibrium failed")?;
            Ok((t, l))
        })
        .collect()
}

fn linearisation_table(all: &[(Tension, Linearisation)]) -> Table {
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
    for (t, lin) in all {
        for r in linearisation_rows(lin, t) {
            table.row(vec![
                t.approach.number().to_string(),
                r.key.to_string(),
                display_unit(r.unit).0.to_string(),
                vector(&r.linear, r.unit),
                vector(&r.nonlinear, r.unit),
                number(r.deviation.absolute, r.unit),
                format!("{:.2e}", r.deviation.relative),
            ]);
        }
    }
    table
}

/// `cellinject model`.
pub fn model(d: &Description, format: Format) -> Result<()> {
    let m = d.mechanism();
    let jac = m.jacobians();
    let b = m.compliance().context("compliance B_l")?;
    let all = linearisations(&m)?;
    match format {
        Format::Json => {
            let lin: Vec<Value> = all
                .iter()
                .map(|(t, l)| {
                    let mut o = serde_json::Map::new();
                    o.insert("approach".into(), json!(t.approach.number()));
                    for r in linearisation_rows(l, t) {
                        o.insert(
                            r.key.into(),
                            json!({
                                "linear": r.linear,
                                "nonlinear": r.nonlinear,
                                "absolute": r.deviation.absolute,
                                "relative": r.deviation.relative,
                            }),
                        );
                    }
                    o.insert("dz_tensioned".into(), json!(l.dz_tensioned));
                    o.insert(
                        "equilibrium_residual".into(),
                        json!([l.tensioned.residual, l.work.residual]),
                    );
                    Value::Object(o)
                })
                .collect();
            let out = json!({
                "design": d.name,
                "J": matrix_rows(&jac.j),
                "L": matrix_rows(&jac.l),
                "W": matrix_rows(&jac.w),
                "B_l": matrix_rows(&b),
                "B_l_axes": ["A1", "A2"],
                "linearisation": lin,
            });
            println!("{}", serde_json::to_string_pretty(&out)?);
        }
        Format::Text => {
            println!("Mechanism model of {}\n", d.name);
            println!(
                "Jacobians at the home pose (eqs. 5-7), obtained by differentiating the nonlinear kinematics:"
            );
            print!(
                "{}",
                matrix_text("J = dX/dq", &matrix_rows(&jac.j), "m/rad; column 3: m/m")
            );
            print!(
                "{}",
                matrix_text("L = dl/dq", &matrix_rows(&jac.l), "m/rad; column 3: m/m")
            );
            print!(
                "{}",
                matrix_text("W = dw/dq", &matrix_rows(&jac.w), "rad/rad")
            );
            let b_um: Vec<Vec<f64>> = matrix_rows(&b)
                .into_iter()
                .map(|r| r.into_iter().map(|x| x * 1e6).collect())
                .collect();
            print!(
                "{}",
                matrix_text(
                    "B_l, compliance on the actuator axes A1, A2 (eq. 23)",
                    &b_um,
                    "µm/N"
                )
            );
            println!(
                "  (A3 is a serial axis with neither flexure nor preload: no compliance entry)\n"
            );
            println!("Large-deflection check: constant Jacobians vs the nonlinear equilibrium");
            print!("{}", linearisation_table(&all).text());
            for (t, l) in &all {
                println!(
                    "approach {}: out-of-plane drop of M after tensioning {} µm; equilibrium residuals {:.1e}, {:.1e}",
                    t.approach.number(),
                    number(l.dz_tensioned, "m"),
                    l.tensioned.residual,
                    l.work.residual
                );
            }
        }
    }
    Ok(())
}

/// `cellinject reproduce`.
pub fn reproduce(d: &Description, out: &Path) -> Result<()> {
    let m = d.mechanism();
    let all = linearisations(&m)?;
    let rows = paper::compare(|a, k| {
        all.iter()
            .find(|(t, _)| t.approach.number() == a)
            .and_then(|(t, _)| t.quantity(k))
    })
    .map_err(anyhow::Error::msg)?;
    let (n, ok) = paper::summary(&rows);
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
    for r in &rows {
        let f = &r.figure;
        table.row(vec![
            format!("({})", f.eq),
            f.approach.to_string(),
            f.key.clone(),
            display_unit(&f.unit).0.to_string(),
            vector(&f.value, &f.unit),
            vector(&r.computed, &f.unit),
            format!("{:.2e}", r.rel_diff),
            paper::status(r).to_string(),
        ]);
    }
    let is_prototype = d.design == cellinject_model::prototype();
    let caveat = if is_prototype {
        String::new()
    } else {
        format!(
            "Note: the design `{}` is not the paper's prototype; differences from the paper's figures are expected.\n",
            d.name
        )
    };
    println!(
        "Reproduction of Sec. 3.2 (eqs. 37-58), design: {}\n",
        d.name
    );
    print!("{}", table.text());
    println!(
        "\n{ok} of {n} computed figures agree with the paper (tolerance {:.1} %).",
        paper::tolerance() * 100.0
    );
    print!("{caveat}");

    let mut md = String::new();
    md.push_str("# Reproduction of Sec. 3.2 (eqs. 37-58)\n\n");
    md.push_str(&format!(
        "Design: **{}**. Source: Chakarov, Kostadinov et al., *Development of a Piezo-actuated \
         Robot for Cell Injection*, ICINCO 2012. The paper rounds its figures and truncates some; \
         a figure agrees when the relative difference is at most {:.1} % (measured against the \
         largest component where the paper prints 0), or, for a truncated figure, when the \
         computed value truncates to it.\n\n",
        d.name,
        paper::tolerance() * 100.0
    ));
    md.push_str(&caveat);
    md.push_str(&format!("**{ok} of {n}** computed figures agree.\n\n"));
    md.push_str(&table.markdown());
    md.push_str("\n## Notes on the printed figures\n\n");
    for r in rows.iter().filter(|r| r.figure.note.is_some()) {
        let f = &r.figure;
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
    for (t, _) in &all {
        md.push_str(&format!(
            "Approach {}: {}.\n\n```\n{}```\n\n",
            t.approach.number(),
            approach_title(t.approach),
            margins_text(t, &m)
        ));
        for w in t.margins.warnings(m.design()) {
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
    md.push_str(&linearisation_table(&all).markdown());

    std::fs::create_dir_all(out).map_err(|e| {
        InputError(format!(
            "--out `{}`: cannot create the report directory: {e}",
            out.display()
        ))
    })?;
    let path = out.join("reproduce.md");
    write_atomic(&path, &md).map_err(|e| {
        InputError(format!(
            "--out `{}`: cannot write the report: {e}",
            path.display()
        ))
    })?;
    println!("Report written to {}", path.display());
    Ok(())
}
