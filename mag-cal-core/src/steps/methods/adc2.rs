//! ADC2 (design document, section 5): re-estimate `T` and `b` from the
//! artificial field vectors with the noise covariance ignored.
//!
//! With `Theta = [dT | beta]` (3x4), `z_i = [h_i; 1]`, the residual model
//! `r_i ~ Theta z_i` and the statistics of [`crate::steps::artificial::Stats`]:
//!
//! ```text
//! J(Theta)    = J0 - 2 <Theta, Q> + <Theta G, Theta>,   Q = [S_rh | s_r],  G = [[S_hh, s_h], [s_h^T, n]]
//! grad J      = 2 (Theta G - Q)
//! d^T H d     = 2 <D G, D>                                (H = 2 G (x) I3)
//! ```
//!
//! `J` is exactly quadratic, so BFGS runs with the exact line search and
//! each evaluation is O(1): the samples are not visited again. The
//! minimiser is `Theta = Q G^-1` (the closed form used as a test oracle);
//! BFGS reaches it in at most a few iterations because `H` has only four
//! distinct eigenvalues.

use nalgebra::{ArrayStorage, Matrix3, Matrix3x4, Matrix4, SVector, Vector3};

use crate::numerics::linalg::{
    cholesky, cholesky_solve, columns_of, min_max, sym_eigenvalues, sym_inv_sqrt,
};
use crate::numerics::quasi_newton::{bfgs, BfgsOptions, Objective};
use crate::sample::Sample;
use crate::steps::artificial::Stats;
use crate::steps::ellipsoid::Ellipsoid;
use crate::steps::final_pass::DirectionSums;
use crate::steps::methods::{weighted_stats, Estimate, Weights};
use crate::steps::normalize::Normalization;
use crate::{Config, Error, Real, Warnings};

/// Number of parameters: `dT` (9) and `beta` (3).
pub const PARAMS: usize = 12;

/// The ADC2 objective in terms of the correction `Theta` to the start.
#[derive(Clone, Copy, Debug)]
pub struct Adc2Objective<T: Real> {
    j0: T,
    q: Matrix3x4<T>,
    g: Matrix4<T>,
}

impl<T: Real> Adc2Objective<T> {
    /// Builds `J0`, `Q` and `G` from the statistics.
    pub fn new(stats: &Stats<T>) -> Self {
        Self {
            j0: stats.s_rr.trace(),
            q: stats.q(),
            g: stats.gram(),
        }
    }

    /// `Theta G` and `tr(Theta G Theta^T)` (as `(Theta G) . Theta`), for the
    /// cost and the curvature alike. Out of line: one copy of the unrolled
    /// 3x4 by 4x4 product serves both (less flash on the M4F, `bash
    /// bench.sh flash`; the same arithmetic, so the same values).
    #[inline(never)]
    fn quadratic(&self, th: &Matrix3x4<T>) -> (Matrix3x4<T>, T) {
        let thg = th * self.g;
        let q = thg.dot(th);
        (thg, q)
    }
}

/// `Theta = [dT | db]` split into the correction of `T` and of the centre
/// (whole columns of the storage: no view, no index check).
pub(crate) fn split<T: Real>(th: &Matrix3x4<T>) -> (Matrix3<T>, Vector3<T>) {
    let [c0, c1, c2, c3] = th.data.0;
    (
        Matrix3::from_data(ArrayStorage([c0, c1, c2])),
        Vector3::from(c3),
    )
}

/// The 3x4 matrix `Theta` held column-major in a parameter vector.
pub(crate) fn theta<T: Real>(x: &SVector<T, PARAMS>) -> Matrix3x4<T> {
    Matrix3x4::from_column_slice(x.as_slice())
}

impl<T: Real> Objective<T, PARAMS> for Adc2Objective<T> {
    fn cost_grad(&self, x: &SVector<T, PARAMS>) -> (T, SVector<T, PARAMS>) {
        let th = theta(x);
        let (thg, quad) = self.quadratic(&th);
        let two = T::lit(2.0);
        let cost = self.j0 - two * th.dot(&self.q) + quad;
        let grad = (thg - self.q) * two;
        (cost, SVector::from_column_slice(grad.as_slice()))
    }

