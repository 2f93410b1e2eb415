//! Plane–mesh slicing into polylines (thesis ch. 7.3, Algorithm 1: cross-sections of the
//! parenchyma).
//!
//! Each vertex gets the side `s = n·(v − p) ≥ 0` (positive) or `s < 0` (negative): a vertex exactly
//! on the plane counts as positive, which is the symbolic perturbation of the plane by an
//! infinitesimal step along `−n`. No vertex is then on the plane, every triangle with mixed sides
//! gives exactly one segment between two edge crossings, and crossings are identified by their
//! mesh edge, so the segments of a closed 2-manifold chain into closed loops. A crossing on an edge
//! with an end on the plane is that vertex exactly; after chaining, repeated consecutive points
//! are merged, so no output segment has zero length. Consequences: a plane touching the surface
//! only at a vertex or along an edge yields nothing, and a plane containing a face yields its
//! outline only if the mesh continues on the negative side.
//!
//! Loops are oriented counter-clockwise seen from the `+n` side for an outward-oriented mesh
//! (enclosed material on the left), so outer outlines and holes can be told apart by orientation.

use std::collections::HashMap;

use crate::error::GeomError;
use crate::math::{Real, Vec3};
use crate::mesh::TriMesh;

/// A plane through `point` with normal `normal` (any non-zero length; [`Plane::new`] normalises).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    pub point: Vec3,
    pub normal: Vec3,
}

impl Plane {
    /// A plane with unit normal; refuses non-finite input and a zero normal.
    pub fn new(point: Vec3, normal: Vec3) -> Result<Self, GeomError> {
        let finite = point.iter().chain(normal.iter()).all(|c| c.is_finite());
        match normal.try_normalize(0.0) {
            Some(normal) if finite => Ok(Self { point, normal }),
            _ => Err(GeomError::InvalidParameter {
                name: "plane",
                reason: "needs a finite point and a finite non-zero normal",
            }),
        }
    }

    /// `normal·(p − point)`: the signed distance when the normal is unit.
    pub fn signed_distance(&self, p: &Vec3) -> Real {
        self.normal.dot(&(p - self.point))
    }
}

/// A polyline; when `is_closed` the last point joins the first (not repeated).
#[derive(Debug, Clone, PartialEq)]
pub struct Polyline {
    pub points: Vec<Vec3>,
    pub is_closed: bool,
}

impl Polyline {
    /// Segments as point pairs, including the closing one.
    pub fn segments(&self) -> impl Iterator<Item = (Vec3, Vec3)> + '_ {
        let n = self.points.len();
        let count = if self.is_closed {
            n
        } else {
            n.saturating_sub(1)
        };
        (0..count).map(move |i| (self.points[i], self.points[(i + 1) % n]))
    }

    pub fn length(&self) -> Real {
        self.segments().map(|(a, b)| (b - a).norm()).sum()
    }

    /// Vector area `½ Σ pᵢ × pᵢ₊₁` of a closed polyline (its dot with a unit normal is the signed
    /// enclosed area about that normal); zero for open ones.
    pub fn vector_area(&self) -> Vec3 {
        if !self.is_closed {
            return Vec3::zeros();
        }
        let o = self.points.first().copied().unwrap_or_else(Vec3::zeros);
        self.segments()
            .map(|(a, b)| (a - o).cross(&(b - o)))
            .sum::<Vec3>()
            * 0.5
    }
}

