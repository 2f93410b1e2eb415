//! Isosurfaces of scalar lattices by marching cubes, closed and manifold by construction.
//!
//! The case table is derived from the cube's faces ([`table`]): ambiguous faces are resolved by
//! the asymptotic decider on that face alone (ties separate the inside corners), so two cubes
//! sharing a face always cut it the same way and the surface has no cracks. Vertices are shared
//! through lattice-edge ids, so the output is an indexed mesh, closed whenever the lattice
//! border is outside (or [`Options::close_border`] is set), with triangles facing outward
//! (from values above the iso-value towards values below it).
//!
//! The work is split into z-layers processed in parallel (rayon); vertex and triangle order
//! depend only on the input, never on the thread count. Output is in lattice (index)
//! coordinates; map it to RAS with [`TriMesh::transformed`].
//!
//! [`voxel_boundary`] gives the other surface of a mask: the exact boundary of its voxels taken
//! as cubes, in RAS, the one safety margins are measured to.

mod table;
mod voxels;

pub use voxels::voxel_boundary;

use rayon::prelude::*;
use resecta_geom::{GeomError, TriMesh, Vec3, Volume};
use table::{EDGES, FACES, TABLE};

/// What can go wrong extracting a surface.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IsoError {
    #[error("lattice dimensions {dims:?} need at least 2 nodes along every axis")]
    TooSmall { dims: [usize; 3] },
    #[error("lattice has {got} values but dimensions {dims:?} need {expected}")]
    DataLength {
        dims: [usize; 3],
        expected: usize,
        got: usize,
    },
    #[error("iso-value {0} is not finite")]
    BadIso(f32),
    #[error("value at lattice node {0} is not finite")]
    NonFinite(usize),
    #[error("surface has more than u32::MAX vertices")]
    TooManyVertices,
    #[error("device: {0}")]
    Device(String),
    #[error(transparent)]
    Geometry(#[from] GeomError),
}

/// A lattice value: anything that reads as an `f32`.
pub trait Sample: Copy + Send + Sync {
    fn value(self) -> f32;
}
impl Sample for f32 {
    #[inline]
    fn value(self) -> f32 {
        self
    }
}
impl Sample for u8 {
    #[inline]
    fn value(self) -> f32 {
        f32::from(self)
    }
}
impl Sample for bool {
    #[inline]
    fn value(self) -> f32 {
        if self { 1.0 } else { 0.0 }
    }
}

/// Extraction options.
#[derive(Debug, Clone, Copy, Default)]
pub struct Options {
    /// Treat nodes on the lattice border as outside, so the surface is closed even where the
    /// object touches the border (there it follows the border, as if the lattice were padded).
    pub close_border: bool,
}

/// Surface `value = iso` of the lattice `values` (`i` fastest) with `dims` nodes, in lattice
/// coordinates. Inside is `value > iso`.
pub fn extract<T: Sample>(
    dims: [usize; 3],
    values: &[T],
    iso: f32,
    options: Options,
) -> Result<TriMesh, IsoError> {
    check(dims, values.len(), iso)?;
    let classes = classify(dims, values, iso, options);
    Lattice::new(dims, values, iso, classes)?.extract()
}

/// The first pass of [`extract`], over every lattice node: its class (1 inside: `value > iso`
/// and, with [`Options::close_border`], not on the border; else 0), and per node row (j, k) the
/// state bits: 1 some node inside, 2 some node outside, 4 some value not finite.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeClasses {
    /// Per node, `i` fastest.
    pub class: Vec<u8>,
    /// Per node row, index `j + ny·k`.
    pub rows: Vec<u8>,
}

/// Computes [`NodeClasses`] of an f32 lattice (a device may; [`CpuClassifier`] by default).
pub trait NodeClassifier: Send + Sync + std::fmt::Debug {
    /// `"cpu"`, `"wgpu"`, …
    fn backend(&self) -> &'static str;
    /// The classes of `values` (already checked against `dims`). [`IsoError::Device`] when the
    /// device failed: [`extract_with`] then classifies on the CPU.
    fn classify(
        &self,
        dims: [usize; 3],
        values: &[f32],
        iso: f32,
        options: Options,
    ) -> Result<NodeClasses, IsoError>;
}

