//! The controllers on the twin, through its two cameras: calibrations, the paper's
//! repeatability experiment (Sec. 4, Fig. 8) per controller, the range of motion
//! (Fig. 7), lost frames, and J3's yield check in the envelope.
//!
//! The acceptance figures come from the paper (`paper-values.toml`, Sec. 4: 3-5 µm and
//! under 1 µm open loop; 50 nm DIC resolution) and the issue (closed loop under
//! 100 nm; the range within 3 % of eqs. 49/58); the twin's truth is independent of the
//! cameras that measure it.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use cellinject_control::Kind;
use cellinject_core::bench::{Bench, Timing};
use cellinject_core::calibrate::{self, PixelCalibration};
use cellinject_core::experiment::{self, Calibrations, RepeatabilityOptions, RepeatabilityReport};
use cellinject_core::vision::Acquisition;
use cellinject_model::{Approach, prototype};
use cellinject_rig::RigParams;
// The calibrations' parameters, as every front end makes them.
use cellinject_session::calibration::{
    HYSTERESIS_SAMPLES, HYSTERESIS_SIZE, JACOBIAN_REPEATS, JACOBIAN_STEP, PIXEL_STEP,
};
use cellinject_twin::{SharedTwin, Twin, TwinParams};

fn params(approach: Approach) -> TwinParams {
    let mut p = TwinParams::default();
    p.rig.approach = approach;
    p.rig.j3_yield = Some(j3_check(approach, 465e6));
    p
}

fn twin(approach: Approach) -> SharedTwin {
    Twin::new(&prototype(), params(approach))
        .unwrap()
        .into_shared()
}

fn truth(t: &SharedTwin) -> Box<dyn FnMut() -> [f64; 3] + '_> {
    Box::new(move || {
        let p = t.lock().unwrap().tip();
        [p.x, p.depth, p.z]
    })
}

/// J3's yield check as the front end builds it (`fea::j3_yield_check`), built once
/// per approach and yield strength and shared by the tests (the joint FEM, without a
/// cache here, takes seconds in a test build, and each twin and bench asks for it).
fn j3_check(approach: Approach, yield_strength: f64) -> cellinject_rig::guard::YieldCheck {
    use cellinject_rig::guard::YieldCheck;
    type Built = Vec<((Approach, u64), YieldCheck)>;
    static BUILT: std::sync::Mutex<Built> = std::sync::Mutex::new(Vec::new());
    let key = (approach, yield_strength.to_bits());
    if let Some((_, c)) = BUILT.lock().unwrap().iter().find(|(k, _)| *k == key) {
        return *c;
    }
    let c = j3_check_built(approach, yield_strength);
    BUILT.lock().unwrap().push((key, c));
    c
}

fn j3_check_built(approach: Approach, yield_strength: f64) -> cellinject_rig::guard::YieldCheck {
    use cellinject_fea::{FeaModel, FeaOptions, NoCache, StructureParams};
    use cellinject_rig::guard::{StressPoint, YIELD_POINTS, YieldCheck};
    let params = StructureParams {
        yield_strength,
        ..StructureParams::default()
    };
    let m = FeaModel::build(&prototype(), &params, FeaOptions::default(), &NoCache).unwrap();
    let map = m.j3_yield_map(approach, YIELD_POINTS).unwrap();
    YieldCheck::new(
        "J3",
        map.yield_strength,
        map.fit_error,
        map.points.iter().map(|a| StressPoint {
            at_zero: a.at_zero,
            per_newton: a.per_newton,
        }),
    )
}

/// A fresh twin of `approach` as its calibrations leave it, with them: calibrated
/// once per approach and copied for each test (the twin is deterministic, so a copy
/// is the twin each test would have calibrated itself).
fn calibrated_twin(approach: Approach) -> (SharedTwin, PixelCalibration, Calibrations) {
    type Done = Vec<(Approach, Twin, PixelCalibration, Calibrations)>;
    static DONE: std::sync::Mutex<Done> = std::sync::Mutex::new(Vec::new());
    let copy = |t: &Twin| t.clone().into_shared();
    if let Some((_, t, px, cal)) = DONE.lock().unwrap().iter().find(|x| x.0 == approach) {
        return (copy(t), *px, cal.clone());
    }
    let tw = twin(approach);
    let (px, cal) = calibrated(&tw, approach);
    let t = tw.lock().unwrap().clone();
    DONE.lock().unwrap().push((approach, t, px, cal.clone()));
    (tw, px, cal)
}

