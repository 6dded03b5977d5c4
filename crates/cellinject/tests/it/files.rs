//! The rules of "Files, exit codes and output" (README), each over the commands that
//! write files or take numbers: nothing an input or another output is replaced, a bad
//! output path is refused before any computation, failures leave no half-set of files,
//! formats follow extensions, the same inputs give the same bytes, numbers are typed as
//! people type them and NaN is refused with the option named.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Output;

use common::err;

fn dir(name: &str) -> PathBuf {
    common::dir("files", name)
}

fn run(dir: &Path, args: &[&str]) -> Output {
    common::cmd(dir)
        .env("XDG_CACHE_HOME", dir.join("cache"))
        .args(args)
        .output()
        .unwrap()
}

fn files(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n != "cache")
        .collect();
    v.sort();
    v
}

/// A speckle pair in `d`.
fn pair(d: &Path) {
    let o = run(
        d,
        &[
            "dic",
            "synth",
            "--size",
            "96,96",
            "--shift",
            "0.3,-0.2",
            "--reference",
            "reference.png",
            "--current",
            "current.png",
        ],
    );
    assert!(o.status.success(), "{}", err(&o));
}

#[test]
fn no_output_replaces_an_input_or_another_output() {
    let d = dir("collide");
    pair(&d);
    let reference = fs::read(d.join("reference.png")).unwrap();
    // `--out reference.csv`: its companion map would be reference.png, the input.
    for out in ["reference.csv", "reference.png", "reference.svg"] {
        let o = run(
            &d,
            &[
                "dic",
                "field",
                "--reference",
                "reference.png",
                "--current",
                "current.png",
                "--out",
                out,
            ],
        );
        assert_eq!(o.status.code(), Some(2), "{out}: {}", err(&o));
        assert!(err(&o).contains("--reference"), "{}", err(&o));
    }
    assert_eq!(fs::read(d.join("reference.png")).unwrap(), reference);
    // Two outputs on one path.
    let o = run(
        &d,
        &[
            "dic",
            "synth",
            "--reference",
            "same.png",
            "--current",
            "./same.png",
        ],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(err(&o).contains("same file"), "{}", err(&o));
    // A frame list that holds the output is refused too (the CSV cannot be a frame, but
    // a frame may not be written over by a companion either).
    fs::create_dir_all(d.join("frames")).unwrap();
    fs::copy(d.join("reference.png"), d.join("frames/a.png")).unwrap();
    fs::copy(d.join("current.png"), d.join("frames/b.png")).unwrap();
    let o = run(
        &d,
        &[
            "dic",
            "track",
            "--frames",
            "frames",
            "--roi",
            "30,30,33,33",
            "--out",
            "frames/a.csv",
        ],
    );
    assert!(o.status.success(), "{}", err(&o));
    // Companions share the stem: `--out loop.svg` writes loop.csv, .svg and .png.
    let o = run(
        &d,
        &["sim", "loop", "--amplitude", "5", "--out", "loop.svg"],
    );
    assert!(o.status.success(), "{}", err(&o));
    for f in ["loop.csv", "loop.svg", "loop.png"] {
        assert!(d.join(f).is_file(), "{f}");
    }
    let o = run(
        &d,
        &["sim", "loop", "--amplitude", "5", "--out", "loop.txt"],
    );
    assert_eq!(o.status.code(), Some(2));
    let _ = fs::remove_dir_all(&d);
}

#[test]
fn a_bad_output_directory_is_refused_before_any_computation() {
    let d = dir("nodir");
    pair(&d);
    fs::write(d.join("plain.txt"), "x").unwrap();
    for (args, arg) in [
        (
            vec![
                "fea",
                "--approach",
                "1",
                "--forces",
                "-100,-100",
                "--plot",
                "no/x.svg",
            ],
            "--plot",
        ),
        (vec!["sim", "loop", "--out", "no/loop.csv"], "--out"),
        (
            vec!["sim", "step", "--voltage", "5", "--out", "plain.txt/s.csv"],
            "--out",
        ),
        (vec!["sim", "frame", "--out", "no/frame.png"], "--out"),
        (
            vec![
                "dic",
                "field",
                "--reference",
                "reference.png",
                "--current",
                "current.png",
                "--out",
                "no/f.csv",
            ],
            "--out",
        ),
        (
            vec![
                "dic",
                "synth",
                "--reference",
                "no/r.png",
                "--current",
                "c2.png",
            ],
            "--reference",
        ),
        (
            vec![
                "hinge",
                "--profile",
                "leaf",
                "--thickness",
                "1e-3",
                "--width",
                "5e-3",
                "--length",
                "4e-3",
                "--method",
                "fem",
                "--export-mesh",
                "no/m.json",
            ],
            "--export-mesh",
        ),
        (vec!["reproduce", "--out", "plain.txt/rep"], "--out"),
    ] {
        let o = run(&d, &args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", err(&o));
        assert!(err(&o).contains(arg), "{args:?}: {}", err(&o));
        assert!(!d.join("no").exists(), "{args:?} created the directory");
    }
    // The fea refusal came before the joints were solved: nothing in the cache.
    assert!(
        fs::read_dir(d.join("cache/cellinject"))
            .map(|e| e.count() == 0)
            .unwrap_or(true)
    );
    let _ = fs::remove_dir_all(&d);
}

#[test]
fn a_failed_command_leaves_no_half_set_and_exits_1() {
    let d = dir("textureless");
    let flat = image::GrayImage::from_pixel(96, 96, image::Luma([90]));
    flat.save(d.join("a.png")).unwrap();
    flat.save(d.join("b.png")).unwrap();
    let before = files(&d);
    let o = run(
        &d,
        &[
            "dic",
            "field",
            "--reference",
            "a.png",
            "--current",
            "b.png",
            "--out",
            "f.csv",
        ],
    );
    assert_eq!(o.status.code(), Some(1), "{}", err(&o));
    assert!(err(&o).contains("no grid point matched"), "{}", err(&o));
    assert_eq!(files(&d), before, "files were left behind");
    let o = run(
        &d,
        &[
            "dic",
            "--reference",
            "a.png",
            "--current",
            "b.png",
            "--at",
            "48,48",
        ],
    );
    assert_eq!(o.status.code(), Some(1), "{}", err(&o));
    let _ = fs::remove_dir_all(&d);
}

#[test]
fn formats_follow_extensions_and_the_same_inputs_give_the_same_bytes() {
    let d = dir("formats");
    let o = run(&d, &["sim", "frame", "--vga", "--out", "f.tif"]);
    assert!(o.status.success(), "{}", err(&o));
    let tif = fs::read(d.join("f.tif")).unwrap();
    assert!(
        tif.starts_with(b"II*\0") || tif.starts_with(b"MM\0*"),
        "not a TIFF"
    );
    let o = run(&d, &["sim", "frame", "--vga", "--out", "f.png"]);
    assert!(o.status.success());
    assert!(fs::read(d.join("f.png")).unwrap().starts_with(b"\x89PNG"));
    for bad in ["f.jpg", "f.bmp", "f"] {
        let o = run(&d, &["sim", "frame", "--vga", "--out", bad]);
        assert_eq!(o.status.code(), Some(2), "{bad}");
        assert!(!d.join(bad).exists());
    }
    // Twice the same loop: the same bytes in every file (no timestamps).
    let a = dir("formats-a");
    let b = dir("formats-b");
    for x in [&a, &b] {
        let o = run(x, &["sim", "loop", "--amplitude", "5", "--out", "l.csv"]);
        assert!(o.status.success());
    }
    for f in ["l.csv", "l.svg", "l.png"] {
        assert_eq!(
            fs::read(a.join(f)).unwrap(),
            fs::read(b.join(f)).unwrap(),
            "{f}"
        );
    }
    for x in [d, a, b] {
        let _ = fs::remove_dir_all(x);
    }
}

#[test]
fn numbers_are_typed_as_people_type_them() {
    let d = dir("numbers");
    // Negative numbers without `=` reach the real check, not clap's "unexpected argument".
    let o = run(
        &d,
        &[
            "hinge",
            "--profile",
            "circular",
            "--thickness",
            "-1e-3",
            "--radius",
            "2e-3",
            "--width",
            "5e-3",
        ],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(err(&o).contains("--thickness -0.001"), "{}", err(&o));
    let o = run(
        &d,
        &[
            "fea",
            "--approach",
            "1",
            "--forces",
            "-100,-100",
            "--format",
            "json",
        ],
    );
    assert!(o.status.success(), "{}", err(&o));
    let o = run(
        &d,
        &[
            "dic",
            "synth",
            "--size",
            "64",
            "64",
            "--shift",
            "-0.4,0.25",
            "--rotation",
            "-0.5",
        ],
    );
    assert!(o.status.success(), "{}", err(&o));
    // Lists take `1,2` and `1 2`.
    for levels in [vec!["1,1"], vec!["1", "1"]] {
        let mut args = vec!["fea", "joints", "--levels"];
        args.extend(levels);
        let o = run(&d, &args);
        assert!(o.status.success(), "{args:?}: {}", err(&o));
    }
    // NaN and infinities are refused with the option named.
    for (args, opt) in [
        (
            vec![
                "hinge",
                "--profile",
                "leaf",
                "--thickness",
                "nan",
                "--width",
                "1",
                "--length",
                "1",
            ],
            "--thickness",
        ),
        (vec!["hinge-table", "--radius", "inf"], "--radius"),
        (vec!["sim", "step", "--voltage", "NaN"], "--voltage"),
        (vec!["sim", "frame", "--zoom", "-inf"], "--zoom"),
        (vec!["sim", "frame", "--volts", "1,nan,3"], "--volts"),
        (vec!["sim", "loop", "--amplitude", "nan"], "--amplitude"),
        (vec!["dic", "synth", "--noise", "nan"], "--noise"),
        (vec!["dic", "synth", "--shift", "nan,0"], "--shift"),
        (
            vec![
                "dic",
                "track",
                "--frames",
                ".",
                "--roi",
                "1,1,9,9",
                "--out",
                "t.csv",
                "--um-per-px",
                "inf",
            ],
            "--um-per-px",
        ),
        (
            vec!["fea", "--approach", "1", "--forces", "nan,-1"],
            "--forces",
        ),
        (
            vec![
                "hinge",
                "--profile",
                "circular",
                "--thickness",
                "1e-3",
                "--radius",
                "2e-3",
                "--width",
                "5e-3",
                "--angle",
                "nan",
            ],
            "--angle",
        ),
    ] {
        let o = run(&d, &args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", err(&o));
        assert!(err(&o).contains(opt), "{args:?}: {}", err(&o));
    }
    let _ = fs::remove_dir_all(&d);
}

#[test]
fn a_hinge_outside_the_checked_range_is_computed_with_a_warning() {
    let d = dir("validity");
    // t/R = 1.5: computed, with a warning citing the range, on standard error.
    let o = run(
        &d,
        &[
            "hinge",
            "--profile",
            "circular",
            "--thickness",
            "3e-3",
            "--radius",
            "2e-3",
            "--width",
            "5e-3",
            "--format",
            "json",
        ],
    );
    assert!(o.status.success(), "{}", err(&o));
    assert!(err(&o).contains("0.05-1"), "{}", err(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["warnings"][0].as_str().unwrap().contains("t/R"));
    // Inside the range: no warning.
    let o = run(
        &d,
        &[
            "hinge",
            "--profile",
            "circular",
            "--thickness",
            "1e-3",
            "--radius",
            "2e-3",
            "--width",
            "5e-3",
        ],
    );
    assert!(o.status.success() && err(&o).is_empty(), "{}", err(&o));
    let _ = fs::remove_dir_all(&d);
}

#[test]
fn what_a_newcomer_tried_is_answered() {
    let d = dir("newcomer");
    // A current image shifted far beyond the search: no reliable match, exit 1.
    let o = run(
        &d,
        &[
            "dic",
            "synth",
            "--size",
            "128,128",
            "--shift",
            "1000,0",
            "--reference",
            "a.png",
            "--current",
            "b.png",
        ],
    );
    assert!(o.status.success());
    let o = run(
        &d,
        &[
            "dic",
            "--reference",
            "a.png",
            "--current",
            "b.png",
            "--at",
            "64,64",
            "--format",
            "json",
        ],
    );
    assert_eq!(o.status.code(), Some(1), "{}", err(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v[0]["u"].is_null(), "{v}");
    // A step shorter than the ringing window has one panel, not an error.
    let o = run(
        &d,
        &[
            "sim",
            "step",
            "--voltage",
            "50",
            "--duration",
            "0.03",
            "--out",
            "s.csv",
        ],
    );
    assert!(o.status.success(), "{}", err(&o));
    // `--out` naming a directory, or a name without a stem, is refused.
    fs::create_dir_all(d.join("sub")).unwrap();
    for out in ["sub", ".csv"] {
        let o = run(&d, &["sim", "loop", "--amplitude", "5", "--out", out]);
        assert_eq!(o.status.code(), Some(2), "{out}: {}", err(&o));
    }
    // `--config` on a command that reads none is said, not silently dropped.
    let o = run(
        &d,
        &["--config", "none.toml", "hinge-table", "--format", "json"],
    );
    assert!(o.status.success());
    assert!(err(&o).contains("--config"), "{}", err(&o));
    let o = run(&d, &["fea", "modes", "--count", "0"]);
    assert_eq!(o.status.code(), Some(2));
    let _ = fs::remove_dir_all(&d);
}

#[test]
fn hysteresis_identify_fit_invert_round_trip_and_refusals() {
    let d = dir("hysteresis");
    let o = run(
        &d,
        &[
            "hysteresis",
            "identify",
            "--samples",
            "2000",
            "--out",
            "ident.csv",
        ],
    );
    assert!(o.status.success(), "{}", err(&o));
    let o = run(
        &d,
        &[
            "hysteresis",
            "fit",
            "--data",
            "ident.csv",
            "--out",
            "model.json",
            "--format",
            "json",
        ],
    );
    assert!(o.status.success(), "{}", err(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["model"]["model"], "preisach");
    // The twin's stacks are Preisach operators with creep: the fit is close.
    assert!(v["rms_relative"].as_f64().unwrap() < 0.01, "{v}");
    for f in ["model.json", "model.svg", "model.png"] {
        assert!(d.join(f).is_file(), "{f}");
    }
    let mut traj = String::from("time_s,displacement_m\n");
    for k in 0..200 {
        let t = k as f64 * 1e-3;
        traj += &format!("{t},{}\n", (6.0 + 4.0 * (30.0 * t).sin()) * 1e-6);
    }
    fs::write(d.join("desired.csv"), &traj).unwrap();
    let o = run(
        &d,
        &[
            "hysteresis",
            "invert",
            "--model",
            "model.json",
            "--trajectory",
            "desired.csv",
            "--out",
            "cmd.csv",
        ],
    );
    assert!(o.status.success(), "{}", err(&o));
    let cmd = fs::read_to_string(d.join("cmd.csv")).unwrap();
    assert_eq!(cmd.lines().count(), 201);
    assert!(cmd.lines().skip(1).all(|l| {
        let v: f64 = l.split(',').nth(1).unwrap().parse().unwrap();
        (0.0..=100.0).contains(&v)
    }));
    // Out of reach: refused with the sample named, no command file.
    fs::write(
        d.join("far.csv"),
        "time_s,displacement_m\n0,1e-6\n0.001,1e-3\n",
    )
    .unwrap();
    let o = run(
        &d,
        &[
            "hysteresis",
            "invert",
            "--model",
            "model.json",
            "--trajectory",
            "far.csv",
            "--out",
            "far-cmd.csv",
        ],
    );
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    assert!(err(&o).contains("sample 1"), "{}", err(&o));
    assert!(!d.join("far-cmd.csv").exists());
    // Bad data: the line is named; too little data is refused.
    fs::write(
        d.join("bad.csv"),
        "time_s,voltage_v,displacement_m\n0,1,2\n0,x,3\n",
    )
    .unwrap();
    let o = run(
        &d,
        &["hysteresis", "fit", "--data", "bad.csv", "--out", "b.json"],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(err(&o).contains("line 3"), "{}", err(&o));
    fs::write(
        d.join("short.csv"),
        "time_s,voltage_v,displacement_m\n0,1,2e-6\n0.1,2,3e-6\n",
    )
    .unwrap();
    let o = run(
        &d,
        &[
            "hysteresis",
            "fit",
            "--data",
            "short.csv",
            "--out",
            "s.json",
        ],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(err(&o).contains("at least 100"), "{}", err(&o));
    let _ = fs::remove_dir_all(&d);
}

/// The files under `d`, recursively, sorted (paths relative to `d`).
fn tree(d: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut todo = vec![d.to_path_buf()];
    while let Some(p) = todo.pop() {
        for e in fs::read_dir(&p).unwrap() {
            let e = e.unwrap().path();
            if e.is_dir() {
                todo.push(e);
            } else {
                out.push(e.strip_prefix(d).unwrap().to_path_buf());
            }
        }
    }
    out.sort();
    out
}

/// "Files are never lost" over every command that writes files (found from the help
/// texts, with `no_panic`'s cheap valid invocations, so a new command is covered at
/// once): a file of the user's in the way of an output is kept beside it as
/// `NAME.~1~`, and the command says so on standard error; with `--force` it is
/// replaced without keeping. For an output directory, a file of the user's where the
/// command writes one of its files.
#[test]
fn every_writing_command_keeps_a_file_in_its_way_unless_forced() {
    use crate::no_panic::{baseline, bin, command_paths, setup};
    let d = setup("kept");
    let paths = command_paths(&d);
    let mine = b"a file of the user's own\n";
    let cases: Vec<(Vec<String>, PathBuf, usize)> = paths
        .iter()
        .filter_map(|p| {
            let base = baseline(p);
            let i = base.iter().position(|a| *a == "--out")?;
            // Each command its own output name in the shared directory.
            let out = PathBuf::from(format!("{}-{}", p.join("-"), base[i + 1]));
            let mut args = p.clone();
            args.extend(base.iter().map(|s| s.to_string()));
            args[p.len() + i + 1] = out.display().to_string();
            Some((args, out, p.len()))
        })
        .collect();
    assert!(cases.len() >= 15, "{cases:?}");
    let exec = |args: &[String]| {
        let o = bin(&d).args(args).output().unwrap();
        (
            o.status.code(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let check = |(args, out, at): &(Vec<String>, PathBuf, usize)| -> Option<String> {
        let said = |what: &str, e: &str| Some(format!("{}: {what}\n{e}", args.join(" ")));
        let target = if out.extension().is_some() {
            // A file of the user's where the output goes: replaced with --force, no copy
            // kept.
            fs::write(d.join(out), mine).unwrap();
            // Before the arguments (`design merge` takes files after its options).
            let mut forced = args.clone();
            forced.insert(*at, "--force".into());
            let (code, e) = exec(&forced);
            if code == Some(2) && e.contains("genicam") {
                return None; // `camera grab` in a build without GenICam.
            }
            if code != Some(0) || fs::read(d.join(out)).unwrap() == mine {
                return said("--force did not replace the file", &e);
            }
            if e.contains("kept as")
                || tree(&d)
                    .iter()
                    .any(|f| f.starts_with(format!("{}.~", out.display())))
            {
                return said("--force kept a copy", &e);
            }
            out.clone()
        } else {
            // An output directory: made by a first run, one of its files then the user's.
            let (code, e) = exec(args);
            if code != Some(0) {
                return said("the first run failed", &e);
            }
            let first = tree(&d.join(out)).into_iter().next()?;
            out.join(first)
        };
        fs::write(d.join(&target), mine).unwrap();
        let (code, e) = exec(args);
        let kept = d.join(format!("{}.~1~", target.display()));
        if code != Some(0) {
            return said("the second run failed", &e);
        }
        if fs::read(&kept).ok().as_deref() != Some(&mine[..]) {
            return said(
                &format!("`{}` does not hold the user's file", kept.display()),
                &e,
            );
        }
        if fs::read(d.join(&target)).unwrap() == mine || !e.contains("kept as") {
            return said("not written, or not said", &e);
        }
        None
    };
    // Two at a time (two cores); each case writes under its own names.
    let queue = std::sync::Mutex::new(cases.iter());
    let failures: Vec<String> = std::thread::scope(|s| {
        let workers: Vec<_> = (0..2)
            .map(|_| {
                s.spawn(|| {
                    let mut bad = Vec::new();
                    // The lock released before the case runs.
                    let next = || queue.lock().unwrap().next();
                    while let Some(c) = next() {
                        bad.extend(check(c));
                    }
                    bad
                })
            })
            .collect();
        workers
            .into_iter()
            .flat_map(|w| w.join().unwrap())
            .collect()
    });
    let _ = fs::remove_dir_all(&d);
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}
