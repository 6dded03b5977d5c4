//! `cellinject dic ...`: digital image correlation on image files.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Result;
use cellinject_core::dic::{PointReport, field_report, points};
use cellinject_dic::field::FieldOptions;
use cellinject_dic::track::{Roi, Status, Tracker};
use cellinject_dic::{DicError, Image, PointOptions, Shape};
use clap::{Args, Subcommand, ValueEnum};

use crate::output::{Table, write_atomic};
use crate::{Format, InputError};

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
#[command(args_conflicts_with_subcommands = true)]
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
    #[arg(long, value_name = "FILE")]
    reference: Option<PathBuf>,
    /// Current image, same size.
    #[arg(long, value_name = "FILE")]
    current: Option<PathBuf>,
    /// A point of the reference, pixels (x = column, y = row, origin at the centre of the
    /// top-left pixel); repeat for more points.
    #[arg(long = "at", value_name = "X,Y", value_parser = parse_pair, allow_negative_numbers = true)]
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
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
}

/// DIC subcommands.
#[derive(Debug, Subcommand)]
pub enum DicCommand {
    /// Displacement field on a grid (reliability-guided, parallel).
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
        /// CSV output; a displacement-map PNG is written beside it.
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
    },
    /// Write a pair of exact synthetic speckle images (Gaussians integrated over the
    /// pixels, Gaussian noise, 8-bit) related by a known shift and rotation.
    Synth {
        /// Image size: width,height.
        #[arg(long, value_delimiter = ',', num_args = 1, default_value = "512,512")]
        size: Vec<usize>,
        /// Shift of the current image: u,v pixels.
        #[arg(long, value_parser = parse_pair, allow_negative_numbers = true, default_value = "0.25,0")]
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
        /// Reference image output (PNG).
        #[arg(long, default_value = "reference.png")]
        reference: PathBuf,
        /// Current image output (PNG).
        #[arg(long, default_value = "current.png")]
        current: PathBuf,
    },
    /// Follow a region through a sequence of frames.
    Track {
        /// A directory of frames (PNG/TIFF, in name order) or a pattern such as `run/*.png`.
        #[arg(long, value_name = "DIR|GLOB")]
        frames: String,
        /// Region to follow in the first frame: x,y,width,height (pixels).
        #[arg(long, value_name = "X,Y,W,H", value_delimiter = ',', num_args = 1)]
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

/// Loads a PNG or TIFF as grey levels in its own units (0-255 or 0-65535).
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
    let r = load_grey(reference)?;
    let c = load_grey(current)?;
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
    let (r, c) = pair(reference, current)?;
    let opts = PointOptions {
        subset: a.subset,
        shape: a.shape.into(),
        search_radius: a.search,
        prefilter: a.prefilter,
        ..PointOptions::default()
    };
    let res = points(&r, &c, &a.at, &opts).map_err(|e| match e {
        DicError::SubsetSize { .. } => dic_error("--subset", e),
        DicError::SubsetOutside { .. } => dic_error("--at", e),
        other => dic_error("dic", other),
    })?;
    match a.format {
        Format::Json => println!("{}", serde_json::to_string_pretty(&res)?),
        Format::Text => {
            let mut t = Table::new(
                &[
                    "x",
                    "y",
                    "u [px]",
                    "v [px]",
                    "zncc",
                    "iter.",
                    "σ_u [px]",
                    "σ_v [px]",
                ],
                &[true; 8],
            );
            for p in &res {
                t.row(match *p {
                    PointReport::Found {
                        x,
                        y,
                        u,
                        v,
                        zncc,
                        iterations,
                        converged,
                        sigma_u,
                        sigma_v,
                        ..
                    } => vec![
                        format!("{x}"),
                        format!("{y}"),
                        format!("{u:.4}"),
                        format!("{v:.4}"),
                        format!("{zncc:.4}"),
                        format!("{iterations}{}", if converged { "" } else { "!" }),
                        format!("{sigma_u:.4}"),
                        format!("{sigma_v:.4}"),
                    ],
                    PointReport::Missing { x, y, .. } => vec![
                        format!("{x}"),
                        format!("{y}"),
                        "no match".into(),
                        String::new(),
                        String::new(),
                        String::new(),
                        String::new(),
                        String::new(),
                    ],
                });
            }
            print!("{}", t.text());
        }
    }
    Ok(())
}

