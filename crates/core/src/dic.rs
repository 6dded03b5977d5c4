//! `dic` and `dic field`: reports over the image correlation of `cellinject-dic`.
//! Decoding image files is the front end's; these take decoded [`Image`]s.

use cellinject_dic::field::{Field, FieldOptions, field_with_progress};
use cellinject_dic::{
    Acceptance, DicError, Dropped, Image, PointOptions, PointResult, correlate_points, judge,
};
use serde::Serialize;

/// A DIC setting out of its domain: `name` (the command line's, without dashes, e.g.
/// `min-zncc`) `rule`, and the value given. Displays as `min-zncc must lie in [-1, 1],
/// got 2`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{name} {rule}, got {value}")]
pub struct ArgError {
    /// The setting, as the command line names it without its dashes.
    pub name: &'static str,
    /// What it must be.
    pub rule: &'static str,
    /// The value given, as text.
    pub value: String,
}

fn arg_error(name: &'static str, rule: &'static str, value: impl std::fmt::Display) -> ArgError {
    ArgError {
        name,
        rule,
        value: value.to_string(),
    }
}

/// The acceptance rule of `dic` and `dic field`, checked: `min_zncc` in [-1, 1],
/// `max_sigma` (px) positive.
pub fn acceptance(min_zncc: f64, max_sigma: f64) -> Result<Acceptance, ArgError> {
    if !(-1.0..=1.0).contains(&min_zncc) {
        return Err(arg_error("min-zncc", "must lie in [-1, 1]", min_zncc));
    }
    if max_sigma.is_nan() || max_sigma <= 0.0 {
        return Err(arg_error(
            "max-sigma",
            "must be a positive number of pixels",
            max_sigma,
        ));
    }
    Ok(Acceptance {
        min_zncc,
        max_sigma,
    })
}

/// A Gaussian prefilter's sigma, checked: in [0, 20] px.
pub fn check_prefilter(sigma: f64) -> Result<(), ArgError> {
    if !(0.0..=20.0).contains(&sigma) {
        return Err(arg_error("prefilter", "must lie in [0, 20] pixels", sigma));
    }
    Ok(())
}

/// The settings of [`synth_pair`], checked: each side 16 to 20000 px, the noise
/// non-negative.
pub fn check_synth(size: (usize, usize), noise: f64) -> Result<(), ArgError> {
    let (w, h) = size;
    if w < 16 || h < 16 || w > 20000 || h > 20000 {
        return Err(arg_error(
            "size",
            "takes WIDTH,HEIGHT between 16 and 20000",
            format!("{:?}", [w, h]),
        ));
    }
    if !(noise >= 0.0 && noise.is_finite()) {
        return Err(arg_error("noise", "must be a non-negative number", noise));
    }
    Ok(())
}

/// `dic synth`: the exact speckle pair, `width` x `height` px (16 to 20000 each), the
/// current image shifted by `shift` (px) and rotated by `rotation` (degrees) about the
/// centre, each with Gaussian noise of `noise` grey levels (independent streams of
/// `seed`).
pub fn synth_pair(
    size: (usize, usize),
    shift: (f64, f64),
    rotation: f64,
    noise: f64,
    seed: u64,
) -> Result<(Image, Image), ArgError> {
    check_synth(size, noise)?;
    let (w, h) = size;
    let mut p = cellinject_dic::synth::SpeckleParams::default_for(w, h);
    p.noise = noise;
    let sp = cellinject_dic::synth::Speckle::new(&p, seed);
    // Two independent noise streams for any seed (wrapping: every u64 is a seed).
    let noise_seed = |k: u64| seed.wrapping_mul(2).wrapping_add(k);
    let r = sp.render_shifted(0.0, 0.0, 0.0, noise_seed(1));
    let c = sp.render_shifted(shift.0, shift.1, rotation.to_radians(), noise_seed(2));
    Ok((r, c))
}

