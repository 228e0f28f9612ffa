//! Contaminated magnetometer data with known truth, and the study of how a
//! calibration configuration copes with it (design document,
//! `shared/design/ALGORITHMS.md`, section 14).
//!
//! Real logs and on-device collections contain rows that are not on the
//! ellipsoid: I2C glitches (wild values, a saturated or clipped axis, exact
//! zeros), a stuck sensor (repeated rows), and disturbances (a magnet or a
//! motor current displacing one stretch of the trajectory). This module
//! builds such data from a clean simulated run and keeps the clean rows, so
//! that a fit on the contaminated rows can be compared with the same
//! method's fit on the clean rows of the same run.
//!
//! # Data
//! A [`CleanRun`] is `y_i = T h_i + b + e_i` (section 1) in one of two unit
//! systems ([`Units`]):
//! - [`Units::Counts`]: `T = 400 * sim::random_t` (field strength
//!   `|det T|^(1/3)` = 415 counts), `b` uniform in +-300 counts per axis,
//!   noise 1 % of the nominal field (4 counts) per axis, rows rounded to
//!   integers and stored also as `[i16; 3]`;
//! - [`Units::MicroTesla`]: `T = 50 * sim::random_t` (51.9 uT), `b` uniform
//!   in +-40 uT per axis, noise 0.5 uT, floats.
//!
//! `n` = 600 or 1000 directions, uniform on the full sphere or on the
//! +-30 deg band ([`Coverage`]), put in the order of a path over the
//! sphere ([`order_along_path`]), so that a contiguous index range is a
//! compact patch of directions: the trajectory of a sensor turned by hand.
//!
//! [`contaminate`] replaces a fraction `f` of the rows by one [`Kind`] of
//! contamination and marks exactly the rows it changed;
//! [`degenerate`] builds inputs that are not calibration data at all
//! ([`Degenerate`]), which a good calibrator refuses.
//!
//! # Metrics
//! Gauge-free (section 1): with `M = W^T W` (`W` the calibration's
//! soft-iron correction, [`mag_cal_core::Calibration::soft_iron`]) and
//! `M_true = T^-T T^-1`, `e_M = |M_hat - M_true|_F / |M_true|_F` and
//! `e_b = |b_hat - b| / rho`, `rho = |det T|^(1/3)` the true field strength
//! ([`fit_errors`]). The *error ratio* of a run is the error on the
//! contaminated rows over the error of the same method, precision and
//! sample type on the clean rows of the same run, the denominator clamped
//! below at [`RATIO_FLOOR`] ([`error_ratio`]).
//!
//! # Study
//! [`run_study`] runs one [`mag_cal_core::Config`] in one [`Precision`] over
//! a [`Grid`] of cells (case x coverage x units, `runs` runs a cell) and
//! collects per cell a [`CellStats`]: accepted share, median error ratios,
//! the share of "silently wrong" results ([`WRONG_LIMIT`]) and the refusal
//! reasons. [`render_table`] writes the markdown table of the
//! `contamination-table` binary. Every run has its own seed, independent of
//! the grid's other cells and of the thread count: the tables are
//! reproducible bit for bit (timings aside). The clean run of run `r` of a
//! units x coverage block is the same for every case, configuration and
//! precision, so the tables compare them on identical data. Cost: the full
//! grid ([`Grid::full`], 268 cells) at 64 runs a cell is 17 152 fits, about
//! 1 s for one-step ADC2 and 2 s for iterated ADC2 per precision (release,
//! x86_64).
//!
//! ```
//! use host_tests::contamination::{
//!     contaminate, fit_errors, fit_rows, CleanRun, Coverage, Kind, Precision, Setting, Units,
//! };
//! use host_tests::sim::Rng;
//! use mag_cal_core::Config;
//!
//! let setting = Setting { units: Units::Counts, coverage: Coverage::Sphere, n: 600 };
//! let run = CleanRun::generate(setting, &mut Rng(1));
//! let dirty = contaminate(&run, Kind::Zeros, 0.01, &mut Rng(2));
//! assert_eq!(dirty.count(), 6);
//! let zeros = dirty.marked_rows();
//! assert_eq!(dirty.rows.counts.as_ref().unwrap()[zeros[0]], [0, 0, 0]);
//!
//! // The same method on the clean and the contaminated rows (as i16, in f32).
//! let config = Config::default();
//! let clean = fit_rows(&run.clean, &config, Precision::F32).unwrap();
//! let e_clean = fit_errors(&clean.b, &clean.w, &run.truth);
//! assert!(e_clean.e_m < 0.02 && e_clean.e_b < 0.02);
//! if let Ok(fit) = fit_rows(&dirty.rows, &config, Precision::F32) {
//!     let e = fit_errors(&fit.b, &fit.w, &run.truth);
//!     println!("e_M ratio {}", e.e_m / e_clean.e_m.max(1e-4));
//! }
//! ```

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use mag_cal_core::{calibrate, Config, Error, Fit, Real, Warnings};
use nalgebra::{Matrix3, Vector3};

use crate::metrics::median;
use crate::scenarios::Truth;
use crate::sim::{self, Rng};

/// Nominal field of [`Units::Counts`], counts (the scale of `T`).
pub const FIELD_COUNTS: f64 = 400.0;
/// Nominal field of [`Units::MicroTesla`], uT.
pub const FIELD_UT: f64 = 50.0;
/// Largest hard-iron component of [`Units::Counts`] per axis, counts (a
/// few hundred; 0.75 of the nominal field).
pub const OFFSET_COUNTS: f64 = 300.0;
/// Largest hard-iron component of [`Units::MicroTesla`] per axis, uT (0.8
/// of the nominal field).
pub const OFFSET_UT: f64 = 40.0;
/// Noise standard deviation per axis, as a fraction of the nominal field.
pub const NOISE_REL: f64 = 0.01;
/// Elevation limit of [`Coverage::Band`], degrees.
pub const BAND_DEG: f64 = 30.0;
/// The run sizes; run `r` of a cell has `SIZES[r % 2]` rows.
pub const SIZES: [usize; 2] = [600, 1000];
/// The contaminated fractions of the study.
pub const FRACTIONS: [f64; 7] = [0.005, 0.01, 0.02, 0.05, 0.10, 0.20, 0.30];
/// Range of a wild value ([`Kind::Spike`]) in uT: +-5000 uT, 100x the
/// field. In counts the range is the whole `i16` (+-32767).
pub const SPIKE_UT: f64 = 5000.0;
/// The rail of a saturated axis ([`Kind::RailSaturation`]) in uT: the full
/// scale of an AK8963 / AK09916, +-4912 uT. In counts the rails are
/// `i16::MAX` and `i16::MIN`.
pub const RAIL_UT: f64 = 4912.0;
/// Clip level of [`Kind::ClipSaturation`], as a fraction of an axis's
/// extent from the centre of the clean data.
pub const CLIP_LEVEL: f64 = 0.8;
/// Length of [`Kind::Displace03`]'s and [`Kind::Patch`]'s displacement, in
/// field strengths.
pub const DISPLACE_SMALL: f64 = 0.3;
/// Length of [`Kind::Displace1`]'s displacement, in field strengths.
pub const DISPLACE_LARGE: f64 = 1.0;
/// Peak of [`Kind::Moving`]'s displacement, in field strengths.
pub const MOVING_PEAK: f64 = 0.5;
/// Shortest and longest run of repeats of [`Kind::Stuck`].
pub const STUCK_RUN: (usize, usize) = (5, 20);
/// Rows of [`Degenerate::Stationary`].
pub const STATIONARY_ROWS: usize = 200;
/// Floor of the clean error in [`error_ratio`]: a clean fit better than
/// this (relative to the field, or to `|M|`) counts as this good, so a
/// near-perfect clean fit does not turn a harmless contaminated one into
/// a huge ratio. At 1 % noise and n >= 600 the clean `e_M` and `e_b` are
/// about 1e-3, so the floor rarely acts.
pub const RATIO_FLOOR: f64 = 1e-4;
/// A result is *silently wrong* when it is accepted with `e_M` or `e_b`
/// above this.
pub const WRONG_LIMIT: f64 = 0.05;

