//! The liver voxels as x-runs per (y, z) row with a compact index, plus a dense index over the
//! liver's bounding box for O(1) lookups (set-up once per patient).

use resecta_geom::{Grid, Mat3, Real, Vec3, Volume};

use crate::error::VolumetryError;

/// Liver voxels `x0..x1` of one row; `offset` is the compact index of `x0`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Run {
    pub x0: u32,
    pub x1: u32,
    pub offset: u32,
}

/// The functional liver of one patient, ready for repeated cuts.
#[derive(Debug)]
pub struct LiverVoxels {
    grid: Grid,
    /// Bounding box of the liver voxels (index space, `hi` exclusive).
    pub(crate) lo: [usize; 3],
    pub(crate) hi: [usize; 3],
    /// Runs of row r = (y − lo.y) + by·(z − lo.z) are `runs[row_start[r]..row_start[r + 1]]`.
    pub(crate) row_start: Vec<u32>,
    pub(crate) runs: Vec<Run>,
    /// Compact index of each bounding-box voxel, `u32::MAX` outside the liver.
    pub(crate) index: Vec<u32>,
    count: usize,
    /// World→index linear map.
    pub(crate) to_index: Mat3,
}

impl LiverVoxels {
    /// Set-up from a functional-liver mask (true = the voxel counts).
    pub fn new(mask: &Volume<bool>) -> Result<Self, VolumetryError> {
        let grid = mask.grid().clone();
        let [nx, ny, _] = grid.dims();
        let data = mask.data();
        let (mut lo, mut hi) = ([usize::MAX; 3], [0usize; 3]);
        for (v, _) in data.iter().enumerate().filter(|(_, b)| **b) {
            let ijk = [v % nx, (v / nx) % ny, v / (nx * ny)];
            for a in 0..3 {
                lo[a] = lo[a].min(ijk[a]);
                hi[a] = hi[a].max(ijk[a] + 1);
            }
        }
        if lo[0] == usize::MAX {
            return Err(VolumetryError::EmptyLiver);
        }
        let [bx, by, bz] = [0, 1, 2].map(|a| hi[a] - lo[a]);
        let mut index = vec![u32::MAX; bx * by * bz];
        let mut row_start = Vec::with_capacity(by * bz + 1);
        let mut runs = Vec::new();
        let mut count: usize = 0;
        for z in 0..bz {
            for y in 0..by {
                row_start.push(runs.len() as u32);
                let src = (lo[0]) + nx * ((y + lo[1]) + ny * (z + lo[2]));
                let row = &data[src..src + bx];
                let mut x = 0;
                while x < bx {
                    if !row[x] {
                        x += 1;
                        continue;
                    }
                    let x0 = x;
                    while x < bx && row[x] {
                        x += 1;
                    }
                    if count + (x - x0) >= u32::MAX as usize {
                        return Err(VolumetryError::TooManyVoxels(count + x - x0));
                    }
                    let base = x0 + bx * (y + by * z);
                    for (k, slot) in index[base..base + (x - x0)].iter_mut().enumerate() {
                        *slot = (count + k) as u32;
                    }
                    runs.push(Run {
                        x0: x0 as u32,
                        x1: x as u32,
                        offset: count as u32,
                    });
                    count += x - x0;
                }
            }
        }
        row_start.push(runs.len() as u32);
        let to_index = grid.linear().try_inverse().ok_or(VolumetryError::Geometry(
            resecta_geom::GeomError::SingularDirection,
        ))?;
        Ok(Self {
            grid,
            lo,
            hi,
            row_start,
            runs,
            index,
            count,
            to_index,
        })
    }

    /// Liver voxels.
    /// The grid offset ([`Grid::offset`]) of every liver voxel, in compact order (the order of
    /// [`crate::Volumetry::cuts_with_fractions`]' fractions).
    pub fn offsets(&self) -> Vec<usize> {
        let [nx, ny, _] = self.grid.dims();
        let [_, by, _] = self.bdims();
        let mut out = Vec::with_capacity(self.count);
        for (row, w) in self.row_start.windows(2).enumerate() {
            let (y, z) = (row % by + self.lo[1], row / by + self.lo[2]);
            for r in &self.runs[w[0] as usize..w[1] as usize] {
                out.extend((r.x0..r.x1).map(|x| x as usize + self.lo[0] + nx * (y + ny * z)));
            }
        }
        out
    }

    pub fn len(&self) -> usize {
        self.count
    }
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }
    pub fn grid(&self) -> &Grid {
        &self.grid
    }
    /// Total functional liver volume (mm³).
    pub fn total_mm3(&self) -> Real {
        self.count as Real * self.grid.voxel_volume_mm3()
    }

    /// Dims of the liver's bounding box (index space).
    pub fn bdims(&self) -> [usize; 3] {
        [0, 1, 2].map(|a| self.hi[a] - self.lo[a])
    }

    /// Grid index of the bounding box's first voxel.
    pub fn box_lo(&self) -> [usize; 3] {
        self.lo
    }

    /// Compact index of each bounding-box voxel (`x + bx·(y + by·z)`), `u32::MAX` outside the
    /// liver; compact indices run along x, then y, then z.
    pub fn box_index(&self) -> &[u32] {
        &self.index
    }

    /// Bounding-box coordinates of the liver voxel with compact index `c`.
    pub(crate) fn box_of(&self, c: u32) -> Option<[usize; 3]> {
        let k = self
            .runs
            .partition_point(|r| r.offset <= c)
            .checked_sub(1)?;
        let r = self.runs[k];
        if c >= r.offset + (r.x1 - r.x0) {
            return None;
        }
        let row = self.row_start.partition_point(|&s| s as usize <= k) - 1;
        let by = self.bdims()[1];
        Some([(r.x0 + c - r.offset) as usize, row % by, row / by])
    }

    /// Compact index of the voxel at bounding-box coordinates, if liver.
    pub(crate) fn at(&self, b: [i64; 3]) -> Option<u32> {
        let d = self.bdims();
        if (0..3).any(|a| b[a] < 0 || b[a] >= d[a] as i64) {
            return None;
        }
        let i = self.index[b[0] as usize + d[0] * (b[1] as usize + d[1] * b[2] as usize)];
        (i != u32::MAX).then_some(i)
    }

    /// Continuous bounding-box coordinates of a world point.
    pub(crate) fn to_box(&self, p: &Vec3) -> Vec3 {
        let g = self.to_index * (p - self.grid.origin());
        Vec3::new(
            g.x - self.lo[0] as Real,
            g.y - self.lo[1] as Real,
            g.z - self.lo[2] as Real,
        )
    }

    /// World centre of bounding-box voxel `b`.
    pub(crate) fn centre(&self, b: [usize; 3]) -> Vec3 {
        self.grid
            .voxel_center([b[0] + self.lo[0], b[1] + self.lo[1], b[2] + self.lo[2]])
    }

    /// Whether the world point lies in a liver voxel (nearest voxel centre).
    pub fn contains(&self, p: &Vec3) -> bool {
        let g = self.to_box(p);
        self.at([g.x.round() as i64, g.y.round() as i64, g.z.round() as i64])
            .is_some()
    }
}
