//! Poisson surface reconstruction of a mask (Paper I): oriented points from the mask's
//! gradient, the screened Poisson solve on a dense grid, marching cubes at the iso-value.

use resecta_geom::{TriMesh, Volume};
use resecta_isosurface::{Options, extract};
use resecta_poisson::{OrientedPoints, PoissonParams, oriented_points, solve};

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

/// The PSR surface of `points` at `depth`, in RAS with vertex normals. The grid's border is
/// treated as outside, so the surface is closed.
pub fn surface(points: &OrientedPoints, depth: u32) -> Result<TriMesh, ReconError> {
    let field = solve(
        points,
        &PoissonParams {
            depth,
            ..PoissonParams::default()
        },
    )?;
    let mesh = extract(
        field.dims,
        &field.values,
        field.iso,
        Options { close_border: true },
    )?;
    let mesh = mesh.transformed(&field.index_to_ras())?;
    let normals = mesh.compute_vertex_normals();
    Ok(mesh.with_normals(normals)?)
}

/// Points and surface in one call.
pub fn reconstruct(mask: &Volume<bool>, depth: u32) -> Result<PsrModel, ReconError> {
    let points = points(mask)?;
    let mesh = surface(&points, depth)?;
    Ok(PsrModel {
        mesh,
        points,
        depth,
    })
}
