//! Risk analysis of a resection: the vessels it cuts, and the remnant that loses its portal
//! supply (devascularised) or its hepatic drainage (congested).
//!
//! A vessel is cut where its centreline crosses a resection surface inside the liver. Flow
//! runs away from the root in a portal tree and towards it in a hepatic one; either way the
//! part of the tree beyond a cut (farther from the root along the centreline) is disconnected.
//! Each liver voxel is served by its nearest centreline point of each system (the Voronoi
//! diagram of [`crate::territories`], kept per voxel once); a remnant voxel whose nearest portal
//! point is disconnected is devascularised, whose nearest hepatic point is disconnected is
//! congested. The functional remnant is the remnant that is neither.

use rayon::prelude::*;
use resecta_geom::{Grid, MeshBvh, NO_FEATURE, Ray, Vec3};

use crate::error::VesselError;
use crate::graph::VesselTree;
use crate::territory::{nearest_features, rasterise, sample_step};

/// Which vascular system a tree belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum VesselSystem {
    /// Portal veins: supply, flowing from the hilum outwards.
    Portal,
    /// Hepatic veins: drainage, flowing towards the vena cava.
    Hepatic,
}

impl VesselSystem {
    pub fn name(self) -> &'static str {
        match self {
            VesselSystem::Portal => "portal",
            VesselSystem::Hepatic => "hepatic",
        }
    }

    /// How its trees are rooted: the portal vein at its trunk (the widest end), the hepatic
    /// veins at each of their ostia (one tree per component).
    pub fn root_choice(self) -> crate::graph::RootChoice {
        match self {
            VesselSystem::Portal => crate::graph::RootChoice::Auto,
            VesselSystem::Hepatic => crate::graph::RootChoice::EveryComponent,
        }
    }
}

/// One system's tree and the nearest centreline point of every liver voxel.
#[derive(Debug, Clone)]
struct SystemModel {
    system: VesselSystem,
    tree: VesselTree,
    /// Rasterised centreline points: (edge, arc length in mm along it).
    features: Vec<(u32, f32)>,
    /// Per liver voxel (the caller's order): its nearest feature.
    nearest: Vec<u32>,
}

/// The vessel trees of a liver, ready to assess cuts (built once per patient).
#[derive(Debug, Clone)]
pub struct RiskModel {
    systems: Vec<SystemModel>,
    grid: Grid,
    /// Grid offsets of the liver voxels, ascending (u32: the EDT's nearest features are u32
    /// offsets too, so grids are smaller).
    liver: Vec<u32>,
}

/// Where a resection surface cuts a vessel (the crossing nearest the root on its edge).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Crossing {
    pub system: VesselSystem,
    pub edge: usize,
    /// Arc length along the edge from its proximal node, mm.
    pub arc_mm: f64,
    /// RAS mm.
    pub point: Vec3,
    /// Vessel radius at the crossing, mm (of the nearest centreline point).
    pub radius_mm: f64,
    /// Which cut surface ([`RiskModel::crossings`]' order) and where on it (its triangle and
    /// barycentric weights).
    pub surface: usize,
    pub triangle: usize,
    pub barycentric: [f64; 3],
}

/// The liver voxels a set of cuts puts at risk (per liver voxel; `None` without a tree of
/// that system).
#[derive(Debug, Clone, PartialEq)]
pub struct RiskRegions {
    pub cut: Vec<CutBranch>,
    pub devascularised: Option<Vec<bool>>,
    pub congested: Option<Vec<bool>>,
}

/// A cut vessel branch of [`RiskAssessment`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CutBranch {
    pub crossing: Crossing,
    pub generation: u32,
    /// Already disconnected by a cut nearer the root.
    pub downstream_of_another_cut: bool,
}

