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
//!    `f32` at offsets of tens of thousands of counts. In the same pass,
//!    **still periods** ([`Config::still`]): a time run of rows within six
//!    noise sigmas of its moving average (the noise from the rows' second
//!    differences), holding a tenth of the rows, is a device lying still;
//!    its ball ([`Dwell`], at most 3) is set aside in every later pass, so
//!    that a log that starts and ends still calibrates like its motion
//!    ([`SampleClass::Dwell`], [`Report::dwell`]; too few rows left:
//!    [`Error::HardlyMoved`]).
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
//!    quadratic: solved in closed form on the statistics, a 4x4 Cholesky
//!    solve, no further pass). Iterated ADC2 repeats steps 3-4 from each new estimate
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
//!    shape, `CLEAN_SHAPE`); a plain
//!    attempt whose LS residuals already show heavy tails
//!    (`CLEAN_KURTOSIS`), rows pulled inwards (`CLEAN_SKEWNESS`) or a
//!    residual beyond the limit stops before its solve or its final pass;
//!    and none is made when an axis's extreme is shared by
//!    `CLIP_HINT_ROWS` rows of a subsample (a clip level, which
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
//!    one use a fixed subsample of about `SUBSAMPLE_ROWS` rows (every
//!    `k`-th row), so their cost hardly grows with `n`. Where consecutive
//!    rows lie far beyond the cut (a disturbance passing), the rows beside
//!    them, displaced less, are left out too ([`runs`]);
//! 4. when that result is in doubt (lack of fit beyond
//!    `DOUBT_LACK_OF_FIT`, or refused for too many outliers or as a
//!    misfit), scores the robust LS from four more starts, each on the rows
//!    outside one half of the recording, and from the crude start (the
//!    median residual over the subsample), and runs step 3 again from the
//!    best: a disturbance of a fifth of the rows bends the crude start's
//!    fit into a compromise that keeps it, and one window holds most of it.
//!    A start whose fit leaves out more rows than a calibration may
//!    ([`Thresholds::refuse_outlier_share`]) wins when it scores within
//!    `AMBIGUOUS_SCORE` of the best: with a third of the rows displaced,
//!    the honest reading is a refusal, not a compromise that scores as
//!    well.
//!
//! The report says what happened ([`Report::drops`], [`Report::screened`],
//! [`Report::rejected`], [`Report::start`], [`Quality::fit_error`], [`Quality::lack_of_fit`])
//! and [`Selection::classify`] tells, row by row, which rows the fit used.
//!
//! Steps 2-4 are the cargo feature `robust` (default). Without it (an
//! opt-in for parts where flash decides: LS9 + ADC2 on a Cortex-M4F then
//! takes about 20 KB of flash instead of 33 KB and 2.9 KB of stack instead
//! of 3.5 KB, `cd firmware-example && bash bench.sh footprint`; each pass
//! keeps its gated loop only, and its instructions are not counted, as the
//! bench needs `robust`)
//! only the plain pipeline is
//! compiled: step 1's
//! rules, then the plain fit, whose answer, a calibration or a refusal,
//! is returned as it is. It keeps the glitch rules (with
//! [`Config::robust`], still the default: zero rows, rails and repeats
//! are dropped and counted; without the screening no clip levels are
//! found) and every refusal of degenerate data ([`Error::Planar`],
//! [`Error::NoSphere`], [`Error::AmbiguousQuadric`],
//! [`Error::ExtremeDistortion`], [`Error::PoorCoverage`],
//! [`Error::FieldStrengthMismatch`], ...), and it **trusts every row the
//! rules keep**: a displaced stretch of rows, a magnet passing or an axis
//! clipped below the rails bends the fit instead of being left out, and
//! [`Error::TooManyOutliers`], [`Error::SystematicMisfit`] and
//! [`Error::FilledCloud`] are never returned. On data the robust build
//! finds clean (no robust pass, [`Report::robust_passes`] 0) the two
//! builds give the same answer, bit for bit: it is the same plain path.
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
//! 626 000 instructions on clean samples (two passes over the samples for
//! the fit, one for the scan and one for the figures); 0.9-1.9 M on samples
//! with 10 % of the rows contaminated, and about 8.1 M when a result in
//! doubt runs the window starts (a third of the rows displaced); about
//! 33 KB of flash and 3.5 KB of stack (`cd firmware-example && bash
//! bench.sh all`). A [`Config`] known at compile time links only its method and LS
//! variant.
//!
//! # Features
//! - `robust` (default): outlier handling (see [Outliers](#outliers)):
//!   the screening, the robust LS refits, the runs, the window starts,
//!   and [`planar`], whose fit screens. Off, the plain pipeline alone,
//!   trusting every row the rules keep; [`Config::robust`] then selects
//!   the glitch rules only. The outlier constants ([`CLEAN_LIMIT`],
//!   [`SCREEN_RADIUS`], ...) are not compiled either.
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
//! Temperature compensation, and sensor models beyond `y = T h + b + e`.
//! Outlier handling for subMLE beyond the drop rules and the screening (its
//! cost changes with the weights between its own cost evaluations). A
//! device that turns about one axis only gets a heading calibration
//! ([`planar`]), not the three-dimensional one.
//!
//! # Source layout
//! - `pipeline/`: the sequencing only: `plain.rs`, `robust.rs` (the robust
//!   path and its window starts), `finish.rs` (the method and the final
//!   pass, then the judging).
//! - `steps/`: one file per step of Algorithm 1: `rules.rs` and
//!   `normalize.rs` (the scan), `moments.rs` and `ellipsoid.rs` (the LS
//!   fit), `artificial.rs` (the artificial data), `methods/` (the
//!   re-estimation).
//! - `robust/`: the outlier handling: `screen.rs`, `refit.rs`, `runs.rs`.
//! - `judge/`: the figures, their limits and the judging (`quality.rs`).
//! - `numerics/`: `real.rs`, `linalg.rs`, `histogram.rs`, `quasi_newton.rs`.
//! - `device/`: the modules around the fit: `collector.rs`,
//!   `background.rs`, `offsets.rs`, `planar.rs`, `heading.rs`, `align.rs`,
//!   `persist.rs`.
//! - `calibration.rs`, `config.rs`, `report.rs`, `error.rs`, `sample.rs`:
//!   the API's types.

