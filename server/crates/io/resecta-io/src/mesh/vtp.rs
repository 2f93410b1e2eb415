//! VTK XML PolyData (`.vtp`).
//!
//! Reads one `Piece` with `Points`, `Polys` and `Strips` (`Verts` and `Lines` are counted), the
//! `PointData` normals (the array named by the `Normals` attribute, else a 3-component array called
//! `Normals`) and every one-component numeric point array as a scalar, and the `SPACE` field
//! array Slicer writes. Arrays may be `ascii`, inline `binary` (base64) or `appended` (raw or
//! base64), little- or big-endian, with `UInt32` or `UInt64` headers, uncompressed or compressed
//! with `vtkZLibDataCompressor`. Base64 is decoded segment by segment, so both VTK's separate
//! header/data encodings and a single joint encoding work.

use std::fmt::Write as _;
use std::io::{Read, Write as _};

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD as B64;
use flate2::Compression;
use flate2::read::ZlibDecoder;
use flate2::write::ZlibEncoder;
use quick_xml::events::{BytesStart, Event};
use resecta_geom::{TriMesh, Vec3};

use super::{Cursor, Num, RawMesh, VtpLayout, WriteOptions, fmt_f64, mul};
use crate::error::ErrorKind;

/// Deflate cannot expand data by more than about 1032:1; a header claiming more is corrupt.
const MAX_INFLATE_RATIO: u64 = 1100;
const BLOCK: usize = 1 << 15;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Section {
    None,
    PointData,
    Points,
    Polys,
    Strips,
    FieldData,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Ascii,
    Binary,
    Appended,
}

#[derive(Debug)]
struct Array {
    /// Its place among the file's `DataArray` elements (from 0): errors name an array by this
    /// and its section, never by its `Name` (the file's text).
    index: usize,
    section: Section,
    name: String,
    /// `None` for `String` arrays.
    ty: Option<Num>,
    ncomp: usize,
    format: Format,
    offset: usize,
    text: String,
}

#[derive(Debug)]
enum Appended<'a> {
    None,
    Raw(&'a [u8]),
    Base64(&'a [u8]),
}

#[derive(Debug)]
struct Doc<'a> {
    big: bool,
    header_u64: bool,
    zlib: bool,
    appended: Appended<'a>,
    /// Sorted start offsets of the appended arrays (to bound each base64 run).
    offsets: Vec<usize>,
}

impl Array {
    /// How errors name the array.
    fn label(&self) -> String {
        format!("DataArray {} ({:?})", self.index, self.section)
    }
}

/// The value of attribute `key` (this reader's word). Errors name the key, never the file's
/// text (quick-xml's own messages may quote it).
fn attr(e: &BytesStart<'_>, key: &str) -> Result<Option<String>, ErrorKind> {
    for a in e.attributes() {
        let a = a.map_err(|_| ErrorKind::Header("XML: malformed attributes".into()))?;
        if a.key.as_ref() == key {
            let v = a
                .normalized_value(quick_xml::XmlVersion::Implicit1_0)
                .map_err(|_| {
                    ErrorKind::Header(format!("XML attribute {key}: bad escape or entity"))
                })?;
            return Ok(Some(v.trim().to_owned()));
        }
    }
    Ok(None)
}

fn attr_count(e: &BytesStart<'_>, key: &str) -> Result<usize, ErrorKind> {
    match attr(e, key)? {
        None => Ok(0),
        Some(v) => v
            .parse()
            .map_err(|_| ErrorKind::Header(format!("attribute {key} is not a count"))),
    }
}

