#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! EDT of a 512×512×300 CT-like mask (ellipsoid liver with spherical holes) at 0.8×0.8×2.5 mm,
//! on 1 and 2 rayon threads. Throughput is reported in voxels per second.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use resecta_geom::{Grid, Vec3, distance_transform, signed_distance_transform};

fn mask(g: &Grid) -> Vec<bool> {
    let spheres = [
        (Vec3::new(-40.0, 10.0, 0.0), 25.0),
        (Vec3::new(50.0, -20.0, 30.0), 15.0),
        (Vec3::new(10.0, 40.0, -60.0), 20.0),
    ];
    (0..g.len())
        .map(|o| {
            let p = g.voxel_center(g.ijk(o));
            let e = (p.x / 110.0).powi(2) + (p.y / 90.0).powi(2) + (p.z / 120.0).powi(2);
            e <= 1.0 && spheres.iter().all(|(c, r)| (p - c).norm() > *r)
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let dims = [512, 512, 300];
    let spacing = [0.8, 0.8, 2.5];
    let origin = Vec3::new(-204.4, -204.4, -373.75);
    let Ok(g) = Grid::axis_aligned(dims, spacing, origin) else {
        return;
    };
    let m = mask(&g);
    let mut group = c.benchmark_group("edt_512x512x300");
    group.sample_size(10);
    group.throughput(Throughput::Elements(g.len() as u64));
    for threads in [1, 2] {
        let Ok(pool) = rayon::ThreadPoolBuilder::new().num_threads(threads).build() else {
            continue;
        };
        group.bench_function(format!("unsigned_{threads}t"), |b| {
            b.iter(|| pool.install(|| distance_transform(&g, &m)));
        });
        group.bench_function(format!("signed_{threads}t"), |b| {
            b.iter(|| pool.install(|| signed_distance_transform(&g, &m)));
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
