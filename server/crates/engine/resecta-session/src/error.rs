//! Errors of the operation layer, each with the [`ErrorKind`] the edges map to a gRPC status or
//! an HTTP problem, once. Messages name the quantity at fault and never patient data (display
//! names, file names, label-map contents).

use resecta_plan::PlanError;
use resecta_store::StoreError;

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

/// An operation-layer error.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error("no session {0:?}")]
    UnknownSession(String),
    #[error("{0}")]
    Invalid(String),
    /// An uploaded label map that cannot be read or does not match its geometry.
    #[error("{0}")]
    BadLabelMap(String),
    #[error("no model or resection {0:?}")]
    ModelNotFound(String),
    #[error("the edit was made against plan version {base}, but the plan is at version {current}")]
    StaleVersion { base: u64, current: u64 },
    #[error("{1}")]
    Precondition(Missing, String),
    #[error("{1}")]
    Quota(Quota, String),
    #[error("cancelled")]
    Cancelled,
    #[error("plan: {0}")]
    Plan(#[from] PlanError),
    #[error("storage: {0}")]
    Store(#[from] StoreError),
    #[error("internal: {0}")]
    Internal(String),
}

impl SessionError {
    pub fn kind(&self) -> ErrorKind {
        match self {
            Self::UnknownSession(_) | Self::ModelNotFound(_) => ErrorKind::NotFound,
            Self::Invalid(_) | Self::BadLabelMap(_) => ErrorKind::InvalidArgument,
            Self::StaleVersion { .. } => ErrorKind::Conflict,
            Self::Precondition(..) => ErrorKind::FailedPrecondition,
            Self::Quota(..) => ErrorKind::ResourceExhausted,
            Self::Cancelled => ErrorKind::Cancelled,
            Self::Plan(e) => plan_class(e).0,
            Self::Store(e) => store_class(e).0,
            Self::Internal(_) => ErrorKind::Internal,
        }
    }

    /// The stable machine-readable code both faces send (`resecta.v1.ErrorInfo.code`, the
    /// problem's `code`); the table is in proto/README.md.
    pub fn code(&self) -> &'static str {
        match self {
            Self::UnknownSession(_) => "SESSION_NOT_FOUND",
            Self::ModelNotFound(_) => "MODEL_NOT_FOUND",
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
    }
}

pub type Result<T, E = SessionError> = std::result::Result<T, E>;
