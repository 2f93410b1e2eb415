//! What the two faces of the planning server (gRPC in `resecta-grpc`, HTTP/JSON in
//! `resecta-http`) share, so that they are one API: both take and give the `resecta.v1`
//! messages (the HTTP face in their canonical proto JSON), and both translate them to and from
//! the operation layer ([`resecta_session::Service`]) here, once.
//!
//! - [`convert`]: wire ⇄ operation types, with the wire validation the message types cannot
//!   express (required fields, finite numbers, lengths, UNSPECIFIED enums, label ranges);
//! - [`error`]: [`WireError`] (input refused before the operation layer) and [`FaceError`]
//!   (that or a [`resecta_session::SessionError`]), which each face maps to its statuses once;
//! - [`info`]: the one `GetServerInfoResponse` (limits, capabilities) both faces report;
//! - [`upload`]: a label-map upload assembled from its header and data;
//! - [`watch`]: a session's watch events as `WatchResponse` messages (snapshots in parts);
//! - [`shutdown`]: long-lived streams ended once the server shuts down.

pub mod convert;
pub mod error;
pub mod info;
pub mod shutdown;
pub mod upload;
pub mod watch;

pub use error::{FaceError, MAX_ERROR_MESSAGE_BYTES, WireError, bounded_message};
pub use shutdown::{SHUTTING_DOWN, ShutdownSignal, until_shutdown};

/// Largest message the server sends (`ServerLimits.max_message_bytes`): one snapshot part
/// holding one big surface. Clients raise their receive limit to it.
pub const MAX_MESSAGE_BYTES: usize = 64 << 20;

/// Snapshot parts are filled up to this; a larger single surface travels in a part of its own.
pub const SNAPSHOT_PART_BYTES: usize = resecta_api::MAX_CHUNK_BYTES;
