//! Fields of view over a plate larger than the microscope sees (issue 21): the feeder
//! stage brings the plate under the objective one field at a time.
//!
//! Frames: a plate's coordinates are its file's (`origin + (col·pitch, row·pitch)`,
//! the stage frame with the feeder at home, `[0, 0]`). Moving the feeder to `f` moves
//! the whole plate by `+f`. The workflow works in a *window*: the part of the camera's
//! view where a cell can be found and reached (inside the frame, clear of its edges,
//! below the band the pipette needs above the top row). A field is the rectangle of
//! plate coordinates that the feeder puts in the window; the feeder position that does
//! it is [`Field::feeder`] = window centre − field centre.
//!
//! Fields are laid on the plate's outer walls as a grid with an overlap between
//! neighbours larger than a cell (so that a cell on a boundary is whole in at least
//! one field), evenly spaced, and visited row by row in alternating direction (a
//! serpentine: every move is to a neighbour). Each field *owns* a core (the fields'
//! cores partition the plane at the midpoints between neighbouring centres); a cell
//! is injected in the field that owns its centre, and a cell found in two fields is
//! one cell (the workflow also drops a cell within a radius of one already attempted:
//! a centre measured on a boundary may fall in either core).
//!
//! **Architecture invariant:** pure geometry: no devices, no files, no clock.

use thiserror::Error;

use crate::{CELL_MAX, Plate};

/// Smallest overlap between neighbouring fields, m: a cell's diameter plus 10 µm for
/// the membrane's blur and the detector's margin at a frame's edge.
pub const MIN_OVERLAP: f64 = CELL_MAX + 10e-6;

/// The part of the view where cells are found and reached, in the stage frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    /// m, its centre.
    pub centre: [f64; 2],
    /// m, its width (x) and height (y).
    pub size: [f64; 2],
}

/// The feeder stage's reach: the positions it can take on each axis, m.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Travel {
    /// Lowest position of x and y.
    pub lo: [f64; 2],
    /// Highest position of x and y.
    pub hi: [f64; 2],
}

/// One field of view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Field {
    /// Its number in the visiting order, from 0.
    pub index: usize,
    /// `[row, col]` in the grid of fields.
    pub grid: [u32; 2],
    /// m, plate coordinates of its centre.
    pub centre: [f64; 2],
    /// m, the plate rectangle in the window: `[x_lo, y_lo, x_hi, y_hi]`.
    pub rect: [f64; 4],
    /// m, the part of the plane it owns: `[x_lo, y_lo, x_hi, y_hi]` (infinite at the
    /// plan's outer edges).
    pub core: [f64; 4],
    /// m, the feeder's position that puts the field in the window.
    pub feeder: [f64; 2],
}

impl Field {
    /// Whether the field owns plate point `p` (its core contains it, lower edges
    /// included).
    pub fn owns(&self, p: [f64; 2]) -> bool {
        p[0] >= self.core[0] && p[1] >= self.core[1] && p[0] < self.core[2] && p[1] < self.core[3]
    }

    /// Whether the disc of radius `r` around plate point `p` lies wholly in the field.
    pub fn holds(&self, p: [f64; 2], r: f64) -> bool {
        p[0] - r >= self.rect[0]
            && p[1] - r >= self.rect[1]
            && p[0] + r <= self.rect[2]
            && p[1] + r <= self.rect[3]
    }
}

/// The fields over a plate, in visiting order.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldPlan {
    /// Every field, in the order the feeder visits them.
    pub fields: Vec<Field>,
    /// Rows and columns of the grid of fields.
    pub grid: [u32; 2],
    /// m, the smallest overlap between neighbours along x and y (`f64::INFINITY`
    /// along an axis with one field).
    pub overlap: [f64; 2],
}

impl FieldPlan {
    /// The field that owns plate point `p`.
    pub fn owner(&self, p: [f64; 2]) -> &Field {
        self.fields
            .iter()
            .find(|f| f.owns(p))
            .expect("the cores partition the plane")
    }

    /// The feeder's path length over the plan, m (from the first field to the last).
    pub fn path_length(&self) -> f64 {
        self.fields
            .windows(2)
            .map(|w| (w[1].feeder[0] - w[0].feeder[0]).hypot(w[1].feeder[1] - w[0].feeder[1]))
            .sum()
    }
}

