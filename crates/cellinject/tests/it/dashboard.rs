//! `cellinject serve` as a user meets it: bad arguments exit 2 naming the argument;
//! remote access prints a token and refuses requests without it, over real TCP; the
//! server's end aborts and records a run that is going; and the end-to-end test in
//! Debian's headless Chromium (playwright-core, `tests/e2e/dashboard.mjs`): frames
//! arrive at 10 a second or more during a run, ABORT retracts the pipette and the run
//! is recorded aborted.
//!
//! The browser test needs `chromium` (Debian's package), `node` and
//! `tests/e2e/node_modules` (`npm ci` there). `.ci/run` installs them and sets
//! `CELLINJECT_E2E=required`, under which a missing piece fails the test; elsewhere
//! it is skipped with a notice on standard error (`cargo test -- --nocapture` shows
//! it).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use common::{dir, err, run};

/// `cellinject serve` on a free port, killed when dropped.
struct Server {
    child: Child,
    addr: String,
    token: Option<String>,
    lines: mpsc::Receiver<String>,
}

impl Server {
    fn start(dir: &Path, extra: &[&str]) -> Self {
        let mut child = Command::new(env!("CARGO_BIN_EXE_cellinject"))
            .current_dir(dir)
            .args(["serve", "--bind", "127.0.0.1:0"])
            .args(extra)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let stderr = child.stderr.take().unwrap();
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for l in BufReader::new(stderr).lines().map_while(Result::ok) {
                let _ = tx.send(l);
            }
        });
        let mut addr = None;
        let mut token = None;
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_secs(60) {
            let Ok(l) = lines.recv_timeout(Duration::from_millis(100)) else {
                continue;
            };
            if let Some(rest) = l.strip_prefix("dashboard: http://") {
                addr = Some(rest.split('/').next().unwrap().to_string());
            }
            if let Some(t) = l.strip_prefix("access token: ") {
                token = Some(t.trim().to_string());
            }
            if addr.is_some() && (token.is_some() || !extra.contains(&"--allow-remote")) {
                break;
            }
        }
        Server {
            child,
            addr: addr.expect("the server names its address"),
            token,
            lines,
        }
    }

    fn url(&self) -> String {
        format!("http://{}/", self.addr)
    }

    /// One HTTP/1.1 request: (status, body).
    fn http(&self, method: &str, path: &str, headers: &[(&str, &str)]) -> (u16, String) {
        let mut s = TcpStream::connect(&self.addr).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
        let mut req =
            format!("{method} {path} HTTP/1.1\r\nConnection: close\r\nContent-Length: 0\r\n");
        if !headers.iter().any(|(k, _)| k.eq_ignore_ascii_case("host")) {
            req.push_str(&format!("Host: {}\r\n", self.addr));
        }
        for (k, v) in headers {
            req.push_str(&format!("{k}: {v}\r\n"));
        }
        req.push_str("\r\n");
        s.write_all(req.as_bytes()).unwrap();
        let mut out = String::new();
        let _ = s.read_to_string(&mut out);
        let code = out
            .split_whitespace()
            .nth(1)
            .and_then(|c| c.parse().ok())
            .unwrap_or(0);
        let body = out
            .split_once("\r\n\r\n")
            .map_or("", |(_, b)| b)
            .to_string();
        (code, body)
    }

    fn status(&self) -> serde_json::Value {
        let (c, b) = self.http("GET", "/api/status", &[]);
        assert_eq!(c, 200, "{b}");
        serde_json::from_str(&b).unwrap()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn bad_arguments_exit_2_naming_the_argument() {
    let d = dir("serve", "bad");
    std::fs::write(d.join("runs.sqlite"), b"").unwrap();
    // A plate beyond the feeder's reach (±25 mm): refused at start, not at the first
    // run.
    std::fs::write(
        d.join("far.toml"),
        "[plate]\nrows = 2\ncols = 2\npitch = 1.5e-4\norigin = [40e-3, 0.0]\n",
    )
    .unwrap();
    let busy = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let busy_addr = busy.local_addr().unwrap().to_string();
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["--bind", "0.0.0.0:0"], "--allow-remote"),
        (vec!["--bind", "192.168.0.1:8080"], "not a loopback address"),
        (vec!["--bind", "localhost"], "--bind `localhost`"),
        (vec!["--bind", &busy_addr], "--bind"),
        (vec!["--public-view"], "--public-view"),
        (
            vec![
                "--bind",
                "0.0.0.0:0",
                "--allow-remote",
                "--allowed-host",
                "a b",
            ],
            "--allowed-host `a b`",
        ),
        (vec!["--serve-for", "NaN"], "--serve-for"),
        (vec!["--serve-for", "-1"], "--serve-for"),
        (vec!["--dose", "0.5"], "--dose"),
        (vec!["--plate", "missing.toml"], "--plate `missing.toml`"),
        (
            vec!["--plate", "far.toml"],
            "--plate: the plate cannot be served: [0, 0], [0, 1], [1, 0], [1, 1] lie outside the feeder stage's travel",
        ),
        (
            vec![
                "--backend",
                "gcs://127.0.0.1:1",
                "--fast",
                "--plate",
                "p.toml",
            ],
            "--fast",
        ),
        (vec!["--backend", "gcs://127.0.0.1:1"], "--plate"),
        (vec!["--backend", "ftp://x"], "--backend"),
    ];
    for (args, what) in cases {
        let mut all = vec!["serve", "--db", "fresh.sqlite"];
        all.extend(&args);
        let o = run(&d, &all);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", err(&o));
        assert!(err(&o).contains(what), "{args:?}: {}", err(&o));
        assert!(!err(&o).contains("panicked"), "{args:?}");
    }
    // A file that is not a run database is refused before anything listens.
    let o = run(&d, &["serve", "--bind", "127.0.0.1:0", "--serve-for", "1"]);
    std::fs::write(d.join("notes.txt"), b"my notes").unwrap();
    let o2 = run(
        &d,
        &[
            "serve",
            "--db",
            "notes.txt",
            "--bind",
            "127.0.0.1:0",
            "--serve-for",
            "1",
        ],
    );
    assert_eq!(o2.status.code(), Some(2), "{}", err(&o2));
    assert!(err(&o2).contains("--db notes.txt"), "{}", err(&o2));
    assert_eq!(std::fs::read(d.join("notes.txt")).unwrap(), b"my notes");
    // (runs.sqlite is empty: an empty file is a fresh database.)
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let o = run(&d, &["serve", "--help"]);
    assert_eq!(o.status.code(), Some(0));
    let help = String::from_utf8_lossy(&o.stdout);
    assert!(help.contains("--allow-remote") && help.contains("/api/abort"));
    drop(busy);
}

