//! `cellinject vision`: cells and the pipette's tip in a lab's own images
//! (`cellinject_cells::vision`, `cellinject_cells::tip`).

use std::path::PathBuf;

use anyhow::Result;
use cellinject_cells::CellsError;
use cellinject_cells::tip::find_tip_in;
use cellinject_cells::vision::{Arg, Contrast, Request, RequestError, find_cells};
use cellinject_files::{Kind, Plan, Staged, encode_rgb};
use cellinject_plot::frame::{stretched, with_outlines, with_tip};
use cellinject_print::vision::{CellsReport, VisionTip, outlines};
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
    /// The pipette's tip in one micrograph (the pipette entering from any edge): tip, axis, width near the tip and confidence; no pipette in view is exit 1.
    #[command(
        after_help = "Examples:\n  cellinject vision tip --image pipette.png --pixel-size 0.345e-6\n  cellinject vision tip --image frame.tif --out tip.png --format json\n\nExit codes: 0 a tip found; 1 no pipette in view; 2 bad input.\nSee docs/vision.md."
    )]
    Tip(TipArgs),
}

/// `vision tip`'s arguments.
#[derive(Debug, Args)]
pub struct TipArgs {
    /// The image: PNG, TIFF or JPEG, 8 or 16 bit (colour is read as grey).
    #[arg(long)]
    image: PathBuf,
    /// m per pixel in the object plane (e.g. 0.345e-6); the width is then given in m too [default: the image's shorter side taken as 240 µm].
    #[arg(long, value_name = "M")]
    pixel_size: Option<f64>,
    /// The image with the tip marked and the axis drawn towards the shank (PNG).
    #[arg(long, value_name = "OVERLAY.png")]
    out: Option<PathBuf>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
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
        VisionCommand::Tip(a) => tip(a),
    }
}

fn tip(a: &TipArgs) -> Result<()> {
    if let Some(p) = a.pixel_size
        && !(p.is_finite() && p > 0.0)
    {
        return Err(InputError(format!("--pixel-size {p}: must be a positive length in m")).into());
    }
    let (img, out) = open(&a.image, a.out.as_deref())?;
    let (w, h) = (img.width(), img.height());
    let found = match find_tip_in(img.data(), w, h, a.pixel_size) {
        Ok(t) => t,
        // The image was read and searched: no pipette is a result, not bad input.
        Err(CellsError::NoPipette) => {
            anyhow::bail!("--image `{}`: {}", a.image.display(), CellsError::NoPipette)
        }
        Err(CellsError::Invalid {
            what: "pixel_size",
            value,
            reason,
        }) => return Err(InputError(format!("--pixel-size {value:e}: {reason}")).into()),
        Err(e) => return Err(InputError(format!("--image `{}`: {e}", a.image.display())).into()),
    };
    let report = VisionTip::new(&found, a.pixel_size);
    let overlay = match &out {
        Some(path) => {
            let grey = stretched(img.data());
            let (tip, axis) = (report.tip_px, found.axis_rad);
            Some((
                path,
                with_tip(&grey, w as u32, h as u32, tip, axis, found.width)?,
            ))
        }
        None => None,
    };
    let text = report.text(&a.image.display().to_string(), w, h);
    finish(&report, &text, overlay, a.format)
}

/// A `vision` command's start: the image and the overlay's path checked as a pair
/// (the overlay may not be the image), then the image read as grey levels.
fn open(
    image: &std::path::Path,
    out: Option<&std::path::Path>,
) -> Result<(cellinject_dic::Image, Option<PathBuf>)> {
    let mut plan = Plan::new();
    plan.input("--image", image);
    let out = match out {
        Some(o) => Some(plan.output("--out", o, &[Kind::Png])?),
        None => None,
    };
    plan.check()?;
    let img = crate::dic::load_grey(image).map_err(|e| InputError(format!("--image: {e}")))?;
    Ok((img, out))
}

/// A `vision` command's end: the overlay written (staged: a crash leaves no part of
/// it), then the report as JSON (with the file) or as text (and `wrote FILE`).
fn finish(
    report: &impl serde::Serialize,
    text: &str,
    overlay: Option<(&PathBuf, cellinject_plot::Rgb)>,
    format: Format,
) -> Result<()> {
    let mut written = Vec::new();
    if let Some((path, rgb)) = overlay {
        let mut staged = Staged::new();
        staged.add(path, &encode_rgb(rgb, path)?)?;
        staged.commit()?;
        written.push(path.clone());
    }
    if format == Format::Json {
        let files: Vec<&std::path::Path> = written.iter().map(|p| p.as_path()).collect();
        return print_json(report, &files);
    }
    outln!("{}", text.trim_end());
    if let Some(p) = written.first() {
        outln!("wrote {}", p.display());
    }
    Ok(())
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
    let (img, out) = open(&a.image, a.out.as_deref())?;
    let (w, h) = (img.width(), img.height());
    let options = request.options(w, h).map_err(refused)?;
    let census = find_cells(img.data(), w, h, &options)
        .map_err(|e| InputError(format!("--image `{}`: {e}", a.image.display())))?;
    let report = CellsReport::new(&census, a.pixel_size);
    let overlay = match &out {
        // Stretched over the image's own range, the outlines drawn over it.
        Some(path) => {
            let grey = stretched(img.data());
            Some((
                path,
                with_outlines(&grey, w as u32, h as u32, &outlines(&census))?,
            ))
        }
        None => None,
    };
    let text = report.text(&a.image.display().to_string(), w, h);
    finish(&report, &text, overlay, a.format)
}
