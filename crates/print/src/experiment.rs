//! The experiments' files and summaries (`cellinject experiment range`,
//! `repeatability`, `tracking`): CSV tables, charts and the text a person reads.

use std::fmt::Write as _;

use cellinject_core::bench::FrameRecord;
use cellinject_core::experiment::{RangeReport, RepeatabilityReport, TrackingReport};
use cellinject_plot::{Chart, Series, Style};

use crate::table::fixed;

/// The range experiment's CSV: one row a sample of each sweep (NaN where unmeasured).
pub fn range_csv(r: &RangeReport) -> String {
    let mut csv = String::from("actuator,voltage_v,axis,displacement_m,true_displacement_m\n");
    for (i, sweep) in r.sweeps.iter().enumerate() {
        for p in sweep {
            let _ = writeln!(
                csv,
                "A{},{:.4},{},{:.6e},{:.6e}",
                i + 1,
                p.volts,
                ["x", "y"][i],
                p.measured.unwrap_or(f64::NAN),
                p.truth.unwrap_or(f64::NAN)
            );
        }
    }
    csv
}

/// The range experiment's two charts: each stack's sweep against the end-effector's
/// displacement through the cameras (and the twin's truth, when known), µm.
pub fn range_charts(r: &RangeReport) -> Vec<Chart> {
    (0..2)
        .map(|i| {
            let axis = ["x", "y"][i];
            let camera = ["top camera", "side camera"][i];
            let mut series = vec![Series {
                name: format!("{axis}, {camera}"),
                points: r.sweeps[i]
                    .iter()
                    .filter_map(|p| p.measured.map(|m| (p.volts, m * 1e6)))
                    .collect(),
                style: Style::Line,
            }];
            if r.sweeps[i].iter().all(|p| p.truth.is_some()) {
                series.push(Series {
                    name: format!("{axis}, twin's truth"),
                    points: r.sweeps[i]
                        .iter()
                        .step_by(4)
                        .filter_map(|p| p.truth.map(|t| (p.volts, t * 1e6)))
                        .collect(),
                    style: Style::Dots,
                });
            }
            Chart {
                title: format!(
                    "A{} swept, approach {}: range {:.1} µm",
                    i + 1,
                    r.approach,
                    [r.range_m.x, r.range_m.y][i] * 1e6
                ),
                x_label: format!("A{} voltage [V]", i + 1),
                y_label: format!("end-effector {axis} [µm]"),
                series,
            }
        })
        .collect()
}

/// The repeatability experiment's CSV: one row a run.
pub fn repeatability_csv(r: &RepeatabilityReport) -> String {
    let mut csv =
        String::from("run,x_m,y_m,true_x_m,true_y_m,settling_frames,a1_voltage_v,a2_voltage_v\n");
    for run in &r.run_list {
        let t = run.truth.unwrap_or([f64::NAN; 2]);
        let _ = writeln!(
            csv,
            "{},{:.6e},{:.6e},{:.6e},{:.6e},{},{:.5},{:.5}",
            run.run,
            run.measured[0],
            run.measured[1],
            t[0],
            t[1],
            run.settling_frames
                .map(|f| f.to_string())
                .unwrap_or_default(),
            run.volts[0],
            run.volts[1]
        );
    }
    csv
}

