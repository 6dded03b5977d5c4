//! The web side: the page, the JSON API, the live stream, and the checks every request
//! passes first (Host and Origin against DNS rebinding and cross-site requests, the
//! access token when remote access is on, a rate limit on control requests that abort
//! never meets).

use std::collections::HashMap;
use std::convert::Infallible;
use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::Ordering;
use std::sync::mpsc::Sender;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::Router;
use axum::extract::connect_info::Connected;
use axum::extract::{ConnectInfo, Path, Query, Request, State};
use axum::http::{HeaderMap, HeaderValue, Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{Html, IntoResponse, Redirect, Response};
use axum::routing::{get, post};
use base64::Engine;
use serde_json::json;
use thiserror::Error;
use tokio::net::TcpListener;
use tokio::sync::watch;

use crate::bench::{Archive, BenchState, Command, Jog, Shared, ViewFrame};
use crate::watch::lock;

/// How the server is reached and who may use it.
#[derive(Debug, Clone, PartialEq)]
pub struct Access {
    /// The address it listens on.
    pub bind: SocketAddr,
    /// Every request but the page's login needs the token (or the session cookie it
    /// buys); None on loopback, where no token is needed.
    pub token: Option<String>,
    /// Viewing (the page, status, stream, records) without the token.
    pub public_view: bool,
    /// Further names the Host header may carry.
    pub allowed_hosts: Vec<String>,
    /// Control requests per second (abort excepted), sustained.
    pub control_rate: f64,
    /// Control requests in a burst.
    pub control_burst: f64,
    /// How long a session cookie bought with the token lasts (the browser forgets it
    /// then too, and the token must be given again).
    pub session_lifetime: Duration,
}

/// Why the server cannot start.
#[derive(Debug, Error)]
pub enum DashboardError {
    /// A non-loopback address without `--allow-remote`.
    #[error(
        "--bind {0}: not a loopback address; a control page on a network can move the pipette: give --allow-remote (every control request then needs the access token printed at start)"
    )]
    RemoteNotAllowed(SocketAddr),
    /// The address cannot be listened on.
    #[error("--bind {addr}: {source}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// Why.
        source: std::io::Error,
    },
    /// A `--allowed-host` that is not a host name.
    #[error("--allowed-host `{0}`: not a host name (letters, digits, '-', '.', or an IP address)")]
    BadHost(String),
    /// The system's random source failed.
    #[error("no random access token: {0}")]
    Random(String),
    /// The bench did not reach its safe state when the server stopped.
    #[error(
        "the bench did not reach its safe state within {0} s of the stop (a device is not answering): check it before using it"
    )]
    Stuck(f64),
    /// The runtime could not start.
    #[error("the web runtime: {0}")]
    Runtime(std::io::Error),
}

impl Access {
    /// Loopback-only access, or remote access with a fresh random token. Refuses a
    /// non-loopback address without `allow_remote`, and host names that are not.
    pub fn new(
        bind: SocketAddr,
        allow_remote: bool,
        public_view: bool,
        allowed_hosts: Vec<String>,
    ) -> Result<Self, DashboardError> {
        for h in &allowed_hosts {
            let ok = !h.is_empty()
                && (h.parse::<IpAddr>().is_ok()
                    || h.chars()
                        .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '.'));
            if !ok {
                return Err(DashboardError::BadHost(h.clone()));
            }
        }
        let loopback = bind.ip().is_loopback();
        if !loopback && !allow_remote {
            return Err(DashboardError::RemoteNotAllowed(bind));
        }
        let token = if allow_remote {
            Some(random_hex(24).map_err(DashboardError::Random)?)
        } else {
            None
        };
        Ok(Access {
            bind,
            token,
            public_view,
            allowed_hosts: allowed_hosts
                .into_iter()
                .map(|h| h.to_ascii_lowercase())
                .collect(),
            control_rate: 10.0,
            control_burst: 20.0,
            session_lifetime: Duration::from_secs(12 * 3600),
        })
    }

    /// Whether a request may name `host` (its Host header, or its Origin's host),
    /// coming in on local address `local`.
    pub fn host_allowed(&self, host: &str, local: Option<SocketAddr>) -> bool {
        let name = host_name(host).to_ascii_lowercase();
        if matches!(name.as_str(), "localhost" | "127.0.0.1" | "::1") {
            return true;
        }
        if self.allowed_hosts.contains(&name) {
            return true;
        }
        let Ok(ip) = name.parse::<IpAddr>() else {
            return false;
        };
        let ip = ip.to_canonical();
        if self.bind.ip().is_unspecified() {
            // One of the machine's own addresses: the one this connection came to
            // (an IPv4 client of a dual-stack socket arrives as ::ffff:a.b.c.d).
            local.is_some_and(|l| l.ip().to_canonical() == ip)
        } else {
            ip == self.bind.ip().to_canonical()
        }
    }
}

