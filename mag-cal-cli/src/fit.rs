//! The `fit` subcommand: read, parse, calibrate (timed), report.

use std::io::Write;

use mag_cal_core::{calibrate, Calibration, Config, Method, Real, SampleClass, Warnings};
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

use crate::cli::{FitArgs, Format, NoiseStd, Precision};
use crate::error::CliError;
use crate::input::{self, Source};
use crate::output;
use crate::selection::{DropCounts, SelectionJson};
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
    /// Outlier handling was on (`false` with `--plain`).
    pub robust: bool,
    /// Rows the final fit used.
    pub samples_used: usize,
    /// Rows dropped by the rules before any fit, all rules together.
    pub samples_dropped: usize,
    /// Rows dropped by each rule (by [`mag_cal_core::Rule::name`]).
    pub drops: DropCounts,
    /// Rows kept by the rules but set aside as still periods (a device
    /// lying still: not outliers; the rows in the balls of
    /// `selection.dwell`).
    pub dwell: usize,
    /// Rows kept by the rules but screened out (too far from the others).
    pub screened: usize,
    /// Rows inside the screening rejected by their radial residual, or
    /// beside a run of such rows.
    pub rejected: usize,
    /// Of the rejected rows, those beside a run with a residual within the
    /// cut (not counted in the outlier share).
    pub beside_runs: usize,
    /// Hard-iron offset `b`, sensor units.
    pub hard_iron: [f64; 3],
    /// Soft-iron matrix `W`, rows; symmetric; `W (raw - b)` is on the unit
    /// sphere.
    pub soft_iron: [[f64; 3]; 3],
    /// Local field strength `det(W)^(-1/3)`, sensor units.
    pub field_strength: f64,
    /// BFGS iterations (`adc1`, `submle`; 0 for `ls`, `adc2` and
    /// `adc2-iter`, solved in closed form).
    pub iterations: u32,
    /// Passes over the samples after the LS fit (for `ls` 1 with outlier handling, which judges
    /// the fit, else 0; 1 for `adc1`
    /// and `adc2`, one per step for `adc2-iter`, one per cost evaluation
    /// for `submle`).
    pub passes: u32,
    /// Passes of the outlier handling over the samples: screening and
    /// robust LS refits (0 when the plain fit was clean, and with `--plain`).
    pub robust_passes: u32,
    /// The rows the robust LS started without, `[[start, end], ...]`: a
    /// window of half the rows, when the first fit was in doubt and the
    /// fit from the rows outside it scored best (empty otherwise).
    #[serde(serialize_with = "crate::selection::spans")]
    pub start_window: mag_cal_core::Runs,
    /// Wall time of the `calibrate` call alone, microseconds.
    pub timing_us: f64,
    /// How well the calibration fits the samples.
    pub quality: Quality,
    /// Which rows the fit used: what `apply --flags` needs to classify
    /// rows again.
    pub selection: SelectionJson,
    /// What the fit did with each input row (in input order; for the plot,
    /// not in the JSON).
    #[serde(skip)]
    pub classes: Vec<SampleClass>,
}

/// Quality figures of a fit.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Quality {
    /// RMS of `|W (y - b)| - 1` over the samples used (from the core).
    pub radial_rms: f64,
    /// Standard deviation over mean of `|W (y - b)|` over the rows used.
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
    /// Fit error: robust standard deviation of `|W (y - b)| - 1` over the
    /// rows kept by the rules and the screening, in units of the field
    /// (warned above 0.05, refused above 0.2).
    pub fit_error: f64,
    /// Lack of fit: the systematic part of the radial residual over
    /// direction cells, in units of the field (refused above 0.01 when
    /// significant).
    pub lack_of_fit: f64,
    /// Share of the rows kept by the rules that the fit did not use
    /// (screened or rejected; refused above 0.25).
    pub outlier_share: f64,
    /// Skewness of the radial residuals of the rows used, with outlier
    /// handling (0 when the plain fit was clean): a filled cloud is skewed
    /// inwards (refused below -0.6 with a fit error above 0.05).
    pub skewness: f64,
    /// Names of the core's warnings (`pass_cap`, ...), empty when none.
    pub warnings: Vec<&'static str>,
    /// The core's sentence of each warning, in the same order, with the
    /// figure and the limit that raised it ([`mag_cal_core::Warning::explain`]).
    #[serde(skip)]
    pub warning_texts: Vec<String>,
}

