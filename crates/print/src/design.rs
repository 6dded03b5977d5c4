//! The design studies' output (`cellinject design evaluate`, `optimise`): one design's
//! figures as text, and a front as text, CSV, one description file a design and a
//! chart.

use std::fmt::Write as _;

use cellinject_design::study::{FrontEntry, Study};
use cellinject_design::{DesignError, Figures};
use cellinject_plot::{Chart, Series, Style};

use crate::table::Table;

/// One design's figures (`cellinject design evaluate`): the table of ranges,
/// stiffness and margins, the modes and safety factors, and whether it is feasible.
pub fn figures_text(name: &str, f: &Figures) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{name}: approach {}, {} fidelity{}",
        f.approach,
        f.fidelity.name(),
        f.level
            .map(|l| format!(" (FEM level {l})"))
            .unwrap_or_default()
    );
    let mut t = Table::new(&["figure", "x", "y"], &[false, true, true]);
    t.row(vec![
        "working range [µm]".into(),
        format!("{:.2}", f.range_m.x * 1e6),
        format!("{:.2}", f.range_m.y * 1e6),
    ]);
    t.row(vec![
        "stiffness at the end-effector [N/µm]".into(),
        format!("{:.4}", f.stiffness_n_per_m.x * 1e-6),
        format!("{:.4}", f.stiffness_n_per_m.y * 1e-6),
    ]);
    let m = &f.stack_margins;
    t.row(vec![
        "A1 | A2 push-capacity margin [N]".into(),
        format!("{:.1}", m.push_capacity_n[0]),
        format!("{:.1}", m.push_capacity_n[1]),
    ]);
    t.row(vec![
        "A1 | A2 compression margin [N]".into(),
        format!("{:.2}", m.compression_n[0]),
        format!("{:.2}", m.compression_n[1]),
    ]);
    t.row(vec![
        "A1 | A2 travel margin [µm]".into(),
        format!("{:.2}", m.travel_m[0] * 1e6),
        format!("{:.2}", m.travel_m[1] * 1e6),
    ]);
    t.row(vec![
        "J1 | J2 torque margin [mN·m]".into(),
        format!("{:.1}", m.torque_nm[0] * 1e3),
        format!("{:.1}", m.torque_nm[1] * 1e3),
    ]);
    let _ = writeln!(out, "{}", t.text());
    let s = &f.safety_factors;
    let _ = writeln!(
        out,
        "first modes {:.1} and {:.1} Hz; yield safety factors J1 {:.2}, J2 {:.2}, J3 {:.2} (smallest {:.2}); cross-axis coupling {:.3} µm; body 1 {:.1} g",
        f.modes_hz[0],
        f.modes_hz[1],
        s.j1,
        s.j2,
        s.j3,
        f.min_safety_factor,
        f.coupling_m * 1e6,
        f.body_mass_kg * 1e3
    );
    if f.feasible {
        let _ = writeln!(out, "feasible: every margin of the safety envelope holds");
    } else {
        let _ = writeln!(out, "NOT feasible: {}", f.violations.join(", "));
    }
    out.pop();
    out
}

/// A study's front (`cellinject design optimise`): one row a design, its variables,
/// objectives and constraints, then the base design's objectives.
pub fn front_text(
    study: &Study,
    front: &[FrontEntry],
    base: Option<&Figures>,
    name: &str,
) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "front of {} designs after {} generations ({} evaluations, {} fidelity)",
        front.len(),
        study.search.generation,
        study.search.evaluations,
        study.fidelity.name()
    );
    let mut head: Vec<String> = study
        .space
        .variables
        .iter()
        .map(|v| v.key.clone())
        .collect();
    head.extend(
        study
            .space
            .objectives
            .iter()
            .map(|o| format!("{} ({})", o.figure, if o.maximise { "max" } else { "min" })),
    );
    head.extend(
        study
            .space
            .constraints
            .iter()
            .map(|c| format!("{} >= {}", c.figure, c.min)),
    );
    let refs: Vec<&str> = head.iter().map(String::as_str).collect();
    let right: Vec<bool> = refs.iter().map(|_| true).collect();
    let mut t = Table::new(&refs, &right);
    for e in front {
        let mut row = variable_cells(study, e);
        for o in &study.space.objectives {
            row.push(format!(
                "{:.6e}",
                e.figures.get(&o.figure).unwrap_or(f64::NAN)
            ));
        }
        for c in &study.space.constraints {
            row.push(format!(
                "{:.4}",
                e.figures.get(&c.figure).unwrap_or(f64::NAN)
            ));
        }
        t.row(row);
    }
    let _ = writeln!(out, "{}", t.text());
    if let Some(b) = base {
        let figs: Vec<String> = study
            .space
            .objectives
            .iter()
            .map(|o| format!("{} {:.6e}", o.figure, b.get(&o.figure).unwrap_or(f64::NAN)))
            .collect();
        let _ = writeln!(
            out,
            "{name} itself: {} ({})",
            figs.join(", "),
            if b.feasible {
                "feasible"
            } else {
                "not feasible"
            }
        );
    }
    out.pop();
    out
}

/// A front design's variables in the study's order ([`variable_cell`]).
fn variable_cells(study: &Study, e: &FrontEntry) -> Vec<String> {
    study
        .space
        .variables
        .iter()
        .map(|v| variable_cell(e.variables.get(&v.key)))
        .collect()
}

/// A variable's cell: a real number in shortest round-trip exponent form (`1.05e-4`,
/// one format down a column, where JSON's own form switches between `0.0001` and
/// `1e-7`), anything else as written, empty where missing.
fn variable_cell(x: Option<&serde_json::Value>) -> String {
    match x {
        Some(serde_json::Value::Number(n)) if n.is_f64() => {
            format!("{:e}", n.as_f64().unwrap_or(f64::NAN))
        }
        Some(x) => x.to_string(),
        None => String::new(),
    }
}

