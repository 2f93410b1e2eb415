//! Every error of the HTTP face as an RFC 9457 `application/problem+json` document, mapped once
//! from [`SessionError`], [`WireError`] and [`AccessError`].

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use resecta_auth::AccessError;
use resecta_face::{FaceError, WireError};
use resecta_session::{ErrorKind, SessionError};
use serde::Serialize;

/// Media type of problem documents.
pub const PROBLEM_JSON: &str = "application/problem+json";

/// Nginx's "client closed request": the operation was cancelled.
const CLIENT_CLOSED: u16 = 499;

/// An error response: `type` is `urn:resecta:problem:<code>`, `title` the status' reason,
/// `detail` the message (never patient data), `code` the stable machine-readable code shared
/// with the gRPC face's `ErrorInfo`, and for stale plan versions `current_version`.
#[derive(Debug, Clone, Serialize)]
pub struct Problem {
    #[serde(rename = "type")]
    pub type_uri: String,
    pub title: String,
    pub status: u16,
    pub detail: String,
    pub code: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub current_version: Option<u64>,
    /// Adds `WWW-Authenticate: Bearer` (401 answers).
    #[serde(skip)]
    pub challenge: bool,
}

impl Problem {
    pub fn new(status: StatusCode, code: &'static str, detail: impl Into<String>) -> Self {
        Self {
            type_uri: format!("urn:resecta:problem:{code}"),
            title: status
                .canonical_reason()
                .unwrap_or("Client Closed Request")
                .to_owned(),
            status: status.as_u16(),
            detail: detail.into(),
            code,
            current_version: None,
            challenge: false,
        }
    }

    /// 400 `invalid_argument`.
    pub fn invalid(detail: impl Into<String>) -> Self {
        Self::new(StatusCode::BAD_REQUEST, "INVALID_ARGUMENT", detail)
    }

    /// 413 `payload_too_large`.
    pub fn too_large(limit: u64) -> Self {
        Self::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "PAYLOAD_TOO_LARGE",
            format!("the request body exceeds the limit of {limit} bytes"),
        )
    }
}

/// The HTTP status of each operation-layer error kind (docs/server.md, "Errors").
fn status_of(kind: ErrorKind) -> StatusCode {
    match kind {
        ErrorKind::InvalidArgument => StatusCode::BAD_REQUEST,
        ErrorKind::NotFound => StatusCode::NOT_FOUND,
        ErrorKind::AlreadyExists | ErrorKind::Conflict | ErrorKind::FailedPrecondition => {
            StatusCode::CONFLICT
        }
        ErrorKind::ResourceExhausted => StatusCode::TOO_MANY_REQUESTS,
        ErrorKind::Cancelled => {
            StatusCode::from_u16(CLIENT_CLOSED).unwrap_or(StatusCode::BAD_REQUEST)
        }
        ErrorKind::Internal => StatusCode::INTERNAL_SERVER_ERROR,
    }
}

impl From<SessionError> for Problem {
    fn from(e: SessionError) -> Self {
        let status = if e.is_payload_too_large() {
            StatusCode::PAYLOAD_TOO_LARGE
        } else {
            status_of(e.kind())
        };
        if status.is_server_error() {
            tracing::error!(code = e.code(), error = %e, "operation failed");
        }
        let mut p = Self::new(status, e.code(), e.to_string());
        if let SessionError::StaleVersion { current, .. } = e {
            p.current_version = Some(current);
        }
        p
    }
}

impl From<WireError> for Problem {
    fn from(e: WireError) -> Self {
        let status = match &e {
            WireError::Invalid { .. } | WireError::BadChunk { .. } => StatusCode::BAD_REQUEST,
            WireError::TooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            WireError::MessageTooLarge(_) => StatusCode::TOO_MANY_REQUESTS,
            WireError::Precondition { .. } => StatusCode::CONFLICT,
            WireError::Unsupported { .. } => StatusCode::NOT_IMPLEMENTED,
        };
        Self::new(status, e.code(), e.to_string())
    }
}

impl From<FaceError> for Problem {
    fn from(e: FaceError) -> Self {
        match e {
            FaceError::Wire(e) => e.into(),
            FaceError::Session(e) => e.into(),
        }
    }
}

impl From<AccessError> for Problem {
    fn from(e: AccessError) -> Self {
        let status = if e.is_auth() {
            StatusCode::UNAUTHORIZED
        } else {
            StatusCode::BAD_REQUEST
        };
        let mut p = Self::new(status, e.code(), e.to_string());
        p.challenge = e.is_auth();
        p
    }
}

impl IntoResponse for Problem {
    fn into_response(self) -> Response {
        let status = StatusCode::from_u16(self.status).unwrap_or(StatusCode::INTERNAL_SERVER_ERROR);
        let body = serde_json::to_vec(&self).unwrap_or_default();
        let mut res = (
            status,
            [(header::CONTENT_TYPE, HeaderValue::from_static(PROBLEM_JSON))],
            body,
        )
            .into_response();
        if self.challenge {
            res.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Bearer realm=\"resecta\""),
            );
        }
        res
    }
}
