//! The fit's error type, and the printing of figures against limits.

use core::fmt;

/// Why a calibration was refused.
///
/// Every input, however malformed, ends either in a calibration or in one of
/// these values; the core never panics. The enum is `Copy` and small so that
/// firmware can log or store it without ceremony. Stored records fail with
/// [`crate::persist::Error`], the planar fit with [`crate::planar::Error`].
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
    /// The device hardly moved: beside the rows of its still periods
    /// (set aside, [`crate::Dwell`]) too few rows are left.
    HardlyMoved {
        /// Rows in motion (outside the still periods).
        moving: usize,
        /// Rows lying still (set aside).
        still: usize,
        /// Rows in motion required.
        required: usize,
    },
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
    /// A configuration value is invalid: a given noise covariance that is
    /// not finite, symmetric and positive definite (`noise_covariance`), or
    /// a judging limit or another setting that is NaN or out of its range
    /// (the field's name; see
    /// [`Thresholds::validate`](crate::Thresholds::validate),
    /// `BackgroundConfig::validate` and `PlanarConfig::validate`).
    InvalidConfig {
        /// The field: `noise_covariance`, a `Thresholds` field, or a field
        /// of the background or planar configuration.
        field: &'static str,
    },
    /// The samples lie near a plane (flat covariance): the third axis is not
    /// observed. Turn the sensor through all orientations.
    Planar {
        /// Flatness: smallest over largest eigenvalue of the samples'
        /// covariance.
        flatness: Figure,
        /// The limit it is below.
        limit: Figure,
    },
    /// More than one quadric fits the samples about equally well (e.g. two
    /// great circles): the ellipsoid is not determined. Judged only on data
    /// that fit their ellipsoid closely (radial RMS below
    /// [`crate::Thresholds::gap_noise_limit`]).
    AmbiguousQuadric {
        /// How much better the best quadric fits than the next one.
        quadric_gap: Figure,
        /// The limit it is below.
        limit: Figure,
    },
    /// The fitted ellipsoid is too eccentric to be a magnetometer's
    /// distortion (condition number of `M` above the limit).
    ExtremeDistortion {
        /// Condition number of `M` (squared axis ratio).
        distortion: Figure,
        /// The limit it exceeds.
        limit: Figure,
    },
    /// The calibrated directions cover too little of the sphere for the
    /// estimate to be trusted (e.g. a spherical cap).
    PoorCoverage {
        /// Smallest eigenvalue of the calibrated directions' covariance.
        coverage: Figure,
        /// The limit it is below.
        limit: Figure,
    },
    /// The fitted field strength is too far from the expected one.
    FieldStrengthMismatch {
        /// `fitted / expected - 1`: positive when the fit is stronger.
        deviation: Figure,
        /// The limit its magnitude exceeds.
        limit: Figure,
    },
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
    /// An offsets-only fit: the readings' directions cover too small a cap
    /// to determine the offsets ([`crate::device::offsets`]).
    OffsetsUndetermined {
        /// Smallest over largest eigenvalue of the normal matrix.
        determinacy: Figure,
        /// The limit it is below.
        limit: Figure,
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
            Error::HardlyMoved {
                moving,
                still,
                required,
            } => write!(
                f,
                "the device hardly moved: {moving} samples in motion, at least {required} \
                 required ({still} more lay still): turn the sensor through all orientations \
                 while recording"
            ),
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
            Error::InvalidConfig {
                field: "noise_covariance",
            } => f.write_str("noise covariance is not finite, symmetric and positive definite"),
            Error::InvalidConfig { field } => {
                write!(f, "the configuration value `{field}` is NaN or out of its range")
            }
            Error::Planar { flatness, limit } => write!(
                f,
                "samples lie near a plane (flatness {}): turn the sensor through all orientations",
                Versus::new(flatness, limit, ""),
            ),
            Error::AmbiguousQuadric { quadric_gap, limit } => write!(
                f,
                "several quadrics fit the samples about equally well (quadric gap {}): \
                 the ellipsoid is not determined; cover more directions",
                Versus::new(quadric_gap, limit, ""),
            ),
            Error::ExtremeDistortion { distortion, limit } => write!(
                f,
                "fitted ellipsoid too eccentric for a magnetometer distortion \
                 (distortion, the condition number of M, {})",
                Versus::new(distortion, limit, ""),
            ),
            Error::PoorCoverage { coverage, limit } => write!(
                f,
                "calibrated directions cover too little of the sphere (coverage {}): turn the sensor further",
                Versus::new(coverage, limit, ""),
            ),
            Error::FieldStrengthMismatch { deviation, limit } => {
                let d = deviation.get();
                write!(
                    f,
                    "fitted field strength too far {} the expected value ({})",
                    if d < 0.0 { "below" } else { "above" },
                    Versus::of(
                        (f64::from(d) * 100.0).abs(),
                        f64::from(limit.get()) * 100.0,
                        " %"
                    ),
                )
            }
            Error::NoSphere { fit_error, limit } if !fit_error.get().is_finite() => write!(
                f,
                "the samples do not lie on a sphere (more than half of them sit at one point; fit error limit {}): \
                 the device was not rotated, or these are not one magnetometer's readings",
                Shown::alone(limit.get()),
            ),
            Error::NoSphere { fit_error, limit } => write!(
                f,
                "the samples do not lie on a sphere (fit error {}, in units of the field): \
                 the device was not rotated, or these are not one magnetometer's readings",
                Versus::new(fit_error, limit, ""),
            ),
            Error::FilledCloud { skewness, limit } => write!(
                f,
                "the samples fill a volume instead of lying on a sphere (radial residuals skewed inwards: \
                 skewness {}): these are not one magnetometer's readings of a turning device",
                Versus::new(skewness, limit, ""),
            ),
            Error::TooManyOutliers {
                rejected,
                valid,
                limit,
            } => {
                // The share as judged: rows left out over the valid rows.
                let share = rejected as f64 / valid as f64 * 100.0;
                write!(
                    f,
                    "too many outliers: {rejected} of {valid} samples off the fitted ellipsoid ({}): \
                     a disturbance or a faulty sensor; collect again",
                    Versus::of(share, f64::from(limit.get()) * 100.0, " %"),
                )
            }
            Error::SystematicMisfit { lack_of_fit, limit } => write!(
                f,
                "the ellipsoid misfits a region of the samples (lack of fit {}): \
                 a disturbance moved part of the trajectory; collect again away from magnets and currents",
                Versus::new(lack_of_fit, limit, ""),
            ),
            Error::OffsetsUndetermined { determinacy, limit } => write!(
                f,
                "the readings cover too few directions to determine the offsets (determinacy {}): turn the sensor further",
                Versus::new(determinacy, limit, ""),
            ),
        }
    }
}

