//! Errors of encoding and decoding surface messages and of the replay ring.

/// What went wrong, naming the offending quantity.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DeltaError {
    #[error("message truncated: {what} needs {needed} bytes, {available} available")]
    Truncated {
        what: &'static str,
        needed: u64,
        available: u64,
    },
    #[error("bad magic {found:?}: expected b\"RSMS\" (snapshot) or b\"RSDL\" (delta)")]
    BadMagic { found: [u8; 4] },
    #[error("a {found:?} message where a {expected:?} was expected")]
    WrongKind {
        found: crate::format::Kind,
        expected: crate::format::Kind,
    },
    #[error("unsupported format version {found} (this build reads version {supported})")]
    UnsupportedVersion { found: u16, supported: u16 },
    #[error("bad flags {flags:#06x}: {reason}")]
    BadFlags { flags: u16, reason: &'static str },
    #[error("{what} count {count} exceeds the limit {limit}")]
    TooLarge {
        what: &'static str,
        count: u64,
        limit: u64,
    },
    #[error(
        "payload size {declared} bytes in the header, but the counts and flags give {expected}"
    )]
    PayloadSize { declared: u64, expected: u64 },
    #[error("{count} trailing bytes after the payload")]
    TrailingBytes { count: u64 },
    #[error("zstd: {0}")]
    Zstd(String),
    #[error("the zstd frame has no content checksum (the format requires one)")]
    ZstdNoChecksum,
    #[error(
        "the zstd frame's content checksum does not match the decompressed payload: the message is corrupt"
    )]
    ChecksumMismatch,
    #[error("triangle {triangle} refers to vertex {index}, but there are {vertices} vertices")]
    TriangleIndex {
        triangle: u64,
        index: u32,
        vertices: u64,
    },
    #[error("changed-vertex set: {0}")]
    ChangedSet(String),
    #[error("{what} has {len} entries, expected {expected} (one per vertex, or none)")]
    AttributeLength {
        what: &'static str,
        len: u64,
        expected: u64,
    },
    #[error("{what} present in {present_in} but not in {absent_in}")]
    AttributeMismatch {
        what: &'static str,
        present_in: &'static str,
        absent_in: &'static str,
    },
    #[error("vertex count differs: {left} vs {right}")]
    VertexCount { left: u64, right: u64 },
    #[error("replay ring: sequence {seq} is not after the last sequence {last}")]
    SeqOrder { seq: u64, last: u64 },
}
