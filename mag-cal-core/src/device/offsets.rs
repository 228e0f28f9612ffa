//! Offsets-only calibration: the soft iron `W` is known (a previous
//! calibration), the hard iron `b` is re-estimated, e.g. after a part got
//! magnetised or a battery was changed, from readings that need not cover
//! the sphere.
//!
//! With `z_i = W y_i` and `c = W b`, a reading satisfies `|z_i - c| = s`,
//! `s` the field strength in the calibrated frame (1 when unchanged):
//!
//! - strength known ([`Strength::Unchanged`]): Gauss-Newton on
//!   `sum (|z_i - c| - 1)^2` over the three unknowns of `c`, from the
//!   previous offsets, one pass an iteration (at most [`MAX_ITERATIONS`]),
//!   the step solving `(sum h_i h_i^T) dc = sum h_i r_i` with
//!   `h_i = (z_i - c) / |z_i - c|`, `r_i = |z_i - c| - 1`;
//! - strength unknown ([`Strength::Unknown`]): the linear least squares
//!   `2 d_i . c' + k = |d_i|^2` in the four unknowns `(c', k)`, with
//!   `d_i = z_i - c_0` centred on the previous offsets `c_0` (so nothing
//!   cancels in `f32`), `c = c_0 + c'` and `s^2 = k + |c'|^2`; one pass.
//!
//! Whether the readings determine the offsets is the smallest eigenvalue
//! of the normal matrix over its largest, the **determinacy**: near 1 for
//! the full sphere with the strength known (0.75 for the four-unknown
//! fit), falling as the cap of directions narrows, much faster for the
//! four-unknown fit (a small cap looks like a plane, where the centre
//! slides along the normal against the radius). Below [`REFUSE_DETERMINACY`] the fit is refused
//! ([`Error::OffsetsUndetermined`]) with the figure.
//!
//! Rows that are not finite, or beyond the working precision, are dropped
//! and counted; rows whose residual exceeds [`crate::OUTLIER_CUT`] robust
//! standard deviations of the previous pass (lagged, from a histogram) are
//! left out of the next (a magnet passing by).
//!
//! ```
//! use mag_cal_core::offsets::{refit_offsets, Strength};
//! use mag_cal_core::Calibration;
//!
//! // A calibration whose hard iron then moved by (30, -20, 10) counts.
//! let w = [[1.0 / 300.0, 0.0, 0.0], [0.0, 1.0 / 320.0, 0.0], [0.0, 0.0, 1.0 / 310.0]];
//! let old = Calibration::<f32>::new([100.0, 50.0, -20.0], w)?;
//! // Readings over a cap of directions within 60 deg of one axis.
//! let samples: Vec<[f32; 3]> = (0..200)
//!     .map(|i| {
//!         let polar = 60f32.to_radians() * (i as f32 / 200.0).sqrt();
//!         let phi = i as f32 * 2.4;
//!         let h = [polar.sin() * phi.cos(), polar.sin() * phi.sin(), polar.cos()];
//!         [130.0 + 300.0 * h[0], 30.0 + 320.0 * h[1], -10.0 + 310.0 * h[2]]
//!     })
//!     .collect();
//! let fit = refit_offsets(&samples, &old, Strength::Unchanged)?;
//! let [bx, by, bz] = fit.calibration.hard_iron();
//! assert!((bx - 130.0).abs() < 0.1 && (by - 30.0).abs() < 0.1 && (bz + 10.0).abs() < 0.1);
//! # Ok::<(), mag_cal_core::Error>(())
//! ```

use crate::tuning::OUTLIER_CUT;
use nalgebra::{Matrix3, Vector3};

use crate::numerics::histogram::LogHistogram;
use crate::numerics::linalg::{
    cholesky, cholesky_solve, columns_of, from_columns, inverse3, min_max, sym_eigenvalues,
};
use crate::sample::Sample;
use crate::steps::methods::robust_sigma;
use crate::steps::rules::{check, Rules};
use crate::{Calibration, Error, Figure, Real};

/// Cap on the Gauss-Newton iterations (each one pass over the samples).
/// From offsets that moved by a tenth of the field it takes 3-4.
pub const MAX_ITERATIONS: u32 = 12;

/// Gauss-Newton passes whose residuals set the outlier cut; later passes
/// keep the last cut.
const CUT_PASSES: u32 = 3;

/// Below this determinacy (smallest over largest eigenvalue of the normal
/// matrix) the offsets are refused as undetermined. Measured on readings
/// over a cap of directions of half-angle alpha (200 rows, noise 1 % of
/// the field per axis, medians of 20 runs): with the strength known the
/// determinacy is 0.16 at 45 deg, 0.029 at 20 deg (`e_b` 0.005 of the
/// field) and 0.016 at 15 deg (refused); with it unknown, 0.066 at 90 deg
/// (`e_b` 0.003) and 0.008 at 60 deg (refused). A full calibration
/// refuses every cap of 60 deg or less.
pub const REFUSE_DETERMINACY: f64 = 0.02;

