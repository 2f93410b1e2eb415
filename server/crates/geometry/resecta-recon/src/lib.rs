//! Surface models from label maps (thesis ch. 6, Paper I).
//!
//! - [`cloud`]: PSR of point clouds with or without normals (catheter points, Paper IV).
//! - [`psr`]: Poisson surface reconstruction from the mask's oriented points (parenchyma), its
//!   multigrid on a [`PoissonSolver`] (CPU by default; `resecta-gpu` has the device's).
//! - [`mcsd`]: marching cubes, decimation, windowed-sinc smoothing — 3D Slicer's method
//!   (tumours, vessels, and the comparison).
//! - [`models`]: the complete patient model of Fig. 6.9: one mesh per vessel label (segment), per
//!   tumour component, and the liver; specks counted, not modelled.
//! - [`quality`]: accuracy against the oriented points, polygons, volume, curvature.
//! - [`study`]: the Paper I study (PSR depths × MCSD parameters, σ, Pareto front) and the
//!   per-patient choice of depth.
//!
//! Everything is in RAS mm; masks may be oblique and anisotropic.

pub mod cloud;
pub mod mask;
pub mod mcsd;
pub mod models;
pub mod psr;
pub mod quality;
pub mod study;

pub use cloud::{
    CloudModel, CloudOptions, CloudReport, DEFAULT_CLOUD_DEPTH, DEFAULT_CLOUD_NEIGHBOURS,
    MAX_CLOUD_NEIGHBOURS, MIN_CLOUD_NEIGHBOURS, MIN_CLOUD_POINTS, NormalSource, orient_cloud,
    reconstruct_cloud,
};
pub use mcsd::McsdParams;
pub use models::{
    Dropped, ModelOptions, ParenchymaMethod, PatientModel, PatientModels, SPECK_MM3,
    patient_models, patient_models_with,
};
pub use psr::{PsrModel, SurfaceDiff};
pub use quality::{Quality, measure};
pub use resecta_poisson::{PoissonError, PoissonSolver};

use resecta_geom::GeomError;

/// What can go wrong building models. Messages name the offending quantity.
#[derive(Debug, thiserror::Error)]
pub enum ReconError {
    #[error("no labels given")]
    NoLabels,
    #[error("label(s) {labels:?} do not occur in the label map")]
    LabelsAbsent { labels: Vec<u16> },
    #[error("the selected mask is empty")]
    EmptyMask,
    #[error("reconstruction cancelled")]
    Cancelled,
    #[error("{name} {reason}")]
    InvalidParameter {
        name: &'static str,
        reason: &'static str,
    },
    #[error("{normals} normals given for {points} points")]
    NormalCount { points: usize, normals: usize },
    #[error("normal {index} is zero or not finite")]
    BadNormal { index: usize },
    #[error("point cloud: {0}")]
    PointCloud(#[from] resecta_pointcloud::PointCloudError),
    #[error("Poisson reconstruction: {0}")]
    Poisson(#[from] resecta_poisson::PoissonError),
    #[error("mesh filter: {0}")]
    Filter(#[from] resecta_meshfilter::FilterError),
    #[error("isosurface: {0}")]
    Isosurface(#[from] resecta_isosurface::IsoError),
    #[error("metrics: {0}")]
    Metrics(#[from] resecta_meshmetrics::MetricsError),
    #[error(transparent)]
    Geometry(#[from] GeomError),
}
