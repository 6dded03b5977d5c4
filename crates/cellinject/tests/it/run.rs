//! `cellinject run` and `runs` from the command line on the twin: a small plate is
//! injected and recorded, the record reads back, a finished run resumes to nothing,
//! a clogged pipette is handled, and foreign databases and bad arguments are refused.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

use common::{err, run};

fn dir(name: &str) -> PathBuf {
    common::dir("run", name)
}

/// Whether `text` writes micrometres as `um` (a number, a space, a parenthesis or a
/// slash before it, no letter after).
fn ascii_um(text: &str) -> bool {
    let b = text.as_bytes();
    text.match_indices("um").any(|(i, _)| {
        let before = i.checked_sub(1).map(|k| b[k]);
        let after = b.get(i + 2).copied();
        matches!(before, Some(c) if c.is_ascii_digit() || b" (/".contains(&c))
            && !after.is_some_and(|c| c.is_ascii_alphabetic())
    })
}

fn plate(d: &Path) {
    common::plate(
        d,
        &[
            "--rows",
            "3",
            "--cols",
            "4",
            "--origin=-225e-6,-120e-6",
            "--seed",
            "3",
        ],
        "p.toml",
    );
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
    let cells = text.lines().filter(|l| l.trim() == "[[cell]]").count();
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
    // The workflow's log writes micrometres as µm (SI in the numbers of the JSON).
    let said = shown["events"]
        .as_array()
        .unwrap()
        .iter()
        .chain(attempts)
        .map(|e| e["reason"].as_str().unwrap_or_default());
    for text in said {
        assert!(!ascii_um(text), "`um` for µm in {text:?}");
    }
    // Resume takes the plate and the seed from the database: others are refused.
    let o = run(&d, &["run", "--db", "r.sqlite", "--resume", "--seed", "99"]);
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    assert!(err(&o).contains("--seed 99"), "{}", err(&o));
    fs::write(
        d.join("other.toml"),
        fs::read_to_string(d.join("p.toml")).unwrap() + "\n",
    )
    .unwrap();
    let o = run(
        &d,
        &[
            "run",
            "--db",
            "r.sqlite",
            "--resume",
            "--plate",
            "other.toml",
        ],
    );
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    assert!(err(&o).contains("other.toml"), "{}", err(&o));
    // A finished run: resume does nothing.
    let o = run(&d, &["run", "--db", "r.sqlite", "--resume"]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("nothing to resume"));
    // The report: one HTML file with the plate map, refused over an existing file.
    let o = run(&d, &["report", "--db", "r.sqlite", "--out", "rep"]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let html = fs::read_to_string(d.join("rep/report.html")).unwrap();
    assert_eq!(html.matches("<circle").count(), cells);
    assert!(html.contains("Tip error at injection") && html.contains("Throughput"));
    // Every figure scales to the page's width (three charts side by side are 1,260 px
    // wide: they overflowed a 1,200 px window) and keeps its proportions (a viewBox).
    assert!(html.contains("svg{max-width:100%;height:auto}"));
    assert_eq!(
        html.matches("<svg").count(),
        html.matches("viewBox=").count()
    );
    assert!(html.matches("<svg").count() >= 2);
    // `--out FILE.html`: that file, the same page (not a directory of that name).
    let o = run(&d, &["report", "--db", "r.sqlite", "--out", "r.html"]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    assert_eq!(fs::read_to_string(d.join("r.html")).unwrap(), html);
    let o = run(&d, &["report", "--db", "r.sqlite", "--out", "p.toml"]);
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    assert!(
        fs::read_to_string(d.join("p.toml"))
            .unwrap()
            .contains("[plate]")
    );
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
    assert!(err(&o).contains("--db notes.sqlite"), "{}", err(&o));
    assert_eq!(fs::read(d.join("notes.sqlite")).unwrap(), before);
    for (args, needle) in [
        (vec!["run", "--fault", "melt@1,0"], "--fault"),
        // Cells are named by their well, as in the plate file and the outputs.
        (vec!["run", "--fault", "clog@5"], "no longer names a cell"),
        (vec!["run", "--fault", "clog@1,x"], "the column `x`"),
        (vec!["run", "--dose", "NaN"], "--dose"),
        (vec!["run", "--dose", "0.5"], "--dose"),
        (vec!["run", "--max-off-centre", "0.7"], "--max-off-centre"),
        (vec!["run", "--max-off-centre", "-0.1"], "--max-off-centre"),
        (
            vec!["runs", "show", "--db", "missing.sqlite"],
            "missing.sqlite",
        ),
    ] {
        let o = run(&d, &args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", err(&o));
        assert!(err(&o).contains(needle), "{args:?}: {}", err(&o));
    }
    // A fault the plate cannot hold is refused before anything is recorded: no database
    // is created.
    plate(&d);
    for (fault, needle) in [
        ("clog@3,0", "well [3, 0] is not on the 3x4 plate"),
        ("clog@1,0,1", "well [1, 0] holds 1 cell: no cell 1 there"),
    ] {
        let o = run(
            &d,
            &[
                "run",
                "--plate",
                "p.toml",
                "--fault",
                fault,
                "--db",
                "none.sqlite",
            ],
        );
        assert_eq!(o.status.code(), Some(2), "{fault}: {}", err(&o));
        assert!(err(&o).contains(needle), "{fault}: {}", err(&o));
        assert!(
            !d.join("none.sqlite").exists(),
            "{fault}: a database was created"
        );
    }
}

/// A rig file naming the twin is the default bench: the same records, byte for byte
/// (the wall-clock creation time aside), as the run without it.
#[test]
fn a_rig_file_naming_the_twin_records_what_the_default_run_records() {
    let d = dir("rig-twin");
    common::plate(&d, &["--rows", "1", "--cols", "2", "--seed", "3"], "p.toml");
    fs::write(d.join("twin.toml"), "[piezo]\ndriver = \"twin\"\n").unwrap();
    let records = |db: &str, extra: &[&str]| {
        let mut args = vec!["run", "--plate", "p.toml", "--db", db];
        args.extend_from_slice(extra);
        let o = run(&d, &args);
        assert_eq!(o.status.code(), Some(0), "{extra:?}: {}", err(&o));
        let mut show: Value =
            serde_json::from_slice(&run(&d, &["runs", "show", "--db", db]).stdout).unwrap();
        assert!(show["run"]["created"].as_i64().is_some(), "{show}");
        show["run"]["created"] = Value::Null;
        let export = run(&d, &["runs", "export", "--db", db]).stdout;
        (show, export)
    };
    let (show, export) = records("plain.sqlite", &[]);
    let (rig_show, rig_export) = records("rig.sqlite", &["--rig", "twin.toml"]);
    assert_eq!(show, rig_show);
    assert!(!export.is_empty());
    assert_eq!(export, rig_export);
}

/// A rig file that is not valid is refused with exit 2, naming the file and the
/// dotted key, before anything is opened or written.
#[test]
fn a_bad_rig_file_is_refused_naming_file_and_key_and_leaves_no_database() {
    let d = dir("rig-bad");
    let bench = "[camera.top]\ndriver = \"bench://127.0.0.1:1\"\n[camera.side]\ndriver = \"bench://127.0.0.1:1\"\n[stage.macro]\ndriver = \"bench://127.0.0.1:1\"\n[stage.feeder]\ndriver = \"bench://127.0.0.1:1\"\n[injector]\ndriver = \"bench://127.0.0.1:1\"\n";
    let gcs = "[piezo]\ndriver = \"gcs://127.0.0.1:1\"\n";
    for (name, text, key) in [
        (
            "driver.toml",
            "[piezo]\ndriver = \"usb://3\"\n".to_string(),
            "piezo.driver",
        ),
        // No [optics] on a real bench.
        ("missing.toml", format!("{gcs}{bench}"), "optics.driver"),
        (
            "section.toml",
            "[piezo]\ndriver = \"twin\"\n[laser]\npower = 1\n".to_string(),
            "laser",
        ),
        // A camera's driver for the injector.
        (
            "kind.toml",
            format!("{gcs}{bench}[optics]\ndriver = \"bench://127.0.0.1:1\"\n").replace(
                "[injector]\ndriver = \"bench://127.0.0.1:1\"",
                "[injector]\ndriver = \"dir:frames\"",
            ),
            "injector.driver",
        ),
    ] {
        fs::write(d.join(name), text).unwrap();
        let o = run(
            &d,
            &[
                "run", "--rig", name, "--plate", "p.toml", "--db", "r.sqlite",
            ],
        );
        assert_eq!(o.status.code(), Some(2), "{name}: {}", err(&o));
        assert!(
            err(&o).contains(name) && err(&o).contains(key),
            "{name}: {}",
            err(&o)
        );
        assert!(
            !d.join("r.sqlite").exists(),
            "{name}: a database was created"
        );
        let o = run(&d, &["rig", "check", "--rig", name]);
        assert_eq!(o.status.code(), Some(2), "{name}: {}", err(&o));
        assert!(err(&o).contains(key), "{name}: {}", err(&o));
    }
}

/// A plate partly beyond the feeder stage's reach is refused before anything moves,
/// naming the wells out of reach, by how much, and the move of the plate's origin that
/// fixes it; it leaves no record: no database file when there was none, no run in one
/// that exists.
#[test]
fn a_plate_partly_beyond_the_feeders_reach_is_refused_naming_the_wells() {
    let d = bench("far");
    // The feeder reaches ±25 mm; the view's usable window ends about 1.1 mm right of
    // the stage's origin. Column 0's centre at 25.9 mm is within reach (its square
    // fits the window with the feeder at -25 mm), columns 1-3 at 26.05-26.35 mm not.
    common::plate(
        &d,
        &["--rows", "2", "--cols", "4", "--origin=25.9e-3,0"],
        "far.toml",
    );
    let o = run(
        &d,
        &["run", "--plate", "far.toml", "--calibration", "hy.json"],
    );
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    let e = err(&o);
    assert!(
        e.contains(
            "[0, 1], [0, 2], [0, 3], [1, 1], [1, 2], [1, 3] lie outside the feeder stage's travel"
        ),
        "{e}"
    );
    // Column 1 is out of reach and column 0 within it, so the worst miss (column 3's)
    // exceeds 0.3 mm (two pitches beyond column 1's) and is at most 0.45 mm (three
    // beyond column 0's); the fix moves the origin back by as much.
    let worst: f64 = e
        .split("the worst by ")
        .nth(1)
        .and_then(|t| t.split(" mm").next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no distance: {e}"));
    assert!((0.3..=0.45).contains(&worst), "{worst}: {e}");
    assert!(
        e.contains(&format!(
            "moving the plate's origin by (-{worst:.3}, +0.000) mm"
        )),
        "{e}"
    );
    assert!(
        !d.join("runs.sqlite").exists(),
        "the refused run left a database"
    );
    // In a database that holds a run, the refused one leaves nothing either.
    let o = run(
        &d,
        &[
            "run",
            "--plate",
            "p.toml",
            "--calibration",
            "hy.json",
            "--db",
            "r.sqlite",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let o = run(
        &d,
        &[
            "run",
            "--plate",
            "far.toml",
            "--calibration",
            "hy.json",
            "--db",
            "r.sqlite",
        ],
    );
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    let o = run(
        &d,
        &["runs", "list", "--db", "r.sqlite", "--format", "json"],
    );
    let runs: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(runs.as_array().unwrap().len(), 1, "{runs}");
    assert_eq!(runs[0]["status"], "finished", "{runs}");
}

/// A plate wider than the view is served in two fields of view: every cell is found
/// and attempted exactly once, those in the fields' overlap (seen twice) and one that
/// straddles a field's edge (whole only in the other field) included. Checked against
/// the plate file's ground truth, which the workflow never reads.
#[test]
fn a_plate_wider_than_the_view_is_served_in_fields_and_each_cell_attempted_once() {
    let d = bench("fields");
    // The plate's floor tilted up to 6 um/mm (the twin draws 3-6 in a random
    // direction; this seed's is 4.8 along x): across the plate its height differs by
    // some 12 um, more than a small cell's radius, so each field must be focused and
    // each cell's height taken from the field's measured tilt. (At 10 um/mm a
    // particle at the field's edge, 11 um out of focus, is taken for a cell.)
    let prototype = fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/prototype.toml"),
    )
    .unwrap();
    let steep = prototype.replace("surface_tilt = 3.0e-3", "surface_tilt = 6e-3");
    assert_ne!(steep, prototype, "the description's surface_tilt key moved");
    fs::write(d.join("steep.toml"), steep).unwrap();
    // 16 columns of 150 um span 2.4 mm; the window at zoom 2.5 is about 2.27 mm wide.
    common::plate(
        &d,
        &[
            "--rows",
            "2",
            "--cols",
            "16",
            "--doublet-fraction",
            "0.3",
            "--origin=-1.1e-3,-0.1e-3",
            "--seed",
            "4",
        ],
        "wide.toml",
    );
    let o = run(
        &d,
        &[
            "run",
            "--config",
            "steep.toml",
            "--plate",
            "wide.toml",
            "--calibration",
            "hy.json",
            "--db",
            "wide.sqlite",
            "--format",
            "json",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    // The fields as the survey recorded them: plate x and y ranges, m.
    let mut fields = Vec::new();
    for ev in v["events"].as_array().unwrap() {
        let r = ev["reason"].as_str().unwrap();
        if ev["event"] == "field_reached" && r.contains(" surveyed: plate x ") {
            let nums: Vec<f64> = r
                .split(" surveyed: plate x ")
                .nth(1)
                .unwrap()
                .replace(" to ", " ")
                .replace(" mm, y ", " ")
                .split(' ')
                .take(4)
                .map(|t| t.trim_end_matches(" mm").parse::<f64>().unwrap() * 1e-3)
                .collect();
            fields.push([nums[0], nums[2], nums[1], nums[3]]);
        }
    }
    assert_eq!(fields.len(), 2, "{}", v["events"]);
    let plate =
        cellinject_config::plate::parse(&fs::read_to_string(d.join("wide.toml")).unwrap()).unwrap();
    let truth: Vec<([f64; 2], f64)> = plate
        .cells
        .iter()
        .map(|c| (plate.centre(c), 0.5 * c.diameter))
        .collect();
    // The fields' inner edges: the first's right, the second's left.
    let (left, right) = if fields[0][0] < fields[1][0] {
        (fields[0], fields[1])
    } else {
        (fields[1], fields[0])
    };
    let inner = [left[2], right[0]];
    let straddling = truth
        .iter()
        .filter(|(c, r)| inner.iter().any(|e| (c[0] - e).abs() < *r))
        .count();
    assert!(
        straddling >= 1,
        "no cell straddles {inner:?}: the test tests nothing"
    );
    let in_both = truth
        .iter()
        .filter(|(c, r)| c[0] - r >= right[0] && c[0] + r <= left[2])
        .count();
    assert!(in_both > truth.len() / 2, "{in_both} of {}", truth.len());
    assert_eq!(v["cells_found"], truth.len(), "{}", v["cells_found"]);
    // Each attempt targets one true cell (within 3 um of its measured centre), and no
    // true cell is attempted twice.
    let attempts = v["attempts"].as_array().unwrap();
    assert_eq!(attempts.len(), truth.len());
    let mut hit = vec![0; truth.len()];
    for a in attempts {
        let p = [
            a["x_m"].as_f64().unwrap() + plate.origin[0],
            a["y_m"].as_f64().unwrap() + plate.origin[1],
        ];
        let (k, dist) = truth
            .iter()
            .enumerate()
            .map(|(k, (c, _))| (k, (c[0] - p[0]).hypot(c[1] - p[1])))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        assert!(dist < 3e-6, "attempt {a} is {dist} m from the nearest cell");
        hit[k] += 1;
        let outcome = a["outcome"].as_str().unwrap();
        assert!(
            outcome == "injected"
                || (outcome == "skipped"
                    && a["reason"]
                        .as_str()
                        .unwrap()
                        .contains("the approach is blocked")),
            "{a}"
        );
    }
    assert!(hit.iter().all(|&h| h == 1), "{hit:?}");
    // Every field focused, the floor under its cells within 1 um of the truth (the
    // plane's residual from the floor's bow over a field is about 0.4 um), the tilt
    // measured along the plate.
    let focus = v["focus"].as_array().unwrap();
    assert!(focus.len() >= 2, "{}", v["focus"]);
    for f in focus {
        let e = f["true_error_m"].as_f64().unwrap();
        assert!(e < 1e-6, "{f}");
        let sx = f["slope"][0].as_f64().unwrap();
        assert!(
            sx.abs() > 2e-3,
            "the tilt along the plate was not seen: {f}"
        );
    }
}

/// A directory with the small plate and a hysteresis calibration (so that each run
/// skips the identification).
fn bench(name: &str) -> PathBuf {
    let d = dir(name);
    plate(&d);
    let o = run(&d, &["calibrate", "hysteresis", "--out", "hy.json"]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    d
}

fn json_run(d: &Path, extra: &[&str]) -> (Option<i32>, Value, String) {
    let mut args = vec![
        "run",
        "--plate",
        "p.toml",
        "--calibration",
        "hy.json",
        "--format",
        "json",
    ];
    args.extend_from_slice(extra);
    let o = run(d, &args);
    let v = serde_json::from_slice(&o.stdout).unwrap_or(Value::Null);
    (o.status.code(), v, err(&o))
}

fn transitions(d: &Path, db: &str) -> String {
    let o = Command::new("sqlite3")
        .arg(d.join(db))
        .arg("select transitions from attempts")
        .output();
    match o {
        Ok(o) if o.status.success() => String::from_utf8_lossy(&o.stdout).into_owned(),
        // Without the sqlite3 tool, the reasons in the JSON summary carry the checks.
        _ => String::new(),
    }
}

#[test]
fn each_fault_ends_safe_with_its_reason_recorded() {
    let d = bench("faults");
    // Each fault is tied to the cell in well [1, 0].
    let cases: [(&str, Option<i32>, &str); 6] = [
        ("clog@1,0", Some(0), "clogged"),
        ("hard-clog@1,0", Some(1), "blocked"),
        ("break@1,0", Some(1), "broken"),
        ("move@1,0", Some(0), ""),
        ("dark@1,0", Some(0), "lost tracking"),
        ("stall@1,0", Some(1), "deadline"),
    ];
    for (fault, code, needle) in cases {
        let db = format!("{}.sqlite", fault.replace(['@', ','], "-"));
        let (c, s, e) = json_run(&d, &["--fault", fault, "--db", &db]);
        assert_eq!(c, code, "{fault}: {e}");
        let attempts = s["attempts"].as_array().unwrap();
        let all = serde_json::to_string(&s).unwrap();
        assert!(all.contains(needle), "{fault}: no `{needle}` in {all}");
        if fault.starts_with("clog") {
            // The cell the fault names is the one that failed, by the same numbering.
            let clogged: Vec<_> = attempts
                .iter()
                .filter(|a| a["reason"].as_str().is_some_and(|r| r.contains("clogged")))
                .map(|a| a["well"].clone())
                .collect();
            assert_eq!(clogged, [serde_json::json!([1, 0])], "{fault}: {all}");
        }
        if code == Some(1) {
            // Stopped: in the safe state, with the reason recorded.
            assert_eq!(s["status"], "stopped", "{fault}");
            let why = s["stopped"].as_str().unwrap();
            assert!(
                why.contains("pipette retracted, stacks at rest") || why.contains("deadline"),
                "{fault}: {why}"
            );
        } else {
            // The run went on: the cells after the faulty ones were injected (16 cells:
            // one blocked by its doublet partner, up to two lost to the fault).
            assert_eq!(s["status"], "finished", "{fault}");
            assert!(s["injected"].as_u64().unwrap() >= 12, "{fault}: {all}");
            assert_eq!(attempts.len(), 16, "{fault}");
        }
        if fault.starts_with("move") {
            let t = transitions(&d, &db);
            assert!(t.is_empty() || t.contains("moved"), "{fault}: {t}");
            assert_eq!(s["failed"], 0, "{fault}: {all}");
        }
    }
}

#[test]
fn a_run_killed_at_any_moment_resumes_without_touching_a_cell_twice() {
    let d = bench("kill");
    let cells = fs::read_to_string(d.join("p.toml"))
        .unwrap()
        .lines()
        .filter(|l| l.trim() == "[[cell]]")
        .count();
    // Kills at 0.7 s and 1.5 s (before or during the survey), then one as soon as the
    // records show a cell done (polled, so that it falls among the cells whatever the
    // machine's speed; a fixed 2.6 s came before the survey here).
    for (k, delay_ms) in [Some(700u64), Some(1500), None].into_iter().enumerate() {
        let db = format!("k{k}.sqlite");
        let mut child = Command::new(env!("CARGO_BIN_EXE_cellinject"))
            .current_dir(&d)
            .args([
                "run",
                "--plate",
                "p.toml",
                "--calibration",
                "hy.json",
                "--db",
                &db,
            ])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        let done = |show: &Value| -> Vec<f64> {
            show["attempts"]
                .as_array()
                .map(|a| a.iter().filter_map(|a| a["t_end"].as_f64()).collect())
                .unwrap_or_default()
        };
        match delay_ms {
            Some(ms) => std::thread::sleep(std::time::Duration::from_millis(ms)),
            None => common::poll(
                std::time::Duration::from_secs(120),
                std::time::Duration::from_millis(100),
                "a cell done",
                || match show(&d, &db) {
                    Some(s) if !done(&s).is_empty() => Ok(()),
                    other => Err(other.map(|s| s["run"]["status"].clone())),
                },
            ),
        }
        let _ = child.kill(); // SIGKILL
        let _ = child.wait();
        // What a reader of the records sees after the kill: the survey's count and the
        // device time of the last cell done, written as the run went (the dashboard's
        // list of runs showed 0 cells and 0.0 s for a run in progress).
        if delay_ms.is_none() {
            let s = show(&d, &db).unwrap();
            let (r, done) = (&s["run"], done(&s));
            let last = done.iter().copied().fold(0.0, f64::max);
            assert!(
                r["cells_found"].as_u64().unwrap() as usize >= done.len().max(1),
                "{r}"
            );
            assert!(r["sim_time_s"].as_f64().unwrap() >= last, "{r}");
            assert_eq!(r["status"], "running", "{r}");
        }
        // Resume once: the run ends (a kill before the run was recorded leaves nothing
        // to resume, and then the plate is run afresh).
        let args = [
            "run",
            "--resume",
            "--calibration",
            "hy.json",
            "--db",
            &db,
            "--format",
            "json",
        ];
        let o = run(&d, &args);
        let s: Value = if o.status.code() == Some(0) {
            serde_json::from_slice(&o.stdout).unwrap()
        } else {
            assert!(err(&o).contains("no run"), "kill {k}: {}", err(&o));
            let args = [
                "run",
                "--plate",
                "p.toml",
                "--calibration",
                "hy.json",
                "--db",
                &db,
                "--format",
                "json",
            ];
            serde_json::from_slice(&run(&d, &args).stdout).unwrap()
        };
        assert_eq!(s["status"], "finished", "kill {k}: {s}");
        let attempts = s["attempts"].as_array().unwrap();
        let mut seen = std::collections::BTreeSet::new();
        for a in attempts {
            let key = (
                a["well"].to_string(),
                (a["x_m"].as_f64().unwrap() * 1e6).round() as i64,
            );
            assert!(seen.insert(key), "kill {k}: a cell attempted twice: {a}");
        }
        assert_eq!(
            attempts.len(),
            cells,
            "kill {k}: every cell accounted for once"
        );
        let interrupted = attempts
            .iter()
            .filter(|a| a["outcome"] == "interrupted")
            .count();
        assert!(interrupted <= 1, "kill {k}: {interrupted} interrupted");
        let touched_twice = attempts
            .iter()
            .filter(|a| a["outcome"] == "injected")
            .count()
            + interrupted;
        assert!(touched_twice <= cells);
    }
}

/// `runs show` of `db` as JSON, once the run is recorded.
fn show(d: &Path, db: &str) -> Option<Value> {
    common::json(d, &["runs", "show", "--db", db])
}

/// A run over two fields of view killed (SIGKILL) in the middle of a field's cells, and
/// between fields (just after the feeder brought the next field), then
/// resumed: the resumed run goes on in the field it was in, every cell is attempted
/// exactly once (cells seen in both fields included), at most one is interrupted.
#[test]
fn a_run_killed_between_and_within_fields_resumes_without_touching_a_cell_twice() {
    let d = bench("kill-fields");
    common::plate(
        &d,
        &[
            "--rows",
            "1",
            "--cols",
            "16",
            "--empty-fraction",
            "0.4",
            "--doublet-fraction",
            "0",
            "--origin=-1.1e-3,0",
            "--seed",
            "2",
        ],
        "w.toml",
    );
    let cells = fs::read_to_string(d.join("w.toml"))
        .unwrap()
        .lines()
        .filter(|l| l.trim() == "[[cell]]")
        .count();
    assert!(cells >= 4, "{cells}");
    // When to kill, from the run's records: two cells ended in the first field
    // injected, and just after the feeder brought the next field for its cells
    // (between fields: its background is being taken).
    type Due<'a> = &'a dyn Fn(&Value) -> bool;
    let kills: [(&str, Due); 2] = [
        ("within a field", &|v: &Value| {
            v["attempts"]
                .as_array()
                .is_some_and(|a| a.iter().filter(|a| a["outcome"] != "started").count() >= 2)
        }),
        ("after the feeder brought the next field", &|v: &Value| {
            v["events"].as_array().is_some_and(|e| {
                e.iter().any(|e| {
                    e["reason"]
                        .as_str()
                        .is_some_and(|r| r.contains("under the objective"))
                })
            })
        }),
    ];
    for (k, (when, due)) in kills.iter().enumerate() {
        let db = format!("k{k}.sqlite");
        let mut child = Command::new(env!("CARGO_BIN_EXE_cellinject"))
            .current_dir(&d)
            .args([
                "run",
                "--plate",
                "w.toml",
                "--calibration",
                "hy.json",
                "--db",
                &db,
            ])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        // Look at the records until the moment comes, the run held still (SIGSTOP)
        // while they are read: between two looks it runs for 100 ms at most, about a
        // second of device time in a debug build, however long a look takes on a
        // loaded machine (the second field's last cell is done in about 3 s of device
        // time, 0.3 s of wall time on an idle machine).
        let pid = rustix::process::Pid::from_child(&child);
        let mut killed = false;
        let mut ended = None;
        for _ in 0..6000 {
            if let Some(status) = child.try_wait().unwrap() {
                ended = Some(status);
                break;
            }
            let _ = rustix::process::kill_process(pid, rustix::process::Signal::STOP);
            if let Some(v) = show(&d, &db)
                && due(&v)
            {
                let _ = child.kill(); // SIGKILL
                killed = true;
                break;
            }
            let _ = rustix::process::kill_process(pid, rustix::process::Signal::CONT);
            std::thread::sleep(std::time::Duration::from_millis(100));
        }
        let _ = child.wait();
        assert!(
            killed,
            "kill {k} ({when}): the run ended first ({ended:?}); its records: {:?}",
            show(&d, &db)
        );
        let before = show(&d, &db).unwrap();
        let o = run(
            &d,
            &[
                "run",
                "--resume",
                "--calibration",
                "hy.json",
                "--db",
                &db,
                "--format",
                "json",
            ],
        );
        assert_eq!(o.status.code(), Some(0), "kill {k} ({when}): {}", err(&o));
        let s: Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(s["status"], "finished", "kill {k} ({when}): {s}");
        let attempts = s["attempts"].as_array().unwrap();
        let mut seen = std::collections::BTreeSet::new();
        for a in attempts {
            let key = (
                a["well"].to_string(),
                (a["x_m"].as_f64().unwrap() * 1e6).round() as i64,
            );
            assert!(
                seen.insert(key),
                "kill {k} ({when}): a cell attempted twice: {a}"
            );
        }
        assert_eq!(attempts.len(), cells, "kill {k} ({when}): every cell once");
        let interrupted = attempts
            .iter()
            .filter(|a| a["outcome"] == "interrupted")
            .count();
        assert!(
            interrupted <= 1,
            "kill {k} ({when}): {interrupted} interrupted"
        );
        // Killed within a field (the first injected, the last surveyed): the resumed
        // run goes on in it. A field's cells go in column order on this one-row plate,
        // and the first field's cells lie right of the second's, so the next cell of
        // the same field is right of the last one done.
        if k == 0 {
            let done = before["attempts"].as_array().unwrap().len();
            let col = |a: &Value| a["well"][1].as_i64().unwrap();
            let (last, next) = (col(&attempts[done - 1]), col(&attempts[done]));
            assert!(
                next > last,
                "kill {k} ({when}): from column {last} to {next}"
            );
        }
    }
}

#[test]
fn a_move_the_safety_envelope_refuses_stops_the_run_with_the_refusal_recorded() {
    let d = bench("refuse");
    // A stage of 5 mm travel: moving the pipette out of view (2.9 mm to the left of
    // the plate's centre) is beyond it, and the guard refuses before the stage moves.
    let proto = fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/prototype.toml"),
    )
    .unwrap();
    let short = proto.replace("travel = 0.025 ", "travel = 0.005 ");
    assert_ne!(short, proto);
    fs::write(d.join("short.toml"), short).unwrap();
    let (code, s, e) = json_run(&d, &["--config", "short.toml", "--db", "ref.sqlite"]);
    assert_eq!(code, Some(1), "{e}");
    assert_eq!(s["status"], "stopped");
    let why = s["stopped"].as_str().unwrap();
    assert!(why.contains("refused") && why.contains("travel"), "{why}");
    assert_eq!(s["attempts"].as_array().unwrap().len(), 0);
}

#[test]
fn re_checks_of_the_calibrations_are_made_on_time_and_recorded_with_their_verdict() {
    let d = dir("recheck");
    plate(&d);
    let every = |db: &str, seconds: &str| {
        run(
            &d,
            &[
                "run",
                "--plate",
                "p.toml",
                "--db",
                db,
                "--recheck-every",
                seconds,
                "--format",
                "json",
            ],
        )
    };
    let o = every("r.sqlite", "10");
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let s: Value = serde_json::from_slice(&o.stdout).unwrap();
    let events = s["events"].as_array().unwrap();
    let t = |e: &Value| e["t"].as_f64().unwrap();
    let of = |name: &str| -> Vec<&Value> { events.iter().filter(|e| e["event"] == name).collect() };
    // The run's own transitions are recorded in order: calibrated, surveyed, ..., the end.
    assert_eq!(events[0]["event"], "begin");
    assert_eq!(of("calibrated").len(), 1);
    assert_eq!(events.last().unwrap()["event"], "no_more_cells");
    assert!(events.windows(2).all(|w| t(&w[0]) <= t(&w[1])));
    // A run of about 40 s of cells re-checks every 10 s of device time: at least twice,
    // each due no earlier than 10 s after the last map or check, each answered.
    let (due, done) = (of("recheck"), of("rechecked"));
    assert!(due.len() >= 2, "{events:?}");
    assert_eq!(due.len(), done.len());
    let mut last = t(of("calibrated")[0]);
    for (a, b) in due.iter().zip(&done) {
        assert!(t(a) - last >= 10.0 - 1e-9, "{a} after {last}");
        assert!(
            a["reason"].as_str().unwrap().contains("(every 10 s)"),
            "{a}"
        );
        // The verdict says what was measured and what was done.
        let r = b["reason"].as_str().unwrap();
        assert!(r.contains("µm from where the map puts it"), "{r}");
        assert!(
            r.contains("the map holds") || r.contains("image mapped to the stage again"),
            "{r}"
        );
        assert_eq!(
            (a["to"].as_str(), b["from"].as_str()),
            (Some("rechecking"), Some("rechecking"))
        );
        last = t(b);
    }
    // The re-checks cost time but not cells.
    let cells = s["cells_found"].as_u64().unwrap() as usize;
    assert_eq!(s["attempts"].as_array().unwrap().len(), cells);
    // The record reads back the same events.
    let o = run(&d, &["runs", "show", "--db", "r.sqlite"]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let shown: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(shown["events"], s["events"]);
    // A period that is not a number of seconds is refused, naming the option.
    for bad in ["-1", "nan", "inf"] {
        let o = every("x.sqlite", bad);
        assert_eq!(o.status.code(), Some(2), "{bad}: {}", err(&o));
        assert!(err(&o).contains("--recheck-every"), "{bad}: {}", err(&o));
    }
    assert!(
        !d.join("x.sqlite").exists(),
        "a refused run writes no database"
    );
}

#[test]
fn touching_partners_are_passed_over_from_above_unless_the_glass_truly_meets_them() {
    // Three doublet wells. The pipette comes down at 45° from smaller plate y, so the
    // partner of a well's second cell (larger y) lies behind it on the glass's way:
    // small behind large (well [0, 0]: a 10 um cell with a 20 um partner behind,
    // touching in the plate's plane; resting on the floor they are 0.8 um apart),
    // equal (well [0, 1], 16 um each), and side by side (well [0, 2]). The cells rest
    // on the floor, a mean radius below the focus: a larger cell stands taller.
    let d = dir("partners");
    let rows = [
        ([0, 0], [0.0, 5e-6], 10e-6),
        ([0, 0], [0.0, -10e-6], 20e-6),
        ([0, 1], [0.0, 8e-6], 16e-6),
        ([0, 1], [0.0, -8e-6], 16e-6),
        ([0, 2], [-6e-6, 0.0], 12e-6),
        ([0, 2], [6e-6, 0.0], 12e-6),
    ];
    let mut text =
        "[plate]\nrows = 1\ncols = 3\npitch = 150e-6\norigin = [-150e-6, 0.0]\n".to_string();
    for (w, o, dia) in rows {
        text += &format!(
            "\n[[cell]]\nwell = [{}, {}]\noffset = [{:e}, {:e}]\ndiameter = {dia:e}\n",
            w[0], w[1], o[0], o[1]
        );
    }
    fs::write(d.join("p.toml"), text).unwrap();
    // The expected decisions, from the plate's truth and the pipette's shape alone:
    // a cell is blocked when, for every aim within 0.3 of its radius of its centre
    // across the axis (on a grid of 0.05 radius), the glass, with the tip as deep as
    // the run lets it go (a fifth of the radius past the aim), comes within 0.5 um of
    // another cell.
    let p = cellinject_rig::PipetteParams::default();
    let ax = p.axis();
    // Across the axis: sideways (x) and up in the axis's vertical plane.
    let (side, up) = ([1.0, 0.0, 0.0], [0.0, ax[2], -ax[1]]);
    let mean_r = rows.iter().map(|r| 0.5 * r.2).sum::<f64>() / rows.len() as f64;
    let centre = |k: usize| {
        let (w, o, dia) = rows[k];
        let x = w[1] as f64 * 150e-6 + o[0];
        [x, -mean_r + 0.5 * dia, o[1]]
    };
    let blocked: Vec<bool> = (0..rows.len())
        .map(|k| {
            let (c, r) = (centre(k), 0.5 * rows[k].2);
            let blocked_at = |a: f64, b: f64| {
                let tip = [0, 1, 2].map(|i| c[i] + a * side[i] + b * up[i] + 0.2 * r * ax[i]);
                (0..rows.len())
                    .filter(|&j| j != k)
                    .any(|j| p.clearance(tip, ax, centre(j), 0.5 * rows[j].2) < 0.5e-6)
            };
            (-6..=6i32)
                .flat_map(|a| (-6..=6i32).map(move |b| (a, b)))
                .filter(|(a, b)| a * a + b * b <= 36)
                .all(|(a, b)| blocked_at(a as f64 * 0.05 * r, b as f64 * 0.05 * r))
        })
        .collect();
    // Only the small cell in front of the large one.
    assert_eq!(blocked, [true, false, false, false, false, false]);
    let o = run(&d, &["run", "--plate", "p.toml", "--format", "json"]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let s: Value = serde_json::from_slice(&o.stdout).unwrap();
    let attempts = s["attempts"].as_array().unwrap();
    assert_eq!(attempts.len(), rows.len(), "{s}");
    for a in attempts {
        // Which cell of the file: the nearest to the attempt's target.
        let (x, y) = (a["x_m"].as_f64().unwrap(), a["y_m"].as_f64().unwrap());
        let k = (0..rows.len())
            .min_by(|&i, &j| {
                let c = |k: usize| (centre(k)[0] - x).hypot(centre(k)[2] - y);
                c(i).total_cmp(&c(j))
            })
            .unwrap();
        let reason = a["reason"].as_str().unwrap_or_default();
        if blocked[k] {
            assert_eq!(a["outcome"], "skipped", "{a}");
            assert!(
                reason.contains("glass would run") && reason.contains("well [0, 0]"),
                "{reason}"
            );
        } else {
            assert_eq!(a["outcome"], "injected", "cell {k}: {a}");
            let f = a["dose_fraction"].as_f64().unwrap();
            assert!((f / 0.05 - 1.0).abs() < 0.2, "{a}");
            assert_eq!(a["alive"], Value::Bool(true));
        }
    }
    // The twin's truth: the glass never ran into a partner.
    assert_eq!(s["grazed"], 0, "{s}");
}

/// Issue 36, point 2: eight doublets of a 10 um cell touching one of 20-30 um, the small
/// one beside or in front of its partner (the pipette comes from smaller plate y, so
/// none is hidden behind it). Every 10 um cell is measured within 1 um of 10 um (they
/// were measured at 7.7-8.6 um, dosed from that and one got 41 % of its dose), every
/// cell is injected and lives: none dies of its dose.
#[test]
fn the_small_partners_of_doublets_are_sized_and_dosed_as_themselves() {
    let d = dir("doublets");
    // (the large cell's diameter, the direction from it to the small one, rad): the
    // twin's images of these were sized 8.6-9.9 um by the darkest ring of old.
    let pairs = [
        (22.4e-6, 4.87f64),
        (23.7e-6, 5.07),
        (26.3e-6, 3.21),
        (20.1e-6, 5.88),
        (22.6e-6, 3.79),
        (30.0e-6, 4.61),
        (28.4e-6, 4.63),
        (26.4e-6, 3.51),
    ];
    let mut text =
        "[plate]\nrows = 1\ncols = 8\npitch = 150e-6\norigin = [-525e-6, 0.0]\n".to_string();
    let mut small = Vec::new();
    for (k, (big, angle)) in pairs.iter().enumerate() {
        // Touching: centres half the sum of the diameters apart, the pair centred.
        let sep = 0.5 * (big + 10e-6);
        let (ux, uy) = (angle.cos(), angle.sin());
        let b = [-0.5 * sep * ux, -0.5 * sep * uy];
        let s = [0.5 * sep * ux, 0.5 * sep * uy];
        small.push([k as f64 * 150e-6 + s[0], s[1]]);
        for (o, dia) in [(b, *big), (s, 10e-6)] {
            text += &format!(
                "\n[[cell]]\nwell = [0, {k}]\noffset = [{:e}, {:e}]\ndiameter = {dia:e}\n",
                o[0], o[1]
            );
        }
    }
    fs::write(d.join("p.toml"), text).unwrap();
    let o = run(&d, &["run", "--plate", "p.toml", "--format", "json"]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let s: Value = serde_json::from_slice(&o.stdout).unwrap();
    let attempts = s["attempts"].as_array().unwrap();
    assert_eq!(attempts.len(), 2 * pairs.len(), "{s}");
    let mut sized = 0;
    for a in attempts {
        assert_eq!(a["outcome"], "injected", "{a}");
        assert_eq!(a["alive"], Value::Bool(true), "{a}");
        let (x, y) = (a["x_m"].as_f64().unwrap(), a["y_m"].as_f64().unwrap());
        if small.iter().any(|p| (p[0] - x).hypot(p[1] - y) < 2e-6) {
            let dia = a["diameter_m"].as_f64().unwrap();
            eprintln!("a 10 um partner measured {:.2} um", dia * 1e6);
            assert!((dia - 10e-6).abs() < 1e-6, "{a}");
            sized += 1;
        }
    }
    assert_eq!(sized, pairs.len());
}

/// On a terminal (a pseudo-terminal from util-linux's `script`) `run` shows its
/// progress over the cells, up to all of them, on a plate of several fields of view;
/// piped, its standard output is the same summary and no bar is drawn.
#[test]
fn on_a_terminal_a_run_shows_its_progress_to_the_last_cell_and_piped_it_does_not() {
    let d = dir("pty");
    common::plate(
        &d,
        &[
            "--rows",
            "1",
            "--cols",
            "17",
            "--origin=-1.2e-3,0",
            "--empty-fraction",
            "0.5",
            "--debris-fraction",
            "0",
            "--doublet-fraction",
            "0",
            "--seed",
            "4",
        ],
        "p.toml",
    );
    let bin = env!("CARGO_BIN_EXE_cellinject");
    let tty = Command::new("script")
        .args([
            "-qec",
            &format!("{bin} run --plate p.toml --db t.sqlite"),
            "/dev/null",
        ])
        .current_dir(&d)
        .output()
        .expect("util-linux's `script` (Debian's bsdutils) runs the command on a pseudo-terminal");
    assert!(
        tty.status.success(),
        "{}",
        String::from_utf8_lossy(&tty.stdout)
    );
    // The terminal's text without its control sequences (ESC [ ... letter), each
    // redraw of the bar on a line of its own.
    let raw = String::from_utf8_lossy(&tty.stdout).replace('\r', "\n");
    let mut screen = String::new();
    let mut chars = raw.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            // The sequence's introducer, then everything up to its final letter.
            let _ = chars.next();
            for d in chars.by_ref() {
                if d.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            screen.push(c);
        }
    }
    let piped = run(&d, &["run", "--plate", "p.toml", "--db", "p.sqlite"]);
    assert_eq!(piped.status.code(), Some(0), "{}", err(&piped));
    let out = String::from_utf8_lossy(&piped.stdout);
    let found: usize = out
        .split_whitespace()
        .zip(out.split_whitespace().skip(1))
        .find(|(_, w)| *w == "cells" || *w == "cell")
        .and_then(|(n, _)| n.parse().ok())
        .expect("the summary's cells found");
    assert!(found >= 3, "{out}");
    let fields: usize = out
        .lines()
        .find_map(|l| l.split(" field").next()?.parse().ok())
        .unwrap_or(1);
    assert!(fields >= 2, "a plate of several fields: {out}");
    let last = format!("{found}/{found} (");
    assert!(
        screen
            .lines()
            .any(|l| l.starts_with("cells [") && l.contains(&last)),
        "no bar reaching {found}/{found}: {screen}"
    );
    // Piped: the same summary, and no bar on either stream.
    for line in out.lines() {
        assert!(
            screen.contains(line.trim_end()),
            "{line:?} not on the terminal: {screen}"
        );
    }
    assert!(
        !out.contains("cells [") && !err(&piped).contains("cells ["),
        "{}",
        err(&piped)
    );
}
