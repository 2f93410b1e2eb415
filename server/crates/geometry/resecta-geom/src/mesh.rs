//! Triangle meshes in RAS mm, validated at construction.

use std::collections::{BTreeMap, HashMap};

use crate::error::GeomError;
use crate::math::{Mat4, Real, Vec3};
use crate::pca::Pca;

/// Vertices, triangles (counter-clockwise seen from outside for closed meshes), optional
/// per-vertex normals and named per-vertex scalars.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TriMesh {
    vertices: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    normals: Option<Vec<Vec3>>,
    scalars: BTreeMap<String, Vec<Real>>,
}

/// Topology and quality of a mesh.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct MeshReport {
    pub vertices: usize,
    pub triangles: usize,
    /// Triangles with a repeated vertex index or (near) zero area.
    pub degenerate_triangles: usize,
    /// Edges used by exactly one triangle.
    pub boundary_edges: usize,
    /// Edges used by more than two triangles.
    pub non_manifold_edges: usize,
    /// Interior edges whose two triangles traverse them in the same direction.
    pub inconsistent_edges: usize,
    /// Closed, 2-manifold, consistently oriented and without degenerate triangles.
    pub watertight: bool,
}

impl TriMesh {
    /// A mesh; every index must refer to a vertex and every vertex must be finite.
    pub fn new(vertices: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Result<Self, GeomError> {
        if u32::try_from(vertices.len()).is_err() {
            return Err(GeomError::TooManyVertices);
        }
        if let Some(i) = vertices
            .iter()
            .position(|v| v.iter().any(|c| !c.is_finite()))
        {
            return Err(GeomError::NonFiniteVertex(i));
        }
        for (t, tri) in triangles.iter().enumerate() {
            if let Some(&index) = tri.iter().find(|&&i| i as usize >= vertices.len()) {
                return Err(GeomError::VertexIndexOutOfRange {
                    triangle: t,
                    index,
                    vertex_count: vertices.len(),
                });
            }
        }
        Ok(Self {
            vertices,
            triangles,
            normals: None,
            scalars: BTreeMap::new(),
        })
    }

    /// One mesh holding the vertices and triangles of all `meshes` (attributes are dropped).
    pub fn concat(meshes: &[TriMesh]) -> Result<Self, GeomError> {
        let mut vertices = Vec::new();
        let mut triangles = Vec::new();
        for m in meshes {
            let base = u32::try_from(vertices.len()).map_err(|_| GeomError::TooManyVertices)?;
            vertices.extend_from_slice(&m.vertices);
            triangles.extend(m.triangles.iter().map(|t| t.map(|i| i + base)));
        }
        Self::new(vertices, triangles)
    }

    /// Attaches per-vertex normals (one per vertex).
    pub fn with_normals(mut self, normals: Vec<Vec3>) -> Result<Self, GeomError> {
        self.check_len("normals", normals.len())?;
        self.normals = Some(normals);
        Ok(self)
    }

    /// Attaches (or replaces) a named per-vertex scalar array.
    pub fn with_scalars(mut self, name: &str, values: Vec<Real>) -> Result<Self, GeomError> {
        self.check_len(name, values.len())?;
        self.scalars.insert(name.to_owned(), values);
        Ok(self)
    }

    fn check_len(&self, attribute: &str, got: usize) -> Result<(), GeomError> {
        if got == self.vertices.len() {
            Ok(())
        } else {
            Err(GeomError::AttributeLength {
                attribute: attribute.to_owned(),
                expected: self.vertices.len(),
                got,
            })
        }
    }

    pub fn vertices(&self) -> &[Vec3] {
        &self.vertices
    }
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    pub fn normals(&self) -> Option<&[Vec3]> {
        self.normals.as_deref()
    }
    pub fn scalars(&self) -> &BTreeMap<String, Vec<Real>> {
        &self.scalars
    }
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    /// Corner positions of triangle `t`.
    #[inline]
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        self.triangles[t].map(|i| self.vertices[i as usize])
    }

    /// Twice-area-weighted normal (cross product) of triangle `t`.
    #[inline]
    fn cross(&self, t: usize) -> Vec3 {
        let [a, b, c] = self.corners(t);
        (b - a).cross(&(c - a))
    }

    /// Total surface area in mm².
    pub fn area(&self) -> Real {
        (0..self.triangles.len())
            .map(|t| self.cross(t).norm())
            .sum::<Real>()
            * 0.5
    }

    /// Signed enclosed volume in mm³ (divergence theorem); positive for outward orientation.
    pub fn signed_volume(&self) -> Real {
        (0..self.triangles.len())
            .map(|t| {
                let [a, b, c] = self.corners(t);
                a.dot(&b.cross(&c))
            })
            .sum::<Real>()
            / 6.0
    }