/// A colour for t in [0, 1] (a perceptual blue-green-yellow ramp).
fn ramp(t: f64) -> [u8; 3] {
    let stops = [
        [68.0, 1.0, 84.0],
        [59.0, 82.0, 139.0],
        [33.0, 145.0, 140.0],
        [94.0, 201.0, 98.0],
        [253.0, 231.0, 37.0],
    ];
    let t = t.clamp(0.0, 1.0) * 4.0;
    let i = (t.floor() as usize).min(3);
    let f = t - i as f64;
    let c = |k: usize| (stops[i][k] + (stops[i + 1][k] - stops[i][k]) * f) as u8;
    [c(0), c(1), c(2)]
}

fn check_prefilter(sigma: f64) -> Result<()> {
    if !(0.0..=20.0).contains(&sigma) {
        return Err(InputError(format!(
            "--prefilter must lie in [0, 20] pixels, got {sigma}"
        ))
        .into());
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn run_field(
    reference: &Path,
    current: &Path,
    step: usize,
    subset: usize,
    shape: ShapeArg,
    prefilter: f64,
    out: &Path,
) -> Result<()> {
    if step == 0 {
        return Err(InputError("--step must be at least 1".into()).into());
    }
    check_prefilter(prefilter)?;
    let (r, c) = pair(reference, current)?;
    let opts = FieldOptions {
        step,
        subset,
        shape: shape.into(),
        prefilter,
        ..FieldOptions::default()
    };
    let t0 = std::time::Instant::now();
    let report = field_report(&r, &c, &opts).map_err(|e| match e {
        DicError::SubsetSize { .. } => dic_error("--subset", e),
        other => dic_error("dic field", other),
    })?;
    let elapsed = t0.elapsed().as_secs_f64();
    let f = &report.field;
    let mut csv =
        String::from("x,y,u,v,du_dx,du_dy,dv_dx,dv_dy,zncc,iterations,converged,sigma_u,sigma_v\n");
    let found = report.found;
    for (k, p) in f.points.iter().enumerate() {
        let (x, y) = report.position(k);
        match p {
            Some(p) => {
                let _ = writeln!(
                    csv,
                    "{x},{y},{:.6},{:.6},{:.6e},{:.6e},{:.6e},{:.6e},{:.6},{},{},{:.6},{:.6}",
                    p.u,
                    p.v,
                    p.gradients[0],
                    p.gradients[1],
                    p.gradients[2],
                    p.gradients[3],
                    p.zncc,
                    p.iterations,
                    p.converged,
                    p.sigma_u,
                    p.sigma_v
                );
            }
            None => {
                let _ = writeln!(csv, "{x},{y},,,,,,,,0,false,,");
            }
        }
    }
    write_atomic(out, &csv)
        .map_err(|e| InputError(format!("--out `{}`: cannot write: {e}", out.display())))?;
    // Displacement maps: u and v side by side, each on its own colour scale.
    let ru = report.u_range.unwrap_or((f64::INFINITY, f64::NEG_INFINITY));
    let rv = report.v_range.unwrap_or((f64::INFINITY, f64::NEG_INFINITY));
    let (nx, ny) = (f.nx as u32, f.ny as u32);
    let gap = 4;
    let mut img = image::RgbImage::from_pixel(2 * nx + gap, ny, image::Rgb([255, 255, 255]));
    for (k, p) in f.points.iter().enumerate() {
        let (i, j) = ((k % f.nx) as u32, (k / f.nx) as u32);
        let (cu, cv) = match p {
            Some(p) => {
                let t = |v: f64, r: (f64, f64)| {
                    if r.1 > r.0 {
                        (v - r.0) / (r.1 - r.0)
                    } else {
                        0.5
                    }
                };
                (ramp(t(p.u, ru)), ramp(t(p.v, rv)))
            }
            None => ([128, 128, 128], [128, 128, 128]),
        };
        img.put_pixel(i, j, image::Rgb(cu));
        img.put_pixel(nx + gap + i, j, image::Rgb(cv));
    }
    let png = out.with_extension("png");
    let tmp = out.with_extension("png.tmp");
    img.save_with_format(&tmp, image::ImageFormat::Png)
        .map_err(anyhow::Error::from)
        .and_then(|()| std::fs::rename(&tmp, &png).map_err(anyhow::Error::from))
        .map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            InputError(format!("cannot write `{}`: {e}", png.display()))
        })?;
    println!(
        "{found} of {} grid points ({}x{}, step {step}) in {elapsed:.3} s ({:.0} points/s)",
        f.nx * f.ny,
        f.nx,
        f.ny,
        found as f64 / elapsed.max(1e-9)
    );
    println!(
        "u from {:.4} to {:.4} px, v from {:.4} to {:.4} px",
        ru.0, ru.1, rv.0, rv.1
    );
    println!(
        "wrote {} and {} (u left, v right)",
        out.display(),
        png.display()
    );
    Ok(())
}

