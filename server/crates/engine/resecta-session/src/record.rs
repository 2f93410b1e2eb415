//! The durable log record: one line of a session's plan log, with its own versioned types,
//! converted explicitly to and from the planner's events. Renaming a field of the engine, the
//! HTTP API or the plan file changes no stored log; a change of this format gets a new
//! [`VERSION`], and every older version stays readable (`tests/fixtures/log-v1.jsonl`).
//!
//! - Version 2 (written): `{"v":2,"kind":"reset","plan":"<resecta-plan/1 text>"}`,
//!   `{"v":2,"kind":"edit","event":{"op":"set_control_point",…}}`, `{"v":2,"kind":"undo"}`,
//!   `{"v":2,"kind":"redo"}`. Resections inside events are plan-file resections
//!   (`resecta-plan/1`).
//! - Version 1 (read): no `v`; `{"type":"reset","plan":…}` and `{"type":"entry","entry":{"kind":…}}`
//!   with the same event objects.
//!
//! The metadata of the label-map summary and model blobs are records of this module too
//! ([`SummaryRecord`], [`ModelRecord`]), not the API's types.

use std::collections::BTreeMap;

use resecta_geom::{Real, RoleMap};
use resecta_plan::{Deformation, Group, LogEntry, PlanEvent, Resection, Target};
use serde::{Deserialize, Serialize};

use crate::api::{LabelMapSummary, ModelInfo, SurfaceKind};
use crate::error::{Result, SessionError};
use crate::support::internal;

/// The version written.
pub(crate) const VERSION: u32 = 2;

/// A record read back: a new base plan (its plan-file text) or a history entry.
#[derive(Debug)]
pub(crate) enum Step {
    Reset(String),
    Entry(LogEntry),
}

/// The record of a new base plan (`plan`: its `resecta-plan/1` text).
pub(crate) fn encode_reset(plan: String) -> Result<String> {
    encode(&Body::Reset { plan })
}

/// The record of one history entry.
pub(crate) fn encode_entry(entry: &LogEntry) -> Result<String> {
    encode(&match entry {
        LogEntry::Edit { event } => Body::Edit {
            event: EventRecord::from(event),
        },
        LogEntry::Undo => Body::Undo,
        LogEntry::Redo => Body::Redo,
    })
}

fn encode(body: &Body) -> Result<String> {
    serde_json::to_string(&V2 { v: VERSION, body }).map_err(internal)
}

/// Reads one record of any version.
pub(crate) fn decode(text: &str) -> Result<Step> {
    // serde's message quotes the record (resection names): give the place only.
    let corrupt = |e: serde_json::Error| {
        internal(format!(
            "unreadable log record ({:?} error at line {} column {})",
            e.classify(),
            e.line(),
            e.column()
        ))
    };
    let body = match serde_json::from_str::<Version>(text).map_err(corrupt)?.v {
        None => match serde_json::from_str::<V1>(text).map_err(corrupt)? {
            V1::Reset { plan } => Body::Reset { plan },
            V1::Entry { entry } => entry,
        },
        Some(VERSION) => {
            serde_json::from_str::<V2<Body>>(text)
                .map_err(corrupt)?
                .body
        }
        Some(v) => {
            return Err(SessionError::Internal(format!(
                "log record version {v} is newer than this server reads ({VERSION})"
            )));
        }
    };
    Ok(match body {
        Body::Reset { plan } => Step::Reset(plan),
        Body::Edit { event } => Step::Entry(LogEntry::Edit {
            event: event.into(),
        }),
        Body::Undo => Step::Entry(LogEntry::Undo),
        Body::Redo => Step::Entry(LogEntry::Redo),
    })
}

#[derive(Deserialize)]
struct Version {
    #[serde(default)]
    v: Option<u32>,
}

