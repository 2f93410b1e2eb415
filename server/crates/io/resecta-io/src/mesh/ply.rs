//! PLY (Stanford polygon files): ASCII, binary little- and big-endian.
//!
//! From `vertex` elements: `x y z`, optional `nx ny nz`, and every other `float`/`double`
//! property as a named scalar (integer properties such as colours are dropped). From `face`
//! elements: the `vertex_indices` (or `vertex_index`) list, with any integer count and index
//! types, fan-triangulated. Other elements and properties are parsed past. Writers store
//! `float` coordinates and normals, `double` scalars, `uchar`/`int` face lists, and a
//! `comment SPACE=RAS` line.

use std::io::Write;

use resecta_geom::{TriMesh, Vec3};

use super::{
    Cursor, Encoding, Num, RawMesh, SPACE_TAG, decode_name, encode_name, fmt_f64, mul, says_lps,
    to_f32,
};
use crate::error::ErrorKind;

fn ply_type(word: &str) -> Result<Num, ErrorKind> {
    Ok(match word {
        "char" | "int8" => Num::I8,
        "uchar" | "uint8" => Num::U8,
        "short" | "int16" => Num::I16,
        "ushort" | "uint16" => Num::U16,
        "int" | "int32" => Num::I32,
        "uint" | "uint32" => Num::U32,
        "float" | "float32" => Num::F32,
        "double" | "float64" => Num::F64,
        _ => {
            return Err(ErrorKind::UnknownValue {
                key: "PLY property type",
                known: "char, uchar, short, ushort, int, uint, float, double (and int8 … float64)",
            });
        }
    })
}

#[derive(Debug)]
struct Property {
    name: String,
    ty: Num,
    /// Count type, for list properties.
    list: Option<Num>,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Storage {
    Ascii,
    Binary { big: bool },
}

struct Body<'a> {
    c: Cursor<'a>,
    storage: Storage,
}

impl Body<'_> {
    fn scalar(&mut self, ty: Num) -> Result<f64, ErrorKind> {
        match self.storage {
            Storage::Binary { big } => Ok(ty.get_f64(self.c.take(ty.size())?, big)),
            // Text values of `float` properties are rounded as the binary form would be.
            Storage::Ascii if ty == Num::F32 => {
                Ok(f64::from(self.c.floats(1, "PLY property")?[0] as f32))
            }
            Storage::Ascii => Ok(self.c.floats(1, "PLY property")?[0]),
        }
    }

    fn int(&mut self, ty: Num) -> Result<i64, ErrorKind> {
        match self.storage {
            Storage::Binary { big } => ty.get_i64(self.c.take(ty.size())?, big),
            Storage::Ascii => Ok(self.c.ints(1, "PLY list")?[0]),
        }
    }

    /// A list property: its count, checked against the bytes left, then the items.
    fn list(&mut self, count_ty: Num, ty: Num, keep: bool) -> Result<Vec<i64>, ErrorKind> {
        let n = self.int(count_ty)?;
        let n =
            usize::try_from(n).map_err(|_| ErrorKind::Mesh(format!("negative list length {n}")))?;
        match self.storage {
            Storage::Binary { big } => {
                let bytes = self.c.take(mul(n, ty.size())?)?;
                if keep {
                    ty.decode_i64(bytes, big)
                } else {
                    Ok(Vec::new())
                }
            }
            Storage::Ascii => {
                if keep {
                    self.c.ints(n, "PLY list")
                } else {
                    self.c.floats(n, "PLY list").map(|_| Vec::new())
                }
            }
        }
    }
}

fn header(c: &mut Cursor<'_>, raw: &mut RawMesh) -> Result<(Storage, Vec<Element>), ErrorKind> {
    if c.line().map(<[u8]>::trim_ascii) != Some(b"ply") {
        return Err(ErrorKind::BadMagic("PLY"));
    }
    let mut storage = None;
    let mut elements: Vec<Element> = Vec::new();
    // Line 1 is the magic.
    for number in 2.. {
        let line = c
            .line()
            .ok_or_else(|| ErrorKind::Header("file ends before end_header".into()))?;
        let text = String::from_utf8_lossy(line);
        let words: Vec<&str> = text.split_whitespace().collect();
        match words.as_slice() {
            [] => {}
            ["end_header", ..] => break,
            ["comment" | "obj_info", ..] => raw.lps |= says_lps(line),
            ["format", f, _version] => {
                storage = Some(match *f {
                    "ascii" => Storage::Ascii,
                    "binary_little_endian" => Storage::Binary { big: false },
                    "binary_big_endian" => Storage::Binary { big: true },
                    _ => {
                        return Err(ErrorKind::UnknownValue {
                            key: "PLY format",
                            known: "ascii, binary_little_endian, binary_big_endian",
                        });
                    }
                });
            }
            ["element", name, count] => elements.push(Element {
                name: (*name).to_owned(),
                count: super::parse_count(Some(count), "element")?,
                props: Vec::new(),
            }),
            ["property", "list", count_ty, ty, name] => {
                let e = elements
                    .last_mut()
                    .ok_or_else(|| ErrorKind::Header("property before element".into()))?;
                let count_ty = ply_type(count_ty)?;
                if count_ty.is_float() {
                    return Err(ErrorKind::Header(format!(
                        "line {number}: a list count type must be an integer type"
                    )));
                }
                e.props.push(Property {
                    name: (*name).to_owned(),
                    ty: ply_type(ty)?,
                    list: Some(count_ty),
                });
            }
            ["property", ty, name] => {
                let e = elements
                    .last_mut()
                    .ok_or_else(|| ErrorKind::Header("property before element".into()))?;
                e.props.push(Property {
                    name: (*name).to_owned(),
                    ty: ply_type(ty)?,
                    list: None,
                });
            }
            _ => {
                return Err(ErrorKind::Header(format!(
                    "line {number} is no PLY header line"
                )));
            }
        }
    }
    let storage = storage.ok_or_else(|| ErrorKind::Header("no format line".into()))?;
    Ok((storage, elements))
}

