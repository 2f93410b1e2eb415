//! Unit normals `N = (∂S/∂u × ∂S/∂v) / |…|` and point-wise evaluation with derivatives.
//!
//! Degenerate samples (a collapsed edge of the net makes ∂S/∂v or ∂S/∂u vanish, or the two
//! derivatives are parallel) are handled in this order:
//! 1. on a border where one derivative vanishes, the limit normal from the mixed second
//!    derivative: `±(∂S/∂u × ∂²S/∂u∂v)` if ∂S/∂v ≈ 0 (sign + at u < ½, − at u ≥ ½), and
//!    `±(∂²S/∂u∂v × ∂S/∂v)` if ∂S/∂u ≈ 0 (+ at v < ½);
//! 2. otherwise the normalised sum of the regular normals in the nearest ring (Chebyshev radius
//!    1..=3) of neighbouring samples;
//! 3. otherwise the zero vector (the whole neighbourhood is degenerate, e.g. a net collapsed to a
//!    curve or point).
//!
//! "≈ 0" means `|∂S| ≤ √ε·L` with L the diagonal of the control points' bounding box, and
//! parallel means `|∂u×∂v| ≤ √ε·|∂u|·|∂v|`.

use rayon::prelude::*;

use crate::basis::{basis_at, binomial_row};
use crate::scalar::{BezierScalar, P3, cross3, norm3, scale3, sub3};
use crate::types::{ControlNet, Resolution, param};

/// Surface point and first derivatives (plus the mixed second derivative) at one (u, v).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointEval<T> {
    /// S(u, v).
    pub point: P3<T>,
    /// ∂S/∂u.
    pub du: P3<T>,
    /// ∂S/∂v.
    pub dv: P3<T>,
    /// ∂²S/∂u∂v.
    pub duv: P3<T>,
}

pub(crate) fn tensor_at<T: BezierScalar>(arr: &[P3<T>], bu: &[T], bv: &[T]) -> P3<T> {
    let nn = bv.len();
    let mut s = [T::ZERO; 3];
    for (i, &wu) in bu.iter().enumerate() {
        for (j, &wv) in bv.iter().enumerate() {
            let w = wu * wv;
            let p = arr[i * nn + j];
            for c in 0..3 {
                s[c] += p[c] * w;
            }
        }
    }
    s
}

/// Evaluates S, ∂S/∂u, ∂S/∂v and ∂²S/∂u∂v at one parameter pair (u, v ∈ [0, 1]).
pub fn eval_point<T: BezierScalar>(net: &ControlNet<T>, u: T, v: T) -> PointEval<T> {
    let (m, n) = net.dims();
    let basis = |count: usize, t: T| {
        let mut b = vec![T::ZERO; count];
        basis_at(&binomial_row(count), t, &mut b);
        b
    };
    let (bu, bv) = (basis(m, u), basis(n, v));
    let (bud, bvd) = (basis(m - 1, u), basis(n - 1, v));
    let du_net = net.diff_u();
    // Mixed net: (N−1)·Δv of the u-difference net, (M−1)×(N−1).
    let f = T::from_f64((n - 1) as f64);
    let duv_net: Vec<P3<T>> = (0..(m - 1) * (n - 1))
        .map(|k| {
            let (i, j) = (k / (n - 1), k % (n - 1));
            scale3(sub3(du_net[i * n + j + 1], du_net[i * n + j]), f)
        })
        .collect();
    PointEval {
        point: tensor_at(net.points(), &bu, &bv),
        du: tensor_at(&du_net, &bud, &bv),
        dv: tensor_at(&net.diff_v(), &bu, &bvd),
        duv: tensor_at(&duv_net, &bud, &bvd),
    }
}

fn unit<T: BezierScalar>(n: P3<T>, tol: T) -> Option<P3<T>> {
    let len = norm3(n);
    (len > tol && len.is_finite()).then(|| scale3(n, T::ONE / len))
}

/// The tolerances of the regular-normal test for `net` (see the module doc): a derivative is
/// "≈ 0" when its length is ≤ `small`, the two are parallel when `|∂u×∂v| ≤ root_eps·|∂u|·|∂v|`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalTolerance<T> {
    /// √ε·L, L the diagonal of the control points' bounding box.
    pub small: T,
    /// √ε of `T`.
    pub root_eps: T,
}

