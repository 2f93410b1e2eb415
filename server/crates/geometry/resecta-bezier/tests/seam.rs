//! The evaluator seam: `MleEvaluator<f64>` through `SurfaceEvaluator`, and normals computed
//! elsewhere finished by `NormalTolerance` + `repair_normals` exactly as the CPU does.
#![allow(clippy::unwrap_used)]

use resecta_bezier::{
    BezierError, ControlNet, MleEvaluator, NormalTolerance, Outputs, Resolution, SurfaceEngine,
    SurfaceGrid, repair_normals,
};

/// Edge u = 0 and edge v = 1 collapsed to one point: both limit normals and, at the shared
/// corner, the neighbours' mean.
fn collapsed() -> ControlNet<f64> {
    ControlNet::from_fn(4, 5, |i, j| {
        if i == 0 || j == 4 {
            return [0.0, 0.0, 30.0];
        }
        let (u, v) = (i as f64 / 3.0, j as f64 / 4.0);
        [
            40.0 * u * (v - 0.5),
            30.0 * u + 5.0 * v,
            30.0 - 25.0 * u * u,
        ]
    })
    .unwrap()
}

#[test]
fn zeroed_degenerate_normals_repaired_are_the_cpu_normals() {
    let net = collapsed();
    let res = Resolution::new(23, 31).unwrap();
    let want = MleEvaluator::new(net.clone(), res).evaluate(Outputs::Normals);
    let tol = NormalTolerance::of(&net);
    let (du, dv) = (want.du().unwrap(), want.dv().unwrap());
    let mut normals: Vec<_> = (0..res.len())
        .map(|k| tol.regular(du[k], dv[k]).unwrap_or([0.0; 3]))
        .collect();
    let zeros = normals.iter().filter(|n| **n == [0.0; 3]).count();
    assert_eq!(zeros, 23 + 31 - 1, "both collapsed edges are degenerate");
    repair_normals(&net, res, &mut normals);
    assert_eq!(normals, want.normals().unwrap());
    assert!(normals.iter().all(|n| n != &[0.0; 3]));
}

#[test]
fn the_cpu_engine_evaluates_as_the_mle_and_wants_a_normals_grid() {
    let net = collapsed();
    let res = Resolution::new(12, 9).unwrap();
    let engine = SurfaceEngine::cpu();
    assert_eq!(engine.backend(), "cpu");
    let mut e = engine.make(net.clone(), res).unwrap();
    let mut grid = SurfaceGrid::zeroed(res, Outputs::Normals);
    e.set_control_point(2, 2, [1.0, 2.0, 3.0]).unwrap();
    e.evaluate_into(&mut grid).unwrap();
    let mut moved = net;
    moved.set(2, 2, [1.0, 2.0, 3.0]).unwrap();
    assert_eq!(
        grid,
        MleEvaluator::new(moved, res).evaluate(Outputs::Normals)
    );
    let mut points = SurfaceGrid::zeroed(res, Outputs::Points);
    assert_eq!(
        e.evaluate_into(&mut points),
        Err(BezierError::MissingOutput("normals"))
    );
    assert!(!BezierError::MissingOutput("normals").is_device());
    assert!(BezierError::Device("lost".into()).is_device());
}