pub(crate) fn read(bytes: &[u8]) -> Result<RawMesh, ErrorKind> {
    read_with(bytes, None)
}

/// The first `vertex` element of a PLY file (positions, normals if it has `nx ny nz`) for a
/// point cloud: elements before it are parsed past, those after it (faces) are not read, and a
/// vertex count above `max_vertices` is refused from the header, before anything is allocated.
pub(crate) fn read_points(bytes: &[u8], max_vertices: usize) -> Result<RawMesh, ErrorKind> {
    read_with(bytes, Some(max_vertices))
}

/// Reads a mesh, or with `points_only` (the most vertices allowed) the vertices alone.
fn read_with(bytes: &[u8], points_only: Option<usize>) -> Result<RawMesh, ErrorKind> {
    let mut raw = RawMesh::default();
    let mut c = Cursor::new(bytes);
    let (storage, elements) = header(&mut c, &mut raw)?;
    if let Some(max) = points_only
        && let Some(e) = elements.iter().find(|e| e.name == "vertex")
        && e.count > max
    {
        return Err(ErrorKind::Header(format!(
            "element vertex: {} vertices, more than the {max} a point cloud may have",
            e.count
        )));
    }
    let faces = points_only.is_none();
    let mut body = Body { c, storage };
    let mut have_vertices = false;
    for e in &elements {
        if have_vertices && !faces {
            break;
        }
        let checked = (faces && e.name == "face") || (e.name == "vertex" && !have_vertices);
        if e.props.is_empty() && !checked {
            continue; // nothing to read, however large the count
        }
        // Every element takes at least one byte per property (binary) or two (text).
        let min = match storage {
            Storage::Binary { .. } => e
                .props
                .iter()
                .map(|p| p.list.unwrap_or(p.ty).size())
                .sum::<usize>(),
            Storage::Ascii => 2 * e.props.len(),
        };
        if mul(e.count, min)? > body.c.remaining() {
            return Err(ErrorKind::DataSize {
                expected: (e.count as u64).saturating_mul(min as u64),
                got: body.c.remaining() as u64,
            });
        }
        match e.name.as_str() {
            "vertex" if !have_vertices => {
                have_vertices = true;
                read_vertices(&mut body, e, &mut raw)?;
            }
            "face" if faces => {
                let key = e
                    .props
                    .iter()
                    .position(|p| {
                        p.list.is_some()
                            && matches!(p.name.as_str(), "vertex_indices" | "vertex_index")
                    })
                    .ok_or_else(|| {
                        ErrorKind::Header("face element without vertex_indices".into())
                    })?;
                for _ in 0..e.count {
                    for (k, p) in e.props.iter().enumerate() {
                        match p.list {
                            Some(ct) => {
                                let ids = body.list(ct, p.ty, k == key)?;
                                if k == key {
                                    raw.push_polygon(&ids)?;
                                }
                            }
                            None => {
                                body.scalar(p.ty)?;
                            }
                        }
                    }
                }
            }
            _ => {
                for _ in 0..e.count {
                    for p in &e.props {
                        match p.list {
                            Some(ct) => drop(body.list(ct, p.ty, false)?),
                            None => drop(body.scalar(p.ty)?),
                        }
                    }
                }
            }
        }
    }
    if !have_vertices {
        return Err(ErrorKind::Header("no vertex element".into()));
    }
    Ok(raw)
}