impl<T: BezierScalar> NormalTolerance<T> {
    /// The tolerances for `net` in `T`'s precision.
    pub fn of(net: &ControlNet<T>) -> Self {
        let (lo, hi) = net.bounds();
        let root_eps = T::EPSILON.sqrt();
        Self {
            small: root_eps * norm3(sub3(hi, lo)),
            root_eps,
        }
    }

    /// The unit normal `∂u×∂v/|…|`, or `None` where the sample is degenerate.
    pub fn regular(&self, du: P3<T>, dv: P3<T>) -> Option<P3<T>> {
        let (la, lb) = (norm3(du), norm3(dv));
        if la <= self.small || lb <= self.small {
            return None;
        }
        unit(cross3(du, dv), self.root_eps * la * lb)
    }
}

/// Fills `normals` from `du`, `dv` (all RU·RV, index `a·RV + b`), repairing degenerate samples
/// as described in the module doc.
pub(crate) fn finish_normals<T: BezierScalar>(
    net: &ControlNet<T>,
    res: Resolution,
    du: &[P3<T>],
    dv: &[P3<T>],
    normals: &mut [P3<T>],
) {
    let tol = NormalTolerance::of(net);
    let degenerate: Vec<usize> = normals
        .par_iter_mut()
        .enumerate()
        .filter_map(|(k, out)| match tol.regular(du[k], dv[k]) {
            Some(nrm) => {
                *out = nrm;
                None
            }
            None => {
                *out = [T::ZERO; 3];
                Some(k)
            }
        })
        .collect();
    repair(net, res, &degenerate, normals);
}

/// Steps 1–3 of the module doc for normals computed elsewhere (e.g. on a GPU) by
/// [`NormalTolerance::regular`], with the zero vector at every degenerate sample: replaces each
/// zero normal by its border limit or its neighbours' mean (or leaves it zero).
pub fn repair_normals<T: BezierScalar>(
    net: &ControlNet<T>,
    res: Resolution,
    normals: &mut [P3<T>],
) {
    let zero = [T::ZERO; 3];
    let degenerate: Vec<usize> = (0..normals.len()).filter(|&k| normals[k] == zero).collect();
    repair(net, res, &degenerate, normals);
}

/// Repairs the samples `degenerate` (zero in `normals`), steps 1–3 of the module doc.
fn repair<T: BezierScalar>(
    net: &ControlNet<T>,
    res: Resolution,
    degenerate: &[usize],
    normals: &mut [P3<T>],
) {
    if degenerate.is_empty() {
        return;
    }
    let small = NormalTolerance::of(net).small;
    let (ru, rv) = (res.ru(), res.rv());
    let half = T::from_f64(0.5);
    let mut is_bad = vec![false; ru * rv];
    for &k in degenerate {
        is_bad[k] = true;
    }
    // Step 1: second-derivative limit on borders.
    let mut still = Vec::new();
    for &k in degenerate {
        let (a, b) = (k / rv, k % rv);
        let (u, v): (T, T) = (param(a, ru), param(b, rv));
        let e = eval_point(net, u, v);
        let cand = if norm3(e.dv) <= small && norm3(e.du) > small {
            let s = if u < half { T::ONE } else { -T::ONE };
            unit(scale3(cross3(e.du, e.duv), s), small * small)
        } else if norm3(e.du) <= small && norm3(e.dv) > small {
            let s = if v < half { T::ONE } else { -T::ONE };
            unit(scale3(cross3(e.duv, e.dv), s), small * small)
        } else {
            None
        };
        match cand {
            Some(nrm) => normals[k] = nrm,
            None => still.push(k),
        }
    }
    // Step 2: nearest ring of regular neighbours.
    for &k in &still {
        let (a, b) = (k / rv, k % rv);
        for r in 1..=3usize {
            let mut sum = [T::ZERO; 3];
            let mut found = false;
            for aa in a.saturating_sub(r)..=(a + r).min(ru - 1) {
                for bb in b.saturating_sub(r)..=(b + r).min(rv - 1) {
                    let kk = aa * rv + bb;
                    if aa.abs_diff(a).max(bb.abs_diff(b)) == r && !is_bad[kk] {
                        let nn = normals[kk];
                        sum = [sum[0] + nn[0], sum[1] + nn[1], sum[2] + nn[2]];
                        found = true;
                    }
                }
            }
            if found {
                normals[k] = unit(sum, T::ZERO).unwrap_or([T::ZERO; 3]);
                break;
            }
        }
    }
}