/// The host part of a Host header (`name`, `name:port`, `[v6]:port`, `[v6]`).
fn host_name(h: &str) -> &str {
    let h = h.trim();
    if let Some(rest) = h.strip_prefix('[') {
        return rest.split(']').next().unwrap_or("");
    }
    match h.rsplit_once(':') {
        Some((name, port)) if !name.contains(':') && port.chars().all(|c| c.is_ascii_digit()) => {
            name
        }
        _ => h,
    }
}

/// `n` random bytes as hex.
fn random_hex(n: usize) -> Result<String, String> {
    let mut b = vec![0u8; n];
    getrandom::fill(&mut b).map_err(|e| e.to_string())?;
    Ok(b.iter().map(|x| format!("{x:02x}")).collect())
}

/// The address a connection came in on and the peer's.
#[derive(Debug, Clone, Copy)]
pub struct Conn {
    /// This machine's address the client connected to.
    pub local: Option<SocketAddr>,
    /// The client.
    pub peer: SocketAddr,
}

impl Connected<axum::serve::IncomingStream<'_, TcpListener>> for Conn {
    fn connect_info(s: axum::serve::IncomingStream<'_, TcpListener>) -> Self {
        Conn {
            local: s.io().local_addr().ok(),
            peer: *s.remote_addr(),
        }
    }
}

/// A token bucket.
struct Bucket {
    tokens: f64,
    at: Instant,
}

/// The server's state.
pub struct App {
    /// Shared with the control and view threads.
    pub shared: Arc<Shared>,
    /// Commands to the control thread.
    cmd: Mutex<Sender<Command>>,
    access: Access,
    /// Session ids and when each expires.
    sessions: Mutex<HashMap<String, Instant>>,
    bucket: Mutex<Bucket>,
    archive: Arc<dyn Archive>,
    /// The newest view frame, as the stream sends it.
    pub frames: watch::Receiver<Option<Arc<FrameMsg>>>,
}

/// A view frame ready to send.
#[derive(Debug)]
pub struct FrameMsg {
    /// The stream event's JSON.
    pub json: String,
    /// Count since the server started.
    pub n: u64,
    /// The frame itself (the tip for the status, the pixels for the MJPEG stream).
    pub frame: ViewFrame,
}

/// The frame as a JPEG (quality 80), or None if it cannot be encoded.
pub fn jpeg(f: &FrameMsg) -> Option<Vec<u8>> {
    let v = &f.frame;
    let mut out = Vec::with_capacity(v.pixels.len() / 4 + 1024);
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 80)
        .encode(&v.pixels, v.width, v.height, image::ExtendedColorType::L8)
        .ok()?;
    Some(out)
}

/// Encodes a view frame for the stream (the frame moves into the message).
pub fn frame_msg(f: ViewFrame, n: u64) -> FrameMsg {
    let data = base64::engine::general_purpose::STANDARD.encode(&f.pixels);
    let json = json!({
        "n": n,
        "width": f.width,
        "height": f.height,
        "origin_m": f.origin_m,
        "pitch_m": f.pitch_m,
        "to_view": f.to_view,
        "tip_m": f.tip_m,
        "roi_m": f.roi_m,
        "time_s": f.time_s,
        "gray8": data,
    })
    .to_string();
    FrameMsg { json, n, frame: f }
}