// ---------------------------------------------------------------- settings

/// The sensor's unit system.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Units {
    /// Integer counts (`[i16; 3]`), field about 400 counts.
    Counts,
    /// Microtesla as floats, field about 50 uT.
    MicroTesla,
}

impl Units {
    /// Both unit systems.
    pub const ALL: [Units; 2] = [Units::Counts, Units::MicroTesla];

    /// Short name: `counts`, `uT`.
    pub const fn name(self) -> &'static str {
        match self {
            Units::Counts => "counts",
            Units::MicroTesla => "uT",
        }
    }

    /// The scale of `T` ([`FIELD_COUNTS`], [`FIELD_UT`]).
    pub const fn nominal_field(self) -> f64 {
        match self {
            Units::Counts => FIELD_COUNTS,
            Units::MicroTesla => FIELD_UT,
        }
    }

    /// Largest hard-iron component.
    pub const fn max_offset(self) -> f64 {
        match self {
            Units::Counts => OFFSET_COUNTS,
            Units::MicroTesla => OFFSET_UT,
        }
    }

    /// Noise standard deviation per axis.
    pub fn noise_std(self) -> f64 {
        NOISE_REL * self.nominal_field()
    }
}

/// Which directions the sensor visits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Coverage {
    /// Uniform on the whole sphere.
    Sphere,
    /// Uniform with elevation within +-[`BAND_DEG`].
    Band,
}

impl Coverage {
    /// Both coverages.
    pub const ALL: [Coverage; 2] = [Coverage::Sphere, Coverage::Band];

    /// Short name: `sphere`, `band`.
    pub const fn name(self) -> &'static str {
        match self {
            Coverage::Sphere => "sphere",
            Coverage::Band => "band",
        }
    }
}

/// The shape of a clean run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Setting {
    /// Unit system.
    pub units: Units,
    /// Directions.
    pub coverage: Coverage,
    /// Rows.
    pub n: usize,
}

// ---------------------------------------------------------------- rows

/// Sample rows in both forms the core takes.
#[derive(Clone, Debug, PartialEq)]
pub struct Rows {
    /// The rows as floats; for [`Units::Counts`] exactly the integers of
    /// `counts`.
    pub samples: Vec<[f64; 3]>,
    /// For [`Units::Counts`], the rows as the sensor gives them; `None` for
    /// [`Units::MicroTesla`].
    pub counts: Option<Vec<[i16; 3]>>,
}

impl Rows {
    /// Rows from values: for [`Units::Counts`] every component rounded to
    /// the nearest integer and saturated to the `i16` range (as the sensor
    /// would), for [`Units::MicroTesla`] kept as they are.
    pub fn from_values(units: Units, values: Vec<[f64; 3]>) -> Self {
        match units {
            Units::MicroTesla => Rows {
                samples: values,
                counts: None,
            },
            Units::Counts => {
                let counts: Vec<[i16; 3]> = values.iter().map(|y| y.map(to_i16)).collect();
                Rows {
                    samples: counts.iter().map(|c| c.map(f64::from)).collect(),
                    counts: Some(counts),
                }
            }
        }
    }

    /// Rows.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// No rows.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }
}

/// Round to nearest and saturate, as an ADC register would.
fn to_i16(v: f64) -> i16 {
    // `as` saturates (and maps NaN to 0); no NaN reaches here.
    v.round() as i16
}

// ---------------------------------------------------------------- clean run

/// A clean simulated run with its truth.
#[derive(Clone, Debug)]
pub struct CleanRun {
    /// Units, coverage and size.
    pub setting: Setting,
    /// `y = T h + b + e`.
    pub truth: Truth,
    /// True field strength `rho = |det T|^(1/3)`, sensor units.
    pub field: f64,
    /// Noise standard deviation per axis, sensor units.
    pub noise_std: f64,
    /// The true directions `h_i`, in path order ([`order_along_path`]).
    pub dirs: Vec<Vector3<f64>>,
    /// The clean rows `y_i` (rounded for counts).
    pub clean: Rows,
}

impl CleanRun {
    /// Draws a run: `T`, `b`, the directions (then ordered along a path)
    /// and the noise, all from `rng`.
    pub fn generate(setting: Setting, rng: &mut Rng) -> Self {
        let units = setting.units;
        let t = sim::random_t(rng) * units.nominal_field();
        let b = Vector3::from_fn(|_, _| (2.0 * rng.unit() - 1.0) * units.max_offset());
        let mut dirs = match setting.coverage {
            Coverage::Sphere => sim::sphere(setting.n, rng),
            Coverage::Band => sim::band(setting.n, BAND_DEG, rng),
        };
        order_along_path(&mut dirs);
        let noise_std = units.noise_std();
        let values = sim::make_samples(&t, &b, &dirs, noise_std, rng);
        CleanRun {
            setting,
            truth: Truth { t, b },
            field: t.determinant().abs().cbrt(),
            noise_std,
            dirs,
            clean: Rows::from_values(units, values),
        }
    }

    /// Rows.
    pub fn len(&self) -> usize {
        self.clean.len()
    }

    /// No rows.
    pub fn is_empty(&self) -> bool {
        self.clean.is_empty()
    }

    /// The noise-free reading of direction `h`.
    fn reading(&self, h: &Vector3<f64>) -> Vector3<f64> {
        self.truth.reading(h)
    }

