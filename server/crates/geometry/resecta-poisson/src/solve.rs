//! The screened Poisson problem on a dense vertex-centred grid, and its solution field.
//!
//! **Domain.** Depth `d` as in Kazhdan's PoissonRecon: a cube of side `scale ×` the largest side
//! of the points' bounding box, centred on the box, cut into `2^d` cells per axis; the unknowns are
//! the `(2^d + 1)³` nodes (cell `h`), `χ` is trilinear (Q1) between them.
//!
//! **Discretisation.** Minimise `∫|∇χ − V|² + (α/h)·Σᵢ aᵢ χ(pᵢ)²` where `V = Σᵢ aᵢ(−nᵢ)δ(· − pᵢ)`
//! is the inward normal field (so `χ` jumps by 1 across the surface and is larger inside) and `aᵢ`
//! the sample areas. `V` is splatted to the nodes with trilinear weights and read as a Q1 field,
//! giving the exact, separable Galerkin right-hand side `bⱼ = ∫V·∇φⱼ` (a 4×4×4 stencil per
//! sample); the stiffness is the 7-point graph Laplacian with free (Neumann) boundaries; the
//! screening term is lumped to the diagonal `α·Wⱼ`, `Wⱼ = Σᵢ (aᵢ/h²) φⱼ(pᵢ)`. Screening pins the
//! field (≈ 0 on the samples, ≈ ½ inside, ≈ −½ outside) and makes the system positive definite.
//! Everything is in finest-cell units, so `α` acts the same at every depth.
//!
//! **Solver.** A [`MultigridSolver`] (the CPU's by default): full multigrid from 2³ nodes up, then V-cycles at the finest level until the
//! relative residual `|b − Aχ|/|b|` is at most `tolerance`: red–black Gauss–Seidel smoothing,
//! full-weighting restriction, trilinear prolongation, rediscretised coarse Laplacians
//! (coefficient doubling per level) and restricted screening weights, all in `f32`.
//!
//! **Iso-value.** The mean of `χ` at the samples (thesis Eq. 6.8).

use std::time::Instant;

use rayon::prelude::*;
use resecta_geom::{Mat4, Real, Vec3};

use crate::error::PoissonError;
use crate::multigrid::{hierarchy_bytes, restrict};
use crate::points::{MIN_POINTS, OrientedPoints};
use crate::system::{CpuMultigrid, MultigridSolver, System, SystemLevel};

/// Largest depth accepted (a dense depth-10 grid needs ~20 GB and is refused by the budget).
pub const MAX_DEPTH: u32 = 10;

/// Solver parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct PoissonParams {
    /// Finest grid: `2^depth` cells across the bounding cube; `1..=10`.
    pub depth: u32,
    /// Bounding cube side over the points' largest bounding-box side (≥ 1; PoissonRecon: 1.1).
    pub scale: Real,
    /// Screening weight `α` (> 0), relative to the gradient term in finest-cell units. Default 4,
    /// as PoissonRecon's point weight: on the real livers of the reconstruction benchmark, 4
    /// against 0.25 lowers the mean distance by 8–11 % and halves the volume loss at d = 7
    /// (docs/reconstruction.md).
    pub screening: Real,
    /// Memory budget in bytes, checked before anything is allocated (default 2 GiB).
    pub max_bytes: u64,
    /// Stop when the relative residual `|b − Aχ|/|b|` is at most this (> 0). Full multigrid alone
    /// reaches ~2.5e-2 and the default 3e-3 takes one more V-cycle; on spheres, iso-surface radii
    /// and volumes agree with a 1e-4 solve to 0.001 mm and 0.002 %.
    pub tolerance: Real,
    /// Most V-cycles after full multigrid.
    pub max_cycles: u32,
    /// Gauss–Seidel sweeps before and after each coarse correction (≥ 1).
    pub sweeps: u32,
}

impl Default for PoissonParams {
    fn default() -> Self {
        Self {
            depth: 7,
            scale: 1.1,
            screening: 4.0,
            max_bytes: 2 << 30,
            tolerance: 3e-3,
            max_cycles: 20,
            sweeps: 2,
        }
    }
}

