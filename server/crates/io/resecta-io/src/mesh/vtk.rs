//! VTK legacy `POLYDATA` files, ASCII and BINARY (big-endian).
//!
//! Reads `POINTS` (any numeric type), `POLYGONS` and `TRIANGLE_STRIPS` (both the classic
//! `n size` cell lists and the version 5.x `OFFSETS`/`CONNECTIVITY` form), counts `VERTICES` and
//! `LINES`, and from `POINT_DATA` keeps `NORMALS` and one-component `SCALARS` and `FIELD` arrays.
//! Other attributes (vectors, tensors, colours, texture coordinates, cell data, `METADATA`) are
//! parsed past and dropped. Writes version 4.2 (as Slicer does, for older readers): `POINTS double`,
//! `POLYGONS`, and `POINT_DATA` with `NORMALS` and the scalars as a `FIELD`.

use std::io::Write;

use resecta_geom::{TriMesh, Vec3};

use super::{
    Cursor, Encoding, Num, RawMesh, SPACE_TAG, decode_name, encode_name, fmt_f64, mul, parse_count,
    says_lps,
};
use crate::error::ErrorKind;

const VTK_TYPES: &str = "unsigned_char, char, unsigned_short, short, unsigned_int, int, \
                         unsigned_long, long, float, double (and their vtkType names)";

fn num_type(word: Option<&str>) -> Result<Num, ErrorKind> {
    let w = word.unwrap_or("").to_ascii_lowercase();
    Ok(match w.as_str() {
        "unsigned_char" | "vtktypeuint8" => Num::U8,
        "char" | "signed_char" | "vtktypeint8" => Num::I8,
        "unsigned_short" | "vtktypeuint16" => Num::U16,
        "short" | "vtktypeint16" => Num::I16,
        "unsigned_int" | "vtktypeuint32" => Num::U32,
        // vtkIdType arrays are written as 32-bit ints by the legacy writer.
        "int" | "vtktypeint32" | "vtkidtype" => Num::I32,
        "unsigned_long" | "vtktypeuint64" => Num::U64,
        "long" | "vtktypeint64" => Num::I64,
        "float" | "vtktypefloat32" => Num::F32,
        "double" | "vtktypefloat64" => Num::F64,
        _ => {
            return Err(ErrorKind::UnknownValue {
                key: "VTK data type",
                known: VTK_TYPES,
            });
        }
    })
}

struct Reader<'a> {
    c: Cursor<'a>,
    binary: bool,
}

