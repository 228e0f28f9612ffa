//! Host-side test support for mag-cal.

pub mod contamination;
pub mod metrics;
pub mod real;
pub mod reference;
pub mod scenarios;
pub mod sim;
pub mod study;
pub mod target_vectors;
