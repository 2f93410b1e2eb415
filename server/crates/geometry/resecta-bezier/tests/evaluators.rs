#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! The three evaluators agree, and the surfaces have the properties of Lemma 1 (ch. 7–8).

mod common;

use common::{bernstein_tol, max_abs, max_diff, random_net};
use proptest::prelude::*;
use resecta_bezier::*;

fn agree<T: BezierScalar>(m: usize, n: usize, ru: usize, rv: usize, seed: u64) {
    let net = random_net::<T>(m, n, seed);
    let res = Resolution::new(ru, rv).unwrap();
    let brf = evaluate_brf(&net, res, Outputs::Derivatives);
    let mut mle = MleEvaluator::new(net.clone(), res);
    let mle_g = mle.evaluate(Outputs::Derivatives);
    let mat = MatEvaluator::new(net.clone());
    let mat_g = mat.evaluate(res, Outputs::Derivatives);
    let tol = bernstein_tol(&net);
    let e = max_diff(brf.points(), mle_g.points());
    assert!(e <= tol, "{}: BRF vs MLE {e} > {tol} ({m}x{n})", T::NAME);
    // Derivatives scale with the degree.
    let dtol = tol * (m.max(n) as f64) * 2.0;
    assert!(max_diff(brf.du().unwrap(), mle_g.du().unwrap()) <= dtol);
    assert!(max_diff(brf.dv().unwrap(), mle_g.dv().unwrap()) <= dtol);
    // MAT: a-priori bound of the power form (see MatEvaluator::error_bound) plus BRF's own error.
    let mtol = mat.error_bound().to_f64() + tol;
    let e = max_diff(brf.points(), mat_g.points());
    assert!(e <= mtol, "{}: BRF vs MAT {e} > {mtol} ({m}x{n})", T::NAME);
    let mdtol = mtol * (m.max(n) as f64) * 2.0;
    assert!(max_diff(brf.du().unwrap(), mat_g.du().unwrap()) <= mdtol);
    // The SoA path gives the AoS points exactly (same operations in the same order).
    let len = res.len();
    let (mut x, mut y, mut z) = (vec![T::ZERO; len], vec![T::ZERO; len], vec![T::ZERO; len]);
    mle.evaluate_points_soa_into(&mut x, &mut y, &mut z)
        .unwrap();
    for (k, p) in mle_g.points().iter().enumerate() {
        assert_eq!([x[k], y[k], z[k]], *p);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn brf_mat_mle_agree_f64(m in 2usize..=12, n in 2usize..=12, ru in 2usize..=33, rv in 2usize..=33, seed in any::<u64>()) {
        agree::<f64>(m, n, ru, rv, seed);
    }

    #[test]
    fn brf_mat_mle_agree_f32(m in 2usize..=12, n in 2usize..=12, ru in 2usize..=33, rv in 2usize..=33, seed in any::<u64>()) {
        agree::<f32>(m, n, ru, rv, seed);
    }

    /// Corners are interpolated exactly by BRF and MLE (only exact zeros and ones enter).
    #[test]
    fn corners_exact(m in 2usize..=12, n in 2usize..=12, ru in 2usize..=20, rv in 2usize..=20, seed in any::<u64>()) {
        let net = random_net::<f64>(m, n, seed);
        let res = Resolution::new(ru, rv).unwrap();
        let grids = [evaluate_brf(&net, res, Outputs::Points), MleEvaluator::new(net.clone(), res).evaluate(Outputs::Points)];
        for g in &grids {
            prop_assert_eq!(g.point(0, 0).unwrap(), net.get(0, 0).unwrap());
            prop_assert_eq!(g.point(ru - 1, 0).unwrap(), net.get(m - 1, 0).unwrap());
            prop_assert_eq!(g.point(0, rv - 1).unwrap(), net.get(0, n - 1).unwrap());
            prop_assert_eq!(g.point(ru - 1, rv - 1).unwrap(), net.get(m - 1, n - 1).unwrap());
        }
        // f32 as well.
        let net32 = net.cast::<f32>();
        let g = MleEvaluator::new(net32.clone(), res).evaluate(Outputs::Points);
        prop_assert_eq!(g.point(ru - 1, rv - 1).unwrap(), net32.get(m - 1, n - 1).unwrap());
    }

    /// Convex hull: the MLE weights B^u[a,i]·B^v[b,j] are ≥ 0 and sum to 1; samples lie in the
    /// control points' bounding box.
    #[test]
    fn convex_hull(m in 2usize..=12, n in 2usize..=12, ru in 2usize..=30, rv in 2usize..=30, seed in any::<u64>()) {
        let net = random_net::<f64>(m, n, seed);
        let res = Resolution::new(ru, rv).unwrap();
        let mut mle = MleEvaluator::new(net.clone(), res);
        let (bu, bv) = mle.basis_tables();
        let (bu, bv) = (bu.to_vec(), bv.to_vec());
        for a in 0..ru {
            for b in 0..rv {
                let mut sum = 0.0;
                for i in 0..m {
                    for j in 0..n {
                        let w = bu[a * m + i] * bv[b * n + j];
                        prop_assert!(w >= 0.0);
                        sum += w;
                    }
                }
                prop_assert!((sum - 1.0).abs() <= 4.0 * (m + n) as f64 * f64::EPSILON, "sum {}", sum);
            }
        }
        let g = mle.evaluate(Outputs::Points);
        let (lo, hi) = net.bounds();
        let tol = bernstein_tol(&net);
        for p in g.points() {
            for c in 0..3 {
                prop_assert!(p[c] >= lo[c] - tol && p[c] <= hi[c] + tol);
            }
        }
    }

    /// Affine invariance (Eq. 7.4 erratum): T(S(P)) = S(T(P)).
    #[test]
    fn affine_invariance(m in 2usize..=10, n in 2usize..=10, seed in any::<u64>(), coeffs in prop::array::uniform12(-2.0f64..2.0)) {
        let net = random_net::<f64>(m, n, seed);
        let tf = |p: [f64; 3]| -> [f64; 3] {
            std::array::from_fn(|r| coeffs[4 * r] * p[0] + coeffs[4 * r + 1] * p[1] + coeffs[4 * r + 2] * p[2] + coeffs[4 * r + 3] * 10.0)
        };
        let moved = ControlNet::new(m, n, net.points().iter().map(|&p| tf(p)).collect()).unwrap();
        let res = Resolution::new(17, 13).unwrap();
        let a: Vec<_> = MleEvaluator::new(net.clone(), res).evaluate(Outputs::Points).points().iter().map(|&p| tf(p)).collect();
        let b = MleEvaluator::new(moved.clone(), res).evaluate(Outputs::Points);
        let tol = 8.0 * bernstein_tol(&moved).max(bernstein_tol(&net));
        prop_assert!(max_diff(&a, b.points()) <= tol);
    }

    /// Degree elevation (in u and in v) leaves the surface unchanged.
    #[test]
    fn degree_elevation(m in 2usize..=11, n in 2usize..=11, seed in any::<u64>()) {
        let net = random_net::<f64>(m, n, seed);
        let res = Resolution::new(21, 19).unwrap();
        let base = MleEvaluator::new(net.clone(), res).evaluate(Outputs::Points);
        for up in [net.elevate_u().unwrap(), net.elevate_v().unwrap()] {
            let g = evaluate_brf(&up, res, Outputs::Points);
            prop_assert!(max_diff(base.points(), g.points()) <= 2.0 * bernstein_tol(&up));
        }
    }

    /// Planar control net → planar surface (distance to the plane within tolerance).
    #[test]
    fn planar_net_planar_surface(m in 2usize..=12, n in 2usize..=12, seed in any::<u64>()) {
        let st = random_net::<f64>(m, n, seed);
        let (o, e1, e2) = ([1.0, -2.0, 3.0], [0.6, 0.8, 0.0], [-0.48, 0.36, 0.8]);
        let net = ControlNet::new(m, n, st.points().iter().map(|p| std::array::from_fn(|c| o[c] + p[0] * e1[c] + p[1] * e2[c])).collect()).unwrap();
        let normal = [0.64, -0.48, 0.6]; // e1 × e2, unit
        let g = MleEvaluator::new(net.clone(), Resolution::new(25, 31).unwrap()).evaluate(Outputs::Normals);
        let tol = 4.0 * bernstein_tol(&net);
        for p in g.points() {
            let d: f64 = (0..3).map(|c| (p[c] - o[c]) * normal[c]).sum();
            prop_assert!(d.abs() <= tol, "off-plane {}", d);
        }
        // Normals are ±the plane normal where regular.
        for nr in g.normals().unwrap() {
            let dot: f64 = (0..3).map(|c| nr[c] * normal[c]).sum();
            prop_assert!(dot.abs() > 1.0 - 1e-6 || nr == &[0.0; 3]);
        }
    }
}

#[test]
fn bilinear_patch_exact() {
    let p = [
        [0.0, 0.0, 1.0],
        [0.0, 2.0, -1.0],
        [3.0, 0.0, 0.5],
        [3.0, 2.0, 4.0],
    ];
    let net = ControlNet::<f64>::new(2, 2, p.to_vec()).unwrap();
    let res = Resolution::new(11, 7).unwrap();
    for g in [
        evaluate_brf(&net, res, Outputs::Points),
        MleEvaluator::new(net.clone(), res).evaluate(Outputs::Points),
        MatEvaluator::new(net.clone()).evaluate(res, Outputs::Points),
    ] {
        for a in 0..11 {
            for b in 0..7 {
                let (u, v): (f64, f64) = (res.u(a), res.v(b));
                let want: [f64; 3] = std::array::from_fn(|c| {
                    (1.0 - u) * (1.0 - v) * p[0][c]
                        + (1.0 - u) * v * p[1][c]
                        + u * (1.0 - v) * p[2][c]
                        + u * v * p[3][c]
                });
                let got = g.point(a, b).unwrap();
                for c in 0..3 {
                    assert!((got[c] - want[c]).abs() <= 1e-14, "{got:?} vs {want:?}");
                }
            }
        }
    }
}

#[test]
fn derivatives_match_central_differences() {
    let net = random_net::<f64>(5, 7, 42);
    let h = 1e-5;
    let scale = max_abs(net.points());
    for &(u, v) in &[(0.3, 0.6), (0.5, 0.5), (0.9, 0.1), (0.05, 0.95)] {
        let e = eval_point(&net, u, v);
        let fd_u: [f64; 3] = {
            let (p, q) = (
                eval_point(&net, u + h, v).point,
                eval_point(&net, u - h, v).point,
            );
            std::array::from_fn(|c| (p[c] - q[c]) / (2.0 * h))
        };
        let fd_v: [f64; 3] = {
            let (p, q) = (
                eval_point(&net, u, v + h).point,
                eval_point(&net, u, v - h).point,
            );
            std::array::from_fn(|c| (p[c] - q[c]) / (2.0 * h))
        };
        let fd_uv: [f64; 3] = {
            let (p, q) = (eval_point(&net, u, v + h).du, eval_point(&net, u, v - h).du);
            std::array::from_fn(|c| (p[c] - q[c]) / (2.0 * h))
        };
        // O(h²)·|S'''| truncation plus rounding ε·|S|/h; 1e-5 relative to the net scale holds.
        let tol = 1e-5 * scale;
        assert!(max_diff(&[e.du], &[fd_u]) <= tol);
        assert!(max_diff(&[e.dv], &[fd_v]) <= tol);
        assert!(max_diff(&[e.duv], &[fd_uv]) <= tol * 10.0);
    }
    // Grid derivatives of MLE equal the point-wise ones.
    let res = Resolution::new(9, 12).unwrap();
    let g = MleEvaluator::new(net.clone(), res).evaluate(Outputs::Derivatives);
    for (a, b) in [(0, 0), (3, 5), (8, 11), (4, 0)] {
        let e = eval_point(&net, res.u(a), res.v(b));
        let k = a * 12 + b;
        assert!(max_diff(&[g.du().unwrap()[k]], &[e.du]) <= 1e-10 * scale);
        assert!(max_diff(&[g.dv().unwrap()[k]], &[e.dv]) <= 1e-10 * scale);
    }
}

#[test]
fn f32_tracks_f64() {
    let net = random_net::<f64>(12, 9, 7);
    let res = Resolution::new(64, 48).unwrap();
    let g64 = MleEvaluator::new(net.clone(), res).evaluate(Outputs::Points);
    let g32 = MleEvaluator::new(net.cast::<f32>(), res).evaluate(Outputs::Points);
    let conv: Vec<[f64; 3]> = g32.points().iter().map(|p| p.map(f64::from)).collect();
    assert!(max_diff(g64.points(), &conv) <= bernstein_tol(&net.cast::<f32>()));
}

#[test]
fn binomials_exact() {
    assert_eq!(binomial(63, 31), 916_312_070_471_295_267);
    assert_eq!(binomial(4, 2), 6);
    assert_eq!(binomial(3, 4), 0);
    for n in 1..64 {
        for k in 1..n {
            assert_eq!(binomial(n, k), binomial(n - 1, k - 1) + binomial(n - 1, k));
        }
    }
    assert_eq!(binomial_row(4), vec![1, 3, 3, 1]);
    // Each Bernstein row of a table sums to 1.
    let t: Vec<f64> = bernstein_table(&binomial_row(12), 50);
    for row in t.chunks(12) {
        assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-14);
    }
    assert!((bernstein::<f64>(3, 1, 0.5) - 0.375).abs() < 1e-16);
}

#[test]
fn large_net_and_resolution_caps_work() {
    // 64×64 (degree 63) still evaluates consistently in f64.
    let net = random_net::<f64>(64, 64, 3);
    let res = Resolution::new(40, 40).unwrap();
    let a = MleEvaluator::new(net.clone(), res).evaluate(Outputs::Points);
    let b = evaluate_brf(&net, res, Outputs::Points);
    assert!(max_diff(a.points(), b.points()) <= bernstein_tol(&net));
    // 2000×2000 samples are allowed.
    assert!(Resolution::new(2000, 2000).is_ok());
}
