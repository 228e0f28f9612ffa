//! Step 1 on contaminated data: the robust LS ellipsoid fit (design
//! document, section 14, steps 4-5).
//!
//! The plain LS fit trusts every sample, and an M-estimator started from it
//! settles on the ellipsoid that a displaced patch of the trajectory bent
//! it to. The robust fit starts instead from the crude sphere of the
//! screening ([`crate::robust::screen`]):
//!
//! 1. LS9 moments over the `CRUDE_SHARE` of the screened
//!    samples closest to the crude sphere (median centre, median distance);
//! 2. weighted LS refits on the moments, weight 1 when the algebraic
//!    residual `|e| = ||u|^2 - 1| / 2` under the previous fit is at most
//!    [`crate::tuning::OUTLIER_CUT`]` sigma_e`, with
//!    `sigma_e = 1.4826 median|e|` from the pass before (lagged one pass,
//!    so each refit is one pass). On the subsample (below), for
//!    `TRIM_REFITS` refits, the cut is also at most the `TRIM_SHARE`
//!    quantile of `|e|` from the pass before: such a refit fits at most
//!    that share of the rows, those closest to the fit before (a
//!    concentration step of least trimmed squares).
//!    Beyond the design document: the first refit's cut comes from the
//!    crude sphere's error, which is large on a distorted ellipsoid (0.1
//!    of the field at 25 % distortion), so it kept a displaced patch
//!    whole, and refits with a cut of 3.5 sigma alone then stayed on the
//!    ellipsoid the patch bulged (a tenth of the rows displaced by 0.3
//!    field: 10.5 % of the runs refused as a systematic misfit, the fits
//!    off by 0.07-0.28 in `M`; 2.0 % with the trimming, which costs the
//!    subsample a few more refits before its count settles).
//!
//! The crude start and the refits run on a fixed subsample of about
//! `SUBSAMPLE_ROWS` rows until its count of rows kept
//! settles (changes by at most one). From the crude start, the untrimmed
//! refits on the subsample also find the runs of rows far beyond the cut
//! ([`crate::robust::runs`]; six consecutive rows of the subsample), those of the
//! last one stand, and one refit on every row follows, which skips the
//! rows beside them, as every later pass does. Measured on a Cortex-M4F
//! (LS9 + ADC2, n = 1000, a tenth of the rows displaced): 1.56 M
//! instructions; a pass on every row that found the runs before that
//! refit cost 0.11 M more, and 0.2 M more when it refitted as well (the
//! contamination study, `docs/results.md`: robust ADC2 silently wrong in
//! 14 of 18 688 f32 runs, as with the pass that found the runs only; every
//! cell within its target). The subsample sees a
//! run only when it lasts six of its rows: on a real recording with a
//! magnet passing (`mag3_raw_541.csv`, a CLI test) the span began 21 rows
//! later, and the hard iron stayed as close to that of the clean rows (0.6
//! counts of a 3 480-count field). A single refit on every row with no
//! run found before it left a disturbance moving past the sensor over a
//! tenth of the rows at median error ratios of 1.27 / 1.39 (target 1.3),
//! and one-step ADC2 from the subsample's fit alone, 1.3-1.5 in every
//! contaminated cell. From a window start (below), whose subsample left
//! out half the rows, the first pass on every row finds the runs and
//! refits: from the subsample's fit alone, a recording of level turns (the
//! heading scenario of the paper tables) was refused as a systematic
//! misfit. Without a subsample (fewer than twice
//! `SUBSAMPLE_ROWS` rows) up to `REFITS` passes run on
//! every row until the count repeats, the third finding the runs and
//! refitting nothing (a limit of zero keeps no row).
//!
//! A disturbance of a fifth of the recording or more can bend the fit from
//! the crude start into a compromise that keeps nearly every row. When the
//! result is in doubt (`crate::tuning::DOUBT_LACK_OF_FIT`), the pipeline runs the
//! robust path again with `STARTS` window starts beside the crude one,
//! each from the rows outside half of the recording, and the fit with the
//! smallest median residual wins ([`robust_ls`]).
//! Each pass on every row
//! costs about 100 instructions a sample on a Cortex-M4F for the selection
//! plus about 100 a kept row for its moments (an exec-log profile of a
//! 10 % contaminated run, `docs/benchmarks.md`). The method's own passes
//! then run with the same gate and a residual cut.

use crate::tuning::{OUTLIER_CUT, REFITS, STARTS, TRIM_REFITS, TRIM_SHARE};
use nalgebra::{Matrix3, Vector3};

