//! Bounding-volume hierarchy of oriented boxes over the tumour triangles, for exact closest
//! points of several query points at once.
//!
//! Why not the axis-aligned [`resecta_geom::MeshBvh`]: far from a smooth tumour many triangles lie
//! within a fraction of a millimetre of the nearest distance, and an axis-aligned box around a
//! tilted patch sticks out towards the query by up to its own size, so the search opens every
//! leaf in a wide cap around the foot point. A box oriented along the patch (thin along its
//! normal) bounds the distance to within the patch's curvature sag, so a node is rejected once the
//! foot point is about its own size away: on a 20 k-triangle sphere seen from 20 mm the search
//! opens ~60 nodes instead of ~300. A tight starting bound hardly helps beyond that: the nodes
//! near the foot point hold genuine near-ties (neighbouring facets within 0.01 mm of the
//! nearest) that any exact search has to look at.
//!
//! Queries run `L` points together ("lanes", structure of arrays): one traversal opens a node if
//! it is strictly nearer than the best so far for any lane, so close-together points (a 4×4 block
//! of surface samples) share the walk, and the box and triangle tests vectorise across lanes.
//!
//! - Topology: top-down binned SAH on triangle centroids (16 bins on the longest axis, median
//!   split as fallback and below depth [`MEDIAN_DEPTH`]). Each box is the smaller (by surface
//!   area) of the axis-aligned box and the box in the principal axes of its triangle corners.
//!   Leaves hold at most [`MAX_LEAF`] triangles, each with its own (flat) oriented box.
//! - Boxes are stored in f32 relative to `origin` (64 bytes) and inflated by `pad`, which exceeds
//!   the f32 rounding of the whole bound computation for query points within `reach` of `origin`
//!   (the caller sends farther points elsewhere): the bound stays a true lower bound.
//! - A leaf triangle is measured exactly (f64, groups of [`GROUP`] lanes) for the groups whose
//!   lanes its box is nearer than their best: a branch-free form (plane distance where the point
//!   projects inside, else the nearest of the three edges) for triangles that are not flat at
//!   corner 0, and [`closest_point_on_triangle`] — the routine a brute force uses — for the rest.
//!   Both agree with the brute force to rounding (~1e-14 mm at 50 mm).

use std::cmp::Ordering;

use resecta_geom::bvh::closest_point_on_triangle;
use resecta_geom::{Mat3, Real, TriMesh, Vec3};

/// Largest number of triangles in a leaf (< 2^COUNT_BITS).
const MAX_LEAF: usize = 8;
/// Low bits of `ObbNode::link` holding a leaf's triangle count.
pub const COUNT_BITS: u32 = 5;
/// Most triangles (and so nodes < 2·MAX_TRIANGLES) that `link` can address.
pub(crate) const MAX_TRIANGLES: usize = 1 << 26;
/// Lanes per vectorised triangle test (one AVX2 vector of f64); lane counts are multiples.
pub(crate) const GROUP: usize = 4;
/// SAH bins.
const BINS: usize = 16;
/// Below this depth every split is a median split, which bounds the depth by
/// `MEDIAN_DEPTH + log2(n)` and so the traversal stack.
const MEDIAN_DEPTH: usize = 48;
/// Traversal stack size: ≥ `MEDIAN_DEPTH + log2(MAX_TRIANGLES) + 1`.
pub const STACK: usize = 96;
/// Query points must lie within `reach = max(extent, region radius) + REACH_MARGIN` mm of the
/// origin (the centre of the mesh's bounding box; `extent` is its half diagonal).
const REACH_MARGIN: Real = 250.0;

/// An oriented box `{origin + c + Σ a[k]·t_k : |t_k| ≤ h[k]}` in f32. The low [`COUNT_BITS`] of
/// `link` are the triangle count of a leaf (0 for an inner node), the rest the first triangle
/// slot of a leaf or the first of the two adjacent children of an inner node.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C, align(64))]
pub struct ObbNode {
    /// Centre relative to the tree's origin.
    pub c: [f32; 3],
    /// Unit axes.
    pub a: [[f32; 3]; 3],
    /// Half extents along the axes (padded).
    pub h: [f32; 3],
    pub link: u32,
}