impl core::error::Error for Error {}

/// Fewest significant digits a figure is printed with.
const MIN_DIGITS: u32 = 2;
/// Most significant digits a figure is printed with: two different `f64`
/// values differ in 17.
const MAX_DIGITS: u32 = 17;

/// A figure and its limit, printed as `figure{unit}, limit limit{unit}`
/// with the fewest significant digits, at least [`MIN_DIGITS`], that tell
/// them apart: the two strings differ when the numbers differ, and equal
/// numbers print alike. Trailing zeros are left out (`0.2`, not `0.20`).
///
/// Plain digits, no `core::fmt` float formatting: no panic path (the FFI's
/// link proof covers it) and a few hundred bytes of flash instead of the
/// several KiB of `core`'s float printing.
pub(crate) struct Versus {
    figure: f64,
    limit: f64,
    unit: &'static str,
}

impl Versus {
    pub(crate) fn new(figure: Figure, limit: Figure, unit: &'static str) -> Self {
        Self::of(f64::from(figure.get()), f64::from(limit.get()), unit)
    }

    /// Of values computed from figures (a percentage: in `f64`, where two
    /// `f32` figures times 100 stay apart).
    pub(crate) fn of(figure: f64, limit: f64, unit: &'static str) -> Self {
        Self {
            figure,
            limit,
            unit,
        }
    }
}

