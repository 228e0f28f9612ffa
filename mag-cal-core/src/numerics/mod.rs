//! Numerics the steps share: the precision trait, small dense linear
//! algebra, fixed histograms (medians without sorting), the
//! quasi-Newton solver and a running sphere fit.

pub mod histogram;
pub mod linalg;
pub mod quasi_newton;
pub mod real;
pub mod sphere;