impl App {
    /// The server's state over the control thread's `cmd` channel.
    pub fn new(
        shared: Arc<Shared>,
        cmd: Sender<Command>,
        access: Access,
        archive: Arc<dyn Archive>,
        frames: watch::Receiver<Option<Arc<FrameMsg>>>,
    ) -> Arc<Self> {
        let burst = access.control_burst;
        Arc::new(App {
            shared,
            cmd: Mutex::new(cmd),
            access,
            sessions: Mutex::new(HashMap::new()),
            bucket: Mutex::new(Bucket {
                tokens: burst,
                at: Instant::now(),
            }),
            archive,
            frames,
        })
    }

    fn authorized(&self, headers: &HeaderMap) -> bool {
        let Some(token) = &self.access.token else {
            return true;
        };
        if let Some(a) = headers
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            && let Some((scheme, t)) = a.split_once(' ')
            && scheme.eq_ignore_ascii_case("bearer")
            && same(t.trim(), token)
        {
            return true;
        }
        let sessions = lock(&self.sessions);
        let now = Instant::now();
        cookies(headers)
            .any(|(k, v)| k == COOKIE && sessions.get(v).is_some_and(|expires| *expires > now))
    }

    fn take_control_token(&self) -> bool {
        let mut b = lock(&self.bucket);
        let now = Instant::now();
        let dt = now.duration_since(b.at).as_secs_f64();
        b.at = now;
        b.tokens = (b.tokens + dt * self.access.control_rate).min(self.access.control_burst);
        if b.tokens >= 1.0 {
            b.tokens -= 1.0;
            true
        } else {
            false
        }
    }

    fn send(&self, c: Command) -> bool {
        lock(&self.cmd).send(c).is_ok()
    }

    /// `GET /api/status`'s document.
    pub fn status(&self) -> serde_json::Value {
        let b = self.shared.board();
        let r = self.shared.telemetry.readings();
        let frame = self.frames.borrow().clone();
        json!({
            "state": b.state,
            "task": b.task,
            "stopping": b.stopping,
            "message": b.message,
            "backend": self.shared.backend,
            "fast": self.shared.control.fast(),
            "run": b.run,
            "tip_m": frame.as_ref().and_then(|f| f.frame.tip_m),
            "actuators_v": r.volts,
            "sensors_m": r.sensors,
            "stage_m": r.stage,
            "zoom": r.zoom,
            "time_s": r.time,
            "retracted": r.volts[2] == 0.0,
            "safe": r.volts == [0.0; 3],
            "calibrated": b.calibrated,
            "plate": self.shared.plate,
            "loop_a1": r.loop_a1,
            "log": b.log,
            "frames": frame.as_ref().map_or(0, |f| f.n),
        })
    }
}

const COOKIE: &str = "cellinject_session";

fn cookies(h: &HeaderMap) -> impl Iterator<Item = (&str, &str)> {
    h.get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|kv| kv.trim().split_once('='))
}

