#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Normals and areas against analytic surfaces.

use std::f64::consts::PI;

use resecta_geom::{Real, Vec3};
use resecta_phantom::fibonacci_sphere;
use resecta_pointcloud::{NormalParams, PointCloudError, estimate_normals, point_areas};

/// `n` points of the sphere of `radius` at `centre` (Fibonacci lattice).
fn sphere(n: usize, radius: Real, centre: Vec3) -> Vec<Vec3> {
    fibonacci_sphere(n)
        .into_iter()
        .map(|u| centre + u * radius)
        .collect()
}

fn worst_angle_deg(normals: &[Vec3], truth: impl Fn(usize) -> Vec3) -> Real {
    normals
        .iter()
        .enumerate()
        .map(|(i, n)| n.dot(&truth(i)).clamp(-1.0, 1.0).acos().to_degrees())
        .fold(0.0, Real::max)
}

#[test]
fn sphere_normals_point_outward_and_areas_add_up() {
    let c = Vec3::new(10.0, -5.0, 3.0);
    let pts = sphere(600, 20.0, c);
    let est = estimate_normals(&pts, &NormalParams::default()).unwrap();
    assert_eq!(est.components, 1);
    assert_eq!(est.degenerate, 0);
    let worst = worst_angle_deg(&est.normals, |i| (pts[i] - c).normalize());
    assert!(worst < 5.0, "worst normal {worst}°");
    let area: Real = est.areas.iter().sum();
    let truth = 4.0 * PI * 400.0;
    assert!((area / truth - 1.0).abs() < 0.15, "area {area} vs {truth}");
    // The given-normals path computes the same areas.
    assert_eq!(point_areas(&pts, 10).unwrap(), (est.areas, 600));
}

#[test]
fn thin_tube_between_two_sheets_keeps_orientation() {
    // A capped cylinder of radius 3 mm sampled every ~1.5 mm: the opposite wall (6 mm away) is
    // farther than the tangent neighbours, but close enough to tempt an angle-only MST.
    let (r, len) = (3.0, 40.0);
    let mut pts = Vec::new();
    let mut truth = Vec::new();
    let rings = (len / 1.5) as usize;
    for k in 0..=rings {
        let z = len * k as Real / rings as Real;
        for a in 0..12 {
            let t = 2.0 * PI * (a as Real + 0.5 * (k % 2) as Real) / 12.0;
            let n = Vec3::new(t.cos(), t.sin(), 0.0);
            pts.push(Vec3::new(0.0, 0.0, z) + n * r);
            truth.push(n);
        }
    }
    for (end, s) in [(0.0, -1.0), (len, 1.0)] {
        for n in sphere(40, 1.0, Vec3::zeros())
            .into_iter()
            .filter(|n| n.z * s > 0.3)
        {
            pts.push(Vec3::new(0.0, 0.0, end) + n * r);
            truth.push(n);
        }
    }
    let est = estimate_normals(&pts, &NormalParams { neighbours: 8 }).unwrap();
    let flipped = (0..pts.len())
        .filter(|&i| est.normals[i].dot(&truth[i]) < 0.0)
        .count();
    assert_eq!(flipped, 0);
}

#[test]
fn separate_objects_are_oriented_each_from_its_own_root() {
    let (a, b) = (Vec3::zeros(), Vec3::new(100.0, 0.0, 0.0));
    let mut pts = sphere(300, 10.0, a);
    pts.extend(sphere(300, 15.0, b));
    let est = estimate_normals(&pts, &NormalParams::default()).unwrap();
    assert_eq!(est.components, 2);
    let worst = worst_angle_deg(&est.normals, |i| {
        (pts[i] - if i < 300 { a } else { b }).normalize()
    });
    assert!(worst < 8.0, "worst normal {worst}°");
}

#[test]
fn duplicates_share_a_normal_and_results_follow_input_order() {
    let mut pts = sphere(200, 10.0, Vec3::zeros());
    pts.push(pts[7]);
    pts.push(pts[7]);
    let est = estimate_normals(&pts, &NormalParams::default()).unwrap();
    assert_eq!(est.distinct, 200);
    assert_eq!(est.normals.len(), 202);
    assert_eq!(est.normals[200], est.normals[7]);
    assert_eq!(est.areas[201], est.areas[7]);
    let reversed: Vec<Vec3> = pts.iter().rev().copied().collect();
    let back = estimate_normals(&reversed, &NormalParams::default()).unwrap();
    for i in 0..pts.len() {
        assert!((back.normals[pts.len() - 1 - i] - est.normals[i]).norm() < 1e-9);
    }
}

#[test]
fn bad_clouds_are_refused_by_name() {
    let p = NormalParams::default();
    let mut pts = sphere(50, 5.0, Vec3::zeros());
    pts[3].y = Real::NAN;
    assert_eq!(
        estimate_normals(&pts, &p),
        Err(PointCloudError::NonFinite { index: 3 })
    );
    let three = vec![Vec3::zeros(), Vec3::x(), Vec3::y()];
    assert!(matches!(
        estimate_normals(&three, &p),
        Err(PointCloudError::TooFewPoints { needed: 4, got: 3 })
    ));
    let same = vec![Vec3::x(); 40];
    assert!(matches!(
        estimate_normals(&same, &p),
        Err(PointCloudError::TooFewPoints { got: 1, .. })
    ));
    let line: Vec<Vec3> = (0..30).map(|i| Vec3::x() * i as Real).collect();
    assert_eq!(estimate_normals(&line, &p), Err(PointCloudError::Collinear));
    let ok = sphere(20, 5.0, Vec3::zeros());
    for k in [0, 2, 20, 65] {
        assert!(matches!(
            estimate_normals(&ok, &NormalParams { neighbours: k }),
            Err(PointCloudError::Neighbours { .. })
        ));
    }
}
