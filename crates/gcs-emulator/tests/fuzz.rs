//! Any input, the emulator neither panics nor hangs: random command lines into the
//! controller, random byte streams into the server (which then still answers).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::OnceLock;
use std::time::Duration;

use cellinject_gcs_emulator::{Controller, IDN, Running, start};
use cellinject_model::{Approach, prototype};
use cellinject_twin::{Twin, TwinParams};
use proptest::prelude::*;

fn twin() -> cellinject_twin::SharedTwin {
    let mut p = TwinParams::default();
    p.rig.approach = Approach::DriveTranslation;
    Twin::new(&prototype(), p).unwrap().into_shared()
}

fn server() -> &'static Running {
    static S: OnceLock<Running> = OnceLock::new();
    S.get_or_init(|| {
        start(
            &twin(),
            TcpListener::bind("127.0.0.1:0").unwrap(),
            None,
            false,
        )
        .unwrap()
    })
}

/// Words the controller knows, mixed with noise, so that random lines reach deep.
fn line() -> impl Strategy<Value = String> {
    let word = prop_oneof![
        Just("SVO".to_string()),
        Just("MOV".to_string()),
        Just("MVR".to_string()),
        Just("SVA".to_string()),
        Just("VEL".to_string()),
        Just("POS?".to_string()),
        Just("HLT".to_string()),
        Just("STP".to_string()),
        Just("ONT?".to_string()),
        Just("1".to_string()),
        Just("2".to_string()),
        Just("3".to_string()),
        Just("ALL".to_string()),
        Just("-1e308".to_string()),
        Just("nan".to_string()),
        Just("1e400".to_string()),
        Just("0.5".to_string()),
        Just("60".to_string()),
        "[ -~]{0,6}",
    ];
    proptest::collection::vec(word, 0..8).prop_map(|w| w.join(" "))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn random_lines_never_panic_and_the_stacks_stay_in_range(lines in proptest::collection::vec(line(), 1..12)) {
        let t = twin();
        let rig = cellinject_twin::rig(&t).unwrap();
        let mut c = Controller::new(t.clone(), rig);
        let mut time = c.time();
        for l in &lines {
            let _ = c.execute(l);
            time += 0.002;
            c.step_to(time);
        }
        let w = t.lock().unwrap();
        for k in 0..3 {
            let v = w.world.commanded_voltage(k);
            prop_assert!((0.0..=w.world.params().rig.amplifiers[k].v_max).contains(&v), "{v}");
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_on_the_wire_never_stop_the_server(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let s = server();
        let mut c = TcpStream::connect(s.gcs).unwrap();
        c.set_read_timeout(Some(Duration::from_secs(3))).unwrap();
        c.write_all(&bytes).unwrap();
        // Whatever came before, a fresh line asks for the identification.
        c.write_all(b"\n*IDN?\n").unwrap();
        let mut got = Vec::new();
        let mut b = [0u8; 1024];
        let want = format!("{IDN}\n");
        while !String::from_utf8_lossy(&got).contains(&want) {
            let n = c.read(&mut b).unwrap();
            prop_assert!(n > 0, "closed");
            got.extend_from_slice(&b[..n]);
        }
    }
}
