//! `plate generate` and `plate check` from the command line: a generated plate reads
//! back and holds what was asked; bad plate files are refused with exit 2 naming the
//! file and the key.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use std::fs;
use std::path::PathBuf;
use std::process::Output;

use serde_json::Value;

use common::{err, run};

fn dir(name: &str) -> PathBuf {
    common::dir("plate", name)
}

fn json(o: &Output) -> Value {
    assert_eq!(o.status.code(), Some(0), "{}", err(o));
    serde_json::from_slice(&o.stdout).unwrap()
}

#[test]
fn a_generated_plate_is_checked_and_reads_back_with_what_was_asked() {
    let d = dir("gen");
    let g = json(&run(
        &d,
        &[
            "plate", "generate", "--rows", "10", "--cols", "12", "--seed", "5", "--out", "p.toml",
            "--format", "json",
        ],
    ));
    assert_eq!(g["wells"], 120);
    assert_eq!(g["files"][0], "p.toml");
    let cells = g["cells"].as_u64().unwrap();
    let empty = g["empty_wells"].as_u64().unwrap();
    let doublets = g["doublets"].as_u64().unwrap();
    // Every well holds 0, 1 or 2 cells.
    assert_eq!(cells, 120 - empty + doublets);
    assert!(
        doublets > 0 && empty > 0 && g["debris"].as_u64().unwrap() > 0,
        "{g}"
    );
    let d_range = &g["cell_diameter_m"];
    assert!(d_range[0].as_f64().unwrap() >= 10e-6 && d_range[1].as_f64().unwrap() <= 30e-6);
    // `check` reads the file and finds the same.
    let c = json(&run(
        &d,
        &["plate", "check", "--plate", "p.toml", "--format", "json"],
    ));
    for k in ["wells", "cells", "doublets", "empty_wells", "debris"] {
        assert_eq!(c[k], g[k], "{k}");
    }
    // The same seed writes the same bytes; another seed another plate.
    let first = fs::read(d.join("p.toml")).unwrap();
    run(
        &d,
        &[
            "plate", "generate", "--rows", "10", "--cols", "12", "--seed", "5", "--out", "q.toml",
        ],
    );
    assert_eq!(fs::read(d.join("q.toml")).unwrap(), first);
    run(
        &d,
        &[
            "plate", "generate", "--rows", "10", "--cols", "12", "--seed", "6", "--out", "q.toml",
        ],
    );
    assert_ne!(fs::read(d.join("q.toml")).unwrap(), first);
}

/// The shipped example (`configs/example-plate.toml`).
const GOOD: &str = include_str!("../../../../configs/example-plate.toml");

