//! The measurement chain on the twin: the microscope camera at 10x renders the speckled
//! marker, the DIC tracks it, and a 50 nm step of the injection axis (the paper's finest
//! DIC resolution, Sec. 4) is measured against the twin's true motion.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use cellinject_dic::track::{Roi, Status, Tracker};
use cellinject_dic::{Image, Shape};
use cellinject_hw::{Camera, CameraSettings, Frame, PiezoChannel};
use cellinject_model::prototype;
use cellinject_twin::{Twin, TwinParams, rig};

#[test]
fn a_50_nm_step_of_a3_is_resolved_through_the_camera() {
    let twin = Twin::new(&prototype(), TwinParams::default())
        .unwrap()
        .into_shared();
    let mut dev = rig(&twin).unwrap();
    // A 480x480 window of the sensor on the marker tab (10x: 0.22 µm per pixel).
    let roi = cellinject_hw::Roi {
        x: 1728 - 240,
        y: 267 - 240,
        width: 480,
        height: 480,
    };
    let s = CameraSettings {
        roi,
        binning: 1,
        bit_depth: 12,
        ..dev.camera.settings()
    };
    dev.camera.configure(s).unwrap();
    let mut f = Frame::default();
    let to_image = |f: &Frame| Image::from_frame(f).unwrap();
    let tip_z = || twin.lock().unwrap().tip().z;
    // A3 is pre-set so that the step works on a settled, crept stack.
    dev.piezo[2].set_voltage(10.0).unwrap();
    dev.camera.grab_into(&mut f).unwrap();
    for _ in 0..20 {
        dev.camera.grab_into(&mut f).unwrap();
    }
    let first = to_image(&f);
    let region = Roi {
        x: 240 - 100,
        y: 240 - 100,
        width: 201,
        height: 201,
    };
    let mut tracker = Tracker::new(&first, region, Shape::Rigid, 0.9).unwrap();
    let z0 = tip_z();
    // The stack creeps (1.5 % per decade): compare with the true position of each frame.
    let (mut before, mut true_before) = (Vec::new(), Vec::new());
    for _ in 0..10 {
        dev.camera.grab_into(&mut f).unwrap();
        let p = tracker.track(&to_image(&f)).unwrap();
        assert_eq!(p.status, Status::Tracked);
        before.push(p.v);
        true_before.push(tip_z() - z0);
    }
    // 50 nm of A3: 60 µm of travel over 100 V.
    dev.piezo[2]
        .set_voltage(10.0 + 50e-9 / 60e-6 * 100.0)
        .unwrap();
    for _ in 0..3 {
        dev.camera.grab_into(&mut f).unwrap();
    }
    let (mut after, mut true_after) = (Vec::new(), Vec::new());
    for _ in 0..10 {
        dev.camera.grab_into(&mut f).unwrap();
        after.push(tracker.track(&to_image(&f)).unwrap().v);
        true_after.push(tip_z() - z0);
    }
    let px = 2.2e-6 / 10.0;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let sd = |v: &[f64]| {
        let m = mean(v);
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
    };
    let measured = (mean(&after) - mean(&before)) * px;
    let truth = mean(&true_after) - mean(&true_before);
    // Scatter of the measurement about the truth, frame by frame.
    let err: Vec<f64> = before
        .iter()
        .zip(&true_before)
        .chain(after.iter().zip(&true_after))
        .map(|(v, t)| v * px - t)
        .collect();
    let sigma = sd(&err);
    println!(
        "A3 step: true {:.2} nm, measured {:.2} nm, frame-to-frame sigma {:.2} nm, SNR {:.0}",
        truth * 1e9,
        measured * 1e9,
        sigma * 1e9,
        measured / sigma
    );
    // A3 drives the tip down the pipette's axis: the camera sees the step's
    // component along the plate, 50 nm times the cosine of the pipette's angle (the
    // stack's creep and the amplifier's quantisation change it by some percent).
    let along = 50e-9 * cellinject_rig::PipetteParams::default().angle.cos();
    assert!(
        truth > 0.7 * along && truth < 1.3 * along,
        "{truth} vs {along}"
    );
    // The difference of two 10-frame means has a standard error of sigma·√(2/10).
    assert!(
        (measured - truth).abs() < 3.0 * sigma * (0.2f64).sqrt(),
        "{measured} vs {truth}"
    );
    assert!(measured / sigma > 3.0);
}
