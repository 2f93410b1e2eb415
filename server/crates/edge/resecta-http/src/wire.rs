//! JSON forms of the operation layer's answers that carry bytes: watch events (mesh payloads as
//! base64 of the `resecta-delta` encodings), reconstruction events and slice contours (packed
//! little-endian f32 triples, base64), and the server-sent events that carry them.

use axum::response::sse::Event;
use base64::Engine;
use base64::engine::general_purpose::STANDARD;
use resecta_geom::Polyline;
use resecta_plan::SliceProjections;
use resecta_session::SessionError;
use resecta_session::api::{ReconstructEvent, WatchBody, WatchEvent};
use serde::Serialize;
use serde_json::Value;

use crate::problem::Problem;

fn base64(bytes: &[u8]) -> Value {
    Value::String(STANDARD.encode(bytes))
}

/// Sets `key` of each object in the array `list` to the base64 of the matching `bytes`.
fn put_bytes<'a>(list: Option<&mut Value>, key: &str, bytes: impl Iterator<Item = &'a Vec<u8>>) {
    let Some(items) = list.and_then(Value::as_array_mut) else {
        return;
    };
    for (item, b) in items.iter_mut().zip(bytes) {
        if let Some(obj) = item.as_object_mut() {
            obj.insert(key.to_owned(), base64(b));
        }
    }
}

/// A watch event as JSON: its serde form with the mesh bytes (`mesh` of surfaces, `bytes` of
/// updates) added as base64.
pub fn watch_json(e: &WatchEvent) -> serde_json::Result<Value> {
    let mut v = serde_json::to_value(e)?;
    let body = v.get_mut("body");
    match &e.body {
        WatchBody::Snapshot {
            models, resections, ..
        } => {
            if let Some(body) = body {
                put_bytes(
                    body.get_mut("models"),
                    "mesh",
                    models.iter().map(|s| &s.mesh),
                );
                put_bytes(
                    body.get_mut("resections"),
                    "mesh",
                    resections.iter().map(|s| &s.mesh),
                );
            }
        }
        WatchBody::Delta { updates, .. } => put_bytes(
            body.and_then(|b| b.get_mut("updates")),
            "bytes",
            updates.iter().map(|u| &u.bytes),
        ),
        WatchBody::Models { models } => put_bytes(
            body.and_then(|b| b.get_mut("models")),
            "mesh",
            models.iter().map(|s| &s.mesh),
        ),
        WatchBody::Volumes { .. } => {}
    }
    Ok(v)
}

/// The SSE event name of a watch event.
fn watch_name(body: &WatchBody) -> &'static str {
    match body {
        WatchBody::Snapshot { .. } => "snapshot",
        WatchBody::Delta { .. } => "delta",
        WatchBody::Models { .. } => "models",
        WatchBody::Volumes { .. } => "volumes",
    }
}

/// An `error` event carrying a problem document (the stream ends after it).
pub fn error_event(p: &Problem) -> Event {
    Event::default()
        .event("error")
        .json_data(p)
        .unwrap_or_else(|_| Event::default().event("error"))
}

fn internal(e: impl std::fmt::Display) -> Problem {
    Problem::from(SessionError::Internal(e.to_string()))
}

/// A watch event as an SSE event: `id` = seq, `event` = snapshot | delta | models | volumes.
pub fn watch_event(e: &WatchEvent) -> Event {
    let event = watch_json(e).map_err(internal).and_then(|json| {
        Event::default()
            .id(e.seq.to_string())
            .event(watch_name(&e.body))
            .json_data(json)
            .map_err(internal)
    });
    event.unwrap_or_else(|p| error_event(&p))
}

/// A reconstruction event as an SSE event: `event` = progress | model | done.
pub fn reconstruct_event(e: &ReconstructEvent) -> Event {
    let name = match e {
        ReconstructEvent::Progress { .. } => "progress",
        ReconstructEvent::Model { .. } => "model",
        ReconstructEvent::Done { .. } => "done",
    };
    Event::default()
        .event(name)
        .json_data(e)
        .unwrap_or_else(|e| error_event(&internal(e)))
}

/// One contour: `points` as base64 of packed little-endian f32 (x, y, z) triples.
#[derive(Debug, Serialize)]
pub struct Contour {
    pub points: String,
    pub closed: bool,
}

/// Slice contours per plane.
#[derive(Debug, Serialize)]
pub struct Slices {
    pub axial: Vec<Contour>,
    pub coronal: Vec<Contour>,
    pub sagittal: Vec<Contour>,
}

impl From<&SliceProjections> for Slices {
    fn from(s: &SliceProjections) -> Self {
        let contours = |lines: &[Polyline]| {
            lines
                .iter()
                .map(|l| Contour {
                    points: STANDARD.encode(
                        l.points
                            .iter()
                            .flat_map(|p| [p.x as f32, p.y as f32, p.z as f32])
                            .flat_map(f32::to_le_bytes)
                            .collect::<Vec<u8>>(),
                    ),
                    closed: l.is_closed,
                })
                .collect()
        };
        Self {
            axial: contours(&s.axial),
            coronal: contours(&s.coronal),
            sagittal: contours(&s.sagittal),
        }
    }
}
