//! Profiling aid (not committed): `dic field` defaults on an 8-bit PNG pair.
#![allow(missing_docs, clippy::unwrap_used)]
use std::time::Instant;

use cellinject_dic::Image;
use cellinject_dic::field::{FieldOptions, field};

fn load(p: &str) -> Image {
    let g = image::open(p).unwrap().to_luma8();
    let (w, h) = g.dimensions();
    Image::new(
        w as usize,
        h as usize,
        g.pixels().map(|p| f64::from(p.0[0])).collect(),
    )
    .unwrap()
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let (r, c) = (load(&a[1]), load(&a[2]));
    let step: usize = a[3].parse().unwrap();
    let threads: usize = a[4].parse().unwrap();
    let opts = FieldOptions {
        step,
        subset: 33,
        threads,
        ..FieldOptions::default()
    };
    let t = Instant::now();
    let f = field(&r, &c, &opts).unwrap();
    let n = f.points.iter().flatten().count();
    let grown = f.points.iter().flatten().filter(|p| p.subset > 33).count();
    let dt = t.elapsed().as_secs_f64();
    println!(
        "{n} points ({grown} grown) in {dt:.3} s ({:.0} points/s)",
        n as f64 / dt
    );
}
