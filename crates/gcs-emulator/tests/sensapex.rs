//! The twin's stages and injector as Sensapex devices (`emulate gcs --sensapex`),
//! driven by the Sensapex driver over loopback UDP: a goto moves the twin's stage,
//! a pulse reaches the twin's injector at its pressure and for its duration; and the
//! bench endpoint's injector beside it.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::net::{TcpListener, UdpSocket};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use cellinject_gcs_emulator::{Running, start};
use cellinject_hw::{Injector, Stage};
use cellinject_model::{Approach, prototype};
use cellinject_sensapex::emulator::{self, parse_devices};
use cellinject_sensapex::{Link, Model, Positioner, PressureChannel};
use cellinject_twin::{SharedTwin, Twin, TwinParams};

fn bench() -> (SharedTwin, Running, emulator::Running) {
    let mut p = TwinParams::default();
    p.rig.approach = Approach::DriveTranslation;
    let twin = Twin::new(&prototype(), p).unwrap().into_shared();
    let gcs = TcpListener::bind("127.0.0.1:0").unwrap();
    let bench = TcpListener::bind("127.0.0.1:0").unwrap();
    let running = start(&twin, gcs, Some(bench), false).unwrap();
    let backed = cellinject_gcs_emulator::sensapex::backed(
        &twin,
        &parse_devices("ump:1,ums:21,umv:31").unwrap(),
    )
    .unwrap();
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    let sx = emulator::serve_backed(socket, backed, None).unwrap();
    (twin, running, sx)
}

fn pulses(twin: &SharedTwin) -> Vec<(f64, f64)> {
    let t = twin.lock().unwrap();
    t.world
        .pulses()
        .iter()
        .map(|p| (p.pressure, p.duration))
        .collect()
}

#[test]
fn a_sensapex_goto_moves_the_twins_stage_and_a_pulse_reaches_its_injector() {
    let (twin, _gcs, sx) = bench();
    let link = Arc::new(Mutex::new(Link::to(sx.addr()).unwrap()));
    assert_eq!(link.lock().unwrap().discover().unwrap(), vec![1, 21, 31]);
    let mut stage = Positioner::open(&link, 1, Model::Manipulator, &[], 1e-3).unwrap();
    let mut feeder = Positioner::open(&link, 21, Model::Stage, &[], 1e-3).unwrap();
    // The twin's stages start at 0, the middle of the devices' travel.
    assert!(stage.position(0).unwrap().abs() < 1e-9);
    stage.move_to(0, 150e-6).unwrap();
    feeder.move_to(1, -1e-3).unwrap();
    let t0 = Instant::now();
    while stage.is_busy().unwrap() || feeder.is_busy().unwrap() {
        assert!(t0.elapsed() < Duration::from_secs(20), "never arrived");
        std::thread::sleep(Duration::from_millis(5));
    }
    let mut own = cellinject_twin::devices(&twin);
    // The twin's own encoders say where the Sensapex devices say.
    for (s, own, axis, want) in [
        (&mut stage, &mut own.stage, 0, 150e-6),
        (&mut feeder, &mut own.feeder, 1, -1e-3),
    ] {
        let (p, e) = (s.position(axis).unwrap(), own.position(axis).unwrap());
        assert!((p - e).abs() < 1e-9, "{p} against the twin's {e}");
        assert!((p - want).abs() < 0.2e-6, "{p} against {want}");
    }
    let mut inj = PressureChannel::open(&link, 31, 1, 200e3).unwrap();
    let before = pulses(&twin).len();
    inj.pulse(20e3, 0.05).unwrap();
    let p = pulses(&twin);
    assert_eq!(p.len(), before + 1, "{p:?}");
    let (pressure, duration) = p[before];
    assert_eq!(pressure, 20e3);
    assert!((0.05..0.15).contains(&duration), "{duration}");
}

#[test]
fn the_bench_endpoints_injector_pulses_the_twin() {
    use cellinject_gcs_emulator::bench::Bench;
    let (twin, gcs, _sx) = bench();
    let b = Bench::connect(&gcs.bench.unwrap().to_string(), Duration::from_secs(2)).unwrap();
    let mut inj = b.injector().unwrap();
    let before = pulses(&twin).len();
    inj.pulse(15e3, 0.02).unwrap();
    assert_eq!(pulses(&twin)[before..], [(15e3, 0.02)]);
    assert!(inj.pulse(inj.max_pressure() * 1.01, 0.02).is_err());
}
