//! Margins against brute force and analytic answers.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::f64::consts::PI;

use proptest::prelude::*;
use resecta_bezier::{ControlNet, eval_point};
use resecta_geom::bvh::closest_point_on_triangle;
use resecta_geom::primitives::{ellipsoid, icosphere, inscribed_radius};
use resecta_geom::{Mat3, TriMesh, Vec3};
use resecta_margin::{
    FAR_TOLERANCE_MM, MarginClass, MarginError, MarginField, MarginMemo, MarginSettings, Nearest,
    OUTSIDE_TOLERANCE_MM, SurfaceMargins, SurfaceOracle, TOLERANCE_MM, Verdict, evaluate,
    evaluate_exact_into, evaluate_into, evaluate_reusing,
};

/// Deterministic xorshift generator.
struct Rng(u64);

impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn point(&mut self, lo: &Vec3, hi: &Vec3) -> Vec3 {
        Vec3::new(
            lo.x + (hi.x - lo.x) * self.unit(),
            lo.y + (hi.y - lo.y) * self.unit(),
            lo.z + (hi.z - lo.z) * self.unit(),
        )
    }
    fn direction(&mut self) -> Vec3 {
        loop {
            let v = self.point(&Vec3::repeat(-1.0), &Vec3::repeat(1.0));
            let n = v.norm();
            if n > 0.1 && n <= 1.0 {
                return v / n;
            }
        }
    }
}

fn brute_force(mesh: &TriMesh, p: &Vec3) -> f64 {
    (0..mesh.triangles().len())
        .map(|t| (closest_point_on_triangle(p, &mesh.corners(t)).point - p).norm())
        .fold(f64::INFINITY, f64::min)
}

fn field_around(mesh: &TriMesh, pad: f64, spacing: f64) -> MarginField {
    let (lo, hi) = mesh.bounds().unwrap();
    MarginField::new(
        mesh,
        lo - Vec3::repeat(pad),
        hi + Vec3::repeat(pad),
        spacing,
    )
    .unwrap()
}

/// Checks every query path against a brute force: `nearest`, `nearest_into`, `distances_into`
/// and `distances_grid_into` (the points read as a 4-row grid).
/// Whether `p` lies within the field's hint grid (where its lower bound is tight).
fn field_covers(field: &MarginField, p: &Vec3) -> bool {
    let (lo, hi) = field.region();
    (0..3).all(|a| p[a] >= lo[a] && p[a] <= hi[a])
}

fn check_against_brute_force(mesh: &TriMesh, field: &MarginField, points: &[Vec3]) {
    let mut near = vec![Nearest::NONE; points.len()];
    field.nearest_into(points, &mut near).unwrap();
    let mut dist = vec![0.0; points.len()];
    field.distances_into(points, &mut dist).unwrap();
    // The points read as grids of 4, 3 and 1 rows (whole and partial 4×4 blocks).
    let grids: Vec<(usize, Vec<f64>)> = [4, 3, 1]
        .iter()
        .map(|&rows| {
            let cols = points.len() / rows;
            let mut grid = vec![0.0; rows * cols];
            field
                .distances_grid_into(rows, cols, &points[..rows * cols], &mut grid)
                .unwrap();
            (rows * cols, grid)
        })
        .collect();
    // Within a tolerance: never below the exact distance, at most the tolerance above.
    let tol = 0.05;
    let mut within = vec![0.0; points.len()];
    // Odd samples exact (a negative or NaN tolerance means exact), even ones within `tol`.
    let tolerance = |k: usize| [tol, -1.0, tol, f64::NAN][k % 4];
    field
        .distances_grid_within(1, points.len(), points, tolerance, &mut within)
        .unwrap();
    for (k, p) in points.iter().enumerate() {
        let excess = within[k] - brute_force(mesh, p);
        let allowed = if k % 2 == 0 { tol } else { 0.0 };
        assert!(
            (-1e-9..=allowed + 1e-9).contains(&excess),
            "{p:?}: {excess}"
        );
    }
    for (k, p) in points.iter().enumerate() {
        let d = brute_force(mesh, p);
        let one = field.nearest(p);
        assert!(
            (one.distance - d).abs() <= 1e-9,
            "{p:?}: {} vs {d}",
            one.distance
        );
        assert!(((one.point - p).norm() - one.distance).abs() <= 1e-12);
        let on = closest_point_on_triangle(p, &mesh.corners(one.triangle as usize)).point;
        assert!((on - one.point).norm() <= 1e-12);
        assert!((near[k].distance - d).abs() <= 1e-9);
        assert!((dist[k] - d).abs() <= 1e-9);
        // A lower bound, and not a vacuous one: within the grid's node spacing √3/2·h of it.
        let lower = field.lower_bound(p);
        assert!(lower <= d + 1e-9, "{p:?}: bound {lower} above {d}");
        assert!(
            d - lower <= 2.0 * 0.5 * 3f64.sqrt() * field.spacing() + 1e-9
                || !field_covers(field, p)
        );
        for (len, grid) in &grids {
            if k < *len {
                assert!((grid[k] - d).abs() <= 1e-9);
            }
        }
    }
}

