//! Step 4 of Algorithm 1: the re-estimation methods. ADC2 solves its
//! quadratic cost in closed form; ADC1 and subMLE are small objectives over
//! the shared BFGS solver (`numerics/quasi_newton.rs`), iterated ADC2 a
//! fixed-point map accelerated there.

#[cfg(feature = "robust")]
use crate::tuning::OUTLIER_CUT;
use nalgebra::{Matrix3, Vector3};

use crate::numerics::histogram::LogHistogram;
use crate::numerics::linalg::larger;
use crate::robust::runs::Runs;
use crate::sample::Sample;
use crate::steps::artificial::Stats;
#[cfg(feature = "robust")]
use crate::steps::artificial::{AdcPass, Pass, Residuals};
use crate::steps::ellipsoid::Ellipsoid;
use crate::steps::final_pass::DirectionSums;
use crate::steps::normalize::Normalization;
use crate::steps::rules::Gate;
use crate::{Config, Error, Real, Warnings};

#[cfg(feature = "adc1")]
pub mod adc1;
pub mod adc2;
#[cfg(feature = "adc2-iter")]
pub mod adc2_iter;
#[cfg(feature = "submle")]
pub mod submle;

/// Which method produced a calibration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Method {
    /// The algebraic least-squares ellipsoid fit alone (step 1).
    Ls,
    /// The paper's ADC1: artificial data, then a noise-weighted re-estimate.
    /// Its minimiser equals ADC2's for every noise covariance (both
    /// regress on the same `[h_i, 1]`); it is kept to reproduce the paper
    /// and to show that.
    Adc1,
    /// One-step artificial data creation with least-squares re-estimation
    /// (the paper's ADC2, steps 1-5; its quadratic cost solved in closed
    /// form, where the paper uses a quasi-Newton solver).
    #[default]
    Adc2,
    /// ADC2 repeated to its fixed point, accelerated (Anderson); beyond the
    /// paper. As accurate as subMLE, at one O(n) pass per iteration.
    Adc2Iterated,
    /// The paper's baseline (Vasconcelos et al. 2011): approximate maximum
    /// likelihood with isotropic noise, BFGS with one O(n) pass per
    /// evaluation.
    SubMle,
}

impl Method {
    /// Every method, in the order of the paper's tables.
    pub const ALL: [Method; 5] = [
        Method::Ls,
        Method::SubMle,
        Method::Adc1,
        Method::Adc2,
        Method::Adc2Iterated,
    ];

    /// Short lower-case name (`ls`, `adc1`, `adc2`, `adc2-iter`, `submle`),
    /// as used by the CLI.
    pub const fn name(self) -> &'static str {
        match self {
            Method::Ls => "ls",
            Method::Adc1 => "adc1",
            Method::Adc2 => "adc2",
            Method::Adc2Iterated => "adc2-iter",
            Method::SubMle => "submle",
        }
    }

    /// Whether the method fits the radial residual `|u| - 1` (ADC1, ADC2,
    /// iterated ADC2): its residuals then average to zero in every region
    /// of directions at a good fit, and the lack-of-fit figure judges it
    /// (`REFUSE_LACK_OF_FIT`).
    pub const fn fits_radial_residual(self) -> bool {
        matches!(self, Method::Adc1 | Method::Adc2 | Method::Adc2Iterated)
    }

    /// The cargo feature that compiles the method in (`""` for the ones
    /// always there: LS and ADC2).
    pub const fn feature(self) -> &'static str {
        match self {
            Method::Ls | Method::Adc2 => "",
            Method::Adc1 => "adc1",
            Method::Adc2Iterated => "adc2-iter",
            Method::SubMle => "submle",
        }
    }

    /// Whether this build has the method ([`Method::feature`] enabled).
    pub const fn is_enabled(self) -> bool {
        match self {
            Method::Ls | Method::Adc2 => true,
            Method::Adc1 => cfg!(feature = "adc1"),
            Method::Adc2Iterated => cfg!(feature = "adc2-iter"),
            Method::SubMle => cfg!(feature = "submle"),
        }
    }

    /// The method named `name` (see [`Method::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }
}

/// A method's work after the LS fit, as [`crate::calibrate`] calls it,
/// with the 0/1 weights of its passes.
pub(crate) type Step<T, S> =
    fn(&[S], &Normalization<T>, &Ellipsoid<T>, &Config, &Weights<T>) -> Result<Estimate<T>, Error>;

