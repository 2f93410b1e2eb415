//! Errors of the metrics.

use resecta_geom::{GeomError, Real};

/// What can be wrong with the input of a metric. Messages name the offending quantity.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MetricsError {
    #[error("no reference points")]
    NoPoints,
    #[error("reference point {0} is not finite")]
    NonFinitePoint(usize),
    #[error("mesh has no triangles")]
    EmptyMesh,
    #[error("percentiles [{lo}, {hi}] must satisfy 0 ≤ lo ≤ hi ≤ 100")]
    BadPercentiles { lo: Real, hi: Real },
    #[error("no vertex has a defined curvature (every vertex is on a boundary or has zero area)")]
    NoCurvature,
    #[error("no model records")]
    NoRecords,
    #[error("model {label:?}: {field} must be finite and non-negative")]
    BadRecord { label: String, field: &'static str },
    #[error("model label {0:?} is used twice")]
    DuplicateLabel(String),
    #[error(transparent)]
    Geom(#[from] GeomError),
}