    /// One noise vector of the run.
    fn noise(&self, rng: &mut Rng) -> Vector3<f64> {
        Vector3::new(rng.normal(), rng.normal(), rng.normal()) * self.noise_std
    }
}

/// Puts directions in the order of a closed path over the sphere, so that
/// a contiguous range of indices is a compact patch of directions.
///
/// The path is a Hilbert curve on the equal-area cylindrical map
/// `(azimuth, z)`, cut into `m` nearly square tiles along the azimuth (3 for
/// the sphere, 6 for a +-30 deg band; `m = round(2 pi / (z_max - z_min))`).
/// Each tile's curve starts at its lower left corner and ends at its lower
/// right one, where the next tile's begins, and the last ends where the
/// first begins. Equal-area map: a range of `k` of `n` indices covers
/// about `k / n` of the visited area. The order is a pure function of the
/// directions (no randomness).
pub fn order_along_path(dirs: &mut [Vector3<f64>]) {
    const ORDER: u32 = 16;
    const SIDE: u64 = 1 << ORDER;
    if dirs.is_empty() {
        return;
    }
    let (lo, hi) = dirs
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), d| {
            (lo.min(d.z), hi.max(d.z))
        });
    let height = (hi - lo).max(1e-9);
    let tiles = ((std::f64::consts::TAU / height).round() as u64).max(1);
    let cell = |x: f64| ((x * SIDE as f64) as u64).min(SIDE - 1);
    let key = |d: &Vector3<f64>| {
        let az = d.y.atan2(d.x).rem_euclid(std::f64::consts::TAU) / std::f64::consts::TAU;
        let a = (az * tiles as f64).min(tiles as f64 - 1e-12);
        let tile = a.floor();
        let x = cell(a - tile);
        let y = cell((d.z - lo) / height);
        (tile as u64) * SIDE * SIDE + hilbert_index(ORDER, x, y)
    };
    dirs.sort_by_cached_key(key);
}

/// Index of cell `(x, y)` along the Hilbert curve of a `2^order` square
/// grid, from `(0, 0)` to `(2^order - 1, 0)` (the classic `xy2d`).
pub fn hilbert_index(order: u32, mut x: u64, mut y: u64) -> u64 {
    let n = 1u64 << order;
    let mut d = 0;
    let mut s = n / 2;
    while s > 0 {
        let rx = u64::from(x & s > 0);
        let ry = u64::from(y & s > 0);
        d += s * s * ((3 * rx) ^ ry);
        if ry == 0 {
            if rx == 1 {
                x = n - 1 - x;
                y = n - 1 - y;
            }
            std::mem::swap(&mut x, &mut y);
        }
        s /= 2;
    }
    d
}

// ---------------------------------------------------------------- contamination

/// One kind of contamination.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Kind {
    /// Wild values (an I2C glitch): the row, or with probability 1/2 one
    /// random axis only, uniform over the sensor's range (counts: +-32767;
    /// uT: +-[`SPIKE_UT`]).
    Spike,
    /// One random axis at a rail of the sample type, random sign (counts:
    /// `i16::MAX` or `i16::MIN`; uT: +-[`RAIL_UT`]).
    RailSaturation,
    /// One axis clipped at a lower level: at [`CLIP_LEVEL`] of that axis's
    /// extent of the clean data from its centre (mid-range), on the side the
    /// value lies. Only rows beyond the level of some axis are chosen, and
    /// the axis beyond its level by the largest share of the extent is the
    /// one clipped, so every clipped value moves towards the centre. (A real
    /// lower range would clip every row beyond it, about half of them.)
    ClipSaturation,
    /// A sensor range that ends below the field on one side of one axis:
    /// every row beyond a level is clipped to it (the level is the one
    /// that clips the fraction of the rows), as a saturating axis does.
    /// Unlike [`Kind::ClipSaturation`], the clipped rows share the axis's
    /// extreme value. Rows already at the level (ties in counts) stay as
    /// they are, so a few fewer rows than the fraction may change.
    RangeClip,
    /// Rows set to exactly `(0, 0, 0)`.
    Zeros,
    /// A stuck sensor: a row repeated 5 to 20 times in place of the rows
    /// that follow it; the repeats are the contaminated rows (the stuck row
    /// itself is clean). The last run is shorter when fewer repeats remain.
    Stuck,
    /// Isolated rows displaced by a random vector of 0.3 field.
    Displace03,
    /// Isolated rows displaced by a random vector of 1 field.
    Displace1,
    /// A contiguous stretch of the trajectory displaced by one constant
    /// random vector of 0.3 field.
    Patch,
    /// A moving disturbance, e.g. a magnet passing: a contiguous stretch of
    /// `k` rows displaced along one random direction by
    /// `0.5 field sin(pi t_j)`, `t_j = (j + 1/2) / k`.
    Moving,
}

impl Kind {
    /// Every kind, in the order of the tables.
    pub const ALL: [Kind; 10] = [
        Kind::Spike,
        Kind::RailSaturation,
        Kind::ClipSaturation,
        Kind::RangeClip,
        Kind::Zeros,
        Kind::Stuck,
        Kind::Displace03,
        Kind::Displace1,
        Kind::Patch,
        Kind::Moving,
    ];

    /// Short name, as the tables print it.
    pub const fn name(self) -> &'static str {
        match self {
            Kind::Spike => "spike",
            Kind::RailSaturation => "rail",
            Kind::ClipSaturation => "clip",
            Kind::RangeClip => "range-clip",
            Kind::Zeros => "zeros",
            Kind::Stuck => "stuck",
            Kind::Displace03 => "displace-0.3",
            Kind::Displace1 => "displace-1",
            Kind::Patch => "patch",
            Kind::Moving => "moving",
        }
    }

    /// The kind named `name` (see [`Kind::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// Inputs that are not calibration data: a good calibrator refuses them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Degenerate {
    /// A device that does not turn: [`STATIONARY_ROWS`] readings of one
    /// direction with the run's noise.
    Stationary,
    /// A filled ball: `n` points uniform inside the run's ellipsoid (not on
    /// its shell), with the run's noise.
    NoiseBall,
    /// `n` points uniform in the cube of half side one field around `b`.
    Cube,
}

impl Degenerate {
    /// Every degenerate input.
    pub const ALL: [Degenerate; 3] = [
        Degenerate::Stationary,
        Degenerate::NoiseBall,
        Degenerate::Cube,
    ];

    /// Short name, as the tables print it.
    pub const fn name(self) -> &'static str {
        match self {
            Degenerate::Stationary => "stationary",
            Degenerate::NoiseBall => "noise-ball",
            Degenerate::Cube => "cube",
        }
    }
}

