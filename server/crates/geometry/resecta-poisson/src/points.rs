//! Oriented points from a binary mask (thesis Sec. 6.2.1): 3D Sobel gradient, physical normals,
//! and the half-voxel correction of sample positions.

use rayon::prelude::*;
use resecta_geom::{Real, Vec3, Volume};

use crate::error::PoissonError;

/// Fewest samples [`oriented_points`] returns and [`crate::solve`] accepts.
pub const MIN_POINTS: usize = 4;

/// Surface samples in RAS mm with unit outward normals and the surface area (mm²) each stands for.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct OrientedPoints {
    pub positions: Vec<Vec3>,
    /// Unit outward normals.
    pub normals: Vec<Vec3>,
    /// Surface area per sample in mm²; weights the normal field and the screening term.
    pub areas: Vec<Real>,
}

impl OrientedPoints {
    /// Samples that all stand for the same `area_mm2` (e.g. points not from a voxel grid).
    pub fn with_uniform_area(positions: Vec<Vec3>, normals: Vec<Vec3>, area_mm2: Real) -> Self {
        let areas = vec![area_mm2; positions.len()];
        Self {
            positions,
            normals,
            areas,
        }
    }

    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
}

/// Sobel smoothing weights for offsets −1, 0, 1.
const S: [i32; 3] = [1, 2, 1];

/// The object's bounding box grown by one voxel, as a zero-padded `u8` copy (1 = object): every
/// Sobel read of an object voxel is then in range. Voxel `(i, j, k)` of the mask is at padded
/// index `(i, j, k) − lo + 1`.
#[derive(Debug, Clone, PartialEq)]
pub struct MaskBox {
    /// Mask index of the box's first object-range voxel.
    pub lo: [usize; 3],
    /// Padded dimensions (box + 2 per axis).
    pub dims: [usize; 3],
    /// `dims` voxels, `i` fastest.
    pub data: Vec<u8>,
}

/// A pass computing the index-space 3D Sobel gradient of every voxel of a [`MaskBox`]: the seam
/// for device implementations, [`CpuSobel`] the reference.
pub trait SobelPass: Send + Sync {
    /// Where it runs (`"cpu"`, `"gpu"`).
    fn backend(&self) -> &'static str;
    /// One gradient per voxel of `mask_box.data` (`[0; 3]` for background and border voxels);
    /// device failures are [`PoissonError::Backend`].
    fn gradients(&self, mask_box: &MaskBox) -> Result<Vec<[i8; 3]>, PoissonError>;
}

/// The CPU's Sobel pass ([`sobel`] per voxel).
#[derive(Debug, Clone, Copy, Default)]
pub struct CpuSobel;

impl SobelPass for CpuSobel {
    fn backend(&self) -> &'static str {
        "cpu"
    }
    fn gradients(&self, b: &MaskBox) -> Result<Vec<[i8; 3]>, PoissonError> {
        let [px, py, pz] = b.dims;
        let mut out = vec![[0i8; 3]; b.data.len()];
        out.par_chunks_mut(px * py)
            .enumerate()
            .filter(|(k, _)| (1..pz - 1).contains(k))
            .for_each(|(k, plane)| {
                for j in 1..py - 1 {
                    for i in 1..px - 1 {
                        let c = i + px * (j + py * k);
                        if b.data[c] != 0 {
                            // |g| ≤ 16 per component.
                            plane[i + px * j] = sobel(b, c).map(|v| v as i8);
                        }
                    }
                }
            });
        Ok(out)
    }
}

/// Index-space 3D Sobel gradient at padded voxel `c` of `b` (an interior voxel).
pub fn sobel(b: &MaskBox, c: usize) -> [i32; 3] {
    let (pad, px, plane) = (&b.data, b.dims[0], b.dims[0] * b.dims[1]);
    let mut g = [0i32; 3];
    for (zc, sz) in S.iter().enumerate() {
        for (yb, sy) in S.iter().enumerate() {
            let r = c + px * (yb + b.dims[1] * zc) - px - plane;
            let (l, m, rr) = (
                i32::from(pad[r - 1]),
                i32::from(pad[r]),
                i32::from(pad[r + 1]),
            );
            g[0] += sy * sz * (rr - l);
            let row = l + 2 * m + rr;
            g[1] += (yb as i32 - 1) * sz * row;
            g[2] += (zc as i32 - 1) * sy * row;
        }
    }
    g
}

/// The [`MaskBox`] of `mask`; [`PoissonError::EmptyMask`] without object voxels.
pub fn mask_box(mask: &Volume<bool>) -> Result<MaskBox, PoissonError> {
    let [nx, ny, nz] = mask.grid().dims();
    let data = mask.data();

    // Bounding box of the object voxels, one slice per task.
    let bounds = data
        .par_chunks(nx * ny)
        .enumerate()
        .filter_map(|(k, slice)| {
            let mut b: Option<[usize; 6]> = None;
            for (o, _) in slice.iter().enumerate().filter(|(_, v)| **v) {
                let (i, j) = (o % nx, o / nx);
                b = Some(match b {
                    None => [i, i, j, j, k, k],
                    Some(c) => [c[0].min(i), c[1].max(i), c[2].min(j), c[3].max(j), k, k],
                });
            }
            b
        })
        .reduce_with(|a, c| {
            [
                a[0].min(c[0]),
                a[1].max(c[1]),
                a[2].min(c[2]),
                a[3].max(c[3]),
                a[4].min(c[4]),
                a[5].max(c[5]),
            ]
        })
        .ok_or(PoissonError::EmptyMask)?;

    // Zero-padded u8 copy of the box grown by one voxel: every Sobel read is then in range.
    let lo = [bounds[0], bounds[2], bounds[4]];
    let pd = [
        bounds[1] - bounds[0] + 3,
        bounds[3] - bounds[2] + 3,
        bounds[5] - bounds[4] + 3,
    ];
    let plane = pd[0] * pd[1];
    let mut pad = vec![0u8; plane * pd[2]];
    pad.par_chunks_mut(plane).enumerate().for_each(|(pk, out)| {
        let Some(k) = (lo[2] + pk).checked_sub(1).filter(|&k| k < nz) else {
            return;
        };
        for pj in 0..pd[1] {
            let Some(j) = (lo[1] + pj).checked_sub(1).filter(|&j| j < ny) else {
                continue;
            };
            for pi in 0..pd[0] {
                if let Some(i) = (lo[0] + pi).checked_sub(1).filter(|&i| i < nx) {
                    out[pi + pd[0] * pj] = u8::from(data[i + nx * (j + ny * k)]);
                }
            }
        }
    });
    Ok(MaskBox {
        lo,
        dims: pd,
        data: pad,
    })
}