#[test]
fn nearest_equals_brute_force() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let rotation = rotation(0.3, -0.7, 1.1);
    let meshes = [
        icosphere(Vec3::new(1.0, 2.0, 3.0), 10.0, 3).unwrap(),
        ellipsoid(
            Vec3::new(-2.0, 1.0, 0.5),
            Vec3::new(12.0, 7.0, 4.0),
            rotation,
            3,
        )
        .unwrap(),
        TriMesh::concat(&[
            icosphere(Vec3::new(-10.0, 0.0, 0.0), 7.0, 3).unwrap(),
            icosphere(Vec3::new(10.0, 0.0, 0.0), 7.0, 3).unwrap(),
        ])
        .unwrap(),
    ];
    for (m, mesh) in meshes.iter().enumerate() {
        let field = field_around(mesh, 15.0, 2.0);
        let (lo, hi) = mesh.bounds().unwrap();
        let (rlo, rhi) = (lo - Vec3::repeat(15.0), hi + Vec3::repeat(15.0));
        // Inside the region, near the surface, outside the region, far beyond reach.
        let mut points: Vec<Vec3> = (0..240).map(|_| rng.point(&rlo, &rhi)).collect();
        points.extend(
            mesh.vertices()
                .iter()
                .step_by(7)
                .take(80)
                .map(|v| v + rng.direction() * 1e-6 * rng.unit()),
        );
        points.extend((0..40).map(|_| rng.point(&(rlo * 4.0), &(rhi * 4.0))));
        points.extend((0..8).map(|_| rng.direction() * 3000.0));
        if m == 2 {
            // The medial plane between the two spheres.
            points.extend(
                (0..40).map(|_| Vec3::new(0.0, 16.0 * rng.unit() - 8.0, 16.0 * rng.unit() - 8.0)),
            );
        }
        check_against_brute_force(mesh, &field, &points);
    }
}

/// Rotation by Euler angles (z·y·x).
fn rotation(a: f64, b: f64, c: f64) -> Mat3 {
    let rx = Mat3::new(1.0, 0.0, 0.0, 0.0, c.cos(), -c.sin(), 0.0, c.sin(), c.cos());
    let ry = Mat3::new(b.cos(), 0.0, b.sin(), 0.0, 1.0, 0.0, -b.sin(), 0.0, b.cos());
    let rz = Mat3::new(a.cos(), -a.sin(), 0.0, a.sin(), a.cos(), 0.0, 0.0, 0.0, 1.0);
    rz * ry * rx
}

#[test]
fn non_finite_queries_have_no_answer() {
    let mesh = icosphere(Vec3::zeros(), 5.0, 2).unwrap();
    let field = field_around(&mesh, 5.0, 2.0);
    let bad = Vec3::new(f64::NAN, 0.0, 0.0);
    let n = field.nearest(&bad);
    assert!(n.distance.is_nan() && n.triangle == u32::MAX);
    let points = [
        Vec3::new(9.0, 0.0, 0.0),
        bad,
        Vec3::new(0.0, 0.0, f64::INFINITY),
    ];
    let mut out = [Nearest::NONE; 3];
    field.nearest_into(&points, &mut out).unwrap();
    assert!((out[0].distance - brute_force(&mesh, &points[0])).abs() <= 1e-9);
    assert!(out[1].distance.is_nan() && out[2].distance.is_nan());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// Triangle soups with slivers, needles, repeated and collinear corners.
    #[test]
    fn soups_equal_brute_force(seed in any::<u64>()) {
        let mut rng = Rng(seed | 1);
        let mut v = Vec::new();
        let mut t = Vec::new();
        let box_lo = Vec3::repeat(-8.0);
        let box_hi = Vec3::repeat(8.0);
        for i in 0..120u32 {
            let a = rng.point(&box_lo, &box_hi);
            let size = [2.0, 1e-3, 1e-7][i as usize % 3];
            let b = a + rng.direction() * size;
            let c = match i % 5 {
                0 => a + (b - a) * rng.unit(),
                1 => b,
                _ => a + rng.direction() * size * rng.unit(),
            };
            let k = v.len() as u32;
            v.extend([a, b, c]);
            t.push([k, k + 1, k + 2]);
        }
        let mesh = TriMesh::new(v, t).unwrap();
        let field = field_around(&mesh, 4.0, 1.5);
        let points: Vec<Vec3> = (0..64)
            .map(|_| rng.point(&Vec3::repeat(-14.0), &Vec3::repeat(14.0)))
            .collect();
        check_against_brute_force(&mesh, &field, &points);
    }
}