/// Volumes at risk after a set of cuts, mm³ (remnant voxels weighted by their remnant
/// fraction).
#[derive(Debug, Clone, PartialEq)]
pub struct RiskAssessment {
    pub remnant_mm3: f64,
    /// Remnant whose nearest portal centreline point is disconnected.
    pub devascularised_mm3: f64,
    /// Remnant whose nearest hepatic centreline point is disconnected.
    pub congested_mm3: f64,
    /// Remnant that is devascularised or congested (or both).
    pub at_risk_mm3: f64,
    /// Remnant that is neither.
    pub functional_remnant_mm3: f64,
    /// Every cut branch (its crossing nearest the root), largest radius first.
    pub cut: Vec<CutBranch>,
    /// Whether the model has a tree of each system: a volume of a system without one is 0.
    pub has_portal: bool,
    pub has_hepatic: bool,
}

impl RiskModel {
    /// The model of `trees` (each on `grid`) for the liver voxels at the grid offsets
    /// `liver`, ascending (the order [`RiskModel::assess`]'s remnant fractions come in).
    /// Centrelines are sampled every `sample_mm` (`None`: half the smallest spacing).
    pub fn new(
        grid: &Grid,
        liver: &[usize],
        trees: Vec<(VesselSystem, VesselTree)>,
        sample_mm: Option<f64>,
    ) -> Result<Self, VesselError> {
        if liver.is_empty() {
            return Err(VesselError::EmptyLiver);
        }
        if liver.iter().any(|&o| o >= grid.len()) {
            return Err(VesselError::GridMismatch);
        }
        if liver.windows(2).any(|w| w[0] >= w[1]) {
            return Err(VesselError::InvalidParameter {
                name: "liver voxel offsets",
                reason: "must be strictly ascending",
            });
        }
        let step = sample_step(grid, sample_mm)?;
        let mut systems = Vec::with_capacity(trees.len());
        for (system, tree) in trees {
            if tree.grid != *grid {
                return Err(VesselError::GridMismatch);
            }
            let hits = rasterise(&tree, step);
            if hits.is_empty() {
                return Err(VesselError::NoCentreline);
            }
            let mut index = std::collections::HashMap::with_capacity(hits.len());
            let mut features = Vec::with_capacity(hits.len());
            let mut offsets: Vec<(&usize, _)> = hits.iter().collect();
            offsets.sort_unstable_by_key(|(o, _)| **o);
            for (&o, h) in offsets {
                index.insert(o, features.len() as u32);
                features.push((h.edge as u32, h.arc_mm as f32));
            }
            let nearest = nearest_features(grid, hits.keys().copied(), liver)?
                .into_iter()
                .map(|f| f.and_then(|f| index.get(&f).copied()).unwrap_or(NO_FEATURE))
                .collect();
            systems.push(SystemModel {
                system,
                tree,
                features,
                nearest,
            });
        }
        Ok(Self {
            systems,
            grid: grid.clone(),
            liver: liver
                .iter()
                .map(|&o| {
                    u32::try_from(o).map_err(|_| VesselError::InvalidParameter {
                        name: "liver voxel offsets",
                        reason: "must be below 2^32 (the grid is too large)",
                    })
                })
                .collect::<Result<_, _>>()?,
        })
    }

    /// The trees, with their system.
    pub fn trees(&self) -> impl Iterator<Item = (VesselSystem, &VesselTree)> {
        self.systems.iter().map(|s| (s.system, &s.tree))
    }

    /// Per liver voxel (the order given to [`RiskModel::new`]): 1 + the branch of generation
    /// at most `generation` above its nearest centreline point of `system` (0 without one).
    pub fn voxel_territories(&self, system: VesselSystem, generation: u32) -> Option<Vec<u32>> {
        let s = self.systems.iter().find(|s| s.system == system)?;
        let edges = &s.tree.edges;
        let head: Vec<u32> = edges
            .iter()
            .map(|e| {
                let mut k = e.id;
                while let Some(p) = edges[k].parent.filter(|_| edges[k].generation > generation) {
                    k = p;
                }
                k as u32 + 1
            })
            .collect();
        Some(
            s.nearest
                .iter()
                .map(|&f| {
                    s.features
                        .get(f as usize)
                        .map_or(0, |&(e, _)| head[e as usize])
                })
                .collect(),
        )
    }

