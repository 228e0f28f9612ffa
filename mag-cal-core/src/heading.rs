//! Heading from calibrated readings, tilt compensation and circular
//! smoothing (design document, section 9).
