//! Step 2 of the calibration: alignment to a reference frame (orthogonal
//! Procrustes).
//!
//! A calibration fixes `u = W (y - b)` only up to a rotation: the data
//! determine `M = W^T W` and `b`, never the orientation of the calibrated
//! frame. Where the true field directions
//! `h_i` of some readings are known (a reference instrument, a rig, or the
//! simulation's truth), [`procrustes`] finds the proper rotation `Q` that
//! best maps the calibrated readings onto them, and [`AlignedCalibration`]
//! applies calibration and rotation in one step.
//!
//! # How the rotation is computed
//! `Q = U diag(1, 1, det(U V^T)) V^T` from the SVD `B = U S V^T` of
//! `B = sum h_i u_i^T` (the Kabsch form of orthogonal Procrustes, restricted
//! to `det Q = +1`). The SVD is a one-sided Jacobi (Hestenes) iteration on
//! the 3x3 `B`, not nalgebra's `SVD`: for a `Matrix3` nalgebra switches to a
//! special path through the eigenvectors of `B^T B`, which squares the
//! condition number. On pairs within a cone of +-0.05 rad (`s2 / s1` about
//! `1e-3`) that path returned `f32` rotations off by up to 0.07 rad, and by
//! up to 0.5 rad on narrower cones; the Jacobi iteration stayed within
//! `2e-6` rad on the same data, and converges in 2-4 sweeps of three plane
//! rotations.

use nalgebra::{Matrix3, Vector3};

use crate::numerics::linalg::{dot, from_rows, rows};
use crate::steps::moments::BLOCK;
use crate::{Calibration, Error, Real, Sample};

/// Sweep cap of the Jacobi SVD. A 3x3 converges quadratically, in 2-4
/// sweeps (each of three plane rotations); 32 is far beyond that.
const MAX_SWEEPS: u32 = 32;

/// The proper rotation `Q` (orthonormal, `det Q = +1`) minimising
/// `sum |Q u_i - h_i|^2` over pairs of calibrated readings `u_i`
/// (`calibrated`) and reference vectors `h_i` (`reference`), both in any
/// consistent unit.
///
/// The vectors need not be unit vectors: a pair weighs in with `|u_i| |h_i|`,
/// as the cost says; scaling either whole set leaves `Q` unchanged (the
/// inputs are rescaled internally, so no magnitude overflows). Pairs with a
/// non-finite component are skipped.
///
/// When the best orthogonal fit of the data would be a reflection (e.g. a
/// reference frame of the other handedness), the result is still a
/// rotation: the best one.
///
/// # Errors
/// - [`Error::MismatchedLengths`] when the slices differ in length;
/// - [`Error::TooFewSamples`] (`required: 2`) for fewer than two finite
///   pairs;
/// - [`Error::SingularSystem`] when the pairs do not determine a rotation:
///   `B = sum h_i u_i^T` is zero or has rank below 2 (all vectors parallel),
///   or, more precisely, the curvature of the cost at its minimum,
///   `s2 + det(U V^T) s3` in the singular values `s1 >= s2 >= s3` of `B`,
///   is below `sqrt(eps) s1`. That covers rank < 2, and also the one other
///   case without a unique minimiser: data best fitted by a reflection with
///   `s2 = s3` (e.g. `h_i = -u_i` for directions spread evenly). Below that
///   bound the rounding of `B` alone could turn the result by more than
///   `sqrt(eps)` rad (`2e-2` deg in `f32`);
/// - [`Error::NoConvergence`] if the Jacobi SVD does not converge (not
///   observed: it takes 2-4 of its 32 sweeps).
///
/// The result is by rows: `q[i][j]` in row `i`, column `j`, so that
/// `h = Q u`.
///
/// ```
/// use mag_cal_core::align::procrustes;
///
/// // The reference frame is the calibrated one turned a quarter about z.
/// let turn = |u: [f64; 3]| [-u[1], u[0], u[2]];
/// let calibrated = [[1.0, 0.0, 0.0], [0.0, 0.6, 0.8], [0.0, -1.0, 0.0]];
/// let reference = calibrated.map(turn);
/// let q = procrustes::<f64>(&calibrated, &reference)?;
/// let want = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]];
/// for (row, want_row) in q.iter().zip(want) {
///     for (x, w) in row.iter().zip(want_row) {
///         assert!((x - w).abs() < 1e-12);
///     }
/// }
/// # Ok::<(), mag_cal_core::Error>(())
/// ```
pub fn procrustes<T: Real>(
    calibrated: &[[T; 3]],
    reference: &[[T; 3]],
) -> Result<[[T; 3]; 3], Error> {
    procrustes_matrix(calibrated, reference).map(|q| rows(&q))
}

