//! The whole bench over the wire: `cellinject emulate gcs` in one process, the
//! commands with `--backend gcs://...` in another, compared with the twin backend on
//! the same seed; a link cut in the middle of a run (through a proxy) ends in the safe
//! state with the reason recorded; bad backend arguments exit 2.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use std::fs;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use serde_json::Value;

use common::err;

fn dir(name: &str) -> PathBuf {
    common::dir("gcs", name)
}

fn run(dir: &Path, args: &[&str]) -> Output {
    let t = std::time::Instant::now();
    let o = common::cmd(dir).args(args).output().unwrap();
    eprintln!("{:.1} s: {}", t.elapsed().as_secs_f64(), args.join(" "));
    o
}

fn ok(o: &Output) -> Value {
    assert_eq!(o.status.code(), Some(0), "{}", err(o));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// `cellinject emulate gcs` on a free port, killed when dropped.
struct Emulator {
    child: Child,
    gcs: String,
    /// The bench endpoint's address.
    bench: String,
}

impl Emulator {
    fn start(dir: &Path, extra: &[&str]) -> Self {
        Emulator::try_start(dir, extra).expect("the emulator did not start")
    }

    /// The emulator, or `None` when it exits before saying where it listens (a port
    /// taken).
    fn try_start(dir: &Path, extra: &[&str]) -> Option<Self> {
        let mut child = Command::new(env!("CARGO_BIN_EXE_cellinject"))
            .current_dir(dir)
            .args(["emulate", "gcs", "--bind", "127.0.0.1:0"])
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        if line.is_empty() {
            let _ = child.wait();
            return None;
        }
        let addrs: Vec<String> = line
            .split_whitespace()
            .filter(|w| w.starts_with("127.0.0.1:"))
            .map(|w| {
                w.trim_end_matches(|c: char| !c.is_ascii_digit())
                    .to_string()
            })
            .collect();
        let [gcs, bench] = <[String; 2]>::try_from(addrs)
            .unwrap_or_else(|_| panic!("not two addresses in {line:?}"));
        Some(Emulator { child, gcs, bench })
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn plate(d: &Path) {
    common::plate(
        d,
        &[
            "--rows",
            "2",
            "--cols",
            "2",
            "--origin=-75e-6,-45e-6",
            "--seed",
            "5",
        ],
        "p.toml",
    );
}

fn rms(v: &Value) -> f64 {
    let r = &v["rms_error_m"];
    r[0].as_f64().unwrap().hypot(r[1].as_f64().unwrap())
}

/// `experiment repeatability` (6 runs, JSON) writing to `out`, with `extra` options.
fn repeatability<'a>(out: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec![
        "experiment",
        "repeatability",
        "--runs",
        "6",
        "--calibration",
        "cal",
        "--format",
        "json",
        "--out",
        out,
    ];
    a.extend_from_slice(extra);
    a
}

/// `run` of p.toml (JSON) recorded in `db`, with `extra` options.
fn injection<'a>(db: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec![
        "run",
        "--plate",
        "p.toml",
        "--calibration",
        "cal/hysteresis.json",
        "--db",
        db,
        "--format",
        "json",
    ];
    a.extend_from_slice(extra);
    a
}