impl Reader<'_> {
    fn floats(&mut self, ty: Num, count: usize, what: &str) -> Result<Vec<f64>, ErrorKind> {
        if self.binary {
            let bytes = self.c.take(mul(count, ty.size())?)?;
            ty.decode_f64(bytes, true)
        } else {
            self.c.floats(count, what)
        }
    }

    fn ints(&mut self, ty: Num, count: usize, what: &str) -> Result<Vec<i64>, ErrorKind> {
        if self.binary {
            let bytes = self.c.take(mul(count, ty.size())?)?;
            ty.decode_i64(bytes, true)
        } else {
            self.c.ints(count, what)
        }
    }

    /// Unsigned bytes in binary files, floats in ASCII ones (colour scalars, lookup tables).
    fn skip_colors(&mut self, count: usize, what: &str) -> Result<(), ErrorKind> {
        if self.binary {
            self.c.take(count).map(drop)
        } else {
            self.c.floats(count, what).map(drop)
        }
    }

    /// Words of the next non-blank line.
    fn words(&mut self) -> Option<Vec<String>> {
        let line = self.c.nonblank_line()?;
        Some(
            String::from_utf8_lossy(line)
                .split_whitespace()
                .map(str::to_owned)
                .collect(),
        )
    }

    /// Peeks at the next line: consumes it only if its first word is `keyword`.
    fn optional_line(&mut self, keyword: &str) -> Option<Vec<String>> {
        let save = self.c.pos;
        match self.words() {
            Some(w) if w.first().is_some_and(|k| k.eq_ignore_ascii_case(keyword)) => Some(w),
            _ => {
                self.c.pos = save;
                None
            }
        }
    }

    /// Skips a `METADATA` block (it ends at a blank line).
    fn skip_metadata(&mut self) {
        while let Some(line) = self.c.line() {
            if line.iter().all(u8::is_ascii_whitespace) {
                break;
            }
        }
    }

    /// Reads a cell section and calls `f` for every cell's point ids.
    fn cells(
        &mut self,
        words: &[String],
        new_form: bool,
        mut f: impl FnMut(&[i64]) -> Result<(), ErrorKind>,
    ) -> Result<(), ErrorKind> {
        // One of the cell keywords (matched case-insensitively by the caller).
        let kw = &words[0].to_ascii_uppercase();
        let a = parse_count(words.get(1).map(String::as_str), kw)?;
        let b = parse_count(words.get(2).map(String::as_str), kw)?;
        if new_form {
            let off = self
                .optional_line("OFFSETS")
                .ok_or_else(|| ErrorKind::Header(format!("{kw}: OFFSETS line missing")))?;
            let offsets = self.ints(num_type(off.get(1).map(String::as_str))?, a, "OFFSETS")?;
            let con = self
                .optional_line("CONNECTIVITY")
                .ok_or_else(|| ErrorKind::Header(format!("{kw}: CONNECTIVITY line missing")))?;
            let conn = self.ints(num_type(con.get(1).map(String::as_str))?, b, "CONNECTIVITY")?;
            if offsets.first().is_some_and(|&o| o != 0)
                || offsets.last().is_some_and(|&o| o != b as i64)
            {
                return Err(ErrorKind::Mesh(format!(
                    "{kw}: offsets must run from 0 to the connectivity size {b}"
                )));
            }
            for w in offsets.windows(2) {
                let (s, e) = (w[0], w[1]);
                if s > e {
                    return Err(ErrorKind::Mesh(format!("{kw}: offsets decrease")));
                }
                f(&conn[s as usize..e as usize])?;
            }
        } else {
            let data = self.ints(Num::I32, b, kw)?;
            let mut p = 0usize;
            for cell in 0..a {
                let k = data.get(p).copied().unwrap_or(-1);
                let end = usize::try_from(k)
                    .ok()
                    .and_then(|k| (p + 1).checked_add(k))
                    .filter(|&e| e <= data.len())
                    .ok_or_else(|| {
                        ErrorKind::Mesh(format!(
                            "{kw}: cell {cell} of {a} does not fit in the {b} listed values"
                        ))
                    })?;
                f(&data[p + 1..end])?;
                p = end;
            }
            if p != data.len() {
                return Err(ErrorKind::Mesh(format!(
                    "{kw}: {a} cells use {p} values but the size is {b}"
                )));
            }
        }
        Ok(())
    }
}

#[derive(Clone, Copy)]
enum Attr {
    None,
    Point(usize),
    Cell(usize),
}

