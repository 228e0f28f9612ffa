//! Quality figures of a calibration, the refusals of degenerate data, and
//! the warnings a report carries.
//!
//! Every check is relative (unit-free); the thresholds and the measurements
//! that justify them are documented beside each constant. Refusals are
//! [`Error`]s; milder findings are [`Warning`]s in the report.

use crate::tuning::{
    GAP_NOISE_LIMIT, REFUSE_COVERAGE, REFUSE_DISTORTION, REFUSE_FIELD_DEVIATION, REFUSE_FIT_ERROR,
    REFUSE_FLATNESS, REFUSE_LACK_OF_FIT, REFUSE_OUTLIER_SHARE, REFUSE_QUADRIC_GAP, REFUSE_SKEWNESS,
    WARN_FIT_ERROR, WARN_FLATNESS, WARN_GRAM_CONDITION, WARN_QUADRIC_GAP, WARN_SAMPLES,
    WARN_SPREAD_OVER_NOISE,
};
use nalgebra::{Matrix3, SMatrix};

use crate::numerics::linalg::{columns_of, eigen_range, larger, tridiagonal};
use crate::steps::final_pass::FinalPass;
use crate::steps::moments::Moments;
use crate::{Error, Figure, Real};

/// The figures behind the checks, for the report.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Quality<T: Real> {
    /// `lambda_min / lambda_max` of the 3x3 covariance of the samples: 1/3
    /// to 1 for a sphere seen from all sides, 0 for a plane.
    pub flatness: T,
    /// `lambda_1 / lambda_0` of the normalised 10x10 LS scatter: how much
    /// better the best quadric fits than the next one (large is good).
    pub quadric_gap: T,
    /// Condition number of `M = W^T W`: the squared ratio of the ellipsoid's
    /// longest to shortest axis.
    pub distortion: T,
    /// `lambda_min` of the covariance of the calibrated directions
    /// `h = W (y - b) / |W (y - b)|`: 1/3 for a full sphere, 0.085 for a
    /// +-30 deg band, 0.02 for +-10 deg.
    ///
    /// For [`crate::Method::Adc2`] and [`crate::Method::Adc1`] the
    /// directions are those of their artificial data, i.e. of the LS fit
    /// they start from (the statistics
    /// already summed, so the last pass need not sum them again);
    /// for the other methods, those of the final calibration. On the
    /// simulated test scenarios the two differ by at most 2 % (0.05 %
    /// to 0.6 % except the noisiest, E).
    pub coverage: T,
    /// Condition number of `G / n`, the Gram matrix of the regressors
    /// `[h, 1]` (about 3 on a full sphere, 12 on a +-30 deg band), of the
    /// same directions as [`Quality::coverage`].
    pub gram_condition: T,
    /// The fit error: the robust standard deviation
    /// `1.4826 median ||u| - 1|` of the radial residuals of every row kept
    /// by the rules and the screening, in units of the field. Noise and
    /// model error of a calibratable recording; an outlier does not move
    /// it. Scenario E (10-20 % noise) 0.13-0.16; a filled ball 0.24-0.27, a
    /// device lying still 0.37-0.44 ([`Thresholds::refuse_fit_error`]).
    ///
    /// For [`crate::Method::Ls`] with [`crate::Config::robust`], divided by
    /// the rows' mean radius `1 + mean(|u| - 1)`: the algebraic fit's
    /// radius shrinks under noise, and about it a noise ball's shell would
    /// look thinner than it is (0.185-0.200 about the fitted radius,
    /// 0.206-0.227 about the mean).
    pub fit_error: T,
    /// Lack of fit: the systematic part of the radial residual, in units of
    /// the field. The mean residual `m_c` of the rows used in each of
    /// `LOF_CELLS` direction cells, its noise share `fit_error^2 / n_c`
    /// removed: `sqrt(max(0, mean_c(m_c^2 - fit_error^2 / n_c)))`. About 0
    /// when the residuals are noise around the ellipsoid; large when a
    /// region of the sphere sits off it (a displaced stretch of the
    /// trajectory that the ellipsoid bends towards). Refused above
    /// [`Thresholds::refuse_lack_of_fit`] when the misfit is also
    /// significant against the noise (`LOF_SIGNIFICANCE`).
    pub lack_of_fit: T,
    /// Share of the rows kept by the rules that the fit did not use
    /// (screened out, or residual beyond the cut; not the rows left out
    /// beside a run of rejected rows with a residual within the cut).
    pub outlier_share: T,
    /// Skewness of the radial residuals `|u| - 1` of the rows used: about
    /// 0 on a noisy shell (the clean test scenarios -0.38 to 0.1), -0.7 to
    /// -0.9 on a filled ball, whose rows lie inside the fitted shell
    /// ([`Thresholds::refuse_skewness`]). Measured by the robust path's
    /// final pass; 0 when the plain fit was taken (its first pass's
    /// residuals were tested for rows pulled inwards instead,
    /// `CLEAN_SKEWNESS`) and in [`crate::background`].
    pub skewness: T,
}

