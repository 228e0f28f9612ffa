//! The sequencing of the batch fit: the plain path, and the robust path
//! when the plain fit is not clean. The steps themselves are in `steps`,
//! the outlier handling in `robust`, the judging in `judge`.

mod finish;
mod plain;
#[cfg(feature = "robust")]
mod robust;

use crate::judge::quality::{self, Figures};
use crate::robust::runs;
#[cfg(feature = "robust")]
use crate::robust::{refit, screen};
use crate::steps::{ellipsoid, final_pass, methods, moments, normalize, rules};
use crate::{Calibration, Config, Error, Fit, Method, Real, Report, Sample, Selection};

use finish::{finish, judge_failure, method_step};
use plain::plain_path;
#[cfg(feature = "robust")]
use robust::robust_path;

/// Calibrates from a slice of raw samples, in precision `T`.
///
/// Non-finite samples are skipped and counted. Passes over the data:
/// validation and normalisation, moments, then (except [`Method::Ls`]) the
/// method's own passes, and finally one pass for the quality figures. On
/// contaminated data ([`Config::robust`](crate::Config::robust)), screening and robust LS passes
/// come before the method's (see [the crate docs](crate#outliers)). The
/// figures are then judged in one place ([`quality`]): planar, shapeless,
/// outlier-ridden, ambiguous, too eccentric or poorly covered data are
/// refused with a specific [`Error`], milder findings reported as
/// [`Warning`](crate::Warning)s.
///
/// # Flash
/// The method and the LS variant are resolved to functions here, in a
/// small wrapper inlined at the call site; the pipeline takes them as
/// function pointers. With a constant [`Config`] (e.g. `Config::default()`)
/// the optimiser sees which are used and links only those: LS9 + ADC2
/// alone is what firmware pays for. A `Config` chosen at run time links
/// every method its cargo features enable (see [Features](crate#features)):
/// a method or LS variant whose feature is off is refused with
/// [`Error::NotEnabled`].
#[inline(always)]
pub fn calibrate<T: Real, S: Sample>(samples: &[S], config: &Config) -> Result<Fit<T>, Error> {
    // Here, inlined: with a constant `Config` the check folds away (inside
    // the out-of-line `pipeline` it cost 716 B: `bash bench.sh flash`).
    config.thresholds.validate()?;
    let step: methods::Step<T, S> = match config.method {
        Method::Ls => methods::ls_only,
        #[cfg(feature = "adc1")]
        Method::Adc1 => methods::adc1::step,
        Method::Adc2 => methods::adc2::step,
        #[cfg(feature = "adc2-iter")]
        Method::Adc2Iterated => methods::adc2_iter::step,
        #[cfg(feature = "submle")]
        Method::SubMle => methods::submle::step,
        #[allow(unreachable_patterns)] // with every method enabled
        other => {
            return Err(Error::NotEnabled {
                feature: other.feature(),
            })
        }
    };
    pipeline(samples, config, ellipsoid::solver(config.ls)?, step)
}

/// [`calibrate`] with the LS solve and the method's step resolved.
fn pipeline<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    ls_solve: ellipsoid::Solve<T>,
    step: methods::Step<T, S>,
) -> Result<Fit<T>, Error> {
    // The still periods are set aside in the scan (issue 36), into this
    // frame.
    let mut dwell = crate::Dwell::NONE;
    let still = config.still.then_some(&mut dwell);
    let scan = normalize::scan_still::<T, S>(samples, config.robust, still)?;
    // Without outlier handling the plain path's answer is the answer.
    #[cfg(not(feature = "robust"))]
    return plain_path(samples, config, &scan, ls_solve, step);
    #[cfg(feature = "robust")]
    robust_pipeline(samples, config, &scan, ls_solve, step)
}

/// [`pipeline`] after the scan, with outlier handling compiled in: the
/// plain path, then the robust path when [`Config::robust`] is set and
/// the plain fit is not clean. Inlined (its one caller).
#[cfg(feature = "robust")]
#[inline(always)]
fn robust_pipeline<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    scan: &normalize::Scan<T>,
    ls_solve: ellipsoid::Solve<T>,
    step: methods::Step<T, S>,
) -> Result<Fit<T>, Error> {
    let gate = rules::Gate::of(scan.rules, scan.dwell);
    if config.robust && screen::clip_hint(samples, &gate, scan.used) {
        // A clip level may bend the plain fit unseen: screening finds it.
        return robust_path(samples, config, scan, ls_solve, step);
    }
    // The plain answer is returned as it is, or not at all. It has this
    // function's own type, so that it goes straight into the caller's slot
    // and this frame holds no second fit under the robust path (224 bytes
    // of stack; an `Option` of the answer, or a route in its error, took
    // 480: the footprint's `measured_call`).
    let mut route = Route::Robust;
    let plain = plain_path(samples, config, scan, ls_solve, step, &mut route);
    match route {
        Route::Plain => plain,
        Route::Robust => robust_path(samples, config, scan, ls_solve, step),
    }
}

/// Whose answer the batch fit returns: the plain path's or the robust
/// path's. Private to the pipeline: a caller sees a calibration or an
/// [`Error`], never a route.
#[cfg(feature = "robust")]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Route {
    /// The plain path's answer, a fit or a refusal: always without outlier
    /// handling; with it ([`Config::robust`]), when the plain fit is clean.
    Plain,
    /// The robust path's: outlier handling is on, and the plain path
    /// refused, failed, or its fit is not clean: residuals with heavy tails
    /// or pulled inwards in the method's first pass (`CLEAN_KURTOSIS`,
    /// `CLEAN_SKEWNESS`), a residual beyond [`CLEAN_LIMIT`](crate::tuning::CLEAN_LIMIT) robust
    /// sigmas, an RMS beyond [`CLEAN_TAIL`](crate::tuning::CLEAN_TAIL) of them, a lack of fit beyond
    /// its limit, or an LS fit misshapen beyond `CLEAN_SHAPE`.
    Robust,
}

/// What the steps before the method leave for it and for the judging.
pub(super) struct Start<'r, T: Real> {
    /// The robust LS's start ([`Report::start`]).
    start: u8,
    norm: normalize::Normalization<T>,
    ls: ellipsoid::Ellipsoid<T>,
    weights: methods::Weights<'r, T>,
    robust_passes: u32,
}

/// Step 1 on the moments: the LS fit, and the quadric gap of the same
/// scatter (judged after the method, against its radial RMS; see
/// `REFUSE_QUADRIC_GAP`). Out of line, so the 10x10 scatter
/// takes stack only while it is used.
#[inline(never)]
pub(crate) fn ls_step<T: Real>(
    moments: &moments::Moments<T>,
    solve: ellipsoid::Solve<T>,
) -> (Result<ellipsoid::Ellipsoid<T>, Error>, Option<T>) {
    let scatter = moments.scatter();
    let quadric_gap = quality::quadric_gap(&scatter).ok();
    (ellipsoid::fit_with(&scatter, solve), quadric_gap)
}
