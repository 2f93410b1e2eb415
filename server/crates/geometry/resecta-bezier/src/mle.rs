//! MLE: multi-level evaluation (Sec. 8.4). Level 3 = binomials (per grid size), level 2 =
//! Bernstein tables B^u (RU×M) and B^v (RV×N) (per resolution and grid size), level 1 =
//! the tensor product S = B^u·P·B^vᵀ (per control-point change), computed per coordinate as
//! Q = P·B^vᵀ (M×RV, stored interleaved x,y,z so Q's rows match the AoS output rows) followed
//! by S = B^u·Q, one contiguous multiply-add sweep over each output row, rows in parallel.

use std::ops::Range;

use rayon::prelude::*;

use crate::basis::{bernstein_table, binomial_row};
use crate::brf::check_len;
use crate::error::BezierError;
use crate::normals::finish_normals;
use crate::scalar::{BezierScalar, P3};
use crate::types::{ControlNet, Outputs, Resolution, SurfaceGrid};

/// How often each level has been computed since construction (for tests and profiling).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MleCounters {
    /// Binomial rows (level 3) computed.
    pub level3: u64,
    /// Bernstein tables B^u, B^v (level 2) computed.
    pub level2: u64,
    /// Degree-reduced tables for derivatives (level 2 of ∂S/∂u, ∂S/∂v) computed.
    pub level2_derivative: u64,
    /// Surface evaluations (level 1) run.
    pub level1: u64,
}

#[derive(Debug, Clone)]
struct Level3 {
    u: Vec<u64>,
    v: Vec<u64>,
    du: Vec<u64>,
    dv: Vec<u64>,
}

#[derive(Debug, Clone)]
struct Level2<T> {
    u: Vec<T>,
    v: Vec<T>,
}

/// Stateful multi-level evaluator. Setters invalidate only what they affect:
/// [`set_control_points`](Self::set_control_points) (requirement A) keeps levels 2 and 3,
/// [`set_resolution`](Self::set_resolution) (B) drops level 2, [`set_net`](Self::set_net)
/// with new M×N (C) drops levels 2 and 3. Levels are rebuilt lazily on the next evaluation.
#[derive(Debug, Clone)]
pub struct MleEvaluator<T> {
    net: ControlNet<T>,
    resolution: Resolution,
    level3: Option<Level3>,
    level2: Option<Level2<T>>,
    level2_d: Option<Level2<T>>,
    q: Vec<T>,
    d: Vec<T>,
    counters: MleCounters,
}

impl<T: BezierScalar> MleEvaluator<T> {
    /// Evaluator for `net` sampled at `resolution`; nothing is computed yet.
    pub fn new(net: ControlNet<T>, resolution: Resolution) -> Self {
        Self {
            net,
            resolution,
            level3: None,
            level2: None,
            level2_d: None,
            q: Vec::new(),
            d: Vec::new(),
            counters: MleCounters::default(),
        }
    }
    /// Current control net.
    pub fn net(&self) -> &ControlNet<T> {
        &self.net
    }
    /// Current resolution.
    pub fn resolution(&self) -> Resolution {
        self.resolution
    }
    /// Level computation counts.
    pub fn counters(&self) -> MleCounters {
        self.counters
    }
    /// Requirement A: new coordinates for the same M×N; levels 2 and 3 stay valid.
    pub fn set_control_points(&mut self, points: &[P3<T>]) -> Result<(), BezierError> {
        self.net.set_points(points)
    }
    /// Requirement A for one point.
    pub fn set_control_point(&mut self, i: usize, j: usize, p: P3<T>) -> Result<(), BezierError> {
        self.net.set(i, j, p)
    }
    /// Requirement B: a new resolution drops level 2 (level 3 kept).
    pub fn set_resolution(&mut self, resolution: Resolution) {
        if resolution != self.resolution {
            self.resolution = resolution;
            self.level2 = None;
            self.level2_d = None;
        }
    }
    /// Requirement C: a net of another M×N drops levels 3 and 2; same M×N acts like A.
    pub fn set_net(&mut self, net: ControlNet<T>) {
        if net.dims() != self.net.dims() {
            self.level3 = None;
            self.level2 = None;
            self.level2_d = None;
        }
        self.net = net;
    }