/// Compares secrets in time independent of where they differ.
fn same(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

fn error(code: StatusCode, msg: impl Into<String>) -> Response {
    (code, axum::Json(json!({ "error": msg.into() }))).into_response()
}

/// What a route needs.
#[derive(PartialEq)]
enum Need {
    /// The login exchange and the login page: nothing.
    Nothing,
    /// Viewing: the token unless `--public-view`.
    View,
    /// Control: the token, and the rate limit unless `limited` is false (abort).
    Control { limited: bool },
}

fn need(method: &Method, path: &str) -> Need {
    if path == "/api/session" || path == "/" {
        // The page decides itself between the dashboard and the login (and takes a
        // token link).
        return Need::Nothing;
    }
    if method == Method::POST {
        return Need::Control {
            limited: path != "/api/abort",
        };
    }
    Need::View
}

/// Every request's checks: Host, Origin, the token, the rate limit.
async fn guard(State(app): State<Arc<App>>, req: Request, next: Next) -> Response {
    let local = req
        .extensions()
        .get::<ConnectInfo<Conn>>()
        .and_then(|c| c.0.local);
    let headers = req.headers();
    let host = headers
        .get(header::HOST)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    if !app.access.host_allowed(host, local) {
        return error(
            StatusCode::FORBIDDEN,
            format!(
                "Host `{host}` is not this server's (localhost, its address, or an --allowed-host)"
            ),
        );
    }
    if let Some(origin) = headers.get(header::ORIGIN) {
        // The page's own origin only: the scheme this server speaks and the very host
        // and port the request is addressed to (another port on the same host is
        // another site: a dev server, a notebook).
        let o = origin.to_str().unwrap_or("");
        let ok = o
            .strip_prefix("http://")
            .is_some_and(|rest| rest.trim_end_matches('/').eq_ignore_ascii_case(host.trim()));
        if !ok {
            return error(
                StatusCode::FORBIDDEN,
                format!("Origin `{o}` is not this server's: cross-site requests are refused"),
            );
        }
    }
    let n = need(req.method(), req.uri().path());
    let authorized = app.authorized(headers);
    match n {
        Need::Nothing => {}
        Need::View if authorized || app.access.public_view => {}
        Need::Control { .. } | Need::View if !authorized => {
            return error(
                StatusCode::UNAUTHORIZED,
                "remote access needs the access token: `Authorization: Bearer TOKEN`, or the session cookie from POST /api/session",
            );
        }
        _ => {}
    }
    let limited = n == (Need::Control { limited: true })
        || (req.method() == Method::POST && req.uri().path() == "/api/session");
    if limited && !app.take_control_token() {
        return error(
            StatusCode::TOO_MANY_REQUESTS,
            format!(
                "too many control requests: at most {} a second (abort is never limited)",
                app.access.control_rate
            ),
        );
    }
    let mut r = next.run(req).await;
    // Never in a frame of another site (clickjacking), never sniffed, and no token
    // link in a Referer.
    let h = r.headers_mut();
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static("frame-ancestors 'none'"),
    );
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    r
}

/// The router: every route behind [`guard`].
pub fn router(app: Arc<App>) -> Router {
    Router::new()
        .route("/", get(page))
        .route("/api/status", get(status))
        .route("/api/events", get(events))
        .route("/api/stream.mjpeg", get(mjpeg))
        .route("/api/runs", get(runs))
        .route("/runs/{id}", get(report))
        .route("/api/session", post(session))
        .route("/api/run", post(run))
        .route("/api/pause", post(pause))
        .route("/api/resume", post(resume))
        .route("/api/abort", post(abort))
        .route("/api/calibrate", post(calibrate))
        .route("/api/safe", post(safe))
        .route("/api/jog", post(jog))
        .fallback(|| async { error(StatusCode::NOT_FOUND, "no such page: see /api/status") })
        .layer(axum::middleware::from_fn_with_state(app.clone(), guard))
        .with_state(app)
}

const PAGE: &str = include_str!("page.html");
const LOGIN: &str = include_str!("login.html");

#[derive(serde::Deserialize)]
struct TokenQuery {
    token: Option<String>,
}

async fn page(
    State(app): State<Arc<App>>,
    Query(q): Query<TokenQuery>,
    headers: HeaderMap,
) -> Response {
    if let (Some(t), Some(token)) = (q.token, &app.access.token) {
        // A link with the token: exchanged for a session cookie, and the token leaves
        // the address bar.
        if !same(&t, token) {
            return (StatusCode::UNAUTHORIZED, Html(LOGIN)).into_response();
        }
        return with_session(&app, Redirect::to("/").into_response());
    }
    if app.access.token.is_some() && !app.authorized(&headers) && !app.access.public_view {
        return (StatusCode::UNAUTHORIZED, Html(LOGIN)).into_response();
    }
    Html(PAGE).into_response()
}

