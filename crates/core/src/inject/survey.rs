//! The plate's fields: planned over the plate for the view, visited with the feeder,
//! focused (the floor's plane measured) and surveyed for cells, the targets placed.

use super::*;

impl<B: Backend> Workflow<'_, B> {
    /// The fields over the plate for the view `map` gives, narrowed by `narrow` m on
    /// every side, with the feeder now at `at`.
    pub(super) fn plan_for(
        &self,
        map: &ImageMap,
        narrow: f64,
        at: [f64; 2],
    ) -> Result<FieldPlan, WorkflowError> {
        let (sw, sh) = self.rig.camera.sensor_size();
        let too_small = || {
            WorkflowError::Plan(PlanError::WindowTooSmall {
                window: [0.0; 2],
                pitch: self.plate.pitch,
                overlap: fields::MIN_OVERLAP,
            })
        };
        let win = window::window(
            map,
            [sw as f64, sh as f64],
            TOP_BAND + narrow,
            WINDOW_MARGIN + narrow,
        )
        .ok_or_else(too_small)?;
        let plan = fields::plan_near(&self.plate, win, fields::MIN_OVERLAP, self.travel, Some(at))
            .map_err(WorkflowError::Plan)?;
        // The image map's points lie on wall crossings in the field: two walls along
        // each axis. A field of width L holds at least ⌊L / pitch⌋ walls of a larger
        // plate; a plate in one field holds all its own.
        for (a, axis) in [(0, "x"), (1, "y")] {
            let many = plan.grid[1 - a] > 1;
            if many && win.size[a] < 2.0 * self.plate.pitch {
                return Err(WorkflowError::PitchTooLarge {
                    pitch_um: self.plate.pitch * 1e6,
                    field_um: win.size[a] * 1e6,
                    axis,
                    zoom: self.options.zoom,
                });
            }
        }
        Ok(plan)
    }

    /// The fields for the view the rig's set-up gives, before the image is mapped: the
    /// stage's origin puts the resting tip near the image's centre and the image's
    /// columns and rows run along stage x and z, so the window is taken from a nominal
    /// map, narrowed by [`BOOTSTRAP_MARGIN`]. The image is mapped in its first field;
    /// the fields are planned again with the measured map.
    pub(super) fn bootstrap_plan(&mut self) -> Result<FieldPlan, WorkflowError> {
        let frame = self.rig.camera.grab().map_err(dev("camera"))?;
        let pixel = frame.pixel_size / self.rig.camera.settings().binning as f64;
        let nominal = self.nominal_map(pixel);
        let at = self.feeder_position()?;
        self.plan_for(&nominal, BOOTSTRAP_MARGIN, at)
    }

    /// The image-to-stage map before it is measured: the frame's centre at the
    /// stage's origin, image columns and rows along stage x and z, `pixel` m each.
    pub(super) fn nominal_map(&self, pixel: f64) -> ImageMap {
        let (sw, sh) = self.rig.camera.sensor_size();
        ImageMap {
            pixel0: [0.5 * (sw as f64 - 1.0), 0.5 * (sh as f64 - 1.0)],
            stage0: [0.0, 0.0],
            b: [[1.0 / pixel, 0.0], [0.0, 1.0 / pixel]],
            residual_px: 0.0,
            a1: [0.0; 2],
            a3: [0.0; 2],
            pixel_size: pixel,
        }
    }

    /// m, where the feeder is (x, y).
    pub(super) fn feeder_position(&mut self) -> Result<[f64; 2], WorkflowError> {
        Ok([
            self.rig.feeder.position(0).map_err(dev("feeder stage"))?,
            self.rig.feeder.position(1).map_err(dev("feeder stage"))?,
        ])
    }

    /// Time passes: with the loops running if they are.
    pub(super) fn idle(&mut self, seconds: f64) -> Result<(), WorkflowError> {
        if self.servo.is_some() {
            self.wait(seconds)
        } else {
            self.rig.clock.sleep(seconds).map_err(dev("clock"))
        }
    }

    /// Brings `field` under the objective: the pipette lifted first (the plate moves
    /// under it), then the feeder moved and waited for (its deadline: the run's stage
    /// deadline plus 1 s per mm). The feeder's position is read back: plate and stage
    /// coordinates differ by it until the next move.
    pub(super) fn goto_field(&mut self, field: Field) -> Result<Result<(), String>, WorkflowError> {
        if let Err(e) = self.stage_to([None, Some(self.home[1]), None])? {
            return Ok(Err(format!("the pipette cannot be lifted: {e}")));
        }
        let now = self.feeder_position()?;
        let now_z = self.rig.feeder.position(2).map_err(dev("feeder stage"))?;
        // The field's height: measured if it (or a field centred within FOCUS_REUSE of
        // it, its plane extended) was focused, else predicted from the nearest field
        // focused, else where the feeder stands.
        let known = self
            .focused
            .iter()
            .map(|f| {
                (
                    f,
                    (f.centre_m[0] - field.centre[0]).hypot(f.centre_m[1] - field.centre[1]),
                )
            })
            .filter(|(_, d)| *d < FOCUS_REUSE)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(f, d)| {
                if d < 1e-6 {
                    *f
                } else {
                    FieldFocus {
                        centre_m: field.centre,
                        rect_m: field.rect,
                        feeder_z_m: f.feeder_z_at(field.centre),
                        frames: 0,
                        ..*f
                    }
                }
            });
        if let Some(k) = known
            && k.frames == 0
            && !self.focused.iter().any(|f| f.centre_m == k.centre_m)
        {
            self.focused.push(k);
        }
        let z = match known {
            Some(f) => f.feeder_z_m,
            None => self.predicted_focus(field.centre).unwrap_or(now_z),
        };
        self.field_focus = known;
        // A field served again: the pipette starts on its shortest way out of view
        // (for the background) while the feeder moves; the background waits for it
        // there, or tries the other ways if the stage refused this one.
        if known.is_some() && !self.survey_cells.is_empty() {
            // The background's pixel, as the background takes its ways with (a
            // fallback way computed with none would stop inside the view).
            let pixel = self
                .background
                .as_ref()
                .map_or_else(|| self.map.map_or(0.0, |m| m.pixel_size), |b| b.pixel_size);
            if let Some(&way) = self.ways_out(self.home[1], pixel)?.first() {
                // Refused (the stage's travel): the background tries the other ways.
                if self.stage_start(way)?.is_ok() {
                    self.leaving = Some(way);
                }
            }
        }
        let far = (field.feeder[0] - now[0])
            .abs()
            .max((field.feeder[1] - now[1]).abs())
            .max((z - now_z).abs());
        // Within the feeder's resolution: already there.
        if far > 0.05e-6 {
            for (a, v) in [field.feeder[0], field.feeder[1], z].iter().enumerate() {
                if let Err(e) = self.rig.feeder.move_to(a, *v) {
                    return Ok(Err(format!(
                        "the feeder stage refused the move to field {} ({:.3}, {:.3}) mm: {e}",
                        field.index,
                        field.feeder[0] * 1e3,
                        field.feeder[1] * 1e3
                    )));
                }
            }
            let deadline = self.options.stage_deadline + far * 1e3;
            let t0 = self.now();
            while self.rig.feeder.is_busy().map_err(dev("feeder stage"))? {
                if self.now() - t0 > deadline {
                    return Err(WorkflowError::Device {
                        what: "feeder stage",
                        source: HwError::Timeout {
                            device: "feeder stage (missed its deadline)".into(),
                            seconds: deadline,
                        },
                    });
                }
                self.idle(0.005)?;
            }
        }
        self.feeder_at = self.feeder_position()?;
        self.field = Some(field);
        Ok(Ok(()))
    }

    /// How the current field was focused, for the log.
    pub(super) fn focus_note(&self) -> String {
        match self.field_focus {
            Some(f) => format!(
                ", height {:.1} µm: the floor slopes {:.2} µm/mm{}",
                f.feeder_z_m * 1e6,
                f.slope[0].hypot(f.slope[1]) * 1e3,
                if f.tiles > 0 {
                    format!(
                        " ({} tiles, {:.2} µm rms, {} focus frames)",
                        f.tiles,
                        f.residual_m * 1e6,
                        f.frames
                    )
                } else {
                    format!(" (whole frame, {} focus frames)", f.frames)
                }
            ),
            None => String::new(),
        }
    }

    /// m, the feeder height predicted to focus plate point `p`: the plane of the
    /// nearest field focused, extended; `None` before any.
    pub(super) fn predicted_focus(&self, p: [f64; 2]) -> Option<f64> {
        self.focused
            .iter()
            .min_by(|a, b| {
                let d = |f: &FieldFocus| (f.centre_m[0] - p[0]).hypot(f.centre_m[1] - p[1]);
                d(a).total_cmp(&d(b))
            })
            .map(|f| f.feeder_z_at(p))
    }

    /// m, how far above the focal plane the floor at plate point `p` stands in the
    /// current field (its measured tilt; 0 before it is measured).
    pub(super) fn floor_at(&self, p: [f64; 2]) -> f64 {
        self.field_focus.map_or(0.0, |f| f.floor_at(p))
    }

    /// Moves the feeder's height to `z` and waits for it to settle.
    pub(super) fn feeder_height(&mut self, z: f64) -> Result<Result<(), String>, WorkflowError> {
        if let Err(e) = self.rig.feeder.move_to(2, z) {
            return Ok(Err(format!(
                "the feeder stage refused the height {:.1} µm: {e}",
                z * 1e6
            )));
        }
        let t0 = self.now();
        while self.rig.feeder.is_busy().map_err(dev("feeder stage"))? {
            if self.now() - t0 > self.options.stage_deadline {
                return Err(WorkflowError::Device {
                    what: "feeder stage",
                    source: HwError::Timeout {
                        device: "feeder stage (missed its deadline)".into(),
                        seconds: self.options.stage_deadline,
                    },
                });
            }
            self.idle(0.005)?;
        }
        self.idle(FOCUS_SETTLE)?;
        Ok(Ok(()))
    }

    /// One frame of a focus sweep: the feeder's height moved to `z`, a whole frame
    /// binned by `binning`, and its tiles' sharpness.
    pub(super) fn focus_sample(
        &mut self,
        z: f64,
        binning: u32,
    ) -> Result<Result<(f64, Vec<f64>), String>, WorkflowError> {
        if let Err(e) = self.feeder_height(z)? {
            return Ok(Err(e));
        }
        let full = self.settings_full.expect("full settings");
        let shot = self.shoot_with(CameraSettings { binning, ..full })?;
        let f = shot.frame;
        let w = f.width as usize;
        let sharp = cellinject_cells::focus::tile_sharpness(&f.pixels, w, FOCUS_TILES);
        Ok(Ok((z, sharp)))
    }

    /// Focuses the current field (the pipette lifted out of view): the feeder's
    /// height swept through focus in equal steps, a full frame at each; the frame cut
    /// into 3 x 3 tiles, each tile's best focus the midpoint of its sharpness curve's
    /// half-height crossings, the plane through them the field's tilt
    /// (`cellinject_cells::focus`). The first field is swept over ±[`FOCUS_RANGE`] in
    /// 4 um steps, then again over ±8 um in 1.5 um steps about its peak; a later
    /// one over ±12 um in 1.5 um steps about the height its nearest focused
    /// neighbour's plane predicts. A peak beyond a sweep's end moves the sweep that way
    /// (three times at most). The feeder ends at the plane's height at the field's
    /// centre.
    pub(super) fn focus_field(&mut self) -> Result<Result<FieldFocus, String>, WorkflowError> {
        use cellinject_cells::focus;
        let field = self.field.expect("field");
        let first = self.focused.is_empty();
        let now_z = self.rig.feeder.position(2).map_err(dev("feeder stage"))?;
        let mut centre = self.predicted_focus(field.centre).unwrap_or(now_z);
        let mut frames = 0;
        // (half range, step): every frame binned 2 x 2 (a quarter of the pixels to
        // move and read). Not 4 x 4: pixels of 3.5 um average the walls' and rings'
        // edges away, and such frames were sharpest far from focus.
        let passes: &[(f64, f64)] = if first {
            &[(FOCUS_RANGE, 4e-6), (8e-6, 1.5e-6)]
        } else {
            &[(12e-6, 1.5e-6)]
        };
        // The last pass's samples, by height: (z, each tile's sharpness).
        let mut samples: Vec<(f64, Vec<f64>)> = Vec::new();
        let mut whole = None;
        let mut step = 0.0;
        for &(half, dz) in passes {
            step = dz;
            let mut shifts = 0;
            loop {
                let n = (2.0 * half / step).round() as usize + 1;
                samples.clear();
                for k in 0..n {
                    match self.focus_sample(centre - half + k as f64 * step, FOCUS_BINNING)? {
                        Ok(s) => samples.push(s),
                        Err(e) => return Ok(Err(e)),
                    }
                    frames += 1;
                }
                let zs: Vec<f64> = samples.iter().map(|s| s.0).collect();
                let total: Vec<f64> = samples.iter().map(|s| s.1.iter().sum()).collect();
                match focus::peak(&zs, &total, focus::FRAME_CONTRAST) {
                    Ok(p) => {
                        centre = p.z;
                        whole = Some(p);
                        break;
                    }
                    Err(focus::FocusError::OutOfRange { side, .. }) if shifts < 3 => {
                        shifts += 1;
                        centre += if side == "above" { 1.5 } else { -1.5 } * half;
                    }
                    Err(e) => {
                        return Ok(Err(format!(
                            "field {} could not be focused: {e}",
                            field.index
                        )));
                    }
                }
            }
        }
        let whole = whole.expect("a pass found the peak");
        // A tile whose focus lies beyond an end (the floor tilted steeply across the
        // field) extends the sweep on that side, up to FOCUS_RANGE from the peak.
        let tiles = FOCUS_TILES[0] * FOCUS_TILES[1];
        let curve = |samples: &[(f64, Vec<f64>)], t: usize| {
            let zs: Vec<f64> = samples.iter().map(|s| s.0).collect();
            let c: Vec<f64> = samples
                .iter()
                .map(|s| s.1.get(t).copied().unwrap_or(0.0))
                .collect();
            focus::peak(&zs, &c, focus::TILE_CONTRAST)
        };
        loop {
            let (lo, hi) = (samples[0].0, samples[samples.len() - 1].0);
            let (mut below, mut above) = (false, false);
            for t in 0..tiles {
                if let Err(focus::FocusError::OutOfRange { side, .. }) = curve(&samples, t) {
                    below |= side == "below";
                    above |= side == "above";
                }
            }
            let below = below && whole.z - lo < FOCUS_RANGE;
            let above = above && hi - whole.z < FOCUS_RANGE;
            if !below && !above {
                break;
            }
            for k in 1..=3 {
                if below {
                    match self.focus_sample(lo - k as f64 * step, FOCUS_BINNING)? {
                        Ok(s) => samples.insert(0, s),
                        Err(e) => return Ok(Err(e)),
                    }
                    frames += 1;
                }
                if above {
                    match self.focus_sample(hi + k as f64 * step, FOCUS_BINNING)? {
                        Ok(s) => samples.push(s),
                        Err(e) => return Ok(Err(e)),
                    }
                    frames += 1;
                }
            }
        }
        // Each tile's focus where its sharpness comes from (read in a frame at the whole
        // frame's focus), at that point of the plate.
        if let Err(e) = self.feeder_height(whole.z)? {
            return Ok(Err(e));
        }
        let full = self.shoot(None)?.frame;
        frames += 1;
        let at = focus::tile_centroids(&full.pixels, full.width as usize, FOCUS_TILES);
        let map = self
            .map
            .unwrap_or_else(|| self.nominal_map(full.pixel_size));
        let mut points = Vec::new();
        for t in 0..tiles {
            // A real focus curve spans several steps; noise peaks in one.
            let Ok(p) = curve(&samples, t) else { continue };
            if p.width < 2.0 * step {
                continue;
            }
            let Some(&px) = at.get(t) else {
                continue;
            };
            let st = map.stage_of(px);
            points.push(([st[0] - self.feeder_at[0], st[1] - self.feeder_at[1]], p.z));
        }
        let result = match focus::fit_plane(&points, field.centre) {
            Ok(plane) => FieldFocus {
                centre_m: field.centre,
                rect_m: field.rect,
                feeder_z_m: plane.z,
                slope: plane.slope,
                tiles: plane.points,
                residual_m: plane.residual,
                frames,
            },
            Err(_) => FieldFocus {
                centre_m: field.centre,
                rect_m: field.rect,
                feeder_z_m: whole.z,
                slope: [0.0; 2],
                tiles: 0,
                residual_m: 0.0,
                frames,
            },
        };
        if let Err(e) = self.feeder_height(result.feeder_z_m)? {
            return Ok(Err(e));
        }
        Ok(Ok(result))
    }

    /// The cells in the current field's background frame (the pipette out of view):
    /// plate coordinates of their centres and their diameters, m. Only cells whole in
    /// the field.
    pub(super) fn detect_field(&self) -> Result<Vec<Seen>, WorkflowError> {
        let map = self.map.expect("map");
        let field = self.field.expect("field");
        let bg = self.background.as_ref().expect("background");
        let (w, h) = (bg.width, bg.pixels.len() / bg.width);
        let o = DetectOptions::for_pixel_size(map.pixel_size);
        let blobs = cellinject_cells::detect(&bg.pixels, w, h, &[], &o).map_err(|e| {
            WorkflowError::Calibration {
                what: "survey",
                reason: e.to_string(),
            }
        })?;
        Ok(blobs
            .iter()
            .filter(|b| b.kind == BlobKind::Cell)
            .filter_map(|b| {
                let s = map.stage_of([b.x, b.y]);
                let p = [s[0] - self.feeder_at[0], s[1] - self.feeder_at[1]];
                field
                    .holds(p, 0.5 * b.diameter)
                    .then_some((p, b.diameter, b.diameter_se))
            })
            .collect())
    }

    /// The survey: the feeder brings every field under the objective in turn, and one
    /// frame of each (the background, the pipette out of view) shows where its cells
    /// are. A cell seen in two fields (in their overlap) is one cell: detections whose
    /// centres lie within a radius of each other are merged, and the cell is given to
    /// the field that owns its centre if that field holds it whole, else to the first
    /// that does. Cells are then numbered in the order they are injected: field by
    /// field in the reverse of the survey's order (the feeder is over the last field
    /// surveyed), row by row within a field in alternating direction, top cell first
    /// within a well.
    pub(super) fn survey(&mut self, obs: &mut dyn Observer) -> Result<Vec<Target>, WorkflowError> {
        let plan = self.plan.clone().expect("plan");
        let n = plan.fields.len();
        // (plate point, diameter, field, the diameter's standard error) of every
        // detection.
        let mut seen: Vec<([f64; 2], f64, usize, Option<f64>)> = Vec::new();
        for field in &plan.fields {
            if let Err(reason) = self.goto_field(*field)? {
                return Err(WorkflowError::Calibration {
                    what: "survey",
                    reason,
                });
            }
            if let Err(reason) = self.take_background()? {
                return Err(WorkflowError::Calibration {
                    what: "survey",
                    reason: format!("field {}: {reason}", field.index),
                });
            }
            obs.field(field.index, n, field.rect, self.feeder_at);
            let found = self.detect_field()?;
            let r = format!(
                "field {} of {n} surveyed: plate x {:.3} to {:.3} mm, y {:.3} to {:.3} mm (feeder at {:.3}, {:.3} mm{}): {} cells whole in it",
                field.index,
                field.rect[0] * 1e3,
                field.rect[2] * 1e3,
                field.rect[1] * 1e3,
                field.rect[3] * 1e3,
                self.feeder_at[0] * 1e3,
                self.feeder_at[1] * 1e3,
                self.focus_note(),
                found.len()
            );
            self.fire(Event::FieldReached, r, obs, None)?;
            for (p, d, se) in found {
                seen.push((p, d, field.index, se));
            }
        }
        // One cell, one entry: detections within a radius of a cell's first.
        let mut cells: Vec<Vec<usize>> = Vec::new();
        for (k, (p, d, _, _)) in seen.iter().enumerate() {
            let same = cells.iter_mut().find(|c| {
                let (q, e, _, _) = seen[c[0]];
                (p[0] - q[0]).hypot(p[1] - q[1]) < 0.5 * d.min(e)
            });
            match same {
                Some(c) => c.push(k),
                None => cells.push(vec![k]),
            }
        }
        let pl = &self.plate;
        let half = 0.5 * pl.pitch;
        let mut targets: Vec<(Target, usize)> = Vec::new();
        for c in &cells {
            let m = c.len() as f64;
            let mean = [
                c.iter().map(|&k| seen[k].0[0]).sum::<f64>() / m,
                c.iter().map(|&k| seen[k].0[1]).sum::<f64>() / m,
            ];
            let owner = plan.owner(mean).index;
            let &k = c.iter().find(|&&k| seen[k].2 == owner).unwrap_or(&c[0]);
            let (p, d, field, se) = seen[k];
            let rel = [p[0] - pl.origin[0], p[1] - pl.origin[1]];
            let (col, row) = ((rel[0] / pl.pitch).round(), (rel[1] / pl.pitch).round());
            if col < 0.0 || row < 0.0 || col >= pl.cols as f64 || row >= pl.rows as f64 {
                continue;
            }
            let w = pl.well_centre([row as u32, col as u32]);
            if (p[0] - w[0]).abs() > half || (p[1] - w[1]).abs() > half {
                continue;
            }
            targets.push((
                Target {
                    index: 0,
                    well: [row as u32, col as u32],
                    x_m: rel[0],
                    y_m: rel[1],
                    diameter_m: d,
                    diameter_se_m: se,
                    stage_m: [p[0] + self.feeder_at[0], p[1] + self.feeder_at[1]],
                },
                field,
            ));
        }
        let key = |t: &Target, f: usize| {
            (
                n - 1 - f,
                t.well[0],
                if t.well[0] % 2 == 0 {
                    t.well[1]
                } else {
                    u32::MAX - t.well[1]
                },
            )
        };
        targets.sort_by(|(a, fa), (b, fb)| {
            key(a, *fa)
                .cmp(&key(b, *fb))
                .then(a.y_m.total_cmp(&b.y_m))
                .then(a.x_m.total_cmp(&b.x_m))
        });
        for (k, (t, _)) in targets.iter_mut().enumerate() {
            t.index = k;
        }
        self.target_field = targets.iter().map(|(_, f)| *f).collect();
        let targets: Vec<Target> = targets.into_iter().map(|(t, _)| t).collect();
        self.survey_cells = targets.clone();
        self.mean_diameter = if targets.is_empty() {
            0.0
        } else {
            targets.iter().map(|t| t.diameter_m).sum::<f64>() / targets.len() as f64
        };
        self.place_targets();
        Ok(targets)
    }

    /// The surveyed cells' stage positions for the feeder where it is now.
    pub(super) fn place_targets(&mut self) {
        let (o, f) = (self.plate.origin, self.feeder_at);
        for t in &mut self.survey_cells {
            t.stage_m = [t.x_m + o[0] + f[0], t.y_m + o[1] + f[1]];
        }
    }
}
