//! The plan: a role map and its resections; edits as events; the `resecta-plan/1` file format.

use resecta_geom::{Real, RoleMap};
use serde::{Deserialize, Serialize};

use crate::error::PlanError;
use crate::resection::{Group, Resection, ResectionKind, Target, check_length};
use resecta_traces::Deformation;

/// The plan file format this engine reads and writes.
pub const FORMAT: &str = "resecta-plan/1";

/// A resection plan: which labels are which, and the virtual resections. Always valid.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Plan {
    pub format: &'static str,
    pub roles: RoleMap,
    pub resections: Vec<Resection>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PlanFile {
    format: String,
    roles: RoleMap,
    #[serde(default)]
    resections: Vec<Resection>,
}

/// Largest plan file accepted (bytes).
pub const MAX_PLAN_BYTES: usize = 16 << 20;

/// One edit of a plan. Events carry everything they need (an initialised resection arrives with
/// its control points), so a plan replays from its events without the patient's images.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case", deny_unknown_fields)]
pub enum PlanEvent {
    AddResection {
        resection: Resection,
    },
    DeleteResection {
        name: String,
    },
    SetControlPoint {
        name: String,
        i: usize,
        j: usize,
        point: [Real; 3],
    },
    SetControlPoints {
        name: String,
        points: Vec<[Real; 3]>,
    },
    MoveGroup {
        name: String,
        group: Group,
        delta: [Real; 3],
    },
    Translate {
        name: String,
        delta: [Real; 3],
    },
    Rotate {
        name: String,
        axis: [Real; 3],
        angle_deg: Real,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        centre: Option<[Real; 3]>,
    },
    SetMargin {
        name: String,
        margin_mm: Real,
    },
    SetBand {
        name: String,
        band_mm: Real,
    },
    SetResolution {
        name: String,
        resolution: [usize; 2],
    },
    SetTarget {
        name: String,
        target: Target,
    },
    /// DS, CP: appends a trace.
    AddTrace {
        name: String,
        trace: Vec<[Real; 3]>,
    },
    /// DS, CP: redraws trace `index`.
    SetTrace {
        name: String,
        index: usize,
        trace: Vec<[Real; 3]>,
    },
    /// DS, CP: removes trace `index`.
    RemoveTrace {
        name: String,
        index: usize,
    },
    /// CP: appends a deformation.
    AddDeformation {
        name: String,
        deformation: Deformation,
    },
    /// CP: takes back the last deformation.
    UndoDeformation {
        name: String,
    },
}

impl PlanEvent {
    /// The resection the event is about.
    pub fn resection_name(&self) -> &str {
        match self {
            PlanEvent::AddResection { resection } => &resection.name,
            PlanEvent::DeleteResection { name }
            | PlanEvent::SetControlPoint { name, .. }
            | PlanEvent::SetControlPoints { name, .. }
            | PlanEvent::MoveGroup { name, .. }
            | PlanEvent::Translate { name, .. }
            | PlanEvent::Rotate { name, .. }
            | PlanEvent::SetMargin { name, .. }
            | PlanEvent::SetBand { name, .. }
            | PlanEvent::SetResolution { name, .. }
            | PlanEvent::SetTarget { name, .. }
            | PlanEvent::AddTrace { name, .. }
            | PlanEvent::SetTrace { name, .. }
            | PlanEvent::RemoveTrace { name, .. }
            | PlanEvent::AddDeformation { name, .. }
            | PlanEvent::UndoDeformation { name } => name,
        }
    }

    /// Whether the event changes only the surface geometry (not margins or targets).
    pub fn moves_surface(&self) -> bool {
        matches!(
            self,
            PlanEvent::SetControlPoint { .. }
                | PlanEvent::SetControlPoints { .. }
                | PlanEvent::MoveGroup { .. }
                | PlanEvent::Translate { .. }
                | PlanEvent::Rotate { .. }
                | PlanEvent::AddTrace { .. }
                | PlanEvent::SetTrace { .. }
                | PlanEvent::RemoveTrace { .. }
                | PlanEvent::AddDeformation { .. }
                | PlanEvent::UndoDeformation { .. }
        )
    }
}

