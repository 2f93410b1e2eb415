//! Quality of one model against the oriented points of its mask (Sec. 6.3).

use resecta_geom::{Real, TriMesh, Vec3};
use resecta_meshmetrics::{mean_gaussian_curvature, point_to_surface};

use crate::ReconError;

/// Accuracy, complexity and smoothness of a model.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Quality {
    /// Triangles.
    pub polys: usize,
    /// Vertices.
    pub points: usize,
    /// Point-to-surface distance from the reference points (Eq. 6.9): mean, 95th percentile
    /// and maximum, mm.
    pub mean_mm: Real,
    pub p95_mm: Real,
    pub max_mm: Real,
    /// Enclosed volume, ml (meaningful when watertight).
    pub volume_ml: Real,
    /// Closed, manifold, consistently oriented, no degenerate triangles.
    pub watertight: bool,
    /// Mean Gaussian curvature over the 5–95 percentile (Eq. 6.13), 1/mm².
    pub curvature: Real,
}

/// Measures `mesh` against the reference `points` (the oriented points of the mask).
pub fn measure(mesh: &TriMesh, points: &[Vec3]) -> Result<Quality, ReconError> {
    let d = point_to_surface(points, mesh)?;
    let report = mesh.report();
    Ok(Quality {
        polys: mesh.triangles().len(),
        points: mesh.vertices().len(),
        mean_mm: d.mean,
        p95_mm: d.p95,
        max_mm: d.max,
        volume_ml: mesh.signed_volume() / 1000.0,
        watertight: report.watertight,
        curvature: mean_gaussian_curvature(mesh, 5.0, 95.0)?,
    })
}
