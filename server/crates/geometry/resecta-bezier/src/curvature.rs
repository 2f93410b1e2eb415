//! A Bézier net as a [`CutSurface`]: exact first and second derivatives, hence the mean
//! curvature of thesis Eq. 7.10 (`H = (κ₁ + κ₂)/2`, signed by the normal ∂S/∂u × ∂S/∂v, in the
//! net's coordinates⁻¹: mm⁻¹ for a resection); samples by the multi-level evaluator.

use resecta_geom::{CutSurface, Real, SurfacePoint, Vec3};

use crate::basis::{basis_at, binomial_row};
use crate::mle::MleEvaluator;
use crate::normals::{eval_point, tensor_at};
use crate::scalar::P3;
use crate::types::{ControlNet, Outputs, Resolution};

fn basis(count: usize, t: f64) -> Vec<f64> {
    let mut b = vec![0.0; count];
    basis_at(&binomial_row(count), t, &mut b);
    b
}

/// ∂²S/∂u² at (u, v): the net's second differences along u, scaled by (M−1)(M−2); 0 for M < 3.
fn second_u(net: &ControlNet<f64>, u: f64, v: f64) -> P3<f64> {
    let (m, n) = net.dims();
    if m < 3 {
        return [0.0; 3];
    }
    let p = net.points();
    let f = ((m - 1) * (m - 2)) as f64;
    let d2: Vec<P3<f64>> = (0..(m - 2) * n)
        .map(|k| {
            let (i, j) = (k / n, k % n);
            let (a, b, c) = (p[i * n + j], p[(i + 1) * n + j], p[(i + 2) * n + j]);
            [0, 1, 2].map(|x| f * (c[x] - 2.0 * b[x] + a[x]))
        })
        .collect();
    tensor_at(&d2, &basis(m - 2, u), &basis(n, v))
}

fn v3(p: P3<f64>) -> Vec3 {
    Vec3::new(p[0], p[1], p[2])
}

impl CutSurface for ControlNet<f64> {
    fn at(&self, u: Real, v: Real) -> SurfacePoint {
        let e = eval_point(self, u, v);
        SurfacePoint {
            p: v3(e.point),
            du: v3(e.du),
            dv: v3(e.dv),
            duu: v3(second_u(self, u, v)),
            duv: v3(e.duv),
            dvv: v3(second_u(&self.transposed(), v, u)),
        }
    }

    /// The hodograph bound: |∂S/∂u| ≤ (m−1)·max|P₍ᵢ₊₁₎ⱼ − Pᵢⱼ| (and likewise along v), since
    /// ∂S/∂u is a Bernstein combination (weights summing to 1) of the scaled differences.
    fn speeds(&self) -> [Real; 2] {
        let (m, n) = self.dims();
        let p = |i: usize, j: usize| v3(self.points()[i * n + j]);
        let su = (0..(m - 1) * n)
            .map(|k| (p(k / n + 1, k % n) - p(k / n, k % n)).norm())
            .fold(0.0, Real::max);
        let sv = (0..m * (n - 1))
            .map(|k| {
                let (i, j) = (k / (n - 1), k % (n - 1));
                (p(i, j + 1) - p(i, j)).norm()
            })
            .fold(0.0, Real::max);
        [(m - 1) as Real * su, (n - 1) as Real * sv]
    }

    /// By the multi-level evaluator, degenerate normals repaired as it does.
    fn sample(&self, ru: usize, rv: usize, points: &mut Vec<Vec3>, normals: &mut Vec<Vec3>) {
        let Ok(res) = Resolution::new(ru, rv) else {
            points.clear();
            normals.clear();
            return;
        };
        let mut e = MleEvaluator::new(self.clone(), res);
        let g = e.evaluate(Outputs::Normals);
        *points = g.points().iter().map(|&q| v3(q)).collect();
        *normals = g
            .normals()
            .unwrap_or_default()
            .iter()
            .map(|&q| v3(q))
            .collect();
    }
}

/// Mean curvature at (u, v) ∈ [0, 1]²; `None` where the surface is not regular (∂S/∂u and
/// ∂S/∂v parallel or vanishing: no tangent plane).
pub fn mean_curvature(net: &ControlNet<f64>, u: f64, v: f64) -> Option<f64> {
    net.at(u, v).mean_curvature()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A parabolic cylinder z = a·x² over x, y ∈ [−1, 1] (quadratic in u, linear in v): its
    /// mean curvature is half the parabola's, `a / (1 + 4a²x²)^{3/2}`, at x = 2u − 1.
    #[test]
    fn a_parabolic_cylinder_has_its_analytic_mean_curvature() {
        let a = 0.3;
        let pts = vec![
            [-1.0, -1.0, a],
            [-1.0, 1.0, a],
            [0.0, -1.0, -a],
            [0.0, 1.0, -a],
            [1.0, -1.0, a],
            [1.0, 1.0, a],
        ];
        let net = ControlNet::new(3, 2, pts).unwrap();
        for k in 0..=10 {
            let u = f64::from(k) / 10.0;
            let x = 2.0 * u - 1.0;
            let want = a / (1.0 + 4.0 * a * a * x * x).powf(1.5);
            for v in [0.0, 0.37, 1.0] {
                let h = mean_curvature(&net, u, v).unwrap();
                // The normal du × dv points down (−z) here: the parabola bends towards +z.
                assert!((h.abs() - want).abs() < 1e-12, "u {u} v {v}: {h} vs {want}");
            }
        }
        // The same surface transposed (quadratic in v) has the same |H|.
        let t = net.transposed();
        let (h, g) = (mean_curvature(&net, 0.3, 0.6), mean_curvature(&t, 0.6, 0.3));
        assert!((h.unwrap().abs() - g.unwrap().abs()).abs() < 1e-12);
    }

    #[test]
    fn a_plane_is_flat_and_a_collapsed_corner_has_no_curvature() {
        let net = ControlNet::from_fn(4, 5, |i, j| [i as f64 * 2.0, j as f64 * 1.5, 3.0]).unwrap();
        for (u, v) in [(0.0, 0.0), (0.4, 0.9), (1.0, 0.5)] {
            assert!(mean_curvature(&net, u, v).unwrap().abs() < 1e-12);
        }
        // All of row 0 at one point: no tangent plane at u = 0.
        let net = ControlNet::from_fn(3, 3, |i, j| {
            if i == 0 {
                [0.0; 3]
            } else {
                [i as f64, j as f64 * i as f64, 0.0]
            }
        })
        .unwrap();
        assert_eq!(mean_curvature(&net, 0.0, 0.5), None);
    }
}
