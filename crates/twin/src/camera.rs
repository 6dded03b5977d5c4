//! The microscope camera: renders what the sensor sees from the twin's true state.
//!
//! Brightfield image formation in the object plane: a vignetted background multiplied by
//! the transmission of every object (cells, debris, feeder walls, pipette, marker tab,
//! speckles). Every object has an analytic profile blurred by a Gaussian whose variance
//! is the optics' blur (focus blur plus defocus for the pipette's distance from the focal
//! plane), the pixel's box integration (`pitch²/12`) and, for moving objects, the motion
//! during the exposure (`(v·T)²/12` per axis). Then the sensor: signal electrons
//! proportional to exposure, shot noise, read noise, saturation at full well, 8- or
//! 12-bit quantisation. Binning sums `b x b` sensor pixels (read noise `b·σ_read`).
//!
//! The static part (background, feeder, cells, debris) depends only on the pixel grid
//! and is rendered once per camera configuration; each frame copies it and draws the
//! moving pipette over it, so a frame costs little more than its noise.

use std::sync::OnceLock;

use cellinject_hw::{CameraSettings, Frame, HwError, Roi, check_range};

use cellinject_rig::params::OpticsSetup;

use crate::params::{CameraParams, LensParams};
use crate::scene::Scene;
use crate::surface::PlateSurface;
use crate::world::stream;
use cellinject_numeric::Rng;

/// Object point at the centre of the sensor, relative to the tip's aligned position (x, z), m.
pub const VIEW_CENTER: [f64; 2] = [0.0, 30e-6];

/// Where the end-effector (pipette tip) is during an exposure, in the object plane.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TipPose {
    /// m, mean position along the image columns.
    pub x: f64,
    /// m, mean position along the image rows.
    pub z: f64,
    /// m, distance from the focal plane (along the optical axis).
    pub depth: f64,
    /// m/s, velocity along x during the exposure.
    pub vx: f64,
    /// m/s, velocity along z during the exposure.
    pub vz: f64,
}

/// How a cell looks now, when it differs from the scene's resting cell: pushed or
/// moved, swollen by an injection, darkened by the dye, or dead.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CellLook {
    /// m, displacement of the centre (x, z).
    pub offset: [f64; 2],
    /// Radius over the resting radius.
    pub scale: f64,
    /// Extra darkening of the cytoplasm by the injected dye.
    pub dye: f64,
    /// Lysed: the cell's contrast fades and its membrane ring breaks up.
    pub dead: bool,
}

/// How much a cell of the scene darkens the point (dx, dz) from its resting centre
/// (the factor the background is multiplied by), as it looks now.
fn cell_factor(
    c: &crate::scene::Cell,
    look: &CellLook,
    dx: f64,
    dz: f64,
    sigma: f64,
    ring: (f64, f32),
) -> f32 {
    let (ring_w2, ring_gain) = ring;
    let (dx, dz) = (dx - look.offset[0], dz - look.offset[1]);
    let radius = c.radius * look.scale;
    let rho = (dx * dx + dz * dz).sqrt();
    let nx = dx - c.nucleus[0] * look.scale;
    let nz = dz - c.nucleus[1] * look.scale;
    let rn = (nx * nx + nz * nz).sqrt();
    let inside = step(((radius - rho) / sigma) as f32);
    let ring = (-(rho - radius).powi(2) / ring_w2).exp() as f32;
    let nucleus = step(((c.nucleus_radius - rn) as f32) / sigma as f32);
    let (k_in, k_ring, k_nuc) = if look.dead {
        (0.35, 0.3, 0.5)
    } else {
        (1.0, 1.0, 1.0)
    };
    1.0 - (0.10 + look.dye as f32) * k_in * inside
        - 0.32 * ring_gain * k_ring * ring
        - 0.22 * k_nuc * nucleus
}

const REST: CellLook = CellLook {
    offset: [0.0, 0.0],
    scale: 1.0,
    dye: 0.0,
    dead: false,
};

/// The output pixel grid in the object plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    /// m, object x of the centre of output pixel (0, 0).
    pub x0: f64,
    /// m, object z of the centre of output pixel (0, 0).
    pub z0: f64,
    /// m, object-plane size of one output pixel.
    pub pitch: f64,
    /// Output columns.
    pub width: usize,
    /// Output rows.
    pub height: usize,
    /// Binning factor.
    pub binning: u32,
}

/// Standard normal CDF Φ, tabulated on [−8, 8].
fn phi_table() -> &'static [f32] {
    static T: OnceLock<Vec<f32>> = OnceLock::new();
    T.get_or_init(|| {
        (0..=PHI_N)
            .map(|i| {
                let u = -PHI_RANGE + 2.0 * PHI_RANGE * i as f64 / PHI_N as f64;
                cellinject_numeric::normal_cdf(u) as f32
            })
            .collect()
    })
}
const PHI_N: usize = 8192;
const PHI_RANGE: f64 = 8.0;

/// Φ(u), a smooth step of unit width.
#[inline]
fn step(u: f32) -> f32 {
    let t = phi_table();
    let s = (u + PHI_RANGE as f32) * (PHI_N as f32 / (2.0 * PHI_RANGE as f32));
    if s <= 0.0 {
        return 0.0;
    }
    if s >= PHI_N as f32 {
        return 1.0;
    }
    let i = s as usize;
    let f = s - i as f32;
    t[i] + (t[i + 1] - t[i]) * f
}

/// Samples of a 1-D Gaussian `exp(−(c − center)² / 2σ²)` at the pixel centres `c0 + k·pitch`
/// for k in `[lo, hi)`, written into `out`.
fn gauss_row(
    out: &mut Vec<f32>,
    c0: f64,
    pitch: f64,
    lo: usize,
    hi: usize,
    center: f64,
    sigma: f64,
) {
    out.clear();
    let inv = 1.0 / (2.0 * sigma * sigma);
    for k in lo..hi {
        let d = c0 + k as f64 * pitch - center;
        out.push((-d * d * inv).exp() as f32);
    }
}

