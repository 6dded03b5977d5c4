//! `cellinject sim ...`: programs of `cellinject-core` run on the digital twin through
//! its guarded rig, measured by the twin's own truth; this file writes what they did.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use cellinject_config::Description;
use cellinject_core::sim::{self as core, Acquisition, FrameSummary, SimError, StepSample};
use cellinject_hw::{Frame, HwError};
use cellinject_model::Approach;
use cellinject_print::hysteresis as print;
use cellinject_rig::Rig;
use cellinject_twin::devices::displacement_in;
use cellinject_twin::{SharedTwin, Twin, TwinBackend};
use clap::{Args, Subcommand};

use crate::output::print_json;
use crate::{Format, InputError};
use cellinject_files::{Kind, Plan, Staged, encode_image, encode_rgb, write_with_plots, wrote};

/// Options shared by every `sim` command.
#[derive(Debug, Args)]
pub struct TwinArgs {
    /// Pre-tensioning approach the twin is assembled with (default: the description's `twin.approach`).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
    approach: Option<u8>,
    /// Seed of the twin's random processes (default: the description's `twin.seed`).
    #[arg(long)]
    seed: Option<u64>,
    /// Output format of the summary on standard output (the files are the same).
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
}

impl TwinArgs {
    /// The description's approach, this seed, text output.
    pub(crate) fn with_seed(seed: u64) -> Self {
        TwinArgs {
            approach: None,
            seed: Some(seed),
            format: Format::Text,
        }
    }

    /// This approach and seed (each `None`: the description's), text output.
    pub(crate) fn new(approach: Option<u8>, seed: Option<u64>) -> Self {
        TwinArgs {
            approach,
            seed,
            format: Format::Text,
        }
    }

    /// The seed `--seed` gave.
    pub(crate) fn seed_value(&self) -> Option<u64> {
        self.seed
    }

    /// The approach `--approach` asked for.
    pub(crate) fn approach_given(&self) -> Option<Approach> {
        self.approach.and_then(Approach::from_number)
    }

    /// The output format asked for.
    pub(crate) fn format(&self) -> Format {
        self.format
    }
}

/// The `sim` commands.
#[derive(Debug, Subcommand)]
pub enum SimCommand {
    /// Drive one stack through a full hysteresis loop and nested minor loops.
    #[command(
        after_help = "Examples:\n  cellinject sim loop --actuator A2\n  cellinject sim loop --actuator A1 --amplitude 60 --approach 1 --out a1-loop.csv"
    )]
    Loop {
        /// Actuator: A1, A2 or A3.
        #[arg(long, default_value = "A1")]
        actuator: String,
        /// Largest voltage of the loop, V (default: the amplifier's full range).
        #[arg(long, allow_negative_numbers = true)]
        amplitude: Option<f64>,
        /// CSV output (`time_s,voltage_v,displacement_m`); the plot is written beside it
        /// with the same stem as SVG and PNG (`--out loop.svg` means the same three files).
        #[arg(long, default_value = "loop.csv")]
        out: PathBuf,
        #[command(flatten)]
        twin: TwinArgs,
    },
    /// Render one camera frame of the prototype's scene.
    #[command(
        after_help = "Examples:\n  cellinject sim frame --vga --out frame.png\n  cellinject sim frame --zoom 5 --bits 16 --volts 20,10,0 --out frame.tif"
    )]
    Frame {
        /// Magnification (2.5 to 10).
        #[arg(long, default_value_t = 10.0, allow_negative_numbers = true)]
        zoom: f64,
        /// 640x480 by 4x4 binning of the sensor centre (30 fps).
        #[arg(long, conflicts_with = "crop")]
        vga: bool,
        /// 640x480 by cropping the sensor centre at full resolution (30 fps).
        #[arg(long)]
        crop: bool,
        /// PNG bit depth: 8, or 16 (the camera's 12-bit output scaled by 16).
        #[arg(long, default_value_t = 8, value_parser = parse_bits)]
        bits: u8,
        /// Burn a scale bar into the image (an 8-bit colour figure, not data for DIC).
        #[arg(long, conflicts_with = "bits")]
        scale_bar: bool,
        /// Voltages of A1, A2, A3 applied before the frame, V.
        #[arg(long, value_delimiter = ',', value_name = "V1,V2,V3")]
        volts: Option<Vec<f64>>,
        /// Image output: `.png`, or `.tif` for TIFF.
        #[arg(long, default_value = "frame.png")]
        out: PathBuf,
        /// A plate file (`cellinject plate generate`): its cells and debris under the
        /// microscope instead of the feeder the twin generates from its seed.
        #[arg(long, value_name = "FILE")]
        plate: Option<PathBuf>,
        #[command(flatten)]
        twin: TwinArgs,
    },
    /// The pipette's tip found in the image (never from the commanded position) against
    /// the twin's truth; A1 and A3 at random voltages between frames, A2 at 0 V (in focus).
    #[command(
        after_help = "Examples:\n  cellinject sim tip\n  cellinject sim tip --zoom 5 --runs 50 --format json"
    )]
    Tip {
        /// Magnification (2.5 to 10); full frames.
        #[arg(long, default_value_t = 10.0, allow_negative_numbers = true)]
        zoom: f64,
        /// Frames.
        #[arg(long, default_value_t = 20)]
        runs: usize,
        #[command(flatten)]
        twin: TwinArgs,
    },
    /// Step response of one stack: ringing of the structure, then creep.
    #[command(
        after_help = "Examples:\n  cellinject sim step --voltage 50\n  cellinject sim step --actuator A3 --voltage 30 --duration 0.5 --out a3-step.csv --format json"
    )]
    Step {
        /// Actuator: A1, A2 or A3.
        #[arg(long, default_value = "A1")]
        actuator: String,
        /// Step voltage, V.
        #[arg(long, allow_negative_numbers = true)]
        voltage: f64,
        /// Simulated duration, s (up to 3600; sampled every step for 50 ms, then every
        /// millisecond, or every duration/100000 s for runs over 100 s).
        #[arg(long, default_value_t = 2.0, allow_negative_numbers = true)]
        duration: f64,
        /// CSV output; the plot is written beside it with the same stem as SVG and PNG.
        #[arg(long, default_value = "step.csv")]
        out: PathBuf,
        #[command(flatten)]
        twin: TwinArgs,
    },
}

