//! Every error this face returns, mapped to a gRPC status once: operation-layer errors
//! ([`SessionError`]), access refusals ([`AccessError`]) and malformed wire input ([`WireError`],
//! from `resecta-face`).
//! Each status carries a `google.rpc.Status` in its details (the `grpc-status-details-bin`
//! trailer) whose one `Any` is a `resecta.v1.ErrorInfo`, as proto/README.md prescribes.

use prost::Message;
use resecta_api::ERROR_INFO_TYPE_URL;
use resecta_api::v1::ErrorInfo;
use resecta_auth::AccessError;
use resecta_face::{FaceError, WireError};
use resecta_session::{ErrorKind, SessionError};
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

/// A status with `info` in its details.
fn status(code: Code, message: String, info: ErrorInfo) -> Status {
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
    };
    if code == Code::Internal {
        tracing::error!(error = %e, "internal error");
    }
    let mut detail = info(e.code(), "");
    if let SessionError::StaleVersion { current, .. } = e {
        detail.current_plan_version = Some(*current);
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
    status(code, e.to_string(), info(name, field))
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
