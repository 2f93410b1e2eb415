#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Point-cloud reconstruction against analytic spheres.

use std::f64::consts::PI;

use resecta_geom::{Real, Vec3};
use resecta_phantom::fibonacci_sphere;
use resecta_recon::{CloudOptions, NormalSource, PoissonSolver, ReconError, reconstruct_cloud};

/// `n` points of the sphere of `radius` at `centre` (Fibonacci lattice).
fn sphere(n: usize, radius: Real, centre: Vec3) -> Vec<Vec3> {
    fibonacci_sphere(n)
        .into_iter()
        .map(|u| centre + u * radius)
        .collect()
}

/// Largest |distance to the sphere| over the mesh's vertices.
fn worst(mesh: &resecta_geom::TriMesh, radius: Real, centre: Vec3) -> Real {
    mesh.vertices()
        .iter()
        .map(|v| ((v - centre).norm() - radius).abs())
        .fold(0.0, Real::max)
}

#[test]
fn dense_sphere_without_normals_is_within_a_tenth_of_a_millimetre() {
    let (r, c) = (20.0, Vec3::new(3.0, -7.0, 11.0));
    let pts = sphere(40_000, r, c);
    // Measured: 0.032 mm at d = 6, 0.020 mm at d = 7, 0.048 mm at d = 8.
    for depth in [6, 7] {
        let opts = CloudOptions {
            depth,
            ..CloudOptions::default()
        };
        let model = reconstruct_cloud(&pts, None, &opts, &PoissonSolver::cpu()).unwrap();
        let w = worst(&model.mesh, r, c);
        assert!(w <= 0.1, "depth {depth}: {w} mm");
        assert_eq!(model.report.normals, NormalSource::Estimated);
        assert_eq!(model.report.components, Some(1));
        assert_eq!(model.report.distinct, 40_000);
        let area = model.report.sampled_area_mm2 / (4.0 * PI * r * r);
        assert!((area - 1.0).abs() < 0.1, "sampled area ratio {area}");
    }
}

#[test]
fn sparse_sphere_with_and_without_normals_agree() {
    let (r, c) = (20.0, Vec3::zeros());
    let pts = sphere(300, r, c);
    let normals: Vec<Vec3> = pts.iter().map(|p| (p - c) * 3.0).collect();
    let opts = CloudOptions::default();
    let given = reconstruct_cloud(&pts, Some(&normals), &opts, &PoissonSolver::cpu()).unwrap();
    let est = reconstruct_cloud(&pts, None, &opts, &PoissonSolver::cpu()).unwrap();
    assert_eq!(given.report.normals, NormalSource::Given);
    // 300 points at d = 5 (cells of 1.4 mm): measured 0.41 mm either way.
    let (wg, we) = (worst(&given.mesh, r, c), worst(&est.mesh, r, c));
    assert!(wg < 1.0 && we < 1.0, "given {wg} mm, estimated {we} mm");
    assert!((wg - we).abs() < 0.2);
    assert!(given.mesh.signed_volume() > 0.0 && est.mesh.signed_volume() > 0.0);
}

#[test]
fn bad_normals_are_refused() {
    let pts = sphere(50, 10.0, Vec3::zeros());
    let mut normals: Vec<Vec3> = pts.clone();
    let opts = CloudOptions::default();
    let cpu = PoissonSolver::cpu();
    assert!(matches!(
        reconstruct_cloud(&pts, Some(&normals[..49]), &opts, &cpu),
        Err(ReconError::NormalCount {
            points: 50,
            normals: 49
        })
    ));
    normals[9] = Vec3::zeros();
    assert!(matches!(
        reconstruct_cloud(&pts, Some(&normals), &opts, &cpu),
        Err(ReconError::BadNormal { index: 9 })
    ));
}
