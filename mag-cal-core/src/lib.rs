//! Allocation-free three-axis magnetometer calibration for microcontrollers.
//!
//! From a batch of raw readings (a few hundred, taken while the device is
//! turned through many orientations) [`calibrate`] finds the hard-iron
//! offset and the soft-iron correction, in `f32` or `f64`, on the stack,
//! with every loop bounded and no panic for any input. It reports how well
//! the result fits, or refuses data that are not a calibration with an
//! [`Error`] that names the cause and the figure that decided it.
//!
//! ```
//! use mag_cal_core::{calibrate, Config};
//!
//! // Samples on a shifted, stretched ellipsoid (here generated; in firmware
//! // they come from the sensor, e.g. as `[i16; 3]` or `(i16, i16, i16)`).
//! let samples: Vec<[f32; 3]> = (0..200)
//!     .map(|i| {
//!         let z = 1.0 - 2.0 * (i as f32 + 0.5) / 200.0;
//!         let r = (1.0 - z * z).sqrt();
//!         let phi = i as f32 * 2.399_963;
//!         let h = [r * phi.cos(), r * phi.sin(), z];
//!         [300.0 + 40.0 * h[0], -120.0 + 55.0 * h[1], 75.0 + 48.0 * h[2]]
//!     })
//!     .collect();
//!
//! let fit = calibrate::<f32, _>(&samples, &Config::default())?;
//! let [bx, by, _] = fit.calibration.hard_iron();
//! assert!((bx - 300.0).abs() < 1e-2 && (by + 120.0).abs() < 1e-2);
//! let [ux, uy, uz] = fit.calibration.apply(samples[17]);
//! assert!(((ux * ux + uy * uy + uz * uz).sqrt() - 1.0).abs() < 1e-4);
//! assert!(fit.report.radial_rms < 1e-4);
//! # Ok::<(), mag_cal_core::Error>(())
//! ```
//!
//! # The model and what is determined
//!
//! A raw reading is `y = T h + b + e`: the unit direction `h` of the local
//! field in the sensor frame, distorted by the soft-iron matrix `T` (scale,
//! non-orthogonality and misalignment of the axes, soft iron nearby),
//! shifted by the hard-iron offset `b`, plus noise `e`. Calibration finds
//! `b` and `W = T^-1`, so that `u = W (y - b)` lies on the unit sphere
//! ([`Calibration::apply`]; [`Calibration::apply_scaled`] multiplies by
//! the field strength).
//!
//! The data fix `b` and `M = W^T W` only: for any rotation `Q`, `Q W`
//! maps the samples onto the sphere as well (the gauge). The calibration
//! therefore holds the canonical `W = M^(1/2)`, symmetric positive
//! definite; [`Calibration::shape`] is `M`, and
//! [`Calibration::field_strength`] is `rho = det(W)^(-1/3)`, the radius of
//! the sphere of equal volume, in sensor units. Comparing two calibrations
//! means comparing `M` and `b`, not `W`. Turning the calibrated frame into
//! the device's body frame is a separate step with reference directions
//! ([`align`]); headings are in [`heading`].
//!
//! Vectors are `[T; 3]`, matrices `[[T; 3]; 3]` by rows (`w[i][j]` in row
//! `i`, column `j`). Samples are any [`Sample`]: `[i16; 3]`, `[i32; 3]`,
//! `[f32; 3]`, `[f64; 3]` and the tuples of those types.
//!
//! # The fit
//!
//! The paper's Algorithm 1 with ADC2 ("artificial data creation"), in
//! passes over the read-only samples:
//!
//! 1. **Scan**: rows that cannot be readings are dropped by rule and
//!    counted ([`Drops`]): non-finite, too large for the working precision,
//!    and with outlier handling `(0, 0, 0)`, an axis on the integer rails,
//!    a row equal to the one before, an axis at a clip level. The rest are
//!    centred and scaled, `x = (y - c) / s`, so that nothing cancels in
//!    `f32` at offsets of tens of thousands of counts.
//! 2. **LS ellipsoid fit**: the quadric `x^T A x + g^T x = 1` through the
//!    normalised samples by algebraic least squares on 35 moments summed
//!    in one pass ([`LsVariant::Ls9`]; also the smallest eigenvector of
//!    the 10x10 scatter and an ellipsoid-specific fit), then its centre
//!    `b0` and `W0 = M0^(1/2)`.
//! 3. **Artificial data**: the unit vectors `h_i = u_i / |u_i|` of
//!    `u_i = W0 (x_i - b0)`, reduced in a second pass to sufficient
//!    statistics of the residuals `x_i - b0 - T0 h_i` (sums of small terms,
//!    exact in `f32`).
//! 4. **Re-estimation** ([`Method`]): ADC2 minimises
//!    `sum |x_i - b - T h_i|^2` over `T` and `b` (linear in them, so exactly
//!    quadratic: BFGS with the exact line search on the statistics, no
//!    further pass). Iterated ADC2 repeats steps 3-4 from each new estimate
//!    to the fixed point (Anderson-accelerated, a pass each); ADC1 weights
//!    the residuals by the noise covariance and has ADC2's minimiser;
//!    subMLE (the paper's baseline) minimises the first-order likelihood
//!    `sum (|u_i|^2 - 1)^2 / |W^T u_i|^2` with one pass per evaluation.
//! 5. **Final pass**: the figures of the result ([`Quality`]), judged in one
//!    place.
//!
//! # Quality figures and refusals
//!
//! Every figure is relative (unit-free). [`Thresholds::DEFAULT`] holds the
//! measured limits; [`Config::thresholds`] sets others.
//!
//! | figure ([`Quality`]) | what it measures | refused | warned |
//! |---|---|---|---|
//! | `flatness` | smallest / largest eigenvalue of the samples' covariance: 1/3-1 for a sphere, 0 for a plane | below 0.03: [`Error::Planar`] | below 0.1 |
//! | `quadric_gap` | how much better the LS quadric fits than the next one | below 3 on data that fit well: [`Error::AmbiguousQuadric`] | below 10 |
//! | `distortion` | condition number of `M` (squared axis ratio) | above 16: [`Error::ExtremeDistortion`] | |
//! | `coverage` | smallest eigenvalue of the calibrated directions' covariance: 1/3 full sphere, 0.085 a +-30 deg band | below 0.05: [`Error::PoorCoverage`] | Gram condition above 20 |
//! | `fit_error` | robust sigma `1.4826 median||u| - 1|` of the radial residuals, in units of the field (for the LS fit alone with outlier handling, of the rows' mean radius: LS's radius shrinks under noise) | above 0.2: [`Error::NoSphere`] (a device lying still, a filled cloud) | above 0.05 |
//! | `outlier_share` | share of the valid rows the fit left out as outliers (screened, or beyond the cut) | above 0.25: [`Error::TooManyOutliers`] | |
//! | `lack_of_fit` | systematic radial misfit over 24 direction cells | above 0.01 and significant: [`Error::SystematicMisfit`] | |
//! | `skewness` | skewness of the radial residuals of the rows used (outlier handling): about 0 on a noisy shell, -0.7 to -0.9 on a filled ball | below -0.6 with a fit error above 0.05: [`Error::FilledCloud`] | |
//!
//! With [`Config::expected_field_strength`] a field strength more than
//! 25 % off is refused ([`Error::FieldStrengthMismatch`]); fewer than 50
//! rows and a spread below 10 noise deviations are warned ([`Warning`]).
//!
//! # Outliers
//!
//! Real logs hold rows that are not on the ellipsoid: bus glitches (wild
//! values, exact zeros, a saturated axis), a stuck sensor (repeated rows),
//! a magnet or a motor current displacing a stretch of the trajectory. With
//! [`Config::robust`] (the default) the fit:
//!
//! 1. drops rows by rule (above) and counts them by rule;
//! 2. fits plainly, and keeps that fit when no residual exceeds
//!    [`CLEAN_LIMIT`] robust standard deviations, their RMS is at most
//!    [`CLEAN_TAIL`] robust standard deviations and nothing misfits (clean
//!    data pay one extra pass's worth of figures, no robust pass; the LS
//!    fit alone, whose lack of fit is not judged, makes ADC2's first
//!    artificial-data pass for its residuals' tails and must not misfit in
//!    shape, [`CLEAN_SHAPE`]); a plain
//!    attempt whose LS residuals already show heavy tails
//!    ([`CLEAN_KURTOSIS`]), rows pulled inwards ([`CLEAN_SKEWNESS`]) or a
//!    residual beyond the limit stops before its solve or its final pass;
//!    and none is made when an axis's extreme is shared by
//!    [`CLIP_HINT_ROWS`] rows of a subsample (a clip level, which
//!    bends the plain fit without standing out of its residuals);
//! 3. otherwise screens the rows farther than [`SCREEN_RADIUS`] median
//!    distances from a coordinate-wise median centre (or, when samples
//!    crowded on one side of the sphere put that centre near the crowded
//!    side and its ball leaves out the far side, from an algebraic sphere
//!    fit of the rows within 6 median distances), starts from the
//!    crude sphere (that centre, the median distance), and refits LS with 0/1
//!    weights on the residual (at [`OUTLIER_CUT`]` = 3.5` robust standard
//!    deviations `1.4826 median|r|`, from fixed histograms: no sorting,
//!    nothing stored per sample), then runs the method with the same
//!    weights. The screening's histograms and the refits before the last
//!    one use a fixed subsample of about [`SUBSAMPLE_ROWS`] rows (every
//!    `k`-th row), so their cost hardly grows with `n`. Where consecutive
//!    rows lie far beyond the cut (a disturbance passing), the rows beside
//!    them, displaced less, are left out too ([`runs`]);
//! 4. when that result is in doubt (lack of fit beyond
//!    [`DOUBT_LACK_OF_FIT`], or refused for too many outliers or as a
//!    misfit), scores the robust LS from four more starts, each on the rows
//!    outside one half of the recording, and from the crude start (the
//!    median residual over the subsample), and runs step 3 again from the
//!    best: a disturbance of a fifth of the rows bends the crude start's
//!    fit into a compromise that keeps it, and one window holds most of it.
//!    A start whose fit leaves out more rows than a calibration may
//!    ([`Thresholds::refuse_outlier_share`]) wins when it scores within
//!    [`AMBIGUOUS_SCORE`] of the best: with a third of the rows displaced,
//!    the honest reading is a refusal, not a compromise that scores as
//!    well.
//!
//! The report says what happened ([`Report::drops`], [`Report::screened`],
//! [`Report::rejected`], [`Report::start`], [`Quality::fit_error`], [`Quality::lack_of_fit`])
//! and [`Selection::classify`] tells, row by row, which rows the fit used.
//!
//! # Around the fit
//!
//! [`collector`] gathers samples one at a time on the device, with
//! coverage and progress; [`background`] calibrates from ordinary use,
//! without a calibration dance, in slices of bounded work, and follows a
//! moved hard iron; [`offsets`] re-estimates the hard iron alone
//! when the soft iron is known, from a part of the sphere; [`planar`]
//! gives a heading-only calibration to a device that turns about one axis
//! (a car, a boat), which the three-dimensional fit refuses as planar;
//! [`SampleStore`] is a plain fixed-capacity store;
//! [`persist`] stores a calibration as 92 checksummed bytes.
//!
//! # Cost
//!
//! LS9 + ADC2 on 1000 `[i16; 3]` samples in `f32` on a Cortex-M4F: about
//! 400 000 instructions on clean samples (two passes over the samples for
//! the fit, one for the scan and one for the figures); 0.7-1.6 M on samples
//! with 10 % of the rows contaminated, and about 8.3 M when a result in
//! doubt runs the window starts (a third of the rows displaced); about
//! 46 KB of flash and 4 KB of stack. A [`Config`] known at compile time links only its method and LS
//! variant.
//!
//! # Features
//! - `all-methods` (default): `adc1`, `adc2-iter`, `submle` (the
//!   methods) and `svd10`, `lg10` (the LS variants). LS, LS9 and
//!   ADC2 are always there. Firmware that picks the method at run time
//!   links only the enabled ones (`default-features = false`); asking for
//!   one left out is [`Error::NotEnabled`]. A constant [`Config`] links
//!   only its own method either way.
//! - `defmt`: `defmt::Format` for [`Calibration`], [`Fit`], [`Report`],
//!   [`Quality`], [`Selection`] (in `f32` and `f64`), [`Error`],
//!   [`Method`], [`LsVariant`], [`Warning`], [`Warnings`] (by name),
//!   [`Drops`], [`Rule`], [`SampleClass`], [`Thresholds`] and the
//!   collector's `Offer` and `Progress`.
//! - `serde`: `Serialize` and `Deserialize` for [`Calibration`] as
//!   `{"hard_iron": [..], "soft_iron": [[..], [..], [..]], "field_strength": ..}`
//!   (`W` by rows; the field strength is recomputed on reading, which
//!   validates as [`Calibration::new`] does).
//! - `nalgebra`: conversions for host code that computes with `nalgebra`
//!   0.35 (`Calibration::hard_iron_vector` and the like, [`Sample`] for
//!   `nalgebra::Vector3`). Without it no `nalgebra` type is in the API.
//!
//! # Not supported
//! Online (recursive) estimation: every method runs on a stored batch.
//! Temperature compensation, and sensor models beyond `y = T h + b + e`.
//! Outlier handling for subMLE beyond the drop rules and the screening (its
//! cost changes with the weights between its own cost evaluations).
//!
//! # Source layout
//! One file per step of Algorithm 1: `rules.rs` and `normalize.rs` (step
//! 1), `moments.rs` and `ellipsoid.rs` (2), `artificial.rs` (3),
//! `quasi_newton.rs` and `methods/` (4), `quality.rs` (5), `calibration.rs`
//! (the result); `screen.rs` and `robust.rs` for outliers.

