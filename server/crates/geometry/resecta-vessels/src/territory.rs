//! Vascular territories: every liver voxel labelled by the branch with the nearest centreline.

use std::collections::HashMap;

use resecta_geom::{Grid, NO_FEATURE, Vec3, Volume, distance_transform_with_nearest};

use crate::error::VesselError;
use crate::graph::VesselTree;

/// Which branches get a territory. A branch is an edge with all its descendants; an edge lying
/// under several selected edges belongs to the nearest one above it (or itself).
#[derive(Debug, Clone, PartialEq)]
pub enum BranchSelection {
    /// These edge ids.
    Ids(Vec<usize>),
    /// Every edge of generation `k`, plus every terminal edge of a lower generation (a vessel
    /// that ends before generation `k` keeps its territory).
    Generation(u32),
    /// `k` branches found by splitting the largest: starting from the edges leaving the roots,
    /// the branch with the longest centreline (itself and its descendants) that has children is
    /// replaced by its children until there are `k` (or none can split). With `k = 8` on a
    /// portal tree this is a Couinaud-style grouping: an approximation of the eight segments
    /// from the tree's shape, not an anatomical labelling of segments I–VIII.
    Largest(usize),
}

/// The [`BranchSelection::Largest`] branches of `tree`, ids ascending.
fn largest(tree: &VesselTree, k: usize) -> Vec<usize> {
    let n = tree.edges.len();
    // Centreline length of each subtree (children come after parents: sum backwards).
    let mut weight: Vec<f64> = tree.edges.iter().map(|e| e.length_mm).collect();
    for e in tree.edges.iter().rev() {
        if let Some(p) = e.parent {
            weight[p] += weight[e.id];
        }
    }
    let mut chosen: Vec<usize> = (0..n).filter(|&e| tree.edges[e].parent.is_none()).collect();
    while chosen.len() < k {
        let split = chosen
            .iter()
            .enumerate()
            .filter(|(_, e)| !tree.edges[**e].children.is_empty())
            .max_by(|a, b| weight[*a.1].total_cmp(&weight[*b.1]).then(b.1.cmp(a.1)));
        let Some((at, &e)) = split else { break };
        chosen.swap_remove(at);
        chosen.extend(tree.edges[e].children.iter().copied());
    }
    chosen.sort_unstable();
    chosen
}

/// Parameters of [`territories`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TerritoryParams {
    /// Step in mm at which centrelines are resampled before rasterisation; `None`: half the
    /// smallest voxel spacing.
    pub sample_mm: Option<f64>,
}

/// One territory.
#[derive(Debug, Clone, PartialEq)]
pub struct Territory {
    /// The selected edge heading the branch; `None` for the proximal territory (the centrelines
    /// above every selected branch, e.g. the trunk).
    pub branch: Option<usize>,
    pub voxels: usize,
    pub volume_ml: f64,
}

/// Territories partitioning a liver mask.
#[derive(Debug, Clone, PartialEq)]
pub struct Territories {
    /// `0` outside the liver, `i + 1` for a voxel of `territories[i]`.
    pub labels: Volume<u32>,
    /// `territories[0]` is the proximal territory, then one per selected branch in the order of
    /// the selection (ids ascending for [`BranchSelection::Generation`]).
    pub territories: Vec<Territory>,
    pub liver_voxels: usize,
    pub liver_ml: f64,
}

/// Points along a polyline every `step` mm (both ends included), with their arc length.
fn resample(points: &[Vec3], step: f64) -> Vec<(Vec3, f64)> {
    let mut out = Vec::new();
    let Some(&first) = points.first() else {
        return out;
    };
    out.push((first, 0.0));
    let (mut carry, mut done) = (0.0, 0.0);
    for w in points.windows(2) {
        let seg = w[1] - w[0];
        let len = seg.norm();
        if len <= 0.0 {
            continue;
        }
        let mut s = step - carry;
        while s < len {
            out.push((w[0] + seg * (s / len), done + s));
            s += step;
        }
        carry = len - (s - step);
        done += len;
    }
    if let Some(&last) = points.last()
        && out.last().is_none_or(|p| (p.0 - last).norm() > 1e-9)
    {
        out.push((last, done));
    }
    out
}

