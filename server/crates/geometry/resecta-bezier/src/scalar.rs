//! The floating-point scalar of the evaluators ([`BezierScalar`], for `f32` and `f64`).

use std::fmt::{Debug, Display};
use std::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

/// Floating-point type the surfaces are evaluated in. Implemented for `f32` and `f64`.
///
/// A small self-contained trait (rather than a generic numeric tower) so that the hot loops
/// monomorphise to plain float arithmetic the compiler can vectorise.
pub trait BezierScalar:
    Copy
    + Send
    + Sync
    + Debug
    + Display
    + Default
    + PartialOrd
    + 'static
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
{
    /// 0.
    const ZERO: Self;
    /// 1.
    const ONE: Self;
    /// Machine epsilon (distance from 1 to the next larger value).
    const EPSILON: Self;
    /// `"f32"` or `"f64"`.
    const NAME: &'static str;
    /// Nearest representable value.
    fn from_f64(x: f64) -> Self;
    /// Exact widening (f32) or identity (f64).
    fn to_f64(self) -> f64;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// Neither NaN nor infinite.
    fn is_finite(self) -> bool;
    /// Larger of two values (NaN-ignoring like `f64::max`).
    fn max(self, other: Self) -> Self;
    /// Smaller of two values.
    fn min(self, other: Self) -> Self;
}

macro_rules! impl_scalar {
    ($t:ty, $name:literal) => {
        impl BezierScalar for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            const EPSILON: Self = <$t>::EPSILON;
            const NAME: &'static str = $name;
            #[inline(always)]
            fn from_f64(x: f64) -> Self {
                x as $t
            }
            #[inline(always)]
            fn to_f64(self) -> f64 {
                f64::from(self)
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline(always)]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline(always)]
            fn is_finite(self) -> bool {
                <$t>::is_finite(self)
            }
            #[inline(always)]
            fn max(self, other: Self) -> Self {
                <$t>::max(self, other)
            }
            #[inline(always)]
            fn min(self, other: Self) -> Self {
                <$t>::min(self, other)
            }
        }
    };
}

#[allow(clippy::cast_possible_truncation)]
mod impls {
    use super::BezierScalar;
    impl_scalar!(f32, "f32");
    impl_scalar!(f64, "f64");
}

/// A 3-D point or vector as three coordinates (x, y, z); plain array so buffers can be handed
/// to a GPU upload or flattened with `as_flattened()` without copying.
pub type P3<T> = [T; 3];

#[inline(always)]
pub(crate) fn sub3<T: BezierScalar>(a: P3<T>, b: P3<T>) -> P3<T> {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline(always)]
pub(crate) fn scale3<T: BezierScalar>(a: P3<T>, s: T) -> P3<T> {
    [a[0] * s, a[1] * s, a[2] * s]
}

#[inline(always)]
pub(crate) fn cross3<T: BezierScalar>(a: P3<T>, b: P3<T>) -> P3<T> {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline(always)]
pub(crate) fn norm3<T: BezierScalar>(a: P3<T>) -> T {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}
