//! The robust path: screening, the robust LS, the method with 0/1
//! weights, and the window starts when the result is in doubt.

use super::*;
use crate::tuning::{AMBIGUOUS_SCORE, DOUBT_LACK_OF_FIT};

/// The robust pipeline (section 14 of the design document): screening, the
/// robust LS fit, the method with 0/1 weights. When the result is in doubt
/// (`DOUBT_LACK_OF_FIT`), the robust LS from each of the window starts
/// (`STARTS`) and from the crude start is scored (the median
/// residual over the subsample, [`refit::window`], `AMBIGUOUS_SCORE`),
/// and the path runs
/// again from the window start that scored best; when the crude start
/// scores best, the first run's fit stands. The screening does not depend
/// on the start: the scoring makes it once for every start, and each run
/// makes its own, so that no screening is held on the stack while a
/// method runs (only the first run's fit is kept while the starts are
/// scored and the second run goes). Out of line (see [`plain_path`]).
#[inline(never)]
pub(super) fn robust_path<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    scan: &normalize::Scan<T>,
    ls_solve: ellipsoid::Solve<T>,
    step: methods::Step<T, S>,
) -> Result<Fit<T>, Error> {
    let mut first = Attempt::default();
    let mut fit = robust_attempt(samples, config, scan, ls_solve, step, 0, 0, &mut first);
    // (Ablation, docs/robustness.md: `windows` lets the first run stand.)
    if cfg!(mag_cal_ablate = "windows") || !first.doubt {
        return fit;
    }
    let Some(k) = best_start(samples, config, scan, ls_solve, &mut first.passes) else {
        return fit;
    };
    let passes = first.passes;
    if k == 0 {
        // The crude start scored best: its run is the first one.
        if let Ok(f) = &mut fit {
            f.report.robust_passes = passes;
        }
        return fit;
    }
    robust_attempt(samples, config, scan, ls_solve, step, k, passes, &mut first)
}

/// The start of the robust LS ([`refit::window`]) whose fit scores best,
/// if any fits; adds the passes the scoring took to `passes`. One screening
/// for every start, held in this frame, which [`robust_start`] is given
/// in place of its own: a result in doubt takes 4 076 B of stack (the
/// footprint's `-doubtful` run; 4 068 B with [`start_from`] inlined into
/// the scorer as well, 248 bytes more flash; 4 092 B
/// with the scoring inlined into [`robust_path`] and a screening for each
/// start; 4 116 B with this function out of line and no screening in it),
/// and `robust-patch-0.3` 7.38 M instructions instead of 8.26 M.
#[inline(never)]
pub(super) fn best_start<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    scan: &normalize::Scan<T>,
    ls_solve: ellipsoid::Solve<T>,
    passes: &mut u32,
) -> Option<usize> {
    // The screening does not depend on the start: made once for all.
    // Read in place in its `Result`, as the screenings, robust LS fits,
    // starts and estimates of this path: taken out by `?` or a `match` by
    // value, each was copied into a local of its own, 152 bytes of flash
    // more (LS9 + ADC2 31 684 -> 31 836, `bash bench.sh flash`).
    let screened = screen::screen(samples, scan);
    let Ok(screening) = &screened else {
        return None;
    };
    *passes = passes.saturating_add(screening.passes);
    // The start that scores best, and its score.
    let mut best: Option<(usize, T)> = None;
    for k in 0..=crate::tuning::STARTS {
        let (score, made) = robust_score(samples, config, scan, screening, ls_solve, k);
        *passes = passes.saturating_add(made);
        if let Some(s) = score.filter(|&s| best.is_none_or(|(_, b)| s < b)) {
            best = Some((k, s));
        }
    }
    best.map(|(k, _)| k)
}

/// What [`robust_attempt`] tells its caller beside the fit.
#[derive(Default)]
pub(super) struct Attempt {
    /// The result is in doubt: its lack of fit is beyond
    /// `DOUBT_LACK_OF_FIT`, or it is refused for it or for too many
    /// outliers.
    doubt: bool,
    /// The robust passes it made (with those before it).
    passes: u32,
}

