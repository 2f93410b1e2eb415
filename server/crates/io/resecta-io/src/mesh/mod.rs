//! Surface mesh files: VTK legacy (`.vtk`), VTK XML PolyData (`.vtp`), STL, PLY and Wavefront OBJ.
//!
//! Readers turn every polygon and triangle strip into triangles (fans for polygons) and return a
//! validated [`TriMesh`]. Polylines and vertex cells are ignored next to a surface; a file that
//! holds *only* such cells (a vessel centreline, say) is refused with [`ErrorKind::Mesh`], since a
//! triangle mesh cannot carry its connectivity.
//!
//! # Coordinates
//!
//! Meshes are RAS millimetres and writers store them as they are (no LPS flip), tagging the file
//! the way 3D Slicer does: `SPACE=RAS` in the VTK title line, the STL header, a PLY and an OBJ
//! comment, and a one-value `SPACE` string array in the VTP field data. Slicer writes LPS by
//! default since 4.11 (and assumes LPS for untagged legacy model files), so readers honour an
//! explicit `SPACE=LPS` tag by negating x and y (of vertices and normals); untagged files are taken
//! as RAS.
//!
//! # Precision
//!
//! VTK, VTP and OBJ keep `f64` exactly (binary doubles; text in shortest round-trip form). STL
//! and PLY store coordinates and normals as `f32`, so they round-trip to `f32` precision; PLY
//! scalars are written as `double`.
//!
//! # Bad input
//!
//! Every failure is an [`IoError`] naming the file. Counts read from headers are checked against
//! the bytes that remain before anything is allocated for them.

pub mod obj;
pub mod ply;
pub mod stl;
pub mod vtk;
pub mod vtp;

use std::path::Path;

use resecta_geom::{TriMesh, Vec3};

use crate::error::{ErrorKind, IoError};

/// A mesh file format, chosen by file extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MeshFormat {
    Vtk,
    Vtp,
    Stl,
    Ply,
    Obj,
}

const EXTENSIONS: &str = ".vtk, .vtp, .stl, .ply, .obj";

impl MeshFormat {
    pub const ALL: [Self; 5] = [Self::Vtk, Self::Vtp, Self::Stl, Self::Ply, Self::Obj];

    /// The format for a file name's extension (case-insensitive).
    pub fn from_path(path: impl AsRef<Path>) -> Result<Self, IoError> {
        let path = path.as_ref();
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        Ok(match ext.as_str() {
            "vtk" => Self::Vtk,
            "vtp" => Self::Vtp,
            "stl" => Self::Stl,
            "ply" => Self::Ply,
            "obj" => Self::Obj,
            _ => {
                return Err(IoError::new(
                    path,
                    ErrorKind::UnknownFormat(ext, EXTENSIONS),
                ));
            }
        })
    }

    /// The usual file extension, without the dot.
    pub fn extension(self) -> &'static str {
        match self {
            Self::Vtk => "vtk",
            Self::Vtp => "vtp",
            Self::Stl => "stl",
            Self::Ply => "ply",
            Self::Obj => "obj",
        }
    }
}

/// Text or binary storage, where the format offers a choice.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Encoding {
    /// VTK `ASCII`, VTP `format="ascii"`, ASCII STL, PLY `ascii`. OBJ is always text.
    Ascii,
    /// VTK `BINARY` (big-endian by definition), VTP base64/raw binary, binary STL, PLY
    /// `binary_little_endian`.
    #[default]
    Binary,
    /// PLY `binary_big_endian`; the same as [`Encoding::Binary`] for the other formats.
    BinaryBigEndian,
}

/// Where VTP binary arrays go.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum VtpLayout {
    /// Base64 inside each `DataArray` (`format="binary"`).
    Inline,
    /// One `AppendedData` block, `encoding="raw"` (not valid XML text, but VTK's default on
    /// disk when encoding is off).
    AppendedRaw,
    /// One `AppendedData` block, `encoding="base64"` (what VTK writes by default).
    #[default]
    AppendedBase64,
}

