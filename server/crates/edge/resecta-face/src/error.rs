//! Errors of the wire: input refused before it reaches the operation layer ([`WireError`]), and
//! [`FaceError`], either that or an operation-layer error. Each face maps them to its statuses
//! once (`resecta-grpc`'s `error.rs`, `resecta-http`'s `problem.rs`); [`WireError::code`] is the
//! stable code both send.
//!
//! No error carries client text (issue #19): a [`WireError`]'s field and message are this
//! crate's words and numbers, never a value, name or id the request held; ids are shown as a
//! [`resecta_session::IdPrefix`] at most. Both faces pass every message through
//! [`bounded_message`] as a last guard: a status message travels in gRPC metadata (twice:
//! `grpc-message` and the details), whose size clients limit.

use resecta_session::SessionError;

/// The longest message (bytes) an error response carries; longer ones are cut at a character
/// boundary and end with `…`.
pub const MAX_ERROR_MESSAGE_BYTES: usize = 1024;

/// `m`, cut to at most [`MAX_ERROR_MESSAGE_BYTES`] (plus the `…` that marks the cut).
pub fn bounded_message(mut m: String) -> String {
    if m.len() > MAX_ERROR_MESSAGE_BYTES {
        let mut end = MAX_ERROR_MESSAGE_BYTES;
        while !m.is_char_boundary(end) {
            end -= 1;
        }
        m.truncate(end);
        m.push('…');
    }
    m
}

/// Request input refused before it reaches the operation layer. `field` names the request field
/// (its path in the message, with indices) and `message` what is wrong: neither repeats the
/// value the client sent.
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_are_bounded_at_a_character_boundary() {
        assert_eq!(bounded_message("short".into()), "short");
        let long = "é".repeat(MAX_ERROR_MESSAGE_BYTES);
        let cut = bounded_message(long);
        assert!(
            cut.len() <= MAX_ERROR_MESSAGE_BYTES + '…'.len_utf8(),
            "{}",
            cut.len()
        );
        assert!(cut.ends_with('…') && cut.starts_with("éé"));
    }
}
