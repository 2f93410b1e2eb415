//! Analytic spheres voxelised on axis-aligned, anisotropic and oblique grids.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use nalgebra::Rotation3;
use resecta_geom::{Grid, Mat3, Real, Vec3, Volume};
use resecta_poisson::PoissonField;

pub const RADIUS: Real = 40.0;

/// A sphere of `RADIUS` mm around `centre()` voxelised by voxel centres (closed ball).
pub fn sphere_mask(spacing: [Real; 3], direction: Mat3) -> Volume<bool> {
    let dims = spacing.map(|s| (2.0 * (RADIUS + 6.0) / s).ceil() as usize);
    let half = Vec3::from_fn(|i, _| spacing[i] * (dims[i] - 1) as Real / 2.0);
    // Centre off the voxel lattice so the voxelisation is generic.
    let origin = centre() - direction * half + Vec3::new(0.31, -0.17, 0.23);
    let grid = Grid::new(dims, spacing, origin, direction).unwrap();
    let data = (0..grid.len())
        .map(|o| (grid.voxel_center(grid.ijk(o)) - centre()).norm() <= RADIUS)
        .collect();
    Volume::from_vec(grid, data).unwrap()
}

pub fn centre() -> Vec3 {
    Vec3::new(12.0, -30.0, 55.0)
}

pub fn oblique() -> Mat3 {
    Rotation3::from_euler_angles(0.4, -0.3, 0.9).into_inner()
}

/// Count × voxel volume.
pub fn mask_volume(mask: &Volume<bool>) -> Real {
    mask.data().iter().filter(|v| **v).count() as Real * mask.grid().voxel_volume_mm3()
}

/// ~`n` directions spread over the sphere (Fibonacci lattice).
pub fn directions(n: usize) -> Vec<Vec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as Real + 0.5) / n as Real;
            let r = (1.0 - z * z).sqrt();
            let t = golden * i as Real;
            Vec3::new(r * t.cos(), r * t.sin(), z)
        })
        .collect()
}

/// Radius of the iso-surface along `dir` from `centre()`, by bisection of `value − iso`.
pub fn iso_radius(f: &PoissonField, dir: Vec3) -> Real {
    let g = |t: Real| f.value_at(centre() + t * dir).unwrap() - f.iso;
    let (mut a, mut b) = (RADIUS - 3.0, RADIUS + 3.0);
    assert!(g(a) > 0.0 && g(b) < 0.0, "no sign change along {dir:?}");
    for _ in 0..50 {
        let m = 0.5 * (a + b);
        if g(m) > 0.0 { a = m } else { b = m }
    }
    0.5 * (a + b)
}

/// Volume of `{value > iso}`: each cell sampled at `s³` points (trilinear field).
pub fn enclosed_volume(f: &PoissonField, s: usize) -> Real {
    let n = f.dims[0];
    let h = f.cell;
    let mut count = 0u64;
    for k in 0..n - 1 {
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                let v =
                    |a: usize, b: usize, c: usize| f.values[(i + a) + n * ((j + b) + n * (k + c))];
                let corners = [
                    v(0, 0, 0),
                    v(1, 0, 0),
                    v(0, 1, 0),
                    v(1, 1, 0),
                    v(0, 0, 1),
                    v(1, 0, 1),
                    v(0, 1, 1),
                    v(1, 1, 1),
                ];
                let (mn, mx) = corners
                    .iter()
                    .fold((f32::MAX, f32::MIN), |(a, b), &c| (a.min(c), b.max(c)));
                if mn > f.iso {
                    count += (s * s * s) as u64;
                    continue;
                }
                if mx <= f.iso {
                    continue;
                }
                for c in 0..s {
                    for b in 0..s {
                        for a in 0..s {
                            let (x, y, z) = (
                                (a as f32 + 0.5) / s as f32,
                                (b as f32 + 0.5) / s as f32,
                                (c as f32 + 0.5) / s as f32,
                            );
                            let lx = |p: f32, q: f32| p * (1.0 - x) + q * x;
                            let y0 = lx(corners[0], corners[1]) * (1.0 - y)
                                + lx(corners[2], corners[3]) * y;
                            let y1 = lx(corners[4], corners[5]) * (1.0 - y)
                                + lx(corners[6], corners[7]) * y;
                            if y0 * (1.0 - z) + y1 * z > f.iso {
                                count += 1;
                            }
                        }
                    }
                }
            }
        }
    }
    count as Real * h * h * h / (s * s * s) as Real
}
