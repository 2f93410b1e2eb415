//! Snapshot and delta encoders and decoders.

use serde::Serialize;

use crate::error::DeltaError;
use crate::format::{
    HEADER_BYTES, Header, Kind, Reader, VERSION, align4, attribute_bytes, flags, header_of,
};
use crate::frame::{DecodeLimits, EncodeOptions, SurfaceFrame, Topology};
use crate::quant::{QuantBox, oct_decode, oct_encode};

fn put_f32s(out: &mut Vec<u8>, v: &[f32]) {
    for x in v {
        out.extend_from_slice(&x.to_le_bytes());
    }
}

/// Writes the attribute sections of the vertices `rows` (in order) for the attributes in `f`.
fn write_attributes<I>(out: &mut Vec<u8>, frame: &SurfaceFrame, rows: I, f: u16)
where
    I: Iterator<Item = usize> + Clone,
{
    if f & flags::POSITIONS != 0 {
        if f & flags::POSITIONS_U16 != 0 {
            let qb = QuantBox::of(rows.clone().map(|i| &frame.positions[i]));
            put_f32s(out, &qb.min);
            put_f32s(out, &qb.step);
            for i in rows.clone() {
                for c in qb.encode(&frame.positions[i]) {
                    out.extend_from_slice(&c.to_le_bytes());
                }
            }
            align4(out);
        } else {
            for i in rows.clone() {
                put_f32s(out, &frame.positions[i]);
            }
        }
    }
    if f & flags::NORMALS != 0 {
        for i in rows.clone() {
            if f & flags::NORMALS_OCT16 != 0 {
                for c in oct_encode(&frame.normals[i]) {
                    out.extend_from_slice(&c.to_le_bytes());
                }
            } else {
                put_f32s(out, &frame.normals[i]);
            }
        }
    }
    if f & flags::MARGINS != 0 {
        for i in rows.clone() {
            out.extend_from_slice(&frame.margins[i].to_le_bytes());
        }
    }
    if f & flags::CLASSES != 0 {
        out.extend(rows.map(|i| frame.classes[i]));
        align4(out);
    }
}

/// Reads `rows` vertices of the attributes in `f`; absent attributes come back empty. The
/// caller has checked that the payload holds `attribute_bytes(f, rows)`.
fn read_attributes(r: &mut Reader, f: u16, rows: usize) -> Result<SurfaceFrame, DeltaError> {
    let mut out = SurfaceFrame::default();
    if f & flags::POSITIONS != 0 {
        out.positions.reserve_exact(rows);
        if f & flags::POSITIONS_U16 != 0 {
            let qb = QuantBox {
                min: [r.f32("box")?, r.f32("box")?, r.f32("box")?],
                step: [r.f32("box")?, r.f32("box")?, r.f32("box")?],
            };
            for c in r.take("positions", 6 * rows)?.chunks_exact(6) {
                let q = [0, 2, 4].map(|k| u16::from_le_bytes([c[k], c[k + 1]]));
                out.positions.push(qb.decode(q));
            }
            r.align4()?;
        } else {
            out.positions
                .extend(r.take("positions", 12 * rows)?.chunks_exact(12).map(vec3));
        }
    }
    if f & flags::NORMALS != 0 {
        out.normals.reserve_exact(rows);
        if f & flags::NORMALS_OCT16 != 0 {
            for c in r.take("normals", 4 * rows)?.chunks_exact(4) {
                out.normals.push(oct_decode([
                    i16::from_le_bytes([c[0], c[1]]),
                    i16::from_le_bytes([c[2], c[3]]),
                ]));
            }
        } else {
            out.normals
                .extend(r.take("normals", 12 * rows)?.chunks_exact(12).map(vec3));
        }
    }
    if f & flags::MARGINS != 0 {
        out.margins = r
            .take("margins", 4 * rows)?
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
    }
    if f & flags::CLASSES != 0 {
        out.classes = r.take("classes", rows)?.to_vec();
        r.align4()?;
    }
    Ok(out)
}