    /// The territory holding `p`: the branch of generation at most `generation` above the
    /// nearest centreline point of `system` to the liver voxel holding `p` (`None` outside the
    /// liver or without a tree of `system`).
    pub fn territory_at(&self, system: VesselSystem, p: &Vec3, generation: u32) -> Option<usize> {
        let c = self.grid.world_to_index(*p).map(f64::round);
        let dims = self.grid.dims();
        if c.iter()
            .zip(dims)
            .any(|(&x, d)| !(x >= 0.0 && x < d as f64))
        {
            return None;
        }
        let o = self
            .grid
            .offset([c[0] as usize, c[1] as usize, c[2] as usize]);
        let i = self.liver.binary_search(&u32::try_from(o).ok()?).ok()?;
        self.systems
            .iter()
            .filter(|s| s.system == system)
            .find_map(|s| {
                let &(mut e, _) = s.features.get(*s.nearest.get(i)? as usize)?;
                let edges = &s.tree.edges;
                while let Some(p) = edges[e as usize]
                    .parent
                    .filter(|_| edges[e as usize].generation > generation)
                {
                    e = p as u32;
                }
                Some(e as usize)
            })
    }

    /// The crossings of every edge's centreline with the surfaces (their triangles in `bvhs`)
    /// that `inside` accepts (in the liver); per edge and surface the one nearest the root.
    pub fn crossings(
        &self,
        bvhs: &[&MeshBvh],
        inside: &(dyn Fn(&Crossing) -> bool + Sync),
    ) -> Vec<Crossing> {
        let work: Vec<(&SystemModel, &crate::graph::Edge, usize)> = self
            .systems
            .iter()
            .flat_map(|s| {
                s.tree
                    .edges
                    .iter()
                    .flat_map(move |e| (0..bvhs.len()).map(move |k| (s, e, k)))
            })
            .collect();
        work.par_iter()
            .filter_map(|&(s, e, k)| {
                first_crossing(e, bvhs[k], &|c: Crossing| {
                    let c = Crossing {
                        system: s.system,
                        surface: k,
                        ..c
                    };
                    inside(&c).then_some(c)
                })
            })
            .collect()
    }