/// A run with a fraction of its rows contaminated. The truth and the clean
/// rows are those of the [`CleanRun`] it was made from.
#[derive(Clone, Debug)]
pub struct Contaminated {
    /// The contamination.
    pub kind: Kind,
    /// The fraction asked for.
    pub fraction: f64,
    /// The rows as the calibrator sees them.
    pub rows: Rows,
    /// `marked[i]`: row `i` was changed (it differs from the clean row `i`);
    /// every other row is the clean row.
    pub marked: Vec<bool>,
}

impl Contaminated {
    /// Indices of the contaminated rows, ascending.
    pub fn marked_rows(&self) -> Vec<usize> {
        (0..self.marked.len()).filter(|&i| self.marked[i]).collect()
    }

    /// Number of contaminated rows.
    pub fn count(&self) -> usize {
        self.marked.iter().filter(|&&m| m).count()
    }
}

/// Rows contaminated at fraction `f` of `n`: `round(f n)`, at most `n`.
pub fn rows_for(n: usize, fraction: f64) -> usize {
    ((fraction.clamp(0.0, 1.0) * n as f64).round() as usize).min(n)
}

/// `k` distinct elements of `pool` chosen uniformly (a partial
/// Fisher-Yates shuffle), ascending; all of `pool` when it is smaller.
fn choose(mut pool: Vec<usize>, k: usize, rng: &mut Rng) -> Vec<usize> {
    let k = k.min(pool.len());
    for i in 0..k {
        let j = i + rng.index(pool.len() - i);
        pool.swap(i, j);
    }
    pool.truncate(k);
    pool.sort_unstable();
    pool
}

/// Uniform in `[-a, a]`.
fn symmetric(rng: &mut Rng, a: f64) -> f64 {
    (2.0 * rng.unit() - 1.0) * a
}

/// Contaminates [`rows_for`]`(n, fraction)` rows of `run` with `kind`.
///
/// The rows chosen depend only on `rng`; the values are computed in `f64`
/// and, for counts, rounded and saturated to `i16` like the clean rows.
/// Every marked row differs from its clean row (a draw that would leave a
/// row unchanged, such as a one-axis spike equal to the clean value, is
/// redrawn), and every unmarked row equals it.
pub fn contaminate(run: &CleanRun, kind: Kind, fraction: f64, rng: &mut Rng) -> Contaminated {
    let n = run.len();
    let k = rows_for(n, fraction);
    let units = run.setting.units;
    let clean = &run.clean.samples;
    let mut y = clean.clone();
    let mut marked = vec![false; n];
    let rho = run.field;
    let all: Vec<usize> = (0..n).collect();
    match kind {
        Kind::Spike => {
            let range = match units {
                Units::Counts => f64::from(i16::MAX),
                Units::MicroTesla => SPIKE_UT,
            };
            for i in choose(all, k, rng) {
                let one_axis = rng.chance(0.5).then(|| rng.index(3));
                let row = loop {
                    let mut row = clean[i];
                    for (a, v) in row.iter_mut().enumerate() {
                        if one_axis.is_none_or(|only| only == a) {
                            *v = symmetric(rng, range);
                            if units == Units::Counts {
                                *v = v.round();
                            }
                        }
                    }
                    if row != clean[i] {
                        break row;
                    }
                };
                y[i] = row;
                marked[i] = true;
            }
        }
        Kind::RailSaturation => {
            let (hi, lo) = match units {
                Units::Counts => (f64::from(i16::MAX), f64::from(i16::MIN)),
                Units::MicroTesla => (RAIL_UT, -RAIL_UT),
            };
            for i in choose(all, k, rng) {
                let a = rng.index(3);
                y[i][a] = if rng.chance(0.5) { hi } else { lo };
                marked[i] = true;
            }
        }
        Kind::ClipSaturation => {
            let levels = clip_levels(clean, units);
            // How far row i's axis a lies beyond its level, in extents.
            let beyond = |i: usize, a: usize| {
                let v = clean[i][a];
                let (lo, hi, extent) = levels[a];
                ((v - hi).max(lo - v)) / extent
            };
            let most = |i: usize| {
                (0..3)
                    .map(|a| (beyond(i, a), a))
                    .fold((f64::NEG_INFINITY, 0), |m, x| if x.0 > m.0 { x } else { m })
            };
            let eligible: Vec<usize> = (0..n).filter(|&i| most(i).0 > 0.0).collect();
            let mut chosen = choose(eligible, k, rng);
            if chosen.len() < k {
                // Not enough rows beyond the level: the rows closest to it
                // are set to it as well (they move outwards). Never needed
                // on the study's grid (about half the rows are beyond).
                let mut rest: Vec<usize> = (0..n).filter(|i| !chosen.contains(i)).collect();
                rest.sort_by(|&p, &q| most(q).0.total_cmp(&most(p).0));
                chosen.extend(rest.into_iter().take(k - chosen.len()));
            }
            for i in chosen {
                let (_, a) = most(i);
                let (lo, hi, _) = levels[a];
                let centre = 0.5 * (lo + hi);
                y[i][a] = if clean[i][a] >= centre { hi } else { lo };
                marked[i] = y[i] != clean[i];
            }
        }
        Kind::RangeClip => {
            let a = rng.index(3);
            let high = rng.chance(0.5);
            // Rows by how far they reach on that side; the k farthest are
            // clipped to the value of the next one.
            let mut order: Vec<usize> = (0..n).collect();
            let key = |i: usize| if high { -clean[i][a] } else { clean[i][a] };
            order.sort_by(|&p, &q| key(p).total_cmp(&key(q)));
            if let Some(&edge) = order.get(k) {
                let level = clean[edge][a];
                let level = if units == Units::Counts {
                    level.round()
                } else {
                    level
                };
                for &i in order.iter().take(k) {
                    y[i][a] = level;
                    marked[i] = y[i] != clean[i];
                }
            }
        }
        Kind::Zeros => {
            let pool: Vec<usize> = (0..n).filter(|&i| clean[i] != [0.0; 3]).collect();
            for i in choose(pool, k, rng) {
                y[i] = [0.0; 3];
                marked[i] = true;
            }
        }
        Kind::Stuck => {
            for (source, len) in stuck_runs(n, k, rng) {
                for i in source + 1..=source + len {
                    y[i] = clean[source];
                    marked[i] = y[i] != clean[i];
                }
            }
        }
        Kind::Displace03 | Kind::Displace1 => {
            let length = if kind == Kind::Displace03 {
                DISPLACE_SMALL
            } else {
                DISPLACE_LARGE
            } * rho;
            for i in choose(all, k, rng) {
                let d = rng.unit_vector() * length;
                y[i] = (Vector3::from(clean[i]) + d).into();
                marked[i] = true;
            }
        }
        Kind::Patch | Kind::Moving => {
            if k > 0 {
                let start = rng.index(n - k + 1);
                let u = rng.unit_vector();
                for j in 0..k {
                    let scale = if kind == Kind::Patch {
                        DISPLACE_SMALL
                    } else {
                        let t = (j as f64 + 0.5) / k as f64;
                        MOVING_PEAK * (std::f64::consts::PI * t).sin()
                    };
                    let i = start + j;
                    y[i] = (Vector3::from(clean[i]) + u * (scale * rho)).into();
                    marked[i] = true;
                }
            }
        }
    }
    let rows = Rows::from_values(units, y);
    // Rounding (counts) can undo a change smaller than half a count: keep
    // the marks honest.
    for (i, m) in marked.iter_mut().enumerate() {
        *m = *m && rows.samples[i] != clean[i];
    }
    Contaminated {
        kind,
        fraction,
        rows,
        marked,
    }
}

