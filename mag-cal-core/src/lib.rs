//! Allocation-free three-axis magnetometer calibration for microcontrollers.
//!
//! A raw reading `y` of a distorted magnetometer follows
//! `y = T h + b + e`: the unit field direction `h`, turned and scaled by the
//! soft-iron matrix `T`, shifted by the hard-iron offset `b`, plus noise.
//! Calibration finds `b` and `W = T^-1` such that `u = W (y - b)` lies on the
//! unit sphere. Only `M = W^T W` and `b` are determined by the data, so `W`
//! is returned in the canonical symmetric form `M^(1/2)`.
//!
//! The crate implements the paper's Algorithm 1, one module per step (the
//! mathematics is specified in the project's `shared/design/ALGORITHMS.md`):
//!
//! | step | module | what |
//! |---|---|---|
//! | 0 | [`normalize`] | centre and scale the samples (section 2) |
//! | 1 | [`moments`], [`ellipsoid`] | algebraic LS ellipsoid fit from 35 moments, one pass (section 3) |
//! | 2-3 | [`artificial`] | unit "artificial" field vectors `h_i` and sufficient statistics, second pass (section 4) |
//! | 4 | [`quasi_newton`], [`methods`] | ADC2: re-estimate `T`, `b` by BFGS on those statistics (section 5) |
//! | 5 | [`calibration`] | canonical result, [`Calibration::apply`] |
//!
//! Everything runs in `f32` or `f64` through one generic code path
//! ([`Real`]), on the stack, in two passes over the samples (plus one for
//! validation and one for the quality figure), with every loop bounded.
//! No input panics: malformed data ends in an [`Error`].
//!
//! ```
//! use mag_cal_core::{calibrate, Config};
//!
//! // Samples on a shifted, stretched ellipsoid (here generated; in firmware
//! // they come from the sensor, e.g. as `[i16; 3]`).
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
//! let b = fit.calibration.hard_iron();
//! assert!((b.x - 300.0).abs() < 1e-2 && (b.y + 120.0).abs() < 1e-2);
//! let u = fit.calibration.apply(samples[17]);
//! assert!((u.norm() - 1.0).abs() < 1e-4);
//! assert!(fit.report.radial_rms < 1e-4);
//! # Ok::<(), mag_cal_core::Error>(())
//! ```
//!
//! Around the fit: [`collector`] gathers samples one at a time on the
//! device with coverage tracking, [`persist`] stores a calibration as
//! checksummed bytes, [`quality`] holds the degenerate-geometry checks.
//!
//! # Features
//! - `defmt`: derive `defmt::Format` for [`Error`], [`Method`], [`LsVariant`],
//!   [`Warning`], [`Warnings`] and the collector's `Offer` and `Progress`.
//!
//! Beyond ADC2, [`Method`] offers the paper's ADC1 (whose minimiser equals
//! ADC2's, see [`methods::adc1`]) and subMLE baseline, and iterated ADC2,
//! which reaches subMLE's accuracy at a fraction of its cost.
//!
//! # Not supported
//! Online (recursive) estimation: every method runs on a stored batch.
//! Temperature compensation, and sensor models beyond `y = T h + b + e`.

#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]
// `!(x > 0)` is deliberate throughout: unlike `x <= 0` it is also true for
// NaN, so a NaN never passes a validity check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod align;
pub mod artificial;
pub mod calibration;
pub mod collector;
pub mod ellipsoid;
mod error;
pub mod heading;
mod linalg;
pub mod methods;
pub mod moments;
pub mod normalize;
pub mod persist;
pub mod quality;
pub mod quasi_newton;
mod real;
mod sample;
#[cfg(test)]
mod test_rng;

/// The README's example runs as a doctest.
#[cfg(doctest)]
#[doc = include_str!("../../README.md")]
struct ReadmeDoctests;

pub use calibration::Calibration;
pub use ellipsoid::LsVariant;
pub use error::Error;
pub use methods::Method;
pub use nalgebra;
pub use normalize::MIN_SAMPLES;
pub use quality::{Quality, Warning, Warnings};
pub use real::Real;
pub use sample::{Sample, SampleStore};

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
}

impl Default for Config {
    fn default() -> Self {
        Self {
            method: Method::Adc2,
            ls: LsVariant::Ls9,
            max_iterations: 50,
            max_passes: 50,
            pass_tolerance: None,
            noise_covariance: None,
            expected_field_strength: None,
        }
    }
}

/// How a calibration was obtained, and how well it fits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Report<T: Real> {
    /// The method that ran.
    pub method: Method,
    /// The LS variant of step 1.
    pub ls: LsVariant,
    /// Quasi-Newton iterations, summed over all solves (0 for [`Method::Ls`]).
    pub iterations: u32,
    /// Passes over the samples after the LS fit: 1 for ADC1 and ADC2, one
    /// per fixed-point step for iterated ADC2, one per cost evaluation for
    /// subMLE (0 for [`Method::Ls`]).
    pub passes: u32,
    /// Finite samples used.
    pub samples_used: usize,
    /// Non-finite samples skipped.
    pub samples_dropped: usize,
    /// RMS of `|W (y - b)| - 1` over the samples used.
    pub radial_rms: T,
    /// The figures behind the degenerate-geometry checks.
    pub quality: Quality<T>,
    /// What the caller should know but that did not refuse the fit.
    pub warnings: Warnings,
}

