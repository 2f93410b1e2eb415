//! Control nets, resolutions and sampled surface grids.

use crate::error::BezierError;
use crate::scalar::{BezierScalar, P3, sub3};

/// Most control points per direction (degree 63). Binomials up to C(63, k) are exact in `u64`.
pub const MAX_CONTROL_POINTS: usize = 64;
/// Most samples per direction.
pub const MAX_RESOLUTION: usize = 4096;
/// Most samples in total (RU·RV); 2048² ≈ 4.2 M, i.e. ≤ 100 MB per f64 output array.
pub const MAX_SAMPLES: usize = 2048 * 2048;

fn check_count(axis: char, got: usize) -> Result<(), BezierError> {
    if got < 2 {
        return Err(BezierError::TooFewControlPoints { axis, got });
    }
    if got > MAX_CONTROL_POINTS {
        return Err(BezierError::TooManyControlPoints {
            axis,
            got,
            max: MAX_CONTROL_POINTS,
        });
    }
    Ok(())
}

/// M×N control points `P_ij` (M along u, N along v; degree M−1 × N−1), stored flat with index
/// `i·N + j`. Always valid: 2 ≤ M, N ≤ [`MAX_CONTROL_POINTS`], every coordinate finite.
#[derive(Debug, Clone, PartialEq)]
pub struct ControlNet<T> {
    m: usize,
    n: usize,
    points: Vec<P3<T>>,
}

impl<T: BezierScalar> ControlNet<T> {
    /// Validates sizes and finiteness. `points[i·N + j]` is `P_ij`.
    pub fn new(m: usize, n: usize, points: Vec<P3<T>>) -> Result<Self, BezierError> {
        check_count('u', m)?;
        check_count('v', n)?;
        if points.len() != m * n {
            return Err(BezierError::PointCount {
                m,
                n,
                expected: m * n,
                got: points.len(),
            });
        }
        check_finite(&points)?;
        Ok(Self { m, n, points })
    }

    /// Builds `P_ij = f(i, j)`.
    pub fn from_fn(
        m: usize,
        n: usize,
        mut f: impl FnMut(usize, usize) -> P3<T>,
    ) -> Result<Self, BezierError> {
        check_count('u', m)?;
        check_count('v', n)?;
        let points = (0..m * n).map(|k| f(k / n, k % n)).collect();
        Self::new(m, n, points)
    }

    /// A planar net: `P_ij = origin + (i/(M−1))·edge_u + (j/(N−1))·edge_v` (a flat patch, the
    /// thesis' initial resection, Sec. 7.3.2).
    pub fn planar(
        m: usize,
        n: usize,
        origin: P3<T>,
        edge_u: P3<T>,
        edge_v: P3<T>,
    ) -> Result<Self, BezierError> {
        Self::from_fn(m, n, |i, j| {
            let s = T::from_f64(i as f64 / (m - 1) as f64);
            let t = T::from_f64(j as f64 / (n - 1) as f64);
            std::array::from_fn(|c| origin[c] + s * edge_u[c] + t * edge_v[c])
        })
    }

    /// Control points along u (M).
    pub fn m(&self) -> usize {
        self.m
    }
    /// Control points along v (N).
    pub fn n(&self) -> usize {
        self.n
    }
    /// (M, N).
    pub fn dims(&self) -> (usize, usize) {
        (self.m, self.n)
    }
    /// Flat points, index `i·N + j`.
    pub fn points(&self) -> &[P3<T>] {
        &self.points
    }
    /// `P_ij`, or `None` outside the net.
    pub fn get(&self, i: usize, j: usize) -> Option<P3<T>> {
        (i < self.m && j < self.n).then(|| self.points[i * self.n + j])
    }
    /// Moves `P_ij` (finite coordinates only).
    pub fn set(&mut self, i: usize, j: usize, p: P3<T>) -> Result<(), BezierError> {
        if i >= self.m || j >= self.n {
            return Err(BezierError::IndexOutOfRange {
                i,
                j,
                m: self.m,
                n: self.n,
            });
        }
        let index = i * self.n + j;
        if !p.iter().all(|c| c.is_finite()) {
            return Err(BezierError::NonFinite { index });
        }
        self.points[index] = p;
        Ok(())
    }
    /// Replaces all points (same M×N).
    pub fn set_points(&mut self, points: &[P3<T>]) -> Result<(), BezierError> {
        if points.len() != self.points.len() {
            return Err(BezierError::PointCount {
                m: self.m,
                n: self.n,
                expected: self.points.len(),
                got: points.len(),
            });
        }
        check_finite(points)?;
        self.points.copy_from_slice(points);
        Ok(())
    }
    /// Axis-aligned bounds (min, max) of the control points.
    pub fn bounds(&self) -> (P3<T>, P3<T>) {
        let mut lo = self.points[0];
        let mut hi = self.points[0];
        for p in &self.points {
            for c in 0..3 {
                lo[c] = lo[c].min(p[c]);
                hi[c] = hi[c].max(p[c]);
            }
        }
        (lo, hi)
    }
    /// Converts the coordinates to another scalar type.
    pub fn cast<U: BezierScalar>(&self) -> ControlNet<U> {
        ControlNet {
            m: self.m,
            n: self.n,
            points: self
                .points
                .iter()
                .map(|p| p.map(|c| U::from_f64(c.to_f64())))
                .collect(),
        }
    }