/// The classification of [`extract`], on the CPU (rayon over node rows).
#[derive(Debug, Clone, Copy, Default)]
pub struct CpuClassifier;

impl NodeClassifier for CpuClassifier {
    fn backend(&self) -> &'static str {
        "cpu"
    }
    fn classify(
        &self,
        dims: [usize; 3],
        values: &[f32],
        iso: f32,
        options: Options,
    ) -> Result<NodeClasses, IsoError> {
        check(dims, values.len(), iso)?;
        Ok(classify(dims, values, iso, options))
    }
}

/// [`extract`] of an f32 lattice with its nodes classified by `classifier` (the CPU's when its
/// device fails); the same mesh as [`extract`] for the same classes.
pub fn extract_with(
    dims: [usize; 3],
    values: &[f32],
    iso: f32,
    options: Options,
    classifier: &dyn NodeClassifier,
) -> Result<TriMesh, IsoError> {
    check(dims, values.len(), iso)?;
    let classes = match classifier.classify(dims, values, iso, options) {
        Err(IsoError::Device(_)) => classify(dims, values, iso, options),
        r => r?,
    };
    let nodes = values.len();
    if classes.class.len() != nodes || classes.rows.len() != dims[1] * dims[2] {
        return Err(IsoError::Device(format!(
            "{} classifier returned {} classes and {} rows for {dims:?}",
            classifier.backend(),
            classes.class.len(),
            classes.rows.len()
        )));
    }
    Lattice::new(dims, values, iso, classes)?.extract()
}

/// Checks the lattice's dimensions, value count and iso-value.
fn check(dims: [usize; 3], len: usize, iso: f32) -> Result<(), IsoError> {
    if dims.iter().any(|&d| d < 2) {
        return Err(IsoError::TooSmall { dims });
    }
    let expected = dims
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .unwrap_or(usize::MAX);
    if len != expected {
        return Err(IsoError::DataLength {
            dims,
            expected,
            got: len,
        });
    }
    if !iso.is_finite() {
        return Err(IsoError::BadIso(iso));
    }
    Ok(())
}

/// [`NodeClasses`] of a checked lattice.
fn classify<T: Sample>(dims: [usize; 3], values: &[T], iso: f32, options: Options) -> NodeClasses {
    let [nx, ny, nz] = dims;
    let mut class = vec![0u8; values.len()];
    let mut rows = vec![0u8; ny * nz];
    class
        .par_chunks_mut(nx)
        .zip(rows.par_iter_mut())
        .enumerate()
        .for_each(|(r, (row, state))| {
            let (j, k) = (r % ny, r / ny);
            let border_row = j == 0 || k == 0 || j + 1 == ny || k + 1 == nz;
            let mut st = 0u8;
            for (i, (c, v)) in row.iter_mut().zip(&values[r * nx..][..nx]).enumerate() {
                let v = v.value();
                let border = border_row || i == 0 || i + 1 == nx;
                let inside = v > iso && !(options.close_border && border);
                *c = u8::from(inside);
                st |= if inside { 1 } else { 2 };
                st |= u8::from(!v.is_finite()) << 2;
            }
            *state = st;
        });
    NodeClasses { class, rows }
}