#![no_std]
// Denied, not forbidden: the one exception is the FPU square root of
// `real.rs` (hard-float ARM only), with its measured reason beside it.
#![deny(unsafe_code)]
#![deny(missing_docs)]
// `!(x > 0)` is deliberate throughout: unlike `x <= 0` it is also true for
// NaN, so a NaN never passes a validity check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Without every method, the helpers only the optional methods use (the
// Anderson step, the dense solves, eigenvectors) are dead code.
#![cfg_attr(not(feature = "all-methods"), allow(dead_code, unused_imports))]

pub mod align;
mod artificial;
pub mod background;
mod calibration;
pub mod collector;
#[cfg(feature = "defmt")]
mod defmt_impls;
mod ellipsoid;
mod error;
pub mod heading;
mod histogram;
mod linalg;
mod methods;
mod moments;
mod normalize;
pub mod offsets;
pub mod persist;
pub mod planar;
pub mod quality;
mod quasi_newton;
mod real;
mod robust;
mod rules;
pub mod runs;
mod sample;
mod screen;
#[cfg(test)]
mod test_rng;

/// The crate README's example runs as a doctest.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
struct ReadmeDoctests;

pub use calibration::Calibration;
pub use ellipsoid::LsVariant;
pub use error::{Error, Figure};
pub use methods::{Method, OUTLIER_CUT};
pub use normalize::MIN_SAMPLES;
use quality::Figures;
pub use quality::{Quality, RowCounts, Thresholds, Warning, Warnings};
pub use real::Real;
pub use rules::{Drops, Rule, SampleClass, Selection};
pub use runs::Runs;
pub use sample::{Sample, SampleStore};
pub use screen::{CLIP_HINT_ROWS, SCREEN_RADIUS, SUBSAMPLE_ROWS};

