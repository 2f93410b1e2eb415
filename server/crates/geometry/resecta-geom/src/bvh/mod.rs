//! Bounding-volume hierarchy over the triangles of a [`TriMesh`]: exact closest points, ray
//! casting and (in [`MeshSdf`]) signed distance and inside/outside.
//!
//! The tree is built top-down with a binned surface-area heuristic (16 bins on the longest centroid
//! axis, median split as fallback), O(n log n), into a flat node array whose children are adjacent.
//! It owns copies of the triangle corners in leaf order, so it is independent of the mesh and
//! `Send + Sync`. Node boxes are inflated by a tiny absolute margin (1e-9 of the largest coordinate
//! magnitude) so box tests stay conservative under rounding; results are exactly those of a brute
//! force over all triangles with the same per-triangle routines.

mod sdf;
mod triangle;

use rayon::prelude::*;

pub use sdf::{MeshSdf, SignedDistance};
pub use triangle::{Feature, TrianglePoint, closest_point_on_triangle};

use crate::error::GeomError;
use crate::math::{Real, Vec3};
use crate::mesh::TriMesh;
use triangle::WatertightRay;

/// Largest number of triangles in a leaf.
const MAX_LEAF: usize = 4;
/// SAH bins.
const BINS: usize = 16;

/// Axis-aligned box; empty when `min > max`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

impl Aabb {
    pub fn empty() -> Self {
        Self {
            min: Vec3::repeat(Real::INFINITY),
            max: Vec3::repeat(Real::NEG_INFINITY),
        }
    }

    fn of_triangle(t: &[Vec3; 3]) -> Self {
        Self {
            min: t[0].inf(&t[1]).inf(&t[2]),
            max: t[0].sup(&t[1]).sup(&t[2]),
        }
    }

    pub fn union(&self, o: &Self) -> Self {
        Self {
            min: self.min.inf(&o.min),
            max: self.max.sup(&o.max),
        }
    }

    fn grow(&mut self, p: &Vec3) {
        self.min = self.min.inf(p);
        self.max = self.max.sup(p);
    }

    fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// Surface area (0 when empty).
    fn area(&self) -> Real {
        let d = (self.max - self.min).sup(&Vec3::zeros());
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }

    /// Squared distance from `p` to the box (0 inside).
    #[inline]
    pub fn distance_squared(&self, p: &Vec3) -> Real {
        (self.min - p)
            .sup(&(p - self.max))
            .sup(&Vec3::zeros())
            .norm_squared()
    }

    /// Entry parameter of the ray `origin + t·dir` (`inv` = 1/dir componentwise) within
    /// `[t_min, t_max]`, or `None` if it misses. Axes where rounding yields NaN do not constrain.
    #[inline]
    fn ray_entry(&self, origin: &Vec3, inv: &Vec3, t_min: Real, t_max: Real) -> Option<Real> {
        let (mut lo, mut hi) = (t_min, t_max);
        for k in 0..3 {
            let t1 = (self.min[k] - origin[k]) * inv[k];
            let t2 = (self.max[k] - origin[k]) * inv[k];
            if t1.is_nan() || t2.is_nan() {
                continue;
            }
            lo = lo.max(t1.min(t2));
            hi = hi.min(t1.max(t2));
        }
        (lo <= hi).then_some(lo)
    }
}

/// A node: a leaf holds `count > 0` triangles from `first`; an inner node (`count == 0`) has its
/// children at `first` and `first + 1`.
#[derive(Debug, Clone, Copy)]
struct Node {
    bounds: Aabb,
    first: u32,
    count: u32,
}

/// Closest point of a mesh to a query point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClosestPoint {
    pub point: Vec3,
    /// Euclidean distance to the query point (mm).
    pub distance: Real,
    /// Index of the triangle in the mesh.
    pub triangle: usize,
    /// Weights of the triangle's corners 0, 1, 2.
    pub barycentric: [Real; 3],
    pub feature: Feature,
}

/// A ray `origin + t·direction`; `t` is in units of `‖direction‖`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    pub origin: Vec3,
    pub direction: Vec3,
}

