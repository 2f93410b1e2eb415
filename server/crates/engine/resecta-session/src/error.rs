//! Errors of the operation layer, each with the [`ErrorKind`] the edges map to a gRPC status or
//! an HTTP problem, once. Messages name the quantity at fault and never client text (display
//! names, resection and model names, file names and contents, ids beyond an [`IdPrefix`]):
//! they reach clients, logs and gRPC metadata.

use std::fmt;

use resecta_plan::PlanError;
use resecta_store::StoreError;

use crate::api::ReplicaAddress;

/// What went wrong, as the edges need it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorKind {
    /// Bad input: the request can never succeed as sent.
    InvalidArgument,
    NotFound,
    AlreadyExists,
    /// The edit was made against an older plan version.
    Conflict,
    /// The session is not in the state the operation needs (no label map yet, ...).
    FailedPrecondition,
    /// A quota (sessions, voxels, memory, upload size) would be exceeded.
    ResourceExhausted,
    Cancelled,
    /// Storage or another internal failure; the request may be retried.
    Internal,
    /// Another replica of a replicated server holds the session: repeat the call there.
    Elsewhere,
}

/// Which quota a request would exceed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quota {
    /// Sessions held by the server.
    Sessions,
    /// Voxels of one label map.
    Voxels,
    /// Bytes of one upload.
    UploadBytes,
    /// Memory of the loaded sessions together.
    Memory,
}

/// What a session lacks for an operation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Missing {
    LabelMap,
    Models,
    /// Anything else (the message says what).
    Other,
}

/// How many characters of a client-supplied id an error may show.
pub const ID_PREFIX_CHARS: usize = 8;

/// What of a client-supplied id an error may show: its first [`ID_PREFIX_CHARS`] characters,
/// and only when the whole id is made of id characters (ASCII letters, digits, `-`, `_`); else
/// only its length. Ids are client text of any size (a 10 KB id echoed in gRPC metadata would
/// overflow a client's limit) and may be anything a client typed; the server's own ids (32 hex
/// digits) are told apart by their prefix.
#[derive(Clone, PartialEq, Eq)]
pub struct IdPrefix {
    /// The shown prefix (empty when nothing is shown).
    shown: String,
    /// The id's length in characters.
    chars: usize,
}

impl IdPrefix {
    /// The shown part of `id`.
    pub fn of(id: &str) -> Self {
        let showable = id.chars().all(is_id_char);
        Self {
            shown: if showable {
                id.chars().take(ID_PREFIX_CHARS).collect()
            } else {
                String::new()
            },
            chars: id.chars().count(),
        }
    }
}

/// The characters of an id an error may show.
pub fn is_id_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '-' || c == '_'
}

impl From<&str> for IdPrefix {
    fn from(id: &str) -> Self {
        Self::of(id)
    }
}

impl From<String> for IdPrefix {
    fn from(id: String) -> Self {
        Self::of(&id)
    }
}

impl fmt::Display for IdPrefix {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let n = self.chars;
        if self.shown.is_empty() && n > 0 {
            write!(
                f,
                "<an id of {n} characters, not all letters, digits, '-' or '_'>"
            )
        } else if n > ID_PREFIX_CHARS {
            write!(f, "\"{}…\"", self.shown)
        } else {
            write!(f, "\"{}\"", self.shown)
        }
    }
}

impl fmt::Debug for IdPrefix {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "IdPrefix({self})")
    }
}

/// An operation-layer error. Its message (`Display`, and `Debug`, which repeats it) names the
/// quantity at fault and never carries client text: no display names, resection or model names,
/// file names or contents, and of ids at most an [`IdPrefix`]. Plan and storage errors, whose
/// own messages quote names and ids, are shown without them, and are not given as a `source`.
#[derive(thiserror::Error)]
pub enum SessionError {
    #[error("no session {0}")]
    UnknownSession(IdPrefix),
    #[error("{0}")]
    Invalid(String),
    /// An uploaded label map that cannot be read or does not match its geometry.
    #[error("{0}")]
    BadLabelMap(String),
    /// A model or resection the request names does not exist (the name is not kept).
    #[error("no model or resection of that name")]
    ModelNotFound,
    #[error("the edit was made against plan version {base}, but the plan is at version {current}")]
    StaleVersion { base: u64, current: u64 },
    #[error("{1}")]
    Precondition(Missing, String),
    #[error("{1}")]
    Quota(Quota, String),
    #[error("cancelled")]
    Cancelled,
    #[error("plan: {}", plan_message(.0))]
    Plan(PlanError),
    #[error("storage: {}", store_message(.0))]
    Store(StoreError),
    /// Another replica holds the session's lease (its address when known).
    #[error("{}", elsewhere_message(.0.as_ref()))]
    Elsewhere(Option<ReplicaAddress>),
    #[error("internal: {0}")]
    Internal(String),
}

