//! What the microscope sees: frames ([`Shot`]) and their background, the tip found in
//! a frame (and its blur learnt), the image mapped to the stage ([`ImageMap`]), and the
//! rechecks of that map during a run.

use super::*;

/// The image-to-stage map and the actuators' directions in the image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ImageMap {
    /// Full-frame pixel of the tip with the stage at `stage0` (A1, A2, A3 at rest).
    pub pixel0: [f64; 2],
    /// m, stage (x, z) of `pixel0`.
    pub stage0: [f64; 2],
    /// Pixels per metre of stage motion: columns and rows by stage x and z.
    pub b: [[f64; 2]; 2],
    /// RMS residual of the four-point fit, pixels.
    pub residual_px: f64,
    /// Pixels per metre of A1's extension (its sensor).
    pub a1: [f64; 2],
    /// Pixels per metre of A3's extension: the tip's motion down the pipette's axis as
    /// the microscope sees it (foreshortened by the mount angle).
    pub a3: [f64; 2],
    /// m per pixel of the frames.
    pub pixel_size: f64,
}

impl ImageMap {
    /// The stage motion (m) that moves the tip by `d` pixels.
    pub(super) fn stage_delta(&self, d: [f64; 2]) -> [f64; 2] {
        let [[a, b], [c, e]] = self.b;
        let det = a * e - b * c;
        [(e * d[0] - b * d[1]) / det, (-c * d[0] + a * d[1]) / det]
    }

    /// The stage position (m) that puts the resting tip at full-frame pixel `px`.
    pub fn stage_of(&self, px: [f64; 2]) -> [f64; 2] {
        let d = self.stage_delta([px[0] - self.pixel0[0], px[1] - self.pixel0[1]]);
        [self.stage0[0] + d[0], self.stage0[1] + d[1]]
    }

    /// The full-frame pixel of the resting tip with the stage at `s` (m) (also where
    /// a cell whose `stage_m` is `s` appears).
    pub fn pixel_of(&self, s: [f64; 2]) -> [f64; 2] {
        let (u, v) = (s[0] - self.stage0[0], s[1] - self.stage0[1]);
        [
            self.pixel0[0] + self.b[0][0] * u + self.b[0][1] * v,
            self.pixel0[1] + self.b[1][0] * u + self.b[1][1] * v,
        ]
    }

    /// The two shortest stage moves (m, stage x and z, the shorter first) that take
    /// the pipette wholly out of a `frame` (columns, rows) from stage position `stage`:
    /// sideways across the image, to the left or to the right, until every column the
    /// glass covers in view (from the tip back along the pipette's axis, `-a3`, to the
    /// frame's edge) stands `margin` (m) beyond the frame, and more by
    /// [`OUT_OF_VIEW_SPREAD`] of the glass's height there above focus (its defocused
    /// shadow). `None` when the tip is not in
    /// the frame or the map has no axis.
    pub fn out_of_view(
        &self,
        stage: [f64; 2],
        frame: [f64; 2],
        margin: f64,
    ) -> Option<[[f64; 2]; 2]> {
        let t = self.pixel_of(stage);
        let n = self.a3[0].hypot(self.a3[1]);
        let inside =
            |p: [f64; 2]| (0.0..=frame[0]).contains(&p[0]) && (0.0..=frame[1]).contains(&p[1]);
        if !(n > 0.0 && n.is_finite() && inside(t) && self.pixel_size > 0.0) {
            return None;
        }
        let s = [-self.a3[0] / n, -self.a3[1] / n];
        // Where the shank leaves the frame.
        let exit = |p: f64, d: f64, hi: f64| {
            if d > 0.0 {
                (hi - p) / d
            } else if d < 0.0 {
                -p / d
            } else {
                f64::INFINITY
            }
        };
        let l = exit(t[0], s[0], frame[0]).min(exit(t[1], s[1], frame[1]));
        let end = t[0] + l * s[0];
        // The glass rises out of focus behind the tip (the image sees its length
        // foreshortened by f = cos of its angle): at the frame's edge it stands `high`
        // above the tip (and the focus sweeps lift it up to 0.2 mm more), and its
        // defocused shadow spreads with that height.
        let f = (n * self.pixel_size).clamp(1e-3, 1.0);
        let high = l * self.pixel_size * (1.0 - f * f).sqrt() / f + 0.2e-3;
        let m = (margin + OUT_OF_VIEW_SPREAD * high) / self.pixel_size;
        let left = -(t[0].max(end) + m);
        let right = frame[0] - t[0].min(end) + m;
        let to = |dc: f64| {
            let d = self.stage_delta([dc, 0.0]);
            [stage[0] + d[0], stage[1] + d[1]]
        };
        Some(if -left <= right {
            [to(left), to(right)]
        } else {
            [to(right), to(left)]
        })
    }
}

/// A frame and where its pixel (0, 0) is on the full sensor.
pub(super) struct Shot {
    pub(super) frame: cellinject_hw::Frame,
    pub(super) origin: [f64; 2],
    /// The glass's outer taper as the microscope sees it (foreshortened).
    pub(super) taper: f64,
}

