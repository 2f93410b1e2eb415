//! Nearest-point queries to the tumour surface, certified to [`TOLERANCE_MM`] and exact where
//! it matters.
//!
//! An exact BVH search is slow far from a convex tumour: a far point sees a wide cap of
//! triangles at almost the same distance, and the search must open every node whose box comes
//! within the best distance (~3 µs per query for a 1 280-triangle sphere 5–80 mm away). A
//! resection surface's samples are close to each other, so a query instead
//! 1. walks over edge-adjacent triangles from its predecessor's nearest triangle to a local
//!    minimum q (an upper bound `d = |p − q|`);
//! 2. proves a lower bound with a supporting plane of the tumour's vertices in the direction
//!    n = (p − q)/d: every tumour point x has n·x ≤ h(n) (the support function, bounded from
//!    above by a cube map of exact values, [`SupportMap`]), so the true distance is at least
//!    `n·p − h(n)`; where the tumour is convex around q this is d up to the map's slack;
//! 3. falls back to the exact BVH search (bounded by d) when the two bounds differ by more than
//!    the tolerance — points inside or between tumours, concave parts, the first point of a batch.
//!
//! [`MarginField::nearest`] is always exact; [`MarginField::nearest_into`] returns every
//! distance within [`TOLERANCE_MM`] of the exact one together with its certified lower bound, so
//! callers can ask for exact answers where a threshold falls between the bounds.

use std::collections::HashMap;

use rayon::prelude::*;
use resecta_geom::bvh::closest_point_on_triangle;
use resecta_geom::{MeshBvh, Real, TriMesh, Vec3};

use crate::error::MarginError;

/// Largest gap (mm) between a returned distance and its certified lower bound on the fast path.
pub const TOLERANCE_MM: Real = 0.01;

/// The nearest point of the tumour surface to a query point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Nearest {
    /// Distance (mm) to `point`: exact, or at most [`TOLERANCE_MM`] above the exact distance.
    pub distance: Real,
    /// Certified lower bound on the exact distance (equal to `distance` when exact).
    pub lower: Real,
    pub point: Vec3,
    /// Triangle index in the tumour mesh.
    pub triangle: u32,
}

impl Nearest {
    const NONE: Nearest = Nearest {
        distance: Real::INFINITY,
        lower: Real::INFINITY,
        point: Vec3::new(Real::NAN, Real::NAN, Real::NAN),
        triangle: u32::MAX,
    };
}

/// Upper bounds of the support function h(n) = max over the vertices of n·v, from exact values
/// on a cube map of directions: h is sublinear (h(Σλᵢcᵢ) ≤ Σλᵢh(cᵢ) for λᵢ ≥ 0), and a direction
/// scaled onto its cube face is a bilinear (non-negative) combination of its cell's corners, so
/// bilinear interpolation of the corner values never underestimates h. It is exact when the
/// corners share their support vertex and otherwise exceeds h by O(R·θ²) for cells of angle θ.
#[derive(Debug)]
struct SupportMap {
    res: usize,
    /// 6 faces × (res + 1)² corner values of h at the unnormalised face points.
    h: Vec<Real>,
}

impl SupportMap {
    const RES: usize = 96;

    fn corner(face: usize, s: Real, t: Real) -> Vec3 {
        let (axis, sign) = (face / 2, if face.is_multiple_of(2) { 1.0 } else { -1.0 });
        let mut c = Vec3::zeros();
        c[axis] = sign;
        c[(axis + 1) % 3] = s;
        c[(axis + 2) % 3] = t;
        c
    }

    fn new(verts: &[Vec3]) -> Self {
        let res = Self::RES;
        let n1 = res + 1;
        let h = (0..6 * n1 * n1)
            .into_par_iter()
            .map(|k| {
                let (face, i, j) = (k / (n1 * n1), (k / n1) % n1, k % n1);
                let c = Self::corner(
                    face,
                    2.0 * i as Real / res as Real - 1.0,
                    2.0 * j as Real / res as Real - 1.0,
                );
                verts
                    .iter()
                    .map(|v| c.dot(v))
                    .fold(Real::NEG_INFINITY, Real::max)
            })
            .collect();
        Self { res, h }
    }