fn xml_type(v: &str) -> Result<Option<Num>, ErrorKind> {
    Ok(Some(match v {
        "Int8" => Num::I8,
        "UInt8" => Num::U8,
        "Int16" => Num::I16,
        "UInt16" => Num::U16,
        "Int32" => Num::I32,
        "UInt32" => Num::U32,
        "Int64" | "IdType" => Num::I64,
        "UInt64" => Num::U64,
        "Float32" => Num::F32,
        "Float64" => Num::F64,
        "String" => return Ok(None),
        _ => {
            return Err(ErrorKind::UnknownValue {
                key: "VTK XML DataArray type",
                known: "Int8, UInt8, Int16, UInt16, Int32, UInt32, Int64, UInt64, IdType, \
                        Float32, Float64, String",
            });
        }
    }))
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

pub(crate) fn read(bytes: &[u8]) -> Result<RawMesh, ErrorKind> {
    // The appended block may be raw binary: parse only the XML before it.
    let (xml_end, appended_at) = match find(bytes, b"<AppendedData") {
        Some(p) => {
            let gt = bytes[p..]
                .iter()
                .position(|&b| b == b'>')
                .ok_or_else(|| ErrorKind::Header("unterminated AppendedData tag".into()))?;
            (p + gt + 1, Some(p + gt + 1))
        }
        None => (bytes.len(), None),
    };
    let xml = std::str::from_utf8(&bytes[..xml_end])
        .map_err(|_| ErrorKind::BadMagic("VTK XML (not UTF-8 text)"))?;
    if !xml
        .trim_start_matches('\u{feff}')
        .trim_start()
        .starts_with('<')
    {
        return Err(ErrorKind::BadMagic("VTK XML"));
    }

    let mut reader = quick_xml::Reader::from_str(xml);
    let mut doc = Doc {
        big: false,
        header_u64: false,
        zlib: false,
        appended: Appended::None,
        offsets: Vec::new(),
    };
    let mut seen_root = false;
    let mut piece: Option<[usize; 5]> = None; // points, polys, strips, lines, verts
    let mut normals_name: Option<String> = None;
    let mut section = Section::None;
    let mut arrays: Vec<Array> = Vec::new();
    let mut current: Option<Array> = None;
    let mut appended_encoding: Option<String> = None;
    let mut array_count = 0usize;

    loop {
        // quick-xml's messages quote the document (tag names, entities): give the place only.
        let event = reader.read_event().map_err(|_| {
            ErrorKind::Header(format!(
                "XML syntax error at byte {}",
                reader.error_position()
            ))
        })?;
        let (e, empty) = match event {
            Event::Eof => break,
            Event::Start(e) => (e, false),
            Event::Empty(e) => (e, true),
            Event::Text(t) => {
                if let Some(a) = current.as_mut() {
                    a.text.push_str(&t);
                }
                continue;
            }
            Event::CData(t) => {
                if let Some(a) = current.as_mut() {
                    a.text.push_str(&t);
                }
                continue;
            }
            Event::End(e) => {
                match e.name().as_ref() {
                    "DataArray" => arrays.extend(current.take()),
                    "PointData" | "CellData" | "Points" | "Verts" | "Lines" | "Strips"
                    | "Polys" | "FieldData" => section = Section::None,
                    _ => {}
                }
                continue;
            }
            Event::Comment(_)
            | Event::Decl(_)
            | Event::PI(_)
            | Event::DocType(_)
            | Event::GeneralRef(_) => continue,
        };
        let name = e.name().as_ref().to_owned();
        if !seen_root {
            if name != "VTKFile" {
                return Err(ErrorKind::BadMagic("VTK XML (no VTKFile element)"));
            }
            seen_root = true;
            let ty = attr(&e, "type")?.unwrap_or_default();
            if ty != "PolyData" {
                return Err(ErrorKind::UnknownValue {
                    key: "VTKFile type",
                    known: "PolyData",
                });
            }
            doc.big = match attr(&e, "byte_order")?.as_deref() {
                Some("BigEndian") => true,
                Some("LittleEndian") | None => false,
                Some(_) => {
                    return Err(ErrorKind::UnknownValue {
                        key: "VTKFile byte_order",
                        known: "LittleEndian, BigEndian",
                    });
                }
            };
            doc.header_u64 = match attr(&e, "header_type")?.as_deref() {
                Some("UInt64") => true,
                Some("UInt32") | None => false,
                Some(_) => {
                    return Err(ErrorKind::UnknownValue {
                        key: "VTKFile header_type",
                        known: "UInt32, UInt64",
                    });
                }
            };
            doc.zlib = match attr(&e, "compressor")?.as_deref() {
                Some("vtkZLibDataCompressor") => true,
                Some("") | None => false,
                Some(_) => {
                    return Err(ErrorKind::UnknownValue {
                        key: "VTKFile compressor",
                        known: "vtkZLibDataCompressor",
                    });
                }
            };
            continue;
        }
        match name.as_str() {
            "Piece" => {
                if piece.is_some() {
                    return Err(ErrorKind::Unsupported {
                        what: "VTP layout",
                        value: "more than one Piece".into(),
                    });
                }
                piece = Some([
                    attr_count(&e, "NumberOfPoints")?,
                    attr_count(&e, "NumberOfPolys")?,
                    attr_count(&e, "NumberOfStrips")?,
                    attr_count(&e, "NumberOfLines")?,
                    attr_count(&e, "NumberOfVerts")?,
                ]);
            }
            "PointData" => {
                normals_name = attr(&e, "Normals")?;
                section = Section::PointData;
            }
            "Points" => section = Section::Points,
            "Polys" => section = Section::Polys,
            "Strips" => section = Section::Strips,
            "FieldData" => section = Section::FieldData,
            "CellData" | "Verts" | "Lines" => section = Section::None,
            "DataArray" => {
                let format = match attr(&e, "format")?.as_deref() {
                    Some("ascii") => Format::Ascii,
                    Some("binary") => Format::Binary,
                    Some("appended") => Format::Appended,
                    Some(_) => {
                        return Err(ErrorKind::UnknownValue {
                            key: "DataArray format",
                            known: "ascii, binary, appended",
                        });
                    }
                    None => return Err(ErrorKind::MissingField("DataArray format")),
                };
                let offset = attr_count(&e, "offset")?;
                if format == Format::Appended {
                    doc.offsets.push(offset);
                }
                let ncomp = match attr(&e, "NumberOfComponents")? {
                    Some(_) => attr_count(&e, "NumberOfComponents")?,
                    None => 1,
                };
                let array = Array {
                    index: array_count,
                    section,
                    name: attr(&e, "Name")?.unwrap_or_default(),
                    ty: xml_type(&attr(&e, "type")?.unwrap_or_default())?,
                    ncomp,
                    format,
                    offset,
                    text: String::new(),
                };
                array_count += 1;
                if empty {
                    arrays.push(array);
                } else {
                    current = Some(array);
                }
            }
            "AppendedData" => {
                appended_encoding = Some(attr(&e, "encoding")?.unwrap_or_default());
                break;
            }
            _ => {}
        }
    }
    if !seen_root {
        return Err(ErrorKind::BadMagic("VTK XML"));
    }
    let Some([npoints, npolys, nstrips, nlines, nverts]) = piece else {
        return Err(ErrorKind::Header("no Piece element".into()));
    };

    if let (Some(at), Some(enc)) = (appended_at, appended_encoding) {
        let rest = &bytes[at..];
        let start = rest
            .iter()
            .position(|&b| b == b'_')
            .ok_or_else(|| ErrorKind::Header("AppendedData without '_' marker".into()))?
            + 1;
        doc.appended = match enc.as_str() {
            "raw" => Appended::Raw(&rest[start..]),
            "base64" => {
                let text = &rest[start..];
                let end = text.iter().position(|&b| b == b'<').unwrap_or(text.len());
                Appended::Base64(&text[..end])
            }
            _ => {
                return Err(ErrorKind::UnknownValue {
                    key: "AppendedData encoding",
                    known: "raw, base64",
                });
            }
        };
    }
    doc.offsets.sort_unstable();
    doc.offsets.dedup();

    let mut raw = RawMesh {
        other_cells: nlines.saturating_add(nverts) as u64,
        ..RawMesh::default()
    };
    for a in arrays.iter().filter(|a| a.section == Section::FieldData) {
        if a.name == "SPACE" && a.ty.is_none() {
            let bytes = doc.string_bytes(a)?;
            raw.lps = super::says_lps(&[b"SPACE=".as_slice(), &bytes].concat());
        }
    }

    let points = arrays
        .iter()
        .find(|a| a.section == Section::Points)
        .ok_or_else(|| ErrorKind::Header("no Points array".into()))?;
    if points.ncomp != 3 {
        return Err(ErrorKind::Mesh(format!(
            "Points has {} components, expected 3",
            points.ncomp
        )));
    }
    let v = doc.floats(points, mul(npoints, 3)?)?;
    raw.vertices = v.chunks_exact(3).map(Vec3::from_column_slice).collect();

    for (sec, ncells, strips) in [
        (Section::Polys, npolys, false),
        (Section::Strips, nstrips, true),
    ] {
        if ncells == 0 {
            continue;
        }
        let get = |name: &str| {
            arrays
                .iter()
                .find(|a| a.section == sec && a.name == name)
                .ok_or_else(|| ErrorKind::Header(format!("{sec:?}: no {name} array")))
        };
        let mut offsets = doc.ints(get("offsets")?, None)?;
        // VTK writes end offsets; accept a leading 0 as well.
        if offsets.len().checked_sub(1) == Some(ncells) && offsets.first() == Some(&0) {
            offsets.remove(0);
        }
        if offsets.len() != ncells {
            return Err(ErrorKind::Mesh(format!(
                "{sec:?}: {} offsets for {ncells} cells",
                offsets.len()
            )));
        }
        let total = offsets.last().copied().unwrap_or(0);
        let total = usize::try_from(total)
            .map_err(|_| ErrorKind::Mesh(format!("{sec:?}: negative offset {total}")))?;
        let conn = doc.ints(get("connectivity")?, Some(total))?;
        let mut start = 0usize;
        for &end in &offsets {
            let end = usize::try_from(end)
                .ok()
                .filter(|&e| e >= start && e <= conn.len())
                .ok_or_else(|| ErrorKind::Mesh(format!("{sec:?}: offsets out of order")))?;
            let cell = &conn[start..end];
            if strips {
                raw.push_strip(cell)?;
            } else {
                raw.push_polygon(cell)?;
            }
            start = end;
        }
    }

    let point_arrays = arrays.iter().filter(|a| a.section == Section::PointData);
    for a in point_arrays {
        let Some(_) = a.ty else { continue };
        let is_normals = match &normals_name {
            Some(n) => *n == a.name,
            None => a.name == "Normals",
        };
        if is_normals && a.ncomp == 3 && raw.normals.is_none() {
            let v = doc.floats(a, mul(npoints, 3)?)?;
            raw.normals = Some(v.chunks_exact(3).map(Vec3::from_column_slice).collect());
        } else if a.ncomp == 1 {
            raw.scalars.push((a.name.clone(), doc.floats(a, npoints)?));
        }
    }
    Ok(raw)
}

/// Splits base64 text at padding and decodes each run, so that separately encoded header and
/// data blocks (VTK) and one joint encoding both decode to the concatenated bytes.
fn base64_runs(text: &[u8]) -> Result<Vec<u8>, ErrorKind> {
    let clean: Vec<u8> = text
        .iter()
        .copied()
        .filter(|b| !b.is_ascii_whitespace())
        .collect();
    let mut out = Vec::with_capacity(clean.len() / 4 * 3 + 3);
    let mut start = 0;
    let mut i = 0;
    while i <= clean.len() {
        let at_end = i == clean.len();
        if at_end || clean[i] == b'=' {
            let mut j = i;
            while j < clean.len() && clean[j] == b'=' {
                j += 1;
            }
            if j > start {
                B64.decode_vec(&clean[start..j], &mut out).map_err(|e| {
                    // The decoder's message quotes the offending byte: give its place only.
                    let at = match e {
                        base64::DecodeError::InvalidByte(k, _)
                        | base64::DecodeError::InvalidLastSymbol(k, _) => {
                            format!(" at offset {}", start + k)
                        }
                        base64::DecodeError::InvalidLength(_)
                        | base64::DecodeError::InvalidPadding => String::new(),
                    };
                    ErrorKind::Decompress(format!("bad base64{at}"))
                })?;
            }
            start = j;
            i = j + usize::from(at_end);
        } else {
            i += 1;
        }
    }
    Ok(out)
}

impl Doc<'_> {
    fn uint(&self, s: &[u8], i: usize) -> Result<u64, ErrorKind> {
        let h = if self.header_u64 { 8 } else { 4 };
        let b = s.get(i * h..(i + 1) * h).ok_or(ErrorKind::DataSize {
            expected: ((i + 1) * h) as u64,
            got: s.len() as u64,
        })?;
        Ok(if self.header_u64 {
            Num::U64.get_i64(b, self.big).map(|v| v as u64)?
        } else {
            Num::U32.get_i64(b, self.big)? as u64
        })
    }

    /// The array's bytes after base64 decoding, header parsing and decompression.
    fn payload(&self, a: &Array) -> Result<Vec<u8>, ErrorKind> {
        let decoded;
        let block: &[u8] = match (a.format, &self.appended) {
            (Format::Binary, _) => {
                decoded = base64_runs(a.text.as_bytes())?;
                &decoded
            }
            (Format::Appended, Appended::Raw(data)) => {
                data.get(a.offset..).ok_or(ErrorKind::DataSize {
                    expected: a.offset as u64,
                    got: data.len() as u64,
                })?
            }
            (Format::Appended, Appended::Base64(text)) => {
                let end = self
                    .offsets
                    .iter()
                    .find(|&&o| o > a.offset)
                    .map_or(text.len(), |&o| o.min(text.len()));
                let run = text.get(a.offset..end).ok_or(ErrorKind::DataSize {
                    expected: a.offset as u64,
                    got: text.len() as u64,
                })?;
                decoded = base64_runs(run)?;
                &decoded
            }
            (Format::Appended, Appended::None) => {
                return Err(ErrorKind::Header(format!(
                    "{} is appended but there is no AppendedData",
                    a.label()
                )));
            }
            (Format::Ascii, _) => return Ok(Vec::new()),
        };
        self.unpack(block)
    }

    fn unpack(&self, s: &[u8]) -> Result<Vec<u8>, ErrorKind> {
        let h = if self.header_u64 { 8 } else { 4 };
        let too_short = |need: u64| ErrorKind::DataSize {
            expected: need,
            got: s.len() as u64,
        };
        if !self.zlib {
            let n = self.uint(s, 0)?;
            let end = n.checked_add(h as u64).ok_or_else(|| too_short(u64::MAX))?;
            return usize::try_from(end)
                .ok()
                .and_then(|e| s.get(h..e))
                .map(<[u8]>::to_vec)
                .ok_or_else(|| too_short(end));
        }
        let nblocks = self.uint(s, 0)?;
        let block_size = self.uint(s, 1)?;
        let last = self.uint(s, 2)?;
        let header_len = nblocks
            .checked_add(3)
            .and_then(|n| n.checked_mul(h as u64))
            .filter(|&n| n <= s.len() as u64)
            .ok_or_else(|| too_short(nblocks.saturating_add(3).saturating_mul(h as u64)))?;
        let sizes: Vec<u64> = (0..nblocks as usize)
            .map(|i| self.uint(s, 3 + i))
            .collect::<Result<_, _>>()?;
        let compressed: u64 = sizes
            .iter()
            .try_fold(0u64, |a, &b| a.checked_add(b))
            .unwrap_or(u64::MAX);
        let data = header_len
            .checked_add(compressed)
            .and_then(|e| s.get(header_len as usize..usize::try_from(e).ok()?))
            .ok_or_else(|| too_short(header_len.saturating_add(compressed)))?;
        if last > block_size {
            return Err(ErrorKind::Decompress(format!(
                "last block {last} is larger than the block size {block_size}"
            )));
        }
        let full = match nblocks {
            0 => 0,
            n => (n - 1)
                .checked_mul(block_size)
                .and_then(|f| f.checked_add(if last == 0 { block_size } else { last }))
                .unwrap_or(u64::MAX),
        };
        if full > MAX_INFLATE_RATIO.saturating_mul(compressed + 64) {
            return Err(ErrorKind::Decompress(format!(
                "header claims {full} bytes from {compressed} compressed bytes"
            )));
        }
        let mut out = Vec::with_capacity(full as usize);
        let mut at = 0usize;
        for (i, &cs) in sizes.iter().enumerate() {
            let want = if i + 1 == sizes.len() && last != 0 {
                last
            } else {
                block_size
            };
            let chunk = &data[at..at + cs as usize];
            at += cs as usize;
            let before = out.len();
            ZlibDecoder::new(chunk)
                .take(want + 1)
                .read_to_end(&mut out)
                .map_err(|e| ErrorKind::Decompress(format!("block {i}: {e}")))?;
            let got = out.len() - before;
            if got as u64 != want {
                return Err(ErrorKind::Decompress(format!(
                    "block {i} inflates to {got} bytes, header says {want}"
                )));
            }
        }
        Ok(out)
    }

    fn check_len(a: &Array, ty: Num, bytes: &[u8], count: usize) -> Result<(), ErrorKind> {
        let expected = mul(count, ty.size())?;
        if bytes.len() != expected {
            return Err(ErrorKind::Mesh(format!(
                "{} has {} bytes, {count} values need {expected}",
                a.label(),
                bytes.len()
            )));
        }
        Ok(())
    }

    fn ascii_end(a: &Array, c: &mut Cursor<'_>) -> Result<(), ErrorKind> {
        match c.token() {
            None => Ok(()),
            Some(_) => Err(ErrorKind::Mesh(format!(
                "{} has more values than expected",
                a.label()
            ))),
        }
    }

    fn floats(&self, a: &Array, count: usize) -> Result<Vec<f64>, ErrorKind> {
        let ty =
            a.ty.ok_or_else(|| ErrorKind::Mesh(format!("{} is a string array", a.label())))?;
        if a.format == Format::Ascii {
            let mut c = Cursor::new(a.text.as_bytes());
            let v = c.floats(count, &a.label())?;
            Self::ascii_end(a, &mut c)?;
            return Ok(v);
        }
        let bytes = self.payload(a)?;
        Self::check_len(a, ty, &bytes, count)?;
        ty.decode_f64(&bytes, self.big)
    }

    /// Integers; without `count`, as many as the data holds.
    fn ints(&self, a: &Array, count: Option<usize>) -> Result<Vec<i64>, ErrorKind> {
        let ty =
            a.ty.ok_or_else(|| ErrorKind::Mesh(format!("{} is a string array", a.label())))?;
        if a.format == Format::Ascii {
            let mut c = Cursor::new(a.text.as_bytes());
            let n = count.unwrap_or_else(|| a.text.split_ascii_whitespace().count());
            let v = c.ints(n, &a.label())?;
            Self::ascii_end(a, &mut c)?;
            return Ok(v);
        }
        let bytes = self.payload(a)?;
        if let Some(n) = count {
            Self::check_len(a, ty, &bytes, n)?;
        }
        ty.decode_i64(&bytes, self.big)
    }

    fn string_bytes(&self, a: &Array) -> Result<Vec<u8>, ErrorKind> {
        if a.format == Format::Ascii {
            let mut c = Cursor::new(a.text.as_bytes());
            let n = a.text.split_ascii_whitespace().count();
            let codes = c.ints(n, &a.label())?;
            return Ok(codes.into_iter().map(|v| v as u8).collect());
        }
        self.payload(a)
    }
}

