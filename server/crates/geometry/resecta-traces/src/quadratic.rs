//! Piecewise quadratic Lagrange interpolation on a knot sequence t₀ < … < t_{N−1} (N ≥ 3): the
//! pieces interpolate the triples (0, 1, 2), (2, 3, 4), …; with N even the last interval takes
//! (N−3, N−2, N−1). Continuous through every node, quadratic (hence exact for quadratic data)
//! on every piece.

use resecta_geom::Real;

/// The three nodes of the piece holding `x` and their weights (value, first and second
/// derivative) at `x`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Weights {
    pub first: usize,
    pub w: [Real; 3],
    pub d1: [Real; 3],
    pub d2: [Real; 3],
}

pub(crate) fn weights(knots: &[Real], x: Real) -> Weights {
    let n = knots.len();
    debug_assert!(n >= 3);
    // The interval holding x (clamped to the knot range).
    let i = knots[1..n - 1].partition_point(|&t| t <= x);
    let first = (i - i % 2).min(n - 3);
    let [a, b, c] = [knots[first], knots[first + 1], knots[first + 2]];
    let (da, db, dc) = ((a - b) * (a - c), (b - a) * (b - c), (c - a) * (c - b));
    Weights {
        first,
        w: [
            (x - b) * (x - c) / da,
            (x - a) * (x - c) / db,
            (x - a) * (x - b) / dc,
        ],
        d1: [
            (2.0 * x - b - c) / da,
            (2.0 * x - a - c) / db,
            (2.0 * x - a - b) / dc,
        ],
        d2: [2.0 / da, 2.0 / db, 2.0 / dc],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quadratics_are_reproduced_and_nodes_interpolated() {
        let knots = [0.0, 0.1, 0.35, 0.5, 0.8, 1.0];
        let f = |x: Real| 3.0 * x * x - x + 2.0;
        for k in 0..=40 {
            let x = Real::from(k) / 40.0;
            let w = weights(&knots, x);
            let at = |s: [Real; 3]| (0..3).map(|j| s[j] * f(knots[w.first + j])).sum::<Real>();
            assert!((at(w.w) - f(x)).abs() < 1e-12);
            assert!((at(w.d1) - (6.0 * x - 1.0)).abs() < 1e-11);
            assert!((at(w.d2) - 6.0).abs() < 1e-9);
        }
        for (k, &t) in knots.iter().enumerate() {
            let w = weights(&knots, t);
            let one = (0..3).find(|&j| w.first + j == k).unwrap();
            assert!((w.w[one] - 1.0).abs() < 1e-12);
        }
        assert_eq!(weights(&knots, 0.9).first, 3);
        assert_eq!(weights(&knots, 0.2).first, 0);
        assert_eq!(weights(&knots, 0.4).first, 2);
    }
}
