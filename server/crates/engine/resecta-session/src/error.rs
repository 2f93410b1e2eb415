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

/// An operation-layer error.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error("no session {0:?}")]
    UnknownSession(String),
    #[error("{0}")]
    Invalid(String),
    #[error("{0}")]
    NotFound(String),
    #[error("the edit was made against plan version {base}, but the plan is at version {current}")]
    StaleVersion { base: u64, current: u64 },
    #[error("{0}")]
    Precondition(String),
    #[error("{0}")]
    Quota(String),
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
            Self::UnknownSession(_) | Self::NotFound(_) => ErrorKind::NotFound,
            Self::Invalid(_) => ErrorKind::InvalidArgument,
            Self::StaleVersion { .. } => ErrorKind::Conflict,
            Self::Precondition(_) => ErrorKind::FailedPrecondition,
            Self::Quota(_) => ErrorKind::ResourceExhausted,
            Self::Cancelled => ErrorKind::Cancelled,
            Self::Plan(e) => plan_kind(e),
            Self::Store(e) => match e {
                StoreError::NotFound { .. } => ErrorKind::NotFound,
                StoreError::AlreadyExists { .. } => ErrorKind::AlreadyExists,
                StoreError::Conflict { .. } => ErrorKind::Conflict,
                StoreError::TooLarge { .. } => ErrorKind::ResourceExhausted,
                StoreError::Invalid { .. } => ErrorKind::InvalidArgument,
                _ => ErrorKind::Internal,
            },
            Self::Internal(_) => ErrorKind::Internal,
        }
    }

    /// A short machine-readable code (`resecta.v1.ErrorInfo.code`, problem `type`).
    pub fn code(&self) -> &'static str {
        match self {
            Self::UnknownSession(_) => "unknown_session",
            Self::Invalid(_) => "invalid_argument",
            Self::NotFound(_) => "not_found",
            Self::StaleVersion { .. } => "stale_version",
            Self::Precondition(_) => "failed_precondition",
            Self::Quota(_) => "quota_exceeded",
            Self::Cancelled => "cancelled",
            Self::Plan(e) => match plan_kind(e) {
                ErrorKind::NotFound => "not_found",
                ErrorKind::FailedPrecondition => "failed_precondition",
                ErrorKind::ResourceExhausted => "quota_exceeded",
                ErrorKind::Internal => "internal",
                _ => "invalid_argument",
            },
            Self::Store(_) => "storage",
            Self::Internal(_) => "internal",
        }
    }
}

fn plan_kind(e: &PlanError) -> ErrorKind {
    match e {
        PlanError::UnknownResection(_) => ErrorKind::NotFound,
        PlanError::NothingToUndo | PlanError::NothingToRedo => ErrorKind::FailedPrecondition,
        PlanError::HistoryFull(_) | PlanError::TooManyResections(_) => ErrorKind::ResourceExhausted,
        PlanError::Volumetry(_) | PlanError::Margin(_) | PlanError::Recon(_) => ErrorKind::Internal,
        _ => ErrorKind::InvalidArgument,
    }
}

pub type Result<T, E = SessionError> = std::result::Result<T, E>;
