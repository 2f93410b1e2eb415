//! Binary masks from label maps: selection, cropping to the object, connected components and
//! the liver envelope used for the parenchyma model.

use std::collections::BTreeSet;

use rayon::prelude::*;
use resecta_geom::{Grid, LabelMap, Real, Role, RoleMap, Volume, distance_transform};

use crate::ReconError;

/// Voxels whose label is one of `labels`. Fails naming the labels that do not occur at all.
pub fn select(labels: &LabelMap, wanted: &[u16]) -> Result<Volume<bool>, ReconError> {
    if wanted.is_empty() {
        return Err(ReconError::NoLabels);
    }
    let set: BTreeSet<u16> = wanted.iter().copied().collect();
    let mut lut = vec![false; usize::from(u16::MAX) + 1];
    for &l in &set {
        lut[usize::from(l)] = true;
    }
    let data: Vec<bool> = labels
        .data()
        .par_iter()
        .map(|&l| lut[usize::from(l)])
        .collect();
    if !data.par_iter().any(|&b| b) {
        let present: BTreeSet<u16> = labels.data().par_iter().copied().collect();
        let absent: Vec<u16> = set
            .iter()
            .copied()
            .filter(|l| !present.contains(l))
            .collect();
        return Err(ReconError::LabelsAbsent { labels: absent });
    }
    Ok(Volume::from_vec(labels.grid().clone(), data)?)
}

/// Index bounds `[lo, hi)` of the set voxels, or `None` for an empty mask.
pub fn bounds(mask: &Volume<bool>) -> Option<([usize; 3], [usize; 3])> {
    let [nx, ny, _] = mask.grid().dims();
    mask.data()
        .par_chunks(nx)
        .enumerate()
        .filter_map(|(r, row)| {
            let first = row.iter().position(|&b| b)?;
            let last = row.iter().rposition(|&b| b)?;
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

/// The sub-volume `[lo, hi)` of `vol`, with its grid moved so world positions are unchanged.
pub fn sub_volume<T: Copy + Send + Sync>(
    vol: &Volume<T>,
    lo: [usize; 3],
    hi: [usize; 3],
) -> Result<Volume<T>, ReconError> {
    let g = vol.grid();
    let [nx, ny, _] = g.dims();
    let dims = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
    let origin = g.index_to_world(resecta_geom::Vec3::new(
        lo[0] as Real,
        lo[1] as Real,
        lo[2] as Real,
    ));
    let grid = Grid::new(dims, g.spacing(), origin, g.direction())?;
    let src = vol.data();
    let data: Vec<T> = (0..dims[1] * dims[2])
        .into_par_iter()
        .flat_map_iter(|r| {
            let (j, k) = (lo[1] + r % dims[1], lo[2] + r / dims[1]);
            src[lo[0] + nx * (j + ny * k)..][..dims[0]].iter().copied()
        })
        .collect();
    Ok(Volume::from_vec(grid, data)?)
}

/// The mask cropped to its set voxels plus `pad` voxels of margin (within the volume).
pub fn crop(mask: &Volume<bool>, pad: usize) -> Result<Volume<bool>, ReconError> {
    let (lo, hi) = bounds(mask).ok_or(ReconError::EmptyMask)?;
    let dims = mask.grid().dims();
    let lo = lo.map(|v| v.saturating_sub(pad));
    let hi = [0, 1, 2].map(|a| (hi[a] + pad).min(dims[a]));
    sub_volume(mask, lo, hi)
}

/// Face-connected (6-neighbour) components, largest first (ties: first voxel in memory
/// order), each cropped to itself with one voxel of margin. Face connectivity matches the
/// surfaces: marching cubes separates objects that touch only along an edge or a corner.
pub fn components(mask: &Volume<bool>) -> Result<Vec<Volume<bool>>, ReconError> {
    let [nx, ny, nz] = mask.grid().dims();
    let data = mask.data();
    let mut label = vec![u32::MAX; data.len()];
    // (size, first voxel, bounds lo, bounds hi)
    let mut sizes: Vec<(usize, usize, [usize; 3], [usize; 3])> = Vec::new();
    let mut stack = Vec::new();
    for start in 0..data.len() {
        if !data[start] || label[start] != u32::MAX {
            continue;
        }
        let id = sizes.len() as u32;
        label[start] = id;
        stack.push(start);
        let mut size = 0usize;
        let (mut lo, mut hi) = ([usize::MAX; 3], [0usize; 3]);
        while let Some(v) = stack.pop() {
            size += 1;
            let (i, j, k) = (v % nx, (v / nx) % ny, v / (nx * ny));
            for (a, c) in [i, j, k].into_iter().enumerate() {
                lo[a] = lo[a].min(c);
                hi[a] = hi[a].max(c + 1);
            }
            for n in face_neighbours(v, [nx, ny, nz]) {
                if data[n] && label[n] == u32::MAX {
                    label[n] = id;
                    stack.push(n);
                }
            }
        }
        sizes.push((size, start, lo, hi));
    }
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    order.sort_by(|&a, &b| {
        sizes[b]
            .0
            .cmp(&sizes[a].0)
            .then(sizes[a].1.cmp(&sizes[b].1))
    });
    let dims = [nx, ny, nz];
    let ids = Volume::from_vec(mask.grid().clone(), label)?;
    order
        .into_iter()
        .map(|id| {
            let (_, _, lo, hi) = sizes[id];
            let lo = lo.map(|v| v.saturating_sub(1));
            let hi = [0, 1, 2].map(|a| (hi[a] + 1).min(dims[a]));
            let sub = sub_volume(&ids, lo, hi)?;
            let id = id as u32;
            let data = sub.data().iter().map(|&l| l == id).collect();
            Ok(Volume::from_vec(sub.grid().clone(), data)?)
        })
        .collect()
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
pub fn fill_cavities(mask: &Volume<bool>) -> Result<Volume<bool>, ReconError> {
    let [nx, ny, nz] = mask.grid().dims();
    let data = mask.data();
    let mut outside = vec![false; data.len()];
    let mut stack = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let border =
                    i == 0 || j == 0 || k == 0 || i + 1 == nx || j + 1 == ny || k + 1 == nz;
                let v = i + nx * (j + ny * k);
                if border && !data[v] && !outside[v] {
                    outside[v] = true;
                    stack.push(v);
                }
            }
        }
    }
    while let Some(v) = stack.pop() {
        for n in face_neighbours(v, [nx, ny, nz]) {
            if !data[n] && !outside[n] {
                outside[n] = true;
                stack.push(n);
            }
        }
    }
    Ok(Volume::from_vec(
        mask.grid().clone(),
        outside.into_par_iter().map(|o| !o).collect(),
    )?)
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