use crate::numerics::histogram::LogHistogram;
use crate::numerics::linalg::smaller;
use crate::robust::runs::Runs;
use crate::robust::screen::{stride, Screening};
use crate::sample::Sample;
use crate::steps::ellipsoid::{fit_with, Ellipsoid, Solve};
use crate::steps::methods::robust_sigma;
use crate::steps::moments::{Cut, Moments};
use crate::steps::normalize::{Normalization, Projector};
use crate::steps::rules::Gate;
use crate::{Error, Real};

/// The robust LS fit and what the method's passes need from it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RobustLs<T: Real> {
    /// The fit, in the screening's normalised coordinates.
    pub ls: Ellipsoid<T>,
    /// The moments of the rows the last refit kept (flatness and quadric
    /// gap are judged on them).
    pub moments: Moments<T>,
    /// Robust sigma of the residuals under the fit before the last one
    /// (for the method's first pass: lagged).
    pub sigma: T,
    /// Passes over the samples.
    pub passes: u32,
}

/// The LS fit of `moments`. Out of line: the 10x10 scatter takes stack
/// only while it is solved.
#[inline(never)]
fn fit_moments<T: Real>(moments: &Moments<T>, solve: Solve<T>) -> Result<Ellipsoid<T>, Error> {
    fit_with(&moments.scatter(), solve)
}

/// What a refit pass measured of the residuals `|e|` under the fit it
/// started from, for the next pass's cut.
#[derive(Clone, Copy)]
struct Spread<T: Real> {
    /// Robust sigma, `1.4826 median|e|`.
    sigma: T,
    /// The `TRIM_SHARE` quantile of `|e|`.
    trim: T,
}

/// One weighted LS refit pass: the moments of the rows whose algebraic
/// residual under `ls` is within `limit` (with `sums`; without, none),
/// what the residuals under `ls` measure (for the next pass), and into
/// `runs`, when given, the runs of rows beyond `STRONG`
/// times the limit ([`crate::robust::runs`]). Out of line: its histogram takes
/// stack only during the pass.
#[inline(never)]
#[allow(clippy::too_many_arguments)]
fn weighted_moments<T: Real, S: Sample>(
    samples: &[S],
    screening: &Screening<T>,
    gate: &Gate<T>,
    skip: &Runs,
    ls: &Ellipsoid<T>,
    limit: T,
    stride: usize,
    runs: Option<&mut Runs>,
    sums: bool,
) -> (Moments<T>, Option<Spread<T>>) {
    let norm = &screening.norm;
    let mut hist = LogHistogram::new();
    let find = runs.map(|r| (r, limit * T::lit(crate::tuning::STRONG)));
    let cut = Cut {
        map: Projector::new(norm, &ls.centre, &ls.w),
        // A limit of zero keeps no row: no moments to sum.
        limit: if sums { limit } else { T::zero() },
    };
    let m = Moments::accumulate_finding(
        samples,
        norm,
        gate,
        skip,
        Some(&cut),
        Some(&mut hist),
        stride,
        find,
    );
    let measured = robust_sigma(&hist)
        .zip(hist.quantile(T::lit(TRIM_SHARE)))
        .map(|(sigma, trim)| Spread { sigma, trim });
    (m, measured)
}

/// The moments of the crude start: the rows `gate` passes (the rules and
/// the screening ball of `screening`) outside `window` within the band
/// around the crude sphere that holds `CRUDE_SHARE` of
/// them, in the screening's normalised coordinates. Out of line (stack, as
/// [`robust_ls`]).
#[inline(never)]
pub(crate) fn crude_moments<T: Real, S: Sample>(
    samples: &[S],
    screening: &Screening<T>,
    gate: &Gate<T>,
    window: &Runs,
) -> Moments<T> {
    let every = stride(screening.valid);
    let crude = crude_cut(screening);
    Moments::accumulate_finding(
        samples,
        &screening.norm,
        gate,
        window,
        Some(&crude),
        None,
        every,
        None,
    )
}

/// Start `k` of the robust LS: for `k = 0` the crude start on every row,
/// for `k = 1..=STARTS` on the rows outside window `k - 1` of
/// `STARTS`, which leaves out the rows `q n / STARTS .. q n / STARTS + n
/// / 2` (`q = k - 1`, in the samples' order, wrapping at the end): half
/// the rows. The rows the start leaves out, as spans (none for `k = 0`
/// or beyond `STARTS`).
pub(crate) fn window(k: usize, rows: usize) -> Runs {
    let q = k.wrapping_sub(1);
    if q >= STARTS {
        return Runs::NONE;
    }
    let (s, e) = (q * rows / STARTS, q * rows / STARTS + rows / 2);
    let spans = if e <= rows {
        Runs::from_spans(&[(s, e)])
    } else {
        Runs::from_spans(&[(0, e - rows), (s, rows)])
    };
    spans.unwrap_or(Runs::NONE)
}

