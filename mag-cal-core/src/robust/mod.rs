//! Outlier handling: the screening (clip levels, the median centre and
//! its ball), the robust LS refits with 0/1 weights, and the runs of
//! rejected rows.

pub mod refit;
pub mod runs;
pub mod screen;
