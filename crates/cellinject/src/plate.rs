//! `cellinject plate`: the matrix feeder's description file: realistic plates from a
//! seed, and a check of any plate file.

use std::path::{Path, PathBuf};

use anyhow::Result;
use cellinject_plate::{GenerateOptions, Plate, generate};
use clap::Subcommand;
use serde::Serialize;

use crate::output::print_json;
use crate::{Format, InputError};
use cellinject_files::{Kind as FileKind, Plan, write_one};

/// The plate subcommands.
#[derive(Debug, Subcommand)]
pub enum PlateCommand {
    /// A realistic plate: cells of 10-30 µm off-centre in their wells, empty wells,
    /// doublets of touching cells, debris; deterministic for a seed.
    #[command(
        after_help = "Examples:\n  cellinject plate generate --rows 4 --cols 6 --out plate.toml\n  cellinject plate generate --rows 10 --cols 12 --seed 7 --debris-fraction 0.3 --out big.toml"
    )]
    Generate {
        /// Rows of wells (along plate y).
        #[arg(long, default_value_t = 4)]
        rows: u32,
        /// Columns of wells (along plate x).
        #[arg(long, default_value_t = 6)]
        cols: u32,
        /// m between well centres.
        #[arg(long, default_value_t = 150e-6, allow_negative_numbers = true)]
        pitch: f64,
        /// m, stage coordinates of well [0, 0] (`X,Y`).
        #[arg(long, value_name = "X,Y", default_value = "0,0", value_parser = parse_origin, allow_hyphen_values = true)]
        origin: [f64; 2],
        /// Fraction of wells left empty.
        #[arg(long, default_value_t = 0.1, allow_negative_numbers = true)]
        empty_fraction: f64,
        /// Fraction of wells that also hold a piece of debris (3-9 µm).
        #[arg(long, default_value_t = 0.2, allow_negative_numbers = true)]
        debris_fraction: f64,
        /// Fraction of occupied wells holding two touching cells.
        #[arg(long, default_value_t = 0.1, allow_negative_numbers = true)]
        doublet_fraction: f64,
        /// Seed of the plate's randomness.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// The plate file to write (`.toml`).
        #[arg(long)]
        out: PathBuf,
        /// What to print.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// Puts a plate under the twin's microscope, finds its cells in one frame (the
    /// pipette moved out of view) and scores them against the plate's truth:
    /// precision, recall, centre and diameter errors.
    #[command(
        after_help = "Examples:\n  cellinject plate detect --plate plate.toml\n  cellinject plate detect --plate plate.toml --zoom 5 --format json"
    )]
    Detect {
        /// The plate file.
        #[arg(long)]
        plate: PathBuf,
        /// Magnification (2.5 to 10); the frame is the full sensor.
        #[arg(long, default_value_t = 2.5, allow_negative_numbers = true)]
        zoom: f64,
        #[command(flatten)]
        twin: crate::sim::TwinArgs,
    },
    /// Reads a plate file, checks it (cells inside their wells, no overlaps, sizes in
    /// their class) and says what it holds.
    #[command(after_help = "Examples:\n  cellinject plate check --plate plate.toml")]
    Check {
        /// The plate file.
        #[arg(long)]
        plate: PathBuf,
        /// What to print.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
}

/// What a plate holds.
#[derive(Debug, Serialize)]
struct Summary {
    rows: u32,
    cols: u32,
    pitch_m: f64,
    wells: usize,
    cells: usize,
    /// Wells holding two or more cells.
    doublets: usize,
    empty_wells: usize,
    debris: usize,
    /// Smallest and largest cell, m (null without cells).
    cell_diameter_m: Option<[f64; 2]>,
}

fn summary(p: &Plate) -> Summary {
    let mut per_well = vec![0usize; p.wells()];
    for c in &p.cells {
        per_well[c.well[0] as usize * p.cols as usize + c.well[1] as usize] += 1;
    }
    let d = p.cells.iter().map(|c| c.diameter);
    let cell_diameter_m = (!p.cells.is_empty()).then(|| {
        [
            d.clone().fold(f64::INFINITY, f64::min),
            d.fold(0.0, f64::max),
        ]
    });
    Summary {
        rows: p.rows,
        cols: p.cols,
        pitch_m: p.pitch,
        wells: p.wells(),
        cells: p.cells.len(),
        doublets: per_well.iter().filter(|n| **n >= 2).count(),
        empty_wells: per_well.iter().filter(|n| **n == 0).count(),
        debris: p.debris.len(),
        cell_diameter_m,
    }
}

