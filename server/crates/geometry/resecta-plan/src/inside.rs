//! The liver's inside level for margin classes: the envelope mask packed into 4×4×4 bit bricks
//! (one `u64` each, 1/8 of a byte per voxel), so the eight corners of a trilinear lookup usually
//! share a cache line even on a 512×512×300 grid.

use rayon::prelude::*;
use resecta_geom::{Grid, Real, Vec3, Volume};

/// Bricked bit copy of a mask with trilinear lookups and the bounds of its set voxels.
#[derive(Debug, Clone)]
pub struct InsideField {
    grid: Grid,
    dims: [usize; 3],
    /// Bricks along x and y.
    bricks: [usize; 2],
    words: Vec<u64>,
    bounds: Option<(Vec3, Vec3)>,
}

/// [`InsideField`]'s data: voxel (i, j, k) is bit `(k & 3) << 4 | (j & 3) << 2 | (i & 3)` of
/// word `((k >> 2)·bricks[1] + (j >> 2))·bricks[0] + (i >> 2)`; the level at a point is the
/// trilinear interpolation of the bits at `grid.world_to_index(p)`, 0 beyond the grid, minus ½.
#[derive(Debug, Clone, Copy)]
pub struct InsideLayout<'a> {
    pub grid: &'a Grid,
    pub dims: [usize; 3],
    /// Bricks along x and y.
    pub bricks: [usize; 2],
    pub words: &'a [u64],
}

impl InsideField {
    pub fn new(mask: &Volume<bool>) -> Self {
        let grid = mask.grid().clone();
        let dims = grid.dims();
        let nb = dims.map(|d| d.div_ceil(4));
        let layer = nb[0] * nb[1];
        let plane = dims[0] * dims[1];
        let data = mask.data();
        let mut words = vec![0u64; layer * nb[2]];
        // One job per layer of bricks (four voxel planes): its words and the bounds of its set
        // voxels.
        let bounds_per_layer: Vec<Option<([usize; 3], [usize; 3])>> = words
            .par_chunks_mut(layer.max(1))
            .enumerate()
            .map(|(bk, out)| {
                let mut lo = [usize::MAX; 3];
                let mut hi = [0usize; 3];
                for k in 4 * bk..(4 * bk + 4).min(dims[2]) {
                    for j in 0..dims[1] {
                        let row = &data[k * plane + j * dims[0]..][..dims[0]];
                        if !row.iter().fold(false, |any, &b| any | b) {
                            continue;
                        }
                        for (i, _) in row.iter().enumerate().filter(|(_, b)| **b) {
                            let (w, bit) = Self::slot(nb, [i, j, k]);
                            out[w - bk * layer] |= 1 << bit;
                            let ijk = [i, j, k];
                            for a in 0..3 {
                                lo[a] = lo[a].min(ijk[a]);
                                hi[a] = hi[a].max(ijk[a]);
                            }
                        }
                    }
                }
                (lo[0] != usize::MAX).then_some((lo, hi))
            })
            .collect();
        let (lo, hi) = bounds_per_layer.into_iter().flatten().fold(
            ([usize::MAX; 3], [0usize; 3]),
            |(lo, hi), (a, b)| {
                (
                    [0, 1, 2].map(|x| lo[x].min(a[x])),
                    [0, 1, 2].map(|x| hi[x].max(b[x])),
                )
            },
        );
        let bounds = (lo[0] != usize::MAX).then(|| {
            // The voxel-centre box's corners, mapped to RAS (any affine: take all 8).
            let mut a = Vec3::repeat(Real::INFINITY);
            let mut b = Vec3::repeat(Real::NEG_INFINITY);
            for c in 0..8 {
                let p = grid
                    .voxel_center([0, 1, 2].map(|k| if c >> k & 1 == 1 { hi[k] } else { lo[k] }));
                a = a.inf(&p);
                b = b.sup(&p);
            }
            (a, b)
        });
        Self {
            grid,
            dims,
            bricks: [nb[0], nb[1]],
            words,
            bounds,
        }
    }

    #[inline]
    fn slot(nb: [usize; 3], [i, j, k]: [usize; 3]) -> (usize, u32) {
        let w = ((k >> 2) * nb[1] + (j >> 2)) * nb[0] + (i >> 2);
        let bit = ((k & 3) << 4 | (j & 3) << 2 | (i & 3)) as u32;
        (w, bit)
    }

    #[inline]
    fn bit(&self, ijk: [usize; 3]) -> bool {
        let (w, bit) = Self::slot([self.bricks[0], self.bricks[1], 0], ijk);
        self.words.get(w).is_some_and(|x| x >> bit & 1 == 1)
    }

