//! The part of the microscope's view where the workflow can find and reach cells, in
//! stage coordinates: the input of `cellinject_plate::fields::plan` (issue 21).
//!
//! The window is the largest rectangle aligned with the stage's axes inside the image
//! region the workflow uses, mapped through the image-to-stage map: the frame less a
//! margin at the left, right and bottom edges (a cell must be whole in view, with its
//! blur) and less a band at the top (the pipette comes in from the top of the image,
//! and the tip finder needs that much of it in view above the top row).

use cellinject_plate::fields::Window;

use super::ImageMap;

/// The window of a `width × height` pixel frame under `map`: `margin` m kept clear of
/// the left, right and bottom edges, `top_band` m of the top. `None` when nothing is
/// left (a margin or band larger than the frame).
pub fn window(map: &ImageMap, size_px: [f64; 2], top_band: f64, margin: f64) -> Option<Window> {
    let p = map.pixel_size;
    if !(p.is_finite() && p > 0.0) {
        return None;
    }
    let (m, band) = (margin / p, top_band / p);
    let (left, right) = (m, size_px[0] - 1.0 - m);
    let (top, bottom) = (band, size_px[1] - 1.0 - m);
    if right <= left || bottom <= top {
        return None;
    }
    // The region's corners on the stage. Along each stage axis the rectangle lies
    // between the inner two of the four corners: that holds for a small rotation of
    // the image against the stage, and for mirrored axes.
    let corners =
        [[left, top], [right, top], [left, bottom], [right, bottom]].map(|c| map.stage_of(c));
    let mut lo = [0.0; 2];
    let mut hi = [0.0; 2];
    for a in 0..2 {
        // The image's two sides across this axis: which corners form each side depends
        // on the map's orientation, so pair the corners by the pixel side they lie on.
        let side = |px_side: &[usize]| -> [f64; 2] {
            let s: Vec<f64> = px_side.iter().map(|&k| corners[k][a]).collect();
            [s[0].min(s[1]), s[0].max(s[1])]
        };
        // The pixel axis that runs mostly along this stage axis.
        let along_cols =
            (corners[1][a] - corners[0][a]).abs() >= (corners[2][a] - corners[0][a]).abs();
        let (first, second) = if along_cols {
            (side(&[0, 2]), side(&[1, 3]))
        } else {
            (side(&[0, 1]), side(&[2, 3]))
        };
        // The side at lower stage coordinates gives the rectangle's low edge (its
        // larger corner), the other its high edge (its smaller corner).
        let (low_side, high_side) = if first[0] + first[1] <= second[0] + second[1] {
            (first, second)
        } else {
            (second, first)
        };
        lo[a] = low_side[1];
        hi[a] = high_side[0];
        if hi[a] <= lo[a] {
            return None;
        }
    }
    Some(Window {
        centre: [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])],
        size: [hi[0] - lo[0], hi[1] - lo[1]],
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use proptest::prelude::*;

    fn map(pixel: f64, angle: f64, flip_x: bool) -> ImageMap {
        let (c, s) = (angle.cos() / pixel, angle.sin() / pixel);
        let fx = if flip_x { -1.0 } else { 1.0 };
        ImageMap {
            pixel0: [1296.0, 972.0],
            stage0: [0.0, 30e-6],
            b: [[fx * c, -s], [fx * s, c]],
            residual_px: 0.0,
            a1: [0.0; 2],
            a3: [0.0; 2],
            pixel_size: pixel,
        }
    }

    #[test]
    fn an_aligned_map_gives_the_frame_less_its_margins() {
        // 2592 x 1944 px at 0.88 µm: 2.28 x 1.71 mm.
        let p = 0.88e-6;
        let w = window(&map(p, 0.0, false), [2592.0, 1944.0], 200e-6, 10e-6).unwrap();
        let width = 2591.0 * p - 20e-6;
        let height = 1943.0 * p - 210e-6;
        assert!((w.size[0] - width).abs() < 1e-12, "{w:?}");
        assert!((w.size[1] - height).abs() < 1e-12, "{w:?}");
        // The band is at the top (small rows, small z): the centre moves down by half
        // of band minus margin.
        assert!((w.centre[1] - (30e-6 + (0.5 * 1943.0 - 972.0) * p + 95e-6)).abs() < 1e-12);
        assert!(window(&map(p, 0.0, false), [2592.0, 1944.0], 2e-3, 10e-6).is_none());
    }

    proptest! {
        #[test]
        fn the_window_lies_inside_the_usable_region_of_the_image(
            angle in -0.05f64..0.05, flip in any::<bool>(), p in 0.2e-6f64..1e-6,
            band in 0.0f64..300e-6, margin in 0.0f64..50e-6,
        ) {
            let m = map(p, angle, flip);
            let size = [2592.0, 1944.0];
            let w = window(&m, size, band, margin).unwrap();
            for dx in [-0.5, 0.5] {
                for dy in [-0.5, 0.5] {
                    let s = [w.centre[0] + dx * w.size[0], w.centre[1] + dy * w.size[1]];
                    let px = m.pixel_of(s);
                    let eps = 1e-6;
                    prop_assert!(px[0] >= margin / p - eps && px[0] <= size[0] - 1.0 - margin / p + eps, "{px:?}");
                    prop_assert!(px[1] >= band / p - eps && px[1] <= size[1] - 1.0 - margin / p + eps, "{px:?}");
                }
            }
            // And it is nearly all of it: a rotation of θ costs about θ times the
            // other side.
            let full = [(size[0] - 1.0) * p - 2.0 * margin, (size[1] - 1.0) * p - band - margin];
            let loss = angle.abs() * (full[0] + full[1]);
            prop_assert!(w.size[0] >= full[0] - loss - 1e-9 && w.size[1] >= full[1] - loss - 1e-9);
        }
    }
}
