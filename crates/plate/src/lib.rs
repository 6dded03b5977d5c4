//! # cellinject-plate
//!
//! The matrix feeder of Sec. 3.1 of the paper: a grid of wells on the macro stage, each
//! holding a cell of 10-30 µm, two touching cells, debris, or nothing. A [`Plate`] says
//! where every well sits and, for the digital twin, what truly lies in each (the
//! injection workflow never reads that: it finds the cells in the image).
//!
//! Coordinates (SI, m): plate x runs along the columns, plate y along the rows; a well
//! is the `pitch × pitch` square around its centre `origin + (col·pitch, row·pitch)`,
//! and an object's centre is its well's centre plus its `offset`.
//!
//! [`Plate::check`] refuses what cannot be: an object reaching outside its well, two
//! objects overlapping (touching is allowed: doublets), sizes that are not positive or
//! outside their class (cells 10-30 µm, debris below 10 µm), wells outside the grid.
//! [`generate`] makes realistic plates from a seed: cells off-centre, empty wells,
//! doublets, debris.
//!
//! **Architecture invariant:** pure data and computation: no files, no TOML (the
//! description file is `cellinject-config`'s), no clock.

pub mod fields;

use cellinject_numeric::rng::Rng;
use thiserror::Error;

/// Smallest cell diameter, m (the manipulator's design range, Sec. 1).
pub const CELL_MIN: f64 = 10e-6;
/// Largest cell diameter, m.
pub const CELL_MAX: f64 = 30e-6;
/// Debris is smaller than this, m.
pub const DEBRIS_MAX: f64 = 10e-6;
/// Objects may overlap by this much and still count as touching, m (a generated
/// plate's numbers are rounded to the nanometre).
pub const TOUCH_SLACK: f64 = 5e-9;

/// What is wrong with a plate, naming the key at fault in the description file's terms
/// (`plate.pitch`, `cell[3].offset`, `debris[0].diameter`).
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PlateError {
    /// A value outside its domain, or objects that cannot be where they are said to be.
    #[error("key `{key}`: {reason}")]
    Invalid {
        /// Dotted key.
        key: String,
        /// What is wrong, with the numbers.
        reason: String,
    },
}

fn invalid(key: impl Into<String>, reason: impl Into<String>) -> PlateError {
    PlateError::Invalid {
        key: key.into(),
        reason: reason.into(),
    }
}

/// Which kind of object lies in a well.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kind {
    /// A cell, to be injected.
    Cell,
    /// Not a cell (smaller, irregular): never injected.
    Debris,
}

impl Kind {
    /// The description file's name for a list of these (`cell`, `debris`).
    pub fn key(self) -> &'static str {
        match self {
            Kind::Cell => "cell",
            Kind::Debris => "debris",
        }
    }
}

/// A cell or a piece of debris in a well.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Object {
    /// `[row, col]` of its well.
    pub well: [u32; 2],
    /// m, its centre from the well's centre: plate `[x, y]`.
    pub offset: [f64; 2],
    /// m.
    pub diameter: f64,
}

/// The feeder: its grid, where it sits on the stage, and what truly lies in it.
#[derive(Debug, Clone, PartialEq)]
pub struct Plate {
    /// Rows of wells (along plate y).
    pub rows: u32,
    /// Columns of wells (along plate x).
    pub cols: u32,
    /// m between well centres.
    pub pitch: f64,
    /// m, stage coordinates of well `[0, 0]`'s centre.
    pub origin: [f64; 2],
    /// The cells (the twin's ground truth).
    pub cells: Vec<Object>,
    /// The debris (the twin's ground truth).
    pub debris: Vec<Object>,
}

/// What a plate holds: its grid and the counts `plate generate|check` report (the
/// cells of wells outside the grid are counted as cells, in no well).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Summary {
    /// Rows of wells.
    pub rows: u32,
    /// Columns of wells.
    pub cols: u32,
    /// Distance between wells, m.
    pub pitch_m: f64,
    /// Wells in all.
    pub wells: usize,
    /// Cells in all.
    pub cells: usize,
    /// Wells holding two or more cells.
    pub doublets: usize,
    /// Wells without a cell.
    pub empty_wells: usize,
    /// Pieces of debris.
    pub debris: usize,
    /// Smallest and largest cell, m (null without cells).
    pub cell_diameter_m: Option<[f64; 2]>,
}