pub(crate) fn read(bytes: &[u8]) -> Result<RawMesh, ErrorKind> {
    let mut c = Cursor::new(bytes);
    let first = c.line().unwrap_or_default();
    let first = String::from_utf8_lossy(first).to_ascii_lowercase();
    let Some(version) = first.trim().strip_prefix("# vtk datafile version") else {
        return Err(ErrorKind::BadMagic("VTK legacy"));
    };
    let major: u32 = version
        .trim()
        .split('.')
        .next()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3);
    let title = c
        .line()
        .ok_or_else(|| ErrorKind::Header("title line missing".into()))?;
    let mut raw = RawMesh {
        lps: says_lps(title),
        ..RawMesh::default()
    };
    let mut r = Reader { c, binary: false };
    let enc = r.words().unwrap_or_default();
    r.binary = match enc.first().map(|w| w.to_ascii_uppercase()).as_deref() {
        Some("ASCII") => false,
        Some("BINARY") => true,
        _ => {
            return Err(ErrorKind::Header(
                "the encoding line is not ASCII or BINARY".into(),
            ));
        }
    };
    let ds = r.words().unwrap_or_default().join(" ").to_ascii_uppercase();
    if ds != "DATASET POLYDATA" {
        return Err(ErrorKind::UnknownValue {
            key: "VTK DATASET",
            known: "POLYDATA",
        });
    }

    let mut npoints: Option<usize> = None;
    let mut attr = Attr::None;
    while let Some(words) = r.words() {
        let Some(kw) = words.first().map(|w| w.to_ascii_uppercase()) else {
            continue;
        };
        let word = |i: usize| words.get(i).map(String::as_str);
        let attr_count = |attr: Attr| match attr {
            Attr::Point(n) | Attr::Cell(n) => Ok(n),
            Attr::None => Err(ErrorKind::Header(format!(
                "{kw} before POINT_DATA or CELL_DATA"
            ))),
        };
        match kw.as_str() {
            "POINTS" => {
                let n = parse_count(word(1), "POINTS")?;
                let v = r.floats(num_type(word(2))?, mul(n, 3)?, "POINTS")?;
                raw.vertices = v.chunks_exact(3).map(Vec3::from_column_slice).collect();
                npoints = Some(n);
            }
            "VERTICES" | "LINES" => {
                let mut n = 0;
                r.cells(&words, major >= 5, |_| {
                    n += 1;
                    Ok(())
                })?;
                raw.other_cells += n;
            }
            "POLYGONS" => r.cells(&words, major >= 5, |p| raw.push_polygon(p))?,
            "TRIANGLE_STRIPS" => r.cells(&words, major >= 5, |s| raw.push_strip(s))?,
            "POINT_DATA" | "CELL_DATA" => {
                let n = parse_count(word(1), &kw)?;
                if kw == "POINT_DATA" {
                    if npoints != Some(n) {
                        return Err(ErrorKind::Mesh(format!(
                            "POINT_DATA {n} does not match POINTS {npoints:?}"
                        )));
                    }
                    attr = Attr::Point(n);
                } else {
                    attr = Attr::Cell(n);
                }
            }
            "SCALARS" => {
                let n = attr_count(attr)?;
                let name = decode_name(word(1).unwrap_or(""));
                let ty = num_type(word(2))?;
                let ncomp = match word(3) {
                    Some(w) => parse_count(Some(w), "SCALARS components")?,
                    None => 1,
                };
                r.optional_line("LOOKUP_TABLE");
                let v = r.floats(ty, mul(n, ncomp)?, "SCALARS")?;
                if matches!(attr, Attr::Point(_)) && ncomp == 1 {
                    raw.scalars.push((name, v));
                }
            }
            "COLOR_SCALARS" => {
                let n = attr_count(attr)?;
                let ncomp = parse_count(word(2), "COLOR_SCALARS components")?;
                r.skip_colors(mul(n, ncomp)?, "COLOR_SCALARS")?;
            }
            "LOOKUP_TABLE" => {
                let size = parse_count(word(2), "LOOKUP_TABLE")?;
                r.skip_colors(mul(size, 4)?, "LOOKUP_TABLE")?;
            }
            "NORMALS" | "VECTORS" => {
                let n = attr_count(attr)?;
                let v = r.floats(num_type(word(2))?, mul(n, 3)?, &kw)?;
                if kw == "NORMALS" && matches!(attr, Attr::Point(_)) && raw.normals.is_none() {
                    raw.normals = Some(v.chunks_exact(3).map(Vec3::from_column_slice).collect());
                }
            }
            "TEXTURE_COORDINATES" => {
                let n = attr_count(attr)?;
                let dim = parse_count(word(2), "TEXTURE_COORDINATES dimension")?;
                r.floats(num_type(word(3))?, mul(n, dim)?, &kw)?;
            }
            "TENSORS" | "TENSORS6" => {
                let n = attr_count(attr)?;
                let k = if kw == "TENSORS" { 9 } else { 6 };
                r.floats(num_type(word(2))?, mul(n, k)?, &kw)?;
            }
            "GLOBAL_IDS" | "PEDIGREE_IDS" => {
                let n = attr_count(attr)?;
                r.floats(num_type(word(2))?, n, &kw)?;
            }
            "FIELD" => {
                let narrays = parse_count(word(2), "FIELD")?;
                for _ in 0..narrays {
                    let a = r
                        .words()
                        .ok_or_else(|| ErrorKind::Header("FIELD: array line missing".into()))?;
                    let aw = |i: usize| a.get(i).map(String::as_str);
                    let ncomp = parse_count(aw(1), "FIELD array components")?;
                    let ntuples = parse_count(aw(2), "FIELD array tuples")?;
                    let v = r.floats(num_type(aw(3))?, mul(ncomp, ntuples)?, "FIELD array")?;
                    if ncomp == 1 && matches!(attr, Attr::Point(n) if n == ntuples) {
                        raw.scalars.push((decode_name(&a[0]), v));
                    }
                    if r.optional_line("METADATA").is_some() {
                        r.skip_metadata();
                    }
                }
            }
            "METADATA" => r.skip_metadata(),
            _ => {
                // The word is the file's text: the error gives its place, not the word.
                return Err(ErrorKind::Header(format!(
                    "unknown keyword at byte {}",
                    r.c.pos
                )));
            }
        }
    }
    if raw.vertices.is_empty() && npoints.is_none() {
        return Err(ErrorKind::Header("no POINTS section".into()));
    }
    Ok(raw)
}

