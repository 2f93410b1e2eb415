//! The watch stream of both faces: the session's [`WatchStream`] pulled one event at a time as
//! the client reads (the transport's flow control is the back-pressure; nothing queues here
//! beyond one snapshot's parts), each event translated to `WatchResponse` messages.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::Arc;

use futures_util::Stream;
use prost::Message;
use resecta_api::v1 as pb;
use resecta_api::v1::resection_surface::Mesh;
use resecta_api::v1::watch_response::Event;
use resecta_plan::{Resection, Verdict};
use resecta_session::api::{WatchBody, WatchEvent};
use resecta_session::{Service, SessionError, WatchStream};

use crate::convert;
use crate::error::{FaceError, WireError};
use crate::{MAX_MESSAGE_BYTES, SNAPSHOT_PART_BYTES};

/// Room left in a message for its envelope (seq, version, field tags and lengths).
const ENVELOPE_BYTES: usize = 64;

/// Snapshot parts of at most [`SNAPSHOT_PART_BYTES`] each, except that a single surface larger
/// than that travels alone (up to [`MAX_MESSAGE_BYTES`]).
#[derive(Debug)]
struct Parts {
    parts: Vec<pb::Snapshot>,
    size: usize,
}

impl Parts {
    fn new(session: pb::Session) -> Self {
        let size = session.encoded_len();
        Self {
            parts: vec![pb::Snapshot {
                session: Some(session),
                ..pb::Snapshot::default()
            }],
            size,
        }
    }

    /// The part that takes `len` more bytes for the surface `name`.
    fn room(&mut self, name: &str, len: usize) -> Result<&mut pb::Snapshot, WireError> {
        let len = len + ENVELOPE_BYTES;
        if len > MAX_MESSAGE_BYTES {
            return Err(WireError::MessageTooLarge(format!(
                "surface {name:?} needs {len} bytes, more than the largest message ({MAX_MESSAGE_BYTES} bytes)"
            )));
        }
        if self.size + len > SNAPSHOT_PART_BYTES && self.size > 0 {
            self.parts.push(pb::Snapshot::default());
            self.size = 0;
        }
        self.size += len;
        let last = self.parts.len() - 1;
        Ok(&mut self.parts[last])
    }
}

fn resection_surface(
    name: &str,
    params: &BTreeMap<String, Resection>,
    verdicts: &BTreeMap<String, Verdict>,
    mesh: Option<Mesh>,
) -> pb::ResectionSurface {
    pb::ResectionSurface {
        name: name.to_owned(),
        resection: params.get(name).map(convert::resection),
        verdict: verdicts.get(name).map(convert::verdict),
        mesh,
    }
}

/// The messages of one event; `None` for a models event (the stream then takes a fresh
/// snapshot, which holds the new models).
fn responses(
    e: &WatchEvent,
    session: Option<pb::Session>,
) -> Result<Option<Vec<pb::WatchResponse>>, WireError> {
    let wrap = |event| pb::WatchResponse {
        seq: e.seq,
        plan_version: e.plan_version,
        event: Some(event),
    };
    Ok(Some(match &e.body {
        WatchBody::Snapshot {
            models,
            resections,
            verdicts,
            resection_params,
            volumes,
        } => {
            let mut parts = Parts::new(session.unwrap_or_default());
            for m in models {
                let s = convert::surface(m);
                parts.room(&s.name, s.encoded_len())?.models.push(s);
            }
            for r in resections {
                let mesh = Some(Mesh::FullMesh(r.mesh.clone()));
                let s = resection_surface(&r.name, resection_params, verdicts, mesh);
                parts.room(&s.name, s.encoded_len())?.resections.push(s);
            }
            if let Some(v) = volumes {
                let v = convert::volumes(v);
                let len = v.encoded_len();
                parts.room("volumes", len)?.volumes = Some(v);
            }
            let mut parts = parts.parts;
            if let Some(last) = parts.last_mut() {
                last.complete = true;
            }
            parts
                .into_iter()
                .map(|p| wrap(Event::Snapshot(p)))
                .collect()
        }
        WatchBody::Delta {
            updates,
            removed,
            resections,
            verdicts,
        } => {
            let mut out: Vec<pb::ResectionSurface> = updates
                .iter()
                .map(|u| {
                    let mesh = if u.full {
                        Mesh::FullMesh(u.bytes.clone())
                    } else {
                        Mesh::MeshDelta(u.bytes.clone())
                    };
                    resection_surface(&u.name, resections, verdicts, Some(mesh))
                })
                .collect();
            let updated: BTreeSet<&str> = updates.iter().map(|u| u.name.as_str()).collect();
            out.extend(
                resections
                    .keys()
                    .filter(|n| !updated.contains(n.as_str()))
                    .map(|n| resection_surface(n, resections, verdicts, None)),
            );
            vec![wrap(Event::Delta(pb::Delta {
                resections: out,
                removed: removed.clone(),
            }))]
        }
        WatchBody::Volumes { volumes } => vec![wrap(Event::Volumes(convert::volumes(volumes)))],
        WatchBody::Models { .. } => return Ok(None),
    }))
}

#[derive(Debug)]
struct State {
    service: Arc<Service>,
    id: String,
    events: WatchStream,
    pending: VecDeque<pb::WatchResponse>,
    ended: bool,
}