/// Oriented points of the object (`true`) voxels of `mask`.
///
/// Every object voxel whose 3D Sobel gradient is non-zero gives one sample (voxels outside the
/// volume count as background, so a mask touching the border has samples there). With `g` the
/// index-space gradient and `J = grid.linear()`, the outward normal is `n = −J⁻ᵀg / |J⁻ᵀg|`
/// (right for anisotropic and oblique grids).
///
/// **Half-voxel correction.** For a locally planar boundary with unit normal `n`, the voxels with a
/// background voxel among their 26 neighbours (exactly those with a non-zero Sobel gradient) have
/// centres at depths uniformly spread over `[0, w)` below the surface of the voxelised solid, where
/// `w = Σₐ |n·Jₐ|` is the voxel's extent along `n` (`Jₐ` the columns of `J`). Each sample is
/// therefore moved outward by `w/2`, which centres the band of samples on the voxelised surface,
/// and stands for the area `V_voxel / w` (the band holds `w / V_voxel` samples per unit area).
///
/// Ordering is by voxel index (`i` fastest). Fewer than [`MIN_POINTS`] samples (e.g. a single
/// voxel, whose Sobel gradient is zero) is [`PoissonError::TooFewPoints`]; no object voxel is
/// [`PoissonError::EmptyMask`].
pub fn oriented_points(mask: &Volume<bool>) -> Result<OrientedPoints, PoissonError> {
    let b = mask_box(mask)?;
    samples(mask, &b, |c| sobel(&b, c))
}

/// [`oriented_points`] with the gradients from `pass`: the same samples whenever `pass` gives
/// the [`CpuSobel`] gradients.
pub fn oriented_points_with(
    mask: &Volume<bool>,
    pass: &dyn SobelPass,
) -> Result<OrientedPoints, PoissonError> {
    let b = mask_box(mask)?;
    let g = pass.gradients(&b)?;
    if g.len() != b.data.len() {
        return Err(PoissonError::Backend {
            backend: pass.backend(),
            reason: format!("{} gradients for {} voxels", g.len(), b.data.len()),
        });
    }
    samples(mask, &b, |c| g[c].map(i32::from))
}

/// The samples of the object voxels of `b` whose gradient (`gradient(c)` at padded index `c`) is
/// non-zero.
fn samples(
    mask: &Volume<bool>,
    b: &MaskBox,
    gradient: impl Fn(usize) -> [i32; 3] + Sync,
) -> Result<OrientedPoints, PoissonError> {
    let grid = mask.grid();
    let (pad, pd, lo) = (&b.data, b.dims, b.lo);
    let jac = grid.linear();
    let jinv_t = jac
        .try_inverse()
        .ok_or(PoissonError::SingularGrid)?
        .transpose();
    let voxel_volume = grid.voxel_volume_mm3();
    let cols = [
        jac.column(0).into_owned(),
        jac.column(1).into_owned(),
        jac.column(2).into_owned(),
    ];

    let per_slice: Vec<Vec<(Vec3, Vec3, Real)>> = (1..pd[2] - 1)
        .into_par_iter()
        .map(|pk| {
            let mut out = Vec::new();
            for pj in 1..pd[1] - 1 {
                for pi in 1..pd[0] - 1 {
                    let c = pi + pd[0] * (pj + pd[1] * pk);
                    if pad[c] == 0 {
                        continue;
                    }
                    let g = gradient(c);
                    if g == [0; 3] {
                        continue;
                    }
                    let gw = jinv_t * Vec3::new(g[0].into(), g[1].into(), g[2].into());
                    let n = -gw / gw.norm();
                    let extent: Real = cols.iter().map(|a| n.dot(a).abs()).sum();
                    let ijk = [lo[0] + pi - 1, lo[1] + pj - 1, lo[2] + pk - 1];
                    let centre = grid.voxel_center(ijk);
                    out.push((centre + 0.5 * extent * n, n, voxel_volume / extent));
                }
            }
            out
        })
        .collect();

    let total: usize = per_slice.iter().map(Vec::len).sum();
    if total < MIN_POINTS {
        return Err(PoissonError::TooFewPoints {
            found: total,
            needed: MIN_POINTS,
        });
    }
    let mut pts = OrientedPoints {
        positions: Vec::with_capacity(total),
        normals: Vec::with_capacity(total),
        areas: Vec::with_capacity(total),
    };
    for (p, n, a) in per_slice.into_iter().flatten() {
        pts.positions.push(p);
        pts.normals.push(n);
        pts.areas.push(a);
    }
    Ok(pts)
}
