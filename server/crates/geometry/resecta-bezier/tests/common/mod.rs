#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Shared helpers for the integration tests.
#![allow(dead_code)]

use resecta_bezier::{BezierScalar, ControlNet, P3};

/// Deterministic pseudo-random coordinates in [−100, 100] (SplitMix64).
pub fn random_net<T: BezierScalar>(m: usize, n: usize, seed: u64) -> ControlNet<T> {
    let mut s = seed;
    let mut next = move || {
        s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = s;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64 * 200.0 - 100.0
    };
    ControlNet::from_fn(m, n, |_, _| [next(), next(), next()].map(T::from_f64)).unwrap()
}

pub fn max_abs<T: BezierScalar>(pts: &[P3<T>]) -> f64 {
    pts.iter()
        .flat_map(|p| p.iter().map(|c| c.to_f64().abs()))
        .fold(0.0, f64::max)
}

/// Largest coordinate difference between two point arrays.
pub fn max_diff<T: BezierScalar>(a: &[P3<T>], b: &[P3<T>]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c].to_f64() - q[c].to_f64()).abs()))
        .fold(0.0, f64::max)
}

/// Error allowance of the Bernstein-form evaluators (convex weights): 16·(M+N)·ε·max|P|.
pub fn bernstein_tol<T: BezierScalar>(net: &ControlNet<T>) -> f64 {
    let (m, n) = net.dims();
    16.0 * (m + n) as f64 * T::EPSILON.to_f64() * max_abs(net.points()).max(1.0)
}