/// How the solve went.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SolveReport {
    /// V-cycles after full multigrid.
    pub cycles: u32,
    /// Where the multigrid ran ([`MultigridSolver::backend`]).
    pub backend: &'static str,
    /// Relative residual after full multigrid and after each further V-cycle.
    pub residuals: Vec<Real>,
    /// Wall-clock seconds: splatting the samples, multigrid, iso-value.
    pub splat_s: Real,
    pub solve_s: Real,
    pub iso_s: Real,
}

/// The indicator field on the finest grid: larger inside, the surface is `value == iso`.
#[derive(Debug, Clone, PartialEq)]
pub struct PoissonField {
    /// Nodes per axis (`2^depth + 1` each).
    pub dims: [usize; 3],
    /// RAS mm of node (0, 0, 0); node `(i, j, k)` is at `origin + cell·(i, j, k)`.
    pub origin: Vec3,
    /// Node spacing in mm.
    pub cell: Real,
    /// `values[i + dims[0]·(j + dims[1]·k)]`; inside where `value > iso`.
    pub values: Vec<f32>,
    pub iso: f32,
    pub report: SolveReport,
}

impl PoissonField {
    /// Trilinear value at `p` (RAS mm), `None` outside the grid.
    pub fn value_at(&self, p: Vec3) -> Option<f32> {
        let u = (p - self.origin) / self.cell;
        trilinear(&self.values, self.dims, u)
    }

    /// Node index → RAS affine.
    pub fn index_to_ras(&self) -> Mat4 {
        let mut m = Mat4::identity();
        for a in 0..3 {
            m[(a, a)] = self.cell;
            m[(a, 3)] = self.origin[a];
        }
        m
    }
}

fn trilinear(values: &[f32], dims: [usize; 3], u: Vec3) -> Option<f32> {
    let mut c = [0usize; 3];
    let mut f = [0f32; 3];
    for a in 0..3 {
        let hi = (dims[a] - 1) as Real;
        if !(u[a] >= 0.0 && u[a] <= hi) || dims[a] < 2 {
            return None;
        }
        let ca = (u[a].floor() as usize).min(dims[a] - 2);
        c[a] = ca;
        f[a] = (u[a] - ca as Real) as f32;
    }
    let idx = |i: usize, j: usize, k: usize| i + dims[0] * (j + dims[1] * k);
    let mut v = 0.0f32;
    for dz in 0..2 {
        let wz = if dz == 0 { 1.0 - f[2] } else { f[2] };
        for dy in 0..2 {
            let wy = if dy == 0 { 1.0 - f[1] } else { f[1] };
            let o = idx(c[0], c[1] + dy, c[2] + dz);
            v += wz * wy * ((1.0 - f[0]) * values[o] + f[0] * values[o + 1]);
        }
    }
    Some(v)
}

/// Bytes [`solve`] allocates for `points` samples at `depth` (the grid hierarchy, four `f32`
/// arrays per node, plus 32 bytes per sample).
pub fn bytes_needed(depth: u32, points: usize) -> u64 {
    hierarchy_bytes(depth) + 32 * points as u64
}

fn check_params(p: &PoissonParams) -> Result<(), PoissonError> {
    if !(1..=MAX_DEPTH).contains(&p.depth) {
        return Err(PoissonError::DepthOutOfRange { depth: p.depth });
    }
    let bad = |name, value, expected| PoissonError::BadParameter {
        name,
        value,
        expected,
    };
    if !(p.scale.is_finite() && p.scale >= 1.0) {
        return Err(bad("scale", p.scale, "a finite number ≥ 1"));
    }
    if !(p.screening.is_finite() && p.screening > 0.0) {
        return Err(bad("screening", p.screening, "a finite number > 0"));
    }
    if !(p.tolerance.is_finite() && p.tolerance > 0.0) {
        return Err(bad("tolerance", p.tolerance, "a finite number > 0"));
    }
    if p.sweeps == 0 {
        return Err(bad("sweeps", 0.0, "at least 1"));
    }
    Ok(())
}

/// One sample in finest-grid coordinates.
#[derive(Debug, Clone, Copy)]
struct Sample {
    /// Cell (lower node) per axis, `0..2^d`.
    c: [usize; 3],
    /// Fraction within the cell.
    f: [f32; 3],
    /// Inward normal × area / h².
    v: [f32; 3],
    /// Area / h².
    w: f32,
}

