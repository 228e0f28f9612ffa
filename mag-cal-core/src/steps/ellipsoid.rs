//! Step 1 of Algorithm 1: the algebraic least-squares ellipsoid fit
//! (design document, section 3), in three variants sharing the moments.

use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

#[cfg(feature = "lg10")]
use crate::numerics::linalg::{cholesky, min_max, solve_lower, solve_lower_transposed};
use crate::numerics::linalg::{cholesky_in_place, cholesky_solve, solve3, sym_sqrt_and_inv_sqrt};
#[cfg(any(feature = "svd10", feature = "lg10"))]
use crate::numerics::linalg::{columns_of, sym_eigen};
use crate::{Error, Real};

/// Which algebraic least-squares solve turns the moments into a quadric.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum LsVariant {
    /// Constant coefficient fixed to `-1`, a 9x9 Cholesky solve. The
    /// cheapest, and the best start on partial coverage; legitimate because
    /// after centring the origin lies inside the ellipsoid.
    #[default]
    Ls9,
    /// Coefficients = eigenvector of the smallest eigenvalue of the 10x10
    /// scatter (closest to the paper's reference \[4\]). Its normalisation
    /// `|v| = 1` counts each off-diagonal coefficient of the quadric once,
    /// so unlike the other variants it is not rotation-equivariant: on noisy
    /// data the fit depends slightly on the sensor frame.
    Svd10,
    /// Li and Griffiths' ellipsoid-specific fit (`4J - I^2 = 1`, with
    /// `I = tr A`, `J` the sum of the principal 2x2 minors of `A`), as used
    /// by Magneto. The most biased under noise, and limited by its
    /// constraint: an ellipsoid with `4J - I^2 <= 0` (elongated: e.g. semi-axes
    /// 1.46, 1.07, 0.5) cannot be represented, so even noise-free samples of
    /// it give a wrong ellipsoid (the report's radial RMS shows it).
    LiGriffiths,
}

impl LsVariant {
    /// Short lower-case name (`ls9`, `svd10`, `lg10`), as used by the CLI.
    pub const fn name(self) -> &'static str {
        match self {
            LsVariant::Ls9 => "ls9",
            LsVariant::Svd10 => "svd10",
            LsVariant::LiGriffiths => "lg10",
        }
    }

    /// The cargo feature that compiles the variant in (`""` for LS9, always
    /// there).
    pub const fn feature(self) -> &'static str {
        match self {
            LsVariant::Ls9 => "",
            LsVariant::Svd10 => "svd10",
            LsVariant::LiGriffiths => "lg10",
        }
    }
}

/// An ellipsoid `(x - c)^T M (x - c) = 1`, in normalised coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ellipsoid<T: Real> {
    /// Centre `b'`.
    pub centre: Vector3<T>,
    /// Shape `M'`, symmetric positive definite.
    pub m: Matrix3<T>,
    /// `W' = M'^(1/2)`: maps the ellipsoid onto the unit sphere.
    pub w: Matrix3<T>,
    /// `T' = M'^(-1/2)`: maps the unit sphere onto the ellipsoid.
    pub t: Matrix3<T>,
}

/// Fits an ellipsoid to the 10x10 scatter with the chosen variant.
#[cfg(feature = "bench-internals")]
pub fn fit_scatter<T: Real>(
    s: &SMatrix<T, 10, 10>,
    variant: LsVariant,
) -> Result<Ellipsoid<T>, Error> {
    fit_with(s, solver(variant)?)
}

/// A variant's solve: quadric coefficients from the scatter.
pub type Solve<T> = fn(&SMatrix<T, 10, 10>) -> Result<SVector<T, 10>, Error>;

/// The solve of a variant (inlined, so that a constant variant links only
/// its own solve), or [`Error::NotEnabled`] when its cargo feature is off.
#[inline(always)]
pub fn solver<T: Real>(variant: LsVariant) -> Result<Solve<T>, Error> {
    match variant {
        LsVariant::Ls9 => Ok(ls9),
        #[cfg(feature = "svd10")]
        LsVariant::Svd10 => Ok(svd10),
        #[cfg(feature = "lg10")]
        LsVariant::LiGriffiths => Ok(li_griffiths),
        #[allow(unreachable_patterns)] // with every variant enabled
        other => Err(Error::NotEnabled {
            feature: other.feature(),
        }),
    }
}

