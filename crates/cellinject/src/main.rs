//! `cellinject`: the command-line front end. It reads files, parses arguments and
//! prints; every computation lives in the library crates.

/// `print!` that survives a closed pipe (`output::print`).
macro_rules! out {
    ($($t:tt)*) => { $crate::output::print(format_args!($($t)*)) };
}

/// `println!` that survives a closed pipe (`output::print`).
macro_rules! outln {
    () => { $crate::output::print(format_args!("\n")) };
    ($($t:tt)*) => {{
        $crate::output::print(format_args!($($t)*));
        $crate::output::print(format_args!("\n"));
    }};
}

mod backend;
mod calibrate;
mod camera;
mod commands;
mod design;
mod dic;
mod emulate;
mod experiment;
mod fea;
mod hinge;
mod hysteresis;
mod output;
mod plate;
mod progress;
mod report;
mod rigcheck;
mod run;
mod serve;
mod sim;
mod vision;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::builder::ValueParser;
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand, ValueEnum};

/// Software for a piezo-actuated compliant micromanipulator that injects biological cells.
///
/// With no command, runs `run`: the injection workflow on the default plate of the
/// embedded prototype's twin.
#[derive(Debug, Parser)]
#[command(
    name = "cellinject",
    version,
    about,
    long_about,
    after_help = "Examples:\n  cellinject                      (inject every cell of the default plate on the twin: cellinject run)\n  cellinject reproduce            (the paper's Sec. 3.2 on the embedded prototype)\n  cellinject tension --approach 2\n  cellinject sim frame --vga --out frame.png\n\nExit codes: 0 success; 1 the computation ran but its result is not usable; 2 bad input or usage."
)]
struct Cli {
    /// Manipulator description file (TOML, SI units). Default: the embedded ICINCO-2012 prototype.
    #[arg(long, global = true, value_name = "FILE")]
    config: Option<PathBuf>,

    /// Replace output files in the way without keeping them. Default: a file whose contents would change is kept beside it as FILE.~N~ (N one more than the highest there), and the command says so on standard error.
    #[arg(long, global = true)]
    force: bool,

    #[command(subcommand)]
    command: Option<Command>,
}

