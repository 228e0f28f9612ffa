//! Planar (heading-only) calibration, for a device that turns about one
//! axis only: a car, a boat, a heavy drone.
//!
//! Turning about a fixed axis `a`, the sensor sees the field
//! `h = cos(theta) a + sin(theta) (cos(phi) e1 + sin(phi) e2)` and reads
//! `y = T h + b + noise`: an ellipse in a plane, centred at
//! `b + cos(theta) T a`. Only that ellipse is observable; the offset out of
//! the plane and the rest of `T` are not, and this fit does not invent
//! them. What it gives is the turn angle `phi` up to a constant, which one
//! known heading fixes ([`PlanarCalibration::aligned`]).
//!
//! The steps, as in the three-dimensional fit:
//! 1. the glitch rules, the still periods set aside
//!    ([`crate::Dwell`], with [`PlanarConfig::still`]) and the
//!    screening ball (median centre, median distance) of the
//!    three-dimensional fit;
//! 2. the plane: the normal is the eigenvector of the smallest eigenvalue of
//!    the screened samples' covariance, its sign set to point along the
//!    `up` axis the caller names; `flatness` is that eigenvalue over the
//!    largest (0 for a plane, 1/3-1 for a sphere);
//! 3. a conic in the plane's coordinates `p` (centred on the samples' mean
//!    and divided by their median distance): the least squares
//!    `a x^2 + b y^2 + 2c xy + 2d x + 2e y = 1`, the two-dimensional LS9,
//!    refitted without rows whose algebraic residual exceeds
//!    [`crate::OUTLIER_CUT`] robust standard deviations of the previous
//!    pass when any exceeds [`crate::tuning::CLEAN_LIMIT`];
//! 4. artificial data: the unit vectors `g = W2 (p - c2) / |W2 (p - c2)|`
//!    of that ellipse and the regression `p ~ T2 g + beta` in closed form
//!    (ADC2 in two dimensions), then `W2 = (T2 T2^T)^(-1/2)`, `c2 = beta`;
//!    repeated once with the radial residual cut when the first pass has
//!    outliers;
//! 5. a last pass for the figures: the robust fit error of `|u| - 1`, the
//!    sectors of 30 deg of turn angle that hold samples, the thickness out
//!    of the plane. [`judge`] turns them into the calibration or a refusal.
//!
//! ```
//! use mag_cal_core::planar::{calibrate_planar, PlanarConfig};
//!
//! // A level vehicle turning through two circles; the sensor's z axis
//! // points down (the convention of `heading`), the hard iron is
//! // (40, -25, 10) and the soft iron stretches x by 10 %.
//! let samples: Vec<[f32; 3]> = (0..200)
//!     .map(|i| {
//!         let psi = i as f32 * 0.063;
//!         let field = [0.2 * psi.cos(), -0.2 * psi.sin(), 0.45]; // NED body frame
//!         [40.0 + 1100.0 * field[0], -25.0 + 1000.0 * field[1], 10.0 + 1000.0 * field[2]]
//!     })
//!     .collect();
//! let fit = calibrate_planar::<f32, _>(&samples, &PlanarConfig::default())?;
//! // Heading 0 at the first sample; the others follow the turn.
//! let cal = fit.calibration.aligned(samples[0], 0.0)?;
//! let h = cal.heading_deg(samples[10]); // psi = 0.63 rad
//! assert!((h - 0.63f32.to_degrees()).abs() < 0.05);
//! // The hard iron in the plane (x, y here) is found; z is not observable.
//! let centre = cal.centre();
//! assert!((centre[0] - 40.0).abs() < 0.1 && (centre[1] + 25.0).abs() < 0.1);
//! # Ok::<(), mag_cal_core::planar::Error>(())
//! ```

use crate::tuning::{CLEAN_LIMIT, OUTLIER_CUT};
use core::fmt;

use crate::device::heading::{atan2_deg, wrap_deg};
use crate::error::{Shown, Versus};
use crate::judge::planar;
use crate::numerics::histogram::LogHistogram;
use crate::numerics::linalg::{cholesky, cholesky_solve, dot, larger, sym_eigen, Mat};
use crate::robust::screen::{screen, Unscreened};
use crate::sample::Sample;
use crate::steps::methods::robust_sigma;
use crate::steps::normalize::{scan_still, MIN_SAMPLES};
use crate::steps::rules::{pieces, Drops, Gate};
use crate::{Dwell, Error as FitError, Figure, Real};

