//! DIC speed: one IC-GN refinement; the full field on 512 x 512 speckle with 33 x 33
//! subsets at step 10 and at step 2, and the point mode on a 32 x 32 grid of points,
//! each with the corrections and σ of every field point (each prints its points per
//! second once, then criterion's figures); point mode's integer search at one point;
//! tracking one region in a VGA frame.
//! `cargo bench -p cellinject-dic`.

#![allow(missing_docs, clippy::unwrap_used)]

use std::hint::black_box;
use std::time::Instant;

use cellinject_dic::field::{FieldOptions, field};
use cellinject_dic::icgn::{IcgnOptions, refine};
use cellinject_dic::search::{pyramid, search_pyramid};
use cellinject_dic::synth::{Speckle, SpeckleParams};
use cellinject_dic::track::{Roi, Tracker};
use cellinject_dic::{BSpline, PointOptions, Reference, Shape, Subset, correlate_points};
use criterion::{Criterion, criterion_group, criterion_main};

fn point(c: &mut Criterion) {
    let sp = Speckle::new(&SpeckleParams::default_for(256, 256), 1);
    let r = Reference::new(sp.render_shifted(0.0, 0.0, 0.0, 1));
    let s = BSpline::new(&sp.render_shifted(0.3, -0.2, 0.0, 2));
    let opts = IcgnOptions::default();
    c.bench_function("icgn: one 33x33 affine point", |b| {
        b.iter(|| {
            refine(
                &r,
                &s,
                128,
                128,
                Subset::square(33),
                Shape::Affine,
                [0.0; 6],
                &opts,
            )
            .map(|p| black_box(p.u))
        })
    });
}

fn integer_search(c: &mut Criterion) {
    // What point mode does first at every point: a pyramid search for a 33 x 33
    // subset within ±64 px (3 levels).
    let sp = Speckle::new(&SpeckleParams::default_for(512, 512), 4);
    let pr = pyramid(&sp.render_shifted(0.0, 0.0, 0.0, 1), 3);
    let pc = pyramid(&sp.render_shifted(23.6, -11.35, 0.0, 2), 3);
    c.bench_function("search: one 33x33 subset, radius 64, 3 levels", |b| {
        b.iter(|| black_box(search_pyramid(&pr, &pc, 256, 240, 16, 64).map(|h| h.u)))
    });
}

fn full_field(c: &mut Criterion) {
    let sp = Speckle::new(&SpeckleParams::default_for(512, 512), 2);
    let r = sp.render_shifted(0.0, 0.0, 0.0, 1);
    let cur = sp.render_shifted(2.3, -1.4, 0.002, 2);
    let mut g = c.benchmark_group("field");
    g.sample_size(10);
    for step in [10, 2] {
        let opts = FieldOptions {
            step,
            subset: 33,
            ..FieldOptions::default()
        };
        let t = Instant::now();
        let f = field(&r, &cur, &opts).unwrap();
        let n = f.points.iter().flatten().count();
        println!(
            "field 512x512 step {step}: {n} points in {:.3} s ({:.0} points/s, {} threads)",
            t.elapsed().as_secs_f64(),
            n as f64 / t.elapsed().as_secs_f64(),
            rayon::current_num_threads()
        );
        g.bench_function(
            format!("field: 512x512 at step {step}, 33x33 subsets"),
            |b| b.iter(|| black_box(field(&r, &cur, &opts).unwrap().points.len())),
        );
    }
    g.finish();
}

fn point_mode(c: &mut Criterion) {
    let sp = Speckle::new(&SpeckleParams::default_for(512, 512), 4);
    let r = sp.render_shifted(0.0, 0.0, 0.0, 1);
    let cur = sp.render_shifted(0.6, 0.35, 0.0, 2);
    let points: Vec<(f64, f64)> = (0..32)
        .flat_map(|j| (0..32).map(move |i| (40.0 + 13.5 * i as f64, 40.0 + 13.5 * j as f64)))
        .collect();
    let opts = PointOptions {
        subset: 33,
        ..PointOptions::default()
    };
    let t = Instant::now();
    let n = correlate_points(&r, &cur, &points, &opts)
        .unwrap()
        .iter()
        .flatten()
        .count();
    println!(
        "points 512x512: {n} points in {:.3} s ({:.0} points/s, {} threads)",
        t.elapsed().as_secs_f64(),
        n as f64 / t.elapsed().as_secs_f64(),
        rayon::current_num_threads()
    );
    let mut g = c.benchmark_group("points");
    g.sample_size(10);
    g.bench_function("points: 1024 points of 512x512, 33x33 subsets", |b| {
        b.iter(|| black_box(correlate_points(&r, &cur, &points, &opts).unwrap().len()))
    });
    g.finish();
}

fn tracking(c: &mut Criterion) {
    let sp = Speckle::new(&SpeckleParams::default_for(640, 480), 3);
    let first = sp.render_shifted(0.0, 0.0, 0.0, 1);
    let frames: Vec<_> = (0..8)
        .map(|k| sp.render_shifted(0.3 * k as f64, -0.1 * k as f64, 0.0, 10 + k))
        .collect();
    let roi = Roi {
        x: 288,
        y: 208,
        width: 65,
        height: 65,
    };
    let mut t = Tracker::new(&first, roi, Shape::Rigid, 0.8).unwrap();
    let mut k = 0;
    c.bench_function("track: one 64x64 region in a VGA frame", |b| {
        b.iter(|| {
            k = (k + 1) % frames.len();
            black_box(t.track(&frames[k]).unwrap().u)
        })
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30);
    targets = point, integer_search, full_field, point_mode, tracking
}
criterion_main!(benches);