impl ObbNode {
    /// Squared distances (lower bounds) from each lane's point (relative to `origin`) to the box.
    #[inline(always)]
    fn distance_squared<const L: usize>(&self, x: &[[f32; L]; 3]) -> [f32; L] {
        let mut d = [[0.0f32; L]; 3];
        for k in 0..3 {
            for l in 0..L {
                d[k][l] = x[k][l] - self.c[k];
            }
        }
        let mut s = [0.0f32; L];
        for k in 0..3 {
            let (a, h) = (self.a[k], self.h[k]);
            for l in 0..L {
                let t = (a[0] * d[0][l] + a[1] * d[1][l] + a[2] * d[2][l]).abs() - h;
                let t = if t > 0.0 { t } else { 0.0 };
                s[l] += t * t;
            }
        }
        s
    }
}

/// A triangle prepared for the branch-free exact distance (`distance_squared`, crate-private):
/// corners, edges `e_k = v_{k+1} − v_k`, inward in-plane edge normals `n × e_k`, the normal
/// `n = e_0 × (v_2 − v_0)` and reciprocals.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PreparedTriangle {
    pub v: [[Real; 3]; 3],
    pub e: [[Real; 3]; 3],
    pub m: [[Real; 3]; 3],
    pub n: [Real; 3],
    /// `1 / |e_k|²` (0 for a zero edge).
    pub inv_ee: [Real; 3],
    pub inv_nn: Real,
}

impl PreparedTriangle {
    fn new(tri: &[Vec3; 3]) -> Self {
        let [a, b, c] = *tri;
        let n = (b - a).cross(&(c - a));
        let edge = [b - a, c - b, a - c];
        let arr = |v: Vec3| [v.x, v.y, v.z];
        Self {
            v: tri.map(arr),
            e: edge.map(arr),
            m: edge.map(|e| arr(n.cross(&e))),
            n: arr(n),
            inv_ee: edge.map(|e| {
                let ee = e.norm_squared();
                if ee > 0.0 { 1.0 / ee } else { 0.0 }
            }),
            inv_nn: 1.0 / n.norm_squared(),
        }
    }

    /// Exact squared distances from the lanes in the groups set in `mask` (bit g: lanes
    /// `g·GROUP..(g+1)·GROUP`) to this triangle (not flat at corner 0), folded into `best`: the
    /// plane distance where the point projects inside (all three in-plane edge functions ≥ 0),
    /// else the nearest of the three edge segments. Branch-free within a group.
    #[inline(always)]
    fn fold<const L: usize>(&self, p: &[[Real; L]; 3], mask: u32, slot: u32, best: &mut Best<L>) {
        for g in 0..L / GROUP {
            if (mask >> g) & 1 == 0 {
                continue;
            }
            let o = g * GROUP;
            let d2 = self.distance_squared(&std::array::from_fn(|k| {
                std::array::from_fn(|l| p[k][o + l])
            }));
            for (l, &d) in d2.iter().enumerate() {
                if d < best.d2[o + l] {
                    best.d2[o + l] = d;
                    best.slot[o + l] = slot;
                }
            }
        }
    }

    /// Squared distances from [`GROUP`] points (structure of arrays), written as plain lane
    /// loops so that they vectorise.
    #[inline(always)]
    fn distance_squared(&self, p: &[[Real; GROUP]; 3]) -> [Real; GROUP] {
        let mut wmin = [Real::INFINITY; GROUP];
        let mut seg = [Real::INFINITY; GROUP];
        let mut plane = [0.0; GROUP];
        for k in 0..3 {
            let (v, e, m, ie) = (self.v[k], self.e[k], self.m[k], self.inv_ee[k]);
            let mut d = [[0.0; GROUP]; 3];
            for c in 0..3 {
                for l in 0..GROUP {
                    d[c][l] = p[c][l] - v[c];
                }
            }
            for l in 0..GROUP {
                let w = m[0] * d[0][l] + m[1] * d[1][l] + m[2] * d[2][l];
                wmin[l] = if w < wmin[l] { w } else { wmin[l] };
                let t = (e[0] * d[0][l] + e[1] * d[1][l] + e[2] * d[2][l]) * ie;
                let t = if t > 0.0 { t } else { 0.0 };
                let t = if t < 1.0 { t } else { 1.0 };
                let (rx, ry, rz) = (d[0][l] - t * e[0], d[1][l] - t * e[1], d[2][l] - t * e[2]);
                let s = rx * rx + ry * ry + rz * rz;
                seg[l] = if s < seg[l] { s } else { seg[l] };
            }
            if k == 0 {
                let n = self.n;
                for l in 0..GROUP {
                    let h = n[0] * d[0][l] + n[1] * d[1][l] + n[2] * d[2][l];
                    plane[l] = h * h * self.inv_nn;
                }
            }
        }
        let mut out = [0.0; GROUP];
        for l in 0..GROUP {
            out[l] = if wmin[l] >= 0.0 { plane[l] } else { seg[l] };
        }
        out
    }
}

