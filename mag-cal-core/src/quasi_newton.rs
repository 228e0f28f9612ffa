//! Step 4 of Algorithm 1: a fixed-size BFGS quasi-Newton solver, and the
//! fixed-point accelerator of iterated ADC2.
//!
//! Parameters live in a stack vector `SVector<T, N>`, the inverse-Hessian
//! approximation in an `N x N` stack matrix; nothing is allocated. Every
//! method of the crate minimises its objective with this one solver.
//!
//! Line search: an objective that is exactly quadratic reports its
//! curvature `d^T H d` along a direction, and the step is the closed-form
//! minimiser `alpha = -g^T d / d^T H d`. Other objectives get a backtracking
//! (Armijo) search. Stop criteria, checked every iteration:
//! - the step is below `step_tol` relative to the parameter scale,
//!   `max|dx| <= step_tol * (1 + max|x|)` (the paper's criterion, `1e-6`);
//! - or the gradient is below `grad_tol` (`max|g| <= grad_tol`);
//! - the iteration cap `max_iter` turns into [`Error::NoConvergence`].

use nalgebra::{Cholesky, SMatrix, SVector};

use crate::{Error, Real};

/// A smooth objective over `N` parameters.
pub trait Objective<T: Real, const N: usize> {
    /// Cost and gradient at `x`.
    fn cost_grad(&self, x: &SVector<T, N>) -> (T, SVector<T, N>);

    /// For an exactly quadratic objective, the curvature `d^T H d` along
    /// `d` (then the line search is exact and closed form); `None` otherwise.
    fn curvature(&self, _d: &SVector<T, N>) -> Option<T> {
        None
    }
}

/// Stop criteria and the iteration cap.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BfgsOptions<T> {
    /// Relative step tolerance.
    pub step_tol: T,
    /// Absolute gradient tolerance (max norm), in the objective's units.
    pub grad_tol: T,
    /// Hard cap on iterations.
    pub max_iter: u32,
}

/// Which criterion stopped the solver.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Stop {
    /// The step fell below the step tolerance.
    Step,
    /// The gradient fell below the gradient tolerance.
    Gradient,
}

/// The minimiser found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Minimum<T: Real, const N: usize> {
    /// Parameters.
    pub x: SVector<T, N>,
    /// Cost at `x`.
    pub cost: T,
    /// Iterations performed (steps taken).
    pub iterations: u32,
    /// Why it stopped.
    pub stop: Stop,
}

/// Backtracking halvings before the line search gives up.
const MAX_BACKTRACK: u32 = 60;
/// Armijo sufficient-decrease constant.
const ARMIJO: f64 = 1e-4;

/// Minimises `f` from `x0` with BFGS.
pub fn bfgs<T: Real, F: Objective<T, N>, const N: usize>(
    f: &F,
    x0: SVector<T, N>,
    opts: &BfgsOptions<T>,
) -> Result<Minimum<T, N>, Error> {
    let mut x = x0;
    let (mut cost, mut g) = f.cost_grad(&x);
    let mut h_inv = SMatrix::<T, N, N>::identity();
    let mut scaled = false;
    for iteration in 0..opts.max_iter {
        if !cost.is_finite() || !g.iter().all(|v| v.is_finite()) {
            return Err(Error::SingularSystem);
        }
        if g.amax() <= opts.grad_tol {
            return Ok(Minimum {
                x,
                cost,
                iterations: iteration,
                stop: Stop::Gradient,
            });
        }
        let mut d = -(h_inv * g);
        let mut slope = g.dot(&d);
        if !(slope < T::zero()) {
            // Rounding destroyed positive definiteness: restart from steepest descent.
            h_inv = SMatrix::identity();
            scaled = false;
            d = -g;
            slope = -g.norm_squared();
        }
        // Quadratic objectives: closed-form step, and the new cost from the
        // exact line model `f + alpha g^T d + alpha^2/2 d^T H d`, which
        // never cancels. Others: a backtracking search that hands back the
        // cost and gradient of the accepted point (one evaluation each).
        let (step, cost_new, g_new) = match f.curvature(&d) {
            Some(c) => {
                if !(c > T::zero()) {
                    return Err(Error::SingularSystem);
                }
                let alpha = -slope / c;
                let step = d * alpha;
                let (_, g_new) = f.cost_grad(&(x + step));
                (step, cost + alpha * slope * T::lit(0.5), g_new)
            }
            None => match backtrack(f, &x, cost, slope, &d, scaled) {
                Some((alpha, c, g_new)) => (d * alpha, c, g_new),
                // No decrease along a descent direction: the cost is flat to
                // rounding, i.e. we are at the minimum.
                None => {
                    return Ok(Minimum {
                        x,
                        cost,
                        iterations: iteration,
                        stop: Stop::Step,
                    })
                }
            },
        };
        let x_new = x + step;
        let y = g_new - g;
        let sy = step.dot(&y);
        if sy > T::zero() {
            if !scaled {
                // Nocedal & Wright (6.20): scale the initial inverse Hessian.
                h_inv *= sy / y.norm_squared();
                scaled = true;
            }
            let rho = T::one() / sy;
            let hy = h_inv * y;
            let yhy = y.dot(&hy);
            // H+ = H - rho (s (Hy)^T + (Hy) s^T) + (rho^2 y^T H y + rho) s s^T
            h_inv += (step * hy.transpose() + hy * step.transpose()) * (-rho)
                + step * step.transpose() * (rho * rho * yhy + rho);
        }
        x = x_new;
        cost = cost_new;
        g = g_new;
        if step.amax() <= opts.step_tol * (T::one() + x.amax()) {
            return Ok(Minimum {
                x,
                cost,
                iterations: iteration + 1,
                stop: Stop::Step,
            });
        }
    }
    Err(Error::NoConvergence {
        iterations: opts.max_iter,
    })
}