#[test]
fn bad_plate_files_are_refused_naming_the_file_and_the_key() {
    let d = dir("bad");
    fs::write(d.join("good.toml"), GOOD).unwrap();
    let o = run(&d, &["plate", "check", "--plate", "good.toml"]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let cases: Vec<(String, &str)> = vec![
        // A cell outside its well.
        (
            GOOD.replace("offset = [3e-6", "offset = [70e-6"),
            "cell[0].offset",
        ),
        // Two cells overlapping.
        (
            format!("{GOOD}[[cell]]\nwell = [0, 0]\noffset = [10e-6, 0.0]\ndiameter = 12e-6\n"),
            "cell[1].offset",
        ),
        // An unknown key.
        (
            GOOD.replace("rows = 4", "rows = 4\ncolour = \"blue\""),
            "plate.colour",
        ),
        // A negative size.
        (
            GOOD.replace("diameter = 6e-6", "diameter = -6e-6"),
            "debris[0].diameter",
        ),
        // Debris the size of a cell.
        (
            GOOD.replace("diameter = 6e-6", "diameter = 16e-6"),
            "debris[0].diameter",
        ),
        // A well off the grid.
        (
            GOOD.replace("well = [1, 2]", "well = [4, 2]"),
            "debris[0].well",
        ),
        // A missing key.
        (GOOD.replace("pitch = 150e-6", "#"), "plate.pitch"),
        // A pitch typed in mm (160 mm is no feeder's): refused with a units hint.
        (
            GOOD.replace("pitch = 150e-6", "pitch = 0.16"),
            "did you mean 0.16 mm",
        ),
        // TOML syntax.
        (GOOD.replace("rows = 4", "rows = [4"), "not valid TOML"),
    ];
    for (text, key) in cases {
        fs::write(d.join("bad.toml"), &text).unwrap();
        let o = run(&d, &["plate", "check", "--plate", "bad.toml"]);
        assert_eq!(o.status.code(), Some(2), "{key}: {}", err(&o));
        let e = err(&o);
        assert!(e.contains("bad.toml") && e.contains(key), "{key}: {e}");
        assert!(!e.contains("panicked"), "{e}");
    }
    // A file with three distinct faults: all three listed, one per line (exit 2).
    let three = GOOD
        .replace("[plate]\n", "[plate]\ncolour = \"red\"\n")
        .replace("offset = [3e-6", "offset = [70e-6")
        + "[[cell]]\nwell = [1, 1]\noffset = [0.0, 0.0]\ndiameter = -20e-6\n";
    fs::write(d.join("three.toml"), &three).unwrap();
    let o = run(&d, &["plate", "check", "--plate", "three.toml"]);
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    let e = err(&o);
    assert!(e.contains("three.toml") && e.contains("3 problems"), "{e}");
    for key in ["plate.colour", "cell[0].offset", "].diameter"] {
        assert_eq!(
            e.lines().filter(|l| l.contains(key)).count(),
            1,
            "{key}: {e}"
        );
    }
    // A plate the feeder cannot present (50 mm off the stage's origin): `plate check`
    // refuses it as `run` does, naming the wells and the move that would fix it.
    let far = GOOD.replace("origin = [0.0, 0.0]", "origin = [0.05, 0.0]");
    assert_ne!(far, GOOD);
    fs::write(d.join("far.toml"), &far).unwrap();
    let check = run(&d, &["plate", "check", "--plate", "far.toml"]);
    let run_it = run(&d, &["run", "--plate", "far.toml", "--db", "far.sqlite"]);
    for o in [&check, &run_it] {
        assert_eq!(o.status.code(), Some(2), "{}", err(o));
        let e = err(o);
        assert!(
            e.contains("outside the feeder stage's travel") && e.contains("[0, 0]"),
            "{e}"
        );
        assert!(e.contains("moving the plate's origin"), "{e}");
    }
    assert!(err(&check).contains("far.toml"), "{}", err(&check));
    // Bad generator options: exit 2, the option named, nothing written.
    for (args, name) in [
        (vec!["--rows", "0"], "--rows"),
        (vec!["--empty-fraction", "1.5"], "--empty-fraction"),
        (vec!["--pitch", "20e-6"], "--pitch"),
        (vec!["--origin", "nan,0"], "--origin"),
    ] {
        let mut a = vec!["plate", "generate", "--out", "x.toml"];
        a.extend(args);
        let o = run(&d, &a);
        assert_eq!(o.status.code(), Some(2), "{name}: {}", err(&o));
        assert!(err(&o).contains(name), "{name}: {}", err(&o));
        assert!(!d.join("x.toml").exists());
    }
    let o = run(&d, &["plate", "generate", "--out", "x.csv"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(err(&o).contains(".toml"), "{}", err(&o));
}

/// Cell detection on the twin against the plate's truth, over plates with many
/// doublets and much debris: every cell found once, no debris called a cell, centres
/// within half a micrometre.
#[test]
fn plate_detect_finds_every_cell_and_no_debris_on_generated_plates() {
    let d = dir("detect");
    let (mut cells, mut found, mut splits) = (0, 0, 0);
    for (seed, zoom) in [("21", "2.5"), ("21", "10")] {
        let name = format!("g{seed}.toml");
        let o = run(
            &d,
            &[
                "plate",
                "generate",
                "--rows",
                "5",
                "--cols",
                "7",
                "--seed",
                seed,
                "--doublet-fraction",
                "0.3",
                "--debris-fraction",
                "0.4",
                "--out",
                &name,
            ],
        );
        assert_eq!(o.status.code(), Some(0), "{}", err(&o));
        let r = json(&run(
            &d,
            &[
                "plate", "detect", "--plate", &name, "--zoom", zoom, "--format", "json",
            ],
        ));
        println!(
            "seed {seed}: {}",
            serde_json::to_string(&r)
                .unwrap()
                .chars()
                .take(400)
                .collect::<String>()
        );
        assert_eq!(r["debris_called_cells"], 0, "{r}");
        assert_eq!(r["false_positives"], 0, "{r}");
        assert!(r["recall"].as_f64().unwrap() >= 0.99, "{r}");
        assert!(r["centre_error_m"][1].as_f64().unwrap() < 0.5e-6, "{r}");
        assert!(r["diameter_error_m"].as_f64().unwrap() < 1e-6, "{r}");
        splits += r["cells"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|c| c["split"] == true)
            .count();
        cells += r["true_cells"].as_u64().unwrap();
        found += r["true_positives"].as_u64().unwrap();
    }
    // 35 wells at 2.5x (the whole plate), a corner at 10x.
    assert!(cells >= 35, "{cells}");
    assert_eq!(found, cells);
    // Doublets were split.
    assert!(splits >= 4, "{splits}");
}

/// A plate that lies outside the frame: exit 1 with a sentence saying where the frame
/// and the wells are, not a report of NaN.
#[test]
fn plate_detect_with_no_cell_in_view_says_where_the_plate_is() {
    let d = dir("detect-none");
    common::plate(&d, &["--origin=5e-3,5e-3"], "far.toml");
    for format in ["text", "json"] {
        let o = run(
            &d,
            &["plate", "detect", "--plate", "far.toml", "--format", format],
        );
        assert_eq!(o.status.code(), Some(1), "{}", err(&o));
        let e = err(&o);
        assert!(
            e.contains("no cell in view") && e.contains("far.toml"),
            "{e}"
        );
        assert!(e.contains("[4.925, 5.825] mm"), "the wells' span: {e}");
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(!out.contains("NaN") && !e.contains("NaN"), "{out}{e}");
    }
}

/// The pipette's tip found from the image alone, in focus, against the twin's truth.
#[test]
fn sim_tip_finds_the_tip_to_a_fraction_of_a_micrometre() {
    let d = dir("tip");
    for zoom in ["10", "2.5"] {
        let r = json(&run(
            &d,
            &[
                "sim", "tip", "--runs", "6", "--zoom", zoom, "--format", "json",
            ],
        ));
        println!("{zoom}x: {r}");
        assert_eq!(r["not_found"], 0, "{r}");
        let e = &r["error_m"];
        assert!(e[1].as_f64().unwrap() < 0.5e-6, "{zoom}x: {r}");
        // Across the axis the tube is symmetric: tighter still.
        assert!(
            r["along_across_m"][1].as_f64().unwrap() < 0.1e-6,
            "{zoom}x: {r}"
        );
    }
}
