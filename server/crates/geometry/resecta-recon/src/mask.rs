//! Binary masks from label maps: selection, cropping to the object, connected components and
//! the liver envelope used for the parenchyma model.

use std::collections::BTreeSet;

use rayon::prelude::*;
use resecta_geom::{Grid, LabelMap, Real, Role, RoleMap, Volume, distance_transform};

use crate::ReconError;
pub use resecta_geom::crop::{bounds, bounds_where, padded, sub_volume, sub_volume_map};

/// Voxels whose label is one of `labels`. Fails naming the labels that do not occur at all.
pub fn select(labels: &LabelMap, wanted: &[u16]) -> Result<Volume<bool>, ReconError> {
    fn with<F: Fn(u16) -> bool + Sync>(labels: &LabelMap, is: F) -> Vec<bool> {
        labels.data().par_iter().map(|&l| is(l)).collect()
    }
    let data = match Wanted::new(wanted)? {
        Wanted::One(one) => with(labels, |l| l == one),
        Wanted::Table(t) => with(labels, |l| t[usize::from(l)]),
    };
    if !data.par_iter().any(|&b| b) {
        return Err(absent(labels, wanted));
    }
    Ok(Volume::from_vec(labels.grid().clone(), data)?)
}

/// [`select`] cropped to the selected voxels plus `pad` voxels of margin (within the volume),
/// in one scan of the label map and without a mask of its full size.
pub fn select_cropped(
    labels: &LabelMap,
    wanted: &[u16],
    pad: usize,
) -> Result<Volume<bool>, ReconError> {
    fn with<F: Fn(u16) -> bool + Sync>(
        labels: &LabelMap,
        pad: usize,
        is: F,
    ) -> Option<Result<Volume<bool>, ReconError>> {
        let (lo, hi) = bounds_where(labels, &is)?;
        let (lo, hi) = padded(labels.grid(), lo, hi, pad);
        Some(sub_volume_map(labels, lo, hi, &is).map_err(ReconError::from))
    }
    let cropped = match Wanted::new(wanted)? {
        Wanted::One(one) => with(labels, pad, |l| l == one),
        Wanted::Table(t) => with(labels, pad, |l| t[usize::from(l)]),
    };
    cropped.unwrap_or_else(|| Err(absent(labels, wanted)))
}

/// Which labels [`select`] takes: a comparison for one (it vectorises), a table otherwise.
enum Wanted {
    One(u16),
    Table(Vec<bool>),
}

impl Wanted {
    fn new(wanted: &[u16]) -> Result<Self, ReconError> {
        match wanted {
            [] => Err(ReconError::NoLabels),
            [one] => Ok(Self::One(*one)),
            _ => {
                let mut t = vec![false; usize::from(u16::MAX) + 1];
                for &l in wanted {
                    t[usize::from(l)] = true;
                }
                Ok(Self::Table(t))
            }
        }
    }
}

/// [`ReconError::LabelsAbsent`] naming the labels of `wanted` that `labels` lacks.
pub(crate) fn absent(labels: &LabelMap, wanted: &[u16]) -> ReconError {
    let present: BTreeSet<u16> = labels.data().par_iter().copied().collect();
    let absent: BTreeSet<u16> = wanted
        .iter()
        .copied()
        .filter(|l| !present.contains(l))
        .collect();
    ReconError::LabelsAbsent {
        labels: absent.into_iter().collect(),
    }
}

/// The mask cropped to its set voxels plus `pad` voxels of margin (within the volume).
pub fn crop(mask: &Volume<bool>, pad: usize) -> Result<Volume<bool>, ReconError> {
    let (lo, hi) = bounds(mask).ok_or(ReconError::EmptyMask)?;
    let (lo, hi) = padded(mask.grid(), lo, hi, pad);
    Ok(sub_volume(mask, lo, hi)?)
}

/// Face-connected (6-neighbour) components, largest first (ties: first voxel in memory
/// order), each cropped to itself with one voxel of margin. Face connectivity matches the
/// surfaces: marching cubes separates objects that touch only along an edge or a corner.
pub fn components(mask: &Volume<bool>) -> Result<Vec<Volume<bool>>, ReconError> {
    let parts = Components::new(mask, 0)?;
    (0..parts.len()).map(|k| parts.crop(k)).collect()
}

/// One kept component: voxel count and index bounds `[lo, hi)`.
#[derive(Debug, Clone, Copy)]
struct Part {
    voxels: usize,
    lo: [usize; 3],
    hi: [usize; 3],
}

