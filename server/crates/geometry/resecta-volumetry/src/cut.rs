//! Volumes on either side of a Bézier cut.
//!
//! 1. The surface is sampled with spacing δ ≤ the smallest voxel spacing (points and unit
//!    normals), estimated from the control polygon's lengths.
//! 2. **Band**: every liver voxel in a sample's slab-disc (within `hs` of its tangent plane, hs
//!    above half the voxel's largest extent w_max and above its longest edge, and within 0.75 δ of
//!    it laterally) keeps its nearest such sample. Its signed offset
//!    `s = σ·n·(c − S)` from that sample's tangent plane (σ orients the tumour side negative)
//!    gives the voxel's fraction on the tumour side, `f = clamp(½ − s/w(n), 0, 1)` with
//!    `w(n) = |n·a| + |n·b| + |n·c|` the voxel's extent along n — exact when the plane is
//!    parallel to a voxel face and unbiased otherwise (f(s) + f(−s) = 1, like the exact
//!    plane–box fraction), so errors cancel over a cut.
//! 3. **Sides**: the other liver voxels form 6-connected components with the band as a barrier
//!    (union–find over x-runs split at band voxels). A component touching only tumour-side band
//!    voxels is resected, only the other side is remnant; both sides means the cut does not
//!    separate the liver (**leak**); neither (a liver island away from the cut) takes the side
//!    of its first voxel relative to the nearest sample's tangent plane.
//! 4. **Incomplete cuts**: no band voxel (the surface misses the liver), a boundary sample of
//!    the surface inside a liver voxel (the patch ends inside the liver), or a leak.
//!
//! Resected volume = Σ tumour-side component voxels + Σ band fractions, × voxel volume. For an
//! incomplete cut `resected_mm3` holds this sum all the same but is not a valid volume.

use rayon::prelude::*;
use resecta_bezier::{ControlNet, MleEvaluator, Outputs, Resolution};
use resecta_geom::{Real, Vec3, Volume};
use serde::Serialize;

use crate::error::VolumetryError;
use crate::liver::LiverVoxels;

/// Most samples per direction of the cut surface.
const MAX_SAMPLES_PER_AXIS: usize = 2048;

/// Why a cut does not separate the liver.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "reason")]
pub enum IncompleteCut {
    /// The surface does not pass through the liver.
    MissesLiver,
    /// The surface ends inside the liver at this point (RAS).
    EdgeInsideLiver { point: [Real; 3] },
    /// The surface passes through the liver but does not divide it: one region reaches both sides.
    Leak,
}

impl std::fmt::Display for IncompleteCut {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            IncompleteCut::MissesLiver => f.write_str("the surface misses the liver"),
            IncompleteCut::EdgeInsideLiver { point } => write!(
                f,
                "the surface ends inside the liver near ({:.1}, {:.1}, {:.1})",
                point[0], point[1], point[2]
            ),
            IncompleteCut::Leak => {
                f.write_str("the surface does not divide the liver (the liver connects around it)")
            }
        }
    }
}

/// One cut's result.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CutResult {
    /// Functional liver on the tumour side (mm³); valid only when `complete`.
    pub resected_mm3: Real,
    pub complete: bool,
    pub incomplete: Option<IncompleteCut>,
    /// Voxels in the band (fractional).
    pub band_voxels: usize,
    /// Surface samples [ru, rv].
    pub samples: [usize; 2],
}

/// Several cuts.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MultiCut {
    pub cuts: Vec<CutResult>,
    pub total_mm3: Real,
    /// Union of the resected regions (per voxel the largest fraction).
    pub resected_mm3: Real,
    pub remnant_mm3: Real,
    pub complete: bool,
}

/// Per-cut state kept for the union and label maps.
struct Sides {
    result: CutResult,
    /// Band voxels (compact index) and their tumour-side fraction.
    band: Vec<(u32, f32)>,
    /// Component id per sub-run → resected?
    resected_runs: Vec<(u32, u32)>,
}

