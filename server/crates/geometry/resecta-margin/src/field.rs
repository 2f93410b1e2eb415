//! Exact nearest-point queries to the tumour surface, fast because every query starts with a
//! tight upper bound.
//!
//! A BVH search for the closest triangle visits every node whose box lies within the best
//! distance found so far; far from a convex tumour many triangles lie within a small slack of
//! the true distance, so an unbounded search is slow. At set-up a grid of nodes over the region
//! of interest stores each node's nearest triangle (computed row by row, each node bounded by
//! its predecessor's triangle). A query takes the exact distance to the hint triangles of its
//! cell's 8 corners (and of the previous query in a batch) as the bound — typically within a
//! few hundredths of a millimetre of the answer — and the bounded BVH search then returns the
//! exact closest point. Results equal a brute-force search over all triangles.

use rayon::prelude::*;
use resecta_geom::bvh::closest_point_on_triangle;
use resecta_geom::{MeshBvh, Real, TriMesh, Vec3};

use crate::error::MarginError;

/// Most hint nodes (≈ 8 M: 32 MB of hints).
pub const MAX_NODES: usize = 8 << 20;

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
    origin: Vec3,
    spacing: Real,
    dims: [usize; 3],
    hints: Vec<u32>,
}

impl MarginField {
    /// Builds the BVH and the hint grid over the box `region_min..region_max` at `spacing_mm`.
    pub fn new(
        tumours: &TriMesh,
        region_min: Vec3,
        region_max: Vec3,
        spacing_mm: Real,
    ) -> Result<Self, MarginError> {
        if tumours.triangles().is_empty() {
            return Err(MarginError::EmptyMesh);
        }
        if !(spacing_mm.is_finite() && spacing_mm > 0.0) {
            return Err(MarginError::Spacing(spacing_mm));
        }
        let finite = region_min
            .iter()
            .chain(region_max.iter())
            .all(|c| c.is_finite());
        if !finite || (0..3).any(|a| region_max[a] < region_min[a]) {
            return Err(MarginError::Region {
                min: region_min.into(),
                max: region_max.into(),
            });
        }
        let mut dims = [0usize; 3];
        let mut nodes: u128 = 1;
        for a in 0..3 {
            let cells = ((region_max[a] - region_min[a]) / spacing_mm).ceil();
            if cells > MAX_NODES as Real {
                return Err(MarginError::TooManyNodes { max: MAX_NODES });
            }
            dims[a] = cells as usize + 2;
            nodes *= dims[a] as u128;
        }
        if nodes > MAX_NODES as u128 {
            return Err(MarginError::TooManyNodes { max: MAX_NODES });
        }
        let bvh = MeshBvh::new(tumours)?;
        let corners: Vec<[Vec3; 3]> = (0..tumours.triangles().len())
            .map(|t| tumours.corners(t))
            .collect();
        let mut field = Self {
            bvh,
            corners,
            origin: region_min,
            spacing: spacing_mm,
            dims,
            hints: Vec::new(),
        };
        let [nx, ny, nz] = dims;
        let rows: Vec<Vec<u32>> = (0..ny * nz)
            .into_par_iter()
            .map(|row| {
                let (j, k) = (row % ny, row / ny);
                let mut out = Vec::with_capacity(nx);
                let mut prev = Nearest::NONE;
                for i in 0..nx {
                    let p = field.node(i, j, k);
                    prev = field.bounded(&p, field.bound(&p, &[prev.triangle]));
                    out.push(prev.triangle);
                }
                out
            })
            .collect();
        field.hints = rows.concat();
        Ok(field)
    }

    fn node(&self, i: usize, j: usize, k: usize) -> Vec3 {
        self.origin + Vec3::new(i as Real, j as Real, k as Real) * self.spacing
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

    /// Hint triangles of the cell holding `p` (empty outside the region).
    fn cell_hints(&self, p: &Vec3, out: &mut Vec<u32>) {
        out.clear();
        let g = (p - self.origin) / self.spacing;
        let [nx, ny, nz] = self.dims;
        let inside = (0..3).all(|a| g[a] >= 0.0 && g[a] <= (self.dims[a] - 1) as Real);
        if !inside {
            return;
        }
        let base = [0, 1, 2].map(|a| (g[a].floor() as usize).min(self.dims[a] - 2));
        for c in 0..8 {
            let (i, j, k) = (
                base[0] + (c & 1),
                base[1] + ((c >> 1) & 1),
                base[2] + (c >> 2),
            );
            if i < nx && j < ny && k < nz {
                let h = self.hints[i + nx * (j + ny * k)];
                if !out.contains(&h) {
                    out.push(h);
                }
            }
        }
    }

    fn query(&self, p: &Vec3, extra: u32, scratch: &mut Vec<u32>) -> Nearest {
        if !p.iter().all(|c| c.is_finite()) {
            return Nearest::NONE;
        }
        self.cell_hints(p, scratch);
        if extra != u32::MAX && !scratch.contains(&extra) {
            scratch.push(extra);
        }
        self.bounded(p, self.bound(p, scratch))
    }

    /// The exact nearest point of the tumour surface to `p` (distance ∞ for a non-finite `p`).
    pub fn nearest(&self, p: &Vec3) -> Nearest {
        self.query(p, u32::MAX, &mut Vec::with_capacity(9))
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
                let mut scratch = Vec::with_capacity(9);
                let mut prev = u32::MAX;
                for (p, o) in ps.iter().zip(os.iter_mut()) {
                    *o = self.query(p, prev, &mut scratch);
                    prev = o.triangle;
                }
            });
        Ok(())
    }

    /// Hint grid nodes per axis.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }
    /// Triangles of the tumour mesh.
    pub fn triangles(&self) -> usize {
        self.corners.len()
    }
}
