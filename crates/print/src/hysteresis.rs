//! The stacks' files: `cellinject hysteresis identify|fit|invert|validate` and
//! `cellinject sim loop|step`, CSV tables and charts.

use std::fmt::Write as _;

use cellinject_core::hysteresis::{FitReport, IdentifyReport, InvertReport, ValidateReport};
use cellinject_core::sim::{LoopReport, StepReport, StepSample};
use cellinject_hysteresis::Model as _;
use cellinject_plot::{Chart, Series, Style};

/// The identification's excitation: the stack's displacement against the command.
pub fn identify_chart(r: &IdentifyReport) -> Chart {
    volts_against_displacement(
        format!("{}: identification excitation", r.actuator),
        ("amplifier command [V]", "stack displacement [µm]"),
        r.actuator,
        &r.samples,
    )
}

/// `sim loop`'s chart: the hysteresis loop with nested minor loops.
pub fn loop_chart(r: &LoopReport) -> Chart {
    volts_against_displacement(
        format!("{}: hysteresis loop with nested minor loops", r.actuator),
        ("amplifier output [V]", "actuator displacement [µm]"),
        r.actuator,
        &r.samples,
    )
}

/// One line of (s, V, m) samples: the displacement (µm) against the voltage.
fn volts_against_displacement(
    title: String,
    (x_label, y_label): (&str, &str),
    name: &str,
    samples: &[[f64; 3]],
) -> Chart {
    Chart {
        title,
        x_label: x_label.into(),
        y_label: y_label.into(),
        series: vec![Series {
            name: name.into(),
            points: samples.iter().map(|s| (s[1], s[2] * 1e6)).collect(),
            style: Style::Line,
        }],
    }
}

/// (s, V, m) samples as the CSV `time_s,voltage_v,displacement_m` that `sim loop` and
/// `hysteresis identify` write and `hysteresis fit` reads.
pub fn voltage_displacement_csv(samples: &[[f64; 3]]) -> String {
    let mut csv = String::from("time_s,voltage_v,displacement_m\n");
    for s in samples {
        let _ = writeln!(csv, "{:.6},{:.6},{:.6e}", s[0], s[1], s[2]);
    }
    csv
}

/// `sim step`'s CSV: one row a sample, the stack's and the end-effector's
/// displacement.
pub fn step_csv(r: &StepReport) -> String {
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
    csv
}

/// `sim step`'s charts: the first 30 ms, and the creep over the run after the ringing
/// (left out when the run ends within it).
pub fn step_charts(r: &StepReport, voltage: f64, duration: f64) -> Vec<Chart> {
    let name = r.actuator;
    // Samples within `keep`: time times `scale` against the displacement in µm.
    let panel = |title: String, x_label: &str, keep: &dyn Fn(f64) -> bool, scale: f64| Chart {
        title,
        x_label: x_label.into(),
        y_label: "actuator displacement [µm]".into(),
        series: vec![Series {
            name: name.into(),
            points: r
                .samples
                .iter()
                .filter(|s| keep(s.time))
                .map(|s| (s.time * scale, s.displacement * 1e6))
                .collect(),
            style: Style::Line,
        }],
    };
    let mut charts = vec![
        panel(
            format!("{name} step to {voltage} V: first 30 ms"),
            "time [ms]",
            &|t| t <= 0.03,
            1e3,
        ),
        // After the ringing, so that the vertical axis shows the creep.
        panel(
            format!("{name} step to {voltage} V: creep over {duration} s"),
            "time [s]",
            &|t| t >= 0.05,
            1.0,
        ),
    ];
    // A run that ends within the ringing has no creep to show: one panel.
    if charts[1].series[0].points.len() < 2 {
        charts.truncate(1);
    }
    charts
}

/// `sim step`'s summary: the displacement at 0.1 s (when the run lasts that long) and at
/// its end, and the twin's natural frequencies `f` (Hz: the tilt modes, the A3 axis).
pub fn step_text(r: &StepReport, voltage: f64, duration: f64, f: [f64; 3]) -> String {
    let um = |s: &StepSample| s.displacement * 1e6;
    // Only what was measured is printed: no NaN for a run shorter than 0.1 s.
    let at_100ms = r
        .displacement_at(0.1)
        .filter(|_| duration >= 0.1)
        .map(|x| format!("{:.3} µm at 0.1 s, ", x * 1e6))
        .unwrap_or_default();
    let last = r
        .samples
        .last()
        .map(|s| format!("{:.3} µm at {duration} s", um(s)))
        .unwrap_or_else(|| "no sample".into());
    format!(
        "{}: step to {voltage} V; displacement {at_100ms}{last}; tilt modes {:.0} Hz and {:.0} Hz, A3 axis {:.0} Hz",
        r.actuator, f[0], f[1], f[2]
    )
}

