//! Step 2-3 of Algorithm 1: artificial field vectors and the sufficient
//! statistics of ADC2 (design document, section 4), in one pass.
//!
//! With the current estimate (`b0`, `T0`, `W0 = T0^-1`, normalised units):
//!
//! ```text
//! d_i = x_i - b0,   u_i = W0 d_i,   h_i = u_i / |u_i|
//! r_i = d_i - T0 h_i = d_i (1 - 1/|u_i|)      (the residual at the start)
//! ```
//!
//! ADC2 regresses `d_i` on `[h_i, 1]`. Writing the unknowns as a correction
//! `(T, beta) = (T0 + dT, beta)` makes that a regression of the small
//! residuals `r_i` on `[h_i, 1]`, so every statistic is a sum of small
//! terms and nothing cancels, even in `f32`:
//!
//! ```text
//! n,  s_h = sum h_i,  S_hh = sum h_i h_i^T,  s_r = sum r_i,  S_rh = sum r_i h_i^T,  S_rr = sum r_i r_i^T
//! ```
//!
//! The ADC2 cost at the start is `J0 = tr S_rr`; ADC1 weights the same
//! quantities. (The design document's `s_d`, `S_dh` are `s_r + T0 s_h` and
//! `S_rh + T0 S_hh`.)

use nalgebra::{Matrix3, Matrix3x4, Matrix4, Vector3};

use crate::moments::BLOCK;
use crate::normalize::{Normalization, Projector};
use crate::sample::{finite, Sample};
use crate::{Error, Real};

/// Sufficient statistics of the artificial data (normalised units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stats<T: Real> {
    /// Samples that contributed (finite, and not at the fitted centre).
    pub count: usize,
    /// `sum h_i`.
    pub s_h: Vector3<T>,
    /// `sum h_i h_i^T`.
    pub s_hh: Matrix3<T>,
    /// `sum r_i`.
    pub s_r: Vector3<T>,
    /// `sum r_i h_i^T`.
    pub s_rh: Matrix3<T>,
    /// `sum r_i r_i^T` (symmetric); its trace is the ADC2 cost at the start.
    pub s_rr: Matrix3<T>,
}

impl<T: Real> Stats<T> {
    /// `Q = [S_rh | s_r]` (3x4): residuals against the regressors `[h, 1]`.
    pub fn q(&self) -> Matrix3x4<T> {
        let mut q = Matrix3x4::zeros();
        q.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.s_rh);
        q.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.s_r);
        q
    }

    /// `G = [[S_hh, s_h], [s_h^T, n]]` (4x4): the Gram matrix of `[h, 1]`.
    pub fn gram(&self) -> Matrix4<T> {
        let mut g = Matrix4::zeros();
        g.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.s_hh);
        g.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.s_h);
        g.fixed_view_mut::<1, 3>(3, 0)
            .copy_from(&self.s_h.transpose());
        g[(3, 3)] = T::from_count(self.count);
        g
    }

    /// Covariance of the start residuals, `S_rr/n - (s_r/n)(s_r/n)^T`: the
    /// paper's noise estimate for ADC1 (normalised units).
    pub fn residual_covariance(&self) -> Matrix3<T> {
        let n = T::from_count(self.count);
        let mean = self.s_r / n;
        self.s_rr / n - mean * mean.transpose()
    }

    /// One pass over the samples with the start `(centre, w)` = (`b0`, `W0`)
    /// in the coordinates of `norm`.
    ///
    /// The loop is written on scalars (27 accumulators, one inverse square
    /// root, about 90 flops a sample): generic small-matrix operations in a
    /// per-sample loop cost about ten times as much on a Cortex-M4F.
    pub fn accumulate<S: Sample>(
        samples: &[S],
        norm: &Normalization<T>,
        centre: &Vector3<T>,
        w: &Matrix3<T>,
    ) -> Result<Self, Error> {
        let one = T::one();
        let map = Projector::new(norm, centre, w);
        let mut total = [T::zero(); 27];
        let mut count = 0usize;
        for block in samples.chunks(BLOCK) {
            let mut a = [T::zero(); 27];
            for sample in block {
                let Some([y0, y1, y2]) = finite::<T, S>(sample) else {
                    continue;
                };
                let ([dx, dy, dz], [ux, uy, uz]) = map.project([y0, y1, y2]);
                let q = ux * ux + uy * uy + uz * uz;
                if !(q >= T::MIN_POSITIVE) {
                    // At the fitted centre the direction is undefined.
                    continue;
                }
                let inv = q.rsqrt();
                let (hx, hy, hz) = (ux * inv, uy * inv, uz * inv);
                // r = d - T0 h = d (1 - 1/|u|)
                let k = one - inv;
                let (rx, ry, rz) = (dx * k, dy * k, dz * k);
                a[0] += hx;
                a[1] += hy;
                a[2] += hz;
                a[3] += hx * hx;
                a[4] += hx * hy;
                a[5] += hx * hz;
                a[6] += hy * hy;
                a[7] += hy * hz;
                a[8] += hz * hz;
                a[9] += rx;
                a[10] += ry;
                a[11] += rz;
                a[12] += rx * hx;
                a[13] += rx * hy;
                a[14] += rx * hz;
                a[15] += ry * hx;
                a[16] += ry * hy;
                a[17] += ry * hz;
                a[18] += rz * hx;
                a[19] += rz * hy;
                a[20] += rz * hz;
                a[21] += rx * rx;
                a[22] += rx * ry;
                a[23] += rx * rz;
                a[24] += ry * ry;
                a[25] += ry * rz;
                a[26] += rz * rz;
                count += 1;
            }
            for (t, v) in total.iter_mut().zip(a) {
                *t += v;
            }
        }
        if count < crate::normalize::MIN_SAMPLES {
            return Err(Error::TooFewSamples {
                found: count,
                required: crate::normalize::MIN_SAMPLES,
            });
        }
        let t = total;
        let sym = |a: T, b: T, c: T, d: T, e: T, f: T| Matrix3::new(a, b, c, b, d, e, c, e, f);
        Ok(Self {
            count,
            s_h: Vector3::new(t[0], t[1], t[2]),
            s_hh: sym(t[3], t[4], t[5], t[6], t[7], t[8]),
            s_r: Vector3::new(t[9], t[10], t[11]),
            s_rh: Matrix3::new(
                t[12], t[13], t[14], t[15], t[16], t[17], t[18], t[19], t[20],
            ),
            s_rr: sym(t[21], t[22], t[23], t[24], t[25], t[26]),
        })
    }
}