impl Shot {
    pub(super) fn full(&self, p: [f64; 2]) -> [f64; 2] {
        [p[0] + self.origin[0], p[1] + self.origin[1]]
    }
    pub(super) fn local(&self, p: [f64; 2]) -> [f64; 2] {
        [p[0] - self.origin[0], p[1] - self.origin[1]]
    }
    /// This frame divided by the background (the same view with the pipette out of
    /// it: the feeder's walls and the cells divide out, the pipette stays), scaled to
    /// 2000; `None` for a frame far darker or brighter than the background (the light
    /// off, a bubble, a flash), which shows nothing to trust.
    pub(super) fn normalised(&self, background: &Background) -> Option<Vec<u16>> {
        let f = &self.frame;
        let (w, h) = (f.width as usize, f.height as usize);
        let (ox, oy) = (self.origin[0] as usize, self.origin[1] as usize);
        let mut norm = Vec::with_capacity(w * h);
        for (j, row) in f.pixels.chunks_exact(w).take(h).enumerate() {
            let start = (oy + j) * background.width + ox;
            let bg = &background.pixels[start..start + w];
            norm.extend(row.iter().zip(bg).map(|(&p, &b)| {
                let v = p as f64 / b.max(1) as f64 * 2000.0;
                v.clamp(0.0, 65535.0) as u16
            }));
        }
        let mean = norm.iter().map(|&v| v as f64).sum::<f64>() / norm.len().max(1) as f64;
        (1000.0..4000.0).contains(&mean).then_some(norm)
    }

    /// The tip in `norm` (this frame [`Shot::normalised`]), in full-frame pixels;
    /// `blur`: the tip's blur (pixels) if known, else it is fitted too.
    pub(super) fn locate(&self, norm: &[u16], blur: Option<f64>) -> Option<Tip> {
        let f = &self.frame;
        let (w, h) = (f.width as usize, f.height as usize);
        cellinject_cells::tip::locate_tapered(norm, w, h, f.pixel_size, blur, self.taper)
            .ok()
            .map(|t| {
                let [x, y] = self.full([t.x, t.y]);
                Tip { x, y, ..t }
            })
    }

    /// The tip, found in this frame divided by the background, with the tip's blur
    /// (pixels) if known.
    pub(super) fn tip(&self, background: &Background, blur: Option<f64>) -> Option<[f64; 2]> {
        let norm = self.normalised(background)?;
        self.locate(&norm, blur).map(|t| [t.x, t.y])
    }
    /// Mean intensity of pixel (column, row) rounded, or None outside.
    pub(super) fn at(&self, c: f64, r: f64) -> Option<f64> {
        let (w, h) = (self.frame.width as i64, self.frame.height as i64);
        let (i, j) = (c.round() as i64, r.round() as i64);
        (i >= 0 && j >= 0 && i < w && j < h).then(|| self.frame.pixels[(j * w + i) as usize] as f64)
    }
}

/// A full frame of the plate with the pipette out of view.
pub(super) struct Background {
    pub(super) pixels: Vec<u16>,
    pub(super) width: usize,
    /// m per pixel.
    pub(super) pixel_size: f64,
}