/// A reusable volumetry engine for one liver.
#[derive(Debug)]
pub struct Volumetry {
    liver: LiverVoxels,
    epoch: u32,
    stamp: Vec<u32>,
    best_d2: Vec<f32>,
    offset: Vec<f32>,
    extent: Vec<f32>,
}

impl Volumetry {
    pub fn new(liver: LiverVoxels) -> Self {
        let n = liver.len();
        Self {
            liver,
            epoch: 0,
            stamp: vec![0; n],
            best_d2: vec![0.0; n],
            offset: vec![0.0; n],
            extent: vec![0.0; n],
        }
    }

    pub fn liver(&self) -> &LiverVoxels {
        &self.liver
    }

    /// One resection; the resected side is the side holding `tumour_points`.
    pub fn cut(
        &mut self,
        net: &ControlNet<Real>,
        tumour_points: &[Vec3],
    ) -> Result<CutResult, VolumetryError> {
        Ok(self.sides(net, tumour_points)?.result)
    }

    /// Several resections: each one's result, their union and the remnant.
    pub fn cuts(
        &mut self,
        cuts: &[(&ControlNet<Real>, &[Vec3])],
    ) -> Result<MultiCut, VolumetryError> {
        let n = self.liver.len();
        let vox = self.liver.grid().voxel_volume_mm3();
        let mut union = vec![0f32; if cuts.len() > 1 { n } else { 0 }];
        let mut results = Vec::with_capacity(cuts.len());
        for (net, pts) in cuts {
            let s = self.sides(net, pts)?;
            if cuts.len() > 1 {
                for &(a, b) in &s.resected_runs {
                    union[a as usize..b as usize].fill(1.0);
                }
                for &(v, f) in &s.band {
                    let u = &mut union[v as usize];
                    *u = u.max(f);
                }
            }
            results.push(s.result);
        }
        let total = self.liver.total_mm3();
        let resected = match results.as_slice() {
            [] => 0.0,
            [one] => one.resected_mm3,
            _ => union.iter().map(|&f| Real::from(f)).sum::<Real>() * vox,
        };
        Ok(MultiCut {
            complete: results.iter().all(|r| r.complete),
            cuts: results,
            total_mm3: total,
            resected_mm3: resected,
            remnant_mm3: total - resected,
        })
    }

    /// Label map on the liver grid: 0 not liver, 1 remnant, 2 + i resected by cut i (voxel
    /// fraction ≥ ½; the first cut wins where they overlap).
    pub fn resected_labels(
        &mut self,
        cuts: &[(&ControlNet<Real>, &[Vec3])],
    ) -> Result<Volume<u8>, VolumetryError> {
        let n = self.liver.len();
        let mut label = vec![1u8; n];
        for (i, (net, pts)) in cuts.iter().enumerate().rev() {
            let tag = u8::try_from(i + 2).unwrap_or(u8::MAX);
            let s = self.sides(net, pts)?;
            for &(a, b) in &s.resected_runs {
                label[a as usize..b as usize].fill(tag);
            }
            for &(v, f) in &s.band {
                if f >= 0.5 {
                    label[v as usize] = tag;
                }
            }
        }
        let grid = self.liver.grid().clone();
        let [nx, ny, _] = grid.dims();
        let mut out = vec![0u8; grid.len()];
        let l = &self.liver;
        let [_, by, _] = l.bdims();
        for (row, w) in l.row_start.windows(2).enumerate() {
            let (y, z) = (row % by + l.lo[1], row / by + l.lo[2]);
            for r in &l.runs[w[0] as usize..w[1] as usize] {
                for x in r.x0..r.x1 {
                    let c = (r.offset + x - r.x0) as usize;
                    out[x as usize + l.lo[0] + nx * (y + ny * z)] = label[c];
                }
            }
        }
        Ok(Volume::from_vec(grid, out)?)
    }

