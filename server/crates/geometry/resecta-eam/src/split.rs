//! The plane between the upper atrium, which holds the pulmonary veins, and the lower.
//!
//! The thesis drew it by hand: as low as possible, with every vein above it. Here it is found
//! automatically. The axis runs from the body's centroid to the centroid of the vein ostia.
//! The plane lies across that axis, through the lowest ostium point along it, so every vein
//! and its whole ostium lie above it.

use std::collections::BinaryHeap;

use resecta_geom::{Real, TriMesh, Vec3};
use serde::Serialize;

use crate::EamError;

/// How a [`Split`] was found.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum SplitSource {
    /// Given by the user.
    Given,
    /// From the ostia of the phantom's veins or of a label map's vein labels (vein voxels
    /// that touch body voxels across a face).
    Ostia { veins: usize, ostium_points: usize },
    /// From a mesh's openings. The largest boundary loop is the mitral valve; the others are
    /// clipped veins. Each vein's ostium is where its tube flares into the body: walking away
    /// from its opening, the first geodesic ring longer than `flare` times the opening's
    /// perimeter.
    Openings { veins: usize, flare: Real },
}

/// `upper ⇔ normal·p ≥ offset`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Split {
    /// Unit normal pointing into the upper part.
    #[serde(serialize_with = "xyz")]
    pub normal: Vec3,
    /// mm along `normal`.
    pub offset: Real,
    pub source: SplitSource,
}

fn xyz<S: serde::Serializer>(v: &Vec3, s: S) -> Result<S::Ok, S::Error> {
    s.collect_seq(v.iter())
}

impl Split {
    /// The plane through `point` with `normal` (towards the upper part).
    pub fn given(point: Vec3, normal: Vec3) -> Result<Self, EamError> {
        let len = normal.norm();
        if !(len.is_finite() && len > 1e-12 && point.iter().all(|c| c.is_finite())) {
            return Err(EamError::InvalidParameter {
                name: "plane",
                reason: "needs a finite point and a non-zero normal".into(),
            });
        }
        let normal = normal / len;
        Ok(Self {
            normal,
            offset: normal.dot(&point),
            source: SplitSource::Given,
        })
    }

    /// Across the axis from `body_centroid` to the ostia's centroid, through the lowest ostium
    /// point (see the module doc). `ostia` holds the points of each vein's ostium.
    pub fn from_ostia(body_centroid: Vec3, ostia: &[Vec<Vec3>]) -> Result<Self, EamError> {
        let all: Vec<Vec3> = ostia.iter().flatten().copied().collect();
        if all.is_empty() {
            return Err(EamError::NoOstia);
        }
        let centre = all.iter().sum::<Vec3>() / all.len() as Real;
        let axis = centre - body_centroid;
        if axis.norm() < 1e-9 {
            return Err(EamError::NoOstia);
        }
        let normal = axis.normalize();
        let offset = all
            .iter()
            .map(|p| normal.dot(p))
            .fold(Real::INFINITY, Real::min);
        Ok(Self {
            normal,
            offset,
            source: SplitSource::Ostia {
                veins: ostia.iter().filter(|o| !o.is_empty()).count(),
                ostium_points: all.len(),
            },
        })
    }

    /// Whether `p` lies in the upper part.
    pub fn is_upper(&self, p: &Vec3) -> bool {
        self.normal.dot(p) >= self.offset
    }

    /// The split of an open atrium mesh from its openings (see [`SplitSource::Openings`]).
    pub fn from_openings(mesh: &TriMesh) -> Result<Self, EamError> {
        let loops = boundary_loops(mesh);
        if loops.len() < 3 {
            return Err(EamError::NoVeinOpenings { loops: loops.len() });
        }
        let v = mesh.vertices();
        let perimeter = |l: &Vec<u32>| -> Real {
            (0..l.len())
                .map(|i| (v[l[i] as usize] - v[l[(i + 1) % l.len()] as usize]).norm())
                .sum()
        };
        let mitral = (0..loops.len())
            .max_by(|&a, &b| perimeter(&loops[a]).total_cmp(&perimeter(&loops[b])))
            .unwrap_or(0);
        let centroid =
            |l: &Vec<u32>| l.iter().map(|&i| v[i as usize]).sum::<Vec3>() / l.len() as Real;
        let graph = EdgeGraph::new(mesh);
        let mut ostia = Vec::new();
        for (k, l) in loops.iter().enumerate() {
            if k == mitral {
                continue;
            }
            let dist = graph.distances_from(l);
            let ostium = flare_ring(mesh, &dist, FLARE * perimeter(l));
            ostia.push(ostium);
        }
        let mut split = Self::from_ostia(centroid(&loops[mitral]), &ostia)?;
        split.source = SplitSource::Openings {
            veins: ostia.len(),
            flare: FLARE,
        };
        Ok(split)
    }
}

