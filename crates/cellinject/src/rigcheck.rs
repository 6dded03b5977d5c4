//! `cellinject rig check`: what a rig file (or its shorthand options) holds, and
//! whether each device answers.

use anyhow::{Result, anyhow};
use cellinject_config::Description;
use clap::{Args, Subcommand};

use crate::Format;
use crate::backend::BackendArgs;
use crate::output::print_json;

/// The `rig` commands.
#[derive(Debug, Subcommand)]
pub enum RigCommand {
    /// Read a rig file, open each device through its driver and ask it one harmless
    /// question (a voltage, a frame, a position, a limit, the zoom); nothing moves.
    /// Exit 0 when every device answers, 1 when one does not, 2 for a bad rig file.
    #[command(
        after_help = "Examples:\n  cellinject rig check --rig bench.toml\n  cellinject rig check                      # the twin\n  cellinject rig check --backend gcs://127.0.0.1:50000 --format json\n\nSee docs/rig.md for the rig file's drivers and keys."
    )]
    Check(CheckArgs),
}

/// `cellinject rig check`.
#[derive(Debug, Args)]
pub struct CheckArgs {
    #[command(flatten)]
    backend: BackendArgs,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
}

/// Runs a `rig` command.
pub fn run(d: &Description, cmd: &RigCommand) -> Result<()> {
    let RigCommand::Check(a) = cmd;
    let rig = a.backend.rig()?;
    let answers = {
        let _p = crate::progress::spinner("asking each device of the rig");
        cellinject_session::check(d, &rig).map_err(crate::backend::session_error)?
    };
    let silent = answers.iter().filter(|a| a.result.is_err()).count();
    if a.format == Format::Json {
        print_json(cellinject_session::CheckReport::new(&rig, &answers), &[])?;
    } else {
        let title = match (&rig.name, &a.backend.rig) {
            (Some(n), _) => format!("rig `{n}` ({})", rig.backend()),
            (None, Some(p)) => format!("rig {} ({})", p.display(), rig.backend()),
            (None, None) => format!("rig {}", rig.backend()),
        };
        outln!("{title}");
        out!("{}", cellinject_session::check_text(&answers));
    }
    if silent > 0 {
        return Err(anyhow!(
            "{silent} of {} devices did not answer (see above)",
            answers.len()
        ));
    }
    Ok(())
}
