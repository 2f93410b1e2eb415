#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! MLE level invalidation, meshes, normals at degenerate corners, typed errors.

mod common;

use common::{max_diff, random_net};
use resecta_bezier::*;

#[test]
fn mle_levels_invalidate_only_what_changed() {
    let net = random_net::<f64>(4, 5, 1);
    let res = Resolution::new(30, 20).unwrap();
    let mut e = MleEvaluator::new(net.clone(), res);
    e.evaluate(Outputs::Points);
    let c = e.counters();
    assert_eq!((c.level3, c.level2, c.level1), (1, 1, 1));

    // A: moving control points recomputes level 1 only, and the result follows the move.
    let moved = random_net::<f64>(4, 5, 2);
    e.set_control_points(moved.points()).unwrap();
    e.set_control_point(1, 1, [5.0, 5.0, 5.0]).unwrap();
    let g = e.evaluate(Outputs::Points);
    let c = e.counters();
    assert_eq!((c.level3, c.level2, c.level1), (1, 1, 2));
    let mut want_net = moved.clone();
    want_net.set(1, 1, [5.0, 5.0, 5.0]).unwrap();
    let want = evaluate_brf(&want_net, res, Outputs::Points);
    assert!(max_diff(g.points(), want.points()) < 1e-11);

    // B: new resolution recomputes level 2 but not level 3; same resolution changes nothing.
    e.set_resolution(res);
    e.evaluate(Outputs::Points);
    assert_eq!(e.counters().level2, 1);
    let res2 = Resolution::new(31, 20).unwrap();
    e.set_resolution(res2);
    let g = e.evaluate(Outputs::Points);
    let c = e.counters();
    assert_eq!((c.level3, c.level2), (1, 2));
    assert_eq!(g.resolution(), res2);

    // Derivative tables are built once on demand and kept under A.
    e.evaluate(Outputs::Derivatives);
    e.set_control_points(net.points()).unwrap();
    e.evaluate(Outputs::Normals);
    assert_eq!(e.counters().level2_derivative, 1);

    // C: same M×N keeps levels; another M×N recomputes levels 3 and 2.
    e.set_net(random_net::<f64>(4, 5, 9));
    e.evaluate(Outputs::Points);
    assert_eq!((e.counters().level3, e.counters().level2), (1, 2));
    e.set_net(random_net::<f64>(6, 5, 9));
    let g = e.evaluate(Outputs::Points);
    let c = e.counters();
    assert_eq!((c.level3, c.level2), (2, 3));
    let want = evaluate_brf(e.net(), res2, Outputs::Points);
    assert!(max_diff(g.points(), want.points()) < 1e-11);
}

#[test]
fn row_ranges_equal_the_whole_surface() {
    let net = random_net::<f64>(7, 5, 11);
    let res = Resolution::new(23, 17).unwrap();
    let mut e = MleEvaluator::new(net.clone(), res);
    let whole = e.evaluate(Outputs::Points);
    // Not prepared yet for rows: refused.
    let mut part = vec![[0.0; 3]; 3 * 17];
    assert!(
        MleEvaluator::new(net, res)
            .rows_into(0..3, &mut part)
            .is_err()
    );
    e.prepare_rows();
    // Ranges on both sides of u = 1/2 (the partition-of-unity base switches there).
    for rows in [0..3, 10..13, 11..14, 20..23] {
        e.rows_into(rows.clone(), &mut part).unwrap();
        assert_eq!(
            part.as_slice(),
            &whole.points()[rows.start * 17..rows.end * 17]
        );
    }
    assert!(e.rows_into(21..24, &mut part).is_err());
    assert!(e.rows_into(0..2, &mut part).is_err());
}

#[test]
fn evaluate_into_caller_buffers() {
    let net = random_net::<f32>(4, 4, 5);
    let res = Resolution::new(16, 16).unwrap();
    let mut e = MleEvaluator::new(net.clone(), res);
    let mut buf = vec![[0.0f32; 3]; res.len()];
    e.evaluate_points_into(&mut buf).unwrap();
    assert_eq!(buf.as_slice(), e.evaluate(Outputs::Points).points());
    let mut short = vec![[0.0f32; 3]; 10];
    assert_eq!(
        e.evaluate_points_into(&mut short),
        Err(BezierError::BufferLength {
            expected: 256,
            got: 10
        })
    );
    let mut wrong = SurfaceGrid::zeroed(Resolution::new(8, 32).unwrap(), Outputs::Points);
    assert!(e.evaluate_into(&mut wrong).is_err());
    let mut p = Prepared::new(Method::Mle, net.clone(), res, Outputs::Points).unwrap();
    p.run().unwrap();
    assert_eq!(p.output().points(), buf.as_slice());
}

#[test]
fn prepared_methods_agree() {
    let net = random_net::<f64>(4, 4, 11);
    let res = Resolution::new(32, 32).unwrap();
    let outs: Vec<_> = Method::ALL
        .iter()
        .map(|&m| {
            let mut p = Prepared::new(m, net.clone(), res, Outputs::Normals).unwrap();
            assert_eq!(p.method(), m);
            p.set_control_points(random_net::<f64>(4, 4, 12).points())
                .unwrap();
            p.run().unwrap();
            p.output().clone()
        })
        .collect();
    for o in &outs[1..] {
        assert!(max_diff(outs[0].points(), o.points()) < 1e-9);
        assert!(max_diff(outs[0].normals().unwrap(), o.normals().unwrap()) < 1e-7);
    }
    let mut buf = vec![[0.0f64; 3]; res.len()];
    write_ceiling(&mut buf, 2.5);
    assert!(buf.iter().all(|p| *p == [2.5; 3]));
}

