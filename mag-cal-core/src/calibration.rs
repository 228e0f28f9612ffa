//! Step 5 of Algorithm 1: the calibration value, in canonical form.

use nalgebra::{Matrix3, Vector3};

use crate::numerics::linalg::{from_rows, rows, sym_sqrt};
use crate::steps::normalize::Normalization;
use crate::{Error, Real, Sample};

/// A magnetometer calibration: `u = W (y - b)` lies on the unit sphere.
///
/// Only `M = W^T W` and `b` are determined by data (any rotation of the
/// calibrated frame fits equally well); `W` is kept in the canonical
/// symmetric positive definite form `W = M^(1/2)`. Aligning the calibrated
/// frame with a reference frame is a separate step.
///
/// Constructed only through a fit or [`Calibration::new`], both of which
/// validate, so the accessors never fail.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(
        into = "Stored<T>",
        try_from = "Stored<T>",
        bound = "T: Real + serde::Serialize + serde::de::DeserializeOwned"
    )
)]
pub struct Calibration<T: Real> {
    hard_iron: Vector3<T>,
    soft_iron: Matrix3<T>,
    field_strength: T,
}

impl<T: Real> Calibration<T> {
    /// Builds a calibration from a hard-iron offset `b` and a soft-iron
    /// matrix `W` (sensor units; `W` by rows, `soft_iron[i][j]` in row `i`,
    /// column `j`). `W` is replaced by its canonical form `(W^T W)^(1/2)`;
    /// it must be finite and non-singular.
    ///
    /// # Errors
    /// [`Error::OutOfRange`] for a non-finite entry or a field strength
    /// beyond the type's range, [`Error::SingularSystem`] for a singular
    /// `W`.
    pub fn new(hard_iron: [T; 3], soft_iron: [[T; 3]; 3]) -> Result<Self, Error> {
        Self::from_matrices(Vector3::from(hard_iron), from_rows(soft_iron))
    }

    /// [`Calibration::new`] on the internal types.
    pub(crate) fn from_matrices(
        hard_iron: Vector3<T>,
        soft_iron: Matrix3<T>,
    ) -> Result<Self, Error> {
        if !hard_iron
            .iter()
            .chain(soft_iron.iter())
            .all(|v| v.is_finite())
        {
            return Err(Error::OutOfRange);
        }
        // A singular W makes W^T W singular: say so in the user's terms.
        let w = sym_sqrt(&(soft_iron.transpose() * soft_iron)).map_err(|e| match e {
            Error::NotAnEllipsoid => Error::SingularSystem,
            other => other,
        })?;
        Self::from_canonical(hard_iron, w)
    }

    /// From a symmetric positive definite `W` already in canonical form.
    pub(crate) fn from_canonical(hard_iron: Vector3<T>, w: Matrix3<T>) -> Result<Self, Error> {
        // rho = det(W)^(-1/3), computed on W scaled to a largest entry of 1:
        // det(W) itself is subnormal in f32 once rho exceeds about 4e12
        // sensor units, and then carries too few bits (20 % errors were
        // found by fuzzing). The scaled determinant is at most 6.
        // `w.amax()` on the slice (nalgebra's iterator took more flash):
        // the same fold, the first entry's magnitude then the largest.
        let entries = w.as_slice();
        let first = entries.first().map_or(T::zero(), |x| x.abs());
        let scale = entries
            .iter()
            .skip(1)
            .fold(first, |a, b| nalgebra::SimdPartialOrd::simd_max(a, b.abs()));
        if !(scale > T::zero()) || !scale.is_finite() {
            return Err(Error::SingularSystem);
        }
        let det = (w / scale).determinant();
        if !(det > T::MIN_POSITIVE / T::EPSILON) || !det.is_finite() {
            return Err(Error::SingularSystem);
        }
        let field_strength = T::one() / (scale * det.positive_cbrt());
        if !field_strength.is_finite() || !hard_iron.as_slice().iter().all(|v| v.is_finite()) {
            return Err(Error::OutOfRange);
        }
        Ok(Self {
            hard_iron,
            soft_iron: w,
            field_strength,
        })
    }

    /// From an ellipsoid in normalised coordinates: `W = W'/s`,
    /// `b = c + s b'`.
    pub(crate) fn from_normalised_w(
        norm: &Normalization<T>,
        w_prime: &Matrix3<T>,
        centre: &Vector3<T>,
    ) -> Result<Self, Error> {
        Self::from_canonical(norm.point_back(centre), w_prime * norm.inv_scale)
    }

    /// Hard-iron offset `b`, sensor units.
    pub fn hard_iron(&self) -> [T; 3] {
        self.hard_iron.into()
    }

    /// Soft-iron correction `W` by rows (symmetric positive definite,
    /// `1 / sensor unit`): `W (y - b)` is on the unit sphere.
    pub fn soft_iron(&self) -> [[T; 3]; 3] {
        rows(&self.soft_iron)
    }

    /// `M = W^T W` by rows: the gauge-free shape, `(y - b)^T M (y - b) = 1`.
    pub fn shape(&self) -> [[T; 3]; 3] {
        rows(&self.m())
    }