/// What is known about the field strength.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Strength {
    /// As in the previous calibration (the same place, the same sensor
    /// gain): three unknowns, holds on small caps.
    Unchanged,
    /// Unknown (another place, or a changed gain): four unknowns, needs a
    /// wider spread of directions.
    Unknown,
}

/// An offsets-only calibration and how it was obtained.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct OffsetsFit<T: Real> {
    /// The previous soft iron with the new hard iron (and, for
    /// [`Strength::Unknown`], `W` divided by the strength ratio, so that
    /// the readings land on the unit sphere).
    pub calibration: Calibration<T>,
    /// The field strength over the previous calibration's (1 for
    /// [`Strength::Unchanged`]).
    pub strength_ratio: T,
    /// Smallest over largest eigenvalue of the normal matrix (see the
    /// module docs).
    pub determinacy: T,
    /// Passes over the samples.
    pub passes: u32,
    /// Rows the last pass used.
    pub samples_used: usize,
    /// Rows dropped: not finite, or beyond the working precision.
    pub samples_dropped: usize,
    /// Rows left out by their residual in the last pass.
    pub rejected: usize,
    /// Robust standard deviation `1.4826 median||u| - 1|` of the radial
    /// residuals under the result, units of the field.
    pub fit_error: T,
}

/// Re-estimates the hard iron of `previous` from `samples` (see the module
/// docs).
///
/// # Errors
/// - [`Error::TooFewSamples`] with fewer than [`crate::MIN_SAMPLES`]
///   usable rows;
/// - [`Error::OffsetsUndetermined`] when the determinacy is below
///   [`REFUSE_DETERMINACY`] (the directions cover too small a cap);
/// - [`Error::NoConvergence`] when Gauss-Newton does not settle within
///   [`MAX_ITERATIONS`];
/// - [`Error::OutOfRange`] for a result beyond the working precision.
pub fn refit_offsets<T: Real, S: Sample>(
    samples: &[S],
    previous: &Calibration<T>,
    strength: Strength,
) -> Result<OffsetsFit<T>, Error> {
    let w = previous.w();
    let c0 = w * previous.b();
    let mut state = State {
        w,
        centre: c0,
        radius: T::one(),
        limit: None,
        passes: 0,
    };
    let (centre, ratio, determinacy) = match strength {
        Strength::Unknown => {
            // Twice: the second pass centred on the first's result and with
            // its residual cut.
            let mut determinacy = T::zero();
            for _ in 0..2 {
                let pass = state.pass(samples, PassKind::Linear)?;
                determinacy = pass.determinacy;
                undetermined(determinacy)?;
                let (centre, ratio) = pass.solution.ok_or(Error::SingularSystem)?;
                state.limit = pass.sigma.map(|s| s * T::lit(OUTLIER_CUT));
                state.centre = centre;
                state.radius = ratio;
            }
            (state.centre, state.radius, determinacy)
        }
        Strength::Unchanged => {
            let mut determinacy = T::zero();
            let mut converged = false;
            for iteration in 0..MAX_ITERATIONS {
                let pass = state.pass(samples, PassKind::GaussNewton)?;
                determinacy = pass.determinacy;
                // The geometry hardly changes with the centre: an
                // undetermined problem is refused at once, not iterated.
                undetermined(determinacy)?;
                let (centre, _) = pass.solution.ok_or(Error::SingularSystem)?;
                let step = (centre - state.centre).amax();
                state.centre = centre;
                // The cut follows the residuals for the first passes, then
                // stays: rows that cross it back and forth would keep the
                // steps from settling.
                if iteration < CUT_PASSES {
                    state.limit = pass.sigma.map(|s| s * T::lit(OUTLIER_CUT));
                }
                // Below the square root of the type's epsilon (of the
                // field): far below the noise of any recording, and above
                // the wobble of the lagged outlier cut.
                if !(step > T::EPSILON.sqrt()) {
                    converged = true;
                    break;
                }
            }
            if !converged {
                return Err(Error::NoConvergence {
                    iterations: MAX_ITERATIONS,
                });
            }
            (state.centre, T::one(), determinacy)
        }
    };
    // b = W^-1 c (W symmetric: its columns are its rows); the soft iron
    // scaled by the strength ratio.
    let t = inverse3(&columns_of(&w)).ok_or(Error::SingularSystem)?;
    let b = from_columns(t) * centre;
    let w_new = w * (T::one() / ratio);
    let calibration = Calibration::from_canonical(b, w_new)?;
    // The figures under the result: one more pass, with the last cut in
    // the new scale (residuals divide by the ratio with W).
    state.w = w_new;
    state.centre = w_new * b;
    state.radius = T::one();
    state.limit = state.limit.map(|l| l / ratio);
    let last = state.pass(samples, PassKind::Residuals)?;
    Ok(OffsetsFit {
        calibration,
        strength_ratio: ratio,
        determinacy,
        passes: state.passes,
        samples_used: last.used,
        samples_dropped: last.dropped,
        rejected: last.rejected,
        fit_error: last.sigma.unwrap_or(T::zero()),
    })
}

