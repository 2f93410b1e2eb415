//! The complete patient model (Fig. 6.9) as 3D Slicer shows a segmentation: the liver by PSR
//! (or MCSD, on request), one MCSD model per vessel label (segment) holding all its pieces and
//! one per tumour component (each is a planning target). Specks — components below a volume —
//! are left out and counted, never silently.

use resecta_geom::{LabelMap, Real, Role, RoleMap, TriMesh};

use crate::mask::{self, Components};
use crate::{McsdParams, PoissonSolver, ReconError, mcsd, psr};

/// Default speck volume (mm³, 0.01 ml): smaller components are segmentation noise (one to a few
/// voxels of a CT) and get no model. Tumours always use it, so the tumour models are exactly the
/// planner's targets ([`tumours`]); vessels take it per request ([`ModelOptions`]).
pub const SPECK_MM3: Real = 10.0;

/// How the parenchyma (the liver envelope) is reconstructed; tumours and vessels are always
/// built by MCSD.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParenchymaMethod {
    /// Screened Poisson surface reconstruction at this octree depth.
    Psr { depth: u32 },
    /// Marching cubes, smoothing and decimation with the MCSD parameters of the call.
    Mcsd,
}

impl ParenchymaMethod {
    /// `"psr"` or `"mcsd"`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Psr { .. } => "psr",
            Self::Mcsd => "mcsd",
        }
    }
}

/// What [`patient_models`] builds and how.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModelOptions {
    pub parenchyma: ParenchymaMethod,
    pub mcsd: McsdParams,
    /// One vessel model per face-connected component instead of one per label.
    pub split_components: bool,
    /// Vessel components smaller than this (mm³, ≥ 0) are left out and counted.
    pub min_component_mm3: Real,
}

impl Default for ModelOptions {
    fn default() -> Self {
        Self {
            parenchyma: ParenchymaMethod::Psr { depth: 7 },
            mcsd: McsdParams::default(),
            split_components: false,
            min_component_mm3: SPECK_MM3,
        }
    }
}

impl ModelOptions {
    /// [`ReconError::InvalidParameter`] for a negative or non-finite speck volume.
    pub fn check(&self) -> Result<(), ReconError> {
        if !(self.min_component_mm3 >= 0.0 && self.min_component_mm3.is_finite()) {
            return Err(ReconError::InvalidParameter {
                name: "min_component_mm3",
                reason: "must be a finite volume ≥ 0",
            });
        }
        Ok(())
    }
}

/// One model of the patient.
#[derive(Debug, Clone)]
pub struct PatientModel {
    pub role: Role,
    /// Position within the role: labels in role-map order, then components largest first.
    pub index: usize,
    /// The label value it was built from; for the parenchyma its label when the role has one.
    pub label: Option<u16>,
    /// `"psr"` or `"mcsd"`.
    pub method: &'static str,
    /// Voxels it was built from.
    pub voxels: usize,
    pub mesh: TriMesh,
}

impl PatientModel {
    /// File stem such as `parenchyma`, `tumor_1`, `portal_2`.
    pub fn name(&self) -> String {
        if self.role == Role::Parenchyma {
            self.role.name().to_owned()
        } else {
            format!("{}_{}", self.role.name(), self.index + 1)
        }
    }
}

/// Components of one role left out as specks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dropped {
    pub role: Role,
    pub components: usize,
    pub voxels: usize,
    pub volume_mm3: Real,
}

/// Every model, and the specks left out (one entry per role with any).
#[derive(Debug, Clone)]
pub struct PatientModels {
    pub models: Vec<PatientModel>,
    pub dropped: Vec<Dropped>,
}

/// One present label of a role and its components above the speck volume.
#[derive(Debug)]
pub struct LabelParts {
    pub label: u16,
    pub parts: Components,
}

/// The labels of `role` present in `labels` (role-map order: ascending), each with its
/// components of at least `min_mm3`.
pub fn label_parts(
    labels: &LabelMap,
    roles: &RoleMap,
    role: Role,
    min_mm3: Real,
) -> Result<Vec<LabelParts>, ReconError> {
    let min_voxels = mask::voxels_for_mm3(labels.grid(), min_mm3);
    let mut out = Vec::new();
    for &label in roles.labels(role) {
        let selected = match mask::select_cropped(labels, &[label], 1) {
            Ok(m) => m,
            Err(ReconError::LabelsAbsent { .. }) => continue,
            Err(e) => return Err(e),
        };
        out.push(LabelParts {
            label,
            parts: Components::new(&selected, min_voxels)?,
        });
    }
    Ok(out)
}

