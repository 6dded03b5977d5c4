//! `cellinject design`: design studies of the manipulator (the front end of
//! [`cellinject_design`]): one design's figures, batches in shards, merging shards, and
//! the multi-objective search with its front, files and plot.

use std::path::{Path, PathBuf};

use anyhow::Result;
use cellinject_design::batch::{self, Shard};
use cellinject_design::study::{FrontEntry, Record, Settings, Study};
use cellinject_design::{DesignError, EvalOptions, Fidelity, Figures, Space, evaluate};
use cellinject_fea::JointStore;
use cellinject_model::Approach;
use clap::{Args, Subcommand, ValueEnum};

use crate::{Format, InputError};
use cellinject_files::{Kind, Plan, Staged, encode_rgb};
use cellinject_print::design as print;

/// `design` subcommands.
#[derive(Debug, Subcommand)]
pub enum DesignCommand {
    /// One design's figures: working range, end-effector stiffness, first modes, every
    /// margin of the safety envelope, cross-axis coupling, feasibility. With --batch,
    /// one slice of a batch of designs.
    #[command(
        after_help = "Examples:\n  cellinject design evaluate\n  cellinject design evaluate --fidelity fea --format json\n  cellinject design evaluate --config mine.toml --approach 1\n  cellinject design evaluate --batch designs.jsonl --out r0.jsonl --shard 0/4\n\nAn infeasible design is a result (exit 0, feasible: false)."
    )]
    Evaluate(EvaluateArgs),
    /// Joins the result slices of `design evaluate --batch --shard`, refusing a missing
    /// or doubled design.
    #[command(
        after_help = "Examples:\n  cellinject design merge --out all.jsonl r0.jsonl r1.jsonl r2.jsonl r3.jsonl\n  cellinject design merge --count 1000 --out all.jsonl results-*.jsonl"
    )]
    Merge {
        /// The joined results (JSON lines).
        #[arg(long, value_name = "FILE.jsonl")]
        out: PathBuf,
        /// The batch's number of designs, to check that no trailing slice is missing.
        #[arg(long, value_name = "M")]
        count: Option<usize>,
        /// The slices, in any order.
        #[arg(required = true, value_name = "RESULTS.jsonl")]
        slices: Vec<PathBuf>,
    },
    /// Multi-objective search (NSGA-II) over the description keys a space file names;
    /// writes the front as CSV and JSON, each front design's description, and a plot of
    /// the front with the base design on it. Resumes from its output directory.
    #[command(
        after_help = "Examples:\n  cellinject design optimise --space configs/design-space.toml\n  cellinject design optimise --space s.toml --population 60 --generations 40 --seed 3 --out study\n  cellinject design optimise --space s.toml --fidelity fea   (screen with the beam formulas, then the front by the FEA)\n\nExit codes: 0 a front was found; 1 no design of the space meets the constraints; 2 bad input."
    )]
    Optimise(OptimiseArgs),
}

/// The joint model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum FidelityArg {
    /// Closed-form notch formulas (about a millisecond per design).
    Beam,
    /// The joints' 3-D FEM (about a second per new joint geometry at level 1).
    Fea,
}

impl From<FidelityArg> for Fidelity {
    fn from(f: FidelityArg) -> Fidelity {
        match f {
            FidelityArg::Beam => Fidelity::Beam,
            FidelityArg::Fea => Fidelity::Fea,
        }
    }
}

/// `design evaluate`.
#[derive(Debug, Args)]
pub struct EvaluateArgs {
    /// Pre-tensioning approach (default: the description's `twin.approach`).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
    approach: Option<u8>,
    /// Joint model.
    #[arg(long, value_enum, default_value_t = FidelityArg::Beam)]
    fidelity: FidelityArg,
    /// The joints' FEM mesh level at --fidelity fea.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=2))]
    level: u8,
    /// A batch of designs: one {"variables": {key: value}} per line, each overriding
    /// keys of the description.
    #[arg(long, value_name = "FILE.jsonl", requires = "out")]
    batch: Option<PathBuf>,
    /// Where --batch writes its results (one JSON line per design).
    #[arg(long, value_name = "FILE.jsonl", requires = "batch")]
    out: Option<PathBuf>,
    /// Evaluate only the slice I of N of the batch (I from 0 to N-1), e.g. a Slurm
    /// array's `$SLURM_ARRAY_TASK_ID/$N`.
    #[arg(long, value_name = "I/N", requires = "batch")]
    shard: Option<String>,
    /// Solve the joints' FEM without the joint cache.
    #[arg(long)]
    no_cache: bool,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
}

