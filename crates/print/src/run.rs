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
