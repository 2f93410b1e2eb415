//! Parametric cut surfaces over [0, 1]²: what every kind of resection (Bézier, drawn on slices,
//! deformable cutting plane) offers the planner, the volumetry and the metrics — points, unit
//! normals `∂S/∂u × ∂S/∂v`, second derivatives and the mean curvature (thesis Eq. 7.10).

use rayon::prelude::*;

use crate::math::{Real, Vec3};

/// A surface point with its first and second derivatives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    pub p: Vec3,
    pub du: Vec3,
    pub dv: Vec3,
    pub duu: Vec3,
    pub duv: Vec3,
    pub dvv: Vec3,
}

impl SurfacePoint {
    /// The unit normal `∂S/∂u × ∂S/∂v`; `None` where there is no tangent plane.
    pub fn normal(&self) -> Option<Vec3> {
        let n = self.du.cross(&self.dv);
        let area = n.norm();
        let regular = area > 1e-12 * self.du.norm() * self.dv.norm() && area.is_finite();
        regular.then(|| n / area)
    }

    /// Mean curvature `H = (κ₁ + κ₂)/2 = (E·N − 2F·M + G·L) / (2(EG − F²))`, signed by
    /// [`SurfacePoint::normal`], in the coordinates' unit⁻¹; `None` without a tangent plane.
    pub fn mean_curvature(&self) -> Option<Real> {
        let nu = self.normal()?;
        let (e, f, g) = (
            self.du.dot(&self.du),
            self.du.dot(&self.dv),
            self.dv.dot(&self.dv),
        );
        let (l, m, n) = (nu.dot(&self.duu), nu.dot(&self.duv), nu.dot(&self.dvv));
        Some((e * n - 2.0 * f * m + g * l) / (2.0 * (e * g - f * f)))
    }
}

/// A cut surface S(u, v), (u, v) ∈ [0, 1]².
pub trait CutSurface: Send + Sync + std::fmt::Debug {
    /// S and its derivatives at (u, v).
    fn at(&self, u: Real, v: Real) -> SurfacePoint;

    /// Upper bounds of the parametric speeds |∂S/∂u| and |∂S/∂v| over [0, 1]² (mm per unit
    /// parameter): samples `⌈speed/δ⌉ + 1` per direction are at most δ apart everywhere, however
    /// unevenly the surface is parametrised.
    fn speeds(&self) -> [Real; 2];

    /// Points and unit normals on a ru×rv grid (index `a·rv + b` at `(a/(ru−1), b/(rv−1))`);
    /// a sample without a tangent plane gets the zero normal.
    fn sample(&self, ru: usize, rv: usize, points: &mut Vec<Vec3>, normals: &mut Vec<Vec3>) {
        let s: Vec<(Vec3, Vec3)> = (0..ru * rv)
            .into_par_iter()
            .map(|k| {
                let e = self.at(grid_param(k / rv, ru), grid_param(k % rv, rv));
                (e.p, e.normal().unwrap_or_else(Vec3::zeros))
            })
            .collect();
        points.clear();
        normals.clear();
        for (p, n) in s {
            points.push(p);
            normals.push(n);
        }
    }
}

/// The parameter of sample `a` of `r` samples on [0, 1].
pub fn grid_param(a: usize, r: usize) -> Real {
    if r < 2 {
        0.0
    } else {
        a as Real / (r - 1) as Real
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A cylinder of radius r about z: S(u, v) = (r cos θ, r sin θ, v) with θ = u·π/2.
    #[derive(Debug)]
    struct Cylinder(Real);

    impl CutSurface for Cylinder {
        fn at(&self, u: Real, v: Real) -> SurfacePoint {
            let (r, w) = (self.0, std::f64::consts::FRAC_PI_2);
            let (s, c) = (u * w).sin_cos();
            SurfacePoint {
                p: Vec3::new(r * c, r * s, v),
                du: Vec3::new(-r * w * s, r * w * c, 0.0),
                dv: Vec3::z(),
                duu: Vec3::new(-r * w * w * c, -r * w * w * s, 0.0),
                duv: Vec3::zeros(),
                dvv: Vec3::zeros(),
            }
        }
        fn speeds(&self) -> [Real; 2] {
            [self.0 * std::f64::consts::FRAC_PI_2, 1.0]
        }
    }

    #[test]
    fn a_cylinder_has_mean_curvature_half_its_inverse_radius() {
        let c = Cylinder(4.0);
        for u in [0.0, 0.3, 1.0] {
            let e = c.at(u, 0.5);
            // du × dv points outwards, the centre lies inside: H = −1/(2r).
            assert!((e.mean_curvature().unwrap() + 0.125).abs() < 1e-12);
            assert!((e.normal().unwrap() - e.p.xy().push(0.0) / 4.0).norm() < 1e-12);
        }
        let (mut p, mut n) = (Vec::new(), Vec::new());
        c.sample(3, 2, &mut p, &mut n);
        assert_eq!((p.len(), n.len()), (6, 6));
        assert!((p[5] - Vec3::new(0.0, 4.0, 1.0)).norm() < 1e-12);
    }

    #[test]
    fn a_degenerate_point_has_no_normal_or_curvature() {
        let e = SurfacePoint {
            p: Vec3::zeros(),
            du: Vec3::x(),
            dv: Vec3::x() * 2.0,
            duu: Vec3::zeros(),
            duv: Vec3::zeros(),
            dvv: Vec3::zeros(),
        };
        assert_eq!(e.normal(), None);
        assert_eq!(e.mean_curvature(), None);
    }
}
