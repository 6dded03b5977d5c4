//! `cellinject`: the command-line front end. It reads files, parses arguments and
//! prints; every computation lives in the library crates.

mod commands;
mod dic;
mod fea;
mod hinge;
mod output;
mod sim;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};

/// Software for a piezo-actuated compliant micromanipulator that injects biological cells.
///
/// With no command, runs `reproduce` on the embedded prototype.
#[derive(Debug, Parser)]
#[command(name = "cellinject", version, about, long_about)]
struct Cli {
    /// Manipulator description file (TOML, SI units). Default: the embedded ICINCO-2012 prototype.
    #[arg(long, global = true, value_name = "FILE")]
    config: Option<PathBuf>,

    #[command(subcommand)]
    command: Option<Command>,
}

/// Output format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Format {
    /// A readable table (µm, mN·m).
    Text,
    /// JSON, SI units.
    Json,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Pre-tension analysis with one of the paper's two approaches (Sec. 2.1, 2.2).
    Tension {
        /// 1: assembly translation along the drive axes; 2: assembly deflection of J3.
        #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
        approach: u8,
        /// Output format.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// The mechanism model: Jacobians J, L, W, compliance B_l and the linearisation error.
    Model {
        /// Output format.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// Stiffness, compliance and stress of one flexure hinge.
    Hinge(hinge::HingeArgs),
    /// Circular notches from t/R = 0.05 to 1: beam integral, Paros-Weisbord and FEM side by side.
    HingeTable(hinge::TableArgs),
    /// Whole-manipulator structural model: displacements, coupling, joint stresses, modes.
    Fea(fea::FeaArgs),
    /// Digital image correlation: points, fields, tracking, synthetic test images.
    Dic(dic::DicArgs),
    /// Run the digital twin: hysteresis loops, step responses, camera frames.
    #[command(subcommand)]
    Sim(sim::SimCommand),
    /// Every figure of the paper's Sec. 3.2 (eqs. 37-58): paper, computed, difference.
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
    match cli.command {
        Some(Command::Tension { approach, format }) => {
            commands::tension(&description()?, approach, format)
        }
        Some(Command::Model { format }) => commands::model(&description()?, format),
        Some(Command::Sim(cmd)) => sim::run(&description()?, &cmd),
        Some(Command::Dic(args)) => dic::run(&args),
        Some(Command::Fea(args)) => fea::run(&description()?, &args),
        Some(Command::Hinge(args)) => hinge::run(&args),
        Some(Command::HingeTable(args)) => hinge::table(&args),
        Some(Command::Reproduce { out, format }) => {
            commands::reproduce(&description()?, &out, format)
        }
        None => commands::reproduce(
            &description()?,
            std::path::Path::new("reports"),
            Format::Text,
        ),
    }
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            let _ = e.print();
            return ExitCode::from(if e.use_stderr() { 2 } else { 0 });
        }
    };
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            if e.downcast_ref::<InputError>().is_some() {
                ExitCode::from(2)
            } else {
                ExitCode::from(1)
            }
        }
    }
}
