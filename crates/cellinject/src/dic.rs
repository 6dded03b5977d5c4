//! `cellinject dic ...`: digital image correlation on image files.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use cellinject_core::dic::{
    PointReport, SynthSummary, TrackSummary, field_report_with_progress, points,
};
use cellinject_dic::accept::DEFAULT_MAX_SIGMA;
use cellinject_dic::field::FieldOptions;
use cellinject_dic::track::{Roi, Status, Tracker};
use cellinject_dic::{Acceptance, DicError, Image, PointOptions, Shape};
use cellinject_plot::map::{maps_rgb, maps_svg};
use clap::{Args, Subcommand, ValueEnum};

use crate::output::print_json;
use crate::{Format, InputError};
use cellinject_files::{Kind, Plan, Staged, encode_image, encode_rgb};

/// Shape function of the subsets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ShapeArg {
    /// First order: displacement and its four gradients.
    Affine,
    /// Translation only.
    Rigid,
}

impl From<ShapeArg> for Shape {
    fn from(s: ShapeArg) -> Self {
        match s {
            ShapeArg::Affine => Shape::Affine,
            ShapeArg::Rigid => Shape::Rigid,
        }
    }
}

/// `cellinject dic`: points, or a subcommand.
#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct DicArgs {
    #[command(subcommand)]
    command: Option<DicCommand>,
    #[command(flatten)]
    points: PointArgs,
}

/// Correlate chosen points.
#[derive(Debug, Args)]
pub struct PointArgs {
    /// Reference image (PNG or TIFF, 8 or 16 bit; colour is converted to grey).
    #[arg(long, required = true, value_name = "FILE")]
    reference: Option<PathBuf>,
    /// Current image, same size.
    #[arg(long, required = true, value_name = "FILE")]
    current: Option<PathBuf>,
    /// A point of the reference, pixels (x = column, y = row, origin at the centre of the
    /// top-left pixel); repeat for more points.
    #[arg(long = "at", required = true, value_name = "X,Y", value_parser = parse_pair, allow_negative_numbers = true)]
    at: Vec<(f64, f64)>,
    /// Subset size, pixels (odd, 7 to 401).
    #[arg(long, default_value_t = 31)]
    subset: usize,
    /// Shape function.
    #[arg(long, value_enum, default_value_t = ShapeArg::Affine)]
    shape: ShapeArg,
    /// Largest displacement searched for, pixels.
    #[arg(long, default_value_t = 64)]
    search: usize,
    /// Sigma of a Gaussian prefilter applied to both images, pixels (0 = none).
    #[arg(long, default_value_t = 0.0)]
    prefilter: f64,
    /// A point whose ZNCC falls below this, or that does not converge, has no match.
    #[arg(long, default_value_t = 0.8)]
    min_zncc: f64,
    /// A point whose predicted standard error (noise and interpolation bias) exceeds
    /// this in u or v has no match (too little texture), pixels.
    #[arg(long, default_value_t = DEFAULT_MAX_SIGMA)]
    max_sigma: f64,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
}