/// Per axis the clip levels `(low, high)` and the extent: with
/// `c = (max + min) / 2` and `e = (max - min) / 2` of the clean data,
/// `c -+ CLIP_LEVEL e` (rounded for counts).
fn clip_levels(clean: &[[f64; 3]], units: Units) -> [(f64, f64, f64); 3] {
    std::array::from_fn(|a| {
        let (lo, hi) = clean
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), y| {
                (lo.min(y[a]), hi.max(y[a]))
            });
        let (c, e) = (0.5 * (hi + lo), 0.5 * (hi - lo));
        let round = |v: f64| if units == Units::Counts { v.round() } else { v };
        (
            round(c - CLIP_LEVEL * e),
            round(c + CLIP_LEVEL * e),
            e.max(1e-300),
        )
    })
}

/// Stuck runs `(source, len)`: rows `source + 1 ..= source + len` repeat row
/// `source`; `k` repeats in all, runs of [`STUCK_RUN`] (the last shorter
/// when fewer remain), laid out without overlap (a run's source is never a
/// repeat) with the free rows spread at random over the gaps.
fn stuck_runs(n: usize, k: usize, rng: &mut Rng) -> Vec<(usize, usize)> {
    let (shortest, longest) = STUCK_RUN;
    let mut lens = Vec::new();
    let mut need = k;
    while need > 0 {
        let len = (shortest + rng.index(longest - shortest + 1)).min(need);
        lens.push(len);
        need -= len;
    }
    let occupied: usize = lens.iter().map(|l| l + 1).sum();
    let free = n.saturating_sub(occupied);
    let mut cuts: Vec<usize> = (0..lens.len()).map(|_| rng.index(free + 1)).collect();
    cuts.sort_unstable();
    let mut runs = Vec::with_capacity(lens.len());
    let (mut pos, mut last_cut) = (0, 0);
    for (len, cut) in lens.into_iter().zip(cuts) {
        pos += cut - last_cut;
        last_cut = cut;
        if pos + len >= n {
            break;
        }
        runs.push((pos, len));
        pos += len + 1;
    }
    runs
}

/// Degenerate input derived from `run` (its `T`, `b`, noise and size).
pub fn degenerate(run: &CleanRun, kind: Degenerate, rng: &mut Rng) -> Rows {
    let n = run.len();
    let values: Vec<[f64; 3]> = match kind {
        Degenerate::Stationary => {
            let at = run.reading(&run.dirs[rng.index(n)]);
            (0..STATIONARY_ROWS)
                .map(|_| (at + run.noise(rng)).into())
                .collect()
        }
        Degenerate::NoiseBall => (0..n)
            .map(|_| {
                let v = rng.unit_vector() * rng.unit().cbrt();
                (run.reading(&v) + run.noise(rng)).into()
            })
            .collect(),
        Degenerate::Cube => (0..n)
            .map(|_| {
                let d = Vector3::from_fn(|_, _| symmetric(rng, run.field));
                (run.truth.b + d).into()
            })
            .collect(),
    };
    Rows::from_values(run.setting.units, values)
}

// ---------------------------------------------------------------- metrics

/// Gauge-free errors of one calibration.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FitErrors {
    /// `|M_hat - M_true|_F / |M_true|_F`.
    pub e_m: f64,
    /// `|b_hat - b| / rho`.
    pub e_b: f64,
}

impl FitErrors {
    /// Either error above [`WRONG_LIMIT`] (or not a number).
    pub fn wrong(&self) -> bool {
        !(self.e_m <= WRONG_LIMIT && self.e_b <= WRONG_LIMIT)
    }
}

/// The errors of a calibration `u = W (y - b_hat)` against `truth`, with
/// `rho = |det T|^(1/3)`.
pub fn fit_errors(b_hat: &Vector3<f64>, w_hat: &Matrix3<f64>, truth: &Truth) -> FitErrors {
    let t_inv = truth.t.try_inverse().expect("invertible truth");
    let m_true = t_inv.transpose() * t_inv;
    let m_hat = w_hat.transpose() * w_hat;
    let rho = truth.t.determinant().abs().cbrt();
    FitErrors {
        e_m: (m_hat - m_true).norm() / m_true.norm(),
        e_b: (b_hat - truth.b).norm() / rho,
    }
}

/// `contaminated / max(clean, RATIO_FLOOR)`.
pub fn error_ratio(contaminated: f64, clean: f64) -> f64 {
    contaminated / clean.max(RATIO_FLOOR)
}

// ---------------------------------------------------------------- fitting

/// The working precision of `calibrate`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Precision {
    /// `calibrate::<f32, _>`.
    F32,
    /// `calibrate::<f64, _>`.
    F64,
}

impl Precision {
    /// Both precisions.
    pub const ALL: [Precision; 2] = [Precision::F32, Precision::F64];

    /// `f32`, `f64`.
    pub const fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F64 => "f64",
        }
    }
}

/// A calibration as the metrics see it, in `f64`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Accepted {
    /// Hard iron `b_hat`.
    pub b: Vector3<f64>,
    /// Soft-iron correction `W`.
    pub w: Matrix3<f64>,
    /// The report's warnings.
    pub warnings: Warnings,
}

impl Accepted {
    fn from_fit<T: Real>(fit: &Fit<T>) -> Self {
        Accepted {
            b: fit.calibration.hard_iron_vector().map(Real::to_f64),
            w: fit.calibration.soft_iron_matrix().map(Real::to_f64),
            warnings: fit.report.warnings,
        }
    }
}