    /// Per edge of `s`'s tree: the arc length of its cut nearest the root (∞ uncut), the
    /// crossing there, and whether an ancestor is cut.
    fn cuts<'a>(
        s: &SystemModel,
        crossings: &'a [Crossing],
    ) -> (Vec<f64>, Vec<Option<&'a Crossing>>, Vec<bool>) {
        let edges = &s.tree.edges;
        let mut cut_at = vec![f64::INFINITY; edges.len()];
        let mut first: Vec<Option<&Crossing>> = vec![None; edges.len()];
        for c in crossings.iter().filter(|c| c.system == s.system) {
            if let Some(a) = cut_at.get_mut(c.edge)
                && c.arc_mm < *a
            {
                *a = c.arc_mm;
                first[c.edge] = Some(c);
            }
        }
        // Parents come first.
        let mut cut_above = vec![false; edges.len()];
        for e in edges {
            if let Some(p) = e.parent {
                cut_above[e.id] = cut_above[p] || cut_at[p].is_finite();
            }
        }
        (cut_at, first, cut_above)
    }

    /// The branches the cuts `crossings` cut (their crossing nearest the root), largest radius
    /// first.
    pub fn cut_branches(&self, crossings: &[Crossing]) -> Vec<CutBranch> {
        let mut cut = Vec::new();
        for s in &self.systems {
            let (_, first, cut_above) = Self::cuts(s, crossings);
            for e in &s.tree.edges {
                if let Some(c) = first[e.id] {
                    cut.push(CutBranch {
                        crossing: *c,
                        generation: e.generation,
                        downstream_of_another_cut: cut_above[e.id],
                    });
                }
            }
        }
        cut.sort_by(|a, b| {
            b.crossing
                .radius_mm
                .total_cmp(&a.crossing.radius_mm)
                .then(a.crossing.system.cmp(&b.crossing.system))
                .then(a.crossing.edge.cmp(&b.crossing.edge))
        });
        cut
    }

    /// The liver voxels (the order given to [`RiskModel::new`]) that lose their supply or
    /// drainage by the cuts `crossings`, and the cut branches.
    pub fn regions(&self, crossings: &[Crossing]) -> RiskRegions {
        let mut lost: [Option<Vec<bool>>; 2] = [None, None];
        for s in &self.systems {
            let (cut_at, _, cut_above) = Self::cuts(s, crossings);
            let disconnected: Vec<bool> = s
                .features
                .iter()
                .map(|&(e, arc)| {
                    let e = e as usize;
                    cut_above[e] || f64::from(arc) > cut_at[e]
                })
                .collect();
            let per_voxel: Vec<bool> = s
                .nearest
                .par_iter()
                .map(|&f| disconnected.get(f as usize).copied().unwrap_or(false))
                .collect();
            let slot = &mut lost[usize::from(s.system == VesselSystem::Hepatic)];
            match slot {
                Some(v) => v.iter_mut().zip(per_voxel).for_each(|(a, b)| *a |= b),
                None => *slot = Some(per_voxel),
            }
        }
        let [devascularised, congested] = lost;
        RiskRegions {
            cut: self.cut_branches(crossings),
            devascularised,
            congested,
        }
    }

    /// Volumes at risk after the cuts `crossings`, for the remnant fraction (0..=1) of every
    /// liver voxel (the order given to [`RiskModel::new`]).
    pub fn assess(
        &self,
        crossings: &[Crossing],
        remnant: &[f32],
    ) -> Result<RiskAssessment, VesselError> {
        if remnant.len() != self.liver.len() {
            return Err(VesselError::InvalidParameter {
                name: "remnant fractions",
                reason: "must have one value per liver voxel of the model",
            });
        }
        let RiskRegions {
            cut,
            devascularised,
            congested,
        } = self.regions(crossings);
        let lost = [devascularised, congested];
        let (mut rem, mut dev, mut con, mut risk) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for (i, &f) in remnant.iter().enumerate() {
            let f = f64::from(f.clamp(0.0, 1.0));
            if f == 0.0 {
                continue;
            }
            rem += f;
            let d = lost[0].as_ref().is_some_and(|v| v[i]);
            let c = lost[1].as_ref().is_some_and(|v| v[i]);
            if d {
                dev += f;
            }
            if c {
                con += f;
            }
            if d || c {
                risk += f;
            }
        }
        let v = self.grid.voxel_volume_mm3();
        Ok(RiskAssessment {
            remnant_mm3: rem * v,
            devascularised_mm3: dev * v,
            congested_mm3: con * v,
            at_risk_mm3: risk * v,
            functional_remnant_mm3: (rem - risk) * v,
            cut,
            has_portal: lost[0].is_some(),
            has_hepatic: lost[1].is_some(),
        })
    }
}

/// The crossing of an edge's centreline with a surface nearest the edge's proximal end that
/// `accept` keeps.
fn first_crossing(
    e: &crate::graph::Edge,
    bvh: &MeshBvh,
    accept: &dyn Fn(Crossing) -> Option<Crossing>,
) -> Option<Crossing> {
    let bounds = bvh.bounds()?;
    let mut arc = 0.0;
    for (i, w) in e.points.windows(2).enumerate() {
        let d = w[1] - w[0];
        let len = d.norm();
        let lo = w[0].inf(&w[1]);
        let hi = w[0].sup(&w[1]);
        let overlaps = (0..3).all(|k| lo[k] <= bounds.max[k] && hi[k] >= bounds.min[k]);
        if len > 0.0 && overlaps {
            let ray = Ray {
                origin: w[0],
                direction: d,
            };
            for h in bvh.ray_hits(&ray, 0.0, 1.0) {
                let r = if h.t < 0.5 {
                    e.radii[i]
                } else {
                    e.radii[i + 1]
                };
                let c = Crossing {
                    system: VesselSystem::Portal,
                    edge: e.id,
                    arc_mm: arc + h.t * len,
                    point: h.point,
                    radius_mm: r,
                    surface: 0,
                    triangle: h.triangle,
                    barycentric: h.barycentric,
                };
                if let Some(c) = accept(c) {
                    return Some(c);
                }
            }
        }
        arc += len;
    }
    None
}