impl Quality {
    /// The figures of the core's `quality` with the calibration's radial RMS
    /// and norm spread (over the rows it used) and its warnings (their
    /// names; `warning_texts` is left empty, for the caller to fill with
    /// [`mag_cal_core::Warning::explain`] or `explain_with`): the `quality`
    /// object of `fit`'s JSON, also `magcal background`'s.
    pub fn from_core<T: Real>(
        quality: &mag_cal_core::Quality<T>,
        radial_rms: T,
        norm_spread: f64,
        warnings: Warnings,
    ) -> Self {
        Quality {
            radial_rms: radial_rms.to_f64(),
            norm_spread,
            flatness: quality.flatness.to_f64(),
            quadric_gap: quality.quadric_gap.to_f64(),
            distortion: quality.distortion.to_f64(),
            coverage: quality.coverage.to_f64(),
            gram_condition: quality.gram_condition.to_f64(),
            fit_error: quality.fit_error.to_f64(),
            lack_of_fit: quality.lack_of_fit.to_f64(),
            outlier_share: quality.outlier_share.to_f64(),
            skewness: quality.skewness.to_f64(),
            warnings: warnings.iter().map(|w| w.name()).collect(),
            warning_texts: Vec::new(),
        }
    }
}

/// A calibration's parameters widened to `f64`, as `fit`'s JSON names them
/// (`hard_iron`, `soft_iron` by rows, `field_strength`): what `magcal
/// apply` reads.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Parameters {
    /// Hard-iron offset `b`, sensor units.
    pub hard_iron: [f64; 3],
    /// Soft-iron matrix `W`, rows; symmetric.
    pub soft_iron: [[f64; 3]; 3],
    /// Local field strength `det(W)^(-1/3)`, sensor units.
    pub field_strength: f64,
}

impl Parameters {
    /// The parameters of `cal`.
    pub fn of<T: Real>(cal: &Calibration<T>) -> Self {
        let b = cal.hard_iron_vector();
        let w = cal.soft_iron_matrix();
        Parameters {
            hard_iron: [b.x, b.y, b.z].map(T::to_f64),
            soft_iron: [0, 1, 2].map(|r| [0, 1, 2].map(|c| w[(r, c)].to_f64())),
            field_strength: cal.field_strength().to_f64(),
        }
    }
}

/// Runs `magcal fit`, writing the report to `out`.
///
/// Returns notes for stderr where the report does not say so (`--format
/// json`): the sample columns, when they were found in the header, and the
/// lines of the input that were no samples ([`input::Skipped::note`]).
pub fn run(args: &FitArgs, out: &mut dyn Write) -> Result<Vec<String>, CliError> {
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
    let skipped = table.skipped.note();
    let samples = table.samples;
    let config = Config {
        method,
        ls: args.ls.to_core(),
        noise_covariance: args.noise_std.map(NoiseStd::covariance),
        robust: !args.plain,
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
            fit_error: outcome.quality.fit_error,
            residual_limit: outcome.selection.residual_limit,
            robust: outcome.robust,
        };
        let picture = svg::plot(&samples, &outcome.classes, &outcome.calibration()?, &title);
        std::fs::write(path, picture).map_err(|err| CliError::WriteFile {
            path: path.display().to_string(),
            err,
        })?;
    }
    let report = match args.format {
        Format::Text => output::text(
            &outcome,
            &source.name(),
            &table.columns.to_string(),
            skipped.as_deref(),
        ),
        Format::Json => output::json(&outcome),
    };
    out.write_all(report.as_bytes())
        .and_then(|()| out.flush())
        .map_err(CliError::Write)?;
    let json = args.format == Format::Json;
    Ok((json && table.columns.detected())
        .then(|| format!("columns {}", table.columns))
        .into_iter()
        .chain(skipped.filter(|_| json).map(|s| format!("input: {s}")))
        .collect())
}