/// Where a ray crosses a triangle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayHit {
    pub t: Real,
    pub point: Vec3,
    pub triangle: usize,
    /// Weights of the triangle's corners 0, 1, 2.
    pub barycentric: [Real; 3],
    /// The ray meets the triangle's front (counter-clockwise) side: entering an outward mesh.
    pub front_face: bool,
}

/// Bounding-volume hierarchy over a mesh's triangles.
#[derive(Debug, Clone)]
pub struct MeshBvh {
    nodes: Vec<Node>,
    /// Triangle corners in leaf order.
    tris: Vec<[Vec3; 3]>,
    /// Mesh index of each entry of `tris`.
    ids: Vec<u32>,
}

impl MeshBvh {
    /// Builds the hierarchy over all triangles of `mesh` (an empty mesh gives an empty tree).
    pub fn new(mesh: &TriMesh) -> Result<Self, GeomError> {
        let n = mesh.triangles().len();
        let limit = (u32::MAX / 2) as usize;
        if n > limit {
            return Err(GeomError::TooManyTriangles { limit });
        }
        let corners: Vec<[Vec3; 3]> = (0..n).map(|t| mesh.corners(t)).collect();
        let bounds: Vec<Aabb> = corners.iter().map(Aabb::of_triangle).collect();
        let centroids: Vec<Vec3> = bounds.iter().map(Aabb::center).collect();
        let scale = mesh
            .vertices()
            .iter()
            .fold(1.0 as Real, |m, v| m.max(v.amax()));
        let pad = Vec3::repeat(scale * 1e-9);
        let mut order: Vec<u32> = (0..n as u32).collect();
        let mut nodes = Vec::with_capacity((2 * n).saturating_sub(1));
        if n > 0 {
            nodes.push(Node {
                bounds: Aabb::empty(),
                first: 0,
                count: 0,
            });
        }
        let mut stack = vec![(0usize, 0usize, n)];
        while let Some((node, start, end)) = stack.pop().filter(|_| n > 0) {
            let items = &mut order[start..end];
            let (mut bb, mut cb) = (Aabb::empty(), Aabb::empty());
            for &t in items.iter() {
                bb = bb.union(&bounds[t as usize]);
                cb.grow(&centroids[t as usize]);
            }
            bb.min -= pad;
            bb.max += pad;
            if items.len() <= MAX_LEAF {
                nodes[node] = Node {
                    bounds: bb,
                    first: start as u32,
                    count: items.len() as u32,
                };
                continue;
            }
            let mid = start + split(items, &bounds, &centroids, &cb);
            let left = nodes.len();
            nodes[node] = Node {
                bounds: bb,
                first: left as u32,
                count: 0,
            };
            // Reserve the two child slots; each is overwritten when it is popped.
            let reserved = nodes[node];
            nodes.extend([reserved, reserved]);
            stack.push((left + 1, mid, end));
            stack.push((left, start, mid));
        }
        let tris = order.iter().map(|&t| corners[t as usize]).collect();
        Ok(Self {
            nodes,
            tris,
            ids: order,
        })
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// Bounds of the mesh (slightly inflated), `None` when empty.
    pub fn bounds(&self) -> Option<Aabb> {
        self.nodes.first().map(|n| n.bounds)
    }

    /// Exact closest point of the mesh to `p`; `None` for an empty mesh or non-finite `p`.
    pub fn closest_point(&self, p: &Vec3) -> Option<ClosestPoint> {
        self.closest_point_within(p, Real::INFINITY)
    }

    /// Closest point if it is within `max_distance` of `p` (inclusive); prunes the search to that
    /// radius, so small radii are cheap.
    pub fn closest_point_within(&self, p: &Vec3, max_distance: Real) -> Option<ClosestPoint> {
        if self.nodes.is_empty()
            || p.iter().any(|c| !c.is_finite())
            || max_distance.is_nan()
            || max_distance < 0.0
        {
            return None;
        }
        let mut best_d2 = max_distance * max_distance;
        let mut best: Option<(usize, TrianglePoint)> = None;
        // (node, squared distance to its box)
        let mut stack: Vec<(u32, Real)> = Vec::with_capacity(64);
        stack.push((0, self.nodes[0].bounds.distance_squared(p)));
        while let Some((i, box_d2)) = stack.pop() {
            if box_d2 > best_d2 {
                continue;
            }
            let node = &self.nodes[i as usize];
            let first = node.first as usize;
            if node.count > 0 {
                for (k, tri) in self.tris[first..first + node.count as usize]
                    .iter()
                    .enumerate()
                {
                    let tp = closest_point_on_triangle(p, tri);
                    let d2 = (p - tp.point).norm_squared();
                    if d2 < best_d2 || (best.is_none() && d2 <= best_d2) {
                        best_d2 = d2;
                        best = Some((first + k, tp));
                    }
                }
            } else {
                let dl = self.nodes[first].bounds.distance_squared(p);
                let dr = self.nodes[first + 1].bounds.distance_squared(p);
                let (near, far, dn, df) = if dl <= dr {
                    (first, first + 1, dl, dr)
                } else {
                    (first + 1, first, dr, dl)
                };
                if df <= best_d2 {
                    stack.push((far as u32, df));
                }
                if dn <= best_d2 {
                    stack.push((near as u32, dn));
                }
            }
        }
        best.map(|(i, tp)| ClosestPoint {
            point: tp.point,
            distance: (p - tp.point).norm(),
            triangle: self.ids[i] as usize,
            barycentric: tp.barycentric,
            feature: tp.feature,
        })
    }

    /// [`Self::closest_point`] for many points, in parallel (rayon), in input order.
    pub fn closest_points(&self, points: &[Vec3]) -> Vec<Option<ClosestPoint>> {
        points.par_iter().map(|p| self.closest_point(p)).collect()
    }

    /// [`Self::closest_point_within`] for many points, in parallel, in input order.
    pub fn closest_points_within(
        &self,
        points: &[Vec3],
        max_distance: Real,
    ) -> Vec<Option<ClosestPoint>> {
        points
            .par_iter()
            .map(|p| self.closest_point_within(p, max_distance))
            .collect()
    }

    fn hit(&self, ray: &Ray, i: usize, t: Real, barycentric: [Real; 3]) -> RayHit {
        let [a, b, c] = self.tris[i];
        RayHit {
            t,
            point: a * barycentric[0] + b * barycentric[1] + c * barycentric[2],
            triangle: self.ids[i] as usize,
            barycentric,
            front_face: ray.direction.dot(&(b - a).cross(&(c - a))) < 0.0,
        }
    }

    /// Visits every leaf whose box the ray meets within `[t_min, *t_max]`, nearer children first;
    /// `visit` may shrink `t_max`.
    fn traverse_ray(
        &self,
        ray: &Ray,
        t_min: Real,
        t_max: &mut Real,
        mut visit: impl FnMut(&WatertightRay, usize, &mut Real),
    ) {
        let Some(wr) = WatertightRay::new(&ray.origin, &ray.direction) else {
            return;
        };
        if self.nodes.is_empty() || t_min.is_nan() || t_max.is_nan() || t_min > *t_max {
            return;
        }
        let inv = ray.direction.map(|d| 1.0 / d);
        let mut stack: Vec<u32> = Vec::with_capacity(64);
        stack.push(0);
        while let Some(i) = stack.pop() {
            let node = &self.nodes[i as usize];
            if node
                .bounds
                .ray_entry(&ray.origin, &inv, t_min, *t_max)
                .is_none()
            {
                continue;
            }
            let first = node.first as usize;
            if node.count > 0 {
                for k in first..first + node.count as usize {
                    visit(&wr, k, t_max);
                }
            } else {
                let entry = |j: usize| {
                    self.nodes[j]
                        .bounds
                        .ray_entry(&ray.origin, &inv, t_min, *t_max)
                };
                match (entry(first), entry(first + 1)) {
                    (Some(l), Some(r)) => {
                        let (near, far) = if l <= r {
                            (first, first + 1)
                        } else {
                            (first + 1, first)
                        };
                        stack.push(far as u32);
                        stack.push(near as u32);
                    }
                    (Some(_), None) => stack.push(first as u32),
                    (None, Some(_)) => stack.push((first + 1) as u32),
                    (None, None) => {}
                }
            }
        }
    }

    /// Nearest crossing of the ray with `t` in `[t_min, t_max]`; `None` for a miss, a zero or
    /// non-finite direction. A crossing exactly through an edge or vertex is reported once.
    pub fn ray_first_hit(&self, ray: &Ray, t_min: Real, t_max: Real) -> Option<RayHit> {
        let mut best: Option<(usize, Real, [Real; 3])> = None;
        let mut t_hi = t_max;
        self.traverse_ray(ray, t_min, &mut t_hi, |wr, k, t_hi| {
            if let Some((t, b)) = wr.intersect(&self.tris[k], t_min, *t_hi) {
                let better = match best {
                    None => true,
                    Some((j, bt, _)) => t < bt || (t == bt && self.ids[k] < self.ids[j]),
                };
                if better {
                    best = Some((k, t, b));
                    *t_hi = t;
                }
            }
        });
        best.map(|(k, t, b)| self.hit(ray, k, t, b))
    }

    /// All crossings of the ray with `t` in `[t_min, t_max]`, by increasing `t`. Transversal
    /// crossings through shared edges or vertices of a closed mesh are counted once, so the count
    /// from a point to infinity is odd exactly when the point is inside (tangential touches count
    /// 0 or 2).
    pub fn ray_hits(&self, ray: &Ray, t_min: Real, t_max: Real) -> Vec<RayHit> {
        let mut hits = Vec::new();
        let mut t_hi = t_max;
        self.traverse_ray(ray, t_min, &mut t_hi, |wr, k, t_hi| {
            if let Some((t, b)) = wr.intersect(&self.tris[k], t_min, *t_hi) {
                hits.push(self.hit(ray, k, t, b));
            }
        });
        hits.sort_by(|a, b| a.t.total_cmp(&b.t).then(a.triangle.cmp(&b.triangle)));
        hits
    }
}

/// Splits `items` by binned SAH along the longest centroid axis; returns the size of the left
/// part (between 1 and `items.len() - 1`).
fn split(items: &mut [u32], bounds: &[Aabb], centroids: &[Vec3], cb: &Aabb) -> usize {
    let n = items.len();
    let ext = cb.max - cb.min;
    let axis = ext.imax();
    let median = |items: &mut [u32]| {
        items.select_nth_unstable_by(n / 2, |&a, &b| {
            centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis])
        });
        n / 2
    };
    let scale = BINS as Real / ext[axis];
    if ext[axis].is_nan() || ext[axis] <= 0.0 || !scale.is_finite() {
        return median(items);
    }
    let bin =
        |t: u32| (((centroids[t as usize][axis] - cb.min[axis]) * scale) as usize).min(BINS - 1);
    let mut counts = [0usize; BINS];
    let mut boxes = [Aabb::empty(); BINS];
    for &t in items.iter() {
        let b = bin(t);
        counts[b] += 1;
        boxes[b] = boxes[b].union(&bounds[t as usize]);
    }
    // right_cost[i]: SAH cost of bins i+1.. as the right child.
    let mut right_cost = [0.0; BINS];
    let (mut acc, mut cnt) = (Aabb::empty(), 0usize);
    for i in (1..BINS).rev() {
        acc = acc.union(&boxes[i]);
        cnt += counts[i];
        right_cost[i - 1] = acc.area() * cnt as Real;
    }
    let (mut acc, mut cnt) = (Aabb::empty(), 0usize);
    let mut best: Option<(usize, Real)> = None;
    for i in 0..BINS - 1 {
        acc = acc.union(&boxes[i]);
        cnt += counts[i];
        if cnt == 0 || cnt == n {
            continue;
        }
        let cost = acc.area() * cnt as Real + right_cost[i];
        if best.is_none_or(|(_, c)| cost < c) {
            best = Some((i, cost));
        }
    }
    let Some((best_bin, _)) = best else {
        return median(items);
    };
    let mut left = 0;
    for j in 0..n {
        if bin(items[j]) <= best_bin {
            items.swap(left, j);
            left += 1;
        }
    }
    left
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::primitives::{cylinder, icosphere};

    /// Deterministic xorshift generator for tests.
    pub(crate) struct Rng(pub u64);

    impl Rng {
        pub(crate) fn unit(&mut self) -> Real {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 11) as Real / (1u64 << 53) as Real
        }
        /// Uniform in `[-s, s]³`.
        pub(crate) fn point(&mut self, s: Real) -> Vec3 {
            Vec3::new(self.unit(), self.unit(), self.unit()).map(|x| (2.0 * x - 1.0) * s)
        }
        /// Uniform unit vector.
        pub(crate) fn direction(&mut self) -> Vec3 {
            loop {
                let v = self.point(1.0);
                let n = v.norm();
                if n > 0.1 && n <= 1.0 {
                    return v / n;
                }
            }
        }
    }

    pub(crate) fn brute_force(mesh: &TriMesh, p: &Vec3) -> (Real, usize) {
        (0..mesh.triangles().len())
            .map(|t| {
                (
                    (closest_point_on_triangle(p, &mesh.corners(t)).point - p).norm(),
                    t,
                )
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .unwrap()
    }

    /// Random triangle soup with slivers, needles, collinear and repeated corners, and many tiny
    /// triangles clustered near a few spots.
    fn nasty_mesh(rng: &mut Rng) -> TriMesh {
        let mut v = Vec::new();
        let mut t = Vec::new();
        for i in 0..3000u32 {
            let base = if i % 3 == 0 {
                rng.point(8.0)
            } else {
                Vec3::new(1.0, 2.0, 3.0) + rng.point(1e-3)
            };
            let size = [1.0, 1e-3, 1e-6, 1e-9][i as usize % 4];
            let a = base;
            let b = base + rng.point(size);
            let c = match i % 7 {
                0 => a + (b - a) * rng.unit(),   // collinear
                1 => b,                          // repeated corner
                2 => b + rng.point(size * 1e-7), // needle
                _ => base + rng.point(size),
            };
            let k = v.len() as u32;
            v.extend([a, b, c]);
            t.push(if i % 11 == 0 {
                [k, k, k + 1]
            } else {
                [k, k + 1, k + 2]
            });
        }
        TriMesh::new(v, t).unwrap()
    }

    #[test]
    fn closest_point_equals_brute_force() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let mut soup_v = Vec::new();
        let mut soup_t = Vec::new();
        for i in 0..2000u32 {
            let c = rng.point(10.0);
            soup_v.extend([c, c + rng.point(2.0), c + rng.point(2.0)]);
            soup_t.push([3 * i, 3 * i + 1, 3 * i + 2]);
        }
        let meshes = [
            icosphere(Vec3::new(1.0, 2.0, 3.0), 5.0, 3).unwrap(),
            cylinder(Vec3::zeros(), Vec3::new(0.0, 3.0, 9.0), 2.0, 64, 7).unwrap(),
            TriMesh::new(soup_v, soup_t).unwrap(),
            nasty_mesh(&mut rng),
        ];
        for mesh in &meshes {
            let bvh = MeshBvh::new(mesh).unwrap();
            assert_eq!(bvh.len(), mesh.triangles().len());
            let (lo, hi) = mesh.bounds().unwrap();
            let (c, half) = ((lo + hi) * 0.5, (hi - lo).amax() * 0.75);
            let mut points: Vec<Vec3> = (0..400).map(|_| c + rng.point(half)).collect();
            points.extend(
                mesh.vertices()
                    .iter()
                    .step_by(97)
                    .map(|v| v + rng.point(1e-7)),
            );
            let batch = bvh.closest_points(&points);
            for (p, cp) in points.iter().zip(&batch) {
                let cp = cp.unwrap();
                let (d, _) = brute_force(mesh, p);
                assert!((cp.distance - d).abs() <= 1e-12, "{} vs {d}", cp.distance);
                let [a, b, cc] = mesh.corners(cp.triangle);
                let w = cp.barycentric;
                assert!((a * w[0] + b * w[1] + cc * w[2] - cp.point).norm() <= 1e-12);
                assert!(((cp.point - p).norm() - cp.distance).abs() <= 1e-12);
                assert_eq!(Some(cp), bvh.closest_point(p));
                // Radius-limited search: found at the distance, absent below it.
                assert_eq!(
                    bvh.closest_point_within(p, d * (1.0 + 1e-9))
                        .map(|c| c.distance),
                    Some(cp.distance)
                );
                if d > 1e-6 {
                    assert!(bvh.closest_point_within(p, d * (1.0 - 1e-9)).is_none());
                }
            }
        }
    }

    #[test]
    fn degenerate_inputs() {
        let empty = MeshBvh::new(&TriMesh::default()).unwrap();
        assert!(empty.is_empty() && empty.closest_point(&Vec3::zeros()).is_none());
        let ray = Ray {
            origin: Vec3::zeros(),
            direction: Vec3::x(),
        };
        assert!(empty.ray_hits(&ray, 0.0, Real::INFINITY).is_empty());
        let bvh = MeshBvh::new(&icosphere(Vec3::zeros(), 1.0, 1).unwrap()).unwrap();
        assert!(bvh.closest_point(&Vec3::new(Real::NAN, 0.0, 0.0)).is_none());
        assert!(bvh.closest_point_within(&Vec3::zeros(), -1.0).is_none());
        let zero = Ray {
            origin: Vec3::zeros(),
            direction: Vec3::zeros(),
        };
        assert!(bvh.ray_first_hit(&zero, 0.0, Real::INFINITY).is_none());
        // All triangles identical: median fallback, still exact.
        let same = TriMesh::new(
            vec![Vec3::zeros(), Vec3::x(), Vec3::y()],
            vec![[0, 1, 2]; 100],
        )
        .unwrap();
        let b = MeshBvh::new(&same).unwrap();
        let cp = b.closest_point(&Vec3::new(0.2, 0.2, 3.0)).unwrap();
        assert!((cp.distance - 3.0).abs() <= 1e-15);
        assert_eq!(cp.feature, Feature::Face);
        fn send_sync<T: Send + Sync>() {}
        send_sync::<MeshBvh>();
        send_sync::<MeshSdf>();
    }

    /// Entry/exit of a ray with the ball of `radius` about `c` (unit direction).
    fn sphere_ts(o: &Vec3, d: &Vec3, c: &Vec3, radius: Real) -> Option<(Real, Real)> {
        let oc = o - c;
        let b = oc.dot(d);
        let disc = b * b - (oc.norm_squared() - radius * radius);
        (disc >= 0.0).then(|| (-b - disc.sqrt(), -b + disc.sqrt()))
    }

    #[test]
    fn rays_against_analytic_sphere() {
        let (c, r) = (Vec3::new(-2.0, 1.0, 4.0), 10.0);
        let mesh = icosphere(c, r, 4).unwrap();
        let r_in = crate::primitives::inscribed_radius(&mesh, &c).unwrap();
        let bvh = MeshBvh::new(&mesh).unwrap();
        let sdf = MeshSdf::new(&mesh).unwrap();
        let mut rng = Rng(42);
        let tol = 1e-9;
        for _ in 0..500 {
            // From outside towards a point well inside: enters and leaves once.
            let o = c + rng.direction() * r * (1.5 + rng.unit());
            let d = ((c + rng.direction() * r_in * 0.9 * rng.unit()) - o).normalize();
            let ray = Ray {
                origin: o,
                direction: d,
            };
            let (t_out0, t_out1) = sphere_ts(&o, &d, &c, r).unwrap();
            let (t_in0, t_in1) = sphere_ts(&o, &d, &c, r_in).unwrap();
            let first = bvh.ray_first_hit(&ray, 0.0, Real::INFINITY).unwrap();
            assert!(first.t >= t_out0 - tol && first.t <= t_in0 + tol);
            assert!(first.front_face);
            assert!((first.point - (o + d * first.t)).norm() <= tol);
            let hits = bvh.ray_hits(&ray, 0.0, Real::INFINITY);
            assert_eq!(hits.len(), 2);
            assert_eq!(hits[0].t, first.t);
            assert!(hits[1].t >= t_in1 - tol && hits[1].t <= t_out1 + tol && !hits[1].front_face);
            // Brute force agrees.
            let wr = WatertightRay::new(&o, &d).unwrap();
            let brute = (0..mesh.triangles().len())
                .filter(|&t| {
                    wr.intersect(&mesh.corners(t), 0.0, Real::INFINITY)
                        .is_some()
                })
                .count();
            assert_eq!(brute, 2);
            // Range limits.
            assert!(bvh.ray_first_hit(&ray, 0.0, t_out0 - tol).is_none());
            assert_eq!(bvh.ray_hits(&ray, first.t + tol, Real::INFINITY).len(), 1);
        }
        // Parity from arbitrary origins (inside, in the thin shell, outside) matches `contains`.
        for _ in 0..2000 {
            let o = c + rng.direction() * r * 1.3 * rng.unit().sqrt();
            let ray = Ray {
                origin: o,
                direction: rng.direction(),
            };
            let n = bvh.ray_hits(&ray, 0.0, Real::INFINITY).len();
            assert_eq!(n % 2 == 1, sdf.contains(&o), "{o:?} {n}");
        }
    }

    #[test]
    fn rays_through_vertices_and_edges_count_once() {
        // Unit cube [0,1]³ (diagonals 1–2 on z=0, 5–6 on z=1, …).
        let unit = crate::primitives::cuboid(Vec3::zeros(), Vec3::repeat(1.0)).unwrap();
        let cube = MeshBvh::new(&unit).unwrap();
        let count = |o: [Real; 3], d: [Real; 3]| {
            let ray = Ray {
                origin: Vec3::from(o),
                direction: Vec3::from(d),
            };
            cube.ray_hits(&ray, 0.0, Real::INFINITY).len()
        };
        assert_eq!(count([0.5, 0.5, -1.0], [0.0, 0.0, 1.0]), 2); // face diagonals
        assert_eq!(count([0.5, 0.5, 2.0], [0.0, 0.0, -1.0]), 2);
        assert_eq!(count([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]), 2); // corners 0 and 7
        assert_eq!(count([0.5, 0.5, 0.5], [1.0, 1.0, 1.0]), 1);
        assert_eq!(count([-1.0, 0.25, -1.0], [1.0, 0.0, 1.0]), 2); // cube edges x=0,z=0 / x=1,z=1
        assert_eq!(count([0.5, -1.0, 0.5], [0.0, 1.0, 0.0]), 2);
        assert_eq!(count([-1.0, 0.0, 0.0], [2.0, 1.0, 1.0]), 2); // diagonal 2–4, corner 7
        // Grazing along faces or edges: an even count.
        assert_eq!(count([-1.0, 0.0, 0.5], [1.0, 0.0, 0.0]) % 2, 0);
        assert_eq!(count([-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]) % 2, 0);
        assert_eq!(count([-1.0, 0.3, 1.0], [1.0, 0.0, 0.0]) % 2, 0);
        // Through the fan centres of both caps of a cylinder.
        let cyl =
            MeshBvh::new(&cylinder(Vec3::zeros(), Vec3::z() * 4.0, 1.0, 37, 3).unwrap()).unwrap();
        let ray = Ray {
            origin: Vec3::new(0.0, 0.0, -2.0),
            direction: Vec3::z(),
        };
        let hits = cyl.ray_hits(&ray, 0.0, Real::INFINITY);
        assert_eq!(hits.iter().map(|h| h.t).collect::<Vec<_>>(), vec![2.0, 6.0]);
        assert!(hits[0].front_face && !hits[1].front_face);
    }
}