/// Pieces of the pipeline for this repository's benchmarks and tests.
/// Not part of the API: anything here may change or go in any release.
#[doc(hidden)]
pub mod __unstable {
    pub use crate::artificial::Stats;
    pub use crate::ellipsoid::{fit_scatter, Ellipsoid};
    pub use crate::methods::adc2;
    pub use crate::moments::Moments;
    pub use crate::normalize::Normalization;
}

/// What to run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Config {
    /// The method (default [`Method::Adc2`]).
    pub method: Method,
    /// The LS variant of step 1 (default [`LsVariant::Ls9`]).
    pub ls: LsVariant,
    /// Iteration cap of each quasi-Newton solve (default 50). ADC2 takes
    /// 2-4: with the exact line search on its quadratic cost, whose Hessian
    /// has four distinct eigenvalues, BFGS ends in at most four steps.
    /// subMLE takes 10-20.
    pub max_iterations: u32,
    /// Cap on the data passes of [`Method::Adc2Iterated`] (default 50;
    /// it needs 5-12, more on partial coverage). Hitting it is reported as
    /// [`Warning::PassCap`].
    pub max_passes: u32,
    /// Stop tolerance of [`Method::Adc2Iterated`] on the gauge-free change
    /// of a pass, `max|dM| rho^2 + max|db| / rho`; `None` (or a value that
    /// is not positive and finite) is `1e-6` in `f64` and `1e-5` in `f32`.
    pub pass_tolerance: Option<f64>,
    /// Per-sample noise covariance `Sigma`, sensor units squared, for
    /// [`Method::Adc1`] (when `None`, it is estimated from the LS residuals,
    /// the paper's procedure) and for the spread check
    /// ([`Warning::LowSpread`]).
    pub noise_covariance: Option<[[f64; 3]; 3]>,
    /// The local field strength the calibration should find, sensor units,
    /// when known (e.g. from a geomagnetic model): a fit whose
    /// `field_strength` is off by more than 25 % is refused
    /// ([`Error::FieldStrengthMismatch`]). It is the only check that catches
    /// a small cap of directions fitted by a too-small sphere.
    pub expected_field_strength: Option<f64>,
    /// Outlier handling (default `true`): the glitch drop rules, screening,
    /// the robust LS start and 0/1 weights on every pass (see
    /// [`robust`](crate#outliers)), and the refusals
    /// [`Error::TooManyOutliers`] and [`Error::SystematicMisfit`]. `false`
    /// trusts every finite row: the plain methods of the paper, with the
    /// same estimates as before outlier handling existed (rows too large
    /// for the working precision are still dropped, and a fit error above
    /// the limit still refuses: [`Error::NoSphere`]).
    pub robust: bool,
    /// The judging limits (default [`Thresholds::DEFAULT`], the measured
    /// constants of [`quality`]).
    pub thresholds: Thresholds,
}

