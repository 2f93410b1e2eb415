//! Risk analysis on a Y tree in a box liver, against the exact answer of the tubes' axes.
#![allow(clippy::unwrap_used)] // test helpers

use resecta_geom::{Mat3, MeshBvh, TriMesh, Vec3};
use resecta_vessels::{
    Crossing, RiskModel, RootChoice, VesselError, VesselParams, VesselSystem, VesselTree,
    vessel_tree,
};

mod common;
use common::*;

/// A square patch of the plane through `p` with unit normal `n`, `half` mm from `p` each way.
fn plane(p: Vec3, n: Vec3, half: f64) -> MeshBvh {
    let a = if n.x.abs() < 0.9 {
        Vec3::x()
    } else {
        Vec3::y()
    };
    let u = n.cross(&a).normalize() * half;
    let v = n.cross(&u).normalize() * half;
    let mesh = TriMesh::new(
        vec![p - u - v, p + u - v, p + u + v, p - u + v],
        vec![[0, 1, 2], [0, 2, 3]],
    )
    .unwrap();
    MeshBvh::new(&mesh).unwrap()
}

struct Setup {
    case: YCase,
    tree: VesselTree,
    /// Liver voxel offsets and centres.
    liver: Vec<usize>,
    centres: Vec<Vec3>,
}

fn setups() -> Vec<Setup> {
    y_cases()
        .into_iter()
        .map(|case| {
            let tree = case.tree();
            let (liver, centres): (Vec<usize>, Vec<Vec3>) = (0..case.grid.len())
                .map(|o| (o, case.grid.voxel_center(case.grid.ijk(o))))
                .filter(|(_, p)| in_box(*p, case.lo, case.hi))
                .unzip();
            Setup {
                case,
                tree,
                liver,
                centres,
            }
        })
        .collect()
}

/// Parameter of `p` projected on the segment `(a, b)` (mm from `a`), and its distance to it.
fn project(p: Vec3, (a, b, _): (Vec3, Vec3, f64)) -> (f64, f64) {
    let d = (b - a).normalize();
    let t = (p - a).dot(&d).clamp(0.0, (b - a).norm());
    (t, (a + d * t - p).norm())
}

/// Exact devascularisation by a cut of the left branch at arc `cut` mm: the voxel's nearest
/// axis point is on the left branch, beyond the cut.
fn exact_lost(y: &Y, p: Vec3, cut: f64) -> bool {
    let (tl, dl) = project(p, y.left);
    let dr = project(p, y.right).1;
    let dt = project(p, y.trunk).1;
    dl < dr && dl < dt && tl > cut
}