/// DIC subcommands.
#[derive(Debug, Subcommand)]
pub enum DicCommand {
    /// Displacement field on a grid (reliability-guided, parallel).
    #[command(
        after_help = "Examples:\n  cellinject dic field --reference reference.png --current current.png --out field.csv\n  cellinject dic field --reference a.tif --current b.tif --step 10 --subset 41 --out field.csv"
    )]
    Field {
        /// Reference image.
        #[arg(long, value_name = "FILE")]
        reference: PathBuf,
        /// Current image.
        #[arg(long, value_name = "FILE")]
        current: PathBuf,
        /// Grid step, pixels.
        #[arg(long, default_value_t = 5)]
        step: usize,
        /// Subset size, pixels (odd).
        #[arg(long, default_value_t = 31)]
        subset: usize,
        /// Shape function.
        #[arg(long, value_enum, default_value_t = ShapeArg::Affine)]
        shape: ShapeArg,
        /// Sigma of a Gaussian prefilter applied to both images, pixels (0 = none).
        #[arg(long, default_value_t = 0.0)]
        prefilter: f64,
        /// A point whose ZNCC falls below this, or that does not converge, is dropped
        /// (the rule of `dic` points).
        #[arg(long, default_value_t = 0.8)]
        min_zncc: f64,
        /// A point whose predicted standard error (noise and interpolation bias) exceeds
        /// this in u or v is dropped (too little texture), pixels.
        #[arg(long, default_value_t = DEFAULT_MAX_SIGMA)]
        max_sigma: f64,
        /// CSV output; maps of u and v are written beside it with the same stem, as PNG
        /// and SVG (axes in pixels, or micrometres with `--um-per-px`).
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
        /// Micrometres per pixel: the maps' axes and colour bars in µm.
        #[arg(long, value_name = "S")]
        um_per_px: Option<f64>,
        /// Output format of the summary (the files are the same).
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
        /// Threads the correlation runs on (default: all the machine's cores; the
        /// result does not depend on it).
        #[arg(long, value_name = "N")]
        threads: Option<usize>,
    },
    /// Write a pair of exact synthetic speckle images (Gaussians integrated over the
    /// pixels, Gaussian noise, 8-bit) related by a known shift and rotation.
    #[command(
        after_help = "Examples:\n  cellinject dic synth\n  cellinject dic synth --size 256,256 --shift -0.4,0.25 --rotation 0.5 --reference r.png --current c.png"
    )]
    Synth {
        /// Image size: width,height.
        #[arg(long, value_delimiter = ',', num_args = 1, default_value = "512,512")]
        size: Vec<usize>,
        /// Shift of the current image: u,v pixels.
        #[arg(long, value_name = "U,V", value_parser = parse_pair, default_value = "0.25,0")]
        shift: (f64, f64),
        /// Rotation about the image centre, degrees.
        #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
        rotation: f64,
        /// Noise, grey levels rms.
        #[arg(long, default_value_t = 2.0)]
        noise: f64,
        /// Seed of the pattern and the noise.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Reference image output (`.png` or `.tif`).
        #[arg(long, default_value = "reference.png")]
        reference: PathBuf,
        /// Current image output (`.png` or `.tif`).
        #[arg(long, default_value = "current.png")]
        current: PathBuf,
        /// Output format of the summary.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// Follow a region through a sequence of frames.
    #[command(
        after_help = "Examples:\n  cellinject dic track --frames run/ --roi 300,200,65,65 --um-per-px 0.22 --out track.csv\n  cellinject dic track --frames 'run/frame_*.png' --roi 300,200,65,65 --out track.csv"
    )]
    Track {
        /// A directory of frames (PNG/TIFF, in name order) or a pattern such as `run/*.png`.
        #[arg(long, value_name = "DIR|GLOB")]
        frames: String,
        /// Region to follow in the first frame: x,y,width,height (pixels).
        #[arg(
            long,
            required = true,
            value_name = "X,Y,W,H",
            value_delimiter = ',',
            num_args = 1
        )]
        roi: Vec<usize>,
        /// Micrometres per pixel, to report metres as well.
        #[arg(long, value_name = "S")]
        um_per_px: Option<f64>,
        /// Reject frames whose ZNCC falls below this.
        #[arg(long, default_value_t = 0.8)]
        min_zncc: f64,
        /// Shape function.
        #[arg(long, value_enum, default_value_t = ShapeArg::Rigid)]
        shape: ShapeArg,
        /// CSV output.
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
        /// Output format of the summary (the CSV is the same).
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
}

fn parse_pair(s: &str) -> Result<(f64, f64), String> {
    let parts: Vec<&str> = s.split(',').collect();
    let bad = || format!("expected X,Y in pixels, got `{s}`");
    if parts.len() != 2 {
        return Err(bad());
    }
    let x: f64 = parts[0].trim().parse().map_err(|_| bad())?;
    let y: f64 = parts[1].trim().parse().map_err(|_| bad())?;
    if !x.is_finite() || !y.is_finite() {
        return Err(bad());
    }
    Ok((x, y))
}