/// A rasterised centreline voxel: the edge of the centreline point nearest its centre and that
/// point's arc length along the edge (mm from its proximal node).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct CentrelineVoxel {
    d2: f64,
    pub edge: usize,
    pub arc_mm: f64,
}

/// The centrelines resampled every `step` mm and rasterised to their nearest voxels (grid
/// offset → voxel); a voxel hit by several edges takes the point nearest its centre. Branch
/// points belong to no edge (so no child is favoured there); roots and distal ends are kept.
pub(crate) fn rasterise(tree: &VesselTree, step: f64) -> HashMap<usize, CentrelineVoxel> {
    let grid = &tree.grid;
    let dims = grid.dims();
    let mut hits: HashMap<usize, CentrelineVoxel> = HashMap::new();
    for e in &tree.edges {
        let pts = resample(&e.points, step);
        let last = pts.len().saturating_sub(1);
        let keep_first = e.parent.is_none() && tree.roots.contains(&e.from);
        let keep_last = e.children.is_empty();
        for (i, &(p, arc_mm)) in pts.iter().enumerate() {
            if (i == 0 && !keep_first) || (i == last && !keep_last) {
                continue;
            }
            let c = grid.world_to_index(p);
            let r = c.map(f64::round);
            if r.iter()
                .zip(dims)
                .any(|(&x, d)| !(x >= 0.0 && x < d as f64))
            {
                continue;
            }
            let o = grid.offset([r[0] as usize, r[1] as usize, r[2] as usize]);
            let d2 = (c - r).norm_squared();
            let v = CentrelineVoxel {
                d2,
                edge: e.id,
                arc_mm,
            };
            hits.entry(o)
                .and_modify(|h| {
                    if d2 < h.d2 {
                        *h = v;
                    }
                })
                .or_insert(v);
        }
    }
    hits
}

/// For each grid offset of `targets`, the grid offset of its nearest voxel of `features` (exact
/// Euclidean, through the EDT; `None` without features). The EDT runs on the bounding box of
/// both: every feature lies in it, so nothing outside could be nearer.
pub(crate) fn nearest_features(
    grid: &Grid,
    features: impl Iterator<Item = usize> + Clone,
    targets: &[usize],
) -> Result<Vec<Option<usize>>, VesselError> {
    let (mut lo, mut hi) = ([usize::MAX; 3], [0usize; 3]);
    for o in features.clone().chain(targets.iter().copied()) {
        let ijk = grid.ijk(o);
        for a in 0..3 {
            lo[a] = lo[a].min(ijk[a]);
            hi[a] = hi[a].max(ijk[a] + 1);
        }
    }
    if lo[0] == usize::MAX {
        return Ok(vec![None; targets.len()]);
    }
    let dims = [0, 1, 2].map(|a| hi[a] - lo[a]);
    let origin = grid.index_to_world(Vec3::new(lo[0] as f64, lo[1] as f64, lo[2] as f64));
    let sub = Grid::new(dims, grid.spacing(), origin, grid.direction())?;
    let to_sub = |o: usize| {
        let ijk = grid.ijk(o);
        sub.offset([ijk[0] - lo[0], ijk[1] - lo[1], ijk[2] - lo[2]])
    };
    let mut mask = vec![false; sub.len()];
    for o in features {
        mask[to_sub(o)] = true;
    }
    let near = distance_transform_with_nearest(&sub, &mask)?;
    Ok(targets
        .iter()
        .map(|&o| {
            let f = near.nearest.data()[to_sub(o)];
            (f != NO_FEATURE).then(|| {
                let ijk = sub.ijk(f as usize);
                grid.offset([ijk[0] + lo[0], ijk[1] + lo[1], ijk[2] + lo[2]])
            })
        })
        .collect())
}

