//! Medical image and mesh files, converted to RAS millimetres on read and back on write.

pub mod error;
pub mod mesh;

pub use error::{ErrorKind, IoError};
pub use mesh::{
    Encoding, MeshFormat, VtpLayout, WriteOptions, mesh_to_bytes, read_mesh, read_mesh_bytes,
    write_mesh, write_mesh_with,
};
