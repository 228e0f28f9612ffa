//! The `fit` subcommand: read, parse, calibrate (timed), report.

use std::io::Write;
use std::time::Instant;

use mag_cal_core::nalgebra::{Matrix3, Vector3};
use mag_cal_core::{calibrate, Calibration, Config, Method, Real};
use serde::Serialize;

use crate::cli::{FitArgs, Format, NoiseStd, Precision};
use crate::error::CliError;
use crate::input::{self, Picked, Source};
use crate::output;
use crate::svg::{self, PlotTitle};

/// The result of a fit, widened to `f64`: what both output formats print.
///
/// Serialised as the JSON object of `--format json`, in field order.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Outcome {
    /// Method name (`ls`, `adc1`, `adc2`, `adc2-iter`, `submle`).
    pub method: &'static str,
    /// LS variant name (`ls9`, `svd10`, `lg10`).
    pub ls: &'static str,
    /// `f32` or `f64`.
    pub precision: &'static str,
    /// Finite samples the fit used.
    pub samples_used: usize,
    /// Non-finite samples it skipped.
    pub samples_dropped: usize,
    /// Hard-iron offset `b`, sensor units.
    pub hard_iron: [f64; 3],
    /// Soft-iron matrix `W`, rows; symmetric; `W (raw - b)` is on the unit
    /// sphere.
    pub soft_iron: [[f64; 3]; 3],
    /// Local field strength `det(W)^(-1/3)`, sensor units.
    pub field_strength: f64,
    /// Quasi-Newton iterations (0 for `ls`).
    pub iterations: u32,
    /// Passes over the samples after the LS fit (0 for `ls`, 1 for `adc1`
    /// and `adc2`, one per step for `adc2-iter`, one per cost evaluation
    /// for `submle`).
    pub passes: u32,
    /// Wall time of the `calibrate` call alone, microseconds.
    pub timing_us: f64,
    /// How well the calibration fits the samples.
    pub quality: Quality,
}

/// Quality figures of a fit.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Quality {
    /// RMS of `|W (y - b)| - 1` over the samples used (from the core).
    pub radial_rms: f64,
    /// Standard deviation over mean of `|W (y - b)|` over the samples used.
    pub norm_spread: f64,
    /// Flatness of the samples (`lambda_min / lambda_max` of their
    /// covariance; refused below 0.03).
    pub flatness: f64,
    /// Quadric gap of the LS scatter (refused below 3 on low-noise data).
    pub quadric_gap: f64,
    /// Condition number of `M` (refused above 16).
    pub distortion: f64,
    /// `lambda_min` of the covariance of the calibrated directions
    /// (refused below 0.05; full sphere about 0.33).
    pub coverage: f64,
    /// Condition number of the directions' Gram matrix (warned above 20).
    pub gram_condition: f64,
    /// Names of the core's warnings (`pass_cap`, ...), empty when none.
    pub warnings: Vec<&'static str>,
}

/// Runs `magcal fit`, writing the report to `out`.
///
/// Returns a note for stderr when the sample columns were found in the
/// header and the report does not say so (`--format json`).
pub fn run(args: &FitArgs, out: &mut dyn Write) -> Result<Option<String>, CliError> {
    let source = Source::from_arg(&args.file);
    let bytes = source.read()?;
    let method = args.method.to_core();
    if args.noise_std.is_some() && method != Method::Adc1 {
        return Err(CliError::Input(format!(
            "--noise-std is used only by --method adc1, not {}",
            method.name()
        )));
    }
    let table = input::parse(&bytes, args.columns.as_ref(), &source.name())?;
    let samples = table.samples;
    let config = Config {
        method,
        ls: args.ls.to_core(),
        noise_covariance: args.noise_std.map(NoiseStd::covariance),
        ..Config::default()
    };
    let outcome = fit(&samples, &config, args.precision)?;
    // The plot first: when it cannot be written, nothing is printed.
    if let Some(path) = &args.plot {
        let title = PlotTitle {
            source: &source.file_name(),
            method: outcome.method,
            ls: outcome.ls,
            radial_rms: outcome.quality.radial_rms,
        };
        let picture = svg::plot(&samples, &outcome.calibration()?, &title);
        std::fs::write(path, picture).map_err(|err| CliError::WriteFile {
            path: path.display().to_string(),
            err,
        })?;
    }
    let report = match args.format {
        Format::Text => output::text(&outcome, &source.name(), &table.columns.to_string()),
        Format::Json => output::json(&outcome),
    };
    out.write_all(report.as_bytes())
        .and_then(|()| out.flush())
        .map_err(CliError::Write)?;
    Ok(
        (args.format == Format::Json && table.columns.picked == Picked::Header)
            .then(|| format!("columns {}", table.columns)),
    )
}

impl Outcome {
    /// The calibration as an `f64` core value (for the plot).
    pub fn calibration(&self) -> Result<Calibration<f64>, CliError> {
        let b = Vector3::from(self.hard_iron);
        let w = Matrix3::from_fn(|r, c| self.soft_iron[r][c]);
        Ok(Calibration::new(b, w)?)
    }
}

