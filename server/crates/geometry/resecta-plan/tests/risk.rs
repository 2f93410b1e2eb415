//! Risk analysis through the planner: an ellipsoid liver with a portal Y and a hepatic vein,
//! cut by Bézier planes, against the exact answer of the tubes' axes.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::{Arc, OnceLock};

use resecta_geom::{Real, Role, RoleMap, Vec3};
use resecta_phantom::{VesselSpec, generate};
use resecta_plan::{Anatomy, Plan, PlanEvent, Planner, Resection, Vascular, VolumeReport};

mod common;

const JUNCTION: [Real; 3] = [0.0, 0.0, -25.0];
const LEFT_END: [Real; 3] = [-40.0, 0.0, -10.0];
const RIGHT_END: [Real; 3] = [40.0, 0.0, -10.0];

fn spec() -> resecta_phantom::PhantomSpec {
    let mut s = common::spec();
    s.vessels = vec![
        VesselSpec {
            role: Role::Portal,
            radius: 4.0,
            points: vec![[0.0, 0.0, -38.0], JUNCTION, RIGHT_END],
        },
        VesselSpec {
            role: Role::Portal,
            radius: 3.5,
            points: vec![JUNCTION, LEFT_END],
        },
        VesselSpec {
            role: Role::Hepatic,
            radius: 3.5,
            points: vec![[0.0, 5.0, 38.0], [0.0, 5.0, 20.0]],
        },
    ];
    s
}

fn anatomy() -> Arc<Anatomy> {
    static A: OnceLock<Arc<Anatomy>> = OnceLock::new();
    A.get_or_init(|| {
        let p = generate(&spec()).unwrap();
        Arc::new(Anatomy::new(&p.labels, &RoleMap::default()).unwrap())
    })
    .clone()
}

/// The Bézier plane x = `x0` (4×4, ±70 mm).
fn plane_x(x0: Real) -> Resection {
    let pts = (0..16)
        .map(|k| {
            let (i, j) = ((k / 4) as Real / 3.0, (k % 4) as Real / 3.0);
            [x0, -70.0 + 140.0 * i, -70.0 + 140.0 * j]
        })
        .collect();
    Resection::new("r", [4, 4], pts)
}

fn volumes(r: Resection) -> VolumeReport {
    let mut plan = Plan::new(RoleMap::default());
    plan.apply(&PlanEvent::AddResection { resection: r })
        .unwrap();
    Planner::new(anatomy(), plan).unwrap().volumes().unwrap()
}

fn project(p: Vec3, a: [Real; 3], b: [Real; 3]) -> (Real, Real) {
    let (a, b) = (Vec3::from(a), Vec3::from(b));
    let d = (b - a).normalize();
    let t = (p - a).dot(&d).clamp(0.0, (b - a).norm());
    (t, (a + d * t - p).norm())
}