/// The limits the judging applies to the figures of a fit, as a value the
/// caller can set ([`crate::Config::thresholds`]); [`Thresholds::DEFAULT`]
/// holds the measured constants of this module.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Thresholds {
    /// Fewer rows used than this: [`Warning::FewSamples`]. Default 50.
    pub warn_samples: usize,
    /// Flatness below this: [`Error::Planar`]. Default 0.03.
    pub refuse_flatness: f32,
    /// Flatness below this: [`Warning::NearlyPlanar`]. Default 0.1.
    pub warn_flatness: f32,
    /// Quadric gap below this, with radial RMS below
    /// [`Thresholds::gap_noise_limit`]: [`Error::AmbiguousQuadric`]. Default 3.
    pub refuse_quadric_gap: f32,
    /// Radial RMS below which a small quadric gap refuses the fit; above
    /// it, noise alone compresses a good geometry's gap, and the gap only
    /// warns. Default 0.05.
    pub gap_noise_limit: f32,
    /// Quadric gap below this: [`Warning::WeakQuadric`]. Default 10.
    pub warn_quadric_gap: f32,
    /// Condition of `M` above this: [`Error::ExtremeDistortion`]. Default 16.
    pub refuse_distortion: f32,
    /// Coverage below this: [`Error::PoorCoverage`]. Default 0.05.
    pub refuse_coverage: f32,
    /// Gram condition above this: [`Warning::WeakCoverage`]. Default 20.
    pub warn_gram_condition: f32,
    /// Relative field-strength deviation above this:
    /// [`Error::FieldStrengthMismatch`]. Default 0.25.
    pub refuse_field_deviation: f32,
    /// Spread below this many noise standard deviations:
    /// [`Warning::LowSpread`]. Default 10.
    pub warn_spread_over_noise: f32,
    /// Fit error above this: [`Error::NoSphere`]. Default 0.20.
    pub refuse_fit_error: f32,
    /// Fit error above this: [`Warning::HighFitError`]. Default 0.05.
    pub warn_fit_error: f32,
    /// Share of rows not used above this: [`Error::TooManyOutliers`]. Default 0.25.
    pub refuse_outlier_share: f32,
    /// Lack of fit above this: [`Error::SystematicMisfit`]. Default 0.01.
    pub refuse_lack_of_fit: f32,
    /// Skewness of the radial residuals below this, with a fit error above
    /// [`Thresholds::warn_fit_error`]: [`Error::FilledCloud`]. Default -0.6.
    pub refuse_skewness: f32,
}

impl Thresholds {
    /// The measured defaults: each value, what it guards and the
    /// measurement behind it are in the crate's tuning module
    /// (`mag-cal-core/src/tuning.rs`).
    pub const DEFAULT: Self = Self {
        warn_samples: WARN_SAMPLES,
        refuse_flatness: REFUSE_FLATNESS as f32,
        warn_flatness: WARN_FLATNESS as f32,
        refuse_quadric_gap: REFUSE_QUADRIC_GAP as f32,
        gap_noise_limit: GAP_NOISE_LIMIT as f32,
        warn_quadric_gap: WARN_QUADRIC_GAP as f32,
        refuse_distortion: REFUSE_DISTORTION as f32,
        refuse_coverage: REFUSE_COVERAGE as f32,
        warn_gram_condition: WARN_GRAM_CONDITION as f32,
        refuse_field_deviation: REFUSE_FIELD_DEVIATION as f32,
        warn_spread_over_noise: WARN_SPREAD_OVER_NOISE as f32,
        refuse_fit_error: REFUSE_FIT_ERROR as f32,
        warn_fit_error: WARN_FIT_ERROR as f32,
        refuse_outlier_share: REFUSE_OUTLIER_SHARE as f32,
        refuse_lack_of_fit: REFUSE_LACK_OF_FIT as f32,
        refuse_skewness: REFUSE_SKEWNESS as f32,
    };

    /// Checks every limit once, before a fit uses them: each must be a
    /// number in its range (shares, flatness and coverage in `[0, 1]`,
    /// condition limits at least 1, the others at least 0; infinity is
    /// allowed and turns a check off; the skewness limit may be any number).
    /// [`calibrate`](crate::calibrate) calls it first; a NaN limit would
    /// otherwise pass or refuse every fit unseen.
    ///
    /// ```
    /// use mag_cal_core::{Error, Thresholds};
    /// assert!(Thresholds::DEFAULT.validate().is_ok());
    /// let t = Thresholds { refuse_fit_error: f32::NAN, ..Thresholds::DEFAULT };
    /// assert_eq!(t.validate(), Err(Error::InvalidConfig { field: "refuse_fit_error" }));
    /// ```
    #[inline]
    pub fn validate(&self) -> Result<(), Error> {
        const INF: f32 = f32::INFINITY;
        let t = self;
        // One check after the other, not a loop over a table: with a
        // constant `Config` every check folds away (a loop over a table
        // kept 716 B in the firmware's footprint build).
        check("refuse_flatness", t.refuse_flatness, 0.0, 1.0)?;
        check("warn_flatness", t.warn_flatness, 0.0, 1.0)?;
        check("refuse_quadric_gap", t.refuse_quadric_gap, 0.0, INF)?;
        check("gap_noise_limit", t.gap_noise_limit, 0.0, INF)?;
        check("warn_quadric_gap", t.warn_quadric_gap, 0.0, INF)?;
        check("refuse_distortion", t.refuse_distortion, 1.0, INF)?;
        check("refuse_coverage", t.refuse_coverage, 0.0, 1.0)?;
        check("warn_gram_condition", t.warn_gram_condition, 1.0, INF)?;
        check("refuse_field_deviation", t.refuse_field_deviation, 0.0, INF)?;
        check("warn_spread_over_noise", t.warn_spread_over_noise, 0.0, INF)?;
        check("refuse_fit_error", t.refuse_fit_error, 0.0, INF)?;
        check("warn_fit_error", t.warn_fit_error, 0.0, INF)?;
        check("refuse_outlier_share", t.refuse_outlier_share, 0.0, 1.0)?;
        check("refuse_lack_of_fit", t.refuse_lack_of_fit, 0.0, INF)?;
        check("refuse_skewness", t.refuse_skewness, -INF, INF)?;
        Ok(())
    }
}

/// `Ok` when `value` lies in `lo..=hi` (NaN does not), else the refusal
/// naming `field`.
#[inline(always)]
pub(crate) fn check(field: &'static str, value: f32, lo: f32, hi: f32) -> Result<(), Error> {
    if value >= lo && value <= hi {
        Ok(())
    } else {
        Err(Error::InvalidConfig { field })
    }
}

