//! `cellinject fea`: the whole-manipulator structural model with joints from the 3-D FEM.
//!
//! The front end of [`cellinject_fea`]: arguments, the joint cache's directory, text
//! and JSON output, the SVG drawing. Every number comes from the library's reports.

use std::path::PathBuf;

use anyhow::Result;
use cellinject_config::Description;
use cellinject_fea::{Approach, FeaError, FeaModel, FeaOptions, JointStore, Member, PreloadKind};
use cellinject_plot::contour::{structure_rgb, structure_svg};
use clap::{Args, Subcommand};

use crate::{Format, InputError};
use cellinject_files::{Kind, Plan, encode_rgb, write_one};
use cellinject_print::fea as print;

/// `cellinject fea`: one load case, or a subcommand.
#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct FeaArgs {
    #[command(subcommand)]
    command: Option<FeaCommand>,
    #[command(flatten)]
    solve: SolveArgs,
}

/// How the structural model is built: the joints' mesh level and approach 2's preload.
#[derive(Debug, Clone, Copy, Args)]
pub struct MeshArgs {
    /// Refinement level of the joints' 3-D FEM (1: 25k unknowns per joint, under a
    /// second; 2: 184k, about ten seconds, 1-2 % stiffer results converged).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=3))]
    level: u8,
    /// Approach 2's pre-tension of J3 in the model.
    #[arg(long, value_enum, default_value_t = PreloadArg::Deflection)]
    preload: PreloadArg,
}

/// Whether the solved joints are kept between runs, and whether a solve larger than
/// the available memory may start.
#[derive(Debug, Clone, Copy, Args)]
pub struct CacheArgs {
    /// Solve the joints' 3-D FEM without reading or writing the joint cache
    /// ($XDG_CACHE_HOME/cellinject, else the platform's cache directory).
    #[arg(long)]
    no_cache: bool,
    /// Do it anyway: start a joint FEM even when its estimated peak memory exceeds the
    /// memory this machine has available (it may then swap for a long time, or be
    /// killed); and, as on every command, replace output files in the way without
    /// keeping them (the same flag as the global `--force`).
    #[arg(long)]
    force: bool,
}

/// Memory a joint solve may use, bytes: what the machine has available (Linux:
/// `MemAvailable`), capped by `CELLINJECT_MAX_MEMORY` (bytes) if set.
fn available_memory() -> Option<f64> {
    let machine = (|| {
        let text = std::fs::read_to_string("/proc/meminfo").ok()?;
        let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
        let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kb * 1024.0)
    })();
    let cap = std::env::var("CELLINJECT_MAX_MEMORY")
        .ok()
        .and_then(|v| v.trim().parse::<f64>().ok())
        .filter(|v| *v > 0.0);
    match (machine, cap) {
        (Some(m), Some(c)) => Some(m.min(c)),
        (m, c) => m.or(c),
    }
}

/// Says what the joint solves will cost when they are long, and refuses them (exit 2)
/// when they would not fit in memory, unless `--force`.
fn check_cost(d: &Description, levels: &[usize], cache: &CacheArgs) -> Result<()> {
    let store = joint_store(cache);
    let cost = cellinject_fea::cost::joints_cost(&d.structure, levels, store.as_ref())
        .map_err(fea_error)?;
    if cost.solves == 0 {
        return Ok(());
    }
    let gb = cost.peak_bytes / 1e9;
    if let Some(avail) = available_memory()
        && cost.peak_bytes > avail
        && !cache.force
    {
        return Err(InputError(format!(
            "the joints' FEM at level {levels:?} ({} unknowns) needs about {gb:.1} GB of memory and {:.0} s; {:.1} GB are available: use a lower --level, or --force",
            cost.unknowns,
            cost.seconds,
            avail / 1e9
        ))
        .into());
    }
    if cost.seconds > 2.0 {
        eprintln!(
            "solving {} joint FEM(s) of up to {} unknowns: about {:.0} s and {gb:.1} GB of memory (kept in the cache for the next run)",
            cost.solves, cost.unknowns, cost.seconds
        );
    }
    Ok(())
}

/// One static load case.
#[derive(Debug, Args)]
pub struct SolveArgs {
    /// Pre-tensioning approach: 1 (assembly translation, the forces alone) or 2 (J3
    /// assembled pre-deflected by the model's Δq0).
    #[arg(long, required = true, value_parser = clap::value_parser!(u8).range(1..=2))]
    approach: Option<u8>,
    /// Forces on the ends of the motor loops A1-J1 and A2-J2, N (negative: compressive),
    /// as the paper's F11,F12.
    #[arg(long, required = true, value_name = "F11,F12", value_parser = parse_forces, allow_hyphen_values = true)]
    forces: Option<[f64; 2]>,
    /// Also draw the deformed structure coloured by displacement, like Fig. 4 (`.svg` or `.png`).
    #[arg(long, value_name = "FILE.svg|FILE.png")]
    plot: Option<PathBuf>,
    #[command(flatten)]
    mesh: MeshArgs,
    #[command(flatten)]
    cache: CacheArgs,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
}

