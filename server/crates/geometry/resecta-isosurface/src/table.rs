//! The marching-cubes case table, derived at start-up from the cube's faces rather than typed
//! in: on every face the crossings are joined by segments (ambiguous faces by a per-face
//! decision shared with the neighbouring cube), and the segments close into loops. Because a
//! face's segments depend only on that face, neighbouring cubes agree and the surface is closed
//! and manifold.
//!
//! Corner `c` of a cube sits at offset `(c & 1, c >> 1 & 1, c >> 2 & 1)`; bit `c` of a case is
//! set when corner `c` is inside.

use std::sync::LazyLock;

/// The 12 edges as (corner, corner, axis), first corner at the lower end.
pub(crate) const EDGES: [(u8, u8, u8); 12] = [
    (0, 1, 0),
    (2, 3, 0),
    (4, 5, 0),
    (6, 7, 0),
    (0, 2, 1),
    (1, 3, 1),
    (4, 6, 1),
    (5, 7, 1),
    (0, 4, 2),
    (1, 5, 2),
    (2, 6, 2),
    (3, 7, 2),
];

/// Faces as (axis, side, corners counter-clockwise seen from outside the cube).
pub(crate) const FACES: [(usize, u8, [u8; 4]); 6] = [
    (0, 0, [0, 4, 6, 2]),
    (0, 1, [1, 3, 7, 5]),
    (1, 0, [0, 1, 5, 4]),
    (1, 1, [2, 6, 7, 3]),
    (2, 0, [0, 2, 3, 1]),
    (2, 1, [4, 5, 7, 6]),
];

fn edge_between(a: u8, b: u8) -> u8 {
    let (lo, hi) = (a.min(b), a.max(b));
    EDGES
        .iter()
        .position(|&(p, q, _)| p == lo && q == hi)
        .map_or(u8::MAX, |e| e as u8)
}

/// The loops of one case under one set of face decisions: edge ids, loop after loop, and
/// their triangles (edge-id triples). No triangle edge other than the loop's own segments lies
/// on a cube face, so every edge on a face is shared with exactly one triangle of the
/// neighbouring cube.
#[derive(Clone, Default)]
pub(crate) struct Loops {
    pub edges: [u8; 12],
    /// Lengths of up to four loops; 0 ends the list.
    pub lengths: [u8; 4],
    pub triangles: Vec<[u8; 3]>,
    /// Loops of four whose both diagonals are off the faces: the shorter one may be chosen.
    pub free_quads: Vec<[u8; 4]>,
    /// Loops with no face-free triangulation (they pass one face twice): fanned around a new
    /// vertex at their centroid.
    pub centred: Vec<Vec<u8>>,
}

impl Loops {
    #[cfg(test)]
    pub fn iter(&self) -> impl Iterator<Item = &[u8]> {
        let mut start = 0usize;
        self.lengths.iter().take_while(|&&l| l > 0).map(move |&l| {
            let s = &self.edges[start..start + l as usize];
            start += l as usize;
            s
        })
    }
}

/// Bit set of the faces that contain each edge.
fn edge_faces(e: u8) -> u8 {
    let (a, b, _) = EDGES[e as usize];
    let mut bits = 0;
    for (f, &(_, _, corners)) in FACES.iter().enumerate() {
        if corners.contains(&a) && corners.contains(&b) {
            bits |= 1 << f;
        }
    }
    bits
}

/// A diagonal between two loop vertices is allowed when their edges share no face.
fn diagonal_ok(a: u8, b: u8) -> bool {
    edge_faces(a) & edge_faces(b) == 0
}

/// Triangulates the polygon `poly` without face-lying diagonals, preferring central apexes.
fn triangulate(poly: &[u8], out: &mut Vec<[u8; 3]>) -> bool {
    let n = poly.len();
    if n < 3 {
        return true;
    }
    if n == 3 {
        out.push([poly[0], poly[1], poly[2]]);
        return true;
    }
    let mut apexes: Vec<usize> = (1..n - 1).collect();
    apexes.sort_by_key(|&k| (2 * k).abs_diff(n - 1));
    for k in apexes {
        if (k > 1 && !diagonal_ok(poly[0], poly[k]))
            || (k < n - 2 && !diagonal_ok(poly[k], poly[n - 1]))
        {
            continue;
        }
        let mut tris = vec![[poly[0], poly[k], poly[n - 1]]];
        if triangulate(&poly[..=k], &mut tris) && triangulate(&poly[k..], &mut tris) {
            out.extend(tris);
            return true;
        }
    }
    false
}

pub(crate) struct Table {
    /// Bit f set when face f of the case is ambiguous (inside corners on one diagonal).
    pub ambiguous: [u8; 256],
    /// `loops[case * 64 + joined]`, where bit f of `joined` says the inside corners of face f
    /// connect across it (only bits of ambiguous faces matter).
    pub loops: Vec<Loops>,
}

pub(crate) static TABLE: LazyLock<Table> = LazyLock::new(build);

