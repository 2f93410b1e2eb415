//! Bounding boxes of volumes and sub-volumes cut out of them, world positions unchanged.

use rayon::prelude::*;

use crate::{GeomError, Grid, Real, Vec3, Volume};

/// Index bounds `[lo, hi)` of the set voxels, or `None` for an empty mask.
pub fn bounds(mask: &Volume<bool>) -> Option<([usize; 3], [usize; 3])> {
    bounds_where(mask, |b| b)
}

/// Index bounds `[lo, hi)` of the voxels where `is` holds, or `None` where it never does.
pub fn bounds_where<T: Copy + Sync>(
    vol: &Volume<T>,
    is: impl Fn(T) -> bool + Sync,
) -> Option<([usize; 3], [usize; 3])> {
    let [nx, ny, _] = vol.grid().dims();
    vol.data()
        .par_chunks(nx)
        .enumerate()
        .filter_map(|(r, row)| {
            // A branch-free test first (it vectorises); most rows hold nothing.
            if !row.iter().fold(false, |any, &v| any | is(v)) {
                return None;
            }
            let first = row.iter().position(|&v| is(v))?;
            let last = row.iter().rposition(|&v| is(v))?;
            let (j, k) = (r % ny, r / ny);
            Some(([first, j, k], [last + 1, j + 1, k + 1]))
        })
        .reduce_with(|(alo, ahi), (blo, bhi)| {
            (
                [alo[0].min(blo[0]), alo[1].min(blo[1]), alo[2].min(blo[2])],
                [ahi[0].max(bhi[0]), ahi[1].max(bhi[1]), ahi[2].max(bhi[2])],
            )
        })
}

/// `[lo, hi)` grown by `pad` voxels on every side, within `grid`.
pub fn padded(grid: &Grid, lo: [usize; 3], hi: [usize; 3], pad: usize) -> ([usize; 3], [usize; 3]) {
    let dims = grid.dims();
    (
        lo.map(|v| v.saturating_sub(pad)),
        [0, 1, 2].map(|a| (hi[a] + pad).min(dims[a])),
    )
}

/// The sub-volume `[lo, hi)` of `vol`, with its grid moved so world positions are unchanged.
pub fn sub_volume<T: Copy + Send + Sync>(
    vol: &Volume<T>,
    lo: [usize; 3],
    hi: [usize; 3],
) -> Result<Volume<T>, GeomError> {
    sub_volume_map(vol, lo, hi, |v| v)
}

/// [`sub_volume`] with `f` applied to every value.
pub fn sub_volume_map<T: Copy + Sync, U: Copy + Send>(
    vol: &Volume<T>,
    lo: [usize; 3],
    hi: [usize; 3],
    f: impl Fn(T) -> U + Sync,
) -> Result<Volume<U>, GeomError> {
    let g = vol.grid();
    let [nx, ny, _] = g.dims();
    let dims = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
    let origin = g.index_to_world(Vec3::new(lo[0] as Real, lo[1] as Real, lo[2] as Real));
    let grid = Grid::new(dims, g.spacing(), origin, g.direction())?;
    let src = vol.data();
    let data: Vec<U> = (0..dims[1] * dims[2])
        .into_par_iter()
        .flat_map_iter(|r| {
            let (j, k) = (lo[1] + r % dims[1], lo[2] + r / dims[1]);
            src[lo[0] + nx * (j + ny * k)..][..dims[0]]
                .iter()
                .map(|&v| f(v))
        })
        .collect();
    Volume::from_vec(grid, data)
}
