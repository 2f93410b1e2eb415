//! Distance-ordered, directional, topology-preserving thinning of a binary mask.

use resecta_geom::{Grid, Vec3, Volume, VoxelLimit, distance_transform};

use crate::error::VesselError;

/// A mask padded by one background voxel on every side, so that every voxel of the original grid
/// has its full 26-neighbourhood in memory.
#[derive(Debug, Clone)]
pub(crate) struct Padded {
    /// The padded grid (origin one voxel before the original's, same spacing and direction).
    pub grid: Grid,
    pub dims: [usize; 3],
}

impl Padded {
    pub fn new(grid: &Grid) -> Result<Self, VesselError> {
        let d = grid.dims();
        let dims = [d[0] + 2, d[1] + 2, d[2] + 2];
        let origin = grid.index_to_world(Vec3::new(-1.0, -1.0, -1.0));
        let padded = Grid::with_limit(
            dims,
            grid.spacing(),
            origin,
            grid.direction(),
            VoxelLimit(u64::MAX),
        )?;
        Ok(Self { grid: padded, dims })
    }

    /// Offsets of the 26 neighbours.
    pub fn neighbour_offsets(&self) -> [isize; 26] {
        let sx = 1isize;
        let sy = self.dims[0] as isize;
        let sz = (self.dims[0] * self.dims[1]) as isize;
        let mut out = [0isize; 26];
        let mut n = 0;
        for dz in -1..=1isize {
            for dy in -1..=1isize {
                for dx in -1..=1isize {
                    if dx == 0 && dy == 0 && dz == 0 {
                        continue;
                    }
                    out[n] = dx * sx + dy * sy + dz * sz;
                    n += 1;
                }
            }
        }
        out
    }

    /// Offsets of the 27 cells of the neighbourhood cube, cell `c = (dx+1) + 3(dy+1) + 9(dz+1)`.
    pub fn cube_offsets(&self) -> [isize; 27] {
        let sy = self.dims[0] as isize;
        let sz = (self.dims[0] * self.dims[1]) as isize;
        let mut out = [0isize; 27];
        for (c, o) in out.iter_mut().enumerate() {
            let (dx, dy, dz) = cell_delta(c);
            *o = dx + dy * sy + dz * sz;
        }
        out
    }

    /// Padded offset of an original index.
    pub fn offset_of(&self, ijk: [usize; 3]) -> usize {
        (ijk[0] + 1) + self.dims[0] * ((ijk[1] + 1) + self.dims[1] * (ijk[2] + 1))
    }

    /// Whether the padded offset lies in the padding (or outside).
    pub fn is_border(&self, offset: usize) -> bool {
        let [nx, ny, nz] = self.dims;
        let (i, j, k) = (offset % nx, (offset / nx) % ny, offset / (nx * ny));
        i == 0 || j == 0 || k == 0 || i + 1 >= nx || j + 1 >= ny || k + 1 >= nz
    }
}

fn cell_delta(c: usize) -> (isize, isize, isize) {
    (
        (c % 3) as isize - 1,
        ((c / 3) % 3) as isize - 1,
        (c / 9) as isize - 1,
    )
}

/// Adjacency bit masks of the 27 cells of a neighbourhood cube.
#[derive(Debug, Clone)]
struct CubeAdjacency {
    /// Cells 26-adjacent to each cell.
    adj26: [u32; 27],
    /// Cells 6-adjacent to each cell.
    adj6: [u32; 27],
    /// The 18-neighbourhood of the centre, centre excluded.
    n18: u32,
    /// The six face neighbours of the centre.
    n6: u32,
}

