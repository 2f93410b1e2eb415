//! Level 3 (binomial coefficients) and level 2 (Bernstein basis tables) of the multi-level
//! evaluation, Sec. 8.4 with the corrected Eq. 8.5:
//! `S(u,v) = Σᵢ Σⱼ P_ij C(m,i)(1−u)^(m−i) uⁱ C(n,j)(1−v)^(n−j) vʲ` (m, n the degrees).

use crate::scalar::BezierScalar;
use crate::types::{MAX_CONTROL_POINTS, param};

/// Exact binomial coefficient C(n, k) (0 when k > n). Exact in `u64` for every n < 64
/// (C(63, 31) ≈ 9.2·10¹⁷ < 2⁶⁴); the multiplicative formula keeps every partial product
/// an exact binomial, so no intermediate overflows for n ≤ 63.
pub fn binomial(n: usize, k: usize) -> u64 {
    if k > n {
        return 0;
    }
    let k = k.min(n - k);
    let mut c: u128 = 1;
    for i in 0..k {
        // c = C(n, i) · (n − i) / (i + 1) = C(n, i + 1), exact at every step.
        c = c * (n - i) as u128 / (i + 1) as u128;
    }
    u64::try_from(c).unwrap_or(u64::MAX)
}

/// Level 3: the row `C(count−1, k)` for k = 0..count (binomials of the Bernstein basis of
/// degree `count − 1`, i.e. for `count` control points).
pub fn binomial_row(count: usize) -> Vec<u64> {
    let degree = count.saturating_sub(1);
    (0..count).map(|k| binomial(degree, k)).collect()
}

/// Bernstein polynomial `B_{i,degree}(t) = C(degree,i) tⁱ (1−t)^(degree−i)` computed from
/// scratch (binomial and powers), as the brute-force method does.
#[inline]
pub fn bernstein<T: BezierScalar>(degree: usize, i: usize, t: T) -> T {
    if i > degree {
        return T::ZERO;
    }
    T::from_f64(binomial(degree, i) as f64) * powi(t, i) * powi(T::ONE - t, degree - i)
}

/// `x^k` by repeated multiplication (k ≤ 63 here).
#[inline]
pub fn powi<T: BezierScalar>(x: T, k: usize) -> T {
    let mut r = T::ONE;
    for _ in 0..k {
        r *= x;
    }
    r
}

/// All `binoms.len()` Bernstein values at `t` into `out` (same length), using level-3 binomials.
#[inline]
pub fn basis_at<T: BezierScalar>(binoms: &[u64], t: T, out: &mut [T]) {
    let count = binoms.len().min(out.len()).min(MAX_CONTROL_POINTS);
    if count == 0 {
        return;
    }
    let degree = count - 1;
    // (1−t)^k for k = 0..=degree, then sweep tⁱ upwards.
    let mut one_minus = [T::ONE; MAX_CONTROL_POINTS];
    let s = T::ONE - t;
    for k in 1..count {
        one_minus[k] = one_minus[k - 1] * s;
    }
    let mut ti = T::ONE;
    for i in 0..count {
        out[i] = T::from_f64(binoms[i] as f64) * ti * one_minus[degree - i];
        ti *= t;
    }
}

/// Level 2: Bernstein table of `r` samples × `binoms.len()` functions, row-major
/// (`table[a·count + i] = B_{i,count−1}(a/(r−1))`). This is B^u (RU×M) or B^v (RV×N).
pub fn bernstein_table<T: BezierScalar>(binoms: &[u64], r: usize) -> Vec<T> {
    let count = binoms.len();
    let mut table = vec![T::ZERO; r * count];
    if count == 0 {
        return table;
    }
    for (a, row) in table.chunks_exact_mut(count).enumerate() {
        basis_at(binoms, param::<T>(a, r), row);
    }
    table
}
