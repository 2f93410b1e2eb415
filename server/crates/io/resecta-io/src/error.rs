//! Errors of the file layer: every one names the file and what is wrong with it.
//!
//! **No error carries text read from a file.** Headers hold free text that is often patient
//! data (a `.nhdr`'s data file is commonly named after the patient, a segment after the
//! patient's tumour, a NIfTI `descrip` or a mesh comment may hold anything), and these errors
//! reach the server's clients and logs. A message therefore names the *key* (from this crate's
//! own vocabulary, never a key as spelt in the file), the line or element by number, sizes and
//! numeric bounds, and what is wrong, but never a value, a name or a line of the file. Numbers
//! read from a file (sizes, indices, counts) may be shown. The one text that is not the file's
//! is [`IoError::path`], the name the *caller* gave (servers pass a fixed name for uploads).

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

/// What is wrong with a file. The `String`s hold this crate's own words and numbers only, never
/// text of the file (see the module documentation).
#[derive(Debug, thiserror::Error)]
pub enum ErrorKind {
    /// A failure of the system (the OS error names no file content).
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// The caller's file name (not the file's content) and the extensions known.
    #[error("unknown file type {0:?} (expected one of {1})")]
    UnknownFormat(String, &'static str),
    #[error("not a {0} file (bad magic)")]
    BadMagic(&'static str),
    /// The decompressor's own message or sizes.
    #[error("corrupt or truncated compressed data: {0}")]
    Decompress(String),
    /// The field or line at fault (by key or number) and what is wrong with it.
    #[error("bad header: {0}")]
    Header(String),
    #[error("data has {got} bytes but the header needs {expected}")]
    DataSize { expected: u64, got: u64 },
    /// A feature this reader does not support; `value` says which in this crate's words or
    /// numbers.
    #[error("unsupported {what}: {value}")]
    Unsupported { what: &'static str, value: String },
    /// A field whose value is none of those this reader knows (the value is not repeated).
    #[error("unsupported value of {key} (known: {known})")]
    UnknownValue {
        key: &'static str,
        known: &'static str,
    },
    #[error("missing required field {0}")]
    MissingField(&'static str),
    /// A detached data file path that leaves the header's folder (the path is not repeated).
    #[error(
        "refused data file path in `{0}` (it must be a relative path inside the header's folder)"
    )]
    UnsafePath(&'static str),
    #[error("not a label map: {0}")]
    NotLabels(String),
    /// A segment (by number) or layer at fault.
    #[error("bad segmentation: {0}")]
    Segmentation(String),
    /// The element at fault (by number or keyword) and what is wrong with it.
    #[error("bad mesh: {0}")]
    Mesh(String),
    #[error(transparent)]
    Geometry(#[from] GeomError),
}