impl Plate {
    /// What the plate holds.
    pub fn summary(&self) -> Summary {
        let mut per_well = vec![0usize; self.wells()];
        for c in &self.cells {
            let [r, k] = c.well;
            if r < self.rows && k < self.cols {
                per_well[r as usize * self.cols as usize + k as usize] += 1;
            }
        }
        let d = self.cells.iter().map(|c| c.diameter);
        let cell_diameter_m = (!self.cells.is_empty()).then(|| {
            [
                d.clone().fold(f64::INFINITY, f64::min),
                d.fold(0.0, f64::max),
            ]
        });
        Summary {
            rows: self.rows,
            cols: self.cols,
            pitch_m: self.pitch,
            wells: self.wells(),
            cells: self.cells.len(),
            doublets: per_well.iter().filter(|n| **n >= 2).count(),
            empty_wells: per_well.iter().filter(|n| **n == 0).count(),
            debris: self.debris.len(),
            cell_diameter_m,
        }
    }

    /// The centre of well `[row, col]` in stage coordinates, m.
    pub fn well_centre(&self, well: [u32; 2]) -> [f64; 2] {
        [
            self.origin[0] + well[1] as f64 * self.pitch,
            self.origin[1] + well[0] as f64 * self.pitch,
        ]
    }

    /// An object's centre in stage coordinates, m.
    pub fn centre(&self, o: &Object) -> [f64; 2] {
        let w = self.well_centre(o.well);
        [w[0] + o.offset[0], w[1] + o.offset[1]]
    }

    /// Number of wells.
    pub fn wells(&self) -> usize {
        self.rows as usize * self.cols as usize
    }

    /// Every object with its kind and its index in its list.
    pub fn objects(&self) -> impl Iterator<Item = (Kind, usize, &Object)> {
        let cells = self
            .cells
            .iter()
            .enumerate()
            .map(|(i, o)| (Kind::Cell, i, o));
        let debris = self
            .debris
            .iter()
            .enumerate()
            .map(|(i, o)| (Kind::Debris, i, o));
        cells.chain(debris)
    }

