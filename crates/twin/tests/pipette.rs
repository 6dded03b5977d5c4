//! The pipette mounted at an angle to the plate: A3 drives the tip down its axis, the
//! microscope sees the glass foreshortened and the side camera sees it at its angle,
//! the glass behind the tip pushes aside the cells it runs into, and a tip driven into
//! the floor breaks.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use cellinject_hw::{Clock, Frame, PiezoChannel};
use cellinject_model::prototype;
use cellinject_numeric::Rng;
use cellinject_rig::PipetteParams;
use cellinject_rig::params::OpticsSetup;
use cellinject_twin::params::{CameraParams, CellBiology, LensParams};
use cellinject_twin::scene::Scene;
use cellinject_twin::{Biology, Microscope, PipetteView, TipPose, Twin, TwinParams, rig};

#[test]
fn a3_drives_the_tip_down_the_pipettes_axis() {
    for deg in [30.0f64, 45.0, 60.0] {
        let mut p = TwinParams::default();
        p.rig.pipette.angle = deg.to_radians();
        let t = Twin::new(&prototype(), p).unwrap().into_shared();
        let mut dev = rig(&t).unwrap();
        let before = t.lock().unwrap().tip();
        let s0 = t.lock().unwrap().world.snapshot();
        dev.piezo[2].set_voltage(50.0).unwrap();
        dev.clock.sleep(0.2).unwrap();
        let after = t.lock().unwrap().tip();
        let s1 = t.lock().unwrap().world.snapshot();
        let e = s1.x[2] - s0.x[2];
        assert!(e > 10e-6, "A3 moved {e}");
        let (sin, cos) = deg.to_radians().sin_cos();
        // Forward along the plate and down, by the stack's motion (A1 and A2 held
        // at rest move the tip by their noise only).
        let dx1 = s1.x[1] - s0.x[1];
        assert!(dx1.abs() < 0.05e-6, "{dx1}");
        assert!(((after.z - before.z) - e * cos).abs() < 1e-12, "{deg}");
        assert!(
            ((after.depth - before.depth) - (dx1 - e * sin)).abs() < 1e-12,
            "{deg}"
        );
        assert!((after.x - before.x - (s1.x[0] - s0.x[0])).abs() < 1e-12);
    }
}

/// The glass alone, as the camera draws it: a frame with the tip at `pose` divided by
/// the same frame (same noise) with the pipette out of view, as darkness `1 - a/b`.
fn glass(cam: &mut Microscope, pose: &TipPose) -> (Vec<f64>, cellinject_twin::Grid) {
    let (mut a, mut b) = (Frame::default(), Frame::default());
    cam.render(pose, 0.0, 7, 1, &mut a);
    let away = TipPose { z: -1.0, ..*pose };
    cam.render(&away, 0.0, 7, 1, &mut b);
    let d = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .map(|(&x, &y)| 1.0 - x as f64 / (y as f64).max(1.0))
        .collect();
    (d, cam.grid())
}

fn microscope(scene: Scene, zoom: f64) -> Microscope {
    let mut m = Microscope::new(
        CameraParams::default(),
        LensParams::default(),
        OpticsSetup::default(),
        scene,
    );
    m.set_zoom(zoom).unwrap();
    m
}