/// The plane x = −c cuts the left branch only; the remnant is x > −c.
#[test]
fn cutting_one_branch_loses_its_cell_beyond_the_cut_and_nothing_else() {
    for s in setups() {
        let c = 5.0;
        let model = RiskModel::new(
            &s.case.grid,
            &s.liver,
            vec![(VesselSystem::Portal, s.tree.clone())],
            None,
        )
        .unwrap();
        let cut = plane(Vec3::new(-c, 0.0, 0.0), Vec3::x(), 60.0);
        let (lo, hi) = (s.case.lo, s.case.hi);
        let inside = move |c: &Crossing| in_box(c.point, lo, hi);
        let crossings = model.crossings(&[&cut], &inside);
        assert_eq!(crossings.len(), 1, "{crossings:?}");
        let x = crossings[0];
        let (sn, cs) = 0.7f64.sin_cos();
        let want = Vec3::new(-c, 0.0, c * cs / sn);
        let d = diag(&s.case.grid);
        assert!((x.point - want).norm() < d, "{:?} vs {want:?}", x.point);
        let edge = &s.tree.edges[x.edge];
        assert!((s.tree.nodes[edge.to].position - s.case.y.left.1).norm() < 2.0 * d + 2.4);
        let remnant: Vec<f32> = s
            .centres
            .iter()
            .map(|p| f32::from(u8::from(p.x > -c)))
            .collect();
        let risk = model.assess(&crossings, &remnant).unwrap();
        let vox = s.case.grid.voxel_volume_mm3();
        let exact: Vec<bool> = s
            .centres
            .iter()
            .map(|&p| p.x > -c && exact_lost(&s.case.y, p, c / sn))
            .collect();
        let exact_mm3 = exact.iter().filter(|&&b| b).count() as f64 * vox;
        let rem_mm3 = remnant.iter().map(|&f| f64::from(f)).sum::<f64>() * vox;
        println!(
            "cut left: devascularised {:.0} mm³ (axes: {exact_mm3:.0}), remnant {rem_mm3:.0}",
            risk.devascularised_mm3
        );
        assert!(exact_mm3 > 500.0);
        // Every voxel classified otherwise than by the axes lies within two voxel diagonals of
        // a boundary of the exact region (a Voronoi bisector or the plane through the cut
        // normal to the branch): the skeleton is medial to within a voxel.
        let lost = model.regions(&crossings).devascularised.unwrap();
        let y = &s.case.y;
        let mut off = 0;
        for ((&p, &e), &l) in s.centres.iter().zip(&exact).zip(&lost) {
            if p.x > -c && e != l {
                off += 1;
                let (tl, dl) = project(p, y.left);
                let other = project(p, y.right).1.min(project(p, y.trunk).1);
                assert!(
                    (dl - other).abs() <= 2.0 * d || (tl - c / sn).abs() <= 2.0 * d,
                    "{p:?}: exact {e}, model {l}"
                );
            }
        }
        // The volumes differ by less than one voxel layer (diagonal thick) along the region's
        // boundaries in the remnant.
        let layer = s
            .centres
            .iter()
            .filter(|&&p| {
                let (tl, dl) = project(p, y.left);
                let other = project(p, y.right).1.min(project(p, y.trunk).1);
                p.x > -c && dl < other + d && (tl - c / sn).abs() <= d / 2.0
                    || p.x > -c && tl > c / sn && (dl - other).abs() <= d / 2.0
            })
            .count() as f64
            * vox;
        println!("{off} voxels differ, all at a boundary; boundary layer {layer:.0} mm³");
        assert!((risk.devascularised_mm3 - exact_mm3).abs() <= layer);
        assert!((risk.remnant_mm3 - rem_mm3).abs() < 1e-6);
        assert_eq!(risk.at_risk_mm3, risk.devascularised_mm3);
        assert_eq!(risk.congested_mm3, 0.0);
        assert!((risk.functional_remnant_mm3 - (rem_mm3 - risk.devascularised_mm3)).abs() < 1e-6);
        assert_eq!(risk.cut.len(), 1);
        assert!(!risk.cut[0].downstream_of_another_cut);
        // Nothing on the right branch's side is lost.
        let right_lost = s
            .centres
            .iter()
            .zip(&remnant)
            .filter(|(p, _)| project(**p, s.case.y.right).1 + d < project(**p, s.case.y.left).1)
            .count();
        assert!(right_lost > 0);
        let only_left = model
            .assess(
                &crossings,
                &s.centres
                    .iter()
                    .map(|p| {
                        let right =
                            project(*p, s.case.y.right).1 + d < project(*p, s.case.y.left).1;
                        f32::from(u8::from(right))
                    })
                    .collect::<Vec<_>>(),
            )
            .unwrap();
        assert_eq!(only_left.devascularised_mm3, 0.0);
    }
}

#[test]
fn no_cut_puts_nothing_at_risk_and_a_cut_outside_the_liver_cuts_nothing() {
    let s = &setups()[0];
    let model = RiskModel::new(
        &s.case.grid,
        &s.liver,
        vec![
            (VesselSystem::Portal, s.tree.clone()),
            (VesselSystem::Hepatic, s.tree.clone()),
        ],
        None,
    )
    .unwrap();
    let all = vec![1.0f32; s.liver.len()];
    let none = model.assess(&[], &all).unwrap();
    let vox = s.case.grid.voxel_volume_mm3();
    assert_eq!(none.at_risk_mm3, 0.0);
    assert!((none.functional_remnant_mm3 - s.liver.len() as f64 * vox).abs() < 1e-6);
    assert!(none.has_portal && none.has_hepatic && none.cut.is_empty());
    // The trunk is crossed below the box liver: not a cut.
    let (lo, hi) = (s.case.lo, s.case.hi);
    let below = plane(Vec3::new(0.0, 0.0, -8.0), Vec3::z(), 60.0);
    assert!(
        model
            .crossings(&[&below], &|c| in_box(c.point, lo, hi))
            .is_empty()
    );
    // Crossing the trunk inside a liver that holds it disconnects everything downstream.
    let x = model.crossings(&[&below], &|_| true);
    // Territories: the left branch's side, and nothing outside the liver.
    let left = model
        .territory_at(VesselSystem::Portal, &Vec3::new(-12.0, 0.0, 15.0), 2)
        .unwrap();
    let right = model
        .territory_at(VesselSystem::Portal, &Vec3::new(12.0, 0.0, 15.0), 2)
        .unwrap();
    assert_ne!(left, right);
    assert_eq!(s.tree.edges[left].generation, 2);
    // Generation 1 is the trunk, above both.
    let trunk = model.territory_at(VesselSystem::Portal, &Vec3::new(12.0, 0.0, 15.0), 1);
    assert_eq!(trunk, s.tree.edges[left].parent);
    assert!((s.tree.nodes[s.tree.edges[left].to].position - s.case.y.left.1).norm() < 6.0);
    assert_eq!(
        model.territory_at(VesselSystem::Portal, &Vec3::new(0.0, 0.0, -15.0), 2),
        None
    );
    assert_eq!(x.len(), 2, "one per system: {x:?}");
    let trunk = model.assess(&x, &all).unwrap();
    assert!(trunk.devascularised_mm3 > 0.95 * s.liver.len() as f64 * vox);
    assert_eq!(trunk.devascularised_mm3, trunk.congested_mm3);
}

