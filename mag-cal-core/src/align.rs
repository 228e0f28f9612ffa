//! Step 2 of the calibration: alignment to a reference frame (orthogonal
//! Procrustes).