/// Output format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Format {
    /// Text for people: tables and summaries in display units (µm, mN·m, px).
    Text,
    /// One JSON document: SI units, pixels for image quantities (docs/json.md).
    Json,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Pre-tension analysis with one of the paper's two approaches (Sec. 2.1, 2.2).
    #[command(
        after_help = "Examples:\n  cellinject tension --approach 2\n  cellinject tension --approach 1 --format json > tension.json"
    )]
    Tension {
        /// 1: assembly translation along the drive axes; 2: assembly deflection of J3.
        #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
        approach: u8,
        /// Output format.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// The mechanism model: Jacobians J, L, W, compliance B_l and the linearisation error.
    #[command(
        after_help = "Examples:\n  cellinject model\n  cellinject --config my-manipulator.toml model --format json"
    )]
    Model {
        /// Output format.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// Stiffness, compliance and stress of one flexure hinge.
    #[command(
        after_help = "Examples:\n  cellinject hinge --profile circular --thickness 1e-3 --radius 2e-3 --width 5e-3\n  cellinject hinge --profile corner --thickness 0.5e-3 --radius 1e-3 --width 4e-3 --length 6e-3 --method fem --angle 0.01"
    )]
    Hinge(hinge::HingeArgs),
    /// Circular notches from t/R = 0.05 to 1: beam integral, Paros-Weisbord and FEM side by side.
    #[command(
        after_help = "Examples:\n  cellinject hinge-table\n  cellinject hinge-table --radius 1e-3 --plane strain --format json"
    )]
    HingeTable(hinge::TableArgs),
    /// Whole-manipulator structural model: displacements, coupling, joint stresses, modes.
    #[command(
        after_help = "Examples:\n  cellinject fea --approach 1 --forces -111.686,-111.686 --plot fig4.svg\n  cellinject fea tables --level 2\n  cellinject fea modes --approach 2 --count 4"
    )]
    Fea(fea::FeaArgs),
    /// Design studies: one design's figures (range, stiffness, first modes, safety
    /// margins, coupling, feasibility), batches in shards, and a multi-objective search
    /// over description keys (NSGA-II) with its front.
    #[command(
        subcommand,
        after_help = "Examples:\n  cellinject design evaluate --fidelity fea\n  cellinject design evaluate --batch designs.jsonl --out r0.jsonl --shard 0/4\n  cellinject design merge --out all.jsonl r0.jsonl r1.jsonl r2.jsonl r3.jsonl\n  cellinject design optimise --space configs/design-space.toml --out study\n\nSee docs/design.md."
    )]
    Design(design::DesignCommand),
    /// Digital image correlation: points, fields, tracking, synthetic test images.
    #[command(
        after_help = "Examples:\n  cellinject dic synth --shift 0.3,-0.2\n  cellinject dic --reference reference.png --current current.png --at 256,256 --at 100,100\n  cellinject dic field --reference reference.png --current current.png --out field.csv"
    )]
    Dic(dic::DicArgs),
    /// Run the digital twin: hysteresis loops, step responses, camera frames.
    #[command(
        subcommand,
        after_help = "Examples:\n  cellinject sim loop --actuator A2\n  cellinject sim step --voltage 50 --duration 0.5\n  cellinject sim frame --vga --scale-bar --out frame.png"
    )]
    Sim(sim::SimCommand),
    /// Hysteresis models of the stacks: identification data, fits, inverses.
    #[command(
        subcommand,
        after_help = "Examples:\n  cellinject hysteresis identify --actuator A1 --out ident.csv\n  cellinject hysteresis fit --data ident.csv --out model.json\n  cellinject hysteresis invert --model model.json --trajectory desired.csv --out command.csv"
    )]
    Hysteresis(hysteresis::HysteresisCommand),
    /// Calibrate the bench: pixels from stage moves, the stacks-to-tip Jacobian, the stacks' hysteresis.
    #[command(
        subcommand,
        after_help = "Examples:\n  cellinject calibrate all --out calibration\n  cellinject calibrate pixels --out pixels.json\n  cellinject calibrate jacobian --pixels pixels.json --out jacobian.json"
    )]
    Calibrate(calibrate::CalibrateCommand),
    /// The paper's bench experiments through the cameras: range, repeatability, tracking.
    #[command(
        subcommand,
        after_help = "Examples:\n  cellinject experiment range --approach 2\n  cellinject experiment repeatability --approach 1 --control closed --runs 200\n  cellinject experiment tracking --control sensor"
    )]
    Experiment(experiment::ExperimentCommand),
    /// The matrix feeder's description file: realistic plates from a seed, checks, and cell detection on the twin.
    #[command(
        subcommand,
        after_help = "Examples:\n  cellinject plate generate --rows 4 --cols 6 --out plate.toml\n  cellinject plate check --plate plate.toml\n  cellinject plate detect --plate plate.toml"
    )]
    Plate(plate::PlateCommand),
    /// Vision on a lab's own micrographs: the cells in one image (phase contrast or bright field, either polarity), the pipette's tip.
    #[command(
        subcommand,
        after_help = "Examples:\n  cellinject vision cells --image cells.png --pixel-size 0.107e-6\n  cellinject vision cells --image field.png --out overlay.png --format json\n  cellinject vision tip --image pipette.png --pixel-size 0.345e-6 --out tip.png\n\nSee docs/vision.md."
    )]
    Vision(vision::VisionCommand),
    /// The unattended injection workflow: every cell of a plate found, injected and checked, recorded in a database (the default command).
    #[command(
        after_help = "Examples:\n  cellinject run\n  cellinject run --plate plate.toml --db runs.sqlite --format json\n  cellinject run --resume\n  cellinject run --fault clog@1,0"
    )]
    Run(run::RunArgs),
    /// The run records: list the runs, show one as JSON, export its attempts.
    #[command(
        subcommand,
        after_help = "Examples:\n  cellinject runs list\n  cellinject runs show --run 2\n  cellinject runs export --format csv > attempts.csv"
    )]
    Runs(run::RunsCommand),
    /// GenICam cameras (GigE Vision, USB3 Vision) through Aravis: list them, show one, grab frames (a build with the `genicam` feature).
    #[command(
        subcommand,
        after_help = "Examples:\n  cellinject camera list\n  cellinject camera info --camera aravis:Aravis-GV01\n  cellinject camera grab --camera aravis:Aravis-GV01 --frames 3 --out g.tif\n\nSee docs/cameras.md."
    )]
    Camera(camera::CameraCommand),
    /// Emulated hardware backed by the twin, for drivers and third-party clients.
    #[command(
        subcommand,
        after_help = "Examples:\n  cellinject emulate gcs\n  cellinject emulate gcs --bind 127.0.0.1:5000 --plate plate.toml\n  cellinject emulate sensapex --devices ump:1,ums:21,umv:31"
    )]
    Emulate(emulate::EmulateCommand),
    /// The bench as a rig file (one TOML naming each device's driver): check what it holds and whether each device answers.
    #[command(
        subcommand,
        after_help = "Examples:\n  cellinject rig check --rig bench.toml\n  cellinject run --rig bench.toml --plate plate.toml\n\nEvery command that drives hardware takes --rig FILE (docs/rig.md)."
    )]
    Rig(rigcheck::RigCommand),
    /// The live web dashboard of the bench: camera view, plots, plate map, run controls (loopback unless --allow-remote).
    #[command(
        after_help = "Examples:\n  cellinject serve                       # http://127.0.0.1:8080/ on the twin, paced to wall time\n  cellinject serve --fast --plate plate.toml\n  cellinject serve --bind 0.0.0.0:8080 --allow-remote --allowed-host bench.lab\n  cellinject serve --backend gcs://192.168.0.20:50000 --plate plate.toml\n\nAPI (docs/dashboard.md): GET /api/status, /api/events (live stream), /api/runs, /runs/ID; POST /api/run, /api/pause, /api/resume, /api/abort, /api/calibrate, /api/safe, /api/jog {\"axis\": \"A1\", \"by\": 1.0}. With --allow-remote every request carries `Authorization: Bearer TOKEN` (or the session cookie from POST /api/session)."
    )]
    Serve(serve::ServeArgs),
    /// A run's records as one self-contained HTML page: plate map, tip-error and dose histograms, throughput, settings and calibrations.
    #[command(
        after_help = "Examples:\n  cellinject report --out report\n  cellinject report --db runs.sqlite --run 2 --out run2"
    )]
    Report {
        /// The run database.
        #[arg(long, default_value = "runs.sqlite")]
        db: PathBuf,
        /// Run id (default: the latest).
        #[arg(long)]
        run: Option<i64>,
        /// Where the page goes: a file ending in `.html` (its directory must exist), or a directory for `report.html` (created if needed).
        #[arg(long, value_name = "FILE.html|DIR", default_value = "report")]
        out: PathBuf,
    },
    /// Every figure of the paper's Sec. 3.2 (eqs. 37-58): paper, computed, difference.
    #[command(
        after_help = "Examples:\n  cellinject reproduce\n  cellinject reproduce --out my-reports --format json"
    )]
    Reproduce {
        /// Directory for the Markdown report (created if needed).
        #[arg(long, value_name = "DIR", default_value = "reports")]
        out: PathBuf,
        /// Output format (the report is written either way).
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
}