#[test]
fn icosphere_distances_within_chord_error() {
    let (c, r) = (Vec3::new(4.0, -3.0, 2.0), 15.0);
    let mesh = icosphere(c, r, 5).unwrap();
    let r_in = inscribed_radius(&mesh, &c).unwrap();
    assert!(r - r_in < 0.01);
    let field = field_around(&mesh, 45.0, 2.0);
    let mut rng = Rng(7);
    let points: Vec<Vec3> = (0..2000)
        .map(|_| c + rng.direction() * (r + 0.5 + 39.5 * rng.unit()))
        .collect();
    let mut d = vec![0.0; points.len()];
    field.distances_into(&points, &mut d).unwrap();
    for (p, d) in points.iter().zip(&d) {
        // The mesh lies between the spheres of radii r_in and r about c.
        let q = (p - c).norm();
        assert!(*d >= q - r - 1e-9 && *d <= q - r_in + 1e-9, "{d} for {q}");
    }
}

/// A planar 4×4 Bézier net over [−30, 30]² at height `z`, with a spherical liver.
struct Plane {
    net: ControlNet<f64>,
    liver_centre: Vec3,
    liver_radius: f64,
}

impl Plane {
    fn new(z: f64, liver_centre: Vec3, liver_radius: f64) -> Self {
        let net = ControlNet::planar(4, 4, [-30.0, -30.0, z], [60.0, 0.0, 0.0], [0.0, 60.0, 0.0])
            .unwrap();
        Self {
            net,
            liver_centre,
            liver_radius,
        }
    }

    /// Samples, inside levels.
    fn sample(&self, n: usize) -> (Vec<Vec3>, Vec<f64>) {
        let mut points = Vec::with_capacity(n * n);
        for i in 0..n {
            for j in 0..n {
                let (u, v) = (i as f64 / (n - 1) as f64, j as f64 / (n - 1) as f64);
                points.push(self.point(u, v));
            }
        }
        let inside = points.iter().map(|p| self.inside(p)).collect();
        (points, inside)
    }
}

impl SurfaceOracle for Plane {
    fn point(&self, u: f64, v: f64) -> Vec3 {
        Vec3::from(eval_point(&self.net, u, v).point)
    }
    fn inside(&self, p: &Vec3) -> f64 {
        self.liver_radius - (p - self.liver_centre).norm()
    }
}

/// Tumour sphere off the grid lines, plane at height 16.
const TUMOUR: [f64; 3] = [3.3, -2.7, 0.0];
const R: f64 = 10.0;
const D: f64 = 16.0;

fn tumour() -> (TriMesh, f64) {
    let c = Vec3::from(TUMOUR);
    let mesh = icosphere(c, R, 5).unwrap();
    let r_in = inscribed_radius(&mesh, &c).unwrap();
    (mesh, r_in)
}

/// The hint region around [`tumour`] and the plane over it.
const REGION: ([f64; 3], [f64; 3]) = ([-32.0, -32.0, -12.0], [32.0, 32.0, 20.0]);

fn tumour_field(mesh: &TriMesh) -> MarginField {
    MarginField::new(mesh, Vec3::from(REGION.0), Vec3::from(REGION.1), 2.0).unwrap()
}

fn run(
    field: &MarginField,
    plane: &Plane,
    n: usize,
    settings: &MarginSettings,
) -> (SurfaceMargins, Verdict) {
    let (points, inside) = plane.sample(n);
    evaluate(field, n, n, &points, &inside, settings, plane).unwrap()
}

