//! Analytic test shapes as watertight, outward-oriented triangle meshes.
//!
//! Every vertex lies on the analytic surface (up to the rounding of its coordinates) and every face
//! is a chord, so each mesh is inscribed in its (convex) shape. For a sphere of radius `r` the mesh
//! lies in the shell `r_in ≤ ‖x − c‖ ≤ r`, `r_in` = distance from the centre to the nearest face,
//! and its Hausdorff distance to the sphere is at most `r − r_in` (see [`inscribed_radius`]).

use std::collections::HashMap;

use crate::error::GeomError;
use crate::math::{Mat3, Real, Vec3};
use crate::mesh::TriMesh;

/// Most subdivisions accepted by [`icosphere`] and [`ellipsoid`]: 20·4⁹ ≈ 5.2 M triangles.
pub const MAX_SUBDIVISIONS: u32 = 9;
/// Most segments around, or stacks along, a [`cylinder`].
pub const MAX_CYLINDER_RESOLUTION: u32 = 1 << 14;

fn invalid(name: &'static str, reason: &'static str) -> GeomError {
    GeomError::InvalidParameter { name, reason }
}

fn check_point(name: &'static str, p: &Vec3) -> Result<(), GeomError> {
    if p.iter().all(|c| c.is_finite()) {
        Ok(())
    } else {
        Err(invalid(name, "must be finite"))
    }
}

fn check_length(name: &'static str, x: Real) -> Result<(), GeomError> {
    if x.is_finite() && x > 0.0 {
        Ok(())
    } else {
        Err(invalid(name, "must be finite and positive"))
    }
}

