//! ADC1 (design document, section 6): the paper's noise-weighted variant.
//!
//! ```text
//! minimise  sum (r_i - Theta z_i)^T Wn (r_i - Theta z_i),   Wn = Sigma^-1,  z_i = [h_i; 1]
//! J(Theta)  = tr(Wn S_rr) - 2 tr(Wn Theta Q^T) + tr(Wn Theta G Theta^T)
//! grad J    = 2 Wn (Theta G - Q)
//! d^T H d   = 2 tr(Wn D G D^T)
//! ```
//!
//! with the statistics of [`crate::steps::artificial::Stats`]. `Sigma` is the
//! user's ([`crate::Config::noise_covariance`]) or, as in the paper, the
//! covariance of the LS residuals.
//!
//! **Its minimiser is ADC2's, for every positive definite `Wn`.** With the
//! `h_i` fixed, every output row shares the regressors `z_i`, so the normal
//! equations `Wn (Theta G - Q) = 0` reduce to `Theta G = Q` whatever `Wn` is
//! (Zellner's seemingly-unrelated-regressions result). The weight changes
//! the path BFGS takes, not where it ends; the paper's small ADC1/ADC2
//! differences come from solver tolerances. The host tests check this
//! against an independent closed-form ADC2.

use nalgebra::{Matrix3, Matrix3x4, Matrix4, SVector};

use crate::numerics::linalg::{
    cholesky, cholesky_inverse, columns_of, from_columns, min_max, sym_eigenvalues, sym_inv_sqrt,
};
use crate::numerics::quasi_newton::{bfgs, BfgsOptions, Minimum, Objective};
use crate::sample::Sample;
use crate::steps::artificial::Stats;
use crate::steps::ellipsoid::Ellipsoid;
use crate::steps::final_pass::DirectionSums;
use crate::steps::methods::adc2::{check_gram, split};
use crate::steps::methods::{weighted_stats, Estimate, Weights};
use crate::steps::normalize::Normalization;
use crate::{Config, Error, Real, Warnings};

/// Number of parameters: `dT` (9) and `beta` (3).
pub const PARAMS: usize = 12;

/// The 3x4 matrix `Theta = [dT | beta]` held column-major in a parameter
/// vector.
fn theta<T: Real>(x: &SVector<T, PARAMS>) -> Matrix3x4<T> {
    Matrix3x4::from_column_slice(x.as_slice())
}

/// The ADC1 objective in terms of the correction `Theta` to the start.
#[derive(Clone, Copy, Debug)]
pub struct Adc1Objective<T: Real> {
    weight: Matrix3<T>,
    s_rr: Matrix3<T>,
    q: Matrix3x4<T>,
    g: Matrix4<T>,
}

impl<T: Real> Adc1Objective<T> {
    /// The objective for the statistics and a weight `Wn` (symmetric
    /// positive definite).
    pub fn new(stats: &Stats<T>, weight: Matrix3<T>) -> Self {
        Self {
            weight,
            s_rr: stats.s_rr,
            q: stats.q(),
            g: stats.gram(),
        }
    }
}

impl<T: Real> Objective<T, PARAMS> for Adc1Objective<T> {
    fn cost_grad(&self, x: &SVector<T, PARAMS>) -> (T, SVector<T, PARAMS>) {
        let th = theta(x);
        let w = &self.weight;
        let two = T::lit(2.0);
        let cost = (w * self.s_rr).trace() - two * (w * th * self.q.transpose()).trace()
            + (w * th * self.g * th.transpose()).trace();
        let grad = w * (th * self.g - self.q) * two;
        (cost, SVector::from_column_slice(grad.as_slice()))
    }

    fn curvature(&self, d: &SVector<T, PARAMS>) -> Option<T> {
        let dm = theta(d);
        Some(T::lit(2.0) * (self.weight * dm * self.g * dm.transpose()).trace())
    }
}

