//! Convex solids with exact inside tests, signed distances and nearest boundary points.

use resecta_geom::{Mat3, Real, Vec3};

/// A closed convex solid in world millimetres.
#[derive(Debug, Clone, PartialEq)]
pub enum Solid {
    /// `{centre + axes·diag(radii)·u : |u| ≤ 1}`; `axes` orthonormal columns.
    Ellipsoid {
        center: Vec3,
        axes: Mat3,
        radii: [Real; 3],
    },
    Ball {
        center: Vec3,
        radius: Real,
    },
    /// Points within `radius` of the segment `a–b`.
    Capsule {
        a: Vec3,
        b: Vec3,
        radius: Real,
    },
}

impl Solid {
    /// Whether `p` lies in the closed solid.
    pub fn contains(&self, p: Vec3) -> bool {
        match self {
            Solid::Ellipsoid {
                center,
                axes,
                radii,
            } => {
                let q = axes.transpose() * (p - center);
                ellipsoid_level(q, *radii) <= 1.0
            }
            Solid::Ball { center, radius } => (p - center).norm_squared() <= radius * radius,
            Solid::Capsule { a, b, radius } => {
                (p - closest_on_segment(*a, *b, p)).norm_squared() <= radius * radius
            }
        }
    }

    /// Exact signed distance to the boundary: negative inside.
    pub fn signed_distance(&self, p: Vec3) -> Real {
        self.nearest_boundary(p).1
    }

    /// A nearest boundary point of `p` and the signed distance to it (negative inside).
    pub fn nearest_boundary(&self, p: Vec3) -> (Vec3, Real) {
        match self {
            Solid::Ellipsoid {
                center,
                axes,
                radii,
            } => {
                let q = axes.transpose() * (p - center);
                let (x, d) = ellipsoid_nearest(*radii, [q.x, q.y, q.z]);
                let inside = ellipsoid_level(q, *radii) < 1.0;
                (center + axes * Vec3::from(x), if inside { -d } else { d })
            }
            Solid::Ball { center, radius } => {
                let (u, d) = unit_or_x(p - center);
                (center + u * *radius, d - radius)
            }
            Solid::Capsule { a, b, radius } => {
                let c = closest_on_segment(*a, *b, p);
                let (u, d) = unit_or_perpendicular(p - c, b - a);
                (c + u * *radius, d - radius)
            }
        }
    }

    /// A cheap lower bound `φ` of the signed distance: same sign, `|φ| ≤ |exact|`.
    pub fn distance_bound(&self, p: Vec3) -> Real {
        match self {
            Solid::Ellipsoid {
                center,
                axes,
                radii,
            } => {
                // ρ(q) = |q/r| has gradient ≤ 1/r_min, so r_min·(ρ − 1) is 1-Lipschitz, zero on
                // the surface and of the right sign: a conservative distance.
                let q = axes.transpose() * (p - center);
                let rho = (0..3)
                    .map(|i| (q[i] / radii[i]).powi(2))
                    .sum::<Real>()
                    .sqrt();
                let rmin = radii.iter().copied().fold(Real::INFINITY, Real::min);
                rmin * (rho - 1.0)
            }
            Solid::Ball { .. } | Solid::Capsule { .. } => self.signed_distance(p),
        }
    }

    /// Outward unit normal at a boundary point `s`.
    pub fn normal(&self, s: Vec3) -> Vec3 {
        match self {
            Solid::Ellipsoid {
                center,
                axes,
                radii,
            } => {
                let q = axes.transpose() * (s - center);
                let g = Vec3::new(
                    q.x / (radii[0] * radii[0]),
                    q.y / (radii[1] * radii[1]),
                    q.z / (radii[2] * radii[2]),
                );
                unit_or_x(axes * g).0
            }
            Solid::Ball { center, .. } => unit_or_x(s - center).0,
            Solid::Capsule { a, b, .. } => {
                unit_or_perpendicular(s - closest_on_segment(*a, *b, s), b - a).0
            }
        }
    }

    /// Radius of a ball that rolls freely inside (the smallest principal radius of curvature).
    pub fn rolling_radius(&self) -> Real {
        match self {
            Solid::Ellipsoid { radii, .. } => {
                let max = radii.iter().copied().fold(0.0, Real::max);
                let min = radii.iter().copied().fold(Real::INFINITY, Real::min);
                min * min / max
            }
            Solid::Ball { radius, .. } | Solid::Capsule { radius, .. } => *radius,
        }
    }

