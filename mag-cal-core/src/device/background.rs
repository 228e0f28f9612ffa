//! Calibration in the background, from ordinary use: no calibration dance.
//!
//! A [`Background`] takes every reading ([`Background::push`], constant
//! work) and keeps an orientation-binned buffer of `N` samples: the
//! directions of the readings, seen from the current calibration (before
//! the first one, from a running sphere fit), fall into 48 equal-area cells
//! of `K` samples each, and in a full cell the newest sample replaces the
//! oldest. A device that dwells in one orientation thus refreshes one cell
//! and cannot crowd out the others.
//!
//! [`Background::step`] does the rest in slices: each call processes at
//! most [`BackgroundConfig::slice`] buffered samples (or one small solve),
//! so that a control loop calling it once per reading is never blocked. A
//! refit is the robust ADC2 of [`crate::calibrate`] started from the
//! current calibration instead of screening: a pass for the residuals under
//! the current calibration (its fit error on the buffer), the LS9 moments
//! of the rows within [`crate::OUTLIER_CUT`] robust standard deviations,
//! two artificial-data passes with the cut of the pass before, a final pass
//! for the quality figures, and the judging of [`crate::judge::quality`]. A new
//! calibration is adopted only when every check passes and its robust fit
//! error on the buffer is below the current calibration's.
//!
//! **Hard-iron tracking.** Under the current calibration every reading has
//! a radial residual `|W (y - b)| - 1`. The running RMS of those residuals (time constant 32 readings) is
//! watched in units of the calibration's own RMS on its buffer: when it
//! stays above
//! [`BackgroundConfig::stale_rms`] for [`BackgroundConfig::stale_readings`]
//! readings, the calibration is stale ([`Background::is_stale`]): a
//! persistent rise, not a burst. The
//! offsets alone are then fitted ([`crate::device::offsets`], strength unchanged)
//! to the recent readings; a moved hard iron fits a sphere of the known
//! radius with a small residual and is adopted at once, while a magnet
//! passing by does not and is not. After a new hard iron, the buffered
//! samples inconsistent with it leave the buffer, so they cannot poison the
//! next full refit.
//!
//! ```
//! use mag_cal_core::background::{Background, BackgroundConfig};
//!
//! // 48 cells of 4 samples; f32.
//! let mut bg: Background<f32, [f32; 3], 192, 4> = Background::new(BackgroundConfig::default())?;
//! for k in 0..6000 {
//!     // A device turned slowly through most orientations.
//!     let z = (k as f32 * 0.0021).sin();
//!     let r = (1.0 - z * z).sqrt();
//!     let phi = k as f32 * 0.05;
//!     let raw = [250.0 + 300.0 * r * phi.cos(), -80.0 + 330.0 * r * phi.sin(), 40.0 + 280.0 * z];
//!     bg.push(raw);
//!     bg.step();
//! }
//! let cal = bg.calibration().expect("calibrated in the background");
//! assert!((cal.hard_iron()[0] - 250.0).abs() < 1.0);
//! assert!(!bg.is_stale());
//! # Ok::<(), mag_cal_core::Error>(())
//! ```

use crate::tuning::OUTLIER_CUT;
use nalgebra::{Matrix3, Vector3};

use crate::device::collector;
use crate::device::offsets::{refit_offsets, Strength};
use crate::judge::background::{self, LsFigures};
use crate::judge::quality;
use crate::numerics::linalg::{dot, larger, sym_inv_sqrt};
use crate::numerics::sphere::CentreFit;
use crate::robust::runs::Runs;
use crate::sample::Sample;
use crate::steps::artificial::AdcPass;
use crate::steps::ellipsoid::{self, Ellipsoid};
use crate::steps::final_pass::{DirectionSums, FinalSums};
use crate::steps::methods::adc2;
use crate::steps::moments::{Cut, Moments, MomentsPass};
use crate::steps::normalize::{Normalization, Projector, MIN_SAMPLES};
use crate::steps::rules::{check, Gate, Rules};
use crate::{Calibration, Error, Quality, Real, Thresholds, Warnings};

/// Direction cells of the buffer (those of [`crate::device::collector`]).
pub const CELLS: usize = collector::CELLS;

/// Recent readings kept for an offsets-only fit.
pub const RECENT: usize = 64;

/// Residual cuts are never tighter than this (units of the field): a
/// calibration that fits its buffer to a thousandth would otherwise call
/// every reading of a noisier day an outlier.
pub const MIN_SIGMA: f64 = 0.005;

pub use crate::judge::background::{
    ADOPT_COVERAGE, ADOPT_RATIO, OFFSETS_ERROR_RATIO, OFFSETS_MAX_FIT_ERROR,
};

/// Readings farther than this many field strengths from the calibrated
/// unit sphere are not buffered (wild readings).
pub const WILD_RESIDUAL: f64 = 1.0;

/// What a [`Background`] does.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct BackgroundConfig {
    /// A reading is buffered only when its direction differs from the last
    /// buffered one by at least this angle, degrees (as
    /// [`crate::device::collector`]).
    pub min_angle_deg: f32,
    /// New buffered samples since the last refit before the next one.
    pub refit_after: usize,
    /// Cells holding samples before a refit (of [`CELLS`]). The judging
    /// decides whether the coverage suffices; this only saves refits that
    /// cannot pass.
    pub min_cells: usize,
    /// Buffered samples a call of [`Background::step`] processes.
    pub slice: usize,
    /// Once a calibration is in use, samples buffered more than this many
    /// readings ago leave the buffer before each refit (0: never), so that
    /// a slowly drifting hard iron is fitted from recent samples.
    pub max_age: u32,
    /// The calibration in use is watched by the running RMS of the radial
    /// residuals of the readings (time constant 32 readings), in units of
    /// its radial RMS on its buffer (at least [`MIN_SIGMA`]): above this
    /// it has risen, and readings beyond it are "off".
    pub stale_rms: f32,
    /// Readings the rise must last before the calibration is stale (it
    /// ends when the RMS falls below three quarters of
    /// [`BackgroundConfig::stale_rms`]): longer than a disturbance that
    /// passes (200: 4 s at 50 Hz).
    pub stale_readings: u32,
    /// The judging limits of a refit.
    pub thresholds: Thresholds,
}

