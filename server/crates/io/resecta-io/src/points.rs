//! Point clouds: 3-D points in RAS millimetres, with or without one normal each (the few hundred
//! points a catheter collects in electro-anatomical mapping, say).
//!
//! # Formats
//!
//! Chosen by extension ([`PointFormat::from_path`]):
//!
//! - **CSV** (`.csv`, `.txt`, `.xyz`), read and written: one point per line, `x,y,z` or
//!   `x,y,z,nx,ny,nz`, the fields separated by commas, semicolons, tabs or spaces (commas and
//!   semicolons may have spaces around them; a line mixing commas and semicolons — decimal commas?
//!   — is refused, as is an empty field). Every row has the same number of columns, 3 or 6. The
//!   first line that is not blank or a comment may be a header (a line none of whose fields is a
//!   number, `x,y,z,nx,ny,nz` say); its text is skipped. `#` starts a comment (a whole line or the
//!   end of one). The writer puts a `# SPACE=RAS` comment first, then the header
//!   `x,y,z[,nx,ny,nz]`, then the values in shortest round-trip form (exact `f64`).
//! - **PLY** (`.ply`), read and written: the first `vertex` element's `x`, `y`, `z` and, when all
//!   three are there, `nx`, `ny`, `nz` properties, of any numeric type, in `ascii`,
//!   `binary_little_endian` or `binary_big_endian` storage, through the mesh reader's parser;
//!   other elements (faces) are allowed, and those after the vertices are not read. The writer
//!   stores `binary_little_endian` `double` properties (exact `f64`, unlike the mesh writer's
//!   `float`) and a `comment SPACE=RAS`.
//! - **VTP** (`.vtp`), read and written: the `Points` of the PolyData (with `Verts`, `Polys`,
//!   any cells or none) and its normals (the point-data array the `Normals` attribute names, else
//!   a 3-component array called `Normals`), through the mesh reader. The writer stores `Float64`
//!   points and `Normals`, one `Verts` cell per point, and the `SPACE` field array, as the mesh
//!   writer does.
//! - **VTK legacy, STL, OBJ** (`.vtk`, `.stl`, `.obj`), read only: the vertices of the mesh
//!   readers (every vertex of the file, used by a cell or not; STL's corners merged as a mesh's
//!   are) and their vertex normals when the reader finds them (VTK `POINT_DATA NORMALS`; OBJ
//!   normals only when the faces give every vertex one; never STL's facet normals).
//!
//! # Coordinates
//!
//! As for meshes (see [`crate::mesh`]): RAS, unless the file carries Slicer's `SPACE=LPS` tag
//! (for CSV, in a comment or the header line), in which case x and y of positions and normals are
//! negated. Writers store RAS and tag it.
//!
//! # Bad input
//!
//! Every failure is an [`IoError`] naming the file; the crate's [`ErrorKind`] has no variant of
//! its own for point clouds, so the cloud's content is refused with [`ErrorKind::Mesh`]: no
//! point, more than [`MAX_POINTS`] (a CSV stops at the first row beyond), a non-finite
//! coordinate or normal, a zero normal, or not one normal per point, each naming the point index
//! or line. A CSV line with a bad number, an empty field, mixed separators or a column count
//! other than the first row's is refused with its line number (and column). The structure of
//! the other formats is checked by the mesh readers (a PLY header's vertex count above
//! [`MAX_POINTS`] is an [`ErrorKind::Header`] error, before anything is allocated; data shorter
//! than the header says is [`ErrorKind::DataSize`]). Messages never repeat the file's text (see
//! [`crate::error`]).

use std::fmt::Write as _;
use std::path::Path;

use resecta_geom::Vec3;

use crate::error::{ErrorKind, IoError};
use crate::mesh::{
    MeshFormat, RawMesh, SPACE_TAG, WriteOptions, fmt_f64, obj, ply, says_lps, stl, vtk, vtp,
};

/// The most points a cloud may have (readers refuse more, before allocating for them).
pub const MAX_POINTS: usize = 10_000_000;

/// Points in RAS millimetres, optionally with one normal each. Normals are not necessarily of
/// unit length: readers return them as stored (finite and non-zero, checked), and writers store
/// them as given.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCloud {
    pub positions: Vec<Vec3>,
    /// One per position, when present.
    pub normals: Option<Vec<Vec3>>,
}

