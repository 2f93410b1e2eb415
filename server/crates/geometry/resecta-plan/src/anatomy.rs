//! The patient as the planner needs it, built once from a label map: the liver envelope (for
//! "inside the liver" tests), the functional liver (for volumetry), the parenchyma surface (for
//! the initial contour) and the tumour components with their margin surfaces (the boundary of
//! their voxels): the components of at least [`resecta_recon::SPECK_MM3`], the same list as the
//! reconstruction's tumour models.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use rayon::prelude::*;
use resecta_geom::{Grid, LabelMap, Real, Role, RoleMap, TriMesh, Vec3, Volume};
use resecta_recon::models::{self, LabelParts};
use resecta_recon::{McsdParams, ReconError, mask, mcsd};
use resecta_volumetry::LiverVoxels;

use crate::engine::{TargetModel, build_target};
use crate::error::PlanError;
use crate::inside::InsideField;
use crate::resection::Target;
use crate::vascular::Vascular;

/// The surface a tumour's margins are measured to: the boundary of its voxels taken as cubes
/// ([`resecta_isosurface::voxel_boundary`]), not its smoothed display model. A distance to it is
/// the exact distance to the segmented tumour: never more than the distance to any tumour voxel
/// centre, and at most half a voxel (along the direction measured) less.
pub fn tumour_model(mask: &Volume<bool>) -> Result<TriMesh, PlanError> {
    Ok(resecta_isosurface::voxel_boundary(mask).map_err(resecta_recon::ReconError::from)?)
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
    /// Margin surface ([`tumour_model`]: its voxels' boundary, with the specks attached to it),
    /// RAS.
    pub mesh: TriMesh,
    /// Voxels of speck components (below the speck volume) whose margins count with this
    /// tumour's (the nearest target of the label).
    pub speck_voxels: usize,
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
    /// Margin structures per selection of tumours (at most [`MAX_TARGETS`]).
    targets: Mutex<BTreeMap<Vec<usize>, Arc<TargetModel>>>,
    /// The functional voxels indexed for volumetry, built with the anatomy and taken by the
    /// first planner's volumetry engine ([`Anatomy::take_liver_voxels`]).
    liver_voxels: Mutex<Option<LiverVoxels>>,
    /// The portal and hepatic trees with each functional voxel's nearest centreline point.
    vascular: Vascular,
}

/// Selections whose margin structures an anatomy keeps (more start the memory afresh).
const MAX_TARGETS: usize = 32;

/// Selections built with the anatomy, before any edit asks: all tumours (a target without
/// labels or points) and the largest one alone (a target point on it); one when there is one
/// tumour. Each costs as much as the rest of the set-up on a large liver, so others wait for
/// their first use.
pub fn likely_targets(tumours: usize) -> Vec<Vec<usize>> {
    match tumours {
        0 => Vec::new(),
        1 => vec![vec![0]],
        n => vec![(0..n).collect(), vec![0]],
    }
}

impl Anatomy {
    /// Builds everything from a label map and its role map (one-time set-up).
    pub fn new(labels: &LabelMap, roles: &RoleMap) -> Result<Self, PlanError> {
        Self::new_cancellable(labels, roles, &|| false)
    }