/// [`Error::OffsetsUndetermined`] below [`REFUSE_DETERMINACY`].
fn undetermined<T: Real>(determinacy: T) -> Result<(), Error> {
    if determinacy >= T::lit(REFUSE_DETERMINACY) {
        Ok(())
    } else {
        Err(Error::OffsetsUndetermined {
            determinacy: Figure::new(determinacy.to_single()),
            limit: Figure::new(REFUSE_DETERMINACY as f32),
        })
    }
}

#[derive(Clone, Copy, PartialEq)]
enum PassKind {
    /// The four-unknown linear fit.
    Linear,
    /// One Gauss-Newton step on the centre.
    GaussNewton,
    /// The residuals only.
    Residuals,
}

struct State<T: Real> {
    w: Matrix3<T>,
    /// `c = W b` of the current estimate.
    centre: Vector3<T>,
    /// `s` of the current estimate.
    radius: T,
    /// Residual limit from the previous pass.
    limit: Option<T>,
    passes: u32,
}

struct PassOut<T: Real> {
    /// The new centre `c` and strength ratio `s`.
    solution: Option<(Vector3<T>, T)>,
    determinacy: T,
    sigma: Option<T>,
    used: usize,
    dropped: usize,
    rejected: usize,
}

impl<T: Real> State<T> {
    /// One pass over the samples under the current centre.
    fn pass<S: Sample>(&mut self, samples: &[S], kind: PassKind) -> Result<PassOut<T>, Error> {
        self.passes += 1;
        let mut hist = LogHistogram::new();
        let (mut a4, mut r4) = ([[T::zero(); 4]; 4], [T::zero(); 4]);
        let (mut a3, mut r3) = ([[T::zero(); 3]; 3], [T::zero(); 3]);
        let (mut used, mut dropped, mut rejected) = (0usize, 0usize, 0usize);
        let limit = self.limit.unwrap_or(T::MAX);
        for s in samples {
            let Ok(y) = check::<T, S>(s, None, &Rules::PLAIN) else {
                dropped += 1;
                continue;
            };
            let d = self.w * Vector3::from(y) - self.centre;
            let q = d.norm_squared();
            if !(q >= T::MIN_POSITIVE) || !q.is_finite() {
                dropped += 1;
                continue;
            }
            let r = q.sqrt();
            let e = r - self.radius;
            hist.add(e);
            if !(e.abs() <= limit) {
                rejected += 1;
                continue;
            }
            used += 1;
            match kind {
                PassKind::Linear => {
                    let v = [
                        d.x * T::lit(2.0),
                        d.y * T::lit(2.0),
                        d.z * T::lit(2.0),
                        T::one(),
                    ];
                    for (i, row) in a4.iter_mut().enumerate() {
                        for (j, x) in row.iter_mut().enumerate() {
                            *x += v[i] * v[j];
                        }
                        r4[i] += v[i] * q;
                    }
                }
                PassKind::GaussNewton => {
                    let h = [d.x / r, d.y / r, d.z / r];
                    for (i, row) in a3.iter_mut().enumerate() {
                        for (j, x) in row.iter_mut().enumerate() {
                            *x += h[i] * h[j];
                        }
                        r3[i] += h[i] * (r - T::one());
                    }
                }
                PassKind::Residuals => {}
            }
        }
        if used < crate::steps::normalize::MIN_SAMPLES {
            return Err(Error::TooFewSamples {
                found: used,
                required: crate::steps::normalize::MIN_SAMPLES,
            });
        }
        let sigma = robust_sigma(&hist);
        let (solution, determinacy) = match kind {
            PassKind::Linear => {
                let (lo, hi) = min_max(&sym_eigenvalues(&a4)?);
                let x = cholesky(&a4).map(|l| cholesky_solve(&l, &r4));
                let sol = x.and_then(|[cx, cy, cz, k]| {
                    let dc = Vector3::new(cx, cy, cz);
                    let s2 = k + dc.norm_squared();
                    (s2 > T::zero()).then(|| (self.centre + dc, s2.sqrt()))
                });
                (sol, lo / hi)
            }
            PassKind::GaussNewton => {
                let (lo, hi) = min_max(&sym_eigenvalues(&a3)?);
                let x = cholesky(&a3).map(|l| cholesky_solve(&l, &r3));
                // r = |z - c| - 1 decreases along h as c moves along h:
                // the step is +dc.
                let sol = x.map(|[dx, dy, dz]| (self.centre + Vector3::new(dx, dy, dz), T::one()));
                (sol, lo / hi)
            }
            PassKind::Residuals => (None, T::one()),
        };
        Ok(PassOut {
            solution,
            determinacy,
            sigma,
            used,
            dropped,
            rejected,
        })
    }
}