// ---------------------------------------------------------------------------------------------

struct Writer<'o> {
    opts: &'o WriteOptions,
    xml: String,
    appended: Vec<u8>,
}

impl Writer<'_> {
    fn header_uint(&self, out: &mut Vec<u8>, v: usize) -> Result<(), ErrorKind> {
        if self.opts.header_u64 {
            out.extend_from_slice(&(v as u64).to_le_bytes());
        } else {
            let v = u32::try_from(v).map_err(|_| ErrorKind::Unsupported {
                what: "array size for a UInt32 header",
                value: v.to_string(),
            })?;
            out.extend_from_slice(&v.to_le_bytes());
        }
        Ok(())
    }

    /// Header and body of one binary array.
    fn pack(&self, data: &[u8]) -> Result<(Vec<u8>, Vec<u8>), ErrorKind> {
        let mut header = Vec::new();
        if !self.opts.compress {
            self.header_uint(&mut header, data.len())?;
            return Ok((header, data.to_vec()));
        }
        let blocks: Vec<&[u8]> = data.chunks(BLOCK).collect();
        let mut body = Vec::new();
        let mut sizes = Vec::with_capacity(blocks.len());
        for b in &blocks {
            let mut enc = ZlibEncoder::new(Vec::new(), Compression::fast());
            enc.write_all(b)?;
            let c = enc.finish()?;
            sizes.push(c.len());
            body.extend_from_slice(&c);
        }
        let last = blocks.last().map_or(0, |b| b.len() % BLOCK);
        for v in [blocks.len(), BLOCK, last].into_iter().chain(sizes) {
            self.header_uint(&mut header, v)?;
        }
        Ok((header, body))
    }

    fn array(
        &mut self,
        ty: &str,
        name: &str,
        ncomp: usize,
        text: impl Iterator<Item = String>,
        le_bytes: Vec<u8>,
    ) -> Result<(), ErrorKind> {
        let name = quick_xml::escape::escape(name);
        let comps = if ncomp > 1 {
            format!(" NumberOfComponents=\"{ncomp}\"")
        } else {
            String::new()
        };
        let open = format!("        <DataArray type=\"{ty}\" Name=\"{name}\"{comps}");
        if self.opts.encoding == super::Encoding::Ascii {
            let values: Vec<String> = text.collect();
            let _ = writeln!(
                self.xml,
                "{open} format=\"ascii\">\n          {}\n        </DataArray>",
                values.join(" ")
            );
            return Ok(());
        }
        let (header, body) = self.pack(&le_bytes)?;
        match self.opts.vtp_layout {
            VtpLayout::Inline => {
                let _ = writeln!(
                    self.xml,
                    "{open} format=\"binary\">\n          {}{}\n        </DataArray>",
                    B64.encode(&header),
                    B64.encode(&body)
                );
            }
            VtpLayout::AppendedRaw | VtpLayout::AppendedBase64 => {
                let _ = writeln!(
                    self.xml,
                    "{open} format=\"appended\" offset=\"{}\"/>",
                    self.appended.len()
                );
                if self.opts.vtp_layout == VtpLayout::AppendedRaw {
                    self.appended.extend_from_slice(&header);
                    self.appended.extend_from_slice(&body);
                } else {
                    self.appended
                        .extend_from_slice(B64.encode(&header).as_bytes());
                    self.appended
                        .extend_from_slice(B64.encode(&body).as_bytes());
                }
            }
        }
        Ok(())
    }

    fn f64s(&mut self, name: &str, ncomp: usize, values: &[f64]) -> Result<(), ErrorKind> {
        let bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.array(
            "Float64",
            name,
            ncomp,
            values.iter().map(|&v| fmt_f64(v)),
            bytes,
        )
    }

    fn i64s(&mut self, name: &str, values: &[i64]) -> Result<(), ErrorKind> {
        let bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.array("Int64", name, 1, values.iter().map(i64::to_string), bytes)
    }
}