impl PointCloud {
    /// Points without normals.
    pub fn new(positions: Vec<Vec3>) -> Self {
        Self {
            positions,
            normals: None,
        }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// Whether there are no points (readers never return such a cloud).
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// What readers accept and writers require: 1 to [`MAX_POINTS`] finite points, and as many
    /// finite, non-zero normals if there are normals.
    fn check(&self) -> Result<(), ErrorKind> {
        let n = self.positions.len();
        if n == 0 {
            return Err(ErrorKind::Mesh("the point cloud has no points".into()));
        }
        if n > MAX_POINTS {
            return Err(too_many(n));
        }
        if let Some(i) = self
            .positions
            .iter()
            .position(|p| p.iter().any(|c| !c.is_finite()))
        {
            return Err(ErrorKind::Mesh(format!("point {i} is not finite")));
        }
        if let Some(normals) = &self.normals {
            if normals.len() != n {
                return Err(ErrorKind::Mesh(format!(
                    "{} normals for {n} points",
                    normals.len()
                )));
            }
            for (i, v) in normals.iter().enumerate() {
                if v.iter().any(|c| !c.is_finite()) {
                    return Err(ErrorKind::Mesh(format!("normal {i} is not finite")));
                }
                if v.iter().all(|&c| c == 0.0) {
                    return Err(ErrorKind::Mesh(format!("normal {i} is zero")));
                }
            }
        }
        Ok(())
    }
}

fn too_many(n: usize) -> ErrorKind {
    ErrorKind::Mesh(format!(
        "{n} points, more than the {MAX_POINTS} a point cloud may have"
    ))
}

/// A point-cloud file format, chosen by file extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PointFormat {
    /// `.csv`, `.txt`, `.xyz`: delimited text (read and written).
    Csv,
    /// `.ply` (read and written).
    Ply,
    /// `.vtp`, VTK XML PolyData (read and written).
    Vtp,
    /// `.vtk`, VTK legacy PolyData (read only: the mesh's vertices).
    Vtk,
    /// `.stl` (read only: the mesh's vertices).
    Stl,
    /// `.obj`, Wavefront (read only: the mesh's vertices).
    Obj,
}

const EXTENSIONS: &str = ".csv, .txt, .xyz, .ply, .vtp, .vtk, .stl, .obj";
const WRITTEN: &str = ".csv, .txt, .xyz, .ply, .vtp";

impl PointFormat {
    pub const ALL: [Self; 6] = [
        Self::Csv,
        Self::Ply,
        Self::Vtp,
        Self::Vtk,
        Self::Stl,
        Self::Obj,
    ];

    /// The format for a file name's extension (case-insensitive): `.csv`, `.txt`, `.xyz`, or
    /// any mesh format's ([`MeshFormat::from_path`]).
    pub fn from_path(path: impl AsRef<Path>) -> Result<Self, IoError> {
        let path = path.as_ref();
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        if matches!(ext.as_str(), "csv" | "txt" | "xyz") {
            return Ok(Self::Csv);
        }
        MeshFormat::from_path(path)
            .map(Self::from)
            .map_err(|_| IoError::new(path, ErrorKind::UnknownFormat(ext, EXTENSIONS)))
    }

    /// The usual file extension, without the dot.
    pub fn extension(self) -> &'static str {
        match self {
            Self::Csv => "csv",
            Self::Ply => MeshFormat::Ply.extension(),
            Self::Vtp => MeshFormat::Vtp.extension(),
            Self::Vtk => MeshFormat::Vtk.extension(),
            Self::Stl => MeshFormat::Stl.extension(),
            Self::Obj => MeshFormat::Obj.extension(),
        }
    }

    /// Whether [`write_points`] and [`points_to_bytes`] can write it.
    pub fn is_writable(self) -> bool {
        match self {
            Self::Csv | Self::Ply | Self::Vtp => true,
            Self::Vtk | Self::Stl | Self::Obj => false,
        }
    }
}

impl From<MeshFormat> for PointFormat {
    fn from(f: MeshFormat) -> Self {
        match f {
            MeshFormat::Ply => Self::Ply,
            MeshFormat::Vtp => Self::Vtp,
            MeshFormat::Vtk => Self::Vtk,
            MeshFormat::Stl => Self::Stl,
            MeshFormat::Obj => Self::Obj,
        }
    }
}

/// Reads a point cloud, choosing the format by extension.
pub fn read_points(path: impl AsRef<Path>) -> Result<PointCloud, IoError> {
    let path = path.as_ref();
    let format = PointFormat::from_path(path)?;
    let bytes = std::fs::read(path).map_err(|e| IoError::new(path, e))?;
    read_points_bytes(&bytes, format, path)
}

