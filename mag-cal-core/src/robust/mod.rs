//! Outlier handling: the screening (clip levels, the median centre and
//! its ball), the robust LS refits with 0/1 weights, and the runs of
//! rejected rows.

#[cfg(feature = "robust")]
pub mod refit;
// The spans' type is in every build: the report's `Selection` holds it
// (without `robust` it is always empty).
pub mod runs;
#[cfg(feature = "robust")]
pub mod screen;