/// One run of the robust path from start `k` ([`refit::window`]), with
/// `before` robust passes made before it. The doubt is judged on its
/// figures, not on the fit: the fit then goes straight to the caller (a
/// fit held here while the caller returns it took 256 bytes of stack). Out
/// of line: the second run's frame takes the place of the first's.
#[inline(never)]
#[allow(clippy::too_many_arguments)]
pub(super) fn robust_attempt<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    scan: &normalize::Scan<T>,
    ls_solve: ellipsoid::Solve<T>,
    step: methods::Step<T, S>,
    k: usize,
    before: u32,
    outcome: &mut Attempt,
) -> Result<Fit<T>, Error> {
    let mut figures = Figures::new(scan, config, true);
    // The spans beside runs of rejected rows, which the weights refer to.
    let mut runs = runs::Runs::NONE;
    *outcome = Attempt::default();
    let mut start = robust_start(
        samples,
        config,
        scan,
        None,
        ls_solve,
        &mut figures,
        &mut runs,
        k,
    );
    let start = match &mut start {
        Ok(s) => s,
        Err(e) => return Err(*e),
    };
    start.robust_passes = start.robust_passes.saturating_add(before);
    outcome.passes = start.robust_passes;
    let fit = robust_rest(samples, config, start, step, &mut figures);
    let th = &config.thresholds;
    outcome.doubt = figures
        .lack_of_fit
        .is_some_and(|l| l > T::lit(DOUBT_LACK_OF_FIT))
        || figures
            .outlier_share()
            .is_some_and(|s| s > T::from_single(th.refuse_outlier_share));
    fit
}

/// The score of the robust LS from start `k` (`None` when it fails) and
/// the passes it took: the median residual ([`refit::score`]), divided by
/// `AMBIGUOUS_SCORE` when the fit leaves out more than
/// [`Thresholds::refuse_outlier_share`](crate::Thresholds::refuse_outlier_share) of the rows. Inlined into
/// [`best_start`] (itself out of line, so the robust path's frame does not
/// hold the scoring loop): out of line, its frame sat between
/// [`best_start`]'s and [`robust_start`]'s, 128 bytes more stack.
#[inline(always)]
pub(super) fn robust_score<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    scan: &normalize::Scan<T>,
    screening: &screen::Screening<T>,
    ls_solve: ellipsoid::Solve<T>,
    k: usize,
) -> (Option<T>, u32) {
    let mut figures = Figures::new(scan, config, true);
    let mut runs = runs::Runs::NONE;
    let started = robust_start(
        samples,
        config,
        scan,
        Some(screening),
        ls_solve,
        &mut figures,
        &mut runs,
        k,
    );
    let Ok(start) = &started else {
        return (None, 0);
    };
    let every = screen::stride(figures.valid);
    let gate = &start.weights.gate;
    let share = T::from_single(config.thresholds.refuse_outlier_share);
    let score = refit::score(samples, &start.norm, gate, &start.ls, every).map(|s| {
        // (Ablation, docs/robustness.md: `ambiguous-score` scores every
        // start by its median alone.)
        if !cfg!(mag_cal_ablate = "ambiguous-score") && s.beyond > share {
            s.median / T::lit(AMBIGUOUS_SCORE)
        } else {
            s.median
        }
    });
    (score, start.robust_passes.saturating_add(1))
}

/// The robust path after its start: the method and the final pass. Out of
/// line, as [`finish_fit`]: the method's estimate and the finished fit then
/// take no stack while the robust start runs, nor the finished fit while
/// the method runs.
#[inline(never)]
pub(super) fn robust_rest<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    start: &Start<T>,
    step: methods::Step<T, S>,
    figures: &mut Figures<T>,
) -> Result<Fit<T>, Error> {
    let est = method_step(samples, config, start, step, figures);
    let est = match &est {
        Ok(e) => e,
        Err(e) => return Err(*e),
    };
    finish_fit(samples, config, start, est, figures)
}

