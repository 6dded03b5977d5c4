//! `cellinject sim ...`: drive the digital twin through its hardware traits (behind the
//! safety wrappers, as a controller would) and write what it did.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use cellinject_config::Description;
use cellinject_hw::{Camera, Clock, Frame, HwError, PiezoChannel};
use cellinject_model::{ACTUATOR_NAMES, Approach};
use cellinject_plot::{Chart, Series};
use cellinject_twin::{GuardedDevices, SharedTwin, Twin, guarded_devices};
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
    ACTUATOR_NAMES
        .iter()
        .position(|a| a.eq_ignore_ascii_case(name))
        .ok_or_else(|| InputError(format!("--actuator must be A1, A2 or A3, got `{name}`")).into())
}

/// Builds the twin of the description and its guarded devices.
fn build(d: &Description, args: &TwinArgs) -> Result<(SharedTwin, GuardedDevices)> {
    let mut p = d.twin;
    if let Some(a) = args.approach {
        p.approach = Approach::from_number(a).unwrap_or(p.approach);
    }
    if let Some(s) = args.seed {
        p.seed = s;
    }
    let twin = Twin::new(&d.design, p)
        .map_err(|e| InputError(format!("cannot build the twin: {e}")))?
        .into_shared();
    let dev =
        guarded_devices(&twin).map_err(|e| InputError(format!("cannot build the twin: {e}")))?;
    Ok((twin, dev))
}

/// A refused command is the user's to fix: exit code 2.
fn refused(e: HwError) -> anyhow::Error {
    InputError(format!("{e}")).into()
}

/// The displacement of an actuator's end as the mechanism sees it, m (positive = extends).
fn displacement(twin: &SharedTwin, ch: usize) -> f64 {
    displacement_in(&lock(twin).world.snapshot(), ch)
}