/// Reads a point cloud from memory; `name` is only used in error messages.
pub fn read_points_bytes(
    bytes: &[u8],
    format: PointFormat,
    name: impl AsRef<Path>,
) -> Result<PointCloud, IoError> {
    let raw = match format {
        PointFormat::Csv => csv(bytes),
        PointFormat::Ply => ply::read_points(bytes, MAX_POINTS),
        PointFormat::Vtp => vtp::read(bytes),
        PointFormat::Vtk => vtk::read(bytes),
        PointFormat::Stl => stl::read(bytes),
        PointFormat::Obj => obj::read(bytes),
    };
    raw.and_then(finish)
        .map_err(|kind| IoError::new(name, kind))
}

/// Writes a point cloud (`.csv`/`.txt`/`.xyz`, `.ply` or `.vtp`), choosing the format by
/// extension. Coordinates are written as RAS, unchanged.
pub fn write_points(path: impl AsRef<Path>, cloud: &PointCloud) -> Result<(), IoError> {
    let path = path.as_ref();
    let format = PointFormat::from_path(path)?;
    let bytes = points_to_bytes(cloud, format, path)?;
    std::fs::write(path, bytes).map_err(|e| IoError::new(path, e))
}

/// Encodes a point cloud in memory (CSV, PLY or VTP); `name` is only used in error messages.
/// The cloud must have 1 to [`MAX_POINTS`] finite points and, if it has normals, one finite,
/// non-zero normal per point.
pub fn points_to_bytes(
    cloud: &PointCloud,
    format: PointFormat,
    name: impl AsRef<Path>,
) -> Result<Vec<u8>, IoError> {
    let encoded = cloud.check().and_then(|()| match format {
        PointFormat::Csv => Ok(write_csv(cloud)),
        PointFormat::Ply => Ok(write_ply(cloud)),
        PointFormat::Vtp => vtp::write_verts(
            &cloud.positions,
            cloud.normals.as_deref(),
            &WriteOptions::default(),
        ),
        PointFormat::Vtk | PointFormat::Stl | PointFormat::Obj => {
            Err(ErrorKind::UnknownFormat(format.extension().into(), WRITTEN))
        }
    });
    encoded.map_err(|kind| IoError::new(name, kind))
}

/// The cloud of a reader's vertices and normals, checked, in RAS.
fn finish(raw: RawMesh) -> Result<PointCloud, ErrorKind> {
    if raw.vertices.len() > MAX_POINTS {
        return Err(too_many(raw.vertices.len()));
    }
    let mut cloud = PointCloud {
        positions: raw.vertices,
        normals: raw.normals,
    };
    cloud.check()?;
    if raw.lps {
        let flip = |v: &mut Vec3| {
            v.x = -v.x;
            v.y = -v.y;
        };
        cloud.positions.iter_mut().for_each(flip);
        if let Some(n) = cloud.normals.as_mut() {
            n.iter_mut().for_each(flip);
        }
    }
    Ok(cloud)
}

// ---------------------------------------------------------------------------------------------
// CSV

/// The fields of a line (comment removed, trimmed, not blank): split at commas or semicolons
/// (spaces around them dropped) when it has any, else at runs of spaces and tabs. `None` when
/// it has both commas and semicolons.
fn fields(line: &[u8]) -> Option<Vec<&[u8]>> {
    let comma = line.contains(&b',');
    let semicolon = line.contains(&b';');
    Some(match (comma, semicolon) {
        (true, true) => return None,
        (true, false) | (false, true) => {
            let sep = if comma { b',' } else { b';' };
            line.split(|&b| b == sep).map(<[u8]>::trim_ascii).collect()
        }
        (false, false) => line
            .split(|&b| b == b' ' || b == b'\t')
            .filter(|f| !f.is_empty())
            .collect(),
    })
}

fn number(field: &[u8]) -> Option<f64> {
    std::str::from_utf8(field).ok()?.parse().ok()
}