    /// An upper bound of h(n) for a non-zero n.
    fn bound(&self, n: &Vec3) -> Real {
        let axis = n.iamax();
        let major = n[axis].abs();
        if major.is_nan() || major <= 0.0 {
            return Real::INFINITY;
        }
        let face = 2 * axis + usize::from(n[axis] < 0.0);
        let (s, t) = (n[(axis + 1) % 3] / major, n[(axis + 2) % 3] / major);
        let res = self.res as Real;
        let (gs, gt) = ((s + 1.0) / 2.0 * res, (t + 1.0) / 2.0 * res);
        let (i, j) = (
            (gs.floor() as usize).min(self.res - 1),
            (gt.floor() as usize).min(self.res - 1),
        );
        let (a, b) = (
            (gs - i as Real).clamp(0.0, 1.0),
            (gt - j as Real).clamp(0.0, 1.0),
        );
        let n1 = self.res + 1;
        let at = |i: usize, j: usize| self.h[face * n1 * n1 + i * n1 + j];
        let m = (1.0 - a) * (1.0 - b) * at(i, j)
            + a * (1.0 - b) * at(i + 1, j)
            + (1.0 - a) * b * at(i, j + 1)
            + a * b * at(i + 1, j + 1);
        major * m
    }
}

/// Distance queries to one tumour mesh (several tumours concatenated).
#[derive(Debug)]
pub struct MarginField {
    bvh: MeshBvh,
    corners: Vec<[Vec3; 3]>,
    /// Edge-adjacent triangles (`u32::MAX`: none).
    adjacent: Vec<[u32; 3]>,
    support: SupportMap,
}

impl MarginField {
    /// Builds the BVH, the triangle adjacency and the support tree of the tumour mesh.
    pub fn new(tumours: &TriMesh) -> Result<Self, MarginError> {
        let tris = tumours.triangles();
        if tris.is_empty() {
            return Err(MarginError::EmptyMesh);
        }
        let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(tris.len() * 3);
        let mut adjacent = vec![[u32::MAX; 3]; tris.len()];
        for (t, tri) in tris.iter().enumerate() {
            for e in 0..3 {
                let (a, b) = (tri[e], tri[(e + 1) % 3]);
                let key = (a.min(b), a.max(b));
                match edges.get(&key) {
                    Some(&o) => {
                        adjacent[t][e] = o;
                        if let Some(slot) =
                            adjacent[o as usize].iter_mut().find(|s| **s == u32::MAX)
                        {
                            *slot = t as u32;
                        }
                    }
                    None => {
                        edges.insert(key, t as u32);
                    }
                }
            }
        }
        Ok(Self {
            bvh: MeshBvh::new(tumours)?,
            corners: (0..tris.len()).map(|t| tumours.corners(t)).collect(),
            adjacent,
            support: SupportMap::new(tumours.vertices()),
        })
    }

    fn at(&self, p: &Vec3, t: u32) -> Nearest {
        match self.corners.get(t as usize) {
            Some(tri) => {
                let q = closest_point_on_triangle(p, tri).point;
                Nearest {
                    distance: (p - q).norm(),
                    lower: 0.0,
                    point: q,
                    triangle: t,
                }
            }
            None => Nearest::NONE,
        }
    }

    /// The exact nearest point, searching only within `ub`'s distance (plus rounding slack).
    fn exact(&self, p: &Vec3, ub: Nearest) -> Nearest {
        let limit = if ub.distance.is_finite() {
            ub.distance * (1.0 + 1e-12) + 1e-12
        } else {
            Real::INFINITY
        };
        let found = match self.bvh.closest_point_within(p, limit) {
            Some(c) if c.distance <= ub.distance => Nearest {
                distance: c.distance,
                lower: 0.0,
                point: c.point,
                triangle: c.triangle as u32,
            },
            _ => ub,
        };
        Nearest {
            lower: found.distance,
            ..found
        }
    }