fn vec3(c: &[u8]) -> [f32; 3] {
    [0, 4, 8].map(|k| f32::from_le_bytes([c[k], c[k + 1], c[k + 2], c[k + 3]]))
}

/// Header + payload, the payload zstd-compressed when asked and smaller.
fn finish(
    mut header: Header,
    payload: Vec<u8>,
    opts: &EncodeOptions,
) -> Result<Vec<u8>, DeltaError> {
    header.payload_bytes = u32::try_from(payload.len()).map_err(|_| DeltaError::TooLarge {
        what: "payload byte",
        count: payload.len() as u64,
        limit: u64::from(u32::MAX),
    })?;
    let compressed = match opts.zstd_level {
        Some(level) => {
            Some(compress(&payload, level).map_err(|e| DeltaError::Zstd(e.to_string()))?)
        }
        None => None,
    };
    let body = match compressed {
        Some(c) if c.len() < payload.len() => {
            header.flags |= flags::ZSTD;
            c
        }
        _ => payload,
    };
    let mut out = Vec::with_capacity(HEADER_BYTES + body.len());
    header.write(&mut out);
    out.extend_from_slice(&body);
    Ok(out)
}

/// One zstd frame of `payload` with its content size and content checksum in the frame.
fn compress(payload: &[u8], level: i32) -> std::io::Result<Vec<u8>> {
    let mut c = zstd::bulk::Compressor::new(level)?;
    c.set_parameter(zstd::zstd_safe::CParameter::ChecksumFlag(true))?;
    c.set_parameter(zstd::zstd_safe::CParameter::ContentSizeFlag(true))?;
    c.compress(payload)
}

/// libzstd's name of the error of a frame whose content checksum does not match.
const ZSTD_CHECKSUM_WRONG: &str = "Restored data doesn't match checksum";
/// The zstd frame magic number, little-endian.
const ZSTD_MAGIC: [u8; 4] = [0x28, 0xB5, 0x2F, 0xFD];
/// `Content_Checksum_flag` of the frame header descriptor (the byte after the magic).
const ZSTD_CHECKSUM_FLAG: u8 = 0x04;

/// Decompresses `body`, which must be exactly one zstd frame with a content checksum, into at
/// most `capacity` bytes; libzstd verifies the checksum.
fn decompress(body: &[u8], capacity: usize) -> Result<Vec<u8>, DeltaError> {
    let frame = zstd::zstd_safe::find_frame_compressed_size(body)
        .map_err(|code| DeltaError::Zstd(zstd::zstd_safe::get_error_name(code).to_owned()))?;
    if frame < body.len() {
        return Err(DeltaError::TrailingBytes {
            count: (body.len() - frame) as u64,
        });
    }
    match body.get(..5) {
        Some([m0, m1, m2, m3, fhd]) if [*m0, *m1, *m2, *m3] == ZSTD_MAGIC => {
            if fhd & ZSTD_CHECKSUM_FLAG == 0 {
                return Err(DeltaError::ZstdNoChecksum);
            }
        }
        _ => return Err(DeltaError::Zstd("not a zstd data frame".to_owned())),
    }
    zstd::bulk::decompress(body, capacity).map_err(|e| {
        let msg = e.to_string();
        if msg == ZSTD_CHECKSUM_WRONG {
            DeltaError::ChecksumMismatch
        } else {
            DeltaError::Zstd(msg)
        }
    })
}

/// The payload of a checked header: the bytes after it, or their zstd decompression; its
/// length must be `expected`, the size the counts and flags give.
fn payload<'a>(
    bytes: &'a [u8],
    h: &Header,
    expected: u64,
) -> Result<std::borrow::Cow<'a, [u8]>, DeltaError> {
    if u64::from(h.payload_bytes) != expected {
        return Err(DeltaError::PayloadSize {
            declared: u64::from(h.payload_bytes),
            expected,
        });
    }
    let body = &bytes[HEADER_BYTES..];
    if h.has(flags::ZSTD) {
        let out = decompress(body, h.payload_bytes as usize)?;
        if out.len() as u64 != expected {
            return Err(DeltaError::PayloadSize {
                declared: out.len() as u64,
                expected,
            });
        }
        Ok(std::borrow::Cow::Owned(out))
    } else {
        let have = body.len() as u64;
        if have < expected {
            return Err(DeltaError::Truncated {
                what: "payload",
                needed: expected,
                available: have,
            });
        }
        if have > expected {
            return Err(DeltaError::TrailingBytes {
                count: have - expected,
            });
        }
        Ok(std::borrow::Cow::Borrowed(body))
    }
}

