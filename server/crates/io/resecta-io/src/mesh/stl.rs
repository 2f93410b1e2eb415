//! STL, binary and ASCII.
//!
//! A file is binary when its size is exactly `84 + 50 × count`; otherwise it must start with
//! `solid` and is read as ASCII. Facet normals are ignored (recomputable), and bit-identical
//! corners are merged so the mesh has shared vertices and usable topology. Writers store `f32`
//! coordinates with unit facet normals; an 80-byte header (or the `solid` line) carries
//! `SPACE=RAS`.

use std::collections::HashMap;
use std::io::Write;

use resecta_geom::{TriMesh, Vec3};

use super::{Cursor, Encoding, Num, RawMesh, SPACE_TAG, says_lps, to_f32};
use crate::error::ErrorKind;

/// Builds a shared-vertex mesh from corner positions.
#[derive(Debug, Default)]
struct Merger {
    raw: RawMesh,
    seen: HashMap<[u64; 3], u32>,
}

impl Merger {
    fn vertex(&mut self, p: [f64; 3]) -> Result<i64, ErrorKind> {
        // +0.0 and -0.0 are the same point.
        let key = p.map(|c| (c + 0.0).to_bits());
        if let Some(&i) = self.seen.get(&key) {
            return Ok(i64::from(i));
        }
        let i = u32::try_from(self.raw.vertices.len())
            .map_err(|_| ErrorKind::Mesh("more than u32::MAX vertices".into()))?;
        self.raw.vertices.push(Vec3::from(p));
        self.seen.insert(key, i);
        Ok(i64::from(i))
    }

    fn facet(&mut self, corners: &[[f64; 3]]) -> Result<(), ErrorKind> {
        let ids = corners
            .iter()
            .map(|&p| self.vertex(p))
            .collect::<Result<Vec<_>, _>>()?;
        self.raw.push_polygon(&ids)
    }
}

pub(crate) fn read(bytes: &[u8]) -> Result<RawMesh, ErrorKind> {
    let count = bytes.get(80..84).map(|b| Num::U32.get_f64(b, false) as u64);
    let binary_len = count.map(|n| 84 + 50 * n);
    let trimmed = bytes.trim_ascii_start();
    let ascii = trimmed.len() >= 5 && trimmed[..5].eq_ignore_ascii_case(b"solid");
    if binary_len == Some(bytes.len() as u64) || (!ascii && bytes.len() >= 84) {
        read_binary(bytes)
    } else if ascii {
        read_ascii(trimmed)
    } else {
        Err(ErrorKind::BadMagic(
            "STL (neither `solid` text nor a binary header)",
        ))
    }
}

fn read_binary(bytes: &[u8]) -> Result<RawMesh, ErrorKind> {
    let mut c = Cursor::new(bytes);
    let header = c.take(80)?;
    let count = Num::U32.get_i64(c.take(4)?, false)? as usize;
    let expected = 84 + 50 * count as u64;
    if bytes.len() as u64 != expected {
        return Err(ErrorKind::DataSize {
            expected,
            got: bytes.len() as u64,
        });
    }
    let body = c.take(count * 50)?;
    let mut m = Merger::default();
    m.raw.lps = says_lps(header);
    m.raw.triangles.reserve(count);
    for f in body.chunks_exact(50) {
        let corner = |k: usize| -> [f64; 3] {
            [0, 1, 2].map(|j| Num::F32.get_f64(&f[12 + 12 * k + 4 * j..], false))
        };
        m.facet(&[corner(0), corner(1), corner(2)])?;
    }
    Ok(m.raw)
}

fn read_ascii(text: &[u8]) -> Result<RawMesh, ErrorKind> {
    let mut c = Cursor::new(text);
    let mut m = Merger::default();
    let mut poly: Vec<[f64; 3]> = Vec::new();
    let mut in_loop = false;
    while let Some(tok) = c.token() {
        let word = tok.to_ascii_lowercase();
        match word.as_slice() {
            b"solid" | b"endsolid" => {
                let name = c.line().unwrap_or_default();
                m.raw.lps |= says_lps(name);
            }
            b"facet" => {
                if c.token().map(<[u8]>::to_ascii_lowercase).as_deref() != Some(b"normal") {
                    return Err(ErrorKind::Mesh("`facet` without `normal`".into()));
                }
                c.floats(3, "facet normal")?;
            }
            b"outer" => {
                if c.token().map(<[u8]>::to_ascii_lowercase).as_deref() != Some(b"loop") {
                    return Err(ErrorKind::Mesh("`outer` without `loop`".into()));
                }
                in_loop = true;
                poly.clear();
            }
            b"vertex" if in_loop => {
                // STL coordinates are `f32`; round text as the binary form would be.
                let v = c.floats(3, "vertex")?;
                poly.push([0, 1, 2].map(|k| f64::from(v[k] as f32)));
            }
            b"endloop" if in_loop => {
                if poly.len() < 3 {
                    return Err(ErrorKind::Mesh(format!(
                        "facet with {} vertices",
                        poly.len()
                    )));
                }
                m.facet(&poly)?;
                in_loop = false;
            }
            b"endfacet" => {}
            _ => {
                // The word is the file's text: give its place, not the word.
                return Err(ErrorKind::Mesh(format!(
                    "unexpected word at byte {} of the ASCII STL",
                    c.pos - tok.len()
                )));
            }
        }
    }
    if in_loop {
        return Err(ErrorKind::Mesh("file ends inside a facet".into()));
    }
    Ok(m.raw)
}

fn facet_normal(mesh: &TriMesh, t: usize) -> Vec3 {
    let [a, b, c] = mesh.corners(t);
    (b - a)
        .cross(&(c - a))
        .try_normalize(0.0)
        .unwrap_or_else(Vec3::zeros)
}

/// Encodes a mesh as binary (default) or ASCII STL.
pub(crate) fn write(mesh: &TriMesh, encoding: Encoding) -> Result<Vec<u8>, ErrorKind> {
    let t = mesh.triangles().len();
    let f32s =
        |v: Vec3| -> Result<[f32; 3], ErrorKind> { Ok([to_f32(v.x)?, to_f32(v.y)?, to_f32(v.z)?]) };
    if encoding == Encoding::Ascii {
        let mut out = Vec::with_capacity(40 + t * 250);
        writeln!(out, "solid resecta {SPACE_TAG}")?;
        for i in 0..t {
            let [nx, ny, nz] = f32s(facet_normal(mesh, i))?;
            writeln!(out, "  facet normal {nx:e} {ny:e} {nz:e}\n    outer loop")?;
            for p in mesh.corners(i) {
                let [x, y, z] = f32s(p)?;
                writeln!(out, "      vertex {x:e} {y:e} {z:e}")?;
            }
            writeln!(out, "    endloop\n  endfacet")?;
        }
        writeln!(out, "endsolid resecta")?;
        return Ok(out);
    }
    let count = u32::try_from(t).map_err(|_| ErrorKind::Unsupported {
        what: "triangle count for binary STL",
        value: t.to_string(),
    })?;
    let mut out = Vec::with_capacity(84 + 50 * t);
    let mut header = [b' '; 80];
    let text = format!("resecta output. {SPACE_TAG}");
    header[..text.len()].copy_from_slice(text.as_bytes());
    out.extend_from_slice(&header);
    out.extend_from_slice(&count.to_le_bytes());
    for i in 0..t {
        for v in std::iter::once(facet_normal(mesh, i)).chain(mesh.corners(i)) {
            for c in f32s(v)? {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        out.extend_from_slice(&[0, 0]);
    }
    Ok(out)
}
