//! The plain path: every row the scan kept, weight 1.

use super::*;

/// A plain fit is taken as the robust one when no row's residual exceeds
/// this many robust standard deviations, in the method's pass and in the
/// final pass. Beyond it a row cannot be Gaussian noise of that sigma
/// (probability 6e-7 a row); below it, the 0/1 weights at
/// [`OUTLIER_CUT`](crate::OUTLIER_CUT) would leave out rows that move the fit by less than the
/// noise. Clean data then pay no robust pass.
#[cfg(feature = "robust")]
pub const CLEAN_LIMIT: f64 = 5.0;

/// A plain fit is taken as the robust one only when the RMS of its radial
/// residuals is at most this many times their robust sigma: about 1 for
/// Gaussian noise (0.8 for quantisation), more when a share of the rows
/// lies off the ellipsoid. (Residuals at the level of rounding, an RMS
/// below the square root of the type's epsilon, are not judged by it.)
#[cfg(feature = "robust")]
pub const CLEAN_TAIL: f64 = 1.25;

/// A plain fit is not taken when the kurtosis `n sum e^4 / (sum e^2)^2`
/// of the algebraic residuals `e = |u|^2 - 1` under its LS start (in the
/// method's artificial-data pass) exceeds this: about 3 for Gaussian
/// noise, below 2 for quantisation; 10 % of the rows displaced by 0.3 of
/// the field give about 10. The robust path then starts without the plain
/// method's solve and final pass.
#[cfg(feature = "robust")]
pub const CLEAN_KURTOSIS: f64 = 6.0;

/// Nor when the skewness `sqrt(n) sum e^3 / (sum e^2)^(3/2)` of the same
/// residuals is below minus this: a share of the rows pulled inwards, as
/// an axis clipped on some reads pulls them (-1.5 when 30 % of the rows
/// are; the robust path's screening then finds the clip levels). Noise
/// skews the other way (`e = 2 n + n^2` for a radial noise `n`), and so do
/// rows displaced outwards, which the kurtosis sees.
#[cfg(feature = "robust")]
pub const CLEAN_SKEWNESS: f64 = 1.0;

/// Nor, for the LS fit alone, when its lack of fit about the mean radial
/// residual ([`Quality::lack_of_fit`] without the common offset, which is
/// the algebraic fit's shrinkage under noise) is significant and exceeds
/// this many fit errors. LS's lack of fit is not judged, as its criterion
/// leaves a pattern under noise; but that pattern grows with the noise, a
/// displaced stretch of rows does not. Measured (f64, LS9): clean
/// scenarios A-G at most 0.17 (200 runs each, E 0.13-0.17, A and C below
/// 0.15); plain LS fits bent by a displaced patch or a moving disturbance
/// (10-30 % of the rows) that passed every other test 0.36 or more, most
/// above 0.44.
#[cfg(feature = "robust")]
pub const CLEAN_SHAPE: f64 = 0.3;

/// What [`plain_path`] returns when the robust path answers
/// ([`Route::Robust`]) and the plain path has no refusal of its own to
/// return: no answer, a value of the answer's type only, which `pipeline`
/// drops. (The answer's own type keeps the plain fit in the caller's slot;
/// see `pipeline`.)
#[cfg(feature = "robust")]
const NOT_TAKEN: Error = Error::NoConvergence { iterations: 0 };

