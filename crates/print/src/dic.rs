//! `cellinject dic field`'s files: the field's CSV and its displacement maps.

use std::fmt::Write as _;

use cellinject_plot::map::GridMap;

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