/// How to write a mesh; options that do not apply to a format are ignored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WriteOptions {
    pub encoding: Encoding,
    /// VTP only: where binary arrays go.
    pub vtp_layout: VtpLayout,
    /// VTP only: zlib-compress binary arrays (`vtkZLibDataCompressor`).
    pub compress: bool,
    /// VTP only: `header_type="UInt64"` (else `UInt32`).
    pub header_u64: bool,
}

impl Default for WriteOptions {
    /// Binary; VTP appended base64 with zlib and 64-bit headers, as VTK 9 writes.
    fn default() -> Self {
        Self {
            encoding: Encoding::Binary,
            vtp_layout: VtpLayout::AppendedBase64,
            compress: true,
            header_u64: true,
        }
    }
}

impl WriteOptions {
    /// Text storage.
    pub fn ascii() -> Self {
        Self {
            encoding: Encoding::Ascii,
            ..Self::default()
        }
    }
}

/// Reads a mesh file, choosing the format by extension.
pub fn read_mesh(path: impl AsRef<Path>) -> Result<TriMesh, IoError> {
    let path = path.as_ref();
    let format = MeshFormat::from_path(path)?;
    let bytes = std::fs::read(path).map_err(|e| IoError::new(path, e))?;
    read_mesh_bytes(&bytes, format, path)
}

/// Reads a mesh from memory; `name` is only used in error messages.
pub fn read_mesh_bytes(
    bytes: &[u8],
    format: MeshFormat,
    name: impl AsRef<Path>,
) -> Result<TriMesh, IoError> {
    let raw = match format {
        MeshFormat::Vtk => vtk::read(bytes),
        MeshFormat::Vtp => vtp::read(bytes),
        MeshFormat::Stl => stl::read(bytes),
        MeshFormat::Ply => ply::read(bytes),
        MeshFormat::Obj => obj::read(bytes),
    };
    raw.and_then(RawMesh::finish)
        .map_err(|kind| IoError::new(name, kind))
}

/// Writes a mesh with default options (binary where the format allows), choosing the format by
/// extension. Coordinates are written as RAS, unchanged.
pub fn write_mesh(path: impl AsRef<Path>, mesh: &TriMesh) -> Result<(), IoError> {
    write_mesh_with(path, mesh, &WriteOptions::default())
}

/// Writes a mesh with the given options, choosing the format by extension.
pub fn write_mesh_with(
    path: impl AsRef<Path>,
    mesh: &TriMesh,
    options: &WriteOptions,
) -> Result<(), IoError> {
    let path = path.as_ref();
    let format = MeshFormat::from_path(path)?;
    let bytes = mesh_to_bytes(mesh, format, options, path)?;
    std::fs::write(path, bytes).map_err(|e| IoError::new(path, e))
}

/// Writes polylines (vessel centrelines, say) with their point and line arrays as VTK XML
/// PolyData `Lines` (`.vtp` only), as RAS like every mesh writer.
pub fn write_polylines(path: impl AsRef<Path>, set: &vtp::PolylineSet) -> Result<(), IoError> {
    let path = path.as_ref();
    if MeshFormat::from_path(path)? != MeshFormat::Vtp {
        return Err(IoError::new(
            path,
            ErrorKind::Mesh("polylines are written as VTK XML PolyData (.vtp) only".into()),
        ));
    }
    let bytes =
        vtp::write_lines(set, &WriteOptions::default()).map_err(|k| IoError::new(path, k))?;
    std::fs::write(path, bytes).map_err(|e| IoError::new(path, e))
}

/// Encodes a mesh in memory; `name` is only used in error messages.
pub fn mesh_to_bytes(
    mesh: &TriMesh,
    format: MeshFormat,
    options: &WriteOptions,
    name: impl AsRef<Path>,
) -> Result<Vec<u8>, IoError> {
    match format {
        MeshFormat::Vtk => vtk::write(mesh, options.encoding),
        MeshFormat::Vtp => vtp::write(mesh, options),
        MeshFormat::Stl => stl::write(mesh, options.encoding),
        MeshFormat::Ply => ply::write(mesh, options.encoding),
        MeshFormat::Obj => obj::write(mesh),
    }
    .map_err(|kind| IoError::new(name, kind))
}

// ---------------------------------------------------------------------------------------------
// Shared by the format readers and writers.