/// [`procrustes`] on the internal types.
fn procrustes_matrix<T: Real>(
    calibrated: &[[T; 3]],
    reference: &[[T; 3]],
) -> Result<Matrix3<T>, Error> {
    if calibrated.len() != reference.len() {
        return Err(Error::MismatchedLengths);
    }
    let finite = |v: &[T; 3]| v.iter().all(|c| c.is_finite());
    let pairs = || {
        calibrated
            .iter()
            .zip(reference)
            .filter(move |(u, h)| finite(u) && finite(h))
    };

    // Pass 1: count the finite pairs and find each set's largest component,
    // by which the vectors are divided so that no product overflows.
    let (mut found, mut u_max, mut h_max) = (0usize, T::zero(), T::zero());
    for (u, h) in pairs() {
        found += 1;
        u_max = u.iter().fold(u_max, |m, c| m.max(c.abs()));
        h_max = h.iter().fold(h_max, |m, c| m.max(c.abs()));
    }
    if found < 2 {
        return Err(Error::TooFewSamples { found, required: 2 });
    }
    if !(u_max > T::zero()) || !(h_max > T::zero()) {
        return Err(Error::SingularSystem);
    }

    // Pass 2: B = sum h u^T of the rescaled vectors (entries of each term
    // at most 1), summed in blocks to keep the `f32` rounding small.
    let mut b = Matrix3::zeros();
    let mut pending = pairs();
    // At most `found / BLOCK + 1` rounds; each takes up to BLOCK pairs.
    for _ in 0..=found / BLOCK {
        let mut block = Matrix3::zeros();
        for (u, h) in pending.by_ref().take(BLOCK) {
            let u = Vector3::from(*u) / u_max;
            let h = Vector3::from(*h) / h_max;
            block += h * u.transpose();
        }
        b += block;
    }
    let b_max = b.amax();
    if !(b_max > T::zero()) || !b_max.is_finite() {
        return Err(Error::SingularSystem);
    }
    let b: Columns<T> = b.into();
    rotation_from_b(&b.map(|column| column.map(|x| x / b_max)))
}

/// A 3x3 matrix as its three columns (column-major, as nalgebra's
/// `From<[[T; 3]; 3]>` takes it). The SVD works on this form, with literal
/// indices only, so that no bounds-check or nalgebra assertion survives
/// optimisation (see `no-panic-check/`).
type Columns<T> = [[T; 3]; 3];

/// `|x|` (the square root of the squared norm, as nalgebra's `norm`).
#[inline(always)]
fn norm<T: Real>(x: &[T; 3]) -> T {
    dot(x, x).sqrt()
}

/// `x x y`.
#[inline(always)]
fn cross<T: Real>(x: &[T; 3], y: &[T; 3]) -> [T; 3] {
    [
        x[1] * y[2] - x[2] * y[1],
        x[2] * y[0] - x[0] * y[2],
        x[0] * y[1] - x[1] * y[0],
    ]
}