/// The tumours: per tumour label its components of at least [`SPECK_MM3`], largest first — the
/// tumour models and the planner's targets alike.
pub fn tumours(labels: &LabelMap, roles: &RoleMap) -> Result<Vec<LabelParts>, ReconError> {
    label_parts(labels, roles, Role::Tumor, SPECK_MM3)
}

/// Builds every model: the parenchyma, then tumours (one per component), then vessels (one per
/// label, or per component with `split_components`). `progress(name)` is called after each one
/// and stops the work with [`ReconError::Cancelled`] when it returns `false`.
pub fn patient_models(
    labels: &LabelMap,
    roles: &RoleMap,
    options: &ModelOptions,
    progress: &mut dyn FnMut(&str) -> bool,
) -> Result<PatientModels, ReconError> {
    patient_models_with(labels, roles, options, &PoissonSolver::cpu(), progress)
}

/// [`patient_models`] with the parenchyma's Poisson system solved by `solver`.
pub fn patient_models_with(
    labels: &LabelMap,
    roles: &RoleMap,
    options: &ModelOptions,
    solver: &PoissonSolver,
    progress: &mut dyn FnMut(&str) -> bool,
) -> Result<PatientModels, ReconError> {
    options.check()?;
    let mcsd_params = &options.mcsd;
    let mut out = PatientModels {
        models: Vec::new(),
        dropped: Vec::new(),
    };
    let all: Vec<u16> = roles.roles().flat_map(|(_, l)| l.iter().copied()).collect();
    if all.is_empty() {
        return Err(ReconError::NoLabels);
    }
    let lut = roles.lookup_table();
    let (lo, hi) = mask::bounds_where(labels, |l| lut[usize::from(l)].is_some())
        .ok_or_else(|| mask::absent(labels, &all))?;
    let (lo, hi) = mask::padded(labels.grid(), lo, hi, 2);
    let region = mask::sub_volume(labels, lo, hi)?;
    let voxel_mm3 = labels.grid().voxel_volume_mm3();
    let parenchyma_labels = roles.labels(Role::Parenchyma);
    if !parenchyma_labels.is_empty() {
        let envelope = mask::liver_envelope(&region, roles)?;
        let voxels = envelope.data().iter().filter(|&&b| b).count();
        let mesh = match options.parenchyma {
            ParenchymaMethod::Psr { depth } => {
                psr::reconstruct_with(&envelope, depth, solver)?.mesh
            }
            ParenchymaMethod::Mcsd => mcsd::reconstruct(&envelope, mcsd_params)?,
        };
        out.models.push(PatientModel {
            role: Role::Parenchyma,
            index: 0,
            label: match parenchyma_labels {
                [one] => Some(*one),
                _ => None,
            },
            method: options.parenchyma.name(),
            voxels,
            mesh,
        });
        if !progress("parenchyma") {
            return Err(ReconError::Cancelled);
        }
    }
    for role in [Role::Tumor, Role::Portal, Role::Hepatic, Role::Vessel] {
        let per_label = if role == Role::Tumor {
            tumours(&region, roles)?
        } else {
            label_parts(&region, roles, role, options.min_component_mm3)?
        };
        let split = role == Role::Tumor || options.split_components;
        let mut index = 0;
        let mut dropped = (0, 0);
        for LabelParts { label, parts } in per_label {
            dropped = (dropped.0 + parts.dropped, dropped.1 + parts.dropped_voxels);
            let masks = if split {
                (0..parts.len())
                    .map(|k| Ok((parts.voxels(k), parts.crop(k)?)))
                    .collect::<Result<Vec<_>, ReconError>>()?
            } else if parts.is_empty() {
                Vec::new()
            } else {
                vec![(parts.kept_voxels(), parts.union()?)]
            };
            drop(parts);
            for (voxels, m) in masks {
                let model = PatientModel {
                    role,
                    index,
                    label: Some(label),
                    method: "mcsd",
                    voxels,
                    mesh: mcsd::reconstruct(&m, mcsd_params)?,
                };
                index += 1;
                if !progress(&model.name()) {
                    return Err(ReconError::Cancelled);
                }
                out.models.push(model);
            }
        }
        if dropped.0 > 0 {
            out.dropped.push(Dropped {
                role,
                components: dropped.0,
                voxels: dropped.1,
                volume_mm3: dropped.1 as Real * voxel_mm3,
            });
        }
    }
    Ok(out)
}