/// Pixel range `[lo, hi)` of the grid axis covering `[a, b]` (object coordinates).
fn span(c0: f64, pitch: f64, n: usize, a: f64, b: f64) -> (usize, usize) {
    let lo = ((a - c0) / pitch).floor().max(0.0);
    let hi = ((b - c0) / pitch).ceil() + 1.0;
    let lo = (lo as usize).min(n);
    let hi = (hi.max(0.0) as usize).min(n);
    (lo, hi.max(lo))
}

/// The pipette's glass as one camera sees it: its outer shape (the rig's) and how its
/// axis lies to the camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PipetteView {
    /// m, outer radius at the tip.
    pub tip_radius: f64,
    /// Outer radius growth per metre behind the tip.
    pub taper: f64,
    /// m, outer radius of the shank.
    pub shank_radius: f64,
    /// Unit direction in the object plane (columns, rows) from the tip back along the
    /// glass; its row component must be negative (the glass comes from the top).
    pub back: [f64; 2],
    /// Image length per metre of glass (the cosine of its angle to the image plane).
    pub foreshortening: f64,
    /// Height gained towards the camera per metre of glass behind the tip.
    pub rise: f64,
}

impl PipetteView {
    /// The glass of `pipette` lying along `back` in the image, foreshortened by
    /// `foreshortening`, rising by `rise` per metre behind the tip.
    pub fn new(
        pipette: &cellinject_rig::PipetteParams,
        back: [f64; 2],
        foreshortening: f64,
        rise: f64,
    ) -> Self {
        PipetteView {
            tip_radius: pipette.tip_outer_radius,
            taper: pipette.outer_taper,
            shank_radius: pipette.shank_radius,
            back,
            foreshortening,
            rise,
        }
    }

    /// The scene's default shape, in the image plane along the rows.
    fn flat(shape: &crate::scene::PipetteShape) -> Self {
        PipetteView {
            tip_radius: shape.tip_radius,
            taper: shape.taper,
            shank_radius: shape.shank_radius,
            back: [0.0, -1.0],
            foreshortening: 1.0,
            rise: 0.0,
        }
    }
}

/// The zoom lens's state: magnification (the rig's) and blur (the simulation's).
#[derive(Debug, Clone, Copy)]
struct Lens {
    zoom: f64,
    zoom_range: [f64; 2],
    focus_blur: f64,
    defocus_rate: f64,
}

/// The camera behind the zoom lens.
#[derive(Debug, Clone)]
pub struct Microscope {
    params: CameraParams,
    optics: Lens,
    scene: Scene,
    settings: CameraSettings,
    static_grid: Option<Grid>,
    static_layer: Vec<f32>,
    work: Vec<f32>,
    scratch_x: Vec<f32>,
    scratch_z: Vec<f32>,
    /// Random stream of the sensor noise (each camera has its own).
    noise_stream: u64,
    /// Cells (indices into the scene's) that look different from their resting state.
    looks: Vec<(usize, CellLook)>,
    /// Frames still to come with the illumination off (a fault of the twin).
    dark_frames: u32,
    /// The magnification over its nominal value (thermal drift), in steps of
    /// [`SCALE_STEP`].
    scale: f64,
    /// m, where the feeder stage has moved the plate (object x, z, and depth along the
    /// optical axis): the plate's walls, cells and debris are drawn this far from the
    /// scene's positions, defocused by the depth.
    plate_offset: [f64; 3],
    /// How the pipette's glass lies in this view.
    pipette: PipetteView,
    /// The plate's floor: each feature is defocused by its own height.
    surface: PlateSurface,
}

/// Resolution of the magnification's thermal drift: the static layer is drawn again
/// when the magnification has changed by this much (at most 0.0013 px at the edge of a
/// 2592-pixel frame).
pub const SCALE_STEP: f64 = 1e-6;

impl Microscope {
    /// A camera at full resolution with the default exposure, behind a lens set up as
    /// `optics` that blurs as `lens` says.
    pub fn new(params: CameraParams, lens: LensParams, optics: OpticsSetup, scene: Scene) -> Self {
        let optics = Lens {
            zoom: optics.zoom,
            zoom_range: optics.zoom_range,
            focus_blur: lens.focus_blur,
            defocus_rate: lens.defocus_rate,
        };
        Microscope {
            pipette: PipetteView::flat(&scene.pipette),
            settings: CameraSettings {
                roi: Roi {
                    x: 0,
                    y: 0,
                    width: params.width,
                    height: params.height,
                },
                binning: 1,
                exposure: params.exposure,
                bit_depth: params.bit_depth,
            },
            params,
            optics,
            scene,
            static_grid: None,
            static_layer: Vec::new(),
            work: Vec::new(),
            scratch_x: Vec::new(),
            scratch_z: Vec::new(),
            noise_stream: stream::CAMERA,
            looks: Vec::new(),
            dark_frames: 0,
            scale: 1.0,
            plate_offset: [0.0; 3],
            surface: PlateSurface::FLAT,
        }
    }

    /// The plate's floor (tilted and bowed): each cell, wall and particle is
    /// defocused by its own height; the static layer is drawn again.
    pub fn set_surface(&mut self, surface: PlateSurface) {
        if surface != self.surface {
            self.surface = surface;
            self.static_grid = None;
        }
    }

    /// The plate moved by the feeder stage to `offset` (m: object x, z, and depth
    /// from the focal plane) from the scene's positions; the static layer is drawn
    /// again when it changed.
    pub fn set_plate_offset(&mut self, offset: [f64; 3]) {
        if offset != self.plate_offset {
            self.plate_offset = offset;
            self.static_grid = None;
        }
    }