/// Loads a PNG, TIFF or JPEG as grey levels in its own units (0-255 or 0-65535).
pub fn load_grey(path: &Path) -> Result<Image> {
    let img = image::open(path)
        .map_err(|e| InputError(format!("cannot read image `{}`: {e}", path.display())))?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    // 16-bit and floating-point sources keep 16 bits; everything else is read as 8-bit.
    let deep = matches!(
        img.color(),
        image::ColorType::L16
            | image::ColorType::La16
            | image::ColorType::Rgb16
            | image::ColorType::Rgba16
            | image::ColorType::Rgb32F
            | image::ColorType::Rgba32F
    );
    let data: Vec<f64> = if deep {
        img.into_luma16()
            .into_raw()
            .into_iter()
            .map(f64::from)
            .collect()
    } else {
        img.into_luma8()
            .into_raw()
            .into_iter()
            .map(f64::from)
            .collect()
    };
    Image::new(w, h, data)
        .map_err(|e| InputError(format!("image `{}`: {e}", path.display())).into())
}

fn dic_error(context: &str, e: DicError) -> anyhow::Error {
    InputError(format!("{context}: {e}")).into()
}

fn pair(reference: &Path, current: &Path) -> Result<(Image, Image)> {
    let r = load_grey(reference).map_err(|e| InputError(format!("--reference: {e}")))?;
    let c = load_grey(current).map_err(|e| InputError(format!("--current: {e}")))?;
    if (r.width(), r.height()) != (c.width(), c.height()) {
        return Err(InputError(format!(
            "`{}` is {}x{} but `{}` is {}x{}: the images must have the same size",
            reference.display(),
            r.width(),
            r.height(),
            current.display(),
            c.width(),
            c.height()
        ))
        .into());
    }
    Ok((r, c))
}

fn run_points(a: &PointArgs) -> Result<()> {
    let (Some(reference), Some(current)) = (&a.reference, &a.current) else {
        return Err(InputError(
            "dic needs --reference FILE and --current FILE (or a subcommand: field, track)".into(),
        )
        .into());
    };
    if a.at.is_empty() {
        return Err(InputError("dic needs at least one --at X,Y".into()).into());
    }
    check_prefilter(a.prefilter)?;
    let acceptance = acceptance(a.min_zncc, a.max_sigma)?;
    let (r, c) = pair(reference, current)?;
    let opts = PointOptions {
        subset: a.subset,
        shape: a.shape.into(),
        search_radius: a.search,
        prefilter: a.prefilter,
        ..PointOptions::default()
    };
    let res = points(&r, &c, &a.at, &opts, &acceptance).map_err(|e| match e {
        DicError::SubsetSize { .. } => dic_error("--subset", e),
        DicError::SubsetOutside { .. } => dic_error("--at", e),
        other => dic_error("dic", other),
    })?;
    match a.format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&res)?),
        Format::Text => out!("{}", cellinject_print::dic::points_text(&res)),
    }
    if res.iter().all(|p| matches!(p, PointReport::Missing { .. })) {
        anyhow::bail!(
            "no point matched reliably (converged, ZNCC at least {}, predicted σ at most {} px): nothing to measure",
            a.min_zncc,
            a.max_sigma
        );
    }
    Ok(())
}

/// The acceptance rule of `dic` and `dic field`, checked.
fn acceptance(min_zncc: f64, max_sigma: f64) -> Result<Acceptance> {
    cellinject_core::dic::acceptance(min_zncc, max_sigma)
        .map_err(|e| InputError(format!("--{e}")).into())
}

fn check_prefilter(sigma: f64) -> Result<()> {
    cellinject_core::dic::check_prefilter(sigma).map_err(|e| InputError(format!("--{e}")).into())
}