    fn ensure_levels(&mut self, derivatives: bool) {
        let (m, n) = self.net.dims();
        if self.level3.is_none() {
            self.counters.level3 += 1;
            let u = binomial_row(m);
            // Copy on isotropy (Algorithm 6).
            let v = if m == n { u.clone() } else { binomial_row(n) };
            let du = binomial_row(m - 1);
            let dv = if m == n {
                du.clone()
            } else {
                binomial_row(n - 1)
            };
            self.level3 = Some(Level3 { u, v, du, dv });
        }
        let Some(l3) = &self.level3 else { return };
        let (ru, rv) = (self.resolution.ru(), self.resolution.rv());
        let iso = m == n && ru == rv;
        // Copy on isotropy (Algorithm 5).
        let tables = |bu: &[u64], bv: &[u64]| {
            let u = bernstein_table(bu, ru);
            let v = if iso {
                u.clone()
            } else {
                bernstein_table(bv, rv)
            };
            Level2 { u, v }
        };
        if self.level2.is_none() {
            self.counters.level2 += 1;
            self.level2 = Some(tables(&l3.u, &l3.v));
        }
        if derivatives && self.level2_d.is_none() {
            self.counters.level2_derivative += 1;
            self.level2_d = Some(tables(&l3.du, &l3.dv));
        }
    }

    /// Level 2 tables (B^u as RU×M, B^v as RV×N, row-major), computing them if needed. For
    /// external level-1 implementations such as the GPU path.
    pub fn basis_tables(&mut self) -> (&[T], &[T]) {
        self.ensure_levels(false);
        match &self.level2 {
            Some(l2) => (&l2.u, &l2.v),
            None => (&[], &[]),
        }
    }

    /// Evaluates into a new grid.
    pub fn evaluate(&mut self, outputs: Outputs) -> SurfaceGrid<T> {
        let mut grid = SurfaceGrid::zeroed(self.resolution, outputs);
        self.fill(&mut grid);
        grid
    }

    /// Evaluates into `grid` without allocating (after the first call); fills every array the
    /// grid holds. The grid's resolution must be the evaluator's.
    pub fn evaluate_into(&mut self, grid: &mut SurfaceGrid<T>) -> Result<(), BezierError> {
        if grid.resolution() != self.resolution {
            return Err(BezierError::BufferLength {
                expected: self.resolution.len(),
                got: grid.resolution().len(),
            });
        }
        self.fill(grid);
        Ok(())
    }

    fn fill(&mut self, grid: &mut SurfaceGrid<T>) {
        let want_d = grid.outputs() >= Outputs::Derivatives;
        self.ensure_levels(want_d);
        let (points, du, dv, normals) = grid.parts_mut();
        self.points_aos(points);
        if let (Some(du), Some(dv), Some(l2), Some(l2d)) = (du, dv, &self.level2, &self.level2_d) {
            let (m, n) = self.net.dims();
            let rv = self.resolution.rv();
            tensor_aos(
                &l2d.u,
                &self.net.diff_u(),
                m - 1,
                n,
                &l2.v,
                rv,
                &mut self.q,
                &mut self.d,
                du,
            );
            tensor_aos(
                &l2.u,
                &self.net.diff_v(),
                m,
                n - 1,
                &l2d.v,
                rv,
                &mut self.q,
                &mut self.d,
                dv,
            );
            if let Some(normals) = normals {
                finish_normals(&self.net, self.resolution, du, dv, normals);
            }
        }
    }

    /// Surface points only, into a caller buffer of RU·RV points (index `a·RV + b`); no
    /// allocation once the scratch is sized.
    pub fn evaluate_points_into(&mut self, out: &mut [P3<T>]) -> Result<(), BezierError> {
        check_len(self.resolution.len(), out.len())?;
        self.ensure_levels(false);
        self.points_aos(out);
        Ok(())
    }

    /// Surface points in structure-of-arrays form (separate x, y, z buffers of RU·RV each).
    pub fn evaluate_points_soa_into(
        &mut self,
        x: &mut [T],
        y: &mut [T],
        z: &mut [T],
    ) -> Result<(), BezierError> {
        let len = self.resolution.len();
        check_len(len, x.len())?;
        check_len(len, y.len())?;
        check_len(len, z.len())?;
        self.ensure_levels(false);
        self.counters.level1 += 1;
        let Some(l2) = &self.level2 else {
            return Ok(());
        };
        let (m, n) = self.net.dims();
        let rv = self.resolution.rv();
        let pts = self.net.points();
        self.q.resize(3 * m * rv, T::ZERO);
        // Q_c = P_c · B^vᵀ per coordinate, layout [c][i][b].
        for (c, qc) in self.q.chunks_exact_mut(m * rv).enumerate() {
            for (i, qrow) in qc.chunks_exact_mut(rv).enumerate() {
                for (b, q) in qrow.iter_mut().enumerate() {
                    let bv = &l2.v[b * n..(b + 1) * n];
                    let mut s = T::ZERO;
                    for j in 0..n {
                        s += pts[i * n + j][c] * bv[j];
                    }
                    *q = s;
                }
            }
        }
        let ru = self.resolution.ru();
        for (c, out) in [x, y, z].into_iter().enumerate() {
            let qc = &self.q[c * m * rv..(c + 1) * m * rv];
            q_differences(qc, m, rv, &mut self.d);
            rows_from_q(&l2.u, m, qc, rv, &self.d, 0, ru, out);
        }
        Ok(())
    }