/// Encodes a mesh as VTK XML PolyData (little-endian, `Float64` points/normals/scalars, `Int64`
/// cells) with a `SPACE`=`RAS` field array.
pub(crate) fn write(mesh: &TriMesh, opts: &WriteOptions) -> Result<Vec<u8>, ErrorKind> {
    let t = mesh.triangles().len();
    let conn: Vec<i64> = mesh
        .triangles()
        .iter()
        .flat_map(|tri| tri.map(i64::from))
        .collect();
    let offsets: Vec<i64> = (1..=t as i64).map(|k| 3 * k).collect();
    let point_data: Vec<(&str, &[f64])> = mesh
        .scalars()
        .iter()
        .map(|(name, values)| (name.as_str(), values.as_slice()))
        .collect();
    write_piece(
        &Piece {
            points: mesh.vertices(),
            normals: mesh.normals(),
            point_data: &point_data,
            cell_data: &[],
            cells: Cells::Polys,
            connectivity: &conn,
            offsets: &offsets,
        },
        opts,
    )
}

/// Polylines with named point and cell arrays (one value per point, in the order of the lines'
/// points; one per line), for [`write_polylines`](super::write_polylines).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PolylineSet {
    pub lines: Vec<Vec<Vec3>>,
    pub point_data: Vec<(String, Vec<f64>)>,
    pub cell_data: Vec<(String, Vec<f64>)>,
}

