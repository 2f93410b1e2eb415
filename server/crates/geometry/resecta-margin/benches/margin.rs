#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Live margins on 2 threads: a gently curved bicubic surface 5–40 mm from a 20 480-triangle
//! bumpy tumour, at 40×40 and 200×200 samples.
//! - `nearest/<grid>/{field_grid, field_grid_1thread, field_into, bvh}`: exact distances of all
//!   samples by `MarginField::distances_grid_into` (4×4 blocks; also on one thread),
//!   `MarginField::nearest_into` (consecutive runs) and plain `MeshBvh::closest_points`;
//! - `evaluate/<grid>`: `evaluate_into` (distances, classes, areas, refined verdict);
//! - `edit/<grid>`: one control-point edit end to end — MLE surface update, inside levels of an
//!   ellipsoidal liver, `evaluate_into`;
//! - `drag/<grid>/{fresh, reusing}`: a drag — an inner control point moving 0.5 mm per edit
//!   round a 4 mm circle — evaluated from scratch (`evaluate_into`) and with the distances kept
//!   from the previous edits (`evaluate_reusing`);
//! - `setup/200mm_2mm`: `MarginField::new` over a 200 mm cube at 2 mm (101³ hint nodes).

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use resecta_bezier::{ControlNet, MleEvaluator, Resolution, basis_at, binomial_row};
use resecta_geom::primitives::icosphere;
use resecta_geom::{MeshBvh, TriMesh, Vec3};
use resecta_margin::{
    MarginField, MarginMemo, MarginSettings, Nearest, SurfaceMargins, SurfaceOracle, evaluate_into,
    evaluate_reusing,
};

/// A 20 480-triangle tumour of mean radius 15 mm with ±8 % bumps, at the origin.
fn tumour() -> TriMesh {
    let s = icosphere(Vec3::zeros(), 1.0, 5).unwrap();
    let v = s
        .vertices()
        .iter()
        .map(|u| {
            let (th, ph) = (u.z.acos(), u.y.atan2(u.x));
            u * 15.0 * (1.0 + 0.08 * (3.0 * th).sin() * (2.0 * ph).cos())
        })
        .collect();
    TriMesh::new(v, s.triangles().to_vec()).unwrap()
}

/// Bicubic net over [−30, 30]² tilted and bowed: 5 mm above the tumour at the centre, ~40 mm
/// at the far corner.
fn net() -> ControlNet<f64> {
    ControlNet::from_fn(4, 4, |i, j| {
        let (x, y) = (-30.0 + 20.0 * i as f64, -30.0 + 20.0 * j as f64);
        [x, y, 20.0 + 0.1 * x + (x * x + y * y) / 120.0]
    })
    .unwrap()
}

/// The surface (cubic Bernstein sums) and an ellipsoidal liver that the surface leaves at
/// x ≲ −25 mm.
struct Oracle {
    net: ControlNet<f64>,
}

impl Oracle {
    fn inside_level(p: &Vec3) -> f64 {
        let q = (p - Vec3::new(10.0, 0.0, 20.0)).component_div(&Vec3::new(35.0, 60.0, 50.0));
        1.0 - q.norm_squared()
    }
}

impl SurfaceOracle for Oracle {
    fn point(&self, u: f64, v: f64) -> Vec3 {
        let binoms = binomial_row(4);
        let (mut bu, mut bv) = ([0.0; 4], [0.0; 4]);
        basis_at(&binoms, u, &mut bu);
        basis_at(&binoms, v, &mut bv);
        let mut s = Vec3::zeros();
        for (i, wu) in bu.iter().enumerate() {
            for (j, wv) in bv.iter().enumerate() {
                s += Vec3::from(self.net.points()[i * 4 + j]) * (wu * wv);
            }
        }
        s
    }
    fn inside(&self, p: &Vec3) -> f64 {
        Self::inside_level(p)
    }
}

