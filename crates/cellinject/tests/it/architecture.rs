//! The dependency rules of ARCHITECTURE.md, checked over `cargo metadata` (after
//! rust-analyzer's `tidy`): a rule written down is a rule a test enforces.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::{BTreeMap, BTreeSet};
use std::process::Command;

use serde_json::Value;

/// The workspace's packages: name → (has a library target, [(dependency, kind)]).
type Packages = BTreeMap<String, (bool, Vec<(String, String)>)>;

fn packages() -> Packages {
    let o = Command::new(env!("CARGO"))
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo metadata");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    v["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let lib = p["targets"]
                .as_array()
                .unwrap()
                .iter()
                .any(|t| t["kind"].as_array().unwrap().iter().any(|k| k == "lib"));
            let deps = p["dependencies"]
                .as_array()
                .unwrap()
                .iter()
                .map(|d| {
                    (
                        d["name"].as_str().unwrap().to_string(),
                        d["kind"].as_str().unwrap_or("normal").to_string(),
                    )
                })
                .collect();
            (p["name"].as_str().unwrap().to_string(), (lib, deps))
        })
        .collect()
}

/// Every package `name` depends on through normal and build dependencies, within and
/// beyond the workspace (external crates as leaves).
fn closure(all: &Packages, name: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut stack = vec![name.to_string()];
    while let Some(n) = stack.pop() {
        if let Some((_, deps)) = all.get(&n) {
            for (d, kind) in deps {
                if kind != "dev" && seen.insert(d.clone()) {
                    stack.push(d.clone());
                }
            }
        }
    }
    seen
}

const TWIN: &str = "cellinject-twin";

/// The front ends: the binary and the Python bindings.
const FRONT_ENDS: [&str; 2] = ["cellinject", "cellinject-python"];

/// Crates allowed to depend on the twin: the front ends, those whose names say they
/// simulate or emulate, the session library that opens whichever bench a rig names
/// for the front ends (the twin one driver among the others), and the station that
/// serves that bench to the dashboard (the twin's scene as its live view).
fn may_use_the_twin(name: &str) -> bool {
    FRONT_ENDS.contains(&name)
        || name.contains("-sim")
        || name.contains("emul")
        || name == "cellinject-session"
        || name == "cellinject-station"
}

#[test]
fn the_twin_is_its_own_crate_and_only_simulators_depend_on_it() {
    let all = packages();
    assert!(
        all.contains_key(TWIN),
        "the twin must stay the crate `{TWIN}`"
    );
    for name in all.keys() {
        if name == TWIN || may_use_the_twin(name) {
            continue;
        }
        // Dev-dependencies included: a model crate's tests must not need the twin either.
        let direct_dev = all[name].1.iter().any(|(d, _)| d == TWIN);
        assert!(
            !closure(&all, name).contains(TWIN) && !direct_dev,
            "{name} depends on {TWIN}: only the binary and simulator/emulator crates may"
        );
    }
    // The crates the issue names explicitly, so that a rename cannot dodge the rule.
    for name in [
        "cellinject-model",
        "cellinject-flexure",
        "cellinject-fem",
        "cellinject-structure",
        "cellinject-dic",
        "cellinject-config",
        "cellinject-hw",
        "cellinject-rig",
        "cellinject-core",
        "cellinject-fea",
        "cellinject-hysteresis",
        "cellinject-control",
        // The GCS driver is tested against the emulator, which does use the twin.
        "cellinject-gcs",
        // The dashboard runs any backend the front end hands it.
        "cellinject-dashboard",
    ] {
        assert!(all.contains_key(name), "{name} is missing");
        assert!(
            !closure(&all, name).contains(TWIN),
            "{name} depends on {TWIN}"
        );
    }
}

#[test]
fn no_library_crate_depends_on_clap_or_anyhow() {
    let all = packages();
    for (name, (lib, deps)) in &all {
        if !lib {
            continue;
        }
        for (d, kind) in deps {
            assert!(
                kind == "dev" || (d != "clap" && d != "anyhow"),
                "library crate {name} depends on {d}: argument parsing and anyhow belong in the binary"
            );
        }
    }
}

/// At most one crate depends on `dep`, and its name contains `home`.
fn only_in(all: &Packages, dep: &str, home: &str) {
    let users: Vec<&String> = all
        .iter()
        .filter(|(_, (_, deps))| deps.iter().any(|(d, k)| d == dep && k != "dev"))
        .map(|(n, _)| n)
        .collect();
    assert!(
        users.len() <= 1,
        "{dep} is used by {users:?}: one crate only"
    );
    for u in users {
        assert!(
            u.contains(home),
            "{dep} is used by {u}, not by the {home} crate"
        );
    }
}

