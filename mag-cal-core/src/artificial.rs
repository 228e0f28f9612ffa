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
use crate::normalize::Normalization;
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
    pub fn accumulate<S: Sample>(
        samples: &[S],
        norm: &Normalization<T>,
        centre: &Vector3<T>,
        w: &Matrix3<T>,
    ) -> Result<Self, Error> {
        let zero = T::zero();
        let one = T::one();
        let mut total = Acc::<T>::zero();
        let mut count = 0usize;
        for block in samples.chunks(BLOCK) {
            let mut acc = Acc::<T>::zero();
            for y in block.iter().filter_map(finite::<T, S>) {
                let d = norm.forward(y) - centre;
                let u = w * d;
                let norm_u = u.norm();
                if !(norm_u > zero) {
                    // At the fitted centre the direction is undefined.
                    continue;
                }
                let inv = one / norm_u;
                let h = u * inv;
                let r = d * (one - inv);
                acc.s_h += h;
                acc.s_hh += h * h.transpose();
                acc.s_r += r;
                acc.s_rh += r * h.transpose();
                acc.s_rr += r * r.transpose();
                count += 1;
            }
            total.add(&acc);
        }
        if count < crate::normalize::MIN_SAMPLES {
            return Err(Error::TooFewSamples {
                found: count,
                required: crate::normalize::MIN_SAMPLES,
            });
        }
        Ok(Self {
            count,
            s_h: total.s_h,
            s_hh: total.s_hh,
            s_r: total.s_r,
            s_rh: total.s_rh,
            s_rr: total.s_rr,
        })
    }
}

struct Acc<T: Real> {
    s_h: Vector3<T>,
    s_hh: Matrix3<T>,
    s_r: Vector3<T>,
    s_rh: Matrix3<T>,
    s_rr: Matrix3<T>,
}

impl<T: Real> Acc<T> {
    fn zero() -> Self {
        Self {
            s_h: Vector3::zeros(),
            s_hh: Matrix3::zeros(),
            s_r: Vector3::zeros(),
            s_rh: Matrix3::zeros(),
            s_rr: Matrix3::zeros(),
        }
    }

    fn add(&mut self, o: &Self) {
        self.s_h += o.s_h;
        self.s_hh += o.s_hh;
        self.s_r += o.s_r;
        self.s_rh += o.s_rh;
        self.s_rr += o.s_rr;
    }
}