/// A calibration and its report.
#[derive(Clone, Copy, Debug, PartialEq)]
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
/// method's own passes, and finally one pass for the quality figures. The
/// degenerate-geometry checks ([`quality`]) refuse planar, ambiguous,
/// too eccentric or poorly covered data with a specific [`Error`], and
/// report milder findings as [`Warning`]s.
///
/// # Flash
/// The method and the LS variant are resolved to functions here, in a
/// small wrapper inlined at the call site; the pipeline takes them as
/// function pointers. With a constant [`Config`] (e.g. `Config::default()`)
/// the optimiser sees which are used and links only those: LS9 + ADC2
/// alone is what firmware pays for (`docs/benchmarks.md`). A `Config`
/// chosen at run time links every method.
#[inline(always)]
pub fn calibrate<T: Real, S: Sample>(samples: &[S], config: &Config) -> Result<Fit<T>, Error> {
    let step: methods::Step<T, S> = match config.method {
        Method::Ls => methods::ls_only,
        Method::Adc1 => methods::adc1::run,
        Method::Adc2 => methods::adc2::run,
        Method::Adc2Iterated => methods::iterated::run,
        Method::SubMle => methods::submle::run,
    };
    pipeline(samples, config, ellipsoid::solver(config.ls), step)
}

/// [`calibrate`] with the LS solve and the method's step resolved.
fn pipeline<T: Real, S: Sample>(
    samples: &[S],
    config: &Config,
    ls_solve: ellipsoid::Solve<T>,
    step: methods::Step<T, S>,
) -> Result<Fit<T>, Error> {
    let scan = normalize::scan::<T, S>(samples)?;
    let norm = scan.norm;
    let mut warnings = Warnings::NONE;
    if scan.dropped > 0 {
        warnings.insert(Warning::NonFiniteDropped);
    }
    if scan.used < quality::WARN_SAMPLES {
        warnings.insert(Warning::FewSamples);
    }
    if let Some(c) = config.noise_covariance {
        // In T: no f64 arithmetic (soft-float on a Cortex-M4F) in the f32 path.
        let var = (T::lit(c[0][0]) + T::lit(c[1][1]) + T::lit(c[2][2])) / T::lit(3.0);
        if norm.scale < T::lit(quality::WARN_SPREAD_OVER_NOISE) * var.sqrt() {
            warnings.insert(Warning::LowSpread);
        }
    }

    let moments = moments::Moments::accumulate(samples, &norm);
    let flatness = quality::flatness(&moments, scan.used)?;
    if !(flatness >= T::lit(quality::REFUSE_FLATNESS)) {
        return Err(Error::Planar);
    }
    if flatness < T::lit(quality::WARN_FLATNESS) {
        warnings.insert(Warning::NearlyPlanar);
    }
    let (ls, quadric_gap) = ls_step(&moments, ls_solve)?;
    let est = step(samples, &norm, &ls, config)?;
    for w in est.warnings.iter() {
        warnings.insert(w);
    }
    let distortion = quality::distortion(&est.w)?;
    if !(distortion <= T::lit(quality::REFUSE_DISTORTION)) {
        return Err(Error::ExtremeDistortion);
    }
    let calibration = Calibration::from_normalised_w(&norm, &est.w, &est.centre)?;
    let last = quality::final_pass(samples, &norm, &est.centre, &est.w, est.directions)?;
    if !(quadric_gap >= T::lit(quality::REFUSE_QUADRIC_GAP))
        && !(last.radial_rms >= T::lit(quality::GAP_NOISE_LIMIT))
    {
        return Err(Error::AmbiguousQuadric);
    }
    if !(quadric_gap >= T::lit(quality::WARN_QUADRIC_GAP)) {
        warnings.insert(Warning::WeakQuadric);
    }
    if !(last.coverage >= T::lit(quality::REFUSE_COVERAGE)) {
        return Err(Error::PoorCoverage);
    }
    if !(last.gram_condition <= T::lit(quality::WARN_GRAM_CONDITION)) {
        warnings.insert(Warning::WeakCoverage);
    }
    if let Some(expected) = config.expected_field_strength {
        let deviation = calibration.field_strength() / T::lit(expected) - T::one();
        if !(deviation.abs() <= T::lit(quality::REFUSE_FIELD_DEVIATION)) {
            return Err(Error::FieldStrengthMismatch);
        }
    }
    Ok(Fit {
        calibration,
        report: Report {
            method: config.method,
            ls: config.ls,
            iterations: est.iterations,
            passes: est.passes,
            samples_used: scan.used,
            samples_dropped: scan.dropped,
            radial_rms: last.radial_rms,
            quality: Quality {
                flatness,
                quadric_gap,
                distortion,
                coverage: last.coverage,
                gram_condition: last.gram_condition,
            },
            warnings,
        },
    })
}

/// Step 1 on the moments: the LS fit, and the quadric gap of the same
/// scatter (judged after the method, against its radial RMS; see
/// [`quality::REFUSE_QUADRIC_GAP`]). Out of line, so the 10x10 scatter
/// takes stack only while it is used.
#[inline(never)]
fn ls_step<T: Real>(
    moments: &moments::Moments<T>,
    solve: ellipsoid::Solve<T>,
) -> Result<(ellipsoid::Ellipsoid<T>, T), Error> {
    let scatter = moments.scatter();
    let quadric_gap = quality::quadric_gap(&scatter)?;
    Ok((ellipsoid::fit_with(&scatter, solve)?, quadric_gap))
}