impl Outcome {
    /// The calibration as an `f64` core value (for the plot).
    pub fn calibration(&self) -> Result<Calibration<f64>, CliError> {
        let b = Vector3::from(self.hard_iron);
        let w = Matrix3::from_fn(|r, c| self.soft_iron[r][c]);
        Ok(Calibration::from_nalgebra(b, w)?)
    }
}

/// Calibrates `samples` in the requested precision, timed by the system's
/// monotonic clock.
pub fn fit(
    samples: &[[f64; 3]],
    config: &Config,
    precision: Precision,
) -> Result<Outcome, CliError> {
    let start = std::time::Instant::now();
    fit_timed(samples, config, precision, &|| {
        start.elapsed().as_secs_f64() * 1e6
    })
}

/// [`fit`] with the clock given: `now_us` reads a monotonic clock in
/// microseconds (the page passes the browser's `performance.now()`, as
/// `wasm32-unknown-unknown` has no `std::time::Instant`).
pub fn fit_timed(
    samples: &[[f64; 3]],
    config: &Config,
    precision: Precision,
    now_us: &dyn Fn() -> f64,
) -> Result<Outcome, CliError> {
    match precision {
        Precision::F32 => fit_in::<f32>(samples, config, precision, now_us),
        Precision::F64 => fit_in::<f64>(samples, config, precision, now_us),
    }
}

/// One timed call of the core in precision `T` (named by `precision`), and
/// the summary of its result.
fn fit_in<T: Real>(
    samples: &[[f64; 3]],
    config: &Config,
    precision: Precision,
    now_us: &dyn Fn() -> f64,
) -> Result<Outcome, CliError> {
    // Integer counts of an i16 sensor are calibrated as such, so that the
    // rails rule sees them (`counts`).
    let ints = counts(samples);
    let start = now_us();
    let fit = match &ints {
        Some(ints) => calibrate::<T, [i16; 3]>(ints, config),
        None => calibrate::<T, [f64; 3]>(samples, config),
    };
    let elapsed_us = now_us() - start;
    let fit = fit?;

    let cal = &fit.calibration;
    let report = &fit.report;
    // What the fit did with each row, in precision `T` as the core decided.
    let classes: Vec<SampleClass> = match &ints {
        Some(ints) => report.selection.classify(cal, ints).collect(),
        None => report.selection.classify(cal, samples).collect(),
    };
    // The calibrated norms of the rows the core used, for the spread figure.
    let norms = samples
        .iter()
        .zip(&classes)
        .filter(|(_, c)| **c == SampleClass::Used)
        .map(|(s, _)| cal.apply_vector(*s).norm().to_f64());
    let Parameters {
        hard_iron,
        soft_iron,
        field_strength,
    } = Parameters::of(cal);
    Ok(Outcome {
        method: report.method.name(),
        ls: report.ls.name(),
        precision: precision.name(),
        robust: config.robust,
        samples_used: report.samples_used,
        samples_dropped: report.samples_dropped,
        drops: DropCounts(report.drops),
        dwell: report.dwell,
        screened: report.screened,
        rejected: report.rejected,
        beside_runs: report.beside_runs,
        hard_iron,
        soft_iron,
        field_strength,
        iterations: report.iterations,
        passes: report.passes,
        robust_passes: report.robust_passes,
        start_window: report.start_window(),
        timing_us: elapsed_us,
        quality: Quality {
            warning_texts: report
                .warnings
                .iter()
                .map(|w| w.explain(report, config).to_string())
                .collect(),
            ..Quality::from_core(
                &report.quality,
                report.radial_rms,
                spread(norms),
                report.warnings,
            )
        },
        selection: SelectionJson::from_core(&report.selection),
        classes,
    })
}