/// Why a planar fit was refused: the refusals of its own, or one it shares
/// with the three-dimensional fit.
///
/// Small and `Copy`, as the fit's [`crate::Error`], whose message a shared
/// refusal prints as it is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Error {
    /// A refusal or failure of the steps shared with the three-dimensional
    /// fit: [`crate::Error::TooFewSamples`],
    /// [`crate::Error::AllSamplesEqual`], [`crate::Error::OutOfRange`],
    /// [`crate::Error::SingularSystem`], [`crate::Error::NoSphere`] (more
    /// than half the rows on one point), [`crate::Error::TooManyOutliers`],
    /// [`crate::Error::HardlyMoved`] (too few rows beside the still
    /// periods).
    Fit(FitError),
    /// The samples do not lie near one plane; the device turned about more
    /// than one axis.
    NotPlanar {
        /// Smallest over largest eigenvalue of the samples' covariance.
        flatness: Figure,
        /// The limit it exceeds.
        limit: Figure,
    },
    /// The samples in their plane do not lie on an ellipse (robust fit
    /// error too large, or a conic that is not an ellipse, given as
    /// infinity).
    NoEllipse {
        /// Robust fit error (standard deviation of `|u| - 1`).
        fit_error: Figure,
        /// The limit it exceeds.
        limit: Figure,
    },
    /// The turns cover too little of the circle.
    ShortArc {
        /// Sectors of 30 deg of turn angle that hold samples.
        sectors: u8,
        /// Sectors required.
        required: u8,
    },
}

impl From<FitError> for Error {
    fn from(e: FitError) -> Self {
        Error::Fit(e)
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Error::Fit(e) => e.fmt(f),
            Error::NotPlanar { flatness, limit } => write!(
                f,
                "the samples do not lie in a plane (flatness {}): \
                 the device turned about more than one axis; use the three-dimensional calibration",
                Versus::new(flatness, limit, ""),
            ),
            Error::NoEllipse { fit_error, limit } if !fit_error.get().is_finite() => write!(
                f,
                "the samples in their plane do not lie on an ellipse (the fitted conic is not one; fit error limit {}): \
                 the device did not turn, or these are not one magnetometer's readings",
                Shown::alone(limit.get()),
            ),
            Error::NoEllipse { fit_error, limit } => write!(
                f,
                "the samples in their plane do not lie on an ellipse (fit error {}, in units of the field in the plane): \
                 the device did not turn, tilted by more than a few degrees while turning, or these are not one magnetometer's readings",
                Versus::new(fit_error, limit, ""),
            ),
            Error::ShortArc { sectors, required } => write!(
                f,
                "the turns cover {sectors} of 12 sectors of 30 deg, at least {required} required: turn through a full circle"
            ),
        }
    }
}

impl core::error::Error for Error {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        match self {
            Error::Fit(e) => Some(e),
            _ => None,
        }
    }
}

pub use crate::judge::planar::{judge, PlanarThresholds, MIN_SECTORS, REFUSE_NOT_PLANAR};

/// The sectors of turn angle counted by [`MIN_SECTORS`].
pub const SECTORS: u8 = 12;

/// Artificial-data passes with the residual cut on data with outliers
/// (step 4).
const ROBUST_ROUNDS: u32 = 2;

/// What to run.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct PlanarConfig {
    /// The sensor axis that points (roughly) up while the device turns,
    /// e.g. `[0, 0, -1]` for a sensor whose z axis points down (the
    /// default, the convention of [`crate::device::heading`]). It sets the sign of
    /// the turn axis, and with it the sense of the heading: clockwise seen
    /// from above is positive.
    pub up: [f64; 3],
    /// The judging limits.
    pub thresholds: PlanarThresholds,
    /// Still periods (default `true`), as [`crate::Config::still`]: the
    /// rows of a device lying still are set aside before any pass (counted in
    /// [`PlanarReport::dwell`], not outliers), so that a log that starts
    /// and ends lying still calibrates like its turns alone; too few rows
    /// left is refused as [`crate::Error::HardlyMoved`]. `false` fits
    /// every row the rules keep.
    pub still: bool,
}

impl PlanarConfig {
    /// `up = [0, 0, -1]`, the measured thresholds.
    pub const DEFAULT: Self = Self {
        up: [0.0, 0.0, -1.0],
        thresholds: PlanarThresholds::DEFAULT,
        still: true,
    };

    /// The defaults with another `up` axis.
    pub const fn with_up(up: [f64; 3]) -> Self {
        Self {
            up,
            ..Self::DEFAULT
        }
    }
}

impl PlanarConfig {
    /// `Ok` when the configuration can be used, else
    /// [`FitError::InvalidConfig`] naming the first value that cannot: an
    /// `up` axis that is not finite or is zero, or a limit
    /// ([`PlanarThresholds::validate`]).
    ///
    /// ```
    /// use mag_cal_core::planar::PlanarConfig;
    /// use mag_cal_core::Error;
    /// assert_eq!(PlanarConfig::DEFAULT.validate(), Ok(()));
    /// let bad = PlanarConfig::with_up([0.0, f64::NAN, 1.0]);
    /// assert_eq!(bad.validate(), Err(Error::InvalidConfig { field: "up" }));
    /// ```
    pub fn validate(&self) -> Result<(), FitError> {
        let [x, y, z] = self.up;
        let norm_sq = x * x + y * y + z * z;
        if !(norm_sq > 0.0 && norm_sq.is_finite()) {
            return Err(FitError::InvalidConfig { field: "up" });
        }
        self.thresholds.validate()
    }
}