/// The sampling step of [`TerritoryParams::sample_mm`] on `grid`.
pub(crate) fn sample_step(
    grid: &resecta_geom::Grid,
    sample_mm: Option<f64>,
) -> Result<f64, VesselError> {
    let sp = grid.spacing();
    match sample_mm {
        None => Ok(0.5 * sp[0].min(sp[1]).min(sp[2])),
        Some(s) if s.is_finite() && s > 0.0 => Ok(s),
        Some(_) => Err(VesselError::InvalidParameter {
            name: "sample_mm",
            reason: "must be finite and positive",
        }),
    }
}

/// Labels every liver voxel with the selected branch whose centreline is nearest (exact
/// Euclidean Voronoi of the rasterised centreline voxels, through the EDT's nearest feature).
pub fn territories(
    tree: &VesselTree,
    liver: &Volume<bool>,
    selection: &BranchSelection,
    params: &TerritoryParams,
) -> Result<Territories, VesselError> {
    let grid = liver.grid();
    if *grid != tree.grid {
        return Err(VesselError::GridMismatch);
    }
    let liver_voxels = liver.data().iter().filter(|&&v| v).count();
    if liver_voxels == 0 {
        return Err(VesselError::EmptyLiver);
    }
    let step = sample_step(grid, params.sample_mm)?;
    let count = tree.edges.len();
    let selected: Vec<usize> = match selection {
        BranchSelection::Ids(ids) => {
            for &id in ids {
                if id >= count {
                    return Err(VesselError::UnknownBranch { id, count });
                }
            }
            let mut v = ids.clone();
            v.dedup();
            v
        }
        BranchSelection::Largest(k) => largest(tree, *k),
        BranchSelection::Generation(k) => tree
            .edges
            .iter()
            .filter(|e| e.generation == *k || (e.generation < *k && e.children.is_empty()))
            .map(|e| e.id)
            .collect(),
    };
    if selected.is_empty() {
        return Err(VesselError::NoBranchSelected);
    }
    // Owner territory of every edge: itself if selected, else its parent's (parents first).
    let mut owner = vec![0u32; count];
    for e in &tree.edges {
        owner[e.id] = match selected.iter().position(|&s| s == e.id) {
            Some(i) => i as u32 + 1,
            None => e.parent.and_then(|p| owner.get(p).copied()).unwrap_or(0),
        };
    }
    let hits = rasterise(tree, step);
    if hits.is_empty() {
        return Err(VesselError::NoCentreline);
    }
    let inside: Vec<usize> = (0..grid.len()).filter(|&o| liver.data()[o]).collect();
    let nearest = nearest_features(grid, hits.keys().copied(), &inside)?;
    let n_terr = selected.len() + 1;
    let mut voxels = vec![0usize; n_terr];
    let mut labels = vec![0u32; grid.len()];
    for (&o, f) in inside.iter().zip(nearest) {
        let t = f.and_then(|f| hits.get(&f)).map_or(0, |h| owner[h.edge]);
        labels[o] = t + 1;
        voxels[t as usize] += 1;
    }
    let ml = grid.voxel_volume_mm3() / 1000.0;
    let territories = voxels
        .iter()
        .enumerate()
        .map(|(i, &v)| Territory {
            branch: i.checked_sub(1).and_then(|j| selected.get(j).copied()),
            voxels: v,
            volume_ml: v as f64 * ml,
        })
        .collect();
    Ok(Territories {
        labels: Volume::from_vec(grid.clone(), labels)?,
        territories,
        liver_voxels,
        liver_ml: liver_voxels as f64 * ml,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resample_keeps_ends_and_step() {
        let pts = [
            Vec3::zeros(),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
        ];
        let r = resample(&pts, 0.5);
        assert_eq!(r.len(), 5);
        assert!((r[4].0 - pts[2]).norm() < 1e-12 && (r[4].1 - 2.0).abs() < 1e-12);
        assert!((r[2].0 - pts[1]).norm() < 1e-12 && (r[2].1 - 1.0).abs() < 1e-12);
        assert!((r[3].1 - 1.5).abs() < 1e-12);
    }
}
