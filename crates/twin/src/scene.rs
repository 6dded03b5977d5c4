//! What the microscope looks at, in the object plane: the matrix feeder with its cells
//! and debris (fixed to the world), and the glass pipette with a speckled marker tab
//! (moving with the end-effector). Generated once from the seed.
//!
//! Object-plane coordinates are metres relative to the pipette tip's aligned position
//! (where it sits after pre-tensioning, with the stage at 0 and the stacks at 0 V; the
//! paper aligns the manipulator to the optics with the stage, Sec. 4):
//! `x` along the first tilt axis (image columns), `z` along the body axis (image rows,
//! downwards: the pipette points down at the cells). The second tilt axis `y` is the
//! optical axis: moving along it defocuses the pipette.

use crate::params::FeederParams;
use crate::world::stream;
use cellinject_numeric::Rng;

/// One cell waiting in a well.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cell {
    /// m, centre.
    pub x: f64,
    /// m, centre.
    pub z: f64,
    /// m, radius.
    pub radius: f64,
    /// m, nucleus centre offset from the cell centre.
    pub nucleus: [f64; 2],
    /// m, nucleus radius.
    pub nucleus_radius: f64,
}

/// A debris particle (small dark spot).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Debris {
    /// m.
    pub x: f64,
    /// m.
    pub z: f64,
    /// m, Gaussian sigma.
    pub sigma: f64,
    /// Absorption at the centre (0..1).
    pub depth: f64,
}

/// Geometry of the pipette and its marker tab.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PipetteShape {
    /// m, outer radius at the tip.
    pub tip_radius: f64,
    /// Growth of the outer radius per metre behind the tip (tan of the taper half-angle).
    pub taper: f64,
    /// m, outer radius of the shank.
    pub shank_radius: f64,
    /// Inner radius over outer radius.
    pub bore: f64,
    /// m, marker tab centre relative to the tip (x, z).
    pub marker_center: [f64; 2],
    /// m, marker tab half-size (x, z).
    pub marker_half: [f64; 2],
}

impl Default for PipetteShape {
    fn default() -> Self {
        PipetteShape {
            tip_radius: 0.5e-6,
            taper: 0.12,
            shank_radius: 45e-6,
            bore: 0.65,
            marker_center: [95e-6, -125e-6],
            marker_half: [40e-6, 40e-6],
        }
    }
}

/// A speckle of the marker tab, relative to the tab centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Speckle {
    /// m.
    pub x: f64,
    /// m.
    pub z: f64,
    /// m, Gaussian sigma.
    pub sigma: f64,
    /// Absorption at the centre.
    pub depth: f64,
}

/// The whole scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// Cells in the feeder.
    pub cells: Vec<Cell>,
    /// Debris.
    pub debris: Vec<Debris>,
    /// Pipette geometry.
    pub pipette: PipetteShape,
    /// Speckles of the marker.
    pub speckles: Vec<Speckle>,
    /// Feeder layout.
    pub feeder: FeederParams,
}

impl Scene {
    /// What the side camera sees: no feeder (it looks along the feeder's plane), sparse
    /// debris on the far window, the same pipette and its second speckled tab (facing
    /// this camera, at the same offset from the tip in the side view's (y, z) plane).
    pub fn side(seed: u64) -> Self {
        let mut rng = Rng::new(seed, stream::SIDE_SCENE);
        let debris = (0..20)
            .map(|_| Debris {
                x: rng.range(-1.2e-3, 1.2e-3),
                z: rng.range(-0.9e-3, 0.9e-3),
                sigma: rng.range(0.4e-6, 1.5e-6),
                depth: rng.range(0.2, 0.6),
            })
            .collect();
        let pipette = PipetteShape::default();
        let speckles = speckles(&pipette, &mut rng);
        Scene {
            cells: Vec::new(),
            debris,
            pipette,
            speckles,
            feeder: FeederParams {
                rows: 0,
                cols: 0,
                ..FeederParams::default()
            },
        }
    }