fn build() -> Table {
    let mut ambiguous = [0u8; 256];
    let mut loops = vec![Loops::default(); 256 * 64];
    for case in 0..256usize {
        let inside = |c: u8| case >> c & 1 == 1;
        for (f, &(_, _, corners)) in FACES.iter().enumerate() {
            let ins = corners.map(inside);
            if ins[0] == ins[2] && ins[1] == ins[3] && ins[0] != ins[1] {
                ambiguous[case] |= 1 << f;
            }
        }
        for joined in 0..64usize {
            if joined & !(ambiguous[case] as usize) != 0 {
                continue;
            }
            let mut l = trace(case, joined);
            let mut start = 0usize;
            for &len in l.lengths.iter().take_while(|&&len| len > 0) {
                let poly: Vec<u8> = l.edges[start..start + len as usize].to_vec();
                start += len as usize;
                if len == 4 && diagonal_ok(poly[0], poly[2]) && diagonal_ok(poly[1], poly[3]) {
                    l.free_quads.push([poly[0], poly[1], poly[2], poly[3]]);
                } else if !triangulate(&poly, &mut l.triangles) {
                    l.centred.push(poly);
                }
            }
            loops[case * 64 + joined] = l;
        }
    }
    // Entries for unused bits copy the canonical one so lookups can mask lazily.
    for case in 0..256usize {
        for joined in 0..64usize {
            let canonical = joined & ambiguous[case] as usize;
            if canonical != joined {
                loops[case * 64 + joined] = loops[case * 64 + canonical].clone();
            }
        }
    }
    Table { ambiguous, loops }
}

/// Segments run from an out→in crossing to an in→out crossing (walking each face
/// counter-clockwise seen from outside), which puts the inside on the right and makes the
/// loops' triangles face outward.
fn trace(case: usize, joined: usize) -> Loops {
    let inside = |c: u8| case >> c & 1 == 1;
    let mut next = [u8::MAX; 12];
    for (f, &(_, _, corners)) in FACES.iter().enumerate() {
        // Crossings on the face's edges e_i = (c_i, c_{i+1}), in walking order.
        let mut entering = Vec::new(); // out → in, at edge position i
        let mut leaving = Vec::new(); // in → out
        for i in 0..4 {
            let (a, b) = (corners[i], corners[(i + 1) % 4]);
            match (inside(a), inside(b)) {
                (false, true) => entering.push(i),
                (true, false) => leaving.push(i),
                _ => {}
            }
        }
        let join = joined >> f & 1 == 1;
        for &i in &entering {
            // Separated: the inside arc starting here ends at the next leaving crossing ahead.
            // Joined: pair with the leaving crossing just behind (cutting off an outside corner).
            let pick = |step: usize| {
                (1..4)
                    .map(|d| (i + 4 + step * d) % 4)
                    .find(|j| leaving.contains(j))
            };
            let j = if join && entering.len() == 2 {
                pick(3)
            } else {
                pick(1)
            };
            if let Some(j) = j {
                let from = edge_between(corners[i], corners[(i + 1) % 4]);
                let to = edge_between(corners[j], corners[(j + 1) % 4]);
                next[from as usize] = to;
            }
        }
    }
    let mut out = Loops::default();
    let mut used = [false; 12];
    let (mut n, mut loop_count) = (0usize, 0usize);
    for start in 0..12u8 {
        if next[start as usize] == u8::MAX || used[start as usize] {
            continue;
        }
        let mut len = 0u8;
        let mut e = start;
        while !used[e as usize] {
            used[e as usize] = true;
            out.edges[n] = e;
            n += 1;
            len += 1;
            e = next[e as usize];
        }
        out.lengths[loop_count] = len;
        loop_count += 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_crossing_edge_is_on_exactly_one_loop() {
        for case in 0..256usize {
            let crossing: Vec<u8> = (0..12u8)
                .filter(|&e| {
                    let (a, b, _) = EDGES[e as usize];
                    (case >> a & 1) != (case >> b & 1)
                })
                .collect();
            for joined in 0..64 {
                let l = &TABLE.loops[case * 64 + joined];
                let mut on: Vec<u8> = l.iter().flatten().copied().collect();
                on.sort_unstable();
                assert_eq!(on, crossing, "case {case} joined {joined}");
                assert!(l.iter().all(|lp| lp.len() >= 3), "case {case}");
            }
        }
    }

    #[test]
    fn every_loop_is_triangulated_once() {
        let mut centred = 0;
        for l in &TABLE.loops {
            let n: usize = l.iter().map(|lp| lp.len() - 2).sum();
            let c: usize = l.centred.iter().map(|lp| lp.len() - 2).sum();
            assert_eq!(l.triangles.len() + 2 * l.free_quads.len() + c, n);
            centred += l.centred.len();
        }
        // Only loops through an ambiguous face twice need a centre vertex.
        assert!(centred > 0 && centred < 256 * 64 / 20, "{centred}");
    }

    #[test]
    fn ambiguous_faces_of_the_checkerboard() {
        // Corners 0, 3, 5, 6 inside: every face has its inside corners on a diagonal.
        let case = 1 | 1 << 3 | 1 << 5 | 1 << 6;
        assert_eq!(TABLE.ambiguous[case], 0b11_1111);
        assert_eq!(TABLE.loops[case * 64].iter().count(), 4);
    }
}