/// `design optimise`.
#[derive(Debug, Args)]
pub struct OptimiseArgs {
    /// The space file: [variables] (description keys and bounds), [objectives]
    /// (maximise/minimise lists of figures), [constraints] (lower bounds on figures).
    #[arg(long, value_name = "FILE.toml")]
    space: PathBuf,
    /// Pre-tensioning approach (default: the description's `twin.approach`).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
    approach: Option<u8>,
    /// Designs per generation (rounded up to an even number, at least 4).
    #[arg(long, default_value_t = 40, value_parser = clap::value_parser!(u64).range(4..=100000))]
    population: u64,
    /// Generations.
    #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u64).range(1..=100000))]
    generations: u64,
    /// Seed of the search: one seed, one front.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Fidelity of the front: beam, or fea (the search screens with the beam formulas
    /// and the front is evaluated again with the joints' FEM).
    #[arg(long, value_enum, default_value_t = FidelityArg::Beam)]
    fidelity: FidelityArg,
    /// The joints' FEM mesh level at --fidelity fea.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=2))]
    level: u8,
    /// Output directory (created; a directory holding a study of the same space,
    /// description and settings is resumed).
    #[arg(long, value_name = "DIR", default_value = "design-study")]
    out: PathBuf,
    /// Solve the joints' FEM without the joint cache.
    #[arg(long)]
    no_cache: bool,
    /// Output format of the summary.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
}

/// The description's text: the file of --config, else the embedded prototype.
fn base_text(config: Option<&Path>) -> Result<String> {
    let Some(path) = config else {
        return Ok(cellinject_config::PROTOTYPE_TOML.to_string());
    };
    let text = std::fs::read_to_string(path).map_err(|e| {
        InputError(format!(
            "cannot read description file `{}`: {e}",
            path.display()
        ))
    })?;
    cellinject_config::parse(&text)
        .map_err(|e| InputError(format!("description file `{}`: {e}", path.display())))?;
    Ok(text)
}

fn design_error(e: DesignError) -> anyhow::Error {
    if e.is_input() {
        InputError(e.to_string()).into()
    } else {
        anyhow::anyhow!("{e}")
    }
}

fn store(no_cache: bool) -> Box<dyn JointStore + Send + Sync> {
    cellinject_fea::default_store(!no_cache)
}

/// `cellinject design`.
pub fn run(config: Option<&Path>, cmd: &DesignCommand) -> Result<()> {
    match cmd {
        DesignCommand::Evaluate(a) => evaluate_cmd(config, a),
        DesignCommand::Merge { out, count, slices } => merge(out, *count, slices),
        DesignCommand::Optimise(a) => optimise(config, a),
    }
}

fn options(approach: Option<u8>, fidelity: FidelityArg, level: u8) -> EvalOptions {
    EvalOptions {
        approach: approach.and_then(Approach::from_number),
        fidelity: fidelity.into(),
        level: level as usize,
    }
}

fn evaluate_cmd(config: Option<&Path>, a: &EvaluateArgs) -> Result<()> {
    let base = base_text(config)?;
    let opts = options(a.approach, a.fidelity, a.level);
    let store = store(a.no_cache);
    if let (Some(batch), Some(out)) = (&a.batch, &a.out) {
        return evaluate_batch(
            &base,
            &opts,
            store.as_ref(),
            batch,
            out,
            a.shard.as_deref(),
            config,
        );
    }
    let desc = cellinject_config::parse(&base).map_err(|e| InputError(e.to_string()))?;
    let _p = (opts.fidelity == Fidelity::Fea).then(|| {
        crate::progress::spinner("the joints' FEM (or the joint cache) and the structure")
    });
    let f = evaluate(&desc, &opts, store.as_ref()).map_err(design_error)?;
    drop(_p);
    match a.format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&f)?),
        Format::Text => outln!("{}", print::figures_text(&desc.name, &f)),
    }
    Ok(())
}