/// An error caused by the user's input: exit code 2.
#[derive(Debug)]
pub struct InputError(pub String);

impl std::fmt::Display for InputError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for InputError {}

fn run(cli: Cli) -> anyhow::Result<()> {
    // Only the commands that use a description read one: `dic` and `hinge` never fail
    // on a bad `--config`.
    let description = || commands::load_description(cli.config.as_deref());
    // Commands that never read a description say so rather than ignore --config.
    let unused_config = || {
        if let Some(c) = &cli.config {
            eprintln!(
                "warning: --config `{}` is not used by this command (it reads no manipulator description)",
                c.display()
            );
        }
    };
    match cli.command {
        Some(Command::Tension { approach, format }) => {
            commands::tension(&description()?, approach, format)
        }
        Some(Command::Model { format }) => commands::model(&description()?, format),
        Some(Command::Sim(cmd)) => sim::run(&description()?, &cmd),
        Some(Command::Dic(args)) => {
            unused_config();
            dic::run(&args)
        }
        Some(Command::Fea(args)) => fea::run(&description()?, &args),
        Some(Command::Design(cmd)) => design::run(cli.config.as_deref(), &cmd),
        Some(Command::Hysteresis(cmd)) => hysteresis::run(description, &cmd),
        Some(Command::Calibrate(cmd)) => calibrate::calibrate(&description()?, &cmd),
        Some(Command::Experiment(cmd)) => experiment::run(&description()?, &cmd),
        Some(Command::Plate(cmd)) => {
            if !plate::uses_description(&cmd) {
                unused_config();
            }
            plate::run(&cmd, description)
        }
        Some(Command::Vision(cmd)) => {
            unused_config();
            vision::run(&cmd)
        }
        Some(Command::Hinge(args)) => {
            unused_config();
            hinge::run(&args)
        }
        Some(Command::HingeTable(args)) => {
            unused_config();
            hinge::table(&args)
        }
        Some(Command::Run(args)) => run::run(&description()?, &args),
        Some(Command::Emulate(cmd)) => emulate::run(&description()?, &cmd),
        Some(Command::Rig(cmd)) => rigcheck::run(&description()?, &cmd),
        Some(Command::Camera(cmd)) => {
            unused_config();
            camera::run(&cmd)
        }
        Some(Command::Serve(args)) => serve::serve(&description()?, &args),
        Some(Command::Report { db, run, out }) => {
            unused_config();
            let f = report::report(&db, run, &out)?;
            outln!("wrote {}", f.display());
            Ok(())
        }
        Some(Command::Runs(cmd)) => {
            unused_config();
            run::runs(&cmd)
        }
        Some(Command::Reproduce { out, format }) => {
            commands::reproduce(&description()?, &out, format)
        }
        None => {
            // No command: the main job, `cellinject run` with its defaults.
            let mut default = Cli::parse_from(["cellinject", "run"]);
            default.config = cli.config.clone();
            run(default)
        }
    }
}