#[test]
fn cutting_the_right_branch_devascularises_its_remnant_cell() {
    assert!(matches!(anatomy().vascular(), Vascular::Ready(_)));
    let x0 = 12.0;
    let v = volumes(plane_x(x0));
    let risk = v.risk.as_ref().expect("risk with vessels");
    assert!(risk.has_portal && risk.has_hepatic);
    let remnant = v.remnant_ml.unwrap();
    // One cut: the right branch, at x = x0 on its axis.
    assert_eq!(risk.cut_vessels.len(), 1, "{:?}", risk.cut_vessels);
    let c = &risk.cut_vessels[0];
    assert_eq!((c.system, c.resection.as_str()), ("portal", "r"));
    let (dir, len) = {
        let d = Vec3::from(RIGHT_END) - Vec3::from(JUNCTION);
        (d.normalize(), d.norm())
    };
    let want = Vec3::from(JUNCTION) + dir * (x0 / dir.x);
    assert!((Vec3::from(c.point) - want).norm() < 2.5, "{:?}", c.point);
    assert!((c.uv[0] - (x0 + 70.0) / 140.0).abs() < 0.02 || (c.uv[1] - 0.5).abs() < 0.5);
    assert!(c.uv.iter().all(|u| (0.0..=1.0).contains(u)));
    // The exact cell: functional voxels left of the plane whose nearest axis point is on the
    // right branch beyond the cut.
    let p = generate(&spec()).unwrap();
    let grid = p.labels.grid().clone();
    let functional = anatomy().functional().clone();
    let t_cut = x0 / dir.x;
    let mut exact = 0usize;
    for (o, &f) in functional.data().iter().enumerate() {
        let q = grid.voxel_center(grid.ijk(o));
        if !f || q.x >= x0 {
            continue;
        }
        let (tr, dr) = project(q, JUNCTION, RIGHT_END);
        let dl = project(q, JUNCTION, LEFT_END).1;
        let dt = project(q, [0.0, 0.0, -38.0], JUNCTION).1;
        if dr < dl && dr < dt && tr > t_cut && tr <= len {
            exact += 1;
        }
    }
    let exact_ml = exact as Real * grid.voxel_volume_mm3() / 1000.0;
    println!(
        "devascularised {:.2} ml (axes {exact_ml:.2}), remnant {remnant:.1}, functional {:.1}",
        risk.devascularised_ml, risk.functional_remnant_ml
    );
    assert!(exact_ml > 3.0);
    assert!((risk.devascularised_ml - exact_ml).abs() < 0.2 * exact_ml);
    assert_eq!(risk.congested_ml, 0.0);
    assert!((risk.functional_remnant_ml - (remnant - risk.at_risk_ml)).abs() < 1e-9);
    assert!(
        (risk.functional_remnant_pct - 100.0 * risk.functional_remnant_ml / v.total_ml).abs()
            < 1e-9
    );
    assert_eq!(
        v.flr_warning,
        Some(risk.functional_remnant_pct < v.flr_threshold_pct)
    );
    let json = serde_json::to_value(&v).unwrap();
    assert!(json["devascularised_ml"].as_f64().unwrap() > 0.0);
    assert_eq!(json["cut_vessels"][0]["system"], "portal");
}

#[test]
fn a_cut_that_crosses_no_vessel_puts_nothing_at_risk() {
    let v = volumes(plane_x(47.0));
    let risk = v.risk.as_ref().unwrap();
    assert!(risk.cut_vessels.is_empty());
    assert_eq!(risk.at_risk_ml, 0.0);
    assert!((risk.functional_remnant_ml - v.remnant_ml.unwrap()).abs() < 1e-9);
}

#[test]
fn without_vessel_roles_there_is_no_risk_analysis() {
    let v = {
        let mut plan = Plan::new(RoleMap::default());
        plan.apply(&PlanEvent::AddResection {
            resection: plane_x(12.0),
        })
        .unwrap();
        Planner::new(common::anatomy(), plan)
            .unwrap()
            .volumes()
            .unwrap()
    };
    assert!(v.risk.is_none() && v.risk_unavailable.is_none());
    let json = serde_json::to_value(&v).unwrap();
    assert!(json.get("devascularised_ml").is_none());
}