impl fmt::Display for Versus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let digits = distinguishing_digits(self.figure, self.limit);
        write_figure(f, self.figure, digits)?;
        f.write_str(self.unit)?;
        f.write_str(", limit ")?;
        write_figure(f, self.limit, digits)?;
        f.write_str(self.unit)
    }
}

/// One `f32` figure with the fewest significant digits, at least
/// [`MIN_DIGITS`], that read back as it (`0.123`, `0.2`), as [`Versus`]
/// prints it.
pub(crate) struct Shown(f32);

impl Shown {
    pub(crate) fn alone(value: f32) -> Self {
        Self(value)
    }
}

impl fmt::Display for Shown {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let x = f64::from(self.0);
        let mut digits = MIN_DIGITS;
        // 9 significant digits tell every two `f32` apart.
        while digits < 9
            && decimal(x, digits).is_some_and(|(negative, m, e)| {
                let k = e + 1 - digits as i32;
                let size = if k >= 0 {
                    m as f64 * pow10(k.unsigned_abs())
                } else {
                    m as f64 / pow10(k.unsigned_abs())
                };
                (if negative { -size } else { size }) as f32 != self.0
            })
        {
            digits += 1;
        }
        write_figure(f, x, digits)
    }
}

/// The fewest significant digits, from [`MIN_DIGITS`] to [`MAX_DIGITS`],
/// in which `a` and `b` round to different decimals (`MIN_DIGITS` when
/// they are equal).
fn distinguishing_digits(a: f64, b: f64) -> u32 {
    let mut digits = MIN_DIGITS;
    while digits < MAX_DIGITS && a != b && decimal(a, digits) == decimal(b, digits) {
        digits += 1;
    }
    digits
}

/// `10^n` (exact up to `n = 22`).
fn pow10(n: u32) -> f64 {
    let mut p = 1.0;
    for _ in 0..n.min(400) {
        p *= 10.0;
    }
    p
}

/// `x` rounded to `digits` significant digits (`digits` in `1..=17`):
/// `Some((negative, m, e))` with `10^(digits - 1) <= m < 10^digits` and
/// `|x| ~ m 10^(e + 1 - digits)`; `None` for zero, infinity and NaN (each
/// printed by name).
fn decimal(x: f64, digits: u32) -> Option<(bool, u64, i32)> {
    let a = x.abs();
    if !(a > 0.0) || !a.is_finite() {
        return None;
    }
    // e = floor(log10 a), to within one (corrected below): f64 spans
    // 1e-324 to 1e308, so each loop ends within 330 steps.
    let mut e = 0i32;
    let mut s = a;
    while s >= 10.0 && e < 400 {
        s /= 10.0;
        e += 1;
    }
    while s < 1.0 && e > -400 {
        s *= 10.0;
        e -= 1;
    }
    let low = pow10(digits.saturating_sub(1)) as u64;
    let high = pow10(digits) as u64;
    let mut m = 0;
    for _ in 0..3 {
        // a 10^(digits - 1 - e), the power exact (or correctly rounded)
        // in either direction.
        let k = digits as i32 - 1 - e;
        let scaled = if k >= 0 {
            a * pow10(k.unsigned_abs())
        } else {
            a / pow10(k.unsigned_abs())
        };
        // Round half up; `as` saturates, never panics.
        m = (scaled + 0.5) as u64;
        if m >= high {
            e += 1;
        } else if m < low {
            e -= 1;
        } else {
            break;
        }
    }
    // Within the digits whatever the rounding did (not `clamp`, which
    // asserts its bounds' order: a panic path).
    Some((x < 0.0, m.max(low).min(high.saturating_sub(1)), e))
}