/// Calibrates `rows` with `config` in `precision`: the `[i16; 3]` rows for
/// counts, the `[f64; 3]` rows for uT.
pub fn fit_rows(rows: &Rows, config: &Config, precision: Precision) -> Result<Accepted, Error> {
    match (precision, &rows.counts) {
        (Precision::F32, Some(c)) => calibrate::<f32, _>(c, config).map(|f| Accepted::from_fit(&f)),
        (Precision::F32, None) => {
            calibrate::<f32, _>(&rows.samples, config).map(|f| Accepted::from_fit(&f))
        }
        (Precision::F64, Some(c)) => calibrate::<f64, _>(c, config).map(|f| Accepted::from_fit(&f)),
        (Precision::F64, None) => {
            calibrate::<f64, _>(&rows.samples, config).map(|f| Accepted::from_fit(&f))
        }
    }
}

/// The variant name of an error (`NotAnEllipsoid`, `NoConvergence`, ...):
/// its `Debug` text up to the first field.
pub fn refusal_name(e: &Error) -> String {
    let text = format!("{e:?}");
    text.split(|c: char| !c.is_alphanumeric())
        .next()
        .unwrap_or_default()
        .to_string()
}

// ---------------------------------------------------------------- study

/// What a cell feeds the calibrator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Case {
    /// The clean rows (the denominators of the ratios).
    Clean,
    /// `rows_for(n, fraction)` rows contaminated with the kind.
    Contaminated(Kind, f64),
    /// Not calibration data.
    Degenerate(Degenerate),
}

impl Case {
    /// `clean`, `spike 1 %`, `cube`, ...
    pub fn label(&self) -> String {
        match self {
            Case::Clean => "clean".into(),
            Case::Contaminated(k, f) => format!("{} {}", k.name(), percent(*f)),
            Case::Degenerate(d) => d.name().into(),
        }
    }
}

/// A fraction as a percentage: `0.5 %`, `10 %`.
pub fn percent(f: f64) -> String {
    let p = 100.0 * f;
    if (p - p.round()).abs() < 1e-9 {
        format!("{p:.0} %")
    } else {
        format!("{p:.1} %")
    }
}

/// One cell of the grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cell {
    /// The input.
    pub case: Case,
    /// Unit system.
    pub units: Units,
    /// Directions.
    pub coverage: Coverage,
}

/// The runs of one cell (or of several, merged).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CellStats {
    /// Runs.
    pub runs: usize,
    /// Runs whose fit was accepted.
    pub accepted: usize,
    /// Accepted runs that are *silently wrong*: `e_M` or `e_b` above
    /// [`WRONG_LIMIT`]; for a [`Case::Degenerate`] input every accepted run
    /// (no calibration is right for it).
    pub wrong: usize,
    /// Of [`CellStats::wrong`], the runs whose report carried a warning.
    pub wrong_warned: usize,
    /// `e_M` of the accepted runs.
    pub e_m: Vec<f64>,
    /// `e_b` of the accepted runs.
    pub e_b: Vec<f64>,
    /// Error ratios of `e_M` ([`error_ratio`]) of the accepted runs whose
    /// clean fit was accepted too (none for a [`Case::Degenerate`] input).
    pub ratio_m: Vec<f64>,
    /// Error ratios of `e_b`, same runs.
    pub ratio_b: Vec<f64>,
    /// Runs whose clean fit was refused (they have no ratio).
    pub clean_refused: usize,
    /// Refusals by [`refusal_name`].
    pub refusals: BTreeMap<String, usize>,
    /// Accepted runs carrying each warning, by [`mag_cal_core::Warning::name`].
    pub warnings: BTreeMap<&'static str, usize>,
}

impl CellStats {
    /// Adds the runs of `other`.
    pub fn merge(&mut self, other: &CellStats) {
        self.runs += other.runs;
        self.accepted += other.accepted;
        self.wrong += other.wrong;
        self.wrong_warned += other.wrong_warned;
        self.e_m.extend_from_slice(&other.e_m);
        self.e_b.extend_from_slice(&other.e_b);
        self.ratio_m.extend_from_slice(&other.ratio_m);
        self.ratio_b.extend_from_slice(&other.ratio_b);
        self.clean_refused += other.clean_refused;
        for (k, v) in &other.refusals {
            *self.refusals.entry(k.clone()).or_default() += v;
        }
        for (k, v) in &other.warnings {
            *self.warnings.entry(k).or_default() += v;
        }
    }

    /// Share of accepted runs.
    pub fn accepted_share(&self) -> f64 {
        self.accepted as f64 / self.runs.max(1) as f64
    }

    /// Share of silently wrong runs (of all runs).
    pub fn wrong_share(&self) -> f64 {
        self.wrong as f64 / self.runs.max(1) as f64
    }

    /// Median `e_M` ratio (NaN without accepted runs).
    pub fn median_ratio_m(&self) -> f64 {
        median(&self.ratio_m)
    }

    /// Median `e_b` ratio (NaN without accepted runs).
    pub fn median_ratio_b(&self) -> f64 {
        median(&self.ratio_b)
    }

    /// Median `e_M` of the accepted runs.
    pub fn median_e_m(&self) -> f64 {
        median(&self.e_m)
    }

    /// Median `e_b` of the accepted runs.
    pub fn median_e_b(&self) -> f64 {
        median(&self.e_b)
    }

    /// Refusals, most frequent first (ties by name).
    pub fn main_refusals(&self) -> Vec<(&str, usize)> {
        by_count(self.refusals.iter().map(|(k, &c)| (k.as_str(), c)))
    }

    /// Warnings of the accepted runs, most frequent first (ties by name).
    pub fn main_warnings(&self) -> Vec<(&str, usize)> {
        by_count(self.warnings.iter().map(|(&k, &c)| (k, c)))
    }

    /// Records one run: the outcome on the cell's input, and the errors of
    /// the clean fit of the same run (`None` when it was refused).
    fn record(
        &mut self,
        case: &Case,
        outcome: &Result<Accepted, Error>,
        truth: &Truth,
        clean: Option<FitErrors>,
    ) {
        self.runs += 1;
        self.clean_refused += usize::from(clean.is_none());
        match outcome {
            Ok(fit) => {
                self.accepted += 1;
                let e = fit_errors(&fit.b, &fit.w, truth);
                let degenerate = matches!(case, Case::Degenerate(_));
                if degenerate || e.wrong() {
                    self.wrong += 1;
                    self.wrong_warned += usize::from(!fit.warnings.is_empty());
                }
                for w in fit.warnings.iter() {
                    *self.warnings.entry(w.name()).or_default() += 1;
                }
                self.e_m.push(e.e_m);
                self.e_b.push(e.e_b);
                // A degenerate input is not the clean run's rows: no ratio.
                if let (Some(c), false) = (clean, degenerate) {
                    self.ratio_m.push(error_ratio(e.e_m, c.e_m));
                    self.ratio_b.push(error_ratio(e.e_b, c.e_b));
                }
            }
            Err(err) => *self.refusals.entry(refusal_name(err)).or_default() += 1,
        }
    }
}

