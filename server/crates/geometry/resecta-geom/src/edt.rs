//! Exact Euclidean distance transforms of voxel masks, in millimetres.
//!
//! Separable algorithm of Felzenszwalb & Huttenlocher (lower envelope of parabolas): one exact 1-D
//! transform per grid axis, each parallel over lines with rayon. Squared distances are computed in
//! `f64` along each line and stored between passes as `f32` (relative rounding ≤ 2⁻²⁴ per pass, so
//! results are exact to ~2·10⁻⁷ relative). Distances are between voxel centres in physical mm:
//! `|Δ| = √Σ (spacingₐ·Δindexₐ)²`, which is the world distance for any grid whose axes are
//! orthogonal (oblique rotations included); sheared grids are refused with
//! [`GeomError::NonOrthogonalGrid`].
//!
//! Memory: the unsigned transform allocates its `f32` output (4 B/voxel), plus 4 B/voxel when the
//! nearest-feature index is asked for, plus per-task line buffers of O(nx·ny + nx·nz). The signed
//! transform peaks at 12 B/voxel. A 512×512×300 grid needs 315 MB (unsigned), 630 MB (with
//! nearest), 945 MB (signed), besides the caller's mask.

use rayon::prelude::*;

use crate::error::GeomError;
use crate::grid::{Grid, Volume};
use crate::math::Real;

/// Nearest-feature index of voxels for which no feature exists (empty mask).
pub const NO_FEATURE: u32 = u32::MAX;

/// Distance of every voxel centre to the nearest feature voxel centre, in mm.
///
/// 0 on features; `+∞` everywhere if the mask has no feature. `mask` is in `i`-fastest order.
pub fn distance_transform(grid: &Grid, mask: &[bool]) -> Result<Volume<f32>, GeomError> {
    check_mask(grid, mask)?;
    distance_transform_by(grid, |o| mask[o])
}

/// [`distance_transform`] with the features given by a predicate on the voxel values.
pub fn distance_transform_where<T: Copy + Sync>(
    volume: &Volume<T>,
    feature: impl Fn(T) -> bool + Sync,
) -> Result<Volume<f32>, GeomError> {
    let data = volume.data();
    distance_transform_by(volume.grid(), |o| feature(data[o]))
}

/// A distance map with, for every voxel, the linear offset of its nearest feature voxel.
#[derive(Debug, Clone, PartialEq)]
pub struct NearestFeature {
    /// Distance in mm to the nearest feature voxel centre (`+∞` without features).
    pub distance: Volume<f32>,
    /// Linear offset ([`Grid::offset`]) of a nearest feature voxel, [`NO_FEATURE`] without
    /// features. Ties are broken arbitrarily.
    pub nearest: Volume<u32>,
}

/// [`distance_transform`] plus the nearest feature voxel of every voxel (4 B/voxel more).
///
/// Fails with [`GeomError::TooManyVoxels`] if offsets do not fit in `u32` (beyond 2³² − 1 voxels).
pub fn distance_transform_with_nearest(
    grid: &Grid,
    mask: &[bool],
) -> Result<NearestFeature, GeomError> {
    check_mask(grid, mask)?;
    check_grid(grid)?;
    check_u32(grid)?;
    let (d2, idx) = squared_edt(grid, |o| mask[o], true);
    let idx = idx.unwrap_or_default();
    Ok(NearestFeature {
        distance: Volume::from_vec(grid.clone(), sqrt_all(d2))?,
        nearest: Volume::from_vec(grid.clone(), idx)?,
    })
}