impl From<PlanError> for SessionError {
    fn from(e: PlanError) -> Self {
        Self::Plan(e)
    }
}

impl From<StoreError> for SessionError {
    fn from(e: StoreError) -> Self {
        Self::Store(e)
    }
}

impl fmt::Debug for SessionError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "SessionError({}: {self})", self.code())
    }
}

/// A plan error's message without the names it quotes: resection names are client text.
fn plan_message(e: &PlanError) -> String {
    match e {
        PlanError::Format(_) => format!(
            "plan format is not supported (expected {:?})",
            resecta_plan::FORMAT
        ),
        PlanError::Json(m) => json_message(m),
        PlanError::InvalidResection { what, .. } => format!("resection: {}", redact_quoted(what)),
        PlanError::UnknownResection(_) => "no resection of that name".into(),
        PlanError::DuplicateName(_) => "a resection of that name already exists".into(),
        PlanError::NonFinite { what, value } => {
            format!("{} must be finite, got {value:?}", redact_quoted(what))
        }
        PlanError::InvalidArgument(m) => redact_quoted(m),
        PlanError::TooManyResections(_)
        | PlanError::NothingToUndo
        | PlanError::NothingToRedo
        | PlanError::HistoryFull(_)
        | PlanError::LabelAbsent(_)
        | PlanError::NotATumourLabel(_)
        | PlanError::NoTumour
        | PlanError::TumourOutsideLiver(_)
        | PlanError::NoTumourAtPoint(_)
        | PlanError::EndPointAtCentroid
        | PlanError::PlaneMissesLiver
        | PlanError::EmptyLiver
        | PlanError::Recon(_)
        | PlanError::Bezier(_)
        | PlanError::Margin(_)
        | PlanError::Volumetry(_)
        | PlanError::Geometry(_) => redact_quoted(&e.to_string()),
    }
}

/// A plan file's JSON error: serde's messages quote the document (names, values), so only the
/// place is kept, or a message that quotes nothing (the size limit).
fn json_message(m: &str) -> String {
    let place = m.rfind(" at line ").map(|k| &m[k + 4..]).filter(|tail| {
        tail.split_whitespace()
            .all(|w| matches!(w, "line" | "column") || w.parse::<u64>().is_ok())
    });
    match place {
        Some(place) => format!("plan JSON is not a valid resecta plan ({place})"),
        None if !m.contains(['"', '`', '\'']) => format!("plan JSON: {m}"),
        None => "plan JSON is not a valid resecta plan".into(),
    }
}

fn elsewhere_message(at: Option<&ReplicaAddress>) -> String {
    match at {
        Some(r) => format!(
            "the session is held by replica {} (gRPC {}, HTTP {}); repeat the call there",
            r.id, r.grpc, r.http
        ),
        None => "the session is now held by another replica; repeat the call".into(),
    }
}

/// A storage error's message with ids cut to an [`IdPrefix`].
fn store_message(e: &StoreError) -> String {
    match e {
        StoreError::NotFound { id } => format!("no session {}", IdPrefix::of(id)),
        StoreError::AlreadyExists { id } => {
            format!("session {} already exists", IdPrefix::of(id))
        }
        StoreError::Conflict { .. }
        | StoreError::TooLarge { .. }
        | StoreError::Invalid { .. }
        | StoreError::Corrupt { .. }
        | StoreError::SchemaTooNew { .. }
        | StoreError::Backend(_) => e.to_string(),
        StoreError::Fenced { id } => format!(
            "session {} is held by another replica: this replica's lease on it has ended",
            IdPrefix::of(id)
        ),
    }
}

/// `m` with every string it quotes as Rust's `Debug` does (`"…"`, with `\"` and `\\` escapes),
/// which is how the engine's messages quote names, replaced by `"…"`.
pub fn redact_quoted(m: &str) -> String {
    let mut out = String::with_capacity(m.len());
    let mut chars = m.chars();
    while let Some(c) = chars.next() {
        if c != '"' {
            out.push(c);
            continue;
        }
        while let Some(d) = chars.next() {
            match d {
                '\\' => {
                    chars.next();
                }
                '"' => break,
                _ => {}
            }
        }
        out.push_str("\"…\"");
    }
    out
}

impl SessionError {
    pub fn kind(&self) -> ErrorKind {
        match self {
            Self::UnknownSession(_) | Self::ModelNotFound => ErrorKind::NotFound,
            Self::Invalid(_) | Self::BadLabelMap(_) => ErrorKind::InvalidArgument,
            Self::StaleVersion { .. } => ErrorKind::Conflict,
            Self::Precondition(..) => ErrorKind::FailedPrecondition,
            Self::Quota(..) => ErrorKind::ResourceExhausted,
            Self::Cancelled => ErrorKind::Cancelled,
            Self::Plan(e) => plan_class(e).0,
            Self::Store(e) => store_class(e).0,
            Self::Internal(_) => ErrorKind::Internal,
            Self::Elsewhere(_) => ErrorKind::Elsewhere,
        }
    }