fn with_session(app: &App, mut r: Response) -> Response {
    let Ok(id) = random_hex(24) else {
        return error(StatusCode::INTERNAL_SERVER_ERROR, "no random session id");
    };
    let life = app.access.session_lifetime;
    {
        let mut sessions = lock(&app.sessions);
        let now = Instant::now();
        sessions.retain(|_, expires| *expires > now);
        sessions.insert(id.clone(), now + life);
    }
    if let Ok(v) = HeaderValue::from_str(&format!(
        "{COOKIE}={id}; HttpOnly; SameSite=Strict; Path=/; Max-Age={}",
        life.as_secs().max(1)
    )) {
        r.headers_mut().insert(header::SET_COOKIE, v);
    }
    r
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Login {
    token: String,
}

async fn session(State(app): State<Arc<App>>, body: axum::body::Bytes) -> Response {
    let Some(token) = &app.access.token else {
        return (
            StatusCode::OK,
            axum::Json(json!({ "session": "not needed on loopback" })),
        )
            .into_response();
    };
    let login: Login = match serde_json::from_slice(&body) {
        Ok(l) => l,
        Err(e) => {
            return error(
                StatusCode::BAD_REQUEST,
                format!("the body must be {{\"token\": \"...\"}}: {e}"),
            );
        }
    };
    if !same(&login.token, token) {
        return error(StatusCode::UNAUTHORIZED, "wrong access token");
    }
    with_session(
        &app,
        axum::Json(json!({ "session": "started" })).into_response(),
    )
}

async fn status(State(app): State<Arc<App>>) -> Response {
    axum::Json(app.status()).into_response()
}

async fn events(State(app): State<Arc<App>>) -> Response {
    let frames = app.frames.clone();
    let start = (app, frames, None::<Instant>);
    let stream = futures_util::stream::unfold(start, |(app, mut frames, last)| async move {
        loop {
            let due = last.map_or(Duration::ZERO, |t| {
                Duration::from_millis(200).saturating_sub(t.elapsed())
            });
            if due.is_zero() {
                let e = Event::default()
                    .event("status")
                    .data(app.status().to_string());
                return Some((Ok::<_, Infallible>(e), (app, frames, Some(Instant::now()))));
            }
            tokio::select! {
                r = frames.changed() => {
                    if r.is_err() {
                        return None;
                    }
                    let f = frames.borrow_and_update().clone();
                    if let Some(f) = f {
                        let e = Event::default().event("frame").data(f.json.as_str());
                        return Some((Ok(e), (app, frames, last)));
                    }
                }
                _ = tokio::time::sleep(due) => {}
            }
        }
    });
    Sse::new(stream)
        .keep_alive(KeepAlive::default())
        .into_response()
}

/// The live view alone as MJPEG (`multipart/x-mixed-replace`, one JPEG per frame):
/// for an `<img>`, a video player or another program. Frames are encoded for each
/// client as they come; a slow client gets the newest frame, never a backlog.
async fn mjpeg(State(app): State<Arc<App>>) -> Response {
    let frames = app.frames.clone();
    let stream = futures_util::stream::unfold(frames, |mut frames| async move {
        loop {
            frames.changed().await.ok()?;
            let Some(f) = frames.borrow_and_update().clone() else {
                continue;
            };
            let Ok(Some(jpg)) = tokio::task::spawn_blocking(move || jpeg(&f)).await else {
                continue;
            };
            let mut part = format!(
                "--frame\r\nContent-Type: image/jpeg\r\nContent-Length: {}\r\n\r\n",
                jpg.len()
            )
            .into_bytes();
            part.extend_from_slice(&jpg);
            part.extend_from_slice(b"\r\n");
            return Some((Ok::<_, Infallible>(axum::body::Bytes::from(part)), frames));
        }
    });
    let mut r = axum::body::Body::from_stream(stream).into_response();
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("multipart/x-mixed-replace; boundary=frame"),
    );
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    r
}

async fn runs(State(app): State<Arc<App>>) -> Response {
    let a = app.archive.clone();
    match tokio::task::spawn_blocking(move || a.runs()).await {
        Ok(Ok(v)) => axum::Json(v).into_response(),
        Ok(Err(e)) => error(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("the run records: {e}"),
        ),
        Err(e) => error(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()),
    }
}