/// Why a plate cannot be tiled.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PlanError {
    /// The window is too small to hold a well and the overlap.
    #[error(
        "the view's usable window is {:.0} x {:.0} µm at this zoom: a field must hold a {:.0} µm well plus {:.0} µm of overlap; use a lower zoom",
        window[0] * 1e6, window[1] * 1e6, pitch * 1e6, overlap * 1e6
    )]
    WindowTooSmall {
        /// m.
        window: [f64; 2],
        /// m.
        pitch: f64,
        /// m.
        overlap: f64,
    },
    /// Wells the feeder cannot bring into the window.
    #[error("{}", out_of_travel_message(wells, *worst, hint))]
    OutOfTravel {
        /// Every well out of reach, `[row, col]`.
        wells: Vec<[u32; 2]>,
        /// m, how far the worst of them lies beyond the reach.
        worst: f64,
        /// m, the smallest move of the plate's origin that brings every well within
        /// reach, if one exists.
        hint: Option<[f64; 2]>,
    },
    /// A setting out of its domain.
    #[error("{what} {value} is not valid: {reason}")]
    Invalid {
        /// Which.
        what: &'static str,
        /// Its value.
        value: f64,
        /// Why.
        reason: &'static str,
    },
}

fn out_of_travel_message(wells: &[[u32; 2]], worst: f64, hint: &Option<[f64; 2]>) -> String {
    let rows = wells.iter().map(|w| w[0]);
    let cols = wells.iter().map(|w| w[1]);
    let (r0, r1) = (rows.clone().min().unwrap_or(0), rows.max().unwrap_or(0));
    let (c0, c1) = (cols.clone().min().unwrap_or(0), cols.max().unwrap_or(0));
    let listed = if wells.len() <= 6 {
        wells
            .iter()
            .map(|w| format!("[{}, {}]", w[0], w[1]))
            .collect::<Vec<_>>()
            .join(", ")
    } else {
        format!(
            "{} wells in rows {r0}-{r1}, columns {c0}-{c1} (first [{}, {}], last [{}, {}])",
            wells.len(),
            wells[0][0],
            wells[0][1],
            wells[wells.len() - 1][0],
            wells[wells.len() - 1][1]
        )
    };
    let fix = match hint {
        Some(h) => format!(
            "; moving the plate's origin by ({:+.3}, {:+.3}) mm in stage x and y brings every well within reach",
            h[0] * 1e3,
            h[1] * 1e3
        ),
        None => "; the plate is larger than the feeder can present: split it".to_string(),
    };
    format!(
        "{listed} lie outside the feeder stage's travel, the worst by {:.3} mm{fix}",
        worst * 1e3
    )
}

/// The fields over `plate`'s outer walls for a `window` and a feeder of `travel`,
/// with at least `overlap` m between neighbours (at least [`MIN_OVERLAP`]).
///
/// Refused, naming the wells, when the feeder cannot bring every well into the window;
/// nothing is planned then.
pub fn plan(
    plate: &Plate,
    window: Window,
    overlap: f64,
    travel: Travel,
) -> Result<FieldPlan, PlanError> {
    plan_near(plate, window, overlap, travel, None)
}

/// [`plan_near`]'s inputs: an overlap of at least [`MIN_OVERLAP`], a finite window
/// and a finite feeder travel with lo <= hi.
fn check_plan_inputs(window: Window, overlap: f64, travel: Travel) -> Result<(), PlanError> {
    if !(overlap.is_finite() && overlap >= MIN_OVERLAP) {
        return Err(PlanError::Invalid {
            what: "overlap",
            value: overlap,
            reason: "must be at least a cell plus 10 µm (40 µm)",
        });
    }
    for v in window.centre.iter().chain(&window.size) {
        if !v.is_finite() {
            return Err(PlanError::Invalid {
                what: "window",
                value: *v,
                reason: "must be finite",
            });
        }
    }
    for a in 0..2 {
        if !(travel.lo[a].is_finite() && travel.hi[a].is_finite() && travel.lo[a] <= travel.hi[a]) {
            return Err(PlanError::Invalid {
                what: "feeder travel",
                value: travel.hi[a] - travel.lo[a],
                reason: "must be finite with lo <= hi",
            });
        }
    }
    Ok(())
}