/// Encodes polylines as VTK XML PolyData `Lines`, like [`write`].
pub(crate) fn write_lines(set: &PolylineSet, opts: &WriteOptions) -> Result<Vec<u8>, ErrorKind> {
    let points: Vec<Vec3> = set.lines.iter().flatten().copied().collect();
    let check = |what: &str, arrays: &[(String, Vec<f64>)], len: usize| match arrays
        .iter()
        .find(|(_, v)| v.len() != len)
    {
        Some((name, v)) => Err(ErrorKind::Mesh(format!(
            "{what} array {name:?} has {} values for {len} {what}s",
            v.len()
        ))),
        None => Ok(()),
    };
    check("point", &set.point_data, points.len())?;
    check("line", &set.cell_data, set.lines.len())?;
    let conn: Vec<i64> = (0..points.len() as i64).collect();
    let offsets: Vec<i64> = set
        .lines
        .iter()
        .scan(0i64, |end, l| {
            *end += l.len() as i64;
            Some(*end)
        })
        .collect();
    let (pd, cd) = (named(&set.point_data), named(&set.cell_data));
    write_piece(
        &Piece {
            points: &points,
            normals: None,
            point_data: &pd,
            cell_data: &cd,
            cells: Cells::Lines,
            connectivity: &conn,
            offsets: &offsets,
        },
        opts,
    )
}