/// The face-connected components of a mask with at least `min_voxels` voxels, largest first
/// (ties: first voxel in memory order), and the count and voxels of those left out.
#[derive(Debug)]
pub struct Components {
    /// Per voxel the rank of its kept component, `u32::MAX` for background and dropped ones.
    ids: Volume<u32>,
    parts: Vec<Part>,
    /// Components below `min_voxels`, left out.
    pub dropped: usize,
    /// Their voxels.
    pub dropped_voxels: usize,
}

impl Components {
    pub fn new(mask: &Volume<bool>, min_voxels: usize) -> Result<Self, ReconError> {
        let dims @ [nx, ny, _] = mask.grid().dims();
        let data = mask.data();
        let mut ids = vec![u32::MAX; data.len()];
        // (part, first voxel) in discovery order.
        let mut found: Vec<(Part, usize)> = Vec::new();
        let mut stack = Vec::new();
        for start in 0..data.len() {
            if !data[start] || ids[start] != u32::MAX {
                continue;
            }
            let id = found.len() as u32;
            ids[start] = id;
            stack.push(start);
            let mut part = Part {
                voxels: 0,
                lo: [usize::MAX; 3],
                hi: [0; 3],
            };
            while let Some(v) = stack.pop() {
                part.voxels += 1;
                let (i, j, k) = (v % nx, (v / nx) % ny, v / (nx * ny));
                for (a, c) in [i, j, k].into_iter().enumerate() {
                    part.lo[a] = part.lo[a].min(c);
                    part.hi[a] = part.hi[a].max(c + 1);
                }
                for n in face_neighbours(v, dims) {
                    if data[n] && ids[n] == u32::MAX {
                        ids[n] = id;
                        stack.push(n);
                    }
                }
            }
            found.push((part, start));
        }
        let mut order: Vec<usize> = (0..found.len()).collect();
        order.sort_by(|&a, &b| {
            (found[b].0.voxels)
                .cmp(&found[a].0.voxels)
                .then(found[a].1.cmp(&found[b].1))
        });
        let kept = order
            .iter()
            .take_while(|&&c| found[c].0.voxels >= min_voxels)
            .count();
        let mut rank = vec![u32::MAX; found.len()];
        for (r, &c) in order[..kept].iter().enumerate() {
            rank[c] = r as u32;
        }
        ids.par_iter_mut().for_each(|id| {
            if *id != u32::MAX {
                *id = rank[*id as usize];
            }
        });
        Ok(Self {
            ids: Volume::from_vec(mask.grid().clone(), ids)?,
            parts: order[..kept].iter().map(|&c| found[c].0).collect(),
            dropped: found.len() - kept,
            dropped_voxels: order[kept..].iter().map(|&c| found[c].0.voxels).sum(),
        })
    }

    /// Kept components.
    pub fn len(&self) -> usize {
        self.parts.len()
    }

    pub fn is_empty(&self) -> bool {
        self.parts.is_empty()
    }

    /// Voxels of kept component `k`.
    pub fn voxels(&self, k: usize) -> usize {
        self.parts[k].voxels
    }

    /// Voxels of all kept components.
    pub fn kept_voxels(&self) -> usize {
        self.parts.iter().map(|p| p.voxels).sum()
    }

    /// Kept component `k` alone, cropped to it with one voxel of margin.
    pub fn crop(&self, k: usize) -> Result<Volume<bool>, ReconError> {
        let Part { lo, hi, .. } = self.parts[k];
        self.cropped(lo, hi, |id| id == k as u32)
    }

    /// Every kept component in one mask, cropped to them with one voxel of margin;
    /// [`ReconError::EmptyMask`] when none is kept.
    pub fn union(&self) -> Result<Volume<bool>, ReconError> {
        let (lo, hi) = self
            .parts
            .iter()
            .map(|p| (p.lo, p.hi))
            .reduce(|(alo, ahi), (blo, bhi)| {
                (
                    [0, 1, 2].map(|a| alo[a].min(blo[a])),
                    [0, 1, 2].map(|a| ahi[a].max(bhi[a])),
                )
            })
            .ok_or(ReconError::EmptyMask)?;
        self.cropped(lo, hi, |id| id != u32::MAX)
    }

    fn cropped(
        &self,
        lo: [usize; 3],
        hi: [usize; 3],
        keep: impl Fn(u32) -> bool + Sync,
    ) -> Result<Volume<bool>, ReconError> {
        let (lo, hi) = padded(self.ids.grid(), lo, hi, 1);
        Ok(sub_volume_map(&self.ids, lo, hi, keep)?)
    }
}