/// `Q = U diag(1, 1, det(U V^T)) V^T` for `B = U S V^T`, `max |B_jk| = 1`.
fn rotation_from_b<T: Real>(b: &Columns<T>) -> Result<Matrix3<T>, Error> {
    let (a, v) = jacobi_svd(b)?;
    // Columns of `a = B V` are `s_k u_k`; order them, with the matching
    // columns of `V`, by decreasing norm.
    let [a1, a2, a3] = a;
    let [v1, v2, v3] = v;
    let mut sorted = [
        (norm(&a1), a1, v1),
        (norm(&a2), a2, v2),
        (norm(&a3), a3, v3),
    ];
    descending(&mut sorted);
    let [(s1, a1, v1), (s2, a2, v2), (s3, a3, v3)] = sorted;
    if !(s1 > T::zero()) {
        return Err(Error::SingularSystem);
    }
    let u1 = a1.map(|x| x / s1);
    let proj = dot(&u1, &a2);
    let u2 = [
        a2[0] - u1[0] * proj,
        a2[1] - u1[1] * proj,
        a2[2] - u1[2] * proj,
    ];
    let u2_norm = norm(&u2);
    // A right-handed U = [u1, u2, u1 x u2]; B's own third left singular
    // vector is sigma (u1 x u2), sigma = +-1 (arbitrary when s3 = 0).
    let u2 = u2.map(|x| x / u2_norm);
    let u3 = cross(&u1, &u2);
    let sigma = if dot(&a3, &u3) < T::zero() {
        -T::one()
    } else {
        T::one()
    };
    // det [v1, v2, v3] = v1 . (v2 x v3).
    let v_det = if dot(&v1, &cross(&v2, &v3)) < T::zero() {
        -T::one()
    } else {
        T::one()
    };
    // det(U V^T) with U = [u1, u2, sigma u3].
    let d = sigma * v_det;
    // The cost's curvature at the minimum (its smallest Hessian eigenvalue).
    let curvature = s2 + d * s3;
    if !(u2_norm > T::zero()) || !(curvature > s1 * T::EPSILON.sqrt()) {
        return Err(Error::SingularSystem);
    }
    // U diag(1, 1, d) V^T = [u1, u2, sigma d u3] V^T = [u1, u2, det(V) u3] V^T;
    // its column l is u1 v1[l] + u2 v2[l] + det(V) u3 v3[l].
    let u3 = u3.map(|x| x * v_det);
    let column = |l: [T; 3]| -> [T; 3] {
        [
            u1[0] * l[0] + u2[0] * l[1] + u3[0] * l[2],
            u1[1] * l[0] + u2[1] * l[1] + u3[1] * l[2],
            u1[2] * l[0] + u2[2] * l[1] + u3[2] * l[2],
        ]
    };
    // Row l of V (the l-th components of v1, v2, v3).
    let q: Columns<T> = [
        column([v1[0], v2[0], v3[0]]),
        column([v1[1], v2[1], v3[1]]),
        column([v1[2], v2[2], v3[2]]),
    ];
    if q.iter().flatten().all(|x| x.is_finite()) {
        Ok(Matrix3::from(q))
    } else {
        Err(Error::SingularSystem)
    }
}

/// Sorts three `(norm, ..)` entries by decreasing norm: three
/// compare-and-swap steps on disjoint references (no index at all).
fn descending<T: Real, C>(x: &mut [(T, C, C); 3]) {
    fn order<T: Real, C>(first: &mut (T, C, C), second: &mut (T, C, C)) {
        if first.0 < second.0 {
            core::mem::swap(first, second);
        }
    }
    let [a, b, c] = x;
    order(a, b);
    order(b, c);
    order(a, b);
}

/// One-sided Jacobi SVD of a finite 3x3 matrix (as columns) with entries of
/// at most 1 in magnitude: returns `(A, V)` (as columns) with `V` orthogonal
/// and `A = B V`, whose columns are mutually orthogonal, so that `A = U S`
/// column by column.
///
/// A column shorter than `eps |B|_F` is left as it is: at that size its
/// direction is rounding noise, and chasing it (its squared norm may
/// underflow) could keep the iteration from ever stopping.
fn jacobi_svd<T: Real>(b: &Columns<T>) -> Result<(Columns<T>, Columns<T>), Error> {
    let (zero, one) = (T::zero(), T::one());
    let mut a = *b;
    let mut v = [[one, zero, zero], [zero, one, zero], [zero, zero, one]];
    // Columns count as orthogonal when their cosine is below a few rounding
    // errors of a 3-term dot product.
    let tol = T::EPSILON * T::lit(8.0);
    // |B|_F = |A|_F throughout (the rotations preserve it).
    let negligible =
        T::EPSILON * (dot(&b[0], &b[0]) + dot(&b[1], &b[1]) + dot(&b[2], &b[2])).sqrt();
    for _ in 0..MAX_SWEEPS {
        // The three column pairs (0, 1), (0, 2), (1, 2), as disjoint
        // references: each call sees its own two columns of A and of V.
        let [a0, a1, a2] = &mut a;
        let [v0, v1, v2] = &mut v;
        let r01 = jacobi_rotation(a0, a1, v0, v1, tol, negligible);
        let r02 = jacobi_rotation(a0, a2, v0, v2, tol, negligible);
        let r12 = jacobi_rotation(a1, a2, v1, v2, tol, negligible);
        if !(r01 || r02 || r12) {
            return Ok((a, v));
        }
    }
    Err(Error::NoConvergence {
        iterations: MAX_SWEEPS,
    })
}