impl Default for Thresholds {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Everything the judging looks at, as far as the pipeline got: a figure
/// is `None` when the step that computes it did not run (an earlier step
/// failed).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Figures<T: Real> {
    /// Rows kept by the rules.
    pub valid: usize,
    /// Rows the final fit used.
    pub used: Option<usize>,
    /// Rows left out beside runs of rejected rows whose residual is within
    /// the cut: left out, but no outliers.
    pub beside: usize,
    pub drops: crate::steps::rules::Drops,
    /// Robust path: outlier handling on, the new refusals apply.
    pub robust: bool,
    /// The lack of fit refuses: for the methods that fit the radial
    /// residual (ADC1, ADC2, iterated ADC2), whose cell means are zero at a
    /// good fit. Not for the LS fit alone nor subMLE, whose algebraic and
    /// Sampson criteria leave a pattern in the radial residual under noise
    /// (lack of fit 2-8 on the noisy clean scenarios B-G): their own
    /// misfit, not the data's.
    pub judge_lack_of_fit: bool,
    pub low_spread: bool,
    pub flatness: Option<T>,
    pub quadric_gap: Option<T>,
    pub distortion: Option<T>,
    pub coverage: Option<T>,
    pub gram_condition: Option<T>,
    pub radial_rms: Option<T>,
    pub fit_error: Option<T>,
    pub lack_of_fit: Option<T>,
    pub misfit_significant: bool,
    /// The final pass's skewness on the robust path, else 0 (which no
    /// limit refuses: a plain `T`, as an `Option` took 4 bytes more of
    /// every frame that holds the figures).
    pub skewness: T,
    /// `field_strength / expected - 1`, when an expected value was given.
    pub field_deviation: Option<T>,
    /// Warnings a step raised itself (the pass cap).
    pub step_warnings: Warnings,
}

impl<T: Real> Figures<T> {
    /// The figures before any step computed one: `valid` rows kept by the
    /// rules, which dropped `drops`.
    pub(crate) fn before_fit(
        valid: usize,
        drops: crate::steps::rules::Drops,
        robust: bool,
        judge_lack_of_fit: bool,
        low_spread: bool,
    ) -> Self {
        Self {
            valid,
            used: None,
            beside: 0,
            drops,
            robust,
            judge_lack_of_fit,
            low_spread,
            flatness: None,
            quadric_gap: None,
            distortion: None,
            coverage: None,
            gram_condition: None,
            radial_rms: None,
            fit_error: None,
            lack_of_fit: None,
            misfit_significant: false,
            skewness: T::zero(),
            field_deviation: None,
            step_warnings: Warnings::NONE,
        }
    }

    /// Whether the lack of fit is judged, significant against the noise,
    /// and beyond its limit.
    pub(crate) fn misfit(&self, th: &Thresholds) -> bool {
        self.judge_lack_of_fit
            && self.misfit_significant
            && self
                .lack_of_fit
                .is_some_and(|l| !(l <= T::from_single(th.refuse_lack_of_fit)))
    }

    /// Records the figures of the final pass `last`, with the fit error
    /// `fit_error` (the pass's, or the batch fit's LS alone taken about
    /// the mean radius).
    #[inline(always)]
    pub(crate) fn record_final(&mut self, last: &FinalPass<T>, fit_error: T) {
        self.used = Some(last.used);
        self.coverage = Some(last.coverage);
        self.gram_condition = Some(last.gram_condition);
        self.radial_rms = Some(last.radial_rms);
        self.fit_error = Some(fit_error);
        self.lack_of_fit = Some(last.lack_of_fit);
        self.misfit_significant = last.misfit_significant;
    }

    /// The quality figures of a fit these figures passed [`judge`] for,
    /// with its `distortion` and the figures of its final pass `last`
    /// recorded with `fit_error` ([`Figures::record_final`]).
    #[inline(always)]
    pub(crate) fn quality(&self, distortion: T, last: &FinalPass<T>, fit_error: T) -> Quality<T> {
        Quality {
            flatness: self.flatness.unwrap_or(T::zero()),
            quadric_gap: self.quadric_gap.unwrap_or(T::zero()),
            distortion,
            coverage: last.coverage,
            gram_condition: last.gram_condition,
            fit_error,
            lack_of_fit: last.lack_of_fit,
            outlier_share: self.outlier_share().unwrap_or(T::zero()),
            skewness: self.skewness,
        }
    }

    pub(crate) fn outlier_share(&self) -> Option<T> {
        let used = self.used?;
        if self.valid == 0 {
            return None;
        }
        let out = self.valid.saturating_sub(used).saturating_sub(self.beside);
        Some(T::from_count(out) / T::from_count(self.valid))
    }
}

