//! Small dense linear algebra on fixed-size arrays: a cyclic Jacobi
//! symmetric eigen-decomposition, Cholesky factorisation and triangular
//! solves, a Householder reduction to tridiagonal form, a 3x3 inverse and
//! solve, and the symmetric square roots of 3x3 matrices.
//!
//! Why not nalgebra's decompositions: they index with run-time indices
//! behind assertions, and those panic paths survive optimisation in the
//! firmware build (the link proof, `no-panic-check/`, listed them); their
//! generic code also cost flash and stack on the Cortex-M4F
//! (`docs/benchmarks.md`). Here every index runs over `0..N` of an
//! `[[T; N]; N]`, so the optimiser can prove each bounds check true and
//! remove it (the link proof checks that none is left), and every iteration
//! is capped. Matrices are symmetric where it matters, so the
//! row/column order of nalgebra's column-major storage does not.

// Index loops are the matrix notation here (`a[i][k] * x[k]`); zipped
// iterators over rows and columns would hide it.
#![allow(clippy::needless_range_loop)]

use nalgebra::{ArrayStorage, Matrix3, SMatrix};

use crate::{Error, Real};

/// Cap on Jacobi sweeps. A sweep visits every pair once and convergence is
/// quadratic: 3x3 matrices need 3-5 sweeps, 10x10 ones 6-10.
pub(crate) const MAX_SWEEPS: u32 = 60;

/// A square array matrix, `a[row][column]`.
pub(crate) type Mat<T, const N: usize> = [[T; N]; N];

/// The columns of an nalgebra matrix, `a[column][row]` (its storage).
///
/// The crate's small matrices are nalgebra's (`Matrix3`, `SMatrix`); the
/// decompositions of this module work on row arrays ([`Mat`], `a[row][column]`)
/// and the public API takes rows ([`rows`], [`from_rows`]). Every matrix
/// passed through `columns_of` / `from_columns` into a [`Mat`] function is
/// symmetric, where rows and columns agree; the one deliberate transpose
/// (subMLE's upper Cholesky factor) says so where it is taken.
pub(crate) fn columns_of<T: Real, const N: usize>(m: &SMatrix<T, N, N>) -> Mat<T, N> {
    m.data.0
}

/// The nalgebra matrix of an array (read as `a[column][row]`).
pub(crate) fn from_columns<T: Real, const N: usize>(a: Mat<T, N>) -> SMatrix<T, N, N> {
    SMatrix::from_data(ArrayStorage(a))
}

/// `a^T b`, summed in index order (`a[0] b[0] + a[1] b[1] + ...`): the one
/// dot product of the crate's arrays.
#[inline]
pub(crate) fn dot<T: Real, const N: usize>(a: &[T; N], b: &[T; N]) -> T {
    a.iter().zip(b).fold(T::zero(), |acc, (&p, &q)| acc + p * q)
}

/// The rows of a 3x3 matrix, `a[row][column]`: the public API's form.
pub(crate) fn rows<T: Real>(m: &Matrix3<T>) -> [[T; 3]; 3] {
    let c = m.data.0;
    [
        [c[0][0], c[1][0], c[2][0]],
        [c[0][1], c[1][1], c[2][1]],
        [c[0][2], c[1][2], c[2][2]],
    ]
}

/// The 3x3 matrix of rows `r` (`r[row][column]`).
pub(crate) fn from_rows<T: Real>(r: [[T; 3]; 3]) -> Matrix3<T> {
    Matrix3::new(
        r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2],
    )
}

/// The larger of two numbers, by one comparison (a NaN `a` is kept, a NaN
/// `b` ignored). `T::max` goes through libm's `fmaxf`/`fmax`: a function
/// call for NaN handling that callers here, on values already checked
/// finite, do not need.
#[inline(always)]
pub(crate) fn larger<T: Real>(a: T, b: T) -> T {
    if b > a {
        b
    } else {
        a
    }
}

/// The smaller of two numbers, by one comparison (see [`larger`]).
#[inline(always)]
pub(crate) fn smaller<T: Real>(a: T, b: T) -> T {
    if b < a {
        b
    } else {
        a
    }
}

/// Eigenvalues and eigenvectors of a symmetric matrix, unsorted:
/// `vectors[k]` belongs to `values[k]`, has unit length, and the vectors
/// are orthogonal to rounding.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SymEigen<T, const N: usize> {
    pub values: [T; N],
    pub vectors: Mat<T, N>,
}

