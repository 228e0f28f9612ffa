//! Step 4 of Algorithm 1 for the iterative methods: a fixed-size BFGS
//! quasi-Newton solver (ADC1 and subMLE; compiled with their features),
//! and the fixed-point accelerator of iterated ADC2 (with its feature).
//! ADC2 itself needs neither: its cost is exactly quadratic and solved in
//! closed form ([`crate::steps::methods::adc2::solve`]).
//!
//! Parameters live in a stack vector `SVector<T, N>`, the inverse-Hessian
//! approximation in an `N x N` stack matrix; nothing is allocated.
//!
//! Line search: an objective that is exactly quadratic reports its
//! curvature `d^T H d` along a direction, and the step is the closed-form
//! minimiser `alpha = -g^T d / d^T H d`. Other objectives get a backtracking
//! (Armijo) search. Stop criteria, checked every iteration:
//! - the step is below `step_tol` relative to the parameter scale,
//!   `max|dx| <= step_tol * (1 + max|x|)` (the paper's criterion, `1e-6`);
//! - or the gradient is below `grad_tol` (`max|g| <= grad_tol`);
//! - the iteration cap `max_iter` turns into [`Error::NoConvergence`].
//!
//! The arithmetic is written as plain loops over fixed-size arrays (the
//! components of an `SVector` are its `[T; N]` storage): the loop bounds
//! are compile-time constants, so there are no bounds checks and no panic
//! paths, and every update (the `N x N` inverse Hessian included) is done
//! in place, without `N x N` temporaries on the stack.

use nalgebra::SVector;

use crate::numerics::linalg::dot;
#[cfg(any(feature = "adc1", feature = "submle"))]
use crate::Error;
use crate::Real;

/// A smooth objective over `N` parameters.
#[cfg(any(feature = "adc1", feature = "submle"))]
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
#[cfg(any(feature = "adc1", feature = "submle"))]
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
#[cfg(any(feature = "adc1", feature = "submle"))]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Stop {
    /// The step fell below the step tolerance.
    Step,
    /// The gradient fell below the gradient tolerance.
    Gradient,
}

/// The minimiser found.
#[cfg(any(feature = "adc1", feature = "submle"))]
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
#[cfg(any(feature = "adc1", feature = "submle"))]
const MAX_BACKTRACK: u32 = 60;
/// Armijo sufficient-decrease constant.
#[cfg(any(feature = "adc1", feature = "submle"))]
const ARMIJO: f64 = 1e-4;

/// The components of a stack vector.
#[inline(always)]
fn arr<T: Real, const N: usize>(v: &SVector<T, N>) -> &[T; N] {
    &v.data.0[0]
}

/// The components of a stack vector, mutable.
#[inline(always)]
fn arr_mut<T: Real, const N: usize>(v: &mut SVector<T, N>) -> &mut [T; N] {
    &mut v.data.0[0]
}

/// `max |a_i|` (NaN components are skipped, as in nalgebra's `amax`).
#[cfg(any(feature = "adc1", feature = "submle"))]
#[inline]
fn amax<T: Real, const N: usize>(a: &[T; N]) -> T {
    a.iter().fold(T::zero(), |m, &v| {
        let v = v.abs();
        if v > m {
            v
        } else {
            m
        }
    })
}

/// `x + alpha d`.
#[cfg(any(feature = "adc1", feature = "submle"))]
#[inline]
fn along<T: Real, const N: usize>(x: &SVector<T, N>, d: &SVector<T, N>, alpha: T) -> SVector<T, N> {
    let mut p = *x;
    for (pi, &di) in arr_mut(&mut p).iter_mut().zip(arr(d)) {
        *pi += di * alpha;
    }
    p
}

/// Sets `h` to the identity.
#[cfg(any(feature = "adc1", feature = "submle"))]
fn set_identity<T: Real, const N: usize>(h: &mut [[T; N]; N]) {
    for (i, row) in h.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = if i == j { T::one() } else { T::zero() };
        }
    }
}