#[test]
fn plane_over_sphere_minimum_and_areas() {
    let (mesh, r_in) = tumour();
    let field = tumour_field(&mesh);
    let plane = Plane::new(D, Vec3::new(0.0, 0.0, D), 100.0);
    let settings = MarginSettings {
        margin_mm: 10.0,
        band_mm: 3.0,
    };
    let foot = Vec3::new(TUMOUR[0], TUMOUR[1], D);
    let disk = |radius: f64| PI * (radius * radius - D * D);
    let mut area_errors = Vec::new();
    for n in [40, 200] {
        let (margins, verdict) = run(&field, &plane, n, &settings);
        // Minimum: d − R at the foot, between the spheres bounding the mesh.
        let min = verdict.min_margin_mm.unwrap();
        assert!(min >= D - R - 1e-9 && min <= D - r_in + 1e-6, "{n}: {min}");
        assert!((min - (D - R)).abs() <= 0.01);
        let vertex_min = margins
            .distance
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min);
        assert!(min <= vertex_min);
        let point = verdict.point.unwrap();
        assert!((point - foot).norm() <= 0.5, "{n}: {point:?}");
        let [u, v] = verdict.uv.unwrap();
        assert!((Vec3::from(eval_point(&plane.net, u, v).point) - point).norm() <= 1e-9);
        assert!(verdict.violation);
        // Areas: violating disk of radius √((R+m)² − d²), warning annulus, whole patch inside.
        let violating = disk(R + settings.margin_mm);
        let warning = disk(R + settings.margin_mm + settings.band_mm) - violating;
        let err = (verdict.violating_area_mm2 - violating).abs() / violating;
        area_errors.push(err);
        let werr = (verdict.warning_area_mm2 - warning).abs() / warning;
        assert!((verdict.inside_area_mm2 - 3600.0).abs() <= 1e-6 * 3600.0);
        if n == 200 {
            assert!(
                err <= 1e-3,
                "violating area {} vs {violating}",
                verdict.violating_area_mm2
            );
            assert!(
                werr <= 1e-3,
                "warning area {} vs {warning}",
                verdict.warning_area_mm2
            );
        } else {
            assert!(err <= 1e-2 && werr <= 1e-2, "{err} {werr}");
        }
        // Per-vertex distances are within TOLERANCE_MM above a brute force (FAR_TOLERANCE_MM
        // where the field's lower bound puts them beyond margin + band); classes are those of
        // the exact distances (checked on every vertex near a threshold and a sample).
        for k in 0..n * n {
            let near = [10.0, 13.0]
                .iter()
                .any(|t| (margins.distance[k] - t).abs() < 2.0 * TOLERANCE_MM);
            if !near && k % 97 != 0 {
                continue;
            }
            let p = plane.point(
                (k / n) as f64 / (n - 1) as f64,
                (k % n) as f64 / (n - 1) as f64,
            );
            let exact = brute_force(&mesh, &p);
            let excess = margins.distance[k] - exact;
            let allowed = if field.lower_bound(&p) > 13.0 {
                assert!(exact > 13.0);
                FAR_TOLERANCE_MM
            } else {
                TOLERANCE_MM
            };
            assert!((-1e-9..=allowed + 1e-9).contains(&excess), "{excess}");
            let expected = if exact < 10.0 {
                MarginClass::Violation
            } else if exact < 13.0 {
                MarginClass::Warning
            } else {
                MarginClass::Safe
            };
            assert_eq!(margins.class[k], expected);
        }
        for (d, c) in margins.distance.iter().zip(&margins.class) {
            let expected = if *d < 10.0 {
                MarginClass::Violation
            } else if *d < 13.0 {
                MarginClass::Warning
            } else {
                MarginClass::Safe
            };
            assert_eq!(*c, expected);
        }
    }
    assert!(area_errors[1] < area_errors[0], "{area_errors:?}");
}

/// Area of the intersection of two disks of radius `r` whose centres are `s` apart.
fn lens(r: f64, s: f64) -> f64 {
    2.0 * r * r * (s / (2.0 * r)).acos() - 0.5 * s * (4.0 * r * r - s * s).sqrt()
}