    fn curvature(&self, d: &SVector<T, PARAMS>) -> Option<T> {
        Some(T::lit(2.0) * self.quadratic(&theta(d)).1)
    }
}

/// The ADC2 estimate in normalised coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Adc2Solution<T: Real> {
    /// `T'`: maps unit field vectors to normalised, centred samples.
    pub t: Matrix3<T>,
    /// Hard iron `b'`, normalised coordinates.
    pub centre: Vector3<T>,
    /// BFGS iterations.
    pub iterations: u32,
    /// Final cost `J`.
    pub cost: T,
}

/// The regressors `[h_i, 1]` must span four dimensions, else the minimiser
/// is not unique (all `h_i` on one plane through the centre, or equal).
/// Weak-but-regular geometry is judged by the quality checks, not here.
pub(crate) fn check_gram<T: Real>(g: &Matrix4<T>) -> Result<(), Error> {
    let (lo, hi) = min_max(&sym_eigenvalues(&columns_of(g))?);
    if lo > hi.abs() * T::EPSILON * T::lit(64.0) {
        Ok(())
    } else {
        Err(Error::SingularSystem)
    }
}

/// BFGS options shared by ADC1 and ADC2. The gradient scales with `2n`
/// (for ADC1, with `2n` times the largest weight). Its rounding noise is
/// about `eps * n * |Theta|`, so `4 eps` per unit is reachable, and it leaves
/// a parameter error of a few `eps / lambda_min(G/n)`. A looser tolerance
/// (`eps^(3/4)` was tried) stops f32 early: 3e-5 off f64 instead of 4e-6.
/// When the gradient test is out of reach, the step test ends the solve.
pub(crate) fn options<T: Real>(count: usize, weight_scale: T, max_iter: u32) -> BfgsOptions<T> {
    BfgsOptions {
        step_tol: T::lit(1e-6),
        grad_tol: T::lit(8.0) * T::from_count(count) * weight_scale * T::EPSILON,
        max_iter,
    }
}

/// Runs ADC2 from the start `(t0, centre0)` whose artificial-data
/// statistics are `stats`.
///
/// Out of line: the solver's arrays (the 12x12 inverse Hessian) then take
/// stack only while it runs, not during the artificial-data pass.
#[inline(never)]
pub fn solve<T: Real>(
    stats: &Stats<T>,
    t0: &Matrix3<T>,
    centre0: &Vector3<T>,
    max_iter: u32,
) -> Result<Adc2Solution<T>, Error> {
    let objective = Adc2Objective::new(stats);
    check_gram(&objective.g)?;
    let opts = options(stats.count, T::one(), max_iter);
    let m = bfgs(&objective, SVector::zeros(), &opts)?;
    let (dt, db) = split(&theta(&m.x));
    Ok(Adc2Solution {
        t: t0 + dt,
        centre: centre0 + db,
        iterations: m.iterations,
        cost: m.cost,
    })
}

/// The ADC2 minimiser in closed form, `Theta = Q G^-1` (a 4x4 Cholesky
/// solve), from the start `(t0, centre0)`. Exact where BFGS stops at the
/// paper's step test; iterated ADC2 needs that, since its corrections near
/// the fixed point are themselves of the order of that tolerance.
pub fn solve_closed_form<T: Real>(
    stats: &Stats<T>,
    t0: &Matrix3<T>,
    centre0: &Vector3<T>,
) -> Result<Adc2Solution<T>, Error> {
    let g = stats.gram();
    check_gram(&g)?;
    let l = cholesky(&columns_of(&g)).ok_or(Error::SingularSystem)?;
    // Theta G = Q  <=>  G Theta^T = Q^T (G symmetric): row r of Theta
    // solves G x = (row r of Q). Rows of the column-major storage are read
    // by whole columns, no run-time index.
    let [[q00, q10, q20], [q01, q11, q21], [q02, q12, q22], [q03, q13, q23]] = stats.q().data.0;
    let [a0, a1, a2, a3] = cholesky_solve(&l, &[q00, q01, q02, q03]);
    let [b0, b1, b2, b3] = cholesky_solve(&l, &[q10, q11, q12, q13]);
    let [c0, c1, c2, c3] = cholesky_solve(&l, &[q20, q21, q22, q23]);
    let th = Matrix3x4::new(a0, a1, a2, a3, b0, b1, b2, b3, c0, c1, c2, c3);
    let objective = Adc2Objective::new(stats);
    let (cost, _) = objective.cost_grad(&SVector::from_column_slice(th.as_slice()));
    let (dt, db) = split(&th);
    Ok(Adc2Solution {
        t: t0 + dt,
        centre: centre0 + db,
        iterations: 0,
        cost,
    })
}