fn parse_bits(s: &str) -> Result<u8, String> {
    match s {
        "8" => Ok(8),
        "16" => Ok(16),
        _ => Err(format!("must be 8 or 16, got `{s}`")),
    }
}

fn channel(name: &str) -> Result<usize> {
    core::channel(name)
        .ok_or_else(|| InputError(format!("--actuator must be A1, A2 or A3, got `{name}`")).into())
}

/// Builds the twin of the description and its guarded rig.
pub(crate) fn build(d: &Description, args: &TwinArgs) -> Result<(SharedTwin, Rig<TwinBackend>)> {
    let twin = twin(d, args)?;
    let rig = cellinject_twin::rig(&twin)
        .map_err(|e| InputError(format!("cannot build the twin: {e}")))?;
    Ok((twin, rig))
}

/// Builds the twin of the description (its J3 yield check from the FEA cache).
pub(crate) fn twin(d: &Description, args: &TwinArgs) -> Result<SharedTwin> {
    let _p =
        crate::progress::spinner("J3's stresses for the safety envelope (joint FEM or its cache)");
    let opts = cellinject_session::TwinOptions {
        approach: args.approach_given(),
        seed: args.seed,
    };
    cellinject_session::twin(d, opts).map_err(crate::backend::session_error)
}

/// Every refusal and every bad argument of a program is the user's to fix: exit code 2.
fn sim_error(e: SimError) -> anyhow::Error {
    InputError(e.to_string()).into()
}

fn lock(twin: &SharedTwin) -> std::sync::MutexGuard<'_, Twin> {
    twin.lock().unwrap_or_else(|e| e.into_inner())
}

/// The CSV and the plot (SVG and PNG) of a loop or step, checked before the twin runs.
fn csv_and_plots(out: &Path) -> Result<Vec<PathBuf>> {
    let mut plan = Plan::new();
    let files = plan.companions("--out", out, &[Kind::Csv, Kind::Svg, Kind::Png])?;
    plan.check()?;
    Ok(files)
}

/// `sim loop`.
fn run_loop(
    d: &Description,
    actuator: &str,
    amplitude: Option<f64>,
    out: &Path,
    args: &TwinArgs,
) -> Result<()> {
    let ch = channel(actuator)?;
    let files = csv_and_plots(out)?;
    let (twin, mut rig) = build(d, args)?;
    let approach = lock(&twin).world.params().rig.approach;
    let progress = crate::progress::spinner("the twin traces the loop");
    let r = core::hysteresis_loop(&mut rig, ch, amplitude, approach, || {
        lock(&twin).actuator_displacement(ch)
    })
    .map_err(sim_error)?;
    drop(progress);
    let csv = print::voltage_displacement_csv(&r.samples);
    let chart = print::loop_chart(&r);
    write_with_plots(&files, csv.as_bytes(), &[chart], 1)?;
    if args.format == Format::Json {
        return print_json(r.summary(), &[&files[0], &files[1], &files[2]]);
    }
    outln!(
        "{}: loop 0-{:.1} V, stroke {:.3} µm under load; {} samples",
        r.actuator,
        r.amplitude,
        r.stroke * 1e6,
        r.samples.len()
    );
    outln!("{}", wrote(&files));
    Ok(())
}

