//! Medical image and mesh files, converted to RAS millimetres on read and back on write.

pub mod error;

pub use error::{ErrorKind, IoError};