    fn sides(
        &mut self,
        net: &ControlNet<Real>,
        tumour_points: &[Vec3],
    ) -> Result<Sides, VolumetryError> {
        if tumour_points.is_empty() {
            return Err(VolumetryError::NoTumourPoints);
        }
        if let Some(k) = tumour_points
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(VolumetryError::NonFinitePoint(k));
        }
        let samples = Samples::new(net, &self.liver)?;
        let sigma = samples.tumour_side(tumour_points);
        let vox = self.liver.grid().voxel_volume_mm3();
        let band = self.splat(&samples, sigma);
        let samples_dims = [samples.ru, samples.rv];
        let edge = samples.edge_inside(&self.liver);
        if band.is_empty() {
            return Ok(Sides {
                result: CutResult {
                    resected_mm3: 0.0,
                    complete: false,
                    incomplete: Some(IncompleteCut::MissesLiver),
                    band_voxels: 0,
                    samples: samples_dims,
                },
                band,
                resected_runs: Vec::new(),
            });
        }
        let comps = Components::new(&self.liver, &self.stamp, self.epoch);
        let (resected_runs, leak) = comps.classify(self, &band, &samples, sigma);
        let band_sum: Real = band.iter().map(|&(_, f)| Real::from(f)).sum();
        let run_sum: usize = resected_runs.iter().map(|&(a, b)| (b - a) as usize).sum();
        let incomplete = if let Some(p) = edge {
            Some(IncompleteCut::EdgeInsideLiver {
                point: [p.x, p.y, p.z],
            })
        } else if leak {
            Some(IncompleteCut::Leak)
        } else {
            None
        };
        Ok(Sides {
            result: CutResult {
                resected_mm3: (band_sum + run_sum as Real) * vox,
                complete: incomplete.is_none(),
                incomplete,
                band_voxels: band.len(),
                samples: samples_dims,
            },
            band,
            resected_runs,
        })
    }

    /// Marks the band: every liver voxel in a sample's slab-disc — within `hs` of its tangent
    /// plane and `ρ` of it laterally — keeps the nearest such sample's offset and extent.
    /// Returns the band voxels with their tumour-side fractions.
    ///
    /// `hs` exceeds both half the largest voxel extent (so two face neighbours never lie outside
    /// the band on opposite sides: the barrier is watertight) and the longest voxel edge (so a
    /// band voxel's non-band neighbours lie on its own side: the side flags are right).
    fn splat(&mut self, s: &Samples, sigma: Real) -> Vec<(u32, f32)> {
        self.epoch = self.epoch.wrapping_add(1);
        if self.epoch == 0 {
            self.stamp.fill(0);
            self.epoch = 1;
        }
        let epoch = self.epoch;
        let l = &self.liver;
        let lin = l.grid().linear();
        let edges = [0, 1, 2].map(|a| lin.column(a).into_owned());
        let w_max = edges.iter().map(|e| e.norm()).sum::<Real>();
        let a_max = edges.iter().map(|e| e.norm()).fold(0.0, Real::max);
        let min_sp = l
            .grid()
            .spacing()
            .iter()
            .copied()
            .fold(Real::INFINITY, Real::min);
        let hs = (0.5 * w_max).max(a_max) + 0.05 * min_sp;
        // Lateral radius: every point of the surface lies within δ/√2 of a grid sample.
        let rho = 0.75 * s.delta;
        let inv = l.to_index;
        let inv_rows = [0, 1, 2].map(|a| inv.row(a).norm());
        let bd = l.bdims();
        let mut touched = Vec::new();
        for (p, n) in s.points.iter().zip(&s.normals) {
            let g = l.to_box(p);
            let w = edges.iter().map(|e| n.dot(e).abs()).sum::<Real>();
            // Offsets in index steps: s(Δg) = n_idx·Δg; iterate the two outer axes over the
            // slab-disc's extent and solve |s| ≤ hs for the axis along which s changes fastest.
            let n_idx = lin.transpose() * n;
            let n_inv = inv * n;
            let m = n_idx.iamax();
            if n_idx[m].abs() < 1e-12 {
                continue;
            }
            let (o1, o2) = ((m + 1) % 3, (m + 2) % 3);
            let range = |o: usize| {
                let e = hs * n_inv[o].abs() + rho * inv_rows[o];
                let lo = ((g[o] - e).ceil() as i64).max(0);
                let hi = ((g[o] + e).floor() as i64).min(bd[o] as i64 - 1);
                lo..=hi
            };
            for a in range(o1) {
                for b in range(o2) {
                    let rest = n_idx[o1] * (a as Real - g[o1]) + n_idx[o2] * (b as Real - g[o2]);
                    let (t0, t1) = ((-hs - rest) / n_idx[m], (hs - rest) / n_idx[m]);
                    let lo = ((t0.min(t1) + g[m]).ceil() as i64).max(0);
                    let hi = ((t0.max(t1) + g[m]).floor() as i64).min(bd[m] as i64 - 1);
                    for c in lo..=hi {
                        let mut ijk = [0usize; 3];
                        ijk[m] = c as usize;
                        ijk[o1] = a as usize;
                        ijk[o2] = b as usize;
                        let v = l.index[ijk[0] + bd[0] * (ijk[1] + bd[1] * ijk[2])];
                        if v == u32::MAX {
                            continue;
                        }
                        let d = l.centre(ijk) - p;
                        let off = n.dot(&d);
                        let d2 = d.norm_squared();
                        if d2 - off * off > rho * rho {
                            continue;
                        }
                        let vi = v as usize;
                        let d2f = d2 as f32;
                        if self.stamp[vi] != epoch {
                            self.stamp[vi] = epoch;
                            touched.push(v);
                        } else if d2f >= self.best_d2[vi] {
                            continue;
                        }
                        self.best_d2[vi] = d2f;
                        self.offset[vi] = (sigma * off) as f32;
                        self.extent[vi] = w as f32;
                    }
                }
            }
        }
        touched.sort_unstable();
        touched
            .into_iter()
            .map(|v| {
                let vi = v as usize;
                let f = (0.5 - self.offset[vi] / self.extent[vi].max(f32::MIN_POSITIVE))
                    .clamp(0.0, 1.0);
                (v, f)
            })
            .collect()
    }
}

