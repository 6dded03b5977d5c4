//! Standard output that survives a closed pipe, and JSON summaries with their files
//! (the tables and numbers for people are `cellinject_print::table`).

use std::io::Write as _;
use std::path::Path;

/// Writes to standard output. A closed pipe (the reader has gone, as with `| head`) ends
/// the command quietly with exit code 0, as ripgrep does: every file the command writes
/// is in place before it prints its results. Any other write error exits with 1.
pub fn print(args: std::fmt::Arguments<'_>) {
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_fmt(args).and_then(|()| out.flush()) {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("error: cannot write to standard output: {e}");
        std::process::exit(1);
    }
}

/// A JSON summary with the files it wrote.
#[derive(serde::Serialize)]
struct Written<'a, T: serde::Serialize> {
    #[serde(flatten)]
    summary: T,
    files: Vec<&'a Path>,
}

pub fn print_json<T: serde::Serialize>(summary: T, files: &[&Path]) -> anyhow::Result<()> {
    let w = Written {
        summary,
        files: files.to_vec(),
    };
    print(format_args!("{}\n", serde_json::to_string_pretty(&w)?));
    Ok(())
}