/// The calibrations of a fresh twin, each checked by its own `problem()`.
fn calibrated(tw: &SharedTwin, approach: Approach) -> (PixelCalibration, Calibrations) {
    let mut rig = cellinject_twin::rig(tw).unwrap();
    let marker = RigParams::default().optics.marker;
    let px = calibrate::pixels(&mut rig, marker, PIXEL_STEP).unwrap();
    let hy = calibrate::hysteresis(&mut rig, HYSTERESIS_SAMPLES, HYSTERESIS_SIZE).unwrap();
    let (jac, _) = jacobian(&mut rig, &px, approach).unwrap();
    (
        px,
        Calibrations {
            jacobian: jac,
            hysteresis: hy,
        },
    )
}

/// The Jacobian calibration on `rig` with the pixel maps `px` (15 V steps, 3 repeats),
/// and the frames each camera measured out of focus on the way.
fn jacobian<B: cellinject_rig::Backend>(
    rig: &mut cellinject_rig::Rig<B>,
    px: &PixelCalibration,
    approach: Approach,
) -> Result<(calibrate::JacobianCalibration, [u64; 2]), cellinject_core::bench::BenchError> {
    let marker = RigParams::default().optics.marker;
    let mut bench = Bench::new(
        rig,
        Acquisition::Marker,
        marker,
        px.maps,
        None,
        Timing::default(),
    )?;
    let jac = calibrate::jacobian(
        &mut bench,
        &prototype(),
        approach,
        JACOBIAN_STEP,
        JACOBIAN_REPEATS,
    )?;
    Ok((jac, bench.defocused()))
}

/// A bench tracking the marker on `rig`, with the twin's truth beside the cameras.
fn marker_bench<'r, B: cellinject_rig::Backend>(
    rig: &'r mut cellinject_rig::Rig<B>,
    maps: &[cellinject_core::vision::PixelMap; 2],
    tw: &'r SharedTwin,
) -> Bench<'r, B> {
    let marker = RigParams::default().optics.marker;
    Bench::new(
        rig,
        Acquisition::Marker,
        marker,
        *maps,
        Some(truth(tw)),
        Timing::default(),
    )
    .unwrap()
}

fn run(
    tw: &SharedTwin,
    approach: Approach,
    px: &PixelCalibration,
    cal: &Calibrations,
    kind: Kind,
    opts: RepeatabilityOptions,
) -> RepeatabilityReport {
    let mut rig = cellinject_twin::rig(tw).unwrap();
    let rp = params(approach).rig;
    let stacks = experiment::stacks(&prototype(), &rp, &cal.hysteresis);
    let mut c = experiment::controller(kind, stacks, cal).unwrap();
    let mut bench = marker_bench(&mut rig, &px.maps, tw);
    let r = experiment::repeatability(&mut bench, c.as_mut(), approach, opts, |_| {}).unwrap();
    println!(
        "approach {} {:>11}: cameras max {:.1}/{:.1} nm (distance {:.1} nm), truth max {:.1}/{:.1} nm (distance {:.1} nm), RMS {:.1}/{:.1} nm, cameras vs truth {:.1} nm, settling {:?} frames",
        approach.number(),
        kind.name(),
        r.max_error_m[0] * 1e9,
        r.max_error_m[1] * 1e9,
        r.max_distance_m * 1e9,
        r.true_max_error_m.unwrap()[0] * 1e9,
        r.true_max_error_m.unwrap()[1] * 1e9,
        r.true_max_distance_m.unwrap() * 1e9,
        r.true_rms_error_m.unwrap()[0] * 1e9,
        r.true_rms_error_m.unwrap()[1] * 1e9,
        r.camera_vs_truth_m.unwrap() * 1e9,
        [r.settling_median_frames, r.settling_max_frames]
    );
    r
}