/// The one place where figures become a calibration's warnings or a
/// refusal. Refusals in order: the geometry of the samples (planar), the
/// shape (not a sphere, too many outliers, systematic misfit), then the
/// ellipsoid (distortion, ambiguity), the coverage, the field strength. A
/// figure that was not computed does not refuse.
pub(crate) fn judge<T: Real>(f: &Figures<T>, th: &Thresholds) -> Result<Warnings, Error> {
    let lit = |x: f32| T::from_single(x);
    let below = |v: Option<T>, limit: f32| v.is_some_and(|v| !(v >= lit(limit)));
    let above = |v: Option<T>, limit: f32| v.is_some_and(|v| !(v <= lit(limit)));
    let mut w = Warnings::NONE;
    if let Some(v) = f.flatness.filter(|_| below(f.flatness, th.refuse_flatness)) {
        return Err(Error::Planar {
            flatness: beyond(v, th.refuse_flatness, false),
            limit: Figure::new(th.refuse_flatness),
        });
    }
    // An infinite fit error (no sphere at all: rows crowded on one point)
    // refuses whatever the limit.
    if let Some(e) = f
        .fit_error
        .filter(|e| above(f.fit_error, th.refuse_fit_error) || !e.is_finite())
    {
        return Err(Error::NoSphere {
            fit_error: beyond(e, th.refuse_fit_error, true),
            limit: Figure::new(th.refuse_fit_error),
        });
    }
    if f.robust {
        // (Ablation, docs/robustness.md: `filled-cloud` refuses no skewness.)
        // Without outlier handling no pass measures the skewness: it is 0.
        if cfg!(feature = "robust")
            && !cfg!(mag_cal_ablate = "filled-cloud")
            && below(Some(f.skewness), th.refuse_skewness)
            && above(f.fit_error, th.warn_fit_error)
        {
            return Err(Error::FilledCloud {
                skewness: beyond(f.skewness, th.refuse_skewness, false),
                limit: Figure::new(th.refuse_skewness),
            });
        }
        if let (Some(used), Some(share)) = (f.used, f.outlier_share()) {
            if above(Some(share), th.refuse_outlier_share) {
                return Err(Error::TooManyOutliers {
                    rejected: f.valid.saturating_sub(used).saturating_sub(f.beside),
                    valid: f.valid,
                    limit: Figure::new(th.refuse_outlier_share),
                });
            }
        }
        if let Some(l) = f.lack_of_fit.filter(|_| f.misfit(th)) {
            return Err(Error::SystematicMisfit {
                lack_of_fit: beyond(l, th.refuse_lack_of_fit, true),
                limit: Figure::new(th.refuse_lack_of_fit),
            });
        }
    }
    if let Some(d) = f
        .distortion
        .filter(|_| above(f.distortion, th.refuse_distortion))
    {
        return Err(Error::ExtremeDistortion {
            distortion: beyond(d, th.refuse_distortion, true),
            limit: Figure::new(th.refuse_distortion),
        });
    }
    if let Some(g) = f.quadric_gap.filter(|_| {
        below(f.quadric_gap, th.refuse_quadric_gap) && below(f.radial_rms, th.gap_noise_limit)
    }) {
        return Err(Error::AmbiguousQuadric {
            quadric_gap: beyond(g, th.refuse_quadric_gap, false),
            limit: Figure::new(th.refuse_quadric_gap),
        });
    }
    if let Some(c) = f.coverage.filter(|_| below(f.coverage, th.refuse_coverage)) {
        return Err(Error::PoorCoverage {
            coverage: beyond(c, th.refuse_coverage, false),
            limit: Figure::new(th.refuse_coverage),
        });
    }
    if let Some(d) = f
        .field_deviation
        .filter(|d| !(d.abs() <= lit(th.refuse_field_deviation)))
    {
        return Err(Error::FieldStrengthMismatch {
            deviation: beyond_magnitude(d, th.refuse_field_deviation),
            limit: Figure::new(th.refuse_field_deviation),
        });
    }
    for x in f.step_warnings.iter() {
        w.insert(x);
    }
    if f.drops.non_finite + f.drops.overflow > 0 {
        w.insert(Warning::NonFiniteDropped);
    }
    if f.drops.glitches() > 0 {
        w.insert(Warning::RowsDropped);
    }
    if f.used.is_some_and(|u| u < f.valid) {
        w.insert(Warning::OutliersRejected);
    }
    if f.used.is_some_and(|u| u < th.warn_samples) {
        w.insert(Warning::FewSamples);
    }
    if f.low_spread {
        w.insert(Warning::LowSpread);
    }
    if below(f.flatness, th.warn_flatness) {
        w.insert(Warning::NearlyPlanar);
    }
    if below(f.quadric_gap, th.warn_quadric_gap) {
        w.insert(Warning::WeakQuadric);
    }
    if above(f.gram_condition, th.warn_gram_condition) {
        w.insert(Warning::WeakCoverage);
    }
    if above(f.fit_error, th.warn_fit_error) {
        w.insert(Warning::HighFitError);
    }
    Ok(w)
}

/// A step failed with `e`: the figures computed so far may explain why
/// (planar data, a cloud that is no shell, rows crowded on one point); if
/// [`judge`] refuses them, that refusal is the answer, else `e`.
///
/// Out of line with outlier handling, one copy for its five callers
/// (`robust_start` twice, `plain_start`, `method_step`, `finish`):
/// inlined, LS9 + ADC2 took 28 bytes of flash more (31 684 -> 31 712).
/// Inlined without it, where out of line it took 4 bytes more (18 712 ->
/// 18 716, `bash bench.sh flash`).
#[cfg_attr(feature = "robust", inline(never))]
pub(crate) fn judge_failure<T: Real>(f: &Figures<T>, th: &Thresholds, e: Error) -> Error {
    match judge(f, th) {
        Err(refusal) => refusal,
        Ok(_) => e,
    }
}

/// `v` as a [`Figure`] beyond `limit` on the side it was judged on
/// (`above`: greater, else less). Rounding an `f64` figure to `f32` can
/// land on the limit itself (a flatness within about 1e-9 of 0.03), which
/// would print "0.03, limit 0.03" and fail a C check `figure < limit`:
/// such a figure becomes the next `f32` beyond the limit. NaN stays NaN.
pub(crate) fn beyond<T: Real>(v: T, limit: f32, above: bool) -> Figure {
    let x = v.to_single();
    if size_of::<T>() == size_of::<f32>() {
        // Judged as it is: already beyond (no code in `f32` builds, 104
        // bytes of text in the firmware's `compass` without this test).
        return Figure::new(x);
    }
    Figure::new(if above && x <= limit {
        limit.next_up()
    } else if !above && x >= limit {
        limit.next_down()
    } else {
        x
    })
}

