//! Speed of the live view's encoding (issue 14; the frame's copy included): a 648 x 486 frame (the twin's whole
//! field binned 4 x 4) into the stream's JSON event, well under the 66 ms a frame of
//! the view's 15 frames a second allows (the rendering is benched in the twin).

#![allow(missing_docs, clippy::unwrap_used)]

use std::hint::black_box;

use cellinject_dashboard::ViewFrame;
use cellinject_dashboard::server::frame_msg;
use criterion::{Criterion, criterion_group, criterion_main};

fn encode(c: &mut Criterion) {
    let (w, h) = (648u32, 486u32);
    let f = ViewFrame {
        width: w,
        height: h,
        pixels: (0..w * h).map(|k| (k % 251) as u8).collect(),
        origin_m: Some([-1e-3, -7e-4]),
        pitch_m: 2.2e-6,
        to_view: None,
        tip_m: Some([0.0, 3e-5, 0.0]),
        roi_m: Some([-1e-4, -1e-4, 1e-4, 1e-4]),
        time_s: 12.5,
    };
    let mut n = 0;
    c.bench_function("stream: 648x486 view frame to its JSON event", |b| {
        b.iter(|| {
            n += 1;
            black_box(frame_msg(f.clone(), n).json.len())
        })
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30);
    targets = encode
}
criterion_main!(benches);