/// Per lane: the leaf-order slot of the nearest triangle found and its squared distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Best<const L: usize> {
    pub slot: [u32; L],
    pub d2: [Real; L],
}

impl<const L: usize> Best<L> {
    pub(crate) fn none() -> Self {
        Self {
            slot: [u32::MAX; L],
            d2: [Real::INFINITY; L],
        }
    }
}

/// Oriented-box hierarchy over the triangles of a mesh (see the module docs). Read-only outside
/// the crate: its arrays are there for accelerators that walk it themselves (`resecta-gpu`).
#[derive(Debug, Clone)]
pub struct ObbTree {
    nodes: Vec<ObbNode>,
    /// Triangle corners in leaf order.
    tris: Vec<[Vec3; 3]>,
    /// Per slot: the triangle's own oriented box (thin along its normal).
    tri_boxes: Vec<ObbNode>,
    /// Per slot: prepared data, or `None` if flat at corner 0 (use the reference routine).
    prepared: Vec<Option<PreparedTriangle>>,
    /// Mesh index of each slot.
    ids: Vec<u32>,
    origin: Vec3,
    reach: Real,
}

impl ObbTree {
    /// Builds the tree; the caller has checked that the mesh is non-empty, has fewer than 2³⁰
    /// triangles, and that `region_radius` (how far from the mesh's bounding-box centre queries
    /// are expected) is finite.
    pub(crate) fn new(mesh: &TriMesh, region_radius: Real) -> Self {
        let n = mesh.triangles().len();
        let corners: Vec<[Vec3; 3]> = (0..n).map(|t| mesh.corners(t)).collect();
        let centroids: Vec<Vec3> = corners.iter().map(|c| (c[0] + c[1] + c[2]) / 3.0).collect();
        let (lo, hi) = mesh.bounds().unwrap_or((Vec3::zeros(), Vec3::zeros()));
        let origin = (lo + hi) * 0.5;
        // Every vertex and every box centre lies within `extent` of the origin.
        let extent = 0.5 * (hi - lo).norm();
        let reach = extent.max(region_radius) + REACH_MARGIN;
        // f32 error of a box bound (u = 2⁻²⁴): rounding the query and centre coordinates
        // (u·reach + u·extent), their difference, the rounded axes and the three-term dot
        // product (≤ 6u·|d| with |d| ≤ reach + extent), then the squared-sum comparison with a
        // rounded best (≤ 3u of the bound, covered because a pad δ per axis raises the bound's
        // root by at least δ): 16u·(reach + extent) covers all with room to spare.
        let pad = (16.0 * (f32::EPSILON as Real / 2.0) * (reach + extent)) as f32;
        let mut order: Vec<u32> = (0..n as u32).collect();
        // A node's slot is reserved when its parent splits and filled when it is popped.
        let unfilled = ObbNode {
            c: [0.0; 3],
            a: [[0.0; 3]; 3],
            h: [0.0; 3],
            link: 0,
        };
        let mut nodes: Vec<ObbNode> = Vec::with_capacity(2 * n);
        nodes.push(unfilled);
        // (node, start, end, depth)
        let mut stack = vec![(0usize, 0usize, n, 0usize)];
        while let Some((node, start, end, depth)) = stack.pop() {
            let items = &mut order[start..end];
            let mut b = bounding_box(items, &corners, &origin, pad);
            if items.len() <= MAX_LEAF {
                b.link = ((start as u32) << COUNT_BITS) | items.len() as u32;
                nodes[node] = b;
                continue;
            }
            let mid = start + split(items, &corners, &centroids, depth >= MEDIAN_DEPTH);
            let left = nodes.len();
            b.link = (left as u32) << COUNT_BITS;
            nodes[node] = b;
            nodes.extend([unfilled, unfilled]);
            stack.push((left + 1, mid, end, depth + 1));
            stack.push((left, start, mid, depth + 1));
        }
        let tris: Vec<[Vec3; 3]> = order.iter().map(|&t| corners[t as usize]).collect();
        let tri_boxes = order
            .iter()
            .map(|&t| bounding_box(&[t], &corners, &origin, pad))
            .collect();
        let prepared = tris
            .iter()
            .map(|t| (!is_flat(t)).then(|| PreparedTriangle::new(t)))
            .collect();
        Self {
            nodes,
            tris,
            tri_boxes,
            prepared,
            ids: order,
            origin,
            reach,
        }
    }