/// Unit icosphere: unit vertex directions and outward triangles (`10·4ˢ + 2` vertices,
/// `20·4ˢ` triangles).
fn unit_icosphere(subdivisions: u32) -> Result<(Vec<Vec3>, Vec<[u32; 3]>), GeomError> {
    if subdivisions > MAX_SUBDIVISIONS {
        return Err(invalid("subdivisions", "must be at most 9"));
    }
    let phi = (1.0 + Real::sqrt(5.0)) / 2.0;
    let mut vertices: Vec<Vec3> = [
        (-1.0, phi, 0.0),
        (1.0, phi, 0.0),
        (-1.0, -phi, 0.0),
        (1.0, -phi, 0.0),
        (0.0, -1.0, phi),
        (0.0, 1.0, phi),
        (0.0, -1.0, -phi),
        (0.0, 1.0, -phi),
        (phi, 0.0, -1.0),
        (phi, 0.0, 1.0),
        (-phi, 0.0, -1.0),
        (-phi, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
    .collect();
    let mut triangles: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..subdivisions {
        let mut midpoints: HashMap<(u32, u32), u32> =
            HashMap::with_capacity(triangles.len() * 3 / 2);
        let mut next = Vec::with_capacity(triangles.len() * 4);
        vertices.reserve(triangles.len() * 3 / 2);
        for &[a, b, c] in &triangles {
            let mut mid = |p: u32, q: u32| {
                *midpoints.entry((p.min(q), p.max(q))).or_insert_with(|| {
                    vertices.push((vertices[p as usize] + vertices[q as usize]).normalize());
                    // At most 10·4⁹ + 2 vertices: fits u32.
                    (vertices.len() - 1) as u32
                })
            };
            let (ab, bc, ca) = (mid(a, b), mid(b, c), mid(c, a));
            next.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        triangles = next;
    }
    Ok((vertices, triangles))
}

/// Axis-aligned box from `min` to `max` (12 triangles; each face split along a diagonal).
pub fn cuboid(min: Vec3, max: Vec3) -> Result<TriMesh, GeomError> {
    check_point("min", &min)?;
    check_point("max", &max)?;
    if (0..3).any(|a| max[a] <= min[a]) {
        return Err(invalid("max", "must exceed min on every axis"));
    }
    let corner = |i: usize| Vec3::from_fn(|a, _| if (i >> a) & 1 == 0 { min[a] } else { max[a] });
    let triangles = vec![
        [0, 2, 1],
        [1, 2, 3], // z = min
        [4, 5, 6],
        [5, 7, 6], // z = max
        [0, 1, 4],
        [1, 5, 4], // y = min
        [2, 6, 3],
        [3, 6, 7], // y = max
        [0, 4, 2],
        [2, 4, 6], // x = min
        [1, 3, 5],
        [3, 7, 5], // x = max
    ];
    TriMesh::new((0..8).map(corner).collect(), triangles)
}

/// Sphere of `radius` about `center`, by `subdivisions` midpoint subdivisions of an icosahedron
/// (`20·4ˢ` triangles: 5 → 20 480, 7 → 327 680).
pub fn icosphere(center: Vec3, radius: Real, subdivisions: u32) -> Result<TriMesh, GeomError> {
    check_point("center", &center)?;
    check_length("radius", radius)?;
    let (unit, triangles) = unit_icosphere(subdivisions)?;
    let vertices = unit.into_iter().map(|u| center + u * radius).collect();
    TriMesh::new(vertices, triangles)
}

/// Ellipsoid `{center + rotation · diag(radii) · u : ‖u‖ = 1}`, the affine image of the unit
/// icosphere. `rotation` must be a proper rotation (orthonormal to 1e-9, determinant +1).
///
/// Being an affine image of the unit icosphere, the mesh lies between the ellipsoid and its copy
/// scaled by the unit icosphere's [`inscribed_radius`] `h` about `center`; its Hausdorff distance
/// to the ellipsoid is at most `max(radii) · (1 − h)`.
pub fn ellipsoid(
    center: Vec3,
    radii: Vec3,
    rotation: Mat3,
    subdivisions: u32,
) -> Result<TriMesh, GeomError> {
    check_point("center", &center)?;
    for &r in radii.iter() {
        check_length("radii", r)?;
    }
    if rotation.iter().any(|x| !x.is_finite())
        || (rotation.transpose() * rotation - Mat3::identity()).amax() > 1e-9
        || rotation.determinant() <= 0.0
    {
        return Err(invalid("rotation", "must be a proper rotation matrix"));
    }
    let (unit, triangles) = unit_icosphere(subdivisions)?;
    let linear = rotation * Mat3::from_diagonal(&radii);
    let vertices = unit.into_iter().map(|u| center + linear * u).collect();
    TriMesh::new(vertices, triangles)
}

/// Closed, capped circular cylinder (tube) of `radius` with axis from `start` to `end`:
/// `segments` (≥ 3) around, `stacks` (≥ 1) along the axis, and a triangle fan on each cap
/// about its centre. Its Hausdorff distance to the analytic cylinder is `radius·(1 − cos(π/segments))`.
pub fn cylinder(
    start: Vec3,
    end: Vec3,
    radius: Real,
    segments: u32,
    stacks: u32,
) -> Result<TriMesh, GeomError> {
    check_point("start", &start)?;
    check_point("end", &end)?;
    check_length("radius", radius)?;
    if !(3..=MAX_CYLINDER_RESOLUTION).contains(&segments) {
        return Err(invalid("segments", "must be between 3 and 16384"));
    }
    if !(1..=MAX_CYLINDER_RESOLUTION).contains(&stacks) {
        return Err(invalid("stacks", "must be between 1 and 16384"));
    }
    let axis = end - start;
    let Some(dir) = axis
        .try_normalize(0.0)
        .filter(|d| d.iter().all(|c| c.is_finite()))
    else {
        return Err(invalid("end", "must differ from start"));
    };
    // Right-handed frame (e1, e2, dir).
    let helper = if dir.x.abs() < 0.9 {
        Vec3::x()
    } else {
        Vec3::y()
    };
    let e1 = dir.cross(&helper).normalize();
    let e2 = dir.cross(&e1);
    let (n, s) = (segments as usize, stacks as usize);
    let ring = |j: usize, k: usize| (j * n + k % n) as u32;
    let mut vertices = Vec::with_capacity((s + 1) * n + 2);
    for j in 0..=s {
        let along = start + axis * (j as Real / s as Real);
        for k in 0..n {
            let theta = std::f64::consts::TAU * k as Real / n as Real;
            vertices.push(along + (e1 * theta.cos() + e2 * theta.sin()) * radius);
        }
    }
    let (bottom, top) = (vertices.len() as u32, vertices.len() as u32 + 1);
    vertices.push(start);
    vertices.push(end);
    let mut triangles = Vec::with_capacity(2 * n * (s + 1));
    for j in 0..s {
        for k in 0..n {
            let (v00, v01, v10, v11) = (
                ring(j, k),
                ring(j, k + 1),
                ring(j + 1, k),
                ring(j + 1, k + 1),
            );
            triangles.push([v00, v01, v11]);
            triangles.push([v00, v11, v10]);
        }
    }
    for k in 0..n {
        triangles.push([bottom, ring(0, k + 1), ring(0, k)]);
        triangles.push([top, ring(s, k), ring(s, k + 1)]);
    }
    TriMesh::new(vertices, triangles)
}

/// Smallest distance from `center` to any triangle of `mesh` (the radius of the largest ball
/// about `center` inside a mesh inscribed in a sphere about `center`); `None` for an empty mesh.
pub fn inscribed_radius(mesh: &TriMesh, center: &Vec3) -> Option<Real> {
    (0..mesh.triangles().len())
        .map(|t| {
            let tp = crate::bvh::closest_point_on_triangle(center, &mesh.corners(t));
            (tp.point - center).norm()
        })
        .min_by(Real::total_cmp)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn icosphere_is_watertight_outward_and_on_the_sphere() {
        let c = Vec3::new(1.0, -2.0, 3.0);
        let r = 7.5;
        for s in 0..=4 {
            let m = icosphere(c, r, s).unwrap();
            assert_eq!(m.triangles().len(), 20 * 4usize.pow(s));
            assert_eq!(m.vertices().len(), 10 * 4usize.pow(s) + 2);
            let rep = m.report();
            assert!(rep.watertight, "{rep:?}");
            for v in m.vertices() {
                assert!(((v - c).norm() - r).abs() <= 1e-12 * r);
            }
            let r_in = inscribed_radius(&m, &c).unwrap();
            let vol = m.signed_volume();
            assert!(vol > 4.0 / 3.0 * PI * r_in.powi(3) && vol < 4.0 / 3.0 * PI * r.powi(3));
        }
        // Polyhedral bound shrinks about 4× per subdivision: (r − r_in)/r.
        let gap = |s| {
            let m = icosphere(c, r, s).unwrap();
            1.0 - inscribed_radius(&m, &c).unwrap() / r
        };
        assert!(
            gap(4) < 1.2e-3 && gap(5) < gap(4) / 3.5,
            "{} {}",
            gap(4),
            gap(5)
        );
    }

    #[test]
    fn ellipsoid_vertices_on_surface() {
        let c = Vec3::new(-3.0, 0.5, 2.0);
        let radii = Vec3::new(12.0, 7.0, 4.0);
        let rot = *nalgebra::Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vec3::new(1.0, 2.0, -0.5)),
            0.7,
        )
        .matrix();
        let m = ellipsoid(c, radii, rot, 3).unwrap();
        assert!(m.report().watertight);
        assert!(m.signed_volume() > 0.0);
        for v in m.vertices() {
            let u = (rot.transpose() * (v - c)).component_div(&radii);
            assert!((u.norm() - 1.0).abs() <= 1e-12);
        }
        let reflection = Mat3::from_diagonal(&Vec3::new(1.0, 1.0, -1.0));
        assert!(ellipsoid(c, radii, reflection, 2).is_err());
        assert!(ellipsoid(c, Vec3::new(1.0, 0.0, 1.0), rot, 2).is_err());
        assert!(ellipsoid(c, radii, rot * 1.01, 2).is_err());
    }

    #[test]
    fn cylinder_is_closed_tube() {
        let (a, b, r, n) = (
            Vec3::new(1.0, 2.0, 3.0),
            Vec3::new(4.0, -2.0, 15.0),
            2.5,
            48,
        );
        let m = cylinder(a, b, r, n, 5).unwrap();
        let rep = m.report();
        assert!(rep.watertight, "{rep:?}");
        let dir = (b - a).normalize();
        let len = (b - a).norm();
        for v in &m.vertices()[..m.vertices().len() - 2] {
            let d = v - a;
            let radial = (d - dir * d.dot(&dir)).norm();
            assert!((radial - r).abs() <= 1e-12 * r);
        }
        let vol = m.signed_volume();
        let r_in = r * (PI / n as Real).cos();
        // The polygon's area lies between the inscribed and circumscribed-by-r discs.
        assert!(
            vol > PI * r_in * r_in * len && vol < PI * r * r * len,
            "{vol}"
        );
        let polygon = 0.5 * n as Real * r * r * (2.0 * PI / n as Real).sin() * len;
        assert!((vol - polygon).abs() <= 1e-9 * polygon);
    }

    #[test]
    fn bad_parameters_are_refused() {
        let o = Vec3::zeros();
        assert!(matches!(
            icosphere(o, -1.0, 2),
            Err(GeomError::InvalidParameter { name: "radius", .. })
        ));
        assert!(icosphere(o, 1.0, MAX_SUBDIVISIONS + 1).is_err());
        assert!(icosphere(Vec3::new(Real::NAN, 0.0, 0.0), 1.0, 1).is_err());
        assert!(cylinder(o, o, 1.0, 8, 1).is_err());
        assert!(cylinder(o, Vec3::z(), 1.0, 2, 1).is_err());
        assert!(cylinder(o, Vec3::z(), 1.0, 8, 0).is_err());
    }
}