/// The section flags `f` with the encoding flags of the options for the sections present (an
/// absent section has no flag of its own encoding).
fn with_encodings(f: u16, opts: &EncodeOptions) -> u16 {
    let q = opts.quant_flags();
    let mut out = f;
    if f & flags::POSITIONS != 0 {
        out |= q & flags::POSITIONS_U16;
    }
    if f & flags::NORMALS != 0 {
        out |= q & flags::NORMALS_OCT16;
    }
    out
}

fn check_limit(what: &'static str, count: u32, limit: u32) -> Result<(), DeltaError> {
    if count > limit {
        return Err(DeltaError::TooLarge {
            what,
            count: u64::from(count),
            limit: u64::from(limit),
        });
    }
    Ok(())
}

/// Full snapshot of one surface: topology and every vertex attribute the frame carries.
pub fn encode_mesh(
    topology: &Topology,
    frame: &SurfaceFrame,
    opts: &EncodeOptions,
) -> Result<Vec<u8>, DeltaError> {
    frame.validate()?;
    let n = frame.positions.len();
    let t = u32::try_from(topology.triangles.len()).map_err(|_| DeltaError::TooLarge {
        what: "triangle",
        count: topology.triangles.len() as u64,
        limit: u64::from(u32::MAX),
    })?;
    for (ti, tri) in topology.triangles.iter().enumerate() {
        if let Some(&index) = tri.iter().find(|&&i| i as usize >= n) {
            return Err(DeltaError::TriangleIndex {
                triangle: ti as u64,
                index,
                vertices: n as u64,
            });
        }
    }
    let f = with_encodings(frame.attribute_flags(), opts);
    let size = 12 * u64::from(t) + attribute_bytes(f, n as u64);
    let mut payload = Vec::with_capacity(usize::try_from(size).unwrap_or(0));
    for tri in &topology.triangles {
        for i in tri {
            payload.extend_from_slice(&i.to_le_bytes());
        }
    }
    write_attributes(&mut payload, frame, 0..n, f);
    let header = Header {
        kind: Kind::Mesh,
        version: VERSION,
        flags: f,
        vertex_count: n as u32,
        count2: t,
        payload_bytes: 0,
    };
    finish(header, payload, opts)
}

/// Decodes a snapshot, checking counts against `limits` and the message length before any
/// allocation, and every triangle index against the vertex count.
pub fn decode_mesh(
    bytes: &[u8],
    limits: &DecodeLimits,
) -> Result<(Topology, SurfaceFrame), DeltaError> {
    let h = header_of(bytes, Kind::Mesh)?;
    if !h.has(flags::POSITIONS) || h.has(flags::INDEX_LIST) {
        return Err(DeltaError::BadFlags {
            flags: h.flags,
            reason: "a snapshot has positions and no changed-index list",
        });
    }
    check_limit("vertex", h.vertex_count, limits.max_vertices)?;
    check_limit("triangle", h.count2, limits.max_triangles)?;
    let n = h.vertex_count as usize;
    let t = h.count2 as usize;
    let expected = 12 * t as u64 + attribute_bytes(h.flags, n as u64);
    let payload = payload(bytes, &h, expected)?;
    let mut r = Reader::new(&payload);
    let mut triangles = Vec::with_capacity(t);
    for (ti, c) in r.take("triangles", 12 * t)?.chunks_exact(12).enumerate() {
        let tri = [0, 4, 8].map(|k| u32::from_le_bytes([c[k], c[k + 1], c[k + 2], c[k + 3]]));
        if let Some(&index) = tri.iter().find(|&&i| i as usize >= n) {
            return Err(DeltaError::TriangleIndex {
                triangle: ti as u64,
                index,
                vertices: n as u64,
            });
        }
        triangles.push(tri);
    }
    let frame = read_attributes(&mut r, h.flags, n)?;
    Ok((Topology { triangles }, frame))
}