/// `sim step`.
fn run_step(
    d: &Description,
    actuator: &str,
    voltage: f64,
    duration: f64,
    out: &Path,
    args: &TwinArgs,
) -> Result<()> {
    let ch = channel(actuator)?;
    let files = csv_and_plots(out)?;
    let (twin, mut rig) = build(d, args)?;
    let (start, x0, dt) = {
        let t = lock(&twin);
        (
            t.actuator_displacement(ch),
            t.world.snapshot().x,
            t.world.dt(),
        )
    };
    let progress = crate::progress::spinner(format!("the twin simulates {duration} s"));
    let r = core::step_response(&mut rig, ch, voltage, duration, dt, |t| {
        let s = lock(&twin).world.snapshot();
        let ee = s.x - x0;
        StepSample {
            time: t,
            voltage: s.voltage[ch],
            displacement: displacement_in(&s, ch) - start,
            end_effector: [ee[0], ee[1], ee[2]],
        }
    })
    .map_err(sim_error)?;
    drop(progress);
    let csv = print::step_csv(&r);
    let charts = print::step_charts(&r, voltage, duration);
    write_with_plots(&files, csv.as_bytes(), &charts, charts.len())?;
    let f = lock(&twin).world.natural_frequencies();
    if args.format == Format::Json {
        return print_json(
            r.summary([f[0], f[1], f[2]]),
            &[&files[0], &files[1], &files[2]],
        );
    }
    outln!(
        "{}",
        print::step_text(&r, voltage, duration, [f[0], f[1], f[2]])
    );
    outln!("{}", wrote(&files));
    Ok(())
}

/// A frame as an 8- or 16-bit greyscale image in the format `path`'s extension names.
pub fn encode_frame(frame: &Frame, bits: u8, path: &Path) -> Result<Vec<u8>> {
    if bits == 16 {
        let shift = 16 - frame.bit_depth as u32;
        let data: Vec<u16> = frame.pixels.iter().map(|&v| v << shift).collect();
        let img =
            image::ImageBuffer::<image::Luma<u16>, _>::from_raw(frame.width, frame.height, data)
                .context("frame buffer size")?;
        Ok(encode_image(&img, path)?)
    } else {
        let down = frame.bit_depth as u32 - 8;
        let data: Vec<u8> = frame.pixels.iter().map(|&v| (v >> down) as u8).collect();
        let img = image::GrayImage::from_raw(frame.width, frame.height, data)
            .context("frame buffer size")?;
        Ok(encode_image(&img, path)?)
    }
}

/// How `sim frame` acquires and writes.
struct FrameArgs<'a> {
    zoom: f64,
    vga: bool,
    crop: bool,
    bits: u8,
    scale_bar: bool,
    plate: Option<&'a Path>,
}