/// One ADC2 step from the LS fit: artificial data (one pass), then the
/// solve on the statistics, then the canonical `W' = (T' T'^T)^(-1/2)`
/// (for the benchmarks, which time it alone).
#[cfg(feature = "bench-internals")]
pub fn run<T: Real, S: Sample>(
    samples: &[S],
    norm: &Normalization<T>,
    ls: &Ellipsoid<T>,
    config: &Config,
) -> Result<Estimate<T>, Error> {
    step(samples, norm, ls, config, &Weights::PLAIN)
}

/// [`run`] with 0/1 weights: the artificial-data pass leaves out the rows
/// the weights reject.
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
    let sol = solve(&stats, &ls.t, &ls.centre, config.max_iterations)?;
    Ok(Estimate {
        centre: sol.centre,
        w: sym_inv_sqrt(&(sol.t * sol.t.transpose()))?,
        iterations: sol.iterations,
        passes: 1,
        warnings: Warnings::NONE,
        directions: Some(DirectionSums::from(&stats)),
        sigma,
        max_residual: Some(max),
        beyond_tails_limit: false,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::stats_by_definition;

    /// Statistics of a made-up but consistent regression problem: 40
    /// directions, residuals that are an exact affine function of `[h, 1]`
    /// plus a wobble, accumulated by hand.
    fn stats() -> Stats<f64> {
        stats_by_definition((0..40).map(|i| {
            let z = 1.0 - 2.0 * (f64::from(i) + 0.5) / 40.0;
            let (r, phi) = (libm::sqrt(1.0 - z * z), f64::from(i) * 2.4);
            let h = Vector3::new(r * libm::cos(phi), r * libm::sin(phi), z);
            let wobble = 0.01 * libm::sin(f64::from(i) * 1.7);
            let res = Vector3::new(0.05 * h.x - 0.02, 0.03 * h.z + wobble, -0.04 * h.y + 0.01);
            (h, res)
        }))
    }

    #[test]
    fn bfgs_reaches_the_closed_form_from_the_same_statistics() {
        let st = stats();
        let obj = Adc2Objective::new(&st);
        // Closed form Theta = Q G^-1, by a 4x4 inverse.
        let g_inv: Matrix4<f64> = st.gram().try_inverse().unwrap();
        let want = st.q() * g_inv;
        let t0 = Matrix3::identity();
        let sol = solve(&st, &t0, &Vector3::zeros(), 50).unwrap();
        let got_t = sol.t - t0;
        let err_t = (got_t - want.fixed_view::<3, 3>(0, 0)).amax();
        let err_b = (sol.centre - want.column(3)).amax();
        assert!(err_t < 1e-12 && err_b < 1e-12, "{err_t} {err_b}");
        assert!(sol.iterations <= 6, "{} iterations", sol.iterations);
        // The cost tracked by the exact line model equals a fresh evaluation.
        let x = SVector::<f64, PARAMS>::from_column_slice(want.as_slice());
        let (fresh, grad) = obj.cost_grad(&x);
        assert!((sol.cost - fresh).abs() < 1e-12 * st.s_rr.trace());
        assert!(grad.amax() < 1e-12);
        assert!(sol.cost < st.s_rr.trace());
    }

    #[test]
    fn degenerate_statistics_are_refused() {
        // All directions equal: G is singular, the curvature along some
        // direction is zero. An error, not a panic or a NaN result.
        let h = Vector3::new(0.0, 0.0, 1.0);
        let st = Stats {
            count: 20,
            s_h: h * 20.0,
            s_hh: h * h.transpose() * 20.0,
            s_r: Vector3::new(0.1, 0.0, 0.0),
            s_rh: Matrix3::zeros(),
            s_rr: Matrix3::identity(),
        };
        let r = solve(&st, &Matrix3::identity(), &Vector3::zeros(), 50);
        assert_eq!(r.unwrap_err(), Error::SingularSystem);
    }
}