#[cfg(test)]
thread_local! {
    /// Events applied on this thread (the tests that an edit applies its event once count them).
    pub(crate) static APPLIED: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// Most resections in one plan.
pub const MAX_RESECTIONS: usize = 32;

impl Plan {
    /// An empty plan.
    pub fn new(roles: RoleMap) -> Self {
        Self {
            format: FORMAT,
            roles,
            resections: Vec::new(),
        }
    }

    /// Parses and validates a plan file.
    pub fn from_json(text: &str) -> Result<Self, PlanError> {
        if text.len() > MAX_PLAN_BYTES {
            return Err(PlanError::Json(format!(
                "{} bytes exceed the limit of {MAX_PLAN_BYTES}",
                text.len()
            )));
        }
        let file: PlanFile =
            serde_json::from_str(text).map_err(|e| PlanError::Json(e.to_string()))?;
        if file.format != FORMAT {
            return Err(PlanError::Format(file.format));
        }
        let mut plan = Plan::new(file.roles);
        for r in file.resections {
            plan.apply(&PlanEvent::AddResection { resection: r })?;
        }
        Ok(plan)
    }

    /// The plan file text (pretty JSON).
    pub fn to_json(&self) -> Result<String, PlanError> {
        serde_json::to_string_pretty(self).map_err(|e| PlanError::Json(e.to_string()))
    }

    /// The resection called `name`.
    pub fn resection(&self, name: &str) -> Result<&Resection, PlanError> {
        self.resections
            .iter()
            .find(|r| r.name == name)
            .ok_or_else(|| PlanError::UnknownResection(name.to_owned()))
    }

    fn resection_mut(&mut self, name: &str) -> Result<&mut Resection, PlanError> {
        self.resections
            .iter_mut()
            .find(|r| r.name == name)
            .ok_or_else(|| PlanError::UnknownResection(name.to_owned()))
    }

    /// Applies one event. On error the plan is unchanged.
    pub fn apply(&mut self, event: &PlanEvent) -> Result<(), PlanError> {
        #[cfg(test)]
        APPLIED.with(|n| n.set(n.get() + 1));
        if let PlanEvent::AddResection { resection } = event {
            resection.validate()?;
            self.check_target(&resection.name, &resection.target)?;
            if self.resections.iter().any(|r| r.name == resection.name) {
                return Err(PlanError::DuplicateName(resection.name.clone()));
            }
            if self.resections.len() >= MAX_RESECTIONS {
                return Err(PlanError::TooManyResections(self.resections.len() + 1));
            }
            self.resections.push(resection.clone());
            return Ok(());
        }
        if let PlanEvent::DeleteResection { name } = event {
            self.resection(name)?;
            self.resections.retain(|r| &r.name != name);
            return Ok(());
        }
        if let PlanEvent::SetTarget { name, target } = event {
            self.check_target(name, target)?;
        }
        // Edit a copy so that a failing edit leaves the resection as it was.
        let mut r = self.resection(event.resection_name())?.clone();
        match event {
            PlanEvent::SetControlPoint { i, j, point, .. } => {
                r.set_control_point(*i, *j, *point)?
            }
            PlanEvent::SetControlPoints { points, .. } => r.set_control_points(points)?,
            PlanEvent::MoveGroup { group, delta, .. } => r.move_group(*group, *delta)?,
            PlanEvent::Translate { delta, .. } => r.move_group(Group::All, *delta)?,
            PlanEvent::Rotate {
                axis,
                angle_deg,
                centre,
                ..
            } => r.rotate(*axis, *angle_deg, *centre)?,
            PlanEvent::SetMargin { margin_mm, .. } => {
                check_length("margin_mm", *margin_mm, true)
                    .map_err(|w| PlanError::resection(&r.name, w))?;
                r.margin_mm = *margin_mm;
            }
            PlanEvent::SetBand { band_mm, .. } => {
                check_length("band_mm", *band_mm, false)
                    .map_err(|w| PlanError::resection(&r.name, w))?;
                r.band_mm = *band_mm;
            }
            PlanEvent::SetResolution { resolution, .. } => {
                if r.kind == ResectionKind::Cp {
                    return Err(PlanError::resection(
                        &r.name,
                        "a CP resection is sampled at its grid of 30 × n quads: it has no resolution to set",
                    ));
                }
                r.resolution = *resolution
            }
            PlanEvent::AddTrace { trace, .. } => r.add_trace(trace.clone())?,
            PlanEvent::SetTrace { index, trace, .. } => r.set_trace(*index, trace.clone())?,
            PlanEvent::RemoveTrace { index, .. } => r.remove_trace(*index)?,
            PlanEvent::AddDeformation { deformation, .. } => r.add_deformation(*deformation)?,
            PlanEvent::UndoDeformation { .. } => r.undo_deformation()?,
            PlanEvent::SetTarget { target, .. } => r.target = target.clone(),
            PlanEvent::AddResection { .. } | PlanEvent::DeleteResection { .. } => {}
        }
        r.validate()?;
        *self.resection_mut(event.resection_name())? = r;
        Ok(())
    }

    fn check_target(&self, name: &str, target: &Target) -> Result<(), PlanError> {
        let tumours = self.roles.labels(resecta_geom::roles::Role::Tumor);
        if tumours.is_empty() {
            return Err(PlanError::NoTumour);
        }
        for &l in &target.labels {
            if !tumours.contains(&l) {
                return Err(PlanError::resection(
                    name,
                    format!("target label {l} is not a tumour label of the role map"),
                ));
            }
        }
        Ok(())
    }

    /// The tumour labels a resection targets (its own, or every tumour label).
    pub fn target_labels(&self, r: &Resection) -> Vec<u16> {
        if r.target.labels.is_empty() {
            self.roles.labels(resecta_geom::roles::Role::Tumor).to_vec()
        } else {
            r.target.labels.clone()
        }
    }
}