/// `sim frame`.
fn run_frame(
    d: &Description,
    f: FrameArgs<'_>,
    volts: Option<&[f64]>,
    out: &Path,
    args: &TwinArgs,
) -> Result<()> {
    let FrameArgs {
        zoom,
        vga,
        crop,
        bits,
        scale_bar,
        plate,
    } = f;
    let volts = match volts {
        None => None,
        Some(&[a, b, c]) => Some([a, b, c]),
        Some(v) => {
            return Err(InputError(format!(
                "--volts takes three voltages V1,V2,V3, got {}",
                v.len()
            ))
            .into());
        }
    };
    let acquisition = match (vga, crop) {
        (true, _) => Acquisition::VgaBinned,
        (false, true) => Acquisition::VgaCropped,
        (false, false) => Acquisition::Full,
    };
    let mut plan = Plan::new();
    if let Some(p) = plate {
        plan.input("--plate", p);
    }
    plan.output("--out", out, &[Kind::Png, Kind::Tiff])?;
    plan.check()?;
    let plate = plate
        .map(|p| crate::plate::load("--plate", p))
        .transpose()?;
    let (twin, mut rig) = build(d, args)?;
    if let Some(p) = &plate {
        twin.lock().unwrap_or_else(|e| e.into_inner()).load_plate(p);
    }
    let frame = core::frame(&mut rig, zoom, acquisition, volts).map_err(|e| match e {
        SimError::Device {
            what,
            source: HwError::Refused(r),
        } => InputError(format!("{what}: refused: {r}")).into(),
        other => sim_error(other),
    })?;
    let bytes = if scale_bar {
        let down = frame.bit_depth as u32 - 8;
        let grey: Vec<u8> = frame.pixels.iter().map(|&v| (v >> down) as u8).collect();
        let rgb = cellinject_plot::frame::with_scale_bar(
            &grey,
            frame.width,
            frame.height,
            frame.pixel_size,
        )
        .context("scale bar")?;
        encode_rgb(rgb, out)?
    } else {
        encode_frame(&frame, bits, out)?
    };
    let mut staged = Staged::new();
    staged.add(out, &bytes)?;
    staged.commit()?;
    let tip = lock(&twin).tip();
    if args.format == Format::Json {
        let s = FrameSummary::new(&frame, zoom, Some([tip.x, tip.z, tip.depth]));
        return print_json(s, &[out]);
    }
    outln!(
        "frame {}x{} at {zoom}x: {:.3} µm per pixel, field of view {:.0} x {:.0} µm; exposure {:.1} ms at t = {:.3} s",
        frame.width,
        frame.height,
        frame.pixel_size * 1e6,
        frame.width as f64 * frame.pixel_size * 1e6,
        frame.height as f64 * frame.pixel_size * 1e6,
        frame.exposure * 1e3,
        frame.timestamp
    );
    outln!(
        "pipette tip at x = {:.3} µm, z = {:.3} µm, {:.3} µm from focus",
        tip.x * 1e6,
        tip.z * 1e6,
        tip.depth * 1e6
    );
    outln!("wrote {} ({bits}-bit)", out.display());
    Ok(())
}

/// Runs a `sim` command.
pub fn run(d: &Description, cmd: &SimCommand) -> Result<()> {
    match cmd {
        SimCommand::Loop {
            actuator,
            amplitude,
            out,
            twin,
        } => run_loop(d, actuator, *amplitude, out, twin),
        SimCommand::Tip { zoom, runs, twin } => run_tip(d, *zoom, *runs, twin),
        SimCommand::Step {
            actuator,
            voltage,
            duration,
            out,
            twin,
        } => run_step(d, actuator, *voltage, *duration, out, twin),
        SimCommand::Frame {
            zoom,
            vga,
            crop,
            bits,
            scale_bar,
            volts,
            out,
            plate,
            twin,
        } => run_frame(
            d,
            FrameArgs {
                zoom: *zoom,
                vga: *vga,
                crop: *crop,
                bits: *bits,
                scale_bar: *scale_bar,
                plate: plate.as_deref(),
            },
            volts.as_deref(),
            out,
            twin,
        ),
    }
}

/// `sim tip`.
fn run_tip(d: &Description, zoom: f64, runs: usize, args: &TwinArgs) -> Result<()> {
    let (twin, mut rig) = build(d, args)?;
    let seed = args.seed.unwrap_or(d.sim.seed);
    let mut truth = || {
        let t = twin.lock().unwrap_or_else(|e| e.into_inner());
        let (pose, g) = (t.tip(), t.camera.grid());
        [(pose.x - g.x0) / g.pitch, (pose.z - g.z0) / g.pitch]
    };
    let r = {
        let _p = crate::progress::spinner(format!("finding the tip in {runs} frames"));
        cellinject_core::cells::tip_trials(&mut rig, &d.rig.pipette, zoom, runs, seed, &mut truth)
            .map_err(|e| match e {
            SimError::Device {
                what,
                source: HwError::Refused(r),
            } => InputError(format!("{what}: refused: {r}")).into(),
            SimError::Device {
                what: "--zoom",
                source,
            } => InputError(format!("--zoom: {source}")).into(),
            SimError::Invalid { .. } => InputError(e.to_string()).into(),
            other => sim_error(other),
        })?
    };
    if args.format() == Format::Json {
        return print_json(&r, &[]);
    }
    outln!(
        "tip found in {} of {} frames at {zoom}x ({:.3} µm per pixel), against the twin's truth:",
        r.runs - r.not_found,
        r.runs,
        r.pixel_size_m * 1e6
    );
    outln!(
        "  error median {:.3} µm, 95th percentile {:.3} µm, largest {:.3} µm (median along the axis {:.3} µm, across {:.3} µm)",
        r.error_m[0] * 1e6,
        r.error_m[1] * 1e6,
        r.error_m[2] * 1e6,
        r.along_across_m[0] * 1e6,
        r.along_across_m[1] * 1e6
    );
    Ok(())
}
