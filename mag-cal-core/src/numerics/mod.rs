//! Numerics the steps share: the precision trait, small dense linear
//! algebra, fixed histograms (medians without sorting), the
//! quasi-Newton solver of the iterative methods (with their features) and
//! a running sphere fit.

pub mod histogram;
pub mod linalg;
#[cfg(any(feature = "adc1", feature = "submle", feature = "adc2-iter"))]
pub mod quasi_newton;
pub mod real;
pub mod sphere;
