//! One cell's attempt, state by state (the states of [`super::machine`]): the stage
//! brings the pipette to the cell's approach ([`Workflow::travel`]), the camera finds
//! the tip and the cell ([`Workflow::look`], following a cell that moved), A1 aligns
//! the tip on the cell's axis ([`Workflow::align`]), A3 drives it through the
//! membrane to the centre ([`Workflow::penetrate`]), the injector doses it
//! ([`Workflow::inject`]), A3 withdraws ([`Workflow::retract`]) and the cell's
//! darkness says how much went in and whether it lives ([`Workflow::verify`]).

use cellinject_hw::{Camera, Clock, Injector, Stage};
use cellinject_rig::Backend;
use cellinject_rig::pipette::cell_volume;

use super::{
    Attempt, BlobKind, DetectOptions, Event, Fail, ImageMap, Observer, Options, Outcome,
    RETRACT_TIMEOUT, STILL_RESIDUAL, Shot, TIP_FRAMES, Target, Workflow, WorkflowError, approach,
    cell_darkness, decompose, dev, dose_diameter, far_edge, median, unit,
};

/// What the way to one cell fixes for the whole attempt.
#[derive(Debug, Clone, Copy)]
pub(super) struct Way {
    /// The image-to-stage map.
    map: ImageMap,
    /// The workflow's options.
    o: Options,
    /// m per pixel.
    pix: f64,
    /// The cell's radius, m, and in pixels.
    r: f64,
    r_px: f64,
    /// A1's and A3's directions on the stage.
    d1: [f64; 2],
    d3: [f64; 2],
    /// The cell's centre on the stage (the survey's), m.
    c: [f64; 2],
    /// The start's distance up the pipette's axis from the aim, and across it, m.
    back: f64,
    lead: f64,
    /// The aim's move off the cell's centre: across the axis, and up, m.
    shift: f64,
    raise: f64,
    /// The pipette's angle's sine and cosine.
    sin: f64,
    cos: f64,
    /// Where the tip goes in the image, relative to the cell's centre, pixels.
    aim_off: [f64; 2],
    /// The macro stage's height above the plate between cells, m.
    lift: f64,
    /// The centre of the camera's region of interest, pixels.
    roi_centre: [f64; 2],
}

impl Way {
    /// The tip's offset from the aim when the cell is at `cell_px`: across the cell's
    /// axis (A1's direction: its coefficient, and m) and along it (A3's extension to
    /// the cell's centre, m).
    fn offset(&self, cell_px: [f64; 2], tip: [f64; 2]) -> (f64, f64, f64) {
        let (map, pix) = (self.map, self.pix);
        let e = [
            cell_px[0] + self.aim_off[0] - tip[0],
            cell_px[1] + self.aim_off[1] - tip[1],
        ];
        let [alpha, b] = decompose(e, map.a1, map.a3);
        (alpha, alpha.abs() * map.a1[0].hypot(map.a1[1]) * pix, b)
    }
}

/// What the camera last saw: the frame, the tip in it and the cell's centre (pixels).
pub(super) struct Seen {
    shot: Shot,
    tip: [f64; 2],
    cell_px: [f64; 2],
}