    /// Where the plate is drawn from the scene's positions, m.
    pub fn plate_offset(&self) -> [f64; 3] {
        self.plate_offset
    }

    /// The blur of the plate's features at plate point `at`, m: the lens's, plus its
    /// defocus rate times the floor's distance from the focal plane there (as the
    /// pipette's).
    fn plate_blur(&self, at: [f64; 2]) -> f64 {
        let depth = self.plate_offset[2] + self.surface.height(at);
        self.optics.focus_blur + self.optics.defocus_rate * depth.abs()
    }

    /// The membrane ring's contrast relative to in focus for a plate blur `blur`: a
    /// defocused ring spreads its darkness (a line's profile keeps its integral), 1
    /// exactly in focus.
    fn ring_gain(&self, blur: f64) -> f32 {
        let (w, f) = (0.5e-6f64, self.optics.focus_blur);
        ((w * w + f * f) / (w * w + blur * blur)).sqrt() as f32
    }

    /// Squared blur of the plate at `at` on grid `g` (the pixels' own width
    /// included), its square root, and the membrane ring's width and gain.
    fn plate_sigma(&self, g: &Grid, at: [f64; 2]) -> (f64, f64, (f64, f32)) {
        let b = self.plate_blur(at);
        let blur2 = b * b + g.pitch * g.pitch / 12.0;
        let ring = (2.0 * (0.5e-6f64.powi(2) + blur2), self.ring_gain(b));
        (blur2, blur2.sqrt(), ring)
    }

    /// The grid `g` in the plate's frame: the scene's plate positions map onto it.
    fn plate_grid(&self, g: &Grid) -> Grid {
        Grid {
            x0: g.x0 - self.plate_offset[0],
            z0: g.z0 - self.plate_offset[1],
            ..*g
        }
    }

    /// The lens's magnification drifted by `relative` of its nominal value (temperature):
    /// things look `1 + relative` times larger while the frames still report the
    /// nominal pixel size, as a real camera does. Applied in steps of [`SCALE_STEP`].
    pub fn set_magnification_drift(&mut self, relative: f64) {
        let scale = 1.0 + (relative / SCALE_STEP).round() * SCALE_STEP;
        if scale.is_finite() && scale > 0.5 {
            self.scale = scale;
        }
    }

    /// The magnification over its nominal value (1 without drift).
    pub fn magnification_drift(&self) -> f64 {
        self.scale
    }

    /// How the cells that changed look now (index into the scene's cells, look); the
    /// others look as they rest. Drawn over the cached static layer each frame.
    pub fn set_cell_looks(&mut self, looks: &[(usize, CellLook)]) {
        self.looks.clear();
        self.looks.extend_from_slice(looks);
    }

    /// The next `frames` frames come with the illumination off (a fault: the tip and
    /// the cells cannot be seen).
    pub fn go_dark(&mut self, frames: u32) {
        self.dark_frames = frames;
    }

    /// How the pipette's glass lies in this view from now on.
    pub fn set_pipette(&mut self, view: PipetteView) {
        self.pipette = view;
    }

    /// Looks at another scene from now on (e.g. a plate file's).
    pub fn set_scene(&mut self, scene: Scene) {
        self.scene = scene;
        self.static_grid = None;
    }

