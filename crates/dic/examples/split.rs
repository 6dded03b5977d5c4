//! Times the parts of one field point's measurement (prepare, IC-GN, interpolation
//! correction, rounding bound) on a 512 x 512 speckle pair, single thread, and compares
//! the tabulated corrections with the per-subset simulations.
#![allow(missing_docs, clippy::unwrap_used)]
use std::time::Instant;

use cellinject_dic::accept::{Acceptance, measure};
use cellinject_dic::correction::Corrections;
use cellinject_dic::icgn::{self, IcgnOptions, Scratch};
use cellinject_dic::synth::{Speckle, SpeckleParams};
use cellinject_dic::{BSpline, Degree, Reference, Shape, Subset};

fn main() {
    let (su, sv) = (0.3, -0.15);
    let sp = Speckle::new(&SpeckleParams::default_for(512, 512), 2);
    let q = |i: cellinject_dic::Image| {
        let d: Vec<f64> = i.data().iter().map(|v| v.round()).collect();
        cellinject_dic::Image::new(i.width(), i.height(), d).unwrap()
    };
    let r = q(sp.render_shifted(0.0, 0.0, 0.0, 1));
    let c = q(sp.render_shifted(su, sv, 0.0, 2));
    let t = Instant::now();
    let rf = Reference::with_degree(r.clone(), Degree::Quintic);
    println!(
        "reference spline: {:.1} ms",
        t.elapsed().as_secs_f64() * 1e3
    );
    let t = Instant::now();
    let s = BSpline::with_degree(&c, Degree::Quintic);
    println!("current spline: {:.1} ms", t.elapsed().as_secs_f64() * 1e3);
    let opts = IcgnOptions {
        tolerance: 5e-4,
        quantisation_step: 1.0,
        residual_floor: 1.0 / 6.0,
        ..IcgnOptions::default()
    };
    let t = Instant::now();
    let corr = Corrections::new(&rf, Degree::Quintic, 1.0);
    println!("rounding tables: {:.1} ms", t.elapsed().as_secs_f64() * 1e3);
    let pts: Vec<(usize, usize)> = (0..40)
        .flat_map(|j| (0..40).map(move |i| (40 + i * 10, 40 + j * 10)))
        .collect();
    let n = pts.len() as f64;
    let sub = Subset::square(33);
    let init = [su, 0.0, 0.0, sv, 0.0, 0.0];
    let time = |name: &str, f: &mut dyn FnMut(usize, usize)| {
        let t = Instant::now();
        for &(x, y) in &pts {
            f(x, y)
        }
        println!(
            "{name:<12} {:8.1} us/point",
            t.elapsed().as_secs_f64() * 1e6 / n
        );
    };
    time("prepare", &mut |x, y| {
        std::hint::black_box(icgn::prepare(&rf, x, y, sub, Shape::Affine));
    });
    let prep: Vec<_> = pts
        .iter()
        .map(|&(x, y)| icgn::prepare(&rf, x, y, sub, Shape::Affine).unwrap())
        .collect();
    let mut k = 0;
    let mut sc = Scratch::default();
    time("iterate", &mut |_, _| {
        std::hint::black_box(icgn::iterate(&prep[k], &s, init, &opts, &mut sc));
        k += 1;
    });
    let acc = Acceptance::default();
    let at = |x: usize, y: usize, sc: &mut Scratch| {
        measure(
            &rf,
            &s,
            x,
            y,
            33,
            true,
            Shape::Affine,
            init,
            &opts,
            &acc,
            &corr,
            sc,
        )
    };
    let res: Vec<_> = prep
        .iter()
        .map(|p| icgn::refine_prepared(p, &s, init, &opts).unwrap())
        .collect();
    let _ = at(256, 256, &mut sc);
    // SPLIT_REPEAT=N measures the points N times (for a profiler's samples).
    let repeat: usize = std::env::var("SPLIT_REPEAT")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    for _ in 0..repeat {
        time("measure", &mut |x, y| {
            std::hint::black_box(at(x, y, &mut sc));
        });
    }
    if std::env::var("SPLIT_NEW").is_ok() {
        return;
    }
    k = 0;
    time("old corrected", &mut |_, _| {
        std::hint::black_box(icgn::corrected(&rf, &prep[k], &s, &res[k], &opts, 0.3));
        k += 1;
    });
    k = 0;
    time("old rounding", &mut |_, _| {
        std::hint::black_box(icgn::rounding_error(&rf, &prep[k], &res[k], &opts));
        k += 1;
    });
    println!("{corr:?}");
    let mut e = Vec::new();
    for (k, &(x, y)) in pts.iter().enumerate() {
        let m = at(x, y, &mut sc).unwrap();
        let o = icgn::corrected(&rf, &prep[k], &s, &res[k], &opts, 0.3).unwrap();
        let (du, _) = icgn::rounding_error(&rf, &prep[k], &o, &opts).unwrap();
        e.push([
            m.u - su,
            o.u - su,
            m.v - sv,
            o.v - sv,
            m.sigma_u,
            o.sigma_u.max(du),
            res[k].u - su,
            m.u - o.u,
            m.sigma_u / o.sigma_u.max(du),
        ]);
    }
    let mean = |i: usize| e.iter().map(|v| v[i]).sum::<f64>() / n;
    let rms = |i: usize| (e.iter().map(|v| v[i] * v[i]).sum::<f64>() / n).sqrt();
    let max = |i: usize| e.iter().map(|v| v[i].abs()).fold(0.0, f64::max);
    println!(
        "new u bias {:.5} rms {:.5} | old u bias {:.5} rms {:.5} | raw u bias {:.5}",
        mean(0),
        rms(0),
        mean(1),
        rms(1),
        mean(6)
    );
    println!(
        "new v bias {:.5} rms {:.5} | old v bias {:.5} rms {:.5}",
        mean(2),
        rms(2),
        mean(3),
        rms(3)
    );
    println!(
        "sigma_u new {:.5} old {:.5}; ratio new/old mean {:.3} max dev {:.3}; |u new - old| max {:.6} rms {:.6}",
        mean(4),
        mean(5),
        mean(8),
        e.iter().map(|v| (v[8] - 1.0).abs()).fold(0.0, f64::max),
        max(7),
        rms(7)
    );
}
