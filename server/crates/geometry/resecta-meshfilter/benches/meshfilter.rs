#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Windowed sinc (Slicer's default: 40 iterations, passband 0.01) and decimation (50 %) on a
//! noisy icosphere of 327 680 triangles; decimation (50 %) also on 1 310 720 triangles.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use resecta_geom::{TriMesh, Vec3, primitives};
use resecta_meshfilter::{DecimateParams, SincParams, decimate, windowed_sinc};

/// Deterministic value in [-1, 1) from an integer (SplitMix64).
fn hash_unit(i: u64) -> f64 {
    let mut z = i.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

fn noisy_sphere(subdivisions: u32, radius: f64, noise: f64) -> TriMesh {
    let s = primitives::icosphere(Vec3::zeros(), radius, subdivisions).unwrap();
    let v = s
        .vertices()
        .iter()
        .enumerate()
        .map(|(i, p)| p * (1.0 + noise * hash_unit(i as u64)))
        .collect();
    TriMesh::new(v, s.triangles().to_vec()).unwrap()
}

fn bench(c: &mut Criterion) {
    let mesh = noisy_sphere(7, 50.0, 0.01);
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
    let big = noisy_sphere(8, 50.0, 0.01);
    let mut g = c.benchmark_group("meshfilter_1311k_triangles");
    g.sample_size(10);
    g.bench_function("decimate_0.5", |b| {
        b.iter(|| decimate(black_box(&big), &dec).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
