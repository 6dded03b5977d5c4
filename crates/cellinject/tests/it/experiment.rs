//! `calibrate` and `experiment` from the command line, as a newcomer uses them: the
//! files they write, their JSON, calibration files that are broken, made for another
//! bench or failing their check, outputs that collide with inputs, bad numbers.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Output;
use std::sync::OnceLock;

use serde_json::Value;

use common::err;

fn dir(name: &str) -> PathBuf {
    common::dir("exp", name)
}

fn run(dir: &Path, args: &[&str]) -> Output {
    common::cmd(dir)
        .env(
            "XDG_CACHE_HOME",
            std::env::temp_dir().join(format!("cellinject-exp-cache-{}", std::process::id())),
        )
        .args(args)
        .output()
        .unwrap()
}

/// One calibration directory (approach 2) shared by the tests: `calibrate all`.
fn calibration() -> &'static PathBuf {
    static CAL: OnceLock<PathBuf> = OnceLock::new();
    CAL.get_or_init(|| {
        let d = dir("cal");
        let o = run(
            &d,
            &["calibrate", "all", "--out", "cal", "--format", "json"],
        );
        assert_eq!(o.status.code(), Some(0), "{}", err(&o));
        let v: Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(v["files"].as_array().unwrap().len(), 3);
        // Each file records what it was made on, and when.
        let px: Value =
            serde_json::from_str(&fs::read_to_string(d.join("cal/pixels.json")).unwrap()).unwrap();
        assert_eq!(px["kind"], "pixels");
        assert_eq!(px["made"]["backend"], "twin");
        assert_eq!(px["made"]["approach"], 2);
        // What it printed is what it wrote (the figures it found, each calibration's).
        assert_eq!(v["pixels"], px["calibration"]);
        for kind in ["jacobian", "hysteresis"] {
            let f: Value = serde_json::from_str(
                &fs::read_to_string(d.join(format!("cal/{kind}.json"))).unwrap(),
            )
            .unwrap();
            assert_eq!(v[kind], f["calibration"], "{kind}");
        }
        assert!(px["made"]["created_utc"].as_str().unwrap().ends_with('Z'));
        let m = px["calibration"]["maps"][0]["metres_per_pixel"][0]
            .as_f64()
            .unwrap();
        assert!((m / 0.22e-6 - 1.0).abs() < 0.005, "{m}");
        d.join("cal")
    })
}

/// A short repeatability run (2 runs, 0.2 s hold) with `extra` arguments.
fn quick_repeatability(d: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "experiment",
        "repeatability",
        "--runs",
        "2",
        "--hold",
        "0.2",
    ];
    args.extend_from_slice(extra);
    run(d, &args)
}

/// Copies the shared calibration's three files into `to`, for a test to spoil.
fn copy_calibration(from: &Path, to: &Path) {
    fs::create_dir_all(to).unwrap();
    for f in ["pixels.json", "jacobian.json", "hysteresis.json"] {
        fs::copy(from.join(f), to.join(f)).unwrap();
    }
}