/// Encodes a mesh as VTK legacy 4.2 (binary data is big-endian).
pub(crate) fn write(mesh: &TriMesh, encoding: Encoding) -> Result<Vec<u8>, ErrorKind> {
    let binary = encoding != Encoding::Ascii;
    let n = mesh.vertices().len();
    let t = mesh.triangles().len();
    let mut out = Vec::with_capacity(64 + n * 24 + t * 16);
    let text = if binary { "BINARY" } else { "ASCII" };
    write!(
        out,
        "# vtk DataFile Version 4.2\nresecta output. {SPACE_TAG}\n{text}\nDATASET POLYDATA\n"
    )?;
    let floats = |out: &mut Vec<u8>, values: &mut dyn Iterator<Item = f64>| {
        if binary {
            values.for_each(|v| out.extend_from_slice(&v.to_be_bytes()));
            out.push(b'\n');
        } else {
            for (i, v) in values.enumerate() {
                out.extend_from_slice(fmt_f64(v).as_bytes());
                out.push(if i % 9 == 8 { b'\n' } else { b' ' });
            }
            out.push(b'\n');
        }
    };
    writeln!(out, "POINTS {n} double")?;
    floats(
        &mut out,
        &mut mesh.vertices().iter().flat_map(|v| v.iter().copied()),
    );

    writeln!(out, "POLYGONS {t} {}", t * 4)?;
    for tri in mesh.triangles() {
        if binary {
            out.extend_from_slice(&3i32.to_be_bytes());
            for &i in tri {
                let i = i32::try_from(i).map_err(|_| ErrorKind::Unsupported {
                    what: "vertex index for VTK legacy (32-bit)",
                    value: i.to_string(),
                })?;
                out.extend_from_slice(&i.to_be_bytes());
            }
        } else {
            writeln!(out, "3 {} {} {}", tri[0], tri[1], tri[2])?;
        }
    }
    if binary {
        out.push(b'\n');
    }

    if mesh.normals().is_some() || !mesh.scalars().is_empty() {
        writeln!(out, "POINT_DATA {n}")?;
    }
    if let Some(normals) = mesh.normals() {
        writeln!(out, "NORMALS Normals double")?;
        floats(
            &mut out,
            &mut normals.iter().flat_map(|v| v.iter().copied()),
        );
    }
    if !mesh.scalars().is_empty() {
        writeln!(out, "FIELD FieldData {}", mesh.scalars().len())?;
        for (name, values) in mesh.scalars() {
            writeln!(out, "{} 1 {n} double", encode_name(name))?;
            floats(&mut out, &mut values.iter().copied());
        }
    }
    Ok(out)
}
