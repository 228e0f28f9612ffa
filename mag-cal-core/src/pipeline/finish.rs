//! The method's step and the final pass, and the judging of their figures.

use super::*;
#[cfg(feature = "robust")]
use crate::tuning::{CLEAN_SHAPE, CLEAN_TAIL};

/// Without outlier handling, the fit alone: it goes straight into the
/// caller's slot (a `Finished` holding it was copied there, 260 bytes:
/// LS9 + ADC2 without `robust` 21 360 -> 21 324 bytes of flash, `bash
/// bench.sh flash`).
#[cfg(not(feature = "robust"))]
pub(super) type Finished<T> = Fit<T>;

/// A fit and what decides whether the plain one is clean.
#[cfg(feature = "robust")]
pub(super) struct Finished<T: Real> {
    pub(super) fit: Fit<T>,
    /// The final pass's largest residual.
    pub(super) final_max: T,
    /// The lack of fit is beyond its limit (`Figures::misfit`).
    pub(super) misfit: bool,
    /// The LS fit alone: its lack of shape is beyond `CLEAN_SHAPE` fit
    /// errors.
    pub(super) misshapen: bool,
    /// The radial residuals have heavier tails than noise: their RMS is
    /// above [`CLEAN_TAIL`] robust sigmas, and above the level of
    /// rounding (`sqrt(eps)` of the field), where the tails are the
    /// rounding's own.
    pub(super) heavy_tails: bool,
}

/// The method from the start; a failure is judged on the figures so far.
/// Out of line, as [`finish()`]: the method's passes and the final pass then
/// take their stack one after the other, not one under the other.
#[inline(never)]
pub(super) fn method_step<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    start: &Start<T>,
    step: methods::Step<T, S>,
    figures: &Figures<T>,
) -> Result<methods::Estimate<T>, Error> {
    // The step's answer is returned as it came, an error replaced in place:
    // mapped (`map_err`), a copy of it made this frame 164 bytes instead
    // of 48 with the method chosen at run time, under the method's passes.
    match step(samples, &start.norm, &start.ls, config, &start.weights) {
        Err(e) => Err(judge_failure(figures, config, e)),
        est => est,
    }
}