/// Fits an ellipsoid to the scatter with a given solve.
pub fn fit_with<T: Real>(s: &SMatrix<T, 10, 10>, solve: Solve<T>) -> Result<Ellipsoid<T>, Error> {
    // On the slice: nalgebra's own iterator over a matrix is a longer
    // loop at opt-level "s" (with the scan's centre and the calibration's
    // hard iron and scale, 200 bytes of flash, LS9 + ADC2 without `robust`).
    if !s.as_slice().iter().all(|v| v.is_finite()) {
        return Err(Error::OutOfRange);
    }
    from_quadric(&solve(s)?)
}

/// `v = [v9, -1]` with `S9 v9 = sum phi9` (Cholesky). Out of line: its
/// arrays then occupy stack only during the call (docs/benchmarks.md).
#[inline(never)]
pub(crate) fn ls9<T: Real>(s: &SMatrix<T, 10, 10>) -> Result<SVector<T, 10>, Error> {
    // Straight from `s`, not through a 10x10 copy (400 bytes of stack in
    // `f32` under the robust path's refits).
    // The scatter is symmetric (to the bit: each entry is a moment times
    // a factor, `Moments::scatter`): its columns are its rows. Column by
    // column, not entry by entry through nalgebra's indexing (36 bytes of
    // flash more, LS9 + ADC2 without `robust`; 40 with it).
    let mut s9 = [[T::zero(); 9]; 9];
    let mut rhs = [T::zero(); 9];
    for ((row, r), column) in s9.iter_mut().zip(rhs.iter_mut()).zip(&s.data.0) {
        let [head @ .., last] = *column;
        *row = head;
        *r = last;
    }
    if !cholesky_in_place(&mut s9) {
        return Err(Error::SingularSystem);
    }
    let [a, b, c, d, e, f, g, h, i] = cholesky_solve(&s9, &rhs);
    Ok(SVector::from([a, b, c, d, e, f, g, h, i, -T::one()]))
}

/// `v` = eigenvector of the smallest eigenvalue of `S`. Out of line, as
/// [`ls9`].
#[cfg(feature = "svd10")]
#[inline(never)]
fn svd10<T: Real>(s: &SMatrix<T, 10, 10>) -> Result<SVector<T, 10>, Error> {
    let eig = sym_eigen(&columns_of(s))?;
    Ok(SVector::from(eig.min_vector()))
}

/// Li and Griffiths: `(S11 - S12 S22^-1 S21) v1 = lambda C1 v1` for the one
/// positive `lambda`, `v2 = -S22^-1 S21 v1`.
///
/// Solved in symmetric form: with `Red = L L^T` (Cholesky),
/// `L^-1 C1 L^-T w = mu w`, `mu = 1 / lambda`, `v1 = L^-T w`. `Red` is
/// positive semi-definite and `C1` has one positive eigenvalue, so exactly
/// one `mu` is positive: the largest. Noise-free data make `Red` singular
/// (the exact quadric is its null vector, `lambda = 0`): only when the
/// Cholesky fails, a ridge of 16 ulps of its trace keeps it defined and moves
/// the solution by about that relative amount. (Always adding the ridge cost
/// f32 fits on noisy data 3e-5 relative, against 1e-6 without it.)
#[allow(clippy::needless_range_loop)] // matrix notation, as in linalg
#[cfg(feature = "lg10")]
#[inline(never)] // as ls9
fn li_griffiths<T: Real>(s: &SMatrix<T, 10, 10>) -> Result<SVector<T, 10>, Error> {
    let s = columns_of(s);
    let zero = T::zero();
    // The blocks: S11 (6x6), S12 (rows 0-5, columns 6-9), S22 (4x4).
    let mut s22 = [[zero; 4]; 4];
    let mut s12 = [[zero; 4]; 6];
    for i in 0..4 {
        for j in 0..4 {
            s22[i][j] = s[6 + i][6 + j];
        }
    }
    for i in 0..6 {
        for j in 0..4 {
            s12[i][j] = s[i][6 + j];
        }
    }
    let l22 = cholesky(&s22).ok_or(Error::SingularSystem)?;
    // K = S22^-1 S21 (4x6), kept by columns: k[j] = S22^-1 (row j of S12).
    let mut k = [[zero; 4]; 6];
    for (kj, row) in k.iter_mut().zip(&s12) {
        *kj = cholesky_solve(&l22, row);
    }
    // Red = S11 - S12 K, symmetrised; trace for the ridge.
    let mut red = [[zero; 6]; 6];
    let mut trace = zero;
    for i in 0..6 {
        for j in 0..6 {
            let mut sik = zero;
            let mut sjk = zero;
            for m in 0..4 {
                sik += s12[i][m] * k[j][m];
                sjk += s12[j][m] * k[i][m];
            }
            red[i][j] = (s[i][j] - sik) * T::lit(0.5) + (s[j][i] - sjk) * T::lit(0.5);
        }
        trace += red[i][i];
    }
    let l = match cholesky(&red) {
        Some(l) => l,
        None => {
            let ridge = trace * T::EPSILON * T::lit(16.0);
            for (i, row) in red.iter_mut().enumerate() {
                if let Some(d) = row.get_mut(i) {
                    *d += ridge;
                }
            }
            cholesky(&red).ok_or(Error::SingularSystem)?
        }
    };
    // C1: -1 on the first diagonal block, +1 off it (the I^2 - 4J form),
    // -4 for the cross terms' diagonal.
    let mut c1 = [[zero; 6]; 6];
    for i in 0..3 {
        for j in 0..3 {
            c1[i][j] = if i == j { -T::one() } else { T::one() };
        }
        c1[i + 3][i + 3] = T::lit(-4.0);
    }
    // A = L^-1 C1 by columns (C1 is symmetric: its rows are its columns),
    // then L^-1 A^T = L^-1 C1 L^-T by columns.
    let mut a = [[zero; 6]; 6];
    for (aj, cj) in a.iter_mut().zip(&c1) {
        *aj = solve_lower(&l, cj);
    }
    let mut kmat = [[zero; 6]; 6];
    for j in 0..6 {
        let mut row = [zero; 6];
        for (r, aj) in row.iter_mut().zip(&a) {
            *r = aj[j];
        }
        kmat[j] = solve_lower(&l, &row);
    }
    let eig = sym_eigen(&kmat)?;
    if !(min_max(&eig.values).1 > zero) {
        return Err(Error::NotAnEllipsoid);
    }
    let v1 = solve_lower_transposed(&l, &eig.max_vector());
    let mut v = SVector::<T, 10>::zeros();
    for i in 0..6 {
        v[i] = v1[i];
    }
    for m in 0..4 {
        let mut kv = zero;
        for (kj, &x) in k.iter().zip(&v1) {
            kv += kj[m] * x;
        }
        v[6 + m] = -kv;
    }
    if !v.iter().all(|x| x.is_finite()) {
        return Err(Error::SingularSystem);
    }
    Ok(v)
}