/// Boundary surface of a binary mask in voxel-index coordinates (vertices at edge midpoints, as
/// discrete marching cubes / flying edges), closed also where the mask touches the volume
/// border: the mask is treated as padded with one layer of background.
pub fn extract_mask(mask: &Volume<bool>) -> Result<TriMesh, IsoError> {
    let [nx, ny, nz] = mask.grid().dims();
    let padded_dims = [nx + 2, ny + 2, nz + 2];
    let mut padded = vec![false; padded_dims.iter().product()];
    let src = mask.data();
    padded
        .par_chunks_mut(padded_dims[0] * padded_dims[1])
        .enumerate()
        .for_each(|(k, plane)| {
            if k == 0 || k > nz {
                return;
            }
            for j in 0..ny {
                let row = &src[(k - 1) * nx * ny + j * nx..][..nx];
                plane[(j + 1) * padded_dims[0] + 1..][..nx].copy_from_slice(row);
            }
        });
    let mesh = extract(padded_dims, &padded, 0.5, Options::default())?;
    let shift = Vec3::repeat(-1.0);
    let vertices = mesh.vertices().iter().map(|v| v + shift).collect();
    Ok(TriMesh::new(vertices, mesh.triangles().to_vec())?)
}

/// Vertex positions along lattice edges are kept this far from the nodes, so no triangle
/// collapses when a node value equals the iso-value.
const T_MARGIN: f32 = 1e-4;

/// Column code (bits: y, z, y+z neighbours) → the case bits of the cube's x = 0 corners.
const SPREAD: [u8; 16] = {
    let mut t = [0u8; 16];
    let mut q = 0;
    while q < 16 {
        t[q] = (q as u8 & 1)
            | (q as u8 >> 1 & 1) << 2
            | (q as u8 >> 2 & 1) << 4
            | (q as u8 >> 3 & 1) << 6;
        q += 1;
    }
    t
};

/// Marks a layer-local centre vertex id until the layers are joined.
const CENTRE: u32 = 1 << 31;

struct Lattice<'a, T> {
    dims: [usize; 3],
    values: &'a [T],
    iso: f32,
    /// 1 where the node is inside, else 0.
    class: Vec<u8>,
    /// Per node row (j, k): bit 0 some node inside, bit 1 some node outside.
    rows: Vec<u8>,
}

/// Per z-slice vertex counts: x-edges and y-edges in the slice, z-edges to the next slice.
#[derive(Clone, Copy, Default)]
struct SliceCounts {
    x: usize,
    y: usize,
    z: usize,
    /// Does the slice have inside nodes / outside nodes?
    any_in: bool,
    any_out: bool,
}

impl<'a, T: Sample> Lattice<'a, T> {
    /// The lattice (checked) with its node classes.
    fn new(
        dims: [usize; 3],
        values: &'a [T],
        iso: f32,
        classes: NodeClasses,
    ) -> Result<Self, IsoError> {
        let NodeClasses { class, rows } = classes;
        if rows.par_iter().any(|&st| st & 4 != 0) {
            let i = values.iter().position(|v| !v.value().is_finite());
            return Err(IsoError::NonFinite(i.unwrap_or(0)));
        }
        Ok(Self {
            dims,
            values,
            iso,
            class,
            rows,
        })
    }

    #[inline]
    fn at(&self, i: usize, j: usize, k: usize) -> f32 {
        self.values[i + self.dims[0] * (j + self.dims[1] * k)].value()
    }

    /// Does the cell row (j, k) .. (j + 1, k + 1) hold both inside and outside nodes?
    #[inline]
    fn mixed_cells(&self, j: usize, k: usize) -> bool {
        let ny = self.dims[1];
        let s = self.rows[j + ny * k]
            | self.rows[j + 1 + ny * k]
            | self.rows[j + ny * (k + 1)]
            | self.rows[j + 1 + ny * (k + 1)];
        s == 3
    }

    /// Crossing parameter along the edge from node `a` (value `va`) to `b`.
    #[inline]
    fn crossing(&self, va: f32, vb: f32) -> f32 {
        let t = if va == vb {
            0.5
        } else {
            (self.iso - va) / (vb - va)
        };
        // NaN-free: values and iso are finite, and va != vb here.
        t.clamp(T_MARGIN, 1.0 - T_MARGIN)
    }