/// Surface samples with unit normals.
struct Samples {
    ru: usize,
    rv: usize,
    points: Vec<Vec3>,
    normals: Vec<Vec3>,
    delta: Real,
}

impl Samples {
    fn new(net: &ControlNet<Real>, liver: &LiverVoxels) -> Result<Self, VolumetryError> {
        let spacing = liver.grid().spacing();
        let delta = spacing.iter().copied().fold(Real::INFINITY, Real::min);
        let (m, n) = net.dims();
        let p = |i: usize, j: usize| {
            let q = net.points()[i * n + j];
            Vec3::new(q[0], q[1], q[2])
        };
        // Control-polygon lengths bound the curve lengths along u and v.
        let lu = (0..n)
            .map(|j| (1..m).map(|i| (p(i, j) - p(i - 1, j)).norm()).sum::<Real>())
            .fold(0.0, Real::max);
        let lv = (0..m)
            .map(|i| (1..n).map(|j| (p(i, j) - p(i, j - 1)).norm()).sum::<Real>())
            .fold(0.0, Real::max);
        let count = |l: Real| ((l / delta).ceil() as usize + 1).clamp(2, MAX_SAMPLES_PER_AXIS);
        let (ru, rv) = (count(lu), count(lv));
        // The achieved spacing (may exceed the voxel size when clamped).
        let delta = (lu / (ru - 1) as Real)
            .max(lv / (rv - 1) as Real)
            .max(delta);
        let mut e = MleEvaluator::new(net.clone(), Resolution::new(ru, rv)?);
        let g = e.evaluate(Outputs::Normals);
        let v3 = |q: &[Real; 3]| Vec3::new(q[0], q[1], q[2]);
        let points = g.points().iter().map(v3).collect();
        let normals = g.normals().unwrap_or_default().iter().map(v3).collect();
        Ok(Self {
            ru,
            rv,
            points,
            normals,
            delta,
        })
    }