/// How well a start's robust fit explains the rows ([`score`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Score<T: Real> {
    /// The median algebraic residual `|e|`: lower is better.
    pub median: T,
    /// The share of the rows scored whose `|e|` exceeds
    /// [`OUTLIER_CUT`] robust sigmas (`1.4826` medians): the rows the fit
    /// leaves out.
    pub beyond: T,
}

/// The score of a robust fit `ls` (in the normalised coordinates of
/// `norm`) over every `every`-th row that `gate` passes, none skipped (one
/// pass, which sums no moments). Out of line, as [`weighted_moments`].
#[inline(never)]
pub(crate) fn score<T: Real, S: Sample>(
    samples: &[S],
    norm: &Normalization<T>,
    gate: &Gate<T>,
    ls: &Ellipsoid<T>,
    every: usize,
) -> Option<Score<T>> {
    let mut hist = LogHistogram::new();
    // A limit of zero keeps no row: the pass only counts the residuals.
    let cut = Cut {
        map: Projector::new(norm, &ls.centre, &ls.w),
        limit: T::zero(),
    };
    Moments::accumulate_finding(
        samples,
        norm,
        gate,
        &Runs::NONE,
        Some(&cut),
        Some(&mut hist),
        every,
        None,
    );
    let median = hist.quantile(T::lit(0.5))?;
    let cut = robust_sigma::<T>(&hist)? * T::lit(OUTLIER_CUT);
    let total = hist.total();
    let within = hist.count_below(cut).min(total);
    let beyond = T::from_count((total - within) as usize) / T::from_count(total as usize);
    Some(Score { median, beyond })
}

/// The band around the crude sphere as a cut on the algebraic residual
/// `e = (|x|^2 - 1) / 2` with `x = (y - c) / m`, which is `t + t^2 / 2` at
/// `|x| = 1 + t`.
fn crude_cut<T: Real>(screening: &Screening<T>) -> Cut<T> {
    let norm = &screening.norm;
    let t = screening.band * norm.inv_scale;
    Cut {
        map: Projector::new(norm, &Vector3::zeros(), &Matrix3::identity()),
        limit: t + t * t * T::lit(0.5),
    }
}

/// Why [`robust_ls`] found no fit.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Failure {
    /// The crude start's rows are flat ([`crate::judge::quality::flatness`]).
    Flat(Error),
    /// No ellipsoid from the crude start.
    Fit(Error),
}