fn repeatability_on(approach: Approach) -> Vec<(Kind, RepeatabilityReport)> {
    let (tw, px, cal) = calibrated_twin(approach);
    // The calibrations agree with the twin they were made on.
    for m in &px.maps {
        assert!(
            (m.metres_per_pixel[0] / 0.22e-6 - 1.0).abs() < 0.005,
            "{m:?}"
        );
    }
    for i in 0..2 {
        assert!(cal.hysteresis.fit_rms_relative[i] < 0.005);
    }
    let mut out = Vec::new();
    // Open loop over the paper's 200 runs (it settles in two frames: a short hold);
    // the sensor loop and the cascade over 40 runs each. (The feedforward alone,
    // which nothing here asserts on, is measured against hysteresis recordings in
    // crates/hysteresis/tests/duhem.rs and crates/core/tests/hysteresis_recording.rs;
    // the sensor loop runs on top of it.)
    let open = RepeatabilityOptions {
        hold: 0.3,
        ..RepeatabilityOptions::default()
    };
    out.push((Kind::Open, run(&tw, approach, &px, &cal, Kind::Open, open)));
    for kind in [Kind::Sensor, Kind::Closed] {
        let opts = RepeatabilityOptions {
            runs: 40,
            ..RepeatabilityOptions::default()
        };
        out.push((kind, run(&tw, approach, &px, &cal, kind, opts)));
    }
    out
}

fn of(v: &[(Kind, RepeatabilityReport)], k: Kind) -> &RepeatabilityReport {
    &v.iter().find(|(kind, _)| *kind == k).unwrap().1
}

#[test]
fn approach_1_open_loop_scatters_3_to_5_um_and_the_cascade_brings_it_under_100_nm() {
    let r = repeatability_on(Approach::DriveTranslation);
    // The paper's 200 open-loop runs: 3-5 µm (Sec. 4, paper-values max_error_approach1).
    let open = of(&r, Kind::Open);
    assert!(
        (3e-6..=5e-6).contains(&open.true_max_distance_m.unwrap()),
        "{open:?}"
    );
    // The stack sensors cannot see the joints' stick-slip: the sensor loop leaves
    // micrometres of it.
    let sensor = of(&r, Kind::Sensor);
    assert!(sensor.true_max_distance_m.unwrap() > 1e-6, "{sensor:?}");
    // The cameras see it: the cascade lands within 100 nm every time.
    let closed = of(&r, Kind::Closed);
    let t = closed.true_max_error_m.unwrap();
    assert!(t[0] < 100e-9 && t[1] < 100e-9, "{closed:?}");
    for (_, x) in &r {
        assert!(x.camera_vs_truth_m.unwrap() < 50e-9, "{x:?}");
    }
}

#[test]
fn approach_2_open_loop_stays_under_1_um_and_the_cascade_under_100_nm() {
    let r = repeatability_on(Approach::JointDeflection);
    let open = of(&r, Kind::Open);
    assert!(open.true_max_distance_m.unwrap() <= 1e-6, "{open:?}");
    let closed = of(&r, Kind::Closed);
    let t = closed.true_max_error_m.unwrap();
    assert!(t[0] < 100e-9 && t[1] < 100e-9, "{closed:?}");
    for (_, x) in &r {
        assert!(x.camera_vs_truth_m.unwrap() < 50e-9, "{x:?}");
    }
}

