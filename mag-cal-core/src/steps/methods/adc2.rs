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
//! `J` is exactly quadratic, so its minimiser is the solution of the
//! normal equations `Theta G = Q`: `Theta = Q G^-1`, a 4x4 Cholesky solve
//! on the statistics, no iteration and no further pass over the samples.
//! The batch fit, the background calibrator and iterated ADC2 share this
//! one solve. BFGS with the exact line search (compiled for ADC1 and
//! subMLE) reaches the same minimiser in 2-4 iterations; a test compares
//! the two where it is compiled.

use nalgebra::{ArrayStorage, Matrix3, Matrix3x4, Matrix4, Vector3};

use crate::numerics::linalg::{cholesky, cholesky_solve, columns_of, eigen_range, sym_inv_sqrt};
use crate::sample::Sample;
use crate::steps::artificial::Stats;
use crate::steps::ellipsoid::Ellipsoid;
use crate::steps::final_pass::DirectionSums;
use crate::steps::methods::{weighted_stats, Estimate, Weights};
use crate::steps::normalize::Normalization;
use crate::{Config, Error, Real, Warnings};

/// `Theta = [dT | db]` split into the correction of `T` and of the centre
/// (whole columns of the storage: no view, no index check).
pub(crate) fn split<T: Real>(th: &Matrix3x4<T>) -> (Matrix3<T>, Vector3<T>) {
    let [c0, c1, c2, c3] = th.data.0;
    (
        Matrix3::from_data(ArrayStorage([c0, c1, c2])),
        Vector3::from(c3),
    )
}

/// The ADC2 estimate in normalised coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Adc2Solution<T: Real> {
    /// `T'`: maps unit field vectors to normalised, centred samples.
    pub t: Matrix3<T>,
    /// Hard iron `b'`, normalised coordinates.
    pub centre: Vector3<T>,
}

/// The regressors `[h_i, 1]` must span four dimensions, else the minimiser
/// is not unique (all `h_i` on one plane through the centre, or equal).
/// Weak-but-regular geometry is judged by the quality checks, not here.
pub(crate) fn check_gram<T: Real>(g: &Matrix4<T>) -> Result<(), Error> {
    let (lo, hi) = eigen_range(&columns_of(g))?;
    if lo > hi.abs() * T::EPSILON * T::lit(64.0) {
        Ok(())
    } else {
        Err(Error::SingularSystem)
    }
}

