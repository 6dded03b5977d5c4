//! Speed of the twin: mechanics against real time, and frame rendering.
//!
//! Targets (issue 3): mechanics at least 1000x faster than real time; a VGA frame in
//! under 5 ms and a full frame in under 40 ms on one core. Issue 14: the dashboard's
//! live view (`Twin::peek` through `Twin::view_camera`, the whole field binned 4 x 4)
//! well under the 66 ms a frame of its 15 frames a second allows.

#![allow(missing_docs, clippy::unwrap_used)]

use std::hint::black_box;

use cellinject_hw::Frame;
use cellinject_model::prototype;
use cellinject_twin::camera::TipPose;
use cellinject_twin::{Twin, TwinParams, World};
use criterion::{Criterion, criterion_group, criterion_main};

fn mechanics(c: &mut Criterion) {
    let mut w = World::new(&prototype(), TwinParams::default()).unwrap();
    let mut k = 0u64;
    // 10 ms of simulated time per iteration (200 steps at 20 kHz) while the voltages
    // keep changing, so the amplifiers slew and the hysteresis operators work.
    c.bench_function("mechanics: 10 ms simulated (200 steps)", |b| {
        b.iter(|| {
            k += 1;
            let v = (k % 50) as f64;
            w.set_voltage(0, v);
            w.set_voltage(1, 50.0 - v);
            w.set_voltage(2, v * 0.5);
            w.advance(0.01);
            black_box(w.snapshot().x)
        })
    });
}

fn frames(c: &mut Criterion) {
    let twin = Twin::new(&prototype(), TwinParams::default()).unwrap();
    let pose = TipPose {
        x: 3e-6,
        z: 1e-6,
        depth: 0.5e-6,
        vx: 1e-4,
        vz: 0.0,
    };
    let mut frame = Frame::default();
    let mut full = twin.camera.clone();
    let mut index = 0;
    c.bench_function("frame: full 2592x1944 at 10x", |b| {
        b.iter(|| {
            index += 1;
            full.render(&pose, 0.0, index, 1, &mut frame);
            black_box(frame.pixels[1000])
        })
    });
    for (name, binned) in [
        ("frame: VGA binned 4x4 at 10x", true),
        ("frame: VGA cropped at 10x", false),
    ] {
        let mut cam = twin.camera.clone();
        let s = cam.vga_settings(binned);
        cam.configure(s).unwrap();
        c.bench_function(name, |b| {
            b.iter(|| {
                index += 1;
                cam.render(&pose, 0.0, index, 1, &mut frame);
                black_box(frame.pixels[1000])
            })
        });
    }
}

fn view(c: &mut Criterion) {
    let mut twin = Twin::new(&prototype(), TwinParams::default()).unwrap();
    let mut cam = twin.view_camera();
    let mut frame = Frame::default();
    c.bench_function(
        "view: live view of the whole field, binned 4x4 (peek)",
        |b| {
            b.iter(|| {
                let g = twin.peek(&mut cam, &mut frame);
                black_box((g.width, frame.pixels[1000]))
            })
        },
    );
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30);
    targets = mechanics, frames, view
}
criterion_main!(benches);