/// Signed distance for margin fields, in mm: negative inside the mask, positive outside.
///
/// Convention: for a voxel centre `x` whose nearest voxel centre of the other class is `y`
/// (`Δ = y − x`, `n` the index difference), the value is `±(|Δ| − ½·|Δ|/‖n‖∞)`: the distance
/// from `x` to where the segment `x→y` enters the cuboid of voxel `y`. The zero level set thus
/// lies half a voxel between the classes (exact in 1-D: a voxel next to the boundary along axis
/// `a` gets `±spacingₐ/2`), and `|value| ≥ ½·min spacing` everywhere. It is never below the
/// distance to the boundary of the union of the other class's voxel cuboids and exceeds it by
/// at most `½·|voxel diagonal| − ½·min spacing`. Without voxels of the other class the value is
/// `+∞` (empty mask) or `−∞` (full mask).
///
/// Against a smooth surface the convention is nearly unbiased next to the boundary and tends to
/// underestimate far from it (by less than half a voxel diagonal), which errs on the safe side for
/// margins: on a voxelised 15 mm sphere at 0.8×0.8×2.5 mm the mean error within 5 mm of the
/// surface is −0.17 mm (raw centre distance: +0.48 mm), and |error| ≤ voxel diagonal everywhere.
pub fn signed_distance_transform(grid: &Grid, inside: &[bool]) -> Result<Volume<f32>, GeomError> {
    check_mask(grid, inside)?;
    signed_by(grid, |o| inside[o])
}

/// [`signed_distance_transform`] with the inside given by a predicate on the voxel values.
pub fn signed_distance_transform_where<T: Copy + Sync>(
    volume: &Volume<T>,
    inside: impl Fn(T) -> bool + Sync,
) -> Result<Volume<f32>, GeomError> {
    let data = volume.data();
    signed_by(volume.grid(), |o| inside(data[o]))
}

fn check_mask(grid: &Grid, mask: &[bool]) -> Result<(), GeomError> {
    if mask.len() == grid.len() {
        Ok(())
    } else {
        Err(GeomError::DataLength {
            expected: grid.len(),
            got: mask.len(),
        })
    }
}

fn check_grid(grid: &Grid) -> Result<(), GeomError> {
    if grid.is_orthogonal() {
        Ok(())
    } else {
        Err(GeomError::NonOrthogonalGrid)
    }
}

fn check_u32(grid: &Grid) -> Result<(), GeomError> {
    if (grid.len() as u64) < u64::from(NO_FEATURE) {
        Ok(())
    } else {
        Err(GeomError::TooManyVoxels {
            dims: grid.dims(),
            limit: u64::from(NO_FEATURE) - 1,
        })
    }
}

fn distance_transform_by(
    grid: &Grid,
    feature: impl Fn(usize) -> bool + Sync,
) -> Result<Volume<f32>, GeomError> {
    check_grid(grid)?;
    let (d2, _) = squared_edt(grid, feature, false);
    Volume::from_vec(grid.clone(), sqrt_all(d2))
}

fn sqrt_all(mut d2: Vec<f32>) -> Vec<f32> {
    d2.par_iter_mut().for_each(|v| *v = v.sqrt());
    d2
}

fn signed_by(grid: &Grid, inside: impl Fn(usize) -> bool + Sync) -> Result<Volume<f32>, GeomError> {
    check_grid(grid)?;
    check_u32(grid)?;
    let spacing = grid.spacing();
    // Pass A: distance to the inside, kept for outside voxels.
    let (mut out, idx) = squared_edt(grid, &inside, true);
    let idx = idx.unwrap_or_default();
    out.par_iter_mut()
        .zip(idx.par_iter())
        .enumerate()
        .for_each(|(o, (v, &n))| {
            if !inside(o) {
                *v = half_voxel(grid, spacing, o, n, Real::INFINITY) as f32;
            }
        });
    drop(idx);
    // Pass B: distance to the outside, negated for inside voxels.
    let (_, idx) = squared_edt(grid, |o| !inside(o), true);
    let idx = idx.unwrap_or_default();
    out.par_iter_mut()
        .zip(idx.par_iter())
        .enumerate()
        .for_each(|(o, (v, &n))| {
            if inside(o) {
                *v = -half_voxel(grid, spacing, o, n, Real::INFINITY) as f32;
            }
        });
    Volume::from_vec(grid.clone(), out)
}