/// Names with counts, most frequent first (ties by name).
fn by_count<'a>(items: impl Iterator<Item = (&'a str, usize)>) -> Vec<(&'a str, usize)> {
    let mut v: Vec<(&str, usize)> = items.collect();
    v.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(b.0)));
    v
}

/// The cells of a study and its runs.
#[derive(Clone, Debug, PartialEq)]
pub struct Grid {
    /// Contamination kinds.
    pub kinds: Vec<Kind>,
    /// Fractions of every kind.
    pub fractions: Vec<f64>,
    /// Degenerate inputs (one cell each per units x coverage).
    pub degenerate: Vec<Degenerate>,
    /// Unit systems.
    pub units: Vec<Units>,
    /// Coverages.
    pub coverages: Vec<Coverage>,
    /// Run sizes, used in turn (run `r` has `sizes[r % sizes.len()]` rows).
    pub sizes: Vec<usize>,
    /// Runs per cell.
    pub runs: usize,
    /// Seed of the whole grid.
    pub seed: u64,
    /// Worker threads (at least 1; the results do not depend on it).
    pub threads: usize,
}

impl Grid {
    /// The full grid: every kind at every fraction, every degenerate input,
    /// both unit systems and coverages, n = 600 and 1000 in turn; one thread
    /// per available core.
    pub fn full(runs: usize) -> Self {
        Grid {
            kinds: Kind::ALL.to_vec(),
            fractions: FRACTIONS.to_vec(),
            degenerate: Degenerate::ALL.to_vec(),
            units: Units::ALL.to_vec(),
            coverages: Coverage::ALL.to_vec(),
            sizes: SIZES.to_vec(),
            runs,
            seed: 0x5EED_C0DE,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
        }
    }

    /// The cases of one units x coverage block, in table order: clean, then
    /// every kind at every fraction, then the degenerate inputs.
    pub fn cases(&self) -> Vec<Case> {
        let mut v = vec![Case::Clean];
        for &k in &self.kinds {
            for &f in &self.fractions {
                v.push(Case::Contaminated(k, f));
            }
        }
        v.extend(self.degenerate.iter().map(|&d| Case::Degenerate(d)));
        v
    }

    /// Calls of `calibrate` a study of this grid makes.
    pub fn fits(&self) -> usize {
        self.cases().len() * self.units.len() * self.coverages.len() * self.runs
    }
}

/// One configuration's results over a grid.
#[derive(Clone, Debug)]
pub struct Study {
    /// The configuration.
    pub config: Config,
    /// The working precision.
    pub precision: Precision,
    /// The grid.
    pub grid: Grid,
    /// Every cell with its runs, blocks of units x coverage in grid order.
    pub cells: Vec<(Cell, CellStats)>,
    /// Wall-clock seconds of the study.
    pub seconds: f64,
}

impl Study {
    /// The runs of `case` merged over every units and coverage of the grid.
    pub fn pooled(&self, case: &Case) -> CellStats {
        let mut s = CellStats::default();
        for (c, stats) in &self.cells {
            if c.case == *case {
                s.merge(stats);
            }
        }
        s
    }

    /// The runs of one cell.
    pub fn cell(&self, case: &Case, units: Units, coverage: Coverage) -> Option<&CellStats> {
        self.cells
            .iter()
            .find(|(c, _)| c.case == *case && c.units == units && c.coverage == coverage)
            .map(|(_, s)| s)
    }
}

/// A seed from a list of parts (SplitMix64 of each part in turn).
fn seed_of(parts: &[u64]) -> u64 {
    parts.iter().fold(0x0123_4567_89AB_CDEF, |acc, &p| {
        Rng(acc ^ p.wrapping_mul(0x9E37_79B9_7F4A_7C15)).next_u64()
    })
}

/// Runs `config` in `precision` over `grid`.
///
/// Per units x coverage block and run `r`: one clean run (seeded by the
/// grid's seed, the block and `r`; the same for every configuration and
/// precision, so the tables compare configurations on identical data), its
/// clean fit, then every case of [`Grid::cases`] on it, each contamination
/// drawn from its own seed (block, run, kind, fraction). The blocks run on
/// `grid.threads` threads.
pub fn run_study(config: &Config, precision: Precision, grid: &Grid) -> Study {
    let start = Instant::now();
    let cases = grid.cases();
    let blocks: Vec<(Units, Coverage)> = grid
        .units
        .iter()
        .flat_map(|&u| grid.coverages.iter().map(move |&c| (u, c)))
        .collect();
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<Vec<CellStats>>>> = Mutex::new(vec![None; blocks.len()]);
    std::thread::scope(|s| {
        for _ in 0..grid.threads.clamp(1, blocks.len().max(1)) {
            s.spawn(|| loop {
                let b = next.fetch_add(1, Ordering::Relaxed);
                let Some(&(units, coverage)) = blocks.get(b) else {
                    break;
                };
                let stats = run_block(config, precision, grid, &cases, units, coverage);
                results.lock().expect("no worker panicked")[b] = Some(stats);
            });
        }
    });
    let results = results.into_inner().expect("no worker panicked");
    let mut cells = Vec::with_capacity(blocks.len() * cases.len());
    for (&(units, coverage), stats) in blocks.iter().zip(results) {
        for (case, s) in cases.iter().zip(stats.expect("every block ran")) {
            cells.push((
                Cell {
                    case: *case,
                    units,
                    coverage,
                },
                s,
            ));
        }
    }
    Study {
        config: *config,
        precision,
        grid: grid.clone(),
        cells,
        seconds: start.elapsed().as_secs_f64(),
    }
}

fn units_id(u: Units) -> u64 {
    match u {
        Units::Counts => 1,
        Units::MicroTesla => 2,
    }
}

fn coverage_id(c: Coverage) -> u64 {
    match c {
        Coverage::Sphere => 1,
        Coverage::Band => 2,
    }
}

/// The seed of the contamination of `case` in a run (cases other than
/// contamination draw from it too).
fn case_seed(base: u64, case: &Case) -> u64 {
    match *case {
        Case::Clean => seed_of(&[base, 0]),
        Case::Contaminated(k, f) => seed_of(&[base, 1, k as u64, f.to_bits()]),
        Case::Degenerate(d) => seed_of(&[base, 2, d as u64]),
    }
}

/// The seed of run `run` of a units x coverage block.
pub fn run_seed(grid_seed: u64, units: Units, coverage: Coverage, run: usize) -> u64 {
    seed_of(&[
        grid_seed,
        units_id(units),
        coverage_id(coverage),
        run as u64,
    ])
}