fn read_vertices(body: &mut Body<'_>, e: &Element, raw: &mut RawMesh) -> Result<(), ErrorKind> {
    let find = |n: &str| e.props.iter().position(|p| p.name == n && p.list.is_none());
    let [Some(x), Some(y), Some(z)] = [find("x"), find("y"), find("z")] else {
        return Err(ErrorKind::Header("vertex element needs x, y and z".into()));
    };
    let normal = match [find("nx"), find("ny"), find("nz")] {
        [Some(a), Some(b), Some(c)] => Some([a, b, c]),
        _ => None,
    };
    let taken = |k: usize| [x, y, z].contains(&k) || normal.is_some_and(|n| n.contains(&k));
    let scalar_props: Vec<usize> = (0..e.props.len())
        .filter(|&k| !taken(k) && e.props[k].list.is_none() && e.props[k].ty.is_float())
        .collect();
    raw.vertices.reserve(e.count);
    let mut normals = Vec::with_capacity(if normal.is_some() { e.count } else { 0 });
    let mut scalars = vec![Vec::with_capacity(e.count); scalar_props.len()];
    let mut row = vec![0.0; e.props.len()];
    for _ in 0..e.count {
        for (k, p) in e.props.iter().enumerate() {
            match p.list {
                Some(ct) => drop(body.list(ct, p.ty, false)?),
                None => row[k] = body.scalar(p.ty)?,
            }
        }
        raw.vertices.push(Vec3::new(row[x], row[y], row[z]));
        if let Some([a, b, c]) = normal {
            normals.push(Vec3::new(row[a], row[b], row[c]));
        }
        for (s, &k) in scalars.iter_mut().zip(&scalar_props) {
            s.push(row[k]);
        }
    }
    if normal.is_some() {
        raw.normals = Some(normals);
    }
    for (values, &k) in scalars.into_iter().zip(&scalar_props) {
        raw.scalars.push((decode_name(&e.props[k].name), values));
    }
    Ok(())
}

const RESERVED: [&str; 6] = ["x", "y", "z", "nx", "ny", "nz"];

/// Encodes a mesh as PLY: binary little-endian by default, ASCII or big-endian on request.
pub(crate) fn write(mesh: &TriMesh, encoding: Encoding) -> Result<Vec<u8>, ErrorKind> {
    let n = mesh.vertices().len();
    let t = mesh.triangles().len();
    let (format, big) = match encoding {
        Encoding::Ascii => ("ascii", false),
        Encoding::Binary => ("binary_little_endian", false),
        Encoding::BinaryBigEndian => ("binary_big_endian", true),
    };
    let names: Vec<String> = mesh.scalars().keys().map(|k| encode_name(k)).collect();
    if let Some(clash) = names.iter().find(|s| RESERVED.contains(&s.as_str())) {
        return Err(ErrorKind::Unsupported {
            what: "PLY scalar name (clashes with a coordinate or normal)",
            value: clash.clone(),
        });
    }
    let mut out = Vec::with_capacity(256 + n * (12 + 8 * names.len()) + t * 13);
    write!(
        out,
        "ply\nformat {format} 1.0\ncomment {SPACE_TAG}\ncomment written by resecta\n\
         element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
    )?;
    let normals = mesh.normals();
    if normals.is_some() {
        write!(
            out,
            "property float nx\nproperty float ny\nproperty float nz\n"
        )?;
    }
    for name in &names {
        writeln!(out, "property double {name}")?;
    }
    write!(
        out,
        "element face {t}\nproperty list uchar int vertex_indices\nend_header\n"
    )?;
    let put_f32 = |out: &mut Vec<u8>, v: f64| -> Result<(), ErrorKind> {
        let f = to_f32(v)?;
        match encoding {
            Encoding::Ascii => write!(out, "{f} ")?,
            Encoding::Binary | Encoding::BinaryBigEndian if big => {
                out.extend_from_slice(&f.to_be_bytes());
            }
            Encoding::Binary | Encoding::BinaryBigEndian => out.extend_from_slice(&f.to_le_bytes()),
        }
        Ok(())
    };
    let scalars: Vec<&Vec<f64>> = mesh.scalars().values().collect();
    for (i, p) in mesh.vertices().iter().enumerate() {
        for &c in p.iter() {
            put_f32(&mut out, c)?;
        }
        if let Some(nm) = normals {
            for &c in nm[i].iter() {
                put_f32(&mut out, c)?;
            }
        }
        for s in &scalars {
            match encoding {
                Encoding::Ascii => write!(out, "{} ", fmt_f64(s[i]))?,
                Encoding::Binary | Encoding::BinaryBigEndian if big => {
                    out.extend_from_slice(&s[i].to_be_bytes());
                }
                Encoding::Binary | Encoding::BinaryBigEndian => {
                    out.extend_from_slice(&s[i].to_le_bytes());
                }
            }
        }
        if encoding == Encoding::Ascii {
            out.pop();
            out.push(b'\n');
        }
    }
    for tri in mesh.triangles() {
        let ids = tri.map(|i| {
            i32::try_from(i).map_err(|_| ErrorKind::Unsupported {
                what: "vertex index for PLY int",
                value: i.to_string(),
            })
        });
        if encoding == Encoding::Ascii {
            writeln!(out, "3 {} {} {}", tri[0], tri[1], tri[2])?;
            continue;
        }
        out.push(3);
        for id in ids {
            let id = id?;
            out.extend_from_slice(&if big {
                id.to_be_bytes()
            } else {
                id.to_le_bytes()
            });
        }
    }
    Ok(out)
}