    fn nearest(&self, q: &Vec3) -> usize {
        self.points
            .par_iter()
            .enumerate()
            .map(|(k, p)| ((p - q).norm_squared(), k))
            .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)))
            .map_or(0, |(_, k)| k)
    }

    /// Signed side of `q` relative to its nearest sample's tangent plane (+1 or −1).
    fn side(&self, q: &Vec3) -> Real {
        let k = self.nearest(q);
        if self.normals[k].dot(&(q - self.points[k])) >= 0.0 {
            1.0
        } else {
            -1.0
        }
    }

    /// σ such that σ·(n·(x − S)) < 0 on the tumour side: the majority side of the tumour points
    /// (ties: the first point's).
    fn tumour_side(&self, tumour_points: &[Vec3]) -> Real {
        let sides: Vec<Real> = tumour_points.iter().map(|t| self.side(t)).collect();
        let sum: Real = sides.iter().sum();
        let side = if sum == 0.0 { sides[0] } else { sum.signum() };
        -side
    }

    /// A boundary sample lying in a liver voxel, if any.
    fn edge_inside(&self, liver: &LiverVoxels) -> Option<Vec3> {
        let (ru, rv) = (self.ru, self.rv);
        let border = (0..ru * rv).filter(|&k| {
            let (a, b) = (k / rv, k % rv);
            a == 0 || b == 0 || a == ru - 1 || b == rv - 1
        });
        border.map(|k| self.points[k]).find(|p| liver.contains(p))
    }
}

/// Liver voxels outside the band, as sub-runs joined by union–find.
struct Components {
    /// Sub-runs (compact start, compact end) per bounding-box row.
    row_start: Vec<u32>,
    subs: Vec<(u32, u32, u32)>, // (x0, x1, compact offset)
    parent: Vec<u32>,
}

impl Components {
    fn new(l: &LiverVoxels, stamp: &[u32], epoch: u32) -> Self {
        let mut row_start = Vec::with_capacity(l.row_start.len());
        let mut subs = Vec::new();
        for w in l.row_start.windows(2) {
            row_start.push(subs.len() as u32);
            for r in &l.runs[w[0] as usize..w[1] as usize] {
                let mut x = r.x0;
                while x < r.x1 {
                    let c = r.offset + (x - r.x0);
                    if stamp[c as usize] == epoch {
                        x += 1;
                        continue;
                    }
                    let x0 = x;
                    while x < r.x1 && stamp[(r.offset + (x - r.x0)) as usize] != epoch {
                        x += 1;
                    }
                    subs.push((x0, x, r.offset + (x0 - r.x0)));
                }
            }
        }
        row_start.push(subs.len() as u32);
        let mut c = Self {
            parent: (0..subs.len() as u32).collect(),
            row_start,
            subs,
        };
        let [_, by, bz] = l.bdims();
        for z in 0..bz {
            for y in 0..by {
                let row = y + by * z;
                if y + 1 < by {
                    c.join_rows(row, row + 1);
                }
                if z + 1 < bz {
                    c.join_rows(row, row + by);
                }
            }
        }
        c
    }

    fn find(&mut self, mut a: u32) -> u32 {
        while self.parent[a as usize] != a {
            let p = self.parent[a as usize];
            self.parent[a as usize] = self.parent[p as usize];
            a = p;
        }
        a
    }