/// Files of a directory (PNG/TIFF, sorted) or of a `dir/pattern` with `*` and `?`.
fn frame_list(spec: &str) -> Result<Vec<PathBuf>> {
    let path = Path::new(spec);
    let is_image = |p: &Path| {
        p.extension()
            .and_then(|e| e.to_str())
            .map(|e| matches!(e.to_ascii_lowercase().as_str(), "png" | "tif" | "tiff"))
            .unwrap_or(false)
    };
    let (dir, pattern) = if path.is_dir() {
        (path.to_path_buf(), None)
    } else {
        let dir = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        (dir.to_path_buf(), Some(name.to_string()))
    };
    let entries = std::fs::read_dir(&dir).map_err(|e| {
        InputError(format!(
            "--frames `{spec}`: cannot read directory `{}`: {e}",
            dir.display()
        ))
    })?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && is_image(p))
        .filter(|p| match &pattern {
            None => true,
            Some(pat) => p
                .file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| wildcard(pat, n)),
        })
        .collect();
    files.sort();
    if files.len() < 2 {
        return Err(InputError(format!(
            "--frames `{spec}`: needs at least two PNG/TIFF frames, found {}",
            files.len()
        ))
        .into());
    }
    Ok(files)
}

/// Matches `*` (any run) and `?` (one character).
fn wildcard(pattern: &str, name: &str) -> bool {
    let (p, n): (Vec<char>, Vec<char>) = (pattern.chars().collect(), name.chars().collect());
    let (mut i, mut j, mut star, mut mark) = (0, 0, None, 0);
    while j < n.len() {
        if i < p.len() && (p[i] == '?' || p[i] == n[j]) {
            i += 1;
            j += 1;
        } else if i < p.len() && p[i] == '*' {
            star = Some(i);
            mark = j;
            i += 1;
        } else if let Some(s) = star {
            i = s + 1;
            mark += 1;
            j = mark;
        } else {
            return false;
        }
    }
    while i < p.len() && p[i] == '*' {
        i += 1;
    }
    i == p.len()
}

fn run_track(
    frames: &str,
    roi: &[usize],
    um_per_px: Option<f64>,
    min_zncc: f64,
    shape: ShapeArg,
    out: &Path,
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
    let mut csv = String::from("frame,file,u_px,v_px,u_m,v_m,zncc,iterations,sigma_u_px,status\n");
    let (mut tracked, mut rejected) = (0, 0);
    let t0 = std::time::Instant::now();
    for (k, f) in files.iter().enumerate() {
        let img = if k == 0 { first.clone() } else { load_grey(f)? };
        let p = tracker
            .track(&img)
            .map_err(|e| dic_error(&format!("frame `{}`", f.display()), e))?;
        let status = match p.status {
            Status::Tracked => "tracked",
            Status::Recovered => "recovered",
            Status::Rejected => "rejected",
        };
        if p.status == Status::Rejected {
            rejected += 1;
        } else {
            tracked += 1;
        }
        let m = |v: f64| {
            um_per_px
                .map(|s| format!("{:.6e}", v * s * 1e-6))
                .unwrap_or_default()
        };
        let num = |v: f64| {
            if v.is_finite() {
                format!("{v:.6}")
            } else {
                String::new()
            }
        };
        let _ = writeln!(
            csv,
            "{k},{},{},{},{},{},{:.6},{},{},{status}",
            f.file_name().and_then(|n| n.to_str()).unwrap_or(""),
            num(p.u),
            num(p.v),
            m(p.u),
            m(p.v),
            p.zncc,
            p.iterations,
            num(p.sigma_u)
        );
    }
    write_atomic(out, &csv)
        .map_err(|e| InputError(format!("--out `{}`: cannot write: {e}", out.display())))?;
    println!(
        "{} frames: {tracked} measured, {rejected} rejected (ZNCC below {min_zncc}); {:.1} ms per frame with file reading",
        files.len(),
        t0.elapsed().as_secs_f64() * 1e3 / files.len() as f64
    );
    println!("wrote {}", out.display());
    Ok(())
}