impl<B: Backend> Workflow<'_, B> {
    /// One cell, from the stage's move to its approach to the dose's verdict.
    pub(super) fn procedure(
        &mut self,
        a: &mut Attempt,
        obs: &mut dyn Observer,
    ) -> Result<(), Fail> {
        let way = self.travel(a, obs)?;
        let seen = self.look(a, &way, obs)?;
        let dark0 = cell_darkness(&seen.shot, seen.cell_px, way.r_px);
        let (seen, beta) = self.align(a, &way, seen, obs)?;
        let seen = self.penetrate(a, &way, seen, beta, obs)?;
        self.inject(a, way.o, obs)?;
        self.retract(a, obs)?;
        self.verify(a, &way, &seen, dark0, obs)
    }

    /// The way in to the cell planned past its neighbours, and the stage's move to its
    /// start: lift, travel, lower.
    fn travel(&mut self, a: &mut Attempt, obs: &mut dyn Observer) -> Result<Way, Fail> {
        let map = self.map.expect("map");
        let o = self.options;
        let pix = map.pixel_size;
        let r = 0.5 * a.target.diameter_m;
        // Directions of A1 and A3 on the stage.
        let to_stage_dir = |v: [f64; 2]| unit(map.stage_delta(v));
        let (d1, d3) = (to_stage_dir(map.a1), to_stage_dir(map.a3));
        let c = a.target.stage_m;
        let back = r + o.gap;
        let lead = 1.5e-6;
        // The glass's way in, in three dimensions: the cells rest on the floor, the
        // plate focused on their mean equator, so each centre stands half its
        // diameter's excess over the mean above the focal plane. The tip may go
        // `depth_limit` radii past the centre; the glass must keep 0.5 um from every
        // other cell; the aim may move sideways by up to `max_off_centre` of the radius
        // (the membrane takes an entry that far off-centre), else the cell is skipped.
        // The floor under each cell lies as far off the focal plane as the field's
        // measured tilt puts it.
        let origin = self.plate.origin;
        let height = |t: &Target| {
            0.5 * (t.diameter_m - self.mean_diameter)
                + self.floor_at([t.x_m + origin[0], t.y_m + origin[1]])
        };
        let sphere = |t: &Target| approach::Sphere {
            index: t.index,
            well: t.well,
            centre: [t.stage_m[0], height(t), t.stage_m[1]],
            radius: 0.5 * t.diameter_m,
        };
        let neighbours: Vec<approach::Sphere> = self.survey_cells.iter().map(sphere).collect();
        let way = approach::plan(
            &self.pipette,
            &sphere(&a.target),
            &neighbours,
            d1,
            d3,
            o.depth_limit * r,
            o.max_off_centre,
            0.5e-6,
        );
        let clears = match way {
            Ok(approach::Way {
                clearance,
                closest: Some(k),
                ..
            }) if clearance < 20e-6 => {
                format!(
                    "; the glass passes cell {k} {:.1} µm clear",
                    clearance * 1e6
                )
            }
            _ => String::new(),
        };
        let [shift, raise] = match way {
            Ok(w) => w.shift,
            Err(b) => {
                return Err(Fail::Blocked(format!(
                    "the approach is blocked by cell {} in well [{}, {}]: the pipette's glass would run {:.1} µm into it{}",
                    b.by.index,
                    b.by.well[0],
                    b.by.well[1],
                    -b.clearance * 1e6,
                    if o.max_off_centre > 0.0 {
                        format!(
                            " on the centred way, and no aim up to {:.2} radius off-centre clears",
                            o.max_off_centre
                        )
                    } else {
                        String::new()
                    }
                )));
            }
        };
        let (sin, cos) = self.pipette.angle.sin_cos();
        // A raised aim lies `raise` across the axis in its vertical plane: up by its
        // cosine, forward by its sine.
        let aim = [
            c[0] + d1[0] * shift + d3[0] * raise * sin,
            c[1] + d1[1] * shift + d3[1] * raise * sin,
        ];
        // The start: `back` up the axis from the aim, `lead` short across.
        let start = [
            aim[0] - d1[0] * lead - d3[0] * back * cos,
            aim[1] - d1[1] * lead - d3[1] * back * cos,
        ];
        let start_height = self.focus + height(&a.target) + raise * cos + back * sin;
        // Where the tip goes in the image, relative to the cell's centre (pixels).
        let aim_off = {
            let (p, q) = (map.pixel_of(aim), map.pixel_of(c));
            [p[0] - q[0], p[1] - q[1]]
        };
        // Lift, travel, lower.
        let t0 = self.now();
        let lift = self.home[1];
        for p in [
            [None, Some(lift), None],
            [Some(start[0]), None, Some(start[1])],
            [None, Some(start_height), None],
        ] {
            if let Err(e) = self.stage_to(p)? {
                return Err(Fail::Cell(e));
            }
        }
        let why = format!(
            "tip {:.1} µm before the membrane along the pipette, {:.1} µm above the focus, after {:.2} s{clears}",
            o.gap * 1e6,
            (start_height - self.focus) * 1e6,
            self.now() - t0
        );
        self.fire(Event::StageArrived, why, obs, Some(&mut a.transitions))
            .map_err(Fail::Error)?;
        let cell_px = map.pixel_of(c);
        Ok(Way {
            map,
            o,
            pix,
            r,
            r_px: r / pix,
            d1,
            d3,
            c,
            back,
            lead,
            shift,
            raise,
            sin,
            cos,
            aim_off,
            lift,
            roi_centre: [cell_px[0], cell_px[1] - 60e-6 / pix],
        })
    }

    /// The tip and the cell found in the image; a cell that moved since the survey is
    /// followed.
    fn look(&mut self, a: &mut Attempt, way: &Way, obs: &mut dyn Observer) -> Result<Seen, Fail> {
        let Way {
            map,
            pix,
            r,
            r_px,
            c,
            cos,
            roi_centre,
            ..
        } = *way;
        // Look.
        let mut cell_px = map.pixel_of(c);
        let mut shot = self.shoot(Some(roi_centre))?;
        let mut tip = None;
        // Half a second of patience (a bubble, a flicker) before giving up on the tip.
        for k in 0..15 {
            if k > 0 {
                shot = self.shoot(Some(roi_centre))?;
            }
            tip = shot.tip(self.background.as_ref().expect("background"), self.blur());
            if tip.is_some() {
                break;
            }
        }
        let Some(mut tip) = tip else {
            return Err(Fail::Cell(
                "lost tracking: the tip was not found in 15 frames (0.5 s)".into(),
            ));
        };
        // The cell, with the pipette masked out.
        let f = &shot.frame;
        let (w, h) = (f.width as usize, f.height as usize);
        let tl = shot.local(tip);
        let mut exclude = vec![false; w * h];
        for j in 0..h.min((tl[1] - 1.0).max(0.0) as usize) {
            // The glass's radius that far behind the tip (the image foreshortens it).
            let half = 4.0 + self.pipette.radius_at((tl[1] - j as f64) * pix / cos) / pix;
            for i in 0..w {
                if (i as f64 - tl[0]).abs() < half {
                    exclude[j * w + i] = true;
                }
            }
        }
        let blobs = cellinject_cells::detect(
            &f.pixels,
            w,
            h,
            &exclude,
            &DetectOptions::for_pixel_size(pix),
        )
        .map_err(|e| Fail::Cell(format!("cell detection failed: {e}")))?;
        let found = blobs
            .iter()
            .filter(|b| b.kind == BlobKind::Cell)
            .map(|b| (shot.full([b.x, b.y]), b.diameter))
            .min_by(|x, y| {
                let dx = (x.0[0] - cell_px[0]).hypot(x.0[1] - cell_px[1]);
                let dy = (y.0[0] - cell_px[0]).hypot(y.0[1] - cell_px[1]);
                dx.total_cmp(&dy)
            });
        let Some((p, _)) = found
            .filter(|(p, _)| (p[0] - cell_px[0]).hypot(p[1] - cell_px[1]) * pix < 0.5 * r + 5e-6)
        else {
            return Err(Fail::Cell(format!(
                "the cell is gone: nothing within {:.1} µm of where the survey saw it",
                (0.5 * r + 5e-6) * 1e6
            )));
        };
        let mut moved = (p[0] - cell_px[0]).hypot(p[1] - cell_px[1]) * pix;
        // The detector splits touching cells afresh in each frame (a partner just
        // injected looks darker and larger): its centre alone may say a cell moved
        // that did not. In the frame divided by the background (the survey's view,
        // renewed where cells were injected), a cell still in place divides out; one
        // that moved leaves its old and new rims. Followed only when they show.
        let residual = shot
            .normalised(self.background.as_ref().expect("background"))
            .map(|n| {
                let l = shot.local(cell_px);
                let (mut sum, mut count) = (0.0, 0usize);
                for j in 0..h {
                    for i in 0..w {
                        let d = (i as f64 - l[0]).hypot(j as f64 - l[1]);
                        if d <= r_px + 2.0 && !exclude[j * w + i] {
                            sum += (n[j * w + i] as f64 / 2000.0 - 1.0).abs();
                            count += 1;
                        }
                    }
                }
                sum / count.max(1) as f64
            });
        // Mean |frame / background - 1| over the cell: 0.015 where it stayed (the
        // sensor's noise), 0.14 after a move of 3.6 um (the twin, 2.5x).
        let still = residual.is_some_and(|v| v < STILL_RESIDUAL);
        if still {
            moved = 0.0;
        }
        let old_px = cell_px;
        if !still {
            cell_px = p;
        }
        if moved > 1.5e-6 {
            let why = format!(
                "the cell moved {:.1} µm since the survey: target follows it",
                moved * 1e6
            );
            self.fire(Event::CellMoved, why, obs, Some(&mut a.transitions))
                .map_err(Fail::Error)?;
        } else {
            let why = format!("tip and cell found ({:.2} µm from the survey)", moved * 1e6);
            self.fire(Event::Found, why, obs, Some(&mut a.transitions))
                .map_err(Fail::Error)?;
        }
        if moved > 1.5e-6 {
            (shot, tip) = self.follow(way, cell_px, old_px, moved)?;
        }
        Ok(Seen { shot, tip, cell_px })
    }

    /// The pipette brought back to the start of the approach of a cell that moved
    /// `moved` m from `old_px` to `cell_px`, the background renewed round both places,
    /// and the tip found again.
    fn follow(
        &mut self,
        way: &Way,
        cell_px: [f64; 2],
        old_px: [f64; 2],
        moved: f64,
    ) -> Result<(Shot, [f64; 2]), Fail> {
        let Way {
            map,
            pix,
            r_px,
            d1,
            d3,
            back,
            lead,
            shift,
            raise,
            sin,
            cos,
            roi_centre,
            ..
        } = *way;
        // Bring the pipette back to the start of the moved cell's approach (in focus,
        // a few um sideways, still outside the cell), and look again.
        let c = map.stage_of(cell_px);
        let start = [
            c[0] + d1[0] * (shift - lead) + d3[0] * (raise * sin - back * cos),
            c[1] + d1[1] * (shift - lead) + d3[1] * (raise * sin - back * cos),
        ];
        if let Err(e) = self.stage_to([Some(start[0]), None, Some(start[1])])? {
            return Err(Fail::Cell(e));
        }
        // The background still has the cell where the survey saw it, and the tip
        // stands over that old place: the pipette backs up its axis until the tip
        // is clear of both places in the image, the background is renewed around
        // them, and the pipette comes back to the start.
        let reach = r_px + moved / pix + 3.0;
        let mid = [
            0.5 * (cell_px[0] + old_px[0]),
            0.5 * (cell_px[1] + old_px[1]),
        ];
        let up = ((reach * pix + 8e-6) / cos - back).max(0.0);
        let at = start;
        let y = self.rig.stage.position(1).map_err(dev("stage"))?;
        if let Err(e) = self.stage_to([
            Some(at[0] - d3[0] * up * cos),
            Some(y + up * sin),
            Some(at[1] - d3[1] * up * cos),
        ])? {
            return Err(Fail::Cell(e));
        }
        let clear = self.shoot(Some(roi_centre))?;
        self.refresh_background(&clear, mid, reach, [f64::NAN; 2]);
        if let Err(e) = self.stage_to([Some(at[0]), Some(y), Some(at[1])])? {
            return Err(Fail::Cell(e));
        }
        let shot = self.shoot(Some(roi_centre))?;
        match shot.tip(self.background.as_ref().expect("background"), self.blur()) {
            Some(t) => Ok((shot, t)),
            None => Err(Fail::Cell(
                "lost tracking: the tip was not found after following the cell".into(),
            )),
        }
    }

    /// A1 brings the tip onto the cell's axis; A3's extension to the cell's centre
    /// (`beta`, m) is measured on the way, and the tip backed off to the full gap where
    /// it stands too close to the membrane.
    fn align(
        &mut self,
        a: &mut Attempt,
        way: &Way,
        seen: Seen,
        obs: &mut dyn Observer,
    ) -> Result<(Seen, f64), Fail> {
        let Way {
            o,
            r,
            d3,
            sin,
            cos,
            roi_centre,
            ..
        } = *way;
        let Seen {
            mut shot,
            mut tip,
            cell_px,
        } = seen;
        // Align: A1 under the sensor loop, its reference corrected from each frame.
        // A3 does not move while A1 aligns: every frame's tip measures the same
        // extension to the cell's centre (`beta`), and their median is taken (one
        // frame's tip can stand a few um behind the true one along the axis).
        let mut lateral = f64::INFINITY;
        let mut betas = Vec::new();
        let mut misses = 0;
        let mut converged = 0;
        for _ in 0..15 {
            let (alpha, l, b) = way.offset(cell_px, tip);
            betas.push(b);
            lateral = l;
            if lateral < o.align_tolerance {
                converged += 1;
                if converged >= 2 {
                    break;
                }
            } else {
                converged = 0;
            }
            let s = self.servo.as_mut().expect("servo");
            s.refs[0] = (s.refs[0] + 0.8 * alpha).clamp(0.0, 8e-6);
            shot = self.shoot(Some(roi_centre))?;
            match shot.tip(self.background.as_ref().expect("background"), self.blur()) {
                Some(t) => {
                    tip = t;
                    misses = 0;
                }
                None => {
                    misses += 1;
                    if misses >= 3 {
                        return Err(Fail::Cell(
                            "lost tracking: the tip vanished while aligning".into(),
                        ));
                    }
                }
            }
        }
        if lateral > 3.0 * o.align_tolerance {
            return Err(Fail::Cell(format!(
                "alignment did not converge: {:.2} µm off the cell's axis after 15 frames",
                lateral * 1e6
            )));
        }
        let mut beta = median(betas);
        // Along the pipette's axis (A3's extension: the map's A3 is per metre of it).
        let mut along = beta;
        // The approach must start outside the membrane: the withdrawal comes back to
        // this point, and a tip still in the cell when A1 relaxes tears it sideways. The
        // stage placed the tip `gap` before the membrane by the survey's map; where the
        // image says it stands closer than half that, the stage backs it off straight
        // along the pipette's axis to the full gap.
        let mut backed = String::new();
        if along - r < 0.5 * o.gap {
            let short = r + o.gap - along;
            let x = self.rig.stage.position(0).map_err(dev("stage"))?;
            let y = self.rig.stage.position(1).map_err(dev("stage"))?;
            let z = self.rig.stage.position(2).map_err(dev("stage"))?;
            if let Err(e) = self.stage_to([
                Some(x - d3[0] * short * cos),
                Some(y + short * sin),
                Some(z - d3[1] * short * cos),
            ])? {
                return Err(Fail::Cell(e));
            }
            let (mut laterals, mut betas) = (Vec::new(), Vec::new());
            for _ in 0..TIP_FRAMES + 2 {
                shot = self.shoot(Some(roi_centre))?;
                if let Some(t) =
                    shot.tip(self.background.as_ref().expect("background"), self.blur())
                {
                    let (_, l, b) = way.offset(cell_px, t);
                    laterals.push(l);
                    betas.push(b);
                    if betas.len() == TIP_FRAMES {
                        break;
                    }
                }
            }
            if betas.len() < TIP_FRAMES.div_ceil(2) {
                return Err(Fail::Cell(
                    "lost tracking: the tip was not found after backing off".into(),
                ));
            }
            (lateral, beta) = (median(laterals), median(betas));
            backed = format!(
                " (backed off {:.2} µm along the axis: the tip stood {:.2} µm from the membrane)",
                short * 1e6,
                (along - r) * 1e6
            );
            along = beta;
        }
        a.measured_tip_error_m = Some(lateral);
        let why = format!(
            "tip {:.2} µm off the cell's axis, {:.2} µm from its centre along it{backed}",
            lateral * 1e6,
            along * 1e6
        );
        self.fire(Event::Aligned, why, obs, Some(&mut a.transitions))
            .map_err(Fail::Error)?;
        Ok((Seen { shot, tip, cell_px }, beta))
    }

    /// A3 drives the tip `beta` m through the membrane to the cell's centre, the last
    /// micrometres in closed loop on the image.
    fn penetrate(
        &mut self,
        a: &mut Attempt,
        way: &Way,
        seen: Seen,
        beta: f64,
        obs: &mut dyn Observer,
    ) -> Result<Seen, Fail> {
        let Way {
            map,
            o,
            pix,
            r,
            r_px,
            aim_off,
            roi_centre,
            ..
        } = *way;
        let Seen {
            mut shot,
            tip,
            cell_px,
        } = seen;
        // Approach: from here on the cell counts as touched.
        a.contact = true;
        obs.contact(a)
            .map_err(|e| Fail::Error(WorkflowError::Record(e)))?;
        let e3_0 = self.servo.as_mut().expect("servo").a3(self.rig)?;
        let target_ext = e3_0 + beta;
        let limit = target_ext + o.depth_limit * r;
        let edge0 = far_edge(&shot, cell_px, r_px);
        let Some(edge0) = edge0 else {
            return Err(Fail::Cell("the cell's far membrane is not visible".into()));
        };
        let period = 1.0 / self.rig.camera.frame_rate();
        let exposure = self.rig.camera.settings().exposure;
        let (mut max_push, mut gave_at) = (0.0f64, None);
        let (mut last_push, mut unseen_give) = (f64::INFINITY, false);
        let mut held = 0;
        let mut frames = 0;
        loop {
            frames += 1;
            if frames > 200 {
                return Err(Fail::Cell("the approach took more than 200 frames".into()));
            }
            self.ramp_a3(
                target_ext.min(limit),
                o.approach_speed,
                (period - exposure - 2e-3).max(1e-3),
            )?;
            let s = self.rig.camera.grab().map_err(dev("camera"))?;
            shot.frame = s;
            let ext = self.servo.as_mut().expect("servo").a3(self.rig)?;
            if ext > limit + 0.2e-6 {
                return Err(Fail::Cell(format!(
                    "A3 overshot the depth limit ({:.2} µm past it)",
                    (ext - limit) * 1e6
                )));
            }
            if let Some(edge) = far_edge(&shot, cell_px, r_px) {
                let push = (edge - edge0) * pix;
                last_push = push;
                max_push = max_push.max(push);
                if gave_at.is_none() && max_push > 0.3e-6 && push < 0.4 * max_push {
                    gave_at = Some(ext - e3_0);
                }
            }
            if ext >= target_ext - 0.15e-6 {
                held += 1;
                if gave_at.is_some() && held >= 2 {
                    break;
                }
                // The tip at the centre of a cell that is not pushed: an intact membrane
                // would have carried the cell ahead by a good part of its radius
                // (several um), so the membrane gave without a visible snap.
                if held >= 3 && gave_at.is_none() && last_push.abs() < 0.05 * r {
                    unseen_give = true;
                    gave_at = Some(ext - e3_0);
                }
                if held >= 4 {
                    return Err(Fail::Cell(format!(
                        "the membrane did not give (the cell was pushed {:.2} µm, the tip is at the centre)",
                        max_push * 1e6
                    )));
                }
            }
        }
        // The last micrometres in closed loop on the image: the tip, seen through the
        // cell (the background divides the resting cell out), brought to the centre.
        // Each frame's tip gives the extension that puts it there (A3's reference plus
        // the tip's offset along the axis); A3 goes to the median of those so far (one
        // frame's tip a few um off along the axis would otherwise drive it that far
        // too deep), until three frames agree within 0.1 um.
        let mut target_ext = target_ext;
        let mut aims = Vec::new();
        for _ in 0..TIP_FRAMES {
            let shot = self.shoot(Some(roi_centre))?;
            let Some(t) = shot.tip(self.background.as_ref().expect("background"), self.blur())
            else {
                continue;
            };
            let e = [
                cell_px[0] + aim_off[0] - t[0],
                cell_px[1] + aim_off[1] - t[1],
            ];
            aims.push(target_ext + decompose(e, map.a1, map.a3)[1]);
            let aim = median(aims.clone()).min(limit);
            if aims.len() >= 3 && (aim - target_ext).abs() < 0.1e-6 {
                break;
            }
            target_ext = aim;
            self.ramp_a3(target_ext, o.approach_speed, 0.03)?;
        }
        let ext = self.servo.as_mut().expect("servo").a3(self.rig)?;
        a.depth_m = Some(ext - e3_0 - o.gap);
        let why = format!(
            "the membrane gave {}{:.1} µm into the approach (pushed {:.2} µm); tip at the centre, {:.1} µm past the membrane",
            if unseen_give {
                "unseen (the cell is not pushed with the tip at its centre), by "
            } else {
                ""
            },
            gave_at.unwrap_or(0.0) * 1e6,
            max_push * 1e6,
            (ext - e3_0 - o.gap) * 1e6
        );
        self.fire(Event::Penetrated, why, obs, Some(&mut a.transitions))
            .map_err(Fail::Error)?;
        Ok(Seen { shot, tip, cell_px })
    }

    /// The dose: a pulse sized to the cell's volume.
    fn inject(&mut self, a: &mut Attempt, o: Options, obs: &mut dyn Observer) -> Result<(), Fail> {
        // Inject.
        let dosed = dose_diameter(a.target.diameter_m, a.target.diameter_se_m);
        let volume = o.target_fraction * cell_volume(dosed.diameter);
        let mut pressure = o.pressure;
        let mut duration = volume / (self.conductance * pressure);
        if duration < 0.05 {
            pressure *= duration / 0.05;
            duration = 0.05;
        } else if duration > 2.0 {
            pressure = (pressure * duration / 2.0).min(self.rig.injector.max_pressure());
            duration = volume / (self.conductance * pressure);
        }
        a.truth.tip_error_m = obs.tip_error(&a.target);
        self.rig
            .injector
            .pulse(pressure, duration)
            .map_err(dev("injector"))?;
        a.pulse = Some([pressure, duration]);
        let why = format!(
            "{:.3} pL at {:.1} kPa for {:.3} s{}",
            volume * 1e15,
            pressure * 1e-3,
            duration,
            dosed.note()
        );
        self.fire(Event::Pulsed, why, obs, Some(&mut a.transitions))
            .map_err(Fail::Error)?;
        Ok(())
    }

    /// A3 withdrawn, the stack back at rest.
    fn retract(&mut self, a: &mut Attempt, obs: &mut dyn Observer) -> Result<(), Fail> {
        // Retract.
        self.ramp_a3(0.0, 500e-6, 0.08)?;
        // The stack is back within 0.3 µm in a few tens of ms; a bench whose clock is the
        // wall clock (a GCS controller on a loaded host) is given 2 s before it is a fault.
        let since = self.rig.clock.now();
        loop {
            let at = self.servo.as_mut().expect("servo").a3(self.rig)?;
            if at <= 0.3e-6 {
                break;
            }
            if self.rig.clock.now() - since > RETRACT_TIMEOUT {
                return Err(Fail::Fatal(format!(
                    "A3 does not retract: still {:.2} µm out after {RETRACT_TIMEOUT} s",
                    at * 1e6
                )));
            }
            // The reference keeps ramping to 0 until the stack is back.
            self.ramp_a3(0.0, 500e-6, 0.01)?;
        }
        self.servo.as_mut().expect("servo").refs = [0.0; 2];
        self.fire(
            Event::Retracted,
            "tip out of the cell".into(),
            obs,
            Some(&mut a.transitions),
        )
        .map_err(Fail::Error)?;
        Ok(())
    }

    /// The cell's darkness before (`dark0`) and after says the dose and whether it
    /// lives; the pipette is lifted for the next cell.
    fn verify(
        &mut self,
        a: &mut Attempt,
        way: &Way,
        seen: &Seen,
        dark0: Option<f64>,
        obs: &mut dyn Observer,
    ) -> Result<(), Fail> {
        let Way {
            o,
            pix,
            r,
            r_px,
            lift,
            roi_centre,
            ..
        } = *way;
        let (tip, cell_px) = (seen.tip, seen.cell_px);
        // Verify.
        let shot = self.shoot(Some(roi_centre))?;
        let dark1 = cell_darkness(&shot, cell_px, r_px);
        let (Some(d0), Some(d1)) = (dark0, dark1) else {
            return Err(Fail::Cell(
                "the cell's darkness could not be measured".into(),
            ));
        };
        // The injected cell looks different from now on: renew the background there
        // (a disc around the cell that stops short of the retracted tip).
        let reach = r_px + (0.5 * r).min(o.gap - 2e-6) / pix;
        self.refresh_background(&shot, cell_px, reach, tip);
        let dose = (d1 - d0) / self.dye_contrast;
        a.measured_dose_fraction = Some(dose);
        let ratio = dose / o.target_fraction;
        if ratio > 3.0 {
            a.outcome = Outcome::Failed;
            a.reason = format!("dose {:.1} times the target: the pipette is broken", ratio);
            return Err(Fail::Fatal(a.reason.clone()));
        }
        if d1 < 0.6 * d0 {
            a.outcome = Outcome::Failed;
            a.reason = format!(
                "the cell looks dead after the injection (darkness {:.3} -> {:.3})",
                d0, d1
            );
            self.low_doses = 0;
            self.dead_in_row += 1;
            if self.dead_in_row >= 2 {
                return Err(Fail::Fatal(format!(
                    "two cells in a row died at injection: the pipette is broken or its flow far too high ({})",
                    a.reason
                )));
            }
            self.fire(
                Event::DoseOk,
                a.reason.clone(),
                obs,
                Some(&mut a.transitions),
            )
            .map_err(Fail::Error)?;
            return Ok(());
        }
        self.dead_in_row = 0;
        if ratio < 0.3 {
            a.outcome = Outcome::Failed;
            a.reason = format!(
                "dose {:.0} % of the target: the pipette may be clogged",
                100.0 * ratio
            );
            self.fire(
                Event::DoseLow,
                a.reason.clone(),
                obs,
                Some(&mut a.transitions),
            )
            .map_err(Fail::Error)?;
            self.low_doses += 1;
            if self.low_doses >= 2 {
                return Err(Fail::Fatal(format!(
                    "no flow after clearing: the pipette is blocked ({})",
                    a.reason
                )));
            }
            let p = 0.85 * self.rig.injector.max_pressure();
            self.rig.injector.pulse(p, 0.2).map_err(dev("injector"))?;
            self.fire(
                Event::Cleared,
                format!("clearing pulse {:.0} kPa for 0.2 s in the medium", p * 1e-3),
                obs,
                Some(&mut a.transitions),
            )
            .map_err(Fail::Error)?;
            return Ok(());
        }
        self.low_doses = 0;
        if !(0.5..=2.0).contains(&ratio) {
            a.outcome = Outcome::Failed;
            a.reason = format!("dose {:.0} % of the target", 100.0 * ratio);
        } else {
            a.outcome = Outcome::Injected;
        }
        let why = format!(
            "dose {:.0} % of the target, the cell looks alive",
            100.0 * ratio
        );
        self.fire(Event::DoseOk, why, obs, Some(&mut a.transitions))
            .map_err(Fail::Error)?;
        // Lift for the next cell.
        self.stage_to([None, Some(lift), None])?
            .map_err(Fail::Cell)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::{ImageMap, Options, Way};

    #[test]
    fn the_offset_is_nothing_at_the_aim_and_splits_a_miss_into_a1_and_a3() {
        // Independent: a tip placed α of A1's image direction and β of A3's short of
        // the aim (e = α·a1 + β·a3) gives back α, β, and α·|a1|·pixel across the axis.
        let (a1, a3, pix) = ([2.0, 0.5], [-0.3, 1.5], 0.4e-6);
        let map = ImageMap {
            pixel0: [0.0; 2],
            stage0: [0.0; 2],
            b: [[1.0 / pix, 0.0], [0.0, 1.0 / pix]],
            residual_px: 0.0,
            a1,
            a3,
            pixel_size: pix,
        };
        let way = Way {
            map,
            o: Options::default(),
            pix,
            r: 10e-6,
            r_px: 25.0,
            d1: [1.0, 0.0],
            d3: [0.0, 1.0],
            c: [0.0; 2],
            back: 16e-6,
            lead: 1.5e-6,
            shift: 0.0,
            raise: 0.0,
            sin: 0.0,
            cos: 1.0,
            aim_off: [3.0, -4.0],
            lift: 30e-6,
            roi_centre: [0.0; 2],
        };
        let cell = [100.0, 50.0];
        let aim = [103.0, 46.0];
        let (alpha, lateral, beta) = way.offset(cell, aim);
        assert!(alpha.abs() < 1e-12 && lateral.abs() < 1e-18 && beta.abs() < 1e-12);
        for (a, b) in [(0.5, 2.0), (-1.25, 0.0), (0.0, -3.5)] {
            let tip = [
                aim[0] - a * a1[0] - b * a3[0],
                aim[1] - a * a1[1] - b * a3[1],
            ];
            let (alpha, lateral, beta) = way.offset(cell, tip);
            assert!((alpha - a).abs() < 1e-12, "{alpha} against {a}");
            assert!((beta - b).abs() < 1e-12, "{beta} against {b}");
            let across = a.abs() * 2.0f64.hypot(0.5) * pix;
            assert!(
                (lateral - across).abs() < 1e-18,
                "{lateral} against {across}"
            );
        }
    }
}