/// Steps and a 1 Hz circle under approach 2: the cascade follows a moving target (each
/// frame compared with where the tip should have been while it was exposed), and the
/// linear open loop misses by the stacks' hysteresis. Before the frame's reference was
/// used the circle's RMS error was ~260 nm; before per-stack anti-windup, targets near a
/// stack's rest were never corrected.
#[test]
fn the_cascade_tracks_steps_and_a_circle_where_open_loop_misses_by_microns() {
    use cellinject_core::experiment::TrackingOptions;
    let approach = Approach::JointDeflection;
    let (tw, px, cal) = calibrated_twin(approach);
    let rp = params(approach).rig;
    let mut rig = cellinject_twin::rig(&tw).unwrap();
    let stacks = experiment::stacks(&prototype(), &rp, &cal.hysteresis);
    let mut bench = marker_bench(&mut rig, &px.maps, &tw);
    let opts = TrackingOptions {
        duration: 2.0,
        ..TrackingOptions::default()
    };
    let mut report = |kind| {
        let mut c = experiment::controller(kind, stacks, &cal).unwrap();
        let j = cal.jacobian.jacobian;
        // The device time the front ends' progress bars are sized with.
        let seen = std::rc::Rc::new(std::cell::Cell::new(0.0));
        let last = seen.clone();
        bench.watch(move |t| last.set(t));
        let r = experiment::tracking(&mut bench, c.as_mut(), approach, j, opts).unwrap();
        assert!(
            (seen.get() - opts.seconds()).abs() < 0.1,
            "{} s of device time, {} s foreseen",
            seen.get(),
            opts.seconds()
        );
        println!(
            "{:>8}: steps RMS {:.1}/{:.1} nm (true {:.1}/{:.1}), circle RMS {:.1}/{:.1} nm (true {:.1}/{:.1}), settling {:?}",
            kind.name(),
            r.steps.rms_error_m[0] * 1e9,
            r.steps.rms_error_m[1] * 1e9,
            r.steps.true_rms_error_m.unwrap()[0] * 1e9,
            r.steps.true_rms_error_m.unwrap()[1] * 1e9,
            r.sine.rms_error_m[0] * 1e9,
            r.sine.rms_error_m[1] * 1e9,
            r.sine.true_rms_error_m.unwrap()[0] * 1e9,
            r.sine.true_rms_error_m.unwrap()[1] * 1e9,
            r.steps.settling_frames
        );
        r
    };
    let closed = report(Kind::Closed);
    for p in [&closed.steps, &closed.sine] {
        for a in 0..2 {
            assert!(p.rms_error_m[a] < 60e-9, "{p:?}");
            assert!(p.true_rms_error_m.unwrap()[a] < 60e-9, "{p:?}");
        }
    }
    assert!(closed.steps.settling_frames.iter().all(|s| s.is_some()));
    let open = report(Kind::Open);
    assert!(
        open.steps.true_rms_error_m.unwrap()[0] > 1e-6,
        "{:?}",
        open.steps
    );
    assert!(open.steps.settling_frames.iter().all(|s| s.is_none()));
}

#[test]
fn the_range_of_motion_is_the_models_under_approach_2_and_torque_limited_under_approach_1() {
    // The paper's eq. (58), from its figures.
    let chi = cellinject_paper::figures()
        .iter()
        .find(|f| f.eq == 58 && f.key == "chi")
        .unwrap()
        .value[0];
    for approach in [Approach::JointDeflection, Approach::DriveTranslation] {
        let tw = twin(approach);
        let mut rig = cellinject_twin::rig(&tw).unwrap();
        let marker = RigParams::default().optics.marker;
        let px = calibrate::pixels(&mut rig, marker, PIXEL_STEP).unwrap();
        let mut bench = Bench::new(
            &mut rig,
            Acquisition::Wide,
            marker,
            px.maps,
            Some(truth(&tw)),
            Timing::default(),
        )
        .unwrap();
        let seen = std::rc::Rc::new(std::cell::Cell::new(0.0));
        let last = seen.clone();
        bench.watch(move |t| last.set(t));
        let r = experiment::range(&mut bench, &prototype(), &params(approach).rig, 3.0).unwrap();
        let foreseen = experiment::range_seconds(3.0);
        assert!(
            (seen.get() - foreseen).abs() < 0.1,
            "{} s of device time, {foreseen} s foreseen",
            seen.get()
        );
        println!(
            "approach {}: range x {:.2} µm, y {:.2} µm (true {:.2}, {:.2}); stacks up to {:.1} V, {:.1} V; {:?}",
            approach.number(),
            r.range_m.x * 1e6,
            r.range_m.y * 1e6,
            r.true_range_m.unwrap().x * 1e6,
            r.true_range_m.unwrap().y * 1e6,
            r.v_max[0],
            r.v_max[1],
            r.limited_by
        );
        let t = r.true_range_m.unwrap();
        // The cameras measure the range to better than 0.1 %.
        assert!((r.range_m.x / t.x - 1.0).abs() < 1e-3);
        assert!((r.range_m.y / t.y - 1.0).abs() < 1e-3);
        match approach {
            Approach::JointDeflection => {
                // Eqs. 49/58: 177.4 µm per axis, with every check (J3's yield too) on.
                assert!((r.range_m.x / chi - 1.0).abs() < 0.03, "{}", r.range_m.x);
                assert!((r.range_m.y / chi - 1.0).abs() < 0.03, "{}", r.range_m.y);
                assert_eq!(r.limited_by, [None, None]);
            }
            Approach::DriveTranslation => {
                // J1/J2's 0.35 N·m torque limit stops the stacks near 68 V (Sec. 3.2.1).
                for i in 0..2 {
                    assert!((66.0..70.0).contains(&r.v_max[i]), "{}", r.v_max[i]);
                    assert!(r.limited_by[i].as_deref().unwrap().contains("torque"));
                }
                assert!(r.range_m.x < 0.75 * chi);
            }
        }
    }
}

