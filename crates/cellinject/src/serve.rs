//! `cellinject serve`: the live web dashboard of one bench (the twin by default).

use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Result;
use cellinject_config::Description;
use cellinject_core::inject::Options;
use cellinject_dashboard::{Access, Control, DashboardError, Lifetime, Setup, Telemetry};
use cellinject_records::Records;
use clap::Args;

use crate::InputError;
use crate::run::{default_plate_text, records_error};

/// `cellinject serve`.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Address to listen on (loopback by default; any other needs --allow-remote;
    /// port 0 picks a free one).
    #[arg(long, default_value = "127.0.0.1:8080", value_name = "HOST:PORT")]
    bind: String,
    /// Listen beyond loopback: prints a random access token (`access token: TOKEN` on
    /// standard error) that every request must then carry.
    #[arg(long)]
    allow_remote: bool,
    /// With --allow-remote: the page, the status, the live view and the records
    /// without the token (control still needs it).
    #[arg(long)]
    public_view: bool,
    /// A further name the page may be reached by (e.g. bench.lab.example), checked
    /// against the Host header (repeatable).
    #[arg(long, value_name = "NAME")]
    allowed_host: Vec<String>,
    /// The plate a run injects (TOML; default: `run`'s generated 8 x 12 plate from
    /// the seed).
    #[arg(long, value_name = "FILE.toml")]
    plate: Option<PathBuf>,
    /// Seed of the twin (and of the default plate); default: the description's.
    #[arg(long)]
    seed: Option<u64>,
    /// The run database (as `cellinject run`'s).
    #[arg(long, default_value = "runs.sqlite")]
    db: PathBuf,
    /// Injected volume, fraction of each cell's volume.
    #[arg(long, default_value_t = 0.05, allow_negative_numbers = true)]
    dose: f64,
    /// The twin flat out instead of paced to wall time (the live view then shows
    /// moments of a faster world).
    #[arg(long)]
    fast: bool,
    #[command(flatten)]
    backend: crate::backend::BackendArgs,
    /// Stop serving after this many seconds (default: until Ctrl-C or SIGTERM, which
    /// also end it earlier); whatever is going is aborted and recorded first.
    #[arg(long, value_name = "SECONDS", allow_negative_numbers = true)]
    serve_for: Option<f64>,
}

fn dashboard_error(e: DashboardError) -> anyhow::Error {
    match e {
        DashboardError::RemoteNotAllowed(_)
        | DashboardError::BadHost(_)
        | DashboardError::Bind { .. } => InputError(e.to_string()).into(),
        other => anyhow::anyhow!("{other}"),
    }
}

/// `cellinject serve`.
pub fn serve(d: &Description, a: &ServeArgs) -> Result<()> {
    let lifetime = match a.serve_for {
        None => Lifetime::UntilSignal,
        Some(t) if t.is_finite() && t > 0.0 && t <= 1e7 => Lifetime::For(t),
        Some(t) => {
            return Err(InputError(format!("--serve-for must lie in (0, 1e7] s, got {t}")).into());
        }
    };
    let bind: SocketAddr = a.bind.parse().map_err(|_| {
        InputError(format!(
            "--bind `{}`: expected HOST:PORT with HOST an IP address (127.0.0.1:8080, [::1]:8080, 0.0.0.0:8080)",
            a.bind
        ))
    })?;
    if a.public_view && !a.allow_remote {
        return Err(InputError(
            "--public-view opens viewing to the network without the token: it needs --allow-remote (on loopback nothing needs a token)".into(),
        )
        .into());
    }
    let access = Access::new(bind, a.allow_remote, a.public_view, a.allowed_host.clone())
        .map_err(dashboard_error)?;
    let options = Options {
        target_fraction: a.dose,
        ..Options::default()
    };
    options
        .check(&d.rig)
        .map_err(|e| InputError(e.to_string()))?;
    let bench = a.backend.rig()?;
    let remote = !bench.is_twin();
    if remote {
        crate::run::gcs_run_checks(a.plate.is_some(), a.seed.is_some())?;
        if a.fast {
            return Err(InputError(
                "--fast runs the twin flat out: a GCS backend keeps wall-clock time".into(),
            )
            .into());
        }
    }
    let seed = a.seed.unwrap_or(d.sim.seed);
    let (plate, plate_text) = match &a.plate {
        Some(p) => crate::run::read_plate(p)?,
        None => default_plate_text(seed)?,
    };
    let control = Arc::new(Control::new(a.fast));
    let telemetry = Arc::new(Telemetry::default());
    let opened = crate::backend::open_with(
        d,
        &if remote {
            crate::sim::TwinArgs::new(None, None)
        } else {
            crate::sim::TwinArgs::with_seed(seed)
        },
        &bench,
        |devices| cellinject_dashboard::instrument(devices, &telemetry, &control, remote),
    )?;
    let mut opened = opened;
    // A plate the feeder cannot present is refused now, not at the first run.
    crate::plate::feeder_presents(d, &mut opened, &plate, options, "--plate")?;
    // The database is opened (and refused if foreign) before anything is listened on,
    // and after the plate is checked (a refused plate leaves no file).
    drop(Records::open(&a.db).map_err(records_error)?);
    let (station, viewer, archive) = cellinject_station::station(
        cellinject_station::Bench {
            d: d.clone(),
            opened,
            plate,
            plate_text,
            seed,
            db: a.db.clone(),
            options,
        },
        &telemetry,
    );
    let token = access.token.clone();
    let setup = Setup {
        station,
        viewer,
        archive,
        control,
        telemetry,
    };
    cellinject_dashboard::serve(access, setup, lifetime, |addr| {
        let shown = if addr.ip().is_unspecified() {
            format!("http://localhost:{}/", addr.port())
        } else {
            format!("http://{addr}/")
        };
        // Standard error may be a closed pipe (`2>&1 | head -1`): never a panic.
        let mut e = std::io::stderr();
        let _ = writeln!(e, "dashboard: {shown} (Ctrl-C to stop)");
        if let Some(t) = &token {
            let _ = writeln!(e, "access token: {t}");
            let _ = writeln!(
                e,
                "open {shown}?token={t} once in a browser: it keeps a session cookie"
            );
        }
    })
    .map_err(dashboard_error)
}
