//! Scalar and vector aliases: precision changes in one place.

/// The scalar of all engine geometry.
pub type Real = f64;
/// A point or direction in RAS millimetres.
pub type Vec3 = nalgebra::Vector3<Real>;
/// A 3×3 matrix (directions, covariances).
pub type Mat3 = nalgebra::Matrix3<Real>;
/// A homogeneous 4×4 transform.
pub type Mat4 = nalgebra::Matrix4<Real>;