/// `|Δ| − ½|Δ|/‖n‖∞` from voxel `o` to voxel `n`, recomputed exactly in `f64`.
fn half_voxel(grid: &Grid, spacing: [Real; 3], o: usize, n: u32, none: Real) -> Real {
    if n == NO_FEATURE {
        return none;
    }
    let a = grid.ijk(o);
    let b = grid.ijk(n as usize);
    let mut d2 = 0.0;
    let mut cheb = 0usize;
    for ax in 0..3 {
        let k = a[ax].abs_diff(b[ax]);
        cheb = cheb.max(k);
        let mm = spacing[ax] * k as Real;
        d2 += mm * mm;
    }
    let d = d2.sqrt();
    // cheb ≥ 1: a voxel and its nearest voxel of the other class differ.
    d - 0.5 * d / cheb.max(1) as Real
}

/// Squared distances (mm²) to the nearest feature, and optionally the nearest feature offsets.
fn squared_edt(
    grid: &Grid,
    feature: impl Fn(usize) -> bool + Sync,
    track: bool,
) -> (Vec<f32>, Option<Vec<u32>>) {
    let [nx, ny, nz] = grid.dims();
    let w = grid.spacing().map(|s| s * s);
    let len = grid.len();
    let mut d2 = vec![0f32; len];
    let mut idx = track.then(|| vec![NO_FEATURE; len]);

    // Pass 1, along i: nearest feature in the row by two sweeps.
    let rows = |o: usize, row: &mut [f32], ids: Option<&mut [u32]>| {
        let mut near = vec![usize::MAX; nx];
        let mut last = usize::MAX;
        for (i, v) in near.iter_mut().enumerate() {
            if feature(o + i) {
                last = i;
            }
            *v = last;
        }
        let mut next = usize::MAX;
        for i in (0..nx).rev() {
            if near[i] == i {
                next = i;
            } else if next != usize::MAX && (near[i] == usize::MAX || next - i < i - near[i]) {
                near[i] = next;
            }
        }
        for (i, v) in row.iter_mut().enumerate() {
            *v = if near[i] == usize::MAX {
                f32::INFINITY
            } else {
                let k = i.abs_diff(near[i]) as Real;
                (w[0] * k * k) as f32
            };
        }
        if let Some(ids) = ids {
            for (i, v) in ids.iter_mut().enumerate() {
                if near[i] != usize::MAX {
                    *v = (o + near[i]) as u32;
                }
            }
        }
    };
    match idx.as_mut() {
        Some(ids) => d2
            .par_chunks_mut(nx)
            .zip(ids.par_chunks_mut(nx))
            .enumerate()
            .for_each(|(r, (row, ids))| rows(r * nx, row, Some(ids))),
        None => d2
            .par_chunks_mut(nx)
            .enumerate()
            .for_each(|(r, row)| rows(r * nx, row, None)),
    }

    // Pass 2, along j: each k-slab is one task.
    if ny > 1 {
        let slab = nx * ny;
        let id_slabs: Vec<Option<&mut [u32]>> = match idx.as_mut() {
            Some(ids) => ids.chunks_mut(slab).map(Some).collect(),
            None => (0..nz).map(|_| None).collect(),
        };
        d2.par_chunks_mut(slab)
            .zip(id_slabs)
            .for_each(|(d, mut ids)| {
                let mut line = Line::new(ny);
                let mut tmp = vec![NO_FEATURE; ny];
                for i in 0..nx {
                    for (j, f) in line.f.iter_mut().enumerate() {
                        *f = f64::from(d[i + nx * j]);
                    }
                    let any = line.envelope(w[1]);
                    for (j, o) in line.out.iter().enumerate() {
                        d[i + nx * j] = *o as f32;
                    }
                    if let (true, Some(ids)) = (any, ids.as_deref_mut()) {
                        for (j, t) in tmp.iter_mut().enumerate() {
                            *t = ids[i + nx * line.arg[j]];
                        }
                        for (j, t) in tmp.iter().enumerate() {
                            ids[i + nx * j] = *t;
                        }
                    }
                }
            });
    }

    // Pass 3, along k: each j is one task owning row j of every slab.
    if nz > 1 {
        let mut by_j: Vec<Vec<&mut [f32]>> = (0..ny).map(|_| Vec::with_capacity(nz)).collect();
        for s in d2.chunks_mut(nx * ny) {
            for (j, row) in s.chunks_mut(nx).enumerate() {
                by_j[j].push(row);
            }
        }
        let mut ids_by_j: Vec<Option<Vec<&mut [u32]>>> = (0..ny).map(|_| None).collect();
        if let Some(ids) = idx.as_mut() {
            ids_by_j = (0..ny).map(|_| Some(Vec::with_capacity(nz))).collect();
            for s in ids.chunks_mut(nx * ny) {
                for (j, row) in s.chunks_mut(nx).enumerate() {
                    if let Some(v) = ids_by_j[j].as_mut() {
                        v.push(row);
                    }
                }
            }
        }
        by_j.into_par_iter()
            .zip(ids_by_j)
            .for_each(|(mut rows, mut id_rows)| {
                let mut line = Line::new(nz);
                let mut tmp = vec![NO_FEATURE; nz];
                for i in 0..nx {
                    for (k, r) in rows.iter().enumerate() {
                        line.f[k] = f64::from(r[i]);
                    }
                    let any = line.envelope(w[2]);
                    for (k, r) in rows.iter_mut().enumerate() {
                        r[i] = line.out[k] as f32;
                    }
                    if let (true, Some(id_rows)) = (any, id_rows.as_mut()) {
                        for (k, t) in tmp.iter_mut().enumerate() {
                            *t = id_rows[line.arg[k]][i];
                        }
                        for (k, r) in id_rows.iter_mut().enumerate() {
                            r[i] = tmp[k];
                        }
                    }
                }
            });
    }
    (d2, idx)
}