/// Smallest whole number of voxels of `grid` holding at least `mm3` (0 for `mm3` ≤ 0).
pub fn voxels_for_mm3(grid: &Grid, mm3: Real) -> usize {
    (mm3 / grid.voxel_volume_mm3()).ceil().max(0.0) as usize
}

/// Vessel voxels within this distance (mm) of the parenchyma count as liver for the envelope.
pub const VESSEL_MARGIN_MM: Real = 3.0;

/// The whole liver as one solid, for the parenchyma model: parenchyma and tumour labels, vessel
/// labels lying within [`VESSEL_MARGIN_MM`] of the parenchyma (vessels running inside the liver,
/// not their trunks outside it), and every cavity fully enclosed by these.
pub fn liver_envelope(labels: &LabelMap, roles: &RoleMap) -> Result<Volume<bool>, ReconError> {
    let lut = roles.lookup_table();
    let role = |l: u16| lut.get(usize::from(l)).copied().flatten();
    let parenchyma: Vec<bool> = labels
        .data()
        .par_iter()
        .map(|&l| matches!(role(l), Some(Role::Parenchyma | Role::Tumor)))
        .collect();
    if !parenchyma.iter().any(|&b| b) {
        return Err(ReconError::LabelsAbsent {
            labels: roles.labels(Role::Parenchyma).to_vec(),
        });
    }
    let solid = Volume::from_vec(labels.grid().clone(), parenchyma)?;
    let has_vessels = labels
        .data()
        .par_iter()
        .any(|&l| matches!(role(l), Some(Role::Portal | Role::Hepatic | Role::Vessel)));
    let solid = if has_vessels && labels.grid().is_orthogonal() {
        let dist = distance_transform(solid.grid(), solid.data())?;
        let data = labels
            .data()
            .par_iter()
            .zip(solid.data().par_iter())
            .zip(dist.data().par_iter())
            .map(|((&l, &s), &d)| {
                s || (matches!(role(l), Some(Role::Portal | Role::Hepatic | Role::Vessel))
                    && Real::from(d) <= VESSEL_MARGIN_MM)
            })
            .collect();
        Volume::from_vec(labels.grid().clone(), data)?
    } else {
        solid
    };
    fill_cavities(&solid)
}

/// Sets every background voxel not connected (6-neighbour) to the volume border.
///
/// The fill runs on the mask's bounding box grown by one voxel (every voxel beyond it is
/// background joined to the border along a straight line, and the box's own border voxels that
/// are background are joined to the border the same way), by spans along x.
pub fn fill_cavities(mask: &Volume<bool>) -> Result<Volume<bool>, ReconError> {
    let Some((lo, hi)) = bounds(mask) else {
        return Ok(mask.clone());
    };
    let (lo, hi) = padded(mask.grid(), lo, hi, 1);
    let [nx, ny, _] = mask.grid().dims();
    let [cx, cy, cz] = [0, 1, 2].map(|a| hi[a] - lo[a]);
    let data = mask.data();
    let solid =
        |i: usize, j: usize, k: usize| data[lo[0] + i + nx * (lo[1] + j + ny * (lo[2] + k))];
    let mut outside = vec![false; cx * cy * cz];
    let at = |i: usize, j: usize, k: usize| i + cx * (j + cy * k);
    let mut seeds: Vec<[usize; 3]> = Vec::new();
    for k in 0..cz {
        for j in 0..cy {
            if k == 0 || j == 0 || k + 1 == cz || j + 1 == cy {
                seeds.extend((0..cx).map(|i| [i, j, k]));
            } else {
                seeds.push([0, j, k]);
                seeds.push([cx - 1, j, k]);
            }
        }
    }
    while let Some([i, j, k]) = seeds.pop() {
        if solid(i, j, k) || outside[at(i, j, k)] {
            continue;
        }
        // The span of background voxels along x through (i, j, k) not yet reached.
        let mut x0 = i;
        while x0 > 0 && !solid(x0 - 1, j, k) && !outside[at(x0 - 1, j, k)] {
            x0 -= 1;
        }
        let mut x1 = i;
        while x1 + 1 < cx && !solid(x1 + 1, j, k) && !outside[at(x1 + 1, j, k)] {
            x1 += 1;
        }
        outside[at(x0, j, k)..=at(x1, j, k)].fill(true);
        let rows = [
            (j > 0).then(|| (j - 1, k)),
            (j + 1 < cy).then_some((j + 1, k)),
            (k > 0).then(|| (j, k - 1)),
            (k + 1 < cz).then_some((j, k + 1)),
        ];
        for (jj, kk) in rows.into_iter().flatten() {
            // One seed per run of open voxels next to the span.
            let mut open = false;
            for x in x0..=x1 {
                let free = !solid(x, jj, kk) && !outside[at(x, jj, kk)];
                if free && !open {
                    seeds.push([x, jj, kk]);
                }
                open = free;
            }
        }
    }
    let mut filled = vec![false; data.len()];
    filled.par_chunks_mut(nx).enumerate().for_each(|(r, row)| {
        let (j, k) = (r % ny, r / ny);
        if (lo[1]..hi[1]).contains(&j) && (lo[2]..hi[2]).contains(&k) {
            let (cj, ck) = (j - lo[1], k - lo[2]);
            let inner = &outside[at(0, cj, ck)..][..cx];
            for (v, o) in row[lo[0]..hi[0]].iter_mut().zip(inner) {
                *v = !o;
            }
        }
    });
    Ok(Volume::from_vec(mask.grid().clone(), filled)?)
}

