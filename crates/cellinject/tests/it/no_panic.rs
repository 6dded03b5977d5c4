//! No panic reaches a user: every subcommand (found from `--help`, so a new one is
//! covered at once) runs with each of its options set, in turn, to values drawn from
//! the option's domain and its edges (negative, zero, NaN, infinities, garbage, paths
//! that collide or do not exist). Every run must end with exit code 0, 1 or 2, print no
//! panic or backtrace, and, with `--format json` and exit 0, print one JSON document.
//! Costly settings are bounded by their own value lists, and each run has a timeout.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

pub(crate) fn bin(dir: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_cellinject"));
    c.current_dir(dir)
        .env("XDG_CACHE_HOME", dir.join("cache"))
        .env_remove("RUST_BACKTRACE")
        .stdin(Stdio::null());
    c
}

fn help(dir: &Path, path: &[String]) -> String {
    let o = bin(dir).args(path).arg("--help").output().unwrap();
    assert!(o.status.success(), "{path:?} --help");
    String::from_utf8(o.stdout).unwrap()
}

/// Every command path (`["dic", "field"]`, ...), from the help texts run in `dir`,
/// sorted: a new command is found at once.
pub(crate) fn command_paths(dir: &Path) -> Vec<Vec<String>> {
    let mut paths: Vec<Vec<String>> = Vec::new();
    let mut todo: Vec<Vec<String>> = vec![Vec::new()];
    while let Some(p) = todo.pop() {
        let subs = subcommands(&help(dir, &p));
        if !p.is_empty() {
            paths.push(p.clone());
        }
        for s in subs {
            let mut q = p.clone();
            q.push(s);
            todo.push(q);
        }
    }
    paths.sort();
    paths
}

/// Subcommand names of a help text ("Commands:" section, `help` left out).
fn subcommands(help: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut inside = false;
    for l in help.lines() {
        if l.starts_with("Commands:") {
            inside = true;
            continue;
        }
        if inside {
            if !l.starts_with("  ") {
                break;
            }
            let name = l.split_whitespace().next().unwrap_or("");
            if !name.is_empty() && name != "help" {
                out.push(name.to_string());
            }
        }
    }
    out
}

/// An option of a help text: its long name, whether it takes a value, its documented
/// default (`[default: X]`) and its possible values if clap lists them.
#[derive(Debug, Clone)]
struct Opt {
    name: String,
    takes_value: bool,
    default: Option<String>,
    possible: Vec<String>,
}

fn options(help: &str) -> Vec<Opt> {
    let lines: Vec<&str> = help.lines().collect();
    let mut out: Vec<Opt> = Vec::new();
    for (i, l) in lines.iter().enumerate() {
        let t = l.trim_start();
        let t = t
            .strip_prefix("-h, ")
            .or_else(|| t.strip_prefix("-V, "))
            .unwrap_or(t);
        let Some(rest) = t.strip_prefix("--") else {
            continue;
        };
        let name: String = rest
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '-')
            .collect();
        if name.is_empty() || name == "help" || name == "version" {
            continue;
        }
        let takes_value = rest[name.len()..].trim_start().starts_with('<');
        // "[possible values: a, b]" may follow within the option's description.
        let mut possible = Vec::new();
        let mut default = None;
        for d in lines.iter().skip(i + 1).take(8) {
            if d.trim_start().starts_with("--") {
                break;
            }
            if let Some(v) = d.split("[default: ").nth(1) {
                default = v.split(']').next().map(|v| v.to_string());
            }
            if let Some(p) = d.split("[possible values: ").nth(1) {
                possible = p
                    .trim_end_matches(']')
                    .split(", ")
                    .map(|s| s.to_string())
                    .collect();
            }
        }
        out.push(Opt {
            name,
            takes_value,
            default,
            possible,
        });
    }
    out
}