/// Writes `x` with `digits` significant digits, trailing zeros left out:
/// positional from `1e-4` to below `1e7` (`0.0012`, `25`, `1200000`), else
/// in exponent form (`1.2e-7`); `0`, `inf`, `-inf`, `NaN` by name.
pub(crate) fn write_figure(f: &mut fmt::Formatter<'_>, x: f64, digits: u32) -> fmt::Result {
    let Some((negative, mut m, e)) = decimal(x, digits) else {
        return f.write_str(if x.is_nan() {
            "NaN"
        } else if x == f64::INFINITY {
            "inf"
        } else if x == f64::NEG_INFINITY {
            "-inf"
        } else {
            "0"
        });
    };
    // Trailing zeros out: `n` digits left in `m`.
    let mut n = digits;
    while n > 1 && m % 10 == 0 {
        m /= 10;
        n -= 1;
    }
    if negative {
        f.write_str("-")?;
    }
    let positional = (-4..7).contains(&e);
    // Digits of `m` from the most significant; `point` of them before the
    // decimal point (zeros written for the missing ones).
    let point: i32 = if positional { e + 1 } else { 1 };
    if point <= 0 {
        f.write_str("0.")?;
        for _ in 0..(-point).min(400) {
            f.write_str("0")?;
        }
    }
    let mut unit = pow10(n.saturating_sub(1)) as u64;
    let mut written = 0i32;
    while unit > 0 || written < point {
        if written == point && point > 0 {
            f.write_str(".")?;
        }
        let d = m.checked_div(unit).unwrap_or(0) % 10;
        fmt::Write::write_char(f, char::from(b'0' + d as u8))?;
        written += 1;
        unit /= 10;
        if written > 30 {
            break;
        }
    }
    if !positional {
        write!(f, "e{e}")?;
    }
    Ok(())
}

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

#[cfg(test)]
mod tests {
    extern crate std;

    use std::string::{String, ToString};
    use std::vec::Vec;

    use super::*;
    #[cfg(feature = "robust")]
    use crate::device::planar;
    use crate::judge::quality::Thresholds;

    /// The figure and the limit an error was decided by, when it has them;
    /// an exhaustive match, so that a new variant does not compile here
    /// until it says whether it carries a figure.
    fn figure_and_limit(e: &Error) -> Option<(f32, f32)> {
        match *e {
            Error::TooFewSamples { .. }
            | Error::HardlyMoved { .. }
            | Error::AllSamplesEqual
            | Error::OutOfRange
            | Error::NotAnEllipsoid
            | Error::SingularSystem
            | Error::NoConvergence { .. }
            | Error::MismatchedLengths
            | Error::NotEnabled { .. }
            | Error::InvalidConfig { .. } => None,
            Error::Planar { flatness: x, limit }
            | Error::AmbiguousQuadric {
                quadric_gap: x,
                limit,
            }
            | Error::ExtremeDistortion {
                distortion: x,
                limit,
            }
            | Error::PoorCoverage { coverage: x, limit }
            | Error::NoSphere {
                fit_error: x,
                limit,
            }
            | Error::FilledCloud { skewness: x, limit }
            | Error::SystematicMisfit {
                lack_of_fit: x,
                limit,
            }
            | Error::OffsetsUndetermined {
                determinacy: x,
                limit,
            } => Some((x.get(), limit.get())),
            // Printed as percentages.
            Error::FieldStrengthMismatch { deviation, limit } => {
                Some((deviation.get().abs() * 100.0, limit.get() * 100.0))
            }
            Error::TooManyOutliers {
                rejected,
                valid,
                limit,
            } => Some((rejected as f32 / valid as f32 * 100.0, limit.get() * 100.0)),
        }
    }

