//! Errors of the margin crate.

use resecta_geom::{GeomError, Real};

/// What can be wrong with margin input. Messages name the offending quantity.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MarginError {
    #[error("tumour mesh has no triangles")]
    EmptyMesh,
    #[error("tumour mesh has {got} triangles, more than the {limit} supported")]
    TooManyTriangles { got: usize, limit: usize },
    #[error("region corner {name} {value:?} must be finite")]
    NonFiniteRegion {
        name: &'static str,
        value: [Real; 3],
    },
    #[error("region max {max:?} must not be below region min {min:?} on any axis")]
    InvertedRegion { min: [Real; 3], max: [Real; 3] },
    #[error("hint spacing {0} mm must be finite and positive")]
    BadSpacing(Real),
    #[error(
        "hint grid {dims:?} has more than {limit} nodes; use a coarser spacing or a smaller region"
    )]
    TooManyNodes { dims: [u64; 3], limit: u64 },
    #[error("{what} has {got} entries but {expected} are needed")]
    LengthMismatch {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("surface grid {ru}×{rv} must have at least 2 samples along u and v")]
    GridTooSmall { ru: usize, rv: usize },
    #[error("margin {0} mm must be finite and positive")]
    BadMargin(Real),
    #[error("warning band {0} mm must be finite and non-negative")]
    BadBand(Real),
    #[error(transparent)]
    Geom(#[from] GeomError),
}