    /// The stable machine-readable code both faces send (`resecta.v1.ErrorInfo.code`, the
    /// problem's `code`); the table is in proto/README.md.
    pub fn code(&self) -> &'static str {
        match self {
            Self::UnknownSession(_) => "SESSION_NOT_FOUND",
            Self::ModelNotFound => "MODEL_NOT_FOUND",
            Self::Invalid(_) => "INVALID_ARGUMENT",
            Self::BadLabelMap(_) => "BAD_LABEL_MAP",
            Self::StaleVersion { .. } => "STALE_VERSION",
            Self::Precondition(Missing::LabelMap, _) => "NO_LABEL_MAP",
            Self::Precondition(Missing::Models, _) => "MODELS_NOT_BUILT",
            Self::Precondition(Missing::Other, _) => "FAILED_PRECONDITION",
            Self::Quota(Quota::Sessions, _) => "SESSION_QUOTA",
            Self::Quota(Quota::Voxels, _) => "VOXEL_QUOTA",
            Self::Quota(Quota::UploadBytes, _) => "UPLOAD_TOO_LARGE",
            Self::Quota(Quota::Memory, _) => "MEMORY_QUOTA",
            Self::Cancelled => "CANCELLED",
            Self::Plan(e) => plan_class(e).1,
            Self::Store(e) => store_class(e).1,
            Self::Internal(_) => "INTERNAL",
            Self::Elsewhere(_) => "SESSION_ELSEWHERE",
        }
    }

    /// Whether the request's payload is what is too large (an upload's bytes, voxels or the
    /// memory they need) rather than a quota of the server (sessions, plan size).
    pub fn is_payload_too_large(&self) -> bool {
        matches!(
            self,
            Self::Quota(Quota::Voxels | Quota::UploadBytes | Quota::Memory, _)
                | Self::Store(StoreError::TooLarge { .. })
        )
    }
}

/// Status kind and code of an engine error, in one exhaustive match so a new variant needs both.
fn plan_class(e: &PlanError) -> (ErrorKind, &'static str) {
    match e {
        PlanError::UnknownResection(_) => (ErrorKind::NotFound, "RESECTION_NOT_FOUND"),
        PlanError::NothingToUndo => (ErrorKind::FailedPrecondition, "NOTHING_TO_UNDO"),
        PlanError::NothingToRedo => (ErrorKind::FailedPrecondition, "NOTHING_TO_REDO"),
        PlanError::HistoryFull(_) | PlanError::TooManyResections(_) => {
            (ErrorKind::ResourceExhausted, "PLAN_QUOTA")
        }
        PlanError::Volumetry(_) | PlanError::Margin(_) | PlanError::Recon(_) => {
            (ErrorKind::Internal, "INTERNAL")
        }
        PlanError::Format(_) | PlanError::Json(_) => (ErrorKind::InvalidArgument, "BAD_PLAN"),
        PlanError::InvalidResection { .. }
        | PlanError::DuplicateName(_)
        | PlanError::NonFinite { .. }
        | PlanError::InvalidArgument(_)
        | PlanError::LabelAbsent(_)
        | PlanError::NotATumourLabel(_)
        | PlanError::NoTumour
        | PlanError::TumourOutsideLiver(_)
        | PlanError::NoTumourAtPoint(_)
        | PlanError::EndPointAtCentroid
        | PlanError::PlaneMissesLiver
        | PlanError::EmptyLiver
        | PlanError::Bezier(_)
        | PlanError::Geometry(_) => (ErrorKind::InvalidArgument, "INVALID_ARGUMENT"),
    }
}

/// Status kind and code of a storage error (one exhaustive match).
fn store_class(e: &StoreError) -> (ErrorKind, &'static str) {
    match e {
        StoreError::NotFound { .. } => (ErrorKind::NotFound, "SESSION_NOT_FOUND"),
        StoreError::AlreadyExists { .. } => (ErrorKind::AlreadyExists, "STORAGE"),
        StoreError::Conflict { .. } => (ErrorKind::Conflict, "STALE_VERSION"),
        StoreError::TooLarge { .. } => (ErrorKind::ResourceExhausted, "UPLOAD_TOO_LARGE"),
        StoreError::Invalid { .. } => (ErrorKind::InvalidArgument, "STORAGE"),
        StoreError::Corrupt { .. } | StoreError::SchemaTooNew { .. } | StoreError::Backend(_) => {
            (ErrorKind::Internal, "STORAGE")
        }
        StoreError::Fenced { .. } => (ErrorKind::Elsewhere, "SESSION_ELSEWHERE"),
    }
}

