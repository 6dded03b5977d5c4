//! The web side over a fake bench, request by request (`tower::ServiceExt::oneshot`):
//! the API's answers, abort (also under a flood of control requests and with the
//! bench stuck), the access token, the session cookie, Host and Origin checks.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use axum::Router;
use axum::body::Body;
use axum::http::{Request, StatusCode, header};
use cellinject_core::calibrate::HysteresisCalibration;
use cellinject_core::inject::{Attempt, Observer, Outcome, Target, Truth};
use cellinject_dashboard::bench::spawn;
use cellinject_dashboard::{
    Access, App, Archive, Control, PlateView, RunEnd, Station, Telemetry, ViewFrame, Viewer,
    instrument, router, shared, spawn_viewer,
};
use cellinject_hw::{PiezoChannel, PositionSensor};
use cellinject_model::prototype;
use cellinject_rig::{DynBackend, Rig, RigParams, fake};
use serde_json::Value;
use tower::ServiceExt;

/// A bench whose run works on `cells` cells for `per_cell` s of device time each
/// (A3 forward meanwhile), or hangs in a stalled device when `stall` is set.
struct FakeStation {
    rig: Rig<DynBackend>,
    cells: usize,
    per_cell: f64,
    stall: Arc<AtomicBool>,
}

fn target(i: usize) -> Target {
    Target {
        index: i,
        well: [0, i as u32],
        x_m: i as f64 * 150e-6,
        y_m: 0.0,
        diameter_m: 20e-6,
        diameter_se_m: None,
        stage_m: [0.0; 2],
    }
}

impl Station for FakeStation {
    fn backend(&self) -> String {
        "fake".into()
    }
    fn plate(&self) -> PlateView {
        PlateView {
            rows: 1,
            cols: self.cells as u32,
            pitch_m: 150e-6,
            origin_m: [0.0; 2],
        }
    }
    fn rig(&mut self) -> &mut Rig<DynBackend> {
        &mut self.rig
    }
    fn sweep_drop(&self) -> Result<f64, String> {
        Ok(0.0)
    }
    fn run(
        &mut self,
        watch: &mut dyn Observer,
        _h: Option<HysteresisCalibration>,
        aborted: &dyn Fn() -> bool,
    ) -> Result<RunEnd, String> {
        let targets: Vec<Target> = (0..self.cells).map(target).collect();
        watch.surveyed(&targets)?;
        let end = |status: &str, why: Option<String>| RunEnd {
            id: 1,
            status: status.into(),
            stopped: why,
            cells_per_min: 0.0,
            calibration: None,
        };
        for t in targets {
            if self.stall.load(Ordering::SeqCst) {
                // A camera that never answers: the control thread is stuck here.
                while self.stall.load(Ordering::SeqCst) {
                    std::thread::sleep(Duration::from_millis(5));
                }
            }
            if let Err(why) = watch.proceed() {
                return Ok(end("aborted", Some(why)));
            }
            let mut a = Attempt {
                target: t,
                outcome: Outcome::Injected,
                reason: String::new(),
                contact: true,
                measured_tip_error_m: Some(0.3e-6),
                depth_m: None,
                pulse: None,
                measured_dose_fraction: None,
                truth: Truth::default(),
                t: [self.rig.clock.now(), 0.0],
                transitions: Vec::new(),
            };
            watch.started(&a)?;
            self.rig.piezo[2]
                .set_voltage(20.0)
                .map_err(|e| e.to_string())?;
            let steps = (self.per_cell / 1e-3) as usize;
            for _ in 0..steps {
                if let Err(e) = self.rig.clock.sleep(1e-3) {
                    // The way out: A3 back first.
                    let _ = self.rig.piezo[2].set_voltage(0.0);
                    a.outcome = Outcome::Skipped;
                    a.t[1] = self.rig.clock.now();
                    watch.finished(&a)?;
                    let status = if aborted() { "aborted" } else { "stopped" };
                    return Ok(end(status, Some(e.to_string())));
                }
            }
            let _ = self.rig.sensors[2].read();
            self.rig.piezo[2]
                .set_voltage(0.0)
                .map_err(|e| e.to_string())?;
            a.t[1] = self.rig.clock.now();
            watch.finished(&a)?;
        }
        Ok(end("finished", None))
    }
}

