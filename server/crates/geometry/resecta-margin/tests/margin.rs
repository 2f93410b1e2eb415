//! Exactness against brute force and analytic spheres, the verdict on a plane beside a
//! spherical tumour, and bad input.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::f64::consts::PI;

use proptest::prelude::*;
use resecta_bezier::{ControlNet, MleEvaluator, Outputs, Resolution, eval_point};
use resecta_geom::bvh::closest_point_on_triangle;
use resecta_geom::primitives::{ellipsoid, icosphere, inscribed_radius};
use resecta_geom::{Mat3, Real, TriMesh, Vec3};
use resecta_margin::{
    MarginClass, MarginError, MarginField, MarginSettings, SurfaceOracle, TOLERANCE_MM, evaluate,
};

fn brute(mesh: &TriMesh, p: &Vec3) -> Real {
    (0..mesh.triangles().len())
        .map(|t| (p - closest_point_on_triangle(p, &mesh.corners(t)).point).norm())
        .fold(Real::INFINITY, Real::min)
}

fn meshes() -> Vec<TriMesh> {
    let two = TriMesh::concat(&[
        icosphere(Vec3::new(-12.0, 0.0, 0.0), 8.0, 3).unwrap(),
        icosphere(Vec3::new(12.0, 0.0, 0.0), 8.0, 3).unwrap(),
    ])
    .unwrap();
    vec![
        icosphere(Vec3::new(1.0, 2.0, 3.0), 10.0, 3).unwrap(),
        ellipsoid(
            Vec3::zeros(),
            Vec3::new(15.0, 9.0, 6.0),
            Mat3::identity(),
            3,
        )
        .unwrap(),
        two,
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    /// Near and far, inside and outside, the answer equals brute force.
    #[test]
    fn nearest_equals_brute_force(
        which in 0usize..3,
        pts in prop::collection::vec(prop::array::uniform3(-70.0..70.0f64), 1..24),
    ) {
        let mesh = &meshes()[which];
        let field = MarginField::new(mesh).unwrap();
        let points: Vec<Vec3> = pts.iter().map(|p| Vec3::from(*p)).collect();
        let mut out = vec![field.nearest(&Vec3::zeros()); points.len()];
        field.nearest_into(&points, &mut out).unwrap();
        for (p, q) in points.iter().zip(&out) {
            let want = brute(mesh, p);
            // Batch answers: within the tolerance above exact, with a true lower bound.
            prop_assert!(q.distance >= want - 1e-9 && q.distance <= want + TOLERANCE_MM + 1e-9,
                "{p:?}: {} vs {want}", q.distance);
            prop_assert!(q.lower <= want + 1e-9 && q.lower >= q.distance - TOLERANCE_MM - 1e-9);
            prop_assert!(((p - q.point).norm() - q.distance).abs() < 1e-9);
            // Single answers are exact.
            prop_assert!((field.nearest(p).distance - want).abs() <= 1e-9);
            prop_assert!((field.exact_from(p, *q).distance - want).abs() <= 1e-9);
        }
    }

    /// Coherent batches (samples along a curve, as on a resection surface) take the fast path.
    #[test]
    fn coherent_batches_are_within_tolerance(
        which in 0usize..3,
        start in prop::array::uniform3(-60.0..60.0f64),
        step in prop::array::uniform3(-1.5..1.5f64),
    ) {
        let mesh = &meshes()[which];
        let field = MarginField::new(mesh).unwrap();
        let points: Vec<Vec3> = (0..80)
            .map(|k| Vec3::from(start) + Vec3::from(step) * k as Real + Vec3::new(0.0, (k as Real * 0.2).sin() * 5.0, 0.0))
            .collect();
        let mut out = vec![field.nearest(&Vec3::zeros()); points.len()];
        field.nearest_into(&points, &mut out).unwrap();
        for (p, q) in points.iter().zip(&out) {
            let want = brute(mesh, p);
            prop_assert!(q.distance >= want - 1e-9 && q.distance <= want + TOLERANCE_MM + 1e-9);
            prop_assert!(q.lower <= want + 1e-9);
        }
    }
}

#[test]
fn distances_to_a_sphere_are_within_the_tessellation_bound() {
    let c = Vec3::new(3.0, -4.0, 5.0);
    let r = 12.0;
    let mesh = icosphere(c, r, 5).unwrap();
    let r_in = inscribed_radius(&mesh, &c).unwrap();
    assert!(r - r_in < 0.01);
    let field = MarginField::new(&mesh).unwrap();
    for k in 0..200 {
        let t = k as Real * 0.7;
        let dir = Vec3::new(t.sin() * (2.0 * t).cos(), t.cos(), (3.0 * t).sin()).normalize();
        let p = c + dir * (r + 0.1 * k as Real);
        let d = field.nearest(&p).distance;
        let (lo, hi) = ((p - c).norm() - r, (p - c).norm() - r_in);
        assert!(d >= lo - 1e-9 && d <= hi + 1e-9, "{d} not in [{lo}, {hi}]");
    }
}

/// A planar 4×4 patch x = x0, y, z ∈ [−half, half]; the liver is a ball of radius 60.
struct Patch {
    net: ControlNet<Real>,
}

impl Patch {
    fn new(x0: Real, half: Real) -> Self {
        let net = ControlNet::planar(
            4,
            4,
            [x0, -half, -half],
            [0.0, 2.0 * half, 0.0],
            [0.0, 0.0, 2.0 * half],
        )
        .unwrap();
        Self { net }
    }
    fn sample(&self, res: usize) -> Vec<Vec3> {
        let mut e = MleEvaluator::new(self.net.clone(), Resolution::new(res, res).unwrap());
        e.evaluate(Outputs::Points)
            .points()
            .iter()
            .map(|p| Vec3::new(p[0], p[1], p[2]))
            .collect()
    }
}

impl SurfaceOracle for Patch {
    fn point(&self, u: Real, v: Real) -> Vec3 {
        let p = eval_point(&self.net, u, v).point;
        Vec3::new(p[0], p[1], p[2])
    }
    fn inside(&self, p: &Vec3) -> Real {
        60.0 - p.norm()
    }
}

#[test]
fn plane_beside_a_sphere_gives_the_exact_minimum_and_areas() {
    // Tumour: sphere of radius R at (d, 3, −2) with the plane x = 0: min margin d − R at the
    // foot (0, 3, −2), i.e. u = (3 + 40)/80, v = (−2 + 40)/80 on an 80 mm patch.
    let (d, big_r, m, band) = (25.0, 10.0, 18.0, 4.0);
    let centre = Vec3::new(d, 3.0, -2.0);
    let mesh = icosphere(centre, big_r, 6).unwrap();
    let r_in = inscribed_radius(&mesh, &centre).unwrap();
    let field = MarginField::new(&mesh).unwrap();
    let patch = Patch::new(0.0, 40.0);
    let settings = MarginSettings {
        margin_mm: m,
        band_mm: band,
    };
    let mut last_err = Real::INFINITY;
    for res in [40usize, 100, 200] {
        let pts = patch.sample(res);
        let inside: Vec<Real> = pts.iter().map(|p| patch.inside(p)).collect();
        let (margins, v) = evaluate(&field, res, res, &pts, &inside, &settings, &patch).unwrap();
        let min = v.min_margin_mm.unwrap();
        // The exact answer for the tessellated sphere lies in [d − R, d − r_in].
        assert!(
            min >= d - big_r - 1e-9 && min <= d - r_in + 0.01,
            "{res}: {min}"
        );
        let [u, w] = v.uv.unwrap();
        assert!(
            (u - 0.5375).abs() < 2e-3 && (w - 0.475).abs() < 2e-3,
            "{res}: {u} {w}"
        );
        assert!((v.point.unwrap() - Vec3::new(0.0, 3.0, -2.0)).norm() < 0.2);
        assert!(v.violation);
        // Violating disc: radius √((R + m)² − d²); warning ring out to √((R + m + band)² − d²).
        let area = PI * ((big_r + m).powi(2) - d * d);
        let warn = PI * ((big_r + m + band).powi(2) - d * d) - area;
        let err = (v.violating_area_mm2 - area).abs() / area;
        if res == 200 {
            assert!(err < 0.01, "violating {} vs {area}", v.violating_area_mm2);
            assert!(
                (v.warning_area_mm2 - warn).abs() / warn < 0.01,
                "warning {}",
                v.warning_area_mm2
            );
        }
        assert!(err <= last_err + 1e-3, "area error grows with resolution");
        last_err = err;
        // Inside area: the 80×80 patch lies wholly within the ball of radius 60.
        assert!((v.inside_area_mm2 - 6400.0).abs() < 1e-6);
        let viol = margins
            .class
            .iter()
            .filter(|&&c| c == MarginClass::Violation)
            .count();
        assert!(viol > 0 && margins.class.iter().all(|&c| c != MarginClass::Outside));
    }
}

#[test]
fn outside_the_liver_does_not_count() {
    // The tumour sits at the patch's corner region, which is outside the liver ball: the
    // minimum comes from the inside part only.
    let centre = Vec3::new(12.0, 70.0, 70.0);
    let mesh = icosphere(centre, 5.0, 3).unwrap();
    let field = MarginField::new(&mesh).unwrap();
    let patch = Patch::new(0.0, 80.0);
    let pts = patch.sample(60);
    let inside: Vec<Real> = pts.iter().map(|p| patch.inside(p)).collect();
    let settings = MarginSettings {
        margin_mm: 10.0,
        band_mm: 0.0,
    };
    let (margins, v) = evaluate(&field, 60, 60, &pts, &inside, &settings, &patch).unwrap();
    let min = v.min_margin_mm.unwrap();
    let p = v.point.unwrap();
    assert!(patch.inside(&p) > 0.0);
    // Nearest inside point: on the circle of radius 60 towards the tumour's (y, z).
    let dir = Vec3::new(0.0, 1.0, 1.0).normalize();
    let want = (dir * 60.0 - centre).norm() - 5.0;
    assert!((min - want).abs() < 0.05, "{min} vs {want}");
    let all_min = margins
        .distance
        .iter()
        .copied()
        .fold(Real::INFINITY, Real::min);
    assert!(
        all_min < min,
        "an outside vertex is nearer but must not count"
    );
    assert!(margins.class.contains(&MarginClass::Outside));
    assert!(!v.violation);
    // Nothing inside: no minimum.
    let none = vec![-1.0; pts.len()];
    let (_, v) = evaluate(&field, 60, 60, &pts, &none, &settings, &patch).unwrap();
    assert_eq!(v.min_margin_mm, None);
    assert_eq!(v.inside_area_mm2, 0.0);
}

#[test]
fn bad_input_is_refused() {
    let mesh = icosphere(Vec3::zeros(), 5.0, 1).unwrap();
    let empty = TriMesh::new(vec![], vec![]).unwrap();
    assert!(matches!(
        MarginField::new(&empty),
        Err(MarginError::EmptyMesh)
    ));
    let nan = Vec3::new(Real::NAN, 0.0, 0.0);
    let field = MarginField::new(&mesh).unwrap();
    assert!(field.nearest(&nan).distance.is_infinite());
    let patch = Patch::new(0.0, 5.0);
    let pts = patch.sample(4);
    let ins = vec![1.0; 16];
    let ok = MarginSettings {
        margin_mm: 1.0,
        band_mm: 0.0,
    };
    assert!(matches!(
        evaluate(&field, 4, 5, &pts, &ins, &ok, &patch),
        Err(MarginError::Length { .. })
    ));
    assert!(matches!(
        evaluate(&field, 4, 4, &pts, &ins[..3], &ok, &patch),
        Err(MarginError::Length { .. })
    ));
    assert!(matches!(
        evaluate(&field, 1, 16, &pts, &ins, &ok, &patch),
        Err(MarginError::Grid { .. })
    ));
    for (m, b) in [
        (0.0, 0.0),
        (-1.0, 0.0),
        (Real::NAN, 0.0),
        (1.0, -0.5),
        (1.0, Real::INFINITY),
    ] {
        let s = MarginSettings {
            margin_mm: m,
            band_mm: b,
        };
        assert!(matches!(
            evaluate(&field, 4, 4, &pts, &ins, &s, &patch),
            Err(MarginError::Setting { .. })
        ));
    }
    let mut out = vec![field.nearest(&Vec3::zeros()); 3];
    assert!(field.nearest_into(&pts, &mut out).is_err());
}
