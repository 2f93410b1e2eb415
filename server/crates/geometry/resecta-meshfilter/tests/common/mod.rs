//! Deterministic test meshes.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use resecta_geom::{Mat3, Real, TriMesh, Vec3, primitives};

/// Deterministic value in [-1, 1) from an integer (SplitMix64).
pub fn hash_unit(i: u64) -> Real {
    let mut z = i.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as Real / (1u64 << 52) as Real - 1.0
}

pub const CENTER: Vec3 = Vec3::new(3.0, -7.0, 11.0);
pub const RADIUS: Real = 50.0;

/// Icosphere of `RADIUS` about `CENTER` with radial noise of relative amplitude `noise`
/// (uniform in ±noise).
pub fn noisy_sphere(subdivisions: u32, noise: Real) -> TriMesh {
    let s = primitives::icosphere(CENTER, RADIUS, subdivisions).unwrap();
    let v = s
        .vertices()
        .iter()
        .enumerate()
        .map(|(i, p)| CENTER + (p - CENTER) * (1.0 + noise * hash_unit(i as u64)))
        .collect();
    TriMesh::new(v, s.triangles().to_vec()).unwrap()
}

/// RMS and max of `|‖v − CENTER‖ − RADIUS|` over the vertices.
pub fn radial_error(m: &TriMesh) -> (Real, Real) {
    let e: Vec<Real> = m
        .vertices()
        .iter()
        .map(|p| ((p - CENTER).norm() - RADIUS).abs())
        .collect();
    let rms = (e.iter().map(|x| x * x).sum::<Real>() / e.len() as Real).sqrt();
    (rms, e.iter().copied().fold(0.0, Real::max))
}

/// The sphere without the triangles whose centroid lies above `CENTER.z + 0.6·RADIUS`.
pub fn open_sphere(subdivisions: u32, noise: Real) -> TriMesh {
    let s = noisy_sphere(subdivisions, noise);
    let tris = s
        .triangles()
        .iter()
        .copied()
        .filter(|t| {
            t.iter()
                .map(|&v| s.vertices()[v as usize].z - CENTER.z)
                .sum::<Real>()
                < 3.0 * 0.6 * RADIUS
        })
        .collect();
    TriMesh::new(s.vertices().to_vec(), tris).unwrap()
}

pub const RADII: Vec3 = Vec3::new(40.0, 30.0, 20.0);

/// A fixed proper rotation `Rz(0.5)·Ry(−0.4)·Rx(0.3)`.
pub fn rotation() -> Mat3 {
    let (a, b, c): (Real, Real, Real) = (0.5, -0.4, 0.3);
    let rz = Mat3::new(a.cos(), -a.sin(), 0.0, a.sin(), a.cos(), 0.0, 0.0, 0.0, 1.0);
    let ry = Mat3::new(b.cos(), 0.0, b.sin(), 0.0, 1.0, 0.0, -b.sin(), 0.0, b.cos());
    let rx = Mat3::new(1.0, 0.0, 0.0, 0.0, c.cos(), -c.sin(), 0.0, c.sin(), c.cos());
    rz * ry * rx
}

/// Ellipsoid `RADII` rotated by [`rotation`] about `CENTER`.
pub fn ellipsoid(subdivisions: u32) -> TriMesh {
    primitives::ellipsoid(CENTER, RADII, rotation(), subdivisions).unwrap()
}

/// Upper bound on the distance from `p` to the analytic ellipsoid: `|p − p/s|` where
/// `s = ‖diag(1/r)·Rᵀ(p − c)‖` (p/s lies on the ellipsoid).
pub fn ellipsoid_distance_bound(p: &Vec3) -> Real {
    let local = rotation().transpose() * (p - CENTER);
    let s = local.component_div(&RADII).norm();
    (local - local / s).norm()
}

/// Max over vertices and triangle centroids of [`ellipsoid_distance_bound`].
pub fn max_ellipsoid_distance(m: &TriMesh) -> Real {
    let v = m.vertices().iter().map(ellipsoid_distance_bound);
    let c = (0..m.triangles().len()).map(|t| {
        let [a, b, c] = m.corners(t);
        ellipsoid_distance_bound(&((a + b + c) / 3.0))
    });
    v.chain(c).fold(0.0, Real::max)
}

pub fn bits(m: &TriMesh) -> Vec<[u64; 3]> {
    m.vertices()
        .iter()
        .map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
        .collect()
}