impl Default for PlanarConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// A heading calibration valid for turns about one axis:
/// `u = K (y - centre)` is a unit 2-vector whose angle is the turn angle,
/// and the heading is that angle less a constant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlanarCalibration<T: Real> {
    axis: [T; 3],
    centre: [T; 3],
    matrix: [[T; 3]; 2],
    zero_deg: T,
}

impl<T: Real> PlanarCalibration<T> {
    /// A calibration from its parts (e.g. read back from storage): the turn
    /// axis (unit length), the centre of the ellipse in sensor units, the
    /// 2x3 matrix `K` by rows and the angle of heading 0, in degrees.
    ///
    /// # Errors
    /// [`crate::Error::OutOfRange`] for a non-finite part or an axis that
    /// is not of unit length (to 1e-3).
    pub fn new(
        axis: [T; 3],
        centre: [T; 3],
        matrix: [[T; 3]; 2],
        zero_deg: T,
    ) -> Result<Self, FitError> {
        let finite = axis
            .iter()
            .chain(centre.iter())
            .chain(matrix.iter().flatten())
            .all(|v| v.is_finite())
            && zero_deg.is_finite();
        let unit = (dot(&axis, &axis) - T::one()).abs() <= T::lit(1e-3);
        if finite && unit {
            Ok(Self {
                axis,
                centre,
                matrix,
                zero_deg: wrap_deg(zero_deg),
            })
        } else {
            Err(FitError::OutOfRange)
        }
    }

    /// The turn axis, unit length, in sensor coordinates, on the side of
    /// the caller's `up` axis.
    pub fn axis(&self) -> [T; 3] {
        self.axis
    }

    /// The centre of the ellipse, sensor units: the hard iron within the
    /// plane of the turns. Along the axis it is the samples' level, which
    /// includes the vertical field: not the hard iron.
    pub fn centre(&self) -> [T; 3] {
        self.centre
    }

    /// `K` (2x3, by rows): `u = K (y - centre)`.
    pub fn matrix(&self) -> [[T; 3]; 2] {
        self.matrix
    }

    /// The turn angle of heading 0, degrees.
    pub fn zero_deg(&self) -> T {
        self.zero_deg
    }

    /// The field strength in the plane (the horizontal field for a level
    /// vehicle), sensor units: `1 / sqrt(det(K K^T))`.
    pub fn plane_strength(&self) -> T {
        let [k0, k1] = self.matrix;
        let (a, b, c) = (dot(&k0, &k0), dot(&k1, &k1), dot(&k0, &k1));
        let det = a * b - c * c;
        if det > T::zero() {
            T::one() / det.sqrt().sqrt()
        } else {
            T::zero()
        }
    }

    /// `u = K (y - centre)`: unit length for a sample on the ellipse.
    pub fn apply<S: Sample>(&self, sample: S) -> [T; 2] {
        let y = sample.xyz::<T>();
        let d = [
            y[0] - self.centre[0],
            y[1] - self.centre[1],
            y[2] - self.centre[2],
        ];
        [dot(&self.matrix[0], &d), dot(&self.matrix[1], &d)]
    }

    /// The turn angle of a sample, degrees in `(-180, 180]`, increasing
    /// counter-clockwise about [`PlanarCalibration::axis`] (the field turns
    /// against the device: clockwise turns of the device seen from above
    /// increase it).
    pub fn turn_angle_deg<S: Sample>(&self, sample: S) -> T {
        let [x, y] = self.apply(sample);
        if x == T::zero() && y == T::zero() || !(x.is_finite() && y.is_finite()) {
            return T::zero();
        }
        atan2_deg(y, x)
    }

    /// The heading of a sample, degrees in `(-180, 180]`: the turn angle
    /// less that of heading 0.
    pub fn heading_deg<S: Sample>(&self, sample: S) -> T {
        wrap_deg(self.turn_angle_deg(sample) - self.zero_deg)
    }

    /// The same calibration with heading 0 set so that `sample` has the
    /// heading `heading_deg` (one reading at a known heading aligns it).
    ///
    /// # Errors
    /// [`crate::Error::OutOfRange`] for a non-finite heading.
    pub fn aligned<S: Sample>(&self, sample: S, heading_deg: T) -> Result<Self, FitError> {
        let zero = self.turn_angle_deg(sample) - heading_deg;
        Self::new(self.axis, self.centre, self.matrix, zero)
    }
}

