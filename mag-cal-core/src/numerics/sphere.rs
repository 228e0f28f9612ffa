//! A running algebraic sphere fit (Kasa) in `f32`: Welford sums of the
//! rows and of their squared norms, and the centre that minimises the
//! algebraic residual, with a weak prior towards the per-axis midrange.
//! The collector, the background calibrator and the screening's
//! re-centring use it.

use crate::numerics::linalg::dot;
use crate::tuning::PRIOR_WEIGHT;

/// Running sums of the centre estimate, in `f32`, on `x = y - origin`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct CentreFit {
    /// The first sample kept.
    origin: [f32; 3],
    /// Samples in the sums.
    n: f32,
    /// Mean of `x`.
    mean: [f32; 3],
    /// Mean of `q = |x|^2`.
    mean_q: f32,
    /// Covariance of `x` (population): `xx, xy, xz, yy, yz, zz`.
    cov: [f32; 6],
    /// Covariance of `x` with `q`.
    cov_q: [f32; 3],
    /// Per-axis minimum of `x`.
    lo: [f32; 3],
    /// Per-axis maximum of `x`.
    hi: [f32; 3],
}

impl CentreFit {
    pub(crate) const EMPTY: CentreFit = CentreFit {
        origin: [0.0; 3],
        n: 0.0,
        mean: [0.0; 3],
        mean_q: 0.0,
        cov: [0.0; 6],
        cov_q: [0.0; 3],
        lo: [0.0; 3],
        hi: [0.0; 3],
    };

    /// The sums with `y` added, or `None` when they would not be finite.
    pub(crate) fn with(&self, y: [f32; 3]) -> Option<CentreFit> {
        let mut f = *self;
        if f.n == 0.0 {
            f.origin = y;
        }
        let x = sub(y, f.origin);
        let q = dot(&x, &x);
        f.n += 1.0;
        let w = 1.0 / f.n;
        let dx = sub(x, f.mean);
        let dq = q - f.mean_q;
        for k in 0..3 {
            f.mean[k] += dx[k] * w;
            f.lo[k] = f.lo[k].min(x[k]);
            f.hi[k] = f.hi[k].max(x[k]);
        }
        f.mean_q += dq * w;
        // Welford, population form: C_n = C_{n-1} + (dx dx^T (n-1)/n - C_{n-1}) / n
        // with dx = x - mean_{n-1}; symmetric by construction.
        let v = 1.0 - w;
        let outer = [
            dx[0] * dx[0],
            dx[0] * dx[1],
            dx[0] * dx[2],
            dx[1] * dx[1],
            dx[1] * dx[2],
            dx[2] * dx[2],
        ];
        for (c, o) in f.cov.iter_mut().zip(outer) {
            *c += (o * v - *c) * w;
        }
        for (c, d) in f.cov_q.iter_mut().zip(dx) {
            *c += (d * dq * v - *c) * w;
        }
        let finite = f
            .mean
            .iter()
            .chain(&f.cov)
            .chain(&f.cov_q)
            .chain(&f.lo)
            .chain(&f.hi)
            .chain(core::iter::once(&f.mean_q))
            .all(|v| v.is_finite());
        finite.then_some(f)
    }

    /// Mean squared distance of the samples from `centre` (sensor units):
    /// `mean|x - c|^2 = mean(q) - 2 c.mean(x) + |c|^2` with `c` relative to
    /// the origin.
    pub(crate) fn radius_sq(&self, centre: [f32; 3]) -> f32 {
        let c = sub(centre, self.origin);
        self.mean_q - 2.0 * dot(&c, &self.mean) + dot(&c, &c)
    }

    /// The centre estimate, sensor units.
    pub(crate) fn centre(&self) -> [f32; 3] {
        let mid = [
            0.5 * (self.lo[0] + self.hi[0]),
            0.5 * (self.lo[1] + self.hi[1]),
            0.5 * (self.lo[2] + self.hi[2]),
        ];
        let [xx, xy, xz, yy, yz, zz] = self.cov;
        let trace = xx + yy + zz;
        let fallback = add(self.origin, mid);
        if !(trace > 0.0) || !trace.is_finite() {
            return fallback;
        }
        // (C + mu I) a = g + mu 2 m, divided by trace(C) so that the matrix
        // has entries of order one (its determinant cannot overflow).
        let s = 1.0 / trace;
        let mu = PRIOR_WEIGHT / 3.0;
        let (a11, a12, a13) = (xx * s + mu, xy * s, xz * s);
        let (a22, a23, a33) = (yy * s + mu, yz * s, zz * s + mu);
        let rhs = [
            self.cov_q[0] * s + 2.0 * mu * mid[0],
            self.cov_q[1] * s + 2.0 * mu * mid[1],
            self.cov_q[2] * s + 2.0 * mu * mid[2],
        ];
        // Cofactors of the symmetric matrix.
        let c11 = a22 * a33 - a23 * a23;
        let c12 = a13 * a23 - a12 * a33;
        let c13 = a12 * a23 - a13 * a22;
        let c22 = a11 * a33 - a13 * a13;
        let c23 = a12 * a13 - a11 * a23;
        let c33 = a11 * a22 - a12 * a12;
        let det = a11 * c11 + a12 * c12 + a13 * c13;
        if !(det > 0.0) {
            return fallback;
        }
        let h = 0.5 / det;
        let centre = [
            self.origin[0] + h * (c11 * rhs[0] + c12 * rhs[1] + c13 * rhs[2]),
            self.origin[1] + h * (c12 * rhs[0] + c22 * rhs[1] + c23 * rhs[2]),
            self.origin[2] + h * (c13 * rhs[0] + c23 * rhs[1] + c33 * rhs[2]),
        ];
        if centre.iter().all(|v| v.is_finite()) {
            centre
        } else {
            fallback
        }
    }
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn add(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_fit_is_exact_on_a_cap() {
        // A cap of a sixth of the sphere, centre (10, -20, 30), radius 5.
        let mut fit = CentreFit::EMPTY;
        for i in 0..200 {
            let z = 1.0 - (i as f32 + 0.5) / 600.0;
            let r = libm::sqrtf(1.0 - z * z);
            let phi = i as f32 * 2.399_963;
            let y = [
                10.0 + 5.0 * r * libm::cosf(phi),
                -20.0 + 5.0 * r * libm::sinf(phi),
                30.0 + 5.0 * z,
            ];
            fit = fit.with(y).unwrap();
        }
        let c = fit.centre();
        // The midrange is 4.2 units up (z = 34.17); the regularised fit is
        // pulled towards it by about 1 % along the cap's axis.
        let mid = fit.origin[2] + 0.5 * (fit.lo[2] + fit.hi[2]);
        assert!((mid - 34.17).abs() < 0.01, "{mid}");
        assert!(
            (c[0] - 10.0).abs() < 1e-3 && (c[1] + 20.0).abs() < 1e-3,
            "{c:?}"
        );
        assert!((c[2] - 30.0).abs() < 0.06, "{c:?}");
    }
}