fn evaluate_batch(
    base: &str,
    opts: &EvalOptions,
    store: &dyn JointStore,
    batch_path: &Path,
    out: &Path,
    shard: Option<&str>,
    config: Option<&Path>,
) -> Result<()> {
    let mut plan = Plan::new();
    plan.input("--batch", batch_path);
    if let Some(c) = config {
        plan.input("--config", c);
    }
    plan.output("--out", out, &[Kind::Jsonl])?;
    plan.check()?;
    let shard = match shard {
        Some(s) => Shard::parse(s).map_err(design_error)?,
        None => Shard { index: 0, count: 1 },
    };
    let text = std::fs::read_to_string(batch_path).map_err(|e| {
        InputError(format!(
            "cannot read --batch `{}`: {e}",
            batch_path.display()
        ))
    })?;
    let name = batch_path.display().to_string();
    let lines = batch::parse(&name, &text).map_err(design_error)?;
    // Every line's keys are checked before anything is computed.
    let descs = batch::descriptions(base, &name, &lines).map_err(design_error)?;
    let range = shard.range(lines.len());
    let bar = crate::progress::rate_bar(range.len() as u64, "designs");
    let (results, failed) =
        batch::evaluate_lines(&lines, &descs, range.clone(), opts, store, &|| bar.inc());
    let mut body = String::new();
    for line in &results {
        body.push_str(&serde_json::to_string(line)?);
        body.push('\n');
    }
    drop(bar);
    cellinject_files::write_one(out, body.as_bytes())?;
    eprintln!(
        "evaluated designs {}..{} of {} ({}failed: {failed}); wrote {}",
        range.start,
        range.end,
        lines.len(),
        if shard.count > 1 {
            format!("shard {}/{}; ", shard.index, shard.count)
        } else {
            String::new()
        },
        out.display()
    );
    Ok(())
}

fn merge(out: &Path, count: Option<usize>, slices: &[PathBuf]) -> Result<()> {
    let mut plan = Plan::new();
    for s in slices {
        plan.input("a slice", s);
    }
    plan.output("--out", out, &[Kind::Jsonl])?;
    plan.check()?;
    let mut files = Vec::new();
    for s in slices {
        let text = std::fs::read_to_string(s)
            .map_err(|e| InputError(format!("cannot read slice `{}`: {e}", s.display())))?;
        files.push((s.display().to_string(), text));
    }
    let merged = batch::merge(&files, count).map_err(design_error)?;
    cellinject_files::write_one(out, merged.as_bytes())?;
    eprintln!(
        "merged {} designs from {} slices into {}",
        merged.lines().count(),
        slices.len(),
        out.display()
    );
    Ok(())
}

/// The study's files in its directory.
struct StudyFiles {
    state: PathBuf,
    front_json: PathBuf,
    front_csv: PathBuf,
    front_svg: PathBuf,
    front_png: PathBuf,
    designs: PathBuf,
}

impl StudyFiles {
    fn new(dir: &Path) -> Self {
        StudyFiles {
            state: dir.join("state.json"),
            front_json: dir.join("front.json"),
            front_csv: dir.join("front.csv"),
            front_svg: dir.join("front.svg"),
            front_png: dir.join("front.png"),
            designs: dir.join("designs"),
        }
    }
}

