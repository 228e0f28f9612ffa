//! How a calibration was obtained: [`Report`] and [`Fit`].

#[cfg(feature = "robust")]
use crate::robust::refit;
use crate::{Calibration, Drops, LsVariant, Method, Quality, Real, Runs, Selection, Warnings};

/// How a calibration was obtained, and how well it fits.
///
/// Every row of the input is counted once:
/// `samples_used + samples_dropped + dwell + screened + rejected` is the
/// input's length.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Report<T: Real> {
    /// The method that ran.
    pub method: Method,
    /// The LS variant of step 1.
    pub ls: LsVariant,
    /// BFGS iterations, summed over all solves: ADC1's and subMLE's; 0 for
    /// [`Method::Ls`], [`Method::Adc2`] and [`Method::Adc2Iterated`], whose
    /// solves are closed form (their work is in `passes`).
    pub iterations: u32,
    /// Passes over the samples after the LS fit: 1 for ADC1 and ADC2, one
    /// per fixed-point step for iterated ADC2, one per cost evaluation for
    /// subMLE; for [`Method::Ls`] 1 with [`Config::robust`](crate::Config::robust) (ADC2's first
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
    /// Rows kept by the rules but set aside in a still period's ball
    /// ([`crate::Dwell`], [`crate::SampleClass::Dwell`]): not outliers,
    /// and not counted by the outlier share.
    pub dwell: usize,
    /// Rows kept by the rules but screened out: too far from the others.
    pub screened: usize,
    /// Rows kept and inside the screening, rejected by their residual or
    /// left out beside a run of rows rejected by theirs ([`runs`](crate::runs)).
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
    /// `DOUBT_LACK_OF_FIT`) and the fit from those rows scored best (the
    /// smallest median residual over every row, `AMBIGUOUS_SCORE`).
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
        #[cfg(feature = "robust")]
        {
            let rows = self
                .samples_used
                .saturating_add(self.samples_dropped)
                .saturating_add(self.dwell)
                .saturating_add(self.screened)
                .saturating_add(self.rejected);
            refit::window(usize::from(self.start), rows)
        }
        // Without the `robust` feature no robust start is made (`start` is
        // always 0): no rows.
        #[cfg(not(feature = "robust"))]
        {
            Runs::NONE
        }
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
