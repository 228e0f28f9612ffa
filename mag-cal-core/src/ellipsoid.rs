//! Step 1 of Algorithm 1: the algebraic least-squares ellipsoid fit
//! (design document, section 3), in three variants sharing the moments.

use nalgebra::{Cholesky, Matrix3, SMatrix, SVector, Vector3};

use crate::linalg::{sym_eigen, sym_sqrt_and_inv_sqrt};
use crate::moments::Moments;
use crate::{Error, Real};

/// Which algebraic least-squares solve turns the moments into a quadric.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
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

/// Fits an ellipsoid to the moments with the chosen variant.
pub fn fit<T: Real>(moments: &Moments<T>, variant: LsVariant) -> Result<Ellipsoid<T>, Error> {
    fit_scatter(&moments.scatter(), variant)
}

/// Fits an ellipsoid to the 10x10 scatter with the chosen variant.
pub fn fit_scatter<T: Real>(
    s: &SMatrix<T, 10, 10>,
    variant: LsVariant,
) -> Result<Ellipsoid<T>, Error> {
    if !s.iter().all(|v| v.is_finite()) {
        return Err(Error::OutOfRange);
    }
    let v = match variant {
        LsVariant::Ls9 => ls9(s)?,
        LsVariant::Svd10 => svd10(s)?,
        LsVariant::LiGriffiths => li_griffiths(s)?,
    };
    from_quadric(&v)
}

/// `v = [v9, -1]` with `S9 v9 = sum phi9` (Cholesky).
fn ls9<T: Real>(s: &SMatrix<T, 10, 10>) -> Result<SVector<T, 10>, Error> {
    let s9: SMatrix<T, 9, 9> = s.fixed_view::<9, 9>(0, 0).into_owned();
    let rhs: SVector<T, 9> = s.fixed_view::<9, 1>(0, 9).into_owned();
    let v9 = Cholesky::new(s9).ok_or(Error::SingularSystem)?.solve(&rhs);
    let mut v = SVector::<T, 10>::zeros();
    v.fixed_rows_mut::<9>(0).copy_from(&v9);
    v[9] = -T::one();
    Ok(v)
}

/// `v` = eigenvector of the smallest eigenvalue of `S`.
fn svd10<T: Real>(s: &SMatrix<T, 10, 10>) -> Result<SVector<T, 10>, Error> {
    let eig = sym_eigen(*s)?;
    let k = eig.eigenvalues.imin();
    Ok(eig.eigenvectors.column(k).into_owned())
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
fn li_griffiths<T: Real>(s: &SMatrix<T, 10, 10>) -> Result<SVector<T, 10>, Error> {
    let s11: SMatrix<T, 6, 6> = s.fixed_view::<6, 6>(0, 0).into_owned();
    let s12: SMatrix<T, 6, 4> = s.fixed_view::<6, 4>(0, 6).into_owned();
    let s22: SMatrix<T, 4, 4> = s.fixed_view::<4, 4>(6, 6).into_owned();
    let s22 = Cholesky::new(s22).ok_or(Error::SingularSystem)?;
    // S22^-1 S21 (4x6)
    let k = s22.solve(&s12.transpose());
    let red = s11 - s12 * k;
    let red = (red + red.transpose()) * T::lit(0.5);
    let l = match Cholesky::new(red) {
        Some(c) => c,
        None => {
            let ridge = red.trace() * T::EPSILON * T::lit(16.0);
            Cholesky::new(red + SMatrix::<T, 6, 6>::identity() * ridge)
                .ok_or(Error::SingularSystem)?
        }
    }
    .unpack();
    let mut c1 = SMatrix::<T, 6, 6>::zeros();
    for i in 0..3 {
        for j in 0..3 {
            c1[(i, j)] = if i == j { -T::one() } else { T::one() };
        }
        c1[(i + 3, i + 3)] = T::lit(-4.0);
    }
    // L^-1 C1 L^-T by two triangular solves.
    let a = l.solve_lower_triangular(&c1).ok_or(Error::SingularSystem)?;
    let kmat = l
        .solve_lower_triangular(&a.transpose())
        .ok_or(Error::SingularSystem)?;
    let kmat = (kmat + kmat.transpose()) * T::lit(0.5);
    let eig = sym_eigen(kmat)?;
    let top = eig.eigenvalues.imax();
    if !(eig.eigenvalues[top] > T::zero()) {
        return Err(Error::NotAnEllipsoid);
    }
    let w = eig.eigenvectors.column(top).into_owned();
    let v1 = l
        .transpose()
        .solve_upper_triangular(&w)
        .ok_or(Error::SingularSystem)?;
    let v2 = -(k * v1);
    let mut v = SVector::<T, 10>::zeros();
    v.fixed_rows_mut::<6>(0).copy_from(&v1);
    v.fixed_rows_mut::<4>(6).copy_from(&v2);
    Ok(v)
}

/// From quadric coefficients `v` to the ellipsoid: `A`, `p`,
/// `b' = -A^-1 p`, `k = b'^T A b' - v9`, `M' = A / k`. The sign of `v` does
/// not matter (it cancels in `A / k`). Refuses anything but an ellipsoid.
pub fn from_quadric<T: Real>(v: &SVector<T, 10>) -> Result<Ellipsoid<T>, Error> {
    if !v.iter().all(|x| x.is_finite()) {
        return Err(Error::SingularSystem);
    }
    let a = Matrix3::new(v[0], v[3], v[4], v[3], v[1], v[5], v[4], v[5], v[2]);
    let p = Vector3::new(v[6], v[7], v[8]);
    // A is definite (of either sign) for an ellipsoid; LU handles both.
    let centre = -a.lu().solve(&p).ok_or(Error::NotAnEllipsoid)?;
    let k = centre.dot(&(a * centre)) - v[9];
    if !(k != T::zero()) || !centre.iter().all(|x| x.is_finite()) {
        return Err(Error::NotAnEllipsoid);
    }
    let m = a / k;
    let (w, t) = sym_sqrt_and_inv_sqrt(&m)?;
    Ok(Ellipsoid { centre, m, w, t })
}
