//! Exact single-triangle queries: closest point (Ericson's Voronoi-region test) and the
//! watertight ray–triangle test of Woop, Benthin and Wald (JCGT 2013).

use crate::math::{Real, Vec3};

/// The part of a triangle a closest point lies on. Corners are numbered 0, 1, 2 as in the mesh;
/// `Edge(k)` joins corners `k` and `(k + 1) % 3`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Feature {
    Vertex(u8),
    Edge(u8),
    Face,
}

/// Closest point of a triangle to a query point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrianglePoint {
    pub point: Vec3,
    /// Weights of corners 0, 1, 2 (non-negative, summing to 1).
    pub barycentric: [Real; 3],
    pub feature: Feature,
}

/// `n / d` clamped to [0, 1]; 0 when `d` is not positive (degenerate edge).
#[inline]
fn ratio(n: Real, d: Real) -> Real {
    if d > 0.0 {
        (n / d).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// Closest point of segment `k` (corners `k`, `k + 1`) to `p`.
fn on_edge(p: &Vec3, tri: &[Vec3; 3], k: usize) -> TrianglePoint {
    let (a, b) = (tri[k], tri[(k + 1) % 3]);
    let e = b - a;
    let t = ratio((p - a).dot(&e), e.norm_squared());
    let mut barycentric = [0.0; 3];
    barycentric[k] = 1.0 - t;
    barycentric[(k + 1) % 3] = t;
    let (point, feature) = if t <= 0.0 {
        (a, Feature::Vertex(k as u8))
    } else if t >= 1.0 {
        (b, Feature::Vertex(((k + 1) % 3) as u8))
    } else {
        (a + e * t, Feature::Edge(k as u8))
    };
    TrianglePoint {
        point,
        barycentric,
        feature,
    }
}

/// Exact closest point of triangle `tri` to `p` (Ericson, *Real-Time Collision Detection* §5.1.5),
/// classifying it as on a vertex, an edge or the interior. Triangles that are flat at corner 0
/// (sin² of its angle below 1e-4, including zero-area ones) are handled by projecting onto the
/// plane and testing the three edges, which stays accurate where the region test cancels.
pub fn closest_point_on_triangle(p: &Vec3, tri: &[Vec3; 3]) -> TrianglePoint {
    let [a, b, c] = *tri;
    let vertex = |k: u8, point: Vec3| {
        let mut barycentric = [0.0; 3];
        barycentric[k as usize] = 1.0;
        TrianglePoint {
            point,
            barycentric,
            feature: Feature::Vertex(k),
        }
    };
    let edge = |k: u8, point: Vec3, barycentric: [Real; 3]| TrianglePoint {
        point,
        barycentric,
        feature: Feature::Edge(k),
    };
    let ab = b - a;
    let ac = c - a;
    let n = ab.cross(&ac);
    // Flat or needle-like at corner 0: the Gram-determinant region test below would cancel
    // catastrophically; project onto the plane (the cross product keeps its accuracy) instead.
    let nn = n.norm_squared();
    if nn.is_nan() || nn <= 1e-4 * ab.norm_squared() * ac.norm_squared() {
        return closest_point_flat(p, tri, &n);
    }
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return vertex(0, a);
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return vertex(1, b);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 && d1 - d3 > 0.0 {
        let v = ratio(d1, d1 - d3);
        return edge(0, a + ab * v, [1.0 - v, v, 0.0]);
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return vertex(2, c);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 && d2 - d6 > 0.0 {
        let w = ratio(d2, d2 - d6);
        return edge(2, a + ac * w, [1.0 - w, 0.0, w]);
    }
    let va = d3 * d6 - d5 * d4;
    let (e4, e5) = (d4 - d3, d5 - d6);
    if va <= 0.0 && e4 >= 0.0 && e5 >= 0.0 && e4 + e5 > 0.0 {
        let w = ratio(e4, e4 + e5);
        return edge(1, b + (c - b) * w, [0.0, 1.0 - w, w]);
    }
    let denom = va + vb + vc;
    let (v, w) = (vb / denom, vc / denom);
    if denom > 0.0 && v >= 0.0 && w >= 0.0 && v + w <= 1.0 {
        return TrianglePoint {
            point: a + ab * v + ac * w,
            barycentric: [1.0 - v - w, v, w],
            feature: Feature::Face,
        };
    }
    // Rounding left no valid interior solution.
    closest_point_flat(p, tri, &n)
}

/// Closest point by projection onto the plane of the triangle (normal `n`, possibly zero): the
/// projection if it falls inside, else the nearest point of the three edges.
fn closest_point_flat(p: &Vec3, tri: &[Vec3; 3], n: &Vec3) -> TrianglePoint {
    let [a, b, c] = *tri;
    if let Some(n) = n.try_normalize(0.0) {
        let q = p - n * n.dot(&(p - a));
        // Signed sub-areas opposite each corner.
        let wa = (c - b).cross(&(q - b)).dot(&n);
        let wb = (a - c).cross(&(q - c)).dot(&n);
        let wc = (b - a).cross(&(q - a)).dot(&n);
        let sum = wa + wb + wc;
        if wa > 0.0 && wb > 0.0 && wc > 0.0 && sum.is_finite() {
            return TrianglePoint {
                point: q,
                barycentric: [wa / sum, wb / sum, wc / sum],
                feature: Feature::Face,
            };
        }
    }
    let dist = |t: &TrianglePoint| (p - t.point).norm_squared();
    let (e0, e1, e2) = (on_edge(p, tri, 0), on_edge(p, tri, 1), on_edge(p, tri, 2));
    let best = if dist(&e1) < dist(&e0) { e1 } else { e0 };
    if dist(&e2) < dist(&best) { e2 } else { best }
}

/// A ray prepared for the watertight test: the permuted axes and the shear that maps the ray
/// direction onto +z.
#[derive(Debug, Clone, Copy)]
pub(crate) struct WatertightRay {
    origin: Vec3,
    k: [usize; 3],
    shear: [Real; 3],
}

impl WatertightRay {
    /// `None` for a non-finite origin or a zero or non-finite direction.
    pub(crate) fn new(origin: &Vec3, direction: &Vec3) -> Option<Self> {
        if origin
            .iter()
            .chain(direction.iter())
            .any(|c| !c.is_finite())
        {
            return None;
        }
        let kz = direction.iamax();
        if direction[kz] == 0.0 {
            return None;
        }
        let (mut kx, mut ky) = ((kz + 1) % 3, (kz + 2) % 3);
        if direction[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let sz = 1.0 / direction[kz];
        Some(Self {
            origin: *origin,
            k: [kx, ky, kz],
            shear: [direction[kx] * sz, direction[ky] * sz, sz],
        })
    }

    /// Hit parameter `t` in `[t_min, t_max]` and barycentrics of corners 0, 1, 2.
    ///
    /// Points exactly on an edge or vertex (edge function exactly 0) are resolved by symbolic
    /// perturbation of the ray origin by `(ε, ε²)` in the sheared plane (a top-left rule): of the
    /// triangles sharing an edge or vertex that the ray crosses transversally, exactly one reports
    /// the hit. The edge functions of a shared edge are exact negatives of each other, so no ray
    /// slips between neighbours either.
    pub(crate) fn intersect(
        &self,
        tri: &[Vec3; 3],
        t_min: Real,
        t_max: Real,
    ) -> Option<(Real, [Real; 3])> {
        let [kx, ky, kz] = self.k;
        let [sx, sy, sz] = self.shear;
        let rel = tri.map(|v| v - self.origin);
        let xy = rel.map(|v| (v[kx] - sx * v[kz], v[ky] - sy * v[kz]));
        let [(ax, ay), (bx, by), (cx, cy)] = xy;
        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        let det = u + v + w;
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let s = det.signum();
        // Edge function `e` of edge P→Q grows along perp(Q − P) = (gx, gy).
        let inside = |e: Real, gx: Real, gy: Real| {
            let e = e * s;
            e > 0.0 || (e == 0.0 && (gx * s > 0.0 || (gx == 0.0 && gy * s > 0.0)))
        };
        if !inside(u, -(by - cy), bx - cx)
            || !inside(v, -(cy - ay), cx - ax)
            || !inside(w, -(ay - by), ax - bx)
        {
            return None;
        }
        let t = (u * rel[0][kz] + v * rel[1][kz] + w * rel[2][kz]) * sz / det;
        (t >= t_min && t <= t_max).then(|| (t, [u / det, v / det, w / det]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::tests::Rng;

    /// `q` is the projection of `p` onto the triangle iff `q` is in it and
    /// `(p − q)·(x − q) ≤ 0` for every corner `x`.
    #[test]
    fn closest_point_is_the_projection() {
        let mut rng = Rng(7);
        for case in 0..20_000 {
            let mut tri = [rng.point(5.0), rng.point(5.0), rng.point(5.0)];
            match case % 5 {
                1 => tri[2] = tri[0] + (tri[1] - tri[0]) * rng.unit(), // collinear
                2 => tri[1] = tri[0],                                  // repeated corner
                3 => tri[2] = tri[1] + rng.point(1e-9),                // needle
                _ => {}
            }
            let p = rng.point(10.0);
            let tp = closest_point_on_triangle(&p, &tri);
            let b = tp.barycentric;
            assert!(b.iter().all(|&x| x >= 0.0), "{b:?}");
            assert!((b.iter().sum::<Real>() - 1.0).abs() <= 1e-12);
            let q = tri[0] * b[0] + tri[1] * b[1] + tri[2] * b[2];
            assert!((q - tp.point).norm() <= 1e-12 * 10.0, "case {case}");
            for x in &tri {
                assert!(
                    (p - tp.point).dot(&(x - tp.point)) <= 1e-9,
                    "case {case} {tri:?} {p:?} {tp:?} {}",
                    (p - tp.point).dot(&(x - tp.point))
                );
            }
            match tp.feature {
                Feature::Vertex(k) => assert_eq!(b[k as usize], 1.0),
                Feature::Edge(k) => assert_eq!(b[(k as usize + 2) % 3], 0.0),
                Feature::Face => assert!(b.iter().all(|&x| x > 0.0)),
            }
        }
    }

    #[test]
    fn watertight_hit_parameter_and_barycentrics() {
        let tri = [
            Vec3::new(0.0, 0.0, 2.0),
            Vec3::new(3.0, 0.0, 2.0),
            Vec3::new(0.0, 3.0, 2.0),
        ];
        let ray =
            WatertightRay::new(&Vec3::new(1.0, 0.5, -1.0), &Vec3::new(0.0, 0.0, 0.5)).unwrap();
        let (t, b) = ray.intersect(&tri, 0.0, Real::INFINITY).unwrap();
        assert!((t - 6.0).abs() <= 1e-15);
        let hit = tri[0] * b[0] + tri[1] * b[1] + tri[2] * b[2];
        assert!((hit - Vec3::new(1.0, 0.5, 2.0)).norm() <= 1e-15);
        assert!(ray.intersect(&tri, 0.0, 5.9).is_none());
        let away =
            WatertightRay::new(&Vec3::new(1.0, 0.5, -1.0), &Vec3::new(0.0, 0.0, -1.0)).unwrap();
        assert!(away.intersect(&tri, 0.0, Real::INFINITY).is_none());
        assert!(WatertightRay::new(&Vec3::zeros(), &Vec3::zeros()).is_none());
    }
}