fn save_grey8(img: &Image, path: &Path) -> Result<()> {
    let data: Vec<u8> = img
        .data()
        .iter()
        .map(|v| v.round().clamp(0.0, 255.0) as u8)
        .collect();
    let buf = image::GrayImage::from_raw(img.width() as u32, img.height() as u32, data)
        .ok_or_else(|| anyhow::anyhow!("image buffer size"))?;
    let tmp = path.with_extension("png.tmp");
    buf.save_with_format(&tmp, image::ImageFormat::Png)
        .map_err(anyhow::Error::from)
        .and_then(|()| std::fs::rename(&tmp, path).map_err(anyhow::Error::from))
        .map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            InputError(format!("cannot write `{}`: {e}", path.display())).into()
        })
}

#[allow(clippy::too_many_arguments)]
fn run_synth(
    size: &[usize],
    shift: (f64, f64),
    rotation: f64,
    noise: f64,
    seed: u64,
    reference: &Path,
    current: &Path,
) -> Result<()> {
    if size.len() != 2 || size[0] < 16 || size[1] < 16 || size[0] > 20000 || size[1] > 20000 {
        return Err(InputError(format!(
            "--size takes WIDTH,HEIGHT between 16 and 20000, got {size:?}"
        ))
        .into());
    }
    if !(noise >= 0.0 && noise.is_finite()) {
        return Err(InputError(format!(
            "--noise must be a non-negative number, got {noise}"
        ))
        .into());
    }
    let mut p = cellinject_dic::synth::SpeckleParams::default_for(size[0], size[1]);
    p.noise = noise;
    let sp = cellinject_dic::synth::Speckle::new(&p, seed);
    let r = sp.render_shifted(0.0, 0.0, 0.0, 2 * seed + 1);
    let c = sp.render_shifted(shift.0, shift.1, rotation.to_radians(), 2 * seed + 2);
    save_grey8(&r, reference)?;
    save_grey8(&c, current)?;
    println!(
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
            out,
        }) => run_field(reference, current, *step, *subset, *shape, *prefilter, out),
        Some(DicCommand::Synth {
            size,
            shift,
            rotation,
            noise,
            seed,
            reference,
            current,
        }) => run_synth(size, *shift, *rotation, *noise, *seed, reference, current),
        Some(DicCommand::Track {
            frames,
            roi,
            um_per_px,
            min_zncc,
            shape,
            out,
        }) => run_track(frames, roi, *um_per_px, *min_zncc, *shape, out),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wildcards_match_like_a_shell() {
        assert!(wildcard("*.png", "frame_001.png"));
        assert!(wildcard("frame_??1.png", "frame_001.png"));
        assert!(!wildcard("*.png", "frame_001.tif"));
        assert!(wildcard("*", "x"));
        assert!(!wildcard("a*b", "acd"));
    }

    #[test]
    fn pairs_parse_and_refuse_garbage() {
        assert_eq!(parse_pair("10,20.5"), Ok((10.0, 20.5)));
        assert!(parse_pair("10").is_err());
        assert!(parse_pair("a,b").is_err());
        assert!(parse_pair("nan,1").is_err());
    }
}
