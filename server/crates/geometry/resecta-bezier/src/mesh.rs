//! Triangulated sample grid.

use resecta_geom::{TriMesh, Vec3};

use crate::error::BezierError;
use crate::scalar::{BezierScalar, P3};
use crate::types::SurfaceGrid;

fn to_vec3<T: BezierScalar>(p: &P3<T>) -> Vec3 {
    Vec3::new(p[0].to_f64(), p[1].to_f64(), p[2].to_f64())
}

/// Triangle indices of an RU×RV grid: 2·(RU−1)·(RV−1) triangles, each quad
/// (a,b)–(a+1,b)–(a+1,b+1)–(a,b+1) split along its (a,b)–(a+1,b+1) diagonal, wound so the
/// geometric normal points along ∂S/∂u × ∂S/∂v.
pub fn grid_triangles(ru: usize, rv: usize) -> Vec<[u32; 3]> {
    let mut tris = Vec::with_capacity(2 * (ru - 1) * (rv - 1));
    let id = |a: usize, b: usize| (a * rv + b) as u32;
    for a in 0..ru.saturating_sub(1) {
        for b in 0..rv.saturating_sub(1) {
            let (p00, p10, p11, p01) = (id(a, b), id(a + 1, b), id(a + 1, b + 1), id(a, b + 1));
            tris.push([p00, p10, p11]);
            tris.push([p00, p11, p01]);
        }
    }
    tris
}

/// The grid as a [`TriMesh`] in f64, with the grid's unit normals attached (or, if the grid has
/// none, area-weighted vertex normals of the mesh).
pub fn to_trimesh<T: BezierScalar>(grid: &SurfaceGrid<T>) -> Result<TriMesh, BezierError> {
    let res = grid.resolution();
    let vertices: Vec<Vec3> = grid.points().iter().map(to_vec3).collect();
    let mesh = TriMesh::new(vertices, grid_triangles(res.ru(), res.rv()))?;
    let normals = match grid.normals() {
        Some(n) => n.iter().map(to_vec3).collect(),
        None => mesh.compute_vertex_normals(),
    };
    Ok(mesh.with_normals(normals)?)
}
