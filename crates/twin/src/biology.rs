//! The cells of a loaded plate as living things: the pipette's contact with them
//! (the cell pushed ahead of the tip, the membrane dimpling until it gives), the dose a
//! pressure pulse delivers into a punctured cell, and whether the cell survives; and
//! the faults the twin can inject into a run (a clogged or broken pipette, a cell that
//! moves, a stage that jams, the light going out).
//!
//! Geometry is the plate's: x along the image columns, z along the rows, and height
//! (the tip's `depth`) up the optical axis from the focal plane. Cells are spheres
//! resting on the plate's floor, which lies a mean cell radius below the focal plane
//! (the plate is focused on its cells' equators), so a larger cell stands taller. A3
//! pushes the tip forward along the pipette's axis ([`PipetteParams::axis`]: towards
//! +z and down). The tip dimples and punctures a cell; the glass behind it (its taper
//! and shank, [`PipetteParams::clearance`]) pushes aside any cell it runs into; a tip
//! driven into the floor breaks.

use cellinject_numeric::Rng;
use cellinject_rig::PipetteParams;
use cellinject_rig::pipette::cell_volume;
use cellinject_simparams::CellBiology;
use thiserror::Error;

use crate::camera::{CellLook, TipPose};
use crate::world::TwinError;

/// Why a cell died.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Death {
    /// The tip entered too far off-centre and tore the membrane.
    TornAtEntry,
    /// The tip moved sideways inside the cell.
    TornInside,
    /// The tip went too deep past the centre (the nucleus).
    TooDeep,
    /// Too large a volume was injected.
    Lysed,
}

impl Death {
    /// A short description.
    pub fn describe(self) -> &'static str {
        match self {
            Death::TornAtEntry => "membrane torn: the tip entered too far off-centre",
            Death::TornInside => "membrane torn: the tip moved sideways inside",
            Death::TooDeep => "the tip went too deep (nucleus damaged)",
            Death::Lysed => "lysed: too large a volume",
        }
    }
}

/// One cell's state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellState {
    /// m, resting centre now (x, z); a cell can move in its well.
    pub centre: [f64; 2],
    /// m, resting centre in the plate file.
    pub origin: [f64; 2],
    /// m, radius before any injection.
    pub radius: f64,
    /// m, the centre's height above the focal plane (the floor plus the radius).
    pub height: f64,
    /// m, dimple depth at which this cell's membrane gives.
    pub puncture_dimple: f64,
    /// m, how far the tip pushes the cell now (x, z).
    pub push: [f64; 2],
    /// The tip is inside (the membrane gave and has not resealed).
    pub punctured: bool,
    /// The pipette has touched the cell.
    pub touched: bool,
    /// The glass behind the tip ran into the cell (it was pushed aside by the taper or
    /// the shank, not by the tip).
    pub grazed: bool,
    /// Times the membrane was punctured.
    pub punctures: u32,
    /// m, the tip's lateral (x) extent while inside: min, max.
    pub inside_x: [f64; 2],
    /// m, deepest the tip went past the centre (along the pipette's axis).
    pub max_depth: f64,
    /// m³, injected.
    pub injected: f64,
    /// Dead, and why.
    pub dead: Option<Death>,
}

impl CellState {
    /// Injected volume over the cell's volume.
    pub fn dose_fraction(&self) -> f64 {
        self.injected / cell_volume(2.0 * self.radius)
    }

    fn look(&self, dye_contrast: f64) -> CellLook {
        let f = self.dose_fraction();
        CellLook {
            offset: [
                self.centre[0] - self.origin[0] + self.push[0],
                self.centre[1] - self.origin[1] + self.push[1],
            ],
            scale: (1.0 + f).cbrt(),
            dye: dye_contrast * f,
            dead: self.dead.is_some(),
        }
    }

    fn changed(&self) -> bool {
        self.centre != self.origin
            || self.push != [0.0, 0.0]
            || self.injected > 0.0
            || self.dead.is_some()
    }
}

