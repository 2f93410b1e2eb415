//! Point-to-surface distance (Eq. 6.9).

use rayon::prelude::*;
use resecta_geom::{MeshBvh, Real, TriMesh, Vec3};

use crate::error::MetricsError;
use crate::stats::percentile;

/// Summary of the distances from a reference cloud to a surface, in mm.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DistanceStats {
    /// Mean distance δ̄ (Eq. 6.9).
    pub mean: Real,
    /// 95th percentile (linear interpolation, see [`percentile`]).
    pub p95: Real,
    pub max: Real,
    /// Number of reference points.
    pub count: usize,
}

/// Distances from every point of `points` (the reference cloud 𝒱, e.g. the oriented points of the
/// label map) to the closest point of `mesh`, exact per triangle (through [`MeshBvh`]).
///
/// Parallel over points (rayon); the sum is taken sequentially in input order, so the result is
/// bit-for-bit the same for any number of threads. Eq. 6.9 divides by "the number of points in
/// ∂M", which can only mean the number of reference points `L`: so does this function.
pub fn point_to_surface(points: &[Vec3], mesh: &TriMesh) -> Result<DistanceStats, MetricsError> {
    if points.is_empty() {
        return Err(MetricsError::NoPoints);
    }
    if let Some(i) = points.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
        return Err(MetricsError::NonFinitePoint(i));
    }
    if mesh.is_empty() {
        return Err(MetricsError::EmptyMesh);
    }
    let bvh = MeshBvh::new(mesh)?;
    let mut d: Vec<Real> = points
        .par_iter()
        .map(|p| bvh.closest_point(p).map_or(Real::INFINITY, |c| c.distance))
        .collect();
    // Finite points and a non-empty mesh always have a closest point; guard anyway.
    if let Some(i) = d.iter().position(|x| !x.is_finite()) {
        return Err(MetricsError::NonFinitePoint(i));
    }
    let mean = d.iter().sum::<Real>() / d.len() as Real;
    d.sort_unstable_by(Real::total_cmp);
    let max = d[d.len() - 1];
    let p95 = percentile(&d, 95.0).unwrap_or(max);
    Ok(DistanceStats {
        mean,
        p95,
        max,
        count: d.len(),
    })
}