impl<B: Backend> Workflow<'_, B> {
    pub(super) fn shoot(&mut self, roi: Option<[f64; 2]>) -> Result<Shot, WorkflowError> {
        let full = self.settings_full.expect("full settings");
        let s = match roi {
            None => full,
            Some(c) => {
                let (sw, sh) = self.rig.camera.sensor_size();
                let (w, h) = (640u32.min(sw), 480u32.min(sh));
                let x = (c[0] - 0.5 * w as f64).round().clamp(0.0, (sw - w) as f64) as u32;
                let y = (c[1] - 0.5 * h as f64).round().clamp(0.0, (sh - h) as f64) as u32;
                CameraSettings {
                    roi: Roi {
                        x,
                        y,
                        width: w,
                        height: h,
                    },
                    binning: 1,
                    ..full
                }
            }
        };
        self.shoot_with(s)
    }

    /// A frame taken with camera settings `s`.
    pub(super) fn shoot_with(&mut self, s: CameraSettings) -> Result<Shot, WorkflowError> {
        if self.rig.camera.settings() != s {
            self.rig.camera.configure(s).map_err(dev("camera"))?;
        }
        // Keep the loops running until just before the next exposure.
        let period = 1.0 / self.rig.camera.frame_rate();
        let wait = (period - s.exposure - 2e-3).max(0.0);
        self.wait(wait)?;
        let frame = self.rig.camera.grab().map_err(dev("camera"))?;
        Ok(Shot {
            frame,
            origin: [s.roi.x as f64, s.roi.y as f64],
            taper: self.pipette.outer_taper / self.pipette.angle.cos(),
        })
    }

    /// The resting tip in full frames: the median of [`TIP_FRAMES`] frames' tips
    /// (`tries`: frames without a tip tolerated on top), each found with the tip's blur
    /// known ([`Workflow::blur`], learnt on plain floor by [`Workflow::learn_blur`];
    /// should that leave fewer than [`BLUR_MIN`] fits, the frames here add theirs
    /// until there are enough):
    /// with the blur free, a frame's tip stood up to 5 px behind the true one along the
    /// axis (the fit trades the end's blur against its position in the noise), and the
    /// image map extrapolates each of its points' errors over the plate: seed 15's map,
    /// two of its four points 2-3 px off, put the first row's cells 7-11 um off along
    /// the pipette.
    pub(super) fn tip_full(&mut self, tries: usize) -> Result<Option<[f64; 2]>, WorkflowError> {
        self.tip_full_at(tries, true)
    }

    /// As [`Self::tip_full`]; a tip out of focus (`in_focus` false) is located by the
    /// free fit alone, and its blur is not learnt.
    pub(super) fn tip_full_at(
        &mut self,
        tries: usize,
        in_focus: bool,
    ) -> Result<Option<[f64; 2]>, WorkflowError> {
        if in_focus && self.blur().is_none() {
            self.learn_blur()?;
        }
        let mut seen = Vec::with_capacity(TIP_FRAMES);
        let mut misses = 0;
        while seen.len() < TIP_FRAMES && misses < tries {
            let shot = self.shoot(None)?;
            let bg = self.background.as_ref().expect("background");
            let Some(free) = shot.normalised(bg).and_then(|n| {
                let free = shot.locate(&n, None)?;
                Some((n, free))
            }) else {
                misses += 1;
                continue;
            };
            let (norm, free) = free;
            if !in_focus {
                seen.push([free.x, free.y]);
                continue;
            }
            // The blur is learnt on plain floor ([`Workflow::learn_blur`]); a frame
            // elsewhere adds its free fit only while too few fits are known (the
            // image map's points lie at the walls' crossings, where free fits learn
            // twice the optics' blur: measured 0.8-1.05 px against 0.5 px on plain
            // floor, and the tip located with it stood 0.1-0.2 um further behind the
            // true one along the axis, differently in every run).
            if self.blur().is_none() {
                self.add_blurs([free.sigma]);
            }
            let Some(blur) = self.blur() else {
                // Still measuring the blur.
                continue;
            };
            match shot.locate(&norm, Some(blur)) {
                Some(t) => seen.push([t.x, t.y]),
                None => misses += 1,
            }
        }
        if seen.len() < TIP_FRAMES.div_ceil(2) {
            return Ok(None);
        }
        let xs: Vec<f64> = seen.iter().map(|t| t[0]).collect();
        let ys: Vec<f64> = seen.iter().map(|t| t[1]).collect();
        Ok(Some([median(xs), median(ys)]))
    }

    /// Learns the tip's blur in focus from free fits of the resting tip over clean
    /// floor, with the stage stepped over a [`BLUR_PHASES`]² pattern a quarter pixel
    /// apart (the stage back where it stood after).
    ///
    /// A free fit trades the end's blur against its position, and it does so worst
    /// where the background is not plain: the image map's points lie at the crossings
    /// of the plate's walls, and there (seed 1 from a saved calibration) 15 frames
    /// learnt 1.4 px of blur where the optics give about 0.4 px; the tip located ever
    /// after with that blur stood 0.2 um behind the true one along the axis, and every
    /// cell's tip error grew by as much, while on a first run the stacks' creep after
    /// the identification had moved the tip's end a pixel off the wall. So the tip is
    /// first moved (lifted over the cells, and down into focus there) to the plainest
    /// floor within [`BLUR_REACH`] (no wall, no cell under the strip the locator reads:
    /// [`plainest`]; with only the end's 31 x 31 px window plain and 18 um of reach, a
    /// run from a saved calibration learnt 1.1 px where the optics give 0.5 px), and
    /// the phases within a pixel, on which a fit's blur also depends, are sampled
    /// evenly there.
    pub(super) fn learn_blur(&mut self) -> Result<(), WorkflowError> {
        let here = [
            self.rig.stage.position(0).map_err(dev("stage"))?,
            self.rig.stage.position(2).map_err(dev("stage"))?,
        ];
        let pixel = self.background.as_ref().expect("background").pixel_size;
        let shot = self.shoot(None)?;
        let bg = self.background.as_ref().expect("background");
        let start = shot.normalised(bg).and_then(|n| shot.locate(&n, None));
        let centre = match start {
            Some(t) => {
                let d = plainest(bg, [t.x, t.y], t.axis, pixel);
                [here[0] + d[0], here[1] + d[1]]
            }
            None => here,
        };
        // Over the cells at the lift, to the patch and back (the patch may be up to
        // BLUR_REACH away, beyond the 18 um the tip could cross at focus height).
        let height = self.rig.stage.position(1).map_err(dev("stage"))?;
        let over = height.max(self.options.focus + self.options.lift);
        self.lifted_to([centre[0], centre[1]], over, height)?;
        let step = pixel / BLUR_PHASES as f64;
        let mut fits = Vec::with_capacity(BLUR_PHASES * BLUR_PHASES);
        for k in 0..BLUR_PHASES * BLUR_PHASES {
            let (i, j) = ((k % BLUR_PHASES) as f64, (k / BLUR_PHASES) as f64);
            let at = [centre[0] + i * step, centre[1] + j * step];
            if self.stage_to([Some(at[0]), None, Some(at[1])])?.is_err() {
                continue;
            }
            let shot = self.shoot(None)?;
            let bg = self.background.as_ref().expect("background");
            if let Some(t) = shot.normalised(bg).and_then(|n| shot.locate(&n, None)) {
                fits.push(t.sigma);
            }
        }
        self.add_blurs(fits);
        self.lifted_to(here, over, height)?;
        Ok(())
    }

    /// The stage to `xz` (m) by way of height `over`, then down to `height`; a move
    /// the stage refuses leaves it where it got.
    pub(super) fn lifted_to(
        &mut self,
        xz: [f64; 2],
        over: f64,
        height: f64,
    ) -> Result<(), WorkflowError> {
        for p in [
            [None, Some(over), None],
            [Some(xz[0]), None, Some(xz[1])],
            [None, Some(height), None],
        ] {
            if self.stage_to(p)?.is_err() {
                break;
            }
        }
        Ok(())
    }

    /// Adds free fits' blurs, keeping the latest [`BLUR_FRAMES`].
    pub(super) fn add_blurs(&mut self, fits: impl IntoIterator<Item = f64>) {
        self.blurs.extend(fits);
        let extra = self.blurs.len().saturating_sub(BLUR_FRAMES);
        self.blurs.drain(..extra);
    }

    /// Pixels, the blur of the tip's end in focus: the lower quartile of the latest
    /// [`BLUR_FRAMES`] free fits of the resting tip, once there are [`BLUR_MIN`] of
    /// them. The optics' blur at the focus is the same in every frame taken there; a
    /// single frame's free fit scatters from 0.3 to 6 px around it, and whatever
    /// spoils a frame (the floor's texture under the glass, the tip moving in the
    /// exposure) widens the fit, never narrows it: so the lower quartile, not the
    /// median (on a dashboard's second run 16 fits on plain floor gave 0.3-3.6 px,
    /// median 2.45 px against 0.5 px in focus, and every tip located with it stood
    /// 0.8 um behind the true one along the axis; three cells died).
    pub(super) fn blur(&self) -> Option<f64> {
        (self.blurs.len() >= BLUR_MIN).then(|| lower_quartile(self.blurs.clone()))
    }

    /// The background: a full frame of the plate with the pipette lifted out of view
    /// (the tip is found against it, and the survey reads it): one field width to the
    /// field's left in the survey, the shortest way sideways out of the frame for a
    /// field served again ([`Workflow::ways_out`]; 1.4-1.7 s for a field change on a
    /// 3 x 40 strip, against 3.4 s and 1.4 s more to come back). Taken again at every
    /// re-check: a bench that drifts moves the plate's image (a change of
    /// magnification of 1e-4 moves the walls at the edge of the field by 0.1 px), and
    /// the stale edges would pull the tip detector.
    pub(super) fn take_background(&mut self) -> Result<Result<(), String>, WorkflowError> {
        let lift = self.home[1];
        // m per pixel of the full frames: the last background's (taken with them), or on
        // the first call a frame's at the current binning.
        let pixel = match &self.background {
            Some(b) => b.pixel_size,
            None => {
                self.rig.camera.grab().map_err(dev("camera"))?.pixel_size
                    / self.rig.camera.settings().binning as f64
            }
        };
        if let Err(e) = self.stage_to([None, Some(lift), None])? {
            return Ok(Err(format!("the pipette cannot be lifted: {e}")));
        }
        let mut refused = Vec::new();
        let mut ways = self.ways_out(lift, pixel)?;
        if let Some(way) = self.leaving.take() {
            ways.insert(0, way);
        }
        for way in ways {
            match self.stage_to(way)? {
                Ok(()) => {
                    refused.clear();
                    break;
                }
                Err(e) => refused.push(e),
            }
        }
        if !refused.is_empty() {
            return Ok(Err(format!(
                "the pipette cannot be moved out of view: {}",
                refused.join("; ")
            )));
        }
        if self.field_focus.is_none() {
            // The plate moves up and down through focus: the pipette goes as much
            // higher first.
            let half = if self.focused.is_empty() {
                FOCUS_RANGE
            } else {
                12e-6
            };
            // (a sweep moved three times goes 5.5 half-ranges from where it started).
            if let Err(e) = self.stage_to([None, Some(lift + 6.0 * half), None])? {
                return Ok(Err(format!("the pipette cannot be lifted: {e}")));
            }
            match self.focus_field()? {
                Ok(f) => {
                    self.field_focus = Some(f);
                    self.focused.push(f);
                }
                Err(e) => return Ok(Err(e)),
            }
            if let Err(e) = self.stage_to([None, Some(lift), None])? {
                return Ok(Err(format!("the pipette cannot be lowered: {e}")));
            }
        }
        let mean = |p: &[u16]| p.iter().map(|&v| v as f64).sum::<f64>() / p.len().max(1) as f64;
        // A background taken again must be lit like the first (a flicker of the lamp
        // would make every later tip a guess): up to 60 frames (20 s) of patience.
        let reference = self.background.as_ref().map(|b| mean(&b.pixels));
        let mut shot = self.shoot(None)?;
        if let Some(r) = reference {
            let mut tries = 0;
            while mean(&shot.frame.pixels) < 0.5 * r {
                tries += 1;
                if tries >= 60 {
                    return Ok(Err(format!(
                        "the image stayed dark for {tries} frames (mean level {:.0} against {r:.0} when the run started)",
                        mean(&shot.frame.pixels)
                    )));
                }
                shot = self.shoot(None)?;
            }
        }
        self.background = Some(Background {
            pixels: shot.frame.pixels,
            width: shot.frame.width as usize,
            pixel_size: shot.frame.pixel_size,
        });
        Ok(Ok(()))
    }

    /// The image map's stage positions: at corners between four wells of the current
    /// field, where the tip is surely in view and, in focus, touches no cell (a cell
    /// lies within its well, so its disc stays clear of the corner), as far apart as
    /// the field allows: along each axis the corners between the first two and the
    /// last two wells the field holds whole. The map is extrapolated no further than
    /// that: from four points 150 um apart at the plate's centre it was more than 5 um
    /// off at the corners of a 10 x 15 plate (it called such a plate with 5 um to spare
    /// too large on 4 seeds of 5); every field lies in the same window of the image,
    /// so points spread over one field serve them all. Along an axis where the field
    /// holds fewer than four whole wells: on a plate that small, a corner near its
    /// centre and one `d` (about 200 um, whole pitches) beyond it; in a field of a
    /// larger plate, the first and the last wall crossing in the field.
    pub(super) fn map_points(&self) -> [[f64; 2]; 4] {
        let p = &self.plate;
        let f = self.field.expect("field");
        let q = 0.5 * p.pitch;
        let d = p.pitch.max(200e-6f64.min(2.0 * p.pitch));
        let d = (d / p.pitch).round() * p.pitch;
        let span = |a: usize| {
            let (o, all) = (p.origin[a], if a == 0 { p.cols } else { p.rows });
            let (lo, hi) = (f.rect[a], f.rect[a + 2]);
            let last = all.saturating_sub(1) as f64;
            let k0 = ((lo - o + q) / p.pitch - 1e-9).ceil().max(0.0);
            let k1 = ((hi - o - q) / p.pitch + 1e-9).floor().min(last);
            let n = if k1 >= k0 { (k1 - k0) as u32 + 1 } else { 0 };
            let (a0, a1) = if n >= 4 {
                (o + k0 * p.pitch + q, o + (k1 - 1.0) * p.pitch + q)
            } else if n == all {
                let c = o + (n / 2) as f64 * p.pitch - q;
                (c, c + d)
            } else {
                let wall = |k: f64| o - q + k * p.pitch;
                let w0 = ((lo - (o - q)) / p.pitch - 1e-9)
                    .ceil()
                    .clamp(0.0, all as f64);
                let w1 = ((hi - (o - q)) / p.pitch + 1e-9)
                    .floor()
                    .clamp(0.0, all as f64);
                (wall(w0), wall(w1.max(w0 + 1.0)))
            };
            (a0 + self.feeder_at[a], a1 + self.feeder_at[a])
        };
        let (x0, x1) = span(0);
        let (z0, z1) = span(1);
        [[x0, z0], [x1, z0], [x0, z1], [x1, z1]]
    }

    /// The tip's full-frame pixel with the stage at `s` (x, z) and the pipette in
    /// focus there (lowered from the lift height, lifted again after).
    pub(super) fn tip_at(
        &mut self,
        s: [f64; 2],
    ) -> Result<Result<[f64; 2], String>, WorkflowError> {
        let lift = self.home[1];
        for p in [
            [None, Some(lift), None],
            [Some(s[0]), None, Some(s[1])],
            [None, Some(self.focus), None],
        ] {
            if let Err(e) = self.stage_to(p)? {
                return Ok(Err(e));
            }
        }
        let Some(px) = self.tip_full(3)? else {
            return Ok(Err(format!(
                "the tip was not found in the image with the stage at ({:.0}, {:.0}) µm",
                s[0] * 1e6,
                s[1] * 1e6
            )));
        };
        if let Err(e) = self.stage_to([None, Some(lift), None])? {
            return Ok(Err(e));
        }
        Ok(Ok(px))
    }

    /// Whether it is time to re-check the image map, and why.
    pub(super) fn recheck_due(&mut self) -> Option<String> {
        if let Some(why) = self.check_due.take() {
            return Some(why);
        }
        let (every, since) = (self.options.recheck_every, self.now() - self.last_check);
        (every > 0.0 && since >= every).then(|| {
            format!("{since:.0} s after the image map was made or checked (every {every:.0} s)")
        })
    }

    /// Re-checks the calibrations between cells (`why`: what made it due): the
    /// background is taken again, and the resting tip is located at two of the map's
    /// stage positions (a diagonal apart) and compared with the map's prediction, in
    /// position and in scale. Within [`RECHECK_TOLERANCE`] the map is kept; else (or
    /// if the tip was not found) the image is mapped again, twice at most. Returns why
    /// the run must stop, if it must.
    pub(super) fn recheck(
        &mut self,
        why: String,
        obs: &mut dyn Observer,
    ) -> Result<Option<String>, WorkflowError> {
        self.fire(Event::Recheck, format!("re-check {why}"), obs, None)?;
        let t0 = self.now();
        let stop = |w: &mut Self, r: String, obs: &mut dyn Observer| {
            w.fire(Event::Fatal, r.clone(), obs, None).map(|()| Some(r))
        };
        if let Err(e) = self.take_background()? {
            return stop(
                self,
                format!("the background could not be taken again: {e}"),
                obs,
            );
        }
        let map = self.map.expect("map");
        let pts = self.map_points();
        let (s0, s1) = (pts[0], pts[3]);
        let mut verdict = None;
        let mut measured = [[0.0; 2]; 2];
        for (k, s) in [s0, s1].into_iter().enumerate() {
            match self.tip_at(s)? {
                Ok(px) => measured[k] = px,
                Err(e) => {
                    verdict = Some(e);
                    break;
                }
            }
        }
        let verdict = match verdict {
            Some(e) => e,
            None => {
                let off =
                    |p: [f64; 2], q: [f64; 2]| (p[0] - q[0]).hypot(p[1] - q[1]) * map.pixel_size;
                let worst =
                    off(measured[0], map.pixel_of(s0)).max(off(measured[1], map.pixel_of(s1)));
                let said = format!(
                    "background taken again; the resting tip is {:.2} µm from where the map puts it (worst of two points {:.0} µm apart)",
                    worst * 1e6,
                    (s1[0] - s0[0]).hypot(s1[1] - s0[1]) * 1e6,
                );
                if worst <= RECHECK_TOLERANCE {
                    let focus = match self.refocus()? {
                        Some(f) => format!("; {f}"),
                        None => String::new(),
                    };
                    self.last_check = self.now();
                    let r = format!(
                        "{said}: the map holds{focus} (re-check {:.1} s)",
                        self.now() - t0
                    );
                    self.fire(Event::Rechecked, r, obs, None)?;
                    return Ok(None);
                }
                format!("{said}, more than {:.1} µm", RECHECK_TOLERANCE * 1e6)
            }
        };
        let mut last = String::new();
        for _ in 0..2 {
            match self.map_image()? {
                Ok(m) => {
                    self.map = Some(m);
                    obs.mapped(&m);
                    let focus = match self.refocus()? {
                        Some(f) => format!("; {f}"),
                        None => String::new(),
                    };
                    self.last_check = self.now();
                    let r = format!(
                        "{verdict}: image mapped to the stage again (4 points, rms {:.2} px{focus}; re-check {:.1} s)",
                        m.residual_px,
                        self.now() - t0
                    );
                    self.fire(Event::Rechecked, r, obs, None)?;
                    return Ok(None);
                }
                Err(reason) => last = reason,
            }
        }
        stop(
            self,
            format!("{verdict}; mapping the image again failed twice: {last}"),
            obs,
        )
    }

    /// Maps the image to the stage: the tip located (in focus, over the plate) at the
    /// four stage positions of [`Workflow::map_points`], and its motion under A1 and A3.
    pub(super) fn map_image(&mut self) -> Result<Result<ImageMap, String>, WorkflowError> {
        let mut pts = Vec::new();
        for s in self.map_points() {
            match self.tip_at(s)? {
                Ok(px) => pts.push((s, px)),
                Err(e) => return Ok(Err(e)),
            }
        }
        let lift = self.home[1];
        // Affine least squares px = p0 + B (s - s0) with s0 the first point.
        let s0 = pts[0].0;
        let mut b = [[0.0; 2]; 2];
        let mut p0 = [0.0; 2];
        for c in 0..2 {
            // Unknowns p0, b_c0, b_c1 from 4 points: normal equations 3x3.
            let mut ata = nalgebra::Matrix3::<f64>::zeros();
            let mut atb = nalgebra::Vector3::<f64>::zeros();
            for (s, px) in &pts {
                let row = nalgebra::Vector3::new(1.0, s[0] - s0[0], s[1] - s0[1]);
                ata += row * row.transpose();
                atb += row * px[c];
            }
            let Some(x) = ata.lu().solve(&atb) else {
                return Ok(Err("the four stage positions are degenerate".into()));
            };
            p0[c] = x[0];
            b[c] = [x[1], x[2]];
        }
        let mut ss = 0.0;
        for (s, px) in &pts {
            for c in 0..2 {
                let pred = p0[c] + b[c][0] * (s[0] - s0[0]) + b[c][1] * (s[1] - s0[1]);
                ss += (pred - px[c]).powi(2);
            }
        }
        let residual = (ss / 8.0).sqrt();
        if residual > 0.5 {
            return Ok(Err(format!(
                "the four-point fit leaves {residual:.2} px rms (more than 0.5)"
            )));
        }
        let pixel = self.background.as_ref().expect("background").pixel_size;
        let scale = 1.0 / pixel;
        let sx = b[0][0].hypot(b[1][0]);
        if (sx / scale - 1.0).abs() > 0.05 {
            return Ok(Err(format!(
                "stage x moves the tip {:.4} px/µm, the camera says {:.4}: more than 5 % apart",
                sx * 1e-6,
                scale * 1e-6
            )));
        }
        // A1 and A3 in the image: 1 um of A1 extension, A3_PROBE of A3, from rest; per metre
        // of extension as the stacks' own sensors read it.
        self.stage_to([Some(s0[0]), None, Some(s0[1])])?.ok();
        self.stage_to([None, Some(self.focus), None])?.ok();
        let mut dir = [[0.0; 2]; 2];
        for (k, (e, what)) in [(1e-6, "A1"), (A3_PROBE, "A3")].into_iter().enumerate() {
            let ch = if k == 0 { 0 } else { 2 };
            let extension = |w: &mut Self| -> Result<f64, WorkflowError> {
                let s = w.servo.as_mut().expect("servo");
                let mut sum = 0.0;
                for _ in 0..10 {
                    sum += w.rig.sensors[ch].read().map_err(dev("stack sensor"))? - s.zero[ch];
                }
                Ok(sum / 10.0)
            };
            // A3 drives the tip down its axis: the probe starts as high above the focus
            // as it will come down, and ends in focus (above the floor).
            let drop = if k == 1 {
                e * self.pipette.angle.sin()
            } else {
                0.0
            };
            if drop > 0.0 {
                self.stage_to([None, Some(self.focus + drop), None])?.ok();
            }
            let Some(p0) = self.tip_full_at(3, drop == 0.0)? else {
                return Ok(Err(format!("the tip was lost before {what} moved")));
            };
            let e0 = extension(self)?;
            let s = self.servo.as_mut().expect("servo");
            if k == 0 {
                s.refs = [e, 0.0];
            } else {
                s.a3_ref = e;
            }
            self.wait(0.3)?;
            let Some(p1) = self.tip_full_at(3, drop == 0.0)? else {
                return Ok(Err(format!("the tip was lost while {what} moved")));
            };
            let e1 = extension(self)?;
            let s = self.servo.as_mut().expect("servo");
            s.refs = [0.0; 2];
            s.a3_ref = 0.0;
            self.wait(0.3)?;
            let de = e1 - e0;
            if de.abs() < 0.3 * e {
                return Ok(Err(format!(
                    "{what} extended {:.2} µm when asked for {:.2} µm",
                    de * 1e6,
                    e * 1e6
                )));
            }
            dir[k] = [(p1[0] - p0[0]) / de, (p1[1] - p0[1]) / de];
        }
        self.stage_to([None, Some(lift), None])?.ok();
        // The microscope sees A3's motion foreshortened by the pipette's angle.
        let cos = self.pipette.angle.cos();
        let a3m = dir[1][0].hypot(dir[1][1]) / scale / cos;
        // A3 carries the pipette directly: the tip follows the stack's extension, less
        // what the structure in series with it gives (some 10-20 %).
        if !(0.5..1.5).contains(&a3m) {
            return Ok(Err(format!(
                "A3 moved the tip {a3m:.2} times its own extension along the pipette (it carries the pipette directly: expected about 1)"
            )));
        }
        if dir[0][0].hypot(dir[0][1]) / scale < 0.5 {
            return Ok(Err("A1 barely moves the tip in the image".into()));
        }
        Ok(Ok(ImageMap {
            pixel0: p0,
            stage0: s0,
            b,
            residual_px: residual,
            a1: dir[0],
            // A3 carries the pipette directly: its direction from the probe, its gain
            // one metre of tip per metre of extension (the probe's magnitude, from two
            // tip positions a few um apart, is only checked).
            a3: {
                let u = unit(dir[1]);
                [u[0] * scale * cos, u[1] * scale * cos]
            },
            pixel_size: pixel,
        }))
    }
}