/// A number that is finite: NaN and infinities are refused where they are typed, with
/// the option named by clap's message.
fn finite(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a number"))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("`{s}` is not a finite number"))
    }
}

/// The command line as people type it, applied to every option of every command:
/// numbers are finite, negative numbers need no `=` (`--forces -100,-100`,
/// `--thickness -1e-3` reaches the real check), and lists take `1,2` or `1 2`.
fn command() -> clap::Command {
    fn people(cmd: clap::Command) -> clap::Command {
        let cmd = cmd.mut_args(|a| {
            if !a.get_action().takes_values() {
                return a;
            }
            let a = if a.get_value_parser().type_id() == std::any::TypeId::of::<f64>() {
                a.value_parser(ValueParser::new(finite))
            } else {
                a
            };
            if a.get_value_delimiter().is_some() {
                // A list: `1,2` or `1 2` (several values after one option).
                a.num_args(1..).allow_negative_numbers(true)
            } else {
                // One value: the next word, whatever it starts with (`-1e-3`, `-100,-100`;
                // clap's own negative-number test refuses exponents like `e-3`).
                a.allow_hyphen_values(true)
            }
        });
        let names: Vec<String> = cmd
            .get_subcommands()
            .map(|s| s.get_name().to_string())
            .collect();
        names
            .into_iter()
            .fold(cmd, |c, n| c.mut_subcommand(n, people))
    }
    people(Cli::command())
}

fn main() -> ExitCode {
    let parsed = command()
        .try_get_matches()
        .and_then(|m| Cli::from_arg_matches(&m));
    let cli = match parsed {
        Ok(cli) => cli,
        Err(e) => {
            let _ = e.print();
            return ExitCode::from(if e.use_stderr() { 2 } else { 0 });
        }
    };
    cellinject_files::replace_existing(cli.force);
    let result = run(cli);
    // Files an output took the place of (their previous versions kept): said once the
    // command is done, on standard error (standard output stays the command's own).
    for k in cellinject_files::take_kept() {
        eprintln!(
            "note: `{}` was in the way: its previous version is kept as `{}` (--force replaces without keeping)",
            k.file.display(),
            k.kept_as.display()
        );
    }
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            let files = e.downcast_ref::<cellinject_files::FilesError>();
            if e.downcast_ref::<InputError>().is_some() || files.is_some_and(|f| f.is_input()) {
                ExitCode::from(2)
            } else {
                ExitCode::from(1)
            }
        }
    }
}