/// Values tried for an option: bounded lists for the options that set how much work
/// is done, file paths for the file options, else the edges of a number's domain.
fn values(opt: &Opt) -> Vec<String> {
    let v = |xs: &[&str]| xs.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let mut out = match opt.name.as_str() {
        "level" => v(&["0", "1", "4", "x", "nan"]),
        "levels" => v(&["0", "1", "4", "1,4", "x", ""]),
        "duration" => v(&["0", "-1", "nan", "inf", "0.02", "1e9"]),
        // dic synth's WIDTH,HEIGHT and hysteresis fit's grid size share the name.
        "size" => v(&["0,0", "16,16", "a,b", "-16,16", "16", "1e9,1e9", "1", "61"]),
        "count" => v(&["0", "1", "1000", "-1"]),
        "step" => v(&["0", "64", "-1", "x", "1e300"]),
        "subset" => v(&["0", "7", "9999", "x", "-31"]),
        "search" => v(&["0", "1", "100000", "-5"]),
        "amplitude" => v(&["0", "-5", "nan", "inf", "1e9", "5"]),
        "seed" => v(&["0", "18446744073709551615", "-1", "x"]),
        "samples" => v(&["200", "100", "1e9", "-1", "x"]),
        "runs" => v(&["0", "1", "2", "-1", "x", "1e9"]),
        "hold" | "sweep" | "dwell" | "rest" => v(&["0", "-1", "nan", "inf", "0.6", "1e9"]),
        "repeats" => v(&["0", "1", "51", "-1", "x"]),
        "calibration" => v(&["", "missing", "cal", "r.png", ".", "bad-cal"]),
        "pixels" => v(&["", "missing.json", "cal/pixels.json", "m0.json", "r.png"]),
        "data" | "model" | "trajectory" => v(&[
            "",
            "missing.csv",
            "r.png",
            "bad.toml",
            "ident.csv",
            "m0.json",
            "desired.csv",
            "far.csv",
        ]),
        "config" => v(&["missing.toml", "bad.toml", "r.png"]),
        "plate" => v(&["", "missing.toml", "bad.toml", "r.png", "plate.toml", "."]),
        "dose" => v(&["0.05", "0", "-1", "nan", "0.5", "x"]),
        "fault" => v(&[
            "clog@0,0",
            "break@0,1",
            "stall@1,0,1",
            "melt@1,0",
            "clog@99,0",
            "clog@3",
            "x",
        ]),
        "db" => v(&["", "r.png", "nr.sqlite", "no/dir/x.sqlite", "."]),
        "run" => v(&["1", "0", "-1", "99", "x"]),
        "origin" => v(&["0,0", "-1e-3,2e-3", "1", "nan,0", "1e300,0", "x"]),
        "rows" | "cols" => v(&["0", "1", "1001", "-1", "x", "3"]),
        "frames" => v(&["", "missing", "frames/*.png", "frames/*.tif", "r.png"]),
        "image" => v(&["", "missing.png", "r.png", "bad.toml", "."]),
        "pixel-size" => v(&["0.2e-6", "0", "-1e-6", "nan", "inf", "x"]),
        "diameter" => v(&["10e-6,30e-6", "30e-6,10e-6", "0,1", "nan,1", "1", "x"]),
        "out" | "reference" | "current" | "plot" | "export-mesh" => v(&[
            "",
            "r.png",
            "no/dir/x.csv",
            "x.jpg",
            ".",
            "out.svg",
            "out.png",
            "out.csv",
            "out.json",
        ]),
        "at" => v(&["32,32", "-5,-5", "1e9,0", "1e300,1e300", "nan,1", "1", ""]),
        "roi" => v(&["16,16,33,33", "0,0,0,0", "60,60,33,33", "1,2", "-1,0,5,5"]),
        "volts" => v(&["1,2,3", "-1,0,0", "nan,0,0", "1,2", "200,0,0"]),
        "forces" => v(&["0,0", "-100,-100", "5,-5", "-1e9,0", "nan,0", "x"]),
        "shift" => v(&["0,0", "-0.4,0.25", "1e9,0", "nan,0", "x"]),
        "backend" => v(&[
            "twin",
            "gcs://127.0.0.1:1",
            "gcs-serial:///dev/null",
            "gcs://",
            "x",
        ]),
        "bench" | "allowed-host" => v(&["127.0.0.1:1", "none", "x", ""]),
        "bind" => v(&["127.0.0.1:0", "nonsense", "127.0.0.1:99999", ""]),
        "serve-for" => v(&["0.2", "0", "-1", "nan", "inf", "x"]),
        "camera" | "side-camera" => v(&["", "missing", "frames", "r.png", "aravis:X"]),
        // Design studies: bounded work (a population of 100000 would run for hours).
        "population" => v(&["0", "3", "4", "5", "-1", "x"]),
        "generations" => v(&["0", "1", "2", "-1", "x"]),
        "space" => v(&[
            "",
            "missing.toml",
            "bad.toml",
            "r.png",
            "space.toml",
            "nan-space.toml",
        ]),
        "batch" => v(&["", "missing.jsonl", "r.png", "designs.jsonl", "nan.jsonl"]),
        "shard" => v(&["0/1", "1/2", "2/2", "0/0", "x", "-1/2", "1e300/2"]),
        _ => v(&["-1", "0", "1e-300", "1e300", "nan", "inf", "-inf", "abc"]),
    };
    out.extend(opt.possible.iter().cloned());
    out.push("x".into());
    out
}

