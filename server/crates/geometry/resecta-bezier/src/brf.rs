//! BRF: brute-force evaluation (Eq. 8.1–8.2, Algorithm 3). Every Bernstein value, including its
//! binomial and powers, is recomputed for every sample and every control point.

use rayon::prelude::*;

use crate::basis::{bernstein, binomial, powi};
use crate::error::BezierError;
use crate::normals::finish_normals;
use crate::scalar::{BezierScalar, P3};
use crate::types::{ControlNet, Outputs, Resolution, SurfaceGrid, param};

/// Evaluates `net` on `resolution` by brute force into a new grid.
pub fn evaluate_brf<T: BezierScalar>(
    net: &ControlNet<T>,
    resolution: Resolution,
    outputs: Outputs,
) -> SurfaceGrid<T> {
    let mut grid = SurfaceGrid::zeroed(resolution, outputs);
    brf_into(net, &mut grid);
    grid
}

/// Brute-force evaluation into `grid` (its resolution and outputs are used as given).
pub fn brf_into<T: BezierScalar>(net: &ControlNet<T>, grid: &mut SurfaceGrid<T>) {
    let res = grid.resolution();
    let (m, n) = net.dims();
    let rv = res.rv();
    let pts = net.points();
    let (points, du, dv, normals) = grid.parts_mut();
    points.par_chunks_mut(rv).enumerate().for_each(|(a, row)| {
        let u: T = param(a, res.ru());
        for (b, out) in row.iter_mut().enumerate() {
            let v: T = param(b, rv);
            let mut s = [T::ZERO; 3];
            for k in 0..m {
                // Algorithm 3, line 7: C(m,k) u^k (1−u)^(m−k) recomputed per control point.
                let bu = T::from_f64(binomial(m - 1, k) as f64)
                    * powi(u, k)
                    * powi(T::ONE - u, m - 1 - k);
                for l in 0..n {
                    let bv = T::from_f64(binomial(n - 1, l) as f64)
                        * powi(v, l)
                        * powi(T::ONE - v, n - 1 - l);
                    let w = bu * bv;
                    let p = pts[k * n + l];
                    s[0] += p[0] * w;
                    s[1] += p[1] * w;
                    s[2] += p[2] * w;
                }
            }
            *out = s;
        }
    });
    if let (Some(du), Some(dv)) = (du, dv) {
        let dnu = net.diff_u();
        let dnv = net.diff_v();
        brute_tensor(&dnu, m - 1, n, res, du);
        brute_tensor(&dnv, m, n - 1, res, dv);
        if let Some(normals) = normals {
            finish_normals(net, res, du, dv, normals);
        }
    }
}

/// Brute-force tensor product of an `mm × nn` array with Bernstein bases of degree mm−1, nn−1.
fn brute_tensor<T: BezierScalar>(
    arr: &[P3<T>],
    mm: usize,
    nn: usize,
    res: Resolution,
    out: &mut [P3<T>],
) {
    let rv = res.rv();
    out.par_chunks_mut(rv).enumerate().for_each(|(a, row)| {
        let u: T = param(a, res.ru());
        for (b, o) in row.iter_mut().enumerate() {
            let v: T = param(b, rv);
            let mut s = [T::ZERO; 3];
            for k in 0..mm {
                let bu = bernstein(mm - 1, k, u);
                for l in 0..nn {
                    let w = bu * bernstein(nn - 1, l, v);
                    let p = arr[k * nn + l];
                    s[0] += p[0] * w;
                    s[1] += p[1] * w;
                    s[2] += p[2] * w;
                }
            }
            *o = s;
        }
    });
}

/// Checks a caller buffer length (helper shared by the evaluators).
pub(crate) fn check_len(expected: usize, got: usize) -> Result<(), BezierError> {
    if expected == got {
        Ok(())
    } else {
        Err(BezierError::BufferLength { expected, got })
    }
}
