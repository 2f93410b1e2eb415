//! Volumetry on a 512×512×300 label map (0.75×0.75×1 mm): set-up, one cut (ours), and the
//! thesis' method (300×300 surface, 3×3×3 thickening, region growing) side by side; the
//! accuracy of both against the analytic cap is printed once.
#![allow(clippy::unwrap_used)]

use std::f64::consts::PI;

use criterion::{Criterion, criterion_group, criterion_main};
use resecta_bezier::ControlNet;
use resecta_geom::{Grid, Real, Vec3, Volume};
use resecta_volumetry::{LiverVoxels, Volumetry, thesis_volumetry};

const AXES: [Real; 3] = [110.0, 85.0, 70.0];

fn liver() -> Volume<bool> {
    let grid = Grid::axis_aligned(
        [512, 512, 300],
        [0.75, 0.75, 1.0],
        Vec3::new(-191.6, -191.6, -149.5),
    )
    .unwrap();
    let [nx, ny, _] = grid.dims();
    let data = (0..grid.len())
        .map(|v| {
            let p = grid.voxel_center([v % nx, (v / nx) % ny, v / (nx * ny)]);
            (p.x / AXES[0]).powi(2) + (p.y / AXES[1]).powi(2) + (p.z / AXES[2]).powi(2) <= 1.0
        })
        .collect();
    Volume::from_vec(grid, data).unwrap()
}

fn cap(t: Real) -> Real {
    let h = t / AXES[0];
    AXES.iter().product::<Real>() * PI * (1.0 - h).powi(2) * (2.0 + h) / 3.0
}

fn net(x: Real) -> ControlNet<Real> {
    ControlNet::planar(
        4,
        4,
        [x, -150.0, -130.0],
        [0.0, 300.0, 0.0],
        [0.0, 0.0, 260.0],
    )
    .unwrap()
}

fn bench(c: &mut Criterion) {
    let m = liver();
    let tumour = [Vec3::new(60.0, 0.0, 0.0)];
    let mut g = c.benchmark_group("volumetry_512x512x300");
    g.sample_size(10);
    g.bench_function("setup", |b| b.iter(|| LiverVoxels::new(&m).unwrap()));
    let mut vol = Volumetry::new(LiverVoxels::new(&m).unwrap());
    let (x_ours, x_thesis) = (20.3, 20.3);
    let ours = vol.cut(&net(x_ours), &tumour).unwrap();
    let thesis = thesis_volumetry(&m, &net(x_thesis), tumour[0], 300, 3).unwrap();
    let truth = cap(x_ours);
    eprintln!(
        "liver {:.1} ml, {} voxels; cap truth {:.2} ml; ours {:.2} ml ({:+.3} %, {} band voxels, {:?} samples); thesis {:.2} ml ({:+.3} %), lost {:.2} ml",
        vol.liver().total_mm3() / 1e3,
        vol.liver().len(),
        truth / 1e3,
        ours.resected_mm3 / 1e3,
        100.0 * (ours.resected_mm3 - truth) / truth,
        ours.band_voxels,
        ours.samples,
        thesis.resected_mm3 / 1e3,
        100.0 * (thesis.resected_mm3 - truth) / truth,
        thesis.lost_mm3 / 1e3
    );
    let mut k = 0u32;
    g.bench_function("cut_ours", |b| {
        b.iter(|| {
            k += 1;
            vol.cut(&net(x_ours + Real::from(k % 2)), &tumour).unwrap()
        })
    });
    g.bench_function("cut_thesis_300x300_3x3x3", |b| {
        b.iter(|| thesis_volumetry(&m, &net(x_thesis), tumour[0], 300, 3).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
