//! Marching cubes on a smooth field (the PSR case) and on a binary mask (the MCSD case).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use criterion::{Criterion, criterion_group, criterion_main};
use resecta_isosurface::{Options, extract};

fn sphere_field(n: usize) -> Vec<f32> {
    let c = (n as f32 - 1.0) / 2.0;
    let r = 0.4 * n as f32;
    let mut v = Vec::with_capacity(n * n * n);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let d = ((i as f32 - c).powi(2) + (j as f32 - c).powi(2) + (k as f32 - c).powi(2))
                    .sqrt();
                v.push(r - d);
            }
        }
    }
    v
}

fn bench(c: &mut Criterion) {
    for n in [129usize, 257] {
        let field = sphere_field(n);
        c.bench_function(&format!("field_sphere_{n}"), |b| {
            b.iter(|| extract([n, n, n], &field, 0.0, Options::default()).unwrap())
        });
        let mask: Vec<bool> = field.iter().map(|&v| v > 0.0).collect();
        c.bench_function(&format!("mask_sphere_{n}"), |b| {
            b.iter(|| extract([n, n, n], &mask, 0.5, Options::default()).unwrap())
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);