// For `planar` (with `robust`) and the LS variants svd10 and lg10.
#[cfg(any(feature = "robust", feature = "svd10", feature = "lg10"))]
impl<T: Real, const N: usize> SymEigen<T, N> {
    /// Index of the smallest eigenvalue.
    #[cfg(any(feature = "robust", feature = "svd10"))]
    pub fn argmin(&self) -> usize {
        let mut k = 0;
        for i in 1..N {
            if self.values[i] < self.values[k] {
                k = i;
            }
        }
        k
    }

    /// Index of the largest eigenvalue.
    #[cfg(any(feature = "robust", feature = "lg10"))]
    pub fn argmax(&self) -> usize {
        let mut k = 0;
        for i in 1..N {
            if self.values[i] > self.values[k] {
                k = i;
            }
        }
        k
    }

    /// The eigenvector of the smallest eigenvalue.
    #[cfg(any(feature = "robust", feature = "svd10"))]
    pub fn min_vector(&self) -> [T; N] {
        let k = self.argmin();
        self.vectors.get(k).copied().unwrap_or([T::zero(); N])
    }

    /// The eigenvector of the largest eigenvalue.
    #[cfg(any(feature = "robust", feature = "lg10"))]
    pub fn max_vector(&self) -> [T; N] {
        let k = self.argmax();
        self.vectors.get(k).copied().unwrap_or([T::zero(); N])
    }
}

/// Symmetric eigen-decomposition by the cyclic Jacobi method (only the
/// symmetric part of `m` is used).
///
/// The matrix is first divided by its largest entry, so no square
/// overflows. A rotation is skipped (and its entry zeroed) once
/// `|a_pq| <= eps sqrt(|a_pp a_qq|)`; the sweep in which nothing rotates
/// ends the method. Every eigenvalue is then accurate to a few `eps` of the
/// largest, and for a definite matrix even the small ones to a few `eps` of
/// themselves. Non-finite entries give [`Error::SingularSystem`], a sweep
/// cap hit [`Error::NoConvergence`]. Eigenvalues of finite entries near the
/// type's maximum can overflow to infinity (e.g. `2 MAX`); callers refuse
/// them through their `!(x > limit)`-style checks.
pub(crate) fn sym_eigen<T: Real, const N: usize>(m: &Mat<T, N>) -> Result<SymEigen<T, N>, Error> {
    let mut eig = SymEigen {
        values: [T::zero(); N],
        vectors: [[T::zero(); N]; N],
    };
    if let Some(mut a4) = as_4x4(m) {
        let mut v4 = [[T::zero(); 4]; 4];
        let scale = jacobi(&mut a4, Some(&mut v4))?;
        scaled_diagonal(&a4, scale, &mut eig.values);
        for (r, r4) in eig.vectors.iter_mut().zip(&v4) {
            for (x, &x4) in r.iter_mut().zip(r4) {
                *x = x4;
            }
        }
        return Ok(eig);
    }
    let mut a = *m;
    let scale = jacobi(&mut a, Some(&mut eig.vectors))?;
    for i in 0..N {
        eig.values[i] = a[i][i] * scale;
    }
    Ok(eig)
}

/// The eigenvalues alone (cheaper: no vectors are accumulated).
pub(crate) fn sym_eigenvalues<T: Real, const N: usize>(m: &Mat<T, N>) -> Result<[T; N], Error> {
    if let Some(mut a4) = as_4x4(m) {
        let mut values = [T::zero(); N];
        let scale = jacobi(&mut a4, None)?;
        scaled_diagonal(&a4, scale, &mut values);
        return Ok(values);
    }
    let mut a = *m;
    let scale = jacobi(&mut a, None)?;
    let mut values = [T::zero(); N];
    for i in 0..N {
        values[i] = a[i][i] * scale;
    }
    Ok(values)
}

/// The smallest and the largest eigenvalue of a symmetric matrix
/// ([`sym_eigenvalues`], [`min_max`]): every caller of the eigenvalues
/// alone wants no more. Out of line, the eigenvalues never leave it: with
/// `min_max(&sym_eigenvalues(m)?)` at each caller (flatness, distortion,
/// coverage and Gram condition, the Gram check) LS9 + ADC2 took 112
/// bytes of flash more (31 684 -> 31 796; without `robust` 18 712 ->
/// 18 848, `bash bench.sh flash`).
#[inline(never)]
pub(crate) fn eigen_range<T: Real, const N: usize>(m: &Mat<T, N>) -> Result<(T, T), Error> {
    Ok(min_max(&sym_eigenvalues(m)?))
}