    /// Degree elevation along u: an (M+1)×N net describing the same surface,
    /// `Q_i = i/M · P_{i−1} + (1 − i/M) · P_i`.
    pub fn elevate_u(&self) -> Result<Self, BezierError> {
        let (m, n) = (self.m, self.n);
        Self::from_fn(m + 1, n, |i, j| {
            let a = T::from_f64(i as f64 / m as f64);
            let prev = if i > 0 {
                self.points[(i - 1) * n + j]
            } else {
                [T::ZERO; 3]
            };
            let cur = if i < m {
                self.points[i * n + j]
            } else {
                [T::ZERO; 3]
            };
            std::array::from_fn(|c| a * prev[c] + (T::ONE - a) * cur[c])
        })
    }

    /// Degree elevation along v (see [`ControlNet::elevate_u`]).
    pub fn elevate_v(&self) -> Result<Self, BezierError> {
        self.transposed().elevate_u().map(|t| t.transposed())
    }

    /// The net with u and v swapped (N×M).
    pub fn transposed(&self) -> Self {
        let (m, n) = (self.m, self.n);
        let points = (0..m * n)
            .map(|k| self.points[(k % m) * n + k / m])
            .collect();
        Self { m: n, n: m, points }
    }

    /// Forward differences along u scaled by the degree: `(M−1)(P_{i+1,j} − P_ij)`, an
    /// (M−1)×N array (the net of ∂S/∂u). Not a [`ControlNet`] since M−1 may be 1.
    pub fn diff_u(&self) -> Vec<P3<T>> {
        let (m, n) = (self.m, self.n);
        let d = T::from_f64((m - 1) as f64);
        (0..(m - 1) * n)
            .map(|k| {
                let (i, j) = (k / n, k % n);
                sub3(self.points[(i + 1) * n + j], self.points[i * n + j]).map(|c| c * d)
            })
            .collect()
    }

    /// Forward differences along v scaled by the degree: `(N−1)(P_{i,j+1} − P_ij)`, M×(N−1).
    pub fn diff_v(&self) -> Vec<P3<T>> {
        let (m, n) = (self.m, self.n);
        let d = T::from_f64((n - 1) as f64);
        (0..m * (n - 1))
            .map(|k| {
                let (i, j) = (k / (n - 1), k % (n - 1));
                sub3(self.points[i * n + j + 1], self.points[i * n + j]).map(|c| c * d)
            })
            .collect()
    }
}

fn check_finite<T: BezierScalar>(points: &[P3<T>]) -> Result<(), BezierError> {
    match points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        Some(index) => Err(BezierError::NonFinite { index }),
        None => Ok(()),
    }
}

/// Sample counts RU×RV (2 ≤ each ≤ [`MAX_RESOLUTION`], RU·RV ≤ [`MAX_SAMPLES`]). Sample (a, b)
/// sits at `u_a = a/(RU−1)`, `v_b = b/(RV−1)`, so both borders are sampled exactly.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Resolution {
    ru: usize,
    rv: usize,
}

