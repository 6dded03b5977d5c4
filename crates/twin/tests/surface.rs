//! A loaded plate's floor is tilted and bowed: each cell is in focus where the feeder
//! brings the floor under it to the focal plane, and the tip meets the floor where the
//! floor truly lies.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use cellinject_hw::Frame;
use cellinject_plate::{Object, Plate};
use cellinject_rig::params::OpticsSetup;
use cellinject_twin::params::{CameraParams, LensParams};
use cellinject_twin::scene::Scene;
use cellinject_twin::{Microscope, PlateSurface, TipPose};

/// Brenner's gradient over a square of `half` pixels around pixel (i, j), over the
/// square's mean squared (computed here, apart from the workflow's focusing).
fn sharpness(f: &Frame, i: usize, j: usize, half: usize) -> f64 {
    let w = f.width as usize;
    let (mut g, mut s, mut n) = (0.0, 0.0, 0.0);
    for y in j - half..j + half {
        for x in i - half..i + half {
            let v = f.pixels[y * w + x] as f64;
            let dx = f.pixels[y * w + x + 2] as f64 - v;
            let dy = f.pixels[(y + 2) * w + x] as f64 - v;
            g += dx * dx + dy * dy;
            s += v;
            n += 1.0;
        }
    }
    g / n / (s / n).powi(2)
}

#[test]
fn each_cell_is_sharpest_where_the_feeder_brings_the_floor_under_it_into_focus() {
    // Three 24 um cells along x, 0.9 mm apart, on a floor tilted 8 um/mm along x and
    // bowed: their foci lie microns apart.
    let plate = Plate {
        rows: 1,
        cols: 3,
        pitch: 0.9e-3,
        origin: [-0.9e-3, 0.0],
        cells: (0..3)
            .map(|c| Object {
                well: [0, c],
                offset: [0.0; 2],
                diameter: 24e-6,
            })
            .collect(),
        debris: Vec::new(),
    };
    let surface = PlateSurface {
        centre: [0.0, 0.0],
        tilt: [8e-3, 1e-3],
        curvature: 2.0,
        extent: [-1.4e-3, -0.5e-3, 1.4e-3, 0.5e-3],
    };
    let mut cam = Microscope::new(
        CameraParams::default(),
        LensParams::default(),
        OpticsSetup::default(),
        Scene::from_plate(&plate, 3),
    );
    cam.set_zoom(2.5).unwrap();
    cam.set_surface(surface);
    // The pipette far out of view.
    let away = TipPose {
        z: -1.0,
        ..TipPose::default()
    };
    let zs: Vec<f64> = (0..=80).map(|k| -10e-6 + k as f64 * 0.25e-6).collect();
    let mut curves = vec![Vec::new(); 3];
    let mut frame = Frame::default();
    for (n, &z) in zs.iter().enumerate() {
        cam.set_plate_offset([0.0, 0.0, z]);
        cam.render(&away, 0.0, n as u64, 1, &mut frame);
        let g = cam.grid();
        for (c, curve) in curves.iter_mut().enumerate() {
            let p = plate.centre(&plate.cells[c]);
            let i = ((p[0] - g.x0) / g.pitch).round() as usize;
            let j = ((p[1] - g.z0) / g.pitch).round() as usize;
            curve.push(sharpness(&frame, i, j, 20));
        }
    }
    let mut best = Vec::new();
    for (c, curve) in curves.iter().enumerate() {
        let k = (0..zs.len())
            .max_by(|&a, &b| curve[a].total_cmp(&curve[b]))
            .unwrap();
        let p = plate.centre(&plate.cells[c]);
        // In focus where the feeder lowers the plate by the floor's height there.
        let want = -surface.height(p);
        assert!(
            (zs[k] - want).abs() <= 0.5e-6,
            "cell {c}: sharpest at {:.2} um, its floor is {:.2} um up",
            zs[k] * 1e6,
            -want * 1e6
        );
        // Not flat: defocus matters.
        let lo = curve.iter().cloned().fold(f64::INFINITY, f64::min);
        assert!(curve[k] > 1.3 * lo, "cell {c}: {curve:?}");
        best.push(zs[k]);
    }
    // The foci differ by the tilt: 0.9 mm at 8 um/mm is 7.2 um.
    assert!(
        (best[2] - best[0] + 2.0 * 8e-3 * 0.9e-3).abs() < 0.75e-6,
        "{best:?}"
    );
}