/// The front's CSV: a design's number, its variables, then every figure of
/// [`cellinject_design::FIGURES`] and whether it is feasible.
pub fn front_csv(study: &Study, front: &[FrontEntry]) -> String {
    let mut csv = String::new();
    let mut head: Vec<String> = vec!["design".into()];
    head.extend(study.space.variables.iter().map(|v| csv_field(&v.key)));
    head.extend(
        cellinject_design::FIGURES
            .iter()
            .map(|(n, _)| n.to_string()),
    );
    head.push("feasible".into());
    csv.push_str(&head.join(","));
    csv.push('\n');
    for (k, e) in front.iter().enumerate() {
        let mut row = vec![format!("{k:03}")];
        row.extend(variable_cells(study, e));
        for (n, _) in cellinject_design::FIGURES {
            row.push(format!("{:e}", e.figures.get(n).unwrap_or(f64::NAN)));
        }
        row.push(e.figures.feasible.to_string());
        csv.push_str(&row.join(","));
        csv.push('\n');
    }
    csv
}

/// Front design `k`'s full description (TOML), for `design evaluate --config` and the
/// rest: the study's base with the design's variables, named after the study of `name`.
pub fn front_design(
    study: &Study,
    k: usize,
    e: &FrontEntry,
    name: &str,
) -> Result<String, DesignError> {
    let x: Vec<f64> = study
        .space
        .variables
        .iter()
        .map(|v| {
            e.variables
                .get(&v.key)
                .and_then(|x| x.as_f64())
                .unwrap_or(f64::NAN)
        })
        .collect();
    let text = cellinject_design::study::description(&study.space, &study.base, &x)?;
    let header = format!(
        "# front design {k:03} of a `cellinject design optimise` study of {name}\n\nname = \"{name}, front design {k:03}\"\n"
    );
    let body: String = text
        .lines()
        .filter(|l| !l.starts_with("name ="))
        .collect::<Vec<_>>()
        .join("\n");
    Ok(format!("{header}{body}\n"))
}

/// The front's chart: the first two objectives (or the first against the smallest
/// safety factor), the front's designs and the base design `name`.
pub fn front_chart(
    study: &Study,
    front: &[FrontEntry],
    base: Option<&Figures>,
    name: &str,
) -> Chart {
    let obj = &study.space.objectives;
    let xname = obj[0].figure.clone();
    let yname = obj
        .get(1)
        .map(|o| o.figure.clone())
        .unwrap_or_else(|| "min_safety_factor".into());
    let (xs, xu) = display_scale(&xname);
    let (ys, yu) = display_scale(&yname);
    let pts: Vec<(f64, f64)> = front
        .iter()
        .map(|e| {
            (
                e.figures.get(&xname).unwrap_or(f64::NAN) * xs,
                e.figures.get(&yname).unwrap_or(f64::NAN) * ys,
            )
        })
        .collect();
    let mut series = vec![Series {
        name: format!("front ({} designs)", front.len()),
        points: pts,
        style: Style::Dots,
    }];
    if let Some(b) = base {
        series.push(Series {
            name: format!("{name}{}", if b.feasible { "" } else { " (not feasible)" }),
            points: vec![(
                b.get(&xname).unwrap_or(f64::NAN) * xs,
                b.get(&yname).unwrap_or(f64::NAN) * ys,
            )],
            style: Style::Dots,
        });
    }
    Chart {
        title: format!(
            "Design front, {} fidelity, {} generations",
            study.fidelity.name(),
            study.search.generation
        ),
        x_label: format!("{xname} [{xu}]"),
        y_label: format!("{yname} [{yu}]"),
        series,
    }
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// Display scale and unit of a figure for the plot.
fn display_scale(name: &str) -> (f64, &'static str) {
    if name.ends_with("_m") || name.contains("travel_m") {
        (1e6, "µm")
    } else if name.ends_with("_hz") {
        (1.0, "Hz")
    } else if name.starts_with("stiffness") {
        (1e-6, "N/µm")
    } else if name.ends_with("_kg") {
        (1e3, "g")
    } else if name.ends_with("_nm") {
        (1e3, "mN·m")
    } else if name.ends_with("_n") {
        (1.0, "N")
    } else {
        (1.0, "1")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_real_variable_is_written_in_one_form_whatever_its_size() {
        use serde_json::json;
        for (v, want) in [
            (json!(0.0001), "1e-4"),
            (json!(1e-7), "1e-7"),
            (json!(0.000105), "1.05e-4"),
            (json!(2.5), "2.5e0"),
            (json!(3), "3"),
            (json!("steel"), "\"steel\""),
        ] {
            assert_eq!(variable_cell(Some(&v)), want, "{v}");
        }
        assert_eq!(variable_cell(None), "");
    }

    #[test]
    fn csv_fields_are_quoted_only_when_they_must_be() {
        assert_eq!(csv_field("joints.j1.t"), "joints.j1.t");
        assert_eq!(csv_field("a,b"), "\"a,b\"");
        assert_eq!(csv_field("say \"hi\""), "\"say \"\"hi\"\"\"");
        assert_eq!(csv_field("two\nlines"), "\"two\nlines\"");
    }

    #[test]
    fn figures_get_units_a_person_reads() {
        assert_eq!(display_scale("range_x_m"), (1e6, "µm"));
        assert_eq!(display_scale("mode1_hz"), (1.0, "Hz"));
        assert_eq!(display_scale("stiffness_x"), (1e-6, "N/µm"));
        assert_eq!(display_scale("min_safety_factor"), (1.0, "1"));
    }
}
