//! Windowed-sinc smoothing (Taubin, Zhang & Golub, "Optimal surface smoothing as filter design",
//! IBM RC-20404, 1996), computed the way VTK ≥ 9.2's `vtkWindowedSincPolyDataFilter` does.
//!
//! With `K = I − W` (W averages each vertex's stencil neighbours), the filter is the polynomial
//! `f(K) = Σⱼ cⱼ Tⱼ(I − K/2)` in Chebyshev polynomials `Tⱼ`, evaluated by the recurrence
//! `x⁽ʲ⁺¹⁾ = 2(I − K/2)x⁽ʲ⁾ − x⁽ʲ⁻¹⁾` and accumulated as `Σ cⱼ x⁽ʲ⁾`. The coefficients are those
//! of an ideal low-pass filter with cut-off `θ_pb + σ` (`θ_pb = acos(1 − k_pb/2)`, `k_pb` the
//! passband) multiplied by a window, with σ found by Newton's method so that `f(k_pb) ≈ 1`
//! (to 10⁻³, at most 500 steps).
//!
//! Stencils (which neighbours a vertex averages), as VTK:
//! - every triangle contributes, for each of its corners, the two other corners; a manifold
//!   interior edge is thus seen twice, a boundary edge once, a non-manifold edge 3+ times;
//! - without boundary and non-manifold smoothing, a vertex whose incident edges all pair up
//!   (closed manifold neighbourhood) averages its distinct neighbours, every other vertex is
//!   fixed;
//! - with boundary smoothing **or** non-manifold smoothing (VTK selects the same analysis for
//!   both): a vertex without boundary edges averages its neighbours (with non-manifold
//!   smoothing and non-manifold weighting, each neighbour counted as often as the edge is used)
//!   unless it has non-manifold edges and non-manifold smoothing is off; a vertex with exactly
//!   two boundary edges, no non-manifold edge and an angle between them below the edge angle
//!   slides along the boundary (**even when boundary smoothing is off**, a VTK quirk kept here);
//!   anything else is fixed;
//! - vertices with 510 or more incident edge uses, or a stencil of more than 255 entries, are
//!   fixed (VTK stores stencil sizes in a byte).
//!
//! "Fixed" vertices take part in the recurrence with an empty stencil, so — exactly as in VTK —
//! they end at `f(0)·x = (Σⱼ cⱼ)·x` in the (normalised) frame rather than exactly at `x`
//! (`Σⱼ cⱼ`, the filter's DC gain, is close to but not exactly 1).

use rayon::prelude::*;
use resecta_geom::{Real, TriMesh, Vec3};

use crate::FilterError;

/// Largest accepted iteration count (the filter's polynomial degree).
pub const MAX_ITERATIONS: u32 = 10_000;

/// Window applied to the ideal low-pass filter's Chebyshev coefficients (VTK's choices).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SincWindow {
    /// VTK's default since 9.2 (and therefore 3D Slicer's).
    #[default]
    Nuttall,
    Blackman,
    Hanning,
    /// VTK's only window before 9.2.
    Hamming,
}

/// Parameters of [`windowed_sinc`]. `Default` gives VTK's defaults (20 iterations, passband
/// 0.1, no normalisation, boundary smoothing on, non-manifold smoothing off, non-manifold
/// weighting on, edge angle 15°, Nuttall window).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SincParams {
    /// Degree of the filter polynomial; 0 returns the input unchanged. At most
    /// [`MAX_ITERATIONS`].
    pub iterations: u32,
    /// Passband `k_pb` in (0, 2]; smaller smooths more.
    pub passband: Real,
    /// Translate the mesh's bounding-box centre to the origin and divide by its diagonal before
    /// filtering (undone afterwards); makes the result translation- and scale-equivariant.
    pub normalize_coordinates: bool,
    /// Let boundary vertices slide along the boundary (see the module notes for the VTK rule
    /// that also does so when `non_manifold_smoothing` is on).
    pub boundary_smoothing: bool,
    /// Smooth vertices on non-manifold edges with all their neighbours.
    pub non_manifold_smoothing: bool,
    /// With non-manifold smoothing: count each neighbour as often as its edge is used.
    pub weight_non_manifold_edges: bool,
    /// A boundary vertex whose two boundary edges turn by more than this (degrees) is fixed.
    pub edge_angle_deg: Real,
    pub window: SincWindow,
}

impl Default for SincParams {
    fn default() -> Self {
        Self {
            iterations: 20,
            passband: 0.1,
            normalize_coordinates: false,
            boundary_smoothing: true,
            non_manifold_smoothing: false,
            weight_non_manifold_edges: true,
            edge_angle_deg: 15.0,
            window: SincWindow::Nuttall,
        }
    }
}