impl CubeAdjacency {
    fn new() -> Self {
        let mut adj26 = [0u32; 27];
        let mut adj6 = [0u32; 27];
        let mut n18 = 0u32;
        let mut n6 = 0u32;
        for a in 0..27 {
            let (ax, ay, az) = cell_delta(a);
            let l1 = ax.abs() + ay.abs() + az.abs();
            if (1..=2).contains(&l1) {
                n18 |= 1 << a;
            }
            if l1 == 1 {
                n6 |= 1 << a;
            }
            for b in 0..27 {
                if a == b {
                    continue;
                }
                let (bx, by, bz) = cell_delta(b);
                let d = [(ax - bx).abs(), (ay - by).abs(), (az - bz).abs()];
                if d.iter().all(|&v| v <= 1) {
                    adj26[a] |= 1 << b;
                    if d.iter().sum::<isize>() == 1 {
                        adj6[a] |= 1 << b;
                    }
                }
            }
        }
        Self {
            adj26,
            adj6,
            n18,
            n6,
        }
    }

    /// Number of connected components of `set` under `adj`; with `seeds`, only those meeting it.
    fn components(set: u32, adj: &[u32; 27], seeds: u32) -> usize {
        let mut left = set;
        let mut count = 0;
        while left != 0 {
            let start = left.trailing_zeros();
            let mut comp = 1u32 << start;
            let mut frontier = comp;
            while frontier != 0 {
                let c = frontier.trailing_zeros() as usize;
                frontier &= frontier - 1;
                let new = adj[c] & set & !comp;
                comp |= new;
                frontier |= new;
            }
            left &= !comp;
            if comp & seeds != 0 {
                count += 1;
            }
        }
        count
    }

    /// Whether the centre of a neighbourhood (object cells set in `cube`, centre bit ignored) is a
    /// simple point for (26, 6) topology: one 26-component of object in N26, and one 6-component
    /// of background in N18 that is 6-adjacent to the centre.
    fn is_simple(&self, cube: u32) -> bool {
        let all = (1u32 << 27) - 1;
        let obj = cube & all & !(1 << 13);
        if Self::components(obj, &self.adj26, obj) != 1 {
            return false;
        }
        let bg = !cube & self.n18;
        Self::components(bg, &self.adj6, self.n6) == 1
    }
}

/// The thinned skeleton of a mask: voxels (padded offsets) and their radii.
#[derive(Debug, Clone)]
pub(crate) struct Thinned {
    pub padded: Padded,
    /// Skeleton membership per padded voxel.
    pub skeleton: Vec<bool>,
    /// Radius in mm per padded voxel (meaningful inside the kept mask).
    pub radius: Vec<f64>,
    /// 26-component label per padded voxel of the kept mask (`u32::MAX` elsewhere).
    pub component: Vec<u32>,
    /// Voxel count per component label.
    pub component_voxels: Vec<usize>,
    pub specks: usize,
    pub speck_voxels: usize,
}

/// Components of the mask (26-connected), specks dropped, radii, then thinning.
pub(crate) fn thin(
    mask: &Volume<bool>,
    min_component_voxels: usize,
) -> Result<Thinned, VesselError> {
    let padded = Padded::new(mask.grid())?;
    let n = padded.grid.len();
    let nb = padded.neighbour_offsets();
    let mut object = vec![false; n];
    let dims = mask.grid().dims();
    for (o, &v) in mask.data().iter().enumerate() {
        if v {
            let ijk = [
                o % dims[0],
                (o / dims[0]) % dims[1],
                o / (dims[0] * dims[1]),
            ];
            object[padded.offset_of(ijk)] = true;
        }
    }
    // 26-connected components; specks dropped.
    let mut component = vec![u32::MAX; n];
    let mut component_voxels = Vec::new();
    let mut specks = 0;
    let mut speck_voxels = 0;
    let mut stack = Vec::new();
    let mut members = Vec::new();
    for start in 0..n {
        if !object[start] || component[start] != u32::MAX {
            continue;
        }
        let label = component_voxels.len() as u32;
        members.clear();
        component[start] = label;
        stack.push(start);
        while let Some(v) = stack.pop() {
            members.push(v);
            for d in nb {
                let w = v.wrapping_add_signed(d);
                if object[w] && component[w] == u32::MAX {
                    component[w] = label;
                    stack.push(w);
                }
            }
        }
        if members.len() < min_component_voxels {
            specks += 1;
            speck_voxels += members.len();
            for &v in &members {
                object[v] = false;
                // Marked with a label no kept component has, so the scan does not revisit it.
                component[v] = u32::MAX - 1;
            }
        } else {
            component_voxels.push(members.len());
        }
    }
    for c in &mut component {
        if *c == u32::MAX - 1 {
            *c = u32::MAX;
        }
    }
    // Radius: the exact EDT of the background, the distance from each voxel centre to the
    // nearest background voxel centre in mm.
    let background: Vec<bool> = object.iter().map(|&o| !o).collect();
    let edt = distance_transform(&padded.grid, &background)?;
    let radius: Vec<f64> = edt
        .data()
        .iter()
        .zip(&object)
        .map(|(&s, &o)| if o { f64::from(s) } else { 0.0 })
        .collect();
    let skeleton = thin_object(&padded, object, &radius);
    Ok(Thinned {
        padded,
        skeleton,
        radius,
        component,
        component_voxels,
        specks,
        speck_voxels,
    })
}