/// What a reader collected, before validation.
#[derive(Debug, Default)]
pub(crate) struct RawMesh {
    pub vertices: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    pub normals: Option<Vec<Vec3>>,
    pub scalars: Vec<(String, Vec<f64>)>,
    /// The file says `SPACE=LPS`.
    pub lps: bool,
    /// Line and vertex cells seen (ignored; refused when there is no surface).
    pub other_cells: u64,
    /// Polygon and strip cells seen.
    pub surface_cells: u64,
}

impl RawMesh {
    fn finish(mut self) -> Result<TriMesh, ErrorKind> {
        if self.surface_cells == 0 && self.other_cells > 0 {
            return Err(ErrorKind::Mesh(format!(
                "no surface: the file holds {} line/vertex cell(s) and no polygons \
                 (a centreline or point set, not a triangle mesh)",
                self.other_cells
            )));
        }
        if self.lps {
            let flip = |v: &mut Vec3| {
                v.x = -v.x;
                v.y = -v.y;
            };
            self.vertices.iter_mut().for_each(flip);
            if let Some(n) = self.normals.as_mut() {
                n.iter_mut().for_each(flip);
            }
        }
        let mut mesh = TriMesh::new(self.vertices, self.triangles)?;
        if let Some(normals) = self.normals {
            if let Some(i) = normals
                .iter()
                .position(|n| n.iter().any(|c| !c.is_finite()))
            {
                return Err(ErrorKind::Mesh(format!("normal {i} is not finite")));
            }
            mesh = mesh.with_normals(normals)?;
        }
        for (k, (name, values)) in self.scalars.into_iter().enumerate() {
            // Checked here, not by `with_scalars`, whose error names the array: the name is
            // the file's text, so the error numbers the array instead.
            let (got, expected) = (values.len(), mesh.vertices().len());
            if got != expected {
                return Err(ErrorKind::Mesh(format!(
                    "point-data array {k} has {got} values but the mesh has {expected} vertices"
                )));
            }
            mesh = mesh.with_scalars(&name, values)?;
        }
        Ok(mesh)
    }

    /// Adds polygon `poly` as a triangle fan (polygons with fewer than 3 corners are skipped).
    pub fn push_polygon(&mut self, poly: &[i64]) -> Result<(), ErrorKind> {
        self.surface_cells += 1;
        if poly.len() < 3 {
            return Ok(());
        }
        let first = index(poly[0])?;
        for w in poly[1..].windows(2) {
            self.triangles.push([first, index(w[0])?, index(w[1])?]);
        }
        Ok(())
    }

    /// Adds a triangle strip, alternating orientation so that all triangles agree.
    pub fn push_strip(&mut self, strip: &[i64]) -> Result<(), ErrorKind> {
        self.surface_cells += 1;
        for (k, w) in strip.windows(3).enumerate() {
            let [a, b, c] = [index(w[0])?, index(w[1])?, index(w[2])?];
            self.triangles
                .push(if k % 2 == 0 { [a, b, c] } else { [b, a, c] });
        }
        Ok(())
    }
}

/// A vertex index from a file: non-negative and within `u32` (the range check against the vertex
/// count is done by [`TriMesh::new`]).
pub(crate) fn index(i: i64) -> Result<u32, ErrorKind> {
    u32::try_from(i).map_err(|_| ErrorKind::Mesh(format!("vertex index {i} is out of range")))
}

/// Whether a header or comment carries Slicer's `SPACE=LPS` tag.
pub(crate) fn says_lps(text: &[u8]) -> bool {
    text.windows(9)
        .any(|w| w.eq_ignore_ascii_case(b"SPACE=LPS"))
}

/// The tag writers put in headers and comments.
pub(crate) const SPACE_TAG: &str = "SPACE=RAS";

/// Numeric element types shared by the binary formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Num {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

macro_rules! get {
    ($t:ty, $b:expr, $big:expr) => {{
        let mut a = [0u8; std::mem::size_of::<$t>()];
        a.copy_from_slice(&$b[..std::mem::size_of::<$t>()]);
        if $big {
            <$t>::from_be_bytes(a)
        } else {
            <$t>::from_le_bytes(a)
        }
    }};
}

