//! Wavefront OBJ (text).
//!
//! Reads `v`, `vn` and `f` (corners `v`, `v/vt`, `v/vt/vn`, `v//vn`; negative indices count back
//! from the latest element), fan-triangulating polygons; counts `l` and `p`; ignores texture
//! coordinates, groups and materials. OBJ normals belong to face corners: they become
//! per-vertex normals when every vertex gets one consistent normal, and are dropped otherwise.
//! The writer stores exact `f64` text, a `vn` per vertex when the mesh has normals, and a
//! `# ... SPACE=RAS` comment.

use std::io::Write;

use resecta_geom::{TriMesh, Vec3};

use super::{Cursor, RawMesh, SPACE_TAG, fmt_f64, says_lps};
use crate::error::ErrorKind;

/// Resolves a 1-based (or negative, relative) OBJ index against `len` elements so far; errors
/// name the line, not the word (the file's text).
fn resolve(word: &str, len: usize, what: &str, line: usize) -> Result<i64, ErrorKind> {
    let i: i64 = word
        .parse()
        .map_err(|_| ErrorKind::Mesh(format!("line {line}: a {what} index is not an integer")))?;
    let r = match i {
        0 => None,
        i if i > 0 => Some(i - 1),
        i => Some(len as i64 + i).filter(|&r| r >= 0),
    };
    r.ok_or_else(|| ErrorKind::Mesh(format!("line {line}: {what} index {i} is out of range")))
}

fn floats3(words: &[&str], what: &str, line: usize) -> Result<Vec3, ErrorKind> {
    let mut c = [0.0; 3];
    for (k, slot) in c.iter_mut().enumerate() {
        let w = words
            .get(k + 1)
            .ok_or_else(|| ErrorKind::Mesh(format!("line {line}: `{what}` needs 3 numbers")))?;
        *slot = w.parse().map_err(|_| {
            ErrorKind::Mesh(format!(
                "line {line}: `{what}` value {} is not a number",
                k + 1
            ))
        })?;
    }
    Ok(Vec3::from(c))
}

pub(crate) fn read(bytes: &[u8]) -> Result<RawMesh, ErrorKind> {
    let mut c = Cursor::new(bytes);
    let mut raw = RawMesh::default();
    let mut vn: Vec<Vec3> = Vec::new();
    // (vertex, normal) of every face corner that names a normal.
    let mut corners: Vec<(i64, usize)> = Vec::new();
    let mut all_corners_have_normals = true;
    let mut ids: Vec<i64> = Vec::new();
    let mut number = 0;
    while let Some(line) = c.line() {
        number += 1;
        let line = line.trim_ascii();
        if line.first() == Some(&b'#') {
            raw.lps |= says_lps(line);
            continue;
        }
        let text = String::from_utf8_lossy(line);
        let words: Vec<&str> = text.split_ascii_whitespace().collect();
        match words.first().copied() {
            Some("v") => raw.vertices.push(floats3(&words, "v", number)?),
            Some("vn") => vn.push(floats3(&words, "vn", number)?),
            Some("f") => {
                ids.clear();
                for corner in &words[1..] {
                    let mut parts = corner.split('/');
                    let v = resolve(
                        parts.next().unwrap_or(""),
                        raw.vertices.len(),
                        "vertex",
                        number,
                    )?;
                    ids.push(v);
                    match parts.nth(1).filter(|s| !s.is_empty()) {
                        Some(n) => {
                            let n = resolve(n, vn.len(), "normal", number)?;
                            let n = usize::try_from(n)
                                .ok()
                                .filter(|&n| n < vn.len())
                                .ok_or_else(|| {
                                    ErrorKind::Mesh(format!(
                                        "line {number}: normal index {} is out of range",
                                        n + 1
                                    ))
                                })?;
                            corners.push((v, n));
                        }
                        None => all_corners_have_normals = false,
                    }
                }
                if ids.len() < 3 {
                    return Err(ErrorKind::Mesh(format!(
                        "line {number}: face with {} vertices",
                        ids.len()
                    )));
                }
                raw.push_polygon(&ids)?;
            }
            Some("l" | "p") => raw.other_cells += 1,
            _ => {}
        }
    }
    if !corners.is_empty() && all_corners_have_normals {
        raw.normals = vertex_normals(raw.vertices.len(), &vn, &corners);
    }
    Ok(raw)
}

/// One normal per vertex, if the corners give every vertex exactly one normal (or the file has
/// one `vn` per `v` and every corner pairs them by index).
fn vertex_normals(nv: usize, vn: &[Vec3], corners: &[(i64, usize)]) -> Option<Vec<Vec3>> {
    if vn.len() == nv && corners.iter().all(|&(v, n)| v == n as i64) {
        return Some(vn.to_vec());
    }
    let mut assigned: Vec<Option<Vec3>> = vec![None; nv];
    for &(v, n) in corners {
        let slot = assigned.get_mut(usize::try_from(v).ok()?)?;
        match slot {
            None => *slot = Some(vn[n]),
            Some(m) if *m == vn[n] => {}
            Some(_) => return None,
        }
    }
    assigned.into_iter().collect()
}

/// Encodes a mesh as OBJ text.
pub(crate) fn write(mesh: &TriMesh) -> Result<Vec<u8>, ErrorKind> {
    let mut out = Vec::with_capacity(64 + mesh.vertices().len() * 60 + mesh.triangles().len() * 30);
    writeln!(out, "# resecta output. {SPACE_TAG}")?;
    let xyz = |p: &Vec3| format!("{} {} {}", fmt_f64(p.x), fmt_f64(p.y), fmt_f64(p.z));
    for p in mesh.vertices() {
        writeln!(out, "v {}", xyz(p))?;
    }
    let normals = mesh.normals();
    for n in normals.unwrap_or_default() {
        writeln!(out, "vn {}", xyz(n))?;
    }
    for tri in mesh.triangles() {
        let [a, b, c] = tri.map(|i| u64::from(i) + 1);
        if normals.is_some() {
            writeln!(out, "f {a}//{a} {b}//{b} {c}//{c}")?;
        } else {
            writeln!(out, "f {a} {b} {c}")?;
        }
    }
    Ok(out)
}