    /// Level 1 in two steps, for callers that split the rows (CPU–GPU cooperation): computes
    /// Q = P·B^vᵀ for the current control points (levels 3 and 2 as needed). Call once per
    /// control-point update, then [`MleEvaluator::rows_into`] for any row ranges.
    pub fn prepare_rows(&mut self) {
        self.ensure_levels(false);
        self.counters.level1 += 1;
        let (m, n) = self.net.dims();
        let rv = self.resolution.rv();
        if let Some(l2) = &self.level2 {
            partial_sums(self.net.points(), m, n, &l2.v, rv, &mut self.q);
            q_differences(&self.q, m, 3 * rv, &mut self.d);
        }
    }

    /// Rows `rows` of the surface (`rows.len()·RV` points) from the Q of the last
    /// [`MleEvaluator::prepare_rows`]; shared access, so disjoint ranges can run concurrently.
    pub fn rows_into(&self, rows: Range<usize>, out: &mut [P3<T>]) -> Result<(), BezierError> {
        let (m, _) = self.net.dims();
        let (ru, rv) = (self.resolution.ru(), self.resolution.rv());
        let w = 3 * rv;
        check_len(rows.len() * rv, out.len())?;
        let Some(l2) = self
            .level2
            .as_ref()
            .filter(|_| self.q.len() == m * w && rows.end <= ru)
        else {
            return Err(BezierError::BufferLength {
                expected: rows.len() * rv,
                got: out.len(),
            });
        };
        rows_from_q(
            &l2.u,
            m,
            &self.q,
            w,
            &self.d,
            rows.start,
            ru,
            out.as_flattened_mut(),
        );
        Ok(())
    }

    fn points_aos(&mut self, out: &mut [P3<T>]) {
        self.counters.level1 += 1;
        if let Some(l2) = &self.level2 {
            let (m, n) = self.net.dims();
            tensor_aos(
                &l2.u,
                self.net.points(),
                m,
                n,
                &l2.v,
                self.resolution.rv(),
                &mut self.q,
                &mut self.d,
                out,
            );
        }
    }
}

/// Level 1 for an `mm×nn` array `arr` with bases `bu` (RU×mm) and `bv` (RV×nn): first
/// Q = arr·B^vᵀ interleaved as `q[i][3b + c]`, then each output row `a` is `Σᵢ B^u[a,i]·Q[i]`.
fn tensor_aos<T: BezierScalar>(
    bu: &[T],
    arr: &[P3<T>],
    mm: usize,
    nn: usize,
    bv: &[T],
    rv: usize,
    q: &mut Vec<T>,
    d: &mut Vec<T>,
    out: &mut [P3<T>],
) {
    partial_sums(arr, mm, nn, bv, rv, q);
    let w = 3 * rv;
    q_differences(q, mm, w, d);
    let ru = out.len() / rv;
    rows_from_q(bu, mm, q, w, d, 0, ru, out.as_flattened_mut());
}

/// Q = arr·B^vᵀ (`mm` rows of RV points, xyz interleaved), rows in parallel when large.
fn partial_sums<T: BezierScalar>(
    arr: &[P3<T>],
    mm: usize,
    nn: usize,
    bv: &[T],
    rv: usize,
    q: &mut Vec<T>,
) {
    let w = 3 * rv;
    q.resize(mm * w, T::ZERO);
    let fill_q = |(i, qrow): (usize, &mut [T])| {
        let prow = &arr[i * nn..(i + 1) * nn];
        for (qb, bvb) in qrow.chunks_exact_mut(3).zip(bv.chunks_exact(nn)) {
            let mut s = [T::ZERO; 3];
            for (p, &w) in prow.iter().zip(bvb) {
                s[0] += p[0] * w;
                s[1] += p[1] * w;
                s[2] += p[2] * w;
            }
            qb.copy_from_slice(&s);
        }
    };
    if mm * nn * rv >= 1 << 16 {
        q.par_chunks_exact_mut(w).enumerate().for_each(fill_q);
    } else {
        q.chunks_exact_mut(w).enumerate().for_each(fill_q);
    }
}

/// `d = [Q_i − Q_0 for i = 1..mm] ++ [Q_i − Q_last for i = 0..last]` (see [`rows_from_q`]).
fn q_differences<T: BezierScalar>(q: &[T], mm: usize, w: usize, d: &mut Vec<T>) {
    let last = mm - 1;
    d.resize(2 * last * w, T::ZERO);
    let (d0, d1) = d.split_at_mut(last * w);
    let q0 = &q[..w];
    let ql = &q[last * w..mm * w];
    for (i, dr) in d0.chunks_exact_mut(w).enumerate() {
        for ((o, &x), &b) in dr.iter_mut().zip(&q[(i + 1) * w..(i + 2) * w]).zip(q0) {
            *o = x - b;
        }
    }
    for (i, dr) in d1.chunks_exact_mut(w).enumerate() {
        for ((o, &x), &b) in dr.iter_mut().zip(&q[i * w..(i + 1) * w]).zip(ql) {
            *o = x - b;
        }
    }
}