    /// Refuses a plate that cannot be: see the crate's documentation. The first of
    /// [`Plate::problems`].
    pub fn check(&self) -> Result<(), PlateError> {
        match self.problems().into_iter().next() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// Everything that makes the plate one that cannot be, in the file's order: the
    /// grid's faults alone if it has any (the objects are placed on it), else each
    /// object's (a well outside the grid, a diameter out of its class, an offset
    /// reaching outside the well) and every overlap.
    pub fn problems(&self) -> Vec<PlateError> {
        let grid = self.grid_problems();
        if !grid.is_empty() {
            return grid;
        }
        let mut out = Vec::new();
        for (kind, i, o) in self.objects() {
            out.extend(self.object_problems(kind, i, o));
        }
        out.extend(self.overlaps());
        out
    }

    /// The grid's faults: rows, columns, pitch, origin.
    fn grid_problems(&self) -> Vec<PlateError> {
        let mut out = Vec::new();
        if self.rows == 0 || self.rows > MAX_SIDE {
            out.push(invalid(
                "plate.rows",
                format!("{} must lie in [1, {MAX_SIDE}]", self.rows),
            ));
        }
        if self.cols == 0 || self.cols > MAX_SIDE {
            out.push(invalid(
                "plate.cols",
                format!("{} must lie in [1, {MAX_SIDE}]", self.cols),
            ));
        }
        if !(self.pitch.is_finite() && self.pitch > CELL_MAX) {
            out.push(invalid(
                "plate.pitch",
                format!(
                    "{} m must be a finite number above the largest cell, {} µm",
                    self.pitch,
                    CELL_MAX * 1e6
                ),
            ));
        } else if self.pitch > PITCH_MAX {
            out.push(invalid(
                "plate.pitch",
                format!(
                    "{} m ({:.0} mm) is not a matrix feeder's pitch (above {} µm, at most {} mm){}",
                    self.pitch,
                    self.pitch * 1e3,
                    CELL_MAX * 1e6,
                    PITCH_MAX * 1e3,
                    units_hint(self.pitch)
                ),
            ));
        }
        for (i, v) in self.origin.iter().enumerate() {
            if !v.is_finite() {
                out.push(invalid(
                    format!("plate.origin[{i}]"),
                    format!("{v} must be a finite number"),
                ));
            }
        }
        out
    }

    /// Whether object `o` lies in a well of the grid.
    fn in_grid(&self, o: &Object) -> bool {
        o.well[0] < self.rows && o.well[1] < self.cols
    }

    /// Object `o`'s own faults (the `i`-th of its `kind`): its well, its diameter, its
    /// offset.
    fn object_problems(&self, kind: Kind, i: usize, o: &Object) -> Vec<PlateError> {
        let key = |k: &str| format!("{}[{i}].{k}", kind.key());
        let mut out = Vec::new();
        if !self.in_grid(o) {
            out.push(invalid(
                key("well"),
                format!(
                    "[{}, {}] is outside the {}x{} grid (rows and columns count from 0)",
                    o.well[0], o.well[1], self.rows, self.cols
                ),
            ));
        }
        let d = o.diameter;
        let (lo, hi, what) = match kind {
            Kind::Cell => (
                CELL_MIN,
                CELL_MAX,
                "a cell's diameter must lie in [10, 30] µm",
            ),
            Kind::Debris => (0.0, DEBRIS_MAX, "debris must be smaller than 10 µm"),
        };
        if !(d.is_finite() && d > 0.0) {
            out.push(invalid(
                key("diameter"),
                format!("{d} m must be a positive number"),
            ));
            return out;
        }
        if d < lo || d > hi || (kind == Kind::Debris && d >= hi) {
            out.push(invalid(
                key("diameter"),
                format!("{:.3} µm: {what}", d * 1e6),
            ));
        }
        let half = 0.5 * self.pitch;
        for (a, v) in o.offset.iter().enumerate() {
            if !v.is_finite() {
                out.push(invalid(
                    format!("{}[{a}]", key("offset")),
                    format!("{v} must be a finite number"),
                ));
                continue;
            }
            let reach = v.abs() + 0.5 * d - half;
            if reach > TOUCH_SLACK {
                out.push(invalid(
                    key("offset"),
                    format!(
                        "the {} of {:.3} µm at {:.3} µm from the centre of well [{}, {}] reaches {:.3} µm outside it (pitch {:.3} µm)",
                        if kind == Kind::Cell { "cell" } else { "debris" },
                        d * 1e6,
                        v * 1e6,
                        o.well[0],
                        o.well[1],
                        reach * 1e6,
                        self.pitch * 1e6
                    ),
                ));
                break;
            }
        }
        out
    }

    /// Objects overlapping in their well (objects outside the grid, or with a size or
    /// position that is not a number, left out: their own faults say why).
    fn overlaps(&self) -> Vec<PlateError> {
        let mut out = Vec::new();
        let mut by_well: Vec<Vec<(Kind, usize, &Object)>> = vec![Vec::new(); self.wells()];
        for (kind, i, o) in self.objects() {
            let finite = o.diameter.is_finite() && o.offset.iter().all(|v| v.is_finite());
            if self.in_grid(o) && finite {
                by_well[o.well[0] as usize * self.cols as usize + o.well[1] as usize]
                    .push((kind, i, o));
            }
        }
        for objects in &by_well {
            for (n, (ka, ia, a)) in objects.iter().enumerate() {
                for (kb, ib, b) in &objects[..n] {
                    let gap = (a.offset[0] - b.offset[0]).hypot(a.offset[1] - b.offset[1])
                        - 0.5 * (a.diameter + b.diameter);
                    if gap < -TOUCH_SLACK {
                        out.push(invalid(
                            format!("{}[{ia}].offset", ka.key()),
                            format!(
                                "overlaps {}[{ib}] in well [{}, {}] by {:.3} µm (objects may touch, not overlap)",
                                kb.key(),
                                a.well[0],
                                a.well[1],
                                -gap * 1e6
                            ),
                        ));
                    }
                }
            }
        }
        out
    }
}

/// Largest number of rows or columns.
pub const MAX_SIDE: u32 = 1000;

/// Largest pitch of a feeder, m: a 96-well plate's wells are 9 mm apart, and no
/// single-cell feeder spaces its wells wider (a larger number is a unit mistake).
pub const PITCH_MAX: f64 = 10e-3;

/// For a length that is out of a feeder's class, what it would be if it had been typed
/// in mm or µm instead of metres (the files are in metres): `"; plate files are in
/// metres: did you mean 0.16 mm, 160e-6?"`, or nothing when neither fits.
fn units_hint(v: f64) -> String {
    [(1e-3, "mm"), (1e-6, "µm")]
        .into_iter()
        .find(|(scale, _)| v * scale > CELL_MAX && v * scale <= PITCH_MAX)
        .map(|(scale, unit)| {
            format!(
                "; plate files are in metres: did you mean {v} {unit}, that is {:e}?",
                v * scale
            )
        })
        .unwrap_or_default()
}

/// How [`generate`] makes a plate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GenerateOptions {
    /// Rows of wells.
    pub rows: u32,
    /// Columns of wells.
    pub cols: u32,
    /// m between well centres.
    pub pitch: f64,
    /// m, stage coordinates of well `[0, 0]`.
    pub origin: [f64; 2],
    /// Fraction of wells left empty.
    pub empty_fraction: f64,
    /// Fraction of wells that also hold a piece of debris.
    pub debris_fraction: f64,
    /// Fraction of occupied wells holding two touching cells.
    pub doublet_fraction: f64,
    /// Seed.
    pub seed: u64,
}