impl SincParams {
    /// 3D Slicer's mapping of its smoothing factor `s` (nominally in [0, 1]): passband
    /// `10^(−4s)`, iterations `⌊20 + 40s⌋`, coordinates normalised, boundary and feature-edge
    /// smoothing off, non-manifold smoothing on, Nuttall window. Slicer skips smoothing when
    /// `s ≤ 0`; so does this (0 iterations). A non-finite `s` gives a passband that
    /// [`windowed_sinc`] rejects.
    pub fn slicer(smoothing_factor: Real) -> Self {
        let s = smoothing_factor;
        let smooth = s > 0.0 || s.is_nan(); // NaN falls through to the (rejected) formula
        Self {
            // Saturating float→int cast, like Slicer's truncating `int` conversion.
            iterations: if smooth { (20.0 + 40.0 * s) as u32 } else { 0 },
            passband: if smooth { 10f64.powf(-4.0 * s) } else { 1.0 },
            normalize_coordinates: true,
            boundary_smoothing: false,
            non_manifold_smoothing: true,
            weight_non_manifold_edges: true,
            edge_angle_deg: 15.0,
            window: SincWindow::Nuttall,
        }
    }

    fn validate(&self) -> Result<(), FilterError> {
        if self.iterations > MAX_ITERATIONS {
            return Err(FilterError::TooManyIterations {
                got: self.iterations,
                max: MAX_ITERATIONS,
            });
        }
        if !(self.passband > 0.0 && self.passband <= 2.0) {
            return Err(FilterError::BadPassband(self.passband));
        }
        if !(0.0..=180.0).contains(&self.edge_angle_deg) {
            return Err(FilterError::BadEdgeAngle(self.edge_angle_deg));
        }
        Ok(())
    }
}

/// The filter's Chebyshev coefficients `c₀ … c_N` (N = `iterations`); `[1]` for 0 iterations.
/// `Σ cⱼ Tⱼ(1 − k/2)` is the filter's response at frequency `k`.
pub fn sinc_coefficients(params: &SincParams) -> Result<Vec<Real>, FilterError> {
    params.validate()?;
    let n = params.iterations as usize;
    if n == 0 {
        return Ok(vec![1.0]);
    }
    let pi = std::f64::consts::PI;
    let kpb = params.passband;
    let theta_pb = (1.0 - 0.5 * kpb).acos();
    let weights: Vec<Real> = (0..=n)
        .map(|i| {
            let a = i as Real * pi / (n + 1) as Real;
            match params.window {
                SincWindow::Nuttall => {
                    0.355768
                        + 0.487396 * a.cos()
                        + 0.144232 * (2.0 * a).cos()
                        + 0.012604 * (3.0 * a).cos()
                }
                SincWindow::Blackman => 0.42 + 0.5 * a.cos() + 0.08 * (2.0 * a).cos(),
                SincWindow::Hanning => 0.5 + 0.5 * a.cos(),
                SincWindow::Hamming => 0.54 + 0.46 * a.cos(),
            }
        })
        .collect();
    let mut c = vec![0.0; n + 1];
    let mut dc = vec![0.0; n + 1];
    let mut sigma = 0.0;
    for _ in 0..500 {
        let cutoff = theta_pb + sigma;
        c[0] = weights[0] * cutoff / pi;
        for i in 1..=n {
            c[i] = 2.0 * weights[i] * (i as Real * cutoff).sin() / (i as Real * pi);
        }
        if n == 1 {
            // Degree 1: no offset can be searched for (VTK keeps σ = 0).
            break;
        }
        // Chebyshev coefficients of the derivative, by the backward recurrence.
        dc[n] = 0.0;
        dc[n - 1] = 0.0;
        dc[n - 2] = 2.0 * (n - 1) as Real * c[n - 1];
        for i in (0..n.saturating_sub(2)).rev() {
            dc[i] = dc[i + 2] + 2.0 * (i + 1) as Real * c[i + 1];
        }
        let (mut f, mut df) = (c[0], dc[0]);
        for i in 1..=n {
            let t = if i == 1 {
                1.0 - 0.5 * kpb
            } else {
                (i as Real * (1.0 - 0.5 * kpb).acos()).cos()
            };
            f += c[i] * t;
            df += dc[i] * t;
        }
        if (f - 1.0).abs() < 1e-3 {
            break;
        }
        sigma -= (f - 1.0) / df;
    }
    Ok(c)
}

/// Smoothing stencils in compressed rows: `edges[offsets[v] .. offsets[v] + counts[v]]`.
struct Stencils {
    offsets: Vec<usize>,
    edges: Vec<u32>,
    counts: Vec<usize>,
}