/// Galerkin 1D tables over nodes `c − 1 … c + 2` of a sample at fraction `f` of cell `c`:
/// `d[t] = Σₖ wₖ ∫φₖ φ′ₜ` and `m[t] = Σₖ wₖ ∫φₖ φₜ / h` (`wₖ` the linear splat weights).
#[inline]
fn tables(f: f32) -> ([f32; 4], [f32; 4]) {
    let g = 1.0 - f;
    (
        [-0.5 * g, -0.5 * f, 0.5 * g, 0.5 * f],
        [
            g / 6.0,
            2.0 * g / 3.0 + f / 6.0,
            g / 6.0 + 2.0 * f / 3.0,
            f / 6.0,
        ],
    )
}

/// Screened Poisson indicator field of `points` (see the module docs of this crate's solver),
/// solved on the CPU ([`CpuMultigrid`]).
pub fn solve(
    points: &OrientedPoints,
    params: &PoissonParams,
) -> Result<PoissonField, PoissonError> {
    solve_with(points, params, &CpuMultigrid)
}

/// [`solve`] with the multigrid run by `solver`: the same system, assembled here, and the same
/// iso-value; only the solve differs.
pub fn solve_with(
    points: &OrientedPoints,
    params: &PoissonParams,
    solver: &dyn MultigridSolver,
) -> Result<PoissonField, PoissonError> {
    check_params(params)?;
    let np = points.positions.len();
    if points.normals.len() != np || points.areas.len() != np {
        return Err(PoissonError::LengthMismatch {
            positions: np,
            normals: points.normals.len(),
            areas: points.areas.len(),
        });
    }
    if np < MIN_POINTS {
        return Err(PoissonError::TooFewPoints {
            found: np,
            needed: MIN_POINTS,
        });
    }
    let depth = params.depth;
    let needed = bytes_needed(depth, np);
    if needed > params.max_bytes {
        return Err(PoissonError::MemoryBudget {
            depth,
            needed,
            limit: params.max_bytes,
        });
    }
    let mut lo = Vec3::repeat(Real::INFINITY);
    let mut hi = Vec3::repeat(Real::NEG_INFINITY);
    for (index, ((p, n), a)) in points
        .positions
        .iter()
        .zip(&points.normals)
        .zip(&points.areas)
        .enumerate()
    {
        let finite = p.iter().chain(n.iter()).all(|v| v.is_finite());
        if !finite || !a.is_finite() || *a <= 0.0 || n.norm() == 0.0 {
            return Err(PoissonError::BadSample { index });
        }
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let extent = (hi - lo).max();
    if extent <= 1e-9 * (1.0 + lo.abs().max()) {
        return Err(PoissonError::DegenerateBounds { extent_mm: extent });
    }
    let cells = 1usize << depth;
    let side = extent * params.scale;
    let h = side / cells as Real;
    let origin = (lo + hi) / 2.0 - Vec3::repeat(side / 2.0);
    let n = cells + 1;
    let plane = n * n;

    // Samples in grid units, bucketed by z-cell (stable counting sort: deterministic).
    let t0 = Instant::now();
    let samples: Vec<Sample> = (0..np)
        .into_par_iter()
        .map(|i| {
            let u = (points.positions[i] - origin) / h;
            let mut c = [0usize; 3];
            let mut f = [0f32; 3];
            for a in 0..3 {
                let ca = u[a].floor().clamp(0.0, (cells - 1) as Real);
                c[a] = ca as usize;
                f[a] = (u[a] - ca).clamp(0.0, 1.0) as f32;
            }
            let w = points.areas[i] / (h * h);
            let nrm = points.normals[i] / points.normals[i].norm();
            Sample {
                c,
                f,
                v: [
                    (-nrm.x * w) as f32,
                    (-nrm.y * w) as f32,
                    (-nrm.z * w) as f32,
                ],
                w: w as f32,
            }
        })
        .collect();
    let mut start = vec![0usize; cells + 1];
    for s in &samples {
        start[s.c[2] + 1] += 1;
    }
    for z in 0..cells {
        start[z + 1] += start[z];
    }
    let mut fill = start.clone();
    let mut order = vec![0u32; np];
    for (i, s) in samples.iter().enumerate() {
        order[fill[s.c[2]]] = i as u32;
        fill[s.c[2]] += 1;
    }
    let bucket = |cz: usize| {
        order[start[cz]..start[cz + 1]]
            .iter()
            .map(|&i| &samples[i as usize])
    };

    // Right-hand side and screening weights, one node plane per task.
    let alpha = params.screening as f32;
    let mut b = vec![0f32; n * plane];
    let mut diag = vec![0f32; n * plane];
    b.par_chunks_mut(plane)
        .zip(diag.par_chunks_mut(plane))
        .enumerate()
        .for_each(|(k, (bp, dp))| {
            for cz in k.saturating_sub(2)..(k + 2).min(cells) {
                let t = k + 1 - cz;
                for s in bucket(cz) {
                    let (dx, mx) = tables(s.f[0]);
                    let (dy, my) = tables(s.f[1]);
                    let (dz, mz) = tables(s.f[2]);
                    for (ty, (dyv, myv)) in dy.iter().zip(&my).enumerate() {
                        let Some(j) = (s.c[1] + ty).checked_sub(1).filter(|&j| j < n) else {
                            continue;
                        };
                        let cyz = s.v[0] * myv * mz[t];
                        let rest = s.v[1] * dyv * mz[t] + s.v[2] * myv * dz[t];
                        for (tx, (dxv, mxv)) in dx.iter().zip(&mx).enumerate() {
                            if let Some(i) = (s.c[0] + tx).checked_sub(1).filter(|&i| i < n) {
                                bp[i + n * j] += cyz * dxv + mxv * rest;
                            }
                        }
                    }
                }
            }
            for cz in k.saturating_sub(1)..(k + 1).min(cells) {
                for s in bucket(cz) {
                    let lin = |a: usize, t: usize| if t == 0 { 1.0 - s.f[a] } else { s.f[a] };
                    let wz = alpha * s.w * lin(2, k - cz);
                    for ty in 0..2 {
                        let row = n * (s.c[1] + ty);
                        let wyz = wz * lin(1, ty);
                        dp[row + s.c[0]] += wyz * lin(0, 0);
                        dp[row + s.c[0] + 1] += wyz * lin(0, 1);
                    }
                }
            }
        });
    let splat_s = t0.elapsed().as_secs_f64();

    // Hierarchy, coarsest first: restricted right-hand sides and screening weights.
    let t1 = Instant::now();
    let mut levels: Vec<SystemLevel> = Vec::with_capacity(depth as usize + 1);
    let mut cur = SystemLevel {
        n,
        lap: 1.0,
        diag,
        b,
    };
    for l in (0..depth).rev() {
        let nc = (1usize << l) + 1;
        let len = nc * nc * nc;
        let mut next = SystemLevel {
            n: nc,
            lap: cur.lap * 2.0,
            diag: vec![0f32; len],
            b: vec![0f32; len],
        };
        restrict(&cur.diag, cur.n, &mut next.diag, nc);
        restrict(&cur.b, cur.n, &mut next.b, nc);
        levels.push(cur);
        cur = next;
    }
    levels.push(cur);
    levels.reverse();

    // Full multigrid, then V-cycles to tolerance, by the given solver.
    let solution = solver.solve(System { levels }, params)?;
    if solution.x.len() != n * plane {
        return Err(PoissonError::Backend {
            backend: solver.backend(),
            reason: format!(
                "{} values returned, {} expected",
                solution.x.len(),
                n * plane
            ),
        });
    }
    let mut report = SolveReport {
        cycles: solution.cycles,
        residuals: solution.residuals,
        backend: solver.backend(),
        ..SolveReport::default()
    };
    report.solve_s = t1.elapsed().as_secs_f64();
    let values = solution.x;

    // Iso-value: mean of the field at the samples, fixed-size chunks summed in order.
    let t2 = Instant::now();
    let dims = [n; 3];
    let sums: Vec<f64> = points
        .positions
        .par_chunks(4096)
        .map(|ch| {
            ch.iter()
                .map(|p| f64::from(trilinear(&values, dims, (p - origin) / h).unwrap_or(0.0)))
                .sum()
        })
        .collect();
    let iso = (sums.iter().sum::<f64>() / np as f64) as f32;
    report.iso_s = t2.elapsed().as_secs_f64();
    report.splat_s = splat_s;
    Ok(PoissonField {
        dims,
        origin,
        cell: h,
        values,
        iso,
        report,
    })
}