/// [`finish()`] for the robust path, which needs only the fit. Out of line:
/// the finished fit then takes stack in this frame only, not in the
/// robust path's while its start and the method run.
#[inline(never)]
pub(super) fn finish_fit<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    start: &Start<T>,
    est: &methods::Estimate<T>,
    figures: &mut Figures<T>,
) -> Result<Fit<T>, Error> {
    finish(samples, config, start, est, figures).map(|done| done.fit)
}

/// The robust path up to the method: the screening (or the one made
/// before, `screened`) and the robust LS fit, and the figures they give
/// (into `figures`). Out of line: their moments and fits take stack only
/// until the method starts. The scoring of the starts calls it with the
/// screening it made before: a copy of [`start_from`] inlined there too
/// took 248 bytes of flash more (LS9 + ADC2).
#[inline(never)]
#[allow(clippy::too_many_arguments)]
pub(super) fn robust_start<'r, T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    scan: &'r normalize::Scan<T>,
    screened: Option<&screen::Screening<T>>,
    ls_solve: ellipsoid::Solve<T>,
    figures: &mut Figures<T>,
    runs: &'r mut runs::Runs,
    k: usize,
) -> Result<Start<'r, T>, Error> {
    let own;
    let (screening, passes) = match screened {
        Some(s) => (s, 0),
        None => {
            own = screen::screen(samples, scan);
            match &own {
                Ok(s) => (s, s.passes),
                Err(screen::Unscreened::AllEqual) => return Err(Error::AllSamplesEqual),
                Err(screen::Unscreened::Crowded) => {
                    // No sphere at all: judged by the crude sphere's fit
                    // error, infinite, which the judging always refuses.
                    figures.fit_error = Some(T::lit(f64::INFINITY));
                    return Err(judge_failure(figures, config, Error::AllSamplesEqual));
                }
            }
        }
    };
    start_from(
        samples, config, screening, passes, ls_solve, figures, runs, k, scan.dwell,
    )
}

/// [`robust_start`] from a screening made before, counting `before`
/// robust passes before it. Inlined: out of line, its frame would sit
/// below the screening's.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn start_from<'r, T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    screening: &screen::Screening<T>,
    before: u32,
    ls_solve: ellipsoid::Solve<T>,
    figures: &mut Figures<T>,
    runs: &'r mut runs::Runs,
    k: usize,
    dwell: &'r crate::Dwell<T>,
) -> Result<Start<'r, T>, Error> {
    let window = &refit::window(k, samples.len());
    figures.drops = screening.drops;
    figures.valid = screening.valid;
    let gate = rules::Gate {
        rules: screening.rules,
        screen: Some(screening.ball),
        dwell,
    };
    let fitted = refit::robust_ls(
        samples,
        screening,
        &gate,
        ls_solve,
        runs,
        window,
        &mut figures.flatness,
    );
    let fitted = match &fitted {
        Ok(f) => f,
        Err(refit::Failure::Flat(e)) => return Err(*e),
        Err(refit::Failure::Fit(e)) => {
            let e = *e;
            // No ellipsoid at all: judged by the crude sphere's fit error.
            figures.fit_error = Some(screening.sphere_error);
            return Err(judge_failure(figures, config, e));
        }
    };
    let kept = fitted.moments.count();
    figures.flatness = Some(quality::flatness(&fitted.moments, kept)?);
    figures.quadric_gap = quality::moments_gap(&fitted.moments);
    let start = Start {
        start: u8::try_from(k).unwrap_or(u8::MAX),
        norm: screening.norm,
        ls: fitted.ls,
        weights: methods::Weights {
            gate,
            runs,
            sigma: Some(fitted.sigma),
            tails_limit: None,
        },
        robust_passes: before.saturating_add(fitted.passes),
    };
    Ok(start)
}