/// Intersection of `mesh` with `plane` as polylines: closed loops for a closed mesh, open
/// polylines where the section runs into a boundary (or a non-manifold edge). A plane missing the
/// mesh, or a zero or non-finite normal, gives nothing.
pub fn slice(mesh: &TriMesh, plane: &Plane) -> Vec<Polyline> {
    let vertices = mesh.vertices();
    let side: Vec<Real> = vertices.iter().map(|v| plane.signed_distance(v)).collect();
    // Crossing edge (lower, higher vertex) → node.
    let mut node_of: HashMap<(u32, u32), u32> = HashMap::new();
    let mut points: Vec<Vec3> = Vec::new();
    let mut segments: Vec<[u32; 2]> = Vec::new();
    let mut node = |p: u32, q: u32| {
        let (i, j) = (p.min(q), p.max(q));
        *node_of.entry((i, j)).or_insert_with(|| {
            let (si, sj) = (side[i as usize], side[j as usize]);
            let (vi, vj) = (vertices[i as usize], vertices[j as usize]);
            points.push(if si == 0.0 {
                vi
            } else if sj == 0.0 {
                vj
            } else {
                vi + (vj - vi) * (si / (si - sj)).clamp(0.0, 1.0)
            });
            (points.len() - 1) as u32
        })
    };
    for tri in mesh.triangles() {
        let s = tri.map(|v| side[v as usize] >= 0.0);
        if s[0] == s[1] && s[1] == s[2] {
            continue;
        }
        // From the crossing of the edge leaving the positive side to the one entering it.
        let (mut from, mut to) = (None, None);
        for k in 0..3 {
            let (p, q) = (tri[k], tri[(k + 1) % 3]);
            match (s[k], s[(k + 1) % 3]) {
                (true, false) => from = Some(node(p, q)),
                (false, true) => to = Some(node(p, q)),
                _ => {}
            }
        }
        if let (Some(a), Some(b)) = (from, to)
            && a != b
        {
            segments.push([a, b]);
        }
    }
    chain(&points, &segments)
}

/// Chains segments (node pairs) into maximal polylines: first the open ones from nodes not of
/// degree 2, then the remaining cycles.
fn chain(points: &[Vec3], segments: &[[u32; 2]]) -> Vec<Polyline> {
    let n = points.len();
    let mut offset = vec![0usize; n + 1];
    for s in segments {
        offset[s[0] as usize + 1] += 1;
        offset[s[1] as usize + 1] += 1;
    }
    for i in 0..n {
        offset[i + 1] += offset[i];
    }
    let mut incident = vec![0u32; offset[n]];
    let mut fill = offset.clone();
    for (i, s) in segments.iter().enumerate() {
        for &v in s {
            incident[fill[v as usize]] = i as u32;
            fill[v as usize] += 1;
        }
    }
    let degree = |v: usize| offset[v + 1] - offset[v];
    let mut used = vec![false; segments.len()];
    let mut out = Vec::new();
    let walk = |start: usize, first: usize, used: &mut Vec<bool>| {
        let (mut seq, mut forward) = (vec![start as u32], 0isize);
        let (mut cur, mut seg) = (start, first);
        let closed = loop {
            used[seg] = true;
            let [a, b] = segments[seg];
            let next = if a as usize == cur {
                forward += 1;
                b
            } else {
                forward -= 1;
                a
            } as usize;
            cur = next;
            if cur == start {
                break true;
            }
            seq.push(cur as u32);
            if degree(cur) != 2 {
                break false;
            }
            match incident[offset[cur]..offset[cur + 1]]
                .iter()
                .find(|&&s| !used[s as usize])
            {
                Some(&s) => seg = s as usize,
                None => break false,
            }
        };
        if forward < 0 {
            seq.reverse();
        }
        finish(points, &seq, closed)
    };
    for v in 0..n {
        if degree(v) == 2 {
            continue;
        }
        for &s in &incident[offset[v]..offset[v + 1]] {
            if !used[s as usize] {
                out.extend(walk(v, s as usize, &mut used));
            }
        }
    }
    for s in 0..segments.len() {
        if !used[s] {
            out.extend(walk(segments[s][0] as usize, s, &mut used));
        }
    }
    out
}

