//! Iterated ADC2 (design document, section 7; beyond the paper).
//!
//! Steps 2-5 of Algorithm 1 repeated, each time from the previous estimate:
//! artificial data (one O(n) pass), the ADC2 solve on the statistics, the
//! canonical form. The fixed point does not depend on the LS start; it
//! satisfies `sum r_i h_i h_i^T = 0` and `sum r_i h_i = 0` with
//! `r_i = |u_i| - 1`, and its accuracy matches subMLE's.
//!
//! Plain iteration converges linearly and slowly on partial coverage (16-22
//! passes on a full sphere, 70-90 on a +-30 deg band), so the map
//! `x -> ADC2 step`, with `x` the 6 upper entries of the symmetric `W'` and
//! `b'` (normalised units), is accelerated by Anderson mixing with memory 5
//! and mixing 1.8 ([`crate::numerics::quasi_newton::Anderson`], `MIXING`). It stops on the gauge-free change of
//! a plain step, `max|dM'| rho'^2 + max|db'| / rho' < tol` (`1e-6` in `f64`,
//! `1e-5` in `f32`; [`crate::Config::pass_tolerance`]), and returns that
//! step's image. Measured on the design document's scenarios A-G (50 runs
//! each, f64): median passes 5/7/7/10/8/7/9 against 15/21/68/83/24/20/77
//! for plain iteration to the same tolerance. The pass cap
//! ([`crate::Config::max_passes`]) ends it with [`Warning::PassCap`].

use crate::tuning::{MEMORY, MIXING};
use nalgebra::{Matrix3, SVector, Vector3};

use crate::numerics::linalg::{cholesky, cholesky_inverse, columns_of, from_columns, sym_inv_sqrt};
use crate::numerics::quasi_newton::Anderson;
use crate::sample::Sample;
use crate::steps::ellipsoid::Ellipsoid;
use crate::steps::methods::{adc2, weighted_stats, Estimate, Weights};
use crate::steps::normalize::Normalization;
use crate::{Config, Error, Real, Warning, Warnings};

/// Dimension of the fixed-point state: `W'` (6) and `b'` (3).
const DIM: usize = 9;

type State<T> = SVector<T, DIM>;

/// Upper entries of `W'` and `b'`.
fn pack<T: Real>(w: &Matrix3<T>, b: &Vector3<T>) -> State<T> {
    State::from_column_slice(&[
        w[(0, 0)],
        w[(0, 1)],
        w[(0, 2)],
        w[(1, 1)],
        w[(1, 2)],
        w[(2, 2)],
        b.x,
        b.y,
        b.z,
    ])
}

fn unpack<T: Real>(x: &State<T>) -> (Matrix3<T>, Vector3<T>) {
    let w = Matrix3::new(x[0], x[1], x[2], x[1], x[3], x[4], x[2], x[4], x[5]);
    (w, Vector3::new(x[6], x[7], x[8]))
}

/// A step of the map: the new state, the robust sigma and the largest
/// residual of its pass.
type Stepped<T> = (State<T>, Option<T>, T);

/// One plain step of the map: `(W', b') -> (W'_new, b'_new)`. The inner
/// solve is ADC2's closed form: near the fixed point the whole correction
/// is of the order of BFGS's 1e-6 step test, and a solve stopped there made
/// the map noisy at 1e-7, which stalled the acceleration.
///
/// With weights, the pass leaves out the rows they reject, and returns the
/// robust sigma and largest residual of its own residuals: the next pass's
/// weights. `None` when the pass's residuals lie beyond
/// [`Weights::tails_limit`].
fn adc2_step<T: Real, S: Sample>(
    samples: &[S],
    norm: &Normalization<T>,
    x: &State<T>,
    weights: &Weights<T>,
) -> Result<Option<Stepped<T>>, Error> {
    let (w, b) = unpack(x);
    let t0 = inverse(&w)?;
    let Some((stats, sigma, max)) = weighted_stats(samples, norm, &b, &w, weights)? else {
        return Ok(None);
    };
    let sol = adc2::solve(&stats, &t0, &b)?;
    let w_new = sym_inv_sqrt(&(sol.t * sol.t.transpose()))?;
    Ok(Some((pack(&w_new, &sol.centre), sigma, max)))
}

/// The gauge-free size of a change from `a` to `b`:
/// `max|dM'| rho'^2 + max|db'| / rho'`, with `M' = W'^2` and
/// `rho' = det(W')^(-1/3)` taken at `b`.
fn change<T: Real>(a: &State<T>, b: &State<T>) -> T {
    let (wa, ba) = unpack(a);
    let (wb, bb) = unpack(b);
    let rho = T::one() / wb.determinant().cbrt();
    let dm = (wb * wb - wa * wa).amax();
    dm * rho * rho + (bb - ba).amax() / rho
}

/// Iterated ADC2 from the LS fit, with 0/1 weights. Each pass's weights come from the residuals
/// of the pass before (the first pass's from `weights`); plain weights
/// (no sigma) stay plain.
pub(crate) fn step<T: Real, S: Sample>(
    samples: &[S],
    norm: &Normalization<T>,
    ls: &Ellipsoid<T>,
    config: &Config,
    weights: &Weights<T>,
) -> Result<Estimate<T>, Error> {
    let tol = match config.pass_tolerance {
        // A tolerance that can never be met (negative, zero, NaN) would only
        // run to the pass cap: it means the default.
        Some(t) if t > 0.0 && t.is_finite() => T::from_double(t),
        _ if T::EPSILON > T::lit(1e-10) => T::lit(1e-5),
        _ => T::lit(1e-6),
    };
    let mut accel = Anderson::<T, DIM, MEMORY>::with_mixing(T::lit(MIXING));
    let mut x = pack(&ls.w, &ls.centre);
    let mut passes = 0u32;
    let mut last = x;
    let mut weights = *weights;
    let mut max_residual = None;
    let mut sigma = None;
    while passes < config.max_passes {
        let Some((g, pass_sigma, pass_max)) = adc2_step(samples, norm, &x, &weights)? else {
            return Ok(Estimate::beyond_tails_limit(ls));
        };
        passes += 1;
        last = g;
        (sigma, max_residual) = (pass_sigma, Some(pass_max));
        if weights.sigma.is_some() {
            weights = weights.with_sigma(pass_sigma);
        }
        if !(change(&x, &g) >= tol) {
            let (w, centre) = unpack(&g);
            return Ok(Estimate {
                centre,
                w,
                iterations: 0,
                passes,
                warnings: Warnings::NONE,
                directions: None,
                sigma,
                max_residual,
                beyond_tails_limit: false,
            });
        }
        let next = accel.step(&x, &g);
        // An extrapolated W' must stay positive definite; else take the
        // plain step and start the history afresh.
        x = if cholesky(&columns_of(&unpack(&next).0)).is_some() {
            next
        } else {
            accel.reset();
            g
        };
    }
    let (w, centre) = unpack(&last);
    let mut warnings = Warnings::NONE;
    warnings.insert(Warning::PassCap);
    Ok(Estimate {
        centre,
        w,
        iterations: 0,
        passes,
        warnings,
        directions: None,
        sigma,
        max_residual,
        beyond_tails_limit: false,
    })
}

/// Inverse of a symmetric positive definite matrix.
fn inverse<T: Real>(m: &Matrix3<T>) -> Result<Matrix3<T>, Error> {
    let l = cholesky(&columns_of(m)).ok_or(Error::NotAnEllipsoid)?;
    Ok(from_columns(cholesky_inverse(&l)))
}