#[test]
fn the_envelope_refuses_what_would_yield_j3_and_says_by_how_much_it_cuts_the_range() {
    use cellinject_hw::SafetyError;
    let design = prototype();
    let rig = |approach, y| {
        let mut r = RigParams {
            approach,
            ..RigParams::default()
        };
        r.j3_yield = Some(j3_check(approach, y));
        cellinject_rig::envelope(&design, &r).unwrap()
    };
    // The prototype's X2CrNi18-9 (465 MPa): approach 2's full stroke stays below yield,
    // with its margins (hysteresis 20 %, overshoot 3 % of travel) on.
    let e = rig(Approach::JointDeflection, 465e6);
    let worst = e.check([100.0, 100.0, 0.0]).unwrap();
    println!(
        "approach 2 at 100 V: J3 up to {:.1} MPa of 465 (margin {:.1} %)",
        worst.j3_stress / 1e6,
        (1.0 - worst.j3_stress / 465e6) * 100.0
    );
    assert!(worst.j3_stress > 400e6 && worst.j3_stress < 465e6);
    // A weaker steel (430 MPa) yields before the stacks' full stroke: refused, and the
    // highest safe voltage says by how much the range is cut.
    let weak = rig(Approach::JointDeflection, 430e6);
    let err = weak.check([100.0, 100.0, 0.0]).unwrap_err();
    assert!(
        matches!(err, SafetyError::Yield { joint: "J3", .. }),
        "{err}"
    );
    let v = weak.max_safe_voltage(0, [0.0, 100.0, 0.0]).unwrap();
    let just_past = weak.check([v + 0.01, 100.0, 0.0]).unwrap_err();
    assert!(
        matches!(just_past, SafetyError::Yield { .. }),
        "{just_past}"
    );
    println!("430 MPa steel: A1 limited to {v:.1} V with A2 at 100 V ({just_past})");
    assert!(v < 100.0 && v > 0.0);
}

