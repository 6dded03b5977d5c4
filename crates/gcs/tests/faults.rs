//! The driver against controllers that misbehave (a fake controller on loopback): a
//! connection lost mid-command, garbage replies, a controller that answers too late,
//! and random replies (proptest). Each ends in an error that says what happened, and
//! the next command first re-establishes the link and stops the axes (`STP`).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{BufRead, BufReader, Write};
use std::net::TcpListener;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use cellinject_gcs::{Gcs, GcsError};
use proptest::prelude::*;

/// What a fake controller does with one command line on connection `conn` (0, 1, ...):
/// the bytes to answer, and whether to hang up afterwards.
type Script = dyn Fn(usize, &str) -> (Vec<u8>, bool) + Send + Sync;

/// A fake controller; returns its address and the lines it received, per connection.
fn fake(script: Arc<Script>) -> (String, Arc<Mutex<Vec<Vec<String>>>>) {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap().to_string();
    let seen: Arc<Mutex<Vec<Vec<String>>>> = Arc::default();
    let s2 = seen.clone();
    std::thread::spawn(move || {
        for (conn, stream) in l.incoming().enumerate() {
            let Ok(stream) = stream else { return };
            s2.lock().unwrap().push(Vec::new());
            let mut w = stream.try_clone().unwrap();
            let r = BufReader::new(stream);
            for line in r.split(b'\n') {
                let Ok(line) = line else { break };
                let line = String::from_utf8_lossy(&line).into_owned();
                s2.lock().unwrap()[conn].push(line.clone());
                let (answer, hang_up) = script(conn, &line);
                if w.write_all(&answer).is_err() || hang_up {
                    break;
                }
            }
        }
    });
    (addr, seen)
}

/// A well-behaved controller of three axes, for what the script does not override.
fn normal(line: &str) -> Vec<u8> {
    match line.split_whitespace().next().unwrap_or("") {
        "SAI?" => b"1 \n2 \n3\n".to_vec(),
        "ERR?" => b"0\n".to_vec(),
        "POS?" => b"1=1.5\n".to_vec(),
        "SVA?" => b"1=0 \n2=0 \n3=0\n".to_vec(),
        _ => Vec::new(),
    }
}

fn open(addr: &str, timeout_ms: u64) -> Gcs {
    Gcs::tcp(addr, Duration::from_millis(timeout_ms)).unwrap()
}

#[test]
fn a_connection_lost_mid_command_is_reported_and_the_axes_stopped_when_it_is_back() {
    let (addr, seen) = fake(Arc::new(|conn, line: &str| {
        // The first connection dies on the first move.
        if conn == 0 && line.starts_with("SVA") {
            return (Vec::new(), true);
        }
        (normal(line), false)
    }));
    let mut g = open(&addr, 500);
    let e = g.set_voltage(&[("3", 10.0)]).unwrap_err();
    assert!(e.link_lost(), "{e}");
    assert!(matches!(e, GcsError::Link { .. }), "{e}");
    // Back: the driver reconnects and stops the axes before anything else.
    assert_eq!(g.position(&["1"]).unwrap(), vec![1.5]);
    assert_eq!(g.reconnections, 1);
    let seen = seen.lock().unwrap();
    assert_eq!(seen[1][0], "STP", "{seen:?}");
    assert_eq!(seen[1][1], "ERR?");
    assert_eq!(seen[1][2], "POS? 1");
    // Nothing but whole lines went out: every line the controller saw is a command.
    for l in seen.iter().flatten() {
        assert!(
            ["SAI?", "ERR?", "SVA 3 10", "STP", "POS? 1"].contains(&l.as_str()),
            "{l}"
        );
    }
}

#[test]
fn garbage_replies_are_refused_with_what_came() {
    let (addr, seen) = fake(Arc::new(|conn, line: &str| {
        if conn == 0 && line.starts_with("POS?") {
            return (b"\xff\xfe#!garbage\n".to_vec(), false);
        }
        if conn == 1 && line.starts_with("POS?") {
            return (b"2=1.0\n".to_vec(), false);
        }
        (normal(line), false)
    }));
    let mut g = open(&addr, 500);
    let e = g.position(&["1"]).unwrap_err();
    assert!(matches!(e, GcsError::Reply { .. }), "{e}");
    assert!(e.to_string().contains("POS? 1"), "{e}");
    // The wrong axis in a reply is refused too (after the link was renewed + STP).
    let e = g.position(&["1"]).unwrap_err();
    assert!(matches!(e, GcsError::Reply { .. }), "{e}");
    assert!(e.to_string().contains("axes"), "{e}");
    assert_eq!(seen.lock().unwrap()[1][0], "STP");
}