/// Reads delimited text (see the module documentation).
fn csv(bytes: &[u8]) -> Result<RawMesh, ErrorKind> {
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    let mut raw = RawMesh::default();
    let mut normals: Vec<Vec3> = Vec::new();
    // The first row's column count and line number.
    let mut columns: Option<(usize, usize)> = None;
    let mut header_allowed = true;
    for (k, line) in bytes.split(|&b| b == b'\n').enumerate() {
        let number_of_line = k + 1;
        let (data, comment) = match line.iter().position(|&b| b == b'#') {
            Some(at) => (&line[..at], &line[at..]),
            None => (line, &[][..]),
        };
        raw.lps |= says_lps(comment);
        let data = data.trim_ascii();
        if data.is_empty() {
            continue;
        }
        let at = |column: usize| format!("line {number_of_line}, column {column}");
        let Some(words) = fields(data) else {
            // A header may be any text; a data line may not mix separators.
            if std::mem::take(&mut header_allowed) {
                raw.lps |= says_lps(data);
                continue;
            }
            return Err(ErrorKind::Mesh(format!(
                "line {number_of_line} mixes ',' and ';' separators (decimal commas?)"
            )));
        };
        if std::mem::take(&mut header_allowed) && words.iter().all(|w| number(w).is_none()) {
            raw.lps |= says_lps(data);
            continue;
        }
        let n = words.len();
        match columns {
            None if n == 3 || n == 6 => columns = Some((n, number_of_line)),
            None => {
                return Err(ErrorKind::Mesh(format!(
                    "line {number_of_line} has {n} columns, expected 3 (x,y,z) or 6 \
                     (x,y,z,nx,ny,nz)"
                )));
            }
            Some((c, first)) if c != n => {
                return Err(ErrorKind::Mesh(format!(
                    "line {number_of_line} has {n} columns, but line {first} has {c}"
                )));
            }
            Some(_) => {}
        }
        if raw.vertices.len() == MAX_POINTS {
            return Err(ErrorKind::Mesh(format!(
                "line {number_of_line}: more than the {MAX_POINTS} points a point cloud may have"
            )));
        }
        let mut v = [0.0; 6];
        for (j, (w, slot)) in words.iter().zip(&mut v).enumerate() {
            if w.is_empty() {
                return Err(ErrorKind::Mesh(format!("{}: empty field", at(j + 1))));
            }
            let x =
                number(w).ok_or_else(|| ErrorKind::Mesh(format!("{}: not a number", at(j + 1))))?;
            if !x.is_finite() {
                return Err(ErrorKind::Mesh(format!(
                    "{}: not a finite number",
                    at(j + 1)
                )));
            }
            *slot = x;
        }
        raw.vertices.push(Vec3::new(v[0], v[1], v[2]));
        if n == 6 {
            if v[3..].iter().all(|&c| c == 0.0) {
                return Err(ErrorKind::Mesh(format!(
                    "line {number_of_line}: normal {} is zero",
                    raw.vertices.len() - 1
                )));
            }
            normals.push(Vec3::new(v[3], v[4], v[5]));
        }
    }
    if matches!(columns, Some((6, _))) {
        raw.normals = Some(normals);
    }
    Ok(raw)
}

fn write_csv(cloud: &PointCloud) -> Vec<u8> {
    let mut out = String::with_capacity(64 + cloud.len() * 48);
    let _ = writeln!(out, "# {SPACE_TAG}");
    let normals = cloud.normals.as_deref();
    out.push_str(if normals.is_some() {
        "x,y,z,nx,ny,nz\n"
    } else {
        "x,y,z\n"
    });
    for (i, p) in cloud.positions.iter().enumerate() {
        let _ = write!(out, "{},{},{}", fmt_f64(p.x), fmt_f64(p.y), fmt_f64(p.z));
        if let Some(n) = normals.and_then(|n| n.get(i)) {
            let _ = write!(out, ",{},{},{}", fmt_f64(n.x), fmt_f64(n.y), fmt_f64(n.z));
        }
        out.push('\n');
    }
    out.into_bytes()
}

fn write_ply(cloud: &PointCloud) -> Vec<u8> {
    let normals = cloud.normals.as_deref();
    let per_point = if normals.is_some() { 48 } else { 24 };
    let mut out = String::with_capacity(256);
    let _ = write!(
        out,
        "ply\nformat binary_little_endian 1.0\ncomment {SPACE_TAG}\ncomment written by resecta\n\
         element vertex {}\nproperty double x\nproperty double y\nproperty double z\n",
        cloud.len()
    );
    if normals.is_some() {
        out.push_str("property double nx\nproperty double ny\nproperty double nz\n");
    }
    out.push_str("end_header\n");
    let mut out = out.into_bytes();
    out.reserve(cloud.len() * per_point);
    for (i, p) in cloud.positions.iter().enumerate() {
        let normal = normals.and_then(|n| n.get(i));
        for c in p.iter().chain(normal.into_iter().flat_map(|n| n.iter())) {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    out
}
