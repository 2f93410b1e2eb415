//! Exact nearest-point queries to the tumour surface: a BVH search, started in a batch with
//! the exact distance to the previous point's nearest triangle as its bound (neighbouring
//! surface samples are close, so the bound is tight). Results equal a brute-force search over
//! all triangles.
//!
//! The cost of an exact query grows with the number of triangles lying within a small slack of
//! the answer (a far point sees a wide cap of a convex tumour at almost the same distance), so
//! it is proportional to the tumour model's tessellation: the planner uses MCSD models
//! decimated as Paper I recommends (see docs/planning.md).

use rayon::prelude::*;
use resecta_geom::bvh::closest_point_on_triangle;
use resecta_geom::{MeshBvh, Real, TriMesh, Vec3};

use crate::error::MarginError;

/// The nearest point of the tumour surface to a query point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Nearest {
    /// Euclidean distance (mm).
    pub distance: Real,
    pub point: Vec3,
    /// Triangle index in the tumour mesh.
    pub triangle: u32,
}

impl Nearest {
    const NONE: Nearest = Nearest {
        distance: Real::INFINITY,
        point: Vec3::new(Real::NAN, Real::NAN, Real::NAN),
        triangle: u32::MAX,
    };
}

/// Distance queries to one tumour mesh (several tumours concatenated).
#[derive(Debug)]
pub struct MarginField {
    bvh: MeshBvh,
    corners: Vec<[Vec3; 3]>,
}

impl MarginField {
    /// Builds the BVH of the tumour mesh.
    pub fn new(tumours: &TriMesh) -> Result<Self, MarginError> {
        if tumours.triangles().is_empty() {
            return Err(MarginError::EmptyMesh);
        }
        Ok(Self {
            bvh: MeshBvh::new(tumours)?,
            corners: (0..tumours.triangles().len())
                .map(|t| tumours.corners(t))
                .collect(),
        })
    }

    /// Exact distance to the best of the given triangles (an upper bound on the answer).
    fn bound(&self, p: &Vec3, triangles: &[u32]) -> Nearest {
        let mut best = Nearest::NONE;
        for &t in triangles {
            if best.triangle == t {
                continue;
            }
            if let Some(tri) = self.corners.get(t as usize) {
                let q = closest_point_on_triangle(p, tri).point;
                let d = (p - q).norm();
                if d < best.distance {
                    best = Nearest {
                        distance: d,
                        point: q,
                        triangle: t,
                    };
                }
            }
        }
        best
    }

    /// The exact nearest point, searching only within `ub`'s distance (plus rounding slack).
    fn bounded(&self, p: &Vec3, ub: Nearest) -> Nearest {
        let limit = if ub.distance.is_finite() {
            ub.distance * (1.0 + 1e-12) + 1e-12
        } else {
            Real::INFINITY
        };
        match self.bvh.closest_point_within(p, limit) {
            Some(c) if c.distance <= ub.distance => Nearest {
                distance: c.distance,
                point: c.point,
                triangle: c.triangle as u32,
            },
            _ if ub.distance.is_finite() => ub,
            _ => Nearest::NONE,
        }
    }

    fn query(&self, p: &Vec3, hint: u32) -> Nearest {
        if !p.iter().all(|c| c.is_finite()) {
            return Nearest::NONE;
        }
        self.bounded(p, self.bound(p, &[hint]))
    }

    /// The exact nearest point of the tumour surface to `p` (distance ∞ for a non-finite `p`).
    pub fn nearest(&self, p: &Vec3) -> Nearest {
        self.query(p, u32::MAX)
    }

    /// [`Self::nearest`] for many points, in parallel chunks; within a chunk each point also
    /// uses its predecessor's triangle as a hint (neighbouring surface samples are close).
    pub fn nearest_into(&self, points: &[Vec3], out: &mut [Nearest]) -> Result<(), MarginError> {
        if points.len() != out.len() {
            return Err(MarginError::Length {
                what: "output",
                expected: points.len(),
                got: out.len(),
            });
        }
        const CHUNK: usize = 128;
        points
            .par_chunks(CHUNK)
            .zip(out.par_chunks_mut(CHUNK))
            .for_each(|(ps, os)| {
                let mut prev = u32::MAX;
                for (p, o) in ps.iter().zip(os.iter_mut()) {
                    *o = self.query(p, prev);
                    prev = o.triangle;
                }
            });
        Ok(())
    }

    /// Triangles of the tumour mesh.
    pub fn triangles(&self) -> usize {
        self.corners.len()
    }
}