#[test]
fn outside_the_liver_does_not_count() {
    let (mesh, r_in) = tumour();
    let field = tumour_field(&mesh);
    // The liver meets the plane in a disk of radius 12 about (−15, 0) that misses the foot.
    let liver = Vec3::new(-15.0, 0.0, D);
    let plane = Plane::new(D, liver, 12.0);
    let settings = MarginSettings {
        margin_mm: 10.0,
        band_mm: 0.0,
    };
    let foot = Vec3::new(TUMOUR[0], TUMOUR[1], D);
    let gap = (foot - liver).norm();
    // Nearest liver point to the foot, and the sphere distance there.
    let lateral = gap - 12.0;
    let expected = (D * D + lateral * lateral).sqrt() - R;
    for n in [40, 200] {
        let (points, inside) = plane.sample(n);
        let (margins, verdict) =
            evaluate(&field, n, n, &points, &inside, &settings, &plane).unwrap();
        for (k, c) in margins.class.iter().enumerate() {
            assert_eq!(*c == MarginClass::Outside, inside[k] <= 0.0);
        }
        let min = verdict.min_margin_mm.unwrap();
        let bound_in = (D * D + lateral * lateral).sqrt() - r_in;
        assert!(
            min >= expected - 1e-9 && min <= bound_in + 1e-3,
            "{n}: {min} vs {expected}"
        );
        let p = verdict.point.unwrap();
        assert!(
            plane.inside(&p) > 0.0 && plane.inside(&p) < 0.01,
            "{n}: {p:?}"
        );
        // Violating part: the lens of the two radius-12 disks; inside part: the liver disk.
        let violating = lens(12.0, gap);
        let inside_area = PI * 144.0;
        let tol = if n == 200 { 2e-3 } else { 2e-2 };
        assert!(
            (verdict.violating_area_mm2 - violating).abs() <= tol * violating,
            "{n}: {} vs {violating}",
            verdict.violating_area_mm2
        );
        assert!((verdict.inside_area_mm2 - inside_area).abs() <= tol * inside_area);
        assert_eq!(verdict.warning_area_mm2, 0.0);
    }
    // Nothing inside: no minimum, no violation.
    let away = Plane::new(D, Vec3::new(0.0, 0.0, 500.0), 10.0);
    let (points, inside) = away.sample(40);
    let (margins, verdict) = evaluate(&field, 40, 40, &points, &inside, &settings, &away).unwrap();
    assert!(margins.class.iter().all(|c| *c == MarginClass::Outside));
    assert_eq!(verdict.min_margin_mm, None);
    assert!(!verdict.violation && verdict.inside_area_mm2 == 0.0);
}

#[test]
fn results_do_not_depend_on_threads_and_serialise() {
    let (mesh, _) = tumour();
    let field = tumour_field(&mesh);
    let plane = Plane::new(D, Vec3::new(0.0, 0.0, D), 35.0);
    let settings = MarginSettings {
        margin_mm: 10.0,
        band_mm: 2.0,
    };
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let two = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let a = one.install(|| run(&field, &plane, 57, &settings));
    let b = two.install(|| run(&field, &plane, 57, &settings));
    assert_eq!(a, b);
    // Reused buffers give the same.
    let (points, inside) = plane.sample(57);
    let mut reused = SurfaceMargins {
        distance: vec![1.0; 7],
        class: vec![MarginClass::Safe; 3],
    };
    let v = evaluate_into(
        &field,
        57,
        57,
        &points,
        &inside,
        &settings,
        &plane,
        &mut reused,
    )
    .unwrap();
    assert_eq!((reused, v), a);
    let json = serde_json::to_value(&a.1).unwrap();
    assert_eq!(json["violation"], true);
    assert_eq!(json["point"].as_array().unwrap().len(), 3);
    assert_eq!(
        serde_json::to_value(MarginClass::Violation).unwrap(),
        "Violation"
    );
    assert_eq!(MarginClass::Violation as u8, 3);
}

