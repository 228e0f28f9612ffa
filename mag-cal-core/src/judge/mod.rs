//! The judging: the figures of a fit, their limits, and the one function
//! that turns them into a result or a refusal.

pub mod quality;
