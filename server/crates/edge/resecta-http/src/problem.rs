//! Every error of the HTTP face as an RFC 9457 `application/problem+json` document, mapped once
//! from [`SessionError`], [`WireError`] and [`AccessError`].
//!
//! A problem's `detail` never carries client text (issue #19). The errors mapped here name no
//! value the client sent; the messages of the parsers of bodies, queries and paths (serde,
//! axum), which quote what they were given, go through [`Problem::invalid`], which cuts what
//! they quote; a path in a message is shown by [`path_for_messages`]; and every detail is
//! bounded ([`bounded_message`]).

use std::collections::HashSet;
use std::sync::OnceLock;

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use resecta_auth::AccessError;
use resecta_face::{FaceError, WireError, bounded_message};
use resecta_session::{ErrorKind, IdPrefix, SessionError};
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
    /// The replica holding the session (`SESSION_ELSEWHERE` only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub replica: Option<Box<ReplicaProblem>>,
    /// Adds `WWW-Authenticate: Bearer` (401 answers).
    #[serde(skip)]
    pub challenge: bool,
}

impl Problem {
    /// A problem; `detail` (this crate's words) is bounded.
    pub fn new(status: StatusCode, code: &'static str, detail: impl Into<String>) -> Self {
        Self {
            type_uri: format!("urn:resecta:problem:{code}"),
            title: status
                .canonical_reason()
                .unwrap_or("Client Closed Request")
                .to_owned(),
            status: status.as_u16(),
            detail: bounded_message(detail.into()),
            code,
            current_version: None,
            replica: None,
            challenge: false,
        }
    }