#[test]
fn bad_input_is_an_error() {
    let mesh = icosphere(Vec3::zeros(), 5.0, 1).unwrap();
    let (lo, hi) = (Vec3::repeat(-10.0), Vec3::repeat(10.0));
    let new = |m: &TriMesh, lo: Vec3, hi: Vec3, s: f64| MarginField::new(m, lo, hi, s).err();
    assert_eq!(
        new(&TriMesh::default(), lo, hi, 1.0),
        Some(MarginError::EmptyMesh)
    );
    let nan = Vec3::new(0.0, f64::NAN, 0.0);
    assert!(matches!(
        new(&mesh, nan, hi, 1.0),
        Some(MarginError::NonFiniteRegion { name: "min", .. })
    ));
    assert!(matches!(
        new(&mesh, lo, nan, 1.0),
        Some(MarginError::NonFiniteRegion { name: "max", .. })
    ));
    assert!(matches!(
        new(&mesh, hi, lo, 1.0),
        Some(MarginError::InvertedRegion { .. })
    ));
    for s in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(matches!(
            new(&mesh, lo, hi, s),
            Some(MarginError::BadSpacing(_))
        ));
    }
    // 10 m at 0.1 mm would be 10¹⁵ nodes: refused before allocating.
    let huge = Vec3::repeat(1e4);
    assert!(matches!(
        new(&mesh, -huge, huge, 0.1),
        Some(MarginError::TooManyNodes { .. })
    ));
    assert!(matches!(
        new(&mesh, lo, hi, 1e-300),
        Some(MarginError::TooManyNodes { .. })
    ));
    // A flat region is fine (one cell along z).
    let flat = MarginField::new(&mesh, lo, Vec3::new(10.0, 10.0, -10.0), 1.0).unwrap();
    assert_eq!(flat.dims(), [21, 21, 2]);

    let field = new_field(&mesh);
    let points = vec![Vec3::zeros(); 6];
    let mut short = vec![Nearest::NONE; 5];
    assert!(matches!(
        field.nearest_into(&points, &mut short),
        Err(MarginError::LengthMismatch {
            expected: 6,
            got: 5,
            ..
        })
    ));
    let mut short = vec![0.0; 5];
    assert!(field.distances_into(&points, &mut short).is_err());
    assert!(
        field
            .distances_grid_into(2, 3, &points, &mut short)
            .is_err()
    );
    assert!(
        field
            .distances_grid_into(2, 2, &points, &mut [0.0; 4])
            .is_err()
    );

    let plane = Plane::new(8.0, Vec3::zeros(), 50.0);
    let (pts, inside) = plane.sample(4);
    let ok = MarginSettings {
        margin_mm: 1.0,
        band_mm: 1.0,
    };
    let eval = |ru, rv, p: &[Vec3], s: &[f64], set: &MarginSettings| {
        evaluate(&field, ru, rv, p, s, set, &plane).err()
    };
    assert!(eval(4, 4, &pts, &inside, &ok).is_none());
    assert!(matches!(
        eval(4, 3, &pts, &inside, &ok),
        Some(MarginError::LengthMismatch { .. })
    ));
    assert!(matches!(
        eval(4, 4, &pts, &inside[1..], &ok),
        Some(MarginError::LengthMismatch { .. })
    ));
    assert_eq!(
        eval(1, 16, &pts, &inside, &ok),
        Some(MarginError::GridTooSmall { ru: 1, rv: 16 })
    );
    assert!(matches!(
        eval(usize::MAX, 3, &pts, &inside, &ok),
        Some(MarginError::GridTooSmall { .. })
    ));
    for m in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let s = MarginSettings {
            margin_mm: m,
            band_mm: 1.0,
        };
        assert!(matches!(
            eval(4, 4, &pts, &inside, &s),
            Some(MarginError::BadMargin(_))
        ));
    }
    for b in [-1e-9, f64::NAN, f64::INFINITY] {
        let s = MarginSettings {
            margin_mm: 1.0,
            band_mm: b,
        };
        assert!(matches!(
            eval(4, 4, &pts, &inside, &s),
            Some(MarginError::BadBand(_))
        ));
    }
    // Messages name the quantity.
    assert!(MarginError::BadBand(-1.0).to_string().contains("band"));
    assert!(MarginError::BadSpacing(0.0).to_string().contains("spacing"));
}

fn new_field(mesh: &TriMesh) -> MarginField {
    field_around(mesh, 5.0, 1.0)
}

#[test]
fn minimum_between_samples_beats_a_vertex_minimum_elsewhere() {
    // 40×40 samples are 60/39 mm apart. Sphere A touches 6.02 mm under a sample; sphere B comes
    // to 6.00 mm under the middle of a cell, where the nearest samples read ≈ 6.037 mm. The best
    // sample lies over A, the true minimum over B.
    let h = 60.0 / 39.0;
    let foot_a = Vec3::new(-30.0 + 26.0 * h, -30.0 + 19.0 * h, D);
    let foot_b = Vec3::new(-30.0 + 12.5 * h, -30.0 + 19.5 * h, D);
    let a = icosphere(foot_a - Vec3::new(0.0, 0.0, 6.02 + R), R, 5).unwrap();
    let b = icosphere(foot_b - Vec3::new(0.0, 0.0, 6.0 + R), R, 5).unwrap();
    let r_in = inscribed_radius(&b, &(foot_b - Vec3::new(0.0, 0.0, 6.0 + R))).unwrap();
    let mesh = TriMesh::concat(&[a, b]).unwrap();
    let field = MarginField::new(
        &mesh,
        Vec3::new(-32.0, -32.0, -20.0),
        Vec3::new(32.0, 32.0, 20.0),
        2.0,
    )
    .unwrap();
    let plane = Plane::new(D, Vec3::new(0.0, 0.0, D), 100.0);
    let settings = MarginSettings {
        margin_mm: 5.0,
        band_mm: 0.0,
    };
    let (margins, verdict) = run(&field, &plane, 40, &settings);
    let best_vertex = (0..margins.distance.len())
        .min_by(|&i, &j| margins.distance[i].total_cmp(&margins.distance[j]))
        .unwrap();
    assert_eq!(best_vertex, 26 * 40 + 19);
    let min = verdict.min_margin_mm.unwrap();
    assert!(min >= 6.0 - 1e-9 && min <= 6.0 + (R - r_in) + 1e-3, "{min}");
    assert!((verdict.point.unwrap() - foot_b).norm() <= 0.5);
    assert!(!verdict.violation && verdict.violating_area_mm2 == 0.0);
}