impl State {
    /// The next message, pulling the session's stream only when nothing is pending.
    async fn next(&mut self) -> Option<Result<pb::WatchResponse, FaceError>> {
        loop {
            if let Some(m) = self.pending.pop_front() {
                return Some(Ok(m));
            }
            if self.ended {
                return None;
            }
            match self.step().await {
                Ok(()) => {}
                Err(e) => {
                    self.ended = true;
                    return Some(Err(e));
                }
            }
        }
    }

    async fn step(&mut self) -> Result<(), FaceError> {
        let event = match self.events.next().await {
            Some(e) => e?,
            // The hub closes when the session is deleted or expires.
            None => return Err(SessionError::UnknownSession(self.id.as_str().into()).into()),
        };
        let session = match event.body {
            WatchBody::Snapshot { .. } => {
                Some(convert::session(&self.service.get_session(&self.id).await?))
            }
            WatchBody::Delta { .. } | WatchBody::Models { .. } | WatchBody::Volumes { .. } => None,
        };
        match responses(&event, session)? {
            Some(messages) => self.pending.extend(messages),
            None => self.events = self.service.watch(&self.id, None).await?,
        }
        Ok(())
    }
}

/// Refuses a watch whose client cannot decode the mesh payloads this server sends (zstd
/// compressed or quantised: `allow_zstd` / `allow_quantized` must then be set).
pub fn check_payloads(service: &Service, r: &pb::WatchRequest) -> Result<(), WireError> {
    let encode = &service.config().encode;
    let refuse = |field: &str, what: &str| WireError::Precondition {
        field: field.to_owned(),
        message: format!("this server sends {what} mesh payloads; the client must accept them"),
    };
    if encode.zstd_level.is_some() && !r.allow_zstd {
        return Err(refuse("allow_zstd", "zstd-compressed"));
    }
    if encode.quantise.is_some() && !r.allow_quantized {
        return Err(refuse("allow_quantized", "quantised"));
    }
    Ok(())
}

/// The `WatchResponse` messages of session `id` after `since` (absent: a snapshot first). It
/// ends after its first error (a deleted session is `UnknownSession`).
pub async fn watch(
    service: Arc<Service>,
    id: String,
    since: Option<u64>,
) -> Result<impl Stream<Item = Result<pb::WatchResponse, FaceError>> + Send + 'static, SessionError>
{
    let events = service.watch(&id, since).await?;
    let state = State {
        service,
        id,
        events,
        pending: VecDeque::new(),
        ended: false,
    };
    Ok(futures_util::stream::unfold(state, |mut s| async move {
        s.next().await.map(|m| (m, s))
    }))
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use resecta_session::api::{Surface, SurfaceKind};

    use super::*;

    fn surface(name: &str, kind: SurfaceKind, bytes: usize) -> Surface {
        Surface::new(name.into(), kind, vec![7; bytes])
    }

    #[test]
    fn snapshots_split_into_parts_that_fit() {
        let mib = 1 << 20;
        let event = WatchEvent {
            seq: 9,
            plan_version: 4,
            body: WatchBody::Snapshot {
                models: vec![
                    surface("parenchyma", SurfaceKind::Parenchyma, 3 * mib),
                    surface("tumor_1", SurfaceKind::Tumor, mib / 2),
                    surface("portal_1", SurfaceKind::Portal, 9 * mib),
                ],
                resections: vec![surface("r1", SurfaceKind::Resection, 2 * mib)],
                verdicts: BTreeMap::new(),
                resection_params: BTreeMap::new(),
                volumes: None,
            },
        };
        let session = pb::Session {
            id: "s".into(),
            ..pb::Session::default()
        };
        let parts = responses(&event, Some(session)).unwrap().unwrap();
        let snapshots: Vec<&pb::Snapshot> = parts
            .iter()
            .map(|m| match &m.event {
                Some(Event::Snapshot(s)) => s,
                other => panic!("{other:?}"),
            })
            .collect();
        // parenchyma + tumour | portal alone (over the part size) | r1.
        let names: Vec<Vec<&str>> = snapshots
            .iter()
            .map(|s| {
                s.models
                    .iter()
                    .map(|m| m.name.as_str())
                    .chain(s.resections.iter().map(|r| r.name.as_str()))
                    .collect()
            })
            .collect();
        assert_eq!(
            names,
            [vec!["parenchyma", "tumor_1"], vec!["portal_1"], vec!["r1"]]
        );
        assert!(parts.iter().all(|m| m.seq == 9 && m.plan_version == 4));
        assert!(parts.iter().all(|m| m.encoded_len() <= MAX_MESSAGE_BYTES));
        assert!(snapshots[0].session.is_some() && snapshots[1].session.is_none());
        let complete: Vec<bool> = snapshots.iter().map(|s| s.complete).collect();
        assert_eq!(complete, [false, false, true]);

        // A models event becomes a fresh snapshot (no messages of its own).
        let models = WatchEvent {
            seq: 1,
            plan_version: 1,
            body: WatchBody::Models { models: Vec::new() },
        };
        assert!(responses(&models, None).unwrap().is_none());
        // A single surface over the largest message is refused.
        let mut parts = Parts::new(pb::Session::default());
        assert!(matches!(
            parts.room("big", MAX_MESSAGE_BYTES),
            Err(WireError::MessageTooLarge(_))
        ));
    }
}