/// The plain pipeline: every row the scan kept, weight 1. Its answer, the
/// fit or a refusal, stands without outlier handling (without the `robust`
/// feature, always); with it, only when
/// the fit is clean ([`CLEAN_LIMIT`], [`CLEAN_TAIL`](crate::CLEAN_TAIL)):
/// `route` is then set to [`Route::Plain`], else left as the caller set it
/// ([`Route::Robust`]). Out of line, as the robust path: inlined, both
/// paths' locals would share `pipeline`'s frame.
#[inline(never)]
pub(super) fn plain_path<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    scan: &normalize::Scan<T>,
    ls_solve: ellipsoid::Solve<T>,
    step: methods::Step<T, S>,
    #[cfg(feature = "robust")] route: &mut Route,
) -> Result<Fit<T>, Error> {
    #[cfg(feature = "robust")]
    if !config.robust {
        *route = Route::Plain;
    }
    let mut figures = Figures::new(scan, config, false);
    let start = plain_start(samples, config, scan, ls_solve, &mut figures)?;
    let est = method_step(samples, config, &start, step, &figures)?;
    // Without outlier handling compiled in, no route to decide: the fit
    // is the answer.
    #[cfg(not(feature = "robust"))]
    return finish(samples, config, &start, &est, &mut figures).map(|done| done.fit);
    #[cfg(feature = "robust")]
    {
        if est.beyond_tails_limit {
            // The method's first pass found heavy tails, or rows pulled
            // inwards (only with outlier handling, which sets the limit).
            return Err(NOT_TAKEN);
        }
        let clean_limit = |max: T, sigma: T| max <= sigma * T::lit(CLEAN_LIMIT);
        let method_clean = est
            .max_residual
            .zip(est.sigma)
            .is_none_or(|(m, s)| clean_limit(m, s));
        if config.robust && !method_clean {
            // Not clean, and this fit will not be returned: no final pass
            // (about 120 instructions a row on a Cortex-M4F).
            return Err(NOT_TAKEN);
        }
        let done = finish(samples, config, &start, &est, &mut figures)?;
        let fit = done.fit;
        let sigma = fit.report.quality.fit_error;
        // Heavy tails: a contamination that broadened every residual, so that
        // none stands out.
        let is_clean = method_clean
            && clean_limit(done.final_max, sigma)
            && !done.heavy_tails
            && !done.misfit
            && !done.misshapen;
        if is_clean {
            *route = Route::Plain;
        }
        Ok(fit)
    }
}

/// The plain path up to the method: the moments and the LS fit, and the
/// figures they give (into `figures`). Out of line, as [`robust_start`]:
/// the moments take stack only until the method starts.
#[inline(never)]
pub(super) fn plain_start<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    scan: &normalize::Scan<T>,
    ls_solve: ellipsoid::Solve<T>,
    figures: &mut Figures<T>,
) -> Result<Start<'static, T>, Error> {
    let norm = scan.norm;
    // The rows the rules dropped stay out; without drops the scan's rules
    // are plain, and so are the loops.
    let gate = rules::Gate {
        rules: scan.rules,
        screen: None,
    };
    let moments = moments::Moments::accumulate_with(samples, &norm, &gate, None, None);
    // (Ablation, docs/robustness.md: `gross-kurtosis` always tries it.)
    #[cfg(feature = "robust")]
    if config.robust
        && !cfg!(mag_cal_ablate = "gross-kurtosis")
        && moments.kurtosis() > T::lit(normalize::GROSS_KURTOSIS)
    {
        // Gross outliers: not worth a plain fit (the robust path screens;
        // the route is left to it).
        return Err(NOT_TAKEN);
    }
    figures.flatness = Some(quality::flatness(&moments, scan.used)?);
    let (ls, gap) = match ls_step(&moments, ls_solve) {
        (Ok(ls), gap) => (ls, gap),
        // A failed fit of planar data is refused as planar.
        (Err(e), _) => return Err(judge_failure(figures, config, e)),
    };
    figures.quadric_gap = gap;
    let start = Start {
        start: 0,
        norm,
        ls,
        weights: methods::Weights {
            gate,
            runs: &runs::Runs::NONE,
            sigma: None,
            tails_limit: config
                .robust
                .then(|| (T::lit(TAILS_LIMIT.0), T::lit(TAILS_LIMIT.1))),
        },
        robust_passes: 0,
    };
    Ok(start)
}

/// The plain pass's tails limit with outlier handling
/// ([`methods::Weights::tails_limit`]): [`CLEAN_KURTOSIS`] and
/// [`CLEAN_SKEWNESS`], beyond which the robust path answers.
#[cfg(feature = "robust")]
const TAILS_LIMIT: (f64, f64) = (CLEAN_KURTOSIS, CLEAN_SKEWNESS);

/// Without the `robust` feature there is no robust path to hand over to:
/// no tails stop the plain pass (no kurtosis exceeds, no skewness is below
/// minus, infinity; nor does a NaN). The limit is still set with
/// [`Config::robust`], so that the LS fit alone makes the artificial-data
/// pass at its fit as it does with the feature (its direction sums are
/// the final pass's), and its figures are the same in both builds.
#[cfg(not(feature = "robust"))]
const TAILS_LIMIT: (f64, f64) = (f64::INFINITY, f64::INFINITY);