/// One point of `cellinject dic` (an element of its JSON list). A point without a
/// trustworthy match has `u`, `v`, `zncc`, `sigma_u` null, `converged` false and an
/// `error`.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `x`, `y` | px | the reference point (x = column, y = row, pixel centres) |
/// | `u`, `v` | px | its displacement in the current image |
/// | `du_dx`, `du_dy`, `dv_dx`, `dv_dy` | 1 | displacement gradients (affine shape) |
/// | `zncc` | 1 | zero-normalised cross-correlation at the match |
/// | `iterations` | | IC-GN iterations |
/// | `converged` | | whether IC-GN converged |
/// | `sigma_u`, `sigma_v` | px | predicted standard deviation from the noise |
/// | `sigma_noise` | grey levels | noise estimated from the residual |
/// | `subset` | px | side of the subset that gave the match: `--subset`, or larger where the self-adaptive subset grew it |
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum PointReport {
    /// A match.
    Found {
        /// px.
        x: f64,
        /// px.
        y: f64,
        /// px.
        u: f64,
        /// px.
        v: f64,
        /// 1.
        du_dx: f64,
        /// 1.
        du_dy: f64,
        /// 1.
        dv_dx: f64,
        /// 1.
        dv_dy: f64,
        /// 1.
        zncc: f64,
        /// IC-GN iterations.
        iterations: usize,
        /// Converged.
        converged: bool,
        /// px.
        sigma_u: f64,
        /// px.
        sigma_v: f64,
        /// Grey levels.
        sigma_noise: f64,
        /// Subset side used, px.
        subset: usize,
    },
    /// No trustworthy match.
    Missing {
        /// px.
        x: f64,
        /// px.
        y: f64,
        /// null.
        u: Option<f64>,
        /// null.
        v: Option<f64>,
        /// null.
        zncc: Option<f64>,
        /// 0.
        iterations: usize,
        /// false.
        converged: bool,
        /// null.
        sigma_u: Option<f64>,
        /// Why.
        error: &'static str,
    },
}

impl PointReport {
    fn new((x, y): (f64, f64), p: &Option<PointResult>) -> Self {
        match p {
            Some(p) => PointReport::Found {
                x,
                y,
                u: p.u,
                v: p.v,
                du_dx: p.gradients[0],
                du_dy: p.gradients[1],
                dv_dx: p.gradients[2],
                dv_dy: p.gradients[3],
                zncc: p.zncc,
                iterations: p.iterations,
                converged: p.converged,
                sigma_u: p.sigma_u,
                sigma_v: p.sigma_v,
                sigma_noise: p.sigma_noise,
                subset: p.subset,
            },
            None => PointReport::Missing {
                x,
                y,
                u: None,
                v: None,
                zncc: None,
                iterations: 0,
                converged: false,
                sigma_u: None,
                error: "no match (no texture, or the subset left the current image)",
            },
        }
    }
}

/// `cellinject dic`: correlates each of `at` (reference pixels) into `current`. A
/// result that [`judge`] rejects (not converged, ZNCC below `acceptance.min_zncc`,
/// predicted σ above `acceptance.max_sigma`: the rule `dic field` applies too) is not a
/// measurement: it is reported as [`PointReport::Missing`], with the reason.
pub fn points(
    reference: &Image,
    current: &Image,
    at: &[(f64, f64)],
    options: &PointOptions,
    acceptance: &Acceptance,
) -> Result<Vec<PointReport>, DicError> {
    // A point off the image is refused here with the error the DIC gives any point
    // whose subset leaves the image: the DIC's own check overflows on coordinates
    // near usize::MAX (`--at 1e300,1e300` panicked).
    let (w, h) = (reference.width() as f64, reference.height() as f64);
    if let Some(&(x, y)) = at
        .iter()
        .find(|(x, y)| !(*x >= 0.0 && *x < w && *y >= 0.0 && *y < h))
    {
        return Err(DicError::SubsetOutside {
            x,
            y,
            size: options.subset,
            width: reference.width(),
            height: reference.height(),
        });
    }
    // The subset grows by the same rule the results are judged by.
    let options = PointOptions {
        acceptance: *acceptance,
        ..*options
    };
    let res = correlate_points(reference, current, at, &options)?;
    Ok(at
        .iter()
        .zip(&res)
        .map(|(&p, r)| match r.as_ref().map(|q| judge(q, acceptance)) {
            Some(Err(why)) => {
                let mut m = PointReport::new(p, &None);
                if let PointReport::Missing { error, .. } = &mut m {
                    *error = why.reason();
                }
                m
            }
            _ => PointReport::new(p, r),
        })
        .collect())
}

/// The result of `cellinject dic field`: the field itself and its summary.
#[derive(Debug, Clone)]
pub struct FieldReport {
    /// The grid of points.
    pub field: Field,
    /// Points with a match.
    pub found: usize,
    /// Points computed but dropped by the acceptance rule, by reason.
    pub dropped: Dropped,
    /// The rule.
    pub acceptance: Acceptance,
    /// Smallest and largest u over the matched points, px (None if none matched).
    pub u_range: Option<(f64, f64)>,
    /// The same for v.
    pub v_range: Option<(f64, f64)>,
}

impl FieldReport {
    /// Reference-image pixel of grid point `k`.
    pub fn position(&self, k: usize) -> (usize, usize) {
        let f = &self.field;
        (f.x0 + (k % f.nx) * f.step, f.y0 + (k / f.nx) * f.step)
    }
}