/// [`beyond`] for a figure whose magnitude was judged above `limit`
/// (the field deviation), its sign kept.
fn beyond_magnitude<T: Real>(v: T, limit: f32) -> Figure {
    if size_of::<T>() == size_of::<f32>() {
        return Figure::new(v.to_single());
    }
    let x = beyond(v.abs(), limit, true).get();
    Figure::new(if v < T::zero() { -x } else { x })
}

/// `lambda_min / lambda_max` of the samples' covariance, from the
/// moments of the normalised samples (their first and second moments).
pub(crate) fn flatness<T: Real>(m: &Moments<T>, count: usize) -> Result<T, Error> {
    let n = T::from_count(count);
    let mean = [m.get(1, 0, 0) / n, m.get(0, 1, 0) / n, m.get(0, 0, 1) / n];
    let second = [
        [m.get(2, 0, 0), m.get(1, 1, 0), m.get(1, 0, 1)],
        [m.get(1, 1, 0), m.get(0, 2, 0), m.get(0, 1, 1)],
        [m.get(1, 0, 1), m.get(0, 1, 1), m.get(0, 0, 2)],
    ];
    // `second / n - mean mean^T` (symmetric), straight from the sums:
    // through nalgebra's temporaries it took 12 bytes of flash more (LS9 +
    // ADC2, with or without `robust`, `bash bench.sh flash`).
    let mut cov = [[T::zero(); 3]; 3];
    for (i, (ci, si)) in cov.iter_mut().zip(&second).enumerate() {
        for (j, (c, &s)) in ci.iter_mut().zip(si).enumerate() {
            *c = s / n - mean[i] * mean[j];
        }
    }
    let (min, max) = eigen_range(&cov)?;
    if !(max > T::zero()) {
        return Err(Error::AllSamplesEqual);
    }
    Ok(larger(min, T::zero()) / max)
}

/// `lambda_1 / lambda_0` of the normalised scatter (two smallest
/// eigenvalues). Noise-free samples of an ellipsoid make `lambda_0` zero to
/// rounding, and the gap is then as large as the precision allows.
///
/// Only two eigenvalues are needed, so instead of a full eigen-decomposition
/// (56 000 instructions on the Cortex-M4F for 10x10) the matrix is reduced
/// to tridiagonal form (Householder, a direct method) and the two smallest
/// eigenvalues are found by Sturm-sequence bisection to 1 % relative,
/// which is all a ratio compared with 3 and 10 needs.
#[inline(never)] // its 10x10 work arrays live only during the call
pub(crate) fn quadric_gap<T: Real>(scatter: &SMatrix<T, 10, 10>) -> Result<T, Error> {
    // On the slice (nalgebra's matrix iterator is a longer loop, as in
    // `ellipsoid::fit_with`: 32 bytes of flash, LS9 + ADC2 with or
    // without `robust`).
    if !scatter.as_slice().iter().all(|v| v.is_finite()) {
        return Err(Error::OutOfRange);
    }
    let (d, e) = tridiagonal(&columns_of(scatter));
    // Gershgorin bound on the spectrum of the tridiagonal matrix.
    let mut top = T::zero();
    let mut left = T::zero();
    for (&di, &ei) in d.iter().zip(&e) {
        top = larger(top, di.abs() + left + ei.abs());
        left = ei.abs();
    }
    if !(top > T::zero()) || !top.is_finite() {
        return Err(Error::AllSamplesEqual);
    }
    let floor = top * T::EPSILON * T::lit(16.0);
    let l0 = kth_eigenvalue(&d, &e, 0, top, floor);
    let l1 = kth_eigenvalue(&d, &e, 1, top, floor);
    Ok(larger(l1, floor) / larger(l0, floor))
}

/// [`quadric_gap`] of the moments' scatter, `None` when it cannot be
/// computed. Out of line: the scatter takes stack only while it is used.
#[inline(never)]
#[cfg(feature = "robust")]
pub(crate) fn moments_gap<T: Real>(m: &Moments<T>) -> Option<T> {
    quadric_gap(&m.scatter()).ok()
}

/// Number of eigenvalues below `x` of the symmetric tridiagonal matrix with
/// diagonal `d` and off-diagonal `e` (Sturm sequence: the negative pivots
/// of the LDL^T factorisation of the matrix minus `x`).
fn count_below<T: Real>(d: &[T; 10], e: &[T; 10], x: T, tiny: T) -> usize {
    let mut count = 0;
    // e[i - 1]^2, the coupling to the previous row (none for the first).
    let mut coupling = T::zero();
    let mut q = T::one();
    for (&di, &ei) in d.iter().zip(e) {
        q = di - x - coupling / q;
        coupling = ei * ei;
        if q.abs() < tiny {
            // A zero pivot: perturb it (the standard remedy).
            q = -tiny;
        }
        if q < T::zero() {
            count += 1;
        }
    }
    count
}