/// One Jacobi step on the column pair `(p, q)` of `A` (and of `V`): rotates
/// both pairs so that `a_p . a_q = 0`, unless the columns are already
/// orthogonal to `tol` or one is below `negligible`. Returns whether it
/// rotated.
fn jacobi_rotation<T: Real>(
    ap: &mut [T; 3],
    aq: &mut [T; 3],
    vp: &mut [T; 3],
    vq: &mut [T; 3],
    tol: T,
    negligible: T,
) -> bool {
    let one = T::one();
    let (norm_p, norm_q) = (norm(ap), norm(aq));
    if !(norm_p > negligible && norm_q > negligible) {
        return false;
    }
    let gamma = dot(ap, aq);
    if !(gamma.abs() > tol * norm_p * norm_q) {
        return false;
    }
    // The rotation that zeroes the (p, q) entry of A^T A:
    // t = tan(theta) the smaller root of t^2 + 2 zeta t - 1 = 0.
    let zeta = (norm_q - norm_p) * (norm_q + norm_p) / (T::lit(2.0) * gamma);
    let abs_zeta = zeta.abs();
    // sqrt(1 + zeta^2) without overflow for a huge zeta.
    let root = if abs_zeta > one {
        abs_zeta * (one + (one / abs_zeta) * (one / abs_zeta)).sqrt()
    } else {
        (one + abs_zeta * abs_zeta).sqrt()
    };
    let t = if zeta < T::zero() { -one } else { one } / (abs_zeta + root);
    let c = one / (one + t * t).sqrt();
    let s = c * t;
    rotate_columns(ap, aq, c, s);
    rotate_columns(vp, vq, c, s);
    true
}

/// Columns `(p, q)` become `(c p - s q, s p + c q)`.
#[inline(always)]
fn rotate_columns<T: Real>(p: &mut [T; 3], q: &mut [T; 3], c: T, s: T) {
    let (mp, mq) = (*p, *q);
    *p = [
        mp[0] * c - mq[0] * s,
        mp[1] * c - mq[1] * s,
        mp[2] * c - mq[2] * s,
    ];
    *q = [
        mp[0] * s + mq[0] * c,
        mp[1] * s + mq[1] * c,
        mp[2] * s + mq[2] * c,
    ];
}

/// A calibration followed by a fixed rotation into a reference frame:
/// `apply(raw) = R W (raw - b)`.
///
/// Built from a [`Calibration`] and, typically, the rotation returned by
/// [`procrustes`]. Validated on construction, so the accessors never fail.
///
/// ```
/// use mag_cal_core::align::AlignedCalibration;
/// use mag_cal_core::Calibration;
///
/// let half = [[0.5, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 0.5]];
/// let cal = Calibration::<f64>::new([10.0, 0.0, 0.0], half)?;
/// // A quarter turn about z, by rows: x goes to y.
/// let r = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]];
/// let aligned = AlignedCalibration::new(cal, r)?;
/// assert_eq!(aligned.apply([12.0, 0.0, 0.0]), [0.0, 1.0, 0.0]);
/// // A reflection is not a rotation.
/// let mirror = [[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]];
/// assert!(AlignedCalibration::new(cal, mirror).is_err());
/// # Ok::<(), mag_cal_core::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AlignedCalibration<T: Real> {
    calibration: Calibration<T>,
    rotation: Matrix3<T>,
    /// `R W`, so that [`AlignedCalibration::apply`] is one product.
    combined: Matrix3<T>,
}

impl<T: Real> AlignedCalibration<T> {
    /// Combines a calibration with a rotation `R` into the reference frame.
    ///
    /// `R` is kept as given (not re-orthonormalised); it must be a proper
    /// rotation to working precision: `max |R^T R - I| <= 1000 eps` and
    /// `det R > 0` (then `det R = 1` to the same precision).
    ///
    /// # Errors
    /// - [`Error::OutOfRange`] when `R` has a non-finite entry (as
    ///   [`Calibration::new`] does for non-finite input);
    /// - [`Error::SingularSystem`] when `R` is not orthonormal to that
    ///   tolerance, or is a reflection (`det R = -1`).
    pub fn new(calibration: Calibration<T>, rotation: [[T; 3]; 3]) -> Result<Self, Error> {
        let rotation = from_rows(rotation);
        if !rotation.iter().all(|x| x.is_finite()) {
            return Err(Error::OutOfRange);
        }
        let defect = (rotation.transpose() * rotation - Matrix3::identity()).amax();
        if !(defect <= T::EPSILON * T::lit(1e3)) || !(rotation.determinant() > T::zero()) {
            return Err(Error::SingularSystem);
        }
        let combined = rotation * calibration.w();
        if !combined.iter().all(|x| x.is_finite()) {
            return Err(Error::OutOfRange);
        }
        Ok(Self {
            calibration,
            rotation,
            combined,
        })
    }