impl BackgroundConfig {
    /// The defaults.
    pub const DEFAULT: Self = Self {
        min_angle_deg: collector::DEFAULT_MIN_ANGLE_DEG,
        refit_after: 48,
        min_cells: 20,
        slice: 32,
        max_age: 10_000,
        stale_rms: 3.0,
        stale_readings: 200,
        thresholds: Thresholds::DEFAULT,
    };
}

impl BackgroundConfig {
    /// `Ok` when every value can be used, else the first that cannot:
    /// [`Error::InvalidConfig`] naming the field (a NaN, an angle outside
    /// 0-180 degrees, a `stale_rms` that is not positive and finite, a
    /// `slice` of 0, more `min_cells` than there are cells ([`CELLS`]),
    /// or one of the [`Thresholds`], [`Thresholds::validate`]).
    ///
    /// ```
    /// use mag_cal_core::background::BackgroundConfig;
    /// use mag_cal_core::Error;
    /// assert_eq!(BackgroundConfig::DEFAULT.validate(), Ok(()));
    /// let mut bad = BackgroundConfig::DEFAULT;
    /// bad.slice = 0;
    /// assert_eq!(bad.validate(), Err(Error::InvalidConfig { field: "slice" }));
    /// ```
    pub fn validate(&self) -> Result<(), Error> {
        quality::check("min_angle_deg", self.min_angle_deg, 0.0, 180.0)?;
        if !(self.stale_rms > 0.0 && self.stale_rms.is_finite()) {
            return Err(Error::InvalidConfig { field: "stale_rms" });
        }
        if self.slice == 0 {
            return Err(Error::InvalidConfig { field: "slice" });
        }
        if self.min_cells > CELLS {
            return Err(Error::InvalidConfig { field: "min_cells" });
        }
        self.thresholds.validate()
    }
}

impl Default for BackgroundConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// What [`Background::push`] did with a reading.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Pushed {
    /// Buffered.
    Stored,
    /// Not buffered: too close in direction to the last buffered reading
    /// (still used to watch the calibration).
    TooClose,
    /// Not buffered: a glitch (zero row, rails), not finite, or beyond the
    /// working precision.
    Invalid,
    /// Not buffered: far off the calibrated sphere (a wild reading).
    Wild,
    /// Not buffered, before the first calibration: the device, smoothed
    /// over its noise, lies within the sensor's noise spacing
    /// ([`crate::device::collector::NOISE_SPACING`]) of the running
    /// centre, as a device lying still does (or while the noise is learnt,
    /// the first few readings after the first).
    Still,
}

/// What [`Background::step`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Stepped {
    /// Nothing to do.
    Idle,
    /// A slice of a refit or of a purge.
    Working,
    /// A refit ended with a new calibration.
    Adopted,
    /// A refit passed every check but does not fit the buffer better than
    /// the current calibration, which stays.
    Kept,
    /// A refit was refused (the reason).
    Refused(Error),
    /// The calibration was stale and the offsets alone were re-estimated
    /// and adopted.
    OffsetsAdopted,
    /// The calibration is stale but the offsets-only fit of the recent
    /// readings was refused (the reason): a disturbance, or too few
    /// directions yet.
    OffsetsRefused(Error),
}

/// The calibration in use and how it fits.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Current<T: Real> {
    /// The calibration.
    pub calibration: Calibration<T>,
    /// Its quality figures at the refit that produced it.
    pub quality: Quality<T>,
    /// Its warnings then.
    pub warnings: Warnings,
    /// Its robust fit error on the buffer (at its refit, or after an
    /// offsets-only fit on the recent readings).
    pub fit_error: T,
    /// Its RMS radial residual on the buffer at its refit: the level the
    /// stale watch measures against.
    pub radial_rms: T,
}

/// Counters of what happened so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub struct Counters {
    /// Readings pushed.
    pub readings: u64,
    /// Refits that ran to the end.
    pub refits: u32,
    /// Calibrations adopted by a refit.
    pub adopted: u32,
    /// Refits refused.
    pub refused: u32,
    /// Offsets-only fits adopted.
    pub offsets_adopted: u32,
    /// Offsets-only fits refused.
    pub offsets_refused: u32,
    /// Buffered samples dropped after a new hard iron.
    pub purged: u32,
}

/// A refit's starting point, normalised: `x = (y - c) / s`, `u = W' x`.
#[derive(Clone, Copy, Debug)]
struct Prior<T: Real> {
    norm: Normalization<T>,
    w: Matrix3<T>,
}

/// An estimate in normalised coordinates: centre, `W'` and `T'`.
#[derive(Clone, Copy, Debug)]
struct Estimate<T: Real> {
    centre: Vector3<T>,
    w: Matrix3<T>,
    t: Matrix3<T>,
}

/// Where a refit or purge is.
#[allow(clippy::large_enum_variant)]
enum Stage<T: Real> {
    Idle,
    /// The residuals under the prior: its robust fit error on the buffer,
    /// which sets the cut of the refit's moments and which the refit must
    /// beat.
    Prior {
        prior: Prior<T>,
        pos: usize,
        sums: FinalSums<T>,
    },
    /// The refit proper.
    Refit(Refit<T>),
    /// Dropping the samples older than [`BackgroundConfig::max_age`], then
    /// the refit.
    Age {
        pos: usize,
    },
    /// Dropping the buffered samples that do not tell the new hard iron from
    /// the old one `old`.
    Purge {
        pos: usize,
        old: Calibration<T>,
    },
}