/// The measured loops (`volts`, `disp`) and the fitted `model`'s, from rest.
pub fn fit_chart(model: &str, r: &FitReport, volts: &[f64], disp: &[f64]) -> Chart {
    let mut m = r.model.clone();
    m.reset();
    let modelled: Vec<(f64, f64)> = volts.iter().map(|v| (*v, m.apply(*v) * 1e6)).collect();
    Chart {
        title: format!(
            "{model} fit: RMS {:.1} nm ({:.2} % of the span)",
            r.rms * 1e9,
            100.0 * r.rms_relative
        ),
        x_label: "voltage [V]".into(),
        y_label: "displacement [µm]".into(),
        series: vec![
            Series {
                name: "measured".into(),
                points: volts.iter().zip(disp).map(|(v, y)| (*v, y * 1e6)).collect(),
                style: Style::Line,
            },
            Series {
                name: "model".into(),
                points: modelled,
                style: Style::Line,
            },
        ],
    }
}

/// The inverted trajectory: the command at each time of `t`.
pub fn invert_csv(t: &[f64], r: &InvertReport) -> String {
    let mut csv = String::from("time_s,voltage_v\n");
    for (time, v) in t.iter().zip(&r.volts) {
        let _ = writeln!(csv, "{time:.6},{v:.6}");
    }
    csv
}

/// The desired and predicted displacements over time `t`, and the command.
pub fn invert_charts(t: &[f64], targets: &[f64], r: &InvertReport) -> [Chart; 2] {
    [
        Chart {
            title: "desired and predicted displacement".into(),
            x_label: "time [s]".into(),
            y_label: "displacement [µm]".into(),
            series: vec![
                Series {
                    name: "desired".into(),
                    points: t.iter().zip(targets).map(|(t, y)| (*t, y * 1e6)).collect(),
                    style: Style::Line,
                },
                Series {
                    name: "model's prediction".into(),
                    points: t
                        .iter()
                        .zip(&r.predicted)
                        .map(|(t, y)| (*t, y * 1e6))
                        .collect(),
                    style: Style::Line,
                },
            ],
        },
        Chart {
            title: "command".into(),
            x_label: "time [s]".into(),
            y_label: "voltage [V]".into(),
            series: vec![Series {
                name: "command".into(),
                points: t.iter().zip(&r.volts).map(|(t, v)| (*t, *v)).collect(),
                style: Style::Line,
            }],
        },
    ]
}

/// The validation, sample by sample: measured, predicted and their difference.
pub fn validate_csv(time: &[f64], volts: &[f64], disp: &[f64], r: &ValidateReport) -> String {
    let mut csv = String::from("time_s,voltage_v,measured_m,predicted_m,error_m\n");
    for k in 0..r.samples {
        let _ = writeln!(
            csv,
            "{:.6},{:.6},{:.6e},{:.6e},{:.6e}",
            time[k],
            volts[k],
            disp[k],
            r.predicted[k],
            r.predicted[k] - disp[k]
        );
    }
    csv
}

/// The measured and predicted displacements over time (or row, without `has_time`)
/// and as loops over the voltage.
pub fn validate_charts(
    time: &[f64],
    has_time: bool,
    volts: &[f64],
    disp: &[f64],
    r: &ValidateReport,
) -> [Chart; 2] {
    let um = |x: &[f64], y: &[f64]| -> Vec<(f64, f64)> {
        x.iter().zip(y).map(|(a, b)| (*a, b * 1e6)).collect()
    };
    let x_time = if has_time { "time [s]" } else { "row" };
    let pair = |x: &[f64]| {
        vec![
            Series {
                name: "measured".into(),
                points: um(x, disp),
                style: Style::Line,
            },
            Series {
                name: "predicted".into(),
                points: um(x, &r.predicted),
                style: Style::Line,
            },
        ]
    };
    [
        Chart {
            title: format!(
                "prediction: RMS {:.3} µm ({:.2} % of stroke), worst {:.3} µm",
                r.rms * 1e6,
                r.rms_percent,
                r.max * 1e6
            ),
            x_label: x_time.into(),
            y_label: "displacement [µm]".into(),
            series: pair(time),
        },
        Chart {
            title: "loops".into(),
            x_label: "voltage [V]".into(),
            y_label: "displacement [µm]".into(),
            series: pair(volts),
        },
    ]
}
