//! `cellinject plate`: the matrix feeder's description file: realistic plates from a
//! seed, and a check of any plate file.

use std::path::{Path, PathBuf};

use anyhow::Result;
use cellinject_plate::{GenerateOptions, Plate, generate};
use clap::Subcommand;

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
    /// their class; every problem listed) and that the feeder of the manipulator
    /// description (--config) can present every well at the run's zoom, as `run`
    /// does, and says what it holds.
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

/// The plate file at `path` (`plate check`), refused with every problem it has, one
/// per line.
fn load_all(path: &Path) -> Result<Plate> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| InputError(format!("--plate `{}`: cannot read: {e}", path.display())))?;
    cellinject_config::plate::parse_all(&text).map_err(|all| {
        let list: Vec<String> = all.iter().map(|e| format!("  {e}")).collect();
        let what = match all.as_slice() {
            [one] => one.to_string(),
            _ => format!("{} problems:\n{}", all.len(), list.join("\n")),
        };
        InputError(format!("plate file `{}`: {what}", path.display())).into()
    })
}

/// Refuses a plate the feeder of the bench `opened` cannot present with `options` (the
/// check `run` makes as it starts, `cellinject_station::check_plate`): exit 2 naming
/// `what` and the wells for a plan that cannot be; 1 for a bench that fails.
pub(crate) fn feeder_presents(
    d: &cellinject_config::Description,
    opened: &mut cellinject_session::Opened,
    plate: &Plate,
    options: cellinject_core::inject::Options,
    what: &str,
) -> Result<()> {
    use cellinject_core::inject::WorkflowError;
    let verdict = cellinject_station::check_plate(d, opened, plate, options)
        .map_err(|e| anyhow::anyhow!("cannot build the twin: {e}"))?;
    verdict.map_err(|e| match e {
        WorkflowError::Plan(_)
        | WorkflowError::PitchTooLarge { .. }
        | WorkflowError::Invalid { .. } => InputError(format!("{what}: {e}")).into(),
        e => anyhow::anyhow!("checking the plate: {e}"),
    })
}

/// Whether a plate subcommand reads the manipulator description (`detect`, which
/// builds the twin, and `check`, which plans the fields over the plate on it).
pub fn uses_description(cmd: &PlateCommand) -> bool {
    matches!(
        cmd,
        PlateCommand::Detect { .. } | PlateCommand::Check { .. }
    )
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
        "{}",
        cellinject_print::plate::detect_text(&r, zoom, (f.width, f.height), g.pitch)
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
            let s = plate.summary();
            if *format == Format::Json {
                return print_json(&s, &[out.as_path()]);
            }
            outln!("{}", cellinject_print::plate::summary_text(&s));
            outln!("wrote {}", out.display());
            Ok(())
        }
        PlateCommand::Check { plate, format } => {
            let p = load_all(plate)?;
            // And what `run` checks with the description: the feeder presents every
            // well (the fields planned at the run's zoom, on the description's twin).
            let d = d()?;
            let mut opened = crate::backend::open_with(
                &d,
                &crate::sim::TwinArgs::with_seed(d.sim.seed),
                &cellinject_config::rigfile::RigFile::twin(),
                |devices| devices,
            )?;
            let options = cellinject_core::inject::Options::default();
            feeder_presents(
                &d,
                &mut opened,
                &p,
                options,
                &format!("plate file `{}`", plate.display()),
            )?;
            let s = p.summary();
            if *format == Format::Json {
                return print_json(&s, &[]);
            }
            outln!("{}", cellinject_print::plate::summary_text(&s));
            Ok(())
        }
    }
}
