//! The complete patient model (Fig. 6.9): the liver by PSR (or MCSD, on request), every tumour
//! and vessel component by MCSD, one mesh each.

use resecta_geom::{LabelMap, Role, RoleMap, TriMesh};

use crate::{McsdParams, ReconError, mask, mcsd, psr};

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

/// One model of the patient.
#[derive(Debug, Clone)]
pub struct PatientModel {
    pub role: Role,
    /// Component index within the role, largest first.
    pub component: usize,
    /// `"psr"` or `"mcsd"`.
    pub method: &'static str,
    /// Voxels of the component.
    pub voxels: usize,
    pub mesh: TriMesh,
}

impl PatientModel {
    /// File stem such as `parenchyma`, `tumor_1`, `portal_2`.
    pub fn name(&self) -> String {
        if self.role == Role::Parenchyma {
            self.role.name().to_owned()
        } else {
            format!("{}_{}", self.role.name(), self.component + 1)
        }
    }
}

/// Builds every model, the parenchyma by `parenchyma`, the other roles by MCSD with
/// `mcsd_params`; `progress(name)` is called after each one and stops the work with
/// [`ReconError::Cancelled`] when it returns `false`.
pub fn patient_models(
    labels: &LabelMap,
    roles: &RoleMap,
    parenchyma: ParenchymaMethod,
    mcsd_params: &McsdParams,
    progress: &mut dyn FnMut(&str) -> bool,
) -> Result<Vec<PatientModel>, ReconError> {
    let mut out = Vec::new();
    let all: Vec<u16> = roles.roles().flat_map(|(_, l)| l.iter().copied()).collect();
    let any = mask::select(labels, &all)?;
    let (lo, hi) = mask::bounds(&any).ok_or(ReconError::EmptyMask)?;
    let dims = labels.grid().dims();
    let lo = lo.map(|v| v.saturating_sub(2));
    let hi = [0, 1, 2].map(|a| (hi[a] + 2).min(dims[a]));
    let region = mask::sub_volume(labels, lo, hi)?;
    if !roles.labels(Role::Parenchyma).is_empty() {
        let envelope = mask::liver_envelope(&region, roles)?;
        let voxels = envelope.data().iter().filter(|&&b| b).count();
        let mesh = match parenchyma {
            ParenchymaMethod::Psr { depth } => psr::reconstruct(&envelope, depth)?.mesh,
            ParenchymaMethod::Mcsd => mcsd::reconstruct(&envelope, mcsd_params)?,
        };
        out.push(PatientModel {
            role: Role::Parenchyma,
            component: 0,
            method: parenchyma.name(),
            voxels,
            mesh,
        });
        if !progress("parenchyma") {
            return Err(ReconError::Cancelled);
        }
    }
    for role in [Role::Tumor, Role::Portal, Role::Hepatic, Role::Vessel] {
        let wanted = roles.labels(role);
        if wanted.is_empty() {
            continue;
        }
        let selected = match mask::select(&region, wanted) {
            Ok(m) => m,
            Err(ReconError::LabelsAbsent { .. }) => continue,
            Err(e) => return Err(e),
        };
        for (component, part) in mask::components(&selected)?.into_iter().enumerate() {
            let voxels = part.data().iter().filter(|&&b| b).count();
            let mesh = mcsd::reconstruct(&part, mcsd_params)?;
            let model = PatientModel {
                role,
                component,
                method: "mcsd",
                voxels,
                mesh,
            };
            if !progress(&model.name()) {
                return Err(ReconError::Cancelled);
            }
            out.push(model);
        }
    }
    Ok(out)
}