/// From quadric coefficients `v` to the ellipsoid: `A`, `p`,
/// `b' = -A^-1 p`, `k = b'^T A b' - v9`, `M' = A / k`. The sign of `v` does
/// not matter (it cancels in `A / k`). Refuses anything but an ellipsoid.
// Out of line: its eigen decomposition's locals then take stack after the
// solve has returned, not under it.
#[inline(never)]
pub fn from_quadric<T: Real>(v: &SVector<T, 10>) -> Result<Ellipsoid<T>, Error> {
    // On scalars, not nalgebra's matrices and iterators nor arrays mapped
    // (copied on the stack at opt-level "s"): those took 180 bytes of
    // flash more (LS9 + ADC2 without `robust`; 184 with it; the same
    // operations in the same order).
    let [v] = v.data.0;
    if !v.iter().all(|x| x.is_finite()) {
        return Err(Error::SingularSystem);
    }
    let [a00, a11, a22, a01, a02, a12, p0, p1, p2, v9] = v;
    // A is definite (of either sign) for an ellipsoid; Cramer's rule
    // handles both.
    let a = [[a00, a01, a02], [a01, a11, a12], [a02, a12, a22]];
    let [c0, c1, c2] = solve3(&a, &[p0, p1, p2]).ok_or(Error::NotAnEllipsoid)?;
    let (b0, b1, b2) = (-c0, -c1, -c2);
    let k = b0 * (a00 * b0 + a01 * b1 + a02 * b2)
        + b1 * (a01 * b0 + a11 * b1 + a12 * b2)
        + b2 * (a02 * b0 + a12 * b1 + a22 * b2)
        - v9;
    if !(k != T::zero() && b0.is_finite() && b1.is_finite() && b2.is_finite()) {
        return Err(Error::NotAnEllipsoid);
    }
    // Each distinct entry of the symmetric `A / k` once.
    let (m00, m11, m22, m01, m02, m12) = (a00 / k, a11 / k, a22 / k, a01 / k, a02 / k, a12 / k);
    let m = Matrix3::new(m00, m01, m02, m01, m11, m12, m02, m12, m22);
    let centre = Vector3::new(b0, b1, b2);
    let (w, t) = sym_sqrt_and_inv_sqrt(&m)?;
    Ok(Ellipsoid { centre, m, w, t })
}