/// A refit under way: its start, the calibration in use's fit error on
/// the buffer, and the pass under way (the steps of the batch fit's robust
/// ADC2, each fed the buffer one slice a call).
struct Refit<T: Real> {
    prior: Prior<T>,
    /// The robust fit error on the buffer under the prior.
    current_error: T,
    /// Where the next slice of the buffer starts.
    pos: usize,
    pass: RefitPass<T>,
}

/// The passes of a refit, in order.
#[allow(clippy::large_enum_variant)]
enum RefitPass<T: Real> {
    /// LS9 moments of the rows within the prior's cut.
    Moments(MomentsPass<T>),
    /// The LS solve (no rows: one call).
    Solve(Moments<T>),
    /// An artificial-data pass from `start` (`round` 0 from the LS fit, 1
    /// from round 0's estimate), then its solve; the figures so far.
    Adc {
        ls: LsFigures<T>,
        round: u8,
        start: Estimate<T>,
        pass: AdcPass<T>,
    },
    /// The final pass under the estimate, then the judging.
    Final {
        ls: LsFigures<T>,
        est: Estimate<T>,
        directions: DirectionSums<T>,
        limit: T,
        sums: FinalSums<T>,
    },
}

/// The stale watch.
#[derive(Clone, Copy, Debug)]
struct Watch {
    /// Running mean of the squared radial residual over the fit error
    /// (clipped), time constant 32 readings.
    mean_square: f32,
    /// Readings since the rise began (0 when calm).
    persistent: u32,
}

impl Watch {
    /// Calm: the mean square of noise at the fit error.
    const CALM: Self = Self {
        mean_square: 1.0,
        persistent: 0,
    };
}

/// The background calibrator: `N` buffered samples in [`CELLS`] cells of
/// `K` (`N` must be `CELLS * K`), calibrations in precision `T`.
///
/// Memory: `N` samples, `N` bytes of cell tags, `2 N` bytes of cell rings,
/// [`RECENT`] recent samples and about 1.5 KB of refit state.
pub struct Background<T: Real, S: Sample, const N: usize, const K: usize> {
    config: BackgroundConfig,
    /// `(2 sin(min_angle / 2))^2`: the squared chord between unit
    /// directions [`BackgroundConfig::min_angle_deg`] apart.
    min_chord_sq: f32,
    store: heapless::Vec<S, N>,
    cell_of: [u8; N],
    /// The reading count when each sample was buffered (wrapping).
    stamp: [u32; N],
    ring: [[u16; K]; CELLS],
    fill: [u8; CELLS],
    head: [u8; CELLS],
    sphere: CentreFit,
    last_direction: Option<[f32; 3]>,
    /// The sensor's noise, learnt from the readings before a calibration.
    noise: collector::NoiseGate,
    recent: heapless::Vec<S, RECENT>,
    recent_next: usize,
    recent_direction: Option<[f32; 3]>,
    current: Option<Current<T>>,
    adopted_at: u64,
    new_samples: usize,
    stage: Stage<T>,
    watch: Watch,
    last_offsets_try: u64,
    counters: Counters,
}

impl<T: Real, S: Sample, const N: usize, const K: usize> Background<T, S, N, K> {
    const SHAPE: () = assert!(
        N == CELLS * K && K > 0 && K < 256 && N <= u16::MAX as usize,
        "Background<_, _, N, K> needs N == 48 * K, 0 < K < 256"
    );

    /// An empty calibrator.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] when a value of `config` cannot be used
    /// ([`BackgroundConfig::validate`]).
    pub fn new(config: BackgroundConfig) -> Result<Self, Error> {
        let () = Self::SHAPE;
        config.validate()?;
        let chord = 2.0 * libm::sinf(0.5 * config.min_angle_deg.to_radians());
        Ok(Self {
            config,
            min_chord_sq: chord * chord,
            store: heapless::Vec::new(),
            cell_of: [0; N],
            stamp: [0; N],
            ring: [[0; K]; CELLS],
            fill: [0; CELLS],
            head: [0; CELLS],
            sphere: CentreFit::EMPTY,
            last_direction: None,
            noise: collector::NoiseGate::EMPTY,
            recent: heapless::Vec::new(),
            recent_next: 0,
            recent_direction: None,
            current: None,
            adopted_at: 0,
            new_samples: 0,
            stage: Stage::Idle,
            watch: Watch::CALM,
            last_offsets_try: 0,
            counters: Counters::default(),
        })
    }

    /// A calibrator that starts from a stored calibration (its fit error
    /// as given, e.g. that of the fit's report).
    ///
    /// # Errors
    /// As [`Background::new`].
    pub fn with_calibration(config: BackgroundConfig, current: Current<T>) -> Result<Self, Error> {
        let mut bg = Self::new(config)?;
        bg.current = Some(current);
        Ok(bg)
    }

    /// The calibration in use, if any.
    pub fn calibration(&self) -> Option<&Calibration<T>> {
        self.current.as_ref().map(|c| &c.calibration)
    }

    /// The calibration in use with its figures, if any.
    pub fn current(&self) -> Option<&Current<T>> {
        self.current.as_ref()
    }

    /// Readings since the calibration in use was adopted (or its offsets
    /// re-estimated); `None` before the first.
    pub fn age(&self) -> Option<u64> {
        self.current
            .as_ref()
            .map(|_| self.counters.readings.saturating_sub(self.adopted_at))
    }

