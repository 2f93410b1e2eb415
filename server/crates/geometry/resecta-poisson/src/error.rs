//! Errors of point extraction and the solver.

use resecta_geom::Real;

/// Why oriented points or a Poisson field could not be produced.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PoissonError {
    #[error("empty mask: no object voxel")]
    EmptyMask,
    #[error("too few oriented points: {found} found, at least {needed} needed")]
    TooFewPoints { found: usize, needed: usize },
    #[error("depth {depth} out of range 1..=10")]
    DepthOutOfRange { depth: u32 },
    #[error("memory budget exceeded at depth {depth}: {needed} bytes needed, limit {limit} bytes")]
    MemoryBudget { depth: u32, needed: u64, limit: u64 },
    #[error(
        "point arrays differ in length: {positions} positions, {normals} normals, {areas} areas"
    )]
    LengthMismatch {
        positions: usize,
        normals: usize,
        areas: usize,
    },
    #[error("sample {index}: position, normal or area is not finite (or area not positive)")]
    BadSample { index: usize },
    #[error("degenerate point set: largest bounding-box side is {extent_mm} mm")]
    DegenerateBounds { extent_mm: Real },
    #[error("parameter {name} = {value} is invalid: expected {expected}")]
    BadParameter {
        name: &'static str,
        value: Real,
        expected: &'static str,
    },
    #[error("the mask's grid has a singular index-to-world matrix")]
    SingularGrid,
    /// The solver's device failed (e.g. a lost GPU); the CPU solver never returns it.
    #[error("the {backend} multigrid solver failed: {reason}")]
    Backend {
        backend: &'static str,
        reason: String,
    },
}