/// Armijo backtracking from a unit step (or, before the inverse Hessian has
/// a scale, a step of unit length), each retry at the minimiser of the
/// quadratic through `f(0)`, `f'(0)` and the rejected trial, kept within
/// `[0.1, 0.5]` of the previous step. Returns the step length with the cost
/// and gradient there, or `None` when no decrease is found.
fn backtrack<T: Real, F: Objective<T, N>, const N: usize>(
    f: &F,
    x: &SVector<T, N>,
    cost: T,
    slope: T,
    d: &SVector<T, N>,
    scaled: bool,
) -> Option<(T, T, SVector<T, N>)> {
    let mut alpha = if scaled {
        T::one()
    } else {
        T::one() / d.norm()
    };
    for _ in 0..MAX_BACKTRACK {
        let (c, g) = f.cost_grad(&(x + d * alpha));
        if c.is_finite() && c <= cost + alpha * slope * T::lit(ARMIJO) {
            return Some((alpha, c, g));
        }
        let (lo, hi) = (alpha * T::lit(0.1), alpha * T::lit(0.5));
        let curvature = c - cost - slope * alpha;
        alpha = if c.is_finite() && curvature > T::zero() {
            let a = -slope * alpha * alpha / (T::lit(2.0) * curvature);
            a.max(lo).min(hi)
        } else {
            hi
        };
    }
    None
}

/// Anderson acceleration (type II) of a fixed-point iteration `x = g(x)` in
/// `D` dimensions with memory `M` and mixing `beta`, on the stack.
///
/// Given the current iterate `x_k` and its image `g_k = g(x_k)`, with
/// residuals `f = g(x) - x`, the next iterate is
/// `x_k + beta f_k - (dX + beta dF) gamma`, where `dX`, `dF` hold the last
/// `M` differences of iterates and residuals and `gamma` is the
/// least-squares solution of `dF gamma ~ f_k` (with `beta = 1` this is the
/// familiar `g_k - dG gamma`). The least squares is solved through its
/// normal equations with a Tikhonov term of 64 ulps of their trace (the
/// columns grow collinear as the iteration converges); a failed solve falls
/// back to the mixing step and a fresh history.
#[derive(Clone, Debug)]
pub struct Anderson<T: Real, const D: usize, const M: usize> {
    mixing: T,
    d_x: SMatrix<T, D, M>,
    d_f: SMatrix<T, D, M>,
    last: Option<(SVector<T, D>, SVector<T, D>)>,
    len: usize,
    next: usize,
}

impl<T: Real, const D: usize, const M: usize> Default for Anderson<T, D, M> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Real, const D: usize, const M: usize> Anderson<T, D, M> {
    /// An accelerator with no history and mixing 1 (the plain step
    /// `g(x)` when there is no history).
    pub fn new() -> Self {
        Self::with_mixing(T::one())
    }

    /// An accelerator whose step without history is `x + mixing (g(x) - x)`.
    pub fn with_mixing(mixing: T) -> Self {
        Self {
            mixing,
            d_x: SMatrix::zeros(),
            d_f: SMatrix::zeros(),
            last: None,
            len: 0,
            next: 0,
        }
    }

    /// Forgets the history (the next step is a plain mixing step).
    pub fn reset(&mut self) {
        *self = Self::with_mixing(self.mixing);
    }