#[derive(Serialize, Deserialize)]
struct V2<B> {
    v: u32,
    #[serde(flatten)]
    body: B,
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
enum V1 {
    Reset { plan: String },
    Entry { entry: Body },
}

#[derive(Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
enum Body {
    Reset { plan: String },
    Edit { event: EventRecord },
    Undo,
    Redo,
}

#[derive(Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case", deny_unknown_fields)]
enum EventRecord {
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
        group: GroupRecord,
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
        target: TargetRecord,
    },
    AddTrace {
        name: String,
        trace: Vec<[Real; 3]>,
    },
    SetTrace {
        name: String,
        index: usize,
        trace: Vec<[Real; 3]>,
    },
    RemoveTrace {
        name: String,
        index: usize,
    },
    AddDeformation {
        name: String,
        deformation: DeformationRecord,
    },
    UndoDeformation {
        name: String,
    },
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct DeformationRecord {
    point: [Real; 3],
    offset_mm: Real,
    radius_mm: Real,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TargetRecord {
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    labels: Vec<u16>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    points: Vec<[Real; 3]>,
}

#[derive(Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
enum GroupRecord {
    Inner,
    Outer,
    Ring(usize),
    All,
}

impl From<&PlanEvent> for EventRecord {
    fn from(e: &PlanEvent) -> Self {
        match e.clone() {
            PlanEvent::AddResection { resection } => Self::AddResection { resection },
            PlanEvent::DeleteResection { name } => Self::DeleteResection { name },
            PlanEvent::SetControlPoint { name, i, j, point } => {
                Self::SetControlPoint { name, i, j, point }
            }
            PlanEvent::SetControlPoints { name, points } => Self::SetControlPoints { name, points },
            PlanEvent::MoveGroup { name, group, delta } => Self::MoveGroup {
                name,
                group: match group {
                    Group::Inner => GroupRecord::Inner,
                    Group::Outer => GroupRecord::Outer,
                    Group::Ring(k) => GroupRecord::Ring(k),
                    Group::All => GroupRecord::All,
                },
                delta,
            },
            PlanEvent::Translate { name, delta } => Self::Translate { name, delta },
            PlanEvent::Rotate {
                name,
                axis,
                angle_deg,
                centre,
            } => Self::Rotate {
                name,
                axis,
                angle_deg,
                centre,
            },
            PlanEvent::SetMargin { name, margin_mm } => Self::SetMargin { name, margin_mm },
            PlanEvent::SetBand { name, band_mm } => Self::SetBand { name, band_mm },
            PlanEvent::SetResolution { name, resolution } => {
                Self::SetResolution { name, resolution }
            }
            PlanEvent::SetTarget { name, target } => Self::SetTarget {
                name,
                target: TargetRecord {
                    labels: target.labels,
                    points: target.points,
                },
            },
            PlanEvent::AddTrace { name, trace } => Self::AddTrace { name, trace },
            PlanEvent::SetTrace { name, index, trace } => Self::SetTrace { name, index, trace },
            PlanEvent::RemoveTrace { name, index } => Self::RemoveTrace { name, index },
            PlanEvent::AddDeformation { name, deformation } => Self::AddDeformation {
                name,
                deformation: DeformationRecord {
                    point: deformation.point,
                    offset_mm: deformation.offset_mm,
                    radius_mm: deformation.radius_mm,
                },
            },
            PlanEvent::UndoDeformation { name } => Self::UndoDeformation { name },
        }
    }
}

impl From<EventRecord> for PlanEvent {
    fn from(e: EventRecord) -> Self {
        match e {
            EventRecord::AddResection { resection } => Self::AddResection { resection },
            EventRecord::DeleteResection { name } => Self::DeleteResection { name },
            EventRecord::SetControlPoint { name, i, j, point } => {
                Self::SetControlPoint { name, i, j, point }
            }
            EventRecord::SetControlPoints { name, points } => {
                Self::SetControlPoints { name, points }
            }
            EventRecord::MoveGroup { name, group, delta } => Self::MoveGroup {
                name,
                group: match group {
                    GroupRecord::Inner => Group::Inner,
                    GroupRecord::Outer => Group::Outer,
                    GroupRecord::Ring(k) => Group::Ring(k),
                    GroupRecord::All => Group::All,
                },
                delta,
            },
            EventRecord::Translate { name, delta } => Self::Translate { name, delta },
            EventRecord::Rotate {
                name,
                axis,
                angle_deg,
                centre,
            } => Self::Rotate {
                name,
                axis,
                angle_deg,
                centre,
            },
            EventRecord::SetMargin { name, margin_mm } => Self::SetMargin { name, margin_mm },
            EventRecord::SetBand { name, band_mm } => Self::SetBand { name, band_mm },
            EventRecord::SetResolution { name, resolution } => {
                Self::SetResolution { name, resolution }
            }
            EventRecord::SetTarget { name, target } => Self::SetTarget {
                name,
                target: Target {
                    labels: target.labels,
                    points: target.points,
                },
            },
            EventRecord::AddTrace { name, trace } => Self::AddTrace { name, trace },
            EventRecord::SetTrace { name, index, trace } => Self::SetTrace { name, index, trace },
            EventRecord::RemoveTrace { name, index } => Self::RemoveTrace { name, index },
            EventRecord::AddDeformation { name, deformation } => Self::AddDeformation {
                name,
                deformation: Deformation {
                    point: deformation.point,
                    offset_mm: deformation.offset_mm,
                    radius_mm: deformation.radius_mm,
                },
            },
            EventRecord::UndoDeformation { name } => Self::UndoDeformation { name },
        }
    }
}

/// A stored label-map summary.
#[derive(Serialize, Deserialize)]
pub(crate) struct SummaryRecord {
    dims: [usize; 3],
    spacing: [Real; 3],
    origin: [Real; 3],
    direction: [Real; 9],
    labels: BTreeMap<u16, u64>,
    liver_ml: Real,
    roles: RoleMap,
}

impl From<&LabelMapSummary> for SummaryRecord {
    fn from(s: &LabelMapSummary) -> Self {
        let s = s.clone();
        Self {
            dims: s.dims,
            spacing: s.spacing,
            origin: s.origin,
            direction: s.direction,
            labels: s.labels,
            liver_ml: s.liver_ml,
            roles: s.roles,
        }
    }
}

impl From<SummaryRecord> for LabelMapSummary {
    fn from(s: SummaryRecord) -> Self {
        Self {
            dims: s.dims,
            spacing: s.spacing,
            origin: s.origin,
            direction: s.direction,
            labels: s.labels,
            liver_ml: s.liver_ml,
            roles: s.roles,
        }
    }
}

/// A stored model's description.
#[derive(Serialize, Deserialize)]
pub(crate) struct ModelRecord {
    name: String,
    kind: KindRecord,
    #[serde(default)]
    label: u16,
    method: String,
    triangles: usize,
    vertices: usize,
    volume_ml: Real,
}

#[derive(Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
enum KindRecord {
    Parenchyma,
    Tumor,
    Portal,
    Hepatic,
    Vessel,
    Resection,
}

impl From<&ModelInfo> for ModelRecord {
    fn from(m: &ModelInfo) -> Self {
        Self {
            name: m.name.clone(),
            kind: match m.kind {
                SurfaceKind::Parenchyma => KindRecord::Parenchyma,
                SurfaceKind::Tumor => KindRecord::Tumor,
                SurfaceKind::Portal => KindRecord::Portal,
                SurfaceKind::Hepatic => KindRecord::Hepatic,
                SurfaceKind::Vessel => KindRecord::Vessel,
                SurfaceKind::Resection => KindRecord::Resection,
            },
            label: m.label,
            method: m.method.clone(),
            triangles: m.triangles,
            vertices: m.vertices,
            volume_ml: m.volume_ml,
        }
    }
}

impl From<ModelRecord> for ModelInfo {
    fn from(m: ModelRecord) -> Self {
        Self {
            name: m.name,
            kind: match m.kind {
                KindRecord::Parenchyma => SurfaceKind::Parenchyma,
                KindRecord::Tumor => SurfaceKind::Tumor,
                KindRecord::Portal => SurfaceKind::Portal,
                KindRecord::Hepatic => SurfaceKind::Hepatic,
                KindRecord::Vessel => SurfaceKind::Vessel,
                KindRecord::Resection => SurfaceKind::Resection,
            },
            label: m.label,
            method: m.method,
            triangles: m.triangles,
            vertices: m.vertices,
            volume_ml: m.volume_ml,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trace_and_deformation_events_round_trip_in_their_record_shape() {
        let trace = vec![[1.0, 2.0, 3.0], [4.0, 5.0, 3.0], [7.0, 1.0, 3.0]];
        let d = Deformation {
            point: [1.0, 2.0, 3.0],
            offset_mm: -4.5,
            radius_mm: 20.0,
        };
        let events = [
            PlanEvent::AddTrace {
                name: "d".into(),
                trace: trace.clone(),
            },
            PlanEvent::SetTrace {
                name: "d".into(),
                index: 2,
                trace,
            },
            PlanEvent::RemoveTrace {
                name: "d".into(),
                index: 0,
            },
            PlanEvent::AddDeformation {
                name: "c".into(),
                deformation: d,
            },
            PlanEvent::UndoDeformation { name: "c".into() },
        ];
        for event in events {
            let text = encode_entry(&LogEntry::Edit {
                event: event.clone(),
            })
            .unwrap();
            let Step::Entry(LogEntry::Edit { event: back }) = decode(&text).unwrap() else {
                panic!("not an edit: {text}");
            };
            assert_eq!(back, event);
        }
        let stored = r#"{"v":2,"kind":"edit","event":{"op":"add_deformation","name":"c","deformation":{"point":[1.0,2.0,3.0],"offset_mm":-4.5,"radius_mm":20.0}}}"#;
        assert!(matches!(
            decode(stored).unwrap(),
            Step::Entry(LogEntry::Edit {
                event: PlanEvent::AddDeformation { .. }
            })
        ));
    }

    #[test]
    fn a_summary_as_stored_by_version_1_reads_and_round_trips() {
        let stored = r#"{"dims":[3,4,5],"spacing":[0.8,0.8,2.5],"origin":[1.0,2.0,3.0],
            "direction":[1.0,0.0,0.0,0.0,1.0,0.0,0.0,0.0,1.0],"labels":{"1":40,"2":7},
            "liver_ml":0.5,"roles":{"parenchyma":[1],"tumor":[2]}}"#;
        let s: LabelMapSummary = serde_json::from_str::<SummaryRecord>(stored)
            .unwrap()
            .into();
        assert_eq!((s.dims, s.labels[&2], s.liver_ml), ([3, 4, 5], 7, 0.5));
        let again = serde_json::to_string(&SummaryRecord::from(&s)).unwrap();
        let back: LabelMapSummary = serde_json::from_str::<SummaryRecord>(&again)
            .unwrap()
            .into();
        assert_eq!(back, s);
    }
}