impl Config {
    /// The defaults: ADC2 from LS9, outlier handling on, the measured
    /// thresholds (a `const`, for `..Config::DEFAULT` in constants).
    pub const DEFAULT: Self = Self {
        method: Method::Adc2,
        ls: LsVariant::Ls9,
        max_iterations: 50,
        max_passes: 50,
        pass_tolerance: None,
        noise_covariance: None,
        expected_field_strength: None,
        robust: true,
        thresholds: Thresholds::DEFAULT,
    };
}

impl Default for Config {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// How a calibration was obtained, and how well it fits.
///
/// Every row of the input is counted once:
/// `samples_used + samples_dropped + screened + rejected` is the input's
/// length.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Report<T: Real> {
    /// The method that ran.
    pub method: Method,
    /// The LS variant of step 1.
    pub ls: LsVariant,
    /// Quasi-Newton iterations, summed over all solves (0 for [`Method::Ls`]).
    pub iterations: u32,
    /// Passes over the samples after the LS fit: 1 for ADC1 and ADC2, one
    /// per fixed-point step for iterated ADC2, one per cost evaluation for
    /// subMLE; for [`Method::Ls`] 1 with [`Config::robust`] (ADC2's first
    /// pass, which judges the fit's residuals and shape), else 0.
    pub passes: u32,
    /// Passes over the samples of the outlier handling: screening and the
    /// robust LS refits (0 when the plain fit was clean).
    pub robust_passes: u32,
    /// Rows the final fit used.
    pub samples_used: usize,
    /// Rows dropped by the rules, all rules together ([`Report::drops`]).
    pub samples_dropped: usize,
    /// Rows dropped by each rule.
    pub drops: Drops,
    /// Rows kept by the rules but screened out: too far from the others.
    pub screened: usize,
    /// Rows kept and inside the screening, rejected by their residual or
    /// left out beside a run of rows rejected by theirs ([`runs`]).
    pub rejected: usize,
    /// Of the rejected rows, those left out beside a run although their
    /// residual is within the cut (not outliers: the outlier share leaves
    /// them out).
    pub beside_runs: usize,
    /// RMS of `|W (y - b)| - 1` over the rows used.
    pub radial_rms: T,
    /// The figures behind the checks.
    pub quality: Quality<T>,
    /// What the caller should know but that did not refuse the fit.
    pub warnings: Warnings,
    /// Which rows the fit used: classifies any row afterwards
    /// ([`Selection::classify`]).
    pub selection: Selection<T>,
    /// The robust LS's start: 0 for the crude start on every row, `k` in
    /// `1..=4` for the rows outside window `k` ([`Report::start_window`]),
    /// when the first result was in doubt (its lack of fit beyond
    /// [`DOUBT_LACK_OF_FIT`]) and the fit from those rows scored best (the
    /// smallest median residual over every row, [`AMBIGUOUS_SCORE`]).
    pub start: u8,
}

