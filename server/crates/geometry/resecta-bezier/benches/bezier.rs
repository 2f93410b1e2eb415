#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! BRF / MAT / MLE × f32 / f64 × 4×4, 12×12 × 256², 1000² × 1 and 2 threads, plus the
//! memory-write ceiling. Throughput is in surfaces per second (one element = one surface).

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use resecta_bezier::{
    BezierScalar, ControlNet, Method, Outputs, Prepared, Resolution, write_ceiling,
};

fn net<T: BezierScalar>(m: usize) -> ControlNet<T> {
    ControlNet::from_fn(m, m, |i, j| {
        let (x, y) = (i as f64, j as f64);
        [x, y, (x * 0.7).sin() + (y * 0.3).cos()].map(T::from_f64)
    })
    .unwrap()
}

fn bench_type<T: BezierScalar>(c: &mut Criterion) {
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        for m in [4usize, 12] {
            for r in [256usize, 1000] {
                let res = Resolution::new(r, r).unwrap();
                let mut group =
                    c.benchmark_group(format!("bezier/{}/{m}x{m}/{r}x{r}/t{threads}", T::NAME));
                group.throughput(Throughput::Elements(1));
                if r >= 1000 || m >= 12 {
                    group.sample_size(10);
                }
                for method in Method::ALL {
                    // BRF at 12×12, 1000² takes seconds per surface; skip it.
                    if method == Method::Brf && m == 12 && r == 1000 {
                        continue;
                    }
                    let mut p = Prepared::new(method, net::<T>(m), res, Outputs::Points).unwrap();
                    group.bench_function(BenchmarkId::from_parameter(method.name()), |b| {
                        pool.install(|| b.iter(|| p.run().unwrap()))
                    });
                }
                let mut buf = vec![[T::ZERO; 3]; res.len()];
                group.bench_function(BenchmarkId::from_parameter("write_ceiling"), |b| {
                    pool.install(|| {
                        b.iter(|| write_ceiling(&mut buf, std::hint::black_box(T::ONE)))
                    })
                });
                group.finish();
            }
        }
    }
}

fn benches(c: &mut Criterion) {
    bench_type::<f64>(c);
    bench_type::<f32>(c);
}

criterion_group!(bezier, benches);
criterion_main!(bezier);
