//! `cellinject run` and `runs` from the command line on the twin: a small plate is
//! injected and recorded, the record reads back, a finished run resumes to nothing,
//! a clogged pipette is handled, and foreign databases and bad arguments are refused.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("cellinject-run-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&d);
    fs::create_dir_all(&d).unwrap();
    d
}

fn run(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cellinject"))
        .current_dir(dir)
        .args(args)
        .output()
        .unwrap()
}

fn err(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn plate(d: &Path) {
    let o = run(
        d,
        &[
            "plate",
            "generate",
            "--rows",
            "3",
            "--cols",
            "4",
            "--origin=-225e-6,-120e-6",
            "--seed",
            "3",
            "--out",
            "p.toml",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
}

#[test]
fn a_small_plate_is_injected_recorded_and_a_finished_run_resumes_to_nothing() {
    let d = dir("small");
    plate(&d);
    let o = run(
        &d,
        &[
            "run", "--plate", "p.toml", "--db", "r.sqlite", "--format", "json",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let s: Value = serde_json::from_slice(&o.stdout).unwrap();
    // The plate file's truth, read independently: every attempt is at a real cell.
    let text = fs::read_to_string(d.join("p.toml")).unwrap();
    let cells = text.matches("[[cell]]").count();
    let attempts = s["attempts"].as_array().unwrap();
    assert_eq!(s["cells_found"].as_u64().unwrap() as usize, cells);
    assert_eq!(attempts.len(), cells, "each cell attempted once");
    let injected = s["injected"].as_u64().unwrap() as usize;
    assert!(injected + 1 >= cells, "{injected} of {cells}");
    for a in attempts.iter().filter(|a| a["outcome"] == "injected") {
        // Dose within 20 % of the 5 % target and the cell alive (the twin's truth).
        let f = a["dose_fraction"].as_f64().unwrap();
        assert!((f / 0.05 - 1.0).abs() < 0.2, "{a}");
        assert_eq!(a["alive"], Value::Bool(true));
    }
    for a in attempts.iter().filter(|a| a["outcome"] != "injected") {
        assert!(!a["reason"].as_str().unwrap().is_empty(), "{a}");
    }
    // The record reads back the same attempts.
    let o = run(&d, &["runs", "show", "--db", "r.sqlite"]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let shown: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(shown["attempts"], s["attempts"]);
    // A finished run: resume does nothing.
    let o = run(&d, &["run", "--db", "r.sqlite", "--resume"]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("nothing to resume"));
    // Export to CSV: a header and one line per attempt.
    let o = run(&d, &["runs", "export", "--db", "r.sqlite"]);
    assert_eq!(
        String::from_utf8_lossy(&o.stdout).lines().count(),
        cells + 1
    );
}

#[test]
fn a_foreign_database_and_bad_arguments_are_refused_with_exit_2() {
    let d = dir("bad");
    fs::write(d.join("notes.sqlite"), b"SQLite format 3\0 but not really").unwrap();
    let before = fs::read(d.join("notes.sqlite")).unwrap();
    let o = run(&d, &["run", "--db", "notes.sqlite"]);
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    assert!(err(&o).contains("notes.sqlite"), "{}", err(&o));
    assert_eq!(fs::read(d.join("notes.sqlite")).unwrap(), before);
    for (args, needle) in [
        (vec!["run", "--fault", "melt@1"], "--fault"),
        (vec!["run", "--dose", "NaN"], "--dose"),
        (vec!["run", "--dose", "0.5"], "--dose"),
        (
            vec!["runs", "show", "--db", "missing.sqlite"],
            "missing.sqlite",
        ),
    ] {
        let o = run(&d, &args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", err(&o));
        assert!(err(&o).contains(needle), "{args:?}: {}", err(&o));
    }
}
