//! What to run: [`Config`].

use crate::{LsVariant, Method, Thresholds};

/// What to run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Config {
    /// The method (default [`Method::Adc2`]).
    pub method: Method,
    /// The LS variant of step 1 (default [`LsVariant::Ls9`]).
    pub ls: LsVariant,
    /// Iteration cap of each BFGS solve, ADC1's and subMLE's (default 50).
    /// ADC1 takes about 12, subMLE 10-30. ADC2 and iterated ADC2 do not
    /// iterate a solver: ADC2's cost is exactly quadratic and solved in
    /// closed form.
    pub max_iterations: u32,
    /// Cap on the data passes of [`Method::Adc2Iterated`] (default 50;
    /// it needs 5-12, more on partial coverage). Hitting it is reported as
    /// [`Warning::PassCap`](crate::Warning::PassCap).
    pub max_passes: u32,
    /// Stop tolerance of [`Method::Adc2Iterated`] on the gauge-free change
    /// of a pass, `max|dM| rho^2 + max|db| / rho`; `None` (or a value that
    /// is not positive and finite) is `1e-6` in `f64` and `1e-5` in `f32`.
    pub pass_tolerance: Option<f64>,
    /// Per-sample noise covariance `Sigma`, sensor units squared, for
    /// [`Method::Adc1`] (when `None`, it is estimated from the LS residuals,
    /// the paper's procedure) and for the spread check
    /// ([`Warning::LowSpread`](crate::Warning::LowSpread)).
    pub noise_covariance: Option<[[f64; 3]; 3]>,
    /// The local field strength the calibration should find, sensor units,
    /// when known (e.g. from a geomagnetic model): a fit whose
    /// `field_strength` is off by more than 25 % is refused
    /// ([`Error::FieldStrengthMismatch`](crate::Error::FieldStrengthMismatch)). It is the only check that catches
    /// a small cap of directions fitted by a too-small sphere.
    pub expected_field_strength: Option<f64>,
    /// Outlier handling (default `true`): the glitch drop rules, screening,
    /// the robust LS start and 0/1 weights on every pass (see
    /// [`robust`](crate#outliers)), and the refusals
    /// [`Error::TooManyOutliers`](crate::Error::TooManyOutliers) and [`Error::SystematicMisfit`](crate::Error::SystematicMisfit). `false`
    /// trusts every finite row: the plain methods of the paper, with the
    /// same estimates as before outlier handling existed (rows too large
    /// for the working precision are still dropped, and a fit error above
    /// the limit still refuses: [`Error::NoSphere`](crate::Error::NoSphere)).
    ///
    /// Without the cargo feature `robust` (the plain build), `true` keeps
    /// its first part, the glitch drop rules (zero rows, rails, repeats),
    /// and the plain fit of the rows they keep is the answer: no screening,
    /// no weights, none of the outlier refusals. Neither ignored nor
    /// refused: the same [`Config`] (e.g. `Config::default()`) then runs in
    /// both builds, and where the robust build takes the plain fit (clean
    /// data) both give the same result; dropping the glitch rules with the
    /// feature, or refusing the default configuration, would surprise more.
    pub robust: bool,
    /// Still periods (default `true`): the rows of a device lying still,
    /// for at least a tenth of the recording, are set aside before any fit
    /// (a ball about where it lay: [`Dwell`](crate::Dwell),
    /// [`SampleClass::Dwell`](crate::SampleClass::Dwell), counted in
    /// [`Report::dwell`](crate::Report::dwell)), so that a log that starts
    /// and ends lying still calibrates like its motion alone; a device that
    /// hardly moved is refused as
    /// [`Error::HardlyMoved`](crate::Error::HardlyMoved). `false` fits every
    /// row the rules keep. In both builds.
    pub still: bool,
    /// The judging limits (default [`Thresholds::DEFAULT`](crate::Thresholds::DEFAULT), the measured
    /// constants of [`quality`](crate::quality)).
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
        still: true,
        thresholds: Thresholds::DEFAULT,
    };
}

impl Default for Config {
    fn default() -> Self {
        Self::DEFAULT
    }
}