/// The settings of `dic field`.
struct FieldArgs {
    step: usize,
    subset: usize,
    shape: ShapeArg,
    prefilter: f64,
    acceptance: (f64, f64),
    um_per_px: Option<f64>,
    format: Format,
    threads: Option<usize>,
}

fn run_field(reference: &Path, current: &Path, a: FieldArgs, out: &Path) -> Result<()> {
    let FieldArgs {
        step,
        subset,
        shape,
        prefilter,
        acceptance: (min_zncc, max_sigma),
        um_per_px,
        format,
        threads,
    } = a;
    if threads == Some(0) {
        return Err(InputError("--threads must be at least 1".into()).into());
    }
    if let Some(s) = um_per_px
        && !(s > 0.0 && s.is_finite())
    {
        return Err(InputError(format!("--um-per-px must be positive, got {s}")).into());
    }
    if step == 0 {
        return Err(InputError("--step must be at least 1".into()).into());
    }
    check_prefilter(prefilter)?;
    let acceptance = acceptance(min_zncc, max_sigma)?;
    let mut plan = Plan::new();
    plan.input("--reference", reference)
        .input("--current", current);
    let files = plan.companions("--out", out, &[Kind::Csv, Kind::Png, Kind::Svg])?;
    plan.check()?;
    let (r, c) = pair(reference, current)?;
    let opts = FieldOptions {
        step,
        subset,
        shape: shape.into(),
        prefilter,
        acceptance,
        threads: threads.unwrap_or(0),
        ..FieldOptions::default()
    };
    let t0 = std::time::Instant::now();
    // A bar for the fields that take more than a second (the grid's size is known
    // once the field has checked its options: the first tile reports it).
    let bar = std::sync::OnceLock::new();
    let progress = |done: usize, total: usize| {
        bar.get_or_init(|| {
            crate::progress::delayed_bar(
                total as u64,
                "correlating the grid",
                std::time::Duration::from_secs(1),
            )
        })
        .set_from(done as u64);
    };
    let report = field_report_with_progress(&r, &c, &opts, &progress).map_err(|e| match e {
        DicError::SubsetSize { .. } => dic_error("--subset", e),
        other => dic_error("dic field", other),
    })?;
    let elapsed = t0.elapsed().as_secs_f64();
    drop(bar);
    let f = &report.field;
    let csv = cellinject_print::dic::field_csv(&report);
    let dropped = report.dropped;
    if report.u_range.is_none() || report.v_range.is_none() {
        anyhow::bail!(
            "no grid point matched ({} tried, {} dropped as unreliable): nothing to measure (no texture, or the images do not overlap); no file written",
            f.nx * f.ny,
            dropped.total()
        );
    }
    let maps = cellinject_print::dic::field_maps(f, um_per_px);
    // Panels as wide as the image's aspect allows, at least 480 px tall.
    let aspect = f.nx as f64 / f.ny.max(1) as f64;
    let height = 520u32;
    let width = ((height as f64 - 100.0) * aspect + 220.0).clamp(420.0, 1400.0) as u32;
    let svg = maps_svg(&maps, (width, height)).context("displacement maps")?;
    let rgb = maps_rgb(&maps, (width, height)).context("displacement maps")?;
    let (csv_path, png, svg_path) = (&files[0], &files[1], &files[2]);
    let mut staged = Staged::new();
    staged.add(csv_path, csv.as_bytes())?;
    staged.add(png, &encode_rgb(rgb, png)?)?;
    staged.add(svg_path, svg.as_bytes())?;
    staged.commit()?;
    if format == Format::Json {
        return print_json(report.summary(), &[csv_path, png, svg_path]);
    }
    outln!(
        "{}",
        cellinject_print::dic::field_text(&report, step, elapsed)
    );
    outln!(
        "wrote {}, {} and {} (u left, v right)",
        csv_path.display(),
        png.display(),
        svg_path.display()
    );
    Ok(())
}

