//! Planning the pipette's way into a cell: the glass's clearance, in three dimensions,
//! past every neighbour.
//!
//! The pipette comes down its axis at the mount angle to the plate
//! ([`PipetteParams::axis`]) and A3 drives the tip from the start of the approach to
//! the cell's centre and at most `reach` past it. Sweeping a glass that only widens
//! behind its tip along its own axis covers exactly the glass at the deepest point:
//! every section the earlier positions held lies inside it. So the approach is clear
//! when the glass with its tip at the deepest point keeps `margin` from every
//! neighbour ([`PipetteParams::clearance`]: the cone, the shank, the flat tip). Heights
//! matter: a neighbour taller than the target (a larger cell resting on the same
//! floor) reaches higher into the glass's way.
//!
//! Frame: stage x and z in the plate's plane, height up from the focal plane; the
//! pipette's forward direction in the plane is A3's, measured by the image map.

use cellinject_rig::PipetteParams;

/// A cell as a sphere resting on the plate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sphere {
    /// Order in the survey.
    pub index: usize,
    /// [row, column].
    pub well: [u32; 2],
    /// m, stage x, height above the focal plane, stage z.
    pub centre: [f64; 3],
    /// m.
    pub radius: f64,
}

/// The way into a cell that clears every neighbour.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Way {
    /// m, the aim's offset from the centre across the axis: sideways (along A1's
    /// direction in the plate's plane) and up (perpendicular to the axis in its
    /// vertical plane: [`up`]).
    pub shift: [f64; 2],
    /// m, the smallest clearance to a neighbour on that way (infinite with none near).
    pub clearance: f64,
    /// The neighbour that comes closest, if any lies within a millimetre.
    pub closest: Option<usize>,
}

/// Why no way clears: the neighbour the glass meets on the straight (centred) way,
/// and by how much.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Blocked {
    /// The neighbour (survey order) nearest the glass on the centred way.
    pub by: Sphere,
    /// m, its clearance there: negative when the glass would run into it.
    pub clearance: f64,
}

/// The pipette's forward axis in the stage's frame (x, height, z), for A3's direction
/// `forward` in the plate's plane (a unit vector, stage x and z).
pub fn axis(pipette: &PipetteParams, forward: [f64; 2]) -> [f64; 3] {
    let (sin, cos) = pipette.angle.sin_cos();
    [forward[0] * cos, -sin, forward[1] * cos]
}

/// The unit vector across the axis `axis` in its vertical plane, pointing up (stage
/// x, height, z): an aim moved along it raises the glass behind the tip.
pub fn up(axis: [f64; 3]) -> [f64; 3] {
    let h = axis[0].hypot(axis[2]);
    if h == 0.0 {
        return [1.0, 0.0, 0.0];
    }
    // The horizontal part scaled by the vertical's size, and vice versa.
    let s = -axis[1];
    [axis[0] / h * s, h, axis[2] / h * s]
}

/// The smallest clearance between the glass with its tip at `tip` along `axis` and
/// the spheres, and which sphere it is (infinite, none, without spheres).
pub fn clearance(
    pipette: &PipetteParams,
    tip: [f64; 3],
    axis: [f64; 3],
    spheres: &[Sphere],
) -> (f64, Option<Sphere>) {
    let mut best = (f64::INFINITY, None);
    for s in spheres {
        let c = pipette.clearance(tip, axis, s.centre, s.radius);
        if c < best.0 {
            best = (c, Some(*s));
        }
    }
    best
}

