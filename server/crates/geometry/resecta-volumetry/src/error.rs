//! Errors of volumetry.

use resecta_geom::GeomError;
use thiserror::Error;

#[derive(Debug, Error)]
#[non_exhaustive]
pub enum VolumetryError {
    #[error("the liver mask is empty")]
    EmptyLiver,
    #[error("the liver spans {0} voxels; at most {max} are supported", max = u32::MAX - 1)]
    TooManyVoxels(usize),
    #[error("a cut needs at least one tumour point")]
    NoTumourPoints,
    #[error("tumour point {0} is not finite")]
    NonFinitePoint(usize),
    #[error("{what} must be {bound}, got {value}")]
    Parameter {
        what: &'static str,
        bound: &'static str,
        value: usize,
    },
    #[error("Bézier surface: {0}")]
    Bezier(#[from] resecta_bezier::BezierError),
    #[error("geometry: {0}")]
    Geometry(#[from] GeomError),
}