fn optimise(config: Option<&Path>, a: &OptimiseArgs) -> Result<()> {
    let base = base_text(config)?;
    let space_text = std::fs::read_to_string(&a.space)
        .map_err(|e| InputError(format!("cannot read --space `{}`: {e}", a.space.display())))?;
    let space = Space::parse(&space_text, &base)
        .map_err(|e| InputError(format!("--space `{}`: {e}", a.space.display())))?;
    if a.out.exists() && !a.out.is_dir() {
        return Err(InputError(format!(
            "--out `{}` is a file; give a directory",
            a.out.display()
        ))
        .into());
    }
    let files = StudyFiles::new(&a.out);
    let settings = Settings {
        approach: a.approach,
        fidelity: a.fidelity.into(),
        level: a.level as usize,
        population: a.population as usize,
        generations: a.generations as usize,
        seed: a.seed,
    };
    let fresh = Study::new(space, base, &settings).map_err(design_error)?;
    let mut study = match std::fs::read_to_string(&files.state) {
        Ok(text) => {
            let saved: Study = serde_json::from_str(&text).map_err(|e| {
                InputError(format!(
                    "`{}` is not a study's state ({e}); give another --out",
                    files.state.display()
                ))
            })?;
            let same = saved.space == fresh.space
                && saved.base == fresh.base
                && saved.approach == fresh.approach
                && saved.search.seed == fresh.search.seed
                && saved.search.population == fresh.search.population;
            if !same {
                return Err(InputError(format!(
                    "--out `{}` holds a study of another space, description, approach, seed or population: give another --out, or the same settings to resume it",
                    a.out.display()
                ))
                .into());
            }
            let mut s = saved;
            s.generations = fresh.generations;
            s.fidelity = fresh.fidelity;
            s.level = fresh.level;
            eprintln!(
                "resuming the study in `{}` at generation {} of {}",
                a.out.display(),
                s.search.generation,
                s.generations
            );
            s
        }
        Err(_) => fresh,
    };
    std::fs::create_dir_all(&a.out)
        .map_err(|e| InputError(format!("cannot create --out `{}`: {e}", a.out.display())))?;
    let store = store(a.no_cache);
    let left = study.generations.saturating_sub(study.search.generation);
    let bar = crate::progress::rate_bar(
        (left * study.search.population) as u64,
        "designs (beam screening)",
    );
    while !study.done() {
        let points = study.ask();
        let records = evaluate_all(&study.task(false), &points, store.as_ref(), &bar);
        study.tell(&points, records).map_err(design_error)?;
        let mut staged = Staged::new();
        staged.add(&files.state, serde_json::to_string(&study)?.as_bytes())?;
        staged.commit()?;
    }
    drop(bar);
    let screened = study.screened_front();
    let points: Vec<Vec<f64>> = screened.iter().map(|(x, _)| x.clone()).collect();
    let records: Vec<Record> = match study.fidelity {
        Fidelity::Beam => screened.into_iter().map(|(_, r)| r).collect(),
        Fidelity::Fea => {
            let bar = crate::progress::rate_bar(points.len() as u64, "front designs (FEA)");
            evaluate_all(&study.task(true), &points, store.as_ref(), &bar)
        }
    };
    let front = study.front(&points, &records);
    // The base design, evaluated as the front was, to place it on the plot.
    let base_desc = cellinject_config::parse(&study.base).map_err(|e| InputError(e.to_string()))?;
    let base_figures = evaluate(&base_desc, &study.final_options(), store.as_ref()).ok();
    write_front(
        &files,
        &study,
        &front,
        base_figures.as_ref(),
        &base_desc.name,
    )?;
    let summary = serde_json::json!({
        "generations": study.search.generation,
        "evaluations": study.search.evaluations,
        "fidelity": study.fidelity.name(),
        "front_size": front.len(),
        "out": a.out.display().to_string(),
        "base": base_figures,
        "front": front,
    });
    match a.format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&summary)?),
        Format::Text => outln!(
            "{}",
            print::front_text(&study, &front, base_figures.as_ref(), &base_desc.name)
        ),
    }
    eprintln!(
        "wrote {}, {}, {}, {} and {} designs in {}",
        files.front_json.display(),
        files.front_csv.display(),
        files.front_svg.display(),
        files.front_png.display(),
        front.len(),
        files.designs.display()
    );
    if front.is_empty() {
        return Err(anyhow::anyhow!(
            "no design of the space meets the constraints and the safety envelope after {} evaluations: widen the bounds or relax the constraints",
            study.search.evaluations
        ));
    }
    Ok(())
}

/// Evaluates `points` of `task` one after the other, ticking `bar`.
fn evaluate_all(
    task: &cellinject_design::study::Task,
    points: &[Vec<f64>],
    store: &dyn JointStore,
    bar: &crate::progress::Progress,
) -> Vec<Record> {
    points
        .iter()
        .map(|x| {
            let r = task.evaluate(x, store);
            bar.inc();
            r
        })
        .collect()
}

fn write_front(
    files: &StudyFiles,
    study: &Study,
    front: &[FrontEntry],
    base: Option<&Figures>,
    name: &str,
) -> Result<()> {
    let mut staged = Staged::new();
    staged.add(
        &files.front_json,
        serde_json::to_string_pretty(front)?.as_bytes(),
    )?;
    std::fs::create_dir_all(&files.designs)?;
    for (k, e) in front.iter().enumerate() {
        let text = print::front_design(study, k, e, name).map_err(design_error)?;
        staged.add(&files.designs.join(format!("{k:03}.toml")), text.as_bytes())?;
    }
    staged.add(&files.front_csv, print::front_csv(study, front).as_bytes())?;
    if !front.is_empty() {
        let chart = print::front_chart(study, front, base, name);
        let size = (800, 560);
        let svg = cellinject_plot::svg(std::slice::from_ref(&chart), 1, size)
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        let rgb = cellinject_plot::rgb(std::slice::from_ref(&chart), 1, size)
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        staged.add(&files.front_svg, svg.as_bytes())?;
        staged.add(&files.front_png, &encode_rgb(rgb, &files.front_png)?)?;
    }
    staged.commit()?;
    Ok(())
}