/// `fea` subcommands.
#[derive(Debug, Subcommand)]
pub enum FeaCommand {
    /// Natural frequencies and mode shapes of the assembled manipulator.
    #[command(
        after_help = "Examples:\n  cellinject fea modes\n  cellinject fea modes --approach 1 --count 3 --format json"
    )]
    Modes {
        /// Pre-tensioning approach (default: the description's `twin.approach`).
        #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
        approach: Option<u8>,
        /// How many modes to list (1 to 16: the model has 16 coordinates).
        #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u64).range(1..=16))]
        count: u64,
        #[command(flatten)]
        mesh: MeshArgs,
        #[command(flatten)]
        cache: CacheArgs,
        /// Output format.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// The paper's Tables 1 and 2 recomputed, with the cross-axis coupling and the
    /// joints' stresses against the yield strength.
    #[command(
        after_help = "Examples:\n  cellinject fea tables\n  cellinject fea tables --level 2 --preload torque"
    )]
    Tables {
        #[command(flatten)]
        mesh: MeshArgs,
        #[command(flatten)]
        cache: CacheArgs,
        /// Output format.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
    /// The double-notched joints' stiffness from the 3-D FEM against the paper's.
    #[command(
        after_help = "Examples:\n  cellinject fea joints --levels 1\n  cellinject fea joints --levels 1,2 --format json"
    )]
    Joints {
        /// Mesh levels to solve (convergence).
        #[arg(long, value_delimiter = ',', default_values_t = [1u8, 2])]
        levels: Vec<u8>,
        #[command(flatten)]
        cache: CacheArgs,
        /// Output format.
        #[arg(long, value_enum, default_value_t = Format::Text)]
        format: Format,
    },
}

fn parse_forces(s: &str) -> Result<[f64; 2], String> {
    crate::commands::parse_pair(s, "F11,F12 in newtons")
}

/// How approach 2's pre-tension of J3 enters the structural model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PreloadArg {
    /// J3 assembled pre-deflected, by the approach's design rule (the stacks carry F10
    /// with the drives at their home length) applied to this model's stiffness.
    Deflection,
    /// The paper's CAD set-up (Sec. 3.3.2): J3 straight and the torques of eq. (53) on
    /// body 1. The net moment on body 1 is then a 0.1 % difference of 3 N·m terms, so
    /// the offset of the first case is ill-conditioned.
    Torque,
}

impl From<PreloadArg> for PreloadKind {
    fn from(p: PreloadArg) -> Self {
        match p {
            PreloadArg::Deflection => PreloadKind::Deflection,
            PreloadArg::Torque => PreloadKind::Torque,
        }
    }
}

/// The user's input errors exit with code 2, named by the argument or key at fault.
fn fea_error(e: FeaError) -> anyhow::Error {
    match e {
        FeaError::PullingForce { .. } | FeaError::PushCapacity { .. } => {
            InputError(format!("--forces: {e}")).into()
        }
        FeaError::NonFinite { ref key, .. } if key.starts_with("F1") => {
            InputError(format!("--forces: {e}")).into()
        }
        FeaError::Level { .. } => InputError(format!("--level: {e}")).into(),
        FeaError::Levels { .. } => {
            InputError("--levels: give levels between 1 and 3, e.g. 1,2".into()).into()
        }
        e if e.is_input() => InputError(e.to_string()).into(),
        e => anyhow::Error::new(e),
    }
}

/// The joint cache: the platform's directory, unless `--no-cache` or there is none.
fn joint_store(c: &CacheArgs) -> Box<dyn JointStore + Send + Sync> {
    cellinject_fea::default_store(!c.no_cache)
}

/// The structural model of a description on its FEM joints.
fn model(d: &Description, mesh: &MeshArgs, cache: &CacheArgs) -> Result<FeaModel> {
    check_cost(d, &[mesh.level as usize], cache)?;
    let options = FeaOptions {
        level: mesh.level as usize,
        preload: mesh.preload.into(),
    };
    let _p = crate::progress::spinner(format!(
        "joints J1/J2 and J3: 3-D FEM at level {} (or the cache)",
        options.level
    ));
    FeaModel::build(
        &d.design,
        &d.structure,
        options,
        joint_store(cache).as_ref(),
    )
    .map_err(fea_error)
}