/// [`values`] for option `opt` of command `path`: where every accepted value means
/// the same costly work (each directory `calibrate all` accepts is a whole calibration
/// of the twin, 9 s of a test build), the refused values and one accepted.
fn values_for(path: &[String], opt: &Opt) -> Vec<String> {
    let p: Vec<&str> = path.iter().map(|s| s.as_str()).collect();
    match (p.as_slice(), opt.name.as_str()) {
        (["calibrate", "all"], "out") => ["", "r.png", "no/dir/x.csv"]
            .iter()
            .map(|s| s.to_string())
            .collect(),
        _ => values(opt),
    }
}

/// A valid, cheap invocation of each command (the options under test replace these).
pub(crate) fn baseline(path: &[String]) -> Vec<&'static str> {
    let p: Vec<&str> = path.iter().map(|s| s.as_str()).collect();
    match p.as_slice() {
        ["tension"] => vec!["--approach", "1"],
        ["hinge"] => vec![
            "--profile",
            "circular",
            "--thickness",
            "1e-3",
            "--radius",
            "2e-3",
            "--width",
            "5e-3",
        ],
        ["fea"] => vec!["--approach", "1", "--forces", "-100,-100"],
        ["fea", "joints"] => vec!["--levels", "1"],
        ["dic"] => vec![
            "--reference",
            "r.png",
            "--current",
            "c.png",
            "--at",
            "32,32",
        ],
        ["dic", "field"] => vec![
            "--reference",
            "r.png",
            "--current",
            "c.png",
            "--out",
            "f.csv",
            "--step",
            "8",
        ],
        ["dic", "synth"] => vec![
            "--size",
            "64,64",
            "--reference",
            "s1.png",
            "--current",
            "s2.png",
        ],
        ["dic", "track"] => vec![
            "--frames",
            "frames",
            "--roi",
            "16,16,33,33",
            "--out",
            "t.csv",
        ],
        ["sim", "loop"] => vec!["--amplitude", "5", "--out", "l.csv"],
        ["sim", "step"] => vec!["--voltage", "5", "--duration", "0.01", "--out", "s.csv"],
        ["sim", "frame"] => vec!["--vga", "--out", "fr.png"],
        ["reproduce"] => vec!["--out", "rep"],
        ["hysteresis", "identify"] => vec!["--samples", "300", "--out", "id.csv"],
        ["experiment", "range"] => vec!["--calibration", "cal", "--sweep", "0.5", "--out", "ex"],
        ["experiment", "repeatability"] => vec![
            "--calibration",
            "cal",
            "--runs",
            "2",
            "--hold",
            "0.2",
            "--out",
            "ex",
        ],
        ["experiment", "tracking"] => vec![
            "--calibration",
            "cal",
            "--dwell",
            "0.1",
            "--duration",
            "0.2",
            "--out",
            "ex",
        ],
        ["calibrate", "pixels"] => vec!["--out", "px.json"],
        ["calibrate", "jacobian"] => vec!["--pixels", "cal/pixels.json", "--out", "jac.json"],
        ["calibrate", "hysteresis"] => vec!["--samples", "2000", "--out", "hy.json"],
        ["calibrate", "all"] => vec!["--out", "cal2"],
        ["hysteresis", "fit"] => vec!["--data", "ident.csv", "--size", "6", "--out", "m.json"],
        ["hysteresis", "invert"] => vec![
            "--model",
            "m0.json",
            "--trajectory",
            "desired.csv",
            "--out",
            "cmd.csv",
        ],
        ["plate", "generate"] => vec!["--out", "p.toml"],
        ["design", "evaluate"] => vec![],
        // In the default build these say how to get GenICam support (exit 2).
        ["camera", "info"] => vec!["--camera", "aravis:X", "--timeout", "1"],
        ["camera", "grab"] => vec!["--camera", "aravis:X", "--out", "g.tif", "--timeout", "1"],
        ["design", "merge"] => vec!["--out", "m.jsonl", "r0.jsonl"],
        ["design", "optimise"] => vec![
            "--space",
            "space.toml",
            "--population",
            "4",
            "--generations",
            "2",
            "--out",
            "study",
        ],
        ["plate", "check"] => vec!["--plate", "plate.toml"],
        ["vision", "cells"] => vec!["--image", "r.png"],
        ["plate", "detect"] => vec!["--plate", "plate.toml"],
        ["sim", "tip"] => vec!["--runs", "2"],
        ["run"] => vec![
            "--plate",
            "plate.toml",
            "--calibration",
            "cal/hysteresis.json",
            "--db",
            "nr.sqlite",
        ],
        ["runs", "show"] | ["runs", "list"] | ["runs", "export"] => vec!["--db", "nr.sqlite"],
        ["emulate", "gcs"] => vec!["--bind", "127.0.0.1:0", "--serve-for", "0.3"],
        // A group of its own (UDP 55564): the Python suite's emulator takes the first
        // free one from 0.
        ["emulate", "sensapex"] => vec!["--group", "9", "--serve-for", "0.3"],
        ["serve"] => vec![
            "--bind",
            "127.0.0.1:0",
            "--serve-for",
            "0.3",
            "--db",
            "nr.sqlite",
        ],
        _ => vec![],
    }
}