#[test]
fn repeatability_writes_csv_json_and_plots_and_prints_only_json() {
    let d = dir("rep");
    let cal = calibration().to_str().unwrap();
    let o = run(
        &d,
        &[
            "experiment",
            "repeatability",
            "--control",
            "closed",
            "--runs",
            "3",
            "--hold",
            "0.5",
            "--calibration",
            cal,
            "--format",
            "json",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let v: Value = serde_json::from_slice(&o.stdout).expect("only JSON on stdout");
    for k in [
        "max_error_m",
        "rms_error_m",
        "true_max_error_m",
        "true_rms_error_m",
    ] {
        assert_eq!(v[k].as_array().unwrap().len(), 2, "{k}");
    }
    assert_eq!(v["control"], "closed");
    assert_eq!(v["runs"], 3);
    // The default output directory, created; no calibration made (all were valid).
    for ext in ["csv", "json", "svg", "png"] {
        assert!(
            d.join(format!("experiments/repeatability-approach2-closed.{ext}"))
                .is_file()
        );
    }
    assert!(!d.join("experiments/calibration").exists());
    let csv = fs::read_to_string(d.join("experiments/repeatability-approach2-closed.csv")).unwrap();
    assert!(
        csv.starts_with(
            "run,x_m,y_m,true_x_m,true_y_m,settling_frames,a1_voltage_v,a2_voltage_v\n"
        )
    );
    assert_eq!(csv.lines().count(), 4);
    // The text form says what it measured.
    let o = quick_repeatability(&d, &["--calibration", cal]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("open control") && text.contains("twin's truth"),
        "{text}"
    );
}

#[test]
fn broken_or_foreign_calibrations_are_refused_or_redone_never_used() {
    let d = dir("bad");
    let cal = calibration();
    // A file that is not a calibration: exit 2, naming it.
    copy_calibration(cal, &d.join("broken"));
    fs::write(d.join("broken/jacobian.json"), "{\"kind\": \"jacobian\"").unwrap();
    let o = run(
        &d,
        &[
            "experiment",
            "repeatability",
            "--runs",
            "2",
            "--calibration",
            "broken",
        ],
    );
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    assert!(err(&o).contains("jacobian.json"), "{}", err(&o));
    // A pixel calibration whose check fails (a residual of 5 px): said, made again, and
    // the new one saved with the experiment's outputs.
    copy_calibration(cal, &d.join("failing"));
    let mut px: Value =
        serde_json::from_str(&fs::read_to_string(cal.join("pixels.json")).unwrap()).unwrap();
    px["calibration"]["maps"][0]["rms_px"] = Value::from(5.0);
    fs::write(d.join("failing/pixels.json"), px.to_string()).unwrap();
    let o = quick_repeatability(&d, &["--calibration", "failing", "--out", "out"]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    assert!(err(&o).contains("fails its check"), "{}", err(&o));
    assert!(d.join("out/calibration/pixels.json").is_file());
    assert!(!d.join("out/calibration/jacobian.json").exists());
    // Made under the other approach: made again for this bench.
    let o = quick_repeatability(
        &d,
        &[
            "--approach",
            "1",
            "--calibration",
            cal.to_str().unwrap(),
            "--out",
            "out1",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    assert!(err(&o).contains("approach 2"), "{}", err(&o));
    assert!(d.join("out1/calibration/jacobian.json").is_file());
    assert!(!d.join("out1/calibration/pixels.json").exists());
}

#[test]
fn bad_arguments_are_exit_2_with_the_option_named() {
    let d = dir("args");
    let cal = calibration().to_str().unwrap().to_string();
    fs::write(d.join("file"), "x").unwrap();
    for (args, needle) in [
        (
            vec!["experiment", "repeatability", "--shift", "nan"],
            "--shift",
        ),
        (
            vec![
                "experiment",
                "repeatability",
                "--shift",
                "1e-3",
                "--calibration",
                &cal,
            ],
            "--shift",
        ),
        (vec!["experiment", "repeatability", "--runs", "1"], "--runs"),
        (vec!["experiment", "repeatability", "--hold", "0"], "--hold"),
        (
            vec!["experiment", "repeatability", "--out", "file"],
            "--out",
        ),
        (
            vec!["experiment", "repeatability", "--calibration", "missing"],
            "--calibration",
        ),
        (vec!["experiment", "range", "--sweep", "-1"], "--sweep"),
        (
            vec![
                "experiment",
                "tracking",
                "--frequency",
                "0",
                "--calibration",
                &cal,
            ],
            "--frequency",
        ),
        (
            vec!["experiment", "tracking", "--latency", "2"],
            "--latency",
        ),
        (vec!["calibrate", "pixels", "--step", "1"], "--step"),
        (vec!["calibrate", "pixels", "--out", "px.csv"], "--out"),
        (vec!["calibrate", "jacobian", "--volts", "0"], "--volts"),
        (
            vec!["calibrate", "hysteresis", "--samples", "10"],
            "--samples",
        ),
    ] {
        let o = run(&d, &args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", err(&o));
        assert!(err(&o).contains(needle), "{args:?}: {}", err(&o));
        assert!(!err(&o).contains("panicked"));
    }
    // An output that is the input.
    let px = format!("{cal}/pixels.json");
    let o = run(
        &d,
        &["calibrate", "jacobian", "--pixels", &px, "--out", &px],
    );
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    assert!(err(&o).contains("--out"), "{}", err(&o));
}