    fn extract(&self) -> Result<TriMesh, IsoError> {
        let nz = self.dims[2];
        let counts: Vec<SliceCounts> = (0..nz).into_par_iter().map(|k| self.count(k)).collect();
        // Vertex ids: slice after slice, x-edges, y-edges, then z-edges up to the next slice.
        let mut base = Vec::with_capacity(nz + 1);
        let mut total = 0usize;
        for c in &counts {
            base.push(total);
            total += c.x + c.y + c.z;
        }
        base.push(total);
        if total >= CENTRE as usize {
            return Err(IsoError::TooManyVertices);
        }
        let vertices: Vec<Vec3> = (0..nz)
            .into_par_iter()
            .flat_map_iter(|k| self.slice_vertices(k))
            .collect();
        let layers: Vec<(Vec<[u32; 3]>, Vec<Vec3>)> = (0..nz - 1)
            .into_par_iter()
            .map(|k| {
                if (!counts[k].any_in && !counts[k + 1].any_in)
                    || (!counts[k].any_out && !counts[k + 1].any_out)
                {
                    return (Vec::new(), Vec::new());
                }
                self.layer_triangles(k, &base, &vertices)
            })
            .collect();
        debug_assert_eq!(vertices.len(), total);
        // Centre vertices of each layer follow all edge vertices, layer after layer.
        let mut vertices = vertices;
        let mut triangles = Vec::with_capacity(layers.iter().map(|l| l.0.len()).sum());
        for (tris, extra) in layers {
            let offset = u32::try_from(vertices.len()).map_err(|_| IsoError::TooManyVertices)?;
            if u32::try_from(vertices.len() + extra.len()).map_or(true, |n| n >= CENTRE) {
                return Err(IsoError::TooManyVertices);
            }
            triangles.extend(
                tris.into_iter()
                    .map(|t| t.map(|v| if v >= CENTRE { v - CENTRE + offset } else { v })),
            );
            vertices.extend(extra);
        }
        Ok(TriMesh::new(vertices, triangles)?)
    }

    /// Classes of node row (j, k).
    #[inline]
    fn row(&self, j: usize, k: usize) -> &[u8] {
        let nx = self.dims[0];
        &self.class[nx * (j + self.dims[1] * k)..][..nx]
    }

