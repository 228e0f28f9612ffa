//! What the unit tests share: a small deterministic generator for their
//! data (xorshift64*), and statistics built by their definition.

use nalgebra::{Matrix3, Rotation3, Unit, Vector3};

pub(crate) struct Rng(pub(crate) u64);

impl Rng {
    pub(crate) fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [lo, hi).
    pub(crate) fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }

    /// Uniform in [-1, 1).
    pub(crate) fn symmetric(&mut self) -> f64 {
        self.range(-1.0, 1.0)
    }

    /// A unit vector, uniform on the sphere (rejection from the cube).
    pub(crate) fn direction(&mut self) -> Vector3<f64> {
        loop {
            let v = Vector3::new(self.symmetric(), self.symmetric(), self.symmetric());
            let n = v.norm();
            if n > 0.1 && n <= 1.0 {
                return v / n;
            }
        }
    }

    /// A rotation about a random axis by a random angle in [0, pi).
    pub(crate) fn rotation(&mut self) -> Matrix3<f64> {
        let axis = Unit::new_normalize(self.direction());
        *Rotation3::from_axis_angle(&axis, core::f64::consts::PI * self.uniform()).matrix()
    }
}

/// The artificial-data statistics of directions `h` and residuals `r`,
/// summed by their definition (for tests that build them by hand).
pub(crate) fn stats_by_definition(
    pairs: impl IntoIterator<Item = (Vector3<f64>, Vector3<f64>)>,
) -> crate::steps::artificial::Stats<f64> {
    let mut s = crate::steps::artificial::Stats {
        count: 0,
        s_h: Vector3::zeros(),
        s_hh: Matrix3::zeros(),
        s_r: Vector3::zeros(),
        s_rh: Matrix3::zeros(),
        s_rr: Matrix3::zeros(),
    };
    for (h, r) in pairs {
        s.count += 1;
        s.s_h += h;
        s.s_hh += h * h.transpose();
        s.s_r += r;
        s.s_rh += r * h.transpose();
        s.s_rr += r * r.transpose();
    }
    s
}