/// The robust LS fit from the crude start ([`crude_moments`], one pass,
/// whose flatness goes into `flatness`), over the rows `gate` passes;
/// writes into `runs` the
/// spans beside runs of rejected rows ([`crate::robust::runs`]), which the later
/// refits skip, as the method's passes will. The refits on the subsample
/// skip the rows of `window` too, as the crude start did
/// ([`window`]); those on every row take in the window's rows that fit.
/// Out of line: its histogram and scatter take stack only while it runs,
/// not during the method's passes. The crude start's moments are its
/// own: made by the caller, they took 140 bytes of the caller's frame,
/// under this one's.
#[inline(never)]
pub(crate) fn robust_ls<T: Real, S: Sample>(
    samples: &[S],
    screening: &Screening<T>,
    gate: &Gate<T>,
    solve: Solve<T>,
    runs: &mut Runs,
    window: &Runs,
    flatness: &mut Option<T>,
) -> Result<RobustLs<T>, Failure> {
    // The answer is made in place: the crude start's moments go straight
    // into it and each refit replaces its fit and moments. Built from
    // locals at the end, it took a copy beside them: this frame 848 bytes
    // instead of 744 (LS9 + ADC2; the footprint's `ls-doubtful` and
    // `adc2-doubtful` runs: 3 564 B of stack instead of 3 452). Its fit is
    // the crude start's, set below.
    let mut fit = RobustLs {
        ls: Ellipsoid {
            centre: Vector3::zeros(),
            m: Matrix3::zeros(),
            w: Matrix3::zeros(),
            t: Matrix3::zeros(),
        },
        moments: crude_moments(samples, screening, gate, window),
        sigma: screening.sphere_error,
        passes: 1,
    };
    let crude = &fit.moments;
    *flatness = Some(crate::judge::quality::flatness(crude, crude.count()).map_err(Failure::Flat)?);
    fit.ls = fit_moments(crude, solve).map_err(Failure::Fit)?;
    let mut found = false;
    // The crude start's pass measured no residuals: no trimming yet.
    let mut trim = None;
    let every = stride(screening.valid);
    // On a subsample the refits run until its kept count settles, and two
    // more on every row settle the fit; without one, all run on every row.
    // From the crude start, the subsample's untrimmed refits find the runs
    // (those of the last one stand; the first refit is one); then one refit
    // on every row follows, not a pass that finds them and a refit.
    let sub_finds = every > 1 && window.is_empty();
    let (sub_refits, full_refits) = match (every > 1, sub_finds) {
        (true, true) => (REFITS - 2, 1),
        (true, false) => (REFITS - 2, 2),
        (false, _) => (0, REFITS),
    };
    for (rounds, rows) in [(sub_refits, every), (full_refits, 1)] {
        let mut last_kept = None;
        for _ in 0..rounds {
            // `passes` counts the crude start's pass: the refits after the
            // first (which has no quantile yet) are trimmed, up to
            // `TRIM_REFITS` of them.
            // (Ablation, docs/robustness.md: `trim` trims no refit.)
            let trimmed = trim.filter(|_| {
                !cfg!(mag_cal_ablate = "trim") && rows > 1 && fit.passes <= TRIM_REFITS + 1
            });
            let limit = trimmed.map_or(fit.sigma * T::lit(OUTLIER_CUT), |t| {
                smaller(fit.sigma * T::lit(OUTLIER_CUT), t)
            });
            // Which pass finds the runs of rejected rows (the passes on
            // every row after it skip the rows beside them): from the crude
            // start each untrimmed refit on the subsample; otherwise the
            // first pass on every row after two refits, which refits
            // nothing without a window (a limit of zero keeps no row, and
            // its moments cost nothing) and refits from a window start,
            // whose subsample left out half the rows.
            // (Ablation, docs/robustness.md: `runs` finds none, and every
            // pass refits.)
            let find = !cfg!(mag_cal_ablate = "runs")
                && if rows > 1 {
                    sub_finds && trimmed.is_none()
                } else {
                    fit.passes >= 3 && !found
                };
            let only_find = find && rows == 1 && window.is_empty();
            let (skip, out) = if find && rows == 1 {
                (&Runs::NONE, Some(&mut *runs))
            } else if find {
                (window, Some(&mut *runs))
            } else if rows > 1 {
                (window, None)
            } else {
                (&*runs, None)
            };
            let (m, measured) = weighted_moments(
                samples, screening, gate, skip, &fit.ls, limit, rows, out, !only_find,
            );
            fit.passes += 1;
            found |= find;
            if let Some(r) = measured {
                fit.sigma = r.sigma;
                trim = Some(r.trim);
            }
            if only_find {
                // A count before rows were left out says nothing of the next.
                last_kept = None;
                continue;
            }
            let Ok(next) = fit_moments(&m, solve) else {
                // The kept rows no longer determine an ellipsoid: keep the
                // last fit (its residuals are those just measured).
                break;
            };
            let kept = m.count();
            fit.moments = m;
            fit.ls = next;
            // The subsample's count need only settle (the refits on every
            // row follow); on every row it must repeat.
            // A trimmed refit keeps about the trimmed share by construction:
            // its count says nothing about settling.
            let settled = |before: usize| kept.abs_diff(before) <= if rows > 1 { 1 } else { 0 };
            if trimmed.is_none() && last_kept.is_some_and(settled) {
                break;
            }
            // A count before rows were left out says nothing of the next.
            last_kept = (trimmed.is_none() && !(find && rows == 1)).then_some(kept);
        }
    }
    Ok(fit)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_windows_leave_out_half_the_rows_and_wrap_at_the_end() {
        assert!(window(0, 1000).is_empty());
        assert!(window(STARTS + 1, 1000).is_empty());
        assert_eq!(window(1, 1000).spans(), &[(0, 500)]);
        assert_eq!(window(2, 1000).spans(), &[(250, 750)]);
        assert_eq!(window(3, 1000).spans(), &[(500, 1000)]);
        assert_eq!(window(4, 1000).spans(), &[(0, 250), (750, 1000)]);
        for rows in [0usize, 1, 3, 7, 601, 1001] {
            for k in 1..=STARTS {
                let w = window(k, rows);
                let left_out: usize = w.spans().iter().map(|&(s, e)| e - s).sum();
                assert!(w.spans().iter().all(|&(_, e)| e <= rows));
                // Half the rows, rounded down; none of too few rows.
                assert!(
                    left_out == rows / 2 || (left_out == 0 && rows < 4),
                    "{rows} {k}"
                );
            }
        }
    }
}