/// The same, from a snapshot already taken.
fn displacement_in(s: &cellinject_twin::Snapshot, ch: usize) -> f64 {
    if ch < 2 { -s.dl[ch] } else { s.q[2] }
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
    let (twin, mut dev) = build(d, args)?;
    let v_max = dev.piezo[ch].voltage_range().1;
    let amp = amplitude.unwrap_or(v_max);
    if !(amp > 0.0 && amp <= v_max) {
        return Err(
            InputError(format!("--amplitude must lie in (0, {v_max}] V, got {amp}")).into(),
        );
    }
    let env = cellinject_twin::devices::envelope(&twin).map_err(|e| InputError(e.to_string()))?;
    let safe = env.max_safe_voltage(ch, [0.0; 3]).unwrap_or(0.0);
    if amp > safe {
        let mut volts = [0.0; 3];
        volts[ch] = amp;
        let why = env
            .check(volts)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        return Err(InputError(format!(
            "--amplitude {amp} V is beyond the safety envelope of {} under approach {} ({why}); at most {safe:.1} V is allowed",
            ACTUATOR_NAMES[ch],
            lock(&twin).world.params().approach.number()
        ))
        .into());
    }
    // A full loop, then nested minor loops closing towards the middle, then back to 0.
    let turning = [1.0, 0.0, 0.8, 0.2, 0.7, 0.3, 0.6, 0.4, 0.0];
    let ramp = amp; // V/s: one second per full leg
    let dt = 1e-3;
    let start = displacement(&twin, ch);
    let mut csv = String::from("time_s,voltage_v,displacement_m\n");
    let mut points = Vec::new();
    let mut v = 0.0;
    for &target in &turning {
        let target = target * amp;
        let n = ((target - v).abs() / (ramp * dt)).ceil().max(1.0) as usize;
        let from = v;
        for k in 1..=n {
            v = from + (target - from) * k as f64 / n as f64;
            dev.piezo[ch]
                .set_voltage(v)
                .map_err(|e| InputError(format!("{} at {v:.3} V: {e}", ACTUATOR_NAMES[ch])))?;
            dev.clock.sleep(dt).map_err(refused)?;
            let out_v = dev.piezo[ch].read_voltage().map_err(refused)?;
            let x = displacement(&twin, ch) - start;
            let _ = writeln!(csv, "{:.6},{:.6},{:.6e}", dev.clock.now(), out_v, x);
            points.push((out_v, x * 1e6));
        }
    }
    write_csv(out, &csv)?;
    let chart = Chart {
        title: format!(
            "{ACTUATOR}: hysteresis loop with nested minor loops",
            ACTUATOR = ACTUATOR_NAMES[ch]
        ),
        x_label: "amplifier output [V]".into(),
        y_label: "actuator displacement [µm]".into(),
        series: vec![cellinject_plot::Series {
            name: ACTUATOR_NAMES[ch].into(),
            points: points.clone(),
        }],
    };
    let plot = write_plot(out, &[chart], 1)?;
    let max = points.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
    println!(
        "{}: loop 0-{amp:.1} V, stroke {:.3} µm under load; {} samples",
        ACTUATOR_NAMES[ch],
        max,
        points.len()
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
    if !(duration > 0.0 && duration <= 3600.0) {
        return Err(InputError(format!(
            "--duration must lie in (0, 3600] s, got {duration}"
        ))
        .into());
    }
    let (twin, mut dev) = build(d, args)?;
    let start = displacement(&twin, ch);
    let x0 = lock(&twin).world.snapshot().x;
    dev.piezo[ch].set_voltage(voltage).map_err(refused)?;
    let dt = lock(&twin).world.dt();
    let mut csv = String::from(
        "time_s,voltage_v,displacement_m,end_effector_x_m,end_effector_y_m,end_effector_z_m\n",
    );
    let (mut fast, mut slow) = (Vec::new(), Vec::new());
    let t0 = dev.clock.now();
    let mut next_slow = 0.0;
    loop {
        let t = dev.clock.now() - t0;
        if t > duration + 0.5 * dt {
            break;
        }
        // Every step for the first 50 ms (ringing), then every millisecond (creep).
        if t <= 0.05 || t >= next_slow {
            let s = lock(&twin).world.snapshot();
            let x = displacement_in(&s, ch) - start;
            let ee = s.x - x0;
            let _ = writeln!(
                csv,
                "{:.6},{:.6},{:.6e},{:.6e},{:.6e},{:.6e}",
                t, s.voltage[ch], x, ee[0], ee[1], ee[2]
            );
            if t <= 0.03 {
                fast.push((t * 1e3, x * 1e6));
            }
            slow.push((t, x * 1e6));
            if t >= next_slow {
                next_slow += 1e-3;
            }
        }
        dev.clock.sleep(dt).map_err(refused)?;
    }
    write_csv(out, &csv)?;
    let name = ACTUATOR_NAMES[ch];
    let charts = [
        Chart {
            title: format!("{name} step to {voltage} V: first 30 ms"),
            x_label: "time [ms]".into(),
            y_label: "actuator displacement [µm]".into(),
            series: vec![Series {
                name: name.into(),
                points: fast,
            }],
        },
        Chart {
            title: format!("{name} step to {voltage} V: creep over {duration} s"),
            x_label: "time [s]".into(),
            y_label: "actuator displacement [µm]".into(),
            series: vec![Series {
                name: name.into(),
                // After the ringing, so that the vertical axis shows the creep.
                points: slow.iter().copied().filter(|p| p.0 >= 0.05).collect(),
            }],
        },
    ];
    let plot = write_plot(out, &charts, 2)?;
    let f = lock(&twin).world.natural_frequencies();
    let at = |t: f64| {
        slow.iter()
            .find(|p| p.0 >= t)
            .map(|p| p.1)
            .unwrap_or(f64::NAN)
    };
    println!(
        "{name}: step to {voltage} V; displacement {:.3} µm at 0.1 s, {:.3} µm at {duration} s; tilt modes {:.0} Hz and {:.0} Hz, A3 axis {:.0} Hz",
        at(0.1),
        slow.last().map(|p| p.1).unwrap_or(f64::NAN),
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
    let (twin, mut dev) = build(d, args)?;
    {
        let mut t = lock(&twin);
        t.camera
            .set_zoom(zoom)
            .map_err(|e| InputError(format!("--zoom: {e}")))?;
        if vga || crop {
            let s = t.camera.vga_settings(vga);
            t.camera
                .configure(s)
                .map_err(|e| InputError(format!("camera: {e}")))?;
        }
    }
    if let Some(v) = volts {
        if v.len() != 3 {
            return Err(InputError(format!(
                "--volts takes three voltages V1,V2,V3, got {}",
                v.len()
            ))
            .into());
        }
        for (ch, volts) in v.iter().enumerate() {
            dev.piezo[ch].set_voltage(*volts).map_err(refused)?;
        }
        dev.clock.sleep(0.1).map_err(refused)?;
    }
    let frame = dev.camera.grab().map_err(refused)?;
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