/// The figures of a planar fit.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct PlanarReport<T: Real> {
    /// Rows the final passes used.
    pub samples_used: usize,
    /// Rows dropped by each rule.
    pub drops: Drops,
    /// Rows kept by the rules but set aside as still periods
    /// ([`crate::Dwell`]), as [`crate::Report::dwell`]: not outliers, and
    /// not counted by the outlier share. `samples_used + drops.total() + dwell +
    /// screened + rejected` is the input's length.
    pub dwell: usize,
    /// The still periods: the balls of those rows ([`Dwell::holds`] tells
    /// a row's).
    pub still_periods: Dwell<T>,
    /// Rows kept by the rules but outside the screening ball.
    pub screened: usize,
    /// Rows inside the ball left out by their residual.
    pub rejected: usize,
    /// Smallest over largest eigenvalue of the screened samples'
    /// covariance (0 for a plane).
    pub flatness: T,
    /// Robust standard deviation `1.4826 median||u| - 1|` of the rows,
    /// units of the field in the plane.
    pub fit_error: T,
    /// Sectors of 30 deg of turn angle (of [`SECTORS`]) with at least two
    /// rows used.
    pub sectors: u8,
    /// RMS distance of the rows used from the plane, units of the field in
    /// the plane (tilt of the turns).
    pub thickness: T,
    /// Angle between the turn axis and the caller's `up` axis, degrees.
    pub axis_tilt_deg: T,
    /// Passes over the samples.
    pub passes: u32,
}

/// A planar calibration and its figures.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct PlanarFit<T: Real> {
    /// The calibration, with heading 0 at turn angle 0.
    pub calibration: PlanarCalibration<T>,
    /// How it was obtained.
    pub report: PlanarReport<T>,
}

/// Fits a heading calibration to samples taken while the device turned
/// about one axis (see the module docs).
///
/// # Errors
/// A configuration that cannot be used ([`PlanarConfig::validate`], as
/// [`Error::Fit`]), the rules' and screening's refusals of the
/// three-dimensional fit ([`Error::Fit`]: too few samples, all equal, ...),
/// and from [`judge`]:
/// [`Error::NotPlanar`], [`Error::NoEllipse`], [`Error::ShortArc`], too
/// many outliers.
pub fn calibrate_planar<T: Real, S: Sample>(
    samples: &[S],
    config: &PlanarConfig,
) -> Result<PlanarFit<T>, Error> {
    config.validate()?;
    let mut dwell = crate::Dwell::NONE;
    let scanned = scan_still::<T, S>(samples, true, config.still.then_some(&mut dwell))?;
    let screening = match screen(samples, &scanned) {
        Ok(s) => s,
        Err(Unscreened::AllEqual) => return Err(FitError::AllSamplesEqual.into()),
        Err(Unscreened::Crowded) => return Err(planar::crowded(&config.thresholds)),
    };
    let gate = Gate {
        rules: screening.rules,
        screen: Some(screening.ball),
        dwell: scanned.dwell,
    };
    let mut passes = SCAN_PASSES + u32::from(!scanned.dwell.is_empty()) + screening.passes;
    let norm = screening.norm;
    let (c, m, inv_m) = (
        [norm.centre.x, norm.centre.y, norm.centre.z],
        norm.scale,
        norm.inv_scale,
    );
    let gated = Rows {
        samples,
        gate: &gate,
        centre: c,
        inv_scale: inv_m,
    };

    // Step 2: the plane.
    let (plane, flatness, axis_tilt_deg) = plane_of(&gated, config)?;
    passes += 1;

    // Steps 3 and 4: the ellipse in it, and the residual cut of its rows.
    let ((w2, c2), cut) = ellipse_of(&gated, &plane, config, &mut passes)?;

    // Step 5: the figures under the result.
    let mut figures = FigureSums::new();
    gated.each(|d| figures.add(&plane, &(w2, c2), cut, d));
    passes += 1;
    let valid = screening.valid;
    let report = figures.report(
        &w2,
        (screening.drops, *scanned.dwell),
        valid,
        (flatness, axis_tilt_deg),
        passes,
    );
    planar::judge(&report, valid, &config.thresholds)?;

    // Back to sensor units: u = W2 P (y - centre) / m.
    let Plane { mean, e1, e2, axis } = plane;
    let mut centre = c;
    let mut matrix = [[T::zero(); 3]; 2];
    for i in 0..3 {
        centre[i] += m * (mean[i] + c2[0] * e1[i] + c2[1] * e2[i]);
        for (row, w) in matrix.iter_mut().zip(&w2) {
            row[i] = (w[0] * e1[i] + w[1] * e2[i]) * inv_m;
        }
    }
    let calibration = PlanarCalibration::new(axis, centre, matrix, T::zero())?;
    Ok(PlanarFit {
        calibration,
        report,
    })
}

