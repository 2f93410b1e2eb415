//! Errors of the wire: input refused before it reaches the operation layer ([`WireError`]), and
//! [`FaceError`], either that or an operation-layer error. Each face maps them to its statuses
//! once (`resecta-grpc`'s `error.rs`, `resecta-http`'s `problem.rs`); [`WireError::code`] is the
//! stable code both send.

use resecta_session::SessionError;

/// Request input refused before it reaches the operation layer.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    /// A field is missing, NaN, out of range, of the wrong length or UNSPECIFIED.
    #[error("{field}: {message}")]
    Invalid { field: String, message: String },
    /// An upload stream is malformed (header missing or repeated, chunk too big, wrong length).
    #[error("{field}: {message}")]
    BadChunk { field: String, message: String },
    /// An upload is larger than the server accepts.
    #[error("{0}")]
    TooLarge(String),
    /// A message would exceed the largest the server sends.
    #[error("{0}")]
    MessageTooLarge(String),
    /// The request needs a state or setting the server does not have.
    #[error("{field}: {message}")]
    Precondition { field: String, message: String },
    /// A valid request this server cannot serve (yet).
    #[error("{field}: {message}")]
    Unsupported { field: String, message: String },
}

impl WireError {
    /// An [`WireError::Invalid`] of `field`.
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self::Invalid {
            field: field.into(),
            message: message.into(),
        }
    }

    /// A [`WireError::BadChunk`] of `field`.
    pub fn bad_chunk(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self::BadChunk {
            field: field.into(),
            message: message.into(),
        }
    }

    /// The stable code both faces send (`ErrorInfo.code`, the problem's `code`).
    pub fn code(&self) -> &'static str {
        match self {
            Self::Invalid { .. } => "INVALID_ARGUMENT",
            Self::BadChunk { .. } => "BAD_CHUNK",
            Self::TooLarge(_) => "UPLOAD_TOO_LARGE",
            Self::MessageTooLarge(_) => "MESSAGE_TOO_LARGE",
            Self::Precondition { .. } => "FAILED_PRECONDITION",
            Self::Unsupported { .. } => "UNSUPPORTED",
        }
    }

    /// The offending request field (`ErrorInfo.field`), empty when none is to blame.
    pub fn field(&self) -> &str {
        match self {
            Self::Invalid { field, .. }
            | Self::BadChunk { field, .. }
            | Self::Precondition { field, .. }
            | Self::Unsupported { field, .. } => field,
            Self::TooLarge(_) | Self::MessageTooLarge(_) => "",
        }
    }
}

/// What a shared face operation fails with.
#[derive(Debug, thiserror::Error)]
pub enum FaceError {
    /// The request was malformed on the wire.
    #[error(transparent)]
    Wire(#[from] WireError),
    /// The operation layer refused or failed.
    #[error(transparent)]
    Session(#[from] SessionError),
}