/// Smallest and largest of some values. Out of line, one copy for 3 and
/// one for 4 values in LS9 + ADC2 ([`eigen_range`],
/// [`positive_definite_eigen`]): inlined, it took as much flash (31 684 bytes)
/// and 16 bytes more without `robust` (18 712 -> 18 728, `bash bench.sh
/// flash`).
#[inline(never)]
pub(crate) fn min_max<T: Real, const N: usize>(values: &[T; N]) -> (T, T) {
    let first = values.first().copied().unwrap_or_else(T::zero);
    let (mut lo, mut hi) = (first, first);
    for &x in values {
        lo = smaller(lo, x);
        hi = larger(hi, x);
    }
    (lo, hi)
}

/// A 3x3 matrix as the 4x4 one with a zero last row and column, for
/// [`jacobi`]: the 3x3 eigenvalues (flatness, distortion, coverage, the
/// square root of `M`) and the 4x4 ones (the Gram condition) then share
/// one copy of the iteration. The same rotations in the same order (one
/// with the zero row is skipped: its entry is zero), so the same values
/// and vectors to the bit. `None` unless `N` is 3. LS9 + ADC2 on a
/// Cortex-M4F, measured at `9db2c0e` (not since): 536 bytes less flash
/// (32 952 -> 32 416, `bash bench.sh flash`), 28 bytes more stack at the
/// robust path's deepest point (4 016 -> 4 044, `bash bench.sh
/// footprint`), clean `adc2` 459 680 -> 465 760 instructions (`bash
/// bench.sh bench`); the contamination table is unchanged.
#[inline(always)]
fn as_4x4<T: Real, const N: usize>(m: &Mat<T, N>) -> Option<Mat<T, 4>> {
    if N != 3 {
        return None;
    }
    let mut a4 = [[T::zero(); 4]; 4];
    for (r4, r) in a4.iter_mut().zip(m) {
        for (x4, &x) in r4.iter_mut().zip(r) {
            *x4 = x;
        }
    }
    Some(a4)
}

/// The diagonal of `a` times `scale`, into `values` (as far as both go).
#[inline(always)]
fn scaled_diagonal<T: Real, const M: usize, const N: usize>(
    a: &Mat<T, M>,
    scale: T,
    values: &mut [T; N],
) {
    for (i, (v, row)) in values.iter_mut().zip(a).enumerate() {
        *v = row.get(i).copied().unwrap_or(T::zero()) * scale;
    }
}

/// The Jacobi iteration, in place: `a` (symmetrised and divided by the
/// returned scale) becomes diagonal, and `v`, when given, receives the
/// eigenvectors as rows.
fn jacobi<T: Real, const N: usize>(
    a: &mut Mat<T, N>,
    mut v: Option<&mut Mat<T, N>>,
) -> Result<T, Error> {
    let zero = T::zero();
    let one = T::one();
    let half = T::lit(0.5);
    let mut scale = zero;
    for row in a.iter() {
        for &x in row {
            if !x.is_finite() {
                return Err(Error::SingularSystem);
            }
            scale = larger(scale, x.abs());
        }
    }
    if let Some(v) = v.as_deref_mut() {
        for i in 0..N {
            for j in 0..N {
                v[i][j] = if i == j { one } else { zero };
            }
        }
    }
    if scale == zero {
        return Ok(zero);
    }
    // Symmetrise while scaling (each half first: no overflow near max).
    for i in 0..N {
        for j in 0..i {
            let x = a[i][j] / scale * half + a[j][i] / scale * half;
            a[i][j] = x;
            a[j][i] = x;
        }
        a[i][i] /= scale;
    }
    let eps = T::EPSILON;
    // Beyond this |theta|, theta^2 + 1 rounds to theta^2.
    let huge = one / eps;
    for _ in 0..MAX_SWEEPS {
        let mut rotated = false;
        for p in 0..N {
            for q in (p + 1)..N {
                let apq = a[p][q];
                let (app, aqq) = (a[p][p], a[q][q]);
                // |a_pq| <= eps sqrt(|a_pp a_qq|), squared: no square root.
                if apq * apq <= eps * eps * (app * aqq).abs() {
                    a[p][q] = zero;
                    a[q][p] = zero;
                    continue;
                }
                rotated = true;
                // The rotation that zeroes a_pq: t = tan(phi), the smaller
                // root of t^2 + 2 theta t - 1 = 0.
                let theta = (aqq - app) / (apq + apq);
                let at = theta.abs();
                // Square roots as x / sqrt(x) = x rsqrt(x) (x >= 1 here):
                // `Real::rsqrt` costs a third of `libm::sqrtf` on the M4F.
                let root = if at > huge {
                    at + at
                } else {
                    let r2 = at * at + one;
                    at + r2 * r2.rsqrt()
                };
                let t = if theta < zero {
                    -one / root
                } else {
                    one / root
                };
                let c = (t * t + one).rsqrt();
                let s = t * c;
                a[p][p] = app - t * apq;
                a[q][q] = aqq + t * apq;
                a[p][q] = zero;
                a[q][p] = zero;
                for r in 0..N {
                    if r != p && r != q {
                        let (arp, arq) = (a[r][p], a[r][q]);
                        let new_p = c * arp - s * arq;
                        let new_q = s * arp + c * arq;
                        a[r][p] = new_p;
                        a[p][r] = new_p;
                        a[r][q] = new_q;
                        a[q][r] = new_q;
                    }
                }
                if let Some(v) = v.as_deref_mut() {
                    for r in 0..N {
                        let (vp, vq) = (v[p][r], v[q][r]);
                        v[p][r] = c * vp - s * vq;
                        v[q][r] = s * vp + c * vq;
                    }
                }
            }
        }
        if !rotated {
            return Ok(scale);
        }
    }
    Err(Error::NoConvergence {
        iterations: MAX_SWEEPS,
    })
}