impl<T: Real> Report<T> {
    /// The rows the robust LS's start left out ([`Report::start`]): half
    /// of the rows, from `(k - 1) n / 4` on, wrapping at the end (`n` the
    /// rows calibrated from); none for the crude start.
    ///
    /// ```
    /// # use mag_cal_core::{calibrate, Config};
    /// # let samples: Vec<[f32; 3]> = (0..400)
    /// #     .map(|i| {
    /// #         let (t, p) = (i as f32 * 2.4, (i as f32 / 400.0 * 2.0 - 1.0).acos());
    /// #         [300.0 * p.sin() * t.cos(), 300.0 * p.sin() * t.sin(), 300.0 * p.cos()]
    /// #     })
    /// #     .collect();
    /// let fit = calibrate::<f32, _>(&samples, &Config::default())?;
    /// // Clean samples: the plain fit, no robust start at all.
    /// assert_eq!(fit.report.start, 0);
    /// assert!(fit.report.start_window().is_empty());
    /// # Ok::<(), mag_cal_core::Error>(())
    /// ```
    pub fn start_window(&self) -> Runs {
        let rows = self
            .samples_used
            .saturating_add(self.samples_dropped)
            .saturating_add(self.screened)
            .saturating_add(self.rejected);
        robust::window(usize::from(self.start), rows)
    }
}

/// A calibration and its report.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Fit<T: Real> {
    /// The calibration.
    pub calibration: Calibration<T>,
    /// How it was obtained.
    pub report: Report<T>,
}

/// Calibrates from a slice of raw samples, in precision `T`.
///
/// Non-finite samples are skipped and counted. Passes over the data:
/// validation and normalisation, moments, then (except [`Method::Ls`]) the
/// method's own passes, and finally one pass for the quality figures. On
/// contaminated data ([`Config::robust`]), screening and robust LS passes
/// come before the method's (see [the crate docs](crate#outliers)). The
/// figures are then judged in one place ([`quality`]): planar, shapeless,
/// outlier-ridden, ambiguous, too eccentric or poorly covered data are
/// refused with a specific [`Error`], milder findings reported as
/// [`Warning`]s.
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

/// A plain fit is taken as the robust one when no row's residual exceeds
/// this many robust standard deviations, in the method's pass and in the
/// final pass. Beyond it a row cannot be Gaussian noise of that sigma
/// (probability 6e-7 a row); below it, the 0/1 weights at
/// [`OUTLIER_CUT`] would leave out rows that move the fit by less than the
/// noise. Clean data then pay no robust pass.
pub const CLEAN_LIMIT: f64 = 5.0;

/// A plain fit is taken as the robust one only when the RMS of its radial
/// residuals is at most this many times their robust sigma: about 1 for
/// Gaussian noise (0.8 for quantisation), more when a share of the rows
/// lies off the ellipsoid. (Residuals at the level of rounding, an RMS
/// below the square root of the type's epsilon, are not judged by it.)
pub const CLEAN_TAIL: f64 = 1.25;

/// A plain fit is not taken when the kurtosis `n sum e^4 / (sum e^2)^2`
/// of the algebraic residuals `e = |u|^2 - 1` under its LS start (in the
/// method's artificial-data pass) exceeds this: about 3 for Gaussian
/// noise, below 2 for quantisation; 10 % of the rows displaced by 0.3 of
/// the field give about 10. The robust path then starts without the plain
/// method's solve and final pass.
pub const CLEAN_KURTOSIS: f64 = 6.0;

/// Nor when the skewness `sqrt(n) sum e^3 / (sum e^2)^(3/2)` of the same
/// residuals is below minus this: a share of the rows pulled inwards, as
/// an axis clipped on some reads pulls them (-1.5 when 30 % of the rows
/// are; the robust path's screening then finds the clip levels). Noise
/// skews the other way (`e = 2 n + n^2` for a radial noise `n`), and so do
/// rows displaced outwards, which the kurtosis sees.
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
pub const CLEAN_SHAPE: f64 = 0.3;

/// [`calibrate`] with the LS solve and the method's step resolved.
fn pipeline<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    ls_solve: ellipsoid::Solve<T>,
    step: methods::Step<T, S>,
) -> Result<Fit<T>, Error> {
    let scan = normalize::scan::<T, S>(samples, config.robust)?;
    let gate = rules::Gate {
        rules: scan.rules,
        screen: None,
    };
    if config.robust && screen::clip_hint(samples, &gate, scan.used) {
        // A clip level may bend the plain fit unseen: screening finds it.
        return robust_path(samples, config, &scan, ls_solve, step);
    }
    // The plain result is returned as it is, or not at all: this frame
    // then holds no second fit under the robust path (224 bytes of stack).
    let mut clean = false;
    let plain = plain_path(samples, config, &scan, ls_solve, step, &mut clean);
    if clean || !config.robust {
        return plain;
    }
    robust_path(samples, config, &scan, ls_solve, step)
}

/// What the steps before the method leave for it and for the judging.
struct Start<'r, T: Real> {
    /// The robust LS's start ([`Report::start`]).
    start: u8,
    norm: normalize::Normalization<T>,
    ls: ellipsoid::Ellipsoid<T>,
    weights: methods::Weights<'r, T>,
    robust_passes: u32,
}

