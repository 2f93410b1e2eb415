//! The thesis' volumetry (Sec. 7.3.5), for comparison: sample the surface at resolution²,
//! mark a k×k×k voxel block around each sample as barrier, region-grow (6-connected) over the
//! liver from the liver voxel nearest a tumour point. Barrier voxels count on neither side —
//! the known loss of the 3D Slicer extension.

use std::collections::VecDeque;

use resecta_bezier::{ControlNet, MleEvaluator, Outputs, Resolution};
use resecta_geom::{Real, Vec3, Volume};
use serde::Serialize;

use crate::error::VolumetryError;

/// Volumes by the thesis' method (mm³).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ThesisResult {
    pub resected_mm3: Real,
    pub remnant_mm3: Real,
    /// Liver voxels painted as barrier: on neither side.
    pub lost_mm3: Real,
}

pub fn thesis_volumetry(
    mask: &Volume<bool>,
    net: &ControlNet<Real>,
    seed: Vec3,
    resolution: usize,
    thickening: usize,
) -> Result<ThesisResult, VolumetryError> {
    if !(2..=2048).contains(&resolution) {
        return Err(VolumetryError::Parameter {
            what: "resolution",
            bound: "2..=2048",
            value: resolution,
        });
    }
    if thickening == 0 || thickening > 9 || thickening.is_multiple_of(2) {
        return Err(VolumetryError::Parameter {
            what: "thickening",
            bound: "odd, 1..=9",
            value: thickening,
        });
    }
    if !seed.iter().all(|c| c.is_finite()) {
        return Err(VolumetryError::NonFinitePoint(0));
    }
    let grid = mask.grid();
    let dims = grid.dims();
    let data = mask.data();
    let total = data.iter().filter(|&&b| b).count();
    if total == 0 {
        return Err(VolumetryError::EmptyLiver);
    }
    // 0 free, 1 barrier, 2 grown.
    let mut state = vec![0u8; data.len()];
    let mut e = MleEvaluator::new(net.clone(), Resolution::new(resolution, resolution)?);
    let h = (thickening / 2) as i64;
    let inside = |c: [i64; 3]| (0..3).all(|a| c[a] >= 0 && c[a] < dims[a] as i64);
    for p in e.evaluate(Outputs::Points).points() {
        let g = grid.world_to_index(Vec3::new(p[0], p[1], p[2]));
        let c = [g.x.round() as i64, g.y.round() as i64, g.z.round() as i64];
        for dz in -h..=h {
            for dy in -h..=h {
                for dx in -h..=h {
                    let q = [c[0] + dx, c[1] + dy, c[2] + dz];
                    if inside(q) {
                        state[grid.offset(q.map(|v| v as usize))] = 1;
                    }
                }
            }
        }
    }
    let lost = (0..data.len())
        .filter(|&v| data[v] && state[v] == 1)
        .count();
    // The liver voxel nearest the seed (breadth-first from the seed's voxel through all voxels).
    let g = grid.world_to_index(seed);
    let s = [g.x.round() as i64, g.y.round() as i64, g.z.round() as i64].map(|v| v.max(0));
    let s = [0, 1, 2].map(|a| (s[a] as usize).min(dims[a] - 1));
    let mut seen = vec![false; data.len()];
    let mut queue = VecDeque::from([grid.offset(s)]);
    seen[grid.offset(s)] = true;
    let mut start = None;
    while let Some(v) = queue.pop_front() {
        if data[v] && state[v] == 0 {
            start = Some(v);
            break;
        }
        for n in neighbours(v, dims) {
            if !seen[n] {
                seen[n] = true;
                queue.push_back(n);
            }
        }
    }
    let mut grown = 0usize;
    if let Some(v0) = start {
        let mut stack = vec![v0];
        state[v0] = 2;
        while let Some(v) = stack.pop() {
            grown += 1;
            for n in neighbours(v, dims) {
                if data[n] && state[n] == 0 {
                    state[n] = 2;
                    stack.push(n);
                }
            }
        }
    }
    let vox = grid.voxel_volume_mm3();
    Ok(ThesisResult {
        resected_mm3: grown as Real * vox,
        remnant_mm3: (total - grown - lost) as Real * vox,
        lost_mm3: lost as Real * vox,
    })
}

fn neighbours(v: usize, [nx, ny, nz]: [usize; 3]) -> impl Iterator<Item = usize> {
    let (i, j, k) = (v % nx, (v / nx) % ny, v / (nx * ny));
    [
        (i > 0).then(|| v - 1),
        (i + 1 < nx).then(|| v + 1),
        (j > 0).then(|| v - nx),
        (j + 1 < ny).then(|| v + nx),
        (k > 0).then(|| v - nx * ny),
        (k + 1 < nz).then(|| v + nx * ny),
    ]
    .into_iter()
    .flatten()
}
