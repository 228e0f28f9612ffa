//! subMLE (design document, section 8): the paper's baseline, after
//! Vasconcelos et al. (2011).
//!
//! Approximate maximum likelihood with isotropic noise (first order,
//! Sampson-type), in normalised coordinates:
//!
//! ```text
//! A = T^-1 upper triangular (6 parameters), b' (3)
//! e_i = x_i - b',  u_i = A e_i,  z_i = |u_i|^2 - 1,  w_i = |A^T u_i|^2
//! minimise  J = sum z_i^2 / w_i
//! ```
//!
//! With `M = A^T A` and `m_i = M e_i`: `z_i = e_i^T m_i - 1`,
//! `w_i = |m_i|^2`, and
//!
//! ```text
//! dJ/dM (symmetric) = sum (2 z_i / w_i) e_i e_i^T - (z_i^2 / w_i^2) (e_i m_i^T + m_i e_i^T)
//! dJ/dA             = 2 A dJ/dM   (upper triangle taken)
//! dJ/db'            = sum -(4 z_i / w_i) m_i + (2 z_i^2 / w_i^2) M m_i
//! ```
//!
//! Started at the LS fit (`A0` = the upper Cholesky factor of `M'`) and
//! minimised by the shared BFGS with the backtracking line search; every
//! evaluation is one O(n) pass over the samples, which is why this method
//! costs many times ADC2's. The diagonal of `A` needs no sign constraint:
//! `J` depends on `A` only through `M`.

use nalgebra::{Matrix3, SVector, Vector3};

use crate::numerics::linalg::{cholesky, columns_of, from_columns, sym_sqrt};
use crate::numerics::quasi_newton::{bfgs, BfgsOptions, Objective};
use crate::robust::runs::Runs;
use crate::sample::Sample;
use crate::steps::ellipsoid::Ellipsoid;
use crate::steps::methods::{Estimate, Weights};
use crate::steps::moments::BLOCK;
use crate::steps::normalize::Normalization;
use crate::steps::rules::Gate;
use crate::{Config, Error, Real, Warnings};

/// Number of parameters: the upper triangle of `A` (6) and `b'` (3).
pub const PARAMS: usize = 9;

/// The parameters: `A`'s upper triangle, row by row, then `b'`. Written
/// out rather than looped over an index table, which left bounds-check
/// paths the optimiser could not remove at opt-level "s".
fn unpack<T: Real>(x: &SVector<T, PARAMS>) -> (Matrix3<T>, Vector3<T>) {
    let z = T::zero();
    let a = Matrix3::new(x[0], x[1], x[2], z, x[3], x[4], z, z, x[5]);
    (a, Vector3::new(x[6], x[7], x[8]))
}

/// `A`'s upper triangle and `b'` as a parameter vector (see [`unpack`]).
fn pack<T: Real>(a: &Matrix3<T>, b: &Vector3<T>) -> SVector<T, PARAMS> {
    SVector::<T, PARAMS>::from([a.m11, a.m12, a.m13, a.m22, a.m23, a.m33, b.x, b.y, b.z])
}

/// The subMLE cost over the samples, normalised by `norm`.
pub struct SubMleObjective<'a, T: Real, S: Sample> {
    samples: &'a [S],
    norm: &'a Normalization<T>,
    gate: Gate<'a, T>,
    runs: Runs,
}

impl<'a, T: Real, S: Sample> SubMleObjective<'a, T, S> {
    /// The objective over the rows `gate` passes outside the spans of
    /// `runs`.
    pub(crate) fn gated(
        samples: &'a [S],
        norm: &'a Normalization<T>,
        gate: Gate<'a, T>,
        runs: Runs,
    ) -> Self {
        Self {
            samples,
            norm,
            gate,
            runs,
        }
    }
}

impl<T: Real, S: Sample> Objective<T, PARAMS> for SubMleObjective<'_, T, S> {
    fn cost_grad(&self, x: &SVector<T, PARAMS>) -> (T, SVector<T, PARAMS>) {
        let (a, b) = unpack(x);
        let m = a.transpose() * a;
        let two = T::lit(2.0);
        let mut cost = T::zero();
        let mut dm = Matrix3::zeros();
        let mut db = Vector3::zeros();
        for (_, prev, block) in self.runs.pieces(self.samples, BLOCK) {
            let (mut c_blk, mut dm_blk, mut db_blk) =
                (T::zero(), Matrix3::zeros(), Vector3::zeros());
            for y in self.gate.rows(block, prev) {
                let e = self.norm.forward(y) - b;
                let me = m * e;
                let z = e.dot(&me) - T::one();
                let w = me.norm_squared();
                if !(w > T::zero()) {
                    // A sample at the centre carries no direction.
                    continue;
                }
                let zw = z / w;
                c_blk += z * zw;
                let c1 = two * zw;
                let c2 = zw * zw;
                dm_blk += e * e.transpose() * c1 - (e * me.transpose() + me * e.transpose()) * c2;
                db_blk += me * (-two * c1) + m * me * (two * c2);
            }
            cost += c_blk;
            dm += dm_blk;
            db += db_blk;
        }
        let da = a * dm * two;
        (cost, pack(&da, &db))
    }
}