/// Calibrates `samples` in the requested precision.
pub fn fit(
    samples: &[[f64; 3]],
    config: &Config,
    precision: Precision,
) -> Result<Outcome, CliError> {
    match precision {
        Precision::F32 => fit_in::<f32>(samples, config, precision),
        Precision::F64 => fit_in::<f64>(samples, config, precision),
    }
}

/// One timed call of the core in precision `T` (named by `precision`), and
/// the summary of its result.
fn fit_in<T: Real>(
    samples: &[[f64; 3]],
    config: &Config,
    precision: Precision,
) -> Result<Outcome, CliError> {
    let start = Instant::now();
    let fit = calibrate::<T, [f64; 3]>(samples, config);
    let elapsed = start.elapsed();
    let fit = fit?;

    let cal = &fit.calibration;
    let b = cal.hard_iron();
    let w = cal.soft_iron();
    // The calibrated norms of the samples the core used (the finite ones in
    // precision `T`), for the spread figure.
    let norms = samples
        .iter()
        .map(|s| s.map(T::lit))
        .filter(|y| y.iter().all(|v| v.is_finite()))
        .map(|y| cal.apply(y).norm().to_f64());
    Ok(Outcome {
        method: fit.report.method.name(),
        ls: fit.report.ls.name(),
        precision: precision.name(),
        samples_used: fit.report.samples_used,
        samples_dropped: fit.report.samples_dropped,
        hard_iron: [b.x, b.y, b.z].map(T::to_f64),
        soft_iron: [0, 1, 2].map(|r| [0, 1, 2].map(|c| w[(r, c)].to_f64())),
        field_strength: cal.field_strength().to_f64(),
        iterations: fit.report.iterations,
        passes: fit.report.passes,
        timing_us: elapsed.as_secs_f64() * 1e6,
        quality: Quality {
            radial_rms: fit.report.radial_rms.to_f64(),
            norm_spread: spread(norms),
            flatness: fit.report.quality.flatness.to_f64(),
            quadric_gap: fit.report.quality.quadric_gap.to_f64(),
            distortion: fit.report.quality.distortion.to_f64(),
            coverage: fit.report.quality.coverage.to_f64(),
            gram_condition: fit.report.quality.gram_condition.to_f64(),
            warnings: fit.report.warnings.iter().map(|w| w.name()).collect(),
        },
    })
}

/// Population standard deviation over mean of `values` (NaN when empty).
fn spread(values: impl Iterator<Item = f64> + Clone) -> f64 {
    let (n, sum) = values
        .clone()
        .fold((0usize, 0.0), |(n, s), v| (n + 1, s + v));
    let mean = sum / n as f64;
    let var = values.map(|v| (v - mean) * (v - mean)).sum::<f64>() / n as f64;
    var.sqrt() / mean
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on a shifted, stretched ellipsoid (a Fibonacci sphere).
    fn ellipsoid(n: usize) -> Vec<[f64; 3]> {
        (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let phi = i as f64 * 2.399_963;
                [
                    300.0 + 40.0 * r * phi.cos(),
                    -120.0 + 55.0 * r * phi.sin(),
                    75.0 + 48.0 * z,
                ]
            })
            .collect()
    }

    #[test]
    fn spread_of_constant_is_zero() {
        assert_eq!(spread([2.0, 2.0, 2.0].into_iter()), 0.0);
        assert!((spread([1.0, 3.0].into_iter()) - 0.5).abs() < 1e-15);
        assert!(spread(std::iter::empty()).is_nan());
    }

    #[test]
    fn fits_in_both_precisions() {
        let mut samples = ellipsoid(200);
        samples.push([f64::NAN, 0.0, 0.0]);
        for (precision, tol) in [(Precision::F64, 1e-8), (Precision::F32, 1e-2)] {
            let o = fit(&samples, &Config::default(), precision).expect("fits");
            assert_eq!(o.precision, precision.name());
            assert_eq!((o.method, o.ls), ("adc2", "ls9"));
            assert_eq!((o.samples_used, o.samples_dropped), (200, 1));
            assert!((o.hard_iron[0] - 300.0).abs() < tol, "{:?}", o.hard_iron);
            assert!(o.quality.norm_spread < 1e-4 && o.quality.radial_rms < 1e-4);
            assert!(o.timing_us >= 0.0);
        }
    }

    #[test]
    fn every_method_reports_passes_and_rebuilds() {
        let samples = ellipsoid(200);
        for method in Method::ALL {
            let config = Config {
                method,
                ..Config::default()
            };
            let o = fit(&samples, &config, Precision::F64).expect("fits");
            assert_eq!(o.method, method.name());
            assert_eq!(
                o.passes == 0,
                method == Method::Ls,
                "{method:?}: {}",
                o.passes
            );
            assert!(o.quality.warnings.is_empty(), "{:?}", o.quality.warnings);
            let cal = o.calibration().expect("rebuilds");
            assert!((cal.field_strength() - o.field_strength).abs() < 1e-9 * o.field_strength);
        }
    }

    #[test]
    fn refusal_is_exit_3() {
        let config = Config {
            method: Method::Ls,
            ..Config::default()
        };
        let err = fit(&[[1.0, 2.0, 3.0]; 20], &config, Precision::F64).unwrap_err();
        assert_eq!(err.exit_code(), 3);
    }
}
