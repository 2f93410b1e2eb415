//! MAT: matrix form (Eq. 8.3–8.4), `S(u,v) = U(u)·G·V(v)ᵀ` with `G = R(m)·P·R(n)ᵀ` per
//! coordinate, precomputed when the control points change; each sample is then a monomial
//! (power-basis) evaluation by Horner's rule in v and u.
//!
//! Numerical caveat: the power basis is ill-conditioned at high degree. `R(m)` has entries
//! `C(m,i)·C(m−i,k−i)·(−1)^(k−i)` whose absolute row sums reach 3^m, so `G` holds large
//! alternating coefficients that cancel near u, v = 1. The rounding error of a sample is bounded
//! by about `(m+n+2)·ε·Σ|G_kl|` ([`MatEvaluator::error_bound`]), which for 12×12 in f32 is no
//! longer small; prefer MLE/BRF (convex Bernstein weights, error ~ (m+n)·ε·max|P|) there.

use rayon::prelude::*;

use crate::basis::binomial;
use crate::normals::finish_normals;
use crate::scalar::{BezierScalar, P3};
use crate::types::{ControlNet, Outputs, Resolution, SurfaceGrid, param};

/// Power-basis coefficient matrix `R` of degree `count − 1`, as `r[k·count + i]` = coefficient of
/// `t^k` in `B_{i}(t)` (the thesis lists the same matrix with the powers descending).
pub fn power_basis_matrix<T: BezierScalar>(count: usize) -> Vec<T> {
    let d = count.saturating_sub(1);
    let mut r = vec![T::ZERO; count * count];
    for k in 0..count {
        for i in 0..=k {
            let mag = binomial(d, i) as f64 * binomial(d - i, k - i) as f64;
            let sign = if (k - i) % 2 == 0 { 1.0 } else { -1.0 };
            r[k * count + i] = T::from_f64(sign * mag);
        }
    }
    r
}

/// `G = R_u·A·R_vᵀ` for an `mm×nn` array `a`, as `mm×nn` coefficients of `u^k v^l`.
fn monomial_coeffs<T: BezierScalar>(a: &[P3<T>], mm: usize, nn: usize) -> Vec<P3<T>> {
    let ru = power_basis_matrix::<T>(mm);
    let rv = power_basis_matrix::<T>(nn);
    // tmp = R_u · A  (mm×nn)
    let mut tmp = vec![[T::ZERO; 3]; mm * nn];
    for k in 0..mm {
        for i in 0..mm {
            let r = ru[k * mm + i];
            for j in 0..nn {
                for c in 0..3 {
                    tmp[k * nn + j][c] += r * a[i * nn + j][c];
                }
            }
        }
    }
    // G = tmp · R_vᵀ
    let mut g = vec![[T::ZERO; 3]; mm * nn];
    for k in 0..mm {
        for l in 0..nn {
            for j in 0..nn {
                let r = rv[l * nn + j];
                for c in 0..3 {
                    g[k * nn + l][c] += tmp[k * nn + j][c] * r;
                }
            }
        }
    }
    g
}

/// Matrix-form evaluator: holds G (and the G of ∂S/∂u, ∂S/∂v), recomputed on every
/// control-point change.
#[derive(Debug, Clone)]
pub struct MatEvaluator<T> {
    net: ControlNet<T>,
    g: Vec<P3<T>>,
    g_du: Vec<P3<T>>,
    g_dv: Vec<P3<T>>,
}

impl<T: BezierScalar> MatEvaluator<T> {
    /// Precomputes G for `net`.
    pub fn new(net: ControlNet<T>) -> Self {
        let mut s = Self {
            net,
            g: Vec::new(),
            g_du: Vec::new(),
            g_dv: Vec::new(),
        };
        s.recompute();
        s
    }
    fn recompute(&mut self) {
        let (m, n) = self.net.dims();
        self.g = monomial_coeffs(self.net.points(), m, n);
        // Derivatives in power form: ∂/∂u of Σ u^k v^l G_kl.
        self.g_du = (0..(m - 1) * n)
            .map(|idx| {
                let (k, l) = (idx / n, idx % n);
                let f = T::from_f64((k + 1) as f64);
                self.g[(k + 1) * n + l].map(|c| c * f)
            })
            .collect();
        self.g_dv = (0..m * (n - 1))
            .map(|idx| {
                let (k, l) = (idx / (n - 1), idx % (n - 1));
                let f = T::from_f64((l + 1) as f64);
                self.g[k * n + l + 1].map(|c| c * f)
            })
            .collect();
    }
    /// The control net.
    pub fn net(&self) -> &ControlNet<T> {
        &self.net
    }
    /// Monomial coefficients G (M×N, index `k·N + l` for `u^k v^l`).
    pub fn coefficients(&self) -> &[P3<T>] {
        &self.g
    }
    /// New coordinates (same M×N); recomputes G.
    pub fn set_control_points(&mut self, points: &[P3<T>]) -> Result<(), crate::BezierError> {
        self.net.set_points(points)?;
        self.recompute();
        Ok(())
    }
    /// A-priori bound on the rounding error of one sample, per coordinate:
    /// `(M+N+2)·ε·Σ|G_kl|` (see the module doc).
    pub fn error_bound(&self) -> T {
        let (m, n) = self.net.dims();
        let mut worst = T::ZERO;
        for c in 0..3 {
            let mut s = T::ZERO;
            for g in &self.g {
                s += g[c].abs();
            }
            worst = worst.max(s);
        }
        T::from_f64((m + n + 2) as f64) * T::EPSILON * worst
    }
    /// Evaluates into a new grid.
    pub fn evaluate(&self, resolution: Resolution, outputs: Outputs) -> SurfaceGrid<T> {
        let mut grid = SurfaceGrid::zeroed(resolution, outputs);
        self.evaluate_into(&mut grid);
        grid
    }
    /// Evaluates every array `grid` holds, at the grid's resolution.
    pub fn evaluate_into(&self, grid: &mut SurfaceGrid<T>) {
        let res = grid.resolution();
        let (m, n) = self.net.dims();
        let (points, du, dv, normals) = grid.parts_mut();
        horner_grid(&self.g, m, n, res, points);
        if let (Some(du), Some(dv)) = (du, dv) {
            horner_grid(&self.g_du, m - 1, n, res, du);
            horner_grid(&self.g_dv, m, n - 1, res, dv);
            if let Some(normals) = normals {
                finish_normals(&self.net, res, du, dv, normals);
            }
        }
    }
}

/// Per sample: `Σ_k u^k (Σ_l v^l G_kl)` by nested Horner.
fn horner_grid<T: BezierScalar>(
    g: &[P3<T>],
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
            for k in (0..mm).rev() {
                let gk = &g[k * nn..(k + 1) * nn];
                let mut h = [T::ZERO; 3];
                for gl in gk.iter().rev() {
                    h = [h[0] * v + gl[0], h[1] * v + gl[1], h[2] * v + gl[2]];
                }
                s = [s[0] * u + h[0], s[1] * u + h[1], s[2] * u + h[2]];
            }
            *o = s;
        }
    });
}