    /// Whether the calibration in use no longer fits the readings (a
    /// persistent rise of their residuals: the hard iron moved).
    pub fn is_stale(&self) -> bool {
        self.current.is_some() && self.watch.persistent >= self.config.stale_readings
    }

    /// Progress towards the first refit, `0..=100`: the smaller of the
    /// share of [`BackgroundConfig::min_cells`] cells filled and of
    /// [`BackgroundConfig::refit_after`] samples buffered (100 once a
    /// calibration is in use).
    pub fn progress(&self) -> u8 {
        if self.current.is_some() {
            return 100;
        }
        let share = |have: usize, need: usize| (have.min(need) * 100 / need.max(1)) as u8;
        share(self.cells_filled(), self.config.min_cells).min(share(
            self.store.len(),
            self.config.refit_after.max(MIN_SAMPLES),
        ))
    }

    /// Cells holding at least one buffered sample.
    pub fn cells_filled(&self) -> usize {
        self.fill.iter().filter(|&&f| f > 0).count()
    }

    /// The buffered samples (in no particular order).
    pub fn samples(&self) -> &[S] {
        &self.store
    }

    /// What happened so far.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Whether a refit or purge is under way.
    pub fn is_working(&self) -> bool {
        !matches!(self.stage, Stage::Idle)
    }

    /// Takes a reading: watches the calibration in use with it, and buffers
    /// it when it adds a direction. Constant work.
    pub fn push(&mut self, sample: S) -> Pushed {
        self.counters.readings += 1;
        let Ok(y) = check::<T, S>(&sample, None, &Rules::GLITCHES) else {
            return Pushed::Invalid;
        };
        let y32 = [y[0].to_single(), y[1].to_single(), y[2].to_single()];
        let direction_from = match &self.current {
            Some(current) => {
                let u = current.calibration.apply(y);
                let r = dot(&u, &u).sqrt() - T::one();
                if !r.is_finite() {
                    return Pushed::Invalid;
                }
                let level = larger(
                    larger(current.radial_rms, current.fit_error),
                    T::lit(MIN_SIGMA),
                );
                let off = self.watch((r / level).to_single());
                let u = [u[0].to_single(), u[1].to_single(), u[2].to_single()];
                if off {
                    // The readings the calibration no longer fits: those an
                    // offsets-only fit takes when the rise persists.
                    if let Some(dir) = unit(u) {
                        self.remember(sample, dir);
                    }
                }
                if r.abs() > T::lit(WILD_RESIDUAL) {
                    return Pushed::Wild;
                }
                u
            }
            None => {
                // Before a calibration, directions are taken from the
                // running sphere's centre. A device lying still puts that
                // centre inside its noise, which then points every way: its
                // readings would fill every cell, and the motion after them
                // would be wild to that tiny sphere (6 000 still readings
                // at 0.2 % noise: all 48 cells filled, never calibrated;
                // `still_periods_change_nothing_in_the_background`). So a
                // reading is buffered only when the device, smoothed over
                // its noise, lies beyond the noise spacing of the collector
                // ([`collector::NOISE_SPACING`]) from that centre, and the
                // wild test waits for a sphere larger than the spacing. A
                // turning device is a field strength from the centre, far
                // beyond the spacing (30 % of the field at 3 % noise).
                let spacing_sq = self.noise.take(y32).map(|d| d * d);
                let c = self.sphere.centre();
                let dist_sq = |p: [f32; 3]| {
                    let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
                    dot(&d, &d)
                };
                let smoothed = dist_sq(self.noise.position);
                if !self.store.is_empty() && !spacing_sq.is_some_and(|s2| smoothed >= s2) {
                    return Pushed::Still;
                }
                let r2 = self.sphere.radius_sq(c);
                if self.store.len() >= collector::OUTLIER_MIN_SAMPLES
                    && spacing_sq.is_some_and(|s2| r2 > s2)
                {
                    let limit = collector::OUTLIER_RADII * collector::OUTLIER_RADII * r2;
                    if !(dist_sq(y32) <= limit) {
                        return Pushed::Wild;
                    }
                }
                [y32[0] - c[0], y32[1] - c[1], y32[2] - c[2]]
            }
        };
        let Some(dir) = unit(direction_from) else {
            return Pushed::TooClose;
        };
        let Some(cell) = collector::cell(dir) else {
            return Pushed::TooClose;
        };
        if let Some(last) = self.last_direction {
            if !far_enough(&dir, &last, self.min_chord_sq) {
                return Pushed::TooClose;
            }
        }
        if self.current.is_none() {
            match self.sphere.with(y32) {
                Some(next) => self.sphere = next,
                None => return Pushed::Invalid,
            }
        }
        self.last_direction = Some(dir);
        self.store_in(sample, cell);
        self.new_samples += 1;
        Pushed::Stored
    }

    /// Does at most one slice of work: a slice of a refit or purge, one
    /// solve, or an offsets-only fit of the [`RECENT`] readings; starts a
    /// refit when enough new samples and cells are buffered.
    pub fn step(&mut self) -> Stepped {
        if matches!(self.stage, Stage::Idle) {
            if self.is_stale() && self.recent.len() >= RECENT / 2 {
                return self.try_offsets();
            }
            if self.new_samples >= self.config.refit_after
                && self.cells_filled() >= self.config.min_cells
                && self.store.len() >= MIN_SAMPLES
            {
                self.new_samples = 0;
                self.stage = if self.current.is_some() && self.config.max_age > 0 {
                    Stage::Age { pos: 0 }
                } else {
                    self.start_refit()
                };
                return Stepped::Working;
            }
            return Stepped::Idle;
        }
        if matches!(self.stage, Stage::Refit(_)) {
            // In place: a refit's state is the largest stage (about 1 KB),
            // and moving it in and out took a tenth of a refit's
            // instructions on a Cortex-M4F.
            return self.refit();
        }
        let stage = core::mem::replace(&mut self.stage, Stage::Idle);
        let (next, result) = self.advance(stage);
        self.stage = next;
        result
    }

