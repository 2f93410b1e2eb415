//! Medical image and mesh files, converted to RAS millimetres on read and back on write.
//!
//! Images: NIfTI-1 ([`nifti`]), NRRD and Slicer `.seg.nrrd` ([`nrrd`]), MetaImage
//! ([`metaimage`]); [`read_image`]/[`write_image`] pick the format from the file name. Every
//! reader takes a [`VoxelLimit`](resecta_geom::VoxelLimit), checks sizes before allocating and
//! has a from-bytes variant.
//!
//! Meshes: VTK legacy, VTP, STL, PLY, OBJ ([`mesh`]); [`read_mesh`]/[`write_mesh`] pick the
//! format from the extension.
//!
//! Point clouds (positions with optional normals): CSV/text, PLY and VTP read and written, the
//! vertices of VTK, STL and OBJ meshes read ([`points`]); [`read_points`]/[`write_points`] pick
//! the format from the extension.

pub mod error;
pub mod image;
pub mod mesh;
pub mod metaimage;
pub mod nifti;
pub mod nrrd;
pub mod points;
pub mod volume_io;

pub use error::{ErrorKind, IoError};
pub use image::{Image, ScalarType, VoxelData};
pub use mesh::vtp::PolylineSet;
pub use mesh::{
    Encoding, MeshFormat, VtpLayout, WriteOptions, mesh_to_bytes, read_mesh, read_mesh_bytes,
    write_mesh, write_mesh_with, write_polylines,
};
pub use nrrd::{Segment, Segmentation};
pub use points::{
    MAX_POINTS, PointCloud, PointFormat, points_to_bytes, read_points, read_points_bytes,
    write_points,
};
pub use volume_io::{ImageFormat, read_image, read_label_map, write_image, write_label_map};
