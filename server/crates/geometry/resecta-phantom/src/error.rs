//! Why a phantom spec is refused.

use resecta_geom::{GeomError, Real, Role};

/// A typed reason a [`crate::PhantomSpec`] cannot be generated. Messages name the shape.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PhantomError {
    #[error("{what} must be finite")]
    NonFinite { what: String },
    #[error("{what} must be positive, got {value}")]
    NonPositive { what: String, value: Real },
    #[error("{what} is not an orthonormal matrix")]
    NotOrthonormal { what: String },
    #[error("the liver needs at least one ellipsoid")]
    NoLiver,
    #[error("tumor[{index}] does not lie inside a single liver ellipsoid")]
    TumorOutsideLiver { index: usize },
    #[error("vessel[{index}] has role {role}, which is not a vessel role")]
    NotAVesselRole { index: usize, role: Role },
    #[error("vessel[{index}] needs at least 2 points, got {got}")]
    TooFewPoints { index: usize, got: usize },
    #[error("{what} reaches outside the grid")]
    OutsideGrid { what: String },
    #[error("role {0} has no label in the role map")]
    MissingRole(Role),
    #[error("grid {dims:?} holds more than {limit} voxels")]
    VoxelLimit { dims: [usize; 3], limit: u64 },
    #[error("an atrium needs 1 to 4 veins, got {got}")]
    VeinCount { got: usize },
    #[error(
        "vein[{index}] must start inside the body and end outside it, each by more than its radius"
    )]
    VeinPlacement { index: usize },
    #[error("grid: {0}")]
    Geom(GeomError),
}
