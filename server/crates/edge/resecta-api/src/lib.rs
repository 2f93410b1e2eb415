//! The `resecta.v1` gRPC API, generated from `proto/resecta/v1/*.proto` at build time: prost
//! messages, the tonic server trait and service
//! ([`v1::planning_service_server::PlanningService`], [`v1::planning_service_server::PlanningServiceServer`])
//! and the client ([`v1::planning_service_client::PlanningServiceClient`]), and every message's
//! serde impls in the canonical protobuf JSON mapping (pbjson: the HTTP face's bodies, equal to
//! what `json_format.MessageToJson` makes of the same message). No logic lives here.

/// Messages and stubs of package `resecta.v1`.
// Generated code; its style is prost's and tonic's (e.g. the inline `Snapshot` of
// `watch_response::Event` trips `large_enum_variant`).
#[allow(clippy::all)]
pub mod v1 {
    include!(concat!(env!("OUT_DIR"), "/resecta.v1.rs"));
    include!(concat!(env!("OUT_DIR"), "/resecta.v1.serde.rs"));
}

/// The encoded `google.protobuf.FileDescriptorSet` of every `resecta.v1` file (with source
/// comments), for `tonic-reflection` and API checks.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/resecta_v1.fds.bin"));

/// The API package, as `GetServerInfoResponse.api_version` reports it.
pub const API_VERSION: &str = "resecta.v1";

/// Metadata key by which clients state the API version they speak (value [`API_VERSION_HEADER_VALUE`]).
pub const API_VERSION_HEADER: &str = "resecta-api-version";

/// The value clients of this package send in [`API_VERSION_HEADER`].
pub const API_VERSION_HEADER_VALUE: &str = "v1";

/// Type URL of [`v1::ErrorInfo`] inside the `google.rpc.Status` details of an error.
pub const ERROR_INFO_TYPE_URL: &str = "type.googleapis.com/resecta.v1.ErrorInfo";

/// Largest `data` of one upload or export chunk (bytes).
pub const MAX_CHUNK_BYTES: usize = 4 << 20;
