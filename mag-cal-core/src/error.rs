//! The one error type of the crate.

use core::fmt;

/// Why a calibration was refused.
///
/// Every input, however malformed, ends either in a calibration or in one of
/// these values; the core never panics. The enum is `Copy` and small so that
/// firmware can log or store it without ceremony.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Error {
    /// Fewer usable (finite) samples than the fit needs.
    TooFewSamples {
        /// Finite samples found.
        found: usize,
        /// Samples required.
        required: usize,
    },
    /// Every finite sample is the same point: there is no spread to fit.
    AllSamplesEqual,
    /// The samples' spread cannot be represented in the working precision:
    /// squares overflow (values near `1e30` in `f32`), or the spread is
    /// subnormal and carries too few significant bits.
    OutOfRange,
    /// The fitted quadric is not an ellipsoid (its matrix `M` is not
    /// positive definite), e.g. for planar or otherwise degenerate motion.
    NotAnEllipsoid,
    /// A linear system of the fit is singular: the samples do not determine
    /// the parameters (coplanar or collinear directions, duplicated points).
    SingularSystem,
    /// An iterative solver hit its iteration cap before its stop criteria.
    NoConvergence {
        /// Iterations performed.
        iterations: u32,
    },
    /// Two inputs that must pair up element by element have different
    /// lengths (e.g. calibrated and reference vectors for alignment).
    MismatchedLengths,
    /// The configuration asks for a method or LS variant that this build
    /// leaves out: enable its cargo feature.
    NotEnabled {
        /// The cargo feature of `mag-cal-core` that compiles it in.
        feature: &'static str,
    },
    /// A given noise covariance is not finite, symmetric and positive
    /// definite.
    InvalidNoiseCovariance,
    /// The samples lie near a plane (flat covariance): the third axis is not
    /// observed. Turn the sensor through all orientations.
    Planar,
    /// More than one quadric fits the samples about equally well (e.g. two
    /// great circles): the ellipsoid is not determined.
    AmbiguousQuadric,
    /// The fitted ellipsoid is too eccentric to be a magnetometer's
    /// distortion (condition number of `M` above the limit).
    ExtremeDistortion,
    /// The calibrated directions cover too little of the sphere for the
    /// estimate to be trusted (e.g. a spherical cap).
    PoorCoverage,
    /// The fitted field strength is too far from the expected one.
    FieldStrengthMismatch,
    /// The samples do not lie on a sphere after calibration: the robust
    /// fit error is too large. The device lay still or was barely moved,
    /// or the rows are not one magnetometer's readings (a filled cloud).
    NoSphere {
        /// Robust fit error (standard deviation of `|u| - 1`).
        fit_error: Figure,
        /// The limit it exceeds.
        limit: Figure,
    },
    /// The samples fill a volume instead of lying on a shell: the radial
    /// residuals of the rows used are skewed inwards, with a fit error
    /// beyond the warning (a filled cloud, which an ellipsoid fit of its
    /// outer rows can pass under the fit-error limit).
    FilledCloud {
        /// Skewness of `|u| - 1` over the rows used.
        skewness: Figure,
        /// The limit it is below.
        limit: Figure,
    },
    /// Too many rows are outliers to trust the rest: more than the limit's
    /// share of the rows kept by the rules were screened out or rejected
    /// by their residual.
    TooManyOutliers {
        /// Rows screened out or rejected.
        rejected: usize,
        /// Rows kept by the rules.
        valid: usize,
        /// The share that may be rejected.
        limit: Figure,
    },
    /// The calibrated samples sit systematically off the unit sphere in
    /// some region of directions: a disturbance displaced part of the
    /// trajectory, or an ellipsoid does not describe the sensor.
    SystematicMisfit {
        /// The lack-of-fit figure.
        lack_of_fit: Figure,
        /// The limit it exceeds.
        limit: Figure,
    },
    /// Stored calibration bytes end early.
    Truncated,
    /// Stored calibration bytes do not start with the expected magic.
    BadMagic,
    /// Stored calibration bytes have a format version this build cannot read.
    UnsupportedVersion {
        /// Version found.
        found: u8,
    },
    /// Stored calibration bytes fail their checksum.
    ChecksumMismatch,
    /// An offsets-only fit: the readings' directions cover too small a cap
    /// to determine the offsets ([`crate::offsets`]).
    OffsetsUndetermined {
        /// Smallest over largest eigenvalue of the normal matrix.
        determinacy: Figure,
        /// The limit it is below.
        limit: Figure,
    },
    /// A planar fit ([`crate::planar`]): the samples do not lie near one
    /// plane; the device turned about more than one axis.
    NotPlanar {
        /// Smallest over largest eigenvalue of the samples' covariance.
        flatness: Figure,
        /// The limit it exceeds.
        limit: Figure,
    },
    /// A planar fit: the samples in their plane do not lie on an ellipse
    /// (robust fit error too large, or a conic that is not an ellipse,
    /// given as infinity).
    NoEllipse {
        /// Robust fit error (standard deviation of `|u| - 1`).
        fit_error: Figure,
        /// The limit it exceeds.
        limit: Figure,
    },
    /// A planar fit: the turns cover too little of the circle.
    ShortArc {
        /// Sectors of 30 deg of turn angle that hold samples.
        sectors: u8,
        /// Sectors required.
        required: u8,
    },
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Error::TooFewSamples { found, required } => write!(
                f,
                "too few usable samples: {found} kept, at least {required} required"
            ),
            Error::AllSamplesEqual => f.write_str("all samples are equal: no spread to fit"),
            Error::OutOfRange => f.write_str(
                "sample spread outside the range of the working precision (overflow or subnormal)",
            ),
            Error::NotAnEllipsoid => {
                f.write_str("the fitted quadric is not an ellipsoid (degenerate or planar motion)")
            }
            Error::SingularSystem => {
                f.write_str("singular system: the samples do not determine the calibration")
            }
            Error::NoConvergence { iterations } => {
                write!(f, "solver did not converge within {iterations} iterations")
            }
            Error::MismatchedLengths => f.write_str("paired inputs have different lengths"),
            Error::NotEnabled { feature } => write!(
                f,
                "this build of mag-cal-core leaves the method out: enable its cargo feature `{feature}`"
            ),
            Error::InvalidNoiseCovariance => {
                f.write_str("noise covariance is not finite, symmetric and positive definite")
            }
            Error::Planar => f.write_str(
                "samples lie near a plane: turn the sensor through all orientations",
            ),
            Error::AmbiguousQuadric => f.write_str(
                "several quadrics fit the samples about equally well: the ellipsoid is not determined",
            ),
            Error::ExtremeDistortion => {
                f.write_str("fitted ellipsoid too eccentric for a magnetometer distortion")
            }
            Error::PoorCoverage => f.write_str(
                "calibrated directions cover too little of the sphere: turn the sensor further",
            ),
            Error::FieldStrengthMismatch => {
                f.write_str("fitted field strength too far from the expected value")
            }
            Error::NoSphere { fit_error, limit } => write!(
                f,
                "the samples do not lie on a sphere (fit error {fit_error:.3} of the field, limit {limit:.2}): \
                 the device was not rotated, or these are not one magnetometer's readings"
            ),
            Error::FilledCloud { skewness, limit } => write!(
                f,
                "the samples fill a volume instead of lying on a sphere (radial residuals skewed inwards: \
                 skewness {skewness:.2}, limit {limit:.2}): these are not one magnetometer's readings of a turning device"
            ),
            Error::TooManyOutliers {
                rejected,
                valid,
                limit,
            } => write!(
                f,
                "too many outliers: {rejected} of {valid} samples off the fitted ellipsoid (more than {:.0} %): \
                 a disturbance or a faulty sensor; collect again",
                limit.get() * 100.0
            ),
            Error::SystematicMisfit { lack_of_fit, limit } => write!(
                f,
                "the ellipsoid misfits a region of the samples (lack of fit {lack_of_fit:.4} of the field, limit {limit:.3}): \
                 a disturbance moved part of the trajectory; collect again away from magnets and currents"
            ),
            Error::Truncated => f.write_str("stored calibration is truncated"),
            Error::BadMagic => f.write_str("stored bytes are not a calibration (bad magic)"),
            Error::UnsupportedVersion { found } => {
                write!(f, "stored calibration has unsupported format version {found}")
            }
            Error::ChecksumMismatch => f.write_str("stored calibration fails its checksum"),
            Error::OffsetsUndetermined { determinacy, limit } => write!(
                f,
                "the readings cover too few directions to determine the offsets (determinacy {determinacy:.3}, limit {limit:.3}): turn the sensor further"
            ),
            Error::NotPlanar { flatness, limit } => write!(
                f,
                "the samples do not lie in a plane (flatness {flatness:.3}, limit {limit:.3}): \
                 the device turned about more than one axis; use the three-dimensional calibration"
            ),
            Error::NoEllipse { fit_error, limit } if !fit_error.get().is_finite() => write!(
                f,
                "the samples in their plane do not lie on an ellipse (the fitted conic is not one, limit {limit:.2}): \
                 the device did not turn, or these are not one magnetometer's readings"
            ),
            Error::NoEllipse { fit_error, limit } => write!(
                f,
                "the samples in their plane do not lie on an ellipse (fit error {fit_error:.3} of the field in the plane, limit {limit:.2}): \
                 the device did not turn, tilted by more than a few degrees while turning, or these are not one magnetometer's readings"
            ),
            Error::ShortArc { sectors, required } => write!(
                f,
                "the turns cover {sectors} of 12 sectors of 30 deg, at least {required} required: turn through a full circle"
            ),
        }
    }
}

impl core::error::Error for Error {}

/// A quality figure carried by an [`Error`]: an `f32` that compares by its
/// bits, so that the error stays `Eq` and `Hash`. Formats as the number.
#[derive(Clone, Copy, Debug)]
pub struct Figure(f32);

impl Figure {
    /// The figure `value`.
    pub const fn new(value: f32) -> Self {
        Self(value)
    }

    /// Its value.
    pub const fn get(self) -> f32 {
        self.0
    }
}

impl PartialEq for Figure {
    fn eq(&self, other: &Self) -> bool {
        self.0.to_bits() == other.0.to_bits()
    }
}

impl Eq for Figure {}

impl core::hash::Hash for Figure {
    fn hash<H: core::hash::Hasher>(&self, state: &mut H) {
        self.0.to_bits().hash(state);
    }
}

impl fmt::Display for Figure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(&self.0, f)
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for Figure {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "{=f32}", self.0);
    }
}
