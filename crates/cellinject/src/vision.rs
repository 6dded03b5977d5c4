//! `cellinject vision`: cell detection on a lab's own images (`cellinject_cells::vision`).

use std::path::PathBuf;

use anyhow::Result;
use cellinject_cells::vision::{Arg, Contrast, Request, RequestError, find_cells};
use cellinject_files::{Kind, Plan, Staged, encode_rgb};
use cellinject_plot::frame::{stretched, with_outlines};
use cellinject_print::vision::{CellsReport, outlines};
use clap::{Args, Subcommand, ValueEnum};

use crate::output::print_json;
use crate::{Format, InputError};

/// `cellinject vision ...`.
#[derive(Debug, Subcommand)]
pub enum VisionCommand {
    /// The cells in one micrograph (phase contrast or bright field, either polarity): centre, diameter, contrast and confidence of each, debris apart.
    #[command(
        after_help = "Examples:\n  cellinject vision cells --image cells.png --pixel-size 0.107e-6\n  cellinject vision cells --image field.tif --pixel-size 0.88e-6 --contrast dark --out overlay.png --format json\n\nSee docs/vision.md."
    )]
    Cells(CellsArgs),
}

/// Which cells to look for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ContrastArg {
    /// Both: bright bodies (phase contrast) and dark ones (bright field).
    Auto,
    /// Cells darker than their surroundings.
    Dark,
    /// Cells brighter than their surroundings.
    Bright,
}

/// `vision cells`'s arguments.
#[derive(Debug, Args)]
pub struct CellsArgs {
    /// The image: PNG, TIFF or JPEG, 8 or 16 bit (colour is read as grey).
    #[arg(long)]
    image: PathBuf,
    /// m per pixel in the object plane (e.g. 0.107e-6); sizes are then given in m too.
    #[arg(long, value_name = "M")]
    pixel_size: Option<f64>,
    /// m, the smallest and largest diameter of a cell (needs --pixel-size) [default: 9.5e-6,30e-6 with a pixel size; 8 px to half the image's shorter side without].
    #[arg(long, value_name = "MIN,MAX", value_parser = parse_range)]
    diameter: Option<(f64, f64)>,
    /// Which cells to look for.
    #[arg(long, value_enum, default_value_t = ContrastArg::Auto)]
    contrast: ContrastArg,
    /// The image with the outlines drawn over it (PNG): cells green, debris orange, numbered as printed.
    #[arg(long, value_name = "OVERLAY.png")]
    out: Option<PathBuf>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
}

/// `MIN,MAX` as two numbers; whether they make a diameter range is
/// [`Request::options`]'s to say, as for every front end.
fn parse_range(s: &str) -> Result<(f64, f64), String> {
    let bad = || format!("expected MIN,MAX in metres, got `{s}`");
    let (a, b) = s.split_once(',').ok_or_else(bad)?;
    let a: f64 = a.trim().parse().map_err(|_| bad())?;
    let b: f64 = b.trim().parse().map_err(|_| bad())?;
    Ok((a, b))
}

/// Runs a `vision` command.
pub fn run(cmd: &VisionCommand) -> Result<()> {
    match cmd {
        VisionCommand::Cells(a) => cells(a),
    }
}

fn cells(a: &CellsArgs) -> Result<()> {
    let request = Request {
        pixel_size: a.pixel_size,
        diameter: a.diameter.map(|(lo, hi)| [lo, hi]),
        contrast: match a.contrast {
            ContrastArg::Auto => Contrast::Auto,
            ContrastArg::Dark => Contrast::Dark,
            ContrastArg::Bright => Contrast::Bright,
        },
    };
    let refused = |e: RequestError| {
        let arg = match e.arg() {
            Arg::PixelSize => "--pixel-size",
            Arg::Diameter => "--diameter",
        };
        InputError(format!("{arg} {e}"))
    };
    // The options checked before any file is read (the image's size not known yet).
    request.options(usize::MAX, usize::MAX).map_err(refused)?;
    let mut plan = Plan::new();
    plan.input("--image", &a.image);
    let out = match &a.out {
        Some(o) => Some(plan.output("--out", o, &[Kind::Png])?),
        None => None,
    };
    plan.check()?;
    let img = crate::dic::load_grey(&a.image).map_err(|e| InputError(format!("--image: {e}")))?;
    let (w, h) = (img.width(), img.height());
    let options = request.options(w, h).map_err(refused)?;
    let census = find_cells(img.data(), w, h, &options)
        .map_err(|e| InputError(format!("--image `{}`: {e}", a.image.display())))?;
    let report = CellsReport::new(&census, a.pixel_size);
    let mut written = Vec::new();
    if let Some(path) = &out {
        // Stretched over the image's own range, the outlines drawn over it.
        let grey = stretched(img.data());
        let outlines = outlines(&census);
        let rgb = with_outlines(&grey, w as u32, h as u32, &outlines)?;
        let mut staged = Staged::new();
        staged.add(path, &encode_rgb(rgb, path)?)?;
        staged.commit()?;
        written.push(path.clone());
    }
    if a.format == Format::Json {
        let files: Vec<&std::path::Path> = written.iter().map(|p| p.as_path()).collect();
        return print_json(&report, &files);
    }
    outln!(
        "{}",
        report.text(&a.image.display().to_string(), w, h).trim_end()
    );
    if let Some(p) = written.first() {
        outln!("wrote {}", p.display());
    }
    Ok(())
}
