#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Output layout of MLE level 1: interleaved xyz (AoS, what meshes and GPUs consume) against
//! separate x, y, z arrays (SoA), single-threaded, f32 / f64 × 4×4, 12×12 × 256², 1000².
//! The method sweep (BRF / MAT / MLE × threads × backends) is `resecta bench bezier`.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use resecta_bezier::{BezierScalar, ControlNet, MleEvaluator, Resolution};

fn net<T: BezierScalar>(m: usize) -> ControlNet<T> {
    ControlNet::from_fn(m, m, |i, j| {
        let (x, y) = (i as f64, j as f64);
        [x, y, (x * 0.7).sin() + (y * 0.3).cos()].map(T::from_f64)
    })
    .unwrap()
}

fn bench_type<T: BezierScalar>(c: &mut Criterion) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    for m in [4usize, 12] {
        for r in [256usize, 1000] {
            let res = Resolution::new(r, r).unwrap();
            let mut group = c.benchmark_group(format!("mle_layout/{}/{m}x{m}/{r}x{r}", T::NAME));
            group.throughput(Throughput::Elements(1));
            group.sample_size(if r >= 1000 { 20 } else { 50 });
            let mut mle = MleEvaluator::new(net::<T>(m), res);
            let mut aos = vec![[T::ZERO; 3]; res.len()];
            group.bench_function(BenchmarkId::from_parameter("aos"), |b| {
                pool.install(|| b.iter(|| mle.evaluate_points_into(&mut aos).unwrap()))
            });
            let (mut x, mut y, mut z) = (
                vec![T::ZERO; res.len()],
                vec![T::ZERO; res.len()],
                vec![T::ZERO; res.len()],
            );
            group.bench_function(BenchmarkId::from_parameter("soa"), |b| {
                pool.install(|| {
                    b.iter(|| {
                        mle.evaluate_points_soa_into(&mut x, &mut y, &mut z)
                            .unwrap()
                    })
                })
            });
            group.finish();
        }
    }
}

fn benches(c: &mut Criterion) {
    bench_type::<f64>(c);
    bench_type::<f32>(c);
}

criterion_group!(bezier, benches);
criterion_main!(bezier);
