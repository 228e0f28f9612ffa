//! Host-side test support for mag-cal.

pub mod real;
pub mod reference;
pub mod sim;
pub mod target_vectors;