/// The final pass after the method's estimate `est`, and the judging.
#[inline(never)]
pub(super) fn finish<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    start: &Start<T>,
    est: &methods::Estimate<T>,
    figures: &mut Figures<T>,
) -> Result<Finished<T>, Error> {
    let norm = &start.norm;
    figures.step_warnings = est.warnings;
    let distortion = quality::distortion(&est.w)?;
    figures.distortion = Some(distortion);
    let calibration = Calibration::from_normalised_w(norm, &est.w, &est.centre)?;
    // The rows the estimate used: with weights, those within the cut of the
    // method's last pass (lagged, as its weights); for LS alone, the robust
    // LS's own cut; subMLE used every row inside the screening.
    // Without outlier handling no weights (`weights.sigma` is never set):
    // every row the rules keep is used.
    #[cfg(not(feature = "robust"))]
    let limit: Option<T> = None;
    #[cfg(feature = "robust")]
    let limit = {
        let sigma = match (start.weights.sigma, est.sigma) {
            (None, _) => None,
            (Some(_), Some(s)) => Some(s),
            (Some(s), None) if config.method == Method::Ls => Some(s),
            (Some(_), None) => None,
        };
        sigma.map(|s| s * T::lit(crate::tuning::OUTLIER_CUT))
    };
    // Without outlier handling no runs (`weights.runs` is always empty):
    // the constant, which the pass's loop folds (LS9 + ADC2 without
    // `robust` 21 324 -> 21 236 bytes of flash, `bash bench.sh flash`).
    #[cfg(not(feature = "robust"))]
    let runs = &runs::Runs::NONE;
    #[cfg(feature = "robust")]
    let runs = start.weights.runs;
    let last = match final_pass::final_pass(
        samples,
        norm,
        &est.centre,
        &est.w,
        est.directions,
        &start.weights.gate,
        runs,
        limit,
    ) {
        Ok(last) => last,
        Err(e) => return Err(judge_failure(figures, config, e)),
    };
    // The rows of the spans beside runs, which the passes skipped: those
    // the gate passes count as rejected, and those of them within the cut
    // are no outliers.
    figures.beside = 0;
    #[cfg(not(feature = "robust"))]
    let spanned = 0usize;
    #[cfg(feature = "robust")]
    let spanned = {
        let mut spanned = 0usize;
        runs.visit(samples, |s, prev| {
            if let Some(y) = start.weights.gate.pass(s, prev) {
                spanned += 1;
                let within = limit.is_none_or(|l| {
                    (calibration.map(y).norm_squared().square_root() - T::one()).abs() <= l
                });
                figures.beside += usize::from(within);
            }
        });
        spanned
    };
    // The LS fit's radius shrinks under noise (its algebraic criterion):
    // with outlier handling, its fit error is taken relative to the rows'
    // mean radius, the shell's own thickness. Measured (f32 and f64): a
    // noise ball 0.185-0.200 about the fitted radius, 0.206-0.227 about the
    // mean; clean scenario E at most 0.166, the others at most 0.086.
    let fit_error = if config.robust && config.method == Method::Ls {
        last.fit_error / (T::one() + last.mean_residual)
    } else {
        last.fit_error
    };
    figures.record_final(&last, fit_error);
    // Only the robust path's pass sums the cubes.
    #[cfg(feature = "robust")]
    if figures.robust {
        figures.skewness = last.skewness;
    }
    figures.field_deviation = config
        .expected_field_strength
        .map(|expected| calibration.field_strength() / T::from_double(expected) - T::one());
    let warnings = quality::judge(figures, &config.thresholds)?;
    #[cfg(feature = "robust")]
    let to_sensor = |b: &rules::Ball<T>| (b.centre, b.radius_sq.square_root());
    let quality = figures.quality(distortion, &last, fit_error);
    let report = Report {
        method: config.method,
        ls: config.ls,
        iterations: est.iterations,
        passes: est.passes,
        robust_passes: start.robust_passes,
        samples_used: last.used,
        samples_dropped: figures.drops.total(),
        drops: figures.drops,
        dwell: start.weights.gate.dwell.rows(),
        screened: figures
            .valid
            .saturating_sub(last.passed)
            .saturating_sub(spanned),
        rejected: last
            .passed
            .saturating_add(spanned)
            .saturating_sub(last.used),
        beside_runs: figures.beside,
        radial_rms: last.radial_rms,
        quality,
        warnings,
        selection: Selection {
            // The rules every row is judged by (a pass skips the glitch
            // rules when they dropped no row: the rows are the same).
            glitch_rules: config.robust,
            #[cfg(feature = "robust")]
            clip_levels: clip_levels(&start.weights.gate.rules.clip),
            #[cfg(feature = "robust")]
            screen: start.weights.gate.screen.as_ref().map(to_sensor),
            // Without outlier handling no screening: no clip levels are
            // found and no ball is set.
            #[cfg(not(feature = "robust"))]
            clip_levels: [[None; 2]; 3],
            #[cfg(not(feature = "robust"))]
            screen: None,
            residual_limit: limit,
            runs: *runs,
            dwell: *start.weights.gate.dwell,
        },
        start: start.start,
    };
    let fit = Fit {
        calibration,
        report,
    };
    #[cfg(not(feature = "robust"))]
    return Ok(fit);
    #[cfg(feature = "robust")]
    Ok(Finished {
        fit,
        final_max: last.max_residual,
        // (Ablation, docs/robustness.md: `misfit-gate` and `heavy-tails`
        // leave these out of the plain fit's cleanness.)
        misfit: !cfg!(mag_cal_ablate = "misfit-gate") && figures.misfit(&config.thresholds),
        misshapen: config.method == Method::Ls
            && last.lack_of_shape > last.fit_error * T::lit(CLEAN_SHAPE),
        heavy_tails: !cfg!(mag_cal_ablate = "heavy-tails")
            && last.radial_rms > last.fit_error * T::lit(CLEAN_TAIL)
            && last.radial_rms * last.radial_rms > T::EPSILON,
    })
}

/// The clip levels of the rules, `None` for an axis's side without one
/// (`T::MAX`). A loop over the flattened array: nested `array::map`s of
/// `Option::filter` took 44 bytes of flash more (LS9 + ADC2 31 684 ->
/// 31 728, `bash bench.sh flash`).
#[cfg(feature = "robust")]
fn clip_levels<T: Real>(clip: &[[T; 2]; 3]) -> [[Option<T>; 2]; 3] {
    let mut out = [[None; 2]; 3];
    for (o, c) in out.as_flattened_mut().iter_mut().zip(clip.as_flattened()) {
        if c.abs() < T::MAX {
            *o = Some(*c);
        }
    }
    out
}

/// [`quality::judge_failure`] with the caller's thresholds.
pub(super) fn judge_failure<T: Real>(figures: &Figures<T>, config: &Config, e: Error) -> Error {
    quality::judge_failure(figures, &config.thresholds, e)
}

impl<T: Real> Figures<T> {
    pub(super) fn new(scan: &normalize::Scan<T>, config: &Config, robust: bool) -> Self {
        let low_spread = config.noise_covariance.is_some_and(|c| {
            // In T: no f64 arithmetic (soft-float on a Cortex-M4F) in the
            // f32 path.
            let var = (T::from_double(c[0][0]) + T::from_double(c[1][1]) + T::from_double(c[2][2]))
                / T::lit(3.0);
            scan.norm.scale
                < T::from_single(config.thresholds.warn_spread_over_noise) * var.square_root()
        });
        Self::before_fit(
            scan.used,
            scan.drops,
            robust,
            config.method.fits_radial_residual(),
            low_spread,
        )
    }
}