fn benches(c: &mut Criterion) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let mesh = tumour();
    let (lo, hi) = (Vec3::repeat(-100.0), Vec3::repeat(100.0));
    let field = MarginField::new(&mesh, lo, hi, 2.0).unwrap();
    let bvh = MeshBvh::new(&mesh).unwrap();
    let settings = MarginSettings {
        margin_mm: 10.0,
        band_mm: 5.0,
    };
    for n in [40usize, 200] {
        let res = Resolution::new(n, n).unwrap();
        let mut mle = MleEvaluator::new(net(), res);
        let mut raw = vec![[0.0; 3]; res.len()];
        mle.evaluate_points_into(&mut raw).unwrap();
        let points: Vec<Vec3> = raw.iter().map(|p| Vec3::from(*p)).collect();
        let inside: Vec<f64> = points.iter().map(Oracle::inside_level).collect();
        let oracle = Oracle { net: net() };
        let grid = format!("{n}x{n}");

        let mut group = c.benchmark_group(format!("nearest/{grid}"));
        group.sample_size(if n > 40 { 20 } else { 100 });
        let mut dist = vec![0.0; points.len()];
        group.bench_function(BenchmarkId::from_parameter("field_grid"), |b| {
            pool.install(|| b.iter(|| field.distances_grid_into(n, n, &points, &mut dist).unwrap()))
        });
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        group.bench_function(BenchmarkId::from_parameter("field_grid_1thread"), |b| {
            one.install(|| b.iter(|| field.distances_grid_into(n, n, &points, &mut dist).unwrap()))
        });
        let mut near = vec![Nearest::NONE; points.len()];
        group.bench_function(BenchmarkId::from_parameter("field_into"), |b| {
            pool.install(|| b.iter(|| field.nearest_into(&points, &mut near).unwrap()))
        });
        group.sample_size(10);
        group.bench_function(BenchmarkId::from_parameter("bvh"), |b| {
            pool.install(|| b.iter(|| bvh.closest_points(&points)))
        });
        group.finish();

        let mut margins = SurfaceMargins::default();
        let mut group = c.benchmark_group("evaluate");
        group.sample_size(if n > 40 { 20 } else { 100 });
        group.bench_function(BenchmarkId::from_parameter(&grid), |b| {
            pool.install(|| {
                b.iter(|| {
                    evaluate_into(
                        &field,
                        n,
                        n,
                        &points,
                        &inside,
                        &settings,
                        &oracle,
                        &mut margins,
                    )
                    .unwrap()
                })
            })
        });
        group.finish();

        // One edit: move an inner control point up and down alternately.
        let mut group = c.benchmark_group("edit");
        group.sample_size(if n > 40 { 20 } else { 100 });
        let mut edit_oracle = Oracle { net: net() };
        let mut live_points = points.clone();
        let mut live_inside = inside.clone();
        let mut flip = false;
        group.bench_function(BenchmarkId::from_parameter(&grid), |b| {
            pool.install(|| {
                b.iter(|| {
                    flip = !flip;
                    let mut p = net().get(1, 2).unwrap();
                    p[2] += if flip { 3.0 } else { -3.0 };
                    mle.set_control_point(1, 2, p).unwrap();
                    edit_oracle.net.set(1, 2, p).unwrap();
                    mle.evaluate_points_into(&mut raw).unwrap();
                    for ((q, s), r) in live_points.iter_mut().zip(&mut live_inside).zip(&raw) {
                        *q = Vec3::from(*r);
                        *s = Oracle::inside_level(q);
                    }
                    evaluate_into(
                        &field,
                        n,
                        n,
                        &live_points,
                        &live_inside,
                        &settings,
                        &edit_oracle,
                        &mut margins,
                    )
                    .unwrap()
                })
            })
        });
        group.finish();

        // A drag, evaluated afresh and reusing kept distances.
        let mut group = c.benchmark_group(format!("drag/{grid}"));
        group.sample_size(if n > 40 { 20 } else { 100 });
        for reuse in [false, true] {
            let mut drag_oracle = Oracle { net: net() };
            let (mut live_points, mut live_inside) = (points.clone(), inside.clone());
            let (mut memo, mut step) = (MarginMemo::default(), 0.0f64);
            let name = if reuse { "reusing" } else { "fresh" };
            group.bench_function(BenchmarkId::from_parameter(name), |b| {
                pool.install(|| {
                    b.iter(|| {
                        step += 0.5 / 4.0;
                        let mut p = net().get(1, 2).unwrap();
                        p[0] += 4.0 * step.cos() - 4.0;
                        p[2] += 4.0 * step.sin();
                        mle.set_control_point(1, 2, p).unwrap();
                        drag_oracle.net.set(1, 2, p).unwrap();
                        mle.evaluate_points_into(&mut raw).unwrap();
                        for ((q, s), r) in live_points.iter_mut().zip(&mut live_inside).zip(&raw) {
                            *q = Vec3::from(*r);
                            *s = Oracle::inside_level(q);
                        }
                        let args = (&field, n, n, &live_points, &live_inside, &settings);
                        if reuse {
                            evaluate_reusing(
                                args.0,
                                args.1,
                                args.2,
                                args.3,
                                args.4,
                                args.5,
                                &drag_oracle,
                                &mut memo,
                                &mut margins,
                            )
                        } else {
                            evaluate_into(
                                args.0,
                                args.1,
                                args.2,
                                args.3,
                                args.4,
                                args.5,
                                &drag_oracle,
                                &mut margins,
                            )
                        }
                        .unwrap()
                    })
                })
            });
        }
        group.finish();
    }

    let mut group = c.benchmark_group("setup");
    group.sample_size(10);
    group.bench_function(BenchmarkId::from_parameter("200mm_2mm"), |b| {
        pool.install(|| b.iter(|| MarginField::new(&mesh, lo, hi, 2.0).unwrap()))
    });
    group.finish();
}

criterion_group!(margin, benches);
criterion_main!(margin);