fn range(f: &Field, sel: fn(&PointResult) -> f64) -> Option<(f64, f64)> {
    f.points.iter().flatten().map(sel).fold(None, |r, v| {
        Some(match r {
            None => (v, v),
            Some((a, b)) => (a.min(v), b.max(v)),
        })
    })
}

/// `cellinject dic field`: the full field on a grid; points the acceptance rule of the
/// point mode rejects (`options.acceptance`) are left out (no number is reported for
/// them) and counted.
pub fn field_report(
    reference: &Image,
    current: &Image,
    options: &FieldOptions,
) -> Result<FieldReport, DicError> {
    field_report_with_progress(reference, current, options, &|_, _| {})
}

/// [`field_report`], calling `progress(done, total)` with the grid points computed
/// so far as the field grows ([`field_with_progress`]).
pub fn field_report_with_progress(
    reference: &Image,
    current: &Image,
    options: &FieldOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<FieldReport, DicError> {
    let f = field_with_progress(reference, current, options, progress)?;
    Ok(FieldReport {
        found: f.points.iter().flatten().count(),
        dropped: f.dropped,
        acceptance: options.acceptance,
        u_range: range(&f, |p| p.u),
        v_range: range(&f, |p| p.v),
        field: f,
    })
}

/// The JSON summary of `dic field` (the points go to its CSV).
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `points`, `found` | | grid points, of which matched (measurements) |
/// | `dropped` | | computed but rejected by the point mode's rule |
/// | `dropped_by` | | the same by reason: `not_converged`, `low_zncc`, `uncertain` (predicted σ above `max_sigma`), `inconsistent` (contradicted by its neighbours, or none to confirm it) |
/// | `min_zncc`, `max_sigma` | 1, px | the rule's thresholds |
/// | `nx`, `ny`, `step` | –, –, px | the grid |
/// | `u_range`, `v_range` | px | smallest and largest displacement over the matched points |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FieldSummary {
    /// Grid points.
    pub points: usize,
    /// Matched.
    pub found: usize,
    /// Dropped by the acceptance rule.
    pub dropped: usize,
    /// The same by reason.
    pub dropped_by: DroppedBy,
    /// 1.
    pub min_zncc: f64,
    /// px.
    pub max_sigma: f64,
    /// Columns.
    pub nx: usize,
    /// Rows.
    pub ny: usize,
    /// px.
    pub step: usize,
    /// px.
    pub u_range: Option<(f64, f64)>,
    /// px.
    pub v_range: Option<(f64, f64)>,
}

/// Points dropped by the acceptance rule, by reason.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct DroppedBy {
    /// IC-GN did not converge.
    pub not_converged: usize,
    /// ZNCC below `min_zncc`.
    pub low_zncc: usize,
    /// Predicted σ above `max_sigma` (too little texture).
    pub uncertain: usize,
    /// Accepted on its own, but contradicted by its grid neighbours or with none kept
    /// to confirm it (the normalised median test of `cellinject_dic::field`).
    pub inconsistent: usize,
}

impl FieldReport {
    /// What `dic field` reports besides its CSV.
    pub fn summary(&self) -> FieldSummary {
        let f = &self.field;
        let d = self.dropped;
        FieldSummary {
            points: f.nx * f.ny,
            found: self.found,
            dropped: d.total(),
            dropped_by: DroppedBy {
                not_converged: d.not_converged,
                low_zncc: d.low_zncc,
                uncertain: d.uncertain,
                inconsistent: d.inconsistent,
            },
            min_zncc: self.acceptance.min_zncc,
            max_sigma: self.acceptance.max_sigma,
            nx: f.nx,
            ny: f.ny,
            step: f.step,
            u_range: self.u_range,
            v_range: self.v_range,
        }
    }
}

/// The JSON summary of `dic track` (the frames go to its CSV).
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `frames` | | frames read |
/// | `measured` | | tracked or recovered (the first frame included) |
/// | `rejected` | | below `min_zncc` |
/// | `min_zncc` | 1 | the threshold |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrackSummary {
    /// Frames.
    pub frames: usize,
    /// Measured.
    pub measured: usize,
    /// Rejected.
    pub rejected: usize,
    /// Threshold.
    pub min_zncc: f64,
}

/// The JSON summary of `dic synth`.
///
/// | field | unit | meaning |
/// |---|---|---|
/// | `size` | px | width, height |
/// | `shift` | px | the current image's shift (u, v) |
/// | `rotation` | degrees | about the image centre |
/// | `noise` | grey levels | rms |
/// | `seed` | | of the pattern and the noise |
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SynthSummary {
    /// px.
    pub size: (usize, usize),
    /// px.
    pub shift: (f64, f64),
    /// Degrees.
    pub rotation: f64,
    /// Grey levels.
    pub noise: f64,
    /// Seed.
    pub seed: u64,
}