struct Records;

impl Archive for Records {
    fn runs(&self) -> Result<Value, String> {
        Ok(serde_json::json!([{ "id": 1, "status": "aborted" }]))
    }
    fn report(&self, id: i64) -> Result<Option<String>, String> {
        Ok((id == 1).then(|| "<html>run 1</html>".to_string()))
    }
}

struct Still;

impl Viewer for Still {
    fn frame(&mut self) -> Option<ViewFrame> {
        Some(ViewFrame {
            width: 4,
            height: 2,
            pixels: vec![0, 64, 128, 255, 1, 2, 3, 4],
            origin_m: Some([0.0, 0.0]),
            pitch_m: 1e-6,
            to_view: None,
            tip_m: Some([1e-6, 0.0, 2e-6]),
            roi_m: None,
            time_s: 0.0,
        })
    }
}

struct Bench {
    app: Arc<App>,
    router: Router,
    stall: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
}

impl Drop for Bench {
    fn drop(&mut self) {
        self.stall.store(false, Ordering::SeqCst);
        self.stop.store(true, Ordering::SeqCst);
        self.app.shared.control.abort();
        self.app.shared.quit.store(true, Ordering::SeqCst);
    }
}

fn bench(access: Access, fast: bool, per_cell: f64) -> Bench {
    let params = RigParams::default();
    let (devices, _log) = fake::devices(&params);
    let control = Arc::new(Control::new(fast));
    let telemetry = Arc::new(Telemetry::default());
    let devices = instrument(devices.boxed(), &telemetry, &control, false);
    let rig = Rig::new(devices, &prototype(), &params).expect("the fake bench");
    let stall = Arc::new(AtomicBool::new(false));
    let station = FakeStation {
        rig,
        cells: 6,
        per_cell,
        stall: stall.clone(),
    };
    let shared = shared(&station, control, telemetry);
    let (cmd, _control) = spawn(Box::new(station), shared.clone());
    let stop = Arc::new(AtomicBool::new(false));
    let (frames, _view) = spawn_viewer(Box::new(Still), stop.clone());
    let app = App::new(shared, cmd, access, Arc::new(Records), frames);
    Bench {
        router: router(app.clone()),
        app,
        stall,
        stop,
    }
}

fn loopback() -> Access {
    Access::new(
        "127.0.0.1:8080".parse().expect("addr"),
        false,
        false,
        vec![],
    )
    .expect("access")
}

fn remote(public_view: bool) -> Access {
    Access::new(
        "0.0.0.0:8080".parse().expect("addr"),
        true,
        public_view,
        vec![],
    )
    .expect("access")
}

fn req(method: &str, path: &str) -> axum::http::request::Builder {
    Request::builder()
        .method(method)
        .uri(path)
        .header(header::HOST, "localhost:8080")
}