/// A vein's ostium is the first geodesic ring longer than this many times its opening.
const FLARE: Real = 2.0;

/// Closed chains of boundary edges (edges with one triangle), as vertex indices.
fn boundary_loops(mesh: &TriMesh) -> Vec<Vec<u32>> {
    use std::collections::HashMap;
    let mut count: HashMap<(u32, u32), (u32, i32)> = HashMap::new();
    for t in mesh.triangles() {
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            let key = (a.min(b), a.max(b));
            let entry = count.entry(key).or_insert((0, 0));
            entry.0 += 1;
            entry.1 = if a < b { 1 } else { -1 };
        }
    }
    // Directed boundary edges a → b as they run in their triangle.
    let mut next: HashMap<u32, u32> = HashMap::new();
    let mut boundary: Vec<(u32, u32)> = count
        .iter()
        .filter(|(_, (n, _))| *n == 1)
        .map(|(&(a, b), &(_, dir))| if dir > 0 { (a, b) } else { (b, a) })
        .collect();
    boundary.sort_unstable();
    for &(a, b) in &boundary {
        next.insert(a, b);
    }
    let mut loops = Vec::new();
    let mut used = std::collections::HashSet::new();
    for &(start, _) in &boundary {
        if used.contains(&start) {
            continue;
        }
        let mut l = vec![start];
        used.insert(start);
        let mut cur = start;
        while let Some(&n) = next.get(&cur) {
            if n == start || !used.insert(n) {
                break;
            }
            l.push(n);
            cur = n;
        }
        if l.len() >= 3 {
            loops.push(l);
        }
    }
    loops
}

/// Vertex adjacency with edge lengths.
struct EdgeGraph {
    adjacency: Vec<Vec<(u32, Real)>>,
}

impl EdgeGraph {
    fn new(mesh: &TriMesh) -> Self {
        let v = mesh.vertices();
        let mut adjacency = vec![Vec::new(); v.len()];
        for t in mesh.triangles() {
            for e in 0..3 {
                let (a, b) = (t[e] as usize, t[(e + 1) % 3] as usize);
                let d = (v[a] - v[b]).norm();
                adjacency[a].push((b as u32, d));
                adjacency[b].push((a as u32, d));
            }
        }
        Self { adjacency }
    }

    /// Dijkstra distances along edges from the `sources`.
    fn distances_from(&self, sources: &[u32]) -> Vec<Real> {
        #[derive(PartialEq)]
        struct Item(Real, u32);
        impl Eq for Item {}
        impl PartialOrd for Item {
            fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
                Some(self.cmp(o))
            }
        }
        impl Ord for Item {
            fn cmp(&self, o: &Self) -> std::cmp::Ordering {
                o.0.total_cmp(&self.0).then(o.1.cmp(&self.1))
            }
        }
        let mut dist = vec![Real::INFINITY; self.adjacency.len()];
        let mut heap = BinaryHeap::new();
        for &s in sources {
            dist[s as usize] = 0.0;
            heap.push(Item(0.0, s));
        }
        while let Some(Item(d, u)) = heap.pop() {
            if d > dist[u as usize] {
                continue;
            }
            for &(w, len) in &self.adjacency[u as usize] {
                let nd = d + len;
                if nd < dist[w as usize] {
                    dist[w as usize] = nd;
                    heap.push(Item(nd, w));
                }
            }
        }
        dist
    }
}

/// Points of the first ring `{dist = t}` (t in steps of the median edge) whose length exceeds
/// `limit`: where the tube has flared into the body. Empty if none does.
fn flare_ring(mesh: &TriMesh, dist: &[Real], limit: Real) -> Vec<Vec3> {
    let v = mesh.vertices();
    let mut edges: Vec<Real> = mesh
        .triangles()
        .iter()
        .map(|t| (v[t[0] as usize] - v[t[1] as usize]).norm())
        .collect();
    edges.sort_unstable_by(Real::total_cmp);
    let step = edges.get(edges.len() / 2).copied().unwrap_or(1.0).max(1e-6);
    let far = dist
        .iter()
        .copied()
        .filter(|d| d.is_finite())
        .fold(0.0, Real::max);
    let mut t = step;
    while t < far {
        let mut length = 0.0;
        let mut ring = Vec::new();
        for tri in mesh.triangles() {
            let mut cut = Vec::with_capacity(2);
            for e in 0..3 {
                let (a, b) = (tri[e] as usize, tri[(e + 1) % 3] as usize);
                let (da, db) = (dist[a], dist[b]);
                if (da < t) != (db < t) && da.is_finite() && db.is_finite() {
                    let f = (t - da) / (db - da);
                    cut.push(v[a] + (v[b] - v[a]) * f);
                }
            }
            if cut.len() == 2 {
                length += (cut[1] - cut[0]).norm();
                ring.extend(cut);
            }
        }
        if length > limit {
            return ring;
        }
        t += step;
    }
    Vec::new()
}
