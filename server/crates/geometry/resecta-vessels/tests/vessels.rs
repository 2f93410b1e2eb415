//! Analytic checks on synthetic tube trees in a box liver, on anisotropic and oblique grids.
#![allow(clippy::unwrap_used)] // test helpers

use proptest::prelude::*;
use resecta_geom::{GeomError, Grid, Mat3, Vec3, Volume};
use resecta_vessels::{
    BranchSelection, NodeKind, RootChoice, TerritoryParams, VesselError, VesselParams, VesselTree,
    territories, vessel_tree,
};

mod common;
use common::*;

fn count(tree: &VesselTree, kind: NodeKind) -> usize {
    tree.nodes.iter().filter(|n| n.kind == kind).count()
}

#[test]
fn straight_tube_is_one_medial_line() {
    for grid in [
        centred_grid([0.8, 1.0, 1.3], 20.0, Mat3::identity()),
        centred_grid([0.9, 1.0, 1.2], 20.0, oblique()),
    ] {
        let (a, b, r) = (Vec3::new(-3.0, -14.0, -2.0), Vec3::new(2.0, 14.0, 3.0), 3.0);
        let m = mask(&grid, |p| seg_dist(p, a, b) <= r);
        let tree = vessel_tree(&m, RootChoice::Auto, &VesselParams::default()).unwrap();
        assert_eq!(tree.edges.len(), 1, "{:?}", tree.report);
        assert_eq!(count(&tree, NodeKind::Branch), 0);
        assert_eq!(count(&tree, NodeKind::End), 1);
        let e = &tree.edges[0];
        let off = e
            .points
            .iter()
            .map(|&p| seg_dist(p, a, b))
            .fold(0.0, f64::max);
        let mut radii = e.radii.clone();
        radii.sort_by(f64::total_cmp);
        let med = radii[radii.len() / 2];
        println!(
            "tube: {} points, max off-axis {off:.3} mm (max spacing {:.1}), median radius {med:.3} \
             (true {r}), length {:.1} mm (axis {:.1})",
            e.points.len(),
            grid.spacing().iter().copied().fold(0.0, f64::max),
            e.length_mm,
            (b - a).norm()
        );
        assert!(
            off <= grid.spacing().iter().copied().fold(0.0, f64::max),
            "{off}"
        );
        assert!((med - r).abs() <= diag(&grid), "{med}");
        assert_eq!(tree.report.specks, 0);
    }
}

#[test]
fn y_has_one_branch_point_and_the_trunk_as_root() {
    for c in y_cases() {
        let tree = vessel_tree(
            &y_mask(&c.grid, &c.y),
            RootChoice::Auto,
            &VesselParams::default(),
        )
        .unwrap();
        println!("Y: {:?}", tree.report);
        assert_eq!(count(&tree, NodeKind::Branch), 1);
        assert_eq!(
            count(&tree, NodeKind::End) + count(&tree, NodeKind::Root),
            3
        );
        assert_eq!(tree.edges.len(), 3);
        let root = &tree.nodes[tree.root];
        assert_eq!(root.kind, NodeKind::Root);
        assert!(
            seg_dist(root.position, c.y.trunk.0, c.y.trunk.1) < c.y.trunk.2
                && root.position.z < -c.y.trunk.0.z.abs() / 2.0,
            "root at {:?}",
            root.position
        );
        assert_eq!(tree.edges[0].generation, 1);
        assert_eq!(tree.edges[0].children.len(), 2);
        for &ch in &tree.edges[0].children {
            assert_eq!(tree.edges[ch].generation, 2);
            assert_eq!(tree.edges[ch].parent, Some(0));
        }
        // Overriding the root: the left branch's end.
        let t2 = vessel_tree(
            &y_mask(&c.grid, &c.y),
            RootChoice::NearestTo(c.y.left.1),
            &VesselParams::default(),
        )
        .unwrap();
        assert!((t2.nodes[t2.root].position - c.y.left.1).norm() < 2.0 * c.y.left.2 + 2.0);
    }
}