/// The `k`-th smallest eigenvalue (0-based) of the positive semi-definite
/// tridiagonal matrix, to 1 % relative, or `floor` when it is not above
/// `floor`. Bisection on a geometric scale between `floor` and `top`:
/// 1 % of a range of 2^19 (`f32`) to 2^48 (`f64`) takes 11 to 13 steps,
/// against 30 to 60 halvings of `[-top, top]`; capped at 64.
fn kth_eigenvalue<T: Real>(d: &[T; 10], e: &[T; 10], k: usize, top: T, floor: T) -> T {
    let tiny = floor * T::EPSILON;
    if count_below(d, e, floor, tiny) > k {
        return floor;
    }
    let (mut lo, mut hi) = (floor, top);
    let close = T::lit(1.01);
    for _ in 0..64 {
        if !(hi > lo * close) {
            break;
        }
        // sqrt(lo hi) as lo sqrt(hi / lo): no overflow; hi / lo >= 1.
        let r = hi / lo;
        let mid = lo * r * r.rsqrt();
        if count_below(d, e, mid, tiny) > k {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let r = hi / lo;
    lo * r * r.rsqrt()
}

/// Condition number of `M = W^2` for a symmetric positive definite `W`.
pub(crate) fn distortion<T: Real>(w: &Matrix3<T>) -> Result<T, Error> {
    let (lo, hi) = eigen_range(&columns_of(w))?;
    if !(lo > T::zero()) {
        return Err(Error::NotAnEllipsoid);
    }
    let r = hi / lo;
    Ok(r * r)
}

/// One thing a caller should know about a calibration that was not refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
#[repr(u16)]
pub enum Warning {
    /// Iterated ADC2 stopped at its pass cap before its tolerance: the
    /// geometry is weak (partial coverage); the estimate is the last pass.
    PassCap = 1 << 0,
    /// Some samples were not finite, or too large for the working
    /// precision, and were skipped.
    NonFiniteDropped = 1 << 1,
    /// Fewer than `WARN_SAMPLES` samples.
    FewSamples = 1 << 2,
    /// The samples' spread is below `WARN_SPREAD_OVER_NOISE` noise
    /// standard deviations (only when a noise covariance is given).
    LowSpread = 1 << 3,
    /// Flatness below `WARN_FLATNESS`.
    NearlyPlanar = 1 << 4,
    /// Quadric gap below `WARN_QUADRIC_GAP`.
    WeakQuadric = 1 << 5,
    /// Gram condition above `WARN_GRAM_CONDITION`: partial coverage.
    WeakCoverage = 1 << 6,
    /// Rows were dropped by the glitch rules (exact zeros, rails, repeated
    /// rows; [`crate::Report::drops`] counts them by rule).
    RowsDropped = 1 << 7,
    /// Some rows were screened out or rejected by their residual
    /// ([`crate::Report::screened`], [`crate::Report::rejected`]).
    OutliersRejected = 1 << 8,
    /// Fit error above `WARN_FIT_ERROR`: noisy data, or a sensor that an
    /// ellipsoid describes only roughly.
    HighFitError = 1 << 9,
}

impl Warning {
    /// Every warning.
    pub const ALL: [Warning; 10] = [
        Warning::PassCap,
        Warning::NonFiniteDropped,
        Warning::FewSamples,
        Warning::LowSpread,
        Warning::NearlyPlanar,
        Warning::WeakQuadric,
        Warning::WeakCoverage,
        Warning::RowsDropped,
        Warning::OutliersRejected,
        Warning::HighFitError,
    ];

    /// Short snake-case name, as used in the CLI's JSON.
    pub const fn name(self) -> &'static str {
        match self {
            Warning::PassCap => "pass_cap",
            Warning::NonFiniteDropped => "non_finite_dropped",
            Warning::FewSamples => "few_samples",
            Warning::LowSpread => "low_spread",
            Warning::NearlyPlanar => "nearly_planar",
            Warning::WeakQuadric => "weak_quadric",
            Warning::WeakCoverage => "weak_coverage",
            Warning::RowsDropped => "rows_dropped",
            Warning::OutliersRejected => "outliers_rejected",
            Warning::HighFitError => "high_fit_error",
        }
    }
}

/// A sentence for people: what the warning means and what to do.
impl core::fmt::Display for Warning {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.sentence())
    }
}

impl Warning {
    /// The sentence for people, without figures.
    const fn sentence(self) -> &'static str {
        match self {
            Warning::PassCap => {
                "iterated ADC2 stopped at its pass cap: the coverage is weak; turn the sensor through more orientations"
            }
            Warning::NonFiniteDropped => {
                "some readings were not finite numbers, or too large, and were skipped"
            }
            Warning::FewSamples => "few readings: collect more for a reliable calibration",
            Warning::LowSpread => {
                "the readings spread little against the given noise: the field is weak or the sensor barely turned"
            }
            Warning::NearlyPlanar => {
                "the readings lie close to a plane: turn the sensor about more axes"
            }
            Warning::WeakQuadric => {
                "another quadric fits nearly as well as the ellipsoid: cover more directions"
            }
            Warning::WeakCoverage => {
                "part of the sphere of directions was not visited: the calibration is weaker there"
            }
            Warning::RowsDropped => {
                "rows that cannot be readings (zeros, saturated axes, repeated rows) were dropped"
            }
            Warning::OutliersRejected => {
                "readings far from the others or off the ellipsoid (a magnet, a glitch) were left out"
            }
            Warning::HighFitError => {
                "the readings scatter widely about the ellipsoid: noisy data or nearby disturbances"
            }
        }
    }
}

impl Warning {
    /// The warning's sentence with the figure of `report` that raised it
    /// and the limit of `config` it passed, printed as the refusals print
    /// theirs (the fewest digits that tell the two apart), e.g. `the
    /// readings lie close to a plane (flatness 0.061, limit 0.1): turn the
    /// sensor about more axes`. The warnings that count rows name the
    /// count; [`Warning::LowSpread`] has no figure in the report and prints
    /// its sentence alone.
    ///
    /// ```
    /// # use mag_cal_core::{calibrate, Config, Warning};
    /// # let samples: Vec<[f32; 3]> = (0..40)
    /// #     .map(|i| {
    /// #         let (t, p) = (i as f32 * 2.4, (i as f32 / 40.0 * 2.0 - 1.0).acos());
    /// #         [300.0 * p.sin() * t.cos(), 300.0 * p.sin() * t.sin(), 300.0 * p.cos()]
    /// #     })
    /// #     .collect();
    /// let config = Config::default();
    /// let fit = calibrate::<f32, _>(&samples, &config)?;
    /// assert!(fit.report.warnings.contains(Warning::FewSamples));
    /// assert_eq!(
    ///     Warning::FewSamples.explain(&fit.report, &config).to_string(),
    ///     "few readings (rows used 40, limit 50): collect more for a reliable calibration"
    /// );
    /// # Ok::<(), mag_cal_core::Error>(())
    /// ```
    pub fn explain<T: Real>(self, report: &crate::Report<T>, config: &crate::Config) -> Explained {
        let rows = RowCounts {
            used: report.samples_used,
            non_finite: report
                .drops
                .non_finite
                .saturating_add(report.drops.overflow),
            glitches: report.drops.glitches(),
            left_out: report.screened.saturating_add(report.rejected),
            max_passes: config.max_passes,
        };
        self.explain_with(&report.quality, Some(&rows), &config.thresholds)
    }