    /// The next iterate from `x_k` and `g_k = g(x_k)`.
    pub fn step(&mut self, x: &SVector<T, D>, g: &SVector<T, D>) -> SVector<T, D> {
        let f = g - x;
        let plain = x + f * self.mixing;
        if let Some((x_prev, f_prev)) = self.last.replace((*x, f)) {
            if M > 0 {
                let k = self.next % M;
                self.d_x.set_column(k, &(x - x_prev));
                self.d_f.set_column(k, &(f - f_prev));
                self.next = (k + 1) % M;
                self.len = (self.len + 1).min(M);
            }
        }
        if self.len == 0 {
            return plain;
        }
        let mut normal = self.d_f.transpose() * self.d_f;
        let ridge = normal.trace() * T::EPSILON * T::lit(64.0);
        for i in 0..M {
            // Unused columns are zero: a unit diagonal keeps their gamma 0.
            normal[(i, i)] += if i < self.len { ridge } else { T::one() };
        }
        let rhs = self.d_f.transpose() * f;
        if let Some(c) = Cholesky::new(normal) {
            let gamma = c.solve(&rhs);
            let next = plain - (self.d_x + self.d_f * self.mixing) * gamma;
            if next.iter().all(|v| v.is_finite()) {
                return next;
            }
        }
        self.reset();
        plain
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Vector2, Vector4};

    struct Rosenbrock;
    impl Objective<f64, 2> for Rosenbrock {
        fn cost_grad(&self, x: &Vector2<f64>) -> (f64, Vector2<f64>) {
            let (a, b) = (x[0], x[1]);
            let c = (1.0 - a).powi(2) + 100.0 * (b - a * a).powi(2);
            let g = Vector2::new(
                -2.0 * (1.0 - a) - 400.0 * a * (b - a * a),
                200.0 * (b - a * a),
            );
            (c, g)
        }
    }

    #[test]
    fn minimises_rosenbrock_with_backtracking() {
        let opts = BfgsOptions {
            step_tol: 1e-12,
            grad_tol: 1e-9,
            max_iter: 200,
        };
        let m = bfgs(&Rosenbrock, Vector2::new(-1.2, 1.0), &opts).unwrap();
        assert!((m.x - Vector2::new(1.0, 1.0)).amax() < 1e-6, "{:?}", m);
    }

    /// f(x) = 1/2 x^T A x - b^T x with a known minimiser A^-1 b.
    struct Quadratic {
        a: SMatrix<f64, 4, 4>,
        b: Vector4<f64>,
    }
    impl Objective<f64, 4> for Quadratic {
        fn cost_grad(&self, x: &Vector4<f64>) -> (f64, Vector4<f64>) {
            let ax = self.a * x;
            (0.5 * x.dot(&ax) - self.b.dot(x), ax - self.b)
        }
        fn curvature(&self, d: &Vector4<f64>) -> Option<f64> {
            Some(d.dot(&(self.a * d)))
        }
    }

    #[test]
    fn exact_line_search_terminates_on_a_quadratic() {
        let l = SMatrix::<f64, 4, 4>::from_fn(|i, j| {
            if j <= i {
                1.0 + (i * 3 + j) as f64 * 0.1
            } else {
                0.0
            }
        });
        let q = Quadratic {
            a: l * l.transpose(),
            b: Vector4::new(1.0, -2.0, 0.5, 3.0),
        };
        let want = q.a.lu().solve(&q.b).unwrap();
        let opts = BfgsOptions {
            step_tol: 1e-14,
            grad_tol: 1e-12,
            max_iter: 50,
        };
        let m = bfgs(&q, Vector4::zeros(), &opts).unwrap();
        assert!((m.x - want).amax() < 1e-9 * want.amax());
        // BFGS with exact line search is conjugate gradients on a quadratic:
        // at most N steps, plus the one that detects convergence.
        assert!(m.iterations <= 5, "{} iterations", m.iterations);
    }

    #[test]
    fn cap_is_reported() {
        let opts = BfgsOptions {
            step_tol: 0.0,
            grad_tol: 0.0,
            max_iter: 3,
        };
        let r = bfgs(&Rosenbrock, Vector2::new(-1.2, 1.0), &opts);
        assert_eq!(r.unwrap_err(), Error::NoConvergence { iterations: 3 });
    }

    #[test]
    fn anderson_accelerates_a_slow_linear_contraction() {
        // x = A x + c with spectral radius 0.95: plain iteration needs
        // hundreds of steps to 1e-12; Anderson(5) on a 3-D linear map
        // converges in a handful (it is GMRES in disguise).
        let a = nalgebra::Matrix3::new(0.95, 0.02, 0.0, 0.0, 0.90, 0.03, 0.01, 0.0, 0.80);
        let c = nalgebra::Vector3::new(1.0, -2.0, 0.5);
        let fixed = (nalgebra::Matrix3::identity() - a).try_inverse().unwrap() * c;
        let mut acc = Anderson::<f64, 3, 5>::new();
        let mut x = nalgebra::Vector3::zeros();
        let mut steps = 0;
        while (x - fixed).amax() > 1e-12 && steps < 100 {
            let g = a * x + c;
            x = acc.step(&x, &g);
            steps += 1;
        }
        assert!((x - fixed).amax() <= 1e-12, "{steps} steps");
        assert!(steps <= 12, "{steps} steps");
    }
}