/// Buffers for one 1-D transform `out[p] = min_q f[q] + w·(p − q)²` over finite `f[q]`.
struct Line {
    f: Vec<f64>,
    out: Vec<f64>,
    arg: Vec<usize>,
    v: Vec<usize>,
    z: Vec<f64>,
}

impl Line {
    fn new(n: usize) -> Self {
        Self {
            f: vec![0.0; n],
            out: vec![0.0; n],
            arg: vec![0; n],
            v: vec![0; n],
            z: vec![0.0; n + 1],
        }
    }

    /// Felzenszwalb–Huttenlocher lower envelope; returns false (all `+∞`) without finite sites.
    fn envelope(&mut self, w: Real) -> bool {
        let n = self.f.len();
        let f = &self.f;
        let (v, z) = (&mut self.v, &mut self.z);
        let mut k = 0usize;
        let mut first = true;
        for q in 0..n {
            let fq = f[q];
            if !fq.is_finite() {
                continue;
            }
            if first {
                v[0] = q;
                z[0] = Real::NEG_INFINITY;
                z[1] = Real::INFINITY;
                first = false;
                continue;
            }
            let qf = q as Real;
            let hq = fq + w * qf * qf;
            loop {
                let p = v[k];
                let pf = p as Real;
                let s = (hq - (f[p] + w * pf * pf)) / (2.0 * w * (qf - pf));
                if s <= z[k] && k > 0 {
                    k -= 1;
                } else {
                    k += 1;
                    v[k] = q;
                    z[k] = s;
                    z[k + 1] = Real::INFINITY;
                    break;
                }
            }
        }
        if first {
            self.out.fill(Real::INFINITY);
            return false;
        }
        let mut k = 0usize;
        for p in 0..n {
            let pf = p as Real;
            while z[k + 1] < pf {
                k += 1;
            }
            let q = v[k];
            let d = pf - q as Real;
            self.out[p] = f[q] + w * d * d;
            self.arg[p] = q;
        }
        true
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::needless_range_loop)]

    use super::*;
    use crate::math::{Mat3, Vec3};
    use nalgebra::Rotation3;

    /// xorshift64*: deterministic test randomness.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }
        fn unit(&mut self) -> f64 {
            (self.next() >> 11) as f64 / (1u64 << 53) as f64
        }
        fn below(&mut self, n: usize) -> usize {
            (self.next() % n as u64) as usize
        }
    }

    fn world_dist(g: &Grid, a: usize, b: usize) -> f64 {
        (g.voxel_center(g.ijk(a)) - g.voxel_center(g.ijk(b))).norm()
    }

    /// Brute force: distance of every voxel to the nearest voxel with `mask == want`.
    fn brute(g: &Grid, mask: &[bool], want: bool) -> Vec<f64> {
        (0..g.len())
            .map(|a| {
                (0..g.len())
                    .filter(|&b| mask[b] == want)
                    .map(|b| world_dist(g, a, b))
                    .fold(f64::INFINITY, f64::min)
            })
            .collect()
    }

    fn random_case(rng: &mut Rng, rotated: bool) -> (Grid, Vec<bool>) {
        let dims = [1 + rng.below(9), 1 + rng.below(9), 1 + rng.below(9)];
        let spacing = [
            0.3 + 3.0 * rng.unit(),
            0.3 + 3.0 * rng.unit(),
            0.3 + 3.0 * rng.unit(),
        ];
        let dir = if rotated {
            Rotation3::from_euler_angles(rng.unit() * 3.0, rng.unit(), rng.unit() * 2.0)
                .into_inner()
        } else {
            Mat3::identity()
        };
        let g = Grid::new(dims, spacing, Vec3::new(-3.0, 7.0, 1.0), dir).unwrap();
        let density = [0.02, 0.1, 0.5, 0.9][rng.below(4)];
        let mask = (0..g.len()).map(|_| rng.unit() < density).collect();
        (g, mask)
    }

    fn close(a: f64, b: f64) -> bool {
        (a.is_infinite() && a == b) || (a - b).abs() <= 1e-5 * b.abs().max(1e-3)
    }

    #[test]
    fn equals_brute_force_on_random_anisotropic_masks() {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        for case in 0..300 {
            let (g, mask) = random_case(&mut rng, case % 2 == 1);
            let want = brute(&g, &mask, true);
            let got = distance_transform(&g, &mask).unwrap();
            let near = distance_transform_with_nearest(&g, &mask).unwrap();
            assert_eq!(near.distance, got);
            for o in 0..g.len() {
                let d = f64::from(got.data()[o]);
                assert!(
                    close(d, want[o]),
                    "case {case} voxel {o}: {d} vs {}",
                    want[o]
                );
                let n = near.nearest.data()[o];
                if want[o].is_finite() {
                    assert!(mask[n as usize], "nearest of {o} is not a feature");
                    assert!(close(world_dist(&g, o, n as usize), want[o]));
                } else {
                    assert_eq!(n, NO_FEATURE);
                }
            }
        }
    }

    #[test]
    fn signed_follows_its_convention_against_brute_force() {
        let mut rng = Rng(42);
        for case in 0..200 {
            let (g, mask) = random_case(&mut rng, case % 2 == 0);
            let sd = signed_distance_transform(&g, &mask).unwrap();
            for o in 0..g.len() {
                let v = f64::from(sd.data()[o]);
                let other: Vec<usize> = (0..g.len()).filter(|&b| mask[b] != mask[o]).collect();
                if other.is_empty() {
                    assert_eq!(
                        v,
                        if mask[o] {
                            f64::NEG_INFINITY
                        } else {
                            f64::INFINITY
                        }
                    );
                    continue;
                }
                assert_eq!(v < 0.0, mask[o], "sign of voxel {o}");
                let d = other
                    .iter()
                    .map(|&b| world_dist(&g, o, b))
                    .fold(f64::INFINITY, f64::min);
                // Any nearest voxel of the other class may be the one used (ties).
                let ok = other.iter().any(|&b| {
                    let (a, c) = (g.ijk(o), g.ijk(b));
                    let cheb = (0..3).map(|x| a[x].abs_diff(c[x])).max().unwrap() as f64;
                    let db = world_dist(&g, o, b);
                    close(db, d) && close(v.abs(), db - 0.5 * db / cheb)
                });
                assert!(ok, "case {case} voxel {o}: {v}, nearest at {d}");
                let smin = g.spacing().into_iter().fold(f64::INFINITY, f64::min);
                assert!(v.abs() >= 0.5 * smin * (1.0 - 1e-6));
            }
        }
    }

    #[test]
    fn signed_is_half_voxel_exact_in_one_dimension() {
        let g = Grid::axis_aligned([1, 1, 7], [1.0, 1.0, 2.5], Vec3::zeros()).unwrap();
        let mask = [true, true, true, false, false, false, false];
        let sd = signed_distance_transform(&g, &mask).unwrap();
        // Boundary between k = 2 and k = 3, i.e. at 6.25 mm.
        let want = [-6.25, -3.75, -1.25, 1.25, 3.75, 6.25, 8.75];
        for (v, w) in sd.data().iter().zip(want) {
            assert!((f64::from(*v) - w).abs() < 1e-6, "{v} vs {w}");
        }
    }

    #[test]
    fn voxelised_sphere_matches_analytic_distance() {
        let spacing = [0.8, 0.8, 2.5];
        let dims = [90, 90, 30];
        let r = Rotation3::from_euler_angles(0.1, -0.05, 0.3).into_inner();
        let g = Grid::new(dims, spacing, Vec3::new(10.0, -20.0, 5.0), r).unwrap();
        let c = g.voxel_center([45, 44, 15]) + Vec3::new(0.13, -0.21, 0.37);
        let radius = 15.0;
        let inside: Vec<bool> = (0..g.len())
            .map(|o| (g.voxel_center(g.ijk(o)) - c).norm() <= radius)
            .collect();
        let d = distance_transform(&g, &inside).unwrap();
        let sd = signed_distance_transform(&g, &inside).unwrap();
        // Feature centres lie in the ball, and every point of the ball is within half a voxel
        // diagonal of a feature centre: 0 ≤ EDT − (|x − c| − R) ≤ voxel diagonal.
        let diag = spacing.iter().map(|s| s * s).sum::<f64>().sqrt();
        let (mut sum_raw, mut sum_sd, mut n) = (0.0f64, 0.0, 0.0);
        for o in 0..g.len() {
            let truth = (g.voxel_center(g.ijk(o)) - c).norm() - radius;
            let e = f64::from(d.data()[o]);
            if inside[o] {
                assert_eq!(e, 0.0);
            } else {
                let err = e - truth;
                assert!(
                    (-1e-4..=diag + 1e-4).contains(&err),
                    "voxel {o}: {e} vs {truth}"
                );
            }
            // Signed: |sd − (|x − c| − R)| ≤ voxel diagonal on both sides.
            let err = f64::from(sd.data()[o]) - truth;
            assert!(err.abs() <= diag + 1e-4, "signed voxel {o}: err {err}");
            if !inside[o] && truth < 5.0 {
                sum_raw += f64::from(d.data()[o]) - truth;
                sum_sd += err;
                n += 1.0;
            }
        }
        // Within 5 mm of the surface the raw centre distance overestimates by about half a voxel;
        // the half-voxel convention roughly centres the error.
        let (raw, centred) = (sum_raw / n, sum_sd / n);
        eprintln!("mean error outside: raw {raw:.3} mm, signed {centred:.3} mm");
        assert!(
            raw > 0.3 && centred.abs() < 0.5 * raw,
            "raw {raw}, signed {centred}"
        );
    }

    #[test]
    fn oblique_grid_gives_the_axis_aligned_distances() {
        let mut rng = Rng(7);
        let dims = [12, 9, 6];
        let spacing = [0.7, 1.1, 2.5];
        let mask: Vec<bool> = (0..dims.iter().product())
            .map(|_| rng.unit() < 0.05)
            .collect();
        let straight = Grid::axis_aligned(dims, spacing, Vec3::zeros()).unwrap();
        let rot = Rotation3::from_euler_angles(0.4, 0.9, -1.3).into_inner();
        let oblique = Grid::new(dims, spacing, Vec3::new(5.0, 1.0, -2.0), rot).unwrap();
        let a = distance_transform(&straight, &mask).unwrap();
        let b = distance_transform(&oblique, &mask).unwrap();
        assert_eq!(a.data(), b.data());
        // And they are world distances on the oblique grid.
        let want = brute(&oblique, &mask, true);
        for (got, w) in b.data().iter().zip(want) {
            assert!(close(f64::from(*got), w));
        }
    }

    #[test]
    fn empty_and_full_masks() {
        let g = Grid::axis_aligned([5, 4, 3], [1.0, 2.0, 3.0], Vec3::zeros()).unwrap();
        let empty = vec![false; g.len()];
        let full = vec![true; g.len()];
        let d = distance_transform(&g, &empty).unwrap();
        assert!(d.data().iter().all(|v| *v == f32::INFINITY));
        let n = distance_transform_with_nearest(&g, &empty).unwrap();
        assert!(n.nearest.data().iter().all(|v| *v == NO_FEATURE));
        assert!(
            distance_transform(&g, &full)
                .unwrap()
                .data()
                .iter()
                .all(|v| *v == 0.0)
        );
        let s = signed_distance_transform(&g, &empty).unwrap();
        assert!(s.data().iter().all(|v| *v == f32::INFINITY));
        let s = signed_distance_transform(&g, &full).unwrap();
        assert!(s.data().iter().all(|v| *v == f32::NEG_INFINITY));
    }

    #[test]
    fn predicate_variants_match_the_mask_variants() {
        let g = Grid::axis_aligned([6, 5, 4], [0.9, 1.0, 2.0], Vec3::zeros()).unwrap();
        let labels: Vec<u16> = (0..g.len() as u16).map(|v| v % 7).collect();
        let vol = Volume::from_vec(g.clone(), labels.clone()).unwrap();
        let mask: Vec<bool> = labels.iter().map(|&l| l == 3).collect();
        assert_eq!(
            distance_transform_where(&vol, |l| l == 3).unwrap(),
            distance_transform(&g, &mask).unwrap()
        );
        assert_eq!(
            signed_distance_transform_where(&vol, |l| l == 3).unwrap(),
            signed_distance_transform(&g, &mask).unwrap()
        );
    }

    #[test]
    fn sheared_grids_and_bad_masks_are_refused() {
        let mut dir = Mat3::identity();
        dir[(0, 1)] = 0.2;
        let g = Grid::new([4, 4, 4], [1.0; 3], Vec3::zeros(), dir).unwrap();
        let mask = vec![true; g.len()];
        assert_eq!(
            distance_transform(&g, &mask),
            Err(GeomError::NonOrthogonalGrid)
        );
        assert_eq!(
            signed_distance_transform(&g, &mask),
            Err(GeomError::NonOrthogonalGrid)
        );
        assert_eq!(
            distance_transform_with_nearest(&g, &mask),
            Err(GeomError::NonOrthogonalGrid)
        );
        let ok = Grid::axis_aligned([4, 4, 4], [1.0; 3], Vec3::zeros()).unwrap();
        assert!(matches!(
            distance_transform(&ok, &mask[..10]),
            Err(GeomError::DataLength {
                expected: 64,
                got: 10
            })
        ));
    }
}
