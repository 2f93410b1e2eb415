//! Quality metrics of surface models, as in Paper I (thesis Sec. 6.3): pure, synchronous, no I/O.
//!
//! - [`point_to_surface`]: exact point-to-surface distances from a reference cloud to a model
//!   (Eq. 6.9), with their mean, 95th percentile and maximum;
//! - [`mean_gaussian_curvature`]: the discrete Gaussian curvature of Eq. 6.13 averaged over the
//!   vertices within a percentile band (5–95 in the thesis);
//! - [`analyse`]: normalised accuracy and complexity (Eq. 6.10), objective score σ (Eq. 6.11),
//!   Pareto front, ∂P_best, ∂C_best, ∂M_best (Eq. 6.12) and ∂C_sim (Eq. 6.14) over a set of
//!   [`ModelRecord`]s, rendered as the thesis' Tables 6.2–6.4 by [`Study::markdown`].

mod curvature;
mod distance;
mod error;
mod report;
mod stats;
mod study;

pub use curvature::{mean_gaussian_curvature, vertex_gaussian_curvature};
pub use distance::{DistanceStats, point_to_surface};
pub use error::MetricsError;
pub use resecta_geom::{Real, TriMesh, Vec3};
pub use stats::percentile;
pub use study::{ModelMethod, ModelRecord, ModelScore, Study, analyse, pareto_front};
