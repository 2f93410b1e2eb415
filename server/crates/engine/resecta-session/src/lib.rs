//! The planning server's operation layer (issue #6): patient sessions over a
//! [`resecta_store::SessionStore`], label-map upload, reconstruction, resection edits with plan
//! versions, volumetry, plan import/export, model export, slice projections, per-session
//! watch streams of mesh snapshots and deltas, and point clouds closed into surfaces (no
//! session). The gRPC and HTTP edges call [`Service`] and map
//! [`SessionError::kind`] to their status codes; no algorithm lives here.

pub mod api;
mod budget;
mod config;
mod edits;
mod error;
mod labelmap;
mod log;
mod ownership;
mod pools;
mod recon;
mod record;
mod registry;
mod service;
mod sessions;
mod state;
mod support;
mod volumes;
mod watch;

pub use budget::UploadMemory;
pub use config::{ReplicaConfig, ServiceConfig};
pub use error::{
    ErrorKind, ID_PREFIX_CHARS, IdPrefix, Missing, Quota, Result, SessionError, is_id_char,
    redact_quoted,
};
pub use service::Service;
pub use watch::{RingBounds, WatchStream};