    /// Enclosed volume in mm³ (meaningful for watertight meshes).
    pub fn enclosed_volume(&self) -> Real {
        self.signed_volume().abs()
    }

    /// Area-weighted centroid of the surface.
    pub fn surface_centroid(&self) -> Option<Vec3> {
        let (mut sum, mut w) = (Vec3::zeros(), 0.0);
        for t in 0..self.triangles.len() {
            let [a, b, c] = self.corners(t);
            let area = (b - a).cross(&(c - a)).norm();
            sum += (a + b + c) * (area / 3.0);
            w += area;
        }
        (w > 0.0).then(|| sum / w)
    }

    /// Centroid of the enclosed solid (for watertight meshes), by signed tetrahedra.
    pub fn volume_centroid(&self) -> Option<Vec3> {
        let (mut sum, mut vol) = (Vec3::zeros(), 0.0);
        for t in 0..self.triangles.len() {
            let [a, b, c] = self.corners(t);
            let v = a.dot(&b.cross(&c)) / 6.0;
            sum += (a + b + c) * (v / 4.0);
            vol += v;
        }
        (vol.abs() > Real::EPSILON).then(|| sum / vol)
    }

    /// The mesh mapped by the affine `m` (e.g. index → RAS). Normals follow the inverse
    /// transpose; triangle winding is reversed when `m` flips orientation, so outward stays
    /// outward. Fails if `m` is singular or not affine.
    pub fn transformed(&self, m: &Mat4) -> Result<Self, GeomError> {
        let linear = m.fixed_view::<3, 3>(0, 0).into_owned();
        let det = linear.determinant();
        let affine = m[(3, 0)] == 0.0 && m[(3, 1)] == 0.0 && m[(3, 2)] == 0.0 && m[(3, 3)] == 1.0;
        let normal_map = linear.try_inverse().map(|inv| inv.transpose());
        let (Some(normal_map), true, true) = (normal_map, affine, det.is_finite() && det != 0.0)
        else {
            return Err(GeomError::InvalidParameter {
                name: "mesh transform",
                reason: "must be an invertible affine matrix",
            });
        };
        let shift = m.fixed_view::<3, 1>(0, 3).into_owned();
        let vertices = self.vertices.iter().map(|v| linear * v + shift).collect();
        let triangles = if det < 0.0 {
            self.triangles.iter().map(|&[a, b, c]| [a, c, b]).collect()
        } else {
            self.triangles.clone()
        };
        let mut out = Self::new(vertices, triangles)?;
        out.normals = self.normals.as_ref().map(|ns| {
            ns.iter()
                .map(|n| {
                    (normal_map * n)
                        .try_normalize(0.0)
                        .unwrap_or_else(Vec3::zeros)
                })
                .collect()
        });
        out.scalars = self.scalars.clone();
        Ok(out)
    }

    /// PCA of the vertex positions.
    pub fn pca(&self) -> Result<Pca, GeomError> {
        Pca::of_points(&self.vertices)
    }

