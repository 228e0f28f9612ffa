//! Small dense helpers over nalgebra's fixed-size decompositions.
//!
//! Every iterative decomposition gets an explicit tolerance and iteration
//! cap (nalgebra treats a cap of 0 as "unbounded"; we never pass 0).

use nalgebra::allocator::Allocator;
use nalgebra::{
    Const, DefaultAllocator, DimDiff, DimSub, Matrix3, SMatrix, SymmetricEigen, Vector3, U1,
};

use crate::{Error, Real};

/// Iteration cap for nalgebra's symmetric QR eigen-solver. A 10x10 matrix
/// converges in a few tens of implicit QR steps; 500 is far beyond that.
const EIGEN_MAX_ITER: usize = 500;

/// Symmetric eigen-decomposition with a bounded iteration count.
pub(crate) fn sym_eigen<T: Real, const D: usize>(
    m: SMatrix<T, D, D>,
) -> Result<SymmetricEigen<T, Const<D>>, Error>
where
    Const<D>: DimSub<U1>,
    DefaultAllocator: Allocator<DimDiff<Const<D>, U1>>,
{
    if !m.iter().all(|v| v.is_finite()) {
        return Err(Error::SingularSystem);
    }
    SymmetricEigen::<T, Const<D>>::try_new(m, T::EPSILON, EIGEN_MAX_ITER).ok_or(
        Error::NoConvergence {
            iterations: EIGEN_MAX_ITER as u32,
        },
    )
}

/// `V f(Lambda) V^T` for a symmetric positive definite 3x3 matrix, or
/// `None`-like error when an eigenvalue is not strictly positive.
fn sym_function<T: Real>(m: &Matrix3<T>, f: impl Fn(T) -> T) -> Result<Matrix3<T>, Error> {
    let eig = sym_eigen(m.symmetric_part())?;
    let max = eig.eigenvalues.amax();
    // A positive definite matrix whose smallest eigenvalue is lost in the
    // rounding of the largest is numerically singular.
    if !eig
        .eigenvalues
        .iter()
        .all(|&l| l > max * T::EPSILON * T::lit(8.0))
    {
        return Err(Error::NotAnEllipsoid);
    }
    let v = &eig.eigenvectors;
    let d = Vector3::from_fn(|i, _| f(eig.eigenvalues[i]));
    // V D V^T is symmetric only to rounding; the canonical form is exactly so.
    Ok((v * Matrix3::from_diagonal(&d) * v.transpose()).symmetric_part())
}

/// `M^(1/2)` and `M^(-1/2)` from one eigen-decomposition.
pub(crate) fn sym_sqrt_and_inv_sqrt<T: Real>(
    m: &Matrix3<T>,
) -> Result<(Matrix3<T>, Matrix3<T>), Error> {
    let eig = sym_eigen(m.symmetric_part())?;
    let max = eig.eigenvalues.amax();
    if !eig
        .eigenvalues
        .iter()
        .all(|&l| l > max * T::EPSILON * T::lit(8.0))
    {
        return Err(Error::NotAnEllipsoid);
    }
    let v = &eig.eigenvectors;
    let root = eig.eigenvalues.map(|l| l.sqrt());
    let sqrt = v * Matrix3::from_diagonal(&root) * v.transpose();
    let inv = v * Matrix3::from_diagonal(&root.map(|r| T::one() / r)) * v.transpose();
    Ok((sqrt.symmetric_part(), inv.symmetric_part()))
}

/// The symmetric positive definite square root `M^(1/2)`.
pub(crate) fn sym_sqrt<T: Real>(m: &Matrix3<T>) -> Result<Matrix3<T>, Error> {
    sym_function(m, |l| l.sqrt())
}

/// The symmetric positive definite inverse square root `M^(-1/2)`.
pub(crate) fn sym_inv_sqrt<T: Real>(m: &Matrix3<T>) -> Result<Matrix3<T>, Error> {
    sym_function(m, |l| T::one() / l.sqrt())
}