    /// [`Anatomy::new`] that stops with [`ReconError::Cancelled`] (as [`PlanError::Recon`])
    /// once `cancelled()` holds; it is asked between the stages. Independent stages run in
    /// parallel (rayon): the liver envelope and then its surface, inside levels and
    /// functional mask beside the tumour components and their margin surfaces.
    pub fn new_cancellable(
        labels: &LabelMap,
        roles: &RoleMap,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Result<Self, PlanError> {
        let go_on = || {
            if cancelled() {
                Err(PlanError::Recon(ReconError::Cancelled))
            } else {
                Ok(())
            }
        };
        if roles.labels(Role::Tumor).is_empty() {
            return Err(PlanError::NoTumour);
        }
        let parenchyma_labels = roles.labels(Role::Parenchyma);
        if !labels
            .data()
            .par_iter()
            .any(|l| parenchyma_labels.contains(l))
        {
            return Err(PlanError::EmptyLiver);
        }
        go_on()?;
        let lut = roles.lookup_table();
        let (envelope, tumours) = rayon::join(
            || -> Result<_, PlanError> {
                let envelope = mask::liver_envelope(labels, roles)?;
                go_on()?;
                let inside = InsideField::new(&envelope);
                Ok((envelope, inside))
            },
            || -> Result<_, PlanError> {
                go_on()?;
                let mut tumours = Vec::new();
                for LabelParts { label, parts } in models::tumours(labels, roles)? {
                    let mut kept = vec![false; labels.grid().len()];
                    let first = tumours.len();
                    for k in 0..parts.len() {
                        go_on()?;
                        tumours.push(tumour(labels, &lut, label, &parts.crop(k)?, &mut kept)?);
                    }
                    if parts.dropped > 0 {
                        attach_specks(labels, label, &kept, &mut tumours[first..])?;
                    }
                }
                Ok(tumours)
            },
        );
        // Errors in the order of the stages done one after the other.
        let (envelope, inside) = envelope?;
        go_on()?;
        // The parenchyma surface and the functional mask beside the margin structures of the
        // likely first targets.
        let ((parenchyma, functional), targets) = rayon::join(
            || {
                rayon::join(
                    || mcsd::reconstruct(&envelope, &McsdParams::default()),
                    || {
                        let functional = functional_mask(labels, &lut, &envelope)?;
                        // An empty liver is reported when a volumetry is asked for.
                        let voxels = LiverVoxels::new(&functional).ok();
                        let vascular = match &voxels {
                            Some(v) => Vascular::build(labels, roles, &v.offsets()),
                            None => Vascular::Absent,
                        };
                        Ok::<_, PlanError>((functional, voxels, vascular))
                    },
                )
            },
            || -> Result<_, PlanError> {
                let Ok(tumours) = &tumours else {
                    return Ok(Vec::new());
                };
                let Some(liver) = inside.bounds() else {
                    return Ok(Vec::new());
                };
                let cell = envelope.grid().linear();
                likely_targets(tumours.len())
                    .into_iter()
                    .map(|selected| {
                        go_on()?;
                        let model = build_target(tumours, &selected, liver, cell)?;
                        Ok((selected, Arc::new(model)))
                    })
                    .collect()
            },
        );
        let (parenchyma, (functional, liver_voxels, vascular)) = (parenchyma?, functional?);
        let tumours = tumours?;
        let targets = targets?;
        go_on()?;
        Ok(Self {
            roles: roles.clone(),
            inside,
            envelope,
            functional,
            parenchyma,
            tumours,
            targets: Mutex::new(targets.into_iter().collect()),
            liver_voxels: Mutex::new(liver_voxels),
            vascular,
        })
    }

    /// The margin structures of the tumours `selected` (indices into [`Anatomy::tumours`]),
    /// built once per patient: those of [`likely_targets`] with the anatomy, others on first
    /// use.
    pub fn target(&self, selected: &[usize]) -> Result<Arc<TargetModel>, PlanError> {
        let cached = |t: &Self| -> Option<Arc<TargetModel>> {
            t.targets.lock().ok()?.get(selected).cloned()
        };
        if let Some(m) = cached(self) {
            return Ok(m);
        }
        let liver = self.liver_bounds().ok_or(PlanError::EmptyLiver)?;
        let model = Arc::new(build_target(
            &self.tumours,
            selected,
            liver,
            self.envelope.grid().linear(),
        )?);
        if let Ok(mut targets) = self.targets.lock() {
            if targets.len() >= MAX_TARGETS {
                targets.clear();
            }
            return Ok(Arc::clone(
                targets.entry(selected.to_vec()).or_insert(model),
            ));
        }
        Ok(model)
    }

    /// The functional voxels indexed for volumetry, once: the first caller takes them (a
    /// volumetry engine is built once per planner), later callers index them again.
    pub fn take_liver_voxels(&self) -> Option<LiverVoxels> {
        self.liver_voxels.lock().ok()?.take()
    }

    /// The vessel trees (risk analysis), when the roles name portal or hepatic labels.
    pub fn vascular(&self) -> &Vascular {
        &self.vascular
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

    /// The envelope's bricks behind [`Anatomy::inside_level`], for accelerators.
    pub fn inside_layout(&self) -> crate::inside::InsideLayout<'_> {
        self.inside.layout()
    }

    /// World bounds (min, max) of the envelope's voxel centres, or `None` when empty.
    pub fn liver_bounds(&self) -> Option<(Vec3, Vec3)> {
        self.inside.bounds()
    }
}

/// Voxels that count in volumetry: envelope voxels whose label is parenchyma or vessel.
fn functional_mask(
    labels: &LabelMap,
    lut: &[Option<Role>],
    envelope: &Volume<bool>,
) -> Result<Volume<bool>, PlanError> {
    let data: Vec<bool> = labels
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
    Ok(Volume::from_vec(labels.grid().clone(), data)?)
}

/// Tumour voxels in components below the speck volume get no model and are no target, but a
/// margin must not ignore them: each joins the margin surface of the target of its label whose
/// centroid is nearest. `kept` marks (by grid offset) the voxels of `targets`.
fn attach_specks(
    labels: &LabelMap,
    label: u16,
    kept: &[bool],
    targets: &mut [Tumour],
) -> Result<(), PlanError> {
    let g = labels.grid();
    let mut owned: Vec<Vec<usize>> = vec![Vec::new(); targets.len()];
    for (o, _) in labels
        .data()
        .iter()
        .zip(kept)
        .enumerate()
        .filter(|(_, (l, k))| **l == label && !**k)
    {
        let p = g.voxel_center(g.ijk(o));
        let nearest = (0..targets.len())
            .min_by(|&a, &b| {
                let da = (targets[a].centroid - p).norm_squared();
                da.total_cmp(&(targets[b].centroid - p).norm_squared())
            })
            .ok_or(PlanError::NoTumour)?;
        owned[nearest].push(o);
    }
    for (t, offsets) in targets.iter_mut().zip(owned) {
        if offsets.is_empty() {
            continue;
        }
        let specks = tumour_model(&voxel_mask(g, &offsets)?)?;
        t.mesh = TriMesh::concat(&[t.mesh.clone(), specks])?;
        t.speck_voxels = offsets.len();
    }
    Ok(())
}

/// The voxels at `offsets` of grid `g` as a mask on their bounding box.
fn voxel_mask(g: &Grid, offsets: &[usize]) -> Result<Volume<bool>, PlanError> {
    let ijk: Vec<[usize; 3]> = offsets.iter().map(|&o| g.ijk(o)).collect();
    let lo = [0, 1, 2].map(|a| ijk.iter().map(|v| v[a]).min().unwrap_or(0));
    let hi = [0, 1, 2].map(|a| ijk.iter().map(|v| v[a] + 1).max().unwrap_or(1));
    let dims = [0, 1, 2].map(|a| hi[a] - lo[a]);
    let origin = g.index_to_world(Vec3::new(lo[0] as Real, lo[1] as Real, lo[2] as Real));
    let sub = Grid::new(dims, g.spacing(), origin, g.direction())?;
    let mut data = vec![false; dims.iter().product()];
    for v in ijk {
        data[((v[2] - lo[2]) * dims[1] + v[1] - lo[1]) * dims[0] + v[0] - lo[0]] = true;
    }
    Ok(Volume::from_vec(sub, data)?)
}

fn tumour(
    labels: &LabelMap,
    lut: &[Option<Role>],
    label: u16,
    comp: &Volume<bool>,
    kept: &mut [bool],
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
        kept[full.offset(g.map(|c| c as usize))] = true;
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
        speck_voxels: 0,
        centres,
    })
}
