//! Every error this face returns, mapped to a gRPC status once: operation-layer errors
//! ([`SessionError`]), access refusals ([`AccessError`]) and malformed wire input ([`WireError`],
//! from `resecta-face`).
//! Each status carries a `google.rpc.Status` in its details (the `grpc-status-details-bin`
//! trailer) whose one `Any` is a `resecta.v1.ErrorInfo`, as proto/README.md prescribes.
//!
//! Status messages, details and `ErrorInfo` never carry client text (issue #19): the messages of
//! the errors mapped here name no value the client sent (ids appear as a
//! [`resecta_session::IdPrefix`] at most), and every message is bounded
//! ([`resecta_face::bounded_message`]) because it travels in metadata twice, whose size the
//! client limits: an echoed 10 KB id made a client see RESOURCE_EXHAUSTED for a NOT_FOUND.

use std::collections::HashSet;
use std::sync::OnceLock;

use prost::Message;
use resecta_api::v1::{ErrorInfo, ReplicaAddress};
use resecta_api::{ERROR_INFO_TYPE_URL, FILE_DESCRIPTOR_SET};
use resecta_auth::AccessError;
use resecta_face::{FaceError, WireError, bounded_message};
use resecta_session::{ErrorKind, IdPrefix, SessionError};
use tonic::{Code, Status};

/// `google.rpc.Status`, the payload of a status' details.
#[derive(Clone, PartialEq, Message)]
pub struct RpcStatus {
    /// The gRPC status code.
    #[prost(int32, tag = "1")]
    pub code: i32,
    /// The status message.
    #[prost(string, tag = "2")]
    pub message: String,
    /// One `resecta.v1.ErrorInfo`.
    #[prost(message, repeated, tag = "3")]
    pub details: Vec<prost_types::Any>,
}

/// A status with `info` in its details; `message` is bounded here.
fn status(code: Code, message: String, info: ErrorInfo) -> Status {
    let message = bounded_message(message);
    let details = RpcStatus {
        code: code as i32,
        message: message.clone(),
        details: vec![prost_types::Any {
            type_url: ERROR_INFO_TYPE_URL.to_owned(),
            value: info.encode_to_vec(),
        }],
    };
    Status::with_details(code, message, details.encode_to_vec().into())
}

fn info(code: &str, field: &str) -> ErrorInfo {
    ErrorInfo {
        code: code.to_owned(),
        field: field.to_owned(),
        current_plan_version: None,
        replica: None,
    }
}

/// The status of an operation-layer error (the table of docs/server.md).
pub fn session_status(e: &SessionError) -> Status {
    let code = match e.kind() {
        ErrorKind::InvalidArgument => Code::InvalidArgument,
        ErrorKind::NotFound => Code::NotFound,
        ErrorKind::AlreadyExists => Code::AlreadyExists,
        ErrorKind::Conflict => Code::Aborted,
        ErrorKind::FailedPrecondition => Code::FailedPrecondition,
        ErrorKind::ResourceExhausted => Code::ResourceExhausted,
        ErrorKind::Cancelled => Code::Cancelled,
        ErrorKind::Internal => Code::Internal,
        ErrorKind::Elsewhere => Code::Unavailable,
    };
    if code == Code::Internal {
        tracing::error!(error = %e, "internal error");
    }
    let mut detail = info(e.code(), "");
    if let SessionError::StaleVersion { current, .. } = e {
        detail.current_plan_version = Some(*current);
    } else if let SessionError::Elsewhere(Some(at)) = e {
        detail.replica = Some(ReplicaAddress {
            id: at.id.clone(),
            grpc_address: at.grpc.clone(),
            http_url: at.http.clone(),
            lease_remaining_ms: at.lease_remaining_ms,
        });
    }
    status(code, e.to_string(), detail)
}

/// The status of a refused call: UNAUTHENTICATED, or FAILED_PRECONDITION for a version mismatch.
pub fn access_status(e: &AccessError) -> Status {
    let (code, name, field) = if e.is_auth() {
        (Code::Unauthenticated, "UNAUTHENTICATED", "authorization")
    } else {
        (
            Code::FailedPrecondition,
            "API_VERSION_MISMATCH",
            resecta_api::API_VERSION_HEADER,
        )
    };
    status(code, access_message(e), info(name, field))
}

/// An access refusal's message: the version a client sent is shown as an id prefix at most.
fn access_message(e: &AccessError) -> String {
    match e {
        AccessError::VersionMismatch { client, server } => format!(
            "the client speaks API version {} but this server speaks {server:?} (resecta.v1); \
             upgrade the client or the server",
            IdPrefix::of(client)
        ),
        AccessError::MissingToken | AccessError::MalformedToken | AccessError::WrongToken => {
            e.to_string()
        }
    }
}