/// The rows as `i16` counts when every value is an integer in `i16`'s
/// range (a raw dump of a 16-bit sensor): the core's rails rule then drops
/// rows with a component at `+-32767` or `-32768`, which in floating point
/// would be ordinary values. `None` for any other file (a fraction, a
/// non-finite or a larger value anywhere), read as `f64`.
pub fn counts(samples: &[[f64; 3]]) -> Option<Vec<[i16; 3]>> {
    let int = |v: f64| {
        (v.fract() == 0.0 && (f64::from(i16::MIN)..=f64::from(i16::MAX)).contains(&v))
            .then_some(v as i16)
    };
    samples
        .iter()
        .map(|r| Some([int(r[0])?, int(r[1])?, int(r[2])?]))
        .collect()
}

/// Population standard deviation over mean of `values` (NaN when empty).
pub fn spread(values: impl Iterator<Item = f64> + Clone) -> f64 {
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
            // Outlier handling on (the default): the LS fit alone makes one
            // artificial-data pass, for its residuals' tails and shape.
            assert!(o.passes >= 1, "{method:?}: {}", o.passes);
            if method == Method::Ls {
                assert_eq!(o.passes, 1);
                let plain = Config {
                    robust: false,
                    ..config
                };
                let p = fit(&samples, &plain, Precision::F64).expect("fits");
                assert_eq!(p.passes, 0, "plain LS makes no pass");
            }
            assert!(o.quality.warnings.is_empty(), "{:?}", o.quality.warnings);
            let cal = o.calibration().expect("rebuilds");
            assert!((cal.field_strength() - o.field_strength).abs() < 1e-9 * o.field_strength);
        }
    }

    #[test]
    fn classes_agree_with_the_counts() {
        let mut samples = ellipsoid(200);
        samples[50] = [900.0, 400.0, -300.0]; // far away: screened
        samples[120] = [300.0, -120.0, 75.0]; // the centre: rejected
        samples.push([f64::NAN, 1.0, 2.0]);
        for precision in [Precision::F64, Precision::F32] {
            let o = fit(&samples, &Config::default(), precision).expect("fits");
            let n = |class: fn(&SampleClass) -> bool| o.classes.iter().filter(|c| class(c)).count();
            assert_eq!(o.classes.len(), samples.len());
            assert_eq!(n(|c| *c == SampleClass::Used), o.samples_used);
            assert_eq!(n(|c| matches!(c, SampleClass::Dropped(_))), 1);
            assert_eq!(n(|c| *c == SampleClass::Screened), o.screened);
            assert_eq!(n(|c| *c == SampleClass::Rejected), o.rejected);
            assert!(o.classes[50] != SampleClass::Used && o.classes[120] != SampleClass::Used);
            assert_eq!(o.samples_used + 1 + o.screened + o.rejected, samples.len());
            assert!(o.robust && o.robust_passes > 0 && o.selection.screen.is_some());
            assert!((o.hard_iron[0] - 300.0).abs() < 1e-2, "{:?}", o.hard_iron);

            // The plain fit trusts every finite row: the far one bends it
            // until the rows lie on no sphere (refused); without it, the
            // row at the centre is used like any other.
            let plain = Config {
                robust: false,
                ..Config::default()
            };
            let err = fit(&samples, &plain, precision).unwrap_err();
            assert!(
                matches!(err, CliError::Refused(mag_cal_core::Error::NoSphere { .. })),
                "{err}"
            );
            let mut near = samples.clone();
            near[50] = ellipsoid(200)[50];
            let o = fit(&near, &plain, precision).expect("fits");
            assert_eq!((o.samples_used, o.samples_dropped), (200, 1));
            assert_eq!((o.screened, o.rejected), (0, 0));
            assert_eq!((o.robust, o.robust_passes), (false, 0));
            assert_eq!(o.selection, SelectionJson::ALL);
            let used = o.classes.iter().filter(|c| **c == SampleClass::Used);
            assert_eq!(used.count(), 200);
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