#[test]
fn children_split_the_box_at_the_bisector_and_partition_it() {
    for c in y_cases() {
        let tree = c.tree();
        let liver = c.liver();
        let t = territories(
            &tree,
            &liver,
            &BranchSelection::Generation(2),
            &TerritoryParams::default(),
        )
        .unwrap();
        assert_eq!(t.territories.len(), 3);
        let sum: usize = t.territories.iter().map(|t| t.voxels).sum();
        assert_eq!(sum, t.liver_voxels, "partition");
        let sum_ml: f64 = t.territories.iter().map(|t| t.volume_ml).sum();
        // Which territory is the left one (−x)?
        let left_edge = tree.edges[0]
            .children
            .iter()
            .copied()
            .find(|&e| tree.edges[e].points.last().unwrap().x < 0.0)
            .unwrap();
        let li = t
            .territories
            .iter()
            .position(|t| t.branch == Some(left_edge))
            .unwrap();
        let ri = 3 - li;
        // Voxels on the wrong side of the bisector x = 0.
        let mut wrong = 0.0f64;
        for (o, &l) in t.labels.data().iter().enumerate() {
            let x = c.grid.voxel_center(c.grid.ijk(o)).x;
            if l as usize == li + 1 && x > 0.0 || l as usize == ri + 1 && x < 0.0 {
                wrong = wrong.max(x.abs());
            }
        }
        let sp = c.grid.spacing().iter().copied().fold(0.0, f64::max);
        let layer_ml = (c.hi.y - c.lo.y) * (c.hi.z - c.lo.z) * sp / 1000.0;
        let half = t.liver_ml / 2.0;
        let (vl, vr) = (t.territories[li].volume_ml, t.territories[ri].volume_ml);
        println!(
            "bisector: liver {:.3} ml (box {:.3}), left {vl:.3}, right {vr:.3}, proximal {:.4} ml; \
             |left − half| {:.4} ml, |right − half| {:.4} ml, one layer {layer_ml:.3} ml; \
             farthest wrong-side voxel {wrong:.3} mm; partition error {:.2e} ml",
            t.liver_ml,
            (c.hi - c.lo).product() / 1000.0,
            t.territories[0].volume_ml,
            (vl - half).abs(),
            (vr - half).abs(),
            (sum_ml - t.liver_ml).abs()
        );
        assert!((vl - half).abs() <= layer_ml && (vr - half).abs() <= layer_ml);
        assert!(wrong <= 2.0 * sp, "{wrong}");
        assert!(t.territories[0].volume_ml <= layer_ml);
    }
}

#[test]
fn sampling_density_moves_volumes_by_less_than_one_percent() {
    for c in y_cases() {
        let tree = c.tree();
        let liver = c.liver();
        let base = 0.5
            * c.grid
                .spacing()
                .iter()
                .copied()
                .fold(f64::INFINITY, f64::min);
        let run = |s: f64| {
            territories(
                &tree,
                &liver,
                &BranchSelection::Ids(tree.edges[0].children.clone()),
                &TerritoryParams { sample_mm: Some(s) },
            )
            .unwrap()
        };
        let t0 = run(base);
        for f in [0.5, 2.0] {
            let t1 = run(base * f);
            for (a, b) in t0.territories.iter().zip(&t1.territories).skip(1) {
                let rel = (a.volume_ml - b.volume_ml).abs() / a.volume_ml;
                println!(
                    "sampling ×{f}: {:.4} → {:.4} ml ({:.3} %)",
                    a.volume_ml,
                    b.volume_ml,
                    100.0 * rel
                );
                assert!(rel < 0.01, "{rel}");
            }
        }
    }
}

#[test]
fn specks_dropped_and_detached_fragments_reported() {
    let grid = centred_grid([0.8, 1.0, 1.2], 20.0, Mat3::identity());
    let (a, b, r) = (Vec3::new(0.0, -14.0, 0.0), Vec3::new(0.0, 14.0, 0.0), 3.0);
    let speck = |p: Vec3| (p - Vec3::new(12.0, 10.0, 10.0)).abs().max() <= 0.9;
    let far = |p: Vec3| {
        seg_dist(
            p,
            Vec3::new(-12.0, -10.0, -12.0),
            Vec3::new(-12.0, 10.0, -12.0),
        ) <= 2.5
    };
    let m = mask(&grid, |p| seg_dist(p, a, b) <= r || speck(p) || far(p));
    let speck_voxels = mask(&grid, speck).data().iter().filter(|&&v| v).count();
    let far_voxels = mask(&grid, far).data().iter().filter(|&&v| v).count();
    let tree = vessel_tree(&m, RootChoice::Auto, &VesselParams::default()).unwrap();
    println!("speck: {:?}", tree.report);
    assert_eq!(tree.report.specks, 1);
    assert_eq!(tree.report.speck_voxels, speck_voxels);
    assert_eq!(tree.report.detached_components, 1);
    assert_eq!(tree.report.detached_voxels, far_voxels);
    assert_eq!(tree.edges.len(), 1);
}

#[test]
fn one_voxel_gap_is_bridged() {
    let grid = centred_grid([0.8, 1.0, 1.2], 20.0, Mat3::identity());
    let (a, b, r) = (Vec3::new(0.0, -15.0, 0.0), Vec3::new(0.0, 15.0, 0.0), 3.0);
    // Remove the voxel layer j nearest y = 0.
    let m = mask(&grid, |p| seg_dist(p, a, b) <= r && p.y.abs() > 0.5);
    let tree = vessel_tree(&m, RootChoice::Auto, &VesselParams::default()).unwrap();
    println!("gap: {:?}", tree.report);
    assert_eq!(tree.report.components, 2);
    assert_eq!(tree.report.gaps_bridged, 1);
    assert_eq!(tree.report.detached_components, 0);
    assert_eq!(tree.edges.len(), 1);
    assert_eq!(tree.edges[0].bridged_gaps, 1);
}