pub type Result<T, E = SessionError> = std::result::Result<T, E>;

#[cfg(test)]
mod tests {
    use super::*;

    const MARKER: &str = "PATIENTMARKER";

    fn clean(e: &SessionError) -> String {
        let (shown, debug) = (e.to_string(), format!("{e:?}"));
        assert!(
            !shown.contains(MARKER),
            "the message carries client text: {shown}"
        );
        assert!(
            !debug.contains(MARKER),
            "the Debug carries client text: {debug}"
        );
        shown
    }

    #[test]
    fn ids_show_a_short_prefix_of_id_characters_at_most() {
        let server_made = "3f2a9c1b0d4e5f60718293a4b5c6d7e8";
        assert_eq!(
            SessionError::UnknownSession(server_made.into()).to_string(),
            "no session \"3f2a9c1b…\""
        );
        assert_eq!(
            SessionError::UnknownSession("nope".into()).to_string(),
            "no session \"nope\""
        );
        assert_eq!(
            SessionError::UnknownSession("".into()).to_string(),
            "no session \"\""
        );
        // A 10 KB id: a bounded message (it goes into gRPC metadata) without the marker.
        let long = format!("{MARKER}{}", "x".repeat(10_000));
        let m = clean(&SessionError::UnknownSession(long.as_str().into()));
        assert_eq!(m, "no session \"PATIENTM…\"");
        // Not made of id characters (a name typed as an id): nothing of it is shown.
        let typed = format!("Jane {MARKER} scan");
        let m = clean(&SessionError::UnknownSession(typed.into()));
        assert!(!m.contains("Jane") && m.contains("23 characters"), "{m}");
        let m = clean(&SessionError::UnknownSession(
            format!("ab\"{MARKER}").into(),
        ));
        assert!(!m.contains("ab"), "{m}");
    }

    #[test]
    fn names_are_never_shown() {
        let m = clean(&SessionError::ModelNotFound);
        assert!(m.contains("model or resection"), "{m}");
        let name = || MARKER.to_owned();
        let quoted = format!("resection {:?}: point (1, 2)", format!("a\"{MARKER}\\"));
        let cases = [
            PlanError::UnknownResection(name()),
            PlanError::DuplicateName(name()),
            PlanError::InvalidResection {
                name: name(),
                what: format!("margin_mm must be positive (resection {MARKER:?})"),
            },
            PlanError::NonFinite {
                what: quoted.clone(),
                value: [f64::NAN, 0.0, 0.0],
            },
            PlanError::InvalidArgument(format!(
                "log entry 3: {}",
                PlanError::UnknownResection(name())
            )),
            PlanError::Format(name()),
            PlanError::Json(format!(
                "unknown variant `{MARKER}`, expected one of `a`, `b` at line 3 column 14"
            )),
            PlanError::Json(format!("invalid type: string {MARKER:?}, expected a map")),
        ];
        for e in cases {
            let m = clean(&SessionError::from(e));
            assert!(m.starts_with("plan: "), "{m}");
        }
        let m = clean(&SessionError::from(PlanError::NonFinite {
            what: quoted,
            value: [f64::NAN, 0.0, 0.0],
        }));
        assert!(m.contains("point (1, 2) must be finite"), "{m}");
        let m = clean(&SessionError::from(PlanError::Json(
            "EOF while parsing a value at line 1 column 0".into(),
        )));
        assert!(m.ends_with("(line 1 column 0)"), "{m}");
    }

    #[test]
    fn storage_errors_show_id_prefixes_and_no_source() {
        let long = format!("{MARKER}{}", "y".repeat(5000));
        for e in [
            StoreError::NotFound { id: long.clone() },
            StoreError::AlreadyExists { id: long.clone() },
        ] {
            let e = SessionError::from(e);
            let m = clean(&e);
            assert!(m.contains("\"PATIENTM…\"") && m.len() < 80, "{m}");
            assert!(std::error::Error::source(&e).is_none());
        }
        let e = SessionError::from(PlanError::UnknownResection(MARKER.into()));
        assert!(std::error::Error::source(&e).is_none());
        assert_eq!(e.code(), "RESECTION_NOT_FOUND");
    }

    #[test]
    fn redaction_follows_debug_escapes() {
        let text = format!("a {:?} b {:?} c", format!("x\\\"{MARKER}"), "plain");
        assert_eq!(redact_quoted(&text), "a \"…\" b \"…\" c");
        assert_eq!(redact_quoted("unclosed \"PATIENTMARKER"), "unclosed \"…\"");
        assert_eq!(redact_quoted("no quotes (1, 2)"), "no quotes (1, 2)");
    }
}