    /// Nodes, root first; the children of an inner node are adjacent.
    pub fn nodes(&self) -> &[ObbNode] {
        &self.nodes
    }

    /// Triangle corners per slot (leaf order).
    pub fn triangles(&self) -> &[[Vec3; 3]] {
        &self.tris
    }

    /// Each slot's own oriented box.
    pub fn triangle_boxes(&self) -> &[ObbNode] {
        &self.tri_boxes
    }

    /// Each slot's prepared data, `None` where the triangle is flat at corner 0 (measured by
    /// [`closest_point_on_triangle`] instead).
    pub fn prepared(&self) -> &[Option<PreparedTriangle>] {
        &self.prepared
    }

    /// The point node centres are relative to.
    pub fn origin(&self) -> Vec3 {
        self.origin
    }

    /// How far from the origin (mm) query points may lie for the f32 bounds to be conservative.
    pub fn reach(&self) -> Real {
        self.reach
    }

    /// Whether `p` is close enough to the origin for the f32 bounds to be conservative.
    #[inline]
    pub fn in_reach(&self, p: &Vec3) -> bool {
        (p - self.origin).norm_squared() <= self.reach * self.reach
    }

    /// Mesh index of the triangle in slot `slot`.
    #[inline]
    pub fn id(&self, slot: u32) -> u32 {
        self.ids[slot as usize]
    }

    /// Exact closest point of triangle `slot` to `p` and its distance, by the reference routine.
    #[inline]
    pub(crate) fn closest_on(&self, p: &Vec3, slot: u32) -> (Vec3, Real) {
        let q = closest_point_on_triangle(p, &self.tris[slot as usize]).point;
        (q, (p - q).norm())
    }

    /// Exact squared distances from every lane's point to triangle `slot`, folded into `best`.
    pub(crate) fn test<const L: usize>(&self, points: &[Vec3; L], slot: u32, best: &mut Best<L>) {
        let p: [[Real; L]; 3] = std::array::from_fn(|k| points.map(|q| q[k]));
        self.test_masked(&p, u32::MAX, slot, best);
    }

    /// [`Self::test`] for the groups of lanes set in `mask`.
    #[inline(always)]
    fn test_masked<const L: usize>(
        &self,
        p: &[[Real; L]; 3],
        mask: u32,
        slot: u32,
        best: &mut Best<L>,
    ) {
        match &self.prepared[slot as usize] {
            Some(t) => t.fold(p, mask, slot, best),
            None => {
                let tri = &self.tris[slot as usize];
                for l in (0..L).filter(|l| (mask >> (l / GROUP)) & 1 == 1) {
                    let x = Vec3::new(p[0][l], p[1][l], p[2][l]);
                    let d2 = (closest_point_on_triangle(&x, tri).point - x).norm_squared();
                    if d2 < best.d2[l] {
                        best.d2[l] = d2;
                        best.slot[l] = slot;
                    }
                }
            }
        }
    }