#![no_std]
// Denied, not forbidden: the one exception is the FPU square root of
// `real.rs` (hard-float ARM only), with its measured reason beside it.
#![deny(unsafe_code)]
#![deny(missing_docs)]
// `!(x > 0)` is deliberate throughout: unlike `x <= 0` it is also true for
// NaN, so a NaN never passes a validity check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

mod calibration;
mod config;
#[cfg(feature = "defmt")]
mod defmt_impls;
mod device;
mod error;
mod judge;
mod numerics;
mod pipeline;
mod report;
mod robust;
mod sample;
mod steps;
#[cfg(test)]
mod test_support;
mod tuning;

/// The crate README's example runs as a doctest.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
struct ReadmeDoctests;

pub use calibration::Calibration;
pub use config::Config;
#[cfg(feature = "robust")]
pub use device::planar;
pub use device::{align, background, collector, heading, offsets, persist};
pub use error::{Error, Figure};
pub use judge::quality;
pub use judge::quality::{Quality, RowCounts, Thresholds, Warning, Warnings};
pub use numerics::real::Real;
pub use pipeline::calibrate;
pub use report::{Fit, Report};
pub use robust::runs;
pub use robust::runs::Runs;
pub use sample::{Sample, SampleStore};
pub use steps::dwell::Dwell;
pub use steps::ellipsoid::LsVariant;
pub use steps::methods::Method;
pub use steps::normalize::MIN_SAMPLES;
pub use steps::rules::{Drops, Rule, SampleClass, Selection};
pub use tuning::OUTLIER_CUT;
/// The robust path's fixed cuts, for front ends that explain a fit's
/// outliers (every tuning constant, with its evidence, is in the
/// crate-private `tuning` module).
#[cfg(feature = "robust")]
pub use tuning::{CLEAN_LIMIT, CLEAN_TAIL, SCREEN_RADIUS};

/// Pieces of the pipeline for this repository's benchmarks and tests
/// (feature `bench-internals`). Not part of the API: anything here may
/// change or go in any release.
#[cfg(feature = "bench-internals")]
#[doc(hidden)]
pub mod __unstable {
    pub use crate::steps::artificial::Stats;
    pub use crate::steps::ellipsoid::{fit_scatter, Ellipsoid};
    pub use crate::steps::methods::adc2;
    pub use crate::steps::moments::Moments;
    pub use crate::steps::normalize::Normalization;
}