/// Step 2, the plane of the rows: their mean and the eigenvectors of
/// their covariance (the normal on the side of the caller's `up` axis),
/// the flatness, and the angle between the normal and `up`, degrees.
fn plane_of<T: Real, S: Sample>(
    gated: &Rows<'_, T, S>,
    config: &PlanarConfig,
) -> Result<(Plane<T>, T, T), Error> {
    let (mut n, mut s1, mut s2) = (0usize, [T::zero(); 3], [[T::zero(); 3]; 3]);
    gated.each(|d| {
        n += 1;
        for i in 0..3 {
            s1[i] += d[i];
            for j in 0..3 {
                s2[i][j] += d[i] * d[j];
            }
        }
    });
    if n < MIN_SAMPLES {
        return Err(FitError::TooFewSamples {
            found: n,
            required: MIN_SAMPLES,
        }
        .into());
    }
    let inv_n = T::one() / T::from_count(n);
    let mean = s1.map(|s| s * inv_n);
    let mut cov: Mat<T, 3> = [[T::zero(); 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            cov[i][j] = s2[i][j] * inv_n - mean[i] * mean[j];
        }
    }
    let eig = sym_eigen(&cov)?;
    let (lo, hi) = (eig.argmin(), eig.argmax());
    let largest = eig.values.get(hi).copied().unwrap_or(T::zero());
    if !(largest > T::zero()) {
        return Err(FitError::AllSamplesEqual.into());
    }
    let flatness = larger(eig.values.get(lo).copied().unwrap_or(T::zero()), T::zero()) / largest;
    let up = config.up.map(T::lit);
    let mut axis = eig.min_vector();
    if dot(&axis, &up) < T::zero() {
        axis = axis.map(|v| -v);
    }
    // e1 along the largest spread, e2 = axis x e1: e1 x e2 = axis.
    let e1 = eig.max_vector();
    let e2 = cross(&axis, &e1);
    let up_norm = dot(&up, &up).sqrt();
    let axis_tilt_deg = if up_norm > T::zero() {
        let cos = dot(&axis, &up) / up_norm;
        let sin = cross(&axis, &up).map(|v| v / up_norm);
        atan2_deg(dot(&sin, &sin).sqrt(), cos)
    } else {
        T::zero()
    };
    Ok((Plane { mean, e1, e2, axis }, flatness, axis_tilt_deg))
}

/// Steps 3 and 4, the ellipse of the rows in their plane: the conic of
/// every row, then artificial data. When the first pass's radial residuals
/// show outliers, the conic is refitted without them, and the
/// artificial-data pass repeated twice with the cut of the pass before.
/// The ellipse and the cut of its rows (`None`: every row); `passes`
/// counts the passes made.
fn ellipse_of<T: Real, S: Sample>(
    gated: &Rows<'_, T, S>,
    plane: &Plane<T>,
    config: &PlanarConfig,
    passes: &mut u32,
) -> Result<(Ellipse<T>, Option<T>), Error> {
    let (mut w2, mut c2) = conic_fit(gated, plane, None, config)?;
    *passes += 1;
    let mut cut: Option<T> = None;
    for round in 0..=ROBUST_ROUNDS {
        let adc = adc_pass(gated, plane, (w2, c2), cut)?;
        *passes += 1;
        let outliers = adc
            .sigma
            .is_some_and(|s| adc.worst > s * T::lit(CLEAN_LIMIT));
        if round == 0 && !outliers {
            (w2, c2) = adc.estimate;
            break;
        }
        let limit = adc.sigma.map(|s| s * T::lit(OUTLIER_CUT));
        if round == 0 {
            // The robust start: the conic of the rows within the cut of the
            // plain conic; its artificial data use the same cut.
            (w2, c2) = conic_fit(gated, plane, limit.map(|l| (l, (w2, c2))), config)?;
            *passes += 1;
        } else {
            (w2, c2) = adc.estimate;
        }
        cut = limit;
    }
    Ok(((w2, c2), cut))
}

/// Step 5, the figures pass under the ellipse, as a value fed one row at a
/// time ([`FigureSums::add`]): the radial residuals of every row, and of
/// the rows within the cut their sectors of turn angle and their distance
/// from the plane.
struct FigureSums<T: Real> {
    hist: LogHistogram,
    sector_rows: [u32; SECTORS as usize],
    /// Rows within the cut (with a direction).
    used: usize,
    /// Rows the gate passed.
    seen: usize,
    /// The sum of the squared distances of the rows used from the plane.
    out_of_plane: T,
}

impl<T: Real> FigureSums<T> {
    fn new() -> Self {
        Self {
            hist: LogHistogram::new(),
            sector_rows: [0; SECTORS as usize],
            used: 0,
            seen: 0,
            out_of_plane: T::zero(),
        }
    }

    /// Adds the row `d` (normalised), under `ellipse` with the residual
    /// `cut`.
    #[inline(always)]
    fn add(&mut self, plane: &Plane<T>, ellipse: &Ellipse<T>, cut: Option<T>, d: [T; 3]) {
        let (p, h) = plane.coordinates(d);
        self.seen += 1;
        let (e, u, r) = radial(ellipse, p);
        self.hist.add(e);
        if cut.is_some_and(|limit| !(e <= limit)) || !(r > T::zero()) {
            return;
        }
        self.used += 1;
        self.out_of_plane += h * h;
        let angle = atan2_deg(u[1], u[0]) + T::lit(180.0);
        let k = (angle * T::lit(f64::from(SECTORS) / 360.0)).to_count();
        if let Some(cell) = self.sector_rows.get_mut(k.min(SECTORS as usize - 1)) {
            *cell = cell.saturating_add(1);
        }
    }