/// [`plan`], with the feeder now at `at`: along an axis where one field holds the whole
/// plate, the feeder stays where it is when the plate is then in the window (no
/// needless move; a plate put under the objective by hand is served where it lies),
/// else the plate is centred as [`plan`] does.
pub fn plan_near(
    plate: &Plate,
    window: Window,
    overlap: f64,
    travel: Travel,
    at: Option<[f64; 2]>,
) -> Result<FieldPlan, PlanError> {
    check_plan_inputs(window, overlap, travel)?;
    let half = 0.5 * plate.pitch;
    // The plate's outer walls.
    let lo = [plate.origin[0] - half, plate.origin[1] - half];
    let span = [
        plate.cols as f64 * plate.pitch,
        plate.rows as f64 * plate.pitch,
    ];
    if window.size[0] < plate.pitch + overlap || window.size[1] < plate.pitch + overlap {
        return Err(PlanError::WindowTooSmall {
            window: window.size,
            pitch: plate.pitch,
            overlap,
        });
    }
    // Every well must fit in the window with the feeder inside its travel: the well
    // square [c − h, c + h] fits when some f in the travel has wlo <= c − h + f and
    // c + h + f <= whi, i.e. f in [wlo − (c − h), whi − (c + h)] (see `reach_at`).
    let mut wells = Vec::new();
    let mut worst = 0.0f64;
    for row in 0..plate.rows {
        for col in 0..plate.cols {
            let c = plate.well_centre([row, col]);
            let miss = reach_at(0, c[0], half, window, travel)
                .max(reach_at(1, c[1], half, window, travel));
            // A nanometre of slack: a plate moved by the hint lands on the edge.
            if miss > 1e-9 {
                wells.push([row, col]);
                worst = worst.max(miss);
            }
        }
    }
    if !wells.is_empty() {
        // The plate moved by s along an axis serves every well when, for the extreme
        // well centres c_min and c_max, wlo + h − thi − c_min <= s <= whi − h − tlo −
        // c_max; the hint is the smallest such move.
        let mut hint = Some([0.0; 2]);
        for a in 0..2 {
            let wlo = window.centre[a] - 0.5 * window.size[a];
            let whi = window.centre[a] + 0.5 * window.size[a];
            let c_min = lo[a] + half;
            let c_max = lo[a] + span[a] - half;
            let s_lo = wlo + half - travel.hi[a] - c_min;
            let s_hi = whi - half - travel.lo[a] - c_max;
            match hint.as_mut() {
                Some(h) if s_lo <= s_hi => h[a] = 0.0f64.clamp(s_lo, s_hi),
                _ => hint = None,
            }
        }
        return Err(PlanError::OutOfTravel { wells, worst, hint });
    }
    // Per axis: the number of fields and their centres, evenly spaced so that the
    // first's low edge is the plate's low wall and the last's high edge its high wall.
    // Every feeder position is then within the travel: the first field's is the
    // lowest position that holds the first well and the last field's the highest that
    // holds the last, both reachable, and the others lie between.
    let mut centres: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    let mut min_overlap = [f64::INFINITY; 2];
    for a in 0..2 {
        let w = window.size[a];
        let n = if span[a] <= w {
            1
        } else {
            ((span[a] - overlap) / (w - overlap)).ceil().max(2.0) as usize
        };
        let c: Vec<f64> = if n == 1 {
            // Centred on the plate if the feeder reaches that, else as near as it
            // reaches with the whole plate in the window (such a position exists
            // when the first and the last well are both within reach).
            let (wlo, whi) = (window.centre[a] - 0.5 * w, window.centre[a] + 0.5 * w);
            let f_lo = travel.lo[a].max(wlo - lo[a]);
            let f_hi = travel.hi[a].min(whi - lo[a] - span[a]);
            let centred = (window.centre[a] - (lo[a] + 0.5 * span[a])).clamp(f_lo.min(f_hi), f_hi);
            let f = match at {
                Some(at) if at[a] >= f_lo && at[a] <= f_hi => at[a],
                _ => centred,
            };
            vec![window.centre[a] - f]
        } else {
            let step = (span[a] - w) / (n - 1) as f64;
            (0..n).map(|k| lo[a] + 0.5 * w + k as f64 * step).collect()
        };
        for k in 1..c.len() {
            min_overlap[a] = min_overlap[a].min(w - (c[k] - c[k - 1]));
        }
        centres[a] = c;
    }
    let (nx, ny) = (centres[0].len(), centres[1].len());
    let edge = |c: &[f64], k: usize, low: bool| -> f64 {
        if low {
            if k == 0 {
                f64::NEG_INFINITY
            } else {
                0.5 * (c[k - 1] + c[k])
            }
        } else if k + 1 == c.len() {
            f64::INFINITY
        } else {
            0.5 * (c[k] + c[k + 1])
        }
    };
    let mut fields = Vec::with_capacity(nx * ny);
    for gy in 0..ny {
        for step in 0..nx {
            let gx = if gy % 2 == 0 { step } else { nx - 1 - step };
            let centre = [centres[0][gx], centres[1][gy]];
            fields.push(Field {
                index: fields.len(),
                grid: [gy as u32, gx as u32],
                centre,
                rect: [
                    centre[0] - 0.5 * window.size[0],
                    centre[1] - 0.5 * window.size[1],
                    centre[0] + 0.5 * window.size[0],
                    centre[1] + 0.5 * window.size[1],
                ],
                core: [
                    edge(&centres[0], gx, true),
                    edge(&centres[1], gy, true),
                    edge(&centres[0], gx, false),
                    edge(&centres[1], gy, false),
                ],
                feeder: [window.centre[0] - centre[0], window.centre[1] - centre[1]],
            });
        }
    }
    Ok(FieldPlan {
        fields,
        grid: [ny as u32, nx as u32],
        overlap: min_overlap,
    })
}