#[test]
fn a_drag_reusing_distances_keeps_classes_verdict_and_tolerances() {
    let (mesh, _) = tumour();
    let field = tumour_field(&mesh);
    let mut plane = Plane::new(D, Vec3::new(0.0, 0.0, D), 35.0);
    let settings = MarginSettings {
        margin_mm: 10.0,
        band_mm: 2.0,
    };
    let w = settings.margin_mm + settings.band_mm;
    let n = 40;
    let (mut memo, mut live) = (MarginMemo::default(), SurfaceMargins::default());
    let mut rng = Rng(11);
    let (mut reused, mut total) = (0, 0);
    for step in 0..60 {
        // Small drag steps of an inner control point, now and then a jump.
        let [x, y, z] = plane.net.get(1, 2).unwrap();
        let len = if step % 17 == 16 {
            20.0
        } else {
            0.2 + 1.3 * rng.unit()
        };
        let d = rng.direction() * len;
        plane.net.set(1, 2, [x + d.x, y + d.y, z + d.z]).unwrap();
        let (points, inside) = plane.sample(n);
        let (fresh, expected) =
            evaluate(&field, n, n, &points, &inside, &settings, &plane).unwrap();
        let verdict = evaluate_reusing(
            &field, n, n, &points, &inside, &settings, &plane, &mut memo, &mut live,
        )
        .unwrap();
        assert_eq!(live.class, fresh.class, "step {step}");
        let mut exact = vec![0.0; points.len()];
        field.distances_into(&points, &mut exact).unwrap();
        for k in 0..points.len() {
            let (d, e) = (live.distance[k], exact[k]);
            if inside[k] <= 0.0 {
                assert!(
                    (d - e).abs() <= OUTSIDE_TOLERANCE_MM + 1e-9,
                    "{step} {k}: {d} vs {e}"
                );
            } else if e > w {
                assert!(
                    (d - e).abs() <= FAR_TOLERANCE_MM + 1e-9,
                    "{step} {k}: {d} vs {e}"
                );
            } else {
                assert!(
                    d >= e - 1e-9 && d <= e + TOLERANCE_MM + 1e-9,
                    "{step} {k}: {d} vs {e}"
                );
            }
        }
        let (got, want) = (
            verdict.min_margin_mm.unwrap(),
            expected.min_margin_mm.unwrap(),
        );
        assert!((got - want).abs() < 1e-6, "step {step}: {got} vs {want}");
        assert_eq!(verdict.violation, expected.violation);
        for (a, b) in [
            (verdict.violating_area_mm2, expected.violating_area_mm2),
            (verdict.warning_area_mm2, expected.warning_area_mm2),
            (verdict.inside_area_mm2, expected.inside_area_mm2),
        ] {
            assert!(
                (a - b).abs() <= 2e-3 * b.max(1.0),
                "step {step}: area {a} vs {b}"
            );
        }
        if step % 17 == 16 {
            assert!(
                memo.reused() < points.len() / 2,
                "a 20 mm jump keeps most samples"
            );
        }
        reused += memo.reused();
        total += points.len();
    }
    assert!(
        reused * 2 > total,
        "only {reused} of {total} samples reused"
    );
}

