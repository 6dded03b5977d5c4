//! The same guard over two backends: the twin and the recording fake of
//! `cellinject-rig` refuse exactly the same commands, with the same reasons, and a
//! refused command never reaches either device.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use cellinject_hw::{HwError, Injector, Optics, PiezoChannel, Stage};
use cellinject_model::{Approach, prototype};
use cellinject_rig::fake::{self, Record};
use cellinject_rig::{Backend, Rig};
use cellinject_twin::{Twin, TwinParams};
use proptest::prelude::*;

/// One command a controller might send.
#[derive(Debug, Clone, Copy)]
enum Command {
    Volts(usize, f64),
    Stage(usize, f64),
    Feeder(usize, f64),
    Pulse(f64, f64),
    Zoom(f64),
}

fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        4 => (0usize..3, -20.0f64..130.0).prop_map(|(c, v)| Command::Volts(c, v)),
        1 => (0usize..3, -0.02f64..0.02).prop_map(|(a, x)| Command::Stage(a, x)),
        // The feeder's ±25 mm, and past it; axis 3 does not exist.
        1 => (0usize..4, -0.04f64..0.04).prop_map(|(a, x)| Command::Feeder(a, x)),
        1 => (-1e5f64..4e5, 0.0f64..0.5).prop_map(|(p, d)| Command::Pulse(p, d)),
        1 => (1.0f64..12.0).prop_map(Command::Zoom),
    ]
}

fn send<B: Backend>(rig: &mut Rig<B>, c: Command) -> Result<(), HwError> {
    match c {
        Command::Volts(ch, v) => rig.piezo[ch].set_voltage(v),
        Command::Stage(a, x) => rig.stage.move_to(a, x),
        Command::Feeder(a, x) => rig.feeder.move_to(a, x),
        Command::Pulse(p, d) => rig.injector.pulse(p, d),
        Command::Zoom(z) => rig.optics.set_zoom(z),
    }
}

fn record_of(c: Command) -> Record {
    match c {
        Command::Volts(channel, volts) => Record::Voltage { channel, volts },
        Command::Stage(axis, position) => Record::Stage { axis, position },
        Command::Feeder(axis, position) => Record::Feeder { axis, position },
        Command::Pulse(pressure, duration) => Record::Pulse { pressure, duration },
        Command::Zoom(zoom) => Record::Zoom { zoom },
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn twin_and_fake_refuse_exactly_the_same_commands(
        approach in prop_oneof![Just(Approach::DriveTranslation), Just(Approach::JointDeflection)],
        commands in prop::collection::vec(command(), 1..40),
    ) {
        let mut p = TwinParams::default();
        p.rig.approach = approach;
        let twin = Twin::new(&prototype(), p).unwrap().into_shared();
        let mut on_twin = cellinject_twin::rig(&twin).unwrap();
        let (devices, log) = fake::devices(&p.rig);
        let mut on_fake = Rig::new(devices, &prototype(), &p.rig).unwrap();
        let mut accepted = Vec::new();
        let mut refused = 0;
        for c in commands {
            let a = send(&mut on_twin, c);
            let b = send(&mut on_fake, c);
            match (&a, &b) {
                (Ok(()), Ok(())) => accepted.push(record_of(c)),
                (Err(HwError::Refused(x)), Err(HwError::Refused(y))) => {
                    prop_assert_eq!(x, y);
                    refused += 1;
                }
                _ => prop_assert!(false, "{c:?}: twin {a:?}, fake {b:?}"),
            }
        }
        // What reached the fake is exactly what the guard accepted.
        prop_assert_eq!(&*fake::records(&log), &accepted);
        let _ = refused;
    }
}

#[test]
fn both_backends_refuse_the_papers_unsafe_stroke_under_approach_1() {
    let mut p = TwinParams::default();
    p.rig.approach = Approach::DriveTranslation;
    let twin = Twin::new(&prototype(), p).unwrap().into_shared();
    let mut on_twin = cellinject_twin::rig(&twin).unwrap();
    let (devices, log) = fake::devices(&p.rig);
    let mut on_fake = Rig::new(devices, &prototype(), &p.rig).unwrap();
    let a = on_twin.piezo[0].set_voltage(100.0).unwrap_err();
    let b = on_fake.piezo[0].set_voltage(100.0).unwrap_err();
    assert_eq!(a, b);
    assert!(a.to_string().contains("torque limit"), "{a}");
    assert!(fake::records(&log).is_empty());
    // Both allow the same highest voltage (the envelope depends on the description only).
    assert_eq!(on_twin.max_safe_voltage(0), on_fake.max_safe_voltage(0));
    let v = on_fake.max_safe_voltage(0).unwrap();
    assert!((60.0..75.0).contains(&v), "{v}");
}