/// subMLE from the LS fit, over the rows the weights' gate passes (the drop rules and the
/// screening ball). No residual cut: the weights would change between the
/// cost evaluations of one BFGS solve, and the cost with them; subMLE
/// starts from the robust LS fit instead.
pub(crate) fn step<T: Real, S: Sample>(
    samples: &[S],
    norm: &Normalization<T>,
    ls: &Ellipsoid<T>,
    config: &Config,
    weights: &Weights<T>,
) -> Result<Estimate<T>, Error> {
    // A0^T A0 = M' with A0 upper triangular: the transposed Cholesky factor.
    // The array factor is L[row][column]; read as nalgebra's column-major
    // storage it is L^T, the upper factor.
    let a0 = from_columns(cholesky(&columns_of(&ls.m)).ok_or(Error::NotAnEllipsoid)?);
    let x0 = pack(&a0, &ls.centre);
    let objective = SubMleObjective::gated(samples, norm, weights.gate, *weights.runs);
    // The paper's stop: a step below 1e-6 of the parameter scale. The
    // gradient test only ends exact fits (noise-free data: J = 0 at the
    // LS start already).
    let n = T::from_count(samples.len());
    let opts = BfgsOptions {
        step_tol: T::lit(1e-6),
        grad_tol: T::lit(8.0) * n * T::EPSILON,
        max_iter: config.max_iterations,
    };
    let counter = Counting::new(&objective);
    let min = bfgs(&counter, x0, &opts)?;
    let (a, centre) = unpack(&min.x);
    Ok(Estimate {
        centre,
        w: sym_sqrt(&(a.transpose() * a))?,
        iterations: min.iterations,
        passes: counter.count(),
        warnings: Warnings::NONE,
        directions: None,
        sigma: None,
        max_residual: None,
        beyond_tails_limit: false,
    })
}

/// Counts the evaluations (passes over the samples) of an objective.
struct Counting<'a, O> {
    inner: &'a O,
    count: core::cell::Cell<u32>,
}

impl<'a, O> Counting<'a, O> {
    fn new(inner: &'a O) -> Self {
        Self {
            inner,
            count: core::cell::Cell::new(0),
        }
    }

    fn count(&self) -> u32 {
        self.count.get()
    }
}

impl<T: Real, O: Objective<T, PARAMS>> Objective<T, PARAMS> for Counting<'_, O> {
    fn cost_grad(&self, x: &SVector<T, PARAMS>) -> (T, SVector<T, PARAMS>) {
        self.count.set(self.count.get().saturating_add(1));
        self.inner.cost_grad(x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn analytic_gradient_matches_central_differences() {
        // A small noisy ellipsoid in normalised-looking coordinates.
        let samples: [[f64; 3]; 40] = core::array::from_fn(|i| {
            let i = i as f64;
            let z = 1.0 - 2.0 * (i + 0.5) / 40.0;
            let (r, phi) = (libm::sqrt(1.0 - z * z), i * 2.4);
            let wobble = 0.02 * libm::sin(i * 1.3);
            [
                1.2 * r * libm::cos(phi) + 0.1 + wobble,
                0.8 * r * libm::sin(phi) - 0.2,
                z + 0.05 - wobble,
            ]
        });
        let norm = Normalization {
            centre: Vector3::zeros(),
            scale: 1.0,
            inv_scale: 1.0,
        };
        let f = SubMleObjective::gated(&samples, &norm, Gate::PLAIN, Runs::NONE);
        let x = SVector::<f64, PARAMS>::from_column_slice(&[
            0.9, 0.05, -0.02, 1.2, 0.03, 1.05, 0.08, -0.15, 0.04,
        ]);
        let (_, g) = f.cost_grad(&x);
        for k in 0..PARAMS {
            let h = 1e-6;
            let mut xp = x;
            let mut xm = x;
            xp[k] += h;
            xm[k] -= h;
            let fd = (f.cost_grad(&xp).0 - f.cost_grad(&xm).0) / (2.0 * h);
            assert!(
                libm::fabs(fd - g[k]) < 1e-6 * (1.0 + libm::fabs(fd)),
                "parameter {k}: analytic {} vs numeric {fd}",
                g[k]
            );
        }
    }
}