    /// 400 `invalid_argument`. `detail` may be a parser's message about the request (serde,
    /// axum's extractors): what it quotes is cut ([`redact_quotes`]).
    pub fn invalid(detail: impl Into<String>) -> Self {
        Self::new(
            StatusCode::BAD_REQUEST,
            "INVALID_ARGUMENT",
            redact_quotes(&detail.into()),
        )
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

/// Where the replica holding a session is reached (the gRPC face's `ReplicaAddress`).
#[derive(Debug, Clone, Serialize)]
pub struct ReplicaProblem {
    pub id: String,
    pub grpc_address: String,
    pub http_url: String,
    pub lease_remaining_ms: u64,
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
        ErrorKind::Elsewhere => StatusCode::MISDIRECTED_REQUEST,
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
        } else if let SessionError::Elsewhere(Some(at)) = e {
            p.replica = Some(Box::new(ReplicaProblem {
                id: at.id,
                grpc_address: at.grpc,
                http_url: at.http,
                lease_remaining_ms: at.lease_remaining_ms,
            }));
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
        // The version a client sent is its text: shown as an id prefix at most.
        let detail = match &e {
            AccessError::VersionMismatch { client, server } => format!(
                "the client speaks API version {} but this server speaks {server:?} \
                 (resecta.v1); upgrade the client or the server",
                IdPrefix::of(client)
            ),
            AccessError::MissingToken | AccessError::MalformedToken | AccessError::WrongToken => {
                e.to_string()
            }
        };
        let mut p = Self::new(status, e.code(), detail);
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

/// axum's query-string rejection: the message after it starts with the path of the offending
/// key (serde_path_to_error), which is the client's key, unquoted.
const QUERY_REJECTION: &str = "Failed to deserialize query string: ";

/// How serde's messages begin (`serde::de::Error`'s constructors).
const SERDE_MESSAGES: [&str; 7] = [
    "unknown field",
    "unknown variant",
    "invalid type",
    "invalid value",
    "invalid length",
    "missing field",
    "duplicate field",
];

/// A parser's message about a request without what it quotes of the request. serde and axum
/// quote the input they were given in backticks or double quotes (escaped or not), before the
/// schema's words, which follow the last `, expected`: everything from the first quote to the
/// last quote before that point becomes `…`. The key path axum puts before a query string's
/// serde message is dropped. A message that quotes nothing is kept.
pub fn redact_quotes(message: &str) -> String {
    if let Some(rest) = message.strip_prefix(QUERY_REJECTION) {
        // The message is the last one to begin before the first quote (a key the path shows
        // may hold such words too, and what follows the first quote is quoted input).
        let first_quote = rest.find(['`', '"']).unwrap_or(rest.len());
        let serde = SERDE_MESSAGES
            .iter()
            .filter_map(|m| rest[..first_quote].rfind(m))
            .max()
            .or_else(|| SERDE_MESSAGES.iter().filter_map(|m| rest.find(m)).min());
        return match serde {
            Some(at) => format!("{QUERY_REJECTION}{}", redact_quotes(&rest[at..])),
            None => format!("{QUERY_REJECTION}a parameter is malformed"),
        };
    }
    let cut = message.rfind(", expected").unwrap_or(message.len());
    let (head, tail) = message.split_at(cut);
    let quote = |c: char| c == '`' || c == '"';
    match (head.find(quote), head.rfind(quote)) {
        (Some(first), Some(last)) => format!("{}…{}{tail}", &head[..first], &head[last + 1..]),
        _ => message.to_owned(),
    }
}

/// A request path as messages may show it: the segments of the API's routes (`v1`,
/// `sessions`, `label-map`, ...) as they are, any other segment (an id, a name, whatever a
/// client typed) as an [`IdPrefix`].
pub fn path_for_messages(path: &str) -> String {
    static LITERALS: OnceLock<HashSet<&'static str>> = OnceLock::new();
    let literals = LITERALS.get_or_init(|| {
        crate::routes()
            .into_iter()
            .flat_map(|r| r.path.split('/'))
            .filter(|s| !s.starts_with('{'))
            .collect()
    });
    path.split('/')
        .map(|segment| {
            if literals.contains(segment) {
                segment.to_owned()
            } else {
                IdPrefix::of(segment).to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("/")
}

#[cfg(test)]
mod tests {
    use super::*;

    const MARKER: &str = "PATIENTMARKER";

    #[test]
    fn parser_messages_lose_what_they_quote_but_keep_the_schema() {
        let cases = [
            (
                format!(
                    "request body: unknown field `{MARKER}`, expected one of `displayName` at line 1 column 17"
                ),
                "request body: unknown field …, expected one of `displayName` at line 1 column 17",
            ),
            (
                format!(
                    "request body: unknown variant `a`{MARKER}`, expected one of `X`, `Y` at line 1 column 9"
                ),
                "request body: unknown variant …, expected one of `X`, `Y` at line 1 column 9",
            ),
            (
                format!(
                    "request body: invalid type: string \"a\\\", expected {MARKER}\", expected u64 at line 1 column 40"
                ),
                "request body: invalid type: string …, expected u64 at line 1 column 40",
            ),
            (
                format!(
                    "Failed to deserialize query string: {MARKER}: unknown field `{MARKER}`, expected `raw` or `file`"
                ),
                "Failed to deserialize query string: unknown field …, expected `raw` or `file`",
            ),
            (
                format!(
                    "Failed to deserialize query string: a {MARKER}: b: unknown field `a {MARKER}: b`, expected `raw` or `file`"
                ),
                "Failed to deserialize query string: unknown field …, expected `raw` or `file`",
            ),
            (
                format!(
                    "Failed to deserialize query string: {MARKER} unknown field: unknown field `{MARKER} unknown field`, expected `raw` or `file`"
                ),
                "Failed to deserialize query string: unknown field …, expected `raw` or `file`",
            ),
            (
                format!("Failed to deserialize query string: {MARKER}: something else"),
                "Failed to deserialize query string: a parameter is malformed",
            ),
            (
                format!("query: unknown parameter {MARKER:?}"),
                "query: unknown parameter …",
            ),
            (
                format!("Cannot parse `{MARKER}` to a `u64`"),
                "Cannot parse …",
            ),
            (
                "request body: EOF while parsing a value at line 1 column 0".to_owned(),
                "request body: EOF while parsing a value at line 1 column 0",
            ),
        ];
        for (message, expected) in cases {
            let p = Problem::invalid(message);
            assert!(!p.detail.contains(MARKER), "{}", p.detail);
            assert_eq!(p.detail, expected);
        }
    }

    #[test]
    fn paths_show_route_words_and_id_prefixes() {
        let id = "3f2a9c1b0d4e5f60718293a4b5c6d7e8";
        assert_eq!(
            path_for_messages(&format!("/v1/sessions/{id}/label-map")),
            "/v1/sessions/\"3f2a9c1b…\"/label-map"
        );
        let p = path_for_messages(&format!("/v1/sessions/x/models/{MARKER}%20liver/{MARKER}"));
        assert!(!p.contains(MARKER), "{p}");
        assert!(p.starts_with("/v1/sessions/\"x\"/models/<an id of"), "{p}");
    }

    #[test]
    fn details_are_bounded_and_versions_are_prefixes() {
        let long = format!("{MARKER}{}", "x".repeat(10_000));
        let p = Problem::from(SessionError::UnknownSession(long.as_str().into()));
        assert!(
            !p.detail.contains(MARKER) && p.detail.len() < 100,
            "{}",
            p.detail
        );
        let p = Problem::new(StatusCode::BAD_REQUEST, "X", "y".repeat(100_000));
        assert!(p.detail.len() <= resecta_face::MAX_ERROR_MESSAGE_BYTES + 3);
        let p = Problem::from(AccessError::VersionMismatch {
            client: format!("v2 {MARKER}"),
            server: "v1",
        });
        assert!(!p.detail.contains(MARKER), "{}", p.detail);
    }
}