/// A camera that loses every `every`-th frame: it delivers sensor noise instead.
struct Lossy {
    inner: cellinject_twin::TwinCamera,
    every: u64,
    count: u64,
    lost: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

impl cellinject_hw::Camera for Lossy {
    fn sensor_size(&self) -> (u32, u32) {
        self.inner.sensor_size()
    }
    fn settings(&self) -> cellinject_hw::CameraSettings {
        self.inner.settings()
    }
    fn configure(
        &mut self,
        s: cellinject_hw::CameraSettings,
    ) -> Result<(), cellinject_hw::HwError> {
        self.inner.configure(s)
    }
    fn frame_rate(&self) -> f64 {
        self.inner.frame_rate()
    }
    fn grab_into(
        &mut self,
        frame: &mut cellinject_hw::Frame,
    ) -> Result<(), cellinject_hw::HwError> {
        self.inner.grab_into(frame)?;
        self.count += 1;
        // The reference frame and the calibration frames are kept.
        if self.count > 3 && self.count % self.every == 0 {
            let mut rng = cellinject_twin::rng::Rng::new(self.count, 99);
            for p in &mut frame.pixels {
                *p = (rng.uniform() * 4095.0) as u16;
            }
            self.lost.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        Ok(())
    }
}

struct LossyTwin;

impl cellinject_rig::Backend for LossyTwin {
    type Piezo = cellinject_twin::devices::TwinPiezo;
    type Sensor = cellinject_twin::devices::TwinSensor;
    type Camera = Lossy;
    type Stage = cellinject_twin::devices::TwinStage;
    type Injector = cellinject_twin::devices::TwinInjector;
    type Optics = cellinject_twin::devices::TwinOptics;
    type Clock = cellinject_twin::devices::TwinClock;
}

#[test]
fn lost_frames_are_rejected_and_hold_the_command_instead_of_steering_it() {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicU64, Ordering};
    let approach = Approach::JointDeflection;
    let (tw, px, cal) = calibrated_twin(approach);
    let d = cellinject_twin::devices(&tw);
    let lost = Arc::new(AtomicU64::new(0));
    let lossy = |inner| Lossy {
        inner,
        every: 4,
        count: 0,
        lost: lost.clone(),
    };
    let devices = cellinject_rig::Devices::<LossyTwin> {
        piezo: d.piezo,
        sensors: d.sensors,
        camera: lossy(d.camera),
        side_camera: lossy(d.side_camera),
        stage: d.stage,
        feeder: d.feeder,
        injector: d.injector,
        optics: d.optics,
        clock: d.clock,
    };
    let rp = params(approach).rig;
    let mut rig = cellinject_rig::Rig::new(devices, &prototype(), &rp).unwrap();
    let stacks = experiment::stacks(&prototype(), &rp, &cal.hysteresis);
    let mut c = experiment::controller(Kind::Closed, stacks, &cal).unwrap();
    let mut bench = marker_bench(&mut rig, &px.maps, &tw);
    let opts = RepeatabilityOptions {
        runs: 10,
        ..RepeatabilityOptions::default()
    };
    let r = experiment::repeatability(&mut bench, c.as_mut(), approach, opts, |_| {}).unwrap();
    // Every noise frame was rejected by the correlation, none was measured.
    let lost = lost.load(Ordering::Relaxed);
    assert!(lost > 50, "{lost}");
    assert_eq!(r.rejected_frames[0] + r.rejected_frames[1], lost);
    // Acting on none of them, the cascade still lands within 100 nm.
    let t = r.true_max_error_m.unwrap();
    println!(
        "{lost} frames lost: true max error {:.1}/{:.1} nm",
        t[0] * 1e9,
        t[1] * 1e9
    );
    assert!(t[0] < 100e-9 && t[1] < 100e-9, "{r:?}");
}

/// A small seed sweep (the large one is `bench/seed_sweep.sh`): on these seeds the
/// marker's correlation with its sharp reference fell to ZNCC 0.755-0.80 while the
/// other camera's axis moved 16-22 µm (defocus), and `calibrate all` exited 1. Both
/// calibrations now hold, the Jacobian within its tolerance of the mechanism model, and
/// the cameras measured out of focus on the way (the ladder was needed).
#[test]
fn calibrations_hold_on_seeds_where_the_marker_went_out_of_focus() {
    for (approach, seed) in [
        (Approach::DriveTranslation, 3),
        (Approach::JointDeflection, 2),
    ] {
        let mut p = params(approach);
        p.sim.seed = seed;
        let tw = Twin::new(&prototype(), p).unwrap().into_shared();
        let mut rig = cellinject_twin::rig(&tw).unwrap();
        let marker = RigParams::default().optics.marker;
        let px = calibrate::pixels(&mut rig, marker, PIXEL_STEP).unwrap();
        assert!(px.problem(px.maps[0].zoom).is_none());
        let (jac, defocused) = jacobian(&mut rig, &px, approach)
            .unwrap_or_else(|e| panic!("approach {approach:?}, seed {seed}: {e}"));
        eprintln!(
            "approach {approach:?}, seed {seed}: Jacobian {:.2} % from the model, spread {:.2} %, steps {:?} V, frames out of focus {defocused:?}",
            jac.deviation * 100.0,
            jac.spread * 100.0,
            jac.volts
        );
        assert!(jac.problem().is_none());
        assert!(
            defocused.iter().sum::<u64>() > 0,
            "the ladder was not needed"
        );
    }
}