impl Resolution {
    /// Validates the counts against the caps.
    pub fn new(ru: usize, rv: usize) -> Result<Self, BezierError> {
        for (axis, got) in [('u', ru), ('v', rv)] {
            if got < 2 {
                return Err(BezierError::ResolutionTooSmall { axis, got });
            }
            if got > MAX_RESOLUTION {
                return Err(BezierError::ResolutionTooLarge {
                    axis,
                    got,
                    max: MAX_RESOLUTION,
                });
            }
        }
        if ru * rv > MAX_SAMPLES {
            return Err(BezierError::TooManySamples {
                ru,
                rv,
                max: MAX_SAMPLES,
            });
        }
        Ok(Self { ru, rv })
    }
    /// Samples along u.
    pub fn ru(&self) -> usize {
        self.ru
    }
    /// Samples along v.
    pub fn rv(&self) -> usize {
        self.rv
    }
    /// RU·RV.
    pub fn len(&self) -> usize {
        self.ru * self.rv
    }
    /// Never true (both counts ≥ 2); for clippy's `len_without_is_empty`.
    pub fn is_empty(&self) -> bool {
        false
    }
    /// `u_a = a/(RU−1)`.
    pub fn u<T: BezierScalar>(&self, a: usize) -> T {
        param(a, self.ru)
    }
    /// `v_b = b/(RV−1)`.
    pub fn v<T: BezierScalar>(&self, b: usize) -> T {
        param(b, self.rv)
    }
}

/// Parameter of sample `a` of `r`: `a/(r−1)`, rounded once from f64 (exactly 0 and 1 at the ends).
#[inline]
pub fn param<T: BezierScalar>(a: usize, r: usize) -> T {
    T::from_f64(a as f64 / (r - 1) as f64)
}

/// Which arrays an evaluation fills; each level includes the previous ones.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub enum Outputs {
    /// Surface points only.
    #[default]
    Points,
    /// Points, ∂S/∂u and ∂S/∂v.
    Derivatives,
    /// Points, derivatives and unit normals.
    Normals,
}

/// A sampled surface: RU·RV points with index `a·RV + b` (u outer, v inner), and optionally
/// ∂S/∂u, ∂S/∂v and unit normals with the same indexing.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceGrid<T> {
    resolution: Resolution,
    points: Vec<P3<T>>,
    du: Option<Vec<P3<T>>>,
    dv: Option<Vec<P3<T>>>,
    normals: Option<Vec<P3<T>>>,
}

impl<T: BezierScalar> SurfaceGrid<T> {
    /// Zero-filled grid with the arrays `outputs` asks for (sizes bounded by the resolution caps).
    pub fn zeroed(resolution: Resolution, outputs: Outputs) -> Self {
        let len = resolution.len();
        let arr = |want: bool| want.then(|| vec![[T::ZERO; 3]; len]);
        Self {
            resolution,
            points: vec![[T::ZERO; 3]; len],
            du: arr(outputs >= Outputs::Derivatives),
            dv: arr(outputs >= Outputs::Derivatives),
            normals: arr(outputs >= Outputs::Normals),
        }
    }
    /// RU×RV.
    pub fn resolution(&self) -> Resolution {
        self.resolution
    }
    /// What this grid holds.
    pub fn outputs(&self) -> Outputs {
        if self.normals.is_some() {
            Outputs::Normals
        } else if self.du.is_some() {
            Outputs::Derivatives
        } else {
            Outputs::Points
        }
    }
    /// Surface points, index `a·RV + b`.
    pub fn points(&self) -> &[P3<T>] {
        &self.points
    }
    /// ∂S/∂u per sample, if evaluated.
    pub fn du(&self) -> Option<&[P3<T>]> {
        self.du.as_deref()
    }
    /// ∂S/∂v per sample, if evaluated.
    pub fn dv(&self) -> Option<&[P3<T>]> {
        self.dv.as_deref()
    }
    /// Unit normals (direction ∂u×∂v) per sample, if evaluated; see [`crate::normals`].
    pub fn normals(&self) -> Option<&[P3<T>]> {
        self.normals.as_deref()
    }
    /// Point at sample (a, b).
    pub fn point(&self, a: usize, b: usize) -> Option<P3<T>> {
        (a < self.resolution.ru && b < self.resolution.rv)
            .then(|| self.points[a * self.resolution.rv + b])
    }
    /// Mutable (points, ∂S/∂u, ∂S/∂v, normals), for evaluators outside this crate.
    #[allow(clippy::type_complexity)]
    pub fn parts_mut(
        &mut self,
    ) -> (
        &mut [P3<T>],
        Option<&mut [P3<T>]>,
        Option<&mut [P3<T>]>,
        Option<&mut [P3<T>]>,
    ) {
        (
            &mut self.points,
            self.du.as_deref_mut(),
            self.dv.as_deref_mut(),
            self.normals.as_deref_mut(),
        )
    }
}
