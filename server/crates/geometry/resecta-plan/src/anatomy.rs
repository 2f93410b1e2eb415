//! The patient as the planner needs it, built once from a label map: the liver envelope (for
//! "inside the liver" tests), the functional liver (for volumetry), the parenchyma surface (for
//! the initial contour) and the tumour components with their surface models: the components of
//! at least [`resecta_recon::SPECK_MM3`], the same list as the reconstruction's tumour models.

use rayon::prelude::*;
use resecta_geom::{LabelMap, Real, Role, RoleMap, TriMesh, Vec3, Volume};
use resecta_recon::models::{self, LabelParts};
use resecta_recon::{McsdParams, mask, mcsd};

use crate::error::PlanError;
use crate::inside::InsideField;
use crate::resection::Target;

/// Tumour models for margins: MCSD with 3D Slicer's smoothing; models of more than this many
/// triangles are decimated down towards it (at most 80 %, Paper I's Pareto front), because an
/// exact margin query costs in proportion to the triangles near the answer. A decimated model is
/// kept only if it stays watertight and within 1 % of the undecimated model's volume (QEM can
/// collapse small coarse meshes).
pub const TUMOUR_MODEL_TRIANGLES: usize = 4000;

/// The tumour's surface model (see [`TUMOUR_MODEL_TRIANGLES`]).
pub fn tumour_model(mask: &Volume<bool>) -> Result<TriMesh, PlanError> {
    let full = mcsd::reconstruct(mask, &McsdParams::default())?;
    let n = full.triangles().len();
    if n <= TUMOUR_MODEL_TRIANGLES {
        return Ok(full);
    }
    let decimation = (1.0 - TUMOUR_MODEL_TRIANGLES as Real / n as Real).min(0.8);
    let reduced = mcsd::reconstruct(
        mask,
        &McsdParams {
            smoothing: 0.5,
            decimation,
        },
    )?;
    let (v0, v1) = (full.enclosed_volume(), reduced.enclosed_volume());
    if reduced.report().watertight && (v1 - v0).abs() <= 0.01 * v0.abs() {
        Ok(reduced)
    } else {
        Ok(full)
    }
}

/// A target point picks the tumour component containing it or the nearest within this (mm).
pub const TARGET_POINT_SNAP_MM: Real = 5.0;

/// One connected tumour (a planning target).
#[derive(Debug, Clone)]
pub struct Tumour {
    pub label: u16,
    /// Mean of its voxel centres (RAS mm).
    pub centroid: Vec3,
    pub voxels: usize,
    pub volume_mm3: Real,
    /// Surface model ([`tumour_model`]), RAS.
    pub mesh: TriMesh,
    /// Voxel centres (RAS), for target-point picking.
    centres: Vec<Vec3>,
}

/// The liver and tumours of one patient.
#[derive(Debug)]
pub struct Anatomy {
    roles: RoleMap,
    /// Parenchyma, tumours, vessels inside the liver and enclosed cavities.
    envelope: Volume<bool>,
    /// The envelope bricked for inside levels.
    inside: InsideField,
    /// Voxels that count in volumetry: envelope voxels whose label is parenchyma or vessel.
    functional: Volume<bool>,
    parenchyma: TriMesh,
    tumours: Vec<Tumour>,
}

impl Anatomy {
    /// Builds everything from a label map and its role map (one-time set-up).
    pub fn new(labels: &LabelMap, roles: &RoleMap) -> Result<Self, PlanError> {
        let present = labels.value_counts();
        let tumour_labels = roles.labels(Role::Tumor);
        if tumour_labels.is_empty() {
            return Err(PlanError::NoTumour);
        }
        if !roles
            .labels(Role::Parenchyma)
            .iter()
            .any(|l| present.contains_key(l))
        {
            return Err(PlanError::EmptyLiver);
        }
        let envelope = mask::liver_envelope(labels, roles)?;
        let lut = roles.lookup_table();
        let functional_data: Vec<bool> = labels
            .data()
            .par_iter()
            .zip(envelope.data().par_iter())
            .map(|(&l, &e)| {
                e && lut
                    .get(usize::from(l))
                    .copied()
                    .flatten()
                    .is_some_and(Role::is_functional_liver)
            })
            .collect();
        let functional = Volume::from_vec(labels.grid().clone(), functional_data)?;
        let parenchyma = mcsd::reconstruct(&envelope, &McsdParams::default())?;
        let mut tumours = Vec::new();
        for LabelParts { label, parts } in models::tumours(labels, roles)? {
            for k in 0..parts.len() {
                tumours.push(tumour(labels, &lut, label, &parts.crop(k)?)?);
            }
        }
        Ok(Self {
            roles: roles.clone(),
            inside: InsideField::new(&envelope),
            envelope,
            functional,
            parenchyma,
            tumours,
        })
    }

    pub fn roles(&self) -> &RoleMap {
        &self.roles
    }
    pub fn envelope(&self) -> &Volume<bool> {
        &self.envelope
    }
    pub fn functional(&self) -> &Volume<bool> {
        &self.functional
    }
    /// The parenchyma (whole-liver) surface model.
    pub fn parenchyma(&self) -> &TriMesh {
        &self.parenchyma
    }
    pub fn tumours(&self) -> &[Tumour] {
        &self.tumours
    }