/// [`Method::Ls`]'s step: the LS fit itself. A plain attempt of the
/// robust pipeline (`weights.tails_limit` set) also makes the
/// artificial-data pass at the fit, as ADC2's first pass: its residuals'
/// tails decide whether the fit is clean (a tenth of the rows displaced by
/// a field gives a kurtosis of 7 or more, clean scenarios at most 4.7;
/// a filled ball a skewness below -1.2), and its direction sums are the
/// final pass's.
pub(crate) fn ls_only<T: Real, S: Sample>(
    samples: &[S],
    norm: &Normalization<T>,
    ls: &Ellipsoid<T>,
    _config: &Config,
    weights: &Weights<T>,
) -> Result<Estimate<T>, Error> {
    if weights.tails_limit.is_none() {
        return Ok(Estimate::from_ellipsoid(ls));
    }
    let Some((stats, _, _)) = weighted_stats(samples, norm, &ls.centre, &ls.w, weights)? else {
        return Ok(Estimate::beyond_tails_limit(ls));
    };
    let mut est = Estimate::from_ellipsoid(ls);
    est.passes = 1;
    est.directions = Some(DirectionSums::from(&stats));
    Ok(est)
}

/// Which rows a method's passes use (design document, section 14): the
/// drop rules and screening ball of the gate, and, when `sigma` is set, a
/// hard cut at [`OUTLIER_CUT`]` sigma` on the radial residual
/// `||u| - 1|` under each pass's start.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Weights<'r, T: Real> {
    pub gate: Gate<'r, T>,
    /// The spans of rows beside runs of rejected rows, skipped
    /// ([`crate::robust::runs`]). By reference: the weights are copied in the
    /// methods' frames, which are the deepest of the robust path.
    pub runs: &'r Runs,
    /// Robust standard deviation of the radial residuals under the start
    /// (from the previous pass: the weights lag one pass).
    pub sigma: Option<T>,
    /// A plain pass whose residuals' kurtosis exceeds the first, or whose
    /// skewness is below minus the second, ends the method before its
    /// solve ([`Estimate::beyond_tails_limit`]): the plain fit is not
    /// clean, and the robust path follows (see `CLEAN_KURTOSIS`
    /// and `CLEAN_SKEWNESS`).
    pub tails_limit: Option<(T, T)>,
}

#[cfg(feature = "bench-internals")]
impl<T: Real> Weights<'static, T> {
    /// Every finite row, weight 1: the plain methods.
    pub(crate) const PLAIN: Self = Self {
        gate: Gate::PLAIN,
        runs: &Runs::NONE,
        sigma: None,
        tails_limit: None,
    };
}

impl<T: Real> Weights<'_, T> {
    /// The residual limit, [`OUTLIER_CUT`] robust standard deviations.
    #[cfg(feature = "robust")]
    pub(crate) fn limit(&self) -> Option<T> {
        self.sigma.map(|s| s * T::lit(OUTLIER_CUT))
    }

    /// The same gate with a new sigma.
    #[cfg(feature = "adc2-iter")]
    pub(crate) fn with_sigma(&self, sigma: Option<T>) -> Self {
        Self {
            gate: self.gate,
            runs: self.runs,
            sigma,
            tails_limit: self.tails_limit,
        }
    }
}

/// What an artificial-data pass gives a method: the statistics, the
/// robust sigma of the residuals and the largest residual.
pub(crate) type PassStats<T> = (Stats<T>, Option<T>, T);

/// The artificial-data pass under the start `(centre, w)` with the 0/1
/// weights: the statistics, the robust sigma of the residuals of the rows
/// the gate passed (`None` for the plain pass, which does not measure
/// them), and the largest residual (0 for the plain pass). `None` when the
/// pass is plain and its residuals lie beyond [`Weights::tails_limit`]:
/// the method then stops ([`Estimate::beyond_tails_limit`]).
pub(crate) fn weighted_stats<T: Real, S: Sample>(
    samples: &[S],
    norm: &Normalization<T>,
    centre: &Vector3<T>,
    w: &Matrix3<T>,
    weights: &Weights<T>,
) -> Result<Option<PassStats<T>>, Error> {
    // The plain build: one pass for every gate. No weights (only the
    // robust path sets a sigma: `weights.sigma` is always `None`), no
    // tails limit that stops the pass, and nothing a gated pass measures
    // is read without weights.
    #[cfg(not(feature = "robust"))]
    {
        Ok(Some((
            Stats::accumulate_rows(samples, norm, centre, w, &weights.gate)?,
            None,
            T::zero(),
        )))
    }
    #[cfg(feature = "robust")]
    {
        if weights.gate.is_plain() && weights.sigma.is_none() {
            let (stats, tails) = Stats::accumulate_plain(samples, norm, centre, w)?;
            // (Ablation, docs/robustness.md: `kurtosis-gate` and
            // `skewness-gate` take either figure out.)
            let outside = |(kurtosis, skewness): (T, T)| {
                (!cfg!(mag_cal_ablate = "kurtosis-gate") && tails.kurtosis > kurtosis)
                    || (!cfg!(mag_cal_ablate = "skewness-gate") && tails.skewness < -skewness)
            };
            if weights.tails_limit.is_some_and(outside) {
                // Heavy tails, or rows pulled inwards: this plain fit will not be
                // taken.
                return Ok(None);
            }
            return Ok(Some((stats, None, T::zero())));
        }
        // A tail call: this frame is gone while the measured pass runs.
        measured_stats(samples, norm, centre, w, weights)
    }
}