fn run_block(
    config: &Config,
    precision: Precision,
    grid: &Grid,
    cases: &[Case],
    units: Units,
    coverage: Coverage,
) -> Vec<CellStats> {
    let mut stats = vec![CellStats::default(); cases.len()];
    for r in 0..grid.runs {
        let base = run_seed(grid.seed, units, coverage, r);
        let setting = Setting {
            units,
            coverage,
            n: grid.sizes[r % grid.sizes.len()],
        };
        let run = CleanRun::generate(setting, &mut Rng(base));
        let clean_fit = fit_rows(&run.clean, config, precision);
        let clean = clean_fit
            .as_ref()
            .ok()
            .map(|f| fit_errors(&f.b, &f.w, &run.truth));
        for (case, s) in cases.iter().zip(stats.iter_mut()) {
            let mut rng = Rng(case_seed(base, case));
            let outcome = match *case {
                Case::Clean => clean_fit,
                Case::Contaminated(k, f) => {
                    fit_rows(&contaminate(&run, k, f, &mut rng).rows, config, precision)
                }
                Case::Degenerate(d) => fit_rows(&degenerate(&run, d, &mut rng), config, precision),
            };
            s.record(case, &outcome, &run.truth, clean);
        }
    }
    stats
}

// ---------------------------------------------------------------- table

/// A ratio or error for the table: 3 significant digits, `-` for none.
fn fmt_num(x: f64) -> String {
    if !x.is_finite() {
        "-".into()
    } else if x >= 100.0 {
        format!("{x:.0}")
    } else if x >= 10.0 {
        format!("{x:.1}")
    } else if x >= 1.0 {
        format!("{x:.2}")
    } else {
        format!("{x:.3}")
    }
}

/// A share as a percentage with one decimal (`0` for none).
fn fmt_share(x: f64) -> String {
    if x == 0.0 {
        "0".into()
    } else {
        format!("{:.1}", 100.0 * x)
    }
}

/// Up to three names with their share of the runs, most frequent first.
fn fmt_counts(r: &[(&str, usize)], runs: usize) -> String {
    if r.is_empty() {
        return "-".into();
    }
    let mut out: Vec<String> = r
        .iter()
        .take(3)
        .map(|(name, c)| format!("{name} {}", fmt_share(*c as f64 / runs.max(1) as f64)))
        .collect();
    if r.len() > 3 {
        out.push(format!("+{} more", r.len() - 3));
    }
    out.join(", ")
}

/// The markdown table of one study, every case pooled over the grid's
/// units and coverages: accepted %, median error ratios `e_M / e_b` (to the
/// clean fit of the same runs), median absolute `e_M / e_b` of the
/// accepted runs, silently wrong % (in brackets the % of the runs that were
/// silently wrong yet carried a warning), the main refusal reasons and the
/// main warnings of the accepted runs (% of the runs). Headed by `label`.
pub fn render_table(study: &Study, label: &str) -> String {
    let g = &study.grid;
    let blocks = g.units.len() * g.coverages.len();
    let heading = format!(
        "{label} ({}, {} runs a row: {} runs x {blocks} units x coverage)",
        study.precision.name(),
        g.runs * blocks,
        g.runs,
    );
    table(study, &heading, |_| true)
}

/// [`render_table`] for one units x coverage block of the grid.
pub fn render_setting_table(
    study: &Study,
    label: &str,
    units: Units,
    coverage: Coverage,
) -> String {
    let heading = format!(
        "{label} ({}, {} {}, {} runs a row)",
        study.precision.name(),
        units.name(),
        coverage.name(),
        study.grid.runs
    );
    table(study, &heading, |c| {
        c.units == units && c.coverage == coverage
    })
}

fn table(study: &Study, heading: &str, select: impl Fn(&Cell) -> bool) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "### {heading}\n");
    s.push_str(
        "| input | accepted % | median ratio e_M / e_b | median e_M / e_b | silently wrong % (warned) | refusals (% of runs) | warnings (% of runs) |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for case in study.grid.cases() {
        let mut c = CellStats::default();
        for (cell, stats) in &study.cells {
            if cell.case == case && select(cell) {
                c.merge(stats);
            }
        }
        let ratio = if c.ratio_m.is_empty() {
            "-".to_string()
        } else {
            format!(
                "{} / {}",
                fmt_num(c.median_ratio_m()),
                fmt_num(c.median_ratio_b())
            )
        };
        let abs = if c.e_m.is_empty() {
            "-".to_string()
        } else {
            format!("{} / {}", fmt_num(c.median_e_m()), fmt_num(c.median_e_b()))
        };
        let mut wrong = fmt_share(c.wrong_share());
        if c.wrong_warned > 0 {
            let warned = c.wrong_warned as f64 / c.runs.max(1) as f64;
            let _ = write!(wrong, " ({})", fmt_share(warned));
        }
        let _ = writeln!(
            s,
            "| {} | {} | {ratio} | {abs} | {wrong} | {} | {} |",
            case.label(),
            fmt_share(c.accepted_share()),
            fmt_counts(&c.main_refusals(), c.runs),
            fmt_counts(&c.main_warnings(), c.runs),
        );
    }
    s
}

/// Totals of a study's contaminated and degenerate runs (the clean cells
/// left out): runs, accepted, silently wrong.
pub fn totals(study: &Study) -> (usize, usize, usize) {
    study
        .cells
        .iter()
        .filter(|(c, _)| c.case != Case::Clean)
        .fold((0, 0, 0), |(r, a, w), (_, s)| {
            (r + s.runs, a + s.accepted, w + s.wrong)
        })
}

// ---------------------------------------------------------------- results.md

/// The name of the contamination section of `docs/results.md`
/// ([`crate::sections`]).
pub const SECTION: &str = "contamination";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hilbert_curve_visits_every_cell_through_neighbours() {
        let order = 4;
        let side = 1u64 << order;
        let mut at = vec![(0, 0); (side * side) as usize];
        for x in 0..side {
            for y in 0..side {
                at[hilbert_index(order, x, y) as usize] = (x, y);
            }
        }
        assert_eq!(at[0], (0, 0));
        assert_eq!(at[at.len() - 1], (side - 1, 0));
        for w in at.windows(2) {
            let d = w[0].0.abs_diff(w[1].0) + w[0].1.abs_diff(w[1].1);
            assert_eq!(d, 1, "{:?}", w);
        }
    }

    #[test]
    fn stuck_runs_are_disjoint_and_count_exactly() {
        for (n, k) in [(600, 3), (600, 180), (1000, 300), (1000, 5), (20, 10)] {
            let mut rng = Rng(n as u64 + k as u64);
            let runs = stuck_runs(n, k, &mut rng);
            let total: usize = runs.iter().map(|r| r.1).sum();
            assert_eq!(total, k, "n {n} k {k}");
            for w in runs.windows(2) {
                assert!(w[0].0 + w[0].1 < w[1].0);
            }
            assert!(runs.last().is_none_or(|r| r.0 + r.1 < n));
        }
    }
}
