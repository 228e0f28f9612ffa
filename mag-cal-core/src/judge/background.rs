//! The judging of the background calibrator ([`crate::background`]): a
//! refit's figures, judged as the batch fit's are ([`quality::judge`] with
//! the caller's thresholds), and the calibrator's own two decisions: whether
//! a refit that passed replaces the calibration in use, and whether an
//! offsets-only fit of the recent readings is taken.

use nalgebra::Matrix3;

use crate::device::offsets::OffsetsFit;
use crate::judge::quality::{self, Figures, Quality, Warnings};
use crate::numerics::linalg::larger;
use crate::steps::final_pass::FinalPass;
use crate::steps::rules::Drops;
use crate::{Error, Figure, Real, Thresholds};

/// An offsets-only fit is adopted when its fit error is at most this many
/// times the current calibration's (or [`OFFSETS_MAX_FIT_ERROR`], the
/// larger).
pub const OFFSETS_ERROR_RATIO: f64 = 2.0;

/// See [`OFFSETS_ERROR_RATIO`].
pub const OFFSETS_MAX_FIT_ERROR: f64 = 0.03;

/// A refit replaces the calibration in use only when its robust fit error
/// on the buffer is below this share of the calibration in use's: a
/// margin over the noise of the figure, so that equally good fits do not
/// replace each other (each new fit, fitted to the buffer, fits it a
/// little better, if only by following its noise).
pub const ADOPT_RATIO: f64 = 0.9;

/// Nor when its coverage (`lambda_min` of the directions' covariance) is
/// below this share of the calibration in use's. (Taking a fit below 0.75
/// of the fit error whatever its coverage was measured and not taken: it
/// doubled the median recovery after a hard-iron jump.)
pub const ADOPT_COVERAGE: f64 = 0.9;

// Measured and not taken (20 runs of each kind, `background-table`):
// comparing the RMS over each fit's inliers instead of the robust fit
// error (one false adoption during a magnet's pass, the median recovery
// after a jump unchanged but its worst 3x longer), and clearing the
// coverage of a calibration whose offsets were re-estimated (drift end
// error 0.063 -> 0.073).

/// The figures of a refit's LS step, which it carries to its judging
/// (the refit's state is kept between calls: these two, not the whole
/// [`Figures`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct LsFigures<T: Real> {
    /// See [`Quality::flatness`].
    pub flatness: T,
    /// See [`Quality::quadric_gap`]; `None` when not computed.
    pub quadric_gap: Option<T>,
}

impl<T: Real> LsFigures<T> {
    /// The figures of a refit of `valid` buffered rows (every row a sample
    /// the rules kept: the buffer holds no other) after its LS step: a
    /// robust fit whose lack of fit is judged, as the batch fit's robust
    /// ADC2.
    pub(crate) fn figures(&self, valid: usize) -> Figures<T> {
        let mut figures = Figures::before_fit(valid, Drops::default(), true, true, false);
        figures.flatness = Some(self.flatness);
        figures.quadric_gap = self.quadric_gap;
        figures
    }
}

/// A refit of `valid` buffered rows after its final pass `last` under the
/// estimate `w` (normalised): its warnings and quality figures, or the
/// refusal of [`quality::judge`] with the caller's thresholds `th`, on the
/// LS step's figures `ls` and the final pass's.
pub(crate) fn judge_refit<T: Real>(
    ls: &LsFigures<T>,
    valid: usize,
    w: &Matrix3<T>,
    last: &FinalPass<T>,
    th: &Thresholds,
) -> Result<(Warnings, Quality<T>), Error> {
    let distortion = quality::distortion(w)?;
    let mut figures = ls.figures(valid);
    figures.record_final(last, last.fit_error);
    figures.distortion = Some(distortion);
    let warnings = quality::judge(&figures, th)?;
    Ok((warnings, figures.quality(distortion, last, last.fit_error)))
}

/// Whether a refit that passed every check, of robust fit error
/// `fit_error` and coverage `coverage` on the buffer, replaces the
/// calibration in use, whose fit error on the same buffer is
/// `current_error` and whose coverage at its refit was `current_coverage`
/// (`None`: no calibration in use, the refit is taken). It must fit the
/// buffer better by the margin [`ADOPT_RATIO`], and its directions must not
/// cover much less ([`ADOPT_COVERAGE`]): a fit of a narrower buffer (after
/// a purge) follows its noise.
pub(crate) fn replaces<T: Real>(
    fit_error: T,
    coverage: T,
    current_error: T,
    current_coverage: Option<T>,
) -> bool {
    let Some(current_coverage) = current_coverage else {
        return true;
    };
    let better = fit_error < current_error * T::lit(ADOPT_RATIO);
    let covered = coverage >= current_coverage * T::lit(ADOPT_COVERAGE);
    better && covered
}

/// An offsets-only fit of the recent readings, while the calibration in
/// use (robust fit error `current_error`) is stale: taken, or refused as
/// [`Error::NoSphere`] when its fit error exceeds [`OFFSETS_ERROR_RATIO`]
/// times `current_error` (at least [`OFFSETS_MAX_FIT_ERROR`]) or it
/// rejected more than a quarter of the rows it used: a disturbance, not a
/// moved hard iron, which fits a sphere of the known radius closely.
pub(crate) fn judge_offsets<T: Real>(fit: &OffsetsFit<T>, current_error: T) -> Result<(), Error> {
    let limit = larger(
        current_error * T::lit(OFFSETS_ERROR_RATIO),
        T::lit(OFFSETS_MAX_FIT_ERROR),
    );
    let outliers = fit.rejected * 4 > fit.samples_used;
    if fit.fit_error > limit || outliers {
        return Err(Error::NoSphere {
            fit_error: Figure::new(fit.fit_error.to_single()),
            limit: Figure::new(limit.to_single()),
        });
    }
    Ok(())
}