/// The repeatability experiment's scatter about the mean position (nm, or µm when
/// over 2 µm).
pub fn repeatability_chart(r: &RepeatabilityReport) -> Chart {
    let unit = if r.max_error_m[0].max(r.max_error_m[1]) > 2e-6 {
        ("µm", 1e6)
    } else {
        ("nm", 1e9)
    };
    let mean = r.mean_m;
    let mut series = vec![Series {
        name: "cameras".into(),
        points: r
            .run_list
            .iter()
            .map(|p| {
                (
                    (p.measured[0] - mean[0]) * unit.1,
                    (p.measured[1] - mean[1]) * unit.1,
                )
            })
            .collect(),
        style: Style::Dots,
    }];
    let truth: Option<Vec<[f64; 2]>> = r.run_list.iter().map(|p| p.truth).collect();
    if let Some(t) = truth {
        let n = t.len().max(1) as f64;
        let tm = [0, 1].map(|a| t.iter().map(|p| p[a]).sum::<f64>() / n);
        series.push(Series {
            name: "twin's truth".into(),
            points: t
                .iter()
                .map(|p| ((p[0] - tm[0]) * unit.1, (p[1] - tm[1]) * unit.1))
                .collect(),
            style: Style::Dots,
        });
    }
    Chart {
        // The title's errors in the axes' unit (µm over axes in nm read as a
        // thousand times the spread).
        title: format!(
            "{} runs, approach {}, {} control: max error {} / {} {}",
            r.runs,
            r.approach,
            r.control.name(),
            fixed(
                r.max_error_m[0] * unit.1,
                if unit.0 == "nm" { 1 } else { 3 }
            ),
            fixed(
                r.max_error_m[1] * unit.1,
                if unit.0 == "nm" { 1 } else { 3 }
            ),
            unit.0
        ),
        x_label: format!("x from the mean [{}]", unit.0),
        y_label: format!("y from the mean [{}]", unit.0),
        series,
    }
}

/// The tracking experiment's CSV: one row a frame.
pub fn tracking_csv(r: &TrackingReport) -> String {
    let mut csv = String::from(
        "time_s,a1_reference_m,a2_reference_m,desired_x_m,desired_y_m,x_m,y_m,z_m,true_x_m,true_y_m,true_z_m,a1_voltage_v,a2_voltage_v\n",
    );
    for (f, d) in r.frames.iter().zip(&r.desired) {
        let m = f.measured.unwrap_or([f64::NAN; 3]);
        let t = f.truth.unwrap_or([f64::NAN; 3]);
        let _ = writeln!(
            csv,
            "{:.5},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.5},{:.5}",
            f.t,
            f.reference[0],
            f.reference[1],
            d[0],
            d[1],
            m[0],
            m[1],
            m[2],
            t[0],
            t[1],
            t[2],
            f.volts[0],
            f.volts[1]
        );
    }
    csv
}

/// The tracking experiment's two charts, desired against measured, per axis.
pub fn tracking_charts(r: &TrackingReport) -> Vec<Chart> {
    (0..2)
        .map(|i| {
            let axis = ["x", "y"][i];
            let pick = |f: &FrameRecord, d: &[f64; 2]| (f.t, d[i] * 1e6);
            Chart {
                title: format!("{axis}: {} control", r.control.name()),
                x_label: "time [s]".into(),
                y_label: format!("end-effector {axis} [µm]"),
                series: vec![
                    Series {
                        name: "desired".into(),
                        points: r
                            .frames
                            .iter()
                            .zip(&r.desired)
                            .map(|(f, d)| pick(f, d))
                            .collect(),
                        style: Style::Line,
                    },
                    Series {
                        name: "cameras".into(),
                        points: r
                            .frames
                            .iter()
                            .filter_map(|f| f.measured.map(|m| (f.t, m[i] * 1e6)))
                            .collect(),
                        style: Style::Dots,
                    },
                ],
            }
        })
        .collect()
}

/// The range experiment's summary: each axis measured, against the model and the
/// full stroke, and where the safety envelope stopped a stack.
pub fn range_text(r: &RangeReport) -> String {
    let mut t = String::new();
    let _ = writeln!(
        t,
        "Range of motion, approach {} (A1 swept for x, A2 for y; through the cameras):",
        r.approach
    );
    for (i, (axis, m, model, full)) in [
        ("x", r.range_m.x, r.model_range_m.x, r.full_stroke_range_m.x),
        ("y", r.range_m.y, r.model_range_m.y, r.full_stroke_range_m.y),
    ]
    .into_iter()
    .enumerate()
    {
        let truth = r
            .true_range_m
            .map(|t| format!(", true {}", um(if i == 0 { t.x } else { t.y })))
            .unwrap_or_default();
        let _ = writeln!(
            t,
            "  {axis}: {} measured{truth}; model {} for 0-{:.1} V ({:+.2} %), full stroke {}",
            um(m),
            um(model),
            r.v_max[i],
            (m / model - 1.0) * 100.0,
            um(full)
        );
        if let Some(why) = &r.limited_by[i] {
            let _ = writeln!(
                t,
                "     the safety envelope stops A{} at {:.1} V: {why}",
                i + 1,
                r.v_max[i]
            );
        }
    }
    t.pop();
    t
}

