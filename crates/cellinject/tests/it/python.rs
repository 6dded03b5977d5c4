//! The Python package's pytest suite (python/tests), run by the README's test command.
//!
//! It builds the wheel of `python/` with maturin once (the `dev` profile by default,
//! whose dependencies `cargo test` has just built; `CELLINJECT_WHEEL_PROFILE=release`
//! for the optimised one), or takes the one `CELLINJECT_WHEEL` names (`.ci/run` builds
//! it in a phase of its own, before the tests), installs it into the Python environment of
//! `CELLINJECT_PYTHON` (default `python3`) with pip, and runs pytest there with this
//! crate's `cellinject` binary (`CELLINJECT_BIN`) to compare against. The environment
//! needs maturin, numpy and pytest; `.ci/run` makes one and sets
//! `CELLINJECT_PYTEST=required`, so that in CI a missing one fails this test. Elsewhere,
//! without them, the test is skipped with a notice on standard error.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The Python to use, if it has maturin, numpy and pytest; else why not.
fn python() -> Result<String, String> {
    let py = std::env::var("CELLINJECT_PYTHON").unwrap_or_else(|_| "python3".into());
    let probe = Command::new(&py)
        .args([
            "-c",
            "import numpy, pytest, maturin, sys; assert sys.version_info >= (3, 9)",
        ])
        .output()
        .map_err(|e| format!("cannot run `{py}`: {e}"))?;
    if !probe.status.success() {
        return Err(format!(
            "`{py}` lacks maturin, numpy or pytest (pip install maturin numpy pytest; set CELLINJECT_PYTHON to that environment's python): {}",
            String::from_utf8_lossy(&probe.stderr).trim()
        ));
    }
    Ok(py)
}

fn run(c: &mut Command, what: &str) {
    let t = std::time::Instant::now();
    let o = c.output().unwrap_or_else(|e| panic!("{what}: {e}"));
    let out = String::from_utf8_lossy(&o.stdout);
    let err = String::from_utf8_lossy(&o.stderr);
    eprintln!("{what}: {:.1} s", t.elapsed().as_secs_f64());
    assert!(o.status.success(), "{what} failed:\n{out}\n{err}");
    print!("{out}");
}

#[test]
fn the_python_package_builds_installs_and_passes_its_pytest_suite() {
    let py = match python() {
        Ok(py) => py,
        Err(why) => {
            assert!(
                std::env::var("CELLINJECT_PYTEST").as_deref() != Ok("required"),
                "CELLINJECT_PYTEST=required but {why}"
            );
            eprintln!("skipped the Python package's tests: {why}");
            return;
        }
    };
    let root = root();
    let wheels = std::env::temp_dir().join(format!("cellinject-wheel-{}", std::process::id()));
    let wheel = match std::env::var_os("CELLINJECT_WHEEL") {
        Some(w) => {
            let w = PathBuf::from(w);
            assert!(
                w.is_file(),
                "CELLINJECT_WHEEL={}: no such wheel",
                w.display()
            );
            w
        }
        None => {
            let _ = std::fs::remove_dir_all(&wheels);
            let profile =
                std::env::var("CELLINJECT_WHEEL_PROFILE").unwrap_or_else(|_| "dev".into());
            run(
                Command::new(&py)
                    .args(["-m", "maturin", "build", "--profile", &profile, "--out"])
                    .arg(&wheels)
                    .current_dir(root.join("python")),
                "maturin build",
            );
            std::fs::read_dir(&wheels)
                .unwrap()
                .map(|e| e.unwrap().path())
                .find(|p| p.extension().is_some_and(|e| e == "whl"))
                .expect("maturin wrote no wheel")
        }
    };
    run(
        Command::new(&py)
            .args([
                "-m",
                "pip",
                "install",
                "--quiet",
                "--force-reinstall",
                "--no-deps",
            ])
            .arg(&wheel),
        "pip install",
    );
    let _ = std::fs::remove_dir_all(&wheels);
    run(
        Command::new(&py)
            .args([
                "-m",
                "pytest",
                "-q",
                "-p",
                "no:cacheprovider",
                "python/tests",
            ])
            .env("CELLINJECT_BIN", env!("CARGO_BIN_EXE_cellinject"))
            .current_dir(&root),
        "pytest",
    );
}
