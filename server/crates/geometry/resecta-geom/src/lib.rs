//! Geometry kernel of resecta: pure, synchronous, no I/O.
//!
//! Every coordinate is in millimetres in the patient frame RAS. Voxel grids carry their full
//! index→RAS affine ([`Grid`]); meshes ([`TriMesh`]) are validated at construction.

pub mod bvh;
pub mod crop;
pub mod edt;
pub mod error;
pub mod grid;
pub mod math;
pub mod mesh;
pub mod pca;
pub mod primitives;
pub mod roles;
pub mod slice;
pub mod surface;

pub use bvh::{Aabb, ClosestPoint, Feature, MeshBvh, MeshSdf, Ray, RayHit, SignedDistance};
pub use edt::{
    NO_FEATURE, NearestFeature, distance_transform, distance_transform_where,
    distance_transform_with_nearest, signed_distance_transform, signed_distance_transform_where,
};
pub use error::GeomError;
pub use grid::{Grid, LabelMap, Volume, VoxelLimit};
pub use math::{Mat3, Mat4, Real, Vec3};
pub use mesh::{MeshReport, TriMesh};
pub use pca::Pca;
pub use roles::{Role, RoleMap};
pub use slice::{Plane, Polyline, slice};
pub use surface::{CutSurface, SurfacePoint, grid_param};