    /// Trilinear interpolation of the mask (as 0/1) at `p`; 0 outside the grid.
    pub fn level(&self, p: &Vec3) -> Real {
        let g = self.grid.world_to_index(*p);
        if !g.iter().all(|c| c.is_finite()) {
            return 0.0;
        }
        let base = [g.x.floor(), g.y.floor(), g.z.floor()];
        let frac = [g.x - base[0], g.y - base[1], g.z - base[2]];
        // Corner c (bit 0: +i, bit 1: +j, bit 2: +k) is set in `corners` when inside and set.
        let mut corners = 0u8;
        if (0..3).all(|a| base[a] >= 0.0 && base[a] + 1.0 < self.dims[a] as Real) {
            let [i, j, k] = base.map(|c| c as usize);
            if i & 3 != 3 && j & 3 != 3 && k & 3 != 3 {
                // All eight in one brick word: bits b, b+1, b+4, b+5, b+16, b+17, b+20, b+21.
                let (w, b) = Self::slot([self.bricks[0], self.bricks[1], 0], [i, j, k]);
                let x = self.words.get(w).map_or(0, |x| x >> b);
                for (c, off) in [0, 1, 4, 5, 16, 17, 20, 21].into_iter().enumerate() {
                    corners |= ((x >> off & 1) as u8) << c;
                }
            } else {
                for c in 0..8 {
                    let ijk = [i + (c & 1), j + (c >> 1 & 1), k + (c >> 2 & 1)];
                    corners |= u8::from(self.bit(ijk)) << c;
                }
            }
        } else {
            for c in 0..8usize {
                let ijk = [0, 1, 2].map(|a| base[a] + Real::from(u8::from(c >> a & 1 == 1)));
                if (0..3).all(|a| ijk[a] >= 0.0 && ijk[a] < self.dims[a] as Real) {
                    corners |= u8::from(self.bit(ijk.map(|x| x as usize))) << c;
                }
            }
        }
        match corners {
            0 => 0.0,
            0xFF => 1.0,
            _ => (0..8)
                .filter(|c| corners >> c & 1 == 1)
                .map(|c| {
                    (0..3)
                        .map(|a| {
                            if c >> a & 1 == 1 {
                                frac[a]
                            } else {
                                1.0 - frac[a]
                            }
                        })
                        .product::<Real>()
                })
                .sum(),
        }
    }

    /// The bricks as laid out in memory, for accelerators that look levels up themselves.
    pub fn layout(&self) -> InsideLayout<'_> {
        InsideLayout {
            grid: &self.grid,
            dims: self.dims,
            bricks: self.bricks,
            words: &self.words,
        }
    }

    /// RAS bounds (min, max) of the set voxels' centres, `None` when the mask is empty.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        self.bounds
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use resecta_geom::Mat3;

    #[test]
    fn bricked_lookup_matches_the_mask_and_interpolates() {
        let dims = [11, 7, 9];
        let dir = Mat3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
        let grid = Grid::new(dims, [0.8, 1.2, 2.5], Vec3::new(-3.0, 4.0, 1.0), dir).unwrap();
        let data: Vec<bool> = (0..dims.iter().product::<usize>())
            .map(|v| (v * 7919) % 5 < 2)
            .collect();
        let mask = Volume::from_vec(grid.clone(), data.clone()).unwrap();
        let f = InsideField::new(&mask);
        for (v, &b) in data.iter().enumerate() {
            let ijk = [v % 11, (v / 11) % 7, v / 77];
            assert!((f.level(&grid.voxel_center(ijk)) - Real::from(u8::from(b))).abs() < 1e-9);
        }
        // Against a plain trilinear interpolation at points over and beyond the grid, which
        // exercise the one-word, cross-brick and grid-edge paths.
        let value = |ijk: [i64; 3]| {
            let ok = (0..3).all(|a| ijk[a] >= 0 && ijk[a] < dims[a] as i64);
            let at = ijk.map(|x| x.max(0) as usize);
            Real::from(u8::from(ok && mask.get(at).unwrap()))
        };
        for n in 0..4000u64 {
            let t = [0u64, 1, 2].map(|a| ((n * 2654435761 + a * 40503) % 100_000) as Real / 1e5);
            let g = Vec3::new(t[0] * 13.0 - 1.5, t[1] * 9.0 - 1.5, t[2] * 11.0 - 1.5);
            let b = [g.x.floor(), g.y.floor(), g.z.floor()];
            let mut expect = 0.0;
            for c in 0..8 {
                let mut w = 1.0;
                let mut ijk = [0i64; 3];
                for a in 0..3 {
                    let up = c >> a & 1 == 1;
                    ijk[a] = b[a] as i64 + i64::from(up);
                    w *= if up { g[a] - b[a] } else { 1.0 - (g[a] - b[a]) };
                }
                expect += w * value(ijk);
            }
            let got = f.level(&grid.index_to_world(g));
            assert!((got - expect).abs() < 1e-9, "{g:?}: {got} vs {expect}");
        }
        let (lo, hi) = f.bounds().unwrap();
        assert!(lo.iter().zip(hi.iter()).all(|(l, h)| l < h));
    }
}