    /// [`Warning::explain`] from the quality figures, the row counts and
    /// the thresholds alone, for a caller without a [`crate::Report`]
    /// (the [`crate::background`] calibrator keeps the figures of its
    /// calibration in use, not the counts). Without `rows`, the warnings
    /// that count rows print their sentence alone, but
    /// [`Warning::OutliersRejected`], which names the quality's outlier
    /// share.
    pub fn explain_with<T: Real>(
        self,
        quality: &Quality<T>,
        rows: Option<&RowCounts>,
        thresholds: &Thresholds,
    ) -> Explained {
        let th = thresholds;
        let q = quality;
        let versus = |name, figure: T, limit: f32, above: bool| {
            Detail::Versus(name, beyond(figure, limit, above), Figure::new(limit))
        };
        let detail = match (self, rows) {
            (Warning::PassCap, Some(r)) => Detail::Cap(r.max_passes),
            (Warning::NonFiniteDropped, Some(r)) => Detail::Rows(r.non_finite),
            (Warning::FewSamples, Some(r)) => Detail::Versus(
                "rows used",
                Figure::new(r.used as f32),
                Figure::new(th.warn_samples as f32),
            ),
            (Warning::LowSpread, _) => Detail::None,
            (Warning::NearlyPlanar, _) => versus("flatness", q.flatness, th.warn_flatness, false),
            (Warning::WeakQuadric, _) => {
                versus("quadric gap", q.quadric_gap, th.warn_quadric_gap, false)
            }
            (Warning::WeakCoverage, _) => versus(
                "Gram condition",
                q.gram_condition,
                th.warn_gram_condition,
                true,
            ),
            (Warning::RowsDropped, Some(r)) => Detail::Rows(r.glitches),
            (Warning::OutliersRejected, Some(r)) => Detail::Rows(r.left_out),
            (Warning::OutliersRejected, None) => {
                Detail::Share(Figure::new(q.outlier_share.to_single()))
            }
            (Warning::HighFitError, _) => versus("fit error", q.fit_error, th.warn_fit_error, true),
            (Warning::PassCap | Warning::NonFiniteDropped | Warning::FewSamples, None)
            | (Warning::RowsDropped, None) => Detail::None,
        };
        Explained {
            warning: self,
            detail,
        }
    }
}

/// The row counts a warning's explanation names ([`Warning::explain_with`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RowCounts {
    /// Rows the fit used ([`Warning::FewSamples`]).
    pub used: usize,
    /// Rows not finite or too large ([`Warning::NonFiniteDropped`]).
    pub non_finite: usize,
    /// Rows dropped by the glitch rules ([`Warning::RowsDropped`]).
    pub glitches: usize,
    /// Rows screened out or rejected ([`Warning::OutliersRejected`]).
    pub left_out: usize,
    /// The pass cap ([`Warning::PassCap`]).
    pub max_passes: u32,
}

/// A warning's sentence with its figure ([`Warning::explain`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Explained {
    warning: Warning,
    detail: Detail,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Detail {
    None,
    /// A figure's name, the figure and the limit it passed.
    Versus(&'static str, Figure, Figure),
    /// Rows counted.
    Rows(usize),
    /// A share of the rows (a fraction, printed as a percentage).
    Share(Figure),
    /// A pass cap.
    Cap(u32),
}

impl core::fmt::Display for Explained {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let mut sentence = self.warning.sentence();
        // The figure goes after the finding, before the advice.
        let advice = sentence.split_once(": ").map(|(finding, advice)| {
            sentence = finding;
            advice
        });
        f.write_str(sentence)?;
        match self.detail {
            Detail::None => {}
            Detail::Versus(name, figure, limit) => write!(
                f,
                " ({name} {})",
                crate::error::Versus::new(figure, limit, "")
            )?,
            Detail::Rows(1) => f.write_str(" (1 row)")?,
            Detail::Rows(n) => write!(f, " ({n} rows)")?,
            Detail::Share(share) => {
                f.write_str(" (")?;
                crate::error::write_figure(f, f64::from(share.get()) * 100.0, 2)?;
                f.write_str(" % of the rows)")?;
            }
            Detail::Cap(n) => write!(f, " ({n} passes)")?,
        }
        match advice {
            Some(advice) => write!(f, ": {advice}"),
            None => Ok(()),
        }
    }
}

/// A set of [`Warning`]s (a bit set: `Copy`, no allocation). With the
/// `defmt` feature it is logged by the warnings' names.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Warnings(u16);

impl Warnings {
    /// No warning.
    pub const NONE: Warnings = Warnings(0);

    /// Adds `w`.
    pub fn insert(&mut self, w: Warning) {
        self.0 |= w as u16;
    }

    /// Whether `w` is present.
    pub const fn contains(self, w: Warning) -> bool {
        self.0 & (w as u16) != 0
    }

