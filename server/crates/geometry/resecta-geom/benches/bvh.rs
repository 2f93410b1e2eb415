//! BVH build time and closest-point throughput on icospheres of 20 480 and 327 680 triangles,
//! with brute force on the smaller mesh for comparison. Query points are uniform in the bounding
//! box enlarged by half its size on every side (inside and outside the surface); points near the
//! centre of a sphere are the worst case of any exact search (all triangles nearly equidistant),
//! so a second set lies within ±10 % of the radius.

// A benchmark is test code: a failed setup should abort it.
#![allow(clippy::unwrap_used)]

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use resecta_geom::bvh::closest_point_on_triangle;
use resecta_geom::primitives::icosphere;
use resecta_geom::{MeshBvh, MeshSdf, Real, TriMesh, Vec3};

/// Deterministic uniform numbers in [-1, 1].
fn uniform() -> impl FnMut() -> Real {
    let mut s: u64 = 0x2545_f491_4f6c_dd1d;
    move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as Real / (1u64 << 53) as Real * 2.0 - 1.0
    }
}

/// Query points uniform in the bounding box enlarged by half its size on every side.
fn queries(mesh: &TriMesh, n: usize) -> Vec<Vec3> {
    let (lo, hi) = mesh.bounds().unwrap_or((Vec3::zeros(), Vec3::zeros()));
    let (c, half) = ((lo + hi) * 0.5, (hi - lo) * 0.75);
    let mut unit = uniform();
    (0..n)
        .map(|_| c + Vec3::new(unit(), unit(), unit()).component_mul(&half))
        .collect()
}

/// Query points within ±10 % of the radius of the sphere about `c` (margin-like queries).
fn near_surface(c: Vec3, r: Real, n: usize) -> Vec<Vec3> {
    let mut unit = uniform();
    (0..n)
        .map(|_| {
            let d = Vec3::new(unit(), unit(), unit()).normalize();
            c + d * r * (1.0 + 0.1 * unit())
        })
        .collect()
}

fn brute_force(mesh: &TriMesh, p: &Vec3) -> Real {
    (0..mesh.triangles().len())
        .map(|t| (closest_point_on_triangle(p, &mesh.corners(t)).point - p).norm_squared())
        .fold(Real::INFINITY, Real::min)
        .sqrt()
}

const CENTER: Vec3 = Vec3::new(10.0, -20.0, 30.0);
const RADIUS: Real = 80.0;

fn bench(c: &mut Criterion) {
    let meshes: Vec<(usize, TriMesh)> = [5u32, 7]
        .iter()
        .map(|&s| {
            let m = icosphere(CENTER, RADIUS, s).unwrap();
            (m.triangles().len(), m)
        })
        .collect();

    let mut build = c.benchmark_group("bvh_build");
    build.sample_size(10);
    for (n, mesh) in &meshes {
        build.throughput(Throughput::Elements(*n as u64));
        build.bench_with_input(BenchmarkId::new("bvh", n), mesh, |b, m| {
            b.iter(|| MeshBvh::new(black_box(m)).unwrap())
        });
        build.bench_with_input(BenchmarkId::new("sdf", n), mesh, |b, m| {
            b.iter(|| MeshSdf::new(black_box(m)).unwrap())
        });
    }
    build.finish();

    let mut query = c.benchmark_group("closest_point");
    query.sample_size(20);
    const N: usize = 10_000;
    for (n, mesh) in &meshes {
        let bvh = MeshBvh::new(mesh).unwrap();
        let sdf = MeshSdf::new(mesh).unwrap();
        let pts = queries(mesh, N);
        query.throughput(Throughput::Elements(N as u64));
        query.bench_with_input(BenchmarkId::new("bvh", n), &pts, |b, pts| {
            b.iter(|| {
                pts.iter()
                    .map(|p| bvh.closest_point(p).map_or(0.0, |c| c.distance))
                    .sum::<Real>()
            })
        });
        query.bench_with_input(BenchmarkId::new("bvh_rayon", n), &pts, |b, pts| {
            b.iter(|| bvh.closest_points(pts).len())
        });
        let near = near_surface(CENTER, RADIUS, N);
        query.bench_with_input(BenchmarkId::new("bvh_near_surface", n), &near, |b, pts| {
            b.iter(|| {
                pts.iter()
                    .map(|p| bvh.closest_point(p).map_or(0.0, |c| c.distance))
                    .sum::<Real>()
            })
        });
        query.bench_with_input(BenchmarkId::new("signed_distance", n), &pts, |b, pts| {
            b.iter(|| {
                pts.iter()
                    .map(|p| sdf.signed_distance(p).map_or(0.0, |s| s.distance))
                    .sum::<Real>()
            })
        });
    }
    // Brute force on the 20 k mesh: 100 queries per iteration.
    let (n, mesh) = &meshes[0];
    let pts = queries(mesh, 100);
    query.throughput(Throughput::Elements(pts.len() as u64));
    query.sample_size(10);
    query.bench_with_input(BenchmarkId::new("brute_force", n), &pts, |b, pts| {
        b.iter(|| pts.iter().map(|p| brute_force(mesh, p)).sum::<Real>())
    });
    query.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
