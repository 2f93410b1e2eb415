#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Oriented points against analytic spheres and planes.

mod common;

use common::*;
use resecta_geom::{Grid, Mat3, Real, Vec3, Volume};
use resecta_poisson::{MIN_POINTS, PoissonError, PoissonParams, oriented_points, solve};

/// Mean angle (degrees) to the radial direction, mean signed and mean absolute radial offset.
fn sphere_stats(spacing: [Real; 3], dir: Mat3) -> (usize, Real, Real, Real) {
    let pts = oriented_points(&sphere_mask(spacing, dir)).unwrap();
    let n = pts.len() as Real;
    let (mut ang, mut dev, mut adev) = (0.0, 0.0, 0.0);
    for (p, nrm) in pts.positions.iter().zip(&pts.normals) {
        let d = p - centre();
        assert!((nrm.norm() - 1.0).abs() < 1e-12);
        ang += nrm.dot(&d.normalize()).clamp(-1.0, 1.0).acos().to_degrees();
        dev += d.norm() - RADIUS;
        adev += (d.norm() - RADIUS).abs();
    }
    (pts.len(), ang / n, dev / n, adev / n)
}

#[test]
fn sphere_normals_and_shifted_positions_on_three_grids() {
    // Sobel normals of a binary staircase scatter (~11–12° mean here); they are unbiased, and
    // the shifted positions straddle the analytic surface.
    // `voxel`: cube root of the voxel volume.
    let aniso = (0.8f64 * 0.9 * 1.5).cbrt();
    for (spacing, dir, max_angle, voxel) in [
        ([1.0; 3], Mat3::identity(), 12.0, 1.0),
        ([0.8, 0.9, 1.5], Mat3::identity(), 13.5, aniso),
        ([0.8, 0.9, 1.5], oblique(), 13.5, aniso),
    ] {
        let (count, angle, dev, adev) = sphere_stats(spacing, dir);
        eprintln!(
            "{spacing:?}: {count} points, mean angle {angle:.2}°, mean offset {dev:.3} mm, mean |offset| {adev:.3} mm"
        );
        assert!(count > 20_000);
        assert!(angle < max_angle, "mean normal error {angle}°");
        assert!(dev.abs() < 0.1, "mean radial offset {dev} mm");
        assert!(adev < 0.5 * voxel, "mean |radial offset| {adev} mm");
    }
}

#[test]
fn unshifted_centres_would_lie_half_a_voxel_inside() {
    // The correction is what removes the bias: undo it and the mean offset is about −w/2.
    let pts = oriented_points(&sphere_mask([1.0; 3], Mat3::identity())).unwrap();
    let mean: Real = pts
        .positions
        .iter()
        .zip(&pts.normals)
        .map(|(p, n)| {
            let w: Real = n.iter().map(|c| c.abs()).sum();
            (p - 0.5 * w * n - centre()).norm() - RADIUS
        })
        .sum::<Real>()
        / pts.len() as Real;
    assert!(mean < -0.5 && mean > -0.8, "unshifted mean offset {mean}");
}

#[test]
fn half_space_on_oblique_anisotropic_grid_is_exact() {
    // Mask = {k < 10}: the top samples lie exactly on the plane k = 9.5 with normal ∝ J⁻ᵀ e_z,
    // and the mask touches the volume's sides, which give samples too.
    let grid = Grid::new(
        [12, 11, 20],
        [0.7, 1.1, 2.5],
        Vec3::new(5.0, -3.0, 1.0),
        oblique(),
    )
    .unwrap();
    let data = (0..grid.len()).map(|o| grid.ijk(o)[2] < 10).collect();
    let mask = Volume::from_vec(grid.clone(), data).unwrap();
    let pts = oriented_points(&mask).unwrap();
    let j = grid.linear();
    let up = (j.try_inverse().unwrap().transpose() * Vec3::z()).normalize();
    let (mut top, mut side) = (0, 0);
    for ((p, n), a) in pts.positions.iter().zip(&pts.normals).zip(&pts.areas) {
        let ijk = grid.world_to_index(*p);
        let interior = (0.5..10.5).contains(&ijk.x) && (0.5..9.5).contains(&ijk.y);
        if interior && ijk.z > 9.0 {
            top += 1;
            assert!((n - up).norm() < 1e-9, "normal {n:?} vs {up:?}");
            assert!((ijk.z - 9.5).abs() < 1e-9, "k = {}", ijk.z);
            // Area per sample = the voxel's cross-section parallel to the plane.
            let face = (j.column(0).cross(&j.column(1))).norm();
            assert!((a - face).abs() < 1e-9 * face);
        } else if ijk.x < 0.0 {
            side += 1;
            assert!(n.dot(&(-j.column(0).normalize())) > 0.5);
        }
    }
    assert_eq!(top, 10 * 9, "top samples");
    assert!(side > 0, "no samples where the mask touches the border");
    // Ordered by voxel index: the first sample is voxel (0, 0, 0).
    let first = grid.world_to_index(pts.positions[0]);
    assert!(first.x < 0.0 && first.z < 0.5);
}

#[test]
fn empty_single_voxel_and_tiny_masks() {
    let grid = Grid::axis_aligned([5, 5, 5], [1.0; 3], Vec3::zeros()).unwrap();
    let empty = Volume::filled(grid.clone(), false);
    assert_eq!(oriented_points(&empty), Err(PoissonError::EmptyMask));
    // A single voxel's Sobel gradient vanishes by symmetry: no samples.
    let mut one = empty.clone();
    one.set([2, 2, 2], true);
    assert_eq!(
        oriented_points(&one),
        Err(PoissonError::TooFewPoints {
            found: 0,
            needed: MIN_POINTS
        })
    );
    // A 2×2×2 block: 8 samples with diagonal normals, and a small closed field around it.
    let mut block = empty;
    for o in 0..8 {
        block.set([1 + (o & 1), 1 + ((o >> 1) & 1), 1 + (o >> 2)], true);
    }
    let pts = oriented_points(&block).unwrap();
    assert_eq!(pts.len(), 8);
    let c = Vec3::repeat(1.5);
    for (p, n) in pts.positions.iter().zip(&pts.normals) {
        let radial = (p - c).normalize();
        assert!((n - radial).norm() < 1e-12);
    }
    let f = solve(
        &pts,
        &PoissonParams {
            depth: 4,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(f.value_at(c).unwrap() > f.iso);
    assert!(f.value_at(f.origin).unwrap() < f.iso);
}

#[test]
fn points_are_deterministic_across_thread_counts() {
    let mask = sphere_mask([0.8, 0.9, 1.5], oblique());
    let run = |t| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap()
            .install(|| oriented_points(&mask).unwrap())
    };
    assert_eq!(run(1), run(2));
}