    /// Generates the scene for a feeder layout and seed.
    pub fn generate(feeder: &FeederParams, seed: u64) -> Self {
        let mut rng = Rng::new(seed, stream::SCENE);
        let mut cells = Vec::new();
        for r in 0..feeder.rows {
            for c in 0..feeder.cols {
                if rng.uniform() < feeder.empty_fraction {
                    continue;
                }
                let d = rng.range(feeder.cell_diameter[0], feeder.cell_diameter[1]);
                let radius = 0.5 * d;
                // Cells sit in their wells with a little play.
                let play = (0.5 * feeder.pitch - radius).max(0.0) * 0.5;
                let (nucleus, nucleus_radius) = nucleus(&mut rng, radius);
                cells.push(Cell {
                    x: feeder.offset[0] + c as f64 * feeder.pitch + rng.range(-play, play),
                    z: feeder.offset[1] + r as f64 * feeder.pitch + rng.range(-play, play),
                    radius,
                    nucleus,
                    nucleus_radius,
                });
            }
        }
        // Debris over a 2.4 mm x 1.8 mm area around the tip (the 2.5x field of view).
        let area_mm2 = 2.4 * 1.8;
        let n = (feeder.debris_density * area_mm2).round() as usize;
        let debris = (0..n)
            .map(|_| Debris {
                x: rng.range(-1.2e-3, 1.2e-3),
                z: rng.range(-0.9e-3, 0.9e-3),
                sigma: rng.range(0.4e-6, 1.5e-6),
                depth: rng.range(0.2, 0.6),
            })
            .collect();
        let pipette = PipetteShape::default();
        let speckles = speckles(&pipette, &mut rng);
        Scene {
            cells,
            debris,
            pipette,
            speckles,
            feeder: *feeder,
        }
    }
}

impl Scene {
    /// The scene of a plate file: its cells where the plate says (plate x along the
    /// scene's x, plate y along z; stage coordinates are the scene's), each with a
    /// nucleus drawn from the seed; its debris as irregular dark clusters of 3-6 spots
    /// within the particle's diameter, darker than the cells; the feeder's walls on the
    /// plate's grid; and the same fine dust and pipette as [`Scene::generate`].
    pub fn from_plate(plate: &cellinject_plate::Plate, seed: u64) -> Self {
        let mut rng = Rng::new(seed, stream::PLATE_SCENE);
        let cells = plate
            .cells
            .iter()
            .map(|o| {
                let [x, z] = plate.centre(o);
                let radius = 0.5 * o.diameter;
                let (nucleus, nucleus_radius) = nucleus(&mut rng, radius);
                Cell {
                    x,
                    z,
                    radius,
                    nucleus,
                    nucleus_radius,
                }
            })
            .collect();
        let mut debris = Vec::new();
        for o in &plate.debris {
            let [x, z] = plate.centre(o);
            let r = 0.5 * o.diameter;
            let n = 3 + (rng.uniform() * 4.0) as usize;
            for _ in 0..n {
                // Blobs inside the particle's disc: an irregular outline.
                let (a, q) = (rng.range(0.0, std::f64::consts::TAU), rng.uniform().sqrt());
                let sigma = r * rng.range(0.25, 0.45);
                let reach = (r - 2.0 * sigma).max(0.0) * q;
                debris.push(Debris {
                    x: x + reach * a.cos(),
                    z: z + reach * a.sin(),
                    sigma,
                    depth: rng.range(0.5, 0.8),
                });
            }
        }
        // Fine dust over the 2.5x field of view around the plate's first well.
        let [x0, z0] = plate.origin;
        for _ in 0..40 {
            debris.push(Debris {
                x: x0 + rng.range(-1.2e-3, 1.2e-3),
                z: z0 + rng.range(-0.9e-3, 0.9e-3),
                sigma: rng.range(0.4e-6, 1.5e-6),
                depth: rng.range(0.2, 0.6),
            });
        }
        let pipette = PipetteShape::default();
        let speckles = speckles(&pipette, &mut rng);
        Scene {
            cells,
            debris,
            pipette,
            speckles,
            feeder: FeederParams {
                rows: plate.rows,
                cols: plate.cols,
                pitch: plate.pitch,
                offset: plate.origin,
                ..FeederParams::default()
            },
        }
    }
}

/// A cell's nucleus: its offset from the cell's centre and its radius (m), drawn from
/// `rng`.
fn nucleus(rng: &mut Rng, radius: f64) -> ([f64; 2], f64) {
    let nr = radius * rng.range(0.3, 0.42);
    let off = (radius - nr) * 0.5 * rng.uniform();
    let ang = rng.range(0.0, std::f64::consts::TAU);
    ([off * ang.cos(), off * ang.sin()], nr)
}

/// Speckles of a marker tab: random positions at about one per (2.5 µm)² of the tab.
fn speckles(pipette: &PipetteShape, rng: &mut Rng) -> Vec<Speckle> {
    let [hx, hz] = pipette.marker_half;
    let count = ((4.0 * hx * hz) / (2.5e-6 * 2.5e-6)).round() as usize;
    (0..count)
        .map(|_| Speckle {
            x: rng.range(-hx, hx),
            z: rng.range(-hz, hz),
            sigma: rng.range(0.5e-6, 0.9e-6),
            depth: rng.range(0.35, 0.75),
        })
        .collect()
}