#[test]
fn the_resectogram_unrolls_the_cut_with_its_liver_boundary_vessel_and_worst_point() {
    let mut plan = Plan::new(RoleMap::default());
    plan.apply(&PlanEvent::AddResection {
        resection: plane_x(12.0),
    })
    .unwrap();
    let p = Planner::new(anatomy(), plan).unwrap();
    let g = p.resectogram("r", 200, 160).unwrap();
    assert_eq!(
        (g.classes.len(), g.territories.len()),
        (200 * 160, 200 * 160)
    );
    // The liver's section by x = 12: an ellipse of semi-axes 45·√(1 − 0.2²) and 40·√(1 − 0.2²)
    // on the 140 × 140 mm square.
    let inside = g.classes.iter().filter(|&&c| c > 0).count() as Real / g.classes.len() as Real;
    let want = std::f64::consts::PI * 45.0 * 40.0 * (1.0 - 0.04) / (140.0 * 140.0);
    println!("inside fraction {inside:.4} (ellipse {want:.4})");
    assert!((inside - want).abs() < 0.01, "{inside} vs {want}");
    // The tumour is 3 mm from the plane: a violation around (y, z) = (0, 0), the worst point.
    assert!(g.classes.contains(&3));
    let w = g.worst_uv.unwrap();
    assert!(
        (w[0] - 0.5).abs() < 0.03 && (w[1] - 0.5).abs() < 0.03,
        "{w:?}"
    );
    assert!((g.min_margin_mm.unwrap() - 3.0).abs() < 1.0);
    // The right branch is cut at z ≈ −19.7: (u, v) ≈ (0.5, 0.36), in its own territory.
    assert_eq!(g.cut_vessels.len(), 1);
    let c = &g.cut_vessels[0];
    assert!(
        (c.uv[0] - 0.5).abs() < 0.03 && (c.uv[1] - (50.3 / 140.0)).abs() < 0.03,
        "{c:?}"
    );
    let (i, j) = ((c.uv[0] * 200.0) as usize, (c.uv[1] * 160.0) as usize);
    assert_eq!(g.territories[j * 200 + i], c.branch as u32 + 1);
    assert!(g.territories.iter().all(|&t| t == 0 || t as usize <= 3));
    // Outside the liver there is no territory.
    assert!(
        g.classes
            .iter()
            .zip(&g.territories)
            .all(|(&c, &t)| c > 0 || t == 0)
    );
    let (pw, ph, rgba) = g.to_rgba(2);
    assert_eq!((pw, ph, rgba.len()), (400, 320, 400 * 320 * 4));
    // Bad sizes and names are refused.
    assert!(p.resectogram("r", 0, 10).is_err());
    assert!(p.resectogram("r", 10, 513).is_err());
    assert!(p.resectogram("nope", 10, 10).is_err());
}

#[test]
fn the_risk_map_agrees_with_the_report() {
    let mut plan = Plan::new(RoleMap::default());
    plan.apply(&PlanEvent::AddResection {
        resection: plane_x(12.0),
    })
    .unwrap();
    let mut p = Planner::new(anatomy(), plan).unwrap();
    let m = p.risk_map().unwrap().unwrap();
    let v = p.volumes().unwrap();
    assert_eq!(Some(&m.report), v.risk.as_ref());
    let ml = m.grid.voxel_volume_mm3() / 1000.0;
    let count = |c: u8| m.classes.iter().filter(|&&k| k == c).count() as Real * ml;
    use resecta_plan::risk_class::*;
    let (dev, res, fun) = (count(DEVASCULARISED), count(RESECTED), count(FUNCTIONAL));
    println!("map: devascularised {dev:.2} ml, resected {res:.1}, functional {fun:.1}");
    // Voxels are whole in the map, fractional in the report: within the cut's band.
    assert!((dev - m.report.devascularised_ml).abs() < 0.1 * m.report.devascularised_ml);
    assert!((res - v.resected_ml.unwrap()).abs() < 0.02 * v.resected_ml.unwrap());
    assert!((fun - m.report.functional_remnant_ml).abs() < 0.02 * m.report.functional_remnant_ml);
    assert_eq!(count(CONGESTED) + count(BOTH), 0.0);
    // Every functional-liver voxel has a territory, no other voxel has one.
    assert!(
        m.classes
            .iter()
            .zip(&m.territories)
            .all(|(&c, &t)| (c == NONE) == (t == 0))
    );
    // The crop is the functional liver's box: the total is the liver.
    let liver = m.classes.iter().filter(|&&c| c != NONE).count() as Real * ml;
    assert!((liver - v.total_ml).abs() < 1e-6 * v.total_ml);
}