#[test]
fn remote_access_needs_the_printed_token_over_tcp() {
    let d = dir("serve", "remote");
    let s = Server::start(&d, &["--allow-remote", "--fast", "--serve-for", "120"]);
    let token = s.token.clone().expect("the token is printed");
    assert_eq!(token.len(), 48);
    assert!(token.chars().all(|c| c.is_ascii_hexdigit()));
    // Without the token: 401 on control and on viewing; the page is the login.
    for path in ["/api/run", "/api/abort", "/api/pause", "/api/jog"] {
        assert_eq!(s.http("POST", path, &[]).0, 401, "{path}");
    }
    assert_eq!(s.http("GET", "/api/status", &[]).0, 401);
    let (c, page) = s.http("GET", "/", &[]);
    assert_eq!(c, 401);
    assert!(page.contains("access token"));
    // A forged Host, a foreign Origin: 403 even with the token.
    let bearer = format!("Bearer {token}");
    let auth = ("Authorization", bearer.as_str());
    assert_eq!(
        s.http(
            "GET",
            "/api/status",
            &[auth, ("Host", "attacker.example:8080")]
        )
        .0,
        403
    );
    assert_eq!(
        s.http(
            "POST",
            "/api/abort",
            &[auth, ("Origin", "http://attacker.example")]
        )
        .0,
        403
    );
    // With it.
    let (c, b) = s.http("GET", "/api/status", &[auth]);
    assert_eq!(c, 200, "{b}");
    assert!(b.contains("\"state\":\"idle\""));
    let (c, b) = s.http("POST", "/api/abort", &[auth]);
    assert_eq!(c, 200, "{b}");
}