/// Householder reduction of a symmetric matrix to tridiagonal form with the
/// same eigenvalues: the diagonal `d` and the off-diagonal `e` (`e[i]`
/// couples `i` and `i + 1`; the last entry is zero). A direct method: one
/// reflection per column, no iteration. The entries must be finite (the
/// caller checks): a NaN would end in a finite, wrong result.
pub(crate) fn tridiagonal<T: Real, const N: usize>(m: &Mat<T, N>) -> ([T; N], [T; N]) {
    let zero = T::zero();
    let two = T::lit(2.0);
    let mut a = *m;
    let mut e = [zero; N];
    for k in 0..N {
        // x = a[k+1.., k]; the reflection maps it onto alpha e_1.
        let mut norm2 = zero;
        let mut big = zero;
        for i in (k + 1)..N {
            big = larger(big, a[i][k].abs());
        }
        if !(big > zero) {
            continue;
        }
        let mut v = [zero; N];
        for i in (k + 1)..N {
            v[i] = a[i][k] / big;
            norm2 += v[i] * v[i];
        }
        // norm2 >= 1: the largest entry of v is 1 after the scaling.
        let norm = norm2 * norm2.rsqrt();
        let mut alpha = norm;
        if let Some(first) = v.get_mut(k + 1) {
            if *first > zero {
                alpha = -norm;
            }
            *first -= alpha;
        }
        let vv: T = v.iter().fold(zero, |acc, &x| acc + x * x);
        if !(vv > zero) {
            continue;
        }
        // H = I - 2 v v^T / (v^T v); A <- H A H on rows/columns k+1..N:
        // p = A v / vv, K = v^T p / vv, q = p - K v, A -= 2 (v q^T + q v^T) / ...
        let mut p = [zero; N];
        for i in (k + 1)..N {
            let mut s = zero;
            for j in (k + 1)..N {
                s += a[i][j] * v[j];
            }
            p[i] = s / vv;
        }
        let mut kk = zero;
        for i in (k + 1)..N {
            kk += v[i] * p[i];
        }
        kk /= vv;
        for i in (k + 1)..N {
            p[i] -= kk * v[i];
        }
        for i in (k + 1)..N {
            for j in (k + 1)..N {
                a[i][j] -= two * (v[i] * p[j] + p[i] * v[j]);
            }
        }
        // Column k below the subdiagonal is now zero; the subdiagonal entry
        // is alpha, in the scale of the original column.
        e[k] = alpha * big;
    }
    let mut d = [zero; N];
    for i in 0..N {
        d[i] = a[i][i];
    }
    (d, e)
}

/// Cholesky factor `L` (lower triangular, `a = L L^T`) of a symmetric
/// positive definite matrix (its lower triangle is read), or `None` when a
/// pivot is not positive and finite.
pub(crate) fn cholesky<T: Real, const N: usize>(a: &Mat<T, N>) -> Option<Mat<T, N>> {
    let mut l = *a;
    if !cholesky_in_place(&mut l) {
        return None;
    }
    for (i, row) in l.iter_mut().enumerate() {
        for x in row.iter_mut().skip(i + 1) {
            *x = T::zero();
        }
    }
    Some(l)
}

