#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Oriented points and the solver on a liver-sized ellipsoid (radii 95 × 70 × 60 mm on 0.8 mm
//! voxels, ~170 K samples) at depths 7 and 8. Prints a stage breakdown before the criterion runs.

use std::hint::black_box;
use std::time::Instant;

use criterion::{Criterion, criterion_group, criterion_main};
use resecta_geom::{Grid, Vec3, Volume};
use resecta_poisson::{PoissonParams, oriented_points, solve};

fn liver_like() -> Volume<bool> {
    let (r, s) = ([95.0, 70.0, 60.0], 0.8);
    let dims = [250, 185, 160];
    let grid = Grid::axis_aligned(dims, [s; 3], Vec3::zeros()).unwrap();
    let c = grid.voxel_center([dims[0] / 2, dims[1] / 2, dims[2] / 2]);
    let data = (0..grid.len())
        .map(|o| {
            let d = grid.voxel_center(grid.ijk(o)) - c;
            (d.x / r[0]).powi(2) + (d.y / r[1]).powi(2) + (d.z / r[2]).powi(2) <= 1.0
        })
        .collect();
    Volume::from_vec(grid, data).unwrap()
}

fn bench(c: &mut Criterion) {
    let mask = liver_like();
    let t = Instant::now();
    let pts = oriented_points(&mask).unwrap();
    eprintln!(
        "points: {} samples in {:.1} ms",
        pts.len(),
        t.elapsed().as_secs_f64() * 1e3
    );
    for depth in [7, 8] {
        let params = PoissonParams {
            depth,
            ..Default::default()
        };
        let t = Instant::now();
        let f = solve(&pts, &params).unwrap();
        let r = &f.report;
        eprintln!(
            "d={depth}: solve {:.1} ms (splat {:.1}, multigrid {:.1}, iso {:.1}); V-cycles after FMG {}, residuals {:?}",
            t.elapsed().as_secs_f64() * 1e3,
            r.splat_s * 1e3,
            r.solve_s * 1e3,
            r.iso_s * 1e3,
            r.cycles,
            r.residuals
        );
    }
    let mut g = c.benchmark_group("poisson");
    g.sample_size(10);
    g.bench_function("oriented_points", |b| {
        b.iter(|| oriented_points(black_box(&mask)).unwrap())
    });
    for depth in [7, 8] {
        let params = PoissonParams {
            depth,
            ..Default::default()
        };
        g.bench_function(format!("solve_d{depth}"), |b| {
            b.iter(|| solve(black_box(&pts), &params).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
