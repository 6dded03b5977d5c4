//! The tip finder on rendered pipettes ([`cellinject_cells::pipette`]) entering the
//! frame at every orientation, with the optics' blur, an illumination ramp and camera
//! noise; and frames with no pipette (bare, or a cell alone), which must say so.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use cellinject_cells::CellsError;
use cellinject_cells::pipette::PipetteScene;
use cellinject_cells::tip::find_tip;

/// m per pixel: the prototype's camera at 10x (3.45 µm pixels).
const PIXEL: f64 = 0.345e-6;

/// Sixteen orientations, 22.5° apart, each with its tip at two places near the
/// frame's centre (seeded noise), at the prototype's 10x and at 0.88 µm/px (the tip
/// then thinner than a pixel): the tip within 1 px at the median and 3 px at worst,
/// the axis within 2°, the width 5 µm behind the tip within 1 px of the rendered
/// tube's there (its darkness's full width at half height, blur included), the
/// confidence at least 0.8.
#[test]
fn the_tip_is_found_at_every_orientation() {
    for pixel in [PIXEL, 0.88e-6] {
        orientations(pixel);
    }
}

fn orientations(pixel: f64) {
    let (w, h) = (320usize, 240usize);
    let mut errors = Vec::new();
    for k in 0..16 {
        let theta = k as f64 * std::f64::consts::PI / 8.0;
        for (m, jitter) in [(0.0, 0.0), (7.3, -5.6)].into_iter().enumerate() {
            let tip = [0.5 * w as f64 + jitter.0, 0.5 * h as f64 + jitter.1];
            let scene = PipetteScene::new(w, h, pixel, tip, theta);
            let px = scene.render(100 + 2 * k as u64 + m as u64);
            let found = find_tip(&px, w, h, pixel)
                .unwrap_or_else(|e| panic!("{:.1}°: {e}", theta.to_degrees()));
            let e = (found.x - tip[0]).hypot(found.y - tip[1]);
            errors.push(e);
            let turn = (found.axis_rad - theta + std::f64::consts::PI)
                .rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            assert!(
                turn.abs() < 2f64.to_radians(),
                "{:.1}°: axis {:.2}°",
                theta.to_degrees(),
                found.axis_rad.to_degrees()
            );
            let truth = rendered_width(0.5e-6 + 0.12 * 5e-6, pixel, scene.blur);
            assert!(
                (found.width - truth).abs() < 1.0,
                "{:.1}°: width {:.2} px, the rendered tube's {truth:.2} px",
                theta.to_degrees(),
                found.width
            );
            assert!(
                found.confidence >= 0.8,
                "{:.1}°: {found:?}",
                theta.to_degrees()
            );
        }
    }
    let mut sorted = errors.clone();
    sorted.sort_by(f64::total_cmp);
    let median = 0.5 * (sorted[15] + sorted[16]);
    let worst = sorted[31];
    eprintln!(
        "{:.3} µm/px: tip error over 32 frames median {median:.2} px, worst {worst:.2} px",
        pixel * 1e6
    );
    assert!(median <= 1.0, "median {median:.2} px: {errors:?}");
    assert!(worst <= 3.0, "worst {worst:.2} px: {errors:?}");
}

/// Pixels, the full width at half its highest of the rendered tube's darkness across
/// its axis where its outer radius is `radius` (m), blurred by `blur` px: the walls'
/// and the lumen's darkness as [`PipetteScene::render`] draws them, evaluated on a
/// hundredth of a pixel.
fn rendered_width(radius: f64, pixel: f64, blur: f64) -> f64 {
    let phi = |u: f64| 0.5 * (1.0 + cellinject_numeric::erf(u / std::f64::consts::SQRT_2));
    let r = radius / pixel;
    let dark = |o: f64| {
        let (outer, inner) = (phi((r - o.abs()) / blur), phi((0.65 * r - o.abs()) / blur));
        0.12 * outer + 0.45 * (outer - inner)
    };
    let xs: Vec<f64> = (0..=2000).map(|k| -10.0 + k as f64 * 0.01).collect();
    let top = xs.iter().map(|&o| dark(o)).fold(0.0f64, f64::max);
    let inside: Vec<f64> = xs.into_iter().filter(|&o| dark(o) >= 0.5 * top).collect();
    inside[inside.len() - 1] - inside[0]
}

/// A pipette entering from the top with its tip 10-25 px from a side edge (its tube,
/// widening behind the tip, is cut along that edge for most of its length): the tip is
/// where the tube ends, within a pixel, not on the top edge (it was found there with
/// a confidence of 1); a tube running on out of the frame has no tip in view. (At
/// 8 px the cut tube's end along the side edge is taken for the tip.)
#[test]
fn a_tip_near_a_side_edge_is_found_and_one_out_of_the_frame_is_not() {
    let (w, h) = (320usize, 240usize);
    for x0 in [11.0, 15.0, 20.0, 25.0, 295.0, 300.0, 305.0, 310.0] {
        let tip = [x0, 150.0];
        let scene = PipetteScene::new(w, h, PIXEL, tip, -std::f64::consts::FRAC_PI_2);
        let t =
            find_tip(&scene.render(5), w, h, PIXEL).unwrap_or_else(|e| panic!("tip at {x0}: {e}"));
        assert!(
            (t.x - tip[0]).hypot(t.y - tip[1]) < 1.0,
            "tip at {x0}: found ({:.1}, {:.1})",
            t.x,
            t.y
        );
    }
    let scene = PipetteScene::new(w, h, PIXEL, [160.0, 300.0], -std::f64::consts::FRAC_PI_2);
    assert_eq!(
        find_tip(&scene.render(6), w, h, PIXEL),
        Err(CellsError::NoPipette)
    );
}

/// A pixel size that makes the locator's 60 µm under 8 px or over twice the frame is
/// refused (it ran for minutes at 1e-12 m).
#[test]
fn a_pixel_size_out_of_scale_is_refused() {
    let (w, h) = (320usize, 240usize);
    let px = PipetteScene::new(w, h, PIXEL, [160.0, 120.0], 1.0).render(7);
    for p in [1e-12, 5e-8, 1e-5, 1.0] {
        assert!(
            matches!(
                find_tip(&px, w, h, p),
                Err(CellsError::Invalid {
                    what: "pixel_size",
                    ..
                })
            ),
            "{p}"
        );
    }
}

/// A bare frame (ramp and noise) and a frame with a cell alone: no pipette.
#[test]
fn a_frame_without_a_pipette_says_so() {
    let (w, h) = (320usize, 240usize);
    let mut scene = PipetteScene::new(w, h, PIXEL, [0.0, 0.0], 0.0);
    scene.tip = None;
    assert_eq!(
        find_tip(&scene.render(1), w, h, PIXEL),
        Err(CellsError::NoPipette)
    );
    scene.cell = Some(([150.0, 110.0], 45.0));
    assert_eq!(
        find_tip(&scene.render(2), w, h, PIXEL),
        Err(CellsError::NoPipette)
    );
}
