//! Whatever a controller is fed (references far outside the stroke, measurements that
//! are noise, NaN or absent), what reaches the amplifiers through the rig stays inside
//! the safety envelope, and every command a controller asks for is finite and within
//! `[0, v_max]`.

#![allow(clippy::unwrap_used)]

use cellinject_control::{
    Cascade, Controller, Feedforward, Kind, Measurement, Open, SensorGains, SensorLoop, Stacks,
    Vision,
};
use cellinject_hysteresis::{AnyModel, LogCreep, PrandtlIshlinskii, Range};
use cellinject_model::{Approach, prototype};
use cellinject_rig::fake::{self, Record};
use cellinject_rig::{Rig, RigParams};
use proptest::prelude::*;

fn stacks() -> Stacks {
    Stacks {
        gain: [0.3e-6; 2],
        v_max: [100.0; 2],
    }
}

/// A hysteretic model of a stack: three plays on 0-100 V, 30 µm at the top.
fn model() -> AnyModel {
    AnyModel::Pi(
        PrandtlIshlinskii::new(
            Range {
                min: 0.0,
                max: 100.0,
            },
            0.0,
            PrandtlIshlinskii::even_thresholds(3),
            vec![24e-6, 4e-6, 2e-6],
            0.0,
        )
        .unwrap(),
    )
}

fn controller(kind: Kind) -> Box<dyn Controller> {
    let creep = LogCreep::new(0.015, 1e-3).unwrap();
    let ff = || Feedforward::new(stacks(), [model(), model()], [Some(creep); 2]).unwrap();
    match kind {
        Kind::Open => Box::new(Open::new(stacks()).unwrap()),
        Kind::Feedforward => Box::new(ff()),
        Kind::Sensor => Box::new(SensorLoop::new(ff(), SensorGains::default()).unwrap()),
        Kind::Closed => Box::new(
            Cascade::new(
                SensorLoop::new(ff(), SensorGains::default()).unwrap(),
                [[-5.9, 0.01], [0.02, -5.9]],
                0.6,
                3e-6,
            )
            .unwrap(),
        ),
    }
}

/// A number a broken sensor or camera could deliver.
fn reading() -> impl Strategy<Value = f64> {
    prop_oneof![
        8 => -60e-6..60e-6f64,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(-1.0f64),
    ]
}

#[derive(Debug, Clone)]
struct Step {
    reference: [f64; 2],
    stacks: Option<[f64; 2]>,
    vision: u8,
    tip: [f64; 2],
}

fn step() -> impl Strategy<Value = Step> {
    (
        [-100e-6..100e-6f64, -100e-6..100e-6f64],
        proptest::option::of([reading(), reading()]),
        0u8..3,
        [reading(), reading()],
    )
        .prop_map(|(reference, stacks, vision, tip)| Step {
            reference,
            stacks,
            vision,
            tip,
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn no_controller_ever_drives_the_stacks_outside_the_envelope(
        kind in prop_oneof![Just(Kind::Open), Just(Kind::Feedforward), Just(Kind::Sensor), Just(Kind::Closed)],
        approach in prop_oneof![Just(Approach::DriveTranslation), Just(Approach::JointDeflection)],
        steps in proptest::collection::vec(step(), 1..120),
    ) {
        let p = RigParams { approach, ..RigParams::default() };
        let (devices, log) = fake::devices(&p);
        let mut rig = Rig::new(devices, &prototype(), &p).unwrap();
        let env = cellinject_rig::envelope(&prototype(), &p).unwrap();
        let mut c = controller(kind);
        for (k, s) in steps.iter().enumerate() {
            let m = Measurement {
frame_reference: None,
                stacks: s.stacks,
                vision: match s.vision {
                    0 => Vision::Nothing,
                    1 => Vision::Tip(s.tip),
                    _ => Vision::Rejected,
                },
            };
            let v = c.step(k as f64 * 1e-3, s.reference, &m);
            for x in v {
                prop_assert!(x.is_finite() && (0.0..=100.0).contains(&x), "{kind:?} asked {v:?}");
            }
            let applied = rig.command_tilt(v).unwrap();
            c.applied(applied);
            prop_assert!(env.check([applied[0], applied[1], 0.0]).is_ok(), "{applied:?}");
        }
        // Every voltage the amplifiers received, with the others where they were.
        let mut now = [0.0; 3];
        for r in log.lock().unwrap().iter() {
            if let Record::Voltage { channel, volts } = r {
                now[*channel] = *volts;
                prop_assert!(env.check(now).is_ok(), "{now:?}");
            }
        }
    }
}