/// VTK stores stencil sizes in a byte and fixes vertices with ≥ 2·255 incident edge uses.
const MAX_STENCIL: usize = 255;

impl Stencils {
    fn build(mesh: &TriMesh, params: &SincParams) -> Self {
        let n = mesh.vertices().len();
        let tris = mesh.triangles();
        let mut offsets = vec![0usize; n + 1];
        for t in tris {
            for &v in t {
                offsets[v as usize + 1] += 2;
            }
        }
        for v in 0..n {
            offsets[v + 1] += offsets[v];
        }
        let mut cursor = offsets[..n].to_vec();
        let mut edges = vec![0u32; offsets[n]];
        for &[a, b, c] in tris {
            for (v, p, q) in [(a, c, b), (b, a, c), (c, b, a)] {
                let at = &mut cursor[v as usize];
                edges[*at] = p;
                edges[*at + 1] = q;
                *at += 2;
            }
        }
        // One mutable slice per vertex, analysed in parallel.
        let mut segments: Vec<&mut [u32]> = Vec::with_capacity(n);
        let mut rest = edges.as_mut_slice();
        for v in 0..n {
            let (head, tail) = rest.split_at_mut(offsets[v + 1] - offsets[v]);
            segments.push(head);
            rest = tail;
        }
        let points = mesh.vertices();
        let cos_edge = params.edge_angle_deg.to_radians().cos();
        let counts = segments
            .into_par_iter()
            .enumerate()
            .map(|(v, seg)| {
                seg.sort_unstable();
                let count = if seg.is_empty() || seg.len() >= 2 * MAX_STENCIL {
                    0
                } else if params.boundary_smoothing || params.non_manifold_smoothing {
                    edge_aware_stencil(v, seg, params, cos_edge, points)
                } else {
                    manifold_stencil(seg)
                };
                if count > MAX_STENCIL { 0 } else { count }
            })
            .collect();
        Self {
            offsets,
            edges,
            counts,
        }
    }

    #[inline]
    fn of(&self, v: usize) -> &[u32] {
        &self.edges[self.offsets[v]..self.offsets[v] + self.counts[v]]
    }
}

/// Closed-manifold neighbourhood (every edge used exactly twice): distinct neighbours moved to
/// the front; otherwise fixed (0).
fn manifold_stencil(seg: &mut [u32]) -> usize {
    if seg.len() % 2 == 1 {
        return 0;
    }
    let pairs = seg.len() / 2;
    let mut prev = None;
    for i in 0..pairs {
        let e = seg[2 * i];
        if seg[2 * i + 1] != e || prev == Some(e) {
            return 0;
        }
        prev = Some(e);
        seg[i] = e;
    }
    pairs
}

/// Boundary / non-manifold aware stencil (VTK's second analysis level); fixed = 0.
fn edge_aware_stencil(
    v: usize,
    seg: &mut [u32],
    params: &SincParams,
    cos_edge: Real,
    points: &[Vec3],
) -> usize {
    if seg.len() == 1 {
        return 0;
    }
    let weighted = params.non_manifold_smoothing && params.weight_non_manifold_edges;
    let (mut total, mut non_manifold) = (0usize, 0usize);
    let (mut boundary, mut boundaries) = ([0u32; 2], 0usize);
    let mut start = 0;
    while start < seg.len() {
        let e = seg[start];
        let mut end = start + 1;
        while end < seg.len() && seg[end] == e {
            end += 1;
        }
        let uses = end - start;
        if uses == 1 {
            if boundaries == 2 {
                return 0;
            }
            boundary[boundaries] = e;
            boundaries += 1;
        } else if uses > 2 {
            non_manifold += 1;
        }
        let copies = if weighted { uses } else { 1 };
        seg[total..total + copies].fill(e);
        total += copies;
        start = end;
    }
    match (&boundary[..boundaries], non_manifold) {
        ([], 0) => total,
        ([], _) if params.non_manifold_smoothing => total,
        (&[b0, b1], 0) => {
            let p = points[v];
            let l1 = unit_or_zero(p - points[b0 as usize]);
            let l2 = unit_or_zero(points[b1 as usize] - p);
            if l1.dot(&l2) < cos_edge {
                0
            } else {
                seg[0] = b0;
                seg[1] = b1;
                2
            }
        }
        _ => 0,
    }
}

fn unit_or_zero(v: Vec3) -> Vec3 {
    let n = v.norm();
    if n > 0.0 { v / n } else { v }
}

/// A position padded to four lanes (the last one 0), so the stencil sums vectorise.
type P4 = [Real; 4];

