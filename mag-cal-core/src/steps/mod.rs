//! The steps of Algorithm 1, one module each, in the order they run:
//! the rules and the normalisation (the scan), the moments and the LS
//! ellipsoid, the artificial data, the methods' re-estimation, and the
//! final pass's figures.

pub mod artificial;
pub mod dwell;
pub mod ellipsoid;
pub mod final_pass;
pub mod methods;
pub mod moments;
pub mod normalize;
pub mod rules;