async fn report(State(app): State<Arc<App>>, Path(id): Path<String>) -> Response {
    let Ok(id) = id.parse::<i64>() else {
        return error(
            StatusCode::BAD_REQUEST,
            format!("run id `{id}` is not a number"),
        );
    };
    let a = app.archive.clone();
    match tokio::task::spawn_blocking(move || a.report(id)).await {
        Ok(Ok(Some(html))) => Html(html).into_response(),
        Ok(Ok(None)) => error(StatusCode::NOT_FOUND, format!("no run {id}")),
        Ok(Err(e)) => error(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("the run records: {e}"),
        ),
        Err(e) => error(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()),
    }
}

fn accepted(app: &App) -> Response {
    (StatusCode::ACCEPTED, axum::Json(app.status())).into_response()
}

/// Takes the control thread for `task`, or says why not. Under the board's lock, as
/// abort's check is: an abort cannot fall between the claim and the switches' reset.
fn claim(app: &App, task: &'static str, state: Option<BenchState>) -> Result<(), String> {
    app.shared.update(|b| {
        if app
            .shared
            .busy
            .compare_exchange(false, true, Ordering::SeqCst, Ordering::SeqCst)
            .is_err()
        {
            let now = b.task.unwrap_or("a task");
            return Err(format!(
                "the bench is busy ({now}): wait for it, or abort it"
            ));
        }
        app.shared.control.reset();
        if let Some(s) = state {
            b.state = s;
        }
        b.task = Some(task);
        b.stopping = false;
        Ok(())
    })
}

fn dispatch(app: &App, c: Command, state: Option<BenchState>, task: &'static str) -> Response {
    if let Err(why) = claim(app, task, state) {
        return error(StatusCode::CONFLICT, why);
    }
    if !app.send(c) {
        app.shared.update(|b| {
            b.task = None;
            app.shared.busy.store(false, Ordering::SeqCst);
        });
        return error(
            StatusCode::INTERNAL_SERVER_ERROR,
            "the control thread has ended",
        );
    }
    accepted(app)
}

async fn run(State(app): State<Arc<App>>) -> Response {
    dispatch(&app, Command::Run, Some(BenchState::Running), "run")
}

async fn calibrate(State(app): State<Arc<App>>) -> Response {
    dispatch(&app, Command::Calibrate, None, "calibrate")
}

async fn safe(State(app): State<Arc<App>>) -> Response {
    dispatch(&app, Command::Safe, None, "safe")
}

async fn jog(State(app): State<Arc<App>>, body: axum::body::Bytes) -> Response {
    let j: Jog = match serde_json::from_slice(&body) {
        Ok(j) => j,
        Err(e) => {
            return error(
                StatusCode::BAD_REQUEST,
                format!(
                    "the body must be {{\"axis\": \"A1\"|\"A2\"|\"A3\"|\"x\"|\"y\"|\"z\", \"by\": step (V or m)}}: {e}"
                ),
            );
        }
    };
    if let Err(e) = j.check() {
        return error(StatusCode::BAD_REQUEST, e);
    }
    let (tx, rx) = tokio::sync::oneshot::channel();
    let r = dispatch(&app, Command::Jog(j, Some(tx)), None, "jog");
    if r.status() != StatusCode::ACCEPTED {
        return r;
    }
    // A jog is short: its outcome is the answer.
    match tokio::time::timeout(Duration::from_secs(10), rx).await {
        Ok(Ok(Ok(()))) => (StatusCode::OK, axum::Json(app.status())).into_response(),
        Ok(Ok(Err(e))) => error(StatusCode::CONFLICT, e),
        _ => error(
            StatusCode::GATEWAY_TIMEOUT,
            "the jog did not finish within 10 s: see /api/status",
        ),
    }
}

// Pause and resume decide under the board's lock, so that an abort between their
// check and their change cannot be overwritten (abort flips its switch first).