/// Files of a directory (PNG/TIFF, sorted) or of a `dir/pattern` with `*` and `?`: at
/// least two.
fn frame_list(spec: &str) -> Result<Vec<PathBuf>> {
    let files = cellinject_cameras::list::frame_files(Path::new(spec))
        .map_err(|e| InputError(format!("--frames `{spec}`: {e}")))?;
    if files.len() < 2 {
        return Err(InputError(format!(
            "--frames `{spec}`: needs at least two PNG/TIFF frames, found {}",
            files.len()
        ))
        .into());
    }
    Ok(files)
}

fn run_track(
    frames: &str,
    roi: &[usize],
    um_per_px: Option<f64>,
    min_zncc: f64,
    shape: ShapeArg,
    out: &Path,
    format: Format,
) -> Result<()> {
    if roi.len() != 4 {
        return Err(InputError(format!("--roi takes X,Y,W,H, got {} numbers", roi.len())).into());
    }
    if let Some(s) = um_per_px {
        if !(s > 0.0 && s.is_finite()) {
            return Err(InputError(format!("--um-per-px must be positive, got {s}")).into());
        }
    }
    if !(-1.0..=1.0).contains(&min_zncc) {
        return Err(InputError(format!("--min-zncc must lie in [-1, 1], got {min_zncc}")).into());
    }
    let files = frame_list(frames)?;
    let mut plan = Plan::new();
    for f in &files {
        plan.input("--frames", f);
    }
    plan.output("--out", out, &[Kind::Csv])?;
    plan.check()?;
    let first = load_grey(&files[0])?;
    let [x, y, width, height] = [0, 1, 2, 3].map(|i| u32::try_from(roi[i]).unwrap_or(u32::MAX));
    let roi = Roi {
        x,
        y,
        width,
        height,
    };
    let mut tracker =
        Tracker::new(&first, roi, shape.into(), min_zncc).map_err(|e| dic_error("--roi", e))?;
    let mut csv = cellinject_print::dic::TrackCsv::new(um_per_px);
    let (mut tracked, mut rejected) = (0, 0);
    let mut worst_zncc = (f64::INFINITY, f64::NEG_INFINITY);
    let t0 = std::time::Instant::now();
    let progress = crate::progress::bar(files.len() as u64, "tracking");
    for (k, f) in files.iter().enumerate() {
        progress.inc();
        let img = if k == 0 { first.clone() } else { load_grey(f)? };
        let p = tracker
            .track(&img)
            .map_err(|e| dic_error(&format!("frame `{}`", f.display()), e))?;
        if p.status == Status::Rejected {
            rejected += 1;
            if p.zncc.is_finite() {
                worst_zncc = (worst_zncc.0.min(p.zncc), worst_zncc.1.max(p.zncc));
            }
        } else {
            tracked += 1;
        }
        let name = f.file_name().and_then(|n| n.to_str()).unwrap_or("");
        csv.row(k, name, &p);
    }
    drop(progress);
    if files.len() > 1 && rejected == files.len() - 1 {
        let zncc = if worst_zncc.0 <= worst_zncc.1 {
            format!(
                "ZNCC from {:.3} to {:.3}, below --min-zncc {min_zncc}",
                worst_zncc.0, worst_zncc.1
            )
        } else {
            "no match at all".to_string()
        };
        anyhow::bail!(
            "every frame after the first was rejected ({zncc}): nothing was tracked; no file written"
        );
    }
    let mut staged = Staged::new();
    staged.add(out, csv.text().as_bytes())?;
    staged.commit()?;
    if format == Format::Json {
        let s = TrackSummary {
            frames: files.len(),
            measured: tracked,
            rejected,
            min_zncc,
        };
        return print_json(s, &[out]);
    }
    outln!(
        "{} frames: {tracked} measured, {rejected} rejected (ZNCC below {min_zncc}); {:.1} ms per frame with file reading",
        files.len(),
        t0.elapsed().as_secs_f64() * 1e3 / files.len() as f64
    );
    outln!("wrote {}", out.display());
    Ok(())
}