/// [`cholesky`] in place: the lower triangle of `a` becomes `L` (the
/// upper one is left as it was, and the solves below never read it);
/// false when a pivot is not positive and finite. No copy of the matrix:
/// the 9x9 LS solve takes its stack only once.
pub(crate) fn cholesky_in_place<T: Real, const N: usize>(a: &mut Mat<T, N>) -> bool {
    for j in 0..N {
        let mut d = a[j][j];
        for k in 0..j {
            d -= a[j][k] * a[j][k];
        }
        if !(d > T::zero()) || !d.is_finite() {
            return false;
        }
        let djj = d.square_root();
        a[j][j] = djj;
        for i in (j + 1)..N {
            let mut s = a[i][j];
            for k in 0..j {
                s -= a[i][k] * a[j][k];
            }
            a[i][j] = s / djj;
        }
    }
    true
}

/// Solves `L x = b` for a lower triangular `L` with a non-zero diagonal.
pub(crate) fn solve_lower<T: Real, const N: usize>(l: &Mat<T, N>, b: &[T; N]) -> [T; N] {
    let mut x = *b;
    for i in 0..N {
        let mut s = x[i];
        for k in 0..i {
            s -= l[i][k] * x[k];
        }
        x[i] = s / l[i][i];
    }
    x
}

/// Solves `L^T x = b` for a lower triangular `L` with a non-zero diagonal.
pub(crate) fn solve_lower_transposed<T: Real, const N: usize>(l: &Mat<T, N>, b: &[T; N]) -> [T; N] {
    let mut x = *b;
    for i in (0..N).rev() {
        let mut s = x[i];
        for k in (i + 1)..N {
            s -= l[k][i] * x[k];
        }
        x[i] = s / l[i][i];
    }
    x
}

/// Solves `L L^T x = b` from the Cholesky factor.
pub(crate) fn cholesky_solve<T: Real, const N: usize>(l: &Mat<T, N>, b: &[T; N]) -> [T; N] {
    solve_lower_transposed(l, &solve_lower(l, b))
}

/// `(L L^T)^-1` from the Cholesky factor (symmetric).
#[cfg(any(feature = "adc1", feature = "adc2-iter"))]
pub(crate) fn cholesky_inverse<T: Real, const N: usize>(l: &Mat<T, N>) -> Mat<T, N> {
    let mut inv = [[T::zero(); N]; N];
    for j in 0..N {
        let mut e = [T::zero(); N];
        e[j] = T::one();
        inv[j] = cholesky_solve(l, &e);
    }
    inv
}

/// The inverse of a 3x3 matrix (the adjugate over the determinant), or
/// `None` when it is singular to working precision (relative to the size of
/// its entries) or the result is not finite.
pub(crate) fn inverse3<T: Real>(a: &Mat<T, 3>) -> Option<Mat<T, 3>> {
    // Divided by its largest entry first, so that the determinant neither
    // underflows nor overflows; the inverse is scaled back at the end.
    let mut size = T::zero();
    for &x in a.as_flattened() {
        size = larger(size, x.abs());
    }
    if !(size > T::zero()) || !size.is_finite() {
        return None;
    }
    // Entry by entry, and the loops over the flattened entries: `a.map`
    // and nested loops copy the rows on the stack at opt-level "s" (132
    // bytes of flash more, LS9 + ADC2 with or without `robust`).
    let [[a00, a01, a02], [a10, a11, a12], [a20, a21, a22]] = *a;
    let (a00, a01, a02) = (a00 / size, a01 / size, a02 / size);
    let (a10, a11, a12) = (a10 / size, a11 / size, a12 / size);
    let (a20, a21, a22) = (a20 / size, a21 / size, a22 / size);
    // Cofactors of the first row, then the rest.
    let c00 = a11 * a22 - a12 * a21;
    let c01 = a12 * a20 - a10 * a22;
    let c02 = a10 * a21 - a11 * a20;
    let det = a00 * c00 + a01 * c01 + a02 * c02;
    if !(det.abs() > T::EPSILON) {
        return None;
    }
    let c10 = a02 * a21 - a01 * a22;
    let c11 = a00 * a22 - a02 * a20;
    let c12 = a01 * a20 - a00 * a21;
    let c20 = a01 * a12 - a02 * a11;
    let c21 = a02 * a10 - a00 * a12;
    let c22 = a00 * a11 - a01 * a10;
    // The inverse is the transposed cofactor matrix over the determinant,
    // and over the scale.
    let k = det * size;
    let inv = [
        [c00 / k, c10 / k, c20 / k],
        [c01 / k, c11 / k, c21 / k],
        [c02 / k, c12 / k, c22 / k],
    ];
    inv.as_flattened()
        .iter()
        .all(|v| v.is_finite())
        .then_some(inv)
}

