//! Synthetic liver phantoms with analytic truth: the backbone of exact tests.
//!
//! A [`PhantomSpec`] (serde) places a liver (union of ellipsoids), spherical tumours inside it
//! and tube vessels (polylines of capsules) on an arbitrary oblique, anisotropic grid.
//! [`generate`] labels every voxel by the shape containing its centre and returns the [`Truth`]:
//! exact shape volumes, region volumes (closed form or with a rigorous numeric bound, see
//! [`volume`]) and voxel counts. [`implicit`] holds the inside tests and signed distances.
//! [`atrium`] is the left-atrium phantom of the mapping study (body ellipsoid, vein tubes).

pub mod atrium;
pub mod error;
pub mod generate;
pub mod implicit;
pub mod spec;
pub mod volume;

pub use atrium::{
    Atrium, AtriumSpec, BODY_LABEL, SurfaceSamples, VEIN_LABELS, VeinSpec, fibonacci_sphere,
};
pub use error::PhantomError;
pub use generate::{LabelTruth, Phantom, ShapeTruth, Truth, generate};
pub use implicit::Solid;
pub use spec::{EllipsoidSpec, GridSpec, Orientation, PhantomSpec, SphereSpec, VesselSpec};
pub use volume::{Measure, Method};