#[test]
fn mesh_count_and_orientation() {
    // A dome: z bulges upwards; ∂u×∂v points along +z for u along x and v along y.
    let net = ControlNet::<f64>::from_fn(5, 4, |i, j| {
        let (x, y) = (i as f64, j as f64);
        [
            x,
            y,
            2.0 - (x - 2.0).powi(2) * 0.3 - (y - 1.5).powi(2) * 0.3,
        ]
    })
    .unwrap();
    let res = Resolution::new(13, 9).unwrap();
    let g = MleEvaluator::new(net, res).evaluate(Outputs::Normals);
    let mesh = to_trimesh(&g).unwrap();
    assert_eq!(mesh.triangles().len(), 2 * 12 * 8);
    assert_eq!(mesh.vertices().len(), 13 * 9);
    let normals = mesh.normals().unwrap();
    for t in 0..mesh.triangles().len() {
        let [a, b, c] = mesh.corners(t);
        let face = (b - a).cross(&(c - a));
        assert!(face.z > 0.0, "triangle {t} flipped");
        let tri = mesh.triangles()[t];
        for &v in &tri {
            assert!(face.dot(&normals[v as usize]) > 0.0);
        }
    }
    // Without normals in the grid, mesh vertex normals are attached.
    let g2 = MleEvaluator::new(random_net::<f32>(3, 3, 1), res).evaluate(Outputs::Points);
    assert_eq!(to_trimesh(&g2).unwrap().normals().unwrap().len(), 13 * 9);
}

#[test]
fn normals_at_collapsed_edge() {
    // Row i = 0 collapsed to one apex: ∂S/∂v = 0 along u = 0 (a cone-like cap).
    let net = ControlNet::<f64>::from_fn(4, 4, |i, j| {
        if i == 0 {
            [0.0, 0.0, 1.0]
        } else {
            let ang = j as f64 * 0.5;
            let r = i as f64;
            [r * ang.cos(), r * ang.sin(), 1.0 - 0.2 * r]
        }
    })
    .unwrap();
    let res = Resolution::new(21, 21).unwrap();
    let g = MleEvaluator::new(net.clone(), res).evaluate(Outputs::Normals);
    let n = g.normals().unwrap();
    for b in 0..21 {
        let apex = n[b];
        let len = (apex[0].powi(2) + apex[1].powi(2) + apex[2].powi(2)).sqrt();
        assert!((len - 1.0).abs() < 1e-9, "apex normal {apex:?} not unit");
        // Continuous with the next row (one sample further from the apex).
        let next = n[21 + b];
        let dot: f64 = (0..3).map(|c| apex[c] * next[c]).sum();
        assert!(dot > 0.9, "apex normal {apex:?} vs neighbour {next:?}");
    }
    // A net collapsed to a single point has no normal anywhere: zero vectors, no NaN.
    let point = ControlNet::<f64>::from_fn(3, 3, |_, _| [1.0, 2.0, 3.0]).unwrap();
    let g = MleEvaluator::new(point, res).evaluate(Outputs::Normals);
    assert!(g.normals().unwrap().iter().all(|n| *n == [0.0; 3]));
}

#[test]
fn invalid_input_is_typed() {
    let p = [0.0f64; 3];
    assert_eq!(
        ControlNet::new(1, 3, vec![p; 3]),
        Err(BezierError::TooFewControlPoints { axis: 'u', got: 1 })
    );
    assert_eq!(
        ControlNet::new(65, 2, vec![p; 130]),
        Err(BezierError::TooManyControlPoints {
            axis: 'u',
            got: 65,
            max: 64
        })
    );
    assert!(matches!(
        ControlNet::new(3, 3, vec![p; 8]),
        Err(BezierError::PointCount {
            expected: 9,
            got: 8,
            ..
        })
    ));
    let mut pts = vec![p; 9];
    pts[4][1] = f64::NAN;
    assert_eq!(
        ControlNet::new(3, 3, pts),
        Err(BezierError::NonFinite { index: 4 })
    );
    let mut net = ControlNet::new(3, 3, vec![p; 9]).unwrap();
    assert_eq!(
        net.set(1, 1, [f64::INFINITY, 0.0, 0.0]),
        Err(BezierError::NonFinite { index: 4 })
    );
    assert!(matches!(
        net.set(3, 0, p),
        Err(BezierError::IndexOutOfRange { .. })
    ));
    assert_eq!(
        Resolution::new(1, 10),
        Err(BezierError::ResolutionTooSmall { axis: 'u', got: 1 })
    );
    assert_eq!(
        Resolution::new(10, 5000),
        Err(BezierError::ResolutionTooLarge {
            axis: 'v',
            got: 5000,
            max: MAX_RESOLUTION
        })
    );
    assert!(matches!(
        Resolution::new(4096, 4096),
        Err(BezierError::TooManySamples { .. })
    ));
    let mut e = MleEvaluator::new(net, Resolution::new(4, 4).unwrap());
    assert!(matches!(
        e.set_control_points(&[p; 4]),
        Err(BezierError::PointCount { .. })
    ));
}
