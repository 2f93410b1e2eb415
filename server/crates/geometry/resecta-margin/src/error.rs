//! Errors of margin computation.

use resecta_geom::GeomError;
use thiserror::Error;

#[derive(Debug, Error)]
#[non_exhaustive]
pub enum MarginError {
    #[error("the tumour mesh has no triangles")]
    EmptyMesh,
    #[error("{what} has {got} values, expected {expected}")]
    Length {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("surface grid {ru}×{rv}: each side must be at least 2")]
    Grid { ru: usize, rv: usize },
    #[error("{what} must be finite and {bound}, got {value}")]
    Setting {
        what: &'static str,
        bound: &'static str,
        value: f64,
    },
    #[error("tumour mesh: {0}")]
    Geometry(#[from] GeomError),
}