#[test]
fn heavy_dependencies_stay_in_their_one_crate() {
    let all = packages();
    only_in(&all, "faer", "fem");
    only_in(&all, "rusqlite", "records");
    only_in(&all, "serialport", "gcs");
    only_in(&all, "axum", "dashboard");
    only_in(&all, "tokio", "dashboard");
    only_in(&all, "pyo3", "python");
    only_in(&all, "numpy", "python");
    only_in(&all, "aravis", "genicam");
    only_in(&all, "aravis-sys", "genicam");
    // The dashboard knows no driver and no database: the front end hands it a
    // station, a viewer and an archive.
    let c = closure(&all, "cellinject-dashboard");
    for bad in [
        "cellinject-gcs",
        "cellinject-records",
        "rusqlite",
        "serialport",
    ] {
        assert!(!c.contains(bad), "cellinject-dashboard depends on {bad}");
    }
}

#[test]
fn the_hardware_vocabulary_depends_on_nothing_of_ours() {
    let all = packages();
    let ours: Vec<&String> = all["cellinject-hw"]
        .1
        .iter()
        .map(|(d, _)| d)
        .filter(|d| d.starts_with("cellinject"))
        .collect();
    assert!(ours.is_empty(), "cellinject-hw depends on {ours:?}");
    // The pure computation crates know nothing of files, terminals or devices' crates.
    for name in [
        "cellinject-model",
        "cellinject-flexure",
        "cellinject-structure",
        "cellinject-numeric",
        "cellinject-simparams",
        "cellinject-hysteresis",
        "cellinject-control",
        "cellinject-plate",
        "cellinject-cells",
    ] {
        let c = closure(&all, name);
        for bad in [
            "cellinject-hw",
            "cellinject-rig",
            "cellinject-config",
            "toml",
        ] {
            assert!(!c.contains(bad), "{name} depends on {bad}");
        }
    }
}

#[test]
fn nothing_depends_on_a_front_end_and_the_bindings_use_libraries_only() {
    let all = packages();
    for fe in FRONT_ENDS {
        assert!(all.contains_key(fe), "{fe} is missing");
        for (name, (_, deps)) in &all {
            assert!(
                !deps.iter().any(|(d, _)| d == fe),
                "{name} depends on the front end {fe}: front ends are leaves"
            );
        }
    }
    // The Python bindings call the library crates, never the binary (whatever they
    // share with the CLI lives in a library), and add no CLI machinery.
    let c = closure(&all, "cellinject-python");
    for bad in ["cellinject", "clap", "anyhow", "indicatif"] {
        assert!(!c.contains(bad), "cellinject-python depends on {bad}");
    }
}

/// `cargo tree`'s features of every package reached through `edges` from the packages
/// `select` picks: "name version" → the sets of features it is built with.
fn features(select: &[&str], edges: &str) -> BTreeMap<String, BTreeSet<String>> {
    let o = Command::new(env!("CARGO"))
        .args(["tree", "--offline", "--locked", "--no-dedupe"])
        .args(["--prefix", "none", "-e", edges, "-f", "{p}|{f}"])
        .args(select)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo tree");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut out: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for line in String::from_utf8_lossy(&o.stdout).lines() {
        let Some((p, f)) = line.rsplit_once('|') else {
            continue;
        };
        let key = p.split_whitespace().take(2).collect::<Vec<_>>().join(" ");
        out.entry(key).or_default().insert(f.trim().to_string());
    }
    out
}

/// The shared dependencies that the build `select` resolves with other features than
/// `cargo test --workspace` does (target code; new host-only units compile once and
/// change nothing downstream), as readable lines.
fn feature_drift(select: &[&str], except: &[&str]) -> Vec<String> {
    let edges = "normal,dev,no-proc-macro";
    let ws = features(&["--workspace"], edges);
    features(select, edges)
        .into_iter()
        .filter(|(k, _)| !except.iter().any(|e| k.starts_with(&format!("{e} "))))
        .filter_map(|(k, f)| {
            let w = ws.get(&k)?;
            (w != &f).then(|| format!("{k}: here {f:?}, cargo test --workspace {w:?}"))
        })
        .collect()
}