    /// Axis-aligned bounds `(min, max)`, or `None` without vertices.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let first = *self.vertices.first()?;
        Some(
            self.vertices
                .iter()
                .fold((first, first), |(lo, hi), v| (lo.inf(v), hi.sup(v))),
        )
    }

    /// Angle-weighted vertex normals (unit; zero for unused vertices).
    pub fn compute_vertex_normals(&self) -> Vec<Vec3> {
        let mut n = vec![Vec3::zeros(); self.vertices.len()];
        for (t, tri) in self.triangles.iter().enumerate() {
            let Some(face) = self.cross(t).try_normalize(0.0) else {
                continue;
            };
            let p = self.corners(t);
            for k in 0..3 {
                let e1 = p[(k + 1) % 3] - p[k];
                let e2 = p[(k + 2) % 3] - p[k];
                let angle = e1.angle(&e2);
                if angle.is_finite() {
                    n[tri[k] as usize] += face * angle;
                }
            }
        }
        n.into_iter()
            .map(|v| v.try_normalize(0.0).unwrap_or_else(Vec3::zeros))
            .collect()
    }

    /// Degenerate triangles, boundary and non-manifold edges, orientation consistency.
    pub fn report(&self) -> MeshReport {
        let scale = self.bounds().map_or(0.0, |(lo, hi)| (hi - lo).norm());
        let area_eps = (scale * 1e-12).powi(2);
        let mut degenerate = 0;
        // undirected edge → (uses, directed uses a→b with a < b)
        let mut edges: HashMap<(u32, u32), (u32, u32)> =
            HashMap::with_capacity(self.triangles.len() * 3 / 2);
        for (t, &[a, b, c]) in self.triangles.iter().enumerate() {
            if a == b || b == c || a == c || self.cross(t).norm() <= area_eps {
                degenerate += 1;
            }
            for (p, q) in [(a, b), (b, c), (c, a)] {
                if p == q {
                    continue;
                }
                let e = edges.entry((p.min(q), p.max(q))).or_insert((0, 0));
                e.0 += 1;
                e.1 += u32::from(p < q);
            }
        }
        let mut report = MeshReport {
            vertices: self.vertices.len(),
            triangles: self.triangles.len(),
            degenerate_triangles: degenerate,
            boundary_edges: 0,
            non_manifold_edges: 0,
            inconsistent_edges: 0,
            watertight: false,
        };
        for &(uses, forward) in edges.values() {
            match uses {
                1 => report.boundary_edges += 1,
                2 if forward != 1 => report.inconsistent_edges += 1,
                2 => {}
                _ => report.non_manifold_edges += 1,
            }
        }
        report.watertight = !self.triangles.is_empty()
            && degenerate == 0
            && report.boundary_edges == 0
            && report.non_manifold_edges == 0
            && report.inconsistent_edges == 0;
        report
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn cuboid(a: Real, b: Real, c: Real) -> TriMesh {
        crate::primitives::cuboid(Vec3::zeros(), Vec3::new(a, b, c)).unwrap()
    }

    #[test]
    fn cuboid_measures() {
        let m = cuboid(2.0, 3.0, 5.0);
        assert_relative_eq!(m.area(), 2.0 * (6.0 + 10.0 + 15.0), epsilon = 1e-12);
        assert_relative_eq!(m.signed_volume(), 30.0, epsilon = 1e-12);
        assert_relative_eq!(
            m.volume_centroid().unwrap(),
            Vec3::new(1.0, 1.5, 2.5),
            epsilon = 1e-12
        );
        let r = m.report();
        assert!(r.watertight, "{r:?}");
        let n = m.compute_vertex_normals();
        assert_relative_eq!(n[7], Vec3::new(1.0, 1.0, 1.0).normalize(), epsilon = 1e-12);
    }

    #[test]
    fn report_finds_defects() {
        let m = cuboid(1.0, 1.0, 1.0);
        // Open: drop a triangle.
        let mut t = m.triangles().to_vec();
        t.pop();
        let open = TriMesh::new(m.vertices().to_vec(), t.clone())
            .unwrap()
            .report();
        assert_eq!(open.boundary_edges, 3);
        assert!(!open.watertight);
        // Flipped triangle.
        let mut t = m.triangles().to_vec();
        t[0].swap(1, 2);
        let flipped = TriMesh::new(m.vertices().to_vec(), t).unwrap().report();
        assert_eq!(flipped.inconsistent_edges, 3);
        // Non-manifold: a fin on an existing edge, plus a degenerate triangle.
        let mut v = m.vertices().to_vec();
        v.push(Vec3::new(0.5, -1.0, 0.0));
        let mut t = m.triangles().to_vec();
        t.push([0, 1, 8]);
        t.push([0, 0, 1]);
        let bad = TriMesh::new(v, t).unwrap().report();
        assert_eq!(bad.non_manifold_edges, 1);
        assert_eq!(bad.degenerate_triangles, 1);
    }

    #[test]
    fn concat_offsets_indices() {
        let a = cuboid(1.0, 1.0, 1.0);
        let b = cuboid(2.0, 2.0, 2.0);
        let m = TriMesh::concat(&[a.clone(), b]).unwrap();
        assert_eq!(m.vertices().len(), 16);
        assert_eq!(m.triangles()[12], a.triangles()[0].map(|i| i + 8));
        assert_relative_eq!(m.signed_volume(), 9.0, epsilon = 1e-12);
        assert!(m.report().watertight);
    }

    #[test]
    fn construction_refuses_bad_input() {
        let v = vec![Vec3::zeros(); 3];
        assert!(matches!(
            TriMesh::new(v.clone(), vec![[0, 1, 3]]),
            Err(GeomError::VertexIndexOutOfRange {
                triangle: 0,
                index: 3,
                vertex_count: 3
            })
        ));
        let mut nan = v.clone();
        nan[1].x = Real::NAN;
        assert_eq!(
            TriMesh::new(nan, vec![]),
            Err(GeomError::NonFiniteVertex(1))
        );
        let m = TriMesh::new(v, vec![[0, 1, 2]]).unwrap();
        assert!(m.clone().with_normals(vec![Vec3::x(); 2]).is_err());
        assert!(m.with_scalars("margin", vec![0.0; 3]).is_ok());
    }
}