    /// Positions along the row where consecutive nodes differ (x-edges).
    #[inline]
    fn x_crossings(row: &[u8]) -> impl Iterator<Item = usize> + '_ {
        row.windows(2)
            .enumerate()
            .filter(|(_, w)| w[0] != w[1])
            .map(|(i, _)| i)
    }

    /// Positions where two rows differ (y- or z-edges between them).
    #[inline]
    fn pair_crossings<'r>(a: &'r [u8], b: &'r [u8]) -> impl Iterator<Item = usize> + 'r {
        a.iter()
            .zip(b)
            .enumerate()
            .filter(|(_, (p, q))| p != q)
            .map(|(i, _)| i)
    }

    #[inline]
    fn count_pair(a: &[u8], b: &[u8]) -> usize {
        a.iter().zip(b).filter(|(p, q)| p != q).count()
    }

    fn count(&self, k: usize) -> SliceCounts {
        let [_, ny, nz] = self.dims;
        let mut c = SliceCounts::default();
        for j in 0..ny {
            let state = self.rows[j + ny * k];
            c.any_in |= state & 1 != 0;
            c.any_out |= state & 2 != 0;
            let row = self.row(j, k);
            if state == 3 {
                c.x += Self::count_pair(&row[..row.len() - 1], &row[1..]);
            }
            if j + 1 < ny && (state == 3 || state != self.rows[j + 1 + ny * k]) {
                c.y += Self::count_pair(row, self.row(j + 1, k));
            }
            if k + 1 < nz && (state == 3 || state != self.rows[j + ny * (k + 1)]) {
                c.z += Self::count_pair(row, self.row(j, k + 1));
            }
        }
        c
    }

    /// Does the row pair hold a crossing? (Rows uniform and equal have none.)
    #[inline]
    fn pair_may_cross(&self, j0: usize, k0: usize, j1: usize, k1: usize) -> bool {
        let ny = self.dims[1];
        let (a, b) = (self.rows[j0 + ny * k0], self.rows[j1 + ny * k1]);
        a == 3 || b == 3 || a != b
    }

    /// Vertices of slice `k` in id order (x-edges, y-edges, z-edges; each in scan order).
    fn slice_vertices(&self, k: usize) -> Vec<Vec3> {
        let [nx, ny, nz] = self.dims;
        let mut out = Vec::new();
        let point = |i: usize, j: usize, kk: usize, axis: usize, a: f32, b: f32| {
            let mut p = Vec3::new(i as f64, j as f64, kk as f64);
            p[axis] += f64::from(self.crossing(a, b));
            p
        };
        let vals = |j: usize, kk: usize| &self.values[nx * (j + ny * kk)..][..nx];
        for j in 0..ny {
            if self.rows[j + ny * k] == 3 {
                let v = vals(j, k);
                out.extend(
                    Self::x_crossings(self.row(j, k))
                        .map(|i| point(i, j, k, 0, v[i].value(), v[i + 1].value())),
                );
            }
        }
        for j in 0..ny - 1 {
            if self.pair_may_cross(j, k, j + 1, k) {
                let (v, w) = (vals(j, k), vals(j + 1, k));
                out.extend(
                    Self::pair_crossings(self.row(j, k), self.row(j + 1, k))
                        .map(|i| point(i, j, k, 1, v[i].value(), w[i].value())),
                );
            }
        }
        if k + 1 < nz {
            for j in 0..ny {
                if self.pair_may_cross(j, k, j, k + 1) {
                    let (v, w) = (vals(j, k), vals(j, k + 1));
                    out.extend(
                        Self::pair_crossings(self.row(j, k), self.row(j, k + 1))
                            .map(|i| point(i, j, k, 2, v[i].value(), w[i].value())),
                    );
                }
            }
        }
        out
    }

    /// Dense id maps for slice `k`: x-edges and y-edges (and z-edges up to `k + 1` when
    /// `with_z`), `u32::MAX` where the edge does not cross. Ids follow [`Self::slice_vertices`].
    fn id_maps(&self, k: usize, base: usize, with_z: bool) -> [Vec<u32>; 3] {
        let [nx, ny, _] = self.dims;
        let mut id = base as u32;
        let mut xs = vec![u32::MAX; nx * ny];
        let mut ys = vec![u32::MAX; nx * ny];
        let mut zs = if with_z {
            vec![u32::MAX; nx * ny]
        } else {
            Vec::new()
        };
        let mut assign = |map: &mut [u32], crossings: &mut dyn Iterator<Item = usize>| {
            for i in crossings {
                map[i] = id;
                id += 1;
            }
        };
        for j in 0..ny {
            if self.rows[j + ny * k] == 3 {
                assign(&mut xs[nx * j..], &mut Self::x_crossings(self.row(j, k)));
            }
        }
        for j in 0..ny - 1 {
            if self.pair_may_cross(j, k, j + 1, k) {
                let mut c = Self::pair_crossings(self.row(j, k), self.row(j + 1, k));
                assign(&mut ys[nx * j..], &mut c);
            }
        }
        if with_z {
            for j in 0..ny {
                if self.pair_may_cross(j, k, j, k + 1) {
                    let mut c = Self::pair_crossings(self.row(j, k), self.row(j, k + 1));
                    assign(&mut zs[nx * j..], &mut c);
                }
            }
        }
        [xs, ys, zs]
    }

    fn layer_triangles(
        &self,
        k: usize,
        base: &[usize],
        vertices: &[Vec3],
    ) -> (Vec<[u32; 3]>, Vec<Vec3>) {
        let [nx, ny, _] = self.dims;
        let [x0, y0, z0] = self.id_maps(k, base[k], true);
        let [x1, y1, _] = self.id_maps(k + 1, base[k + 1], false);
        let mut tris = Vec::new();
        let mut centres = Vec::new();
        // Column codes: bit 0 (j, k), bit 1 (j+1, k), bit 2 (j, k+1), bit 3 (j+1, k+1).
        let mut code = vec![0u8; nx];
        for j in 0..ny - 1 {
            if !self.mixed_cells(j, k) {
                continue;
            }
            let (r00, r10, r01, r11) = (
                self.row(j, k),
                self.row(j + 1, k),
                self.row(j, k + 1),
                self.row(j + 1, k + 1),
            );
            for (i, q) in code.iter_mut().enumerate() {
                *q = r00[i] | r10[i] << 1 | r01[i] << 2 | r11[i] << 3;
            }
            for i in 0..nx - 1 {
                let (qa, qb) = (code[i], code[i + 1]);
                if qa == qb && (qa == 0 || qa == 15) {
                    continue;
                }
                let case = usize::from(SPREAD[qa as usize] | SPREAD[qb as usize] << 1);
                let joined = self.face_decisions(i, j, k, TABLE.ambiguous[case]);
                let loops = &TABLE.loops[case * 64 + joined];
                let edge_id = |e: u8| -> u32 {
                    let (a, _, axis) = EDGES[e as usize];
                    let (di, dj, dk) = (
                        (a & 1) as usize,
                        (a >> 1 & 1) as usize,
                        (a >> 2 & 1) as usize,
                    );
                    let cell = (i + di) + nx * (j + dj);
                    match (axis, dk) {
                        (0, 0) => x0[cell],
                        (0, _) => x1[cell],
                        (1, 0) => y0[cell],
                        (1, _) => y1[cell],
                        _ => z0[cell],
                    }
                };
                tris.extend(loops.triangles.iter().map(|t| t.map(edge_id)));
                for q in &loops.free_quads {
                    let ids = q.map(edge_id);
                    let p = |n: usize| vertices[ids[n] as usize];
                    if (p(0) - p(2)).norm_squared() <= (p(1) - p(3)).norm_squared() {
                        tris.push([ids[0], ids[1], ids[2]]);
                        tris.push([ids[0], ids[2], ids[3]]);
                    } else {
                        tris.push([ids[1], ids[2], ids[3]]);
                        tris.push([ids[1], ids[3], ids[0]]);
                    }
                }
                for lp in &loops.centred {
                    let ids: Vec<u32> = lp.iter().map(|&e| edge_id(e)).collect();
                    let sum: Vec3 = ids.iter().map(|&v| vertices[v as usize]).sum();
                    let c = CENTRE + centres.len() as u32;
                    centres.push(sum / ids.len() as f64);
                    for m in 0..ids.len() {
                        tris.push([c, ids[m], ids[(m + 1) % ids.len()]]);
                    }
                }
            }
        }
        (tris, centres)
    }

    /// Bit f set when ambiguous face f of cell (i, j, k) joins its inside corners: the
    /// asymptotic decider (bilinear saddle value above iso), evaluated from the face's own
    /// four values in a fixed order so the neighbouring cell decides identically.
    fn face_decisions(&self, i: usize, j: usize, k: usize, ambiguous: u8) -> usize {
        let mut joined = 0usize;
        for (f, &(axis, side, _)) in FACES.iter().enumerate() {
            if ambiguous >> f & 1 == 0 {
                continue;
            }
            let mut o = [i, j, k];
            o[axis] += side as usize;
            let (u, v) = match axis {
                0 => (1, 2),
                1 => (0, 2),
                _ => (0, 1),
            };
            let node = |du: usize, dv: usize| {
                let mut p = o;
                p[u] += du;
                p[v] += dv;
                f64::from(self.at(p[0], p[1], p[2]))
            };
            let (a, b, c, d) = (node(0, 0), node(1, 0), node(1, 1), node(0, 1));
            let den = a + c - b - d;
            if den != 0.0 {
                let saddle = (a * c - b * d) / den;
                if saddle > f64::from(self.iso) {
                    joined |= 1 << f;
                }
            }
        }
        joined
    }
}