/// `x_v − mean(x_stencil)`, summed term by term as VTK does (every term divided by the stencil
/// size, in stencil order: VTK's result to the bit; the padding lane costs nothing extra).
#[inline]
fn neg_laplacian(x: &[P4], v: usize, stencil: &[u32]) -> P4 {
    let xv = x[v];
    let n = stencil.len() as Real;
    let mut d = [0.0; 4];
    for &j in stencil {
        let y = x[j as usize];
        for k in 0..4 {
            d[k] += (xv[k] - y[k]) / n;
        }
    }
    d
}

/// Bounding-box centre and diagonal of all vertices (used or not, as VTK's `GetLength`).
fn normalization(mesh: &TriMesh) -> ([Real; 3], Real) {
    let mut lo = [Real::INFINITY; 3];
    let mut hi = [Real::NEG_INFINITY; 3];
    for p in mesh.vertices() {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let center = [0, 1, 2].map(|k| (lo[k] + hi[k]) / 2.0);
    let length = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<Real>().sqrt();
    if length > 0.0 && length.is_finite() {
        (center, length)
    } else {
        ([0.0; 3], 1.0)
    }
}

/// Windowed-sinc smoothing of `mesh`'s vertex positions (topology, vertex order and named
/// scalars kept; normals dropped). 0 iterations or a mesh without triangles: returned as is.
pub fn windowed_sinc(mesh: &TriMesh, params: &SincParams) -> Result<TriMesh, FilterError> {
    let c = sinc_coefficients(params)?;
    if params.iterations == 0 || mesh.triangles().is_empty() {
        return rebuild(mesh, mesh.vertices().to_vec());
    }
    let stencils = Stencils::build(mesh, params);
    let (center, length) = if params.normalize_coordinates {
        normalization(mesh)
    } else {
        ([0.0; 3], 1.0)
    };
    let mut x0: Vec<P4> = mesh
        .vertices()
        .par_iter()
        .map(|p| {
            let [x, y, z] = [0, 1, 2].map(|k| (p[k] - center[k]) / length);
            [x, y, z, 0.0]
        })
        .collect();
    let n = x0.len();
    let mut x1 = vec![[0.0; 4]; n];
    let mut x3 = vec![[0.0; 4]; n];
    // First step: x1 = (I − K/2) x0, accumulator x3 = c0 x0 + c1 x1.
    per_vertex(&mut x1, &mut x3, |v, x1v, x3v| {
        let d = neg_laplacian(&x0, v, stencils.of(v));
        let x = x0[v];
        for k in 0..4 {
            x1v[k] = x[k] - 0.5 * d[k];
            x3v[k] = c[0] * x[k] + c[1] * x1v[k];
        }
    });
    // Chebyshev recurrence x2 = 2(I − K/2) x1 − x0, accumulated with weight c_j.
    let mut x2 = vec![[0.0; 4]; n];
    for &cj in &c[2..] {
        per_vertex(&mut x2, &mut x3, |v, x2v, x3v| {
            let d = neg_laplacian(&x1, v, stencils.of(v));
            let (a, b) = (x1[v], x0[v]);
            for k in 0..4 {
                x2v[k] = a[k] - b[k] + a[k] - d[k];
                x3v[k] += cj * x2v[k];
            }
        });
        // (x0, x1, x2) ← (x1, x2, old x0)
        std::mem::swap(&mut x0, &mut x1);
        std::mem::swap(&mut x1, &mut x2);
    }
    let vertices = x3
        .into_par_iter()
        .map(|p| Vec3::new(p[0], p[1], p[2]) * length + Vec3::new(center[0], center[1], center[2]))
        .collect();
    rebuild(mesh, vertices)
}

/// Vertices per rayon task: large enough that scheduling costs little next to the work.
const CHUNK: usize = 4096;

/// `f(v, &mut out[v], &mut acc[v])` for every vertex, in parallel chunks.
fn per_vertex(out: &mut [P4], acc: &mut [P4], f: impl Fn(usize, &mut P4, &mut P4) + Sync) {
    out.par_chunks_mut(CHUNK)
        .zip(acc.par_chunks_mut(CHUNK))
        .enumerate()
        .for_each(|(c, (out, acc))| {
            for (i, (o, a)) in out.iter_mut().zip(acc).enumerate() {
                f(c * CHUNK + i, o, a);
            }
        });
}

/// `mesh`'s triangles and scalars on new vertex positions.
fn rebuild(mesh: &TriMesh, vertices: Vec<Vec3>) -> Result<TriMesh, FilterError> {
    let mut out = TriMesh::new(vertices, mesh.triangles().to_vec())?;
    for (name, values) in mesh.scalars() {
        out = out.with_scalars(name, values.clone())?;
    }
    Ok(out)
}