    /// The report of the rows added under the ellipse `W2` = `w2`: `drops`
    /// and `valid` are the rules', `dwell` the still periods set aside,
    /// `plane` the flatness and the axis's tilt from `up` (step 2),
    /// `passes` every pass made.
    fn report(
        &self,
        w2: &[[T; 2]; 2],
        (drops, dwell): (Drops, Dwell<T>),
        valid: usize,
        (flatness, axis_tilt_deg): (T, T),
        passes: u32,
    ) -> PlanarReport<T> {
        let fit_error = robust_sigma::<T>(&self.hist).unwrap_or(T::zero());
        let sectors = self.sector_rows.iter().filter(|&&k| k >= 2).count() as u8;
        // The in-plane field strength in `p` units: 1 / sqrt(det W2).
        let det = w2[0][0] * w2[1][1] - w2[0][1] * w2[1][0];
        let radius = if det > T::zero() {
            T::one() / det.sqrt()
        } else {
            T::zero()
        };
        let used = self.used;
        let thickness = if used > 0 && radius > T::zero() {
            (self.out_of_plane / T::from_count(used)).sqrt() / radius
        } else {
            T::zero()
        };
        PlanarReport {
            samples_used: used,
            drops,
            dwell: dwell.rows(),
            still_periods: dwell,
            screened: valid.saturating_sub(self.seen),
            rejected: self.seen - used,
            flatness,
            fit_error,
            sectors,
            thickness,
            axis_tilt_deg,
            passes,
        }
    }
}

/// Passes of the rules' scan: the drop count and the sums (with still
/// periods set aside, one more without their rows, counted; the guard's
/// second when it leaves a ball out is not).
const SCAN_PASSES: u32 = 2;

/// The rows a pass visits, in normalised coordinates `(y - c) / m`.
struct Rows<'a, T: Real, S: Sample> {
    samples: &'a [S],
    gate: &'a Gate<'a, T>,
    centre: [T; 3],
    inv_scale: T,
}

impl<T: Real, S: Sample> Rows<'_, T, S> {
    /// Calls `f` on every row the gate passes (outside the still periods
    /// too).
    #[inline(always)]
    fn each(&self, mut f: impl FnMut([T; 3])) {
        let (c, k) = (self.centre, self.inv_scale);
        for (prev, block) in pieces(self.samples, crate::steps::moments::BLOCK) {
            for y in self.gate.rows(block, prev) {
                f([(y[0] - c[0]) * k, (y[1] - c[1]) * k, (y[2] - c[2]) * k]);
            }
        }
    }
}

/// The plane of the turns, in normalised coordinates.
struct Plane<T: Real> {
    mean: [T; 3],
    e1: [T; 3],
    e2: [T; 3],
    axis: [T; 3],
}

impl<T: Real> Plane<T> {
    /// The coordinates in the plane and the distance along the axis.
    #[inline(always)]
    fn coordinates(&self, d: [T; 3]) -> ([T; 2], T) {
        let m = self.mean;
        let q = [d[0] - m[0], d[1] - m[1], d[2] - m[2]];
        ([dot(&q, &self.e1), dot(&q, &self.e2)], dot(&q, &self.axis))
    }
}

/// An ellipse in the plane: `W2` (symmetric) and the centre `c2`.
type Ellipse<T> = ([[T; 2]; 2], [T; 2]);

/// The radial residual `| |W2 (p - c2)| - 1 |` and `u = W2 (p - c2)`.
#[inline(always)]
fn radial<T: Real>(e: &Ellipse<T>, p: [T; 2]) -> (T, [T; 2], T) {
    let (w2, c2) = e;
    let u = mul2(w2, [p[0] - c2[0], p[1] - c2[1]]);
    let r = (u[0] * u[0] + u[1] * u[1]).sqrt();
    ((r - T::one()).abs(), u, r)
}