/// Encodes points, with their normals if given, as VTK XML PolyData with one `Verts` cell per
/// point (what `vtkVertexGlyphFilter` makes), like [`write`].
pub(crate) fn write_verts(
    points: &[Vec3],
    normals: Option<&[Vec3]>,
    opts: &WriteOptions,
) -> Result<Vec<u8>, ErrorKind> {
    let n = points.len() as i64;
    let conn: Vec<i64> = (0..n).collect();
    let offsets: Vec<i64> = (1..=n).collect();
    write_piece(
        &Piece {
            points,
            normals,
            point_data: &[],
            cell_data: &[],
            cells: Cells::Verts,
            connectivity: &conn,
            offsets: &offsets,
        },
        opts,
    )
}

fn named(arrays: &[(String, Vec<f64>)]) -> Vec<(&str, &[f64])> {
    arrays
        .iter()
        .map(|(n, v)| (n.as_str(), v.as_slice()))
        .collect()
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Cells {
    Verts,
    Lines,
    Polys,
}

struct Piece<'a> {
    points: &'a [Vec3],
    normals: Option<&'a [Vec3]>,
    point_data: &'a [(&'a str, &'a [f64])],
    cell_data: &'a [(&'a str, &'a [f64])],
    cells: Cells,
    connectivity: &'a [i64],
    offsets: &'a [i64],
}