    /// Lists every variant once: an exhaustive match ([`variant_name`])
    /// and the list of names ([`VARIANTS`]) from the same names, so that a
    /// new variant does not compile until it is listed here, and
    /// [`every_error_builds_every_variant`] then fails until
    /// [`every_error`] builds it.
    macro_rules! variants {
        ($($v:ident),* $(,)?) => {
            fn variant_name(e: &Error) -> &'static str {
                match e {
                    $(Error::$v { .. } => stringify!($v),)*
                }
            }
            const VARIANTS: &[&str] = &[$(stringify!($v)),*];
        };
    }

    variants!(
        TooFewSamples,
        AllSamplesEqual,
        HardlyMoved,
        OutOfRange,
        NotAnEllipsoid,
        SingularSystem,
        NoConvergence,
        MismatchedLengths,
        NotEnabled,
        InvalidConfig,
        Planar,
        AmbiguousQuadric,
        ExtremeDistortion,
        PoorCoverage,
        FieldStrengthMismatch,
        NoSphere,
        FilledCloud,
        TooManyOutliers,
        SystematicMisfit,
        OffsetsUndetermined,
    );

    /// [`figure_and_limit`] of a planar fit's refusal.
    #[cfg(feature = "robust")]
    fn planar_figure_and_limit(e: &planar::Error) -> Option<(f32, f32)> {
        match e {
            planar::Error::Fit(e) => figure_and_limit(e),
            planar::Error::NotPlanar { flatness: x, limit }
            | planar::Error::NoEllipse {
                fit_error: x,
                limit,
            } => Some((x.get(), limit.get())),
            planar::Error::ShortArc { .. } => None,
        }
    }

    #[test]
    fn every_error_builds_every_variant() {
        let built: std::collections::BTreeSet<&str> =
            every_error().iter().map(variant_name).collect();
        let all: std::collections::BTreeSet<&str> = VARIANTS.iter().copied().collect();
        assert_eq!(all.len(), VARIANTS.len(), "a name listed twice");
        let missing: Vec<&&str> = all.difference(&built).collect();
        assert!(missing.is_empty(), "every_error builds none of {missing:?}");
        // At most 20: the fit's own concerns (issue 35).
        assert!(VARIANTS.len() <= 20, "{}", VARIANTS.len());
        // The planar fit's: an exhaustive match (a new variant does not
        // compile until it is named here) over what every_planar_error
        // builds.
        #[cfg(feature = "robust")]
        {
            let mut seen = [false; 4];
            for e in every_planar_error() {
                let k = match e {
                    planar::Error::Fit(_) => 0,
                    planar::Error::NotPlanar { .. } => 1,
                    planar::Error::NoEllipse { .. } => 2,
                    planar::Error::ShortArc { .. } => 3,
                };
                seen[k] = true;
            }
            assert_eq!(seen, [true; 4]);
        }
    }

    /// The figures `x` just beyond `limit` (on the refusing side, `sign`
    /// +1 above, -1 below): the next `f32`, and 1e-6, 1e-4, 1e-2 and 0.5
    /// of the limit away.
    fn beyond(limit: f32, sign: f32) -> Vec<f32> {
        let next = if (limit > 0.0) == (sign > 0.0) {
            f32::from_bits(limit.to_bits() + 1)
        } else {
            f32::from_bits(limit.to_bits() - 1)
        };
        let mut v = std::vec![next];
        for rel in [1e-6, 1e-4, 1e-2, 0.5] {
            v.push(limit + sign * rel * limit.abs());
        }
        v
    }

    /// Every variant ([`every_error_builds_every_variant`] checks it), each
    /// figure just beyond its default limit (and a
    /// limit a caller could set: 0.3, whose `f32` is 0.30000001).
    fn every_error() -> Vec<Error> {
        let th = Thresholds::DEFAULT;
        let f = Figure::new;
        let mut all = std::vec![
            Error::TooFewSamples {
                found: 9,
                required: 10
            },
            Error::AllSamplesEqual,
            Error::HardlyMoved {
                moving: 6,
                still: 2400,
                required: 10
            },
            Error::OutOfRange,
            Error::NotAnEllipsoid,
            Error::SingularSystem,
            Error::NoConvergence { iterations: 50 },
            Error::MismatchedLengths,
            Error::NotEnabled { feature: "submle" },
            Error::InvalidConfig {
                field: "noise_covariance",
            },
            Error::InvalidConfig {
                field: "refuse_fit_error",
            },
            Error::NoSphere {
                fit_error: f(f32::INFINITY),
                limit: f(th.refuse_fit_error),
            },
        ];
        let determinacy = crate::device::offsets::REFUSE_DETERMINACY as f32;
        for (limit, sign) in [
            (th.refuse_flatness, -1.0),
            (th.refuse_quadric_gap, -1.0),
            (th.refuse_distortion, 1.0),
            (th.refuse_coverage, -1.0),
            (th.refuse_field_deviation, 1.0),
            (th.refuse_fit_error, 1.0),
            (th.refuse_skewness, -1.0),
            (th.refuse_lack_of_fit, 1.0),
            (determinacy, -1.0),
            (0.3, 1.0),
            (0.3, -1.0),
        ] {
            for x in beyond(limit, sign) {
                let (x, l) = (f(x), f(limit));
                all.extend([
                    Error::Planar {
                        flatness: x,
                        limit: l,
                    },
                    Error::AmbiguousQuadric {
                        quadric_gap: x,
                        limit: l,
                    },
                    Error::ExtremeDistortion {
                        distortion: x,
                        limit: l,
                    },
                    Error::PoorCoverage {
                        coverage: x,
                        limit: l,
                    },
                    Error::FieldStrengthMismatch {
                        deviation: x,
                        limit: l,
                    },
                    Error::FieldStrengthMismatch {
                        deviation: f(-x.get()),
                        limit: l,
                    },
                    Error::NoSphere {
                        fit_error: x,
                        limit: l,
                    },
                    Error::FilledCloud {
                        skewness: x,
                        limit: l,
                    },
                    Error::SystematicMisfit {
                        lack_of_fit: x,
                        limit: l,
                    },
                    Error::OffsetsUndetermined {
                        determinacy: x,
                        limit: l,
                    },
                ]);
            }
        }
        // The outlier share: one row more than the limit allows, of 100 to
        // 10^7 valid rows.
        for limit in [th.refuse_outlier_share, 0.3] {
            for valid in [100usize, 1000, 12_345, 10_000_000] {
                let rejected = (f64::from(limit) * valid as f64) as usize + 1;
                all.push(Error::TooManyOutliers {
                    rejected,
                    valid,
                    limit: f(limit),
                });
            }
        }
        all
    }

    #[cfg(feature = "robust")]
    /// Every variant of the planar fit's refusals, its figures just beyond
    /// their default limits and 0.3, and the fit's refusals it shares.
    fn every_planar_error() -> Vec<planar::Error> {
        let th = planar::PlanarThresholds::DEFAULT;
        let f = Figure::new;
        let mut all = std::vec![
            planar::Error::ShortArc {
                sectors: 7,
                required: 8
            },
            planar::Error::NoEllipse {
                fit_error: f(f32::INFINITY),
                limit: f(th.refuse_fit_error),
            },
        ];
        for (limit, sign) in [
            (th.refuse_not_planar, 1.0),
            (th.refuse_fit_error, 1.0),
            (0.3, 1.0),
        ] {
            for x in beyond(limit, sign) {
                let (x, l) = (f(x), f(limit));
                all.extend([
                    planar::Error::NotPlanar {
                        flatness: x,
                        limit: l,
                    },
                    planar::Error::NoEllipse {
                        fit_error: x,
                        limit: l,
                    },
                ]);
            }
        }
        all.extend(every_error().into_iter().map(planar::Error::Fit));
        all
    }

    /// The printed figure and limit: the numbers either side of
    /// `, limit ` (a percentage without its `%`).
    fn printed(message: &str) -> Option<(String, String)> {
        let (before, after) = message.split_once(", limit ")?;
        let before = before.strip_suffix(" %").unwrap_or(before);
        let figure = before.rsplit([' ', '(']).next()?;
        let limit = after.split([' ', ')', ':', ',']).next()?;
        Some((figure.to_string(), limit.to_string()))
    }

    #[test]
    fn every_refusal_prints_its_figure_and_limit_apart() {
        #[allow(unused_mut)] // without `robust`: no planar refusals
        let mut all: Vec<_> = every_error()
            .into_iter()
            .map(|e| (e.to_string(), std::format!("{e:?}"), figure_and_limit(&e)))
            .collect();
        #[cfg(feature = "robust")]
        all.extend(every_planar_error().into_iter().map(|e| {
            let message = e.to_string();
            if let planar::Error::Fit(inner) = e {
                // A shared refusal reads as the fit's.
                assert_eq!(message, inner.to_string());
            }
            (message, std::format!("{e:?}"), planar_figure_and_limit(&e))
        }));
        let mut with_figures = 0;
        for (message, e, figures) in all {
            assert!(message.is_ascii() && !message.contains('\n'), "{message}");
            match figures {
                Some((x, limit)) if x.is_finite() => {
                    let (a, b) = printed(&message).unwrap_or_else(|| panic!("{message}"));
                    assert_ne!(a, b, "{e:?}: {message}");
                    // Each reads back to the figure within the digits shown.
                    for (s, v) in [(&a, x), (&b, limit)] {
                        let read: f64 = s.parse().unwrap_or_else(|_| panic!("{s}: {message}"));
                        let mantissa = s.split('e').next().unwrap_or(s);
                        let mut digits = mantissa.trim_start_matches(['-', '0', '.']);
                        if !digits.contains('.') {
                            digits = digits.trim_end_matches('0');
                        }
                        let digits = digits.replace('.', "").len();
                        let tol = 10f64.powi(-(digits as i32 - 1)) * f64::from(v).abs();
                        assert!((read - f64::from(v)).abs() <= tol, "{s} vs {v}: {message}");
                    }
                    with_figures += 1;
                }
                Some(_) => {
                    // No finite figure: the limit alone, as a number.
                    assert!(message.contains("limit 0.2)"), "{message}");
                }
                None => assert!(printed(&message).is_none(), "{message}"),
            }
        }
        // Half of them the planar fit's (with `robust`).
        let least = if cfg!(feature = "robust") { 1100 } else { 550 };
        assert!(with_figures > least, "{with_figures}");
    }

    #[test]
    fn counts_are_printed() {
        for (m, words) in [
            (
                Error::TooFewSamples {
                    found: 9,
                    required: 10,
                }
                .to_string(),
                ["9 kept", "10 required"],
            ),
            (
                Error::HardlyMoved {
                    moving: 6,
                    still: 2400,
                    required: 10,
                }
                .to_string(),
                ["6 samples in motion", "at least 10"],
            ),
            #[cfg(feature = "robust")]
            (
                planar::Error::ShortArc {
                    sectors: 7,
                    required: 8,
                }
                .to_string(),
                ["cover 7 of", "at least 8"],
            ),
            (
                Error::TooManyOutliers {
                    rejected: 251,
                    valid: 1000,
                    limit: Figure::new(0.25),
                }
                .to_string(),
                ["251 of 1000", "(25.1 %, limit 25 %)"],
            ),
        ] {
            assert!(words.iter().all(|w| m.contains(w)), "{m}");
        }
    }

    /// The case (a lack of fit of 0.012 printed as `0.0`, as its
    /// limit) and its neighbours, written out.
    #[test]
    fn figures_read_as_written() {
        let misfit = |x: f32| {
            Error::SystematicMisfit {
                lack_of_fit: Figure::new(x),
                limit: Figure::new(crate::tuning::REFUSE_LACK_OF_FIT as f32),
            }
            .to_string()
        };
        assert!(misfit(0.0123).contains("(lack of fit 0.012, limit 0.01)"));
        assert!(misfit(0.0101).contains("(lack of fit 0.0101, limit 0.01)"));
        let no_sphere = Error::NoSphere {
            fit_error: Figure::new(0.3712),
            limit: Figure::new(0.2),
        };
        assert!(no_sphere
            .to_string()
            .contains("(fit error 0.37, limit 0.2, in units of the field)"));
        let field = Error::FieldStrengthMismatch {
            deviation: Figure::new(-0.31),
            limit: Figure::new(0.25),
        };
        assert!(field.to_string().starts_with(
            "fitted field strength too far below the expected value (31 %, limit 25 %)"
        ));
        let planar = Error::Planar {
            flatness: Figure::new(0.0098),
            limit: Figure::new(0.03),
        };
        assert!(planar.to_string().contains("(flatness 0.0098, limit 0.03)"));
        let cloud = Error::FilledCloud {
            skewness: Figure::new(-0.6000001),
            limit: Figure::new(-0.6),
        };
        assert!(cloud
            .to_string()
            .contains("skewness -0.6000001, limit -0.6)"));
    }

    /// The formatter alone: digits, exponents, names, equal figures alike.
    #[test]
    fn versus_digits() {
        let v = |a: f32, b: f32| Versus::new(Figure::new(a), Figure::new(b), "").to_string();
        assert_eq!(v(0.0501, 0.05), "0.0501, limit 0.05");
        assert_eq!(v(0.30004, 0.3), "0.30004, limit 0.3");
        assert_eq!(v(0.3, 0.3), "0.3, limit 0.3");
        assert_eq!(v(16.2, 16.0), "16, limit 16".replace("16,", "16.2,"));
        assert_eq!(v(123456.0, 3.0), "120000, limit 3");
        assert_eq!(v(9.99, 3.0), "10, limit 3");
        assert_eq!(v(0.999, 0.99), "1, limit 0.99");
        assert_eq!(v(0.9951, 0.995), "0.9951, limit 0.995");
        assert_eq!(v(2.5e-7, 0.02), "2.5e-7, limit 0.02");
        assert_eq!(v(3.1e9, 16.0), "3.1e9, limit 16");
        assert_eq!(v(f32::NAN, 0.2), "NaN, limit 0.2");
        assert_eq!(v(f32::INFINITY, 0.2), "inf, limit 0.2");
        assert_eq!(v(0.0, -0.6), "0, limit -0.6");
        assert_eq!(v(f32::MAX, f32::MIN_POSITIVE), "3.4e38, limit 1.2e-38");
        assert_eq!(v(1e-45, 0.0), "1.4e-45, limit 0");
        // Two adjacent f32 apart, whatever their size.
        for x in [1e-30f32, 1e-3, 0.1, 1.0, 7.0, 1e6, 3e38] {
            let y = f32::from_bits(x.to_bits() + 1);
            let s = v(y, x);
            let (a, b) = s.split_once(", limit ").unwrap();
            assert_ne!(a, b, "{s}");
            let (a, b): (f64, f64) = (a.parse().unwrap(), b.parse().unwrap());
            assert!(
                a > b && (a - f64::from(y)).abs() < 1e-7 * f64::from(y),
                "{s}"
            );
        }
        assert_eq!(Shown::alone(0.2).to_string(), "0.2");
        assert_eq!(Shown::alone(0.123).to_string(), "0.123");
        assert_eq!(Shown::alone(0.300_000_1).to_string(), "0.3000001");
        assert_eq!(Shown::alone(f32::INFINITY).to_string(), "inf");
    }
}