/// The conic least squares over the rows, or over those whose radial
/// residual under an ellipse is within a limit; its ellipse.
fn conic_fit<T: Real, S: Sample>(
    rows: &Rows<'_, T, S>,
    plane: &Plane<T>,
    within: Option<(T, Ellipse<T>)>,
    config: &PlanarConfig,
) -> Result<Ellipse<T>, Error> {
    let (mut a5, mut r5) = ([[T::zero(); 5]; 5], [T::zero(); 5]);
    let mut kept = 0usize;
    rows.each(|d| {
        let (p, _) = plane.coordinates(d);
        if let Some((limit, e)) = &within {
            if !(radial(e, p).0 <= *limit) {
                return;
            }
        }
        kept += 1;
        let v = conic_row(p);
        for i in 0..5 {
            r5[i] += v[i];
            for j in 0..5 {
                a5[i][j] += v[i] * v[j];
            }
        }
    });
    if kept < MIN_SAMPLES {
        return Err(FitError::TooFewSamples {
            found: kept,
            required: MIN_SAMPLES,
        }
        .into());
    }
    let phi = cholesky(&a5)
        .map(|l| cholesky_solve(&l, &r5))
        .ok_or(FitError::SingularSystem)?;
    ellipse(&phi).ok_or_else(|| planar::not_an_ellipse(&config.thresholds))
}

/// What an artificial-data pass found.
struct AdcOut<T: Real> {
    estimate: Ellipse<T>,
    /// Robust standard deviation of the radial residuals under the
    /// pass's starting ellipse (every row, the cut ones included).
    sigma: Option<T>,
    /// Their largest magnitude.
    worst: T,
}

/// One artificial-data pass from `start`, without rows beyond `cut`.
fn adc_pass<T: Real, S: Sample>(
    rows: &Rows<'_, T, S>,
    plane: &Plane<T>,
    start: Ellipse<T>,
    cut: Option<T>,
) -> Result<AdcOut<T>, Error> {
    let mut sums = AdcSums::new();
    let mut hist = LogHistogram::new();
    let mut worst = T::zero();
    rows.each(|d| {
        let (p, _) = plane.coordinates(d);
        let (e, u, r) = radial(&start, p);
        if !(r > T::zero()) {
            return;
        }
        hist.add(e);
        worst = larger(worst, e);
        if cut.is_some_and(|limit| !(e <= limit)) {
            return;
        }
        sums.add(p, [u[0] / r, u[1] / r]);
    });
    Ok(AdcOut {
        estimate: sums.solve()?,
        sigma: robust_sigma::<T>(&hist),
        worst,
    })
}

/// The row of the conic least squares for a point of the plane.
#[inline(always)]
fn conic_row<T: Real>(p: [T; 2]) -> [T; 5] {
    let two = T::lit(2.0);
    [
        p[0] * p[0],
        p[1] * p[1],
        two * p[0] * p[1],
        two * p[0],
        two * p[1],
    ]
}

/// `W2` (symmetric, `W2^2 = Q / k`) and the centre of the conic `phi`, or
/// `None` when it is not an ellipse.
fn ellipse<T: Real>(phi: &[T; 5]) -> Option<Ellipse<T>> {
    let [a, b, c, d, e] = *phi;
    let det = a * b - c * c;
    if !(a > T::zero() && det > T::zero()) {
        return None;
    }
    // Q c2 = -[d, e].
    let c2 = [(-d * b + e * c) / det, (-e * a + d * c) / det];
    let k = T::one() + a * c2[0] * c2[0] + b * c2[1] * c2[1] + T::lit(2.0) * c * c2[0] * c2[1];
    if !(k > T::zero()) {
        return None;
    }
    let w2 = sqrt2(&[[a / k, c / k], [c / k, b / k]])?;
    Some((w2, c2))
}

/// The symmetric square root of a symmetric positive definite 2x2 matrix:
/// `(M + sqrt(det M) I) / sqrt(tr M + 2 sqrt(det M))`.
fn sqrt2<T: Real>(m: &[[T; 2]; 2]) -> Option<[[T; 2]; 2]> {
    let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
    if !(det > T::zero()) {
        return None;
    }
    let s = det.sqrt();
    let t = (m[0][0] + m[1][1] + T::lit(2.0) * s).sqrt();
    if !(t > T::zero()) || !t.is_finite() {
        return None;
    }
    Some([
        [(m[0][0] + s) / t, m[0][1] / t],
        [m[1][0] / t, (m[1][1] + s) / t],
    ])
}

fn mul2<T: Real>(m: &[[T; 2]; 2], v: [T; 2]) -> [T; 2] {
    [
        m[0][0] * v[0] + m[0][1] * v[1],
        m[1][0] * v[0] + m[1][1] * v[1],
    ]
}

