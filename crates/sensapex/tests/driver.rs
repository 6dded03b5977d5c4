//! The driver against the emulator, in process: every command, a lost datagram, a
//! device that stops answering, a move stopped halfway, a pressure refused before
//! anything is sent.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::net::{SocketAddr, UdpSocket};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use cellinject_hw::{HwError, Injector, Optics, Stage};
use cellinject_sensapex::emulator::{self, Running};
use cellinject_sensapex::{
    LensChanger, Link, Model, Positioner, PressureChannel, SensapexError, SharedLink,
};

fn emulator() -> Running {
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    let devices = emulator::parse_devices("ump:1,ump4:2,ums:21,umv:31").unwrap();
    emulator::serve(socket, &devices, None).unwrap()
}

fn link(to: SocketAddr) -> SharedLink {
    Arc::new(Mutex::new(Link::to(to).unwrap()))
}

fn wait_idle(s: &mut Positioner) -> Duration {
    let t = Instant::now();
    while s.is_busy().unwrap() {
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "still busy after 10 s"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    t.elapsed()
}

#[test]
fn discovery_finds_every_device_and_positions_start_at_the_origin() {
    let emu = emulator();
    let l = link(emu.addr());
    assert_eq!(l.lock().unwrap().discover().unwrap(), vec![1, 2, 21, 31]);
    let mut m = Positioner::open(&l, 1, Model::Manipulator, &[], 1e-3).unwrap();
    assert_eq!(m.axes(), 3);
    assert_eq!(m.positions().unwrap(), vec![0.0; 3]);
    assert_eq!(m.travel(0), (-0.01, 0.01));
    let d4 = Positioner::open(&l, 2, Model::Manipulator, &[], 1e-3).unwrap();
    assert_eq!(d4.axes(), 4);
    let s = Positioner::open(&l, 21, Model::Stage, &[0.0, 0.0, 0.0], 1e-3).unwrap();
    assert_eq!(s.travel(2), (0.0, 0.025));
}

/// A goto: busy while it moves, idle after, and within a nanometre of its target; a
/// second axis commanded while the first moves carries the first along.
#[test]
fn moves_end_on_target_and_are_busy_only_while_moving() {
    let emu = emulator();
    let l = link(emu.addr());
    let mut m = Positioner::open(&l, 1, Model::Manipulator, &[], 1e-3).unwrap();
    m.move_to(0, 200e-6).unwrap();
    assert!(m.is_busy().unwrap());
    m.move_to(2, -50e-6).unwrap();
    let took = wait_idle(&mut m);
    // 200 µm at 1 mm/s: at least 0.2 s.
    assert!(took >= Duration::from_millis(150), "{took:?}");
    let p = m.positions().unwrap();
    assert!((p[0] - 200e-6).abs() <= 1e-9, "{p:?}");
    assert!((p[2] + 50e-6).abs() <= 1e-9, "{p:?}");
    assert_eq!(p[1], 0.0);
    let on = emu.positions(1).unwrap();
    assert!((on[0] - 10_200_000.0).abs() < 1.0, "{on:?}");
}

#[test]
fn a_move_stopped_halfway_ends_between_start_and_target() {
    let emu = emulator();
    let l = link(emu.addr());
    let mut s = Positioner::open(&l, 21, Model::Stage, &[], 1e-3).unwrap();
    s.move_to(0, 2e-3).unwrap();
    std::thread::sleep(Duration::from_millis(300));
    s.stop().unwrap();
    assert!(!s.is_busy().unwrap());
    std::thread::sleep(Duration::from_millis(100));
    let x = s.position(0).unwrap();
    assert!(x > 100e-6 && x < 1e-3, "{x}");
}

#[test]
fn moves_beyond_the_travel_are_refused_before_anything_is_sent() {
    let emu = emulator();
    let l = link(emu.addr());
    let mut m = Positioner::open(&l, 1, Model::Manipulator, &[], 1e-3).unwrap();
    let before = emu.received();
    assert!(matches!(
        m.move_to(0, 0.011),
        Err(HwError::OutOfRange { .. })
    ));
    assert!(matches!(
        m.move_to(0, f64::NAN),
        Err(HwError::NotFinite { .. })
    ));
    assert!(matches!(m.move_to(3, 0.0), Err(HwError::OutOfRange { .. })));
    assert_eq!(emu.received(), before);
}

/// A device that stops answering is a timeout naming it and its address, after
/// the three sends, never a hang; it is used again once it answers.
#[test]
fn a_device_that_stops_answering_is_a_timeout_that_names_it() {
    let emu = emulator();
    let l = link(emu.addr());
    l.lock().unwrap().set_timeout(Duration::from_millis(50));
    let mut m = Positioner::open(&l, 1, Model::Manipulator, &[], 1e-3).unwrap();
    emu.mute(1, true);
    let t = Instant::now();
    let e = m.positions().unwrap_err();
    let took = t.elapsed();
    assert!(
        matches!(
            e,
            SensapexError::Timeout {
                device: 1,
                sends: 3,
                ..
            }
        ),
        "{e}"
    );
    let text = e.to_string();
    assert!(
        text.contains("device 1") && text.contains(&emu.addr().to_string()),
        "{text}"
    );
    assert!(
        took >= Duration::from_millis(140) && took < Duration::from_secs(1),
        "{took:?}"
    );
    match m.move_to(0, 1e-6) {
        Err(HwError::Timeout { device, .. }) => assert!(device.contains("device 1"), "{device}"),
        other => panic!("{other:?}"),
    }
    emu.mute(1, false);
    assert_eq!(m.positions().unwrap().len(), 3);
}

/// A proxy that drops the first datagram from the client: the retransmission with
/// the same message id gets through, and the request succeeds.
#[test]
fn a_lost_datagram_is_sent_again() {
    let emu = emulator();
    let proxy = UdpSocket::bind("127.0.0.1:0").unwrap();
    let to = proxy.local_addr().unwrap();
    let upstream = emu.addr();
    let dropped = Arc::new(Mutex::new(0));
    {
        let dropped = dropped.clone();
        std::thread::spawn(move || {
            let mut buf = [0u8; 1500];
            let mut client = None;
            proxy
                .set_read_timeout(Some(Duration::from_millis(20)))
                .unwrap();
            for _ in 0..500 {
                let Ok((n, from)) = proxy.recv_from(&mut buf) else {
                    continue;
                };
                if from == upstream {
                    if let Some(c) = client {
                        let _ = proxy.send_to(&buf[..n], c);
                    }
                } else {
                    client = Some(from);
                    let mut d = dropped.lock().unwrap();
                    if *d == 0 {
                        *d += 1;
                        continue;
                    }
                    let _ = proxy.send_to(&buf[..n], upstream);
                }
            }
        });
    }
    let l = link(to);
    l.lock().unwrap().set_timeout(Duration::from_millis(50));
    let r = l
        .lock()
        .unwrap()
        .request(
            1,
            cellinject_sensapex::protocol::cmd::GET_POSITIONS,
            &[],
            true,
        )
        .unwrap();
    assert_eq!(r, vec![10_000_000; 3]);
    assert_eq!(*dropped.lock().unwrap(), 1);
}

#[test]
fn a_pulse_opens_the_valve_at_the_pressure_and_closes_it_after() {
    let emu = emulator();
    let l = link(emu.addr());
    let mut inj = PressureChannel::open(&l, 31, 2, 50_000.0).unwrap();
    assert_eq!(inj.max_pressure(), 50_000.0);
    let t = Instant::now();
    std::thread::scope(|s| {
        let seen = s.spawn(|| {
            std::thread::sleep(Duration::from_millis(60));
            emu.channel(31, 1)
        });
        inj.pulse(12_000.0, 0.15).unwrap();
        assert_eq!(
            seen.join().unwrap(),
            Some((12_000.0, 1)),
            "during the pulse"
        );
    });
    assert!(t.elapsed() >= Duration::from_millis(150));
    assert_eq!(emu.channel(31, 1), Some((0.0, 0)), "after the pulse");
    // Above the limit: refused before anything is sent.
    let before = emu.received();
    assert!(matches!(
        inj.pulse(50_001.0, 0.1),
        Err(HwError::OutOfRange {
            what: "pressure",
            ..
        })
    ));
    assert!(matches!(
        inj.pulse(f64::NAN, 0.1),
        Err(HwError::NotFinite { .. })
    ));
    assert_eq!(emu.received(), before);
    assert!(inj.measure().unwrap().abs() < 12_000.0);
}

#[test]
fn a_refused_command_is_an_error_not_a_timeout() {
    let emu = emulator();
    let l = link(emu.addr());
    // A pressure command to a manipulator.
    let e = l
        .lock()
        .unwrap()
        .request(
            1,
            cellinject_sensapex::protocol::cmd::UMV_GET_VALVE,
            &[0],
            true,
        )
        .unwrap_err();
    assert!(matches!(e, SensapexError::Refused { device: 1, .. }), "{e}");
    assert!(PressureChannel::open(&l, 1, 1, 1e4).is_err());
}

/// What a backed uMv channel passes on: the valve's opening as one pulse at the set
/// point, for as long as it stayed open (the set point falls only after the valve
/// closed).
#[test]
fn a_backed_channel_sees_the_pulse_at_its_pressure_for_its_duration() {
    use cellinject_sensapex::emulator::{Backing, DeviceSpec, Kind};
    type Pulses = Arc<Mutex<Vec<(f64, f64)>>>;
    struct Recorder(Pulses);
    impl Backing for Recorder {
        fn pulse(&mut self, pressure: f64, duration: f64) {
            self.0.lock().unwrap().push((pressure, duration));
        }
    }
    let pulses = Pulses::default();
    let spec = DeviceSpec {
        id: 31,
        kind: Kind::Pressure,
    };
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    let emu = emulator::serve_backed(
        socket,
        vec![(
            spec,
            Some(Box::new(Recorder(pulses.clone())) as Box<dyn Backing>),
        )],
        None,
    )
    .unwrap();
    let l = link(emu.addr());
    let mut inj = PressureChannel::open(&l, 31, 1, 80_000.0).unwrap();
    inj.pulse(30_000.0, 0.1).unwrap();
    let p = pulses.lock().unwrap().clone();
    assert_eq!(p.len(), 1, "{p:?}");
    assert_eq!(p[0].0, 30_000.0);
    assert!(p[0].1 >= 0.1 && p[0].1 < 0.2, "{p:?}");
}

/// A request sent twice with one message id (a retransmission): a query is answered
/// both times; a goto moves once (the second is only acknowledged).
#[test]
fn a_retransmitted_query_is_answered_again_and_a_goto_not_repeated() {
    use cellinject_sensapex::Frame;
    use cellinject_sensapex::protocol::{cmd, opt, param};
    let emu = emulator();
    let s = UdpSocket::bind("127.0.0.1:0").unwrap();
    s.set_read_timeout(Some(Duration::from_millis(300)))
        .unwrap();
    let replies = |f: &Frame| {
        s.send_to(&f.encode(), emu.addr()).unwrap();
        let mut got = Vec::new();
        let mut buf = [0u8; 1500];
        while let Ok((n, _)) = s.recv_from(&mut buf) {
            let r = Frame::decode(&buf[..n]).unwrap();
            if r.message_id == f.message_id && r.kind == f.kind {
                got.push(r);
            }
        }
        got
    };
    let q = Frame::request(
        cmd::GET_PARAMETER,
        0x250,
        1,
        7,
        opt::REQ_ACK | opt::REQ_RESP,
        &[param::AXIS_COUNT as i32],
    );
    for _ in 0..2 {
        let r = replies(&q);
        assert!(r.iter().any(|r| r.options & opt::ACK != 0), "{r:?}");
        assert!(r.iter().any(|r| r.ints(0) == vec![0x105, 3]), "{r:?}");
    }
    let step = Frame::request(
        cmd::TAKE_STEP,
        0x250,
        1,
        8,
        opt::REQ_ACK,
        &[5000, 0, 0, 0, 1000, 0, 0, 0, 0],
    );
    for _ in 0..2 {
        replies(&step);
    }
    std::thread::sleep(Duration::from_millis(200));
    let x = emu.positions(1).unwrap()[0];
    assert!((x - 10_005_000.0).abs() < 1.0, "stepped once: {x}");
}

/// A uMs's lens changer as the optics: a zoom is a lens (the device then reports that
/// lens to a second client); a zoom no lens has, outside the lenses' range or NaN is
/// refused naming the lenses; a uMp has no lens changer.
#[test]
fn the_lens_changer_sets_a_zoom_by_its_lens_and_refuses_any_other() {
    let emu = emulator();
    let l = link(emu.addr());
    let mut o = LensChanger::open(&l, 21, &[4.0, 10.0]).unwrap();
    assert_eq!((o.zoom(), o.zoom_range()), (4.0, (4.0, 10.0)));
    o.set_zoom(10.0).unwrap();
    assert_eq!(o.zoom(), 10.0);
    let other = link(emu.addr());
    assert_eq!(
        LensChanger::open(&other, 21, &[4.0, 10.0])
            .unwrap()
            .read()
            .unwrap(),
        2
    );
    let e = o.set_zoom(5.0).unwrap_err().to_string();
    assert!(
        e.contains("no lens of magnification 5x (lens 1 = 4x, lens 2 = 10x)"),
        "{e}"
    );
    assert!(matches!(o.set_zoom(20.0), Err(HwError::OutOfRange { .. })));
    assert!(matches!(
        o.set_zoom(f64::NAN),
        Err(HwError::NotFinite { .. })
    ));
    assert_eq!(o.zoom(), 10.0, "unchanged by a refusal");
    o.set_zoom(4.0 * (1.0 + 5e-4)).unwrap();
    assert_eq!(o.zoom(), 4.0);
    assert!(matches!(
        LensChanger::open(&l, 1, &[4.0, 10.0]),
        Err(SensapexError::Refused { device: 1, .. })
    ));
}
