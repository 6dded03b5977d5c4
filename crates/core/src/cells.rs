//! `plate detect`: cells found in a microscope frame of a plate, scored against the
//! plate's truth (the twin's `[[cell]]` and `[[debris]]`): precision, recall, centre and
//! diameter errors.

use cellinject_cells::{Blob, CellsError, Kind, Options, detect};
use cellinject_plate::Plate;
use serde::Serialize;

/// Where a frame's pixels lie in plate (stage) coordinates: the centre of pixel (0, 0)
/// and the pixel pitch, m.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PixelFrame {
    /// m, plate x of pixel (0, 0)'s centre.
    pub x0: f64,
    /// m, plate y of pixel (0, 0)'s centre.
    pub y0: f64,
    /// m per pixel.
    pub pitch: f64,
}

/// One cell found, in plate coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Found {
    /// m.
    pub x_m: f64,
    /// m.
    pub y_m: f64,
    /// m.
    pub diameter_m: f64,
    /// `[row, col]` of the well it lies in, if any.
    pub well: Option<[u32; 2]>,
    /// Split from a touching neighbour.
    pub split: bool,
    /// m, distance to the true cell it matched (null: no true cell there).
    pub centre_error_m: Option<f64>,
}

/// The score of a detection against the truth.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DetectionReport {
    /// Cells on the plate wholly in the frame (3 µm clear of its border).
    pub true_cells: usize,
    /// Debris on the plate wholly in the frame.
    pub true_debris: usize,
    /// Blobs called cells.
    pub found_cells: usize,
    /// Blobs called debris.
    pub found_debris: usize,
    /// Found cells matching a true cell (within half its diameter), each true cell at
    /// most once.
    pub true_positives: usize,
    /// Found cells matching no true cell (debris called a cell counts here).
    pub false_positives: usize,
    /// Debris called a cell (a subset of `false_positives`).
    pub debris_called_cells: usize,
    /// True cells not found.
    pub false_negatives: usize,
    /// `true_positives / found_cells` (`None`: no cell found).
    pub precision: Option<f64>,
    /// `true_positives / true_cells` (`None`: no cell in the frame).
    pub recall: Option<f64>,
    /// m, median and 95th percentile of the matched centres' errors (`None`: no match).
    pub centre_error_m: Option<[f64; 2]>,
    /// m, median of |found − true diameter| over the matches (`None`: no match).
    pub diameter_error_m: Option<f64>,
    /// Every cell found.
    pub cells: Vec<Found>,
}