/// Rows `first..first + out.len()/w` of a surface of `ru` rows:
/// `out[a] = Σᵢ bu[a·mm + i] · q[i·w .. (i+1)·w]`, rows in parallel.
///
/// Uses the partition of unity Σᵢ B_i = 1 to save one multiply per value: rows with u < ½ are
/// `Q₀ + Σ_{i≥1} B_i (Q_i − Q₀)`, rows with u ≥ ½ are `Q_last + Σ_{i<last} B_i (Q_i − Q_last)`
/// (differences `d` from [`q_differences`]). At u = 0 and u = 1 all other weights are exactly
/// zero, so borders stay exact. Blocks of up to four terms per sweep keep each value stored once
/// per block; the inner loops are contiguous and vectorise.
fn rows_from_q<T: BezierScalar>(
    bu: &[T],
    mm: usize,
    q: &[T],
    w: usize,
    d: &[T],
    first: usize,
    ru: usize,
    out: &mut [T],
) {
    let last = mm - 1;
    let (d0, d1) = d.split_at(last * w);
    let q0 = &q[..w];
    let ql = &q[last * w..mm * w];
    out.par_chunks_exact_mut(w)
        .with_min_len(4)
        .enumerate()
        .for_each(|(local, row)| {
            let a = first + local;
            let b = &bu[a * mm..(a + 1) * mm];
            let (base, diffs, weights) = if 2 * a < ru {
                (q0, d0, &b[1..])
            } else {
                (ql, d1, &b[..last])
            };
            // First sweep writes base + up to three terms, later sweeps add up to four.
            let k = last.min(3);
            sweep_init(row, base, diffs, w, &weights[..k]);
            let mut i = k;
            while i < last {
                let k = (last - i).min(4);
                sweep(row, diffs, w, &weights[i..i + k], i);
                i += k;
            }
        });
}

/// `row = base + Σ_k b[k] · q[k·w ..]` for up to three terms (one store per value).
#[inline(always)]
fn sweep_init<T: BezierScalar>(row: &mut [T], base: &[T], q: &[T], w: usize, b: &[T]) {
    let qr = |k: usize| &q[k * w..(k + 1) * w];
    match *b {
        [b0, b1, b2] => {
            let (q0, q1, q2) = (qr(0), qr(1), qr(2));
            for ((((o, &y), &x0), &x1), &x2) in row.iter_mut().zip(base).zip(q0).zip(q1).zip(q2) {
                *o = y + b0 * x0 + b1 * x1 + b2 * x2;
            }
        }
        [b0, b1] => {
            let (q0, q1) = (qr(0), qr(1));
            for (((o, &y), &x0), &x1) in row.iter_mut().zip(base).zip(q0).zip(q1) {
                *o = y + b0 * x0 + b1 * x1;
            }
        }
        [b0] => {
            for ((o, &y), &x0) in row.iter_mut().zip(base).zip(qr(0)) {
                *o = y + b0 * x0;
            }
        }
        _ => row.copy_from_slice(base),
    }
}

/// `row += Σ_k b[k] · q[(i+k)·w ..]` for up to four terms.
#[inline(always)]
fn sweep<T: BezierScalar>(row: &mut [T], q: &[T], w: usize, b: &[T], i: usize) {
    let qr = |k: usize| &q[(i + k) * w..(i + k + 1) * w];
    match *b {
        [b0, b1, b2, b3] => {
            let (q0, q1, q2, q3) = (qr(0), qr(1), qr(2), qr(3));
            for ((((o, &x0), &x1), &x2), &x3) in row.iter_mut().zip(q0).zip(q1).zip(q2).zip(q3) {
                *o += b0 * x0 + b1 * x1 + b2 * x2 + b3 * x3;
            }
        }
        [b0, b1, b2] => {
            let (q0, q1, q2) = (qr(0), qr(1), qr(2));
            for (((o, &x0), &x1), &x2) in row.iter_mut().zip(q0).zip(q1).zip(q2) {
                *o += b0 * x0 + b1 * x1 + b2 * x2;
            }
        }
        [b0, b1] => {
            let (q0, q1) = (qr(0), qr(1));
            for ((o, &x0), &x1) in row.iter_mut().zip(q0).zip(q1) {
                *o += b0 * x0 + b1 * x1;
            }
        }
        [b0] => {
            for (o, &x0) in row.iter_mut().zip(qr(0)) {
                *o += b0 * x0;
            }
        }
        _ => {}
    }
}