/// The plain pipeline: every row the scan kept, weight 1. Returns the fit
/// and sets `clean` when it is clean ([`CLEAN_LIMIT`], [`CLEAN_TAIL`]). Out of line, as the robust
/// path: inlined, both paths' locals would share `pipeline`'s frame.
#[inline(never)]
fn plain_path<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    scan: &normalize::Scan<T>,
    ls_solve: ellipsoid::Solve<T>,
    step: methods::Step<T, S>,
    clean: &mut bool,
) -> Result<Fit<T>, Error> {
    let mut figures = Figures::new(scan, config, false);
    let start = plain_start(samples, config, scan, ls_solve, &mut figures)?;
    let est = method_step(samples, config, &start, step, &figures)?;
    let clean_limit = |max: T, sigma: T| max <= sigma * T::lit(CLEAN_LIMIT);
    let method_clean = est
        .max_residual
        .zip(est.sigma)
        .is_none_or(|(m, s)| clean_limit(m, s));
    if config.robust && !method_clean {
        // Not clean, and this fit will not be returned: no final pass
        // (about 120 instructions a row on a Cortex-M4F).
        return Err(Error::OutOfRange);
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
    *clean = is_clean;
    Ok(fit)
}

/// The plain path up to the method: the moments and the LS fit, and the
/// figures they give (into `figures`). Out of line, as [`robust_start`]:
/// the moments take stack only until the method starts.
#[inline(never)]
fn plain_start<T: Real, S: Sample>(
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
    if config.robust && moments.kurtosis() > T::lit(normalize::GROSS_KURTOSIS) {
        // Gross outliers: not worth a plain fit (the caller screens).
        return Err(Error::OutOfRange);
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
                .then(|| (T::lit(CLEAN_KURTOSIS), T::lit(CLEAN_SKEWNESS))),
        },
        robust_passes: 0,
    };
    Ok(start)
}

/// The result of the robust path is in doubt when its lack of fit exceeds
/// this (0.4 of the default refusal limit,
/// [`quality::REFUSE_LACK_OF_FIT`]), or when it is refused for too many
/// outliers or as a systematic misfit: the robust LS may have settled on a
/// compromise that a long disturbance bent. The path then tries the window
/// starts ([`Report::start`]). Measured on the contamination study
/// (f32, 256 runs a cell): 0.003 and 0.004 left 22 of 18 688 runs silently
/// wrong, 0.005 24 (53 without the window starts); of the accepted fits
/// with a tenth of the rows displaced as a patch or by a moving
/// disturbance 1-2 % exceed 0.003, the other kinds none. Real recordings
/// with some model error lie near it (lack of fit 0.003-0.006): at 0.003
/// `mag3_raw_541.csv` (0.0032) and `imu_gnss_1252.csv` (0.0031) were in
/// doubt too, and with a magnet passing the first (a CLI test) a window
/// start that scored a few percent better left the hard iron 0.8 % of the
/// field (28 counts) from the fit of the clean rows, against 0.02 %.
pub const DOUBT_LACK_OF_FIT: f64 = 0.004;

/// Among the window starts of a result in doubt, a start whose fit leaves
/// out more than [`Thresholds::refuse_outlier_share`] of the rows is
/// preferred to the best-scoring one when its score (the median residual)
/// is within this factor of the best: a displaced third of the recording
/// lets the robust LS either leave it out (and then the result is refused
/// for too many outliers) or bend into a compromise whose residuals spread
/// over every row, with a median as low. Measured on the contamination
/// study (f32, 256 runs a cell): with a third of the rows displaced as a
/// patch the compromise left 12 runs accepted and silently wrong, 2 with
/// this preference (the others refused, too many outliers); in all, 22 of
/// 18 688 runs were silently wrong before it and 12 after, and no cell up
/// to a fifth of the rows changed. 1.1 left 17 of them, 1.5 as 1.25, and 2
/// refused 2 % of the runs with a fifth of the rows displaced as a patch.
pub const AMBIGUOUS_SCORE: f64 = 1.25;