impl Default for GenerateOptions {
    fn default() -> Self {
        GenerateOptions {
            rows: 4,
            cols: 6,
            pitch: 150e-6,
            origin: [0.0, 0.0],
            empty_fraction: 0.1,
            debris_fraction: 0.2,
            doublet_fraction: 0.1,
            seed: 1,
        }
    }
}

/// The random stream of plate generation (see `cellinject_numeric::rng`).
const STREAM: u64 = 0x504C_4154;

/// A realistic plate: each well is empty (`empty_fraction`), holds a doublet of two
/// touching cells (`doublet_fraction` of the others) or one cell, placed off-centre
/// anywhere it fits; `debris_fraction` of the wells also hold a piece of debris of
/// 3-9 µm that touches nothing. Deterministic for a seed; the result passes
/// [`Plate::check`].
pub fn generate(opts: &GenerateOptions) -> Result<Plate, PlateError> {
    for (key, v) in [
        ("--empty-fraction", opts.empty_fraction),
        ("--debris-fraction", opts.debris_fraction),
        ("--doublet-fraction", opts.doublet_fraction),
    ] {
        if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
            return Err(invalid(key, format!("{v} must lie in [0, 1]")));
        }
    }
    let mut plate = Plate {
        rows: opts.rows,
        cols: opts.cols,
        pitch: opts.pitch,
        origin: opts.origin,
        cells: Vec::new(),
        debris: Vec::new(),
    };
    // The grid itself must be valid before anything is placed in it.
    plate.check()?;
    let mut rng = Rng::new(opts.seed, STREAM);
    let half = 0.5 * opts.pitch;
    for row in 0..opts.rows {
        for col in 0..opts.cols {
            let well = [row, col];
            let mut here: Vec<Object> = Vec::new();
            if rng.uniform() >= opts.empty_fraction {
                if rng.uniform() < opts.doublet_fraction {
                    here.extend(doublet(&mut rng, well, half));
                }
                if here.is_empty() {
                    let d = rng.range(CELL_MIN, CELL_MAX);
                    let play = half - 0.5 * d;
                    here.push(Object {
                        well,
                        offset: [rng.range(-play, play), rng.range(-play, play)],
                        diameter: d,
                    });
                }
            }
            let cells = here.len();
            if rng.uniform() < opts.debris_fraction {
                let d = rng.range(3e-6, 9e-6);
                let play = half - 0.5 * d;
                for _ in 0..50 {
                    let o = Object {
                        well,
                        offset: [rng.range(-play, play), rng.range(-play, play)],
                        diameter: d,
                    };
                    // Apart from everything by at least a micrometre.
                    if here.iter().all(|c| gap(c, &o) > 1e-6) {
                        here.push(o);
                        break;
                    }
                }
            }
            // To the nanometre: a readable file that reads back exactly.
            for o in &mut here {
                o.offset = o.offset.map(nanometre);
                o.diameter = nanometre(o.diameter);
            }
            plate.cells.extend(&here[..cells]);
            plate.debris.extend(&here[cells..]);
        }
    }
    plate.check()?;
    Ok(plate)
}

fn nanometre(x: f64) -> f64 {
    (x * 1e9).round() / 1e9
}

/// Distance between two objects' rims, m (negative: overlap).
pub fn gap(a: &Object, b: &Object) -> f64 {
    (a.offset[0] - b.offset[0]).hypot(a.offset[1] - b.offset[1]) - 0.5 * (a.diameter + b.diameter)
}