fn login(token: &str) -> Request<Body> {
    req("POST", "/api/session")
        .body(Body::from(format!(r#"{{"token": "{token}"}}"#)))
        .expect("request")
}

/// The Set-Cookie header `POST /api/session` answers the token with.
async fn session_cookie(r: &Router, token: &str) -> String {
    let (s, v, h) = send(r, login(token)).await;
    assert_eq!(s, StatusCode::OK, "{v}");
    h.get(header::SET_COOKIE)
        .and_then(|v| v.to_str().ok())
        .expect("a cookie")
        .to_string()
}

async fn send(r: &Router, req: Request<Body>) -> (StatusCode, Value, axum::http::HeaderMap) {
    let resp = r.clone().oneshot(req).await.expect("infallible");
    let status = resp.status();
    let headers = resp.headers().clone();
    let bytes = axum::body::to_bytes(resp.into_body(), 1 << 24)
        .await
        .expect("body");
    let v = serde_json::from_slice(&bytes)
        .unwrap_or_else(|_| Value::String(String::from_utf8_lossy(&bytes).into()));
    (status, v, headers)
}

async fn call(r: &Router, method: &str, path: &str) -> (StatusCode, Value) {
    let (s, v, _) = send(r, req(method, path).body(Body::empty()).expect("request")).await;
    (s, v)
}

async fn status(r: &Router) -> Value {
    let (s, v) = call(r, "GET", "/api/status").await;
    assert_eq!(s, StatusCode::OK, "{v}");
    v
}

/// s, how long a poll waits for the bench before the test fails: generous, since a
/// poll returns as soon as its condition holds and a loaded CI machine is slow.
const POLL_S: u64 = 30;

/// Polls the status until `ok` holds, for up to `within`.
async fn until(r: &Router, within: Duration, ok: impl Fn(&Value) -> bool) -> Value {
    let t0 = Instant::now();
    loop {
        let v = status(r).await;
        if ok(&v) {
            return v;
        }
        assert!(t0.elapsed() < within, "not within {within:?}: {v:#}");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_run_starts_reports_its_cells_and_aborts_to_the_safe_state() {
    let b = bench(loopback(), false, 0.5);
    let r = &b.router;
    let v = status(r).await;
    assert_eq!(v["state"], "idle");
    assert_eq!(v["backend"], "fake");
    let (s, v) = call(r, "POST", "/api/run").await;
    assert_eq!(s, StatusCode::ACCEPTED, "{v}");
    assert_eq!(v["state"], "running");
    // A second start while running is refused.
    let (s, v) = call(r, "POST", "/api/run").await;
    assert_eq!(s, StatusCode::CONFLICT, "{v}");
    assert!(v["error"].as_str().unwrap_or("").contains("busy"), "{v}");
    // Paced: the first cell takes 0.5 s of wall time, A3 forward meanwhile.
    let v = until(r, Duration::from_secs(POLL_S), |v| {
        v["actuators_v"][2] == 20.0
    })
    .await;
    assert_eq!(v["run"]["cells_found"], 6);
    assert_eq!(v["run"]["current"], 0);
    assert_eq!(v["retracted"], false);
    let t0 = Instant::now();
    let (s, v) = call(r, "POST", "/api/abort").await;
    assert_eq!(s, StatusCode::OK);
    assert_eq!(v["state"], "aborted");
    let v = until(r, Duration::from_secs(1), |v| {
        v["task"].is_null() && v["stopping"] == false
    })
    .await;
    assert!(t0.elapsed() < Duration::from_secs(1));
    assert_eq!(v["state"], "aborted");
    assert_eq!(v["retracted"], true);
    assert_eq!(v["safe"], true);
    assert_eq!(v["run"]["id"], 1);
    assert!(
        v["message"]
            .as_str()
            .unwrap_or("")
            .contains("aborted by the operator"),
        "{v}"
    );
    // The cell in progress was recorded, as skipped.
    assert_eq!(v["run"]["done"], 1);
    assert_eq!(v["run"]["cells"][0]["status"], "skipped");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_run_pauses_between_cells_and_resumes() {
    let b = bench(loopback(), false, 0.05);
    let r = &b.router;
    let (s, _) = call(r, "POST", "/api/pause").await;
    assert_eq!(s, StatusCode::CONFLICT, "nothing to pause yet");
    call(r, "POST", "/api/run").await;
    until(r, Duration::from_secs(POLL_S), |v| {
        v["run"]["cells_found"] == 6
    })
    .await;
    let (s, v) = call(r, "POST", "/api/pause").await;
    assert_eq!(s, StatusCode::OK, "{v}");
    assert_eq!(v["state"], "paused");
    // Held: the count stops moving.
    tokio::time::sleep(Duration::from_millis(150)).await;
    let held = status(r).await["run"]["done"].clone();
    tokio::time::sleep(Duration::from_millis(300)).await;
    let v = status(r).await;
    assert_eq!(v["run"]["done"], held);
    assert_eq!(v["state"], "paused");
    let (s, _) = call(r, "POST", "/api/resume").await;
    assert_eq!(s, StatusCode::OK);
    let v = until(r, Duration::from_secs(POLL_S), |v| v["state"] == "finished").await;
    assert_eq!(v["run"]["done"], 6);
    assert_eq!(v["run"]["injected"], 6);
    let (s, _) = call(r, "POST", "/api/resume").await;
    assert_eq!(s, StatusCode::CONFLICT, "nothing to resume");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_thousand_control_requests_do_not_starve_abort() {
    let b = bench(loopback(), false, 1.0);
    let r = b.router.clone();
    call(&r, "POST", "/api/run").await;
    until(&r, Duration::from_secs(POLL_S), |v| {
        v["run"]["cells_found"] == 6
    })
    .await;
    let mut flood = Vec::new();
    for k in 0..1000 {
        let r = r.clone();
        let path = ["/api/pause", "/api/resume", "/api/run", "/api/calibrate"][k % 4];
        flood.push(tokio::spawn(async move { call(&r, "POST", path).await.0 }));
    }
    let t0 = Instant::now();
    let (s, v) = call(&r, "POST", "/api/abort").await;
    assert_eq!(s, StatusCode::OK, "{v}");
    assert_eq!(v["state"], "aborted");
    let v = status(&r).await;
    assert_eq!(v["state"], "aborted");
    assert!(t0.elapsed() < Duration::from_secs(1), "{:?}", t0.elapsed());
    // The flood is answered; the few requests the rate limit lets through may reach
    // the bench after the abort (the tasks run concurrently with it), and a `run` or
    // `calibrate` among them legitimately starts anew.
    let mut limited = 0;
    for f in flood {
        if f.await.expect("task") == StatusCode::TOO_MANY_REQUESTS {
            limited += 1;
        }
    }
    // A `run` of the flood that reached the bench after the abort may have been
    // paused by a later `pause` of it, and would wait for a resume forever: the
    // operator's abort once the flood is over stops whatever it left.
    let (s, v) = call(&r, "POST", "/api/abort").await;
    assert_eq!(s, StatusCode::OK, "{v}");
    // The bench reaches its safe state once the control thread's clock ticks: the
    // aborted run (or a run started after it, run to its end) with the pipette out.
    let v = until(&r, Duration::from_secs(POLL_S), |v| v["task"].is_null()).await;
    assert!(
        v["state"] == "aborted" || v["state"] == "finished" || v["state"] == "idle",
        "{v}"
    );
    assert_eq!(v["retracted"], true, "{v}");
    // The burst is 20: the rest of the flood was turned away.
    assert!(limited >= 950, "{limited} of 1000 rate-limited");
    // Abort itself is never limited, flood or not.
    for _ in 0..50 {
        assert_eq!(call(&r, "POST", "/api/abort").await.0, StatusCode::OK);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn abort_answers_while_the_bench_is_stuck() {
    let b = bench(loopback(), false, 0.05);
    let r = &b.router;
    b.stall.store(true, Ordering::SeqCst);
    call(r, "POST", "/api/run").await;
    until(r, Duration::from_secs(POLL_S), |v| {
        v["run"]["cells_found"] == 6
    })
    .await;
    let t0 = Instant::now();
    let (s, v) = call(r, "POST", "/api/abort").await;
    assert!(t0.elapsed() < Duration::from_millis(500));
    assert_eq!(s, StatusCode::OK);
    assert_eq!(v["state"], "aborted");
    assert_eq!(
        v["stopping"], true,
        "the bench has not reached its safe state yet"
    );
    // Once the camera answers again, the run ends there.
    b.stall.store(false, Ordering::SeqCst);
    let v = until(r, Duration::from_secs(POLL_S), |v| v["task"].is_null()).await;
    assert_eq!(v["state"], "aborted");
    assert_eq!(v["run"]["done"], 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn jogs_are_refused_past_the_limits() {
    let b = bench(loopback(), true, 0.05);
    let r = &b.router;
    let jog = |body: &str| {
        req("POST", "/api/jog")
            .header(header::CONTENT_TYPE, "application/json")
            .body(Body::from(body.to_string()))
            .expect("request")
    };
    let (s, v, _) = send(r, jog(r#"{"axis": "A3", "by": 5.0}"#)).await;
    assert_eq!(s, StatusCode::OK, "{v}");
    assert_eq!(v["actuators_v"][2], 5.0);
    for (body, what) in [
        (r#"{"axis": "A3", "by": 11.0}"#, "at most 10 V"),
        (r#"{"axis": "x", "by": 1e-3}"#, "at most 0.0001 m"),
        (r#"{"axis": "A4", "by": 1.0}"#, "unknown variant"),
        (r#"{"axis": "A1", "by": "NaN"}"#, "invalid type"),
        (r#"{"axis": "A1"}"#, "missing field"),
        ("not json", "the body must be"),
    ] {
        let (s, v, _) = send(r, jog(body)).await;
        assert_eq!(s, StatusCode::BAD_REQUEST, "{body}: {v}");
        assert!(
            v["error"].as_str().unwrap_or("").contains(what),
            "{body}: {v}"
        );
    }
    // A3 driven up in steps: the amplifier's range (or the envelope) refuses the step
    // that would pass it, and the last accepted voltage stays.
    let v_max = RigParams::default().amplifiers[2].v_max;
    let mut refused = None;
    for _ in 0..40 {
        // Each jog once the last one's task has let go of the bench (its answer may come
        // first): a busy bench is a 409 too, and is not what this measures.
        until(r, Duration::from_secs(POLL_S), |v| v["task"].is_null()).await;
        let (s, v, _) = send(r, jog(r#"{"axis": "A3", "by": 10.0}"#)).await;
        if s == StatusCode::CONFLICT {
            refused = Some(v);
            break;
        }
        assert_eq!(s, StatusCode::OK, "{v}");
        assert!(v["actuators_v"][2].as_f64().unwrap_or(f64::NAN) <= v_max);
    }
    let v = refused.expect("a jog past the range is refused");
    assert!(
        v["error"].as_str().unwrap_or("").contains("jog A3 by 10"),
        "{v}"
    );
    let after = status(r).await;
    assert!(after["actuators_v"][2].as_f64().unwrap_or(f64::NAN) <= v_max);
    // The safe state brings every stack back (once the refused jog's task is released:
    // its answer may come before the control thread lets go of the bench).
    until(r, Duration::from_secs(POLL_S), |v| v["task"].is_null()).await;
    let (s, _) = call(r, "POST", "/api/safe").await;
    assert_eq!(s, StatusCode::ACCEPTED);
    until(r, Duration::from_secs(POLL_S), |v| {
        v["safe"] == true && v["task"].is_null()
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn remote_access_needs_the_token_for_every_control_endpoint() {
    let access = remote(false);
    let token = access.token.clone().expect("a token");
    let b = bench(access, true, 0.05);
    let r = &b.router;
    for path in [
        "/api/run",
        "/api/pause",
        "/api/resume",
        "/api/abort",
        "/api/calibrate",
        "/api/safe",
        "/api/jog",
    ] {
        let (s, v) = call(r, "POST", path).await;
        assert_eq!(s, StatusCode::UNAUTHORIZED, "{path}: {v}");
        let wrong = req("POST", path)
            .header(header::AUTHORIZATION, "Bearer 0000")
            .body(Body::empty())
            .expect("request");
        assert_eq!(send(r, wrong).await.0, StatusCode::UNAUTHORIZED, "{path}");
    }
    // Without --public-view, viewing needs it too; the page answers with the login.
    for path in ["/api/status", "/api/events", "/api/runs", "/runs/1"] {
        assert_eq!(
            call(r, "GET", path).await.0,
            StatusCode::UNAUTHORIZED,
            "{path}"
        );
    }
    let (s, v) = call(r, "GET", "/").await;
    assert_eq!(s, StatusCode::UNAUTHORIZED);
    assert!(v.as_str().unwrap_or("").contains("access token"));
    // With the token.
    let with = req("GET", "/api/status")
        .header(header::AUTHORIZATION, format!("Bearer {token}"))
        .body(Body::empty())
        .expect("request");
    assert_eq!(send(r, with).await.0, StatusCode::OK);
    let with = req("POST", "/api/abort")
        .header(header::AUTHORIZATION, format!("bearer {token}"))
        .body(Body::empty())
        .expect("request");
    assert_eq!(send(r, with).await.0, StatusCode::OK);
    // A wrong token buys no session; the right one buys an HttpOnly cookie.
    let (s, _, _) = send(r, login("nope")).await;
    assert_eq!(s, StatusCode::UNAUTHORIZED);
    let cookie = session_cookie(r, &token).await;
    assert!(cookie.contains("HttpOnly") && cookie.contains("SameSite=Strict"));
    let pair = cookie.split(';').next().expect("name=value").to_string();
    let with = req("GET", "/api/status")
        .header(header::COOKIE, pair.clone())
        .body(Body::empty())
        .expect("request");
    assert_eq!(send(r, with).await.0, StatusCode::OK);
    // Past the token check: nothing to pause.
    let with = req("POST", "/api/pause")
        .header(header::COOKIE, pair.clone())
        .body(Body::empty())
        .expect("request");
    assert_eq!(send(r, with).await.0, StatusCode::CONFLICT);
    // The page link with the token sets the cookie and leaves the token behind.
    let (s, _, h) = send(
        r,
        req("GET", &format!("/?token={token}"))
            .body(Body::empty())
            .expect("request"),
    )
    .await;
    assert_eq!(s, StatusCode::SEE_OTHER);
    assert_eq!(
        h.get(header::LOCATION).and_then(|v| v.to_str().ok()),
        Some("/")
    );
    assert!(h.get(header::SET_COOKIE).is_some());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_session_ends_with_its_lifetime() {
    let access = Access {
        session_lifetime: Duration::from_secs(2),
        ..remote(false)
    };
    let token = access.token.clone().expect("a token");
    let b = bench(access, true, 0.05);
    let r = &b.router;
    let cookie = session_cookie(r, &token).await;
    assert!(cookie.contains("Max-Age=2"), "{cookie}");
    let pair = cookie.split(';').next().expect("name=value").to_string();
    let status = || {
        req("GET", "/api/status")
            .header(header::COOKIE, pair.clone())
            .body(Body::empty())
            .expect("request")
    };
    assert_eq!(send(r, status()).await.0, StatusCode::OK);
    tokio::time::sleep(Duration::from_millis(2500)).await;
    let (s, v, _) = send(r, status()).await;
    assert_eq!(s, StatusCode::UNAUTHORIZED, "{v}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn public_view_opens_viewing_only() {
    let b = bench(remote(true), true, 0.05);
    let r = &b.router;
    assert_eq!(call(r, "GET", "/api/status").await.0, StatusCode::OK);
    assert_eq!(call(r, "GET", "/api/runs").await.0, StatusCode::OK);
    let (s, v) = call(r, "GET", "/").await;
    assert_eq!(s, StatusCode::OK);
    assert!(v.as_str().unwrap_or("").contains("ABORT"));
    assert_eq!(
        call(r, "POST", "/api/run").await.0,
        StatusCode::UNAUTHORIZED
    );
    assert_eq!(
        call(r, "POST", "/api/abort").await.0,
        StatusCode::UNAUTHORIZED
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn forged_hosts_and_foreign_origins_are_refused() {
    let b = bench(loopback(), true, 0.05);
    let r = &b.router;
    for host in ["evil.example", "evil.example:8080", "10.1.2.3:8080", ""] {
        for (m, p) in [("GET", "/"), ("GET", "/api/status"), ("POST", "/api/abort")] {
            let q = Request::builder()
                .method(m)
                .uri(p)
                .header(header::HOST, host)
                .body(Body::empty())
                .expect("request");
            let (s, v, _) = send(r, q).await;
            assert_eq!(s, StatusCode::FORBIDDEN, "Host {host} {m} {p}: {v}");
        }
    }
    for host in [
        "localhost:8080",
        "127.0.0.1:8080",
        "[::1]:8080",
        "LOCALHOST",
    ] {
        let q = Request::builder()
            .uri("/api/status")
            .header(header::HOST, host)
            .body(Body::empty())
            .expect("request");
        assert_eq!(send(r, q).await.0, StatusCode::OK, "{host}");
    }
    for (origin, ok) in [
        ("http://localhost:8080", true),
        ("http://LOCALHOST:8080/", true),
        // Another origin of the same machine: another site (a dev server, a notebook).
        ("http://localhost:3000", false),
        ("http://127.0.0.1:8080", false),
        ("https://localhost:8080", false),
        ("http://localhost", false),
        ("http://evil.example", false),
        ("http://localhost.evil.example:8080", false),
        ("null", false),
        ("file://", false),
    ] {
        let q = req("POST", "/api/safe")
            .header(header::ORIGIN, origin)
            .body(Body::empty())
            .expect("request");
        let (s, v, _) = send(r, q).await;
        if ok {
            assert_ne!(s, StatusCode::FORBIDDEN, "{origin}: {v}");
        } else {
            assert_eq!(s, StatusCode::FORBIDDEN, "{origin}: {v}");
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn records_reports_and_unknown_paths() {
    let b = bench(loopback(), true, 0.05);
    let r = &b.router;
    // Never framed by another site, never sniffed, no token in a Referer.
    let (_, _, h) = send(r, req("GET", "/").body(Body::empty()).expect("request")).await;
    assert_eq!(
        h.get(header::X_FRAME_OPTIONS).and_then(|v| v.to_str().ok()),
        Some("DENY")
    );
    assert_eq!(
        h.get(header::CONTENT_SECURITY_POLICY)
            .and_then(|v| v.to_str().ok()),
        Some("frame-ancestors 'none'")
    );
    assert_eq!(
        h.get(header::REFERRER_POLICY).and_then(|v| v.to_str().ok()),
        Some("no-referrer")
    );
    let (s, v) = call(r, "GET", "/api/runs").await;
    assert_eq!(s, StatusCode::OK);
    assert_eq!(v[0]["status"], "aborted");
    let (s, v) = call(r, "GET", "/runs/1").await;
    assert_eq!(s, StatusCode::OK);
    assert!(v.as_str().unwrap_or("").contains("run 1"));
    let (s, v) = call(r, "GET", "/runs/7").await;
    assert_eq!(s, StatusCode::NOT_FOUND, "{v}");
    let (s, v) = call(r, "GET", "/runs/seven").await;
    assert_eq!(s, StatusCode::BAD_REQUEST, "{v}");
    assert!(v["error"].as_str().unwrap_or("").contains("seven"));
    let (s, v) = call(r, "GET", "/api/nothing").await;
    assert_eq!(s, StatusCode::NOT_FOUND, "{v}");
    // The status carries the view's tip and a frame count once frames flow.
    let v = until(r, Duration::from_secs(POLL_S), |v| {
        v["frames"].as_u64() > Some(0)
    })
    .await;
    assert_eq!(v["tip_m"][2], 2e-6);
}

/// `GET path` as a stream: its content type and what arrives within 1.1 s.
async fn stream(r: &Router, path: &str) -> (Option<String>, Vec<u8>) {
    use futures_util::StreamExt;
    let resp = r
        .clone()
        .oneshot(req("GET", path).body(Body::empty()).expect("request"))
        .await
        .expect("infallible");
    assert_eq!(resp.status(), StatusCode::OK, "{path}");
    let kind = resp
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .map(str::to_string);
    let mut body = resp.into_body().into_data_stream();
    let mut bytes = Vec::new();
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_millis(1100) {
        match tokio::time::timeout(Duration::from_millis(200), body.next()).await {
            Ok(Some(Ok(chunk))) => bytes.extend_from_slice(&chunk),
            Ok(_) => break,
            Err(_) => {}
        }
    }
    (kind, bytes)
}

/// Frames arrive on the live stream at the view's rate.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_live_stream_carries_frames_and_status() {
    let b = bench(loopback(), true, 0.05);
    let (kind, bytes) = stream(&b.router, "/api/events").await;
    assert_eq!(kind.as_deref(), Some("text/event-stream"));
    let text = String::from_utf8_lossy(&bytes);
    let frames = text.matches("event: frame").count();
    let statuses = text.matches("event: status").count();
    // 15 frames a second, 5 statuses.
    assert!(frames >= 10, "{frames} frames in 1.1 s");
    assert!(statuses >= 4, "{statuses} statuses in 1.1 s");
    assert!(
        text.contains("\"gray8\":\"AEC"),
        "the first pixels 0, 64, 128 in base64"
    );
}

/// The MJPEG stream: one JPEG per frame, at the view's rate.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_mjpeg_stream_carries_jpeg_frames() {
    let b = bench(loopback(), true, 0.05);
    let (kind, bytes) = stream(&b.router, "/api/stream.mjpeg").await;
    assert_eq!(
        kind.as_deref(),
        Some("multipart/x-mixed-replace; boundary=frame")
    );
    let parts = bytes.windows(7).filter(|w| w == b"--frame").count();
    assert!(parts >= 10, "{parts} frames in 1.1 s");
    let text = String::from_utf8_lossy(&bytes);
    assert!(text.contains("Content-Type: image/jpeg"));
    // JPEG start and end of image markers.
    assert!(bytes.windows(2).any(|w| w == [0xff, 0xd8]));
    assert!(bytes.windows(2).any(|w| w == [0xff, 0xd9]));
}