/// The robust pipeline (section 14 of the design document): screening, the
/// robust LS fit, the method with 0/1 weights. When the result is in doubt
/// ([`DOUBT_LACK_OF_FIT`]), the robust LS from each of the window starts
/// ([`robust::STARTS`]) and from the crude start is scored (the median
/// residual over the subsample, [`robust::window`], [`AMBIGUOUS_SCORE`]),
/// and the path runs
/// again from the window start that scored best; when the crude start
/// scores best, the first run's fit stands. The screening does not depend
/// on the start: the scoring makes it once for every start, and each run
/// makes its own, so that no screening is held on the stack while a
/// method runs (only the first run's fit is kept while the starts are
/// scored and the second run goes). Out of line (see [`plain_path`]).
#[inline(never)]
fn robust_path<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    scan: &normalize::Scan<T>,
    ls_solve: ellipsoid::Solve<T>,
    step: methods::Step<T, S>,
) -> Result<Fit<T>, Error> {
    let mut first = Attempt::default();
    let mut fit = robust_attempt(samples, config, scan, ls_solve, step, 0, 0, &mut first);
    if !first.doubt {
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

/// The start of the robust LS ([`robust::window`]) whose fit scores best,
/// if any fits; adds the passes the scoring took to `passes`. One screening
/// for every start, held in this frame, which takes the place of the
/// robust start's ([`start_from`] is inlined into the scorer): a result in
/// doubt takes 4 068 B of stack (the footprint's `-doubtful` run; 4 092 B
/// with the scoring inlined into [`robust_path`] and a screening for each
/// start; 4 116 B with this function out of line and no screening in it),
/// and `robust-patch-0.3` 7.38 M instructions instead of 8.26 M.
#[inline(never)]
fn best_start<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    scan: &normalize::Scan<T>,
    ls_solve: ellipsoid::Solve<T>,
    passes: &mut u32,
) -> Option<usize> {
    // The screening does not depend on the start: made once for all.
    let screening = screen::screen(samples, scan, config.thresholds.refuse_fit_error).ok()?;
    *passes = passes.saturating_add(screening.passes);
    // The start that scores best, and its score.
    let mut best: Option<(usize, T)> = None;
    for k in 0..=robust::STARTS {
        let (score, made) = robust_score(samples, config, scan, &screening, ls_solve, k);
        *passes = passes.saturating_add(made);
        if let Some(s) = score.filter(|&s| best.is_none_or(|(_, b)| s < b)) {
            best = Some((k, s));
        }
    }
    best.map(|(k, _)| k)
}

/// What [`robust_attempt`] tells its caller beside the fit.
#[derive(Default)]
struct Attempt {
    /// The result is in doubt: its lack of fit is beyond
    /// [`DOUBT_LACK_OF_FIT`], or it is refused for it or for too many
    /// outliers.
    doubt: bool,
    /// The robust passes it made (with those before it).
    passes: u32,
}

/// One run of the robust path from start `k` ([`robust::window`]), with
/// `before` robust passes made before it. The doubt is judged on its
/// figures, not on the fit: the fit then goes straight to the caller (a
/// fit held here while the caller returns it took 256 bytes of stack). Out
/// of line: the second run's frame takes the place of the first's.
#[inline(never)]
#[allow(clippy::too_many_arguments)]
fn robust_attempt<T: Real, S: Sample>(
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
    let mut start = robust_start(samples, config, scan, ls_solve, &mut figures, &mut runs, k)?;
    start.robust_passes = start.robust_passes.saturating_add(before);
    outcome.passes = start.robust_passes;
    let fit = robust_rest(samples, config, &start, step, &mut figures);
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
/// the passes it took: the median residual ([`robust::score`]), divided by
/// [`AMBIGUOUS_SCORE`] when the fit leaves out more than
/// [`Thresholds::refuse_outlier_share`] of the rows. Out of line, as
/// [`robust_attempt`] (the discount inside the scoring loop took 32 bytes
/// of the robust path's frame, on every contaminated calibration).
#[inline(never)]
fn robust_score<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    scan: &normalize::Scan<T>,
    screening: &screen::Screening<T>,
    ls_solve: ellipsoid::Solve<T>,
    k: usize,
) -> (Option<T>, u32) {
    let mut figures = Figures::new(scan, config, true);
    let mut runs = runs::Runs::NONE;
    let Ok(start) = start_from(
        samples,
        config,
        screening,
        0,
        ls_solve,
        &mut figures,
        &mut runs,
        k,
    ) else {
        return (None, 0);
    };
    let every = screen::stride(figures.valid);
    let gate = &start.weights.gate;
    let share = T::from_single(config.thresholds.refuse_outlier_share);
    let score = robust::score(samples, &start.norm, gate, &start.ls, every).map(|s| {
        if s.beyond > share {
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
fn robust_rest<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    start: &Start<T>,
    step: methods::Step<T, S>,
    figures: &mut Figures<T>,
) -> Result<Fit<T>, Error> {
    let est = method_step(samples, config, start, step, figures)?;
    finish_fit(samples, config, start, &est, figures)
}

/// [`finish`] for the robust path, which needs only the fit. Out of line:
/// the finished fit then takes stack in this frame only, not in the
/// robust path's while its start and the method run.
#[inline(never)]
fn finish_fit<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    start: &Start<T>,
    est: &methods::Estimate<T>,
    figures: &mut Figures<T>,
) -> Result<Fit<T>, Error> {
    finish(samples, config, start, est, figures).map(|done| done.fit)
}

/// The robust path up to the method: the screening and the robust LS fit,
/// and the figures they give (into `figures`). Out of line: their moments and fits take
/// stack only until the method starts.
#[inline(never)]
fn robust_start<'r, T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    scan: &normalize::Scan<T>,
    ls_solve: ellipsoid::Solve<T>,
    figures: &mut Figures<T>,
    runs: &'r mut runs::Runs,
    k: usize,
) -> Result<Start<'r, T>, Error> {
    let screening = screen::screen(samples, scan, config.thresholds.refuse_fit_error)?;
    let passes = screening.passes;
    start_from(
        samples, config, &screening, passes, ls_solve, figures, runs, k,
    )
}

/// [`robust_start`] from a screening made before, counting `before`
/// robust passes before it. Inlined: out of line, its frame would sit
/// below the screening's.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn start_from<'r, T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    screening: &screen::Screening<T>,
    before: u32,
    ls_solve: ellipsoid::Solve<T>,
    figures: &mut Figures<T>,
    runs: &'r mut runs::Runs,
    k: usize,
) -> Result<Start<'r, T>, Error> {
    let window = &robust::window(k, samples.len());
    figures.drops = screening.drops;
    figures.valid = screening.valid;
    let gate = rules::Gate {
        rules: screening.rules,
        screen: Some(screening.ball),
    };
    let crude = robust::crude_moments(samples, screening, &gate, window);
    figures.flatness = Some(quality::flatness(&crude, crude.count())?);
    let fitted = match robust::robust_ls(samples, screening, &gate, &crude, ls_solve, runs, window)
    {
        Ok(f) => f,
        Err(e) => {
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

/// A fit and what decides whether the plain one is clean.
struct Finished<T: Real> {
    fit: Fit<T>,
    /// The final pass's largest residual.
    final_max: T,
    /// The lack of fit is beyond its limit (`Figures::misfit`).
    misfit: bool,
    /// The LS fit alone: its lack of shape is beyond [`CLEAN_SHAPE`] fit
    /// errors.
    misshapen: bool,
    /// The radial residuals have heavier tails than noise: their RMS is
    /// above [`CLEAN_TAIL`] robust sigmas, and above the level of
    /// rounding (`sqrt(eps)` of the field), where the tails are the
    /// rounding's own.
    heavy_tails: bool,
}

/// The method from the start; a failure is judged on the figures so far.
/// Out of line, as [`finish`]: the method's passes and the final pass then
/// take their stack one after the other, not one under the other.
#[inline(never)]
fn method_step<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    start: &Start<T>,
    step: methods::Step<T, S>,
    figures: &Figures<T>,
) -> Result<methods::Estimate<T>, Error> {
    step(samples, &start.norm, &start.ls, config, &start.weights)
        .map_err(|e| judge_failure(figures, config, e))
}

/// The final pass after the method's estimate `est`, and the judging.
#[inline(never)]
fn finish<T: Real, S: Sample>(
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
    let sigma = match (start.weights.sigma, est.sigma) {
        (None, _) => None,
        (Some(_), Some(s)) => Some(s),
        (Some(s), None) if config.method == Method::Ls => Some(s),
        (Some(_), None) => None,
    };
    let limit = sigma.map(|s| s * T::lit(methods::OUTLIER_CUT));
    let last = match quality::final_pass(
        samples,
        norm,
        &est.centre,
        &est.w,
        est.directions,
        &start.weights.gate,
        start.weights.runs,
        limit,
    ) {
        Ok(last) => last,
        Err(e) => return Err(judge_failure(figures, config, e)),
    };
    figures.used = Some(last.used);
    // The rows of the spans beside runs, which the passes skipped: those
    // the gate passes count as rejected, and those of them within the cut
    // are no outliers.
    let (gate, runs) = (&start.weights.gate, start.weights.runs);
    let mut spanned = 0usize;
    figures.beside = 0;
    runs.visit(samples, |s, prev| {
        if let Some(y) = gate.pass(s, prev) {
            spanned += 1;
            let within = limit.is_none_or(|l| (calibration.map(y).norm() - T::one()).abs() <= l);
            figures.beside += usize::from(within);
        }
    });
    figures.coverage = Some(last.coverage);
    figures.gram_condition = Some(last.gram_condition);
    figures.radial_rms = Some(last.radial_rms);
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
    figures.fit_error = Some(fit_error);
    figures.lack_of_fit = Some(last.lack_of_fit);
    figures.misfit_significant = last.misfit_significant;
    // Only the robust path's pass sums the cubes.
    if figures.robust {
        figures.skewness = last.skewness;
    }
    figures.field_deviation = config
        .expected_field_strength
        .map(|expected| calibration.field_strength() / T::lit(expected) - T::one());
    let warnings = quality::judge(figures, &config.thresholds)?;
    let to_sensor = |b: &rules::Ball<T>| (b.centre, b.radius_sq.sqrt());
    let quality = Quality {
        flatness: figures.flatness.unwrap_or(T::zero()),
        quadric_gap: figures.quadric_gap.unwrap_or(T::zero()),
        distortion,
        coverage: last.coverage,
        gram_condition: last.gram_condition,
        fit_error,
        lack_of_fit: last.lack_of_fit,
        outlier_share: figures.outlier_share().unwrap_or(T::zero()),
        skewness: figures.skewness,
    };
    let report = Report {
        method: config.method,
        ls: config.ls,
        iterations: est.iterations,
        passes: est.passes,
        robust_passes: start.robust_passes,
        samples_used: last.used,
        samples_dropped: figures.drops.total(),
        drops: figures.drops,
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
            clip_levels: start
                .weights
                .gate
                .rules
                .clip
                .map(|axis| axis.map(|level| Some(level).filter(|l| l.abs() < T::MAX))),
            screen: start.weights.gate.screen.as_ref().map(to_sensor),
            residual_limit: limit,
            runs: *runs,
        },
        start: start.start,
    };
    Ok(Finished {
        fit: Fit {
            calibration,
            report,
        },
        final_max: last.max_residual,
        misfit: figures.misfit(&config.thresholds),
        misshapen: config.method == Method::Ls
            && last.lack_of_shape > last.fit_error * T::lit(CLEAN_SHAPE),
        heavy_tails: last.radial_rms > last.fit_error * T::lit(CLEAN_TAIL)
            && last.radial_rms * last.radial_rms > T::EPSILON,
    })
}

/// A step failed with `e`: the figures computed so far may explain why
/// (planar data, a cloud that is no shell); if they refuse, that refusal is
/// the answer, else `e`.
fn judge_failure<T: Real>(figures: &Figures<T>, config: &Config, e: Error) -> Error {
    match quality::judge(figures, &config.thresholds) {
        Err(refusal) => refusal,
        Ok(_) => e,
    }
}

impl<T: Real> Figures<T> {
    fn new(scan: &normalize::Scan<T>, config: &Config, robust: bool) -> Self {
        let low_spread = config.noise_covariance.is_some_and(|c| {
            // In T: no f64 arithmetic (soft-float on a Cortex-M4F) in the
            // f32 path.
            let var = (T::lit(c[0][0]) + T::lit(c[1][1]) + T::lit(c[2][2])) / T::lit(3.0);
            scan.norm.scale < T::from_single(config.thresholds.warn_spread_over_noise) * var.sqrt()
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

/// Step 1 on the moments: the LS fit, and the quadric gap of the same
/// scatter (judged after the method, against its radial RMS; see
/// [`quality::REFUSE_QUADRIC_GAP`]). Out of line, so the 10x10 scatter
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