/// The way into `target` (a sphere) past `neighbours`: the centred aim first, then aims
/// moved across the axis (sideways and up, [`up`]) on a grid of 0.05 of the radius, the
/// nearest first, up to `max_off_centre` of the radius from the centre: the first whose
/// glass keeps `margin` from every neighbour with the tip `reach` past the aim (the
/// membrane takes an entry that far off-centre). `across` and `forward` are unit
/// vectors in the plate's plane (A1's and A3's directions).
#[allow(clippy::too_many_arguments)]
pub fn plan(
    pipette: &PipetteParams,
    target: &Sphere,
    neighbours: &[Sphere],
    across: [f64; 2],
    forward: [f64; 2],
    reach: f64,
    max_off_centre: f64,
    margin: f64,
) -> Result<Way, Blocked> {
    let ax = axis(pipette, forward);
    let up = up(ax);
    // Only neighbours the glass could come near: within a millimetre.
    let near: Vec<Sphere> = neighbours
        .iter()
        .filter(|s| {
            s.index != target.index
                && (s.centre[0] - target.centre[0]).hypot(s.centre[2] - target.centre[2]) < 1e-3
        })
        .copied()
        .collect();
    // Offsets in steps of 0.05 radius within the allowed disc, nearest first (then
    // sideways before up, left before right: a fixed order).
    let n = (max_off_centre / 0.05 + 1e-9).floor() as i32;
    let mut grid: Vec<(i32, i32)> = (-n..=n)
        .flat_map(|a| (-n..=n).map(move |b| (a, b)))
        .filter(|(a, b)| a * a + b * b <= n * n)
        .collect();
    grid.sort_by_key(|&(a, b)| (a * a + b * b, b.abs(), b, a));
    let mut centred = None;
    for (a, b) in grid {
        let (sa, sb) = (
            a as f64 * 0.05 * target.radius,
            b as f64 * 0.05 * target.radius,
        );
        let side = [across[0], 0.0, across[1]];
        let tip = [0, 1, 2].map(|i| target.centre[i] + side[i] * sa + up[i] * sb + ax[i] * reach);
        let (c, who) = clearance(pipette, tip, ax, &near);
        if a == 0 && b == 0 {
            centred = who.map(|s| (s, c));
        }
        if c > margin {
            return Ok(Way {
                shift: [sa, sb],
                clearance: c,
                closest: who.map(|s| s.index),
            });
        }
    }
    let (by, clearance) = centred.expect("blocked only by a neighbour");
    Err(Blocked { by, clearance })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Independent of the swept-cone argument and of the closed-form distance: the
    /// tip walked from the start of the approach to its deepest point in 0.1 um
    /// steps, the glass's surface sampled at each step (sections every 0.25 um, 96
    /// points around), the smallest distance to the neighbour's surface.
    fn walked_clearance(
        p: &PipetteParams,
        aim: [f64; 3],
        ax: [f64; 3],
        back: f64,
        reach: f64,
        c: [f64; 3],
        r: f64,
    ) -> f64 {
        // Two unit vectors across the axis (the axis has no x component).
        let e1 = [1.0, 0.0, 0.0];
        let e2 = [0.0, ax[2], -ax[1]];
        let mut best = f64::INFINITY;
        let steps = ((back + reach) / 0.1e-6).ceil() as usize;
        for k in 0..=steps {
            let t = -back + (back + reach) * k as f64 / steps as f64;
            let tip = [0, 1, 2].map(|i| aim[i] + t * ax[i]);
            // Sections up to 150 um behind the tip (the glass is higher beyond).
            for m in 0..=600 {
                let s = m as f64 * 0.25e-6;
                let rho = p.radius_at(s);
                for q in 0..96 {
                    let phi = q as f64 / 96.0 * std::f64::consts::TAU;
                    let (cs, sn) = (phi.cos(), phi.sin());
                    let x = [0, 1, 2].map(|i| tip[i] - s * ax[i] + rho * (cs * e1[i] + sn * e2[i]));
                    let d = ((x[0] - c[0]).powi(2) + (x[1] - c[1]).powi(2) + (x[2] - c[2]).powi(2))
                        .sqrt();
                    best = best.min(d - r);
                }
            }
        }
        best
    }

    #[test]
    fn a_touching_partner_across_the_way_blocks_only_where_the_glass_truly_meets_it() {
        // Cells resting on one floor (a mean radius of 7.5 um below the focal plane):
        // the target, and a partner touching it, lying behind it along the pipette's
        // way (its centre turned `bearing` from straight behind), at several mount
        // angles and sizes. The planner's decision (centred aim only) and its
        // clearance are checked against the walked, sampled glass.
        let floor = -7.5e-6;
        let (margin, reach) = (0.5e-6, 0.2 * 6e-6);
        let mut decided = [0; 2];
        for angle_deg in [20.0f64, 30.0, 45.0, 60.0] {
            let p = PipetteParams {
                angle: angle_deg.to_radians(),
                ..PipetteParams::default()
            };
            for (rt, rn) in [(5e-6, 5e-6), (5e-6, 12e-6), (9e-6, 6e-6), (12e-6, 14e-6)] {
                for bearing_deg in [0.0f64, 25.0, 50.0] {
                    let target = Sphere {
                        index: 0,
                        well: [0, 0],
                        centre: [0.0, floor + rt, 0.0],
                        radius: rt,
                    };
                    // Touching in the plane: centres rt + rn apart horizontally would
                    // overlap for unequal heights; they touch at distance rt + rn in 3-D.
                    let dh = rn - rt;
                    let horizontal = ((rt + rn).powi(2) - dh * dh).sqrt();
                    let b = bearing_deg.to_radians();
                    let partner = Sphere {
                        index: 1,
                        well: [0, 0],
                        centre: [horizontal * b.sin(), floor + rn, -horizontal * b.cos()],
                        radius: rn,
                    };
                    let planned = plan(
                        &p,
                        &target,
                        &[partner],
                        [1.0, 0.0],
                        [0.0, 1.0],
                        reach,
                        0.0,
                        margin,
                    );
                    let ax = axis(&p, [0.0, 1.0]);
                    let walked = walked_clearance(
                        &p,
                        target.centre,
                        ax,
                        rt + 6e-6,
                        reach,
                        partner.centre,
                        rn,
                    );
                    let what = format!(
                        "{angle_deg} deg, target {rt:e}, partner {rn:e} at {bearing_deg} deg: walked {walked:e}"
                    );
                    // Sampling finds the glass up to ~0.05 um late: decisions agree
                    // outside that band.
                    if (walked - margin).abs() > 0.1e-6 {
                        assert_eq!(planned.is_ok(), walked > margin, "{what}: {planned:?}");
                        decided[planned.is_ok() as usize] += 1;
                    }
                    let c = match planned {
                        Ok(w) => w.clearance,
                        Err(b) => {
                            assert_eq!(b.by.index, 1);
                            b.clearance
                        }
                    };
                    if walked > 0.0 {
                        assert!((c - walked).abs() < 0.1e-6, "{what}: planned {c:e}");
                    } else {
                        assert!(c < 0.05e-6, "{what}: planned {c:e}");
                    }
                }
            }
        }
        // Both decisions occur in the sweep.
        assert!(decided[0] > 3 && decided[1] > 3, "{decided:?}");
    }

    #[test]
    fn steeper_passes_more_partners_and_an_off_centre_aim_is_tried_before_giving_up() {
        let floor = -7.5e-6;
        let target = Sphere {
            index: 0,
            well: [0, 0],
            centre: [0.0, floor + 5e-6, 0.0],
            radius: 5e-6,
        };
        // A tall partner straight behind, touching.
        let (rt, rn): (f64, f64) = (5e-6, 10e-6);
        let horizontal = ((rt + rn) * (rt + rn) - (rn - rt) * (rn - rt)).sqrt();
        let partner = Sphere {
            index: 1,
            well: [0, 0],
            centre: [0.0, floor + rn, -horizontal],
            radius: rn,
        };
        // The pipette coming along +z, the aim free to move along x, the tip 1 um past
        // the aim, 0.5 um of margin.
        let go = |p: &PipetteParams, partner: Sphere, off: f64| {
            plan(
                p,
                &target,
                &[partner],
                [1.0, 0.0],
                [0.0, 1.0],
                1e-6,
                off,
                0.5e-6,
            )
        };
        let at = |deg: f64, off: f64| {
            let p = PipetteParams {
                angle: deg.to_radians(),
                ..PipetteParams::default()
            };
            go(&p, partner, off)
        };
        // Straight behind, a partner twice the target's radius: blocked at 45° and 60°
        // (less so), passed over at 75°.
        let c45 = at(45.0, 0.0).unwrap_err();
        let c60 = at(60.0, 0.0).unwrap_err();
        assert!(c45.by.index == 1 && c45.clearance < c60.clearance && c60.clearance < 0.0);
        let w75 = at(75.0, 0.0).unwrap();
        assert!(w75.shift == [0.0, 0.0] && w75.clearance > 0.5e-6, "{w75:?}");
        // Raised aims pass over a partner straight behind that blocks the centred way
        // by less than they raise the glass (and move it no further sideways).
        let mut raised = 0;
        for deg in [45.0f64, 60.0] {
            let p = PipetteParams {
                angle: deg.to_radians(),
                ..PipetteParams::default()
            };
            for rn in [5.5e-6, 6e-6, 7e-6, 8e-6, 10e-6] {
                let h = ((rt + rn) * (rt + rn) - (rn - rt) * (rn - rt)).sqrt();
                let behind = Sphere {
                    centre: [0.0, floor + rn, -h],
                    radius: rn,
                    ..partner
                };
                if let (Err(_), Ok(w)) = (go(&p, behind, 0.0), go(&p, behind, 0.45)) {
                    assert!(w.shift[0] == 0.0 && w.shift[1] > 0.0, "{deg} {rn}: {w:?}");
                    raised += 1;
                }
            }
        }
        assert!(raised > 0);
        // A partner a little to the side: where the centred way grazes it, an aim
        // moved away from it (never towards it) clears.
        let p = PipetteParams::default();
        let mut rescued = 0;
        for bearing in (5..=60).step_by(5) {
            for rn in [6e-6, 8e-6, 10e-6] {
                let b = (bearing as f64).to_radians();
                let h = ((rt + rn) * (rt + rn) - (rn - rt) * (rn - rt)).sqrt();
                let partner = Sphere {
                    centre: [h * b.sin(), floor + rn, -h * b.cos()],
                    radius: rn,
                    ..partner
                };
                if let (Err(_), Ok(w)) = (go(&p, partner, 0.0), go(&p, partner, 0.3)) {
                    assert!(
                        w.shift[0] <= 0.0 && w.clearance > 0.5e-6,
                        "{bearing} {rn}: {w:?}"
                    );
                    rescued += 1;
                }
            }
        }
        assert!(rescued > 0);
    }
}
