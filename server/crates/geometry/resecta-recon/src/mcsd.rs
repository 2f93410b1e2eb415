//! MCSD: marching cubes on the binary mask, decimation, windowed-sinc smoothing — the thesis'
//! baseline with 3D Slicer's closed-surface conversion as reference (see [`McsdParams`]).

use resecta_geom::{Mat4, Real, TriMesh, Volume};
use resecta_isosurface::extract_mask;
use resecta_meshfilter::slicer_surface_filters;

use crate::{ReconError, mask};

/// Slicer's two parameters. Defaults are Slicer's: smoothing factor 0.5 (windowed sinc,
/// passband 10^(-4·0.5) = 0.01, 20 + 40·0.5 = 40 iterations), decimation off. As in Slicer the
/// surface is extracted and filtered in voxel (index) coordinates, decimation before
/// smoothing, and mapped to RAS at the end.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct McsdParams {
    /// Smoothing factor in [0, 1]; 0 disables smoothing.
    pub smoothing: Real,
    /// Target fraction of triangles removed, in [0, 1); 0 disables decimation.
    pub decimation: Real,
}

impl Default for McsdParams {
    fn default() -> Self {
        Self {
            smoothing: 0.5,
            decimation: 0.0,
        }
    }
}

impl McsdParams {
    /// Paper I's smoothing values s ∈ {0, 22, 45, 67, 90} mapped onto Slicer's factor as
    /// s / 90, so s = 45 is Slicer's default and s = 90 its strongest smoothing.
    pub fn from_paper(s: Real, e: Real) -> Self {
        Self {
            smoothing: s / 90.0,
            decimation: e,
        }
    }

    fn check(&self) -> Result<(), ReconError> {
        if !(0.0..=1.0).contains(&self.smoothing) {
            return Err(ReconError::InvalidParameter {
                name: "smoothing",
                reason: "must lie in [0, 1]",
            });
        }
        if !(0.0..1.0).contains(&self.decimation) {
            return Err(ReconError::InvalidParameter {
                name: "decimation",
                reason: "must lie in [0, 1)",
            });
        }
        Ok(())
    }
}

/// Marching cubes of `mask` in the voxel coordinates of its crop (one voxel of margin), and that
/// crop's index→RAS affine.
pub fn marching(mask: &Volume<bool>) -> Result<(TriMesh, Mat4), ReconError> {
    let (lo, hi) = mask::bounds(mask).ok_or(ReconError::EmptyMask)?;
    let (lo, hi) = mask::padded(mask.grid(), lo, hi, 1);
    let cropped;
    let crop = if lo == [0; 3] && hi == mask.grid().dims() {
        mask // already cropped (e.g. by `mask::select_cropped`)
    } else {
        cropped = mask::sub_volume(mask, lo, hi)?;
        &cropped
    };
    Ok((extract_mask(crop)?, crop.grid().affine()))
}

/// Decimation and smoothing of a voxel-space surface (Slicer's filters), then the map to RAS.
pub fn filter(
    voxel_mesh: &TriMesh,
    affine: &Mat4,
    params: &McsdParams,
) -> Result<TriMesh, ReconError> {
    params.check()?;
    let mesh = slicer_surface_filters(voxel_mesh, params.smoothing, params.decimation)?;
    Ok(mesh.transformed(affine)?)
}

/// The MCSD surface of `mask` in RAS, with vertex normals. Closed also where the mask touches
/// the volume border (treated as background beyond it).
pub fn reconstruct(mask: &Volume<bool>, params: &McsdParams) -> Result<TriMesh, ReconError> {
    params.check()?;
    let (mesh, affine) = marching(mask)?;
    filter(&mesh, &affine, params)
}
