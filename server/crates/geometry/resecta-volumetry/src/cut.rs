//! Volumes on either side of a cut surface (any [`CutSurface`]: Bézier, drawn on slices,
//! deformable cutting plane).
//!
//! 1. The surface is sampled with spacing δ ≤ the smallest voxel spacing (points and unit
//!    normals): per direction ⌈speed/δ⌉ + 1 samples from the surface's bound on its parametric
//!    speed ([`CutSurface::speeds`]), so neighbouring samples are at most δ apart everywhere,
//!    however unevenly the surface is parametrised.
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
use resecta_geom::{CutSurface, Mat3, Real, Vec3, Volume};
use serde::Serialize;

use crate::accel::{
    AcceleratorError, BandComponents, BandQuery, CutAccelerator, SlabDisc, cell_coords, mask_ranges,
};
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
    accelerator: Option<Box<dyn CutAccelerator>>,
    fallbacks: usize,
    last_error: Option<AcceleratorError>,
}

/// The band (sorted compact indices and tumour-side fractions), the resected compact ranges,
/// and whether a component reaches both sides.
type SidesParts = (Vec<(u32, f32)>, Vec<(u32, u32)>, bool);

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
            accelerator: None,
            fallbacks: 0,
            last_error: None,
        }
    }

    /// With the band and components of every cut computed by `accelerator` (see
    /// [`crate::accel`]); a cut it fails is computed on the CPU.
    pub fn with_accelerator(mut self, accelerator: Box<dyn CutAccelerator>) -> Self {
        self.accelerator = Some(accelerator);
        self
    }

    /// Installs (or, with `None`, removes) the accelerator; returns the previous one.
    pub fn set_accelerator(
        &mut self,
        accelerator: Option<Box<dyn CutAccelerator>>,
    ) -> Option<Box<dyn CutAccelerator>> {
        std::mem::replace(&mut self.accelerator, accelerator)
    }

    /// Whether an accelerator is installed.
    pub fn is_accelerated(&self) -> bool {
        self.accelerator.is_some()
    }

    /// Cuts the accelerator failed and the CPU computed instead, and the last such failure.
    pub fn accelerator_fallbacks(&self) -> (usize, Option<&AcceleratorError>) {
        (self.fallbacks, self.last_error.as_ref())
    }

    pub fn liver(&self) -> &LiverVoxels {
        &self.liver
    }

    /// One resection; the resected side is the side holding `tumour_points`.
    pub fn cut(
        &mut self,
        surface: &dyn CutSurface,
        tumour_points: &[Vec3],
    ) -> Result<CutResult, VolumetryError> {
        Ok(self.sides(surface, tumour_points)?.result)
    }

    /// Several resections: each one's result, their union and the remnant.
    pub fn cuts(
        &mut self,
        cuts: &[(&dyn CutSurface, &[Vec3])],
    ) -> Result<MultiCut, VolumetryError> {
        Ok(self.cuts_inner(cuts, cuts.len() > 1)?.0)
    }

    /// [`Volumetry::cuts`] and the resected fraction (0..=1, the union over the cuts) of every
    /// liver voxel in compact order ([`LiverVoxels::offsets`]).
    pub fn cuts_with_fractions(
        &mut self,
        cuts: &[(&dyn CutSurface, &[Vec3])],
    ) -> Result<(MultiCut, Vec<f32>), VolumetryError> {
        self.cuts_inner(cuts, true)
    }

    fn cuts_inner(
        &mut self,
        cuts: &[(&dyn CutSurface, &[Vec3])],
        union_wanted: bool,
    ) -> Result<(MultiCut, Vec<f32>), VolumetryError> {
        let n = self.liver.len();
        let vox = self.liver.grid().voxel_volume_mm3();
        let mut union = vec![0f32; if union_wanted { n } else { 0 }];
        let mut results = Vec::with_capacity(cuts.len());
        for &(surface, pts) in cuts {
            let s = self.sides(surface, pts)?;
            if union_wanted {
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
        let multi = MultiCut {
            complete: results.iter().all(|r| r.complete),
            cuts: results,
            total_mm3: total,
            resected_mm3: resected,
            remnant_mm3: total - resected,
        };
        Ok((multi, union))
    }

    /// Label map on the liver grid: 0 not liver, 1 remnant, 2 + i resected by cut i (voxel
    /// fraction ≥ ½; the first cut wins where they overlap).
    pub fn resected_labels(
        &mut self,
        cuts: &[(&dyn CutSurface, &[Vec3])],
    ) -> Result<Volume<u8>, VolumetryError> {
        let n = self.liver.len();
        let mut label = vec![1u8; n];
        for (i, &(surface, pts)) in cuts.iter().enumerate().rev() {
            let tag = u8::try_from(i + 2).unwrap_or(u8::MAX);
            let s = self.sides(surface, pts)?;
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
        let mut out = vec![0u8; grid.len()];
        for (c, o) in self.liver.offsets().into_iter().enumerate() {
            out[o] = label[c];
        }
        Ok(Volume::from_vec(grid, out)?)
    }

    fn sides(
        &mut self,
        surface: &dyn CutSurface,
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
        let samples = Samples::new(surface, &self.liver);
        let sigma = samples.tumour_side(tumour_points);
        let vox = self.liver.grid().voxel_volume_mm3();
        let query = BandGeometry::new(&self.liver, &samples);
        let (band, resected_runs, leak) = match self.accelerated(&query, &samples, sigma) {
            Some(parts) => parts,
            None => self.cpu_sides(&query, &samples, sigma),
        };
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

    /// Step 2 and 3 on the CPU.
    fn cpu_sides(&mut self, q: &BandGeometry, samples: &Samples, sigma: Real) -> SidesParts {
        let band = self.splat(q, samples, sigma);
        if band.is_empty() {
            return (band, Vec::new(), false);
        }
        let comps = Components::new(&self.liver, &self.stamp, self.epoch);
        let (runs, leak) = comps.classify(self, &band, samples, sigma);
        (band, runs, leak)
    }

    /// Step 2 and 3 by the accelerator, if one is installed and the samples are finite; `None`
    /// (the CPU computes the cut) otherwise and when it fails (counted).
    fn accelerated(
        &mut self,
        q: &BandGeometry,
        samples: &Samples,
        sigma: Real,
    ) -> Option<SidesParts> {
        let finite = |v: &Vec3| v.iter().all(|c| c.is_finite());
        if !(samples.points.iter().all(finite) && samples.normals.iter().all(finite)) {
            return None;
        }
        let acc = self.accelerator.as_mut()?;
        let liver = &self.liver;
        let result = (|| {
            let discs = q.discs(liver, samples);
            let query = BandQuery {
                discs: &discs,
                hs: q.hs,
                rho: q.rho,
            };
            let bc = acc.band_components(liver, &query)?;
            let (band, sides) = accelerated_band(liver, &query, &bc, sigma)?;
            if band.is_empty() {
                return Ok((band, Vec::new(), false));
            }
            let (roots, leak) = resected_roots(liver, &bc, &sides, samples, sigma)?;
            let mask = if roots.is_empty() {
                Vec::new()
            } else {
                acc.resected_mask(&roots)?
            };
            Ok((band, mask_ranges(&mask, liver.len()), leak))
        })();
        match result {
            Ok(parts) => Some(parts),
            Err(e) => {
                self.fallbacks += 1;
                self.last_error = Some(e);
                None
            }
        }
    }

    /// Marks the band: every liver voxel in a sample's slab-disc — within `hs` of its tangent
    /// plane and `ρ` of it laterally — keeps the nearest such sample's offset and extent.
    /// Returns the band voxels with their tumour-side fractions.
    fn splat(&mut self, q: &BandGeometry, s: &Samples, sigma: Real) -> Vec<(u32, f32)> {
        self.epoch = self.epoch.wrapping_add(1);
        if self.epoch == 0 {
            self.stamp.fill(0);
            self.epoch = 1;
        }
        let epoch = self.epoch;
        let l = &self.liver;
        let bd = l.bdims();
        let mut touched = Vec::new();
        for (p, n) in s.points.iter().zip(&s.normals) {
            let disc = q.disc(l, p, n);
            let (m, [o1, o2]) = (disc.axis, disc.outer_axes());
            let [[a0, a1], [b0, b1]] = disc.outer;
            for a in a0..=a1 {
                for b in b0..=b1 {
                    let (lo, hi) = disc.column(q.hs, a, b, bd[m]);
                    for c in lo..=hi {
                        let mut ijk = [0usize; 3];
                        ijk[m] = c as usize;
                        ijk[o1] = a as usize;
                        ijk[o2] = b as usize;
                        let v = l.index[ijk[0] + bd[0] * (ijk[1] + bd[1] * ijk[2])];
                        if v == u32::MAX {
                            continue;
                        }
                        let Some((d2f, off)) = disc.reach(&l.centre(ijk), q.rho) else {
                            continue;
                        };
                        let vi = v as usize;
                        if self.stamp[vi] != epoch {
                            self.stamp[vi] = epoch;
                            touched.push(v);
                        } else if d2f >= self.best_d2[vi] {
                            continue;
                        }
                        self.best_d2[vi] = d2f;
                        self.offset[vi] = (sigma * off) as f32;
                        self.extent[vi] = disc.extent as f32;
                    }
                }
            }
        }
        touched.sort_unstable();
        touched
            .into_iter()
            .map(|v| {
                let vi = v as usize;
                (v, fraction(self.offset[vi], self.extent[vi]))
            })
            .collect()
    }
}

/// A band voxel's tumour-side fraction from its signed offset and extent.
fn fraction(offset: f32, extent: f32) -> f32 {
    (0.5 - offset / extent.max(f32::MIN_POSITIVE)).clamp(0.0, 1.0)
}

/// The slab-discs of one cut's samples, made one at a time (the CPU walks each at once).
///
/// `hs` exceeds both half the largest voxel extent (so two face neighbours never lie outside
/// the band on opposite sides: the barrier is watertight) and the longest voxel edge (so a
/// band voxel's non-band neighbours lie on its own side: the side flags are right).
struct BandGeometry {
    hs: Real,
    rho: Real,
    lin: Mat3,
    edges: [Vec3; 3],
    inv_rows: [Real; 3],
}

impl BandGeometry {
    fn new(l: &LiverVoxels, s: &Samples) -> Self {
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
        let inv_rows = [0, 1, 2].map(|a| l.to_index.row(a).norm());
        Self {
            hs,
            rho,
            lin,
            edges,
            inv_rows,
        }
    }

    /// The slab-disc of the sample at `p` with normal `n`.
    fn disc(&self, l: &LiverVoxels, p: &Vec3, n: &Vec3) -> SlabDisc {
        let (hs, rho, bd) = (self.hs, self.rho, l.bdims());
        let g = l.to_box(p);
        let extent = self.edges.iter().map(|e| n.dot(e).abs()).sum::<Real>();
        // Offsets in index steps: s(Δg) = n_idx·Δg; the two outer axes span the slab-disc's
        // extent, |s| ≤ hs is solved along the axis where s changes fastest.
        let n_idx = self.lin.transpose() * n;
        let n_inv = l.to_index * n;
        let axis = n_idx.iamax();
        let range = |o: usize| {
            let e = hs * n_inv[o].abs() + rho * self.inv_rows[o];
            let lo = ((g[o] - e).ceil() as i64).max(0);
            let hi = ((g[o] + e).floor() as i64).min(bd[o] as i64 - 1);
            [lo, hi]
        };
        let outer = if n_idx[axis].abs() < 1e-12 {
            [[0, -1]; 2]
        } else {
            [range((axis + 1) % 3), range((axis + 2) % 3)]
        };
        SlabDisc {
            point: *p,
            normal: *n,
            g,
            n_idx,
            axis,
            outer,
            extent,
        }
    }

    /// Every sample's slab-disc, for an accelerator.
    fn discs(&self, l: &LiverVoxels, s: &Samples) -> Vec<SlabDisc> {
        s.points
            .iter()
            .zip(&s.normals)
            .map(|(p, n)| self.disc(l, p, n))
            .collect()
    }
}

fn bad(what: &str) -> AcceleratorError {
    AcceleratorError(format!("invalid accelerator output: {what}"))
}

/// Band voxels (sorted compact indices) and their tumour-side fractions.
type Band = Vec<(u32, f32)>;

/// A band voxel's signed offset and the component roots of its face neighbours.
type BandSide = (f32, [u32; 6]);

/// An accelerator's band as the CPU's (sorted compact indices and fractions, by the CPU's
/// formulas on the nearest samples it found), with each voxel's signed offset and neighbours.
fn accelerated_band(
    l: &LiverVoxels,
    q: &BandQuery<'_>,
    bc: &BandComponents,
    sigma: Real,
) -> Result<(Band, Vec<BandSide>), AcceleratorError> {
    let mut band = Vec::with_capacity(bc.band.len());
    for bv in &bc.band {
        let v = *l
            .index
            .get(bv.cell as usize)
            .ok_or_else(|| bad("band cell"))?;
        let disc = q
            .discs
            .get(bv.sample as usize)
            .ok_or_else(|| bad("sample"))?;
        if v == u32::MAX {
            return Err(bad("band voxel outside the liver"));
        }
        let ijk = cell_coords(l, bv.cell);
        let reach = disc.reach(&l.centre(ijk), q.rho);
        let (Some((_, off)), true) = (reach, disc.holds(q.hs, ijk, l.bdims())) else {
            return Err(bad("band voxel outside its sample's slab-disc"));
        };
        let offset = (sigma * off) as f32;
        band.push((
            v,
            fraction(offset, disc.extent as f32),
            offset,
            bv.neighbours,
        ));
    }
    band.sort_unstable_by_key(|b| b.0);
    if band.windows(2).any(|w| w[0].0 == w[1].0) {
        return Err(bad("duplicate band voxel"));
    }
    Ok(band
        .into_iter()
        .map(|(v, f, o, n)| ((v, f), (o, n)))
        .unzip())
}

/// The side flags of a component no band voxel touches (an island away from the cut): the side
/// of `first`, its first voxel's centre, relative to the nearest sample's tangent plane.
fn island_flags(samples: &Samples, sigma: Real, first: &Vec3) -> u8 {
    if sigma * samples.side(first) < 0.0 {
        1
    } else {
        2
    }
}

/// The roots of the resected components of an accelerated cut, and whether a component
/// reaches both sides (as [`Components::classify`]).
fn resected_roots(
    l: &LiverVoxels,
    bc: &BandComponents,
    sides: &[BandSide],
    samples: &Samples,
    sigma: Real,
) -> Result<(Vec<u32>, bool), AcceleratorError> {
    let mut roots = bc.roots.clone();
    roots.sort_unstable();
    if roots.windows(2).any(|w| w[0] == w[1]) {
        return Err(bad("duplicate root"));
    }
    let mut flags = vec![0u8; roots.len()];
    for (offset, neighbours) in sides {
        let bit = if *offset < 0.0 { 1u8 } else { 2u8 };
        for &r in neighbours.iter().filter(|&&r| r != u32::MAX) {
            let k = roots.binary_search(&r).map_err(|_| bad("unknown root"))?;
            flags[k] |= bit;
        }
    }
    let mut leak = false;
    for (f, &r) in flags.iter_mut().zip(&roots) {
        leak |= *f == 3;
        if *f == 0 {
            let b = l.box_of(r).ok_or_else(|| bad("root"))?;
            *f = island_flags(samples, sigma, &l.centre(b));
        }
    }
    let resected = roots
        .iter()
        .zip(&flags)
        .filter(|(_, f)| **f == 1)
        .map(|(r, _)| *r)
        .collect();
    Ok((resected, leak))
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
    fn new(surface: &dyn CutSurface, liver: &LiverVoxels) -> Self {
        let spacing = liver.grid().spacing();
        let delta = spacing.iter().copied().fold(Real::INFINITY, Real::min);
        let [su, sv] = surface.speeds();
        let count = |s: Real| ((s / delta).ceil() as usize + 1).clamp(2, MAX_SAMPLES_PER_AXIS);
        let (ru, rv) = (count(su), count(sv));
        // The achieved spacing bound (may exceed the voxel size when clamped).
        let delta = (su / (ru - 1) as Real)
            .max(sv / (rv - 1) as Real)
            .max(delta);
        let (mut points, mut normals) = (Vec::new(), Vec::new());
        surface.sample(ru, rv, &mut points, &mut normals);
        Self {
            ru,
            rv,
            points,
            normals,
            delta,
        }
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
                flags[root] = island_flags(samples, sigma, &c);
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