/// maturin builds the Python extension alone, and CI's GenICam tests add a feature:
/// cargo would resolve the shared dependencies' features differently for either and
/// rebuild the whole graph (190 s and 150 s of CI). The pins in crates/python and
/// crates/genicam's Cargo.toml keep both on the test build's features; a new dependency
/// that breaks this is named here.
#[test]
fn the_wheel_and_the_genicam_build_reuse_the_test_builds_dependencies() {
    let wheel = feature_drift(&["-p", "cellinject-python"], &[]);
    assert!(
        wheel.is_empty(),
        "pin these in crates/python/Cargo.toml:\n{}",
        wheel.join("\n")
    );
    let genicam = feature_drift(
        &[
            "--workspace",
            "--features",
            "cellinject/genicam,cellinject-genicam/aravis",
        ],
        // The crates whose own feature it is (the session opens the GenICam cameras a
        // rig names); only the binary depends on them.
        &["cellinject", "cellinject-genicam", "cellinject-session"],
    );
    assert!(
        genicam.is_empty(),
        "pin these in crates/genicam/Cargo.toml:\n{}",
        genicam.join("\n")
    );
}

/// The crates of the diagram in ARCHITECTURE.md's bird's-eye view: package name →
/// (layer index from the top, the crates of ours it uses).
fn diagram() -> BTreeMap<String, (usize, BTreeSet<String>)> {
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../ARCHITECTURE.md"),
    )
    .unwrap();
    let view = &text[text
        .find("## Bird's-eye view")
        .expect("the bird's-eye view")..];
    let start = view.find("```\n").expect("the diagram's block") + 4;
    let block = &view[start..start + view[start..].find("```").expect("its end")];
    let package = |short: &str| match short {
        "cellinject" => "cellinject".to_string(),
        other => format!("cellinject-{other}"),
    };
    // Parentheses are comments: `(binary)`, `(never the twin)`.
    let uncommented = |line: &str| {
        let mut out = String::new();
        let mut depth = 0;
        for c in line.chars() {
            match c {
                '(' => depth += 1,
                ')' => depth -= 1,
                _ if depth == 0 => out.push(c),
                _ => {}
            }
        }
        out
    };
    let mut out = BTreeMap::new();
    let mut layer = 0;
    let mut seen_layer = false;
    for line in block.lines() {
        let body = if line.starts_with(' ') {
            line.trim()
        } else {
            // A layer's first line: its label, then two or more spaces.
            if seen_layer {
                layer += 1;
            }
            seen_layer = true;
            line.split_once("  ").map_or("", |(_, rest)| rest).trim()
        };
        if body.is_empty() || body == "│" {
            continue;
        }
        let leaves = body.contains("(no crates of ours)");
        let body = uncommented(body);
        let (nodes, deps): (Vec<&str>, BTreeSet<String>) = match body.split_once("─►") {
            Some((node, deps)) => (
                node.split_whitespace().collect(),
                deps.split_whitespace().map(package).collect(),
            ),
            None => {
                assert!(
                    leaves,
                    "a diagram line without ─► that is not `(no crates of ours)`: {line}"
                );
                (body.split_whitespace().collect(), BTreeSet::new())
            }
        };
        assert!(leaves || nodes.len() == 1, "one crate before ─►: {line}");
        for n in nodes {
            let prev = out.insert(package(n), (layer, deps.clone()));
            assert!(prev.is_none(), "{n} drawn twice in the diagram");
        }
    }
    out
}

/// ARCHITECTURE.md's diagram is `cargo metadata`'s graph: every crate of the
/// workspace, each with exactly the crates of ours it uses (normal and build
/// dependencies), none of them in a layer above its own.
#[test]
fn the_architecture_diagram_is_the_dependency_graph() {
    let all = packages();
    let drawn = diagram();
    let mut faults = Vec::new();
    for name in all.keys() {
        if !drawn.contains_key(name) {
            faults.push(format!("{name} is not in the diagram"));
        }
    }
    for (name, (layer, deps)) in &drawn {
        let Some((_, real)) = all.get(name) else {
            faults.push(format!("{name} is in the diagram but not in the workspace"));
            continue;
        };
        let real: BTreeSet<String> = real
            .iter()
            .filter(|(d, kind)| kind != "dev" && all.contains_key(d))
            .map(|(d, _)| d.clone())
            .collect();
        for d in real.difference(deps) {
            faults.push(format!("{name} uses {d}: missing from its line"));
        }
        for d in deps.difference(&real) {
            faults.push(format!("{name}'s line names {d}, which it does not use"));
        }
        for d in deps {
            if let Some((dl, _)) = drawn.get(d)
                && dl < layer
            {
                faults.push(format!("{name} uses {d}, a layer above it"));
            }
        }
    }
    assert!(
        faults.is_empty(),
        "ARCHITECTURE.md's diagram:\n{}",
        faults.join("\n")
    );
}
