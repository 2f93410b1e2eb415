//! The patient's vessel trees and what a plan puts at risk: the vessels its resections cut and
//! the remnant that loses portal supply or hepatic drainage (`resecta-vessels`' risk model).

use std::sync::Arc;

use resecta_geom::{Grid, LabelMap, MeshBvh, Real, Role, RoleMap, TriMesh, Vec3, Volume};
use resecta_vessels::{
    Crossing, CutBranch, RiskAssessment, RiskModel, RiskRegions, VesselParams, VesselSystem,
    VesselTree, vessel_tree,
};
use serde::Serialize;

use crate::anatomy::Anatomy;
use crate::error::PlanError;

/// Territories drawn on a resectogram are the portal branches of this generation (with the
/// shorter vessels that end above it): the sectors and segments of a typical portal tree.
pub const TERRITORY_GENERATION: u32 = 2;

/// The vessel trees of an anatomy, built with it.
#[derive(Debug, Clone)]
pub enum Vascular {
    /// The roles name no portal or hepatic label, or the label map has none of their voxels.
    Absent,
    Ready(Arc<RiskModel>),
    /// The trees could not be built (e.g. every vessel component a speck); why.
    Failed(String),
}

impl Vascular {
    /// The trees of the portal (one trunk, the widest end) and hepatic (one root per component:
    /// the veins enter the vena cava by several ostia) labels of `roles`, for the liver voxels
    /// at the ascending grid offsets `liver`.
    pub fn build(labels: &LabelMap, roles: &RoleMap, liver: &[usize]) -> Self {
        let systems = [
            (VesselSystem::Portal, Role::Portal),
            (VesselSystem::Hepatic, Role::Hepatic),
        ];
        let mut trees: Vec<(VesselSystem, VesselTree)> = Vec::new();
        for (system, role) in systems {
            let wanted = roles.labels(role);
            if wanted.is_empty() {
                continue;
            }
            let data: Vec<bool> = labels.data().iter().map(|l| wanted.contains(l)).collect();
            if !data.contains(&true) {
                continue;
            }
            let tree = Volume::from_vec(labels.grid().clone(), data)
                .map_err(resecta_vessels::VesselError::from)
                .and_then(|mask| {
                    vessel_tree(&mask, system.root_choice(), &VesselParams::default())
                });
            match tree {
                Ok(t) => trees.push((system, t)),
                Err(e) => return Self::Failed(format!("{} tree: {e}", system.name())),
            }
        }
        if trees.is_empty() {
            return Self::Absent;
        }
        match RiskModel::new(labels.grid(), liver, trees, None) {
            Ok(m) => Self::Ready(Arc::new(m)),
            Err(e) => Self::Failed(e.to_string()),
        }
    }

    pub fn model(&self) -> Option<&Arc<RiskModel>> {
        match self {
            Self::Ready(m) => Some(m),
            Self::Absent | Self::Failed(_) => None,
        }
    }
}

/// A vessel cut by a resection.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CutVessel {
    /// `"portal"` or `"hepatic"`.
    pub system: &'static str,
    pub resection: String,
    /// The branch (edge id of its tree) and its generation.
    pub branch: usize,
    pub generation: u32,
    pub radius_mm: Real,
    /// Where the centreline crosses the surface (RAS mm) and its (u, v) on the surface.
    pub point: [Real; 3],
    pub uv: [Real; 2],
    /// Already disconnected by a cut nearer the root.
    pub downstream_of_another_cut: bool,
}

/// What a plan puts at risk (ml, and the functional remnant as % of the functional liver).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RiskReport {
    pub devascularised_ml: Real,
    pub congested_ml: Real,
    pub at_risk_ml: Real,
    pub functional_remnant_ml: Real,
    pub functional_remnant_pct: Real,
    pub has_portal: bool,
    pub has_hepatic: bool,
    /// Largest radius first.
    pub cut_vessels: Vec<CutVessel>,
}

/// A resection's surface as the risk analysis needs it.
#[derive(Debug, Clone)]
pub struct CutMesh {
    pub name: String,
    pub mesh: TriMesh,
    /// Samples per direction: vertex `a·rv + b` sits at `(a/(ru−1), b/(rv−1))`.
    pub resolution: [usize; 2],
}