/// `n` and the noun, singular or plural.
fn count(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

fn say(s: &Summary) {
    let sizes = s
        .cell_diameter_m
        .map(|d| {
            if (d[1] - d[0]).abs() < 0.05e-6 {
                format!(" of {:.1} µm", d[0] * 1e6)
            } else {
                format!(" of {:.1}-{:.1} µm", d[0] * 1e6, d[1] * 1e6)
            }
        })
        .unwrap_or_default();
    outln!(
        "{}x{} wells at {:.1} µm: {}{sizes}, {}, {}, {}",
        s.rows,
        s.cols,
        s.pitch_m * 1e6,
        count(s.cells, "cell", "cells"),
        count(s.doublets, "doublet", "doublets"),
        count(s.empty_wells, "empty well", "empty wells"),
        count(s.debris, "piece of debris", "pieces of debris")
    );
}

fn parse_origin(s: &str) -> Result<[f64; 2], String> {
    crate::commands::parse_pair(s, "X,Y in metres")
}

/// Reads and checks a plate file; errors name the file and the key.
pub fn load(arg: &str, path: &Path) -> Result<Plate> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| InputError(format!("{arg} `{}`: cannot read: {e}", path.display())))?;
    cellinject_config::plate::parse(&text)
        .map_err(|e| InputError(format!("plate file `{}`: {e}", path.display())).into())
}

/// Whether a plate subcommand reads the manipulator description (only `detect`,
/// which builds the twin).
pub fn uses_description(cmd: &PlateCommand) -> bool {
    matches!(cmd, PlateCommand::Detect { .. })
}

/// `plate detect`.
fn detect(
    d: &cellinject_config::Description,
    plate_path: &Path,
    zoom: f64,
    args: &crate::sim::TwinArgs,
) -> Result<()> {
    use cellinject_core::cells::{PixelFrame, detect_and_score};
    use cellinject_core::sim::{Acquisition, frame};
    let plate = load("--plate", plate_path)?;
    let (twin, mut rig) = crate::sim::build(d, args)?;
    let lock = || twin.lock().unwrap_or_else(|e| e.into_inner());
    {
        // The pipette rides on the stage: it starts 2 mm to the side, out of the view
        // (and never sweeps through the cells on its way there).
        let mut t = lock();
        t.load_plate(&plate);
        t.world.stage.place(0, -2e-3);
    }
    let f = frame(&mut rig, zoom, Acquisition::Full, None).map_err(|e| match e {
        cellinject_core::sim::SimError::Device { what, source } => {
            InputError(format!("{what}: {source}")).into()
        }
        other => anyhow::anyhow!("{other}"),
    })?;
    let g = lock().camera.grid();
    let at = PixelFrame {
        x0: g.x0,
        y0: g.z0,
        pitch: g.pitch,
    };
    let r = detect_and_score(&plate, &f.pixels, f.width as usize, f.height as usize, at)
        .map_err(|e| anyhow::anyhow!("cell detection: {e}"))?;
    if r.true_cells == 0 && r.found_cells == 0 {
        // Nothing to score: say where the frame and the plate are instead of NaN.
        let fx = [g.x0, g.x0 + (f.width as f64 - 1.0) * g.pitch];
        let fy = [g.z0, g.z0 + (f.height as f64 - 1.0) * g.pitch];
        let half = 0.5 * plate.pitch;
        let px = [
            plate.origin[0] - half,
            plate.origin[0] - half + plate.cols as f64 * plate.pitch,
        ];
        let py = [
            plate.origin[1] - half,
            plate.origin[1] - half + plate.rows as f64 * plate.pitch,
        ];
        let mm = |v: [f64; 2]| format!("[{:.3}, {:.3}] mm", v[0] * 1e3, v[1] * 1e3);
        anyhow::bail!(
            "no cell in view at {zoom}x: the frame covers stage x {}, y {}, and `{}`'s wells span x {}, y {}{}",
            mm(fx),
            mm(fy),
            plate_path.display(),
            mm(px),
            mm(py),
            if plate.cells.is_empty() {
                " (the plate holds no cell)".to_string()
            } else {
                format!(
                    " ({} cells, none wholly in the frame: set the plate's origin inside the frame)",
                    plate.cells.len()
                )
            }
        );
    }
    if args.format() == Format::Json {
        return print_json(&r, &[]);
    }
    outln!(
        "{}x{} frame at {zoom}x ({:.3} µm per pixel): {} of the plate's cells and {} pieces of debris in view",
        f.width,
        f.height,
        g.pitch * 1e6,
        r.true_cells,
        r.true_debris
    );
    outln!(
        "found {} cells ({} split from a touching neighbour) and {} debris; {} match a true cell, {} do not ({} of them debris), {} cells missed",
        r.found_cells,
        r.cells.iter().filter(|c| c.split).count(),
        r.found_debris,
        r.true_positives,
        r.false_positives,
        r.debris_called_cells,
        r.false_negatives
    );
    let ratio = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.3}"));
    let um = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{:.3} µm", v * 1e6));
    outln!(
        "precision {}, recall {}; centre error median {}, 95th percentile {}; diameter error median {}",
        ratio(r.precision),
        ratio(r.recall),
        um(r.centre_error_m.map(|c| c[0])),
        um(r.centre_error_m.map(|c| c[1])),
        um(r.diameter_error_m)
    );
    Ok(())
}

