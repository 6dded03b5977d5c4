//! `cellinject dic`'s output: the points' table, `dic field`'s summary, CSV and
//! displacement maps, and `dic track`'s CSV.

use std::fmt::Write as _;

use cellinject_core::dic::{FieldReport, PointReport};
use cellinject_dic::track::{Status, TrackPoint};
use cellinject_plot::map::GridMap;

use crate::table::{Table, fixed};

/// The displacement maps, u and v side by side, each on its own colour scale (µm
/// when the pixel size is given, else px).
pub fn field_maps(f: &cellinject_dic::field::Field, um_per_px: Option<f64>) -> [GridMap; 2] {
    let (scale, unit) = match um_per_px {
        Some(s) => (s, "µm"),
        None => (1.0, "px"),
    };
    let map = |name: &str, sel: fn(&cellinject_dic::PointResult) -> f64| GridMap {
        title: format!(
            "{name}: displacement along {}",
            if name == "u" { "x" } else { "y" }
        ),
        x_label: format!("x [{unit}]"),
        y_label: format!("y [{unit}]"),
        value_label: format!("{name} [{unit}]"),
        x: (f.x0 as f64 * scale, f.step as f64 * scale),
        y: (f.y0 as f64 * scale, f.step as f64 * scale),
        nx: f.nx,
        ny: f.ny,
        values: f
            .points
            .iter()
            .map(|p| p.as_ref().map(|p| sel(p) * scale))
            .collect(),
    };
    [map("u", |p| p.u), map("v", |p| p.v)]
}

/// The field's CSV: one row a grid point, empty where none was kept.
pub fn field_csv(report: &cellinject_core::dic::FieldReport) -> String {
    let mut csv = String::from(
        "x,y,u,v,du_dx,du_dy,dv_dx,dv_dy,zncc,iterations,converged,sigma_u,sigma_v,subset\n",
    );
    for (k, p) in report.field.points.iter().enumerate() {
        let (x, y) = report.position(k);
        match p {
            Some(p) => {
                let _ = writeln!(
                    csv,
                    "{x},{y},{:.6},{:.6},{:.6e},{:.6e},{:.6e},{:.6e},{:.6},{},{},{:.6},{:.6},{}",
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
                    p.sigma_v,
                    p.subset
                );
            }
            None => {
                let _ = writeln!(csv, "{x},{y},,,,,,,,0,false,,,");
            }
        }
    }
    csv
}

/// `cellinject dic`'s table: each point's displacement, ZNCC, iterations (`!` when not
/// converged) and predicted σ, or why it was not matched.
pub fn points_text(res: &[PointReport]) -> String {
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
    for p in res {
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
                fixed(u, 4),
                fixed(v, 4),
                fixed(zncc, 4),
                format!("{iterations}{}", if converged { "" } else { "!" }),
                format!("{sigma_u:.4}"),
                format!("{sigma_v:.4}"),
            ],
            PointReport::Missing { x, y, error, .. } => vec![
                format!("{x}"),
                format!("{y}"),
                error.to_string(),
                String::new(),
                String::new(),
                String::new(),
                String::new(),
                String::new(),
            ],
        });
    }
    t.text()
}

/// `cellinject dic field`'s summary: the points kept of the grid and the rate
/// (converged points over `elapsed`, the correlation's wall time; scripts read this
/// line), why the others were dropped, and the displacements' ranges (when any point
/// was kept).
pub fn field_text(r: &FieldReport, step: usize, elapsed: f64) -> String {
    let f = &r.field;
    let dropped = &r.dropped;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{} of {} grid points ({}x{}, step {step}) in {elapsed:.3} s ({:.0} points/s)",
        r.found,
        f.nx * f.ny,
        f.nx,
        f.ny,
        r.found as f64 / elapsed.max(1e-9)
    );
    let _ = writeln!(
        out,
        "{} dropped as unreliable ({} predicted σ above {} px, {} ZNCC below {}, {} not converged, {} contradicted by their neighbours or alone)",
        dropped.total(),
        dropped.uncertain,
        r.acceptance.max_sigma,
        dropped.low_zncc,
        r.acceptance.min_zncc,
        dropped.not_converged,
        dropped.inconsistent
    );
    if let (Some(ru), Some(rv)) = (r.u_range, r.v_range) {
        let _ = writeln!(
            out,
            "u from {:.4} to {:.4} px, v from {:.4} to {:.4} px",
            ru.0, ru.1, rv.0, rv.1
        );
    }
    out.pop();
    out
}

/// `cellinject dic track`'s CSV, a row a frame: the displacement in pixels (and in
/// metres with a pixel size), ZNCC, iterations, σ, the tracker's status and the blur.
/// Displacements below 1e-9 px are rounding (the reference frame against itself) and
/// written as 0; what was not measured is left empty.
pub struct TrackCsv {
    um_per_px: Option<f64>,
    text: String,
}

impl TrackCsv {
    /// The header; `um_per_px` adds the displacements in metres.
    pub fn new(um_per_px: Option<f64>) -> Self {
        TrackCsv {
            um_per_px,
            text: String::from(
                "frame,file,u_px,v_px,u_m,v_m,zncc,iterations,sigma_u_px,status,blur_px\n",
            ),
        }
    }

    /// Frame `k`, file `name`, tracked as `p`.
    pub fn row(&mut self, k: usize, name: &str, p: &TrackPoint) {
        let status = match p.status {
            Status::Tracked => "tracked",
            Status::Recovered => "recovered",
            Status::Defocused => "defocused",
            Status::Rejected => "rejected",
        };
        let clean = |v: f64| if v.abs() < 1e-9 { 0.0 } else { v };
        let m = |v: f64| {
            self.um_per_px
                .filter(|_| v.is_finite())
                .map(|s| format!("{:.6e}", clean(v) * s * 1e-6))
                .unwrap_or_default()
        };
        let num = |v: f64| {
            if v.is_finite() {
                fixed(clean(v), 6)
            } else {
                String::new()
            }
        };
        let _ = writeln!(
            self.text,
            "{k},{name},{},{},{},{},{:.6},{},{},{status},{}",
            num(p.u),
            num(p.v),
            m(p.u),
            m(p.v),
            p.zncc,
            p.iterations,
            num(p.sigma_u),
            p.blur
        );
    }

    /// The CSV so far.
    pub fn text(&self) -> &str {
        &self.text
    }
}