/// A hepatic cut congests exactly what the same portal cut devascularises, and both at once put
/// their union at risk.
#[test]
fn hepatic_cut_congests_only_its_drainage_cell() {
    let s = &setups()[1];
    let model = |systems: &[VesselSystem]| {
        RiskModel::new(
            &s.case.grid,
            &s.liver,
            systems.iter().map(|&k| (k, s.tree.clone())).collect(),
            None,
        )
        .unwrap()
    };
    let cut = plane(Vec3::new(-4.0, 0.0, 0.0), Vec3::x(), 60.0);
    let (lo, hi) = (s.case.lo, s.case.hi);
    let inside = move |c: &Crossing| in_box(c.point, lo, hi);
    let remnant: Vec<f32> = s
        .centres
        .iter()
        .map(|p| f32::from(u8::from(p.x > -4.0)))
        .collect();
    let portal = model(&[VesselSystem::Portal]);
    let hepatic = model(&[VesselSystem::Hepatic]);
    let p = portal
        .assess(&portal.crossings(&[&cut], &inside), &remnant)
        .unwrap();
    let h = hepatic
        .assess(&hepatic.crossings(&[&cut], &inside), &remnant)
        .unwrap();
    assert!(h.congested_mm3 > 0.0);
    assert_eq!(h.devascularised_mm3, 0.0);
    assert_eq!(h.congested_mm3, p.devascularised_mm3);
    assert!(!p.has_hepatic && !h.has_portal);
    let both = model(&[VesselSystem::Portal, VesselSystem::Hepatic]);
    let b = both
        .assess(&both.crossings(&[&cut], &inside), &remnant)
        .unwrap();
    assert_eq!(b.at_risk_mm3, h.congested_mm3);
    assert_eq!(b.cut.len(), 2);
}

/// A cut nearer the root makes a second one downstream redundant, and the lost volume is the
/// proximal cut's.
#[test]
fn cuts_downstream_of_another_are_flagged() {
    let s = &setups()[0];
    let model = RiskModel::new(
        &s.case.grid,
        &s.liver,
        vec![(VesselSystem::Portal, s.tree.clone())],
        None,
    )
    .unwrap();
    let all = vec![1.0f32; s.liver.len()];
    let near = plane(Vec3::new(0.0, 0.0, -3.0), Vec3::z(), 60.0);
    let far = plane(Vec3::new(0.0, 0.0, 12.0), Vec3::z(), 60.0);
    let x = model.crossings(&[&near, &far], &|_| true);
    assert_eq!(x.len(), 3, "trunk, then both branches: {x:?}");
    let r = model.assess(&x, &all).unwrap();
    assert_eq!(
        r.cut.iter().filter(|c| c.downstream_of_another_cut).count(),
        2
    );
    let trunk_only = model.assess(&x[..1], &all).unwrap();
    assert_eq!(r.devascularised_mm3, trunk_only.devascularised_mm3);
}

#[test]
fn every_component_gets_its_own_root() {
    let grid = centred_grid([0.8, 1.0, 1.2], 20.0, Mat3::identity());
    let a = (Vec3::new(-8.0, -14.0, 0.0), Vec3::new(-8.0, 14.0, 0.0), 3.0);
    let b = (Vec3::new(8.0, -14.0, 0.0), Vec3::new(8.0, 12.0, 0.0), 2.0);
    let m = mask(&grid, |p| {
        [a, b].iter().any(|&(s, e, r)| seg_dist(p, s, e) <= r)
    });
    let one = vessel_tree(&m, RootChoice::Auto, &VesselParams::default()).unwrap();
    assert_eq!(one.report.detached_components, 1);
    assert_eq!(one.roots, vec![0]);
    let forest = vessel_tree(&m, RootChoice::EveryComponent, &VesselParams::default()).unwrap();
    assert_eq!(forest.report.detached_components, 0);
    assert_eq!(forest.report.detached_voxels, 0);
    assert_eq!(forest.roots, vec![0, 1]);
    assert_eq!(forest.edges.len(), 2);
    assert!(forest.edges.iter().all(|e| e.parent.is_none()));
    // The wider tube's root comes first.
    assert!((forest.nodes[0].position.x + 8.0).abs() < 2.0);
}

#[test]
fn bad_inputs_give_typed_errors() {
    let s = &setups()[0];
    let trees = || vec![(VesselSystem::Portal, s.tree.clone())];
    assert_eq!(
        RiskModel::new(&s.case.grid, &[], trees(), None).unwrap_err(),
        VesselError::EmptyLiver
    );
    assert_eq!(
        RiskModel::new(&s.case.grid, &[s.case.grid.len()], trees(), None).unwrap_err(),
        VesselError::GridMismatch
    );
    let model = RiskModel::new(&s.case.grid, &s.liver, trees(), None).unwrap();
    assert!(matches!(
        model.assess(&[], &[1.0]),
        Err(VesselError::InvalidParameter { .. })
    ));
}