    /// The calibration (`b`, `W`).
    pub fn calibration(&self) -> Calibration<T> {
        self.calibration
    }

    /// The rotation `R` into the reference frame, by rows.
    pub fn rotation(&self) -> [[T; 3]; 3] {
        rows(&self.rotation)
    }

    /// [`AlignedCalibration::rotation`] as a matrix (feature `nalgebra`).
    #[cfg(feature = "nalgebra")]
    pub fn rotation_matrix(&self) -> Matrix3<T> {
        self.rotation
    }

    /// Calibrated reading in the reference frame, on the unit sphere:
    /// `R W (raw - b)`, from a raw reading of any [`Sample`] type.
    pub fn apply<S: Sample>(&self, raw: S) -> [T; 3] {
        (self.combined * (Vector3::from(raw.xyz::<T>()) - self.calibration.b())).into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    use crate::test_support::Rng;

    fn arr(v: Vector3<f64>) -> [f64; 3] {
        [v.x, v.y, v.z]
    }

    fn arr32(v: [f64; 3]) -> [f32; 3] {
        v.map(|c| c as f32)
    }

    /// Rotation angle of `a^T b`, radians (atan2 of sine and cosine, which
    /// unlike acos stays accurate for small angles).
    fn angle_between(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
        let r = a.transpose() * b;
        let skew = Vector3::new(
            r[(2, 1)] - r[(1, 2)],
            r[(0, 2)] - r[(2, 0)],
            r[(1, 0)] - r[(0, 1)],
        );
        libm::atan2(skew.norm() / 2.0, (r.trace() - 1.0) / 2.0)
    }

    fn cost(q: &Matrix3<f64>, u: &[[f64; 3]], h: &[[f64; 3]]) -> f64 {
        u.iter()
            .zip(h)
            .map(|(u, h)| (q * Vector3::from(*u) - Vector3::from(*h)).norm_squared())
            .sum()
    }

    fn assert_proper_rotation<T: Real>(q: &Matrix3<T>, tol: f64) {
        let defect = (q.transpose() * q - Matrix3::identity()).amax().to_f64();
        assert!(defect < tol, "not orthonormal: {defect:e}");
        let det = q.determinant().to_f64();
        assert!((det - 1.0).abs() < tol, "det {det}");
    }

    #[test]
    fn recovers_a_known_rotation_from_noise_free_pairs() {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        for _ in 0..200 {
            let truth = rng.rotation();
            let mut u = [[0.0; 3]; 20];
            let mut h = [[0.0; 3]; 20];
            for (u, h) in u.iter_mut().zip(h.iter_mut()) {
                // Not unit vectors: the magnitudes only weight the pairs.
                let d = rng.direction() * (0.5 + rng.uniform());
                *u = arr(d);
                *h = arr(truth * d);
            }
            let q = procrustes_matrix(&u, &h).unwrap();
            assert!((q - truth).amax() < 1e-12, "{:e}", (q - truth).amax());
            assert_proper_rotation(&q, 1e-14);

            let (u32s, h32s) = (u.map(arr32), h.map(arr32));
            let q32 = procrustes_matrix(&u32s, &h32s).unwrap();
            let err = (q32.cast::<f64>() - truth).amax();
            assert!(err < 1e-5, "f32: {err:e}");
            assert_proper_rotation(&q32, 1e-6);
        }
    }

    #[test]
    fn two_pairs_suffice() {
        let truth = *Rotation3::from_euler_angles(0.3, -1.1, 2.9).matrix();
        let u = [[1.0, 0.0, 0.0], [0.5, 0.5, 0.0]];
        let h = u.map(|v| arr(truth * Vector3::from(v)));
        let q = procrustes_matrix(&u, &h).unwrap();
        assert!((q - truth).amax() < 1e-14);
    }

    #[test]
    fn narrow_cones_keep_their_accuracy() {
        // Pairs within a cone of +-0.05 rad: B is graded (s2 / s1 ~ 1e-3),
        // where an SVD through B^T B (nalgebra's 3x3 path) is off by up to
        // 0.1 rad in f32.
        let mut rng = Rng(7);
        for _ in 0..50 {
            let truth = rng.rotation();
            let mut u = [[0.0f32; 3]; 50];
            let mut h = [[0.0f32; 3]; 50];
            let mut u64s = [[0.0f64; 3]; 50];
            let mut h64s = [[0.0f64; 3]; 50];
            for k in 0..50 {
                let d = Vector3::new(1.0, 0.05 * rng.symmetric(), 0.05 * rng.symmetric());
                (u64s[k], h64s[k]) = (arr(d), arr(truth * d));
                (u[k], h[k]) = (arr32(u64s[k]), arr32(h64s[k]));
            }
            let q = procrustes_matrix(&u, &h).unwrap();
            let err = angle_between(&q.cast(), &truth);
            assert!(err < 1e-4, "{err:e}");
            // A cone 100 times narrower is refused in f32 (the curvature is
            // below sqrt(eps) s1) but is still well within f64's reach.
            for (u, h) in u64s.iter_mut().zip(h64s.iter_mut()) {
                let d = Vector3::new(1.0, u[1] * 0.01, u[2] * 0.01);
                (*u, *h) = (arr(d), arr(truth * d));
            }
            assert_eq!(
                procrustes_matrix(&u64s.map(arr32), &h64s.map(arr32)),
                Err(Error::SingularSystem)
            );
            let q = procrustes_matrix(&u64s, &h64s).unwrap();
            assert!(angle_between(&q, &truth) < 1e-10);
        }
    }

    #[test]
    fn stays_a_rotation_when_the_best_orthogonal_fit_is_a_reflection() {
        let mut rng = Rng(42);
        let mirror = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        for _ in 0..50 {
            let truth = rng.rotation();
            // Anisotropic directions (distinct singular values of B), mapped
            // by a rotation and then mirrored: a left-handed reference.
            let mut u = [[0.0; 3]; 30];
            let mut h = [[0.0; 3]; 30];
            for (u, h) in u.iter_mut().zip(h.iter_mut()) {
                let d = rng.direction().component_mul(&Vector3::new(3.0, 2.0, 1.0));
                *u = arr(d);
                *h = arr(mirror * truth * d);
            }
            // The unconstrained optimum (U V^T) is a reflection here.
            let b = u.iter().zip(&h).fold(Matrix3::zeros(), |b, (u, h)| {
                b + Vector3::from(*h) * Vector3::from(*u).transpose()
            });
            let svd = nalgebra::SVD::new(b, true, true);
            let (uu, vt) = (svd.u.unwrap(), svd.v_t.unwrap());
            assert!((uu * vt).determinant() < 0.0);
            let expected = uu * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0)) * vt;

            let q = procrustes_matrix(&u, &h).unwrap();
            assert_proper_rotation(&q, 1e-13);
            assert!((q - expected).amax() < 1e-9, "{:e}", (q - expected).amax());
            // And it is a minimum among rotations: small turns cost more.
            let c0 = cost(&q, &u, &h);
            for axis in [Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis()] {
                for angle in [-1e-3, 1e-3, 0.5, 3.0] {
                    let turned = Rotation3::from_axis_angle(&axis, angle).matrix() * q;
                    assert!(cost(&turned, &u, &h) > c0);
                }
            }
        }
    }

    #[test]
    fn refuses_malformed_input() {
        let u = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        assert_eq!(
            procrustes_matrix(&u, &u[..1]),
            Err(Error::MismatchedLengths)
        );
        assert_eq!(
            procrustes_matrix(&u[..1], &u[..1]),
            Err(Error::TooFewSamples {
                found: 1,
                required: 2
            })
        );
        assert_eq!(
            procrustes_matrix::<f64>(&[], &[]),
            Err(Error::TooFewSamples {
                found: 0,
                required: 2
            })
        );
        // Parallel (and anti-parallel) pairs leave the rotation about their
        // common axis free.
        let p = [[1.0, 2.0, 3.0], [-2.0, -4.0, -6.0], [0.5, 1.0, 1.5]];
        let r = *Rotation3::from_euler_angles(0.2, 0.4, 0.6).matrix();
        let ph = p.map(|v| arr(r * Vector3::from(v)));
        assert_eq!(procrustes_matrix(&p, &ph), Err(Error::SingularSystem));
        assert_eq!(
            procrustes_matrix(&p.map(arr32), &ph.map(arr32)),
            Err(Error::SingularSystem)
        );
        // All zero, or pairs that cancel (B = 0).
        let z = [[0.0; 3]; 3];
        assert_eq!(procrustes_matrix(&z, &p), Err(Error::SingularSystem));
        let x = [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
        let xh = [[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]];
        assert_eq!(procrustes_matrix(&x, &xh), Err(Error::SingularSystem));
        // A point reflection of evenly spread directions: every rotation by
        // 180 deg fits equally well, no unique answer.
        let axes = [
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [-1.0, 0.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, -1.0],
        ];
        let minus = axes.map(|v| v.map(|c: f64| -c));
        assert_eq!(procrustes_matrix(&axes, &minus), Err(Error::SingularSystem));
    }

    #[test]
    fn skips_non_finite_pairs() {
        let r = *Rotation3::from_euler_angles(-0.7, 0.1, 1.3).matrix();
        let good = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.3, -0.2, 0.9]];
        let good_h = good.map(|v| arr(r * Vector3::from(v)));
        let mut u = [[0.0; 3]; 6];
        let mut h = [[0.0; 3]; 6];
        u[..3].copy_from_slice(&good);
        h[..3].copy_from_slice(&good_h);
        u[3] = [f64::NAN, 0.0, 0.0];
        h[3] = [1.0, 0.0, 0.0];
        u[4] = [0.0, 1.0, 0.0];
        h[4] = [0.0, f64::INFINITY, 0.0];
        u[5] = [f64::NEG_INFINITY; 3];
        h[5] = [f64::NAN; 3];
        let q = procrustes_matrix(&u, &h).unwrap();
        assert!((q - r).amax() < 1e-14);
        // One finite pair left is too few.
        assert_eq!(
            procrustes_matrix(&u[2..], &h[2..]),
            Err(Error::TooFewSamples {
                found: 1,
                required: 2
            })
        );
    }

    #[test]
    fn noisy_pairs_give_a_rotation_close_to_the_truth() {
        let mut rng = Rng(2024);
        let sigma = 0.01;
        for _ in 0..20 {
            let truth = rng.rotation();
            let mut u = [[0.0; 3]; 300];
            let mut h = [[0.0; 3]; 300];
            for (u, h) in u.iter_mut().zip(h.iter_mut()) {
                let d = rng.direction();
                // Uniform noise of standard deviation sigma per component.
                let noise = Vector3::new(rng.symmetric(), rng.symmetric(), rng.symmetric())
                    * (sigma * libm::sqrt(3.0));
                *u = arr(d);
                *h = arr(truth * d + noise);
            }
            let q = procrustes_matrix(&u, &h).unwrap();
            assert_proper_rotation(&q, 1e-13);
            // Expected error about sigma sqrt(3 / (2 n)) ~ 7e-4 rad.
            let err = angle_between(&q, &truth);
            assert!(err < 3e-3, "{err:e}");
            assert!(err > 0.0);
        }
    }

    #[test]
    fn extreme_magnitudes_do_not_overflow() {
        let r = *Rotation3::from_euler_angles(1.0, 0.5, -2.0).matrix();
        let u = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let h = u.map(|v| arr(r * Vector3::from(v)));
        let big = u.map(|v| v.map(|c| (c * 1e30) as f32));
        let tiny = h.map(|v| v.map(|c| (c * 1e-30) as f32));
        let q = procrustes_matrix(&big, &tiny).unwrap();
        assert!((q.cast::<f64>() - r).amax() < 1e-6);
    }

    #[test]
    fn jacobi_svd_converges_on_hard_matrices() {
        let mut rng = Rng(99);
        let mut cases = [Matrix3::zeros(); 200];
        for (k, m) in cases.iter_mut().enumerate() {
            *m = Matrix3::from_fn(|_, _| rng.symmetric());
            match k % 5 {
                // Rank 1 and rank 2.
                1 => *m = rng.direction() * rng.direction().transpose(),
                2 => m.set_column(2, &(m.column(0) * 0.5 - m.column(1))),
                // Graded columns; in f32 the last is below eps |B| and its
                // square underflows.
                3 => {
                    m.set_column(1, &(m.column(1) * 1e-4));
                    m.set_column(2, &(m.column(2) * if k % 2 == 0 { 1e-8 } else { 1e-30 }));
                }
                // A zero column.
                4 => m.set_column(0, &Vector3::zeros()),
                _ => {}
            }
        }
        for (k, b) in cases.iter().enumerate() {
            let b = b / b.amax().max(f64::MIN_POSITIVE);
            let (a, v) = jacobi_svd(&b.into()).unwrap_or_else(|e| panic!("{k}: {e:?} {b}"));
            let (a, v) = (Matrix3::from(a), Matrix3::from(v));
            assert!((v.transpose() * v - Matrix3::identity()).amax() < 1e-14);
            assert!((b * v - a).amax() < 1e-14);
            let negligible = f64::EPSILON * b.norm();
            for (p, q) in [(0, 1), (0, 2), (1, 2)] {
                let (ap, aq) = (a.column(p), a.column(q));
                if ap.norm() > negligible && aq.norm() > negligible {
                    assert!(ap.dot(&aq).abs() <= 1e-14 * ap.norm() * aq.norm());
                }
            }
            let b32 = b.cast::<f32>();
            let (a32, v32) =
                jacobi_svd(&b32.into()).unwrap_or_else(|e| panic!("f32 {k}: {e:?} {b32}"));
            let (a32, v32) = (Matrix3::from(a32), Matrix3::from(v32));
            assert!((b32 * v32 - a32).amax() < 1e-6);
        }
    }

    #[test]
    fn descending_sorts_every_order_and_keeps_the_payload() {
        let perms = [
            [0, 1, 2],
            [0, 2, 1],
            [1, 0, 2],
            [1, 2, 0],
            [2, 0, 1],
            [2, 1, 0],
        ];
        for p in perms {
            let mut x = p.map(|k| (f64::from(k), k, 10 * k));
            descending(&mut x);
            assert_eq!(x, [(2.0, 2, 20), (1.0, 1, 10), (0.0, 0, 0)]);
        }
    }

    #[test]
    fn aligned_calibration_applies_r_w_y_minus_b() {
        let w = Matrix3::new(0.02, 0.001, 0.0, 0.001, 0.025, -0.002, 0.0, -0.002, 0.018);
        let b = Vector3::new(120.0, -40.0, 15.0);
        let cal = Calibration::from_matrices(b, w).unwrap();
        let r = *Rotation3::from_euler_angles(0.4, -0.2, 1.7).matrix();
        let aligned = AlignedCalibration::new(cal, rows(&r)).unwrap();
        assert_eq!(aligned.calibration(), cal);
        assert_eq!(aligned.rotation(), rows(&r));
        for y in [[150.0, -10.0, 40.0], [90.0, -80.0, -20.0], [0.0, 0.0, 0.0]] {
            let expected = r * (cal.w() * (Vector3::from(y) - b));
            let got = Vector3::from(aligned.apply(y));
            assert!((got - expected).amax() < 1e-14);
            assert!((got - r * Vector3::from(cal.apply(y))).amax() < 1e-14);
        }
        // f32, with the rotation from procrustes.
        let u = [[1.0f32, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let h = u.map(|v| arr32(arr(r * Vector3::from(v.map(f64::from)))));
        let q = procrustes(&u, &h).unwrap();
        let cal32 = Calibration::from_matrices(b.cast::<f32>(), w.cast::<f32>()).unwrap();
        assert!(AlignedCalibration::new(cal32, q).is_ok());
    }

    #[test]
    fn aligned_calibration_rejects_non_rotations() {
        let cal =
            Calibration::from_matrices(Vector3::new(1.0, 2.0, 3.0), Matrix3::identity()).unwrap();
        let new = |m: Matrix3<f64>| AlignedCalibration::new(cal, rows(&m));
        let r = *Rotation3::from_euler_angles(0.4, -0.2, 1.7).matrix();
        let mirror = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, 1.0));
        assert_eq!(new(r * mirror), Err(Error::SingularSystem));
        assert_eq!(new(r * 1.001), Err(Error::SingularSystem));
        let mut skew = r;
        skew[(0, 1)] += 1e-6;
        assert_eq!(new(skew), Err(Error::SingularSystem));
        assert_eq!(new(Matrix3::zeros()), Err(Error::SingularSystem));
        let mut nan = r;
        nan[(2, 2)] = f64::NAN;
        assert_eq!(new(nan), Err(Error::OutOfRange));
        // Rounding-level defects are accepted.
        let mut nearly = r;
        nearly[(0, 1)] += 1e-14;
        assert!(new(nearly).is_ok());
    }
}