#[test]
fn a_controller_that_answers_too_late_times_out_and_its_late_answer_is_dropped() {
    let (addr, seen) = fake(Arc::new(|conn, line: &str| {
        if conn == 0 && line.starts_with("POS?") {
            std::thread::sleep(Duration::from_millis(400));
            return (b"1=9.9\n".to_vec(), false);
        }
        (normal(line), false)
    }));
    let mut g = open(&addr, 150);
    let t = Instant::now();
    let e = g.position(&["1"]).unwrap_err();
    assert!(matches!(e, GcsError::Timeout { .. }), "{e}");
    // One timeout for the query and one for the ERR? that asked why: never a hang.
    assert!(
        t.elapsed() < Duration::from_millis(600),
        "{:?}",
        t.elapsed()
    );
    // The late 9.9 never passes for the answer to a later query.
    assert_eq!(g.position(&["1"]).unwrap(), vec![1.5]);
    let seen = seen.lock().unwrap();
    assert_eq!(seen[1][0], "STP", "{seen:?}");
}

#[test]
fn set_commands_read_back_the_sticky_error() {
    let (addr, _) = fake(Arc::new(|_, line: &str| {
        if line == "ERR?" {
            return (b"7\n".to_vec(), false);
        }
        (normal(line), false)
    }));
    // Connecting clears the error the controller had (ERR? answers 7 once here, then
    // again: the fake's error never clears, so every set command fails with it).
    let mut g = Gcs::tcp(&addr, Duration::from_millis(300)).unwrap();
    let e = g.move_to(&[("1", 50.0)]).unwrap_err();
    assert_eq!(e.controller_error().map(|c| c.code()), Some(7), "{e}");
    assert!(!e.link_lost());
}

#[cfg(feature = "serial")]
#[test]
fn the_driver_speaks_over_a_pseudo_terminal() {
    use serialport::{SerialPort, TTYPort};
    let (mut master, slave) = TTYPort::pair().unwrap();
    let name = slave.name().unwrap_or_default();
    std::thread::spawn(move || {
        let mut buf = Vec::new();
        let mut b = [0u8; 64];
        master.set_timeout(Duration::from_secs(5)).unwrap();
        while let Ok(n) = std::io::Read::read(&mut master, &mut b) {
            buf.extend_from_slice(&b[..n]);
            while let Some(k) = buf.iter().position(|&c| c == b'\n') {
                let line: Vec<u8> = buf.drain(..=k).collect();
                let line = String::from_utf8_lossy(&line[..k]).into_owned();
                let a = if line == "CSV?" {
                    b"2.0\n".to_vec()
                } else {
                    normal(&line)
                };
                master.write_all(&a).unwrap();
            }
        }
    });
    let link =
        cellinject_gcs::link::Serial::from_port(Box::new(slave), &name, Duration::from_secs(1));
    let mut g = Gcs::new(Box::new(link), Duration::from_secs(1)).unwrap();
    assert_eq!(g.axis_ids(), ["1", "2", "3"]);
    assert_eq!(g.syntax_version().unwrap(), "2.0");
    g.set_voltage(&[("2", 5.0)]).unwrap();
    assert!(g.describe().starts_with("gcs-serial://"));
}

proptest! {
    /// The framing functions take any bytes.
    #[test]
    fn framing_takes_any_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        use cellinject_gcs::protocol::*;
        if let Some(end) = reply_end(&bytes) {
            prop_assert!(end <= bytes.len() && bytes[end - 1] == b'\n');
            let text = String::from_utf8_lossy(&bytes[..end]);
            let lines = reply_lines(&text);
            let _ = parse_pairs(&lines);
            for l in lines {
                let _ = (parse_number(l), parse_bool(l), parse_mask(l));
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, ..ProptestConfig::default() })]

    /// Whatever a controller answers, the driver returns within its timeouts, without
    /// panicking.
    #[test]
    fn random_replies_never_panic_or_hang(reply in proptest::collection::vec(any::<u8>(), 0..200)) {
        let r = Arc::new(reply);
        let (addr, _) = fake(Arc::new(move |conn, line: &str| {
            if conn == 0 && (line == "SAI?" || line == "ERR?") {
                return (normal(line), false);
            }
            ((*r).clone(), false)
        }));
        // Connecting (the well-behaved SAI?/ERR?) gets a timeout no loaded machine
        // misses; the random replies then 60 ms each.
        let mut g = open(&addr, 5000);
        g.set_timeout(Duration::from_millis(60)).unwrap();
        let t = Instant::now();
        let _ = g.position(&["1", "2"]);
        let _ = g.servo(&[]);
        let _ = g.moving_mask();
        let _ = g.ready();
        let _ = g.set_voltage(&[("1", 1.0)]);
        let _ = g.identify();
        prop_assert!(t.elapsed() < Duration::from_secs(3), "{:?}", t.elapsed());
    }
}

#[test]
fn a_refused_connection_names_the_address() {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap().to_string();
    drop(l);
    let e = Gcs::tcp(&addr, Duration::from_millis(200)).err().unwrap();
    assert!(e.to_string().contains(&addr), "{e}");
}