/// [`weighted_stats`] of a gated or weighted pass (never `None`: only a
/// plain pass has a tails limit). Out of line: the residuals' histogram
/// takes stack only while it runs, not on the plain path.
#[cfg(feature = "robust")]
#[inline(never)]
fn measured_stats<T: Real, S: Sample>(
    samples: &[S],
    norm: &Normalization<T>,
    centre: &Vector3<T>,
    w: &Matrix3<T>,
    weights: &Weights<T>,
) -> Result<Option<PassStats<T>>, Error> {
    let mut res = Residuals::new();
    let pass = Pass {
        gate: &weights.gate,
        runs: weights.runs,
        limit: weights.limit(),
    };
    let stats = AdcPass::run(samples, norm, centre, w, &pass, &mut res)?;
    Ok(Some((stats, robust_sigma(&res.hist), res.max)))
}

/// `1 / Phi^-1(3/4)`: a standard deviation from the median absolute value
/// of a normal variable.
pub(crate) const MAD_TO_SIGMA: f64 = 1.4826;

/// The robust standard deviation `1.4826 median|r|` of the residuals
/// counted in `hist`, floored at `1024 eps` (below it rounding, not noise,
/// sets the residuals), or `None` when nothing was counted.
///
/// Out of line with outlier handling, one copy for its four callers (the
/// final pass, the measured pass, the robust LS's weights and its
/// scoring): inlined, LS9 + ADC2 took 100 bytes of flash more (31 684 ->
/// 31 784). Inlined without it, where its one caller is the final pass
/// (out of line it took 40 bytes more: 18 712 -> 18 752, `bash bench.sh
/// flash`).
#[cfg_attr(feature = "robust", inline(never))]
pub(crate) fn robust_sigma<T: Real>(hist: &LogHistogram) -> Option<T> {
    let m = hist.quantile(T::lit(0.5))?;
    Some(larger(
        m * T::lit(MAD_TO_SIGMA),
        T::EPSILON * T::lit(1024.0),
    ))
}

/// What a method hands back, in normalised coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate<T: Real> {
    /// Hard iron `b'`.
    pub centre: Vector3<T>,
    /// Canonical soft-iron correction `W'` (symmetric positive definite).
    pub w: Matrix3<T>,
    /// BFGS iterations, summed (ADC1 and subMLE; 0 for the closed-form
    /// solves).
    pub iterations: u32,
    /// Passes over the samples after the LS fit.
    pub passes: u32,
    /// Warnings raised.
    pub warnings: Warnings,
    /// The direction sums of the method's artificial-data pass, when it
    /// made one at the LS fit (ADC1, ADC2): the coverage figures are then
    /// computed from them, and the final pass sums the radial error alone.
    /// They differ from the final calibration's directions by at most 2 %
    /// on the design document's scenarios (0.05 % in A).
    pub(crate) directions: Option<DirectionSums<T>>,
    /// Robust standard deviation `1.4826 median||u| - 1|` of the radial
    /// residuals in the method's last artificial-data pass (under that
    /// pass's start), over the rows its gate passed; `None` for methods
    /// without such a pass (LS, subMLE).
    pub sigma: Option<T>,
    /// The largest radial residual in that pass.
    pub max_residual: Option<T>,
    /// The method stopped after a plain pass whose residuals lie beyond
    /// [`Weights::tails_limit`], before its solve: the estimate is the LS
    /// fit it started from, and the plain fit is not clean (the plain path
    /// routes to the robust path; never set without a tails limit).
    pub(crate) beyond_tails_limit: bool,
}

impl<T: Real> Estimate<T> {
    /// The LS fit itself, as an estimate.
    pub fn from_ellipsoid(e: &Ellipsoid<T>) -> Self {
        Self {
            centre: e.centre,
            w: e.w,
            iterations: 0,
            passes: 0,
            warnings: Warnings::NONE,
            directions: None,
            sigma: None,
            max_residual: None,
            beyond_tails_limit: false,
        }
    }

    /// The LS fit `e`, from a method stopped by [`Weights::tails_limit`].
    pub(crate) fn beyond_tails_limit(e: &Ellipsoid<T>) -> Self {
        Self {
            beyond_tails_limit: true,
            ..Self::from_ellipsoid(e)
        }
    }
}