/// The repeatability experiment's summary: errors through the cameras (and the twin's
/// truth), settling, and the holds.
pub fn repeatability_text(r: &RepeatabilityReport) -> String {
    let mut t = String::new();
    let _ = writeln!(
        t,
        "Repeatability, approach {}, {} control: {} runs of a {} shift of A1 and A2",
        r.approach,
        r.control.name(),
        r.runs,
        um(r.shift_m)
    );
    let _ = writeln!(
        t,
        "  cameras:      max error x {}, y {}, distance {};  RMS x {}, y {}",
        nm(r.max_error_m[0]),
        nm(r.max_error_m[1]),
        nm(r.max_distance_m),
        nm(r.rms_error_m[0]),
        nm(r.rms_error_m[1])
    );
    if let (Some(m), Some(rms), Some(d)) = (
        r.true_max_error_m,
        r.true_rms_error_m,
        r.true_max_distance_m,
    ) {
        let _ = writeln!(
            t,
            "  twin's truth: max error x {}, y {}, distance {};  RMS x {}, y {}",
            nm(m[0]),
            nm(m[1]),
            nm(d),
            nm(rms[0]),
            nm(rms[1])
        );
    }
    if let Some(a) = r.camera_vs_truth_m {
        let _ = writeln!(t, "  the cameras agree with the truth to {}", nm(a));
    }
    let _ = writeln!(
        t,
        "  settling (within {} of the run's position): median {} frames, worst {}{}",
        nm(r.tolerance_m),
        opt(r.settling_median_frames, |f| f.to_string()),
        opt(r.settling_max_frames, |f| format!("{f} frames")),
        if r.unsettled_runs > 0 {
            format!(" ({} runs never settled)", r.unsettled_runs)
        } else {
            String::new()
        }
    );
    let shortest = r
        .run_list
        .iter()
        .map(|run| run.hold_s)
        .fold(f64::INFINITY, f64::min);
    if r.longest_hold_s > shortest + 1e-9 {
        let _ = writeln!(
            t,
            "  held {:.2} to {:.2} s (the closed loop holds until in position)",
            shortest, r.longest_hold_s
        );
    }
    t.pop();
    t
}

/// The tracking experiment's summary: RMS and largest errors of the steps and the
/// circle, and the steps' settling.
pub fn tracking_text(r: &TrackingReport) -> String {
    let mut t = String::new();
    let _ = writeln!(
        t,
        "Tracking, approach {}, {} control, stacks at {} µm plus steps of {} µm and a circle of {} µm (errors against J·r, through the cameras):",
        r.approach,
        r.control.name(),
        r.bias_m * 1e6,
        r.step_m * 1e6,
        r.amplitude_m * 1e6
    );
    for (name, p) in [("steps", &r.steps), ("circle", &r.sine)] {
        let _ = writeln!(
            t,
            "  {name:6}: RMS x {}, y {};  max x {}, y {}",
            nm(p.rms_error_m[0]),
            nm(p.rms_error_m[1]),
            nm(p.max_error_m[0]),
            nm(p.max_error_m[1])
        );
    }
    let settle: Vec<String> = r
        .steps
        .settling_frames
        .iter()
        .map(|s| opt(*s, |f| f.to_string()))
        .collect();
    let _ = writeln!(
        t,
        "  settling of the four steps within {}: {} frames",
        nm(r.tolerance_m),
        settle.join(", ")
    );
    t.pop();
    t
}

/// `x` metres in micrometres, three decimals.
fn um(x: f64) -> String {
    format!("{:.3} µm", x * 1e6)
}

/// `x` metres in nanometres, one decimal.
fn nm(x: f64) -> String {
    format!("{:.1} nm", x * 1e9)
}

/// `f(v)`, or "never" when there is none.
fn opt<T: Copy>(v: Option<T>, f: impl Fn(T) -> String) -> String {
    v.map(f).unwrap_or_else(|| "never".into())
}