/// The crossings of every vessel with the surfaces inside the liver: where the surface around
/// the vessel (a ring of its radius plus `reach` mm in the triangle's plane) meets the liver
/// (`inside` > 0 at one of its 12 points, or at the centreline point). A vessel's lumen need not
/// be liver itself (large vessels leave the envelope at the hilum), the tissue cut around it is.
pub fn crossings(
    model: &RiskModel,
    surfaces: &[CutMesh],
    inside: &(dyn Fn(&Vec3) -> Real + Sync),
    reach: Real,
) -> Result<Vec<Crossing>, resecta_geom::GeomError> {
    let bvhs = surfaces
        .iter()
        .map(|s| MeshBvh::new(&s.mesh))
        .collect::<Result<Vec<_>, _>>()?;
    let refs: Vec<&MeshBvh> = bvhs.iter().collect();
    let in_liver = |c: &Crossing| -> bool {
        if inside(&c.point) > 0.0 {
            return true;
        }
        let Some(mesh) = surfaces.get(c.surface).map(|s| &s.mesh) else {
            return false;
        };
        let [a, b, d] = mesh.corners(c.triangle);
        let (t1, n) = ((b - a).normalize(), (b - a).cross(&(d - a)));
        if !(n.norm() > 0.0 && t1.iter().all(|x| x.is_finite())) {
            return false;
        }
        let t2 = n.normalize().cross(&t1);
        let r = c.radius_mm + reach;
        (0..12).any(|k| {
            let th = std::f64::consts::TAU * Real::from(k) / 12.0;
            inside(&(c.point + (t1 * th.cos() + t2 * th.sin()) * r)) > 0.0
        })
    };
    Ok(model.crossings(&refs, &in_liver))
}

/// The crossings of every vessel with `surfaces` inside `anatomy`'s liver (the ring reaching
/// one voxel, the largest spacing, beyond the vessel's radius).
pub fn liver_crossings(
    anatomy: &Anatomy,
    model: &RiskModel,
    surfaces: &[CutMesh],
) -> Result<Vec<Crossing>, PlanError> {
    let reach = anatomy
        .envelope()
        .grid()
        .spacing()
        .iter()
        .fold(0.0, |m: Real, &s| m.max(s));
    Ok(crossings(
        model,
        surfaces,
        &|p: &Vec3| anatomy.inside_level(p),
        reach,
    )?)
}

/// The cuts of `surfaces` in `anatomy`'s liver and what they put at risk, for the resected
/// fraction of every functional voxel (the model's order) of a liver of `total_mm3`.
pub fn assess(
    anatomy: &Anatomy,
    model: &RiskModel,
    surfaces: &[CutMesh],
    resected: &[f32],
    total_mm3: Real,
) -> Result<(Vec<Crossing>, RiskReport), PlanError> {
    let x = liver_crossings(anatomy, model, surfaces)?;
    let remnant: Vec<f32> = resected.iter().map(|f| 1.0 - f).collect();
    let a = model
        .assess(&x, &remnant)
        .map_err(|e| PlanError::InvalidArgument(format!("risk analysis: {e}")))?;
    let report = risk_report(&a, surfaces, total_mm3);
    Ok((x, report))
}

/// (u, v) of a crossing on its surface.
pub fn crossing_uv(c: &Crossing, surface: &CutMesh) -> [Real; 2] {
    let [ru, rv] = surface.resolution;
    let tri = surface
        .mesh
        .triangles()
        .get(c.triangle)
        .copied()
        .unwrap_or([0; 3]);
    let mut uv = [0.0; 2];
    for (k, w) in tri.iter().zip(c.barycentric) {
        let k = *k as usize;
        uv[0] += w * (k / rv.max(1)) as Real / (ru.max(2) - 1) as Real;
        uv[1] += w * (k % rv.max(1)) as Real / (rv.max(2) - 1) as Real;
    }
    uv
}

/// The cut branches as reported, on their surfaces.
pub fn cut_vessels(cut: &[CutBranch], surfaces: &[CutMesh]) -> Vec<CutVessel> {
    cut.iter()
        .filter_map(|c| {
            let s = surfaces.get(c.crossing.surface)?;
            Some(CutVessel {
                system: c.crossing.system.name(),
                resection: s.name.clone(),
                branch: c.crossing.edge,
                generation: c.generation,
                radius_mm: c.crossing.radius_mm,
                point: [c.crossing.point.x, c.crossing.point.y, c.crossing.point.z],
                uv: crossing_uv(&c.crossing, s),
                downstream_of_another_cut: c.downstream_of_another_cut,
            })
        })
        .collect()
}