    /// Whether there is none.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// The warnings present, in [`Warning::ALL`] order.
    pub fn iter(self) -> impl Iterator<Item = Warning> {
        Warning::ALL.into_iter().filter(move |w| self.contains(*w))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    extern crate std;
    use std::string::ToString;

    /// A limit that is NaN or out of its range is refused before any pass,
    /// naming its field; the defaults and infinite limits (a check turned
    /// off) pass.
    #[test]
    fn thresholds_are_validated_before_the_fit() {
        let sphere: [[f32; 3]; 200] = core::array::from_fn(|i| {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / 200.0;
            let (r, phi) = ((1.0 - z * z).sqrt(), i as f32 * 2.399_963);
            [
                40.0 * r * phi.cos() + 5.0,
                40.0 * r * phi.sin(),
                40.0 * z - 3.0,
            ]
        });
        let fit = |thresholds| {
            let config = crate::Config {
                thresholds,
                ..crate::Config::DEFAULT
            };
            crate::calibrate::<f32, _>(&sphere, &config)
        };
        assert!(fit(Thresholds::DEFAULT).is_ok());
        let off = Thresholds {
            refuse_fit_error: f32::INFINITY,
            refuse_skewness: f32::NEG_INFINITY,
            ..Thresholds::DEFAULT
        };
        assert!(fit(off).is_ok());
        let cases = [
            (
                "refuse_fit_error",
                Thresholds {
                    refuse_fit_error: f32::NAN,
                    ..Thresholds::DEFAULT
                },
            ),
            (
                "refuse_outlier_share",
                Thresholds {
                    refuse_outlier_share: 1.5,
                    ..Thresholds::DEFAULT
                },
            ),
            (
                "refuse_distortion",
                Thresholds {
                    refuse_distortion: 0.5,
                    ..Thresholds::DEFAULT
                },
            ),
            (
                "warn_flatness",
                Thresholds {
                    warn_flatness: -0.1,
                    ..Thresholds::DEFAULT
                },
            ),
        ];
        for (field, t) in cases {
            assert_eq!(
                fit(t).err(),
                Some(Error::InvalidConfig { field }),
                "{field}"
            );
        }
    }

    /// An `f64` figure within 1e-12 of its limit rounds to the limit in
    /// `f32`: the refusal and the warning carry the next `f32` beyond it,
    /// and print the two apart.
    #[test]
    fn a_figure_next_to_its_limit_stays_beyond_it() {
        let th = Thresholds::DEFAULT;
        let near = |limit: f32, above: bool| {
            let l = f64::from(limit);
            l + if above { 1e-12 } else { -1e-12 } * l.abs()
        };
        for (limit, above) in [(0.03f32, false), (0.2, true), (-0.6, false), (16.0, true)] {
            let v = near(limit, above);
            assert_eq!(v as f32, limit, "the case: rounds onto the limit");
            let x = beyond(v, limit, above).get();
            assert!(if above { x > limit } else { x < limit }, "{x} {limit}");
            assert_eq!(x.to_bits().abs_diff(limit.to_bits()), 1, "{x} {limit}");
        }
        assert!(beyond(f64::NAN, 0.2, true).get().is_nan());
        assert_eq!(beyond(0.5f32, 0.2, true).get(), 0.5);
        let d = beyond_magnitude(-near(0.25, true), 0.25).get();
        assert_eq!(d, -0.25f32.next_up());

        let mut f = Figures::<f64>::before_fit(1000, crate::Drops::default(), true, true, false);
        f.flatness = Some(near(th.refuse_flatness, false));
        let e = judge(&f, &th).unwrap_err();
        let Error::Planar { flatness, limit } = e else {
            panic!("{e:?}");
        };
        assert!(flatness.get() < limit.get(), "{e:?}");
        // The printed figure and limit read back apart, on the refusing side.
        let apart = |m: &str, name: &str, above: bool| {
            let (_, rest) = m.split_once(&std::format!("({name} ")).expect(m);
            let (x, rest) = rest.split_once(", limit ").expect(m);
            let l = rest.split([')', ',']).next().expect(m);
            let (x, l): (f64, f64) = (x.parse().expect(m), l.parse().expect(m));
            assert!(if above { x > l } else { x < l }, "{m}");
        };
        apart(&e.to_string(), "flatness", false);

        let q = Quality {
            flatness: near(th.warn_flatness, false),
            quadric_gap: 1e6,
            distortion: 1.0,
            coverage: 0.3,
            gram_condition: near(th.warn_gram_condition, true),
            fit_error: 0.01,
            lack_of_fit: 0.0,
            outlier_share: 0.0123,
            skewness: 0.0,
        };
        let text = |w: Warning| w.explain_with(&q, None, &th).to_string();
        let planar = text(Warning::NearlyPlanar);
        assert!(
            planar.starts_with("the readings lie close to a plane (flatness "),
            "{planar}"
        );
        assert!(
            planar.ends_with("): turn the sensor about more axes"),
            "{planar}"
        );
        apart(&planar, "flatness", false);
        apart(&text(Warning::WeakCoverage), "Gram condition", true);
        // Without the row counts: the outlier share, or the sentence alone.
        assert!(
            text(Warning::OutliersRejected).contains("left out (1.2 % of the rows)"),
            "{}",
            text(Warning::OutliersRejected)
        );
        assert_eq!(text(Warning::FewSamples), Warning::FewSamples.to_string());
    }

    /// The bisection gap agrees with a full eigen-decomposition's.
    #[test]
    fn quadric_gap_matches_the_full_eigen_decomposition() {
        for seed in 1..20u64 {
            let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15);
            let a = SMatrix::<f64, 10, 10>::from_fn(|_, _| {
                state = state
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1);
                (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            });
            let s = a * a.transpose();
            let eig = SMatrix::<f64, 10, 10>::symmetric_eigen(s).eigenvalues;
            let mut l: [f64; 10] = eig.into();
            l.sort_by(|x, y| x.total_cmp(y));
            let want = l[1] / l[0];
            let got = quadric_gap(&s).unwrap();
            assert!(
                // Each eigenvalue to 0.5 % (the geometric middle of a 1 %
                // bracket): the ratio to about 1 %.
                (got / want - 1.0).abs() < 1.2e-2,
                "seed {seed}: {got} vs {want}"
            );
            assert!(want > 1.0);
        }
    }
}