impl Num {
    pub fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::I64 | Self::U64 | Self::F64 => 8,
        }
    }

    pub fn is_float(self) -> bool {
        matches!(self, Self::F32 | Self::F64)
    }

    /// One value from the start of `b` (which holds at least `size()` bytes).
    pub fn get_f64(self, b: &[u8], big: bool) -> f64 {
        match self {
            Self::I8 => f64::from(b[0] as i8),
            Self::U8 => f64::from(b[0]),
            Self::I16 => f64::from(get!(i16, b, big)),
            Self::U16 => f64::from(get!(u16, b, big)),
            Self::I32 => f64::from(get!(i32, b, big)),
            Self::U32 => f64::from(get!(u32, b, big)),
            Self::I64 => get!(i64, b, big) as f64,
            Self::U64 => get!(u64, b, big) as f64,
            Self::F32 => f64::from(get!(f32, b, big)),
            Self::F64 => get!(f64, b, big),
        }
    }

    /// One integer from the start of `b`; floats and values beyond `i64` are refused.
    pub fn get_i64(self, b: &[u8], big: bool) -> Result<i64, ErrorKind> {
        Ok(match self {
            Self::I8 => i64::from(b[0] as i8),
            Self::U8 => i64::from(b[0]),
            Self::I16 => i64::from(get!(i16, b, big)),
            Self::U16 => i64::from(get!(u16, b, big)),
            Self::I32 => i64::from(get!(i32, b, big)),
            Self::U32 => i64::from(get!(u32, b, big)),
            Self::I64 => get!(i64, b, big),
            Self::U64 => {
                let v = get!(u64, b, big);
                i64::try_from(v)
                    .map_err(|_| ErrorKind::Mesh(format!("index or count {v} is too large")))?
            }
            Self::F32 | Self::F64 => {
                return Err(ErrorKind::Unsupported {
                    what: "floating-point type for indices or counts",
                    value: format!("{self:?}"),
                });
            }
        })
    }

    /// Decodes consecutive values; `bytes.len()` must be a multiple of the size (checked).
    pub fn decode_f64(self, bytes: &[u8], big: bool) -> Result<Vec<f64>, ErrorKind> {
        self.check_len(bytes)?;
        Ok(bytes
            .chunks_exact(self.size())
            .map(|c| self.get_f64(c, big))
            .collect())
    }

    /// Decodes consecutive integers.
    pub fn decode_i64(self, bytes: &[u8], big: bool) -> Result<Vec<i64>, ErrorKind> {
        self.check_len(bytes)?;
        bytes
            .chunks_exact(self.size())
            .map(|c| self.get_i64(c, big))
            .collect()
    }

    fn check_len(self, bytes: &[u8]) -> Result<(), ErrorKind> {
        if bytes.len().is_multiple_of(self.size()) {
            Ok(())
        } else {
            Err(ErrorKind::Mesh(format!(
                "{} bytes is not a whole number of {self:?} values",
                bytes.len()
            )))
        }
    }
}

/// A byte cursor for the text formats and the mixed text/binary VTK legacy format.
#[derive(Debug)]
pub(crate) struct Cursor<'a> {
    pub data: &'a [u8],
    pub pos: usize,
}