/// Offsets of the (up to six) face neighbours of voxel offset `v` in a volume of `dims`.
fn face_neighbours(v: usize, [nx, ny, nz]: [usize; 3]) -> impl Iterator<Item = usize> {
    let (i, j, k) = (v % nx, (v / nx) % ny, v / (nx * ny));
    let plane = nx * ny;
    [
        (i > 0).then(|| v - 1),
        (i + 1 < nx).then(|| v + 1),
        (j > 0).then(|| v - nx),
        (j + 1 < ny).then(|| v + nx),
        (k > 0).then(|| v - plane),
        (k + 1 < nz).then(|| v + plane),
    ]
    .into_iter()
    .flatten()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// Every background voxel not joined to the border, by a plain flood fill of the whole grid.
    fn reference_fill(mask: &Volume<bool>) -> Vec<bool> {
        let dims = mask.grid().dims();
        let data = mask.data();
        let mut outside = vec![false; data.len()];
        let mut stack: Vec<usize> = (0..data.len())
            .filter(|&v| {
                let (i, j, k) = (
                    v % dims[0],
                    (v / dims[0]) % dims[1],
                    v / (dims[0] * dims[1]),
                );
                let border = i == 0
                    || j == 0
                    || k == 0
                    || i + 1 == dims[0]
                    || j + 1 == dims[1]
                    || k + 1 == dims[2];
                border && !data[v]
            })
            .collect();
        for &v in &stack {
            outside[v] = true;
        }
        while let Some(v) = stack.pop() {
            for n in face_neighbours(v, dims) {
                if !data[n] && !outside[n] {
                    outside[n] = true;
                    stack.push(n);
                }
            }
        }
        outside.iter().map(|o| !o).collect()
    }

    #[test]
    fn cavities_are_filled_as_a_whole_grid_flood_fill_does() {
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut rand = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for case in 0..60 {
            let dims = [
                3 + (rand() % 14) as usize,
                3 + (rand() % 12) as usize,
                2 + (rand() % 10) as usize,
            ];
            let grid = Grid::new(
                dims,
                [1.0, 0.9, 1.7],
                resecta_geom::Vec3::zeros(),
                resecta_geom::Mat3::identity(),
            )
            .unwrap();
            // Dense random masks (pockets and tunnels), shells with holes, empty and full ones.
            let density = [0, 35, 50, 65, 100][case % 5];
            let mut data: Vec<bool> = (0..grid.len()).map(|_| (rand() % 100) < density).collect();
            if case % 3 == 0 {
                // A box shell inside the grid: a cavity unless a hole opens it.
                let [nx, ny, nz] = dims;
                for k in 0..nz {
                    for j in 0..ny {
                        for i in 0..nx {
                            let on = |c: usize, n: usize| c == 1 || c + 2 == n;
                            let inside = (1..nx - 1).contains(&i)
                                && (1..ny - 1).contains(&j)
                                && (1..nz.max(3) - 1).contains(&k);
                            if inside && (on(i, nx) || on(j, ny) || on(k, nz)) {
                                data[i + nx * (j + ny * k)] = case % 2 == 0 || rand() % 9 != 0;
                            }
                        }
                    }
                }
            }
            let mask = Volume::from_vec(grid, data).unwrap();
            let want = reference_fill(&mask);
            assert_eq!(
                fill_cavities(&mask).unwrap().data(),
                &want[..],
                "case {case}"
            );
        }
    }
}