/// The weight `Wn = Sigma^-1` in normalised units, scaled to a largest
/// eigenvalue of 1 (a constant factor does not move the minimiser and keeps
/// the solver's tolerances those of ADC2).
fn weight<T: Real>(
    stats: &Stats<T>,
    norm: &Normalization<T>,
    config: &Config,
) -> Result<Matrix3<T>, Error> {
    let sigma = match config.noise_covariance {
        Some(c) => {
            let m = Matrix3::from_fn(|i, j| T::from_double(c[i][j]));
            let finite = m.iter().all(|v| v.is_finite());
            if !finite || m != m.transpose() {
                return Err(Error::InvalidConfig {
                    field: "noise_covariance",
                });
            }
            m * (norm.inv_scale * norm.inv_scale)
        }
        None => stats.residual_covariance(),
    };
    let l = cholesky(&columns_of(&sigma)).ok_or(Error::InvalidConfig {
        field: "noise_covariance",
    })?;
    let inv = from_columns(cholesky_inverse(&l));
    let (_, top) = min_max(&sym_eigenvalues(&columns_of(&inv))?);
    if !(top > T::zero()) || !top.is_finite() {
        return Err(Error::InvalidConfig {
            field: "noise_covariance",
        });
    }
    Ok(inv / top)
}

/// The weighted solve on the statistics. Out of line: the solver's arrays
/// take stack only while it runs, not during the artificial-data pass.
#[inline(never)]
fn weighted_solve<T: Real>(
    stats: &Stats<T>,
    norm: &Normalization<T>,
    config: &Config,
) -> Result<Minimum<T, PARAMS>, Error> {
    let objective = Adc1Objective::new(stats, weight(stats, norm, config)?);
    check_gram(&objective.g)?;
    // The gradient scales with `2n` times the largest weight (1, see
    // [`weight`]). Its rounding noise is about `eps * n * |Theta|`, so
    // `4 eps` per unit is reachable, and it leaves a parameter error of a
    // few `eps / lambda_min(G/n)`. A looser tolerance (`eps^(3/4)` was
    // tried) stopped f32 early: 3e-5 off f64 instead of 4e-6.
    // The paper's 1e-6 step test is not a convergence test here: the
    // weighted Hessian 2 G (x) Wn has up to 12 distinct eigenvalues, BFGS
    // steps shrink long before the minimiser is reached, and stopping at a
    // 1e-6 step left ADC1 2e-6 away from it. The solve is O(1) per
    // iteration, so it runs to the gradient test (or a step at rounding
    // level) instead.
    let opts = BfgsOptions {
        step_tol: T::EPSILON * T::lit(16.0),
        grad_tol: T::lit(8.0) * T::from_count(stats.count) * T::EPSILON,
        max_iter: config.max_iterations,
    };
    bfgs(&objective, SVector::zeros(), &opts)
}

/// ADC1 from the LS fit: artificial data (one pass, with the 0/1 weights
/// as ADC2's), the noise weight, the weighted solve, then the canonical
/// `W'`.
pub(crate) fn step<T: Real, S: Sample>(
    samples: &[S],
    norm: &Normalization<T>,
    ls: &Ellipsoid<T>,
    config: &Config,
    weights: &Weights<T>,
) -> Result<Estimate<T>, Error> {
    let Some((stats, sigma, max)) = weighted_stats(samples, norm, &ls.centre, &ls.w, weights)?
    else {
        return Ok(Estimate::beyond_tails_limit(ls));
    };
    let m = weighted_solve(&stats, norm, config)?;
    let th = theta(&m.x);
    let (dt, db) = split(&th);
    let t = ls.t + dt;
    Ok(Estimate {
        centre: ls.centre + db,
        w: sym_inv_sqrt(&(t * t.transpose()))?,
        iterations: m.iterations,
        passes: 1,
        warnings: Warnings::NONE,
        directions: Some(DirectionSums::from(&stats)),
        sigma,
        max_residual: Some(max),
        beyond_tails_limit: false,
    })
}