#[test]
fn the_microscope_sees_the_glass_foreshortened_and_the_side_camera_at_its_angle() {
    let pipette = PipetteParams::default();
    let pose = TipPose::default();
    // Top view: the darkness summed across each row grows with the glass's radius,
    // which grows by the taper per metre of glass: per metre of image, by the taper
    // over the cosine of the angle (the glass rises out of focus too, but summing
    // across the row keeps all the darkness the blur spreads).
    let slope = |angle: f64| {
        let mut cam = microscope(Scene::side(3), 10.0);
        cam.set_pipette(PipetteView::new(
            &pipette,
            [0.0, -1.0],
            angle.cos(),
            angle.sin(),
        ));
        let (d, g) = glass(&mut cam, &pose);
        let row_sum = |behind: f64| {
            let j = ((pose.z - behind - g.z0) / g.pitch).round() as usize;
            d[j * g.width..(j + 1) * g.width].iter().sum::<f64>() * g.pitch
        };
        (row_sum(60e-6) - row_sum(20e-6)) / 40e-6
    };
    let ratio = slope(45f64.to_radians()) / slope(0.0);
    assert!(
        (ratio - 2f64.sqrt()).abs() < 0.05 * 2f64.sqrt(),
        "foreshortening ratio {ratio}"
    );
    // Side view: the glass's dark pixels near the tip lie along a line at the mount
    // angle to the image's rows.
    for deg in [30.0f64, 45.0, 60.0] {
        let a = deg.to_radians();
        let mut cam = microscope(Scene::side(3), 10.0);
        cam.set_pipette(PipetteView::new(&pipette, [a.sin(), -a.cos()], 1.0, 0.0));
        let (d, g) = glass(&mut cam, &pose);
        let (mut n, mut sx, mut sz, mut sxx, mut sxz, mut szz) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for j in 0..g.height {
            for i in 0..g.width {
                let (x, z) = (g.x0 + i as f64 * g.pitch, g.z0 + j as f64 * g.pitch);
                let r = (x - pose.x).hypot(z - pose.z);
                if d[j * g.width + i] > 0.2 && r < 60e-6 && r > 5e-6 {
                    n += 1.0;
                    (sx, sz) = (sx + x, sz + z);
                    (sxx, sxz, szz) = (sxx + x * x, sxz + x * z, szz + z * z);
                }
            }
        }
        assert!(n > 50.0, "{n} glass pixels");
        let (cx, cz) = (sx / n, sz / n);
        let (vxx, vxz, vzz) = (sxx / n - cx * cx, sxz / n - cx * cz, szz / n - cz * cz);
        // Principal axis angle from the rows' direction (z).
        let theta = 0.5 * (2.0 * vxz).atan2(vzz - vxx);
        assert!(
            (theta.abs() - a).abs() < 1.5f64.to_radians(),
            "{deg} deg: the side camera sees {} deg",
            theta.abs().to_degrees()
        );
    }
}

fn biology(pipette: PipetteParams, cells: &[([f64; 2], f64)]) -> Biology {
    let mut rng = Rng::new(1, 99);
    Biology::new(
        CellBiology::default(),
        pipette,
        cells.iter().copied(),
        &mut rng,
    )
}

#[test]
fn the_glass_behind_the_tip_pushes_aside_the_cells_it_runs_into_and_only_those() {
    // A 10 um target at the origin and a partner touching it straight behind the
    // approach, of several sizes. The tip goes down the axis to the target's centre;
    // the partner is grazed exactly when the glass (at the deepest point) overlaps it.
    let p = PipetteParams::default();
    let ax = p.axis();
    let mut seen = [0; 2];
    for rn in [4e-6f64, 8e-6, 12e-6, 16e-6, 20e-6] {
        let rt = 5e-6f64;
        let mean = 0.5 * (rt + rn);
        let floor = -mean;
        let (ht, hn) = (floor + rt, floor + rn);
        let horizontal = ((rt + rn) * (rt + rn) - (hn - ht) * (hn - ht)).sqrt();
        let mut b = biology(p, &[([0.0, 0.0], rt), ([0.0, -horizontal], rn)]);
        assert_eq!(b.floor, floor);
        let aim = [0.0, ht, 0.0];
        let expect = p.clearance(aim, ax, [0.0, hn, -horizontal], rn) < 0.0;
        for k in 0..=400 {
            let t = -(rt + 6e-6) * (1.0 - k as f64 / 400.0);
            b.interact(&TipPose {
                x: aim[0] + t * ax[0],
                depth: aim[1] + t * ax[1],
                z: aim[2] + t * ax[2],
                ..TipPose::default()
            });
        }
        assert!(b.cells[0].punctures == 1, "the target is entered");
        assert_eq!(b.cells[1].grazed, expect, "partner of radius {rn}");
        if expect {
            // Pushed away from the axis, along the plate.
            assert!(b.cells[1].push[1] < 0.0, "{:?}", b.cells[1].push);
        }
        seen[expect as usize] += 1;
    }
    assert!(seen[0] > 0 && seen[1] > 0, "{seen:?}");
}

#[test]
fn a_tip_driven_into_the_floor_breaks_once_per_strike() {
    let p = PipetteParams::default();
    let mut b = biology(p, &[([0.0, 0.0], 8e-6)]);
    let at = |d: f64| TipPose {
        x: 100e-6,
        depth: d,
        ..TipPose::default()
    };
    for d in [0.0, -7.9e-6, -8.1e-6, -8.5e-6, -7.5e-6, -8.2e-6] {
        b.interact(&at(d));
    }
    assert_eq!(b.floor_strikes, 1, "bouncing on the floor is one strike");
    assert!((b.tip_loss - 2e-6).abs() < 1e-12 && b.flow > 1.0);
    b.interact(&at(0.0));
    b.interact(&at(-9e-6));
    assert_eq!(b.floor_strikes, 2);
}