#[test]
fn degenerate_inputs_give_typed_errors() {
    let grid = Grid::axis_aligned([6, 5, 4], [1.0, 1.0, 2.0], Vec3::zeros()).unwrap();
    let empty = Volume::filled(grid.clone(), false);
    assert!(matches!(
        vessel_tree(&empty, RootChoice::Auto, &VesselParams::default()),
        Err(VesselError::EmptyVesselMask { .. })
    ));
    let full = Volume::filled(grid.clone(), true);
    let tree = vessel_tree(&full, RootChoice::Auto, &VesselParams::default()).unwrap();
    assert!(matches!(
        territories(
            &tree,
            &empty,
            &BranchSelection::Generation(1),
            &TerritoryParams::default()
        ),
        Err(VesselError::EmptyLiver)
    ));
    let mut one = Volume::filled(grid.clone(), false);
    one.set([2, 2, 2], true);
    let p = VesselParams {
        min_component_voxels: 1,
        ..VesselParams::default()
    };
    let tree = vessel_tree(&one, RootChoice::Auto, &p).unwrap();
    assert!(tree.edges.is_empty());
    assert!(matches!(
        territories(
            &tree,
            &full,
            &BranchSelection::Generation(1),
            &TerritoryParams::default()
        ),
        Err(VesselError::NoBranchSelected)
    ));
    assert!(matches!(
        territories(
            &tree,
            &full,
            &BranchSelection::Ids(vec![3]),
            &TerritoryParams::default()
        ),
        Err(VesselError::UnknownBranch { id: 3, count: 0 })
    ));
    let other = Grid::axis_aligned([6, 5, 4], [1.0, 1.0, 1.0], Vec3::zeros()).unwrap();
    assert!(matches!(
        territories(
            &tree,
            &Volume::filled(other, true),
            &BranchSelection::Generation(1),
            &TerritoryParams::default()
        ),
        Err(VesselError::GridMismatch)
    ));
    assert!(matches!(
        vessel_tree(
            &one,
            RootChoice::NearestTo(Vec3::new(f64::NAN, 0.0, 0.0)),
            &p
        ),
        Err(VesselError::InvalidParameter { .. })
    ));
    let sheared = Grid::new(
        [4, 4, 4],
        [1.0; 3],
        Vec3::zeros(),
        Mat3::new(1.0, 0.5, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
    )
    .unwrap();
    assert!(matches!(
        vessel_tree(&Volume::filled(sheared, true), RootChoice::Auto, &p),
        Err(VesselError::Geom(GeomError::NonOrthogonalGrid))
    ));
    let tiny = Grid::axis_aligned([1, 1, 1], [1.0; 3], Vec3::zeros()).unwrap();
    let tree = vessel_tree(&Volume::filled(tiny.clone(), true), RootChoice::Auto, &p).unwrap();
    assert_eq!(tree.nodes.len(), 1);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    #[test]
    fn random_masks_never_panic(bits in proptest::collection::vec(any::<bool>(), 7 * 6 * 5), k in 1u32..4) {
        let grid = Grid::axis_aligned([7, 6, 5], [1.0, 0.7, 1.5], Vec3::zeros()).unwrap();
        let m = Volume::from_vec(grid.clone(), bits).unwrap();
        let p = VesselParams { min_component_voxels: 2, ..VesselParams::default() };
        if let Ok(tree) = vessel_tree(&m, RootChoice::Auto, &p) {
            let liver = Volume::filled(grid, true);
            if let Ok(t) = territories(&tree, &liver, &BranchSelection::Generation(k), &TerritoryParams::default()) {
                prop_assert_eq!(t.territories.iter().map(|t| t.voxels).sum::<usize>(), t.liver_voxels);
            }
        }
    }
}

#[test]
fn largest_branches_split_the_longest_subtree_first() {
    let c = &y_cases()[0];
    let tree = c.tree();
    let liver = c.liver();
    let run = |sel: BranchSelection| {
        territories(&tree, &liver, &sel, &TerritoryParams::default()).unwrap()
    };
    let branches = |t: &resecta_vessels::Territories| -> Vec<Option<usize>> {
        t.territories.iter().map(|t| t.branch).collect()
    };
    // One: the trunk with everything below it; two or more: the trunk splits into the Y's arms
    // and nothing splits further.
    assert_eq!(
        branches(&run(BranchSelection::Largest(1))),
        vec![None, Some(0)]
    );
    let two = run(BranchSelection::Largest(2));
    let eight = run(BranchSelection::Largest(8));
    assert_eq!(branches(&two), branches(&eight));
    assert_eq!(two.labels, run(BranchSelection::Generation(2)).labels);
    assert_eq!(two.territories.len(), 3);
}
