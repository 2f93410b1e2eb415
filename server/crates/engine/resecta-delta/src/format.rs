//! The fixed header shared by snapshots and deltas, flags, section sizes, and little-endian
//! reading/writing helpers. The layout is specified in `docs/wire/mesh-delta.md`.

use serde::Serialize;

use crate::error::DeltaError;

/// Snapshot magic.
pub const MESH_MAGIC: [u8; 4] = *b"RSMS";
/// Delta magic.
pub const DELTA_MAGIC: [u8; 4] = *b"RSDL";
/// The format version this build writes and reads. Version 2 (over 1): a zstd payload carries
/// the frame's content checksum, and the encoding flags are set only with their section.
pub const VERSION: u16 = 2;
/// Bytes of the fixed header before the payload.
pub const HEADER_BYTES: usize = 20;

/// Flag bits of the header.
pub mod flags {
    /// Positions section present (always in a snapshot).
    pub const POSITIONS: u16 = 1 << 0;
    /// Normals section present.
    pub const NORMALS: u16 = 1 << 1;
    /// Margins section present.
    pub const MARGINS: u16 = 1 << 2;
    /// Classes section present.
    pub const CLASSES: u16 = 1 << 3;
    /// Positions as u16 over a box (else f32); only together with `POSITIONS`.
    pub const POSITIONS_U16: u16 = 1 << 4;
    /// Normals octahedral 2×i16 (else 3×f32); only together with `NORMALS`.
    pub const NORMALS_OCT16: u16 = 1 << 5;
    /// The payload is one zstd frame with a content checksum.
    pub const ZSTD: u16 = 1 << 6;
    /// Delta only: the changed set is an index list (else a bitmap).
    pub const INDEX_LIST: u16 = 1 << 7;
    /// Every defined bit.
    pub const ALL: u16 = (1 << 8) - 1;
}

/// Largest u16 code of a quantised coordinate; `NAN_U16` marks a non-finite one.
pub const MAX_U16_CODE: u16 = 65534;
pub const NAN_U16: u16 = u16::MAX;
/// Octahedral pair that marks a zero-length or non-finite normal (decoded as [0, 0, 0]).
pub const ZERO_OCT: i16 = i16::MIN;
/// Bytes of the quantisation box (min xyz, step xyz as f32) before u16 positions.
pub const QUANT_BOX_BYTES: u64 = 24;

/// Which message a header belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Kind {
    Mesh,
    Delta,
}

/// The decoded fixed header.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Header {
    pub kind: Kind,
    pub version: u16,
    pub flags: u16,
    pub vertex_count: u32,
    /// Triangles (snapshot) or changed vertices (delta).
    pub count2: u32,
    /// Length of the uncompressed payload.
    pub payload_bytes: u32,
}

impl Header {
    pub fn has(&self, flag: u16) -> bool {
        self.flags & flag != 0
    }

    pub(crate) fn write(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(match self.kind {
            Kind::Mesh => &MESH_MAGIC,
            Kind::Delta => &DELTA_MAGIC,
        });
        out.extend_from_slice(&self.version.to_le_bytes());
        out.extend_from_slice(&self.flags.to_le_bytes());
        out.extend_from_slice(&self.vertex_count.to_le_bytes());
        out.extend_from_slice(&self.count2.to_le_bytes());
        out.extend_from_slice(&self.payload_bytes.to_le_bytes());
    }
}