/// Points of a node sequence with repeated consecutive points merged; `None` if what remains
/// has no length (fewer than 2 points, or fewer than 3 for a loop).
fn finish(points: &[Vec3], seq: &[u32], closed: bool) -> Option<Polyline> {
    let mut pts: Vec<Vec3> = Vec::with_capacity(seq.len());
    for &i in seq {
        let p = points[i as usize];
        if pts.last() != Some(&p) {
            pts.push(p);
        }
    }
    if closed {
        while pts.len() > 1 && pts.first() == pts.last() {
            pts.pop();
        }
    }
    let enough = if closed {
        pts.len() >= 3
    } else {
        pts.len() >= 2
    };
    enough.then_some(Polyline {
        points: pts,
        is_closed: closed,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::tests::Rng;
    use crate::primitives::{cylinder, ellipsoid, icosphere, inscribed_radius};
    use std::f64::consts::PI;

    fn assert_clean(poly: &Polyline) {
        for (a, b) in poly.segments() {
            assert!((b - a).norm() > 0.0, "zero-length segment");
        }
        for (i, p) in poly.points.iter().enumerate() {
            assert!(!poly.points[i + 1..].contains(p), "duplicate point");
        }
    }

    #[test]
    fn sphere_section_is_one_loop_on_the_circle() {
        let (c, r) = (Vec3::new(2.0, -1.0, 5.0), 10.0);
        let mesh = icosphere(c, r, 4).unwrap();
        let r_in = inscribed_radius(&mesh, &c).unwrap();
        let mut rng = Rng(21);
        for _ in 0..50 {
            let n = rng.direction();
            let offset = 0.9 * r * (2.0 * rng.unit() - 1.0);
            let plane = Plane::new(c + n * offset, n).unwrap();
            let loops = slice(&mesh, &plane);
            assert_eq!(loops.len(), 1);
            let l = &loops[0];
            assert!(l.is_closed && l.points.len() > 20);
            assert_clean(l);
            // Mesh points lie in the shell r_in ≤ ‖x − c‖ ≤ r; in the plane that is the annulus
            // between the circles of radii √(r_in² − o²) and √(r² − o²).
            let (rc_in, rc) = (
                (r_in * r_in - offset * offset).sqrt(),
                (r * r - offset * offset).sqrt(),
            );
            let centre = c + n * offset;
            for p in &l.points {
                assert!(plane.signed_distance(p).abs() <= 1e-9);
                let rho = (p - centre).norm();
                assert!(
                    rho >= rc_in - 1e-9 && rho <= rc + 1e-9,
                    "{rho} {rc_in} {rc}"
                );
            }
            let area = l.vector_area().dot(&n);
            assert!(area > 0.0, "loop must be counter-clockwise about n");
            // The section contains the disc of radius rc_in (section of the inscribed ball) and
            // lies in the disc of radius rc.
            assert!(
                area <= PI * rc * rc * (1.0 + 1e-12) && area >= PI * rc_in * rc_in * (1.0 - 1e-12)
            );
        }
    }

    #[test]
    fn ellipsoid_section_is_on_the_ellipse() {
        let c = Vec3::new(-1.0, 4.0, 2.0);
        let radii = Vec3::new(15.0, 9.0, 5.0);
        let rot = *nalgebra::Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vec3::new(2.0, -1.0, 1.0)),
            0.4,
        )
        .matrix();
        let s = 4;
        let mesh = ellipsoid(c, radii, rot, s).unwrap();
        let h =
            inscribed_radius(&icosphere(Vec3::zeros(), 1.0, s).unwrap(), &Vec3::zeros()).unwrap();
        let mut rng = Rng(8);
        for _ in 0..30 {
            let n = rng.direction();
            let plane = Plane::new(c + rng.point(2.0), n).unwrap();
            let loops = slice(&mesh, &plane);
            assert_eq!(loops.len(), 1);
            assert!(loops[0].is_closed);
            assert_clean(&loops[0]);
            for p in &loops[0].points {
                assert!(plane.signed_distance(p).abs() <= 1e-9);
                // The section ellipse is {x in plane : ρ(x) = 1}; mesh points have ρ ∈ [h, 1].
                let rho = (rot.transpose() * (p - c)).component_div(&radii).norm();
                assert!(rho >= h - 1e-12 && rho <= 1.0 + 1e-12, "{rho}");
            }
        }
    }

    #[test]
    fn plane_through_vertices_exactly() {
        // x = 0 through the centre contains icosahedron vertices (0, ±1, ±φ) and all midpoints
        // subdivided between them: many vertices with side exactly 0.
        let mesh = icosphere(Vec3::zeros(), 1.0, 3).unwrap();
        let on_plane = mesh.vertices().iter().filter(|v| v.x == 0.0).count();
        assert!(on_plane >= 30, "{on_plane}");
        for normal in [Vec3::x(), -Vec3::x()] {
            let plane = Plane::new(Vec3::zeros(), normal).unwrap();
            let loops = slice(&mesh, &plane);
            assert_eq!(loops.len(), 1);
            let l = &loops[0];
            assert!(l.is_closed);
            assert_clean(l);
            // Every on-plane vertex is a point of the section, exactly once; all points have x = 0
            // exactly (other crossings are midpoints of edges between mirror-image vertices).
            let r_in = inscribed_radius(&mesh, &Vec3::zeros()).unwrap();
            for v in mesh.vertices().iter().filter(|v| v.x == 0.0) {
                assert_eq!(l.points.iter().filter(|p| *p == v).count(), 1);
            }
            for p in &l.points {
                assert_eq!(p.x, 0.0);
                assert!(p.norm() >= r_in - 1e-15 && p.norm() <= 1.0 + 1e-15);
            }
            assert!(l.vector_area().dot(&normal) > 0.0);
        }
        // A cylinder cut at its cap plane: with the normal pointing out of the solid the cap
        // vertices count as positive and the section is the cap outline; pointing in, the mesh
        // lies entirely on the positive side and the section is empty.
        let n = 24;
        let cyl = cylinder(Vec3::zeros(), Vec3::z() * 4.0, 1.0, n, 4).unwrap();
        let cap_out = slice(&cyl, &Plane::new(Vec3::z() * 4.0, Vec3::z()).unwrap());
        assert_eq!(cap_out.len(), 1);
        assert_eq!(cap_out[0].points.len(), n as usize);
        assert_clean(&cap_out[0]);
        assert!(cap_out[0].points.iter().all(|p| p.z == 4.0));
        assert!(slice(&cyl, &Plane::new(Vec3::z() * 4.0, -Vec3::z()).unwrap()).is_empty());
        // Stack boundary at z = 1 (a ring of vertices) through the side wall.
        let ring = slice(&cyl, &Plane::new(Vec3::z(), Vec3::z()).unwrap());
        assert_eq!(ring.len(), 1);
        assert_eq!(ring[0].points.len(), n as usize);
        // Touching at a single vertex gives nothing.
        let top = mesh
            .vertices()
            .iter()
            .copied()
            .max_by(|a, b| a.z.total_cmp(&b.z))
            .unwrap();
        assert!(slice(&mesh, &Plane::new(top, Vec3::z()).unwrap()).is_empty());
        assert!(slice(&mesh, &Plane::new(top, -Vec3::z()).unwrap()).is_empty());
    }

    #[test]
    fn plane_missing_the_mesh_and_open_meshes() {
        let mesh = icosphere(Vec3::zeros(), 5.0, 3).unwrap();
        assert!(slice(&mesh, &Plane::new(Vec3::z() * 5.5, Vec3::z()).unwrap()).is_empty());
        assert!(
            slice(
                &mesh,
                &Plane {
                    point: Vec3::zeros(),
                    normal: Vec3::zeros()
                }
            )
            .is_empty()
        );
        assert!(Plane::new(Vec3::zeros(), Vec3::zeros()).is_err());
        // Remove both caps (triangles with centroid |z| > 2): open mesh with two boundary loops.
        let kept: Vec<[u32; 3]> = mesh
            .triangles()
            .iter()
            .enumerate()
            .filter(|(t, _)| mesh.corners(*t).iter().map(|v| v.z).sum::<Real>().abs() / 3.0 <= 2.0)
            .map(|(_, t)| *t)
            .collect();
        let open = TriMesh::new(mesh.vertices().to_vec(), kept).unwrap();
        assert!(open.report().boundary_edges > 0);
        // A vertical plane through both holes: two open arcs ending at the boundaries.
        let arcs = slice(
            &open,
            &Plane::new(Vec3::new(0.3, 0.0, 0.0), Vec3::x()).unwrap(),
        );
        assert_eq!(arcs.len(), 2, "{arcs:?}");
        for a in &arcs {
            assert!(!a.is_closed && a.points.len() >= 2);
            assert_clean(a);
        }
        // Between the holes the section is still a closed loop.
        let below = slice(&open, &Plane::new(Vec3::zeros(), Vec3::z()).unwrap());
        assert_eq!(below.len(), 1);
        assert!(below[0].is_closed);
    }
}