/// How far the feeder's travel misses bringing the square of half-side `half` around
/// plate coordinate `c` (axis `a`) into the window (0: it can).
fn reach_at(a: usize, c: f64, half: f64, window: Window, travel: Travel) -> f64 {
    let wlo = window.centre[a] - 0.5 * window.size[a];
    let whi = window.centre[a] + 0.5 * window.size[a];
    let (need_lo, need_hi) = (wlo - (c - half), whi - (c + half));
    (need_lo - travel.hi[a])
        .max(travel.lo[a] - need_hi)
        .max(0.0)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use crate::{GenerateOptions, generate};
    use proptest::prelude::*;

    fn grid(rows: u32, cols: u32, pitch: f64, origin: [f64; 2]) -> Plate {
        Plate {
            rows,
            cols,
            pitch,
            origin,
            cells: vec![],
            debris: vec![],
        }
    }

    const WINDOW: Window = Window {
        centre: [0.0, 0.1e-3],
        size: [2.2e-3, 1.4e-3],
    };
    const TRAVEL: Travel = Travel {
        lo: [-12.5e-3; 2],
        hi: [12.5e-3; 2],
    };

    #[test]
    fn a_plate_inside_the_window_is_one_field_centred_on_it() {
        let p = grid(4, 6, 150e-6, [-0.375e-3, -0.125e-3]);
        let plan = plan(&p, WINDOW, MIN_OVERLAP, TRAVEL).unwrap();
        assert_eq!(plan.fields.len(), 1);
        let f = plan.fields[0];
        // The walls' centre: origin + ((cols − 1)/2, (rows − 1)/2)·pitch.
        assert!((f.centre[0] - (-0.375e-3 + 2.5 * 150e-6)).abs() < 1e-12);
        assert!((f.centre[1] - (-0.125e-3 + 1.5 * 150e-6)).abs() < 1e-12);
        assert!((f.feeder[0] - (WINDOW.centre[0] - f.centre[0])).abs() < 1e-15);
        assert_eq!(plan.path_length(), 0.0);
    }

    #[test]
    fn a_plate_already_in_the_window_stays_where_it_lies() {
        let p = grid(4, 6, 150e-6, [-0.375e-3, -0.125e-3]);
        // With the feeder at 0 the walls span x [-0.45, 0.45] mm, y [-0.2, 0.4] mm:
        // inside the window (x ±1.1 mm, y [-0.6, 0.8] mm), so nothing moves.
        let plan = plan_near(&p, WINDOW, MIN_OVERLAP, TRAVEL, Some([0.0, 0.0])).unwrap();
        assert_eq!(plan.fields.len(), 1);
        assert_eq!(plan.fields[0].feeder, [0.0, 0.0]);
        // The field still holds every well at that feeder position.
        let f = plan.fields[0];
        for w in [[0, 0], [3, 5]] {
            assert!(f.holds(p.well_centre(w), 75e-6), "{w:?}");
        }
        // A feeder 0.7 mm off along x leaves the plate's right wall at 1.15 mm, out of
        // the window: that axis is centred, the other stays.
        let plan = plan_near(&p, WINDOW, MIN_OVERLAP, TRAVEL, Some([0.7e-3, 0.0])).unwrap();
        let f = plan.fields[0];
        assert!((f.feeder[0] - (WINDOW.centre[0] - f.centre[0])).abs() < 1e-15);
        assert!((f.centre[0] - (-0.375e-3 + 2.5 * 150e-6)).abs() < 1e-12);
        assert_eq!(f.feeder[1], 0.0);
    }

    #[test]
    fn a_2400_well_plate_is_tiled_in_a_serpentine_with_the_overlap_asked() {
        let p = grid(40, 60, 150e-6, [1e-3, -2e-3]);
        let plan = plan(&p, WINDOW, 60e-6, TRAVEL).unwrap();
        // 9 mm across a 2.2 mm window with 60 µm of overlap: ceil((9 − 0.06)/(2.2 −
        // 0.06)) = 5 columns; 6 mm over 1.4 mm: ceil(5.94/1.34) = 5 rows.
        assert_eq!(plan.grid, [5, 5]);
        assert!(
            plan.overlap[0] >= 60e-6 && plan.overlap[1] >= 60e-6,
            "{:?}",
            plan.overlap
        );
        for w in plan.fields.windows(2) {
            let d = (w[0].grid[0].abs_diff(w[1].grid[0])) + (w[0].grid[1].abs_diff(w[1].grid[1]));
            assert_eq!(d, 1, "{:?} then {:?}", w[0].grid, w[1].grid);
        }
        // Row 0 left to right, row 1 right to left.
        assert_eq!(plan.fields[4].grid, [0, 4]);
        assert_eq!(plan.fields[5].grid, [1, 4]);
    }

    #[test]
    fn wells_beyond_the_feeders_reach_are_named_with_the_move_that_fixes_it() {
        // 12 mm of plate to the right of a ±12.5 mm feeder's reach: the window's
        // 1.1 mm half-width adds to the reach, so walls beyond 13.6 mm are out.
        let p = grid(3, 10, 150e-6, [12.4e-3, 0.0]);
        let e = plan(&p, WINDOW, MIN_OVERLAP, TRAVEL).unwrap_err();
        let PlanError::OutOfTravel { wells, worst, hint } = &e else {
            panic!("{e}")
        };
        // Wells whose right wall lies beyond 12.5 + 1.1 = 13.6 mm: col·0.15 + 12.4 +
        // 0.075 > 13.6, i.e. col >= 8 (7.5 → 8), on each of the 3 rows.
        assert_eq!(wells.len(), 6, "{wells:?}");
        assert!(wells.iter().all(|w| w[1] >= 8));
        // Column 9's wall at 12.4 + 1.35 + 0.075 = 13.825 mm: 0.225 mm out.
        assert!((worst - 0.225e-3).abs() < 1e-9, "{worst}");
        let h = hint.unwrap();
        assert!((h[0] + 0.225e-3).abs() < 1e-9 && h[1] == 0.0, "{h:?}");
        let msg = e.to_string();
        assert!(msg.contains("[0, 8]") && msg.contains("0.225 mm"), "{msg}");
        // Moved as the hint says, it is served.
        let moved = grid(3, 10, 150e-6, [12.4e-3 + h[0], 0.0]);
        assert!(plan(&moved, WINDOW, MIN_OVERLAP, TRAVEL).is_ok());
    }

    #[test]
    fn a_plate_wider_than_the_reach_has_no_hint_and_a_tiny_window_is_refused() {
        let p = grid(2, 1000, 150e-6, [-75e-3, 0.0]);
        let e = plan(&p, WINDOW, MIN_OVERLAP, TRAVEL).unwrap_err();
        assert!(e.to_string().contains("split it"), "{e}");
        assert!(e.to_string().contains("wells in rows 0-1"), "{e}");
        let small = Window {
            centre: [0.0; 2],
            size: [150e-6, 1e-3],
        };
        let p = grid(2, 2, 150e-6, [0.0; 2]);
        assert!(matches!(
            plan(&p, small, MIN_OVERLAP, TRAVEL),
            Err(PlanError::WindowTooSmall { .. })
        ));
        assert!(matches!(
            plan(&p, WINDOW, 10e-6, TRAVEL),
            Err(PlanError::Invalid { .. })
        ));
    }

    #[test]
    fn every_cell_of_a_generated_plate_is_whole_in_the_field_that_owns_it() {
        let p = generate(&GenerateOptions {
            rows: 20,
            cols: 30,
            doublet_fraction: 0.3,
            origin: [-2e-3, 1e-3],
            seed: 4,
            ..GenerateOptions::default()
        })
        .unwrap();
        let plan = plan(&p, WINDOW, MIN_OVERLAP, TRAVEL).unwrap();
        assert!(plan.fields.len() > 4);
        for c in &p.cells {
            let at = p.centre(c);
            let owner = plan.owner(at);
            assert!(owner.holds(at, 0.5 * c.diameter), "{c:?} in {owner:?}");
            assert_eq!(plan.fields.iter().filter(|f| f.owns(at)).count(), 1);
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        #[test]
        fn plans_cover_every_well_within_the_travel_or_name_what_is_out(
            rows in 1u32..60, cols in 1u32..60, pitch in 40e-6..600e-6f64,
            ox in -20e-3..20e-3f64, oy in -20e-3..20e-3f64,
            ww in 0.7e-3..3e-3f64, wh in 0.7e-3..3e-3f64,
            overlap in MIN_OVERLAP..200e-6, t in 1e-3..15e-3f64,
        ) {
            let p = grid(rows, cols, pitch, [ox, oy]);
            let window = Window { centre: [0.1e-3, 0.2e-3], size: [ww, wh] };
            let travel = Travel { lo: [-t; 2], hi: [t; 2] };
            // Independently: a well can be held when the feeder interval that puts its
            // square in the window meets the travel, on both axes.
            let holdable = |c: [f64; 2]| (0..2).all(|a| {
                let lo = window.centre[a] - 0.5 * window.size[a];
                let hi = window.centre[a] + 0.5 * window.size[a];
                let (f_lo, f_hi) = (lo - (c[a] - 0.5 * pitch), hi - (c[a] + 0.5 * pitch));
                f_lo <= f_hi && f_lo <= t && f_hi >= -t
            });
            match plan(&p, window, overlap, travel) {
                Ok(plan) => {
                    for f in &plan.fields {
                        for a in 0..2 {
                            prop_assert!(f.feeder[a] >= -t - 1e-12 && f.feeder[a] <= t + 1e-12);
                        }
                    }
                    prop_assert!(plan.overlap[0] >= overlap - 1e-12);
                    prop_assert!(plan.overlap[1] >= overlap - 1e-12);
                    for row in 0..rows {
                        for col in 0..cols {
                            let c = p.well_centre([row, col]);
                            prop_assert!(holdable(c));
                            // Any point of the well (a cell's centre) is whole, with
                            // half the least overlap around it, in the field owning it.
                            for d in [[-0.5, -0.5], [0.5, 0.5], [0.0, 0.0], [-0.5, 0.5]] {
                                let r = 0.5 * MIN_OVERLAP;
                                let q = [
                                    c[0] + d[0] * (pitch - 2.0 * r),
                                    c[1] + d[1] * (pitch - 2.0 * r),
                                ];
                                prop_assert!(plan.owner(q).holds(q, r - 1e-12));
                            }
                        }
                    }
                }
                Err(PlanError::OutOfTravel { wells, hint, .. }) => {
                    for row in 0..rows {
                        for col in 0..cols {
                            let out = !holdable(p.well_centre([row, col]));
                            prop_assert_eq!(out, wells.contains(&[row, col]));
                        }
                    }
                    if let Some(h) = hint {
                        let moved = grid(rows, cols, pitch, [ox + h[0], oy + h[1]]);
                        prop_assert!(plan(&moved, window, overlap, travel).is_ok());
                    }
                }
                Err(PlanError::WindowTooSmall { .. }) => {
                    prop_assert!(ww < pitch + overlap || wh < pitch + overlap);
                }
                Err(e) => prop_assert!(false, "{e}"),
            }
        }
    }
}