/// The stage offset (m, x and z, at most [`BLUR_REACH`] along each) that puts the
/// tip's end, now at full-frame pixel `tip` with the glass along `axis` (unit, towards
/// the tip), over the plainest floor of `bg`: the strip the tip locator reads (from
/// [`PLAIN_AHEAD`] ahead of the end to [`PLAIN_BEHIND`] behind it along the glass,
/// [`PLAIN_ACROSS`] either side) with the least relative contrast (standard deviation
/// over mean), nearer offsets first among equals. Stage x and z move the image's x and
/// y by one pixel per `pixel` m (the rig's set-up; the image map is not yet measured
/// when the blur is learnt).
pub(super) fn plainest(bg: &Background, tip: [f64; 2], axis: [f64; 2], pixel: f64) -> [f64; 2] {
    let h = (bg.pixels.len() / bg.width.max(1)) as i64;
    let w = bg.width as i64;
    let n = axis[0].hypot(axis[1]);
    let axis = if n > 0.0 && n.is_finite() {
        [axis[0] / n, axis[1] / n]
    } else {
        [0.0, 1.0]
    };
    let across = [-axis[1], axis[0]];
    let (ahead, behind, side) = (
        (PLAIN_AHEAD / pixel).ceil() as i64,
        (PLAIN_BEHIND / pixel).ceil() as i64,
        (PLAIN_ACROSS / pixel).ceil() as i64,
    );
    let contrast = |c: [f64; 2]| -> Option<f64> {
        let (mut s, mut s2, mut n) = (0.0, 0.0, 0.0);
        for a in -behind..=ahead {
            for b in -side..=side {
                let x = (c[0] + a as f64 * axis[0] + b as f64 * across[0]).round() as i64;
                let y = (c[1] + a as f64 * axis[1] + b as f64 * across[1]).round() as i64;
                if x < 0 || y < 0 || x >= w || y >= h {
                    return None;
                }
                let v = bg.pixels[(y * w + x) as usize] as f64;
                s += v;
                s2 += v * v;
                n += 1.0;
            }
        }
        let mean = s / n;
        (mean > 0.0).then(|| (s2 / n - mean * mean).max(0.0).sqrt() / mean)
    };
    let steps = (BLUR_REACH / 3e-6).round() as i64;
    let mut best = ([0.0, 0.0], f64::INFINITY);
    for i in -steps..=steps {
        for j in -steps..=steps {
            let d = [i as f64 * 3e-6, j as f64 * 3e-6];
            let at = [tip[0] + d[0] / pixel, tip[1] + d[1] / pixel];
            if let Some(c) = contrast(at) {
                // A thousandth of contrast per step of distance: nearer among equals.
                let score = c * (1.0 + 1e-3 * (i.abs() + j.abs()) as f64);
                if score < best.1 {
                    best = (d, score);
                }
            }
        }
    }
    best.0
}

