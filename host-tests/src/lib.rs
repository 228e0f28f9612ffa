//! Host-side test support for mag-cal.

pub mod background;
pub mod contamination;
pub mod metrics;
pub mod planar;
pub mod real;
pub mod reference;
pub mod scenarios;
pub mod sections;
pub mod sim;
pub mod study;
pub mod target_vectors;

/// The repository README's example runs as a doctest here (the core's
/// doctests cover its own crate README, which ships with it).
#[cfg(doctest)]
#[doc = include_str!("../../README.md")]
struct RepositoryReadmeDoctests;