/// Solves `a x = b` for a 3x3 matrix through [`inverse3`], or `None` when
/// `a` is singular to working precision or the result is not finite.
pub(crate) fn solve3<T: Real>(a: &Mat<T, 3>, b: &[T; 3]) -> Option<[T; 3]> {
    let inv = inverse3(a)?;
    let mut x = [T::zero(); 3];
    for i in 0..3 {
        x[i] = inv[i][0] * b[0] + inv[i][1] * b[1] + inv[i][2] * b[2];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// The eigen-decomposition of a symmetric positive definite 3x3 matrix, or
/// [`Error::NotAnEllipsoid`] when an eigenvalue is not clearly positive.
fn positive_definite_eigen<T: Real>(m: &Matrix3<T>) -> Result<SymEigen<T, 3>, Error> {
    let eig = sym_eigen(&columns_of(m))?;
    let (_, max) = min_max(&eig.values);
    // A positive definite matrix whose smallest eigenvalue is lost in the
    // rounding of the largest is numerically singular.
    if !eig
        .values
        .iter()
        .all(|&l| l > max.abs() * T::EPSILON * T::lit(8.0))
    {
        return Err(Error::NotAnEllipsoid);
    }
    Ok(eig)
}

/// `V f(Lambda) V^T` from an eigen-decomposition, exactly symmetric:
/// `f(l) = sqrt(l)` when `root`, else `1 / sqrt(l)`. A flag, not a closure,
/// and out of line: one copy serves both roots (LS9 + ADC2 on a Cortex-M4F,
/// `bash bench.sh flash`: see the commit that made it so).
#[inline(never)]
fn spectral<T: Real>(eig: &SymEigen<T, 3>, root: bool) -> Matrix3<T> {
    let mut fm = [[T::zero(); 3]; 3];
    for (v, &l) in eig.vectors.iter().zip(&eig.values) {
        let fl = if root { l * inv_sqrt(l) } else { inv_sqrt(l) };
        for i in 0..3 {
            for j in i..3 {
                fm[i][j] += fl * (v[i] * v[j]);
            }
        }
    }
    // The lower triangle mirrors the upper.
    for i in 0..3 {
        for j in 0..i {
            fm[i][j] = fm[j][i];
        }
    }
    from_columns(fm)
}

/// `1 / sqrt(l)` for a positive `l`: [`Real::rsqrt`] where it is defined
/// (normal `l`), else the exact quotient.
fn inv_sqrt<T: Real>(l: T) -> T {
    if l >= T::MIN_POSITIVE {
        l.rsqrt()
    } else {
        T::one() / l.square_root()
    }
}

/// `M^(1/2)` and `M^(-1/2)` from one eigen-decomposition.
pub(crate) fn sym_sqrt_and_inv_sqrt<T: Real>(
    m: &Matrix3<T>,
) -> Result<(Matrix3<T>, Matrix3<T>), Error> {
    let eig = positive_definite_eigen(m)?;
    Ok((spectral(&eig, true), spectral(&eig, false)))
}

/// The symmetric positive definite square root `M^(1/2)`.
pub(crate) fn sym_sqrt<T: Real>(m: &Matrix3<T>) -> Result<Matrix3<T>, Error> {
    Ok(spectral(&positive_definite_eigen(m)?, true))
}

/// The symmetric positive definite inverse square root `M^(-1/2)`.
pub(crate) fn sym_inv_sqrt<T: Real>(m: &Matrix3<T>) -> Result<Matrix3<T>, Error> {
    Ok(spectral(&positive_definite_eigen(m)?, false))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::Rng;

    /// A random symmetric matrix with chosen eigenvalues: `Q diag(l) Q^T`
    /// with `Q` from Gram-Schmidt on random vectors.
    fn with_spectrum<const N: usize>(rng: &mut Rng, l: &[f64; N]) -> Mat<f64, N> {
        let mut q = [[0.0; N]; N];
        for k in 0..N {
            let mut v = [0.0; N];
            for x in v.iter_mut() {
                *x = rng.symmetric();
            }
            for prev in q.iter().take(k) {
                let d: f64 = v.iter().zip(prev).map(|(a, b)| a * b).sum();
                for (x, p) in v.iter_mut().zip(prev) {
                    *x -= d * p;
                }
            }
            let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            for x in v.iter_mut() {
                *x /= n;
            }
            q[k] = v;
        }
        let mut a = [[0.0; N]; N];
        for i in 0..N {
            for j in 0..N {
                a[i][j] = (0..N).map(|k| q[k][i] * l[k] * q[k][j]).sum();
            }
        }
        a
    }

    fn sorted<const N: usize>(mut v: [f64; N]) -> [f64; N] {
        v.sort_by(|a, b| a.partial_cmp(b).unwrap());
        v
    }

    #[test]
    fn eigen_recovers_a_known_spectrum_with_relative_accuracy() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15 ^ 7);
        // Widely spread eigenvalues: Jacobi keeps even the smallest to a
        // few ulps relative of itself.
        let l = [1e-9, 3e-4, 0.5, 1.0, 2.0, 7.0, 1e3, 4e3, -2.0, 5e5];
        let a = with_spectrum(&mut rng, &l);
        let eig = sym_eigen(&a).unwrap();
        let (got, want) = (sorted(eig.values), sorted(l));
        for (g, w) in got.iter().zip(&want) {
            // The matrix itself was formed with errors of eps * 5e5.
            assert!((g - w).abs() <= 1e-9 * 5e5, "{got:?} vs {want:?}");
        }
        // A v = lambda v and orthonormality, independently of the values.
        for (v, &lam) in eig.vectors.iter().zip(&eig.values) {
            for i in 0..10 {
                let av: f64 = (0..10).map(|j| a[i][j] * v[j]).sum();
                assert!(
                    (av - lam * v[i]).abs() < 1e-9,
                    "residual {}",
                    av - lam * v[i]
                );
            }
        }
        for p in 0..10 {
            for q in 0..10 {
                let d: f64 = (0..10).map(|i| eig.vectors[p][i] * eig.vectors[q][i]).sum();
                let want = if p == q { 1.0 } else { 0.0 };
                assert!((d - want).abs() < 1e-13);
            }
        }
    }

    #[test]
    fn eigenvalues_alone_match_the_full_decomposition() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15 ^ 3);
        for _ in 0..20 {
            let l = [
                rng.symmetric(),
                rng.symmetric() * 10.0,
                rng.symmetric() * 0.01,
                1.0,
            ];
            let a = with_spectrum(&mut rng, &l);
            let full = sym_eigen(&a).unwrap().values;
            let alone = sym_eigenvalues(&a).unwrap();
            assert_eq!(full, alone);
            let (g, w) = (sorted(alone), sorted(l));
            for (g, w) in g.iter().zip(&w) {
                assert!((g - w).abs() < 1e-13);
            }
        }
    }

    #[test]
    fn eigen_handles_zero_huge_tiny_and_non_finite_matrices() {
        let z = sym_eigen(&[[0.0f32; 3]; 3]).unwrap();
        assert_eq!(z.values, [0.0; 3]);
        let big =
            sym_eigen(&[[1.5e38f32, 5e37, 0.0], [5e37, 1.5e38, 0.0], [0.0, 0.0, 1.0]]).unwrap();
        let (lo, hi) = min_max(&big.values);
        assert!(hi.is_finite() && (hi / 2e38 - 1.0).abs() < 1e-6, "{hi}");
        assert!((lo - 1.0).abs() < 1e-6, "{lo}");
        let tiny = f32::MIN_POSITIVE * 0.25; // subnormal
        let t = sym_eigen(&[[tiny, 0.0, 0.0], [0.0, 2.0 * tiny, 0.0], [0.0, 0.0, tiny]]).unwrap();
        assert_eq!(sorted(t.values.map(f64::from))[2], f64::from(2.0 * tiny));
        for bad in [f32::NAN, f32::INFINITY] {
            let mut m = [[1.0f32, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
            m[1][2] = bad;
            assert_eq!(sym_eigen(&m).unwrap_err(), Error::SingularSystem);
        }
        // Degenerate spectrum (all equal) and a 2x2 rotation-only case.
        let e = sym_eigen(&[[0.0, 1.0], [1.0, 0.0]]).unwrap();
        assert_eq!(sorted(e.values), [-1.0, 1.0]);
    }

    #[test]
    fn tridiagonal_form_keeps_the_spectrum() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15 ^ 13);
        let l = [1e-6, 0.2, 0.5, 1.0, 2.0, 3.0, 5.0, 8.0, 13.0, 21.0];
        let a = with_spectrum(&mut rng, &l);
        let (d, e) = tridiagonal(&a);
        assert_eq!(e[9], 0.0);
        let mut t = [[0.0; 10]; 10];
        for i in 0..10 {
            t[i][i] = d[i];
            if i < 9 {
                t[i][i + 1] = e[i];
                t[i + 1][i] = e[i];
            }
        }
        let (got, want) = (sorted(sym_eigenvalues(&t).unwrap()), sorted(l));
        for (g, w) in got.iter().zip(&want) {
            assert!((g - w).abs() < 1e-13, "{got:?}");
        }
        // Already tridiagonal (and diagonal) input passes through.
        let (d, e) = tridiagonal(&[[2.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 4.0]]);
        assert_eq!((d, e), ([2.0, 3.0, 4.0], [0.0; 3]));
    }

    #[test]
    fn cholesky_solves_and_inverts_and_refuses_indefinite_matrices() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15 ^ 11);
        let a = with_spectrum(&mut rng, &[0.01, 1.0, 3.0, 40.0, 2.0, 0.5]);
        let l = cholesky(&a).unwrap();
        let b = [1.0, -2.0, 0.5, 3.0, 0.0, 1.5];
        let x = cholesky_solve(&l, &b);
        for i in 0..6 {
            let ax: f64 = (0..6).map(|j| a[i][j] * x[j]).sum();
            assert!((ax - b[i]).abs() < 1e-10);
        }
        #[cfg(any(feature = "adc1", feature = "adc2-iter"))]
        {
            let inv = cholesky_inverse(&l);
            for i in 0..6 {
                for j in 0..6 {
                    let p: f64 = (0..6).map(|k| a[i][k] * inv[k][j]).sum();
                    assert!((p - if i == j { 1.0 } else { 0.0 }).abs() < 1e-10);
                }
            }
        }
        let indefinite = with_spectrum(&mut rng, &[1.0, -0.1, 2.0]);
        assert!(cholesky(&indefinite).is_none());
        assert!(cholesky(&[[f64::NAN]]).is_none());
        assert!(cholesky(&[[0.0]]).is_none());
    }

    #[test]
    fn inverse3_of_a_general_matrix() {
        let m = [[2.0, -1.0, 0.5], [0.3, 1.5, -0.7], [0.1, 0.4, 3.0]];
        let inv = inverse3(&m).unwrap();
        for i in 0..3 {
            for j in 0..3 {
                let p: f64 = (0..3).map(|k| m[i][k] * inv[k][j]).sum();
                assert!((p - if i == j { 1.0 } else { 0.0 }).abs() < 1e-14);
            }
        }
    }

    #[test]
    fn inverse3_is_scale_free() {
        for scale in [1e-30f32, 1e-14, 1.0, 1e13, 1e30] {
            let m = [
                [2.0 * scale, 0.0, 0.0],
                [0.0, scale, 0.0],
                [0.0, 0.0, 4.0 * scale],
            ];
            let inv = inverse3(&m).unwrap();
            let want = [0.5 / scale, 1.0 / scale, 0.25 / scale];
            for i in 0..3 {
                assert!((inv[i][i] / want[i] - 1.0).abs() < 1e-6, "{scale}: {inv:?}");
            }
        }
    }

    #[test]
    fn solve3_inverts_and_refuses_singular_matrices() {
        let a = [[2.0, 1.0, 0.0], [1.0, 3.0, 1.0], [0.0, 1.0, -4.0]];
        let b = [1.0, 2.0, 3.0];
        let x = solve3(&a, &b).unwrap();
        for i in 0..3 {
            let ax: f64 = (0..3).map(|j| a[i][j] * x[j]).sum();
            assert!((ax - b[i]).abs() < 1e-14);
        }
        let singular = [[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 1.0, 1.0]];
        assert!(solve3(&singular, &b).is_none());
        assert!(solve3(&[[f64::INFINITY, 0.0, 0.0], [0.0; 3], [0.0; 3]], &b).is_none());
    }

    #[test]
    fn square_roots_are_inverse_and_square_to_the_matrix() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15 ^ 5);
        let a = from_columns(with_spectrum(&mut rng, &[0.3, 1.0, 2.5]));
        let (r, ri) = sym_sqrt_and_inv_sqrt(&a).unwrap();
        assert!((r * r - a).norm() < 1e-13);
        assert!((r * ri - Matrix3::identity()).norm() < 1e-13);
        assert_eq!(r, r.transpose());
        assert!((sym_sqrt(&a).unwrap() - r).norm() < 1e-15);
        assert!((sym_inv_sqrt(&a).unwrap() - ri).norm() < 1e-15);
        let indefinite = from_columns(with_spectrum(&mut rng, &[0.3, -1.0, 2.5]));
        assert_eq!(sym_sqrt(&indefinite).unwrap_err(), Error::NotAnEllipsoid);
    }
}