/// The method of a call as logs may show it: the path when it names a method this server
/// serves (`/resecta.v1.PlanningService/Edit`, health, reflection), else `"unknown"` (a
/// path is the client's text).
pub fn method_for_logs(path: &str) -> &'static str {
    static KNOWN: OnceLock<HashSet<String>> = OnceLock::new();
    let known = KNOWN.get_or_init(|| {
        let mut known: HashSet<String> = [
            "/grpc.health.v1.Health/Check",
            "/grpc.health.v1.Health/Watch",
            "/grpc.reflection.v1.ServerReflection/ServerReflectionInfo",
            "/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo",
        ]
        .map(str::to_owned)
        .into();
        if let Ok(set) = prost_types::FileDescriptorSet::decode(FILE_DESCRIPTOR_SET) {
            for file in &set.file {
                for service in &file.service {
                    for method in &service.method {
                        known.insert(format!(
                            "/{}.{}/{}",
                            file.package(),
                            service.name(),
                            method.name()
                        ));
                    }
                }
            }
        }
        known
    });
    known.get(path).map_or("unknown", String::as_str)
}

/// The status of malformed wire input.
pub fn wire_status(e: &WireError) -> Status {
    let code = match e {
        WireError::Invalid { .. } | WireError::BadChunk { .. } => Code::InvalidArgument,
        WireError::TooLarge(_) | WireError::MessageTooLarge(_) => Code::ResourceExhausted,
        WireError::Precondition { .. } => Code::FailedPrecondition,
        WireError::Unsupported { .. } => Code::Unimplemented,
    };
    status(code, e.to_string(), info(e.code(), e.field()))
}

/// The status of a shared face operation's error.
pub fn face_status(e: &FaceError) -> Status {
    match e {
        FaceError::Wire(e) => wire_status(e),
        FaceError::Session(e) => session_status(e),
    }
}

/// `?`-friendly conversion of operation-layer results inside the handlers.
pub(crate) trait OrStatus<T> {
    fn or_status(self) -> Result<T, Status>;
}

impl<T> OrStatus<T> for Result<T, SessionError> {
    fn or_status(self) -> Result<T, Status> {
        self.map_err(|e| session_status(&e))
    }
}

impl<T> OrStatus<T> for Result<T, WireError> {
    fn or_status(self) -> Result<T, Status> {
        self.map_err(|e| wire_status(&e))
    }
}

/// Decodes the [`ErrorInfo`] of a status made here (or by any server following
/// proto/README.md); `None` when the details hold none.
pub fn error_info(status: &Status) -> Option<ErrorInfo> {
    RpcStatus::decode(status.details())
        .ok()?
        .details
        .iter()
        .find(|any| any.type_url == ERROR_INFO_TYPE_URL)
        .and_then(|any| ErrorInfo::decode(any.value.as_slice()).ok())
}

#[cfg(test)]
mod tests {
    use super::*;

    const MARKER: &str = "PATIENTMARKER";

    #[test]
    fn only_the_server_s_methods_are_logged_by_name() {
        for m in [
            "/resecta.v1.PlanningService/Edit",
            "/resecta.v1.PlanningService/UploadLabelMap",
            "/grpc.health.v1.Health/Check",
        ] {
            assert_eq!(method_for_logs(m), m);
        }
        for path in [
            format!("/resecta.v1.PlanningService/{MARKER}"),
            format!("/{MARKER}/Edit"),
            "/".repeat(10_000),
        ] {
            assert_eq!(method_for_logs(&path), "unknown");
        }
    }

    #[test]
    fn statuses_are_bounded_and_show_versions_as_prefixes() {
        let long = format!("{MARKER}{}", "x".repeat(10_000));
        let s = session_status(&SessionError::UnknownSession(long.as_str().into()));
        assert_eq!(s.code(), Code::NotFound);
        assert!(!s.message().contains(MARKER) && s.message().len() < 100);
        assert!(
            s.details().len() < 200,
            "{} bytes of details",
            s.details().len()
        );
        let s = wire_status(&WireError::invalid("x", "y".repeat(100_000)));
        assert!(s.message().len() <= resecta_face::MAX_ERROR_MESSAGE_BYTES + 3);
        let s = access_status(&AccessError::VersionMismatch {
            client: format!("v2 {MARKER}"),
            server: "v1",
        });
        assert!(!s.message().contains(MARKER), "{}", s.message());
        let s = access_status(&AccessError::VersionMismatch {
            client: "v2".into(),
            server: "v1",
        });
        assert!(s.message().contains("\"v2\""), "{}", s.message());
    }
}