    /// [`Background::push`], then [`Background::step`].
    pub fn update(&mut self, sample: S) -> Stepped {
        self.push(sample);
        self.step()
    }

    // ------------------------------------------------------------ buffer

    /// Stores `sample` in `cell`, over the cell's oldest when it is full.
    fn store_in(&mut self, sample: S, cell: usize) {
        let (Some(ring), Some(fill), Some(head)) = (
            self.ring.get_mut(cell),
            self.fill.get_mut(cell),
            self.head.get_mut(cell),
        ) else {
            return;
        };
        let k = usize::from(*fill);
        if k < K {
            let slot = self.store.len();
            if self.store.push(sample).is_err() {
                return;
            }
            if let Some(tag) = self.cell_of.get_mut(slot) {
                *tag = cell as u8;
            }
            if let Some(t) = self.stamp.get_mut(slot) {
                *t = self.counters.readings as u32;
            }
            if let Some(r) = ring.get_mut((usize::from(*head) + k) % K) {
                *r = slot as u16;
            }
            *fill += 1;
        } else {
            // Full: the oldest (at the head) is overwritten and becomes the
            // newest.
            let h = usize::from(*head);
            let slot = ring.get(h).copied().map_or(0, usize::from);
            if let Some(s) = self.store.get_mut(slot) {
                *s = sample;
            }
            if let Some(t) = self.stamp.get_mut(slot) {
                *t = self.counters.readings as u32;
            }
            *head = ((h + 1) % K) as u8;
        }
    }

    /// Removes buffered sample `slot` (the last one moves into its place).
    fn remove(&mut self, slot: usize) {
        let last = self.store.len().saturating_sub(1);
        if slot > last || self.store.is_empty() {
            return;
        }
        let cell = self.cell_of.get(slot).copied().map_or(0, usize::from);
        self.unlink(cell, slot);
        if slot != last {
            let moved_cell = self.cell_of.get(last).copied().map_or(0, usize::from);
            if let Some(ring) = self.ring.get_mut(moved_cell) {
                for r in ring.iter_mut() {
                    if usize::from(*r) == last {
                        *r = slot as u16;
                    }
                }
            }
            if let Some(tag) = self.cell_of.get_mut(slot) {
                *tag = moved_cell as u8;
            }
            let moved_stamp = self.stamp.get(last).copied().unwrap_or(0);
            if let Some(t) = self.stamp.get_mut(slot) {
                *t = moved_stamp;
            }
        }
        // swap_remove, written out without its bounds assertion.
        if let Some(moved) = self.store.pop() {
            if let Some(s) = self.store.get_mut(slot) {
                *s = moved;
            }
        }
    }

    /// Examines at most one slice of buffered samples from `pos`, removing
    /// those `keep` (given the sample and its stamp) refuses; the position
    /// to go on from.
    fn sweep(&mut self, mut pos: usize, keep: impl Fn(&S, u32) -> bool) -> usize {
        let mut seen = 0;
        while pos < self.store.len() && seen < self.config.slice {
            seen += 1;
            let stamp = self.stamp.get(pos).copied().unwrap_or(0);
            if self.store.get(pos).is_some_and(|s| keep(s, stamp)) {
                pos += 1;
            } else {
                self.remove(pos);
            }
        }
        pos
    }

    /// Takes `slot` out of the ring of `cell`, keeping the others' order.
    fn unlink(&mut self, cell: usize, slot: usize) {
        let (Some(ring), Some(fill), Some(head)) = (
            self.ring.get_mut(cell),
            self.fill.get_mut(cell),
            self.head.get_mut(cell),
        ) else {
            return;
        };
        let (h, k) = (usize::from(*head), usize::from(*fill));
        let Some(at) =
            (0..k).find(|&i| ring.get((h + i) % K).map(|&r| usize::from(r)) == Some(slot))
        else {
            return;
        };
        for i in at..k.saturating_sub(1) {
            let next = ring.get((h + i + 1) % K).copied().unwrap_or(0);
            if let Some(r) = ring.get_mut((h + i) % K) {
                *r = next;
            }
        }
        *fill -= 1;
    }

    /// Keeps `sample` among the recent readings when its direction differs
    /// from the last one kept.
    fn remember(&mut self, sample: S, dir: [f32; 3]) {
        if let Some(last) = self.recent_direction {
            if !far_enough(&dir, &last, self.min_chord_sq) {
                return;
            }
        }
        self.recent_direction = Some(dir);
        if self.recent.push(sample).is_err() {
            if let Some(s) = self.recent.get_mut(self.recent_next) {
                *s = sample;
            }
            self.recent_next = (self.recent_next + 1) % RECENT;
        }
    }

    /// Updates the stale watch with the residual of one reading in fit
    /// errors; whether the reading is off.
    fn watch(&mut self, z: f32) -> bool {
        let limit = self.config.stale_rms;
        // Clipped, so that one wild reading weighs as a strongly off one,
        // not as hundreds (a non-finite one as the clip).
        let clip = 4.0 * limit.abs();
        let z = if z.abs() <= clip { z } else { clip };
        let w = &mut self.watch;
        w.mean_square += (z * z - w.mean_square) / 32.0;
        if w.mean_square > limit * limit {
            w.persistent = w.persistent.saturating_add(1);
        } else if w.mean_square < 0.5625 * limit * limit {
            // Calm again (hysteresis: a dip in directions that a moved hard
            // iron hardly changes does not end a rise).
            w.persistent = 0;
            if w.mean_square < 0.25 * limit * limit {
                // Off readings of an episode that ended are not the new
                // hard iron's.
                self.recent.clear();
                self.recent_next = 0;
                self.recent_direction = None;
            }
        }
        z.abs() > limit
    }

