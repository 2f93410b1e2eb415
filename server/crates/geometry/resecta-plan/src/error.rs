//! Errors of the planning engine; each names the offending resection, quantity or label.

use resecta_geom::GeomError;
use thiserror::Error;

#[derive(Debug, Error)]
pub enum PlanError {
    #[error("plan format {0:?} is not supported (expected \"resecta-plan/1\")")]
    Format(String),
    #[error("plan JSON: {0}")]
    Json(String),
    #[error("resection {name:?}: {what}")]
    InvalidResection { name: String, what: String },
    #[error("no resection named {0:?}")]
    UnknownResection(String),
    #[error("a resection named {0:?} already exists")]
    DuplicateName(String),
    #[error("the plan holds {0} resections; at most {max} are allowed", max = crate::MAX_RESECTIONS)]
    TooManyResections(usize),
    #[error("{what} must be finite, got {value:?}")]
    NonFinite { what: String, value: [f64; 3] },
    #[error("{0}")]
    InvalidArgument(String),
    #[error("nothing to undo")]
    NothingToUndo,
    #[error("nothing to redo")]
    NothingToRedo,
    #[error("history holds {0} entries; at most {max} are allowed", max = crate::history::MAX_LOG)]
    HistoryFull(usize),
    #[error("label {0} is not present in the label map")]
    LabelAbsent(u16),
    #[error("label {0} is not a tumour label of the role map")]
    NotATumourLabel(u16),
    #[error("the role map names no tumour label")]
    NoTumour,
    #[error("tumour label {0} does not touch the liver parenchyma")]
    TumourOutsideLiver(u16),
    #[error("no tumour component contains or lies within 5 mm of the target point {0:?}")]
    NoTumourAtPoint([f64; 3]),
    #[error("the end point is within 1 mm of the tumour centroid: the slicing plane is undefined")]
    EndPointAtCentroid,
    #[error("the slicing plane misses the liver")]
    PlaneMissesLiver,
    #[error("the liver mask is empty (no parenchyma voxels)")]
    EmptyLiver,
    #[error("reconstruction: {0}")]
    Recon(#[from] resecta_recon::ReconError),
    #[error("Bézier surface: {0}")]
    Bezier(#[from] resecta_bezier::BezierError),
    #[error("margins: {0}")]
    Margin(#[from] resecta_margin::MarginError),
    #[error("volumetry: {0}")]
    Volumetry(#[from] resecta_volumetry::VolumetryError),
    #[error("geometry: {0}")]
    Geometry(#[from] GeomError),
}

impl PlanError {
    pub(crate) fn resection(name: &str, what: impl Into<String>) -> Self {
        Self::InvalidResection {
            name: name.to_owned(),
            what: what.into(),
        }
    }
}