    /// Functional liver volume (mm³), voxel count × voxel volume.
    pub fn functional_mm3(&self) -> Real {
        self.functional.data().iter().filter(|&&b| b).count() as Real
            * self.functional.grid().voxel_volume_mm3()
    }

    /// Indices of the tumours a target selects: components of its labels (every tumour label if
    /// none), narrowed to those picked by its points when it has any.
    pub fn select(&self, target: &Target) -> Result<Vec<usize>, PlanError> {
        let tumour_labels = self.roles.labels(Role::Tumor);
        for &l in &target.labels {
            if !tumour_labels.contains(&l) {
                return Err(PlanError::NotATumourLabel(l));
            }
            if !self.tumours.iter().any(|t| t.label == l) {
                return Err(PlanError::LabelAbsent(l));
            }
        }
        let by_label: Vec<usize> = (0..self.tumours.len())
            .filter(|&k| target.labels.is_empty() || target.labels.contains(&self.tumours[k].label))
            .collect();
        if by_label.is_empty() {
            return Err(PlanError::LabelAbsent(
                tumour_labels.first().copied().unwrap_or_default(),
            ));
        }
        if target.points.is_empty() {
            return Ok(by_label);
        }
        let spacing = self.envelope.grid().spacing();
        let half_diag = 0.5 * spacing.iter().map(|s| s * s).sum::<Real>().sqrt();
        let mut picked = Vec::new();
        for p in &target.points {
            let q = Vec3::new(p[0], p[1], p[2]);
            let best = by_label
                .iter()
                .map(|&k| {
                    let d = self.tumours[k]
                        .centres
                        .iter()
                        .map(|c| (c - q).norm())
                        .fold(Real::INFINITY, Real::min);
                    (d, k)
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            match best {
                Some((d, k)) if d <= TARGET_POINT_SNAP_MM + half_diag => {
                    if !picked.contains(&k) {
                        picked.push(k);
                    }
                }
                _ => return Err(PlanError::NoTumourAtPoint(*p)),
            }
        }
        picked.sort_unstable();
        Ok(picked)
    }

    /// Voxel-weighted centroid of the selected tumours.
    pub fn centroid(&self, selected: &[usize]) -> Option<Vec3> {
        let (sum, n) = selected.iter().fold((Vec3::zeros(), 0usize), |(s, n), &k| {
            let t = &self.tumours[k];
            (s + t.centroid * t.voxels as Real, n + t.voxels)
        });
        (n > 0).then(|| sum / n as Real)
    }

    /// The selected tumours' surface models as one mesh.
    pub fn tumour_mesh(&self, selected: &[usize]) -> Result<TriMesh, PlanError> {
        let meshes: Vec<TriMesh> = selected
            .iter()
            .map(|&k| self.tumours[k].mesh.clone())
            .collect();
        Ok(TriMesh::concat(&meshes)?)
    }

    /// Inside level of the liver envelope at `p`: trilinear interpolation of the mask (0/1)
    /// minus ½, so > 0 inside and ≤ 0 outside (−½ beyond the grid).
    pub fn inside_level(&self, p: &Vec3) -> Real {
        self.inside.level(p) - 0.5
    }

    /// World bounds (min, max) of the envelope's voxel centres, or `None` when empty.
    pub fn liver_bounds(&self) -> Option<(Vec3, Vec3)> {
        self.inside.bounds()
    }
}

fn tumour(
    labels: &LabelMap,
    lut: &[Option<Role>],
    label: u16,
    comp: &Volume<bool>,
) -> Result<Tumour, PlanError> {
    let full = labels.grid();
    let sub = comp.grid();
    let o = full.world_to_index(sub.origin());
    let offset = [o.x.round() as i64, o.y.round() as i64, o.z.round() as i64];
    let [sx, sy, _] = sub.dims();
    let dims = full.dims();
    let mut centres = Vec::new();
    let mut touches = false;
    for (v, _) in comp.data().iter().enumerate().filter(|(_, b)| **b) {
        let local = [v % sx, (v / sx) % sy, v / (sx * sy)];
        centres.push(sub.voxel_center(local));
        let g = [0, 1, 2].map(|a| local[a] as i64 + offset[a]);
        for a in 0..3 {
            for d in [-1i64, 1] {
                let mut n = g;
                n[a] += d;
                if n.iter().zip(dims).all(|(&c, d)| c >= 0 && (c as usize) < d) {
                    let ijk = n.map(|c| c as usize);
                    let l = labels.get(ijk).unwrap_or(0);
                    if lut.get(usize::from(l)).copied().flatten() == Some(Role::Parenchyma) {
                        touches = true;
                    }
                }
            }
        }
    }
    if !touches {
        return Err(PlanError::TumourOutsideLiver(label));
    }
    let voxels = centres.len();
    let centroid = centres.iter().sum::<Vec3>() / voxels.max(1) as Real;
    let mesh = tumour_model(comp)?;
    Ok(Tumour {
        label,
        centroid,
        voxels,
        volume_mm3: voxels as Real * full.voxel_volume_mm3(),
        mesh,
        centres,
    })
}
