//! Level heading and its circular smoothing.
//!
//! Kept apart from the application so that it can be replaced by the core's
//! heading module once that exists.

use mag_cal_core::nalgebra::Vector3;

/// Level heading of a calibrated reading `u` in the sensor frame (x
/// forward, y right, z down), radians in `(-pi, pi]`: `atan2(-u_y, u_x)`.
/// Only meaningful while the sensor is level; no tilt compensation.
pub fn heading_rad(u: &Vector3<f32>) -> f32 {
    libm::atan2f(-u.y, u.x)
}

/// An angle in degrees, wrapped to `[0, 360)`.
pub fn wrap_360(deg: f32) -> f32 {
    let d = deg % 360.0;
    if d < 0.0 {
        d + 360.0
    } else {
        d
    }
}

/// A difference of angles in degrees, wrapped to `[-180, 180)`.
pub fn wrap_180(deg: f32) -> f32 {
    wrap_360(deg + 180.0) - 180.0
}

/// Circular moving average of the last `N` headings.
///
/// Averages unit vectors `(cos, sin)`, never the angles themselves, so the
/// wrap at +-180 deg does not matter (the plain mean of 179 deg and -179 deg
/// is 0 deg; the circular mean is 180 deg). A fixed-capacity ring, no heap.
#[derive(Clone, Debug)]
pub struct CircularMean<const N: usize> {
    ring: [(f32, f32); N],
    len: usize,
    next: usize,
}

impl<const N: usize> CircularMean<N> {
    /// An empty window.
    pub const fn new() -> Self {
        Self {
            ring: [(0.0, 0.0); N],
            len: 0,
            next: 0,
        }
    }

    /// Adds a heading in radians, evicting the oldest when the window is full.
    pub fn push(&mut self, rad: f32) {
        if N == 0 {
            return;
        }
        self.ring[self.next] = (libm::cosf(rad), libm::sinf(rad));
        self.next = (self.next + 1) % N;
        self.len = (self.len + 1).min(N);
    }

    /// The circular mean in radians, or `None` when the window is empty or
    /// its headings cancel out (no defined mean).
    pub fn mean_rad(&self) -> Option<f32> {
        // Summed afresh on each call (N is small), so no rounding drift.
        let (c, s) = self.ring[..self.len]
            .iter()
            .fold((0.0f32, 0.0f32), |(c, s), &(ci, si)| (c + ci, s + si));
        if self.len == 0 || libm::hypotf(c, s) < 1e-3 * self.len as f32 {
            None
        } else {
            Some(libm::atan2f(s, c))
        }
    }
}

impl<const N: usize> Default for CircularMean<N> {
    fn default() -> Self {
        Self::new()
    }
}