/// Finds the cells in `pixels` (a `width × height` frame laid on the plate as `at`
/// says) and scores them against the plate's truth. Pixels outside the plate's wells
/// are not searched.
pub fn detect_and_score(
    plate: &Plate,
    pixels: &[u16],
    width: usize,
    height: usize,
    at: PixelFrame,
) -> Result<DetectionReport, CellsError> {
    let to_plate = |b: &Blob| [at.x0 + b.x * at.pitch, at.y0 + b.y * at.pitch];
    // Search inside the plate's outer walls only.
    let half = 0.5 * plate.pitch;
    let (lo_x, lo_y) = (plate.origin[0] - half, plate.origin[1] - half);
    let (hi_x, hi_y) = (
        lo_x + plate.cols as f64 * plate.pitch,
        lo_y + plate.rows as f64 * plate.pitch,
    );
    let exclude: Vec<bool> = (0..width * height)
        .map(|i| {
            let (x, y) = (
                at.x0 + (i % width) as f64 * at.pitch,
                at.y0 + (i / width) as f64 * at.pitch,
            );
            x < lo_x || x > hi_x || y < lo_y || y > hi_y
        })
        .collect();
    let blobs = detect(
        pixels,
        width,
        height,
        &exclude,
        &Options::for_pixel_size(at.pitch),
    )?;
    let (fx1, fy1) = (
        at.x0 + (width as f64 - 1.0) * at.pitch,
        at.y0 + (height as f64 - 1.0) * at.pitch,
    );
    let in_frame = |p: [f64; 2], r: f64| {
        p[0] - r >= at.x0 && p[0] + r <= fx1 && p[1] - r >= at.y0 && p[1] + r <= fy1
    };
    // Centre and diameter of the objects wholly in the frame.
    let in_view = |list: &[cellinject_plate::Object]| -> Vec<([f64; 2], f64)> {
        list.iter()
            .map(|c| (plate.centre(c), c.diameter))
            // With the membrane's blur: a blob touching the border is not measured.
            .filter(|(p, d)| in_frame(*p, 0.5 * d + 3e-6))
            .collect()
    };
    let truth = in_view(&plate.cells);
    let debris = in_view(&plate.debris);
    let mut taken = vec![false; truth.len()];
    let mut cells = Vec::new();
    let mut errors = Vec::new();
    let mut diameter_errors = Vec::new();
    let mut debris_called_cells = 0;
    let mut found_debris = 0;
    for b in &blobs {
        if b.kind == Kind::Debris {
            found_debris += 1;
            continue;
        }
        let p = to_plate(b);
        // Judged like the truth: only what is wholly in the frame counts.
        if !in_frame(p, 0.5 * b.diameter + 3e-6) {
            continue;
        }
        let best = truth
            .iter()
            .enumerate()
            .filter(|(k, _)| !taken[*k])
            .map(|(k, (q, d))| (k, (p[0] - q[0]).hypot(p[1] - q[1]), *d))
            .filter(|(_, dist, d)| *dist <= 0.5 * d)
            .min_by(|a, b| a.1.total_cmp(&b.1));
        let centre_error_m = best.map(|(k, dist, d)| {
            taken[k] = true;
            diameter_errors.push((b.diameter - d).abs());
            dist
        });
        if let Some(e) = centre_error_m {
            errors.push(e);
        } else if debris
            .iter()
            .any(|(q, d)| (p[0] - q[0]).hypot(p[1] - q[1]) <= 0.5 * d + 2e-6)
        {
            debris_called_cells += 1;
        }
        let col = ((p[0] - lo_x) / plate.pitch).floor();
        let row = ((p[1] - lo_y) / plate.pitch).floor();
        let well = (col >= 0.0 && row >= 0.0 && col < plate.cols as f64 && row < plate.rows as f64)
            .then_some([row as u32, col as u32]);
        cells.push(Found {
            x_m: p[0],
            y_m: p[1],
            diameter_m: b.diameter,
            well,
            split: b.split,
            centre_error_m,
        });
    }
    let tp = errors.len();
    let found = cells.len();
    errors.sort_by(f64::total_cmp);
    diameter_errors.sort_by(f64::total_cmp);
    let quantile = |v: &[f64], q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    let centre_error_m =
        (!errors.is_empty()).then(|| [quantile(&errors, 0.5), quantile(&errors, 0.95)]);
    let diameter_error_m = (!diameter_errors.is_empty()).then(|| quantile(&diameter_errors, 0.5));
    Ok(DetectionReport {
        true_cells: truth.len(),
        true_debris: debris.len(),
        found_cells: found,
        found_debris,
        true_positives: tp,
        false_positives: found - tp,
        debris_called_cells,
        false_negatives: truth.len() - tp,
        precision: (found > 0).then(|| tp as f64 / found as f64),
        recall: (!truth.is_empty()).then(|| tp as f64 / truth.len() as f64),
        centre_error_m,
        diameter_error_m,
        cells,
    })
}

/// How well the tip is found in the image (`sim tip`): the tip found in each of `runs`
/// frames against the truth, A1 and A3 at random voltages between frames, the tip in
/// focus.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TipReport {
    /// Frames.
    pub runs: usize,
    /// Magnification.
    pub zoom: f64,
    /// m per pixel.
    pub pixel_size_m: f64,
    /// m, median, 95th percentile and largest distance from the true tip.
    pub error_m: [f64; 3],
    /// m, median |error| along the pipette's axis and across it.
    pub along_across_m: [f64; 2],
    /// Frames where no pipette was found.
    pub not_found: usize,
}