/// Per-delta figures for metrics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct DeltaStats {
    pub vertices: u32,
    pub changed_vertices: u32,
    /// Size of the whole message.
    pub bytes: usize,
    /// Size of the uncompressed payload.
    pub payload_bytes: u32,
    pub compressed: bool,
    /// The changed set is an index list (else a bitmap).
    pub index_list: bool,
}

impl DeltaStats {
    /// Figures of an encoded delta, read from its header.
    pub fn of(delta: &[u8]) -> Result<Self, DeltaError> {
        let h = header_of(delta, Kind::Delta)?;
        Ok(Self {
            vertices: h.vertex_count,
            changed_vertices: h.count2,
            bytes: delta.len(),
            payload_bytes: h.payload_bytes,
            compressed: h.has(flags::ZSTD),
            index_list: h.has(flags::INDEX_LIST),
        })
    }
}

fn bitmap_words(n: u64) -> u64 {
    n.div_ceil(32)
}

fn check_same_shape(prev: &SurfaceFrame, next: &SurfaceFrame) -> Result<(), DeltaError> {
    prev.validate()?;
    next.validate()?;
    if prev.positions.len() != next.positions.len() {
        return Err(DeltaError::VertexCount {
            left: prev.positions.len() as u64,
            right: next.positions.len() as u64,
        });
    }
    for (what, a, b) in [
        ("normals", prev.normals.is_empty(), next.normals.is_empty()),
        ("margins", prev.margins.is_empty(), next.margins.is_empty()),
        ("classes", prev.classes.is_empty(), next.classes.is_empty()),
    ] {
        if a != b {
            let (present_in, absent_in) = if a {
                ("next", "prev")
            } else {
                ("prev", "next")
            };
            return Err(DeltaError::AttributeMismatch {
                what,
                present_in,
                absent_in,
            });
        }
    }
    Ok(())
}

fn bits3(v: &[f32; 3]) -> [u32; 3] {
    v.map(f32::to_bits)
}

/// The changes from `prev` to `next` (same vertex count and attributes): the vertices where
/// any attribute differs bitwise, and for them the attributes that differ anywhere.
pub fn encode_delta(
    prev: &SurfaceFrame,
    next: &SurfaceFrame,
    opts: &EncodeOptions,
) -> Result<Vec<u8>, DeltaError> {
    check_same_shape(prev, next)?;
    let n = next.positions.len();
    let mut changed: Vec<u32> = Vec::new();
    let mut f = 0u16;
    for i in 0..n {
        let mut d = 0u16;
        if bits3(&prev.positions[i]) != bits3(&next.positions[i]) {
            d |= flags::POSITIONS;
        }
        if !next.normals.is_empty() && bits3(&prev.normals[i]) != bits3(&next.normals[i]) {
            d |= flags::NORMALS;
        }
        if !next.margins.is_empty() && prev.margins[i].to_bits() != next.margins[i].to_bits() {
            d |= flags::MARGINS;
        }
        if !next.classes.is_empty() && prev.classes[i] != next.classes[i] {
            d |= flags::CLASSES;
        }
        if d != 0 {
            changed.push(i as u32);
            f |= d;
        }
    }
    let m = changed.len() as u64;
    f = with_encodings(f, opts);
    let use_list = m < bitmap_words(n as u64);
    if use_list {
        f |= flags::INDEX_LIST;
    }
    let set_bytes = 4 * if use_list { m } else { bitmap_words(n as u64) };
    let size = set_bytes + attribute_bytes(f, m);
    let mut payload = Vec::with_capacity(usize::try_from(size).unwrap_or(0));
    if use_list {
        for i in &changed {
            payload.extend_from_slice(&i.to_le_bytes());
        }
    } else {
        let mut words = vec![0u32; bitmap_words(n as u64) as usize];
        for &i in &changed {
            words[i as usize / 32] |= 1 << (i % 32);
        }
        for w in words {
            payload.extend_from_slice(&w.to_le_bytes());
        }
    }
    write_attributes(&mut payload, next, changed.iter().map(|&i| i as usize), f);
    let header = Header {
        kind: Kind::Delta,
        version: VERSION,
        flags: f,
        vertex_count: n as u32,
        count2: m as u32,
        payload_bytes: 0,
    };
    finish(header, payload, opts)
}