async fn pause(State(app): State<Arc<App>>) -> Response {
    let c = &app.shared.control;
    let ok = app.shared.update(|b| {
        let ok = b.task == Some("run") && !c.aborted();
        if ok {
            c.pause(true);
            b.state = BenchState::Paused;
        }
        ok
    });
    if !ok {
        return error(StatusCode::CONFLICT, "no run is going: nothing to pause");
    }
    (StatusCode::OK, axum::Json(app.status())).into_response()
}

async fn resume(State(app): State<Arc<App>>) -> Response {
    let c = &app.shared.control;
    let ok = app.shared.update(|b| {
        let ok = c.paused() && !c.aborted();
        if ok {
            c.pause(false);
            b.state = BenchState::Running;
        }
        ok
    });
    if !ok {
        return error(
            StatusCode::CONFLICT,
            "the run is not paused: nothing to resume",
        );
    }
    (StatusCode::OK, axum::Json(app.status())).into_response()
}

/// Abort: never queued behind anything. A task going is interrupted (the bench goes
/// to its safe state and the run is recorded aborted); with nothing going, the safe
/// state is commanded.
async fn abort(State(app): State<Arc<App>>) -> Response {
    let going = app.shared.update(|b| {
        if !app.shared.busy.load(Ordering::SeqCst) {
            return false;
        }
        app.shared.control.abort();
        if b.task == Some("run") || b.task == Some("calibrate") {
            b.state = BenchState::Aborted;
        }
        b.stopping = true;
        true
    });
    if !going && claim(&app, "safe", None).is_ok() {
        app.shared.update(|b| b.stopping = true);
        if !app.send(Command::Safe) {
            app.shared.update(|b| {
                b.task = None;
                app.shared.busy.store(false, Ordering::SeqCst);
            });
        }
    }
    (StatusCode::OK, axum::Json(app.status())).into_response()
}

/// Serves `app` on `listener` until `stop` resolves.
pub async fn serve_on(
    listener: TcpListener,
    app: Arc<App>,
    stop: impl std::future::Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    axum::serve(
        listener,
        router(app).into_make_service_with_connect_info::<Conn>(),
    )
    .with_graceful_shutdown(stop)
    .await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn host_names_are_parsed_with_and_without_ports() {
        assert_eq!(host_name("localhost:8080"), "localhost");
        assert_eq!(host_name("[::1]:8080"), "::1");
        assert_eq!(host_name("[::1]"), "::1");
        assert_eq!(host_name("10.0.0.2"), "10.0.0.2");
        assert_eq!(host_name("::1"), "::1");
    }

    #[test]
    fn hosts_are_checked_against_the_bound_address() {
        let a = Access::new(
            "127.0.0.1:8080".parse().expect("addr"),
            false,
            false,
            vec![],
        )
        .expect("loopback");
        assert!(a.token.is_none());
        assert!(a.host_allowed("localhost:8080", None));
        assert!(a.host_allowed("[::1]:8080", None));
        assert!(!a.host_allowed("evil.example:8080", None));
        assert!(!a.host_allowed("10.0.0.2:8080", None));
        let any: SocketAddr = "0.0.0.0:8080".parse().expect("addr");
        assert!(matches!(
            Access::new(any, false, false, vec![]),
            Err(DashboardError::RemoteNotAllowed(_))
        ));
        let r = Access::new(any, true, false, vec!["bench.lab".into()]).expect("remote");
        assert_eq!(r.token.as_ref().map(|t| t.len()), Some(48));
        let local = Some("10.0.0.2:8080".parse().expect("addr"));
        assert!(r.host_allowed("10.0.0.2:8080", local));
        assert!(r.host_allowed("BENCH.lab", local));
        assert!(!r.host_allowed("10.0.0.3:8080", local));
        assert!(matches!(
            Access::new(any, true, false, vec!["a b".into()]),
            Err(DashboardError::BadHost(_))
        ));
    }

    #[test]
    fn secrets_compare_whole() {
        assert!(same("abc", "abc"));
        assert!(!same("abc", "abd"));
        assert!(!same("abc", "abcd"));
    }
}