/// The ADC2 minimiser `Theta = Q G^-1` (a 4x4 Cholesky solve) from the
/// start `(t0, centre0)` whose artificial-data statistics are `stats`.
/// Exact to rounding; iterated ADC2 needs that, since its corrections near
/// the fixed point are themselves of the order of an iterative solver's
/// step tolerance.
pub fn solve<T: Real>(
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
    let (dt, db) = split(&th);
    Ok(Adc2Solution {
        t: t0 + dt,
        centre: centre0 + db,
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

/// `run` with 0/1 weights: the artificial-data pass leaves out the rows
/// the weights reject.
pub(crate) fn step<T: Real, S: Sample>(
    samples: &[S],
    norm: &Normalization<T>,
    ls: &Ellipsoid<T>,
    _config: &Config,
    weights: &Weights<T>,
) -> Result<Estimate<T>, Error> {
    let Some((stats, sigma, max)) = weighted_stats(samples, norm, &ls.centre, &ls.w, weights)?
    else {
        return Ok(Estimate::beyond_tails_limit(ls));
    };
    let sol = solve(&stats, &ls.t, &ls.centre)?;
    Ok(Estimate {
        centre: sol.centre,
        w: sym_inv_sqrt(&(sol.t * sol.t.transpose()))?,
        iterations: 0,
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

    /// The oracle: `Theta = Q G^-1` by nalgebra's general 4x4 inverse (LU
    /// with pivoting, not the core's Cholesky).
    fn by_inverse(st: &Stats<f64>) -> Matrix3x4<f64> {
        let g_inv: Matrix4<f64> = st.gram().try_inverse().unwrap();
        st.q() * g_inv
    }

    #[test]
    fn the_solve_matches_a_general_inverse_and_the_normal_equations() {
        let st = stats();
        let want = by_inverse(&st);
        let t0 = Matrix3::new(1.1, 0.02, -0.01, 0.0, 0.95, 0.03, 0.0, 0.0, 1.02);
        let c0 = Vector3::new(0.1, -0.2, 0.05);
        let sol = solve(&st, &t0, &c0).unwrap();
        let (dt, db) = (sol.t - t0, sol.centre - c0);
        let err_t = (dt - want.fixed_view::<3, 3>(0, 0)).amax();
        let err_b = (db - want.column(3)).amax();
        assert!(err_t < 1e-12 && err_b < 1e-12, "{err_t} {err_b}");
        // The gradient 2 (Theta G - Q) vanishes, and the cost is below the
        // start's (J0) and below that of nearby points.
        let th = Matrix3x4::from_columns(&[
            dt.column(0).into(),
            dt.column(1).into(),
            dt.column(2).into(),
            db,
        ]);
        assert!((th * st.gram() - st.q()).amax() < 1e-12);
        let cost = |th: &Matrix3x4<f64>| {
            st.s_rr.trace() - 2.0 * th.dot(&st.q()) + (th * st.gram()).dot(th)
        };
        let at = cost(&th);
        assert!(at < st.s_rr.trace());
        for k in 0..12 {
            let mut d = Matrix3x4::zeros();
            d[k] = 1e-3;
            assert!(cost(&(th + d)) > at && cost(&(th - d)) > at);
        }
    }

    /// Where BFGS is compiled (ADC1, subMLE), it reaches the closed form
    /// on the ADC2 objective, with the exact line search, in a handful of
    /// iterations.
    #[cfg(any(feature = "adc1", feature = "submle"))]
    #[test]
    fn bfgs_on_the_adc2_objective_reaches_the_closed_form() {
        use crate::numerics::quasi_newton::{bfgs, BfgsOptions, Objective};
        use nalgebra::SVector;

        struct Adc2Objective(Stats<f64>);
        impl Objective<f64, 12> for Adc2Objective {
            fn cost_grad(&self, x: &SVector<f64, 12>) -> (f64, SVector<f64, 12>) {
                let th = Matrix3x4::from_column_slice(x.as_slice());
                let (q, g) = (self.0.q(), self.0.gram());
                let cost = self.0.s_rr.trace() - 2.0 * th.dot(&q) + (th * g).dot(&th);
                let grad = (th * g - q) * 2.0;
                (cost, SVector::from_column_slice(grad.as_slice()))
            }
            fn curvature(&self, d: &SVector<f64, 12>) -> Option<f64> {
                let dm = Matrix3x4::from_column_slice(d.as_slice());
                Some(2.0 * (dm * self.0.gram()).dot(&dm))
            }
        }

        let st = stats();
        let opts = BfgsOptions {
            step_tol: 1e-6,
            grad_tol: 8.0 * 40.0 * f64::EPSILON,
            max_iter: 50,
        };
        let m = bfgs(&Adc2Objective(st), SVector::zeros(), &opts).unwrap();
        let sol = solve(&st, &Matrix3::zeros(), &Vector3::zeros()).unwrap();
        let (dt, db) = split(&Matrix3x4::from_column_slice(m.x.as_slice()));
        let err = (dt - sol.t).amax().max((db - sol.centre).amax());
        assert!(err < 1e-12, "{err}");
        assert!(m.iterations <= 6, "{} iterations", m.iterations);
    }

    #[test]
    fn degenerate_statistics_are_refused() {
        // All directions equal: G is singular (the Gram check refuses it
        // before the Cholesky). An error, not a panic or a NaN result.
        let h = Vector3::new(0.0, 0.0, 1.0);
        let st = Stats {
            count: 20,
            s_h: h * 20.0,
            s_hh: h * h.transpose() * 20.0,
            s_r: Vector3::new(0.1, 0.0, 0.0),
            s_rh: Matrix3::zeros(),
            s_rr: Matrix3::identity(),
        };
        let r = solve(&st, &Matrix3::identity(), &Vector3::zeros());
        assert_eq!(r.unwrap_err(), Error::SingularSystem);
    }
}
