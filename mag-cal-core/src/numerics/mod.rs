//! Numerics the steps share: the precision trait, small dense linear
//! algebra, fixed histograms (medians without sorting) and the
//! quasi-Newton solver.

pub mod histogram;
pub mod linalg;
pub mod quasi_newton;
pub mod real;