/// Solves `e = α u + β v` for (α, β).
pub(super) fn decompose(e: [f64; 2], u: [f64; 2], v: [f64; 2]) -> [f64; 2] {
    let det = u[0] * v[1] - u[1] * v[0];
    [
        (e[0] * v[1] - e[1] * v[0]) / det,
        (u[0] * e[1] - u[1] * e[0]) / det,
    ]
}

/// The median of `v` (the mean of the middle two for an even count); NaN if empty.
pub(super) fn median(mut v: Vec<f64>) -> f64 {
    cellinject_numeric::median(&mut v)
}

/// The lower quartile of `v` (not empty): the value a quarter of the way up the
/// sorted values, interpolated linearly between neighbours.
pub(super) fn lower_quartile(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let at = 0.25 * (v.len() - 1) as f64;
    let (k, f) = (at.floor() as usize, at.fract());
    v[k] + f * (v[(k + 1).min(v.len() - 1)] - v[k])
}

pub(super) fn unit(v: [f64; 2]) -> [f64; 2] {
    let n = v[0].hypot(v[1]);
    [v[0] / n, v[1] / n]
}

/// Darkness of a cell's interior against its local background: one minus the mean
/// intensity inside 0.7 radius over the mean of the ring 1.3-1.7 radii below the
/// pipette's side (pixels, full-frame coordinates).
pub(super) fn cell_darkness(shot: &Shot, c: [f64; 2], r: f64) -> Option<f64> {
    let c = shot.local(c);
    let (mut inner, mut ni, mut outer, mut no) = (0.0, 0, 0.0, 0);
    let k = (1.8 * r).ceil() as i64;
    for j in -k..=k {
        for i in -k..=k {
            let rho = ((i * i + j * j) as f64).sqrt();
            let Some(v) = shot.at(c[0] + i as f64, c[1] + j as f64) else {
                continue;
            };
            if rho < 0.7 * r {
                inner += v;
                ni += 1;
            } else if rho > 1.3 * r && rho < 1.7 * r && j >= 0 {
                outer += v;
                no += 1;
            }
        }
    }
    (ni > 10 && no > 10).then(|| 1.0 - (inner / ni as f64) / (outer / no as f64))
}