    /// Exact nearest triangles of `L` points (`L` a multiple of [`GROUP`], at most 32), all finite and [`Self::in_reach`], starting from `best` (seeds folded in
    /// with [`Self::test`]; the tighter, the fewer nodes are opened). A node is opened if it is
    /// strictly nearer than the best so far for any lane; a leaf triangle is tested exactly for
    /// the groups of lanes its own box is nearer than their best.
    ///
    /// With `slack[l]` > 0 (mm) a node or triangle must be nearer than lane l's best so far minus
    /// its slack, so its answer is within the slack above the true distance (the lower bounds
    /// are conservative; the f32 rounding of the shrunken bound is below 1e-6 relative).
    pub(crate) fn closest<const L: usize>(
        &self,
        points: &[Vec3; L],
        mut best: Best<L>,
        slack: &[Real; L],
    ) -> Best<L> {
        let p: [[Real; L]; 3] = std::array::from_fn(|k| points.map(|q| q[k]));
        let x: [[f32; L]; 3] =
            std::array::from_fn(|k| points.map(|q| (q[k] - self.origin[k]) as f32));
        let exact = slack.iter().all(|&s| s <= 0.0);
        let shrink = |d2: &[Real; L]| -> [f32; L] {
            if exact {
                d2.map(|d| d as f32)
            } else {
                std::array::from_fn(|l| {
                    let r = d2[l].sqrt() - slack[l].max(0.0);
                    if r > 0.0 { (r * r) as f32 } else { 0.0 }
                })
            }
        };
        let mut bound: [f32; L] = shrink(&best.d2);
        let mut stack = [(0u32, [0.0f32; L]); STACK];
        stack[0] = (0, self.nodes[0].distance_squared(&x));
        let mut len = 1;
        while len > 0 {
            len -= 1;
            let (i, box_d2) = stack[len];
            if !any_below(&box_d2, &bound) {
                continue;
            }
            let node = &self.nodes[i as usize];
            let (first, count) = (node.link >> COUNT_BITS, node.link & ((1 << COUNT_BITS) - 1));
            if count > 0 {
                let n = count as usize;
                let lbs: [[f32; L]; MAX_LEAF] = std::array::from_fn(|j| {
                    if j < n {
                        self.tri_boxes[first as usize + j].distance_squared(&x)
                    } else {
                        [f32::INFINITY; L]
                    }
                });
                for (j, lb) in lbs.iter().enumerate().take(n) {
                    let mut mask = 0u32;
                    for l in 0..L {
                        mask |= u32::from(lb[l] < bound[l]) << (l / GROUP);
                    }
                    if mask != 0 {
                        self.test_masked(&p, mask, first + j as u32, &mut best);
                        bound = shrink(&best.d2);
                    }
                }
                continue;
            }
            let dl = self.nodes[first as usize].distance_squared(&x);
            let dr = self.nodes[first as usize + 1].distance_squared(&x);
            let (near, far, dn, df) = if dl[L / 2] <= dr[L / 2] {
                (first, first + 1, dl, dr)
            } else {
                (first + 1, first, dr, dl)
            };
            if any_below(&df, &bound) {
                stack[len] = (far, df);
                len += 1;
            }
            if any_below(&dn, &bound) {
                stack[len] = (near, dn);
                len += 1;
            }
        }
        best
    }
}

#[inline(always)]
fn any_below<const L: usize>(a: &[f32; L], b: &[f32; L]) -> bool {
    let mut any = false;
    for l in 0..L {
        any |= a[l] < b[l];
    }
    any
}

/// Flat at corner 0 by the reference routine's test (sin² of the angle below 1e-4, including
/// zero area) or not finite.
fn is_flat(tri: &[Vec3; 3]) -> bool {
    let (ab, ac) = (tri[1] - tri[0], tri[2] - tri[0]);
    let nn = ab.cross(&ac).norm_squared();
    nn.partial_cmp(&(1e-4 * ab.norm_squared() * ac.norm_squared())) != Some(Ordering::Greater)
}

/// Oriented bounding box of the triangles `items` as an f32 node relative to `origin`: the
/// smaller by surface area of the axis-aligned box and the principal-axes box, inflated by `pad`.
fn bounding_box(items: &[u32], corners: &[[Vec3; 3]], origin: &Vec3, pad: f32) -> ObbNode {
    let pts = || items.iter().flat_map(|&t| corners[t as usize].iter());
    let count = (3 * items.len()) as Real;
    let mean = pts().sum::<Vec3>() / count;
    let cov = pts().fold(Mat3::zeros(), |acc, p| {
        let d = p - mean;
        acc + d * d.transpose()
    });
    let box_in = |axes: [Vec3; 3]| {
        let mut lo = Vec3::repeat(Real::INFINITY);
        let mut hi = Vec3::repeat(Real::NEG_INFINITY);
        for p in pts() {
            let d = p - mean;
            let q = Vec3::new(axes[0].dot(&d), axes[1].dot(&d), axes[2].dot(&d));
            lo = lo.inf(&q);
            hi = hi.sup(&q);
        }
        let mid = (lo + hi) * 0.5;
        let center = mean + axes[0] * mid.x + axes[1] * mid.y + axes[2] * mid.z;
        let half = (hi - lo) * 0.5;
        let area = half.x * half.y + half.y * half.z + half.z * half.x;
        (center, axes, half, area)
    };
    let aligned = box_in([Vec3::x(), Vec3::y(), Vec3::z()]);
    let (center, axes, half, _) = principal_axes(&cov)
        .map(box_in)
        .filter(|b| b.3 < aligned.3)
        .unwrap_or(aligned);
    let rel = center - origin;
    ObbNode {
        c: [rel.x as f32, rel.y as f32, rel.z as f32],
        a: axes.map(|v| [v.x as f32, v.y as f32, v.z as f32]),
        h: [
            half.x as f32 + pad,
            half.y as f32 + pad,
            half.z as f32 + pad,
        ],
        link: 0,
    }
}