    // ------------------------------------------------------------- refit

    /// The start of a refit: the calibration in use, or the running sphere.
    fn prior(&self) -> Prior<T> {
        let (centre, scale, w) = match &self.current {
            Some(c) => {
                let rho = c.calibration.field_strength();
                (c.calibration.hard_iron(), rho, c.calibration.w() * rho)
            }
            None => {
                let c = self.sphere.centre();
                let r = libm::sqrtf(self.sphere.radius_sq(c).max(0.0));
                (
                    c.map(T::from_single),
                    T::from_single(r),
                    Matrix3::identity(),
                )
            }
        };
        let scale = if scale > T::zero() && scale.is_finite() {
            scale
        } else {
            T::one()
        };
        Prior {
            norm: Normalization {
                centre: Vector3::from(centre),
                scale,
                inv_scale: T::one() / scale,
            },
            w,
        }
    }

    /// The next slice of the buffer from `pos`, and the position after it.
    fn slice(&self, pos: usize) -> (&[S], usize) {
        let end = pos
            .saturating_add(self.config.slice.max(1))
            .min(self.store.len());
        (self.store.get(pos..end).unwrap_or(&[]), end)
    }

    /// One slice of `stage`; the stage after it and what to report.
    fn advance(&mut self, stage: Stage<T>) -> (Stage<T>, Stepped) {
        match stage {
            Stage::Idle => (Stage::Idle, Stepped::Idle),
            Stage::Prior {
                prior,
                pos,
                mut sums,
            } => {
                let (rows, end) = self.slice(pos);
                let map = Projector::new(&prior.norm, &Vector3::zeros(), &prior.w);
                sums.add(rows, &map, &Gate::PLAIN, &Runs::NONE, None, true);
                if end < self.store.len() {
                    let stage = Stage::Prior {
                        prior,
                        pos: end,
                        sums,
                    };
                    return (stage, Stepped::Working);
                }
                match sums.finish(None) {
                    Ok(pass) => {
                        let limit = cut(pass.fit_error);
                        let moments = MomentsPass::new(prior.norm, Some(Cut { map, limit }));
                        let refit = Refit {
                            prior,
                            current_error: pass.fit_error,
                            pos: 0,
                            pass: RefitPass::Moments(moments),
                        };
                        (Stage::Refit(refit), Stepped::Working)
                    }
                    Err(e) => self.refused(e),
                }
            }
            // Stepped in place (`Background::refit`).
            stage @ Stage::Refit(_) => (stage, Stepped::Working),
            Stage::Age { mut pos } => {
                let now = self.counters.readings as u32;
                let max_age = self.config.max_age;
                pos = self.sweep(pos, |_, stamp| now.wrapping_sub(stamp) <= max_age);
                if pos < self.store.len() {
                    (Stage::Age { pos }, Stepped::Working)
                } else if self.store.len() >= MIN_SAMPLES
                    && self.cells_filled() >= self.config.min_cells
                {
                    (self.start_refit(), Stepped::Working)
                } else {
                    (Stage::Idle, Stepped::Working)
                }
            }
            Stage::Purge { mut pos, old } => {
                let Some(current) = self.current else {
                    return (Stage::Idle, Stepped::Idle);
                };
                let sigma = larger(current.fit_error, T::lit(MIN_SIGMA));
                let limit = sigma * T::lit(OUTLIER_CUT);
                let fits = |cal: &Calibration<T>, s: &S| {
                    let u = cal.apply(*s);
                    (dot(&u, &u).sqrt() - T::one()).abs() <= limit
                };
                // Kept: rows the new hard iron fits and the old does not
                // (taken after the change). Rows both fit are biased by up
                // to the limit in the old direction and would pull the next
                // refit back.
                let before = self.store.len();
                pos = self.sweep(pos, |s, _| fits(&current.calibration, s) && !fits(&old, s));
                let dropped = before - self.store.len();
                self.counters.purged = self.counters.purged.saturating_add(dropped as u32);
                if pos < self.store.len() {
                    (Stage::Purge { pos, old }, Stepped::Working)
                } else {
                    (Stage::Idle, Stepped::Working)
                }
            }
        }
    }

    /// One slice of the refit's pass (or its one solve), in place; at the
    /// end of a pass, what it gives and the next pass, or the refit's end.
    fn refit(&mut self) -> Stepped {
        let Stage::Refit(refit) = &mut self.stage else {
            return Stepped::Idle;
        };
        let len = self.store.len();
        let end = refit.pos.saturating_add(self.config.slice.max(1)).min(len);
        let rows = self.store.get(refit.pos..end).unwrap_or(&[]);
        let (plain, norm) = (Gate::PLAIN, &refit.prior.norm);
        match &mut refit.pass {
            RefitPass::Moments(pass) => pass.feed(rows, &plain),
            RefitPass::Solve(_) => {}
            RefitPass::Adc { pass, .. } => pass.feed(rows, &plain, &Runs::NONE),
            RefitPass::Final {
                est, limit, sums, ..
            } => {
                let map = Projector::new(norm, &est.centre, &est.w);
                sums.add(rows, &map, &plain, &Runs::NONE, Some(*limit), false);
            }
        }
        let sliced = !matches!(refit.pass, RefitPass::Solve(_));
        if sliced && end < len {
            refit.pos = end;
            return Stepped::Working;
        }
        refit.pos = 0;
        let th = &self.config.thresholds;
        let next = match &refit.pass {
            RefitPass::Moments(pass) => Ok(RefitPass::Solve(*pass.moments())),
            RefitPass::Solve(moments) => ls_start(norm, refit.current_error, moments, len, th),
            RefitPass::Adc {
                ls,
                round,
                start,
                pass,
            } => adc_end(norm, *ls, *round, start, pass),
            RefitPass::Final {
                ls,
                est,
                directions,
                sums,
                ..
            } => {
                let result = sums.finish(Some(*directions)).and_then(|last| {
                    let (warnings, quality) = background::judge_refit(ls, len, &est.w, &last, th)?;
                    let calibration = Calibration::from_normalised_w(norm, &est.w, &est.centre)?;
                    Ok(Current {
                        calibration,
                        quality,
                        warnings,
                        fit_error: last.fit_error,
                        radial_rms: last.radial_rms,
                    })
                });
                let current_error = refit.current_error;
                self.counters.refits += 1;
                let (stage, stepped) = match result {
                    Ok(current) => self.conclude(current, current_error),
                    Err(e) => self.refused(e),
                };
                self.stage = stage;
                return stepped;
            }
        };
        match next {
            Ok(pass) => {
                refit.pass = pass;
                Stepped::Working
            }
            Err(e) => {
                let (stage, stepped) = self.refused(e);
                self.stage = stage;
                stepped
            }
        }
    }