#[test]
fn a_memo_of_another_field_or_grid_is_not_used() {
    let (mesh, _) = tumour();
    let a = tumour_field(&mesh);
    let moved = icosphere(Vec3::from(TUMOUR) - Vec3::new(0.0, 0.0, 3.0), R, 5).unwrap();
    let b = tumour_field(&moved);
    let plane = Plane::new(D, Vec3::new(0.0, 0.0, D), 35.0);
    let settings = MarginSettings {
        margin_mm: 10.0,
        band_mm: 2.0,
    };
    let (mut memo, mut out) = (MarginMemo::default(), SurfaceMargins::default());
    let (points, inside) = plane.sample(30);
    let mut eval = |field: &MarginField, n: usize, points: &[Vec3], inside: &[f64]| {
        evaluate_reusing(
            field, n, n, points, inside, &settings, &plane, &mut memo, &mut out,
        )
        .unwrap();
        (memo.reused(), out.clone())
    };
    assert_eq!(eval(&a, 30, &points, &inside).0, 0, "an empty memo");
    let again = eval(&a, 30, &points, &inside).0;
    assert!(
        again > 0 && again < 30 * 30,
        "unmoved far and outside samples: {again}"
    );
    let (reused, got) = eval(&b, 30, &points, &inside);
    assert_eq!(reused, 0, "another field's distances");
    assert_eq!(
        got.class,
        evaluate(&b, 30, 30, &points, &inside, &settings, &plane)
            .unwrap()
            .0
            .class
    );
    let (points, inside) = plane.sample(31);
    assert_eq!(eval(&b, 31, &points, &inside).0, 0, "another grid");
}

#[test]
fn unwanted_samples_are_left_as_they_were() {
    let (mesh, _) = tumour();
    let field = field_around(&mesh, 30.0, 2.0);
    let plane = Plane::new(D, Vec3::new(0.0, 0.0, D), 35.0);
    let n = 37;
    let (points, _) = plane.sample(n);
    let mut exact = vec![0.0; n * n];
    field
        .distances_grid_into(n, n, &points, &mut exact)
        .unwrap();
    // Every third sample wanted (the sparse walk), then all but every third (the blocks).
    for wanted in [
        |k: usize| k.is_multiple_of(3),
        |k: usize| !k.is_multiple_of(3),
    ] {
        let mut out = vec![-1.0; n * n];
        let tolerance = |k: usize| if wanted(k) { 0.0 } else { f64::INFINITY };
        field
            .distances_grid_within(n, n, &points, tolerance, &mut out)
            .unwrap();
        for k in 0..n * n {
            let expected = if wanted(k) { exact[k] } else { -1.0 };
            assert!(
                (out[k] - expected).abs() <= 1e-12,
                "{k}: {} vs {expected}",
                out[k]
            );
        }
    }
}

#[test]
fn exact_distances_from_elsewhere_give_the_same_classes_and_verdict() {
    let (mesh, _) = tumour();
    let field = tumour_field(&mesh);
    let plane = Plane::new(D, Vec3::new(0.0, 0.0, D), 35.0);
    let settings = MarginSettings {
        margin_mm: 10.0,
        band_mm: 2.0,
    };
    for n in [23, 80] {
        let (margins, verdict) = run(&field, &plane, n, &settings);
        let (points, inside) = plane.sample(n);
        let mut exact = SurfaceMargins {
            distance: vec![0.0; n * n],
            class: Vec::new(),
        };
        field.distances_into(&points, &mut exact.distance).unwrap();
        let v = evaluate_exact_into(
            &field, n, n, &points, &inside, &settings, &plane, &mut exact,
        )
        .unwrap();
        assert_eq!(exact.class, margins.class, "{n}");
        // The same minimum; areas differ only through far samples' tolerant distances, which
        // move the clipped lines of cells next to them a little.
        let areas = |v: &Verdict| [v.violating_area_mm2, v.warning_area_mm2, v.inside_area_mm2];
        let same = Verdict {
            violating_area_mm2: v.violating_area_mm2,
            warning_area_mm2: v.warning_area_mm2,
            ..verdict.clone()
        };
        assert_eq!(v, same, "{n}");
        for (a, b) in areas(&v).into_iter().zip(areas(&verdict)) {
            assert!((a - b).abs() <= 0.01 * b, "{n}: areas {a} vs {b}");
        }
        for (a, b) in exact.distance.iter().zip(&margins.distance) {
            assert!(
                b - a <= FAR_TOLERANCE_MM && a - b <= 1e-12,
                "{n}: {a} vs {b}"
            );
        }
        // Too few distances is an error naming them; the classes are left alone.
        exact.distance.pop();
        let before = exact.class.clone();
        let e = evaluate_exact_into(
            &field, n, n, &points, &inside, &settings, &plane, &mut exact,
        )
        .unwrap_err();
        assert!(e.to_string().contains("distances"), "{e}");
        assert_eq!(exact.class, before);
    }
}
