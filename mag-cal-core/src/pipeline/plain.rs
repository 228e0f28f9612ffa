//! The plain path: every row the scan kept, weight 1.

use super::*;
#[cfg(feature = "robust")]
use crate::tuning::{CLEAN_KURTOSIS, CLEAN_LIMIT, CLEAN_SKEWNESS};

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
/// the fit is clean (`CLEAN_LIMIT`, `CLEAN_TAIL`):
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
    // The start and the estimate are read in place, in their `Result`s:
    // taken out by `?`, each was copied into a local of its own, 116 bytes
    // of flash more (LS9 + ADC2 31 684 -> 31 800; without `robust` 140,
    // 18 712 -> 18 852, `bash bench.sh flash`).
    let start = plain_start(samples, config, scan, ls_solve, &mut figures);
    let start = match &start {
        Ok(s) => s,
        Err(e) => return Err(*e),
    };
    let est = method_step(samples, config, start, step, &figures);
    let est = match &est {
        Ok(e) => e,
        Err(e) => return Err(*e),
    };
    // Without outlier handling compiled in, no route to decide: the fit
    // is the answer.
    #[cfg(not(feature = "robust"))]
    return finish(samples, config, start, est, &mut figures);
    #[cfg(feature = "robust")]
    plain_rest(samples, config, start, est, &mut figures, route)
}

/// The plain path after the method, with outlier handling: the final pass
/// and whether the fit is clean (`route`). Out of line, as the robust
/// path's [`finish_fit`](super::robust::finish_fit): the finished fit,
/// read in place in its `Result`, then takes stack in this frame only, not
/// in [`plain_path`]'s while the method runs. Inlined there, with the
/// finished fit taken out by `?`, [`plain_path`]'s frame was 1 088 bytes
/// instead of 528 with the method chosen at run time (this one's: 320),
/// and LS9 + ADC2 took 20 bytes of flash more (31 664 -> 31 684, `bash
/// bench.sh flash`).
#[cfg(feature = "robust")]
#[inline(never)]
fn plain_rest<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    start: &Start<T>,
    est: &methods::Estimate<T>,
    figures: &mut Figures<T>,
    route: &mut Route,
) -> Result<Fit<T>, Error> {
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
    let done = finish(samples, config, start, est, figures);
    let done = match &done {
        Ok(d) => d,
        Err(e) => return Err(*e),
    };
    let sigma = done.fit.report.quality.fit_error;
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
    Ok(done.fit)
}

/// The plain path up to the method: the moments and the LS fit, and the
/// figures they give (into `figures`). Out of line, as `robust_start`:
/// the moments take stack only until the method starts.
#[inline(never)]
pub(super) fn plain_start<'s, T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    scan: &'s normalize::Scan<T>,
    ls_solve: ellipsoid::Solve<T>,
    figures: &mut Figures<T>,
) -> Result<Start<'s, T>, Error> {
    let norm = scan.norm;
    // The rows the rules dropped stay out; without drops the scan's rules
    // are plain, and so are the loops.
    let gate = rules::Gate::of(scan.rules, scan.dwell);
    let moments = moments::Moments::accumulate_with(samples, &norm, &gate, None, None);
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
