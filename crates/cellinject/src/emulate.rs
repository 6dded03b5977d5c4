//! `cellinject emulate gcs`: the twin behind an emulated PI GCS 2.0 controller;
//! `cellinject emulate sensapex`: Sensapex devices over SMCP1.

use std::net::TcpListener;
use std::path::PathBuf;

use anyhow::Result;
use cellinject_config::Description;
use clap::{Args, Subcommand};

use crate::InputError;

/// Emulated devices.
#[derive(Debug, Subcommand)]
pub enum EmulateCommand {
    /// A PI GCS 2.0 piezo controller (E-727-like, axes 1, 2, 3 = the twin's A1, A2, A3)
    /// on TCP, and the rest of the bench (cameras, stage, injector, zoom) on the bench
    /// endpoint; in wall-clock time, until killed (or `--serve-for` ends).
    #[command(
        after_help = "Examples:\n  cellinject emulate gcs\n  cellinject emulate gcs --bind 127.0.0.1:5000 --plate plate.toml --seed 2\n  cellinject experiment repeatability --backend gcs://127.0.0.1:50000\n\nPositions are µm of stack extension (the stack's sensor), voltages V. Closed loop: ONT? is 1 once the position has stayed within ±0.02 µm of the target for 20 ms; #5 reports an axis moving while its servo is on and it is not on target. Errors: 1 syntax, 2 unknown command, 5 MOV with servo off, 7 target beyond TMN?/TMX? or a closed-loop move the safety envelope stopped, 10 stopped (#24, HLT, STP), 15 unknown axis, 17 value out of range (SVA outside 0..Vmax, refused by the safety envelope, or with the servo on)."
    )]
    Gcs(GcsArgs),
    /// Sensapex devices (uMp manipulators, uMs stages, uMv pressure controllers)
    /// speaking SMCP1 over UDP, as Sensapex's own SDK (libum) drives them; in
    /// wall-clock time, until killed (or `--serve-for` ends).
    #[command(
        after_help = "Examples:\n  cellinject emulate sensapex\n  cellinject emulate sensapex --devices ump:1,ump4:2,ums:21,umv:31 --group 1 --verbose\n\nThen, with Sensapex's Python client (pip install sensapex):\n  from sensapex import UMP\n  ump = UMP.get_ump(address=b\"127.0.0.1\", group=0); print(ump.list_devices())\n\nSensapex's client treats device ids 20-29 as stages and ids of 30 and above as not positionable (pressure controllers). Positions are nm on the wire (µm in the client), pressures Pa on the wire (kPa in the client). docs/sensapex.md says what the emulator speaks."
    )]
    Sensapex(SensapexArgs),
}

/// Options of `emulate sensapex`.
#[derive(Debug, Args)]
pub struct SensapexArgs {
    /// Address to listen on (loopback unless told otherwise); the port is 55555 + the
    /// group, where Sensapex's client sends.
    #[arg(long, default_value = "127.0.0.1", value_name = "HOST")]
    bind: String,
    /// Device group 0..10 (UDP port 55555 + group).
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u16).range(0..=10))]
    group: u16,
    /// The devices: KIND:ID pairs, KIND one of ump (3 axes), ump4 (4 axes), ums
    /// (stage), umv (pressure), ID 1..254.
    #[arg(
        long,
        default_value = "ump:1,ums:21,umv:31",
        value_name = "KIND:ID,..."
    )]
    devices: String,
    /// Log every datagram, decoded, on standard error.
    #[arg(long)]
    verbose: bool,
    /// A fault switch: device ID answers nothing from START to END seconds after the
    /// emulator starts (for good without END), as if its cable were pulled; repeat
    /// for more.
    #[arg(long, value_name = "ID@START[..END]")]
    silence: Vec<String>,
    /// Stop serving after this many seconds (default: until killed).
    #[arg(long, value_name = "SECONDS", allow_negative_numbers = true)]
    serve_for: Option<f64>,
}

/// The `--silence` switches, each checked against the devices' ids.
fn silences(
    arg: &str,
    given: &[String],
    devices: &[cellinject_sensapex::emulator::DeviceSpec],
) -> Result<Vec<(u16, f64, Option<f64>)>> {
    given
        .iter()
        .map(|s| {
            let (id, from, until) = cellinject_sensapex::emulator::parse_silence(s)
                .map_err(|e| InputError(format!("{arg}: {e}")))?;
            if !devices.iter().any(|d| d.id == id) {
                return Err(InputError(format!("{arg} {s}: there is no device {id}")).into());
            }
            Ok((id, from, until))
        })
        .collect()
}