    /// The end of a refit that passed every check: `current` is adopted
    /// when there is no calibration in use, or when it replaces the one in
    /// use (whose fit error on the buffer is `current_error`), else kept.
    fn conclude(&mut self, current: Current<T>, current_error: T) -> (Stage<T>, Stepped) {
        let in_use = self.current.map(|c| c.quality.coverage);
        let q = &current.quality;
        if !background::replaces(current.fit_error, q.coverage, current_error, in_use) {
            return (Stage::Idle, Stepped::Kept);
        }
        self.adopt(current, false);
        self.counters.adopted += 1;
        (Stage::Idle, Stepped::Adopted)
    }

    /// The first stage of a refit.
    fn start_refit(&self) -> Stage<T> {
        Stage::Prior {
            prior: self.prior(),
            pos: 0,
            sums: FinalSums::new(),
        }
    }

    fn refused(&mut self, e: Error) -> (Stage<T>, Stepped) {
        self.counters.refused += 1;
        (Stage::Idle, Stepped::Refused(e))
    }

    /// Puts `current` in use. After a new hard iron (`reset_watch`) the
    /// stale watch starts again; after a refit it goes on, so that a drift
    /// the refit followed only in part still shows.
    fn adopt(&mut self, current: Current<T>, reset_watch: bool) {
        self.current = Some(current);
        self.adopted_at = self.counters.readings;
        if reset_watch {
            self.watch = Watch::CALM;
        }
        // Directions are now seen from the new calibration.
        self.last_direction = None;
        self.recent_direction = None;
    }

    /// The offsets-only fit of the recent readings (one call).
    fn try_offsets(&mut self) -> Stepped {
        let Some(current) = self.current else {
            return Stepped::Idle;
        };
        // Not again before half the recent readings are new.
        if self.counters.readings < self.last_offsets_try + (RECENT / 2) as u64 {
            return Stepped::Idle;
        }
        self.last_offsets_try = self.counters.readings;
        let fit = refit_offsets(&self.recent, &current.calibration, Strength::Unchanged);
        let result = fit.and_then(|fit| {
            background::judge_offsets(&fit, current.fit_error)?;
            Ok(fit)
        });
        match result {
            Ok(fit) => {
                self.adopt(
                    Current {
                        calibration: fit.calibration,
                        quality: current.quality,
                        warnings: current.warnings,
                        fit_error: larger(fit.fit_error, current.fit_error),
                        radial_rms: current.radial_rms,
                    },
                    true,
                );
                self.counters.offsets_adopted += 1;
                self.recent.clear();
                self.recent_next = 0;
                self.new_samples = 0;
                self.stage = Stage::Purge {
                    pos: 0,
                    old: current.calibration,
                };
                Stepped::OffsetsAdopted
            }
            Err(e) => {
                self.counters.offsets_refused += 1;
                Stepped::OffsetsRefused(e)
            }
        }
    }
}

/// The LS step of a refit of `valid` buffered rows on the moments of the
/// rows within the prior's cut: the first artificial-data pass from the LS
/// fit, with the same cut (from `current_error`, the prior's fit error); a
/// failed LS fit is judged on the flatness with the thresholds `th`
/// (planar data fail it).
fn ls_start<T: Real>(
    norm: &Normalization<T>,
    current_error: T,
    moments: &Moments<T>,
    valid: usize,
    th: &Thresholds,
) -> Result<RefitPass<T>, Error> {
    let flatness = quality::flatness(moments, moments.count())?;
    let (ls, quadric_gap) = crate::pipeline::ls_step(moments, ellipsoid::ls9);
    let figures = LsFigures {
        flatness,
        quadric_gap: None,
    };
    // Planar data fail the LS fit: say so.
    let ls: Ellipsoid<T> =
        ls.map_err(|e| quality::judge_failure(&figures.figures(valid), th, e))?;
    let limit = cut(current_error);
    Ok(RefitPass::Adc {
        ls: LsFigures {
            flatness,
            quadric_gap,
        },
        round: 0,
        pass: AdcPass::new(norm, &ls.centre, &ls.w, Some(limit)),
        start: Estimate {
            centre: ls.centre,
            w: ls.w,
            t: ls.t,
        },
    })
}