/// The report of an assessment over a functional liver of `total_mm3`.
pub fn risk_report(a: &RiskAssessment, surfaces: &[CutMesh], total_mm3: Real) -> RiskReport {
    let ml = |v: Real| v / 1000.0;
    let cut_vessels = cut_vessels(&a.cut, surfaces);
    RiskReport {
        devascularised_ml: ml(a.devascularised_mm3),
        congested_ml: ml(a.congested_mm3),
        at_risk_ml: ml(a.at_risk_mm3),
        functional_remnant_ml: ml(a.functional_remnant_mm3),
        functional_remnant_pct: if total_mm3 > 0.0 {
            100.0 * a.functional_remnant_mm3 / total_mm3
        } else {
            0.0
        },
        has_portal: a.has_portal,
        has_hepatic: a.has_hepatic,
        cut_vessels,
    }
}

/// Per-voxel risk classes of [`RiskMap::classes`].
pub mod risk_class {
    /// Not functional liver.
    pub const NONE: u8 = 0;
    /// Remnant that keeps portal supply and hepatic drainage.
    pub const FUNCTIONAL: u8 = 1;
    /// Resected (resected fraction ≥ ½).
    pub const RESECTED: u8 = 2;
    pub const DEVASCULARISED: u8 = 3;
    pub const CONGESTED: u8 = 4;
    /// Devascularised and congested.
    pub const BOTH: u8 = 5;
}

/// The plan's risk per voxel of the functional liver's bounding box.
#[derive(Debug, Clone, PartialEq)]
pub struct RiskMap {
    /// The bounding box of the functional liver on the label map's grid.
    pub grid: Grid,
    /// [`risk_class`] per voxel (x fastest).
    pub classes: Vec<u8>,
    /// 1 + the generation-2 portal branch feeding each voxel ([`TERRITORY_GENERATION`]); 0
    /// outside the functional liver or without a portal tree.
    pub territories: Vec<u32>,
    pub report: RiskReport,
}

/// The risk map of liver voxels at grid `offsets` with their resected fractions and lost
/// flags, cropped to their bounding box.
pub(crate) fn risk_map(
    grid: &Grid,
    offsets: &[usize],
    resected: &[f32],
    regions: &RiskRegions,
    territories: Option<Vec<u32>>,
    report: RiskReport,
) -> Result<RiskMap, resecta_geom::GeomError> {
    let (mut lo, mut hi) = ([usize::MAX; 3], [0usize; 3]);
    for &o in offsets {
        let ijk = grid.ijk(o);
        for a in 0..3 {
            lo[a] = lo[a].min(ijk[a]);
            hi[a] = hi[a].max(ijk[a] + 1);
        }
    }
    if lo[0] == usize::MAX {
        lo = [0; 3];
        hi = [1; 3];
    }
    let dims = [0, 1, 2].map(|a| hi[a] - lo[a]);
    let crop = Grid::new(
        dims,
        grid.spacing(),
        grid.voxel_center(lo),
        grid.direction(),
    )?;
    let mut classes = vec![risk_class::NONE; crop.len()];
    let mut terr = vec![0u32; crop.len()];
    let flag = |v: &Option<Vec<bool>>, i: usize| v.as_ref().is_some_and(|v| v[i]);
    for (i, &o) in offsets.iter().enumerate() {
        let ijk = grid.ijk(o);
        let c = crop.offset([ijk[0] - lo[0], ijk[1] - lo[1], ijk[2] - lo[2]]);
        let (d, g) = (
            flag(&regions.devascularised, i),
            flag(&regions.congested, i),
        );
        classes[c] = if resected[i] >= 0.5 {
            risk_class::RESECTED
        } else {
            match (d, g) {
                (true, true) => risk_class::BOTH,
                (true, false) => risk_class::DEVASCULARISED,
                (false, true) => risk_class::CONGESTED,
                (false, false) => risk_class::FUNCTIONAL,
            }
        };
        if let Some(t) = &territories {
            terr[c] = t[i];
        }
    }
    Ok(RiskMap {
        grid: crop,
        classes,
        territories: terr,
        report,
    })
}