/// `base` with option `name` set to `value` (replacing it if present).
fn with(base: &[&str], name: &str, value: Option<&str>) -> Vec<String> {
    let flag = format!("--{name}");
    let mut out = Vec::new();
    let mut skip = false;
    for (i, a) in base.iter().enumerate() {
        if skip {
            skip = false;
            continue;
        }
        if *a == flag {
            // The baselines give every valued option its value as the next word.
            skip = base.get(i + 1).is_some_and(|v| !v.starts_with("--"));
            continue;
        }
        out.push(a.to_string());
    }
    out.push(flag);
    if let Some(v) = value {
        out.push(v.to_string());
    }
    out
}

/// What an argument list asks for: its options and their values, in no order, less
/// those set to their documented default.
fn meaning(
    args: &[String],
    defaults: &BTreeMap<String, String>,
) -> BTreeSet<(String, Option<String>)> {
    let mut out = BTreeSet::new();
    let mut i = 0;
    while i < args.len() {
        let a = &args[i];
        let value = args.get(i + 1).filter(|v| !v.starts_with("--")).cloned();
        i += if value.is_some() { 2 } else { 1 };
        if value.is_some() && defaults.get(a) == value.as_ref() {
            continue;
        }
        out.insert((a.clone(), value));
    }
    out
}