/// An 8-bit image in the format `path`'s extension names.
fn encode_grey8(img: &Image, path: &Path) -> Result<Vec<u8>> {
    let data: Vec<u8> = img
        .data()
        .iter()
        .map(|v| v.round().clamp(0.0, 255.0) as u8)
        .collect();
    let buf = image::GrayImage::from_raw(img.width() as u32, img.height() as u32, data)
        .ok_or_else(|| anyhow::anyhow!("image buffer size"))?;
    Ok(encode_image(&buf, path)?)
}

/// The settings of `dic synth`.
struct SynthArgs {
    shift: (f64, f64),
    rotation: f64,
    noise: f64,
    seed: u64,
    format: Format,
}

fn run_synth(size: &[usize], a: SynthArgs, reference: &Path, current: &Path) -> Result<()> {
    let SynthArgs {
        shift,
        rotation,
        noise,
        seed,
        format,
    } = a;
    if size.len() != 2 {
        return Err(InputError(format!(
            "--size takes WIDTH,HEIGHT between 16 and 20000, got {size:?}"
        ))
        .into());
    }
    cellinject_core::dic::check_synth((size[0], size[1]), noise)
        .map_err(|e| InputError(format!("--{e}")))?;
    let mut plan = Plan::new();
    plan.output("--reference", reference, &[Kind::Png, Kind::Tiff])?;
    plan.output("--current", current, &[Kind::Png, Kind::Tiff])?;
    plan.check()?;
    let (r, c) = cellinject_core::dic::synth_pair((size[0], size[1]), shift, rotation, noise, seed)
        .map_err(|e| InputError(format!("--{e}")))?;
    let mut staged = Staged::new();
    staged.add(reference, &encode_grey8(&r, reference)?)?;
    staged.add(current, &encode_grey8(&c, current)?)?;
    staged.commit()?;
    if format == Format::Json {
        let s = SynthSummary {
            size: (size[0], size[1]),
            shift,
            rotation,
            noise,
            seed,
        };
        return print_json(s, &[reference, current]);
    }
    outln!(
        "wrote {} and {} ({}x{}, shift ({}, {}) px, rotation {rotation} deg about the centre, noise {noise})",
        reference.display(),
        current.display(),
        size[0],
        size[1],
        shift.0,
        shift.1
    );
    Ok(())
}

/// Runs `cellinject dic`.
pub fn run(a: &DicArgs) -> Result<()> {
    match &a.command {
        None => run_points(&a.points),
        Some(DicCommand::Field {
            reference,
            current,
            step,
            subset,
            shape,
            prefilter,
            min_zncc,
            max_sigma,
            out,
            um_per_px,
            format,
            threads,
        }) => run_field(
            reference,
            current,
            FieldArgs {
                step: *step,
                subset: *subset,
                shape: *shape,
                prefilter: *prefilter,
                acceptance: (*min_zncc, *max_sigma),
                um_per_px: *um_per_px,
                format: *format,
                threads: *threads,
            },
            out,
        ),
        Some(DicCommand::Synth {
            size,
            shift,
            rotation,
            noise,
            seed,
            reference,
            current,
            format,
        }) => run_synth(
            size,
            SynthArgs {
                shift: *shift,
                rotation: *rotation,
                noise: *noise,
                seed: *seed,
                format: *format,
            },
            reference,
            current,
        ),
        Some(DicCommand::Track {
            frames,
            roi,
            um_per_px,
            min_zncc,
            shape,
            out,
            format,
        }) => run_track(frames, roi, *um_per_px, *min_zncc, *shape, out, *format),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_parse_and_refuse_garbage() {
        assert_eq!(parse_pair("10,20.5"), Ok((10.0, 20.5)));
        assert!(parse_pair("10").is_err());
        assert!(parse_pair("a,b").is_err());
        assert!(parse_pair("nan,1").is_err());
    }
}