#[test]
fn the_end_of_the_server_aborts_and_records_the_run_going() {
    // The server's time is up, or a service manager stops it (SIGTERM), or Ctrl-C
    // (SIGINT), with a run going.
    for (name, serve_for, signal) in [
        ("end", "6", None),
        ("term", "600", Some("-TERM")),
        ("int", "600", Some("-INT")),
    ] {
        let d = dir("serve", name);
        let s = Server::start(&d, &["--fast", "--serve-for", serve_for]);
        let (c, b) = s.http("POST", "/api/run", &[]);
        assert_eq!(c, 202, "{b}");
        assert_eq!(s.status()["state"], "running");
        let mut s = s;
        if let Some(sig) = signal {
            // Signalled once the run is recorded as going (polled from the records,
            // not a fixed wait).
            common::poll(
                Duration::from_secs(60),
                Duration::from_millis(100),
                &format!("{name}: the run recorded as running"),
                || match common::json(&d, &["runs", "list", "--format", "json"]) {
                    Some(r) if r[0]["status"] == "running" => Ok(()),
                    other => Err(other),
                },
            );
            let k = Command::new("kill")
                .arg(sig)
                .arg(s.child.id().to_string())
                .status()
                .unwrap();
            assert!(k.success());
        }
        let t0 = Instant::now();
        let code = loop {
            if let Some(st) = s.child.try_wait().unwrap() {
                break st.code();
            }
            assert!(
                t0.elapsed() < Duration::from_secs(60),
                "{name}: the server did not end"
            );
            std::thread::sleep(Duration::from_millis(50));
        };
        assert_eq!(code, Some(0), "{name}");
        let o = run(&d, &["runs", "list", "--format", "json"]);
        assert_eq!(o.status.code(), Some(0), "{}", err(&o));
        let runs: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(runs[0]["status"], "aborted", "{name}: {runs}");
        assert!(
            runs[0]["stopped"]
                .as_str()
                .unwrap_or("")
                .contains("aborted by the operator"),
            "{name}: {runs}"
        );
        while let Ok(l) = s.lines.try_recv() {
            assert!(!l.contains("panicked"), "{l}");
        }
    }
}

fn e2e_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/e2e")
}

