//! Around the batch fit, on the device: the collector, the background
//! calibrator, offsets-only and planar calibration, headings, alignment to
//! the body frame and persistence.

pub mod align;
pub mod background;
pub mod collector;
pub mod heading;
pub mod offsets;
pub mod persist;
// Its fit screens the rows (the robust path's screening).
#[cfg(feature = "robust")]
pub mod planar;