/// Runs the tip trials on `rig` with `pipette` mounted: `runs` times, A1 and A3 to
/// random voltages (0-60 V, within the envelope; A2 at 0 V and the stage lifted by A3's
/// descent keep the tip in focus), a full frame at `zoom`, the tip found from the image
/// (with the glass's foreshortened taper) and compared with `truth` (the true tip in
/// the frame's pixels, from the backend's truth).
pub fn tip_trials<B: cellinject_rig::Backend>(
    rig: &mut cellinject_rig::Rig<B>,
    pipette: &cellinject_rig::PipetteParams,
    zoom: f64,
    runs: usize,
    seed: u64,
    truth: &mut dyn FnMut() -> [f64; 2],
) -> Result<TipReport, crate::sim::SimError> {
    use crate::sim::{Acquisition, SimError, frame};
    use cellinject_hw::{Clock, PiezoChannel, PositionSensor, Stage};
    let dev = |what: &'static str| move |source| SimError::Device { what, source };
    // The stage's height and A3's reading at rest: A3 drives the tip down the
    // pipette's axis, and the stage follows it up to keep the tip in focus.
    let y0 = rig.stage.position(1).map_err(dev("stage"))?;
    let e0 = rig.sensors[2].read().map_err(dev("A3 sensor"))?;
    if !(1..=10_000).contains(&runs) {
        return Err(SimError::Invalid {
            arg: "--runs",
            value: runs as f64,
            reason: "must lie in [1, 10000]".into(),
        });
    }
    let mut rng = cellinject_numeric::rng::Rng::new(seed, 0x7419);
    let (mut errors, mut along, mut across) = (Vec::new(), Vec::new(), Vec::new());
    let mut not_found = 0;
    let mut pitch = f64::NAN;
    for _ in 0..runs {
        // A1 (x) and A3 (down the pipette's axis) anywhere in 0-60 V; A2 stays at 0 V,
        // where the optics were focused (A2 tilts the tip along the optical axis), and
        // the stage lifts the pipette by A3's descent (as read by its sensor).
        for ch in [0, 2] {
            let v = rng.range(0.0, 60.0);
            rig.piezo[ch]
                .set_voltage(v)
                .map_err(|source| SimError::Device {
                    what: "piezo",
                    source,
                })?;
        }
        rig.clock.sleep(0.2).map_err(|source| SimError::Device {
            what: "clock",
            source,
        })?;
        let e3 = rig.sensors[2].read().map_err(dev("A3 sensor"))? - e0;
        rig.stage
            .move_to(1, y0 + e3 * pipette.angle.sin())
            .map_err(dev("stage"))?;
        while rig.stage.is_busy().map_err(dev("stage"))? {
            rig.clock.sleep(0.01).map_err(dev("clock"))?;
        }
        let f = frame(rig, zoom, Acquisition::Full, None)?;
        pitch = f.pixel_size;
        let t = truth();
        match cellinject_cells::tip::locate_tapered(
            &f.pixels,
            f.width as usize,
            f.height as usize,
            f.pixel_size,
            None,
            pipette.outer_taper / pipette.angle.cos(),
        ) {
            Ok(tip) => {
                let (dx, dy) = (tip.x - t[0], tip.y - t[1]);
                errors.push(dx.hypot(dy) * f.pixel_size);
                along.push((dx * tip.axis[0] + dy * tip.axis[1]).abs() * f.pixel_size);
                across.push((-dx * tip.axis[1] + dy * tip.axis[0]).abs() * f.pixel_size);
            }
            Err(_) => not_found += 1,
        }
    }
    let q = |v: &mut Vec<f64>, p: f64| {
        if v.is_empty() {
            return f64::NAN;
        }
        v.sort_by(f64::total_cmp);
        v[((v.len() - 1) as f64 * p).round() as usize]
    };
    Ok(TipReport {
        runs,
        zoom,
        pixel_size_m: pitch,
        error_m: [
            q(&mut errors, 0.5),
            q(&mut errors, 0.95),
            q(&mut errors, 1.0),
        ],
        along_across_m: [q(&mut along, 0.5), q(&mut across, 0.5)],
        not_found,
    })
}
