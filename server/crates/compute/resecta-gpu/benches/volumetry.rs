//! One volumetry cut on the CPU and with `GpuVolumetry` side by side, on ellipsoid livers of
//! 128³ (1 mm) and 512×512×300 (0.75×0.75×1 mm; there the 2.74 l liver of
//! `resecta-volumetry`'s bench, semi-axes 110, 85, 70 mm): a planar cut through the liver. Skips (with a line on stderr) without an adapter with `SHADER_F64`.
//! On lavapipe this is a correctness run: the "GPU" is an emulation on the same CPU cores.
#![allow(clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use resecta_bezier::ControlNet;
use resecta_geom::{Grid, Real, Vec3, Volume};
use resecta_gpu::{GpuContext, GpuVolumetry};
use resecta_volumetry::{LiverVoxels, Volumetry};

/// An axis-aligned ellipsoid liver centred in the grid, its semi-axes fractions of the grid's
/// half-extents (those of 110, 85, 70 mm at 512×512×300).
fn liver(dims: [usize; 3], spacing: [Real; 3]) -> Volume<bool> {
    let half = Vec3::from_fn(|a, _| 0.5 * spacing[a] * (dims[a] - 1) as Real);
    let grid = Grid::axis_aligned(dims, spacing, -half).unwrap();
    let axes = Vec3::new(0.574, 0.4436, 0.468).component_mul(&half);
    let data = (0..grid.len())
        .map(|v| {
            let p = grid.voxel_center(grid.ijk(v));
            p.component_div(&axes).norm_squared() <= 1.0
        })
        .collect();
    Volume::from_vec(grid, data).unwrap()
}

fn bench(c: &mut Criterion) {
    let Some(ctx) = GpuContext::try_new().filter(|c| c.caps.f64) else {
        eprintln!("SKIP: no GPU adapter with SHADER_F64");
        return;
    };
    eprintln!("device: {} ({:?})", ctx.info.name, ctx.info.backend);
    for (name, dims, spacing) in [
        ("128^3", [128, 128, 128], [1.0, 1.0, 1.0]),
        ("512x512x300", [512, 512, 300], [0.75, 0.75, 1.0]),
    ] {
        let m = liver(dims, spacing);
        let grid = m.grid();
        let (lo, hi) = (
            grid.voxel_center([0; 3]),
            grid.voxel_center(dims.map(|d| d - 1)),
        );
        // A plane x = 0.2·x_max, slightly tilted, spanning the whole grid.
        let x = 0.2 * hi.x;
        let net = ControlNet::planar(
            4,
            4,
            [x, lo.y - 5.0, lo.z - 5.0],
            [3.0, hi.y - lo.y + 10.0, 0.0],
            [0.0, 0.0, hi.z - lo.z + 10.0],
        )
        .unwrap();
        let tumour = [Vec3::new(0.45 * hi.x, 0.0, 0.0)];
        let mut cpu = Volumetry::new(LiverVoxels::new(&m).unwrap());
        let mut gpu = Volumetry::new(LiverVoxels::new(&m).unwrap())
            .with_accelerator(Box::new(GpuVolumetry::new(&ctx).unwrap()));
        let (a, b) = (
            cpu.cut(&net, &tumour).unwrap(),
            gpu.cut(&net, &tumour).unwrap(),
        );
        eprintln!(
            "{name}: liver {} voxels; resected cpu {:.6} ml, gpu {:.6} ml ({} band voxels, {:?} samples), \
             equal: {}, fallbacks {:?}",
            cpu.liver().len(),
            a.resected_mm3 / 1e3,
            b.resected_mm3 / 1e3,
            b.band_voxels,
            b.samples,
            a == b,
            gpu.accelerator_fallbacks(),
        );
        let mut g = c.benchmark_group(format!("volumetry_cut_{name}"));
        g.sample_size(10);
        g.bench_function("cpu", |bch| bch.iter(|| cpu.cut(&net, &tumour).unwrap()));
        g.bench_function("gpu", |bch| bch.iter(|| gpu.cut(&net, &tumour).unwrap()));
        g.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