/// A fault the twin injects, tied to one cell of the plate (index in the plate file's
/// `[[cell]]` order).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Fault {
    /// The pipette clogs when it punctures the cell (no flow); a clearing pulse
    /// (at least 80 % of the injector's pressure limit, outside any cell) clears it,
    /// unless `hard`.
    Clog {
        /// Cell.
        cell: usize,
        /// The clog does not clear.
        hard: bool,
    },
    /// The tip breaks on touching the cell: it is `length` m shorter from then on and
    /// its orifice much wider.
    Break {
        /// Cell.
        cell: usize,
        /// m lost.
        length: f64,
    },
    /// The cell moves by `by` (m, x and z) when the pipette arrives near it.
    CellMoves {
        /// Cell.
        cell: usize,
        /// m.
        by: [f64; 2],
    },
    /// The light goes out for `frames` frames when the pipette arrives near the cell.
    Dark {
        /// Cell.
        cell: usize,
        /// Frames.
        frames: u32,
    },
    /// The stage jams on the first move after the pipette has been near the cell.
    StageStall {
        /// Cell.
        cell: usize,
    },
}

impl Fault {
    /// The cell it is tied to.
    pub fn cell(&self) -> usize {
        match *self {
            Fault::Clog { cell, .. }
            | Fault::Break { cell, .. }
            | Fault::CellMoves { cell, .. }
            | Fault::Dark { cell, .. }
            | Fault::StageStall { cell } => cell,
        }
    }
}

/// What a fault does, without the cell it is tied to (`--fault KIND@...`'s KIND).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultKind {
    /// `clog`: a clog a clearing pulse clears.
    Clog,
    /// `hard-clog`: a clog that does not clear.
    HardClog,
    /// `break`: the tip breaks 6 µm shorter on touching the cell.
    Break,
    /// `move`: the cell moves by (3, 2) µm when the pipette arrives.
    Move,
    /// `dark`: the light goes out for 40 frames when the pipette arrives.
    Dark,
    /// `stall`: the stage jams on its next move.
    Stall,
}

impl FaultKind {
    /// Every kind, by its name on the command line.
    pub const ALL: [(&'static str, FaultKind); 6] = [
        ("clog", FaultKind::Clog),
        ("hard-clog", FaultKind::HardClog),
        ("break", FaultKind::Break),
        ("move", FaultKind::Move),
        ("dark", FaultKind::Dark),
        ("stall", FaultKind::Stall),
    ];

    /// The fault of this kind on the plate file's cell `cell`.
    pub fn on(self, cell: usize) -> Fault {
        match self {
            FaultKind::Clog => Fault::Clog { cell, hard: false },
            FaultKind::HardClog => Fault::Clog { cell, hard: true },
            FaultKind::Break => Fault::Break { cell, length: 6e-6 },
            FaultKind::Move => Fault::CellMoves {
                cell,
                by: [3e-6, 2e-6],
            },
            FaultKind::Dark => Fault::Dark { cell, frames: 40 },
            FaultKind::Stall => Fault::StageStall { cell },
        }
    }
}

/// A fault addressed as the files, records and outputs number cells: the well
/// `[row, col]` (from 0) and the cell's rank in that well, `0` for the top one (the
/// smallest plate y, then the smallest x: the order in which the workflow works
/// through a well). Written `KIND@ROW,COL` or `KIND@ROW,COL,K`, e.g. `clog@0,3` or
/// `break@2,5,1` (the second cell of a doublet).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaultAt {
    /// What happens.
    pub kind: FaultKind,
    /// `[row, col]` of the well.
    pub well: [u32; 2],
    /// The cell's rank in its well, top first.
    pub nth: usize,
}

/// A `--fault` that does not read as `KIND@ROW,COL[,K]`.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error(
    "`{spec}`: {reason}; expected KIND@ROW,COL or KIND@ROW,COL,K (the K-th cell of the well, top first, from 0) with KIND one of clog, hard-clog, break, move, dark, stall, e.g. clog@0,3"
)]
pub struct FaultSpecError {
    /// What was given.
    pub spec: String,
    /// What is wrong with it.
    pub reason: String,
}

impl std::str::FromStr for FaultAt {
    type Err = FaultSpecError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = |reason: &str| FaultSpecError {
            spec: s.to_string(),
            reason: reason.to_string(),
        };
        let (kind, at) = s.split_once('@').ok_or_else(|| bad("no `@`"))?;
        let kind = FaultKind::ALL
            .iter()
            .find(|(name, _)| *name == kind)
            .map(|(_, k)| *k)
            .ok_or_else(|| bad(&format!("unknown kind `{kind}`")))?;
        let parts: Vec<&str> = at.split(',').map(str::trim).collect();
        let number = |t: &str, what: &str| {
            t.parse::<u32>()
                .map_err(|_| bad(&format!("{what} `{t}` is not a whole number from 0")))
        };
        match parts.as_slice() {
            [one] if one.parse::<u32>().is_ok() => Err(bad(
                "a single number no longer names a cell: cells are named by their well, as in the plate file, the records and the outputs",
            )),
            [row, col] | [row, col, _] => Ok(FaultAt {
                kind,
                well: [number(row, "the row")?, number(col, "the column")?],
                nth: match parts.get(2) {
                    Some(k) => number(k, "the cell's rank in its well")? as usize,
                    None => 0,
                },
            }),
            _ => Err(bad("the cell is ROW,COL or ROW,COL,K")),
        }
    }
}