    fn union(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
            self.parent[hi as usize] = lo;
        }
    }

    fn join_rows(&mut self, r1: usize, r2: usize) {
        let (mut i, e1) = (self.row_start[r1], self.row_start[r1 + 1]);
        let (mut j, e2) = (self.row_start[r2], self.row_start[r2 + 1]);
        while i < e1 && j < e2 {
            let (a0, a1, _) = self.subs[i as usize];
            let (b0, b1, _) = self.subs[j as usize];
            if a0 < b1 && b0 < a1 {
                self.union(i, j);
            }
            if a1 <= b1 {
                i += 1;
            } else {
                j += 1;
            }
        }
    }

    /// The sub-run holding bounding-box voxel (x, row), if any.
    fn sub_at(&self, x: u32, row: usize) -> Option<u32> {
        let (s, e) = (
            self.row_start[row] as usize,
            self.row_start[row + 1] as usize,
        );
        let subs = &self.subs[s..e];
        let k = subs.partition_point(|&(_, x1, _)| x1 <= x);
        subs.get(k)
            .filter(|&&(x0, _, _)| x0 <= x)
            .map(|_| (s + k) as u32)
    }

    /// Resected compact ranges and whether some component touches both sides.
    fn classify(
        mut self,
        vol: &Volumetry,
        band: &[(u32, f32)],
        samples: &Samples,
        sigma: Real,
    ) -> (Vec<(u32, u32)>, bool) {
        let l = &vol.liver;
        let [bx, by, bz] = l.bdims();
        // Compact index → (x, row) for band voxels: walk runs once.
        let mut flags = vec![0u8; self.subs.len()]; // bit 0: tumour side, bit 1: other side
        let mut bi = 0;
        for (row, w) in l.row_start.windows(2).enumerate() {
            if bi >= band.len() {
                break;
            }
            for r in &l.runs[w[0] as usize..w[1] as usize] {
                while bi < band.len() && band[bi].0 < r.offset + (r.x1 - r.x0) {
                    let v = band[bi].0;
                    bi += 1;
                    if v < r.offset {
                        continue;
                    }
                    let x = r.x0 + (v - r.offset);
                    let bit = if vol.offset[v as usize] < 0.0 {
                        1u8
                    } else {
                        2u8
                    };
                    let (y, z) = (row % by, row / by);
                    let mut touch = |xx: i64, rr: Option<usize>| {
                        if let Some(rr) = rr
                            && xx >= 0
                            && (xx as usize) < bx
                            && let Some(s) = self.sub_at(xx as u32, rr)
                        {
                            let root = self.find(s);
                            flags[root as usize] |= bit;
                        }
                    };
                    touch(i64::from(x) - 1, Some(row));
                    touch(i64::from(x) + 1, Some(row));
                    touch(i64::from(x), (y > 0).then(|| row - 1));
                    touch(i64::from(x), (y + 1 < by).then_some(row + 1));
                    touch(i64::from(x), (z > 0).then(|| row - by));
                    touch(i64::from(x), (z + 1 < bz).then_some(row + by));
                }
            }
        }
        let mut leak = false;
        let mut side_of_root = vec![0u8; self.subs.len()];
        for k in 0..self.subs.len() as u32 {
            let root = self.find(k) as usize;
            if flags[root] == 3 {
                leak = true;
            }
            if flags[root] == 0 {
                // An island away from the cut: the side of its first voxel.
                let (x0, _, _) = self.subs[root];
                let row = self.row_of(root);
                let c = l.centre([x0 as usize, row % by, row / by]);
                flags[root] = if sigma * samples.side(&c) < 0.0 { 1 } else { 2 };
            }
            side_of_root[k as usize] = flags[root];
        }
        let resected = self
            .subs
            .iter()
            .zip(&side_of_root)
            .filter(|(_, f)| **f & 1 == 1 && **f != 3)
            .map(|(&(x0, x1, off), _)| (off, off + (x1 - x0)))
            .collect();
        (resected, leak)
    }

    fn row_of(&self, sub: usize) -> usize {
        self.row_start.partition_point(|&s| s as usize <= sub) - 1
    }
}
