//! The boundary of a mask's voxels taken as cubes: the surface whose distance is the exact
//! distance to the segmentation itself.
//!
//! Every face between a voxel inside the mask and one outside it (or beyond the lattice) is part
//! of the boundary of the union of the voxel cubes (each voxel is the box of its grid spacing
//! around its centre, in the grid's oblique frame). Faces in the same plane are merged greedily
//! into rectangles (two triangles each), which changes the surface's triangles, not its points:
//! a point's distance to this mesh is its exact distance to the union of the cubes, the number a
//! safety margin must never exceed (it is at most the distance to any voxel centre) and never
//! fall below. Triangles face outward; edges where voxels touch only along an edge are shared by
//! four faces (the mesh is closed but not manifold there), which distance queries do not mind.

use rayon::prelude::*;
use resecta_geom::{TriMesh, Vec3, Volume};

use crate::IsoError;

/// Rectangles of one face plane: `[u0, u1) × [v0, v1)` in voxel indices.
type Rect = [usize; 4];

/// The boundary of the union of `mask`'s voxel cubes, in RAS (see the module docs).
pub fn voxel_boundary(mask: &Volume<bool>) -> Result<TriMesh, IsoError> {
    let dims = mask.grid().dims();
    let data = mask.data();
    let at = |p: [usize; 3]| data[(p[2] * dims[1] + p[1]) * dims[0] + p[0]];
    // One job per (axis, side, layer): the exposed faces of that layer merged into rectangles.
    let jobs: Vec<(usize, bool, usize)> = (0..3)
        .flat_map(|a| {
            [false, true]
                .into_iter()
                .flat_map(move |up| (0..dims[a]).map(move |t| (a, up, t)))
        })
        .collect();
    let planes: Vec<((usize, bool, usize), Vec<Rect>)> = jobs
        .into_par_iter()
        .map(|(a, up, t)| {
            let (b, c) = ((a + 1) % 3, (a + 2) % 3);
            let exposed = |u: usize, v: usize| {
                let mut p = [0; 3];
                (p[a], p[b], p[c]) = (t, u, v);
                if !at(p) {
                    return false;
                }
                match (up, t) {
                    (true, t) if t + 1 == dims[a] => true,
                    (false, 0) => true,
                    _ => {
                        p[a] = if up { t + 1 } else { t - 1 };
                        !at(p)
                    }
                }
            };
            ((a, up, t), merge(dims[b], dims[c], exposed))
        })
        .collect();
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    for ((a, up, t), rects) in planes {
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        let level = t as f64 + if up { 0.5 } else { -0.5 };
        for [u0, u1, v0, v1] in rects {
            let corner = |u: usize, v: usize| {
                let mut p = Vec3::zeros();
                (p[a], p[b], p[c]) = (level, u as f64 - 0.5, v as f64 - 0.5);
                p
            };
            let first = u32::try_from(vertices.len()).map_err(|_| IsoError::TooManyVertices)?;
            vertices.extend([
                corner(u0, v0),
                corner(u1, v0),
                corner(u1, v1),
                corner(u0, v1),
            ]);
            // e_b × e_c = e_a: counter-clockwise in (b, c) faces +a.
            let [p0, p1, p2, p3] = [first, first + 1, first + 2, first + 3];
            if up {
                triangles.extend([[p0, p1, p2], [p0, p2, p3]]);
            } else {
                triangles.extend([[p0, p2, p1], [p0, p3, p2]]);
            }
        }
    }
    u32::try_from(vertices.len()).map_err(|_| IsoError::TooManyVertices)?;
    Ok(TriMesh::new(vertices, triangles)?.transformed(&mask.grid().affine())?)
}

/// Greedy rectangles covering exactly the cells `(u, v)` of an `nu × nv` plane where
/// `exposed(u, v)`: each starts at the first uncovered cell in v-major order, grows along u as
/// far as the row allows, then along v while the whole row segment does.
fn merge(nu: usize, nv: usize, exposed: impl Fn(usize, usize) -> bool) -> Vec<Rect> {
    let mut open: Vec<bool> = (0..nu * nv).map(|k| exposed(k % nu, k / nu)).collect();
    let mut out = Vec::new();
    for v0 in 0..nv {
        let mut u0 = 0;
        while u0 < nu {
            if !open[v0 * nu + u0] {
                u0 += 1;
                continue;
            }
            let mut u1 = u0 + 1;
            while u1 < nu && open[v0 * nu + u1] {
                u1 += 1;
            }
            let mut v1 = v0 + 1;
            while v1 < nv && (u0..u1).all(|u| open[v1 * nu + u]) {
                v1 += 1;
            }
            for v in v0..v1 {
                open[v * nu + u0..v * nu + u1].fill(false);
            }
            out.push([u0, u1, v0, v1]);
            u0 = u1;
        }
    }
    out
}