/// Applies a delta to the frame it was made from; on any error the frame is unchanged.
pub fn apply_delta(
    frame: &mut SurfaceFrame,
    bytes: &[u8],
    limits: &DecodeLimits,
) -> Result<(), DeltaError> {
    let h = header_of(bytes, Kind::Delta)?;
    check_limit("vertex", h.vertex_count, limits.max_vertices)?;
    frame.validate()?;
    let n = frame.positions.len();
    if h.vertex_count as usize != n {
        return Err(DeltaError::VertexCount {
            left: u64::from(h.vertex_count),
            right: n as u64,
        });
    }
    let m = h.count2 as usize;
    if m > n {
        return Err(DeltaError::ChangedSet(format!(
            "{m} changed vertices of {n}"
        )));
    }
    for (what, flag, empty) in [
        ("normals", flags::NORMALS, frame.normals.is_empty()),
        ("margins", flags::MARGINS, frame.margins.is_empty()),
        ("classes", flags::CLASSES, frame.classes.is_empty()),
    ] {
        if h.has(flag) && empty {
            return Err(DeltaError::AttributeMismatch {
                what,
                present_in: "the delta",
                absent_in: "the frame",
            });
        }
    }
    let list = h.has(flags::INDEX_LIST);
    let set_bytes = 4 * if list {
        m as u64
    } else {
        bitmap_words(n as u64)
    };
    let payload = payload(bytes, &h, set_bytes + attribute_bytes(h.flags, m as u64))?;
    let mut r = Reader::new(&payload);
    let set = r.take("changed set", set_bytes as usize)?;
    let mut changed = Vec::with_capacity(m);
    let words = set
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]));
    if list {
        for i in words {
            if i as usize >= n || changed.last().is_some_and(|&p| i <= p) {
                return Err(DeltaError::ChangedSet(format!(
                    "index {i} not ascending or not below the vertex count {n}"
                )));
            }
            changed.push(i);
        }
    } else {
        for (w, word) in words.enumerate() {
            let mut bits = word;
            while bits != 0 {
                let i = w as u64 * 32 + u64::from(bits.trailing_zeros());
                if i >= n as u64 {
                    return Err(DeltaError::ChangedSet(format!(
                        "bit {i} set beyond the vertex count {n}"
                    )));
                }
                if changed.len() == m {
                    return Err(DeltaError::ChangedSet(format!(
                        "more bits set than the {m} changed vertices in the header"
                    )));
                }
                changed.push(i as u32);
                bits &= bits - 1;
            }
        }
        if changed.len() != m {
            return Err(DeltaError::ChangedSet(format!(
                "{} bits set, {m} changed vertices in the header",
                changed.len()
            )));
        }
    }
    let rows = read_attributes(&mut r, h.flags, m)?;
    for (k, &i) in changed.iter().enumerate() {
        let i = i as usize;
        if let Some(p) = rows.positions.get(k) {
            frame.positions[i] = *p;
        }
        if let Some(v) = rows.normals.get(k) {
            frame.normals[i] = *v;
        }
        if let Some(v) = rows.margins.get(k) {
            frame.margins[i] = *v;
        }
        if let Some(v) = rows.classes.get(k) {
            frame.classes[i] = *v;
        }
    }
    Ok(())
}
