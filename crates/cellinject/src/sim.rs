//! `cellinject sim ...`: programs of `cellinject-core` run on the digital twin through
//! its guarded rig, measured by the twin's own truth; this file writes what they did.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use cellinject_config::Description;
use cellinject_core::sim::{self as core, Acquisition, SimError, StepSample};
use cellinject_hw::{Frame, HwError};
use cellinject_model::Approach;
use cellinject_plot::{Chart, Series};
use cellinject_rig::Rig;
use cellinject_twin::devices::displacement_in;
use cellinject_twin::{SharedTwin, Twin, TwinBackend, TwinParams};
use clap::{Args, Subcommand};

use crate::InputError;
use crate::output::write_atomic;

/// Options shared by every `sim` command.
#[derive(Debug, Args)]
pub struct TwinArgs {
    /// Pre-tensioning approach the twin is assembled with (default: the description's `twin.approach`).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
    approach: Option<u8>,
    /// Seed of the twin's random processes (default: the description's `twin.seed`).
    #[arg(long)]
    seed: Option<u64>,
}

/// The `sim` commands.
#[derive(Debug, Subcommand)]
pub enum SimCommand {
    /// Drive one stack through a full hysteresis loop and nested minor loops.
    Loop {
        /// Actuator: A1, A2 or A3.
        #[arg(long, default_value = "A1")]
        actuator: String,
        /// Largest voltage of the loop, V (default: the amplifier's full range).
        #[arg(long, allow_negative_numbers = true)]
        amplitude: Option<f64>,
        /// CSV output (`time_s,voltage_v,displacement_m`); an SVG plot is written beside it.
        #[arg(long, default_value = "loop.csv")]
        out: PathBuf,
        #[command(flatten)]
        twin: TwinArgs,
    },
    /// Render one camera frame of the prototype's scene.
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
        /// Voltages of A1, A2, A3 applied before the frame, V.
        #[arg(long, value_delimiter = ',', value_name = "V1,V2,V3")]
        volts: Option<Vec<f64>>,
        /// PNG output.
        #[arg(long, default_value = "frame.png")]
        out: PathBuf,
        #[command(flatten)]
        twin: TwinArgs,
    },
    /// Step response of one stack: ringing of the structure, then creep.
    Step {
        /// Actuator: A1, A2 or A3.
        #[arg(long, default_value = "A1")]
        actuator: String,
        /// Step voltage, V.
        #[arg(long, allow_negative_numbers = true)]
        voltage: f64,
        /// Simulated duration, s.
        #[arg(long, default_value_t = 2.0, allow_negative_numbers = true)]
        duration: f64,
        /// CSV output; an SVG plot is written beside it.
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
fn build(d: &Description, args: &TwinArgs) -> Result<(SharedTwin, Rig<TwinBackend>)> {
    let mut p = TwinParams {
        rig: d.rig,
        sim: d.sim,
    };
    if let Some(a) = args.approach {
        p.rig.approach = Approach::from_number(a).unwrap_or(p.rig.approach);
    }
    if let Some(s) = args.seed {
        p.sim.seed = s;
    }
    let twin = Twin::new(&d.design, p)
        .map_err(|e| InputError(format!("cannot build the twin: {e}")))?
        .into_shared();
    let rig = cellinject_twin::rig(&twin)
        .map_err(|e| InputError(format!("cannot build the twin: {e}")))?;
    Ok((twin, rig))
}

/// Every refusal and every bad argument of a program is the user's to fix: exit code 2.
fn sim_error(e: SimError) -> anyhow::Error {
    InputError(e.to_string()).into()
}

fn lock(twin: &SharedTwin) -> std::sync::MutexGuard<'_, Twin> {
    twin.lock().unwrap_or_else(|e| e.into_inner())
}

fn write_plot(csv: &Path, charts: &[Chart], columns: usize) -> Result<PathBuf> {
    let svg = cellinject_plot::svg(charts, columns, (720, 480)).context("plot")?;
    let path = csv.with_extension("svg");
    write_atomic(&path, &svg).map_err(|e| {
        InputError(format!(
            "--out `{}`: cannot write the plot: {e}",
            path.display()
        ))
    })?;
    Ok(path)
}

