//! `cellinject runs list`'s text (a run's own summary is `cellinject_run_sim::Summary::text`).

use cellinject_records::{AttemptRow, RunRow};

/// `cellinject runs list`'s line for the recorded run `r` and its attempts `a`.
pub fn run_line(r: &RunRow, a: &[AttemptRow]) -> String {
    let injected = a.iter().filter(|a| a.outcome == "injected").count();
    format!(
        "run {}: {}, {} cell{} found, {} attempt{}, {} injected, {:.1} s {}{}",
        r.id,
        r.status,
        r.cells_found,
        if r.cells_found == 1 { "" } else { "s" },
        a.len(),
        if a.len() == 1 { "" } else { "s" },
        injected,
        r.sim_time_s,
        if r.backend == "twin" {
            "simulated".to_string()
        } else {
            format!("on {}", r.backend)
        },
        r.stopped
            .as_ref()
            .map(|s| format!(" (stopped: {s})"))
            .unwrap_or_default()
    )
}

/// `cellinject runs export`'s CSV: one row an attempt, SI units, one number format a
/// column (lengths and fractions in shortest round-trip exponent form, `1.25e-5`;
/// times in seconds with six decimals), empty where a value is unknown.
pub fn attempts_csv(attempts: &[AttemptRow]) -> String {
    use std::fmt::Write as _;
    let mut out = String::from(
        "cell,well_row,well_col,x_m,y_m,diameter_m,tip_error_m,measured_tip_error_m,depth_m,dose_fraction,measured_dose_fraction,alive,outcome,reason,t_start_s,t_end_s\n",
    );
    let e = |v: Option<f64>| v.map(|v| format!("{v:e}")).unwrap_or_default();
    let s = |v: Option<f64>| v.map(|v| format!("{v:.6}")).unwrap_or_default();
    for a in attempts {
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},\"{}\",{},{}",
            a.cell,
            a.well[0],
            a.well[1],
            e(Some(a.x_m)),
            e(Some(a.y_m)),
            e(Some(a.diameter_m)),
            e(a.tip_error_m),
            e(a.measured_tip_error_m),
            e(a.depth_m),
            e(a.dose_fraction),
            e(a.measured_dose_fraction),
            a.alive.map(|b| b.to_string()).unwrap_or_default(),
            a.outcome,
            a.reason.replace('"', "\"\""),
            s(Some(a.t_start)),
            s(a.t_end)
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn attempt(t_start: f64, t_end: Option<f64>, x: f64) -> AttemptRow {
        AttemptRow {
            id: 1,
            cell: 3,
            well: [0, 2],
            x_m: x,
            y_m: -2.5e-3,
            diameter_m: 1.8e-5,
            tip_error_m: Some(3.0e-7),
            measured_tip_error_m: None,
            depth_m: Some(1.2e-6),
            dose_fraction: Some(0.5),
            measured_dose_fraction: Some(0.48),
            alive: Some(true),
            outcome: "injected".into(),
            reason: "said \"ok\"".into(),
            t_start,
            t_end,
            transitions: serde_json::Value::Null,
        }
    }

    /// The CSV's numbers: a column is all exponent form or all six decimals, whatever
    /// the values' sizes (times of 0.5 s and 106.5 s, positions of 1 mm and 1e-9 m
    /// once came out as `103.33835` beside `1.0653335e2`); quotes doubled; empty
    /// where unknown.
    #[test]
    fn every_number_column_has_one_format() {
        let rows = [
            attempt(0.5, Some(106.53335), 1e-3),
            attempt(103.33835, None, 1.234e-9),
        ];
        let csv = attempts_csv(&rows);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 3);
        let cells = |l: &str| -> Vec<String> {
            // The reason is the only quoted field: split around it.
            let (head, rest) = l.split_once(",\"").unwrap();
            let (_, tail) = rest.rsplit_once("\",").unwrap();
            head.split(',')
                .chain(tail.split(','))
                .map(String::from)
                .collect()
        };
        let (a, b) = (cells(lines[1]), cells(lines[2]));
        let exponent = |s: &str| s.contains('e') && s.parse::<f64>().is_ok();
        let six = |s: &str| s.split_once('.').is_some_and(|(_, d)| d.len() == 6);
        // x_m .. measured_dose_fraction: columns 3..=10; times: the last two.
        for k in 3..=10 {
            for c in [&a[k], &b[k]] {
                assert!(c.is_empty() || exponent(c), "column {k}: {c}");
            }
        }
        for k in [a.len() - 2, a.len() - 1] {
            for c in [&a[k], &b[k]] {
                assert!(c.is_empty() || six(c), "column {k}: {c}");
            }
        }
        assert_eq!(a[a.len() - 2], "0.500000");
        assert_eq!(b[b.len() - 2], "103.338350");
        assert_eq!(a[a.len() - 1], "106.533350");
        assert_eq!(b[b.len() - 1], "");
        assert_eq!(a[3].parse::<f64>().unwrap(), 1e-3);
        assert!(lines[1].contains("\"said \"\"ok\"\"\""));
    }
}
