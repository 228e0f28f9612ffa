//! Heading display helper.
//!
//! The level heading, tilt compensation and circular smoothing come from
//! the core ([`mag_cal_core::heading`]: `heading_deg`, `HeadingSmoother`,
//! `wrap_deg`); only the compass-style display range is the application's.

use mag_cal_core::heading::wrap_deg;

/// An angle in degrees, wrapped to `[0, 360)` for display (the core's
/// headings are in `(-180, 180]`).
pub fn wrap_360(deg: f32) -> f32 {
    let d = wrap_deg(deg);
    if d < 0.0 {
        d + 360.0
    } else {
        // `+ 0.0` shows -0 as 0.
        d + 0.0
    }
}