// The wire runs in real time (the emulator's twin follows the wall clock), so the
// comparisons are two tests that the harness runs side by side: the calibrations and
// the repeatability experiment here, the injection workflow in the next.
#[test]
fn calibrations_and_experiments_over_gcs_match_the_twin() {
    let d = dir("match");
    // The twin's calibrations (made fast, on simulated time).
    let o = run(&d, &["calibrate", "all", "--out", "cal"]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    // The twin's side of the comparison, in a thread beside the wire's (each side
    // keeps about one core busy; the test's wall time is the longer side's).
    let twin_side = {
        let d = d.clone();
        std::thread::spawn(move || run(&d, &repeatability("rt", &[])))
    };
    // The bench as the calibrations find it (no plate under the microscope).
    let emu = Emulator::start(&d, &[]);
    let backend = format!("gcs://{}", emu.gcs);
    // The cameras' pixel calibration through the wire (stage moves on the bench
    // endpoint, frames of the marker) agrees with the twin's to 0.1 %.
    let o = run(
        &d,
        &[
            "calibrate",
            "pixels",
            "--backend",
            &backend,
            "--out",
            "px.json",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let pg: Value = serde_json::from_slice(&fs::read(d.join("px.json")).unwrap()).unwrap();
    let pt: Value = serde_json::from_slice(&fs::read(d.join("cal/pixels.json")).unwrap()).unwrap();
    assert_eq!(pg["made"]["backend"], backend.as_str());
    for cam in 0..2 {
        for k in 0..2 {
            let g = pg["calibration"]["maps"][cam]["metres_per_pixel"][k]
                .as_f64()
                .unwrap();
            let t = pt["calibration"]["maps"][cam]["metres_per_pixel"][k]
                .as_f64()
                .unwrap();
            assert!(
                ((g - t) / t).abs() < 1e-3,
                "camera {cam} axis {k}: gcs {g}, twin {t}"
            );
        }
    }
    // Repeatability: the same experiment, the same magnitude of scatter (tens of nm).
    let g = ok(&run(&d, &repeatability("rg", &["--backend", &backend])));
    let t = ok(&twin_side.join().unwrap());
    let (eg, et) = (rms(&g), rms(&t));
    assert!(eg < 80e-9 && et < 80e-9, "RMS gcs {eg}, twin {et}");
    assert!(
        g["truth"].is_null(),
        "no truth over the wire: {}",
        g["truth"]
    );
    drop(emu);
}

/// The injection workflow on an emulator with the plate: the same cells injected as on
/// the twin (a blocked doublet may go either way with the survey's noise), every
/// injected cell alive with its dose, each once. Its bench named by a rig file with
/// no bench endpoint for the stages, the injector or the optics: the macro stage, the
/// feeder, the injector and the objectives (a uMs's lens changer) are Sensapex
/// devices over SMCP1 (`emulate gcs --sensapex`; the
/// calibrations of the test above take the shorthands, every device on the bench
/// endpoint), reached through a relay that can silence the manipulator: silenced once
/// the run is under way, it stops the run (exit 1, recorded `stopped` naming the
/// device, the pipette withdrawn); answering again, the run resumes and finishes.
#[test]
fn a_run_over_gcs_injects_what_the_twin_injects() {
    let d = dir("match-run");
    plate(&d);
    fs::create_dir_all(d.join("cal")).unwrap();
    let o = run(
        &d,
        &["calibrate", "hysteresis", "--out", "cal/hysteresis.json"],
    );
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let twin_side = {
        let d = d.clone();
        std::thread::spawn(move || run(&d, &injection("t.sqlite", &[])))
    };
    let (emu, group) = with_sensapex(&d);
    let backend = format!("gcs://{}", emu.gcs);
    let relay = Relay::start(group);
    let rig = sensapex_rig(&rig_file(&backend, &emu.bench), &emu.bench, group)
        .replace("sensapex://127.0.0.1?", "sensapex://127.0.0.2?")
        .replace("sensapex-ums://127.0.0.1?", "sensapex-ums://127.0.0.2?")
        .replace(
            "sensapex-pressure://127.0.0.1?",
            "sensapex-pressure://127.0.0.2?",
        );
    fs::write(d.join("bench.toml"), &rig).unwrap();
    let check = ok(&run(
        &d,
        &["rig", "check", "--rig", "bench.toml", "--format", "json"],
    ));
    // The stacks identified over the wire once, with the plate under the pipette, for
    // both of the wire's runs (day two on a bench: a run from its saved calibration).
    // A run does not use the twin's calibration on another backend and would identify
    // the stacks itself at a run's 20,000 samples (46 s of the wire's clock); 2,000
    // take 11 s. Swept without raising the pipette first, this calibration broke the
    // tip on the floor and the run's injections found no flow.
    let o = run(
        &d,
        &[
            "calibrate",
            "hysteresis",
            "--samples",
            "2000",
            "--rig",
            "bench.toml",
            "--out",
            "cal/wire.json",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let wire = |db: &'static str, extra: &[&'static str]| {
        let mut a = injection(db, extra);
        let k = a.iter().position(|x| *x == "cal/hysteresis.json").unwrap();
        a[k] = "cal/wire.json";
        a
    };
    let devices = check["devices"].as_array().unwrap();
    assert_eq!(devices.len(), 7, "{check}");
    assert!(devices.iter().all(|x| x["answers"] == true), "{check}");
    // The emulated uMs starts at lens 1.
    assert_eq!(
        devices[6]["detail"], "zoom 2.50x (range 2.5x to 10x)",
        "{check}"
    );
    // The manipulator falls silent once the run is under way.
    let mut child = common::cmd(&d)
        .args(wire("g.sqlite", &["--rig", "bench.toml"]))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_running(&d, &mut child, "g.sqlite");
    relay.silence(true);
    let out = child.wait_with_output().unwrap();
    let stderr = err(&out);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    let named = format!("Sensapex device 1 at 127.0.0.2:{}", 55555 + group);
    assert!(stderr.contains(&named), "{stderr}");
    let show = ok(&run(&d, &["runs", "show", "--db", "g.sqlite"]));
    assert_eq!(show["run"]["status"], "stopped", "{show}");
    assert!(
        show["run"]["stopped"].as_str().unwrap().contains(&named),
        "{show}"
    );
    let a3 = a3_volts(&emu.gcs);
    assert!(a3.abs() < 0.05, "A3 withdrawn: {a3} V; {stderr}");
    // Answering again: the run resumes and finishes the plate.
    relay.silence(false);
    let o = run(&d, &wire("g.sqlite", &["--rig", "bench.toml", "--resume"]));
    let g = ok(&o);
    let t = ok(&twin_side.join().unwrap());
    assert_eq!(g["backend"], backend.as_str());
    assert_eq!(g["cells_found"], t["cells_found"]);
    let inj = |v: &Value| v["injected"].as_i64().unwrap();
    assert!((inj(&g) - inj(&t)).abs() <= 1, "gcs {g}, twin {t}");
    assert!(inj(&g) >= 3, "{g}");
    let wells: Vec<&Value> = g["attempts"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|a| a["outcome"] == "injected")
        .map(|a| &a["well"])
        .collect();
    for (k, w) in wells.iter().enumerate() {
        assert!(!wells[..k].contains(w), "well {w} injected twice: {g}");
    }
    for a in g["attempts"].as_array().unwrap() {
        assert!(a["tip_error_m"].is_null(), "no truth over the wire");
        if a["outcome"] == "injected" {
            let m = a["measured_tip_error_m"].as_f64().unwrap();
            assert!(m < 1.5e-6, "measured tip error {m}");
        }
    }
    drop(emu);
}

/// Sensapex devices (an in-process SMCP1 emulator on the first free group) for the
/// stages and the injector beside the GCS controller and its bench endpoint: `rig
/// check` finds every device; when the manipulator stops answering, `run --rig` fails
/// within 2 s with exit 1 naming its id and address, and leaves no database.
#[test]
fn a_sensapex_device_that_does_not_answer_fails_the_run_fast_naming_it() {
    use cellinject_sensapex::emulator;
    let d = dir("sensapex-rig");
    plate(&d);
    let (sx, group) = (0..=10u16)
        .find_map(|g| {
            let s = std::net::UdpSocket::bind(("127.0.0.1", 55555 + g)).ok()?;
            let devices = emulator::parse_devices("ump:1,ums:21,umv:31").unwrap();
            Some((emulator::serve(s, &devices, None).unwrap(), g))
        })
        .expect("a free UDP port in 55555..55565");
    let emu = Emulator::start(&d, &["--plate", "p.toml"]);
    let rig = sensapex_rig(
        &rig_file(&format!("gcs://{}", emu.gcs), &emu.bench),
        &emu.bench,
        group,
    );
    fs::write(d.join("sx.toml"), &rig).unwrap();
    let check = ok(&run(
        &d,
        &["rig", "check", "--rig", "sx.toml", "--format", "json"],
    ));
    let devices = check["devices"].as_array().unwrap();
    assert!(devices.iter().all(|x| x["answers"] == true), "{check}");
    sx.mute(1, true);
    let t = std::time::Instant::now();
    let o = run(
        &d,
        &[
            "run",
            "--rig",
            "sx.toml",
            "--plate",
            "p.toml",
            "--db",
            "sx.sqlite",
        ],
    );
    let took = t.elapsed();
    assert_eq!(o.status.code(), Some(1), "{}", err(&o));
    let e = err(&o);
    let at = format!("127.0.0.1:{}", 55555 + group);
    assert!(e.contains("device 1") && e.contains(&at), "{e}");
    assert!(took < Duration::from_secs(2), "{took:?}");
    assert!(!d.join("sx.sqlite").exists());
    drop(emu);
}

/// Waits until the run `child` writes to `db` is recorded as running (read from the
/// records as the run writes them, however long that takes on a loaded machine).
fn wait_running(d: &Path, child: &mut Child, db: &str) {
    common::poll(
        Duration::from_secs(300),
        Duration::from_millis(200),
        "the run recorded as running",
        || {
            if let Some(status) = child.try_wait().unwrap() {
                panic!("the run ended ({status}) before it was recorded as running");
            }
            match common::json(d, &["runs", "show", "--db", db]) {
                Some(v) if v["run"]["status"] == "running" => Ok(()),
                other => Err(other),
            }
        },
    );
}

/// A UDP relay from 127.0.0.2 to the Sensapex devices on 127.0.0.1 (same group),
/// which can silence device 1: its datagrams, both ways, are dropped (a cable pulled).
struct Relay {
    silent: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
}

impl Drop for Relay {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

impl Relay {
    fn start(group: u16) -> Relay {
        let port = 55555 + group;
        let s = std::net::UdpSocket::bind(("127.0.0.2", port)).unwrap();
        s.set_read_timeout(Some(Duration::from_millis(50))).unwrap();
        let upstream: std::net::SocketAddr = ([127, 0, 0, 1], port).into();
        let silent = Arc::new(AtomicBool::new(false));
        let stop = Arc::new(AtomicBool::new(false));
        let (quiet, end) = (silent.clone(), stop.clone());
        std::thread::spawn(move || {
            let mut buf = [0u8; 1500];
            let mut client = None;
            while !end.load(Ordering::SeqCst) {
                let Ok((n, from)) = s.recv_from(&mut buf) else {
                    continue;
                };
                let b = &buf[..n];
                // Receiver id at bytes 2-3, sender id at 4-5 (big-endian).
                let id = |at: usize| b.get(at..at + 2).map(|x| u16::from_be_bytes([x[0], x[1]]));
                if from == upstream {
                    let gated = quiet.load(Ordering::SeqCst) && id(4) == Some(1);
                    if let (Some(c), false) = (client, gated) {
                        let _ = s.send_to(b, c);
                    }
                } else {
                    client = Some(from);
                    let gated = quiet.load(Ordering::SeqCst) && id(2) == Some(1);
                    if !gated {
                        let _ = s.send_to(b, upstream);
                    }
                }
            }
        });
        Relay { silent, stop }
    }

    fn silence(&self, on: bool) {
        self.silent.store(on, Ordering::SeqCst);
    }
}

/// `cellinject emulate gcs --plate p.toml --sensapex ump:1,ums:21,umv:31` on the
/// first Sensapex group whose port is free (other tests hold some), and the group.
fn with_sensapex(d: &Path) -> (Emulator, u16) {
    for group in 0..=10u16 {
        if std::net::UdpSocket::bind(("127.0.0.1", 55555 + group)).is_err() {
            continue;
        }
        let g = group.to_string();
        let extra = ["--plate", "p.toml", "--sensapex", "ump:1,ums:21,umv:31"];
        if let Some(e) = Emulator::try_start(d, &[&extra[..], &["--sensapex-group", &g]].concat()) {
            return (e, group);
        }
    }
    panic!("no free Sensapex group (UDP 55555..55565)");
}

/// `rig` with the stages, the injector and the optics on the Sensapex devices of
/// `group` (the optics the uMs's lens changer: lens 1 the twin's lowest zoom, lens 2
/// its highest).
fn sensapex_rig(rig: &str, bench: &str, group: u16) -> String {
    let mut rig = rig.to_string();
    for (section, driver) in [
        (
            "stage.macro",
            format!("\"sensapex://127.0.0.1?dev=1&group={group}\""),
        ),
        (
            "stage.feeder",
            format!("\"sensapex-ums://127.0.0.1?dev=21&group={group}\""),
        ),
        (
            "injector",
            format!("\"sensapex-pressure://127.0.0.1?dev=31&channel=1&group={group}\""),
        ),
        (
            "optics",
            format!("\"sensapex-ums://127.0.0.1?dev=21&group={group}\"\nlenses = [2.5, 10.0]"),
        ),
    ] {
        rig = rig.replace(
            &format!("[{section}]\ndriver = \"bench://{bench}\""),
            &format!("[{section}]\ndriver = {driver}"),
        );
    }
    assert_eq!(rig.matches("sensapex").count(), 4, "{rig}");
    rig
}

/// A rig file naming the controller at `backend` and every other device at the bench
/// endpoint `bench`.
fn rig_file(backend: &str, bench: &str) -> String {
    let mut rig = format!("name = \"emulated\"\n[piezo]\ndriver = \"{backend}\"\n");
    for section in [
        "camera.top",
        "camera.side",
        "stage.macro",
        "stage.feeder",
        "injector",
        "optics",
    ] {
        rig += &format!("[{section}]\ndriver = \"bench://{bench}\"\n");
    }
    rig
}

/// A TCP proxy that can cut every connection it carries (those opened later pass).
struct Proxy {
    addr: String,
    open: Arc<std::sync::Mutex<Vec<Arc<AtomicBool>>>>,
}

impl Proxy {
    fn cut(&self) {
        for c in self.open.lock().unwrap().drain(..) {
            c.store(true, Ordering::SeqCst);
        }
    }
}

fn proxy(to: &str) -> Proxy {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap().to_string();
    let open: Arc<std::sync::Mutex<Vec<Arc<AtomicBool>>>> = Arc::default();
    let (to, o) = (to.to_string(), open.clone());
    std::thread::spawn(move || {
        for client in l.incoming() {
            let Ok(client) = client else { return };
            let Ok(server) = TcpStream::connect(&to) else {
                continue;
            };
            let c = Arc::new(AtomicBool::new(false));
            o.lock().unwrap().push(c.clone());
            for (mut a, mut b) in [
                (client.try_clone().unwrap(), server.try_clone().unwrap()),
                (server, client),
            ] {
                let c = c.clone();
                std::thread::spawn(move || {
                    a.set_read_timeout(Some(Duration::from_millis(20))).unwrap();
                    let mut buf = [0u8; 4096];
                    loop {
                        if c.load(Ordering::SeqCst) {
                            let _ = a.shutdown(std::net::Shutdown::Both);
                            let _ = b.shutdown(std::net::Shutdown::Both);
                            return;
                        }
                        match a.read(&mut buf) {
                            Ok(0) => {
                                let _ = b.shutdown(std::net::Shutdown::Both);
                                return;
                            }
                            Ok(n) => {
                                if c.load(Ordering::SeqCst) || b.write_all(&buf[..n]).is_err() {
                                    let _ = b.shutdown(std::net::Shutdown::Both);
                                    return;
                                }
                            }
                            Err(e)
                                if e.kind() == std::io::ErrorKind::WouldBlock
                                    || e.kind() == std::io::ErrorKind::TimedOut => {}
                            Err(_) => return,
                        }
                    }
                });
            }
        }
    });
    Proxy { addr, open }
}

#[test]
fn a_link_cut_mid_run_stops_in_the_safe_state_with_the_reason_recorded() {
    let d = dir("cut");
    plate(&d);
    let o = run(&d, &["calibrate", "hysteresis", "--out", "hy.json"]);
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let emu = Emulator::start(&d, &["--plate", "p.toml"]);
    let p = proxy(&emu.gcs);
    let bench = {
        let (h, port) = emu.gcs.rsplit_once(':').unwrap();
        format!("{h}:{}", port.parse::<u16>().unwrap() + 1)
    };
    let backend = format!("gcs://{}", p.addr);
    let mut child = Command::new(env!("CARGO_BIN_EXE_cellinject"))
        .current_dir(&d)
        .args([
            "run",
            "--plate",
            "p.toml",
            "--calibration",
            "hy.json",
            "--db",
            "r.sqlite",
            "--backend",
            &backend,
            "--bench",
            &bench,
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Cut once the run is under way (its record says running), read from the records
    // as the run writes them, however long that takes on a loaded machine (the fixed
    // 22 s this replaces was meant to reach the first cells, but over the real-time
    // wire the first cell starts about 3 min in, measured alone: it cut before any
    // cell too).
    wait_running(&d, &mut child, "r.sqlite");
    p.cut();
    let out = child.wait_with_output().unwrap();
    let stderr = err(&out);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("stopped"), "{stderr}");
    // The record says why; the run is `stopped`.
    let show = ok(&run(&d, &["runs", "show", "--db", "r.sqlite"]));
    assert_eq!(show["run"]["status"], "stopped", "{show}");
    let why = show["run"]["stopped"].as_str().unwrap();
    assert!(why.contains(&p.addr), "the reason names the link: {why}");
    // The link came back (the proxy carries new connections): the stacks were
    // stopped and the pipette withdrawn.
    let a3 = a3_volts(&emu.gcs);
    assert!(
        a3.abs() < 0.05,
        "A3 withdrawn: {a3} V; run: {why}; stderr: {stderr}"
    );
}

/// A3's commanded voltage (`SVA? 3`) on the controller at `gcs`: at 0 V within
/// 0.05 V (a nanometre of its 60 um stroke), the pipette is out.
fn a3_volts(gcs: &str) -> f64 {
    let mut g = TcpStream::connect(gcs).unwrap();
    g.set_read_timeout(Some(Duration::from_secs(3))).unwrap();
    g.write_all(b"SVA? 3\n").unwrap();
    let mut got = String::new();
    BufReader::new(g).read_line(&mut got).unwrap();
    got.trim()
        .split('=')
        .nth(1)
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("SVA? 3 answered {got:?}"))
}

#[test]
fn bad_backend_arguments_exit_2_and_name_the_argument() {
    let d = dir("bad");
    plate(&d);
    for (args, needle) in [
        (vec!["run", "--backend", "tcp://x:1"], "--backend"),
        (vec!["run", "--backend", "gcs://127.0.0.1:99999"], "port"),
        (
            vec![
                "run",
                "--backend",
                "gcs://127.0.0.1:1",
                "--fault",
                "clog@0,1",
                "--plate",
                "p.toml",
            ],
            "--fault",
        ),
        (vec!["run", "--backend", "gcs://127.0.0.1:1"], "--plate"),
        (
            vec![
                "run",
                "--backend",
                "gcs-serial:///dev/ttyNOPE",
                "--plate",
                "p.toml",
            ],
            "--bench",
        ),
        (
            vec!["experiment", "repeatability", "--bench", "127.0.0.1:1"],
            "--bench",
        ),
        (
            vec![
                "experiment",
                "repeatability",
                "--backend",
                "gcs://127.0.0.1:1",
                "--seed",
                "3",
            ],
            "--seed",
        ),
        (
            vec!["experiment", "repeatability", "--camera", "frames"],
            "--camera",
        ),
        (
            vec![
                "calibrate",
                "pixels",
                "--backend",
                "gcs://127.0.0.1:1",
                "--camera-fps",
                "0",
            ],
            "--camera-fps",
        ),
        (
            vec!["experiment", "repeatability", "--camera-fps", "5"],
            "--camera-fps",
        ),
        (
            vec![
                "calibrate",
                "pixels",
                "--backend",
                "gcs://127.0.0.1:1",
                "--bench",
                "notaport",
            ],
            "--bench",
        ),
        (
            vec!["emulate", "gcs", "--bind", "127.0.0.1:65535"],
            "--bench",
        ),
        (vec!["emulate", "gcs", "--bind", "nonsense"], "--bind"),
        (
            vec![
                "emulate",
                "gcs",
                "--bind",
                "127.0.0.1:0",
                "--fault",
                "clog@0,1",
            ],
            "--plate",
        ),
        (
            vec![
                "emulate",
                "gcs",
                "--bind",
                "127.0.0.1:0",
                "--plate",
                "missing.toml",
            ],
            "missing.toml",
        ),
    ] {
        let o = run(&d, &args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", err(&o));
        assert!(err(&o).contains(needle), "{args:?}: {}", err(&o));
    }
    // Nobody listening: a clear error naming the address (exit 1: the bench, not the
    // arguments).
    let o = run(
        &d,
        &["calibrate", "pixels", "--backend", "gcs://127.0.0.1:1"],
    );
    assert_eq!(o.status.code(), Some(1), "{}", err(&o));
    assert!(err(&o).contains("127.0.0.1:1"), "{}", err(&o));
    // ... and leaves nothing behind: no output directory, no run record.
    let o = run(
        &d,
        &[
            "calibrate",
            "all",
            "--backend",
            "gcs://127.0.0.1:1",
            "--out",
            "cal2",
        ],
    );
    assert_eq!(o.status.code(), Some(1), "{}", err(&o));
    assert!(!d.join("cal2").exists());
    let o = run(
        &d,
        &[
            "run",
            "--backend",
            "gcs://127.0.0.1:1",
            "--plate",
            "p.toml",
            "--db",
            "q.sqlite",
        ],
    );
    assert_eq!(o.status.code(), Some(1), "{}", err(&o));
    assert!(!d.join("q.sqlite").exists());
}