impl FaultAt {
    /// The fault on the plate's cell this address names; refused, naming the well,
    /// when the plate has no such well or no such cell in it.
    pub fn resolve(&self, plate: &cellinject_plate::Plate) -> Result<Fault, TwinError> {
        let [row, col] = self.well;
        if row >= plate.rows || col >= plate.cols {
            return Err(TwinError::Invalid {
                key: "fault".into(),
                reason: format!(
                    "well [{row}, {col}] is not on the {}x{} plate (rows and columns count from 0)",
                    plate.rows, plate.cols
                ),
            });
        }
        let mut here: Vec<(usize, &cellinject_plate::Object)> = plate
            .cells
            .iter()
            .enumerate()
            .filter(|(_, o)| o.well == self.well)
            .collect();
        here.sort_by(|(_, a), (_, b)| {
            a.offset[1]
                .total_cmp(&b.offset[1])
                .then(a.offset[0].total_cmp(&b.offset[0]))
        });
        let (index, _) = here.get(self.nth).ok_or_else(|| TwinError::Invalid {
            key: "fault".into(),
            reason: format!(
                "well [{row}, {col}] holds {} cell{}: no cell {} there (counted from 0, top first)",
                here.len(),
                if here.len() == 1 { "" } else { "s" },
                self.nth
            ),
        })?;
        Ok(self.kind.on(*index))
    }
}

/// What the biology asks of the rest of the twin after an update.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Effects {
    /// Frames of darkness to start.
    pub dark_frames: u32,
    /// The stage should jam on its next move.
    pub stall_stage: bool,
}

/// The cells of a plate, the pipette's state and the pending faults.
#[derive(Debug, Clone)]
pub struct Biology {
    params: CellBiology,
    dye_contrast: f64,
    /// Per cell of the plate.
    pub cells: Vec<CellState>,
    faults: Vec<(Fault, bool)>,
    /// Flow multiplier of the pipette now (1 nominal, 0 clogged, > 1 broken).
    pub flow: f64,
    /// m the tip has lost by breaking.
    pub tip_loss: f64,
    hard_clog: bool,
    /// The stage must jam on its next move.
    pub stall_pending: bool,
    pipette: PipetteParams,
    axis: [f64; 3],
    /// m, the floor's height (below the focal plane).
    pub floor: f64,
    /// Times the tip was driven into the floor (each breaks it).
    pub floor_strikes: u32,
    below_floor: bool,
    /// m, the tallest cell's top above the floor.
    tallest: f64,
}

/// How close (m) to a cell's membrane the tip comes, in focus, for a fault tied to the
/// cell to "arrive" (the workflow stops 6 um before the membrane).
const ARRIVAL: f64 = 20e-6;

impl Biology {
    /// The cells at `centres` (m, x and z) with `radii` (m), resting on a floor a mean
    /// radius below the focal plane, each with its own puncture threshold drawn from
    /// `rng`, met by `pipette`.
    pub fn new(
        params: CellBiology,
        pipette: PipetteParams,
        cells: impl IntoIterator<Item = ([f64; 2], f64)>,
        rng: &mut Rng,
    ) -> Self {
        let cells: Vec<([f64; 2], f64)> = cells.into_iter().collect();
        let mean = if cells.is_empty() {
            0.0
        } else {
            cells.iter().map(|c| c.1).sum::<f64>() / cells.len() as f64
        };
        let floor = -mean;
        let tallest = cells.iter().map(|c| 2.0 * c.1).fold(0.0, f64::max);
        let cells = cells
            .into_iter()
            .map(|(c, r)| CellState {
                centre: c,
                origin: c,
                radius: r,
                height: floor + r,
                puncture_dimple: r * rng.range(params.puncture[0], params.puncture[1]),
                push: [0.0; 2],
                punctured: false,
                touched: false,
                grazed: false,
                punctures: 0,
                inside_x: [0.0; 2],
                max_depth: 0.0,
                injected: 0.0,
                dead: None,
            })
            .collect();
        Biology {
            params,
            dye_contrast: pipette.dye_contrast,
            pipette,
            axis: pipette.axis(),
            floor,
            floor_strikes: 0,
            below_floor: false,
            tallest,
            cells,
            faults: Vec::new(),
            flow: 1.0,
            tip_loss: 0.0,
            hard_clog: false,
            stall_pending: false,
        }
    }

