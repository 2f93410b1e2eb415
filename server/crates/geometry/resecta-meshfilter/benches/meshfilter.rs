#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Windowed sinc (Slicer's default: 40 iterations, passband 0.01) and decimation (50 %) on a
//! noisy icosphere of 327 680 triangles; decimation (50 %) also on 1 310 720 triangles.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use resecta_meshfilter::{DecimateParams, SincParams, decimate, windowed_sinc};

#[path = "../tests/common/mod.rs"]
mod common;
use common::noisy_sphere;

fn bench(c: &mut Criterion) {
    let mesh = noisy_sphere(7, 0.01);
    let mut g = c.benchmark_group("meshfilter_327k_triangles");
    g.sample_size(10);
    let sinc = SincParams::slicer(0.5);
    g.bench_function("windowed_sinc_40_iterations", |b| {
        b.iter(|| windowed_sinc(black_box(&mesh), &sinc).unwrap())
    });
    let dec = DecimateParams::slicer(0.5);
    g.bench_function("decimate_0.5", |b| {
        b.iter(|| decimate(black_box(&mesh), &dec).unwrap())
    });
    g.finish();
    let big = noisy_sphere(8, 0.01);
    let mut g = c.benchmark_group("meshfilter_1311k_triangles");
    g.sample_size(10);
    g.bench_function("decimate_0.5", |b| {
        b.iter(|| decimate(black_box(&big), &dec).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
