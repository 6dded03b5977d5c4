//! Every command's JSON against golden files made before the library core was moved out
//! of the binary (`tests/golden/json`): the same numbers to a relative 1e-9. Fields may
//! be added; none may be lost. `UPDATE_GOLDEN=1` rewrites the files after a deliberate
//! change (say why in the changelog).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

fn golden_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden/json")
}

/// Where `expected` and `actual` differ, as paths with the two values.
fn differences(expected: &Value, actual: &Value, path: &str, out: &mut Vec<String>) {
    match (expected, actual) {
        (Value::Object(e), Value::Object(a)) => {
            for (k, ev) in e {
                match a.get(k) {
                    Some(av) => differences(ev, av, &format!("{path}.{k}"), out),
                    None => out.push(format!("{path}.{k}: missing")),
                }
            }
        }
        (Value::Array(e), Value::Array(a)) => {
            if e.len() != a.len() {
                out.push(format!("{path}: length {} != {}", a.len(), e.len()));
            }
            for (i, (ev, av)) in e.iter().zip(a).enumerate() {
                differences(ev, av, &format!("{path}[{i}]"), out);
            }
        }
        (Value::Number(e), Value::Number(a)) => {
            let (e, a) = (e.as_f64().unwrap(), a.as_f64().unwrap());
            let scale = e.abs().max(a.abs());
            if (e - a).abs() > 1e-9 * scale {
                out.push(format!("{path}: {a} != {e} (golden)"));
            }
        }
        (e, a) => {
            if e != a {
                out.push(format!("{path}: {a} != {e} (golden)"));
            }
        }
    }
}

fn check(name: &str, args: &[&str]) {
    let dir = golden_dir();
    let args: Vec<String> = args
        .iter()
        .map(|a| a.replace("@G", dir.to_str().unwrap()))
        .collect();
    let o = Command::new(env!("CARGO_BIN_EXE_cellinject"))
        .args(&args)
        .env(
            "XDG_CACHE_HOME",
            std::env::temp_dir().join(format!("cellinject-golden-cache-{}", std::process::id())),
        )
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let actual: Value = serde_json::from_slice(&o.stdout).unwrap();
    let path = dir.join(format!("{name}.json"));
    if std::env::var_os("UPDATE_GOLDEN").is_some() {
        std::fs::write(&path, serde_json::to_string_pretty(&actual).unwrap() + "\n").unwrap();
        return;
    }
    let expected: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let mut diff = Vec::new();
    differences(&expected, &actual, name, &mut diff);
    assert!(
        diff.is_empty(),
        "{name}: {} differences:\n{}",
        diff.len(),
        diff.join("\n")
    );
}

#[test]
fn tension_json_is_unchanged() {
    check(
        "tension-1",
        &["tension", "--approach", "1", "--format", "json"],
    );
    check(
        "tension-2",
        &["tension", "--approach", "2", "--format", "json"],
    );
}

#[test]
fn model_json_is_unchanged() {
    check("model", &["model", "--format", "json"]);
}

#[test]
fn reproduce_json_is_unchanged() {
    let out = std::env::temp_dir().join(format!("cellinject-golden-rep-{}", std::process::id()));
    check(
        "reproduce",
        &[
            "reproduce",
            "--format",
            "json",
            "--out",
            out.to_str().unwrap(),
        ],
    );
    let _ = std::fs::remove_dir_all(out);
}

#[test]
fn fea_json_is_unchanged() {
    check("fea-tables", &["fea", "tables", "--format", "json"]);
    check(
        "fea-solve",
        &[
            "fea",
            "--approach",
            "1",
            "--forces=-100,-100",
            "--format",
            "json",
        ],
    );
}

#[test]
fn hinge_json_is_unchanged() {
    check(
        "hinge-circular",
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
            "--angle",
            "0.01",
            "--format",
            "json",
        ],
    );
    check(
        "hinge-corner-fem",
        &[
            "hinge",
            "--profile",
            "corner",
            "--thickness",
            "0.5e-3",
            "--radius",
            "1e-3",
            "--width",
            "4e-3",
            "--length",
            "6e-3",
            "--method",
            "fem",
            "--format",
            "json",
        ],
    );
}

#[test]
fn dic_json_on_a_fixed_image_pair_is_unchanged() {
    check(
        "dic-points",
        &[
            "dic",
            "--reference",
            "@G/dic-reference.png",
            "--current",
            "@G/dic-current.png",
            "--at",
            "64,64",
            "--at",
            "40,90",
            "--at",
            "100,30",
            "--format",
            "json",
        ],
    );
}

#[test]
fn the_comparison_catches_a_changed_or_lost_number() {
    let golden: Value = serde_json::json!({"a": [1.0, 2.0], "b": {"c": 3.0}});
    let mut d = Vec::new();
    differences(
        &golden,
        &serde_json::json!({"a": [1.0, 2.0], "b": {"c": 3.0, "new": 1}}),
        "",
        &mut d,
    );
    assert!(d.is_empty(), "{d:?}");
    differences(
        &golden,
        &serde_json::json!({"a": [1.0, 2.0 + 1e-8], "b": {}}),
        "",
        &mut d,
    );
    assert_eq!(d.len(), 2, "{d:?}");
}