    /// Schedules faults (each fires once).
    pub fn set_faults(&mut self, faults: &[Fault]) {
        self.faults = faults.iter().map(|f| (*f, false)).collect();
    }

    /// The cells that look different from their resting state, for the camera.
    pub fn looks(&self) -> Vec<(usize, CellLook)> {
        self.cells
            .iter()
            .enumerate()
            .filter(|(_, c)| c.changed())
            .map(|(i, c)| (i, c.look(self.dye_contrast)))
            .collect()
    }

    /// The cell the tip is inside, if any.
    pub fn inside(&self) -> Option<usize> {
        self.cells.iter().position(|c| c.punctured)
    }

    /// Updates contact, puncture and viability for the tip at `tip` (its true pose
    /// in the plate's frame, the broken length already taken off).
    pub fn interact(&mut self, tip: &TipPose) -> Effects {
        let mut fx = Effects::default();
        let p = self.params;
        let a = self.axis;
        let t3 = [tip.x, tip.depth, tip.z];
        // The floor: a tip driven into it breaks (2 um of glass lost, the orifice
        // widened), once per strike: a new strike needs the tip lifted 5 um clear.
        if tip.depth < self.floor {
            if !self.below_floor {
                self.below_floor = true;
                self.floor_strikes += 1;
                self.tip_loss += 2e-6;
                self.flow *= 30.0;
            }
        } else if tip.depth > self.floor + 5e-6 {
            self.below_floor = false;
        }
        // How far behind the tip (in the plate's plane) the glass still comes down to
        // the tallest cell's top.
        let (sin, cos) = (-a[1], a[2]);
        let top = self.floor + self.tallest;
        let shank = self.pipette.shank_radius;
        let glass_reach = if sin > 1e-6 {
            ((top - tip.depth + shank * cos).max(0.0) / sin) * cos + shank + self.tallest
        } else {
            f64::INFINITY
        };
        for k in 0..self.cells.len() {
            let c = &mut self.cells[k];
            let (dx, dz) = (tip.x - c.centre[0], tip.z - c.centre[1]);
            let dy = tip.depth - c.height;
            let d = (dx * dx + dy * dy + dz * dz).sqrt();
            let far = d > c.radius + ARRIVAL && !c.punctured && c.push == [0.0, 0.0];
            if far && dx.hypot(dz) > glass_reach + c.radius {
                continue;
            }
            // Faults tied to this cell fire on arrival (the tip within 20 um of the
            // membrane) or on touch.
            let touching = d < c.radius;
            let near = d < c.radius + ARRIVAL;
            for (f, fired) in self.faults.iter_mut() {
                if *fired || f.cell() != k {
                    continue;
                }
                match *f {
                    Fault::CellMoves { by, .. } if near => {
                        c.centre = [c.centre[0] + by[0], c.centre[1] + by[1]];
                        *fired = true;
                    }
                    Fault::Dark { frames, .. } if near => {
                        fx.dark_frames = frames;
                        *fired = true;
                    }
                    Fault::StageStall { .. } if near => {
                        fx.stall_stage = true;
                        *fired = true;
                    }
                    Fault::Break { length, .. } if touching => {
                        self.tip_loss += length;
                        self.flow *= 30.0;
                        *fired = true;
                    }
                    _ => {}
                }
            }
            let (dx, dz) = (tip.x - c.centre[0], tip.z - c.centre[1]);
            let d = (dx * dx + dy * dy + dz * dz).sqrt();
            // Along the axis past the centre, and off the axis.
            let along = dx * a[0] + dy * a[1] + dz * a[2];
            let off = (d * d - along * along).max(0.0).sqrt();
            if !c.punctured {
                let advance = c.radius - d;
                if advance <= 0.0 || d == 0.0 {
                    // The tip is outside: the glass behind it may still press the cell
                    // aside (away from the axis, in the plate's plane). A cell at the
                    // tip itself is the tip's (its membrane just resealed behind it).
                    let gap = if d < c.radius + self.pipette.tip_outer_radius + 0.5e-6 {
                        0.0
                    } else {
                        self.pipette.clearance(
                            t3,
                            a,
                            [c.centre[0], c.height, c.centre[1]],
                            c.radius,
                        )
                    };
                    if gap < 0.0 {
                        c.touched = true;
                        c.grazed = true;
                        // From the axis to the centre, in the plate's plane.
                        let (ux, uz) = (-dx, -(dz - along * a[2]));
                        let n = ux.hypot(uz);
                        c.push = if n > 0.0 {
                            [-gap * ux / n, -gap * uz / n]
                        } else {
                            [-gap, 0.0]
                        };
                    } else {
                        c.push = [0.0; 2];
                    }
                    continue;
                }
                c.touched = true;
                let dimple = (1.0 - p.push_fraction) * advance;
                if dimple < c.puncture_dimple {
                    // Pushed away from the tip, along the plate (the floor holds it).
                    let s = p.push_fraction * advance / d;
                    c.push = [-dx * s, -dz * s];
                    continue;
                }
                c.punctured = true;
                c.punctures += 1;
                c.push = [0.0; 2];
                c.inside_x = [tip.x, tip.x];
                if off > p.tear_offset * c.radius && c.dead.is_none() {
                    c.dead = Some(Death::TornAtEntry);
                }
                for (f, fired) in self.faults.iter_mut() {
                    if let Fault::Clog { cell, hard } = *f
                        && cell == k
                        && !*fired
                    {
                        self.flow = 0.0;
                        self.hard_clog = hard;
                        *fired = true;
                    }
                }
            }
            // Inside.
            if d < c.radius {
                c.inside_x = [c.inside_x[0].min(tip.x), c.inside_x[1].max(tip.x)];
                c.max_depth = c.max_depth.max(along);
                if c.dead.is_none() {
                    if c.inside_x[1] - c.inside_x[0] > p.tear_travel * c.radius {
                        c.dead = Some(Death::TornInside);
                    } else if along > p.lethal_depth * c.radius {
                        c.dead = Some(Death::TooDeep);
                    }
                }
            } else {
                // The tip left the cell (the membrane reseals behind it; leaving through
                // the far side means it went too deep on the way).
                c.punctured = false;
            }
        }
        fx
    }