    /// From a hint triangle: local walk, support-plane lower bound, exact fallback; within
    /// [`TOLERANCE_MM`] of exact, with the certified lower bound.
    pub fn nearest_hinted(&self, p: &Vec3, hint: u32) -> Nearest {
        if !p.iter().all(|c| c.is_finite()) {
            return Nearest::NONE;
        }
        let mut best = self.at(p, hint);
        if !best.distance.is_finite() {
            return self.exact(p, best);
        }
        // Walk to a local minimum over edge-adjacent triangles (bounded steps).
        for _ in 0..64 {
            let next = self.adjacent[best.triangle as usize]
                .iter()
                .filter(|&&t| t != u32::MAX)
                .map(|&t| self.at(p, t))
                .min_by(|a, b| a.distance.total_cmp(&b.distance));
            match next {
                Some(n) if n.distance < best.distance => best = n,
                _ => break,
            }
        }
        if best.distance > 1e-9 {
            let n = (p - best.point) / best.distance;
            let lower = n.dot(p) - self.support.bound(&n);
            if best.distance - lower <= TOLERANCE_MM {
                return Nearest {
                    lower: lower.max(0.0),
                    ..best
                };
            }
        }
        self.exact(p, best)
    }

    /// The exact nearest point of the tumour surface to `p` (distance ∞ for a non-finite `p`).
    pub fn nearest(&self, p: &Vec3) -> Nearest {
        if !p.iter().all(|c| c.is_finite()) {
            return Nearest::NONE;
        }
        self.exact(p, Nearest::NONE)
    }

    /// Makes a hinted answer exact (no-op when it already is).
    pub fn exact_from(&self, p: &Vec3, start: Nearest) -> Nearest {
        if start.lower >= start.distance {
            start
        } else {
            self.exact(p, start)
        }
    }

    /// Nearest points for many points, within [`TOLERANCE_MM`] of exact with certified lower
    /// bounds, in parallel chunks; each point starts from its predecessor's triangle (the first
    /// of a chunk from an exact search).
    pub fn nearest_into(&self, points: &[Vec3], out: &mut [Nearest]) -> Result<(), MarginError> {
        if points.len() != out.len() {
            return Err(MarginError::Length {
                what: "output",
                expected: points.len(),
                got: out.len(),
            });
        }
        const CHUNK: usize = 64;
        points
            .par_chunks(CHUNK)
            .zip(out.par_chunks_mut(CHUNK))
            .for_each(|(ps, os)| {
                let mut prev = u32::MAX;
                for (p, o) in ps.iter().zip(os.iter_mut()) {
                    *o = self.nearest_hinted(p, prev);
                    prev = o.triangle;
                }
            });
        Ok(())
    }

    /// [`Self::nearest_into`] for an ru×rv sample grid (`points[a·rv + b]`): the first column
    /// is walked down first, then every row in parallel starts from its first sample's triangle,
    /// so no query starts far from its hint.
    pub fn nearest_grid_into(
        &self,
        rv: usize,
        points: &[Vec3],
        out: &mut [Nearest],
    ) -> Result<(), MarginError> {
        if points.len() != out.len() || rv == 0 || !points.len().is_multiple_of(rv) {
            return Err(MarginError::Length {
                what: "grid output",
                expected: points.len(),
                got: out.len(),
            });
        }
        let mut prev = u32::MAX;
        for (p, o) in points.iter().step_by(rv).zip(out.iter_mut().step_by(rv)) {
            *o = self.nearest_hinted(p, prev);
            prev = o.triangle;
        }
        points
            .par_chunks(rv)
            .zip(out.par_chunks_mut(rv))
            .for_each(|(ps, os)| {
                let mut prev = os[0].triangle;
                for (p, o) in ps.iter().zip(os.iter_mut()).skip(1) {
                    *o = self.nearest_hinted(p, prev);
                    prev = o.triangle;
                }
            });
        Ok(())
    }

    /// Exact answers for the given indices (where a threshold lies between the bounds).
    pub fn make_exact(&self, points: &[Vec3], out: &mut [Nearest], which: &[usize]) {
        let exact: Vec<(usize, Nearest)> = which
            .par_iter()
            .filter_map(|&k| Some((k, self.exact(points.get(k)?, *out.get(k)?))))
            .collect();
        for (k, n) in exact {
            out[k] = n;
        }
    }

    /// Triangles of the tumour mesh.
    pub fn triangles(&self) -> usize {
        self.corners.len()
    }
}