impl<'a> Cursor<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        Self { data, pos: 0 }
    }

    pub fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }

    /// The next whitespace-separated token.
    pub fn token(&mut self) -> Option<&'a [u8]> {
        let rest = &self.data[self.pos..];
        let start = rest.iter().position(|b| !b.is_ascii_whitespace())?;
        let len = rest[start..]
            .iter()
            .position(u8::is_ascii_whitespace)
            .unwrap_or(rest.len() - start);
        self.pos += start + len;
        Some(&rest[start..start + len])
    }

    /// The rest of the current line (without `\r\n`), moving past its end.
    pub fn line(&mut self) -> Option<&'a [u8]> {
        if self.pos >= self.data.len() {
            return None;
        }
        let rest = &self.data[self.pos..];
        let len = rest.iter().position(|&b| b == b'\n');
        self.pos += len.map_or(rest.len(), |n| n + 1);
        let line = &rest[..len.unwrap_or(rest.len())];
        Some(line.strip_suffix(b"\r").unwrap_or(line))
    }

    /// The next line that is not blank.
    pub fn nonblank_line(&mut self) -> Option<&'a [u8]> {
        loop {
            let line = self.line()?;
            if line.iter().any(|b| !b.is_ascii_whitespace()) {
                return Some(line);
            }
        }
    }

    /// The next `n` bytes, or a size error saying how many were needed.
    pub fn take(&mut self, n: usize) -> Result<&'a [u8], ErrorKind> {
        if n > self.remaining() {
            return Err(ErrorKind::DataSize {
                expected: n as u64,
                got: self.remaining() as u64,
            });
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    /// `count` text numbers, parsed with `parse`; `what` names them in errors (this crate's
    /// words: never a name from the file, and the token is not repeated). The capacity
    /// reserved up front is capped by the bytes left (every number takes at least two).
    pub fn numbers<T>(
        &mut self,
        count: usize,
        what: &str,
        parse: impl Fn(&str) -> Option<T>,
    ) -> Result<Vec<T>, ErrorKind> {
        let mut out = Vec::with_capacity(count.min(self.remaining() / 2 + 1));
        for got in 0..count {
            let tok = self.token().ok_or_else(|| {
                ErrorKind::Mesh(format!(
                    "{what}: the file ends after {got} of {count} values"
                ))
            })?;
            let value = std::str::from_utf8(tok).ok().and_then(&parse);
            out.push(value.ok_or_else(|| {
                ErrorKind::Mesh(format!(
                    "{what}: value {} of {count} is not a number",
                    got + 1
                ))
            })?);
        }
        Ok(out)
    }

    pub fn floats(&mut self, count: usize, what: &str) -> Result<Vec<f64>, ErrorKind> {
        self.numbers(count, what, |s| s.parse().ok())
    }

    pub fn ints(&mut self, count: usize, what: &str) -> Result<Vec<i64>, ErrorKind> {
        self.numbers(count, what, |s| s.parse().ok())
    }
}

/// Parses a count or size from a header word (`what` names it; the word is not repeated).
pub(crate) fn parse_count(word: Option<&str>, what: &str) -> Result<usize, ErrorKind> {
    match word {
        None => Err(ErrorKind::Header(format!("{what}: a count is missing"))),
        Some(w) => w
            .parse::<usize>()
            .map_err(|_| ErrorKind::Header(format!("{what}: expected a count"))),
    }
}

/// `n * m`, refusing overflow.
pub(crate) fn mul(n: usize, m: usize) -> Result<usize, ErrorKind> {
    n.checked_mul(m)
        .ok_or_else(|| ErrorKind::Header(format!("count {n} × {m} overflows")))
}

/// Shortest text that parses back to exactly `v`.
pub(crate) fn fmt_f64(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 || (1e-5..1e16).contains(&a) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// `v` as `f32`, refusing values beyond its range.
pub(crate) fn to_f32(v: f64) -> Result<f32, ErrorKind> {
    let f = v as f32;
    if f.is_finite() {
        Ok(f)
    } else {
        Err(ErrorKind::Unsupported {
            what: "value for a 32-bit float format",
            value: v.to_string(),
        })
    }
}

/// Array names with whitespace, `%` or non-printing bytes escaped as `%XX` (VTK legacy style),
/// so that they stay one word in the text headers.
pub(crate) fn encode_name(name: &str) -> String {
    let mut out = String::with_capacity(name.len());
    for b in name.bytes() {
        if b.is_ascii_graphic() && b != b'%' {
            out.push(char::from(b));
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    if out.is_empty() {
        out.push_str("%00");
    }
    out
}

/// Inverse of [`encode_name`] (invalid escapes are kept as they are).
pub(crate) fn decode_name(word: &str) -> String {
    let b = word.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = b
            .get(i + 1..i + 3)
            .and_then(|h| std::str::from_utf8(h).ok())
            .and_then(|h| u8::from_str_radix(h, 16).ok());
        match (b[i], hex) {
            (b'%', Some(0)) => i += 3,
            (b'%', Some(v)) => {
                out.push(v);
                i += 3;
            }
            (c, _) => {
                out.push(c);
                i += 1;
            }
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}
