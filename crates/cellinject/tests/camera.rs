//! `cellinject camera list|info|grab` and `--camera aravis:ID`.
//!
//! Without the `genicam` feature (the default build): the commands say how to get
//! GenICam support, and bad arguments are refused by name all the same. With it
//! (`cargo test -p cellinject --features genicam --test camera`, needs Debian's
//! libaravis-dev and aravis-tools): the commands against Aravis's GigE Vision simulator
//! on 127.0.0.1.

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{dir, err, run};

#[test]
fn bad_arguments_are_refused_by_name_before_any_camera_is_asked() {
    let d = dir("camera", "bad");
    for (args, name) in [
        (
            vec![
                "camera",
                "grab",
                "--camera",
                "aravis:X",
                "--pixel-format",
                "rgb8",
                "--out",
                "g.tif",
            ],
            "--pixel-format",
        ),
        (
            vec![
                "camera", "grab", "--camera", "aravis:X", "--roi", "1,2,3", "--out", "g.tif",
            ],
            "--roi",
        ),
        (
            vec![
                "camera", "grab", "--camera", "aravis:X", "--roi", "0,0,-5,5", "--out", "g.tif",
            ],
            "--roi",
        ),
        (
            vec![
                "camera",
                "grab",
                "--camera",
                "aravis:X",
                "--exposure",
                "-1e-3",
                "--out",
                "g.tif",
            ],
            "--exposure",
        ),
        (
            vec![
                "camera",
                "grab",
                "--camera",
                "aravis:X",
                "--exposure",
                "nan",
                "--out",
                "g.tif",
            ],
            "--exposure",
        ),
        (
            vec![
                "camera",
                "grab",
                "--camera",
                "aravis:X",
                "--frame-rate",
                "0",
                "--out",
                "g.tif",
            ],
            "--frame-rate",
        ),
        (
            vec!["camera", "grab", "--camera", "aravis:X", "--out", "g.txt"],
            "--out",
        ),
        (
            vec![
                "camera",
                "grab",
                "--camera",
                "aravis:X",
                "--out",
                "no-such-dir/g.tif",
            ],
            "--out",
        ),
        (
            vec![
                "camera", "grab", "--camera", "aravis:X", "--frames", "0", "--out", "g.tif",
            ],
            "--frames",
        ),
        (
            vec!["camera", "grab", "--camera", "frames/", "--out", "g.tif"],
            "--camera",
        ),
        (vec!["camera", "info", "--camera", "aravis:"], "--camera"),
        (
            vec!["camera", "info", "--camera", "aravis:X", "--timeout", "0"],
            "--timeout",
        ),
        (vec!["run", "--camera", "aravis:X"], "--camera"),
        (
            vec![
                "run",
                "--backend",
                "gcs://127.0.0.1:9",
                "--side-camera",
                "aravis:",
            ],
            "--side-camera",
        ),
    ] {
        let o = run(&d, &args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", err(&o));
        assert!(err(&o).contains(name), "{args:?}: {}", err(&o));
    }
    assert_eq!(
        std::fs::read_dir(&d).unwrap().count(),
        0,
        "a refused command wrote a file"
    );
}

#[cfg(not(feature = "genicam"))]
#[test]
fn the_default_build_says_how_to_get_genicam_cameras() {
    let d = dir("camera", "default");
    for args in [
        vec!["camera", "list"],
        vec![
            "camera",
            "grab",
            "--camera",
            "aravis:Aravis-GV01",
            "--out",
            "g.tif",
        ],
        vec![
            "calibrate",
            "pixels",
            "--backend",
            "gcs://127.0.0.1:9",
            "--camera",
            "aravis:Aravis-GV01",
        ],
    ] {
        let o = run(&d, &args);
        assert_eq!(o.status.code(), Some(2), "{args:?}");
        let e = err(&o);
        assert!(
            e.contains("libaravis-dev") && e.contains("--features genicam"),
            "{args:?}: {e}"
        );
    }
}

#[cfg(feature = "genicam")]
mod simulator {
    use std::process::{Output, Stdio};
    use std::sync::Mutex;
    use std::time::{Duration, Instant};

    use cellinject_genicam::simulator::GvSimulator;
    use serde_json::Value;

    use super::common::{cmd, dir, err, run};

    /// One simulator at a time: they share GigE Vision's UDP port 3956.
    static GV: Mutex<()> = Mutex::new(());

    /// A command's JSON output, after checking it succeeded.
    fn json(o: &Output) -> Value {
        assert!(o.status.success(), "{}", err(o));
        serde_json::from_slice(&o.stdout).unwrap()
    }

    #[test]
    fn list_info_and_grab_against_the_gige_simulator() {
        let _one = GV.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let _sim = GvSimulator::start("GV01").unwrap();
        let d = dir("camera", "grab");
        let l = json(&run(&d, &["camera", "list", "--format", "json"]));
        assert!(
            l["cameras"]
                .as_array()
                .unwrap()
                .iter()
                .any(|c| c["serial"] == "GV01" && c["address"] == "127.0.0.1"),
            "{l}"
        );
        let cam = "aravis:Aravis-GV01";
        let g = json(&run(
            &d,
            &[
                "camera", "grab", "--camera", cam, "--frames", "3", "--out", "g.tif", "--format",
                "json",
            ],
        ));
        let frames = g["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 3);
        let mut images = Vec::new();
        let mut stamps = Vec::new();
        for (k, f) in frames.iter().enumerate() {
            let name = format!("g_{k:03}.tif");
            assert_eq!(f["file"], name.as_str());
            let img = image::open(d.join(&name)).unwrap().into_luma8();
            assert_eq!(
                (img.width() as u64, img.height() as u64),
                (f["width"].as_u64().unwrap(), f["height"].as_u64().unwrap())
            );
            assert_eq!(f["pixel_format"], "Mono8");
            images.push(img.into_raw());
            stamps.push(f["timestamp_ns"].as_u64().unwrap());
        }
        assert!(stamps.windows(2).all(|w| w[1] > w[0]), "{stamps:?}");
        assert_ne!(
            images[0], images[2],
            "the simulator's pattern moves between frames"
        );
        // --exposure, --roi and --frame-rate reach the camera, as it reports back.
        let o = run(
            &d,
            &[
                "camera",
                "grab",
                "--camera",
                cam,
                "--exposure",
                "2e-3",
                "--roi",
                "8,16,256,128",
                "--frame-rate",
                "40",
                "--out",
                "r.png",
            ],
        );
        assert!(o.status.success(), "{}", err(&o));
        assert!(String::from_utf8_lossy(&o.stdout).contains("wrote r.png"));
        let i = json(&run(
            &d,
            &["camera", "info", "--camera", cam, "--format", "json"],
        ));
        assert!(
            (i["exposure_s"]["value"].as_f64().unwrap() - 2e-3).abs() < 1e-6,
            "{i}"
        );
        assert_eq!(
            i["roi"],
            serde_json::json!({"x": 8, "y": 16, "width": 256, "height": 128})
        );
        assert!(
            (i["frame_rate_hz"].as_f64().unwrap() - 40.0).abs() < 1e-6,
            "{i}"
        );
        let r = image::open(d.join("r.png")).unwrap();
        assert_eq!((r.width(), r.height()), (256, 128));
        // A region outside the sensor: refused by name, exit 2, nothing changed.
        let o = run(
            &d,
            &[
                "camera",
                "grab",
                "--camera",
                cam,
                "--roi",
                "2000,0,512,512",
                "--out",
                "x.tif",
            ],
        );
        assert_eq!(o.status.code(), Some(2), "{}", err(&o));
        assert!(
            err(&o).contains("--roi") && err(&o).contains("2048x2048"),
            "{}",
            err(&o)
        );
        assert!(!d.join("x.tif").exists());
        // A second controller while one holds the camera: exit 1, no hang.
        let mut holder = cmd(&d)
            .args([
                "camera", "grab", "--camera", cam, "--frames", "100000", "--out", "h.tif",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let t = Instant::now();
        while !d.join("h_00000.tif").exists() && t.elapsed() < Duration::from_secs(30) {
            std::thread::sleep(Duration::from_millis(50));
        }
        let o = run(&d, &["camera", "info", "--camera", cam]);
        let _ = holder.kill();
        let _ = holder.wait();
        assert_eq!(o.status.code(), Some(1), "{}", err(&o));
        assert!(err(&o).contains("control"), "{}", err(&o));
    }

    #[test]
    fn a_simulator_killed_mid_grab_ends_it_with_exit_1_keeping_whole_frames() {
        let _one = GV.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut sim = GvSimulator::start("GV01").unwrap();
        let d = dir("camera", "kill");
        let mut grab = cmd(&d)
            .args([
                "camera",
                "grab",
                "--camera",
                "aravis:Aravis-GV01",
                "--frames",
                "1000",
                "--out",
                "k.tif",
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let t = Instant::now();
        while !d.join("k_005.tif").exists() && t.elapsed() < Duration::from_secs(30) {
            std::thread::sleep(Duration::from_millis(20));
        }
        sim.kill();
        let killed = Instant::now();
        let out = loop {
            if let Some(_s) = grab.try_wait().unwrap() {
                break grab.wait_with_output().unwrap();
            }
            assert!(
                killed.elapsed() < Duration::from_secs(60),
                "the grab hangs after the camera is gone"
            );
            std::thread::sleep(Duration::from_millis(50));
        };
        let took = killed.elapsed().as_secs_f64();
        eprintln!("the grab ended {took:.1} s after the simulator was killed");
        assert_eq!(out.status.code(), Some(1), "{}", err(&out));
        let e = err(&out);
        assert!(
            e.contains("Aravis-GV01")
                && e.contains("stopped answering")
                && e.contains("written and kept"),
            "{e}"
        );
        let mut whole = 0;
        for entry in std::fs::read_dir(&d).unwrap() {
            let p = entry.unwrap().path();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            assert!(
                name.starts_with("k_") && name.ends_with(".tif"),
                "a half-written file is left: {name}"
            );
            image::open(&p).unwrap();
            whole += 1;
        }
        assert!(whole >= 6, "{whole}");
    }

    #[test]
    fn no_camera_is_exit_1_within_a_minute_naming_what_was_tried() {
        let d = dir("camera", "none");
        let t = Instant::now();
        let o = run(
            &d,
            &[
                "camera",
                "info",
                "--camera",
                "aravis:192.0.2.250",
                "--timeout",
                "5",
            ],
        );
        assert!(t.elapsed() < Duration::from_secs(60), "{:?}", t.elapsed());
        assert_eq!(o.status.code(), Some(1), "{}", err(&o));
        let e = err(&o);
        assert!(e.contains("192.0.2.250") && e.contains("tried"), "{e}");
    }
}