/// Options of `emulate gcs`.
#[derive(Debug, Args)]
pub struct GcsArgs {
    /// Address of the GCS port (loopback unless told otherwise; port 0 picks a free one).
    #[arg(long, default_value = "127.0.0.1:50000", value_name = "HOST:PORT")]
    bind: String,
    /// Address of the bench endpoint (default: the GCS port + 1 on the same host;
    /// `none` serves no bench).
    #[arg(long, value_name = "HOST:PORT|none")]
    bench: Option<String>,
    /// A plate for the twin's microscope (as `cellinject run --plate`); the stage then
    /// starts with the pipette lifted 30 µm above the focal plane, as `run` expects
    /// (calibrations and experiments want the emulator without a plate).
    #[arg(long, value_name = "FILE.toml")]
    plate: Option<PathBuf>,
    /// Faults on the plate's cells (as `cellinject run --fault`).
    #[arg(long, value_name = "KIND@ROW,COL[,K]")]
    fault: Vec<String>,
    /// Pre-tensioning approach of the twin (default: the description's).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
    approach: Option<u8>,
    /// Seed of the twin's random processes (default: the description's).
    #[arg(long)]
    seed: Option<u64>,
    /// Log connections and every command line on standard error.
    #[arg(long)]
    verbose: bool,
    /// Stop serving after this many seconds (default: until killed).
    #[arg(long, value_name = "SECONDS", allow_negative_numbers = true)]
    serve_for: Option<f64>,
    /// Also serve the twin's stages and injector as Sensapex devices over SMCP1, from
    /// the same world (KIND:ID pairs: ump, the macro stage; ums, the feeder stage;
    /// umv, the injector), on UDP port 55555 + --sensapex-group of the --bind host.
    #[arg(long, value_name = "KIND:ID,...")]
    sensapex: Option<String>,
    /// The Sensapex devices' group 0..10.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u16).range(0..=10))]
    sensapex_group: u16,
    /// A fault switch on a Sensapex device (as `emulate sensapex --silence`).
    #[arg(long, value_name = "ID@START[..END]")]
    sensapex_silence: Vec<String>,
}

fn bind(arg: &str, addr: &str) -> Result<TcpListener> {
    TcpListener::bind(addr)
        .map_err(|e| InputError(format!("{arg} {addr}: cannot listen: {e}")).into())
}

fn check_serve_for(serve_for: Option<f64>) -> Result<()> {
    match serve_for {
        Some(t) if !(t.is_finite() && t > 0.0 && t <= 1e7) => {
            Err(InputError(format!("--serve-for must lie in (0, 1e7] s, got {t}")).into())
        }
        _ => Ok(()),
    }
}