struct Run {
    args: Vec<String>,
    code: Option<i32>,
    stdout: String,
    stderr: String,
    timed_out: bool,
}

fn run(dir: &Path, args: &[String], limit: Duration) -> Run {
    let mut child = bin(dir)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Read the pipes on threads so that a chatty child cannot block on a full pipe.
    let mut so = child.stdout.take().unwrap();
    let mut se = child.stderr.take().unwrap();
    let ho = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = std::io::Read::read_to_string(&mut so, &mut s);
        s
    });
    let he = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = std::io::Read::read_to_string(&mut se, &mut s);
        s
    });
    let start = Instant::now();
    let mut timed_out = false;
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > limit {
            timed_out = true;
            let _ = child.kill();
            break child.wait().unwrap();
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    Run {
        args: args.to_vec(),
        code: status.code(),
        stdout: ho.join().unwrap(),
        stderr: he.join().unwrap(),
        timed_out,
    }
}

pub(crate) fn setup(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("cellinject-{tag}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(dir.join("frames")).unwrap();
    fs::write(dir.join("bad.toml"), "name = ").unwrap();
    fs::write(
        dir.join("space.toml"),
        "[variables]\n\"geometry.b2\" = [0.12, 0.24]\n[objectives]\nmaximise = [\"range_min_m\"]\n",
    )
    .unwrap();
    fs::write(
        dir.join("nan-space.toml"),
        "[variables]\n\"geometry.b2\" = [nan, 0.24]\n[objectives]\nmaximise = [\"range_min_m\"]\n",
    )
    .unwrap();
    fs::write(
        dir.join("designs.jsonl"),
        "{\"variables\": {\"geometry.b2\": 0.2}}\n{\"variables\": {\"geometry.b2\": 1e300}}\n",
    )
    .unwrap();
    fs::write(
        dir.join("nan.jsonl"),
        "{\"variables\": {\"geometry.b2\": NaN}}\n",
    )
    .unwrap();
    fs::write(
        dir.join("r0.jsonl"),
        "{\"index\":0,\"variables\":{},\"error\":\"x\"}\n",
    )
    .unwrap();
    fs::write(
        dir.join("plate.toml"),
        "[plate]\nrows = 2\ncols = 2\npitch = 150e-6\n[[cell]]\nwell = [1, 1]\noffset = [0.0, 0.0]\ndiameter = 20e-6\n",
    )
    .unwrap();
    let o = bin(&dir)
        .args(["dic", "synth", "--size", "64,64", "--shift", "0.3,-0.2"])
        .args(["--reference", "r.png", "--current", "c.png"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for (f, to) in [("r.png", "frames/0.png"), ("c.png", "frames/1.png")] {
        fs::copy(dir.join(f), dir.join(to)).unwrap();
    }
    // Hysteresis data, a model and trajectories (one out of reach).
    for args in [
        vec![
            "hysteresis",
            "identify",
            "--samples",
            "600",
            "--out",
            "ident.csv",
        ],
        vec![
            "hysteresis",
            "fit",
            "--data",
            "ident.csv",
            "--size",
            "8",
            "--out",
            "m0.json",
        ],
    ] {
        let o = bin(&dir).args(&args).output().unwrap();
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    let traj = |scale: f64| {
        let mut s = String::from("time_s,displacement_m\n");
        for k in 0..50 {
            s += &format!(
                "{},{}\n",
                k as f64 * 1e-3,
                scale * (5.0 + 0.1 * k as f64) * 1e-6
            );
        }
        s
    };
    // Calibrations for the experiments (and a directory whose files are not JSON).
    let o = bin(&dir)
        .args(["calibrate", "all", "--out", "cal"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    fs::create_dir_all(dir.join("bad-cal")).unwrap();
    for f in ["pixels.json", "jacobian.json", "hysteresis.json"] {
        fs::write(dir.join("bad-cal").join(f), "{").unwrap();
    }
    fs::write(dir.join("desired.csv"), traj(1.0)).unwrap();
    fs::write(dir.join("far.csv"), traj(100.0)).unwrap();
    dir
}

#[test]
fn no_argument_list_makes_any_command_panic() {
    let dir = setup("nopanic");
    let paths = command_paths(&dir);
    assert!(paths.len() >= 16, "{paths:?}");
    let mut cases: Vec<Vec<String>> = Vec::new();
    let mut per_command: BTreeMap<String, usize> = BTreeMap::new();
    for p in &paths {
        let before = cases.len();
        let base = baseline(p);
        let mut start = p.clone();
        start.extend(base.iter().map(|s| s.to_string()));
        let opts = options(&help(&dir, p));
        // An argument list that means what another one of this command means (the same
        // options in another order, or an option set to its documented default) is run
        // once: a whole run on the twin costs tens of seconds of CI.
        let defaults: BTreeMap<String, String> = opts
            .iter()
            .filter_map(|o| Some((format!("--{}", o.name), o.default.clone()?)))
            .collect();
        let mut seen = BTreeSet::new();
        seen.insert(meaning(&start[p.len()..], &defaults));
        cases.push(start);
        for o in opts {
            // `--force` only decides what happens to an output file in the way: where
            // the baseline writes none, it means the baseline (`files.rs` tests it).
            if o.name == "force" && !base.contains(&"--out") {
                continue;
            }
            let vals: Vec<Option<String>> = if o.takes_value {
                values_for(p, &o).into_iter().map(Some).collect()
            } else {
                vec![None]
            };
            for v in vals {
                let mut args = p.clone();
                args.extend(with(&base, &o.name, v.as_deref()));
                if seen.insert(meaning(&args[p.len()..], &defaults)) {
                    cases.push(args);
                }
            }
        }
        per_command.insert(p.join(" "), cases.len() - before);
    }
    eprintln!(
        "{} argument lists over {} commands: {per_command:?}",
        cases.len(),
        paths.len()
    );
    // Two at a time (the machine has two cores).
    let queue = Arc::new(Mutex::new(cases));
    let failures = Arc::new(Mutex::new(Vec::<String>::new()));
    // Each case's wall time, for the slowest list printed at the end (--nocapture).
    let times = Arc::new(Mutex::new(Vec::<(Duration, String)>::new()));
    let workers: Vec<_> = (0..2)
        .map(|_| {
            let (queue, failures, dir) = (queue.clone(), failures.clone(), dir.clone());
            let times = times.clone();
            std::thread::spawn(move || {
                loop {
                    let Some(args) = queue.lock().unwrap().pop() else {
                        break;
                    };
                    // A hang, not a slow machine: a whole run on the twin takes some
                    // 30 s of a debug build alone, minutes on a loaded machine.
                    let t0 = Instant::now();
                    let r = run(&dir, &args, Duration::from_secs(300));
                    times.lock().unwrap().push((t0.elapsed(), args.join(" ")));
                    let mut bad = Vec::new();
                    if r.timed_out {
                        bad.push("timed out after 300 s".to_string());
                    }
                    if !matches!(r.code, Some(0..=2)) && !r.timed_out {
                        bad.push(format!("exit code {:?}", r.code));
                    }
                    if r.stderr.contains("panicked") || r.stderr.contains("RUST_BACKTRACE") {
                        bad.push("a panic".into());
                    }
                    // No result is printed as a non-finite number.
                    let non_finite = r
                        .stdout
                        .split(|c: char| c.is_whitespace() || ",;:()[]{}=\"".contains(c))
                        .any(|t| matches!(t, "NaN" | "nan" | "inf" | "-inf" | "Infinity"));
                    if non_finite {
                        bad.push("a non-finite number on standard output".into());
                    }
                    let json = r
                        .args
                        .windows(2)
                        .any(|w| w[0] == "--format" && w[1] == "json");
                    if json
                        && r.code == Some(0)
                        && serde_json::from_str::<serde_json::Value>(&r.stdout).is_err()
                    {
                        bad.push("standard output is not one JSON document".into());
                    }
                    if !bad.is_empty() {
                        failures.lock().unwrap().push(format!(
                            "cellinject {}: {}\n{}",
                            r.args.join(" "),
                            bad.join(", "),
                            r.stderr.lines().take(4).collect::<Vec<_>>().join("\n")
                        ));
                    }
                }
            })
        })
        .collect();
    for w in workers {
        w.join().unwrap();
    }
    let mut t = times.lock().unwrap();
    t.sort_by_key(|x| std::cmp::Reverse(x.0));
    let total: Duration = t.iter().map(|x| x.0).sum();
    eprintln!("{:.1} s of commands; the slowest:", total.as_secs_f64());
    for (d, a) in t.iter().take(15) {
        eprintln!("  {:6.2} s  cellinject {a}", d.as_secs_f64());
    }
    let f = failures.lock().unwrap();
    let _ = fs::remove_dir_all(&dir);
    assert!(f.is_empty(), "{} failures:\n{}", f.len(), f.join("\n\n"));
}

#[test]
fn a_closed_pipe_ends_every_printing_command_quietly() {
    let dir = setup("closedpipe");
    for args in [
        vec!["reproduce", "--out", "rep"],
        vec!["tension", "--approach", "1"],
        vec!["design", "evaluate", "--format", "json"],
        vec!["model", "--format", "json"],
        vec!["hinge-table"],
        vec!["vision", "cells", "--image", "r.png"],
        vec![
            "experiment",
            "repeatability",
            "--calibration",
            "cal",
            "--runs",
            "2",
            "--hold",
            "0.2",
            "--out",
            "ex",
        ],
    ] {
        let mut child = bin(&dir)
            .args(&args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // Close the reading end at once, like `| head -0`.
        drop(child.stdout.take());
        let o = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            matches!(o.status.code(), Some(0)),
            "{args:?}: {:?}\n{err}",
            o.status
        );
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
    let _ = fs::remove_dir_all(&dir);
}

#[test]
fn every_help_has_an_example_and_the_usage_marks_required_options() {
    let dir = std::env::temp_dir().join(format!("cellinject-helps-{}", std::process::id()));
    fs::create_dir_all(&dir).unwrap();
    let mut todo: Vec<Vec<String>> = vec![Vec::new()];
    let mut seen = 0;
    while let Some(p) = todo.pop() {
        let h = help(&dir, &p);
        seen += 1;
        assert!(
            h.contains("Examples:\n  cellinject"),
            "{p:?} has no example:\n{h}"
        );
        for s in subcommands(&h) {
            let mut q = p.clone();
            q.push(s);
            todo.push(q);
        }
    }
    assert!(seen >= 17, "{seen}");
    for (path, required) in [
        (
            vec!["fea"],
            vec!["--approach <APPROACH>", "--forces <F11,F12>"],
        ),
        (
            vec!["dic"],
            vec!["--reference <FILE>", "--current <FILE>", "--at <X,Y>"],
        ),
        (
            vec!["hinge"],
            vec!["--profile <PROFILE>", "--thickness <THICKNESS>"],
        ),
        (vec!["sim", "step"], vec!["--voltage <VOLTAGE>"]),
    ] {
        let p: Vec<String> = path.iter().map(|s| s.to_string()).collect();
        let h = help(&dir, &p);
        let usage = h.lines().find(|l| l.starts_with("Usage:")).unwrap();
        for r in required {
            assert!(usage.contains(r), "{path:?}: {usage}");
        }
    }
    let _ = fs::remove_dir_all(&dir);
}
