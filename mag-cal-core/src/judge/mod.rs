//! The judging: the figures of a fit, their limits, and the functions that
//! turn them into a result or a refusal: [`quality::judge`] for every
//! three-dimensional fit (the batch fit's and the background calibrator's
//! refits), with the background calibrator's own decisions in
//! [`background`], and [`planar::judge`] for the planar fit.

pub(crate) mod background;
#[cfg(feature = "robust")]
pub(crate) mod planar;
pub mod quality;
