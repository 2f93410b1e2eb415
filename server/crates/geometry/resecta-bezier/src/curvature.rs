//! Mean curvature of a Bézier surface (thesis Eq. 7.10, `H = (κ₁ + κ₂)/2`) from its exact first
//! and second derivatives: `H = (E·N − 2F·M + G·L) / (2(EG − F²))` with the first fundamental
//! form E, F, G of ∂S/∂u, ∂S/∂v and the second L, M, N of ∂²S/∂u², ∂²S/∂u∂v, ∂²S/∂v² on the
//! unit normal ∂S/∂u × ∂S/∂v. Its sign follows that normal; in the units of the net's
//! coordinates⁻¹ (mm⁻¹ for a resection).

use crate::basis::{basis_at, binomial_row};
use crate::normals::{eval_point, tensor_at};
use crate::scalar::{P3, cross3, norm3};
use crate::types::ControlNet;

fn dot(a: P3<f64>, b: P3<f64>) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

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

/// Mean curvature at (u, v) ∈ [0, 1]²; `None` where the surface is not regular (∂S/∂u and
/// ∂S/∂v parallel or vanishing: no tangent plane).
pub fn mean_curvature(net: &ControlNet<f64>, u: f64, v: f64) -> Option<f64> {
    let e = eval_point(net, u, v);
    let normal = cross3(e.du, e.dv);
    let area = norm3(normal);
    let regular = area > 1e-12 * norm3(e.du) * norm3(e.dv) && area.is_finite();
    if !regular {
        return None;
    }
    let nu = normal.map(|c| c / area);
    let suu = second_u(net, u, v);
    let svv = second_u(&net.transposed(), v, u);
    let (ee, ff, gg) = (dot(e.du, e.du), dot(e.du, e.dv), dot(e.dv, e.dv));
    let (l, m, n) = (dot(nu, suu), dot(nu, e.duv), dot(nu, svv));
    Some((ee * n - 2.0 * ff * m + gg * l) / (2.0 * area * area))
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