/// What the browser test needs that is missing, if anything.
fn missing() -> Option<String> {
    let chromium = std::env::var("CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into());
    if !Path::new(&chromium).exists() {
        return Some(format!("{chromium} (Debian's package `chromium`)"));
    }
    if Command::new("node").arg("--version").output().is_err() {
        return Some("node".into());
    }
    if !e2e_dir().join("node_modules/playwright-core").is_dir() {
        return Some(format!(
            "{} (`npm ci` there)",
            e2e_dir().join("node_modules/playwright-core").display()
        ));
    }
    None
}

#[test]
fn the_dashboard_in_headless_chromium_shows_frames_and_aborts_a_run() {
    if let Some(what) = missing() {
        let required = std::env::var("CELLINJECT_E2E").is_ok_and(|v| v == "required");
        assert!(!required, "CELLINJECT_E2E=required but {what} is missing");
        eprintln!("SKIPPED the browser test: {what} is missing (CI installs it)");
        return;
    }
    let d = dir("serve", "browser");
    let s = Server::start(&d, &["--fast", "--serve-for", "600"]);
    let o = Command::new("node")
        .current_dir(e2e_dir())
        .arg("dashboard.mjs")
        .arg(s.url())
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    eprintln!("{out}{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(o.status.code(), Some(0), "{out}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(v["ok"], true);
    assert!(v["fps_during_run"].as_f64().unwrap() >= 10.0, "{v}");
    assert!(v["a3_volts_before_abort"].as_f64().unwrap() > 0.0, "{v}");
    assert!(v["aborted_after_s"].as_f64().unwrap() <= 1.0, "{v}");
    assert_eq!(v["recorded"], "aborted");
    // The records say the same. The cell the pipette was in is recorded skipped (not
    // touched yet), interrupted (touched, dose not judged), or keeps the outcome its dose
    // was judged to (the abort came while the pipette was withdrawing), with the
    // operator's abort as its reason either way; if the abort came between two cells
    // (while the last one was being recorded), no cell was in progress and the last
    // attempt is a complete one with its own reason.
    let o = run(&d, &["runs", "list", "--format", "json"]);
    let runs: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(runs[0]["status"], "aborted", "{runs}");
    let o = run(&d, &["runs", "show"]);
    let show: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(
        show["run"]["stopped"]
            .as_str()
            .is_some_and(|s| s.contains("aborted by the operator")),
        "{}",
        show["run"]
    );
    let attempts = show["attempts"].as_array().unwrap();
    let last = attempts.last().unwrap();
    let in_cell = last["reason"]
        .as_str()
        .unwrap()
        .contains("aborted by the operator");
    assert!(last["t_end"].is_number(), "{last}");
    match last["outcome"].as_str().unwrap() {
        "interrupted" => assert!(in_cell, "{last}"),
        "skipped" => {}
        // Judged only after the dose was measured.
        "injected" | "failed" => assert!(last["measured_dose_fraction"].is_number(), "{last}"),
        other => panic!("unexpected outcome {other}: {last}"),
    }
    assert!(
        attempts[..attempts.len() - 1]
            .iter()
            .all(|a| a["outcome"] != "interrupted"),
        "only the cell in progress is interrupted"
    );
}

#[test]
fn a_dashboard_run_records_what_the_cli_records_on_the_same_seed_and_plate() {
    // Both front ends start their runs through cellinject-session's one lifecycle:
    // on the same seed and plate, the same run (attempts, outcomes, events).
    let d = dir("serve", "same");
    common::plate(
        &d,
        &[
            "--rows",
            "1",
            "--cols",
            "2",
            "--origin=-75e-6,-40e-6",
            "--seed",
            "3",
        ],
        "p.toml",
    );
    let common = ["--plate", "p.toml", "--seed", "2"];
    let o = run(
        &d,
        &[&["run", "--db", "cli.sqlite"][..], &common[..]].concat(),
    );
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let s = Server::start(
        &d,
        &[
            &["--fast", "--serve-for", "600", "--db", "dash.sqlite"][..],
            &common[..],
        ]
        .concat(),
    );
    let (c, b) = s.http("POST", "/api/run", &[]);
    assert_eq!(c, 202, "{b}");
    let t0 = Instant::now();
    loop {
        let st = s.status();
        if st["state"] != "running" {
            assert_eq!(st["state"], "finished", "{st}");
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(300),
            "the run did not end: {st}"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    drop(s);
    let show = |db: &str| -> serde_json::Value {
        let o = run(&d, &["runs", "show", "--db", db]);
        assert_eq!(o.status.code(), Some(0), "{}", err(&o));
        let mut v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        v.as_object_mut().unwrap().remove("files");
        v
    };
    let (mut cli, mut dash) = (show("cli.sqlite"), show("dash.sqlite"));
    let injected = |v: &serde_json::Value| {
        v["attempts"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|a| a["outcome"] == "injected")
            .count()
    };
    assert!(injected(&cli) >= 1, "{cli}");
    // What differs by design: when each was created, and the settings' note of the
    // front end (the dashboard's) and of a calibration file (the CLI's).
    for v in [&mut cli, &mut dash] {
        let r = v["run"].as_object_mut().unwrap();
        r.remove("created");
        let s = r["settings"].as_object_mut().unwrap();
        s.remove("front_end");
        s.remove("calibration");
    }
    assert_eq!(cli, dash);
}