/// The devices as the first line lists them (`ump 1, ums 21, umv 31`).
fn device_list(devices: &[cellinject_sensapex::emulator::DeviceSpec]) -> String {
    devices
        .iter()
        .map(|d| format!("{} {}", d.kind.name(), d.id))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The SMCP1 emulator's log: every datagram on standard error, each line after
/// `prefix`, when `verbose`.
fn datagram_log(verbose: bool, prefix: &'static str) -> cellinject_sensapex::emulator::Log {
    verbose.then(|| {
        Box::new(move |line: &str| eprintln!("{prefix}{line}")) as Box<dyn FnMut(&str) + Send>
    })
}

/// `cellinject emulate sensapex`.
fn sensapex(a: &SensapexArgs) -> Result<()> {
    use cellinject_sensapex::{emulator, protocol};
    check_serve_for(a.serve_for)?;
    let devices =
        emulator::parse_devices(&a.devices).map_err(|e| InputError(format!("--devices: {e}")))?;
    let silent = silences("--silence", &a.silence, &devices)?;
    let ip: std::net::IpAddr = a
        .bind
        .parse()
        .map_err(|_| InputError(format!("--bind {}: not an IP address", a.bind)))?;
    let port = protocol::PORT + a.group;
    let socket = std::net::UdpSocket::bind((ip, port)).map_err(|e| {
        InputError(format!(
            "--bind {ip} --group {}: cannot listen on UDP port {port}: {e}",
            a.group
        ))
    })?;
    let running = emulator::serve(socket, &devices, datagram_log(a.verbose, ""))
        .map_err(|e| anyhow::anyhow!("cannot start the emulator: {e}"))?;
    for (id, from, until) in silent {
        running.silence(id, from, until);
    }
    outln!(
        "Sensapex SMCP1 devices on udp://{} (group {}): {}",
        running.addr(),
        a.group,
        device_list(&devices)
    );
    match a.serve_for {
        Some(t) => {
            std::thread::sleep(std::time::Duration::from_secs_f64(t));
            running.stop();
        }
        None => running.wait(),
    }
    Ok(())
}

/// `cellinject emulate ...`.
pub fn run(d: &Description, cmd: &EmulateCommand) -> Result<()> {
    let a = match cmd {
        EmulateCommand::Gcs(a) => a,
        EmulateCommand::Sensapex(a) => return sensapex(a),
    };
    check_serve_for(a.serve_for)?;
    let faults = a
        .fault
        .iter()
        .map(|f| crate::run::parse_fault(f))
        .collect::<Result<Vec<_>>>()?;
    if !faults.is_empty() && a.plate.is_none() {
        return Err(InputError("--fault acts on a plate's cells: give --plate".into()).into());
    }
    let plate = match &a.plate {
        None => None,
        Some(p) => Some(crate::run::read_plate(p)?.0),
    };
    let faults = match &plate {
        Some(p) => crate::run::resolve_faults(&a.fault, &faults, p)?,
        None => Vec::new(),
    };
    let sensapex_specs = match &a.sensapex {
        Some(s) => Some(
            cellinject_sensapex::emulator::parse_devices(s)
                .map_err(|e| InputError(format!("--sensapex: {e}")))?,
        ),
        None if !a.sensapex_silence.is_empty() => {
            return Err(InputError(
                "--sensapex-silence acts on the Sensapex devices: give --sensapex".into(),
            )
            .into());
        }
        None => None,
    };
    let silent = match &sensapex_specs {
        Some(specs) => silences("--sensapex-silence", &a.sensapex_silence, specs)?,
        None => Vec::new(),
    };
    let gcs = bind("--bind", &a.bind)?;
    let gcs_addr = gcs.local_addr()?;
    let bench_addr = match a.bench.as_deref() {
        Some("none") => None,
        Some(b) => Some(b.to_string()),
        None if gcs_addr.port() == u16::MAX => {
            return Err(InputError(format!(
                "--bind {}: the bench endpoint's default port would be {} + 1: give --bench HOST:PORT (or none)",
                a.bind,
                u16::MAX
            ))
            .into());
        }
        None => Some(format!("{}:{}", gcs_addr.ip(), gcs_addr.port() + 1)),
    };
    let bench = match &bench_addr {
        Some(b) if a.bench.is_none() => Some(TcpListener::bind(b.as_str()).map_err(|e| {
            InputError(format!(
                "the bench endpoint's default address {b} (the GCS port + 1): cannot listen: {e} (give --bench HOST:PORT or --bench none)"
            ))
        })?),
        Some(b) => Some(bind("--bench", b)?),
        None => None,
    };
    let twin = crate::sim::twin(d, &crate::sim::TwinArgs::new(a.approach, a.seed))?;
    if let Some(plate) = &plate {
        let mut t = twin.lock().unwrap_or_else(|e| e.into_inner());
        t.load_plate(plate);
        t.set_faults(&faults)
            .map_err(|e| InputError(format!("--fault: {e}")))?;
        let o = cellinject_core::inject::Options::default();
        t.world.stage.place(1, o.focus + o.lift);
    }
    let sensapex = match &sensapex_specs {
        Some(specs) => {
            let backed = cellinject_gcs_emulator::sensapex::backed(&twin, specs)
                .map_err(|e| InputError(format!("--sensapex: {e}")))?;
            let port = cellinject_sensapex::protocol::PORT + a.sensapex_group;
            let socket = std::net::UdpSocket::bind((gcs_addr.ip(), port)).map_err(|e| {
                InputError(format!(
                    "--sensapex-group {}: cannot listen on UDP {}:{port}: {e}",
                    a.sensapex_group,
                    gcs_addr.ip()
                ))
            })?;
            let log = datagram_log(a.verbose, "sensapex ");
            let r = cellinject_sensapex::emulator::serve_backed(socket, backed, log)
                .map_err(|e| anyhow::anyhow!("cannot start the Sensapex emulator: {e}"))?;
            for &(id, from, until) in &silent {
                r.silence(id, from, until);
            }
            Some(r)
        }
        None => None,
    };
    let running = cellinject_gcs_emulator::start(&twin, gcs, bench, a.verbose)
        .map_err(|e| anyhow::anyhow!("cannot start the emulator: {e}"))?;
    // One line, one write: a reader that takes the first line and closes the pipe
    // does not end the emulator.
    let sensapex_line = match (&sensapex, &sensapex_specs) {
        (Some(s), Some(specs)) => format!(
            "; Sensapex SMCP1 devices on udp://{} (group {}): {}",
            s.addr(),
            a.sensapex_group,
            device_list(specs)
        ),
        _ => String::new(),
    };
    outln!(
        "GCS 2.0 controller on {} (axes 1, 2, 3 = A1, A2, A3; µm, V){}{sensapex_line}",
        running.gcs,
        running
            .bench
            .map(|b| format!("; bench endpoint on {b}"))
            .unwrap_or_default()
    );
    match a.serve_for {
        Some(t) => {
            std::thread::sleep(std::time::Duration::from_secs_f64(t));
            running.shutdown();
        }
        None => running.wait(),
    }
    Ok(())
}