fn write_piece(piece: &Piece<'_>, opts: &WriteOptions) -> Result<Vec<u8>, ErrorKind> {
    let n = piece.points.len();
    let cells = piece.offsets.len();
    let (verts, lines, polys, section) = match piece.cells {
        Cells::Verts => (cells, 0, 0, "Verts"),
        Cells::Lines => (0, cells, 0, "Lines"),
        Cells::Polys => (0, 0, cells, "Polys"),
    };
    let binary = opts.encoding != super::Encoding::Ascii;
    let appended = binary && opts.vtp_layout != VtpLayout::Inline;
    let mut w = Writer {
        opts,
        xml: String::new(),
        appended: Vec::new(),
    };
    let header = if opts.header_u64 { "UInt64" } else { "UInt32" };
    let compressor = if binary && opts.compress {
        " compressor=\"vtkZLibDataCompressor\""
    } else {
        ""
    };
    let _ = writeln!(
        w.xml,
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"1.0\" \
         byte_order=\"LittleEndian\" header_type=\"{header}\"{compressor}>\n  <PolyData>\n    \
         <FieldData>\n      <DataArray type=\"String\" Name=\"SPACE\" NumberOfTuples=\"1\" \
         format=\"ascii\">\n        82 65 83 0\n      </DataArray>\n    </FieldData>\n    \
         <Piece NumberOfPoints=\"{n}\" NumberOfVerts=\"{verts}\" NumberOfLines=\"{lines}\" \
         NumberOfStrips=\"0\" NumberOfPolys=\"{polys}\">"
    );
    let normals_attr = if piece.normals.is_some() {
        " Normals=\"Normals\""
    } else {
        ""
    };
    let _ = writeln!(w.xml, "      <PointData{normals_attr}>");
    if let Some(normals) = piece.normals {
        let v: Vec<f64> = normals.iter().flat_map(|p| p.iter().copied()).collect();
        w.f64s("Normals", 3, &v)?;
    }
    for (name, values) in piece.point_data {
        w.f64s(name, 1, values)?;
    }
    let _ = writeln!(w.xml, "      </PointData>\n      <CellData>");
    for (name, values) in piece.cell_data {
        w.f64s(name, 1, values)?;
    }
    let _ = writeln!(w.xml, "      </CellData>\n      <Points>");
    let v: Vec<f64> = piece
        .points
        .iter()
        .flat_map(|p| p.iter().copied())
        .collect();
    w.f64s("Points", 3, &v)?;
    let _ = writeln!(w.xml, "      </Points>\n      <{section}>");
    w.i64s("connectivity", piece.connectivity)?;
    w.i64s("offsets", piece.offsets)?;
    let _ = writeln!(w.xml, "      </{section}>\n    </Piece>\n  </PolyData>");
    let mut out = w.xml.into_bytes();
    if appended {
        let enc = if opts.vtp_layout == VtpLayout::AppendedRaw {
            "raw"
        } else {
            "base64"
        };
        write!(out, "  <AppendedData encoding=\"{enc}\">\n   _")?;
        out.extend_from_slice(&w.appended);
        out.extend_from_slice(b"\n  </AppendedData>\n");
    }
    out.extend_from_slice(b"</VTKFile>\n");
    Ok(out)
}
