//! Point-to-surface distance against analytic answers.
#![allow(clippy::unwrap_used)] // test helpers

use resecta_geom::primitives::{cuboid, icosphere, inscribed_radius};
use resecta_geom::{TriMesh, Vec3};
use resecta_meshmetrics::{MetricsError, point_to_surface};

fn cube() -> TriMesh {
    cuboid(Vec3::zeros(), Vec3::repeat(10.0)).unwrap()
}

/// 21 points above the centres of the six faces at offsets 0, 0.1, …, 2.0 mm: mean 1.0, p95 (rank
/// 0.95·20 = 19) 1.9, max 2.0.
#[test]
fn cube_face_offsets() {
    let dirs = [
        Vec3::x(),
        -Vec3::x(),
        Vec3::y(),
        -Vec3::y(),
        Vec3::z(),
        -Vec3::z(),
    ];
    let centre = Vec3::repeat(5.0);
    let points: Vec<Vec3> = (0..=20)
        .map(|k| centre + dirs[k % 6] * (5.0 + 0.1 * k as f64))
        .collect();
    let s = point_to_surface(&points, &cube()).unwrap();
    assert_eq!(s.count, 21);
    assert!((s.mean - 1.0).abs() < 1e-12, "{s:?}");
    assert!((s.p95 - 1.9).abs() < 1e-12, "{s:?}");
    assert!((s.max - 2.0).abs() < 1e-12, "{s:?}");
}

/// Inside points, edges and corners: distance to the nearest face, edge or corner.
#[test]
fn cube_inside_edge_corner() {
    let cases = [
        (Vec3::new(5.0, 5.0, 5.0), 5.0),
        (Vec3::new(2.0, 5.0, 6.0), 2.0),
        (Vec3::new(12.0, 13.0, 5.0), (4.0f64 + 9.0).sqrt()),
        (Vec3::new(-1.0, -2.0, -2.0), 3.0),
        (Vec3::new(10.0, 10.0, 10.0), 0.0),
    ];
    for (p, want) in cases {
        let s = point_to_surface(&[p], &cube()).unwrap();
        assert!((s.mean - want).abs() < 1e-12, "{p:?}: {s:?}");
        assert_eq!(s.mean, s.max);
        assert_eq!(s.mean, s.p95);
    }
}

/// A polytope inscribed in a sphere is supported at each vertex by the sphere's tangent plane, so
/// the closest point to `v + t·v̂` is `v` itself, at distance exactly `t`. From the centre, the
/// distance is the inscribed radius.
#[test]
fn icosphere_radial_offsets() {
    let (c, r) = (Vec3::new(3.0, -2.0, 1.0), 20.0);
    let mesh = icosphere(c, r, 3).unwrap();
    let offsets: Vec<f64> = (0..mesh.vertices().len())
        .map(|i| 0.01 * (i % 100) as f64)
        .collect();
    let points: Vec<Vec3> = mesh
        .vertices()
        .iter()
        .zip(&offsets)
        .map(|(v, t)| v + (v - c).normalize() * *t)
        .collect();
    let s = point_to_surface(&points, &mesh).unwrap();
    let mean = offsets.iter().sum::<f64>() / offsets.len() as f64;
    assert!((s.mean - mean).abs() < 1e-9, "{s:?} vs {mean}");
    assert!((s.max - 0.99).abs() < 1e-9);
    let inner = inscribed_radius(&mesh, &c).unwrap();
    let s = point_to_surface(&[c], &mesh).unwrap();
    assert!((s.mean - inner).abs() < 1e-9);
    assert!(inner < r && inner > 0.99 * r);
}

/// Bit-identical results for 1 and 3 rayon threads.
#[test]
fn deterministic_across_thread_counts() {
    let mesh = icosphere(Vec3::zeros(), 10.0, 4).unwrap();
    let points: Vec<Vec3> = (0..20_000)
        .map(|i| {
            let t = i as f64 * 0.618_033_988_75;
            Vec3::new(
                t.sin() * 14.0,
                (1.3 * t).cos() * 12.0,
                (0.7 * t).sin() * 9.0,
            )
        })
        .collect();
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| point_to_surface(&points, &mesh).unwrap())
    };
    let (a, b) = (run(1), run(3));
    assert_eq!(a.mean.to_bits(), b.mean.to_bits());
    assert_eq!(a.p95.to_bits(), b.p95.to_bits());
    assert_eq!(a.max.to_bits(), b.max.to_bits());
    assert!(a.mean > 0.0);
}

#[test]
fn bad_input_is_an_error() {
    let mesh = cube();
    assert_eq!(point_to_surface(&[], &mesh), Err(MetricsError::NoPoints));
    let p = [Vec3::zeros(), Vec3::new(f64::NAN, 0.0, 0.0)];
    assert_eq!(
        point_to_surface(&p, &mesh),
        Err(MetricsError::NonFinitePoint(1))
    );
    let empty = TriMesh::new(vec![Vec3::zeros()], vec![]).unwrap();
    assert_eq!(
        point_to_surface(&[Vec3::zeros()], &empty),
        Err(MetricsError::EmptyMesh)
    );
}