/// Two touching cells of 10-18 µm at a random angle, both inside the well (empty if
/// they do not fit).
fn doublet(rng: &mut Rng, well: [u32; 2], half: f64) -> Vec<Object> {
    let (d1, d2) = (rng.range(CELL_MIN, 18e-6), rng.range(CELL_MIN, 18e-6));
    let angle = rng.range(0.0, std::f64::consts::TAU);
    let sep = 0.5 * (d1 + d2);
    let (ux, uy) = (angle.cos(), angle.sin());
    // Centre of the pair's span, placed where both fit.
    let reach_x = (0.5 * sep * ux.abs()) + 0.5 * d1.max(d2);
    let reach_y = (0.5 * sep * uy.abs()) + 0.5 * d1.max(d2);
    let (px, py) = (half - reach_x, half - reach_y);
    if px <= 0.0 || py <= 0.0 {
        return Vec::new();
    }
    let (cx, cy) = (rng.range(-px, px), rng.range(-py, py));
    let a = Object {
        well,
        offset: [cx - 0.5 * sep * ux, cy - 0.5 * sep * uy],
        diameter: d1,
    };
    let b = Object {
        well,
        offset: [cx + 0.5 * sep * ux, cy + 0.5 * sep * uy],
        diameter: d2,
    };
    vec![a, b]
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use proptest::prelude::*;

    #[test]
    fn the_summary_counts_doublets_empty_wells_and_sizes_and_skips_foreign_wells() {
        let o = |well: [u32; 2], d: f64| Object {
            well,
            offset: [0.0; 2],
            diameter: d,
        };
        let p = Plate {
            rows: 2,
            cols: 3,
            pitch: 1e-4,
            origin: [0.0; 2],
            // Well [0, 1] holds two, [1, 2] one; [5, 0] lies outside the grid.
            cells: vec![
                o([0, 1], 12e-6),
                o([0, 1], 20e-6),
                o([1, 2], 15e-6),
                o([5, 0], 18e-6),
            ],
            debris: vec![o([1, 0], 3e-6)],
        };
        let s = p.summary();
        assert_eq!((s.rows, s.cols, s.wells), (2, 3, 6));
        assert_eq!((s.cells, s.doublets, s.empty_wells, s.debris), (4, 1, 4, 1));
        assert_eq!(s.cell_diameter_m, Some([12e-6, 20e-6]));
        let empty = Plate {
            cells: Vec::new(),
            ..p
        };
        assert_eq!(empty.summary().cell_diameter_m, None);
        assert_eq!(empty.summary().empty_wells, 6);
    }

    fn plate() -> Plate {
        Plate {
            rows: 2,
            cols: 3,
            pitch: 150e-6,
            origin: [1e-3, 2e-3],
            cells: vec![Object {
                well: [1, 2],
                offset: [3e-6, -2e-6],
                diameter: 18e-6,
            }],
            debris: vec![Object {
                well: [1, 2],
                offset: [40e-6, 0.0],
                diameter: 6e-6,
            }],
        }
    }

    fn key_of(p: &Plate) -> String {
        match p.check() {
            Err(PlateError::Invalid { key, .. }) => key,
            Ok(()) => "ok".into(),
        }
    }

    #[test]
    fn a_pitch_out_of_a_feeders_class_is_refused_with_a_units_hint() {
        // 0.16 typed for 0.16 mm: 160 mm is no feeder's pitch.
        let mut p = plate();
        p.pitch = 0.16;
        let e = p.check().unwrap_err().to_string();
        assert!(e.contains("plate.pitch"), "{e}");
        assert!(e.contains("did you mean 0.16 mm, that is 1.6e-4"), "{e}");
        // 150 typed for 150 µm.
        p.pitch = 150.0;
        let e = p.check().unwrap_err().to_string();
        assert!(e.contains("did you mean 150 µm, that is 1.5e-4"), "{e}");
        // Out of class either way: no hint.
        p.pitch = 1e6;
        let e = p.check().unwrap_err().to_string();
        assert!(!e.contains("did you mean"), "{e}");
        // A 96-well plate's 9 mm is a feeder's pitch.
        let mut p = plate();
        p.pitch = 9e-3;
        p.debris.clear();
        assert_eq!(p.check(), Ok(()));
    }

    #[test]
    fn centres_follow_columns_along_x_and_rows_along_y() {
        let p = plate();
        let c = p.centre(&p.cells[0]);
        assert!((c[0] - (1e-3 + 2.0 * 150e-6 + 3e-6)).abs() < 1e-15);
        assert!((c[1] - (2e-3 + 150e-6 - 2e-6)).abs() < 1e-15);
        assert_eq!(p.check(), Ok(()));
    }

    #[test]
    fn impossible_plates_are_refused_naming_the_key() {
        let mut p = plate();
        p.cells[0].offset = [70e-6, 0.0];
        assert_eq!(key_of(&p), "cell[0].offset");
        let mut p = plate();
        p.debris[0].offset = [10e-6, 0.0];
        assert_eq!(key_of(&p), "debris[0].offset");
        assert!(
            p.check()
                .unwrap_err()
                .to_string()
                .contains("overlaps cell[0]")
        );
        let mut p = plate();
        p.cells[0].diameter = -1e-6;
        assert_eq!(key_of(&p), "cell[0].diameter");
        let mut p = plate();
        p.cells[0].diameter = 8e-6;
        assert_eq!(key_of(&p), "cell[0].diameter");
        let mut p = plate();
        p.debris[0].diameter = 12e-6;
        assert_eq!(key_of(&p), "debris[0].diameter");
        let mut p = plate();
        p.cells[0].well = [2, 0];
        assert_eq!(key_of(&p), "cell[0].well");
        let mut p = plate();
        p.pitch = 20e-6;
        assert_eq!(key_of(&p), "plate.pitch");
        let mut p = plate();
        p.origin[1] = f64::NAN;
        assert_eq!(key_of(&p), "plate.origin[1]");
        let mut p = plate();
        p.rows = 0;
        assert_eq!(key_of(&p), "plate.rows");
    }

    #[test]
    fn touching_cells_are_a_doublet_not_an_overlap() {
        let mut p = plate();
        p.cells.push(Object {
            well: [1, 2],
            offset: [3e-6 - 16e-6, -2e-6],
            diameter: 14e-6,
        });
        assert_eq!(p.check(), Ok(()));
        // 0.1 µm closer: an overlap.
        p.cells[1].offset[0] += 0.1e-6;
        assert_eq!(key_of(&p), "cell[1].offset");
    }

    #[test]
    fn generated_plates_have_what_was_asked_for() {
        let p = generate(&GenerateOptions {
            rows: 10,
            cols: 12,
            seed: 7,
            ..GenerateOptions::default()
        })
        .unwrap();
        let mut per_well = vec![0usize; p.wells()];
        for c in &p.cells {
            per_well[(c.well[0] * p.cols + c.well[1]) as usize] += 1;
        }
        let empty = per_well.iter().filter(|n| **n == 0).count() as f64 / 120.0;
        let doublets = per_well.iter().filter(|n| **n == 2).count();
        assert!((0.03..0.2).contains(&empty), "{empty}");
        assert!(doublets >= 4, "{doublets}");
        assert!(per_well.iter().all(|n| *n <= 2));
        let debris = p.debris.len() as f64 / 120.0;
        assert!((0.1..0.3).contains(&debris), "{debris}");
        // Same seed, same plate; another seed, another.
        let again = generate(&GenerateOptions {
            rows: 10,
            cols: 12,
            seed: 7,
            ..GenerateOptions::default()
        })
        .unwrap();
        assert_eq!(p, again);
        let other = generate(&GenerateOptions {
            rows: 10,
            cols: 12,
            seed: 8,
            ..GenerateOptions::default()
        })
        .unwrap();
        assert_ne!(p, other);
    }

    #[test]
    fn bad_fractions_are_refused() {
        let e = generate(&GenerateOptions {
            empty_fraction: 1.5,
            ..GenerateOptions::default()
        })
        .unwrap_err();
        assert!(e.to_string().contains("--empty-fraction"), "{e}");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        #[test]
        fn every_generated_plate_passes_its_own_check(
            seed in any::<u64>(),
            rows in 1u32..8,
            cols in 1u32..8,
            pitch in 40e-6f64..300e-6,
            empty in 0.0f64..1.0,
            debris in 0.0f64..1.0,
            doublets in 0.0f64..1.0,
        ) {
            let p = generate(&GenerateOptions {
                rows, cols, pitch, origin: [0.0, 0.0],
                empty_fraction: empty, debris_fraction: debris, doublet_fraction: doublets, seed,
            });
            prop_assert!(p.is_ok(), "{:?}", p);
        }
    }
}
