//! The seam through which an accelerator (the GPU, `resecta-gpu`) computes the two heavy steps
//! of a cut — the band and the components of the other liver voxels — for [`Volumetry`]
//! (installed with [`Volumetry::with_accelerator`]). The rest stays on the host: sampling, the
//! band fractions, the sides of the components, incomplete cuts.
//!
//! The contract makes results equal the CPU's: band membership is the CPU's slab-disc test
//! ([`SlabDisc::column`], [`SlabDisc::reach`]), each band voxel keeps the sample of smallest
//! `f32` squared distance (ties: smallest sample index), and components are 6-connected with
//! the band as barrier, each named by its smallest compact index (the CPU's union–find root).
//! Volumes then differ from the CPU's by nothing but summation order (in practice not at all).
//!
//! The host checks what it gets (each band voxel in the liver and in its sample's slab-disc,
//! no voxel twice, every neighbour root listed); an error or a failed check sends the cut to
//! the CPU, counted by [`Volumetry::accelerator_fallbacks`]. Cuts with non-finite samples stay
//! on the CPU. Planners hold an [`AcceleratorFactory`] and install one accelerator per liver.
//!
//! [`Volumetry`]: crate::Volumetry
//! [`Volumetry::with_accelerator`]: crate::Volumetry::with_accelerator
//! [`Volumetry::accelerator_fallbacks`]: crate::Volumetry::accelerator_fallbacks

use resecta_geom::{Real, Vec3};

use crate::liver::LiverVoxels;

/// An accelerator failed (device lost, out of memory, bad output); the cut is computed on the
/// CPU instead.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("volumetry accelerator: {0}")]
pub struct AcceleratorError(pub String);

/// One surface sample's slab-disc in the liver's bounding-box index space: the voxels within
/// `hs` of its tangent plane (along index axis `axis`, column by column over the two other
/// axes) and within `rho` of it laterally.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlabDisc {
    /// Sample point and unit normal (RAS mm).
    pub point: Vec3,
    pub normal: Vec3,
    /// The point in continuous bounding-box coordinates.
    pub g: Vec3,
    /// The normal's change of offset per index step, `linearᵀ·n`.
    pub n_idx: Vec3,
    /// The axis along which the offset changes fastest; the outer axes are `(axis + 1) % 3` and
    /// `(axis + 2) % 3`.
    pub axis: usize,
    /// Inclusive ranges of the outer axes (empty, `lo > hi`, for a degenerate normal).
    pub outer: [[i64; 2]; 2],
    /// The voxel's extent along the normal, `Σ |n·edge|` (mm).
    pub extent: Real,
}

impl SlabDisc {
    /// The outer axes.
    pub fn outer_axes(&self) -> [usize; 2] {
        [(self.axis + 1) % 3, (self.axis + 2) % 3]
    }

    /// Inclusive range along `axis` of column (`a`, `b`) of the outer axes: the voxels within
    /// `hs` of the tangent plane, clipped to `0..len` (`lo > hi` when empty).
    pub fn column(&self, hs: Real, a: i64, b: i64, len: usize) -> (i64, i64) {
        let (m, [o1, o2]) = (self.axis, self.outer_axes());
        let (n, g) = (&self.n_idx, &self.g);
        let rest = n[o1] * (a as Real - g[o1]) + n[o2] * (b as Real - g[o2]);
        let (t0, t1) = ((-hs - rest) / n[m], (hs - rest) / n[m]);
        let lo = ((t0.min(t1) + g[m]).ceil() as i64).max(0);
        let hi = ((t0.max(t1) + g[m]).floor() as i64).min(len as i64 - 1);
        (lo, hi)
    }

    /// Whether bounding-box voxel `ijk` lies in the slab (an outer range and its column, in a box
    /// of `dims`): what the CPU's walk visits before [`SlabDisc::reach`].
    pub fn holds(&self, hs: Real, ijk: [usize; 3], dims: [usize; 3]) -> bool {
        let [o1, o2] = self.outer_axes();
        let [a, b, c] = [ijk[o1], ijk[o2], ijk[self.axis]].map(|x| x as i64);
        let [[a0, a1], [b0, b1]] = self.outer;
        let (lo, hi) = self.column(hs, a, b, dims[self.axis]);
        (a0..=a1).contains(&a) && (b0..=b1).contains(&b) && (lo..=hi).contains(&c)
    }

    /// For a voxel centre within `rho` of the sample laterally: its squared distance as `f32`
    /// (the key nearest samples are chosen by) and its offset `n·(c − S)`.
    pub fn reach(&self, centre: &Vec3, rho: Real) -> Option<(f32, Real)> {
        let d = centre - self.point;
        let off = self.normal.dot(&d);
        let d2 = d.norm_squared();
        if d2 - off * off > rho * rho {
            return None;
        }
        Some((d2 as f32, off))
    }
}

/// What an accelerator computes the band of one cut from.
#[derive(Debug, Clone, Copy)]
pub struct BandQuery<'a> {
    /// One slab-disc per sample, in sample order.
    pub discs: &'a [SlabDisc],
    /// Half-thickness of the slabs (mm).
    pub hs: Real,
    /// Lateral radius of the discs (mm).
    pub rho: Real,
}