/// The end of a refit's artificial-data pass from `start`: the ADC2
/// solve in closed form; then the next round from its estimate, with the
/// cut of this pass's residuals, or after round 1 the final pass under it.
fn adc_end<T: Real>(
    norm: &Normalization<T>,
    ls: LsFigures<T>,
    round: u8,
    start: &Estimate<T>,
    pass: &AdcPass<T>,
) -> Result<RefitPass<T>, Error> {
    let stats = pass.stats(&start.w)?;
    let sol = adc2::solve(&stats, &start.t, &start.centre)?;
    let est = Estimate {
        centre: sol.centre,
        w: sym_inv_sqrt(&(sol.t * sol.t.transpose()))?,
        t: sol.t,
    };
    let limit = cut(pass.sigma().unwrap_or(T::zero()));
    Ok(if round == 0 {
        RefitPass::Adc {
            ls,
            round: 1,
            pass: AdcPass::new(norm, &est.centre, &est.w, Some(limit)),
            start: est,
        }
    } else {
        RefitPass::Final {
            ls,
            est,
            directions: DirectionSums::from(&stats),
            limit,
            sums: FinalSums::new(),
        }
    })
}

/// The residual cut of a pass: [`OUTLIER_CUT`] robust standard deviations
/// of the pass before, at least [`MIN_SIGMA`] of them.
fn cut<T: Real>(sigma: T) -> T {
    larger(sigma, T::lit(MIN_SIGMA)) * T::lit(OUTLIER_CUT)
}

/// `v / |v|`, or `None` for a zero or non-finite `v`.
fn unit(v: [f32; 3]) -> Option<[f32; 3]> {
    let r = libm::sqrtf(dot(&v, &v));
    if !(r > 0.0) || !r.is_finite() {
        return None;
    }
    Some([v[0] / r, v[1] / r, v[2] / r])
}

/// Whether two unit directions are farther apart than the chord whose
/// square is `chord_sq`.
fn far_enough(a: &[f32; 3], b: &[f32; 3], chord_sq: f32) -> bool {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    dot(&d, &d) > chord_sq
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::Rng;

    /// The rings, fill counts and cell tags describe the store exactly.
    fn consistent<const N: usize, const K: usize>(bg: &Background<f32, [f32; 3], N, K>) {
        let mut seen = [false; N];
        let mut total = 0;
        for cell in 0..CELLS {
            let (h, k) = (usize::from(bg.head[cell]), usize::from(bg.fill[cell]));
            assert!(k <= K);
            for i in 0..k {
                let slot = usize::from(bg.ring[cell][(h + i) % K]);
                assert!(slot < bg.store.len(), "cell {cell}: slot {slot}");
                assert!(!seen[slot], "slot {slot} twice");
                assert_eq!(usize::from(bg.cell_of[slot]), cell);
                seen[slot] = true;
            }
            total += k;
        }
        assert_eq!(total, bg.store.len());
    }

    #[test]
    fn the_buffer_stays_consistent_through_replacements_and_removals() {
        let mut rng = Rng(7);
        let mut bg: Background<f32, [f32; 3], 96, 2> = Background::new(BackgroundConfig {
            min_angle_deg: 0.0,
            ..BackgroundConfig::DEFAULT
        })
        .unwrap();
        for round in 0..2000 {
            let v = [
                rng.symmetric() as f32,
                rng.symmetric() as f32,
                rng.symmetric() as f32,
            ];
            let cell = collector::cell(v).unwrap_or(0);
            bg.store_in(v.map(|x| x * 100.0), cell);
            if round % 7 == 0 && !bg.store.is_empty() {
                let slot = (rng.uniform() * bg.store.len() as f64) as usize;
                bg.remove(slot);
            }
            consistent(&bg);
        }
        assert!(bg.store.len() > 48, "{}", bg.store.len());
    }

    #[test]
    fn a_configuration_that_cannot_be_used_is_refused_by_name() {
        let d = BackgroundConfig::DEFAULT;
        let cases = [
            (
                BackgroundConfig {
                    min_angle_deg: -1.0,
                    ..d
                },
                "min_angle_deg",
            ),
            (
                BackgroundConfig {
                    min_angle_deg: f32::NAN,
                    ..d
                },
                "min_angle_deg",
            ),
            (
                BackgroundConfig {
                    stale_rms: 0.0,
                    ..d
                },
                "stale_rms",
            ),
            (
                BackgroundConfig {
                    stale_rms: f32::INFINITY,
                    ..d
                },
                "stale_rms",
            ),
            (BackgroundConfig { slice: 0, ..d }, "slice"),
            (
                BackgroundConfig {
                    min_cells: CELLS + 1,
                    ..d
                },
                "min_cells",
            ),
            (
                BackgroundConfig {
                    thresholds: Thresholds {
                        refuse_coverage: f32::NAN,
                        ..Thresholds::DEFAULT
                    },
                    ..d
                },
                "refuse_coverage",
            ),
        ];
        for (config, field) in cases {
            let made: Result<Background<f32, [f32; 3], 96, 2>, _> = Background::new(config);
            assert_eq!(made.err(), Some(Error::InvalidConfig { field }));
        }
        let edge = BackgroundConfig {
            min_angle_deg: 0.0,
            min_cells: CELLS,
            slice: 1,
            ..d
        };
        assert!(Background::<f32, [f32; 3], 96, 2>::new(edge).is_ok());
    }

    #[test]
    fn a_full_cell_replaces_its_oldest_sample() {
        let mut bg: Background<f32, [f32; 3], 96, 2> =
            Background::new(BackgroundConfig::DEFAULT).unwrap();
        for k in 0..5 {
            bg.store_in([k as f32, 0.0, 0.0], 3);
        }
        // Two slots: the last two samples, 3 and 4.
        assert_eq!(bg.store.len(), 2);
        let mut kept: heapless::Vec<f32, 2> = bg.store.iter().map(|s| s[0]).collect();
        kept.sort_unstable_by(f32::total_cmp);
        assert_eq!(kept.as_slice(), &[3.0, 4.0]);
        consistent(&bg);
    }
}
