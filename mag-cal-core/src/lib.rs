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
//! # Features
//! - `defmt`: derive `defmt::Format` for [`Error`], [`Method`], [`LsVariant`].
//!
//! # Not supported (yet)
//! ADC1, iterated ADC2, subMLE, alignment, heading and the degenerate-geometry
//! checks beyond positive definiteness are planned; so are streaming
//! collection with coverage and persistence.

#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]
// `!(x > 0)` is deliberate throughout: unlike `x <= 0` it is also true for
// NaN, so a NaN never passes a validity check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod artificial;
pub mod calibration;
pub mod ellipsoid;
mod error;
mod linalg;
pub mod methods;
pub mod moments;
pub mod normalize;
mod quality;
pub mod quasi_newton;
mod real;
mod sample;

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
pub use real::Real;
pub use sample::{Sample, SampleStore};

/// What to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Config {
    /// The method (default [`Method::Adc2`]).
    pub method: Method,
    /// The LS variant of step 1 (default [`LsVariant::Ls9`]).
    pub ls: LsVariant,
    /// Iteration cap of the quasi-Newton solver (default 50). ADC2 takes
    /// 2-4: with the exact line search on its quadratic cost, whose Hessian
    /// has four distinct eigenvalues, BFGS ends in at most four steps.
    pub max_iterations: u32,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            method: Method::Adc2,
            ls: LsVariant::Ls9,
            max_iterations: 50,
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
    /// Quasi-Newton iterations (0 for [`Method::Ls`]).
    pub iterations: u32,
    /// Finite samples used.
    pub samples_used: usize,
    /// Non-finite samples skipped.
    pub samples_dropped: usize,
    /// RMS of `|W (y - b)| - 1` over the samples used.
    pub radial_rms: T,
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
/// validation and normalisation, moments, then (ADC2) artificial data, and
/// finally the radial RMS for the report.
pub fn calibrate<T: Real, S: Sample>(samples: &[S], config: &Config) -> Result<Fit<T>, Error> {
    let scan = normalize::scan::<T, S>(samples)?;
    let norm = scan.norm;
    let moments = moments::Moments::accumulate(samples, &norm);
    let ls = ellipsoid::fit(&moments, config.ls)?;
    let (centre, w, iterations) = match config.method {
        Method::Ls => (ls.centre, ls.w, 0),
        Method::Adc2 => {
            let stats = artificial::Stats::accumulate(samples, &norm, &ls.centre, &ls.w)?;
            let sol = methods::adc2::solve(&stats, &ls.t, &ls.centre, config.max_iterations)?;
            let w = linalg::sym_inv_sqrt(&(sol.t * sol.t.transpose()))?;
            (sol.centre, w, sol.iterations)
        }
    };
    let calibration = Calibration::from_normalised_w(&norm, &w, &centre)?;
    let radial_rms = quality::radial_rms(samples, &norm, &centre, &w);
    Ok(Fit {
        calibration,
        report: Report {
            method: config.method,
            ls: config.ls,
            iterations,
            samples_used: scan.used,
            samples_dropped: scan.dropped,
            radial_rms,
        },
    })
}
