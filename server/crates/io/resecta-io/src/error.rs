//! Errors of the file layer: every one names the file and what is wrong with it.

use std::fmt;
use std::path::{Path, PathBuf};

use resecta_geom::GeomError;

/// A failure to read or write one file.
#[derive(Debug, thiserror::Error)]
pub struct IoError {
    /// The file as the caller named it (or `<bytes>` for in-memory input).
    pub path: PathBuf,
    pub kind: ErrorKind,
}

impl fmt::Display for IoError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.kind)
    }
}

impl IoError {
    pub fn new(path: impl AsRef<Path>, kind: impl Into<ErrorKind>) -> Self {
        Self {
            path: path.as_ref().to_path_buf(),
            kind: kind.into(),
        }
    }

    /// Whether the input (not the system) is at fault: the CLI exits with 2 for these.
    pub fn is_bad_input(&self) -> bool {
        !matches!(&self.kind, ErrorKind::Io(e) if e.kind() != std::io::ErrorKind::NotFound
            && e.kind() != std::io::ErrorKind::UnexpectedEof
            && e.kind() != std::io::ErrorKind::InvalidData)
    }
}

/// What is wrong with a file.
#[derive(Debug, thiserror::Error)]
pub enum ErrorKind {
    #[error("{0}")]
    Io(#[from] std::io::Error),
    #[error("unknown file type {0:?} (expected one of {1})")]
    UnknownFormat(String, &'static str),
    #[error("not a {0} file (bad magic)")]
    BadMagic(&'static str),
    #[error("corrupt or truncated compressed data: {0}")]
    Decompress(String),
    #[error("bad header: {0}")]
    Header(String),
    #[error("data has {got} bytes but the header needs {expected}")]
    DataSize { expected: u64, got: u64 },
    #[error("unsupported {what}: {value}")]
    Unsupported { what: &'static str, value: String },
    #[error("missing required field {0}")]
    MissingField(String),
    #[error("refused data file path {0:?} (must stay inside the header's folder)")]
    UnsafePath(String),
    #[error("not a label map: {0}")]
    NotLabels(String),
    #[error("bad segmentation: {0}")]
    Segmentation(String),
    #[error("bad mesh: {0}")]
    Mesh(String),
    #[error(transparent)]
    Geometry(#[from] GeomError),
}
