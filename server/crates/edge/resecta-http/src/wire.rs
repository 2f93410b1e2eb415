//! The server-sent events of the streaming RPCs: each event's data is the proto JSON of one
//! streamed response message (`WatchResponse`, `ReconstructResponse`; mesh bytes base64 as the
//! mapping has them), its name the message's `event` case; `error` events carry a problem.

use axum::response::sse::Event;
use resecta_api::v1 as pb;
use resecta_session::SessionError;
use serde::Serialize;

use crate::problem::Problem;

/// An `error` event carrying a problem document (the stream ends after it).
pub fn error_event(p: &Problem) -> Event {
    Event::default()
        .event("error")
        .json_data(p)
        .unwrap_or_else(|_| Event::default().event("error"))
}

/// An event named `name` whose data is `message`'s proto JSON.
fn event(name: &str, message: &impl Serialize) -> Event {
    Event::default()
        .event(name)
        .json_data(message)
        .unwrap_or_else(|e| error_event(&Problem::from(SessionError::Internal(e.to_string()))))
}

/// A watch message: `id` = seq, `event` = snapshot | delta | volumes.
pub fn watch_event(m: &pb::WatchResponse) -> Event {
    use pb::watch_response::Event as E;
    let name = match &m.event {
        Some(E::Snapshot(_)) => "snapshot",
        Some(E::Delta(_)) => "delta",
        Some(E::Volumes(_)) => "volumes",
        None => "message",
    };
    event(name, m).id(m.seq.to_string())
}

/// A reconstruction message: `event` = progress | model | done.
pub fn reconstruct_event(m: pb::ReconstructResponse) -> Event {
    use pb::reconstruct_response::Event as E;
    let name = match &m.event {
        Some(E::Progress(_)) => "progress",
        Some(E::Model(_)) => "model",
        Some(E::Done(_)) => "done",
        None => "message",
    };
    event(name, &m)
}
