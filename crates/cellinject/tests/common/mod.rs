//! Helpers shared by the CLI tests that use them: a scratch directory, the binary run
//! in it, its standard error.

#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A fresh scratch directory for test `name` of suite `suite`.
pub fn dir(suite: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("cellinject-{suite}-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&d);
    fs::create_dir_all(&d).unwrap();
    d
}

/// `cellinject`, to be run in `dir`.
pub fn cmd(dir: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_cellinject"));
    c.current_dir(dir);
    c
}

/// `cellinject ARGS` run in `dir`.
pub fn run(dir: &Path, args: &[&str]) -> Output {
    cmd(dir).args(args).output().unwrap()
}

/// Its standard error.
pub fn err(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The JSON document `cellinject ARGS` (run in `dir`) prints, if it exits 0 with one:
/// the records read while a run writes them (`runs show`, `runs list`).
pub fn json(dir: &Path, args: &[&str]) -> Option<serde_json::Value> {
    let o = run(dir, args);
    (o.status.code() == Some(0))
        .then(|| serde_json::from_slice(&o.stdout).ok())
        .flatten()
}

/// Polls `look` every `every` until it gives something, failing the test with `what`
/// and the last look after `limit`: a wait on what the run records, not a fixed sleep.
pub fn poll<T, L: std::fmt::Debug>(
    limit: std::time::Duration,
    every: std::time::Duration,
    what: &str,
    mut look: impl FnMut() -> Result<T, L>,
) -> T {
    let t0 = std::time::Instant::now();
    loop {
        match look() {
            Ok(v) => return v,
            Err(last) => assert!(
                t0.elapsed() < limit,
                "{what} within {} s; last seen: {last:?}",
                limit.as_secs()
            ),
        }
        std::thread::sleep(every);
    }
}

/// `cellinject plate generate ARGS --out OUT` in `dir`, which must succeed: a test's
/// plate.
pub fn plate(dir: &Path, args: &[&str], out: &str) {
    let o = cmd(dir)
        .args(["plate", "generate"])
        .args(args)
        .args(["--out", out])
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(0),
        "plate generate {args:?}: {}",
        err(&o)
    );
}