/// Reads and checks the fixed header of either message (magic, version, reserved flag bits, no
/// encoding flag without its section); counts are checked by the decoders against their limits.
pub fn inspect(bytes: &[u8]) -> Result<Header, DeltaError> {
    let head = bytes.get(..HEADER_BYTES).ok_or(DeltaError::Truncated {
        what: "header",
        needed: HEADER_BYTES as u64,
        available: bytes.len() as u64,
    })?;
    let mut r = Reader::new(head);
    let magic = r.array::<4>("magic")?;
    let kind = match magic {
        MESH_MAGIC => Kind::Mesh,
        DELTA_MAGIC => Kind::Delta,
        found => return Err(DeltaError::BadMagic { found }),
    };
    let version = u16::from_le_bytes(r.array::<2>("version")?);
    if version != VERSION {
        return Err(DeltaError::UnsupportedVersion {
            found: version,
            supported: VERSION,
        });
    }
    let flags = u16::from_le_bytes(r.array::<2>("flags")?);
    if flags & !flags::ALL != 0 {
        return Err(DeltaError::BadFlags {
            flags,
            reason: "reserved bits set",
        });
    }
    for (encoding, section, reason) in [
        (
            flags::POSITIONS_U16,
            flags::POSITIONS,
            "POSITIONS_U16 without a positions section",
        ),
        (
            flags::NORMALS_OCT16,
            flags::NORMALS,
            "NORMALS_OCT16 without a normals section",
        ),
    ] {
        if flags & encoding != 0 && flags & section == 0 {
            return Err(DeltaError::BadFlags { flags, reason });
        }
    }
    Ok(Header {
        kind,
        version,
        flags,
        vertex_count: r.u32("vertex count")?,
        count2: r.u32("second count")?,
        payload_bytes: r.u32("payload size")?,
    })
}

/// `n` rounded up to a multiple of 4.
pub fn pad4(n: u64) -> u64 {
    n.div_ceil(4) * 4
}

/// Bytes of the per-vertex sections for `rows` vertices with the given flags.
pub fn attribute_bytes(flags: u16, rows: u64) -> u64 {
    let mut total = 0;
    if flags & flags::POSITIONS != 0 {
        total += if flags & flags::POSITIONS_U16 != 0 {
            QUANT_BOX_BYTES + pad4(6 * rows)
        } else {
            12 * rows
        };
    }
    if flags & flags::NORMALS != 0 {
        total += if flags & flags::NORMALS_OCT16 != 0 {
            4 * rows
        } else {
            12 * rows
        };
    }
    if flags & flags::MARGINS != 0 {
        total += 4 * rows;
    }
    if flags & flags::CLASSES != 0 {
        total += pad4(rows);
    }
    total
}

/// Reads the header and requires the given kind.
pub(crate) fn header_of(bytes: &[u8], kind: Kind) -> Result<Header, DeltaError> {
    let h = inspect(bytes)?;
    if h.kind != kind {
        return Err(DeltaError::WrongKind {
            found: h.kind,
            expected: kind,
        });
    }
    Ok(h)
}

/// Pads `out` with zero bytes to a multiple of 4.
pub(crate) fn align4(out: &mut Vec<u8>) {
    while !out.len().is_multiple_of(4) {
        out.push(0);
    }
}

/// Sequential little-endian reader that never reads past its slice.
pub(crate) struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub fn new(bytes: &'a [u8]) -> Self {
        Self { bytes, pos: 0 }
    }

    pub fn take(&mut self, what: &'static str, n: usize) -> Result<&'a [u8], DeltaError> {
        let rest = &self.bytes[self.pos.min(self.bytes.len())..];
        let out = rest.get(..n).ok_or(DeltaError::Truncated {
            what,
            needed: n as u64,
            available: rest.len() as u64,
        })?;
        self.pos += n;
        Ok(out)
    }

    pub fn array<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], DeltaError> {
        let s = self.take(what, N)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    pub fn u32(&mut self, what: &'static str) -> Result<u32, DeltaError> {
        Ok(u32::from_le_bytes(self.array::<4>(what)?))
    }

    pub fn f32(&mut self, what: &'static str) -> Result<f32, DeltaError> {
        Ok(f32::from_le_bytes(self.array::<4>(what)?))
    }

    /// Skips padding up to the next multiple of 4.
    pub fn align4(&mut self) -> Result<(), DeltaError> {
        let pad = self.pos.next_multiple_of(4) - self.pos;
        self.take("padding", pad).map(|_| ())
    }
}
