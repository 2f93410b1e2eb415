//! Errors of the geometry layer.

/// What can be wrong with geometric input. Messages name the offending quantity.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeomError {
    #[error("dimensions {0:?} must all be at least 1")]
    EmptyDims([usize; 3]),
    #[error("dimensions {dims:?} hold more than {limit} voxels")]
    TooManyVoxels { dims: [usize; 3], limit: u64 },
    #[error("spacing {0:?} must be finite and positive")]
    BadSpacing([Real; 3]),
    #[error("origin {0:?} must be finite")]
    BadOrigin([Real; 3]),
    #[error("direction matrix is singular or not finite")]
    SingularDirection,
    #[error("voxel data has {got} values but the grid needs {expected}")]
    DataLength { expected: usize, got: usize },
    #[error(
        "triangle {triangle} refers to vertex {index} but the mesh has {vertex_count} vertices"
    )]
    VertexIndexOutOfRange {
        triangle: usize,
        index: u32,
        vertex_count: usize,
    },
    #[error("mesh has more than u32::MAX vertices")]
    TooManyVertices,
    #[error("vertex {0} is not finite")]
    NonFiniteVertex(usize),
    #[error("{attribute} has {got} values but the mesh has {expected} vertices")]
    AttributeLength {
        attribute: String,
        expected: usize,
        got: usize,
    },
    #[error("role map: label {label} is given to both {first} and {second}")]
    LabelInTwoRoles {
        label: u16,
        first: String,
        second: String,
    },
    #[error("role map: label 0 is background and cannot have a role")]
    BackgroundLabel,
    #[error("role map: role {0} has no labels")]
    EmptyRole(String),
    #[error("grid axes are not orthogonal (sheared); distances in mm would be wrong")]
    NonOrthogonalGrid,
    #[error("need at least {needed} points, got {got}")]
    TooFewPoints { needed: usize, got: usize },
    #[error("{name} {reason}")]
    InvalidParameter {
        name: &'static str,
        reason: &'static str,
    },
    #[error("mesh has more than {limit} triangles")]
    TooManyTriangles { limit: usize },
    #[error(
        "mesh is not closed: {boundary_edges} boundary, {non_manifold_edges} non-manifold and \
         {inconsistent_edges} inconsistently oriented edges"
    )]
    NotClosed {
        boundary_edges: usize,
        non_manifold_edges: usize,
        inconsistent_edges: usize,
    },
    #[error("mesh has no triangles")]
    EmptyMesh,
}

use crate::math::Real;