/// Runs a plate subcommand (`d`: the manipulator description, for `detect`).
pub fn run(
    cmd: &PlateCommand,
    d: impl FnOnce() -> Result<cellinject_config::Description>,
) -> Result<()> {
    match cmd {
        PlateCommand::Detect { plate, zoom, twin } => detect(&d()?, plate, *zoom, twin),
        PlateCommand::Generate {
            rows,
            cols,
            pitch,
            origin,
            empty_fraction,
            debris_fraction,
            doublet_fraction,
            seed,
            out,
            format,
        } => {
            let mut plan = Plan::new();
            plan.output("--out", out, &[FileKind::Toml])?;
            plan.check()?;
            let opts = GenerateOptions {
                rows: *rows,
                cols: *cols,
                pitch: *pitch,
                origin: *origin,
                empty_fraction: *empty_fraction,
                debris_fraction: *debris_fraction,
                doublet_fraction: *doublet_fraction,
                seed: *seed,
            };
            let plate = generate(&opts).map_err(
                |cellinject_plate::PlateError::Invalid { key, reason }| {
                    // The grid's keys are the options' here.
                    let arg = match key.as_str() {
                        "plate.rows" => "--rows",
                        "plate.cols" => "--cols",
                        "plate.pitch" => "--pitch",
                        k if k.starts_with("plate.origin") => "--origin",
                        k => k,
                    };
                    InputError(format!("{arg}: {reason}"))
                },
            )?;
            let comment = format!(
                "A matrix feeder made by `cellinject plate generate --rows {rows} --cols {cols} --pitch {pitch:e} --origin {},{} --empty-fraction {empty_fraction} --debris-fraction {debris_fraction} --doublet-fraction {doublet_fraction} --seed {seed}`.\n[[cell]] and [[debris]] are the twin's ground truth; the injection workflow never reads them.",
                origin[0], origin[1]
            );
            let text = cellinject_config::plate::to_toml(&plate, &comment);
            write_one(out, text.as_bytes())?;
            let s = summary(&plate);
            if *format == Format::Json {
                return print_json(&s, &[out.as_path()]);
            }
            say(&s);
            outln!("wrote {}", out.display());
            Ok(())
        }
        PlateCommand::Check { plate, format } => {
            let p = load("--plate", plate)?;
            let s = summary(&p);
            if *format == Format::Json {
                return print_json(&s, &[]);
            }
            say(&s);
            Ok(())
        }
    }
}