/// Sequential thinning in six directional sub-iterations, each ordered by the radius (smallest
/// first); a voxel is deleted when it is simple and not an end point (≤ 1 object neighbour).
fn thin_object(padded: &Padded, mut object: Vec<bool>, radius: &[f64]) -> Vec<bool> {
    let adj = CubeAdjacency::new();
    let cube = padded.cube_offsets();
    let nb = padded.neighbour_offsets();
    let sy = padded.dims[0] as isize;
    let sz = (padded.dims[0] * padded.dims[1]) as isize;
    let directions = [-1isize, 1, -sy, sy, -sz, sz];
    let neighbourhood = |object: &[bool], v: usize| -> u32 {
        let mut bits = 0u32;
        for (c, &d) in cube.iter().enumerate() {
            if object[v.wrapping_add_signed(d)] {
                bits |= 1 << c;
            }
        }
        bits
    };
    let is_end = |object: &[bool], v: usize| -> bool {
        nb.iter()
            .filter(|&&d| object[v.wrapping_add_signed(d)])
            .count()
            <= 1
    };
    let mut candidates: Vec<usize> = Vec::new();
    loop {
        let mut deleted = 0usize;
        for &dir in &directions {
            candidates.clear();
            candidates.extend((0..object.len()).filter(|&v| {
                object[v] && !padded.is_border(v) && !object[v.wrapping_add_signed(dir)]
            }));
            candidates.sort_by(|&a, &b| radius[a].total_cmp(&radius[b]).then(a.cmp(&b)));
            for &v in &candidates {
                if object[v] && !is_end(&object, v) && adj.is_simple(neighbourhood(&object, v)) {
                    object[v] = false;
                    deleted += 1;
                }
            }
        }
        if deleted == 0 {
            break;
        }
    }
    // Final passes without direction: any remaining simple non-end voxel goes (thin corners).
    loop {
        let mut order: Vec<usize> = (0..object.len()).filter(|&v| object[v]).collect();
        order.sort_by(|&a, &b| radius[a].total_cmp(&radius[b]).then(a.cmp(&b)));
        let mut deleted = 0usize;
        for v in order {
            if !is_end(&object, v) && adj.is_simple(neighbourhood(&object, v)) {
                object[v] = false;
                deleted += 1;
            }
        }
        if deleted == 0 {
            break;
        }
    }
    object
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn simple_point_cases() {
        let adj = CubeAdjacency::new();
        // Isolated point: no object neighbour → not simple (deleting it removes a component).
        assert!(!adj.is_simple(1 << 13));
        // End of a line: simple.
        assert!(adj.is_simple((1 << 13) | (1 << 14)));
        // Middle of a line: not simple.
        assert!(!adj.is_simple((1 << 12) | (1 << 13) | (1 << 14)));
        // Interior point of a full cube: not simple (creates a cavity).
        assert!(!adj.is_simple((1 << 27) - 1));
    }
}