fn cross<T: Real>(a: &[T; 3], b: &[T; 3]) -> [T; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// The sums of the regression `p ~ T2 g + beta`.
struct AdcSums<T: Real> {
    /// `sum [g, 1] [g, 1]^T`.
    gg: Mat<T, 3>,
    /// `sum p [g, 1]^T`, by rows of `p`.
    pg: [[T; 3]; 2],
}

impl<T: Real> AdcSums<T> {
    fn new() -> Self {
        Self {
            gg: [[T::zero(); 3]; 3],
            pg: [[T::zero(); 3]; 2],
        }
    }

    #[inline(always)]
    fn add(&mut self, p: [T; 2], g: [T; 2]) {
        let x = [g[0], g[1], T::one()];
        for i in 0..3 {
            for j in 0..3 {
                self.gg[i][j] += x[i] * x[j];
            }
            self.pg[0][i] += p[0] * x[i];
            self.pg[1][i] += p[1] * x[i];
        }
    }

    /// `W2 = (T2 T2^T)^(-1/2)` and `c2 = beta`.
    fn solve(&self) -> Result<Ellipse<T>, FitError> {
        if !(self.gg[2][2] >= T::from_count(MIN_SAMPLES)) {
            return Err(FitError::TooFewSamples {
                found: self.gg[2][2].to_count(),
                required: MIN_SAMPLES,
            });
        }
        let l = cholesky(&self.gg).ok_or(FitError::SingularSystem)?;
        // Each row of [T2 | beta] solves (sum x x^T) t = sum p_r x.
        let r0 = cholesky_solve(&l, &self.pg[0]);
        let r1 = cholesky_solve(&l, &self.pg[1]);
        let t = [[r0[0], r0[1]], [r1[0], r1[1]]];
        let tt = [
            [
                t[0][0] * t[0][0] + t[0][1] * t[0][1],
                t[0][0] * t[1][0] + t[0][1] * t[1][1],
            ],
            [
                t[1][0] * t[0][0] + t[1][1] * t[0][1],
                t[1][0] * t[1][0] + t[1][1] * t[1][1],
            ],
        ];
        // (T2 T2^T)^(-1/2) = inverse of its square root.
        let s = sqrt2(&tt).ok_or(FitError::SingularSystem)?;
        let det = s[0][0] * s[1][1] - s[0][1] * s[1][0];
        if !(det > T::zero()) || !det.is_finite() {
            return Err(FitError::SingularSystem);
        }
        let w = [
            [s[1][1] / det, -s[0][1] / det],
            [-s[1][0] / det, s[0][0] / det],
        ];
        Ok((w, [r0[2], r1[2]]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sqrt2_squares_back() {
        let m = [[2.0f64, 0.3], [0.3, 0.5]];
        let s = sqrt2(&m).unwrap();
        for i in 0..2 {
            for j in 0..2 {
                let sq = s[i][0] * s[0][j] + s[i][1] * s[1][j];
                assert!((sq - m[i][j]).abs() < 1e-12, "{i}{j}: {sq}");
            }
        }
    }

    #[test]
    fn ellipse_of_a_known_conic() {
        // (x - 0.1)^2 / 4 + (y + 0.2)^2 = 1, written as phi . v = 1.
        let (cx, cy, a, b) = (0.1f64, -0.2, 0.25, 1.0);
        let k = 1.0 - a * cx * cx - b * cy * cy;
        let phi = [a / k, b / k, 0.0, -a * cx / k, -b * cy / k];
        let (w2, c2) = ellipse(&phi).unwrap();
        assert!((c2[0] - cx).abs() < 1e-12 && (c2[1] - cy).abs() < 1e-12);
        assert!((w2[0][0] - 0.5).abs() < 1e-12 && (w2[1][1] - 1.0).abs() < 1e-12);
        assert!(w2[0][1].abs() < 1e-12);
    }

    #[test]
    fn a_configuration_that_cannot_be_used_is_refused_by_name() {
        // A level turn the defaults accept.
        let ring: [[f32; 3]; 120] = core::array::from_fn(|i| {
            let a = i as f32 * core::f32::consts::TAU / 120.0;
            [
                30.0 + 40.0 * libm::cosf(a),
                -5.0 + 35.0 * libm::sinf(a),
                20.0,
            ]
        });
        assert!(calibrate_planar::<f32, _>(&ring, &PlanarConfig::DEFAULT).is_ok());
        let cases: [(PlanarConfig, &str); 5] = [
            (PlanarConfig::with_up([0.0; 3]), "up"),
            (PlanarConfig::with_up([f64::INFINITY, 0.0, 0.0]), "up"),
            (
                PlanarConfig {
                    thresholds: PlanarThresholds {
                        refuse_fit_error: f32::NAN,
                        ..PlanarThresholds::DEFAULT
                    },
                    ..PlanarConfig::DEFAULT
                },
                "refuse_fit_error",
            ),
            (
                PlanarConfig {
                    thresholds: PlanarThresholds {
                        refuse_outlier_share: 1.5,
                        ..PlanarThresholds::DEFAULT
                    },
                    ..PlanarConfig::DEFAULT
                },
                "refuse_outlier_share",
            ),
            (
                PlanarConfig {
                    thresholds: PlanarThresholds {
                        min_sectors: SECTORS + 1,
                        ..PlanarThresholds::DEFAULT
                    },
                    ..PlanarConfig::DEFAULT
                },
                "min_sectors",
            ),
        ];
        for (config, field) in cases {
            let got = calibrate_planar::<f32, _>(&ring, &config).map(|_| ());
            assert_eq!(got, Err(Error::Fit(FitError::InvalidConfig { field })));
        }
    }
}