    /// Local field strength `rho = |det T|^(1/3) = det(W)^(-1/3)`, sensor
    /// units: the radius of the sphere of equal volume.
    pub fn field_strength(&self) -> T {
        self.field_strength
    }

    /// Calibrated reading on the unit sphere: `W (y - b)`, from a raw
    /// reading of any [`Sample`] type (a non-finite reading gives a
    /// non-finite result).
    ///
    /// ```
    /// use mag_cal_core::Calibration;
    /// let half = [[0.5, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 0.5]];
    /// let cal = Calibration::<f64>::new([10.0, 0.0, 0.0], half).unwrap();
    /// assert_eq!(cal.apply([12.0, 0.0, 0.0]), [1.0, 0.0, 0.0]);
    /// // Integer counts as the sensor gives them, e.g. a driver's tuple.
    /// assert_eq!(cal.apply((10_i16, 2_i16, 0_i16)), [0.0, 1.0, 0.0]);
    /// assert_eq!(cal.field_strength(), 2.0);
    /// ```
    pub fn apply<S: Sample>(&self, raw: S) -> [T; 3] {
        self.map(raw.xyz()).into()
    }

    /// Calibrated reading in sensor units: `rho W (y - b)`, whose norm is
    /// the local field strength.
    pub fn apply_scaled<S: Sample>(&self, raw: S) -> [T; 3] {
        (self.map(raw.xyz()) * self.field_strength).into()
    }

    /// [`Calibration::apply`] on the internal types.
    pub(crate) fn map(&self, y: [T; 3]) -> Vector3<T> {
        // Written out, the operations of nalgebra's product in its order
        // (each row's terms left to right): its loops took 20 bytes of
        // flash more (LS9 + ADC2 with `robust`, the runs' rows in `finish`).
        let (w, b) = (&self.soft_iron, &self.hard_iron);
        let d = [y[0] - b.x, y[1] - b.y, y[2] - b.z];
        let row = |i: usize| w[(i, 0)] * d[0] + w[(i, 1)] * d[1] + w[(i, 2)] * d[2];
        Vector3::new(row(0), row(1), row(2))
    }

    /// `b` as the internal type.
    pub(crate) fn b(&self) -> Vector3<T> {
        self.hard_iron
    }

    /// `W` as the internal type.
    pub(crate) fn w(&self) -> Matrix3<T> {
        self.soft_iron
    }

    /// `M = W^T W` as the internal type.
    pub(crate) fn m(&self) -> Matrix3<T> {
        self.soft_iron.transpose() * self.soft_iron
    }
}

/// Conversions for host code that computes with `nalgebra` (feature
/// `nalgebra`; the types are those of the `nalgebra` release this crate
/// depends on, 0.35).
#[cfg(feature = "nalgebra")]
impl<T: Real> Calibration<T> {
    /// [`Calibration::new`] from `nalgebra` types.
    ///
    /// # Errors
    /// As [`Calibration::new`].
    pub fn from_nalgebra(hard_iron: Vector3<T>, soft_iron: Matrix3<T>) -> Result<Self, Error> {
        Self::from_matrices(hard_iron, soft_iron)
    }

    /// [`Calibration::hard_iron`] as a vector.
    pub fn hard_iron_vector(&self) -> Vector3<T> {
        self.hard_iron
    }

    /// [`Calibration::soft_iron`] as a matrix.
    pub fn soft_iron_matrix(&self) -> Matrix3<T> {
        self.soft_iron
    }

    /// [`Calibration::shape`] as a matrix.
    pub fn shape_matrix(&self) -> Matrix3<T> {
        self.m()
    }

    /// [`Calibration::apply`] as a vector.
    pub fn apply_vector<S: Sample>(&self, raw: S) -> Vector3<T> {
        self.map(raw.xyz())
    }

    /// [`Calibration::apply_scaled`] as a vector.
    pub fn apply_scaled_vector<S: Sample>(&self, raw: S) -> Vector3<T> {
        self.map(raw.xyz()) * self.field_strength
    }
}

/// The serialised form (feature `serde`): `b` and `W` by rows, and the
/// field strength, which is recomputed (and so need not be given) when
/// read back.
#[cfg(feature = "serde")]
#[derive(serde::Serialize, serde::Deserialize)]
#[serde(bound = "T: serde::Serialize + serde::de::DeserializeOwned")]
struct Stored<T> {
    hard_iron: [T; 3],
    soft_iron: [[T; 3]; 3],
    #[serde(default)]
    field_strength: Option<T>,
}

#[cfg(feature = "serde")]
impl<T: Real> From<Calibration<T>> for Stored<T> {
    fn from(c: Calibration<T>) -> Self {
        Self {
            hard_iron: c.hard_iron(),
            soft_iron: c.soft_iron(),
            field_strength: Some(c.field_strength()),
        }
    }
}

#[cfg(feature = "serde")]
impl<T: Real> TryFrom<Stored<T>> for Calibration<T> {
    type Error = Error;

    fn try_from(s: Stored<T>) -> Result<Self, Error> {
        Calibration::new(s.hard_iron, s.soft_iron)
    }
}