    /// A pressure pulse delivering `volume` m³ (already through the pipette's flow):
    /// into the cell the tip is inside, or into the medium. A pulse of at least
    /// `clear_pressure` Pa in the medium clears a soft clog.
    pub fn pulse(&mut self, volume: f64, pressure: f64, clear_pressure: f64) {
        match self.inside() {
            Some(k) => {
                let c = &mut self.cells[k];
                c.injected += volume;
                if c.dose_fraction() > self.params.lethal_dose && c.dead.is_none() {
                    c.dead = Some(Death::Lysed);
                }
            }
            None => {
                if self.flow == 0.0 && !self.hard_clog && pressure >= clear_pressure {
                    self.flow = 1.0;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fault_names_its_cell_by_well_and_rank_top_first() {
        use cellinject_plate::{Object, Plate};
        let cell = |well, offset: [f64; 2]| Object {
            well,
            offset,
            diameter: 12e-6,
        };
        // File order: the doublet's lower cell is listed first.
        let plate = Plate {
            rows: 2,
            cols: 3,
            pitch: 150e-6,
            origin: [0.0, 0.0],
            cells: vec![
                cell([0, 0], [0.0, 0.0]),
                cell([1, 2], [0.0, 10e-6]),
                cell([1, 2], [0.0, -10e-6]),
            ],
            debris: vec![],
        };
        let at = |s: &str| s.parse::<FaultAt>().unwrap().resolve(&plate);
        assert_eq!(
            at("clog@0,0").unwrap(),
            Fault::Clog {
                cell: 0,
                hard: false
            }
        );
        // Top first: rank 0 is the cell with the smaller y (file index 2).
        assert_eq!(at("stall@1,2").unwrap(), Fault::StageStall { cell: 2 });
        assert_eq!(at("stall@1,2,1").unwrap(), Fault::StageStall { cell: 1 });
        let e = at("stall@1,2,2").unwrap_err().to_string();
        assert!(e.contains("holds 2 cells: no cell 2"), "{e}");
        let e = at("dark@2,0").unwrap_err().to_string();
        assert!(e.contains("well [2, 0] is not on the 2x3 plate"), "{e}");
        let e = at("dark@0,1").unwrap_err().to_string();
        assert!(e.contains("holds 0 cells"), "{e}");
        for (bad, why) in [
            ("clog@3", "no longer names a cell"),
            ("melt@0,0", "unknown kind `melt`"),
            ("clog", "no `@`"),
            ("clog@0,-1", "the column `-1`"),
            ("clog@0,1,2,3", "ROW,COL or ROW,COL,K"),
        ] {
            let e = bad.parse::<FaultAt>().unwrap_err().to_string();
            assert!(e.contains(why) && e.contains(bad), "{bad}: {e}");
        }
    }

    fn one_cell() -> Biology {
        let mut rng = Rng::new(1, 99);
        Biology::new(
            CellBiology {
                // The membrane gives at a 1.35 um dimple (a 2.7 um advance).
                puncture: [0.15, 0.15],
                ..CellBiology::default()
            },
            // In the plate's plane (angle 0), as the tests' paths run along z.
            PipetteParams {
                angle: 0.0,
                ..PipetteParams::default()
            },
            [([0.0, 0.0], 9e-6)],
            &mut rng,
        )
    }

    fn tip(x: f64, z: f64) -> TipPose {
        TipPose {
            x,
            z,
            ..TipPose::default()
        }
    }

    #[test]
    fn the_membrane_gives_after_the_cell_was_pushed_and_then_relaxes() {
        let mut b = one_cell();
        let threshold = b.cells[0].puncture_dimple;
        let mut last_push = 0.0;
        let mut gave_at = None;
        let mut z = -12e-6;
        while z < 0.0 {
            b.interact(&tip(0.0, z));
            let c = b.cells[0];
            if c.punctured {
                gave_at = Some(z);
                assert_eq!(
                    c.push,
                    [0.0, 0.0],
                    "the cell snaps back when the membrane gives"
                );
                break;
            }
            assert!(c.push[1] >= last_push, "pushed ahead of the tip");
            last_push = c.push[1];
            z += 0.05e-6;
        }
        let z = gave_at.expect("gave before the centre");
        // Advance into the undeformed cell at the give: dimple / (1 - push fraction).
        let advance = 9e-6 + z;
        assert!(
            (advance * 0.5 - threshold).abs() < 0.05e-6,
            "{advance} {threshold}"
        );
        assert!(
            last_push > 0.5 * threshold,
            "visible push before the give: {last_push}"
        );
        assert!(b.cells[0].dead.is_none());
    }

    #[test]
    fn too_deep_and_sideways_kill_and_a_clean_entry_and_exit_does_not() {
        for (path, dead) in [
            (vec![(0.0, -10e-6), (0.0, 0.0), (0.0, -10e-6)], None),
            (vec![(0.0, -10e-6), (0.0, 5e-6)], Some(Death::TooDeep)),
            (
                vec![(0.0, -10e-6), (0.0, 0.0), (4e-6, 0.0)],
                Some(Death::TornInside),
            ),
            // 5.8 um off-centre (tear limit 5.4 um): the membrane gives, torn.
            (
                vec![(5.8e-6, -10e-6), (5.8e-6, 0.0)],
                Some(Death::TornAtEntry),
            ),
            // 7 um off-centre: the tip only pushes the cell aside, never enters.
            (vec![(7e-6, -10e-6), (7e-6, 0.0), (7e-6, -10e-6)], None),
            (vec![(0.0, -10e-6), (0.0, 12e-6)], Some(Death::TooDeep)),
        ] {
            let mut b = one_cell();
            let mut at = path[0];
            for &(x, z) in &path[1..] {
                for k in 1..=400 {
                    let a = k as f64 / 400.0;
                    b.interact(&tip(at.0 + a * (x - at.0), at.1 + a * (z - at.1)));
                }
                at = (x, z);
            }
            assert_eq!(b.cells[0].dead, dead, "{path:?}");
        }
    }

    #[test]
    fn a_pulse_doses_the_cell_the_tip_is_in_and_too_much_lyses_it() {
        let mut b = one_cell();
        for k in 0..=100 {
            b.interact(&tip(0.0, -10e-6 + k as f64 * 0.1e-6));
        }
        assert!(b.cells[0].punctured);
        let v = cell_volume(18e-6);
        b.pulse(0.05 * v, 2e4, 1.6e5);
        assert!((b.cells[0].dose_fraction() - 0.05).abs() < 1e-12);
        assert!(b.cells[0].dead.is_none());
        b.pulse(0.11 * v, 2e4, 1.6e5);
        assert_eq!(b.cells[0].dead, Some(Death::Lysed));
    }
}
