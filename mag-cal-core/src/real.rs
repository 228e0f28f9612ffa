//! The scalar type: `f32` or `f64`, through one generic code path.

use nalgebra::RealField;

mod sealed {
    pub trait Sealed {}
    impl Sealed for f32 {}
    impl Sealed for f64 {}
}

/// A floating-point scalar the calibration can run in: `f32` or `f64`.
///
/// Sealed: the numerics (tolerances, range checks) are tuned for these two.
pub trait Real: RealField + Copy + sealed::Sealed {
    /// Machine epsilon of the type.
    const EPSILON: Self;
    /// Smallest positive normal number of the type.
    const MIN_POSITIVE: Self;
    /// Converts a constant, rounding to the nearest representable value.
    fn lit(x: f64) -> Self;
    /// Widens (or keeps) the value as `f64`, for reporting.
    fn to_f64(self) -> f64;
    /// Converts a count, exactly up to `2^24` (`f32`) or `2^53` (`f64`).
    fn from_count(n: usize) -> Self;
    /// Converts an `f32` (exact for both types).
    fn from_single(x: f32) -> Self;
}

impl Real for f32 {
    const EPSILON: Self = f32::EPSILON;
    const MIN_POSITIVE: Self = f32::MIN_POSITIVE;
    #[inline]
    fn lit(x: f64) -> Self {
        x as f32
    }
    #[inline]
    fn to_f64(self) -> f64 {
        self as f64
    }
    #[inline]
    fn from_count(n: usize) -> Self {
        n as f32
    }
    #[inline]
    fn from_single(x: f32) -> Self {
        x
    }
}

impl Real for f64 {
    const EPSILON: Self = f64::EPSILON;
    const MIN_POSITIVE: Self = f64::MIN_POSITIVE;
    #[inline]
    fn lit(x: f64) -> Self {
        x
    }
    #[inline]
    fn to_f64(self) -> f64 {
        self
    }
    #[inline]
    fn from_count(n: usize) -> Self {
        n as f64
    }
    #[inline]
    fn from_single(x: f32) -> Self {
        x as f64
    }
}
