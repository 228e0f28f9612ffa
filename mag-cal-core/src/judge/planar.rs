//! The judging of the planar fit ([`crate::planar`]): its figures
//! ([`PlanarReport`]), their limits ([`PlanarThresholds`]), and the one
//! function that turns them into acceptance or a refusal ([`judge`]), with
//! the refusals the planar fit's steps meet before any figure (rows crowded
//! on one point, a conic that is no ellipse) stated with the same limits.

use crate::device::planar::{Error, PlanarReport};
use crate::steps::normalize::MIN_SAMPLES;
use crate::{Error as FitError, Figure, Real};

/// Flatness above this: [`Error::NotPlanar`]. Measured on level turns
/// (noise 1 % of the field): tilts of up to 10 deg give 0.004-0.02, the
/// real recording `planar_243.txt` 0.010; a +-30 deg band gives 0.18 and
/// the full sphere 0.3-1. Between `REFUSE_FLATNESS` and
/// this, both the planar and the three-dimensional fit may run.
pub const REFUSE_NOT_PLANAR: f64 = 0.06;

/// Sectors of 30 deg of turn angle that must hold samples: fewer is
/// [`Error::ShortArc`]. An ellipse from less than about 240 deg of arc is
/// poorly determined (its centre slides along the missing side).
pub const MIN_SECTORS: u8 = 8;

/// The limits [`judge`] applies.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub struct PlanarThresholds {
    /// Flatness above this: [`Error::NotPlanar`].
    pub refuse_not_planar: f32,
    /// Fit error above this: [`Error::NoEllipse`].
    pub refuse_fit_error: f32,
    /// Fewer sectors than this: [`Error::ShortArc`].
    pub min_sectors: u8,
    /// Share of the rules' rows screened out or rejected above this:
    /// [`crate::Error::TooManyOutliers`] (the still periods set aside are
    /// no outliers, and not among those rows).
    pub refuse_outlier_share: f32,
}

impl PlanarThresholds {
    /// The measured constants of this module and of [`crate::judge::quality`].
    pub const DEFAULT: Self = Self {
        refuse_not_planar: REFUSE_NOT_PLANAR as f32,
        refuse_fit_error: crate::tuning::REFUSE_FIT_ERROR as f32,
        min_sectors: MIN_SECTORS,
        refuse_outlier_share: crate::tuning::REFUSE_OUTLIER_SHARE as f32,
    };
}

impl PlanarThresholds {
    /// `Ok` when every limit can be used, else [`FitError::InvalidConfig`]
    /// naming the first that cannot (a NaN, a share or flatness outside
    /// 0-1, a negative fit error, more sectors than
    /// [`crate::planar::SECTORS`]).
    pub fn validate(&self) -> Result<(), FitError> {
        use crate::judge::quality::check;
        check("refuse_not_planar", self.refuse_not_planar, 0.0, 1.0)?;
        check(
            "refuse_fit_error",
            self.refuse_fit_error,
            0.0,
            f32::INFINITY,
        )?;
        check("refuse_outlier_share", self.refuse_outlier_share, 0.0, 1.0)?;
        if self.min_sectors > crate::device::planar::SECTORS {
            return Err(FitError::InvalidConfig {
                field: "min_sectors",
            });
        }
        Ok(())
    }
}

impl Default for PlanarThresholds {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Turns the figures into acceptance or a refusal: `valid` is the rows the
/// rules kept beside the still periods set aside.
///
/// # Errors
/// In that order: too few samples ([`crate::Error::TooFewSamples`]),
/// [`Error::NotPlanar`], [`Error::NoEllipse`], too many outliers
/// ([`crate::Error::TooManyOutliers`]), [`Error::ShortArc`].
pub fn judge<T: Real>(
    report: &PlanarReport<T>,
    valid: usize,
    th: &PlanarThresholds,
) -> Result<(), Error> {
    if report.samples_used < MIN_SAMPLES {
        return Err(Error::Fit(FitError::TooFewSamples {
            found: report.samples_used,
            required: MIN_SAMPLES,
        }));
    }
    if !(report.flatness.to_single() <= th.refuse_not_planar) {
        return Err(Error::NotPlanar {
            flatness: Figure::new(report.flatness.to_single()),
            limit: Figure::new(th.refuse_not_planar),
        });
    }
    if !(report.fit_error.to_single() <= th.refuse_fit_error) {
        return Err(Error::NoEllipse {
            fit_error: Figure::new(report.fit_error.to_single()),
            limit: Figure::new(th.refuse_fit_error),
        });
    }
    let out = report.screened + report.rejected;
    if valid > 0 && out as f32 > th.refuse_outlier_share * valid as f32 {
        return Err(Error::Fit(FitError::TooManyOutliers {
            rejected: out,
            valid,
            limit: Figure::new(th.refuse_outlier_share),
        }));
    }
    if report.sectors < th.min_sectors {
        return Err(Error::ShortArc {
            sectors: report.sectors,
            required: th.min_sectors,
        });
    }
    Ok(())
}

/// Rows crowded on one point (the screening finds no spread): no sphere,
/// nor circle, at all, [`crate::Error::NoSphere`] with an infinite fit
/// error against the fit error limit of `th`.
pub(crate) fn crowded(th: &PlanarThresholds) -> Error {
    Error::Fit(FitError::NoSphere {
        fit_error: Figure::new(f32::INFINITY),
        limit: Figure::new(th.refuse_fit_error),
    })
}

/// The conic of the rows in their plane is not an ellipse:
/// [`Error::NoEllipse`] with an infinite fit error against the limit of
/// `th`.
pub(crate) fn not_an_ellipse(th: &PlanarThresholds) -> Error {
    Error::NoEllipse {
        fit_error: Figure::new(f32::INFINITY),
        limit: Figure::new(th.refuse_fit_error),
    }
}