/// A band voxel found by an accelerator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BandVoxel {
    /// Linear bounding-box index `x + bx·(y + by·z)` ([`LiverVoxels::box_index`]).
    pub cell: u32,
    /// The nearest sample whose slab-disc holds the voxel (smallest `f32` squared distance,
    /// then smallest index).
    pub sample: u32,
    /// Component roots of the face neighbours −x, +x, −y, +y, −z, +z; `u32::MAX` where the
    /// neighbour is outside the liver or in the band.
    pub neighbours: [u32; 6],
}

/// An accelerator's band and components of one cut.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct BandComponents {
    /// Every band voxel once, any order.
    pub band: Vec<BandVoxel>,
    /// Every component root (smallest compact index of a component), any order.
    pub roots: Vec<u32>,
}

/// The band and side components of cuts on one liver, computed elsewhere (the GPU). An
/// accelerator serves the [`LiverVoxels`] it is first called with; install one per liver.
pub trait CutAccelerator: Send + Sync + std::fmt::Debug {
    /// The band of `query` on `liver` and the components of the other liver voxels.
    fn band_components(
        &mut self,
        liver: &LiverVoxels,
        query: &BandQuery<'_>,
    ) -> Result<BandComponents, AcceleratorError>;

    /// After [`CutAccelerator::band_components`]: the non-band voxels whose component root is
    /// in `roots` (sorted), as a bit set over compact indices (bit `c % 32` of word `c / 32`).
    fn resected_mask(&mut self, roots: &[u32]) -> Result<Vec<u32>, AcceleratorError>;
}

/// The function an [`AcceleratorFactory`] calls.
type Make = dyn Fn() -> Result<Box<dyn CutAccelerator>, AcceleratorError> + Send + Sync;

/// Makes accelerators, one per liver: what a planner holds to accelerate the volumetries it
/// builds (`Volumetry::set_accelerator(factory.make().ok())`; the CPU where making one fails).
/// Cheap to clone.
#[derive(Clone)]
pub struct AcceleratorFactory {
    backend: &'static str,
    make: std::sync::Arc<Make>,
}

impl AcceleratorFactory {
    /// A factory named `backend` (e.g. `"wgpu"`).
    pub fn new(
        backend: &'static str,
        make: impl Fn() -> Result<Box<dyn CutAccelerator>, AcceleratorError> + Send + Sync + 'static,
    ) -> Self {
        Self {
            backend,
            make: std::sync::Arc::new(make),
        }
    }

    /// A new accelerator.
    pub fn make(&self) -> Result<Box<dyn CutAccelerator>, AcceleratorError> {
        (self.make)()
    }

    /// The backend's name.
    pub fn backend(&self) -> &'static str {
        self.backend
    }
}

impl std::fmt::Debug for AcceleratorFactory {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AcceleratorFactory")
            .field("backend", &self.backend)
            .finish_non_exhaustive()
    }
}

/// Compact ranges `[a, b)` of the set bits of `mask` below `n`.
pub(crate) fn mask_ranges(mask: &[u32], n: usize) -> Vec<(u32, u32)> {
    let mut out: Vec<(u32, u32)> = Vec::new();
    let words = mask.iter().take(n.div_ceil(32)).enumerate();
    for (w, &bits) in words.filter(|(_, b)| **b != 0) {
        let mut rest = bits;
        while rest != 0 {
            let lo = rest.trailing_zeros();
            let run = (rest >> lo).trailing_ones();
            let a = (w * 32 + lo as usize).min(n) as u32;
            let b = (w * 32 + (lo + run) as usize).min(n) as u32;
            match out.last_mut() {
                Some(last) if last.1 == a => last.1 = b,
                _ if a < b => out.push((a, b)),
                _ => {}
            }
            rest = if lo + run >= 32 {
                0
            } else {
                rest & !((1u32 << (lo + run)) - 1)
            };
        }
    }
    out
}

/// The liver's bounding-box coordinates of linear bounding-box index `cell`.
pub(crate) fn cell_coords(liver: &LiverVoxels, cell: u32) -> [usize; 3] {
    let [bx, by, _] = liver.bdims();
    let c = cell as usize;
    [c % bx, (c / bx) % by, c / (bx * by)]
}

#[cfg(test)]
mod tests {
    use super::mask_ranges;

    #[test]
    fn mask_ranges_merge_across_words_and_stop_at_n() {
        let mask = [0xF000_0001u32, 0x0000_0003, 0, 0x8000_0000, 0xFFFF_FFFF];
        assert_eq!(mask_ranges(&mask, 140), vec![(0, 1), (28, 34), (127, 140)]);
        assert!(mask_ranges(&[0, 0], 64).is_empty());
        // Words beyond n are ignored.
        assert_eq!(mask_ranges(&[1, 1, 1], 33), vec![(0, 1), (32, 33)]);
    }
}
