//! Rendered top views of a pulled glass pipette, with the tip where the caller puts it:
//! the images [`crate::tip::find_tip`] is tested on (no photograph of a pipette can be
//! committed here), and `docs/vision.md`'s example.
//!
//! The tube's outer radius is 0.5 µm at the tip and grows by 0.12 of the distance
//! behind it (a glass lying in the image plane); its walls (the outer third of the
//! radius) are darker than its lumen; every edge, the tip's end included, is blurred
//! by a Gaussian of the optics' blur, so that its last micrometres, thinner than a
//! pixel or two, are faint. The twin's camera draws its pipette so
//! (`cellinject_twin`'s `render_pipette`). The background is lit unevenly (a ramp across the frame) and the
//! camera adds Gaussian noise. Pure computation: numbers in, pixels out.

use cellinject_numeric::Rng;

/// What a rendered frame shows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PipetteScene {
    /// Pixels across.
    pub width: usize,
    /// Pixels down.
    pub height: usize,
    /// m per pixel in the object plane.
    pub pixel_size: f64,
    /// Pixels, (column, row) of the tip; `None` renders no pipette.
    pub tip: Option<[f64; 2]>,
    /// rad, the axis from the tip towards the shank (`atan2(dy, dx)`, y down).
    pub axis_rad: f64,
    /// Pixels, the optics' blur (a Gaussian's σ).
    pub blur: f64,
    /// Grey levels of the background at the frame's centre.
    pub level: f64,
    /// Share of `level` the illumination changes by from one side of the frame to
    /// the other (along x; half that along y).
    pub ramp: f64,
    /// Grey levels, the camera noise's σ.
    pub noise: f64,
    /// A dark round cell of this diameter (pixels) at this (column, row), if any.
    pub cell: Option<([f64; 2], f64)>,
}

impl PipetteScene {
    /// A 12-bit frame `width` x `height` at `pixel_size` with the tip at `tip` and
    /// the axis at `axis_rad`: blur 0.6 px, level 2000, a 10 % ramp, noise of 30
    /// grey levels, no cell.
    pub fn new(width: usize, height: usize, pixel_size: f64, tip: [f64; 2], axis_rad: f64) -> Self {
        PipetteScene {
            width,
            height,
            pixel_size,
            tip: Some(tip),
            axis_rad,
            blur: 0.6,
            level: 2000.0,
            ramp: 0.1,
            noise: 30.0,
            cell: None,
        }
    }

    /// The frame, row by row, its noise drawn from `seed`.
    pub fn render(&self, seed: u64) -> Vec<u16> {
        let mut rng = Rng::new(seed, 0x7069_7065);
        let (w, h) = (self.width, self.height);
        let phi = |u: f64| 0.5 * (1.0 + cellinject_numeric::erf(u / std::f64::consts::SQRT_2));
        let sigma = self.blur.max(1e-3);
        let (ax, ay) = (self.axis_rad.cos(), self.axis_rad.sin());
        let um = 1e-6 / self.pixel_size;
        let mut out = Vec::with_capacity(w * h);
        for j in 0..h {
            for i in 0..w {
                let (x, y) = (i as f64, j as f64);
                let mut dark = 0.0;
                if let Some([tx, ty]) = self.tip {
                    // Behind the tip along the shank, and across the axis.
                    let behind = (x - tx) * ax + (y - ty) * ay;
                    let across = ((x - tx) * -ay + (y - ty) * ax).abs();
                    let r = 0.5 * um + 0.12 * behind.max(0.0);
                    let outer = phi((r - across) / sigma);
                    let inner = phi((0.65 * r - across) / sigma);
                    let end = phi(behind / sigma);
                    dark += end * (0.12 * outer + 0.45 * (outer - inner));
                }
                if let Some(([cx, cy], d)) = self.cell {
                    let r = (x - cx).hypot(y - cy);
                    dark += 0.3 * phi((0.5 * d - r) / sigma);
                }
                let light = self.level
                    * (1.0
                        + self.ramp * (x / w as f64 - 0.5)
                        + 0.5 * self.ramp * (y / h as f64 - 0.5));
                let v = light * (1.0 - dark.min(1.0)) + self.noise * rng.gaussian();
                out.push(v.round().clamp(0.0, f64::from(u16::MAX)) as u16);
            }
        }
        out
    }
}