/// The far membrane's row (pixels, full frame): the darkest row of the cell's ring
/// beyond its centre, in two column bands either side of the pipette's axis, with
/// sub-pixel interpolation.
pub(super) fn far_edge(shot: &Shot, c: [f64; 2], r: f64) -> Option<f64> {
    let c = shot.local(c);
    let rows: Vec<i64> =
        ((c[1] + 0.5 * r).floor() as i64..=(c[1] + 1.5 * r).ceil() as i64).collect();
    let mut means = Vec::with_capacity(rows.len());
    for &j in &rows {
        let (mut s, mut n) = (0.0, 0);
        let (a, b) = ((0.15 * r).ceil() as i64, (0.5 * r).floor() as i64);
        for i in (a..=b).flat_map(|i| [-i, i]) {
            if let Some(v) = shot.at(c[0] + i as f64, j as f64) {
                s += v;
                n += 1;
            }
        }
        if n == 0 {
            return None;
        }
        means.push(s / n as f64);
    }
    let k = (1..means.len().saturating_sub(1)).min_by(|&a, &b| means[a].total_cmp(&means[b]))?;
    let (l, m, h) = (means[k - 1], means[k], means[k + 1]);
    let den = l - 2.0 * m + h;
    let off = if den > 0.0 {
        (0.5 * (l - h) / den).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    Some(rows[k] as f64 + off + shot.origin[1])
}