    /// The same camera drawing its sensor noise from random stream `stream` (a second
    /// camera must not repeat the first one's noise).
    pub fn with_noise_stream(mut self, stream: u64) -> Self {
        self.noise_stream = stream;
        self
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Sensor parameters.
    pub fn params(&self) -> &CameraParams {
        &self.params
    }

    /// Current settings.
    pub fn settings(&self) -> CameraSettings {
        self.settings
    }

    /// Current magnification.
    pub fn zoom(&self) -> f64 {
        self.optics.zoom
    }

    /// Smallest and largest magnification.
    pub fn zoom_range(&self) -> (f64, f64) {
        (self.optics.zoom_range[0], self.optics.zoom_range[1])
    }

    /// Sets the magnification (within the lens's range).
    pub fn set_zoom(&mut self, zoom: f64) -> Result<(), HwError> {
        let [lo, hi] = self.optics.zoom_range;
        check_range("zoom", zoom, lo, hi)?;
        self.optics.zoom = zoom;
        self.static_grid = None;
        Ok(())
    }

    /// The VGA settings: 640x480 output, by 4x4 binning of the centre of the sensor
    /// (`binned`) or by cropping it at full resolution (`cellinject_hw::vga_settings`).
    pub fn vga_settings(&self, binned: bool) -> CameraSettings {
        cellinject_hw::vga_settings(
            (self.params.width, self.params.height),
            &self.settings,
            binned,
        )
    }

    /// Frames per second: the full-frame rate, or the VGA rate once the output has no
    /// more pixels than VGA.
    pub fn frame_rate_for(&self, s: &CameraSettings) -> f64 {
        let out = (s.roi.width / s.binning) as u64 * (s.roi.height / s.binning) as u64;
        if out <= 640 * 480 {
            self.params.fps_vga
        } else {
            self.params.fps_full
        }
    }

    /// Validates and applies settings.
    pub fn configure(&mut self, s: CameraSettings) -> Result<(), HwError> {
        if ![1, 2, 4].contains(&s.binning) {
            return Err(HwError::OutOfRange {
                what: "binning",
                value: s.binning as f64,
                min: 1.0,
                max: 4.0,
            });
        }
        if s.bit_depth != 8 && s.bit_depth != 12 {
            return Err(HwError::OutOfRange {
                what: "bit depth",
                value: s.bit_depth as f64,
                min: 8.0,
                max: 12.0,
            });
        }
        let r = s.roi;
        check_range(
            "roi width",
            r.width as f64,
            s.binning as f64,
            self.params.width as f64,
        )?;
        check_range(
            "roi height",
            r.height as f64,
            s.binning as f64,
            self.params.height as f64,
        )?;
        check_range(
            "roi x",
            r.x as f64,
            0.0,
            (self.params.width - r.width) as f64,
        )?;
        check_range(
            "roi y",
            r.y as f64,
            0.0,
            (self.params.height - r.height) as f64,
        )?;
        let period = 1.0 / self.frame_rate_for(&s);
        check_range("exposure", s.exposure, 1e-6, period)?;
        if s.roi != self.settings.roi || s.binning != self.settings.binning {
            self.static_grid = None;
        }
        self.settings = s;
        Ok(())
    }

    /// The output pixel grid of the current settings and zoom.
    pub fn grid(&self) -> Grid {
        let s = &self.settings;
        let b = s.binning as usize;
        let p = self.params.pixel_size / (self.optics.zoom * self.scale);
        let (w, h) = ((s.roi.width as usize) / b, (s.roi.height as usize) / b);
        // Centre of output pixel (0, 0) in sensor pixel units, relative to the sensor centre.
        let cx = s.roi.x as f64 + 0.5 * b as f64 - 0.5 * self.params.width as f64;
        let cy = s.roi.y as f64 + 0.5 * b as f64 - 0.5 * self.params.height as f64;
        Grid {
            x0: VIEW_CENTER[0] + cx * p,
            z0: VIEW_CENTER[1] + cy * p,
            pitch: p * b as f64,
            width: w,
            height: h,
            binning: s.binning,
        }
    }

    fn render_static(&mut self, g: &Grid) {
        let n = g.width * g.height;
        self.static_layer.clear();
        self.static_layer.resize(n, 0.0);
        // Background with vignetting, separable, normalised to the full sensor.
        let half_w = 0.5 * self.params.width as f64 * self.params.pixel_size / self.optics.zoom;
        let half_h = 0.5 * self.params.height as f64 * self.params.pixel_size / self.optics.zoom;
        let level = self.params.background_level as f32;
        let gx: Vec<f32> = (0..g.width)
            .map(|i| {
                let u = (g.x0 + i as f64 * g.pitch - VIEW_CENTER[0]) / half_w;
                (1.0 - 0.18 * u * u + 0.03 * u) as f32
            })
            .collect();
        for j in 0..g.height {
            let v = (g.z0 + j as f64 * g.pitch - VIEW_CENTER[1]) / half_h;
            let gz = level * (1.0 - 0.18 * v * v) as f32;
            let row = &mut self.static_layer[j * g.width..(j + 1) * g.width];
            for (o, x) in row.iter_mut().zip(&gx) {
                *o = gz * x;
            }
        }
        // The plate's walls, cells and debris, where the feeder has moved them, each
        // defocused by the floor's height under it.
        let g = &self.plate_grid(g);
        let f = self.scene.feeder;
        // Feeder walls: faint lines between the wells, one well's side at a time.
        let wall_sigma = |cam: &Self, at: [f64; 2]| {
            let (blur2, _, _) = cam.plate_sigma(g, at);
            (0.6e-6f64.powi(2) + blur2).sqrt()
        };
        let (zx0, zx1) = (
            f.offset[1] - 0.5 * f.pitch,
            f.offset[1] + (f.rows as f64 - 0.5) * f.pitch,
        );
        let (xx0, xx1) = (
            f.offset[0] - 0.5 * f.pitch,
            f.offset[0] + (f.cols as f64 - 0.5) * f.pitch,
        );
        let feeder_cols = if f.rows > 0 { f.cols + 1 } else { 0 };
        let feeder_rows = if f.cols > 0 { f.rows + 1 } else { 0 };
        let mut sigmas = Vec::new();
        for k in 0..feeder_cols {
            let xk = xx0 + k as f64 * f.pitch;
            sigmas.clear();
            sigmas.extend(
                (0..f.rows).map(|r| wall_sigma(self, [xk, f.offset[1] + r as f64 * f.pitch])),
            );
            self.multiply_wall(g, true, xk, &sigmas, f.pitch, zx0, zx1);
        }
        for k in 0..feeder_rows {
            let zk = zx0 + k as f64 * f.pitch;
            sigmas.clear();
            sigmas.extend(
                (0..f.cols).map(|c| wall_sigma(self, [f.offset[0] + c as f64 * f.pitch, zk])),
            );
            self.multiply_wall(g, false, zk, &sigmas, f.pitch, xx0, xx1);
        }
        // Cells: cytoplasm, membrane ring, nucleus.
        let cells = self.scene.cells.clone();
        for c in &cells {
            let (_, sigma, ring) = self.plate_sigma(g, [c.x, c.z]);
            let reach = c.radius + 4.0 * sigma + 2e-6;
            let (i0, i1) = span(g.x0, g.pitch, g.width, c.x - reach, c.x + reach);
            let (j0, j1) = span(g.z0, g.pitch, g.height, c.z - reach, c.z + reach);
            for j in j0..j1 {
                let dz = g.z0 + j as f64 * g.pitch - c.z;
                let row = &mut self.static_layer[j * g.width..(j + 1) * g.width];
                for (i, px) in row.iter_mut().enumerate().take(i1).skip(i0) {
                    let dx = g.x0 + i as f64 * g.pitch - c.x;
                    *px *= cell_factor(c, &REST, dx, dz, sigma, ring);
                }
            }
        }
        // Debris: small dark Gaussian spots.
        let debris = self.scene.debris.clone();
        for d in &debris {
            let (blur2, _, _) = self.plate_sigma(g, [d.x, d.z]);
            let sd = (d.sigma * d.sigma + blur2).sqrt();
            let amp = (d.depth * d.sigma * d.sigma / (sd * sd)) as f32;
            self.splat(g, d.x, d.z, sd, sd, amp, true);
        }
        self.static_grid = Some(*g);
    }

    /// Multiplies a wall (a straight dark line, vertical at x = `pos` if `vertical`,
    /// from `from` to `to` along it) made of segments `seg` long, segment `k` blurred
    /// by `sigmas[k]`: each pixel along the line is darkened once, by its segment's
    /// profile.
    #[allow(clippy::too_many_arguments)]
    fn multiply_wall(
        &mut self,
        g: &Grid,
        vertical: bool,
        pos: f64,
        sigmas: &[f64],
        seg: f64,
        from: f64,
        to: f64,
    ) {
        let (c0, n) = if vertical {
            (g.z0, g.height)
        } else {
            (g.x0, g.width)
        };
        let (a0, a1) = span(c0, g.pitch, n, from, to);
        let Some(&first) = sigmas.first() else {
            return;
        };
        if sigmas.iter().all(|&s| s == first) {
            self.multiply_line(g, vertical, pos, first, 0.10, (a0, a1));
            return;
        }
        let mut start = a0;
        for (k, &sigma) in sigmas.iter().enumerate() {
            let end = if k + 1 == sigmas.len() {
                a1
            } else {
                // The first pixel at or past the segment's end.
                let b = ((from + (k + 1) as f64 * seg - c0) / g.pitch).ceil();
                (b.max(0.0) as usize).clamp(start, a1)
            };
            if end > start {
                self.multiply_line(g, vertical, pos, sigma, 0.10, (start, end));
            }
            start = end;
        }
    }

    /// Multiplies a straight dark line (vertical at x = `pos` if `vertical`) over the
    /// pixels `along` (rows if vertical, else columns).
    fn multiply_line(
        &mut self,
        g: &Grid,
        vertical: bool,
        pos: f64,
        sigma: f64,
        depth: f32,
        along: (usize, usize),
    ) {
        let reach = 4.0 * sigma;
        if vertical {
            let (i0, i1) = span(g.x0, g.pitch, g.width, pos - reach, pos + reach);
            let (j0, j1) = along;
            gauss_row(&mut self.scratch_x, g.x0, g.pitch, i0, i1, pos, sigma);
            for j in j0..j1 {
                let row = &mut self.static_layer[j * g.width + i0..j * g.width + i1];
                for (p, w) in row.iter_mut().zip(&self.scratch_x) {
                    *p *= 1.0 - depth * w;
                }
            }
        } else {
            let (j0, j1) = span(g.z0, g.pitch, g.height, pos - reach, pos + reach);
            let (i0, i1) = along;
            gauss_row(&mut self.scratch_z, g.z0, g.pitch, j0, j1, pos, sigma);
            for (k, j) in (j0..j1).enumerate() {
                let a = depth * self.scratch_z[k];
                for p in &mut self.static_layer[j * g.width + i0..j * g.width + i1] {
                    *p *= 1.0 - a;
                }
            }
        }
    }

    /// Multiplies a separable dark Gaussian spot into the static layer or the work buffer.
    #[allow(clippy::too_many_arguments)]
    fn splat(&mut self, g: &Grid, x: f64, z: f64, sx: f64, sz: f64, amp: f32, into_static: bool) {
        let (i0, i1) = span(g.x0, g.pitch, g.width, x - 3.5 * sx, x + 3.5 * sx);
        let (j0, j1) = span(g.z0, g.pitch, g.height, z - 3.5 * sz, z + 3.5 * sz);
        if i0 >= i1 || j0 >= j1 {
            return;
        }
        gauss_row(&mut self.scratch_x, g.x0, g.pitch, i0, i1, x, sx);
        gauss_row(&mut self.scratch_z, g.z0, g.pitch, j0, j1, z, sz);
        let buf = if into_static {
            &mut self.static_layer
        } else {
            &mut self.work
        };
        for (k, j) in (j0..j1).enumerate() {
            let a = amp * self.scratch_z[k];
            let row = &mut buf[j * g.width + i0..j * g.width + i1];
            for (p, w) in row.iter_mut().zip(&self.scratch_x) {
                *p *= 1.0 - a * w;
            }
        }
    }

    /// Redraws the cells whose look changed: divides their resting factor out of the
    /// work buffer and multiplies their present one in (both never below 0.36).
    fn render_looks(&mut self, g: &Grid) {
        if self.looks.is_empty() {
            return;
        }
        let g = &self.plate_grid(g);
        for (k, look) in &self.looks {
            let Some(c) = self.scene.cells.get(*k) else {
                continue;
            };
            let (_, sigma, ring) = self.plate_sigma(g, [c.x, c.z]);
            let reach = c.radius * look.scale.max(1.0)
                + look.offset[0].abs().max(look.offset[1].abs())
                + 4.0 * sigma
                + 2e-6;
            let (i0, i1) = span(g.x0, g.pitch, g.width, c.x - reach, c.x + reach);
            let (j0, j1) = span(g.z0, g.pitch, g.height, c.z - reach, c.z + reach);
            for j in j0..j1 {
                let dz = g.z0 + j as f64 * g.pitch - c.z;
                let row = &mut self.work[j * g.width..(j + 1) * g.width];
                for (i, px) in row.iter_mut().enumerate().take(i1).skip(i0) {
                    let dx = g.x0 + i as f64 * g.pitch - c.x;
                    let rest = cell_factor(c, &REST, dx, dz, sigma, ring);
                    *px *= cell_factor(c, look, dx, dz, sigma, ring) / rest;
                }
            }
        }
    }

    /// Draws the pipette and its speckled marker tab into the work buffer. The glass
    /// is a tube of outer radius `r(s)` at `s` metres behind the tip, lying along the
    /// view's `back` direction foreshortened by `foreshortening`; each section is
    /// blurred by its own distance from the focal plane (the tip's depth plus `rise`
    /// per metre behind it) and by the motion during the exposure.
    fn render_pipette(&mut self, g: &Grid, pose: &TipPose, exposure: f64) {
        let shape = self.scene.pipette;
        let view = self.pipette;
        let blur = self.optics.focus_blur + self.optics.defocus_rate * pose.depth.abs();
        let base2 = blur * blur + g.pitch * g.pitch / 12.0;
        let sx = (base2 + (pose.vx * exposure).powi(2) / 12.0).sqrt();
        let sz = (base2 + (pose.vz * exposure).powi(2) / 12.0).sqrt();
        let (sxf, szf) = (sx as f32, sz as f32);
        let [bu, bv] = view.back;
        let f = view.foreshortening.max(1e-6);
        // Motion along and across the glass's image.
        let v_along = pose.vx * bu + pose.vz * bv;
        let v_across = pose.vx * bv - pose.vz * bu;
        let pix2 = g.pitch * g.pitch / 12.0;
        let sigma = |s: f64, v: f64| {
            let b = self.optics.focus_blur
                + self.optics.defocus_rate * (pose.depth + view.rise * s.max(0.0)).abs();
            (b * b + pix2 + (v * exposure).powi(2) / 12.0).sqrt()
        };
        let v_max = v_across.abs().max(v_along.abs());
        let tip_reach = 4.0 * sigma(0.0, v_along);
        // Rows from the image's top to just past the tip.
        let (j0, j1) = span(
            g.z0,
            g.pitch,
            g.height,
            f64::NEG_INFINITY,
            pose.z + tip_reach + view.tip_radius,
        );
        let j0 = j0.min(j1);
        for j in j0..j1 {
            let z = g.z0 + j as f64 * g.pitch;
            // Where the axis crosses this row, and how wide the glass is there (its
            // radius and blur at that section; a tilted glass's sections across the
            // row lie a little further along it, hence the quarter's margin).
            let dv = z - pose.z;
            let u_c = if bv.abs() > 1e-9 {
                pose.x + dv * bu / bv
            } else {
                pose.x
            };
            let s_c = ((u_c - pose.x) * bu + dv * bv) / f;
            let r_c = (view.tip_radius + view.taper * s_c.max(0.0)).min(view.shank_radius);
            let width = 1.25 * (r_c + 4.0 * sigma(s_c, v_max)) / bv.abs().max(0.05) + 2.0 * g.pitch;
            let (i0, i1) = span(g.x0, g.pitch, g.width, u_c - width, u_c + width);
            let row = &mut self.work[j * g.width..(j + 1) * g.width];
            for (i, px) in row.iter_mut().enumerate().take(i1).skip(i0) {
                let (du, dv) = (g.x0 + i as f64 * g.pitch - pose.x, z - pose.z);
                // Image distance behind the tip along the glass, and across it.
                let along = du * bu + dv * bv;
                let d = (du * bv - dv * bu).abs();
                let s = along / f;
                let r = (view.tip_radius + view.taper * s.max(0.0)).min(view.shank_radius);
                let ri = shape.bore * r;
                let s_across = sigma(s, v_across) as f32;
                let s_along = sigma(s, v_along) as f32;
                let fade = step(along as f32 / s_along);
                let (rf, rif, df) = (r as f32, ri as f32, d as f32);
                let outer = step((rf - df) / s_across);
                let inner = step((rif - df) / s_across);
                *px *= 1.0 - fade * (0.12 * outer + 0.45 * (outer - inner));
            }
        }
        // Marker tab: a translucent film with speckles, rigidly attached to the pipette.
        let cx = pose.x + shape.marker_center[0];
        let cz = pose.z + shape.marker_center[1];
        let [hx, hz] = shape.marker_half;
        let (i0, i1) = span(
            g.x0,
            g.pitch,
            g.width,
            cx - hx - 4.0 * sx,
            cx + hx + 4.0 * sx,
        );
        let (j0, j1) = span(
            g.z0,
            g.pitch,
            g.height,
            cz - hz - 4.0 * sz,
            cz + hz + 4.0 * sz,
        );
        for j in j0..j1 {
            let dz = (g.z0 + j as f64 * g.pitch - cz).abs() as f32;
            let fz = step((hz as f32 - dz) / szf);
            let row = &mut self.work[j * g.width..(j + 1) * g.width];
            for (i, px) in row.iter_mut().enumerate().take(i1).skip(i0) {
                let dx = (g.x0 + i as f64 * g.pitch - cx).abs() as f32;
                *px *= 1.0 - 0.15 * fz * step((hx as f32 - dx) / sxf);
            }
        }
        let speckles = std::mem::take(&mut self.scene.speckles);
        for s in &speckles {
            let ssx = (s.sigma * s.sigma + sx * sx).sqrt();
            let ssz = (s.sigma * s.sigma + sz * sz).sqrt();
            let amp = (s.depth * s.sigma * s.sigma / (ssx * ssz)) as f32;
            self.splat(g, cx + s.x, cz + s.z, ssx, ssz, amp, false);
        }
        self.scene.speckles = speckles;
    }

    /// Renders one frame of the tip at `pose` into `out` (reusing its buffer).
    pub fn render(
        &mut self,
        pose: &TipPose,
        timestamp: f64,
        index: u64,
        seed: u64,
        out: &mut Frame,
    ) {
        let g = self.grid();
        if self.static_grid != Some(g) {
            self.render_static(&g);
        }
        self.work.clear();
        self.work.extend_from_slice(&self.static_layer);
        self.render_looks(&g);
        if self.dark_frames > 0 {
            self.dark_frames -= 1;
            self.work.iter_mut().for_each(|p| *p *= 0.02);
        }
        let exposure = self.settings.exposure;
        self.render_pipette(&g, pose, exposure);
        // Sensor.
        let b2 = (g.binning * g.binning) as f32;
        let full = self.params.full_well as f32 * b2;
        let gain = full * (exposure / self.params.reference_exposure) as f32;
        let read2 = (self.params.read_noise as f32).powi(2) * b2;
        let max_dn = ((1u32 << self.settings.bit_depth) - 1) as f32;
        let to_dn = max_dn / full;
        let mut rng = Rng::new(
            seed ^ index.wrapping_mul(0x9E37_79B9_7F4A_7C15),
            self.noise_stream,
        );
        out.width = g.width as u32;
        out.height = g.height as u32;
        out.bit_depth = self.settings.bit_depth;
        out.timestamp = timestamp;
        out.exposure = exposure;
        // What the camera knows: the nominal pixel size, not the drifted one.
        out.pixel_size = g.pitch * self.scale;
        out.index = index;
        out.pixels.clear();
        out.pixels.resize(self.work.len(), 0);
        for (o, w) in out.pixels.chunks_mut(4).zip(self.work.chunks(4)) {
            let n = rng.gaussian4();
            for k in 0..o.len() {
                let e = w[k] * gain;
                let v = e + (e.max(0.0) + read2).sqrt() * n[k];
                // Non-negative after the clamp: adding ½ and truncating rounds to nearest.
                o[k] = ((v * to_dn).clamp(0.0, max_dn) + 0.5) as u16;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::FeederParams;

    #[test]
    fn phi_table_is_the_normal_cdf() {
        assert!((step(0.0) - 0.5).abs() < 1e-6);
        assert!((step(1.0) - 0.841_344_7).abs() < 1e-5);
        assert!((step(-2.0) - 0.022_750_13).abs() < 1e-5);
        assert_eq!(step(-9.0), 0.0);
        assert_eq!(step(9.0), 1.0);
    }

    #[test]
    fn a_drifted_magnification_enlarges_the_image_while_frames_report_the_nominal_pixel() {
        let mut c = camera();
        c.set_zoom(2.5).unwrap();
        let mut f = Frame::default();
        c.render(&TipPose::default(), 0.0, 0, 1, &mut f);
        let nominal = f.pixel_size;
        // A feeder wall near the right edge: the darkest column of the mean column
        // profile, high-passed (the vignetting removed), near `guess`; sub-pixel by the
        // centroid of darkness within 3 px.
        let wall = |f: &Frame, guess: Option<f64>| -> f64 {
            let (w, h) = (f.width as usize, f.height as usize);
            let mut col = vec![0.0f64; w];
            for j in 0..h {
                for (i, c) in col.iter_mut().enumerate() {
                    *c += f.pixels[j * w + i] as f64 / h as f64;
                }
            }
            let hp: Vec<f64> = (0..w)
                .map(|i| {
                    let (lo, hi) = (i.saturating_sub(30), (i + 31).min(w));
                    col[i] - col[lo..hi].iter().sum::<f64>() / (hi - lo) as f64
                })
                .collect();
            let (a, b) = match guess {
                None => (w * 4 / 5, w * 19 / 20),
                Some(g) => (g as usize - 6, g as usize + 7),
            };
            let k = (a..b).min_by(|x, y| hp[*x].total_cmp(&hp[*y])).unwrap();
            let (mut sw, mut sx) = (0.0, 0.0);
            for (i, v) in hp.iter().enumerate().take(k + 4).skip(k - 3) {
                sw += -v.min(0.0);
                sx += -v.min(0.0) * i as f64;
            }
            sx / sw
        };
        let before = wall(&f, None);
        c.set_magnification_drift(2e-3);
        assert!((c.magnification_drift() - 1.002).abs() < 1e-12);
        c.render(&TipPose::default(), 0.0, 0, 1, &mut f);
        assert_eq!(f.pixel_size, nominal, "the camera does not know its drift");
        assert!((c.grid().pitch - nominal / 1.002).abs() < 1e-18);
        // A point at u pixels from the centre moves to 1.002 u (independent of the
        // renderer: a rescaling about the sensor's centre).
        let centre = 0.5 * f.width as f64 - 0.5 - VIEW_CENTER[0] / nominal;
        let expected = centre + (before - centre) * 1.002;
        let after = wall(&f, Some(before));
        println!("wall {before:.3} -> {after:.3} px (expected {expected:.3})");
        assert!(
            (after - expected).abs() < 0.05,
            "wall at {before:.2} px moved to {after:.2} px, expected {expected:.2} px"
        );
        assert!((after - before).abs() > 1.0, "{before} -> {after}");
    }

    fn camera() -> Microscope {
        Microscope::new(
            CameraParams::default(),
            LensParams::default(),
            OpticsSetup::default(),
            Scene::generate(&FeederParams::default(), 1),
        )
    }

    #[test]
    fn grid_scales_with_zoom_and_binning() {
        let mut c = camera();
        let g = c.grid();
        assert_eq!((g.width, g.height), (2592, 1944));
        assert!((g.pitch - 0.22e-6).abs() < 1e-15);
        c.set_zoom(2.5).unwrap();
        assert!((c.grid().pitch - 0.88e-6).abs() < 1e-15);
        let vga = c.vga_settings(true);
        c.configure(vga).unwrap();
        let g = c.grid();
        assert_eq!((g.width, g.height), (640, 480));
        assert!((g.pitch - 4.0 * 0.88e-6).abs() < 1e-15);
        assert_eq!(c.frame_rate_for(&c.settings()), 30.0);
        assert!(c.set_zoom(12.0).is_err());
        let mut bad = c.settings();
        bad.exposure = 0.1; // longer than the 33 ms frame period
        assert!(c.configure(bad).is_err());
    }

    /// Sum of squared differences between neighbours along x and along z.
    fn gradient_energy(f: &Frame) -> (f64, f64) {
        let (w, h) = (f.width as usize, f.height as usize);
        let px = |i: usize, j: usize| f.pixels[j * w + i] as f64;
        let (mut gx, mut gz) = (0.0, 0.0);
        for j in 0..h - 1 {
            for i in 0..w - 1 {
                gx += (px(i + 1, j) - px(i, j)).powi(2);
                gz += (px(i, j + 1) - px(i, j)).powi(2);
            }
        }
        (gx, gz)
    }

    #[test]
    fn a_plates_cells_and_debris_are_drawn_where_the_plate_says() {
        use cellinject_plate::{Object, Plate};
        let plate = Plate {
            rows: 2,
            cols: 2,
            pitch: 150e-6,
            origin: [0.0, 0.0],
            cells: vec![Object {
                well: [1, 1],
                offset: [20e-6, -10e-6],
                diameter: 24e-6,
            }],
            debris: vec![Object {
                well: [1, 0],
                offset: [0.0, 0.0],
                diameter: 8e-6,
            }],
        };
        let mut c = camera();
        c.params.read_noise = 0.0;
        c.params.full_well = 1e12;
        c.set_zoom(2.5).unwrap();
        c.set_scene(Scene::from_plate(&plate, 1));
        let mut f = Frame::default();
        c.render(&TipPose::default(), 0.0, 0, 1, &mut f);
        let g = c.grid();
        // Mean of the pixels between r0 and r1 (m) from (x, z).
        let mean = |x: f64, z: f64, r0: f64, r1: f64| {
            let (ci, cj) = ((x - g.x0) / g.pitch, (z - g.z0) / g.pitch);
            let (mut sum, mut n) = (0.0, 0.0);
            let reach = (r1 / g.pitch).ceil() as i64 + 1;
            for dj in -reach..=reach {
                for di in -reach..=reach {
                    let (i, j) = (ci.round() as i64 + di, cj.round() as i64 + dj);
                    let d = ((i as f64 - ci).hypot(j as f64 - cj)) * g.pitch;
                    if d >= r0 && d <= r1 {
                        sum += f.pixels[j as usize * g.width + i as usize] as f64;
                        n += 1.0;
                    }
                }
            }
            sum / n
        };
        // The cell, at well [1, 1]'s centre (150, 150) µm plus its offset: darker inside
        // (cytoplasm, membrane, nucleus) than around it.
        let (x, z) = (170e-6, 140e-6);
        let inside = mean(x, z, 0.0, 12e-6);
        let around = mean(x, z, 16e-6, 24e-6);
        assert!(inside < 0.95 * around, "cell {inside} vs {around}");
        // The debris at well [1, 0]'s centre: darker still.
        let spot = mean(0.0, 150e-6, 0.0, 2.5e-6);
        let ring = mean(0.0, 150e-6, 8e-6, 14e-6);
        assert!(spot < 0.8 * ring, "debris {spot} vs {ring}");
        // An empty well's centre is background.
        let empty = mean(150e-6, 0.0, 0.0, 12e-6);
        let bg = mean(150e-6, 0.0, 16e-6, 24e-6);
        assert!((empty / bg - 1.0).abs() < 0.03, "empty {empty} vs {bg}");
    }

    #[test]
    fn motion_during_the_exposure_smears_along_the_motion_only() {
        let mut c = camera();
        // A noiseless view of the speckled tab at full resolution.
        c.params.read_noise = 0.0;
        c.params.full_well = 1e12;
        let tab = Roi {
            x: 1296 + 300,
            y: 972 - 800,
            width: 400,
            height: 400,
        };
        c.configure(CameraSettings {
            roi: tab,
            bit_depth: 12,
            ..c.settings()
        })
        .unwrap();
        let mut still = Frame::default();
        let mut moving = Frame::default();
        c.render(&TipPose::default(), 0.0, 0, 1, &mut still);
        // 5 ms at 2 mm/s along x: a 10 µm smear.
        let pose = TipPose {
            vx: 2e-3,
            ..TipPose::default()
        };
        c.render(&pose, 0.0, 0, 1, &mut moving);
        let (sx, sz) = gradient_energy(&still);
        let (mx, mz) = gradient_energy(&moving);
        assert!(sx > 0.0 && sz > 0.0);
        // Both drop (the smear lowers the speckles' contrast), the gradients along the
        // motion far more than across it.
        let (rx, rz) = (mx / sx, mz / sz);
        assert!(rx < 0.3 * rz && rz < 1.0, "x ratio {rx}, z ratio {rz}");
    }

    #[test]
    fn noise_statistics_follow_shot_and_read_noise() {
        // A flat 50 % field: the variance in electrons is signal + read².
        let mut c = camera();
        let vga = c.vga_settings(false);
        c.configure(CameraSettings {
            bit_depth: 12,
            ..vga
        })
        .unwrap();
        let g = c.grid();
        c.render_static(&g);
        let p = *c.params();
        let n = c.static_layer.len();
        c.static_layer.iter_mut().for_each(|v| *v = 0.5);
        let mut f = Frame::default();
        // Render without the pipette: move it far away.
        let pose = TipPose {
            x: 1.0,
            z: -1.0,
            ..TipPose::default()
        };
        c.render(&pose, 0.0, 0, 1, &mut f);
        let to_e = p.full_well / 4095.0;
        let vals: Vec<f64> = f.pixels.iter().map(|&v| v as f64 * to_e).collect();
        let mean = vals.iter().sum::<f64>() / n as f64;
        let var = vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64;
        let signal = 0.5 * p.full_well;
        let expected = signal + p.read_noise.powi(2) + to_e * to_e / 12.0;
        assert!((mean / signal - 1.0).abs() < 1e-3, "{mean}");
        assert!((var / expected - 1.0).abs() < 0.02, "{var} vs {expected}");
    }
}