fn write_csv(path: &Path, text: &str) -> Result<()> {
    write_atomic(path, text)
        .map_err(|e| InputError(format!("--out `{}`: cannot write: {e}", path.display())).into())
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
    let (twin, mut rig) = build(d, args)?;
    let approach = lock(&twin).world.params().rig.approach;
    let r = core::hysteresis_loop(&mut rig, ch, amplitude, approach, || {
        lock(&twin).actuator_displacement(ch)
    })
    .map_err(sim_error)?;
    let mut csv = String::from("time_s,voltage_v,displacement_m\n");
    for s in &r.samples {
        let _ = writeln!(csv, "{:.6},{:.6},{:.6e}", s[0], s[1], s[2]);
    }
    write_csv(out, &csv)?;
    let chart = Chart {
        title: format!("{}: hysteresis loop with nested minor loops", r.actuator),
        x_label: "amplifier output [V]".into(),
        y_label: "actuator displacement [µm]".into(),
        series: vec![Series {
            name: r.actuator.into(),
            points: r.samples.iter().map(|s| (s[1], s[2] * 1e6)).collect(),
        }],
    };
    let plot = write_plot(out, &[chart], 1)?;
    println!(
        "{}: loop 0-{:.1} V, stroke {:.3} µm under load; {} samples",
        r.actuator,
        r.amplitude,
        r.stroke * 1e6,
        r.samples.len()
    );
    println!("wrote {} and {}", out.display(), plot.display());
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
    let (twin, mut rig) = build(d, args)?;
    let (start, x0, dt) = {
        let t = lock(&twin);
        (
            t.actuator_displacement(ch),
            t.world.snapshot().x,
            t.world.dt(),
        )
    };
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
    let mut csv = String::from(
        "time_s,voltage_v,displacement_m,end_effector_x_m,end_effector_y_m,end_effector_z_m\n",
    );
    for s in &r.samples {
        let _ = writeln!(
            csv,
            "{:.6},{:.6},{:.6e},{:.6e},{:.6e},{:.6e}",
            s.time,
            s.voltage,
            s.displacement,
            s.end_effector[0],
            s.end_effector[1],
            s.end_effector[2]
        );
    }
    write_csv(out, &csv)?;
    let name = r.actuator;
    let um = |s: &StepSample| s.displacement * 1e6;
    let charts = [
        Chart {
            title: format!("{name} step to {voltage} V: first 30 ms"),
            x_label: "time [ms]".into(),
            y_label: "actuator displacement [µm]".into(),
            series: vec![Series {
                name: name.into(),
                points: r
                    .samples
                    .iter()
                    .filter(|s| s.time <= 0.03)
                    .map(|s| (s.time * 1e3, um(s)))
                    .collect(),
            }],
        },
        Chart {
            title: format!("{name} step to {voltage} V: creep over {duration} s"),
            x_label: "time [s]".into(),
            y_label: "actuator displacement [µm]".into(),
            series: vec![Series {
                name: name.into(),
                // After the ringing, so that the vertical axis shows the creep.
                points: r
                    .samples
                    .iter()
                    .filter(|s| s.time >= 0.05)
                    .map(|s| (s.time, um(s)))
                    .collect(),
            }],
        },
    ];
    let plot = write_plot(out, &charts, 2)?;
    let f = lock(&twin).world.natural_frequencies();
    let at = |t: f64| r.displacement_at(t).map(|x| x * 1e6).unwrap_or(f64::NAN);
    println!(
        "{name}: step to {voltage} V; displacement {:.3} µm at 0.1 s, {:.3} µm at {duration} s; tilt modes {:.0} Hz and {:.0} Hz, A3 axis {:.0} Hz",
        at(0.1),
        r.samples.last().map(um).unwrap_or(f64::NAN),
        f[0],
        f[1],
        f[2]
    );
    println!("wrote {} and {}", out.display(), plot.display());
    Ok(())
}

/// Writes a frame as an 8- or 16-bit greyscale PNG.
pub fn write_png(frame: &Frame, bits: u8, path: &Path) -> Result<()> {
    let shift = 16 - frame.bit_depth as u32;
    let tmp = path.with_extension("png.tmp");
    let result = if bits == 16 {
        let data: Vec<u16> = frame.pixels.iter().map(|&v| v << shift).collect();
        image::ImageBuffer::<image::Luma<u16>, _>::from_raw(frame.width, frame.height, data)
            .context("frame buffer size")?
            .save_with_format(&tmp, image::ImageFormat::Png)
    } else {
        let down = frame.bit_depth as u32 - 8;
        let data: Vec<u8> = frame.pixels.iter().map(|&v| (v >> down) as u8).collect();
        image::GrayImage::from_raw(frame.width, frame.height, data)
            .context("frame buffer size")?
            .save_with_format(&tmp, image::ImageFormat::Png)
    };
    result
        .map_err(anyhow::Error::from)
        .and_then(|()| std::fs::rename(&tmp, path).map_err(anyhow::Error::from))
        .map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            InputError(format!(
                "--out `{}`: cannot write the image: {e}",
                path.display()
            ))
            .into()
        })
}

/// `sim frame`.
#[allow(clippy::too_many_arguments)]
fn run_frame(
    d: &Description,
    zoom: f64,
    vga: bool,
    crop: bool,
    bits: u8,
    volts: Option<&[f64]>,
    out: &Path,
    args: &TwinArgs,
) -> Result<()> {
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
    let (twin, mut rig) = build(d, args)?;
    let frame = core::frame(&mut rig, zoom, acquisition, volts).map_err(|e| match e {
        SimError::Device {
            what,
            source: HwError::Refused(r),
        } => InputError(format!("{what}: refused: {r}")).into(),
        other => sim_error(other),
    })?;
    write_png(&frame, bits, out)?;
    let tip = lock(&twin).tip();
    println!(
        "frame {}x{} at {zoom}x: {:.3} µm per pixel, field of view {:.0} x {:.0} µm; exposure {:.1} ms at t = {:.3} s",
        frame.width,
        frame.height,
        frame.pixel_size * 1e6,
        frame.width as f64 * frame.pixel_size * 1e6,
        frame.height as f64 * frame.pixel_size * 1e6,
        frame.exposure * 1e3,
        frame.timestamp
    );
    println!(
        "pipette tip at x = {:.3} µm, z = {:.3} µm, {:.3} µm from focus",
        tip.x * 1e6,
        tip.z * 1e6,
        tip.depth * 1e6
    );
    println!("wrote {} ({bits}-bit PNG)", out.display());
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
            volts,
            out,
            twin,
        } => run_frame(d, *zoom, *vga, *crop, *bits, volts.as_deref(), out, twin),
    }
}