    /// Exact volume in mm³.
    pub fn volume(&self) -> Real {
        use std::f64::consts::PI;
        match self {
            Solid::Ellipsoid { radii, .. } => 4.0 / 3.0 * PI * radii[0] * radii[1] * radii[2],
            Solid::Ball { radius, .. } => 4.0 / 3.0 * PI * radius.powi(3),
            Solid::Capsule { a, b, radius } => {
                PI * radius * radius * (b - a).norm() + 4.0 / 3.0 * PI * radius.powi(3)
            }
        }
    }

    /// Axis-aligned bounds `(lo, hi)` of the image of the solid under the linear map `m`.
    pub fn extent_under(&self, m: &Mat3) -> (Vec3, Vec3) {
        match self {
            Solid::Ellipsoid {
                center,
                axes,
                radii,
            } => {
                let s = m * axes * Mat3::from_diagonal(&Vec3::from(*radii));
                let c = m * center;
                let e = Vec3::from_fn(|i, _| s.row(i).norm());
                (c - e, c + e)
            }
            Solid::Ball { center, radius } => {
                let c = m * center;
                let e = Vec3::from_fn(|i, _| m.row(i).norm() * radius);
                (c - e, c + e)
            }
            Solid::Capsule { a, b, radius } => {
                let (ma, mb) = (m * a, m * b);
                let e = Vec3::from_fn(|i, _| m.row(i).norm() * radius);
                (ma.inf(&mb) - e, ma.sup(&mb) + e)
            }
        }
    }
}

/// Nearest point of segment `a–b` to `p`.
pub fn closest_on_segment(a: Vec3, b: Vec3, p: Vec3) -> Vec3 {
    let ab = b - a;
    let l2 = ab.norm_squared();
    if l2 == 0.0 {
        return a;
    }
    a + ab * ((p - a).dot(&ab) / l2).clamp(0.0, 1.0)
}

/// `Σ (qᵢ/rᵢ)²`: below 1 inside the axis-aligned ellipsoid of radii `radii`.
fn ellipsoid_level(q: Vec3, radii: [Real; 3]) -> Real {
    (0..3).map(|i| (q[i] / radii[i]).powi(2)).sum()
}