/// The consistency warnings between `[flexures]` and `[structure]`: only meaningful
/// when the description sets `[structure]` itself (else its joints are the prototype's).
fn warnings(d: &Description, all: Vec<String>) -> Vec<String> {
    if d.structure_given { all } else { Vec::new() }
}

fn approach_arg(n: Option<u8>, d: &Description) -> Approach {
    n.and_then(Approach::from_number).unwrap_or(d.rig.approach)
}

/// Runs `fea`.
pub fn run(d: &Description, a: &FeaArgs) -> Result<()> {
    match &a.command {
        Some(FeaCommand::Modes {
            approach,
            count,
            mesh,
            cache,
            format,
        }) => modes(
            d,
            approach_arg(*approach, d),
            *count as usize,
            mesh,
            cache,
            *format,
        ),
        Some(FeaCommand::Tables {
            mesh,
            cache,
            format,
        }) => tables(d, mesh, cache, *format),
        Some(FeaCommand::Joints {
            levels,
            cache,
            format,
        }) => joints(d, levels, cache, *format),
        None => solve_case(d, &a.solve),
    }
}

fn solve_case(d: &Description, a: &SolveArgs) -> Result<()> {
    let approach = a
        .approach
        .and_then(Approach::from_number)
        .ok_or_else(|| InputError("fea: --approach 1|2 is required".into()))?;
    let forces = a.forces.ok_or_else(|| {
        InputError("fea: --forces F11,F12 is required (N, e.g. -100,-100)".into())
    })?;
    // Refused before the joints are solved.
    cellinject_fea::check_forces(&d.design, forces).map_err(fea_error)?;
    // The plot's file is checked before the joints are solved.
    if let Some(path) = &a.plot {
        let mut plan = Plan::new();
        plan.output("--plot", path, &[Kind::Svg, Kind::Png])?;
        plan.check()?;
    }
    let m = model(d, &a.mesh, &a.cache)?;
    let case = m.solve_case(approach, forces).map_err(fea_error)?;
    if let Some(path) = &a.plot {
        plot(&m.skeleton(&case.equilibrium, 24), approach, path)?;
    }
    let mut r = case.report;
    r.warnings = warnings(d, r.warnings);
    match a.format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&r)?),
        Format::Text => out!("{}", print::case_text(&r, a.plot.as_deref())),
    }
    Ok(())
}

fn plot(members: &[Member], approach: Approach, path: &std::path::Path) -> Result<()> {
    let panels = print::structure_panels(members, approach);
    let size = (680, 600);
    let bytes = if Kind::of(path) == Some(Kind::Png) {
        encode_rgb(structure_rgb(&panels, size)?, path)?
    } else {
        structure_svg(&panels, size)?.into_bytes()
    };
    write_one(path, &bytes)?;
    Ok(())
}

fn modes(
    d: &Description,
    approach: Approach,
    count: usize,
    mesh: &MeshArgs,
    cache: &CacheArgs,
    format: Format,
) -> Result<()> {
    let m = model(d, mesh, cache)?;
    let mut r = m.modes(approach, count).map_err(fea_error)?;
    r.warnings = warnings(d, r.warnings);
    match format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&r)?),
        Format::Text => out!("{}", print::modes_text(&r)),
    }
    Ok(())
}

fn tables(d: &Description, mesh: &MeshArgs, cache: &CacheArgs, format: Format) -> Result<()> {
    let m = model(d, mesh, cache)?;
    let mut r = m.tables().map_err(fea_error)?;
    r.warnings = warnings(d, r.warnings);
    match format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&r)?),
        Format::Text => out!("{}", print::tables_text(&r)),
    }
    Ok(())
}

fn joints(d: &Description, levels: &[u8], cache: &CacheArgs, format: Format) -> Result<()> {
    let levels: Vec<usize> = levels.iter().map(|&l| l as usize).collect();
    if levels.iter().any(|l| !cellinject_fea::LEVELS.contains(l)) {
        return Err(InputError(format!(
            "--levels: give levels between 1 and 3, e.g. 1,2 (got {levels:?})"
        ))
        .into());
    }
    check_cost(d, &levels, cache)?;
    let r = {
        let _p = crate::progress::spinner(format!(
            "joints J1/J2 and J3: 3-D FEM at levels {levels:?} (or the cache)"
        ));
        cellinject_fea::joints(&d.structure, &levels, joint_store(cache).as_ref())
            .map_err(fea_error)?
    };
    match format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&r)?),
        Format::Text => out!("{}", print::joints_text(&r)),
    }
    Ok(())
}
