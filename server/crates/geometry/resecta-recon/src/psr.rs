//! Poisson surface reconstruction of a mask (Paper I): oriented points from the mask's
//! gradient, the screened Poisson solve on a dense grid, marching cubes at the iso-value.
//! The multigrid runs on the [`PoissonSolver`] given (`*_with`; the CPU's otherwise), the rest
//! on the host, so backends differ only in the solved field.

use resecta_geom::{Real, TriMesh, Volume};
use resecta_isosurface::{Options, extract_with};
use resecta_meshmetrics::point_to_surface;
use resecta_poisson::{
    OrientedPoints, PoissonField, PoissonParams, PoissonSolver, oriented_points,
    oriented_points_with, solve_with,
};

use crate::{ReconError, mask};

/// A PSR model with the samples it was fitted to.
#[derive(Debug, Clone)]
pub struct PsrModel {
    pub mesh: TriMesh,
    pub points: OrientedPoints,
    pub depth: u32,
}

/// Oriented points of `mask` (computed on its bounding box).
pub fn points(mask: &Volume<bool>) -> Result<OrientedPoints, ReconError> {
    let crop = mask::crop(mask, 1)?;
    Ok(oriented_points(&crop)?)
}

/// [`points`] with the Sobel pass of `solver`.
pub fn points_with(
    mask: &Volume<bool>,
    solver: &PoissonSolver,
) -> Result<OrientedPoints, ReconError> {
    let crop = mask::crop(mask, 1)?;
    Ok(oriented_points_with(&crop, solver.sobel())?)
}

/// The PSR surface of `points` at `depth`, in RAS with vertex normals. The grid's border is
/// treated as outside, so the surface is closed.
pub fn surface(points: &OrientedPoints, depth: u32) -> Result<TriMesh, ReconError> {
    surface_with(points, depth, &PoissonSolver::cpu())
}

/// [`surface`] solved by `solver`.
pub fn surface_with(
    points: &OrientedPoints,
    depth: u32,
    solver: &PoissonSolver,
) -> Result<TriMesh, ReconError> {
    let params = PoissonParams {
        depth,
        ..PoissonParams::default()
    };
    field_surface(&field(points, &params, solver)?, solver)
}

/// The indicator field of `points` solved by `solver`; its
/// [`resecta_poisson::SolveReport`] says how.
pub fn field(
    points: &OrientedPoints,
    params: &PoissonParams,
    solver: &PoissonSolver,
) -> Result<PoissonField, ReconError> {
    Ok(solve_with(points, params, solver.solver())?)
}

/// The closed iso-surface of `field` in RAS with vertex normals, its nodes classified by
/// `solver`'s classifier.
pub fn field_surface(field: &PoissonField, solver: &PoissonSolver) -> Result<TriMesh, ReconError> {
    let mesh = extract_with(
        field.dims,
        &field.values,
        field.iso,
        Options { close_border: true },
        solver.classifier(),
    )?;
    let mesh = mesh.transformed(&field.index_to_ras())?;
    let normals = mesh.compute_vertex_normals();
    Ok(mesh.with_normals(normals)?)
}

/// Points and surface in one call.
pub fn reconstruct(mask: &Volume<bool>, depth: u32) -> Result<PsrModel, ReconError> {
    reconstruct_with(mask, depth, &PoissonSolver::cpu())
}

/// [`reconstruct`] solved by `solver`.
pub fn reconstruct_with(
    mask: &Volume<bool>,
    depth: u32,
    solver: &PoissonSolver,
) -> Result<PsrModel, ReconError> {
    let points = points_with(mask, solver)?;
    let mesh = surface_with(&points, depth, solver)?;
    Ok(PsrModel {
        mesh,
        points,
        depth,
    })
}

/// How far two surfaces of one object are apart (e.g. the CPU's and a device's).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SurfaceDiff {
    /// Largest distance from a vertex of either mesh to the other surface, mm.
    pub max_mm: Real,
    /// `|V(b) − V(a)| / |V(a)|` of the enclosed volumes, %.
    pub volume_pct: Real,
}

/// The symmetric vertex-to-surface distance and the volume difference of `a` and `b`.
pub fn surface_diff(a: &TriMesh, b: &TriMesh) -> Result<SurfaceDiff, ReconError> {
    let ab = point_to_surface(a.vertices(), b)?.max;
    let ba = point_to_surface(b.vertices(), a)?.max;
    let (va, vb) = (a.signed_volume(), b.signed_volume());
    Ok(SurfaceDiff {
        max_mm: ab.max(ba),
        volume_pct: 100.0 * (vb - va).abs() / va.abs(),
    })
}