/// Copies the lower triangle of `h` onto the upper one.
// Triangular loops: both indices are below `N`.
#[cfg(any(feature = "adc1", feature = "submle"))]
#[allow(clippy::needless_range_loop)]
fn mirror_lower<T: Real, const N: usize>(h: &mut [[T; N]; N]) {
    for i in 0..N {
        for j in 0..i {
            h[j][i] = h[i][j];
        }
    }
}

/// Minimises `f` from `x0` with BFGS.
#[cfg(any(feature = "adc1", feature = "submle"))]
pub fn bfgs<T: Real, F: Objective<T, N>, const N: usize>(
    f: &F,
    x0: SVector<T, N>,
    opts: &BfgsOptions<T>,
) -> Result<Minimum<T, N>, Error> {
    let mut x = x0;
    let (mut cost, mut g) = f.cost_grad(&x);
    // The inverse-Hessian approximation, row by row. It stays exactly
    // symmetric: the start is, and the update below computes the lower
    // triangle and copies it to the upper one.
    let mut h_inv = [[T::zero(); N]; N];
    set_identity(&mut h_inv);
    let mut scaled = false;
    // The search direction, then (scaled in place) the step taken.
    let mut d = SVector::<T, N>::zeros();
    for iteration in 0..opts.max_iter {
        let ga = arr(&g);
        if !cost.is_finite() || !ga.iter().all(|v| v.is_finite()) {
            return Err(Error::SingularSystem);
        }
        if amax(ga) <= opts.grad_tol {
            return Ok(Minimum {
                x,
                cost,
                iterations: iteration,
                stop: Stop::Gradient,
            });
        }
        // d = -H g
        for (di, row) in arr_mut(&mut d).iter_mut().zip(&h_inv) {
            *di = -dot(row, ga);
        }
        let mut slope = dot(ga, arr(&d));
        if !(slope < T::zero()) {
            // Rounding destroyed positive definiteness: restart from steepest descent.
            set_identity(&mut h_inv);
            scaled = false;
            for (di, &gi) in arr_mut(&mut d).iter_mut().zip(ga) {
                *di = -gi;
            }
            slope = -dot(ga, ga);
        }
        // Quadratic objectives: closed-form step, and the new cost from the
        // exact line model `f + alpha g^T d + alpha^2/2 d^T H d`, which
        // never cancels. Others: a backtracking search that hands back the
        // cost and gradient of the accepted point (one evaluation each).
        let (alpha, cost_new, g_new) = match f.curvature(&d) {
            Some(c) => {
                if !(c > T::zero()) {
                    return Err(Error::SingularSystem);
                }
                let alpha = -slope / c;
                let (_, g_new) = f.cost_grad(&along(&x, &d, alpha));
                (alpha, cost + alpha * slope * T::lit(0.5), g_new)
            }
            None => match backtrack(f, &x, cost, slope, &d, scaled) {
                Some(accepted) => accepted,
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
        // s = alpha d (in place), x <- x + s (the point just evaluated).
        for (si, xi) in arr_mut(&mut d).iter_mut().zip(arr_mut(&mut x)) {
            *si *= alpha;
            *xi += *si;
        }
        let s = arr(&d);
        let mut y = *arr(&g_new);
        for (yi, &gi) in y.iter_mut().zip(arr(&g)) {
            *yi -= gi;
        }
        let sy = dot(s, &y);
        if sy > T::zero() {
            if !scaled {
                // Nocedal & Wright (6.20): scale the initial inverse Hessian.
                let k = sy / dot(&y, &y);
                for v in h_inv.iter_mut().flatten() {
                    *v *= k;
                }
                scaled = true;
            }
            let rho = T::one() / sy;
            let mut hy = [T::zero(); N];
            for (hyi, row) in hy.iter_mut().zip(&h_inv) {
                *hyi = dot(row, &y);
            }
            let yhy = dot(&y, &hy);
            // H+ = H - rho (s (Hy)^T + (Hy) s^T) + (rho^2 y^T H y + rho) s s^T,
            // entry by entry, in place.
            let neg_rho = -rho;
            let c = rho * rho * yhy + rho;
            // The lower triangle, then its mirror (the update is symmetric).
            for (i, ((row, &si), &hyi)) in h_inv.iter_mut().zip(s).zip(&hy).enumerate() {
                for ((hij, &sj), &hyj) in row.iter_mut().zip(s).zip(&hy).take(i + 1) {
                    *hij += (si * hyj + hyi * sj) * neg_rho + si * sj * c;
                }
            }
            mirror_lower(&mut h_inv);
        }
        cost = cost_new;
        g = g_new;
        if amax(s) <= opts.step_tol * (T::one() + amax(arr(&x))) {
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
#[cfg(any(feature = "adc1", feature = "submle"))]
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
        T::one() / dot(arr(d), arr(d)).sqrt()
    };
    for _ in 0..MAX_BACKTRACK {
        let (c, g) = f.cost_grad(&along(x, d, alpha));
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

/// Solves `A z = b` for a symmetric positive definite `A` (its lower
/// triangle is read) by an `L D L^T` factorisation (Cholesky without square
/// roots). `None` when a pivot is not positive (or NaN): `A` is then not
/// numerically positive definite.
// Triangular loops: the indices are the algorithm; every one is below `M`.
#[allow(clippy::needless_range_loop)]
#[cfg(feature = "adc2-iter")]
fn ldl_solve<T: Real, const M: usize>(mut a: [[T; M]; M], mut b: [T; M]) -> Option<[T; M]> {
    let mut piv = [T::zero(); M];
    for j in 0..M {
        for k in 0..j {
            let mut v = a[j][k];
            for m in 0..k {
                v -= a[j][m] * a[k][m] * piv[m];
            }
            a[j][k] = v / piv[k];
        }
        let mut p = a[j][j];
        for k in 0..j {
            p -= a[j][k] * a[j][k] * piv[k];
        }
        if !(p > T::zero()) {
            return None;
        }
        piv[j] = p;
    }
    // L w = b, then D L^T z = w.
    for i in 0..M {
        for k in 0..i {
            let v = a[i][k] * b[k];
            b[i] -= v;
        }
    }
    for i in (0..M).rev() {
        b[i] /= piv[i];
        for k in i + 1..M {
            let v = a[k][i] * b[k];
            b[i] -= v;
        }
    }
    Some(b)
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
#[cfg(feature = "adc2-iter")]
#[derive(Clone, Debug)]
pub struct Anderson<T: Real, const D: usize, const M: usize> {
    mixing: T,
    /// Columns of `dX` (a ring buffer; unused columns are zero).
    d_x: [[T; D]; M],
    /// Columns of `dF`, likewise.
    d_f: [[T; D]; M],
    /// The previous iterate and its residual.
    last: Option<([T; D], [T; D])>,
    len: usize,
    next: usize,
}

#[cfg(feature = "adc2-iter")]
impl<T: Real, const D: usize, const M: usize> Default for Anderson<T, D, M> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(feature = "adc2-iter")]
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
            d_x: [[T::zero(); D]; M],
            d_f: [[T::zero(); D]; M],
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
        let xa = arr(x);
        let mut f = *arr(g);
        let mut plain = *x;
        for ((fi, pi), &xi) in f.iter_mut().zip(arr_mut(&mut plain)).zip(xa) {
            *fi -= xi;
            *pi = xi + *fi * self.mixing;
        }
        if let Some((x_prev, f_prev)) = self.last.replace((*xa, f)) {
            // `None` when M = 0 (no history is kept).
            if let Some(k) = self.next.checked_rem(M) {
                if let (Some(cx), Some(cf)) = (self.d_x.get_mut(k), self.d_f.get_mut(k)) {
                    for (c, (&a, &b)) in cx.iter_mut().zip(xa.iter().zip(&x_prev)) {
                        *c = a - b;
                    }
                    for (c, (&a, &b)) in cf.iter_mut().zip(f.iter().zip(&f_prev)) {
                        *c = a - b;
                    }
                }
                self.next = if k + 1 < M { k + 1 } else { 0 };
                self.len = (self.len + 1).min(M);
            }
        }
        if self.len == 0 {
            return plain;
        }
        // Normal equations dF^T dF gamma = dF^T f.
        let mut normal = [[T::zero(); M]; M];
        let mut rhs = [T::zero(); M];
        let mut trace = T::zero();
        for (i, ((row, ci), ri)) in normal
            .iter_mut()
            .zip(&self.d_f)
            .zip(rhs.iter_mut())
            .enumerate()
        {
            for (j, (nij, cj)) in row.iter_mut().zip(&self.d_f).enumerate() {
                *nij = dot(ci, cj);
                if i == j {
                    trace += *nij;
                }
            }
            *ri = dot(ci, &f);
        }
        let ridge = trace * T::EPSILON * T::lit(64.0);
        for (i, row) in normal.iter_mut().enumerate() {
            if let Some(v) = row.get_mut(i) {
                // Unused columns are zero: a unit diagonal keeps their gamma 0.
                *v += if i < self.len { ridge } else { T::one() };
            }
        }
        if let Some(gamma) = ldl_solve(normal, rhs) {
            // next = plain - (dX + beta dF) gamma, column by column.
            let mut acc = [T::zero(); D];
            for ((cx, cf), &gj) in self.d_x.iter().zip(&self.d_f).zip(&gamma) {
                for ((a, &xi), &fi) in acc.iter_mut().zip(cx).zip(cf) {
                    *a += (xi + fi * self.mixing) * gj;
                }
            }
            let mut next = plain;
            for (ni, &a) in arr_mut(&mut next).iter_mut().zip(&acc) {
                *ni -= a;
            }
            if arr(&next).iter().all(|v| v.is_finite()) {
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
    #[cfg(any(feature = "adc1", feature = "submle"))]
    use nalgebra::Vector2;
    use nalgebra::{SMatrix, Vector4};

    #[cfg(any(feature = "adc1", feature = "submle"))]
    struct Rosenbrock;
    #[cfg(any(feature = "adc1", feature = "submle"))]
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

    #[cfg(any(feature = "adc1", feature = "submle"))]
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
    #[cfg(any(feature = "adc1", feature = "submle"))]
    struct Quadratic {
        a: SMatrix<f64, 4, 4>,
        b: Vector4<f64>,
    }
    #[cfg(any(feature = "adc1", feature = "submle"))]
    impl Objective<f64, 4> for Quadratic {
        fn cost_grad(&self, x: &Vector4<f64>) -> (f64, Vector4<f64>) {
            let ax = self.a * x;
            (0.5 * x.dot(&ax) - self.b.dot(x), ax - self.b)
        }
        fn curvature(&self, d: &Vector4<f64>) -> Option<f64> {
            Some(d.dot(&(self.a * d)))
        }
    }

    #[cfg(any(feature = "adc1", feature = "submle"))]
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

    #[cfg(any(feature = "adc1", feature = "submle"))]
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
    #[cfg(feature = "adc2-iter")]
    fn ldl_solve_matches_lu_and_rejects_indefinite() {
        let l = SMatrix::<f64, 4, 4>::from_fn(|i, j| {
            if j <= i {
                1.0 + (i * 3 + j) as f64 * 0.1
            } else {
                0.0
            }
        });
        let a = l * l.transpose();
        let b = Vector4::new(1.0, -2.0, 0.5, 3.0);
        let want = a.lu().solve(&b).unwrap();
        let rows: [[f64; 4]; 4] = core::array::from_fn(|i| core::array::from_fn(|j| a[(i, j)]));
        let z = ldl_solve(rows, [1.0, -2.0, 0.5, 3.0]).unwrap();
        for (zi, wi) in z.iter().zip(want.iter()) {
            assert!((zi - wi).abs() < 1e-12 * want.amax(), "{z:?} vs {want}");
        }
        let mut singular = rows;
        singular[3] = singular[2];
        for row in singular.iter_mut() {
            row[3] = row[2];
        }
        assert!(ldl_solve(singular, [1.0; 4]).is_none());
        assert!(ldl_solve([[1.0, 2.0], [2.0, 1.0]], [1.0; 2]).is_none());
        assert!(ldl_solve([[f64::NAN]], [1.0]).is_none());
    }

    #[test]
    #[cfg(feature = "adc2-iter")]
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