/// Orthonormal right-handed frame of the eigenvectors of a symmetric 3×3 matrix (largest
/// eigenvalue first), or `None` if it is not finite.
fn principal_axes(cov: &Mat3) -> Option<[Vec3; 3]> {
    let eig = cov.symmetric_eigen();
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let a0 = eig
        .eigenvectors
        .column(order[0])
        .into_owned()
        .try_normalize(1e-12)?;
    let v1 = eig.eigenvectors.column(order[1]).into_owned();
    let a1 = (v1 - a0 * a0.dot(&v1)).try_normalize(1e-12)?;
    let a2 = a0.cross(&a1);
    [a0, a1, a2]
        .iter()
        .all(|a| a.iter().all(|c| c.is_finite()))
        .then_some([a0, a1, a2])
}

/// Splits `items` by binned SAH (axis-aligned boxes) along the longest centroid axis, or at the
/// median if `median` or no SAH split exists; returns the size of the left part (1..len).
fn split(items: &mut [u32], corners: &[[Vec3; 3]], centroids: &[Vec3], median: bool) -> usize {
    let n = items.len();
    let (mut lo, mut hi) = (
        Vec3::repeat(Real::INFINITY),
        Vec3::repeat(Real::NEG_INFINITY),
    );
    for &t in items.iter() {
        lo = lo.inf(&centroids[t as usize]);
        hi = hi.sup(&centroids[t as usize]);
    }
    let ext = hi - lo;
    let axis = ext.imax();
    let at_median = |items: &mut [u32]| {
        items.select_nth_unstable_by(n / 2, |&a, &b| {
            centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis])
        });
        n / 2
    };
    let scale = BINS as Real / ext[axis];
    if median || ext[axis].is_nan() || ext[axis] <= 0.0 || !scale.is_finite() {
        return at_median(items);
    }
    let bin = |t: u32| (((centroids[t as usize][axis] - lo[axis]) * scale) as usize).min(BINS - 1);
    let empty = (
        Vec3::repeat(Real::INFINITY),
        Vec3::repeat(Real::NEG_INFINITY),
    );
    let area = |b: &(Vec3, Vec3)| {
        let d = (b.1 - b.0).sup(&Vec3::zeros());
        d.x * d.y + d.y * d.z + d.z * d.x
    };
    let union = |a: (Vec3, Vec3), b: (Vec3, Vec3)| (a.0.inf(&b.0), a.1.sup(&b.1));
    let mut counts = [0usize; BINS];
    let mut boxes = [empty; BINS];
    for &t in items.iter() {
        let b = bin(t);
        counts[b] += 1;
        for c in &corners[t as usize] {
            boxes[b] = union(boxes[b], (*c, *c));
        }
    }
    let mut right_cost = [0.0; BINS];
    let (mut acc, mut cnt) = (empty, 0usize);
    for i in (1..BINS).rev() {
        acc = union(acc, boxes[i]);
        cnt += counts[i];
        right_cost[i - 1] = area(&acc) * cnt as Real;
    }
    let (mut acc, mut cnt) = (empty, 0usize);
    let mut best: Option<(usize, Real)> = None;
    for i in 0..BINS - 1 {
        acc = union(acc, boxes[i]);
        cnt += counts[i];
        if cnt == 0 || cnt == n {
            continue;
        }
        let cost = area(&acc) * cnt as Real + right_cost[i];
        if best.is_none_or(|(_, c)| cost < c) {
            best = Some((i, cost));
        }
    }
    let Some((best_bin, _)) = best else {
        return at_median(items);
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