/// Distance between segments `p1–q1` and `p2–q2` (Ericson, Real-Time Collision Detection 5.1.9).
pub fn segment_distance(p1: Vec3, q1: Vec3, p2: Vec3, q2: Vec3) -> Real {
    let (d1, d2, r) = (q1 - p1, q2 - p2, p1 - p2);
    let (a, e, f) = (d1.norm_squared(), d2.norm_squared(), d2.dot(&r));
    let (s, t) = if a == 0.0 && e == 0.0 {
        (0.0, 0.0)
    } else if a == 0.0 {
        (0.0, (f / e).clamp(0.0, 1.0))
    } else {
        let c = d1.dot(&r);
        if e == 0.0 {
            ((-c / a).clamp(0.0, 1.0), 0.0)
        } else {
            let b = d1.dot(&d2);
            let denom = a * e - b * b;
            let mut s = if denom > 0.0 {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let mut t = (b * s + f) / e;
            if t < 0.0 {
                t = 0.0;
                s = (-c / a).clamp(0.0, 1.0);
            } else if t > 1.0 {
                t = 1.0;
                s = ((b - c) / a).clamp(0.0, 1.0);
            }
            (s, t)
        }
    };
    ((p1 + d1 * s) - (p2 + d2 * t)).norm()
}

fn unit_or_x(v: Vec3) -> (Vec3, Real) {
    let n = v.norm();
    if n > 0.0 {
        (v / n, n)
    } else {
        (Vec3::x(), 0.0)
    }
}

/// Unit `v`, or any unit vector perpendicular to `axis` when `v` is zero.
fn unit_or_perpendicular(v: Vec3, axis: Vec3) -> (Vec3, Real) {
    let n = v.norm();
    if n > 0.0 {
        return (v / n, n);
    }
    let trial = if axis.x.abs() < 0.9 * axis.norm() {
        Vec3::x()
    } else {
        Vec3::y()
    };
    (unit_or_x(axis.cross(&trial)).0, 0.0)
}

/// Nearest point of the ellipsoid surface `Σ (xᵢ/eᵢ)² = 1` to `y`, and its (unsigned) distance.
///
/// Eberly, "Distance from a point to an ellipse, an ellipsoid, or a hyperellipsoid" (2013): robust
/// bisection on the Lagrange parameter, valid inside and outside.
pub fn ellipsoid_nearest(e: [Real; 3], y: [Real; 3]) -> ([Real; 3], Real) {
    // Sort the axes by decreasing radius and fold y into the first octant.
    let mut perm = [0usize, 1, 2];
    perm.sort_by(|&a, &b| e[b].total_cmp(&e[a]));
    let es = perm.map(|i| e[i]);
    let ys = perm.map(|i| y[i].abs());
    let xs = octant_nearest(es, ys);
    let mut x = [0.0; 3];
    for (k, &i) in perm.iter().enumerate() {
        x[i] = xs[k].copysign(y[i]);
    }
    let d = (0..3).map(|i| (x[i] - y[i]).powi(2)).sum::<Real>().sqrt();
    (x, d)
}

fn octant_nearest(e: [Real; 3], y: [Real; 3]) -> [Real; 3] {
    let [e0, e1, e2] = e;
    let [y0, y1, y2] = y;
    if y2 > 0.0 {
        if y1 > 0.0 {
            if y0 > 0.0 {
                let z = [y0 / e0, y1 / e1, y2 / e2];
                let g = z[0] * z[0] + z[1] * z[1] + z[2] * z[2] - 1.0;
                if g == 0.0 {
                    return y;
                }
                let r = [(e0 / e2).powi(2), (e1 / e2).powi(2), 1.0];
                let s = root(r, z, g);
                [
                    r[0] * y0 / (s + r[0]),
                    r[1] * y1 / (s + r[1]),
                    y2 / (s + 1.0),
                ]
            } else {
                let [a, b] = ellipse_nearest([e1, e2], [y1, y2]);
                [0.0, a, b]
            }
        } else if y0 > 0.0 {
            let [a, b] = ellipse_nearest([e0, e2], [y0, y2]);
            [a, 0.0, b]
        } else {
            [0.0, 0.0, e2]
        }
    } else {
        let (d0, d1) = (e0 * e0 - e2 * e2, e1 * e1 - e2 * e2);
        let (n0, n1) = (e0 * y0, e1 * y1);
        if n0 < d0 && n1 < d1 {
            let (x0, x1) = (n0 / d0, n1 / d1);
            let discr = 1.0 - x0 * x0 - x1 * x1;
            if discr > 0.0 {
                return [e0 * x0, e1 * x1, e2 * discr.sqrt()];
            }
        }
        let [a, b] = ellipse_nearest([e0, e1], [y0, y1]);
        [a, b, 0.0]
    }
}

fn ellipse_nearest(e: [Real; 2], y: [Real; 2]) -> [Real; 2] {
    let [e0, e1] = e;
    let [y0, y1] = y;
    if y1 > 0.0 {
        if y0 > 0.0 {
            let z = [y0 / e0, y1 / e1, 0.0];
            let g = z[0] * z[0] + z[1] * z[1] - 1.0;
            if g == 0.0 {
                return y;
            }
            let r = [(e0 / e1).powi(2), 1.0, 1.0];
            let s = root(r, z, g);
            [r[0] * y0 / (s + r[0]), y1 / (s + 1.0)]
        } else {
            [0.0, e1]
        }
    } else {
        let (n0, d0) = (e0 * y0, e0 * e0 - e1 * e1);
        if n0 < d0 {
            let x0 = n0 / d0;
            [e0 * x0, e1 * (1.0 - x0 * x0).sqrt()]
        } else {
            [e0, 0.0]
        }
    }
}

/// Root `s` of `F(s) = Σ (rᵢzᵢ/(s + rᵢ))² − 1` (unused `z` are 0): `F` is convex and decreasing,
/// so Newton from the lower bracket end rises monotonically to the root; bisection finishes
/// should rounding stall it.
fn root(r: [Real; 3], z: [Real; 3], g: Real) -> Real {
    let n = [r[0] * z[0], r[1] * z[1], r[2] * z[2]];
    let nz = if z[2] == 0.0 { z[1] } else { z[2] };
    let mut s0 = nz - 1.0;
    let mut s1 = if g < 0.0 {
        0.0
    } else {
        (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0
    };
    let f = |s: Real| {
        let mut v = -1.0;
        let mut dv = 0.0;
        for i in 0..3 {
            let t = n[i] / (s + r[i]);
            v += t * t;
            dv -= 2.0 * t * t / (s + r[i]);
        }
        (v, dv)
    };
    let mut s = s0;
    for _ in 0..64 {
        let (v, dv) = f(s);
        if v <= 0.0 || dv >= 0.0 {
            break;
        }
        let next = s - v / dv;
        if !(next > s && next < s1) {
            break;
        }
        let step = next - s;
        s = next;
        s0 = s;
        if step <= 1e-14 * s.abs().max(1.0) {
            break;
        }
    }
    // Tighten the upper end next to the Newton limit, then bisect to machine precision.
    let near = s0 + 1e-12 * s0.abs().max(1.0);
    if near < s1 && f(near).0 <= 0.0 {
        s1 = near;
    }
    for _ in 0..2200 {
        let m = 0.5 * (s0 + s1);
        if m == s0 || m == s1 {
            return m;
        }
        let (v, _) = f(m);
        if v > 0.0 {
            s0 = m;
        } else if v < 0.0 {
            s1 = m;
        } else {
            return m;
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    fn brute_ellipsoid_distance(e: [Real; 3], y: Vec3) -> Real {
        // Dense sampling of the surface; the minimum over samples overestimates slightly.
        let mut best = Real::INFINITY;
        let n = 400;
        for a in 0..=n {
            let th = std::f64::consts::PI * a as Real / n as Real;
            for b in 0..2 * n {
                let ph = std::f64::consts::PI * b as Real / n as Real;
                let s = Vec3::new(
                    e[0] * th.sin() * ph.cos(),
                    e[1] * th.sin() * ph.sin(),
                    e[2] * th.cos(),
                );
                best = best.min((s - y).norm());
            }
        }
        best
    }

    #[test]
    fn ellipsoid_distance_matches_dense_sampling() {
        let e = [30.0, 12.0, 20.0];
        for y in [
            Vec3::new(40.0, 3.0, -5.0),
            Vec3::new(1.0, 2.0, 3.0),
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(-10.0, 0.0, 25.0),
            Vec3::new(29.0, 0.0, 0.0),
            Vec3::new(5.0, -11.0, 0.0),
        ] {
            let (x, d) = ellipsoid_nearest(e, [y.x, y.y, y.z]);
            let on = (0..3).map(|i| (x[i] / e[i]).powi(2)).sum::<Real>();
            assert!((on - 1.0).abs() < 1e-9, "not on surface: {on}");
            let b = brute_ellipsoid_distance(e, y);
            // Sampling step ≤ 30·π/400 ≈ 0.24 mm, so the samples are within 0.03 mm of optimal.
            assert!(d <= b + 1e-9 && b - d < 0.03, "{y:?}: {d} vs sampled {b}");
        }
    }

    #[test]
    fn solids_agree_on_inside_and_distance() {
        let axes = Rotation3::from_euler_angles(0.3, -0.4, 1.1).into_inner();
        let solids = [
            Solid::Ellipsoid {
                center: Vec3::new(1.0, 2.0, 3.0),
                axes,
                radii: [20.0, 10.0, 14.0],
            },
            Solid::Ball {
                center: Vec3::new(-2.0, 0.0, 1.0),
                radius: 7.0,
            },
            Solid::Capsule {
                a: Vec3::new(-5.0, 0.0, 0.0),
                b: Vec3::new(10.0, 4.0, -3.0),
                radius: 3.0,
            },
        ];
        for s in &solids {
            for k in 0..500 {
                let t = k as Real;
                let p = Vec3::new(
                    25.0 * (0.37 * t).sin(),
                    18.0 * (0.11 * t).cos(),
                    15.0 * (0.23 * t).sin(),
                );
                let (b, d) = s.nearest_boundary(p);
                assert_eq!(d <= 0.0, s.contains(p), "{s:?} at {p:?}");
                assert!(((b - p).norm() - d.abs()).abs() < 1e-9);
                let phi = s.distance_bound(p);
                assert!(phi * d >= 0.0 && phi.abs() <= d.abs() + 1e-9);
                // Nudging the boundary point along the normal crosses the surface.
                let n = s.normal(b);
                assert!(s.contains(b - n * 1e-6) && !s.contains(b + n * 1e-6));
            }
        }
    }

    #[test]
    fn segment_distance_cases() {
        let z = Vec3::zeros();
        let x = Vec3::x() * 10.0;
        // Parallel, crossing, skew, degenerate.
        let d = segment_distance(z, x, Vec3::new(0.0, 3.0, 0.0), Vec3::new(10.0, 3.0, 0.0));
        assert!((d - 3.0).abs() < 1e-12);
        let d = segment_distance(z, x, Vec3::new(5.0, -1.0, 2.0), Vec3::new(5.0, 1.0, 2.0));
        assert!((d - 2.0).abs() < 1e-12);
        let d = segment_distance(z, x, Vec3::new(12.0, 0.0, 0.0), Vec3::new(12.0, 0.0, 0.0));
        assert!((d - 2.0).abs() < 1e-12);
    }
}
