//! Collecting samples one at a time on the device, with coverage.
//!
//! A [`Collector`] stores up to `N` raw samples inline (no heap) and decides
//! for each new reading, in constant time, whether it is worth keeping. It
//! tracks which part of the sphere of field directions the kept samples
//! cover and says when that is enough to calibrate ([`Progress::ready`]).
//! It is a gate in front of [`crate::calibrate`], not a calibration: its
//! estimates only need to be good enough to sort samples into cells about
//! 30 deg across. Everything runs in `f32`.
//!
//! # Work per sample
//!
//! [`Collector::offer`] costs the same for the first and the ten-thousandth
//! sample, whatever `N`: a fixed update of running sums (about 40 flops),
//! one 3x3 solve by cofactors (about 50 flops, one division), two
//! normalisations (two square roots), the noise estimate (about 30 flops,
//! two square roots, see "Still devices"), and the re-classification of
//! [`RESCAN_PER_OFFER`] = 4 stored samples in round robin (about 15 flops
//! each, no square root). There is no loop over the stored samples, except
//! once per collection over the first [`OUTLIER_MIN_SAMPLES`] (see
//! "Stalls").
//! [`Collector::progress`] re-examines at most [`CELLS`] samples, one per
//! cell.
//!
//! # Dirty input
//!
//! Glitch rows (exactly `(0, 0, 0)`, a component on an integer type's
//! rails) are refused as [`Offer::Glitch`], the rows [`crate::calibrate`]
//! would drop anyway; an exact repeat is [`Offer::TooClose`]. Once
//! [`OUTLIER_MIN_SAMPLES`] samples are stored, a reading farther than
//! [`OUTLIER_RADII`] radii from the running centre is refused as
//! [`Offer::Outlier`]: one wild reading in the running sums would move the
//! centre, and with it every cell, by more than the field. Moderate
//! disturbances (a magnet passing at a distance) are left to the
//! calibration's own outlier handling.
//!
//! # Still devices
//!
//! A reading is kept only when the device has moved since the last sample
//! kept by more than the sensor's noise: [`NOISE_SPACING`] = 10 standard
//! deviations, measured on the readings smoothed over about 7 readings
//! (exponential weight 1/4), and at least 3 quanta of quantised readings
//! (3 counts for integer samples). The rule guards a device lying still
//! when the collection starts: before the centre is known its noise
//! points every way from a centre inside the noise, and readings spaced
//! by direction alone fill the 36 cells readiness asks for within 300
//! readings, on samples the core refuses.
//!
//! The noise is learnt from the readings themselves, whatever their unit:
//! noise makes consecutive steps `d_k = y_k - y_(k-1)` point against each
//! other (`E[d_k . d_(k-1)] = -3 sigma^2` for independent noise of
//! `sigma` per axis), a turning device makes them point the same way. The
//! estimate `sigma^2 = max(0, -mean(d_k . d_(k-1))) / 3` is therefore the
//! noise of a device lying still and about zero for one that turns, even
//! coarsely sampled: recordings at 11 deg a reading collect as fast as
//! when spaced by direction alone. The mean takes evidence of noise quicker (weight 1/16) than it
//! lets go of it (1/32), so a device that stops is soon recognised and one
//! that starts turning is spaced at most by the noise; its inputs are
//! clipped at 4 times their typical size (a wild reading moves it by a
//! few noise levels). The first reading is stored at once, the next ones
//! from the [`NOISE_READINGS`]-th (9th) reading on, when the estimate
//! exists.
//!
//! Noise correlated from reading to reading (a sensor's low-pass filter,
//! a host's smoothing) looks smaller to this estimate than it is (by the
//! factor `1 - a` for correlation `a`), and a still device then stores
//! some samples, all within the noise of a centre inside them.
//! [`Collector::progress`] therefore counts a cell only when its sample is
//! farther from the running centre than the spacing, averaged over about
//! 256 readings: a sphere's samples are, unless the field is below 10
//! noise standard deviations.
//!
//! Measured (`cargo test -p mag-cal-core --test collector -- --nocapture`,
//! `a_device_lying_still_never_becomes_ready`: `i16`, 320-count field, 8
//! seeds each, in counts and as unquantised `f32`): independent noise of
//! 0.1, 0.3, 1, 2.5 and 3 counts for 300, 3 000 and 30 000 readings stores
//! 1 sample and shows 0 % progress; noise correlated from reading to
//! reading (AR(1), as a low-pass filter makes it) stores at most 2
//! samples (correlation 0.35), 3 (0.5), 29 and 72 (0.7, `i16` and `f32`)
//! and 272 and 454 (0.8), and the highest progress at any reading is 0 %,
//! 2 %, 6 % and 13 %, 72 % and 75 %: strongly filtered noise looks like
//! slow motion (it was never ready in these runs). Real recordings,
//! readings to ready with capacity 600: `icm20948_mag_300.csv` 120,
//! `mag3_raw_541.csv` 181, and after a still start of 300 to 30 000
//! readings 127 and 181-185. `magcal_25598.txt` starts lying still; with
//! capacity 4 000 the collector is ready after 4 952 readings, on samples
//! that calibrate (with 600 it fills at 35 cells: the recording turns
//! mostly about one axis for its first 5 000 readings). `cargo test -p host-tests --test
//! collector_real -- --nocapture`.
//!
//! The rule needs the readings in the order the sensor gave them, from a
//! device that turns smoothly between readings: readings in random order
//! (a shuffled log), or a device jerked to unrelated directions between
//! readings, look like noise of the size of the field, and little is
//! kept. Measured (field 320 counts, noise 2.3 counts, a random walk of
//! the field direction with a fresh random step direction every reading,
//! readings to ready): 5 deg steps 2 706, 10 deg 1 079, 20 deg 1 811,
//! 30 deg never (3 000 readings); a steady turn collects as when spaced by
//! direction alone up to 60 deg a reading.
//! A device turned by hand and read at 5 Hz or more turns smoothly between
//! readings.
//!
//! # Stalls
//!
//! Two kinds of collection leave a store that no later reading can extend,
//! and the collector then starts over ([`Offer::Restarted`]: every sample
//! is discarded, as by [`Collector::clear`]):
//!
//! - **A collection from before the sensor was moved** to another place
//!   (another hard iron): every reading is an outlier of the store. After
//!   [`STALL_OFFERS`] outliers in a row (and at least as many as there are
//!   samples) the store is taken for the stale one.
//! - **A wild reading among the first ones** (a sensor's start-up value
//!   30 000 counts off). Before [`OUTLIER_MIN_SAMPLES`] samples there is no
//!   outlier test, and such a reading drags the running centre so far that
//!   every later reading points the same way from it. The collector starts
//!   over after [`STALL_OFFERS`] readings in a row too close while the
//!   store is that small, and when it reaches [`OUTLIER_MIN_SAMPLES`]
//!   samples it checks them once: it starts over if one is farther than
//!   [`WILD_SPREAD`] times the median distance from their per-axis median.
//!
//! A magnet held at the sensor for [`STALL_OFFERS`] readings (and more
//! than the store holds) also restarts the collection. A device lying
//! still is no stall: it stores nothing (see "Still devices"), and its
//! readings do not count towards [`STALL_OFFERS`].
//!
//! # Numerical choices
//!
//! **Running centre.** Directions are taken from a running estimate `c` of
//! the hard iron. The mean of the samples is no such estimate: it follows
//! the user's dwell time and sits inside whatever part of the sphere has
//! been visited. The midrange (per axis `(min + max) / 2`) ignores dwell
//! time and is exact once the six axis extremes of the ellipsoid are seen,
//! but on partial coverage it is as biased as the mean: for a polar cap of
//! a sixth of the sphere both put the centre 0.83 `rho` up the axis, so the
//! cap's rim is seen 12 deg *below* the equator and the cap appears to
//! cover two thirds of the 48 cells (the failure the firmware's first
//! coverage figure avoided by an O(n) ellipsoid fit per check). The
//! collector uses instead Kasa's algebraic sphere fit, which is O(1) per
//! sample: minimise `sum (|y|^2 - a.y - d)^2`; the centre `a / 2` solves
//! the 3x3 system `C a = g`, with `C` the covariance of the samples and `g`
//! their covariance with `|y|^2`. Both are updated per sample by Welford's
//! recurrences on `y - y_0` (`y_0` the first sample kept), which do not
//! cancel catastrophically in `f32` as raw power sums would. The fit is
//! exact for samples on a sphere, whatever part of it they cover, and by
//! symmetry exact for any centrally symmetric coverage of an ellipsoid (the
//! full sphere, a band). On a cap of a distorted ellipsoid it is biased by
//! the distortion, not by the cap's height (see the table below).
//!
//! Where the samples do not determine the centre (the first few samples,
//! or a plane, whose normal component of `C` is only noise), the solve is
//! regularised towards the midrange `m`: `(C + mu I) a = g + 2 mu m` with
//! `mu = 0.001 trace(C) / 3`. Along well-observed directions (eigenvalues
//! of `C` far above `mu`) this is the sphere fit, pulled towards the
//! midrange by the fraction `mu / (lambda + mu)` (1 % for a cap of a sixth
//! of the sphere); along unobserved ones it is the midrange. The matrix is
//! symmetric positive definite with condition number at most
//! `1 + 3 / 0.001 = 3001`, so the cofactor solve in `f32` is accurate to
//! about `3001 * 2^-24 = 2e-4` relative, plenty for a gate, and no case
//! distinction is needed.
//!
//! **Near-duplicates.** A sample is kept only if its direction from the
//! current centre differs by at least the minimum angle from that of the
//! last sample kept (measured from the same centre). The test compares the
//! chord `|u - v|` of the two unit vectors with `2 sin(angle / 2)`: unlike
//! `u . v` against `cos(angle)` it does not cancel for small angles. A
//! direction must differ by a strictly positive angle, so an exact repeat is
//! refused even with a minimum angle of zero. The default,
//! [`DEFAULT_MIN_ANGLE_DEG`] = 4 deg, is about 10 standard deviations of the
//! angular noise of a typical MEMS magnetometer (1-3 counts of noise on a
//! field of 300-500 counts: 0.2-0.5 deg), so a device held still adds no
//! samples once the centre is known, while a cell (about 30 deg across)
//! still gets about 7 samples on every pass. Slow motion is kept too, one
//! sample per 4 deg turned. Before the centre is known, directions mean
//! nothing for a device held still; the noise spacing (see "Still
//! devices") keeps its readings out.
//!
//! **Cells.** The sphere is cut into [`BANDS`] = 6 zones of equal height in
//! `z` and [`SECTORS`] = 8 sectors of 45 deg in longitude: [`CELLS`] = 48
//! cells. By Archimedes' theorem (Lambert's cylindrical projection
//! preserves area) a zone's area is proportional to its height, so all
//! cells have the same area, `4 pi / 48` sr (about 29 deg across). The band
//! is `floor(3 (z / r + 1))`, found by comparing `9 z^2` with `r^2` and
//! `4 r^2`; the sector comes from the signs of `x`, `y` and the comparison
//! of `|x|` with `|y|`: no square root, no `atan2`. The cells live in the
//! sensor frame around the current centre, so on a distorted sensor they
//! are equal-area up to the soft iron (a few tens of percent).
//!
//! **Moving centre.** A sample's cell depends on the centre, which moves
//! while samples arrive, so classifications made early may be off. Each
//! cell remembers one sample, its *witness*: the latest one classified into
//! it, either when kept or when the round robin of [`Collector::offer`]
//! re-classifies it against the then current centre (at 4 samples a call
//! the round robin laps a store growing by one sample a call within
//! `len / 3` calls). [`Collector::progress`] re-classifies the at most 48
//! witnesses against the current centre and counts the distinct cells they
//! fall in. The count is therefore never more than the number of cells
//! holding a stored sample as seen from the current centre (it is never
//! optimistic); it may be a few cells short while the centre still moves,
//! and it can go down.
//!
//! **Ready.** [`Progress::ready`] needs [`READY_CELLS`] = 36 of the 48
//! cells (75 %) and [`READY_SAMPLES`] = 100 samples (or the capacity, if
//! smaller). The core refuses a fit whose calibrated directions have
//! `lambda_min(cov(h)) < 0.05`: a full sphere has 0.31 to 0.33, a band of
//! elevation `+-a` has `sin(a)^2 / 3`, which is 0.085 at +-30 deg and 0.05
//! at +-23 deg. With six equal-height bands every band from +-19.5 deg to
//! +-41.8 deg touches the same 32 cells (67 %), so a threshold of 60-70 %
//! would call a +-20 deg band ready, which the core refuses; 36 cells
//! needs samples towards both poles. 100 samples is ten times the fit's
//! minimum ([`crate::MIN_SAMPLES`]) and twice the count below which the
//! design has the fit warn; with 36 cells it is about 3 samples a cell.
//! Collecting on after `ready` only improves the calibration.
//!
//! Measured (firmware-like sensor: `rho` = 320 counts, noise 2.5 counts,
//! `i16`, hard iron (180, -95, 240); soft iron `V diag(0.8, 1, 1.25) V^T`
//! or none; spiral motion, 900 offers, cells visited at the end):
//!
//! | field directions | cells, no soft iron | cells, soft iron | ready | with the midrange instead | core fit |
//! |---|---|---|---|---|---|
//! | full sphere | 48 | 47 | yes | 48 | ok |
//! | band +-45 deg | 48 | 44 | yes | 41-45 | ok |
//! | band +-30 deg | 32 | 31 | no | 31-32 | ok |
//! | band +-20 deg | 30 | 26 | no | 24-26 | refused |
//! | cap 65 % (z > -0.3) | 32 | 36 | no / yes | 40, ready | ok |
//! | hemisphere | 29 | 28 | no | 39-40, ready | ok |
//! | cap 35 % (z > 0.3) | 24 | 20 | no | 37-38, ready | refused |
//! | cap 17 % (z > 2/3) | 16 | 13 | no | 31-32 | refused |
//! | level turn (planar) | 16 | 11 | no | 10-16 | refused |
//! | tilted great circle | 19 | 18 | no | 20 | refused |
//!
//! Wherever the collector says ready, the core accepts the fit; it is
//! conservative the other way (a +-30 deg band or a hemisphere still
//! calibrate, with 1.2-11 times the hard-iron error of the full sphere).
//! With the midrange, caps the core refuses would read ready. The firmware
//! example's motion (a pole-to-pole spiral of 600 samples 8 deg apart)
//! becomes ready after 380-410 samples.
//!
//! ```
//! use mag_cal_core::collector::{Collector, Offer};
//!
//! // 6 bytes a sample: 600 samples in 3.6 kB.
//! let mut collector: Collector<[i16; 3], 600> = Collector::default();
//! assert_eq!(collector.offer([120, -40, 300]), Offer::Accepted);
//! assert_eq!(collector.offer([120, -40, 300]), Offer::TooClose);
//! let p = collector.progress();
//! assert_eq!((p.samples, p.ready), (1, false));
//! ```

use crate::numerics::linalg::dot;
use crate::numerics::sphere::CentreFit;
use crate::sample::Sample;

/// Default minimum angle between consecutive kept samples, degrees (see the
/// module documentation for the choice).
pub const DEFAULT_MIN_ANGLE_DEG: f32 = 4.0;

/// Equal-height zones of the sphere (in `z`).
pub const BANDS: usize = 6;

/// Longitude sectors of each zone (45 deg each).
pub const SECTORS: usize = 8;

/// Equal-area direction cells: [`BANDS`] x [`SECTORS`].
pub const CELLS: usize = BANDS * SECTORS;

/// Cells that must hold a sample before the collector is ready (75 %).
pub const READY_CELLS: usize = 36;

/// Samples needed before the collector is ready (or the capacity, if
/// smaller).
pub const READY_SAMPLES: usize = 100;

/// Stored samples re-classified per call of [`Collector::offer`]: more
/// than one, so that the round robin laps a store that grows by one sample
/// a call: at 4 it revisits every sample within about `len / 3` calls.
pub const RESCAN_PER_OFFER: usize = 4;

/// Once this many samples are stored, a reading farther than
/// [`OUTLIER_RADII`] radii from the running centre is refused as
/// [`Offer::Outlier`]: before that the centre and radius estimates are
/// too rough to judge by.
pub const OUTLIER_MIN_SAMPLES: usize = 20;

/// Readings farther than this many radii (the RMS distance of the stored
/// samples from the running centre) are wild: an ellipsoid of axis ratio 4
/// (the largest distortion a calibration accepts) reaches 1.7 radii from
/// its centre, and a centre still biased by partial coverage adds less
/// than one. One such reading, left in the running sums, would move the
/// centre estimate by more than the field (its weight grows with the
/// square of its distance).
pub const OUTLIER_RADII: f32 = 3.0;

/// Readings in a row that the collector cannot use before it starts over
/// ([`Offer::Restarted`]): outliers (at least as many as it holds samples,
/// and at least this many), or readings too close while it holds fewer
/// than [`OUTLIER_MIN_SAMPLES`] samples. At 10-100 readings a second this
/// is 1-10 s of a device that turns but adds nothing.
pub const STALL_OFFERS: usize = 100;

/// When the store reaches [`OUTLIER_MIN_SAMPLES`] samples, it starts over
/// if one of them is farther than this many times the median distance of
/// the samples from their per-axis median. The first samples of a device
/// turning lie on an arc (the farthest at about twice the median distance)
/// or in a noise ball (about twice as well); a wild reading among them is
/// hundreds of times farther.
pub const WILD_SPREAD: f32 = 8.0;

/// No witness for a cell yet.
const NO_WITNESS: usize = usize::MAX;

/// A reading is a new sample only once the device has moved this many
/// standard deviations of the sensor's noise (per axis) since the last
/// sample stored, as the smoothed readings see it (see "Still devices" in
/// the [module documentation](self)). At 2.5 counts of noise on a 320-count
/// field that is 25 counts, 4.5 deg: about the [`DEFAULT_MIN_ANGLE_DEG`]
/// spacing, so a device that turns is not slowed. The smoothed position of
/// a still device moves by 0.53 standard deviations per axis between two
/// readings far apart (independent noise), so 10 is beyond any excursion
/// in 30 000 readings; it also leaves room for noise correlated from
/// reading to reading, which the estimate sees smaller than it is (by the
/// factor `1 - a` for correlation `a`).
pub const NOISE_SPACING: f32 = 10.0;

/// Weight of a reading's spacing in the slow mean of the spacing that
/// [`Collector::progress`] holds samples to (a stored sample marks its
/// cell only when it is farther than that mean from the running centre,
/// see "Still devices" in the [module documentation](self)). About 256
/// readings: the noise estimate of a still device with correlated noise
/// dips for tens of readings at a time; held to the spacing of the moment
/// (even to twice it), a still `f32` device at correlation 0.7 showed
/// 11 % after 300 readings, and one at 0.8 was ready for a moment. The
/// floor is one mean spacing, not more: at 1.25 and above, a device
/// jerked 20 deg a reading in random directions (field 320 counts, noise
/// 2.3) was never ready in 3 000 readings (its noise estimate is a
/// seventh of its step, the field only three steps).
const SPACING_MEAN_WEIGHT: f32 = 1.0 / 256.0;

/// Readings the collector takes to learn the sensor's noise: it stores the
/// first reading offered, and no other before this many have been offered
/// (the noise estimate needs seven pairs of consecutive steps).
pub const NOISE_READINGS: usize = 9;

/// Quanta of quantised readings (the smallest change of a component seen
/// between consecutive readings, one count for integer samples) a reading
/// must also move: noise below one count shows as rare one-count toggles,
/// which the noise estimate cannot see (without this floor a still `i16`
/// device with 0.2-0.3 counts of noise filled a store of 600 in 30 000
/// readings).
const QUANTUM_SPACING: f32 = 3.0;

/// Weight of a reading in the smoothed position the noise spacing is
/// measured on: it averages the noise of about 7 readings (white noise:
/// 0.38 of its standard deviation per axis). Measured on raw readings
/// instead, a still `f32` device with noise correlated 0.7 from reading to
/// reading stored up to 75 samples in 30 000 readings, smoothed up to 32
/// (with the weights of an earlier trial, 1/16 and 1/128).
const POSITION_WEIGHT: f32 = 0.25;

/// Second differences whose smallest seeds the noise level: a wild reading
/// among the first readings touches three of them.
const NOISE_SEED: u8 = 4;

/// Values over which the noise estimates settle (running means before).
const NOISE_WARMUP: u8 = 16;

/// Weight of a second difference in the mean second-difference length
/// (after [`NOISE_WARMUP`]).
const LEVEL_WEIGHT: f32 = 1.0 / 16.0;

/// Weight of a product of consecutive steps in their mean when it points
/// towards noise (more negative than the mean) and towards motion: the
/// estimate takes noise in quicker than it lets go of it. The balance is
/// measured (module documentation, "Still devices"): a weight of 1/16 both
/// ways let a still device with noise correlated 0.5 from reading to
/// reading become ready (221 samples of 600); 1/128 towards motion kept
/// it below 25 % even at correlation 0.7 but collected nothing from a
/// device jerked 10 deg a reading in random directions.
const TOWARDS_NOISE: f32 = 1.0 / 16.0;
/// See [`TOWARDS_NOISE`].
const TOWARDS_MOTION: f32 = 1.0 / 32.0;

/// A second difference, or a product of consecutive steps, enters its mean
/// clipped at this many times the mean's typical size: a wild reading
/// among the first ones moves the estimates by a few noise levels, not by
/// its own size (unclipped, a wild second reading made the collector take
/// every later reading for noise: the collection of
/// `a_wild_reading_among_the_first_does_not_stall_the_collection` never
/// got past one sample).
const NOISE_CLIP: f32 = 4.0;

/// What the collector knows about the sensor's noise, from every reading
/// offered that passes the glitch and outlier checks.
///
/// Noise makes consecutive steps `d_k = y_k - y_(k-1)` point against each
/// other: for independent noise of standard deviation `sigma` per axis,
/// `E[d_k . d_(k-1)] = -3 sigma^2`, while a device turning smoothly makes
/// them point the same way (`E = |v|^2 - 3 sigma^2`, `v` the step of the
/// motion). So `sigma^2 = max(0, -mean(d_k . d_(k-1))) / 3` is the noise
/// of a device lying still and about zero for one that turns, however
/// coarsely sampled (steps up to 90 deg of a steady turn).
#[derive(Clone, Copy, Debug)]
pub(crate) struct NoiseGate {
    /// The last reading.
    last: [f32; 3],
    /// The step to it from the one before.
    step: [f32; 3],
    /// The readings, smoothed ([`POSITION_WEIGHT`]).
    pub(crate) position: [f32; 3],
    /// Readings taken (saturating).
    seen: u8,
    /// Mean length of the second difference `d_k - d_(k-1)`: the scale
    /// for clipping (`3.9 sigma` for noise).
    level: f32,
    /// Mean of `d_k . d_(k-1)`.
    product: f32,
    /// Smallest non-zero change of a component between consecutive
    /// readings (infinite before one is seen).
    quantum: f32,
    /// Slow mean of the spacing ([`SPACING_MEAN_WEIGHT`]), zero before
    /// the noise is known.
    spacing_mean: f32,
}

impl NoiseGate {
    pub(crate) const EMPTY: NoiseGate = NoiseGate {
        last: [0.0; 3],
        step: [0.0; 3],
        position: [0.0; 3],
        seen: 0,
        level: 0.0,
        product: 0.0,
        quantum: f32::INFINITY,
        spacing_mean: 0.0,
    };

    /// Takes a (finite) reading; returns how far the smoothed position
    /// must have moved since the last sample stored for the reading to be
    /// new, or `None` while the noise is not known yet.
    pub(crate) fn take(&mut self, y: [f32; 3]) -> Option<f32> {
        self.seen = self.seen.saturating_add(1);
        if self.seen == 1 {
            (self.last, self.position) = (y, y);
            return None;
        }
        let step = sub(y, self.last);
        for ((p, &v), &d) in self.position.iter_mut().zip(&y).zip(&step) {
            *p += POSITION_WEIGHT * (v - *p);
            let d = d.abs();
            if d > 0.0 && d < self.quantum {
                self.quantum = d;
            }
        }
        if self.seen >= 3 {
            self.learn(step);
        }
        (self.last, self.step) = (y, step);
        if usize::from(self.seen) < NOISE_READINGS {
            return None;
        }
        let sigma = libm::sqrtf((-self.product / 3.0).max(0.0));
        let quantum = if self.quantum.is_finite() {
            QUANTUM_SPACING * self.quantum
        } else {
            0.0
        };
        let spacing = (NOISE_SPACING * sigma).max(quantum);
        let w = if usize::from(self.seen) == NOISE_READINGS {
            1.0
        } else {
            SPACING_MEAN_WEIGHT
        };
        self.spacing_mean += w * (spacing - self.spacing_mean);
        Some(spacing)
    }

    /// Updates the means with the step `d_k` (the previous one is
    /// `self.step`).
    fn learn(&mut self, step: [f32; 3]) {
        let bend = sub(step, self.step);
        let s = libm::sqrtf(dot(&bend, &bend));
        let p = dot(&step, &self.step);
        if !s.is_finite() || !p.is_finite() {
            return;
        }
        // Second differences taken, this one included (`seen >= 3`).
        let k = self.seen.saturating_sub(2).max(1);
        if k <= NOISE_SEED {
            // A wild reading shows in three consecutive second differences:
            // the smallest of the first four is one of noise or motion.
            self.level = if k == 1 { s } else { self.level.min(s) };
        } else {
            let s = if self.level > 0.0 {
                s.min(NOISE_CLIP * self.level)
            } else {
                s
            };
            let w = (1.0 / f32::from(k.saturating_sub(NOISE_SEED).max(1))).max(LEVEL_WEIGHT);
            self.level += w * (s - self.level);
        }
        if k < NOISE_SEED {
            return;
        }
        // For noise the product is typically 3 sigma^2 = level^2 / 5
        // (level = 3.9 sigma); clipped at NOISE_CLIP times in amplitude.
        let lim = NOISE_CLIP * NOISE_CLIP * self.level * self.level / 5.0;
        let p = p.max(-lim).min(lim);
        let j = k.saturating_sub(NOISE_SEED).saturating_add(1); // products taken
        let w = if j <= NOISE_WARMUP {
            1.0 / f32::from(j)
        } else if p < self.product {
            TOWARDS_NOISE
        } else {
            TOWARDS_MOTION
        };
        self.product += w * (p - self.product);
    }
}

/// What [`Collector::offer`] did with a sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Offer {
    /// The sample was stored.
    Accepted,
    /// Refused: its direction from the running centre is within the minimum
    /// angle of the last stored sample's (this includes an exact repeat, and
    /// a sample with no direction because it sits on the centre estimate),
    /// or the device has not moved beyond the sensor's noise since that
    /// sample was stored ([`NOISE_SPACING`]; every reading from the second
    /// to the [`NOISE_READINGS`]-th, while the noise is learnt).
    TooClose,
    /// Refused: a component is NaN or infinite in `f32` (including `f64` or
    /// `i32` values beyond `f32`'s range), or the sample is so far from the
    /// first one (beyond about `1e12` units) that the running sums would
    /// overflow `f32`.
    NotFinite,
    /// Refused: the collector holds `N` samples already.
    Full,
    /// Refused: a glitch, as [`crate::calibrate`]'s drop rules see one:
    /// exactly `(0, 0, 0)`, or a component on the integer type's rails
    /// (an exact repeat is [`Offer::TooClose`]).
    Glitch,
    /// Refused: farther than [`OUTLIER_RADII`] radii from the running
    /// centre, once [`OUTLIER_MIN_SAMPLES`] samples are stored (a wild
    /// reading: an I2C glitch, a magnet held against the sensor).
    Outlier,
    /// The collection started over: every stored sample was discarded (as
    /// by [`Collector::clear`]) and this reading was not stored. The stored
    /// samples could not lead anywhere: [`STALL_OFFERS`] readings in a row
    /// were outliers or too close (see "Stalls" in the [module
    /// documentation](self)), or a wild reading was among the first
    /// [`OUTLIER_MIN_SAMPLES`] ([`WILD_SPREAD`]).
    Restarted,
}

/// How far the collection is, as reported by [`Collector::progress`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub struct Progress {
    /// Samples stored.
    pub samples: usize,
    /// Direction cells holding a stored sample, as seen from the current
    /// centre estimate (a lower bound, see the module documentation);
    /// samples within the noise spacing of the centre do not count (see
    /// "Still devices" there).
    pub cells_visited: usize,
    /// Number of cells, [`CELLS`].
    pub cells: usize,
    /// The visited cells as bits: bit `c` is set when cell `c` holds a
    /// stored sample (`cells_visited` is its count of ones). Cell
    /// `c = band * SECTORS + sector`: band `floor(3 (z + 1))` of the unit
    /// direction `(x, y, z)` from the centre (six bands of equal area, `z`
    /// from -1 up), sector the octant of its longitude `atan2(y, x)` from
    /// 0 deg counter-clockwise. For a display of the coverage.
    pub visited: u64,
    /// Progress towards [`Progress::ready`], `0..=100`: the smaller of the
    /// cell fraction `cells_visited / READY_CELLS` and the sample fraction
    /// `samples / min(READY_SAMPLES, N)`, rounded down. It is 100 exactly
    /// when `ready`.
    pub percent: u8,
    /// Coverage and count are enough to calibrate.
    pub ready: bool,
}

/// The lower median of the values (the smallest value with at least half
/// of them at or below it), by counting ranks: `O(n^2)` comparisons, no
/// sort, no indexing. Zero for no values; meant for a few tens of finite
/// values.
fn lower_median<I: Iterator<Item = f32> + Clone>(values: I) -> f32 {
    let n = values.clone().count();
    let half = n.div_ceil(2);
    let m = values
        .clone()
        .filter(|&v| values.clone().filter(|&w| w <= v).count() >= half)
        .fold(f32::INFINITY, f32::min);
    if m.is_finite() {
        m
    } else {
        0.0
    }
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Unit direction of `y` from `centre`, or `None` when `y` is on the centre
/// (or the distance overflows).
fn direction(y: [f32; 3], centre: [f32; 3]) -> Option<[f32; 3]> {
    let v = sub(y, centre);
    let r = libm::sqrtf(dot(&v, &v));
    if !(r > 0.0) || !r.is_finite() {
        return None;
    }
    let inv = 1.0 / r;
    Some([v[0] * inv, v[1] * inv, v[2] * inv])
}

/// The equal-area cell of the direction of `v` (any length), or `None` when
/// `v` is zero or not finite. Band `floor(3 (z / |v| + 1))`, decided by
/// comparing `9 z^2` with `|v|^2` and `4 |v|^2` (no square root); sector by
/// octant of longitude from signs and `|x|` against `|y|` (no `atan2`).
pub(crate) fn cell(v: [f32; 3]) -> Option<usize> {
    let [x, y, z] = v;
    let r2 = dot(&v, &v);
    if !(r2 > 0.0) || !r2.is_finite() {
        return None;
    }
    let q = 9.0 * z * z;
    // |z| / |v| >= 2/3, >= 1/3, or below.
    let k = if q >= 4.0 * r2 {
        2
    } else if q >= r2 {
        1
    } else {
        0
    };
    let band = if z >= 0.0 { 3 + k } else { 2 - k };
    let (ax, ay) = (x.abs(), y.abs());
    let sector = match (x >= 0.0, y >= 0.0) {
        (true, true) => usize::from(ay >= ax),       // 0..90 deg
        (false, true) => 2 + usize::from(ax >= ay),  // 90..180
        (false, false) => 4 + usize::from(ay >= ax), // 180..270
        (true, false) => 6 + usize::from(ax >= ay),  // 270..360
    };
    Some(band * SECTORS + sector)
}

/// A fixed-capacity sample collector with near-duplicate rejection and
/// coverage tracking (see the [module documentation](self) for the
/// numerics).
///
/// Capacity is the const generic `N`, stored inline: `N * size_of::<S>()`
/// bytes plus about 384 bytes of state on a 32-bit target. With
/// `S = [i16; 3]` a sample takes 6 bytes. Every method is bounded:
/// [`Collector::offer`] is O(1) and [`Collector::progress`] O([`CELLS`]),
/// independent of `N`.
///
/// Wild readings are refused once [`OUTLIER_MIN_SAMPLES`] samples are
/// stored ([`Offer::Outlier`]); one among the first samples makes the
/// collection start over ([`Offer::Restarted`]). A device lying still adds
/// nothing ([`NOISE_SPACING`]).
/// Moderate disturbances are kept: [`crate::calibrate`] judges the stored
/// samples on its own.
///
/// ```
/// use mag_cal_core::collector::{Collector, Offer};
/// use mag_cal_core::{calibrate, Config};
///
/// let mut collector: Collector<[f32; 3], 1000> = Collector::new(4.0);
/// // The device turning in all directions: the field direction follows a
/// // spiral, the raw readings an offset, scaled sphere.
/// let mut k = 0;
/// while !collector.is_ready() && k < 800 {
///     let z = 1.0 - 2.0 * k as f32 / 800.0;
///     let r = (1.0 - z * z).sqrt();
///     let phi = k as f32 * 0.3;
///     let raw = [250.0 + 300.0 * r * phi.cos(), -80.0 + 330.0 * r * phi.sin(), 40.0 + 280.0 * z];
///     let _ = collector.offer(raw);
///     k += 1;
/// }
/// let p = collector.progress();
/// assert!(p.ready && p.percent == 100 && p.cells_visited >= 36);
/// assert_eq!(p.visited.count_ones() as usize, p.cells_visited);
/// let fit = calibrate::<f32, _>(collector.samples(), &Config::default())?;
/// assert!((fit.calibration.hard_iron()[0] - 250.0).abs() < 1.0);
/// # Ok::<(), mag_cal_core::Error>(())
/// ```
#[derive(Clone, Debug)]
pub struct Collector<S: Sample, const N: usize> {
    samples: heapless::Vec<S, N>,
    /// Squared minimum chord between unit directions, `(2 sin(angle/2))^2`.
    min_chord_sq: f32,
    fit: CentreFit,
    /// Centre estimate over the stored samples.
    centre: [f32; 3],
    /// Per cell, the index of the latest sample classified into it (when
    /// stored or re-classified), or [`NO_WITNESS`].
    witness: [usize; CELLS],
    /// Next stored sample to re-classify.
    cursor: usize,
    /// [`Offer::Outlier`] answers since the last sample stored or refused
    /// as too close.
    outliers_in_row: usize,
    /// [`Offer::TooClose`] answers while fewer than
    /// [`OUTLIER_MIN_SAMPLES`] samples are stored, since the last one
    /// stored.
    close_in_row: usize,
    /// The sensor's noise, learnt from the readings offered.
    noise: NoiseGate,
    /// The smoothed position ([`NoiseGate`]) when the last sample was
    /// stored.
    anchor: [f32; 3],
}

/// [`Collector::offer_inner`]'s answer: an [`Offer`], or a reading within
/// the noise of the last sample stored (answered as [`Offer::TooClose`]).
enum Verdict {
    Offer(Offer),
    Still,
}

impl<S: Sample, const N: usize> Default for Collector<S, N> {
    /// A collector with the [`DEFAULT_MIN_ANGLE_DEG`] spacing.
    fn default() -> Self {
        Self::new(DEFAULT_MIN_ANGLE_DEG)
    }
}

impl<S: Sample, const N: usize> Collector<S, N> {
    /// An empty collector keeping samples at least `min_angle_deg` apart in
    /// direction ([`DEFAULT_MIN_ANGLE_DEG`] = 4 deg is a good choice, and
    /// what [`Default`] uses). The angle is clamped to `[0, 180]`; NaN is
    /// taken as the default. Exact repeats are refused even at 0.
    ///
    /// ```
    /// use mag_cal_core::collector::Collector;
    /// let c: Collector<[i16; 3], 500> = Collector::new(5.0);
    /// assert_eq!((c.len(), c.capacity()), (0, 500));
    /// ```
    pub fn new(min_angle_deg: f32) -> Self {
        let deg = if min_angle_deg.is_nan() {
            DEFAULT_MIN_ANGLE_DEG
        } else {
            min_angle_deg.clamp(0.0, 180.0)
        };
        let chord = 2.0 * libm::sinf(deg * (core::f32::consts::PI / 360.0));
        Self {
            samples: heapless::Vec::new(),
            min_chord_sq: chord * chord,
            fit: CentreFit::EMPTY,
            centre: [0.0; 3],
            witness: [NO_WITNESS; CELLS],
            cursor: 0,
            outliers_in_row: 0,
            close_in_row: 0,
            noise: NoiseGate::EMPTY,
            anchor: [0.0; 3],
        }
    }

    /// Offers one sample: stores it and returns [`Offer::Accepted`], or says
    /// why not. The checks, in order: [`Offer::Full`],
    /// [`Offer::NotFinite`], [`Offer::Glitch`], [`Offer::Outlier`],
    /// [`Offer::TooClose`]; then whether the collection is stalled and
    /// starts over, [`Offer::Restarted`] (see "Stalls" in the [module
    /// documentation](self)).
    ///
    /// Constant time: the running sums are updated, the centre re-solved
    /// (3x3), the direction compared with the last stored sample's only,
    /// and [`RESCAN_PER_OFFER`] stored samples re-classified (every call,
    /// whatever the outcome, so offering on after [`Offer::Full`] still
    /// refreshes the coverage). A refused sample is neither stored nor
    /// counted in the centre. Once per collection, when the store reaches
    /// [`OUTLIER_MIN_SAMPLES`] samples, the call also ranks those samples
    /// (about 1 700 comparisons; the same whatever `N`).
    ///
    /// ```
    /// use mag_cal_core::collector::{Collector, Offer, NOISE_READINGS};
    /// let mut c: Collector<[f32; 3], 2> = Collector::default();
    /// assert_eq!(c.offer([f32::NAN, 0.0, 0.0]), Offer::NotFinite);
    /// // A device turning 10 deg a reading: the first reading is stored,
    /// // the next ones once the collector knows the sensor's noise.
    /// let turn = |k: usize| {
    ///     let a = (10 * k) as f32 * core::f32::consts::PI / 180.0;
    ///     [300.0 * a.cos(), 300.0 * a.sin(), 50.0]
    /// };
    /// assert_eq!(c.offer(turn(0)), Offer::Accepted);
    /// for k in 1..NOISE_READINGS - 1 {
    ///     assert_eq!(c.offer(turn(k)), Offer::TooClose);
    /// }
    /// assert_eq!(c.offer(turn(NOISE_READINGS - 1)), Offer::Accepted);
    /// assert_eq!(c.offer(turn(NOISE_READINGS)), Offer::Full);
    /// ```
    pub fn offer(&mut self, sample: S) -> Offer {
        let (mut outcome, still) = match self.offer_inner(sample) {
            Verdict::Offer(o) => (o, false),
            Verdict::Still => (Offer::TooClose, true),
        };
        let len = self.samples.len();
        let stalled = match outcome {
            Offer::Accepted => {
                self.outliers_in_row = 0;
                self.close_in_row = 0;
                len == OUTLIER_MIN_SAMPLES && self.first_samples_are_wild()
            }
            Offer::TooClose => {
                self.outliers_in_row = 0;
                // A device lying still is no stall: only readings that
                // moved but point the same way from the centre count.
                if len < OUTLIER_MIN_SAMPLES && !still {
                    self.close_in_row = self.close_in_row.saturating_add(1);
                }
                self.close_in_row >= STALL_OFFERS
            }
            Offer::Outlier => {
                self.outliers_in_row = self.outliers_in_row.saturating_add(1);
                self.outliers_in_row >= len.max(STALL_OFFERS)
            }
            _ => false,
        };
        if stalled {
            self.clear();
            outcome = Offer::Restarted;
        }
        self.rescan();
        outcome
    }

    /// Whether a stored sample is farther than [`WILD_SPREAD`] times the
    /// median distance of the stored samples from their per-axis median (or
    /// that median distance is zero). Called once, when the store reaches
    /// [`OUTLIER_MIN_SAMPLES`] samples: medians by rank counting, no sort,
    /// `O(OUTLIER_MIN_SAMPLES^2)`.
    fn first_samples_are_wild(&self) -> bool {
        // One array per axis (no indexing by a variable axis: panic-free).
        let mut axes = [[0.0f32; OUTLIER_MIN_SAMPLES]; 3];
        let [xs, ys, zs] = &mut axes;
        let slots = xs.iter_mut().zip(ys.iter_mut()).zip(zs.iter_mut());
        for (((x, y), z), s) in slots.zip(&self.samples) {
            [*x, *y, *z] = s.xyz::<f32>();
        }
        let median = axes.map(|a| lower_median(a.iter().copied()));
        let [xs, ys, zs] = &axes;
        let mut dist_sq = [0.0f32; OUTLIER_MIN_SAMPLES];
        for (d, ((&x, &y), &z)) in dist_sq.iter_mut().zip(xs.iter().zip(ys).zip(zs)) {
            let v = sub([x, y, z], median);
            *d = dot(&v, &v);
        }
        let typical = lower_median(dist_sq.iter().copied());
        let farthest = dist_sq.iter().fold(0.0f32, |m, &d| m.max(d));
        // Squared distances: compare with the square of the factor.
        !(typical > 0.0) || !(farthest <= WILD_SPREAD * WILD_SPREAD * typical)
    }

    /// [`Collector::offer`] without the re-classification step.
    fn offer_inner(&mut self, sample: S) -> Verdict {
        if self.samples.is_full() {
            return Verdict::Offer(Offer::Full);
        }
        let y = sample.xyz::<f32>();
        if !y.iter().all(|v| v.is_finite()) {
            return Verdict::Offer(Offer::NotFinite);
        }
        if sample.is_zero() || sample.on_rails() {
            return Verdict::Offer(Offer::Glitch);
        }
        if self.samples.len() >= OUTLIER_MIN_SAMPLES {
            let d = sub(y, self.centre);
            let r_sq = self.fit.radius_sq(self.centre);
            if dot(&d, &d) > OUTLIER_RADII * OUTLIER_RADII * r_sq {
                return Verdict::Offer(Offer::Outlier);
            }
        }
        let Some(fit) = self.fit.with(y) else {
            return Verdict::Offer(Offer::NotFinite);
        };
        let spacing = self.noise.take(y);
        if !self.samples.is_empty() {
            let moved = sub(self.noise.position, self.anchor);
            let far = spacing.is_some_and(|d| dot(&moved, &moved) >= d * d);
            if !far {
                return Verdict::Still;
            }
        }
        let centre = fit.centre();
        let new_dir = direction(y, centre);
        let last_dir = self
            .samples
            .last()
            .and_then(|s| direction(s.xyz::<f32>(), centre));
        let accept = match (new_dir, last_dir) {
            (None, _) => false,
            (Some(_), None) => true,
            (Some(u), Some(v)) => {
                let d = sub(u, v);
                let chord_sq = dot(&d, &d);
                chord_sq > 0.0 && chord_sq >= self.min_chord_sq
            }
        };
        if !accept && !self.samples.is_empty() {
            return Verdict::Offer(Offer::TooClose);
        }
        let index = self.samples.len();
        if self.samples.push(sample).is_err() {
            return Verdict::Offer(Offer::Full);
        }
        self.fit = fit;
        self.centre = centre;
        self.anchor = self.noise.position;
        if let Some(w) = cell(sub(y, centre)).and_then(|c| self.witness.get_mut(c)) {
            *w = index;
        }
        Verdict::Offer(Offer::Accepted)
    }

    /// Re-classifies the next [`RESCAN_PER_OFFER`] stored samples (round
    /// robin) against the current centre and makes each the witness of its
    /// cell.
    fn rescan(&mut self) {
        let len = self.samples.len();
        for _ in 0..RESCAN_PER_OFFER {
            if self.cursor >= len {
                self.cursor = 0;
            }
            let Some(s) = self.samples.get(self.cursor) else {
                return;
            };
            let v = sub(s.xyz::<f32>(), self.centre);
            if let Some(w) = cell(v).and_then(|c| self.witness.get_mut(c)) {
                *w = self.cursor;
            }
            self.cursor += 1;
        }
    }

    /// Samples, cells visited, percent and readiness.
    ///
    /// Re-classifies the at most [`CELLS`] cell witnesses against the
    /// current centre: bounded work, independent of `N`.
    ///
    /// ```
    /// use mag_cal_core::collector::{Collector, CELLS};
    /// let c: Collector<[i16; 3], 300> = Collector::default();
    /// let p = c.progress();
    /// assert_eq!((p.samples, p.cells_visited, p.cells), (0, 0, CELLS));
    /// assert_eq!((p.percent, p.ready, p.visited), (0, false, 0));
    /// ```
    pub fn progress(&self) -> Progress {
        let mut visited = [false; CELLS];
        // Samples within the noise of the centre have no direction.
        let near_sq = self.noise.spacing_mean * self.noise.spacing_mean;
        for &i in &self.witness {
            let Some(s) = self.samples.get(i) else {
                continue;
            };
            let v = sub(s.xyz::<f32>(), self.centre);
            if dot(&v, &v) <= near_sq {
                continue;
            }
            if let Some(seen) = cell(v).and_then(|c| visited.get_mut(c)) {
                *seen = true;
            }
        }
        let cells_visited = visited.iter().filter(|&&v| v).count();
        let mask = visited
            .iter()
            .enumerate()
            .fold(0u64, |m, (c, &v)| m | (u64::from(v) << (c % 64)));
        let samples = self.samples.len();
        let required = READY_SAMPLES.min(N);
        // A capacity of zero never gets a sample, and never gets ready
        // either (no cell is visited).
        let sample_percent = (samples.min(required) * 100)
            .checked_div(required)
            .unwrap_or(100);
        let cell_percent = cells_visited.min(READY_CELLS) * 100 / READY_CELLS;
        let percent = u8::try_from(sample_percent.min(cell_percent)).unwrap_or(100);
        Progress {
            samples,
            cells_visited,
            cells: CELLS,
            visited: mask,
            percent,
            ready: samples >= required && cells_visited >= READY_CELLS,
        }
    }

    /// Whether coverage and count are enough to calibrate
    /// (`self.progress().ready`).
    pub fn is_ready(&self) -> bool {
        self.progress().ready
    }

    /// The stored samples, oldest first: what [`crate::calibrate`] takes.
    pub fn samples(&self) -> &[S] {
        &self.samples
    }

    /// The running centre estimate (a rough hard iron, sensor units), or
    /// `None` before the first sample.
    pub fn centre(&self) -> Option<[f32; 3]> {
        (!self.samples.is_empty()).then_some(self.centre)
    }

    /// Removes every sample and forgets the centre and the coverage; the
    /// minimum angle is kept.
    pub fn clear(&mut self) {
        self.samples.clear();
        self.fit = CentreFit::EMPTY;
        self.centre = [0.0; 3];
        self.witness = [NO_WITNESS; CELLS];
        self.cursor = 0;
        self.outliers_in_row = 0;
        self.close_in_row = 0;
        self.noise = NoiseGate::EMPTY;
        self.anchor = [0.0; 3];
    }

    /// Number of stored samples.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether no sample is stored.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// The capacity `N`.
    pub const fn capacity(&self) -> usize {
        N
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_are_the_octants_and_bands() {
        let d = core::f32::consts::FRAC_1_SQRT_2;
        let mut seen = [false; CELLS];
        for band in 0..BANDS {
            let z = -1.0 + (band as f32 + 0.5) / 3.0;
            let r = libm::sqrtf(1.0 - z * z);
            for sector in 0..SECTORS {
                let phi = (sector as f32 + 0.5) * core::f32::consts::FRAC_PI_4;
                let u = [r * libm::cosf(phi), r * libm::sinf(phi), z];
                let c = cell(u).unwrap();
                assert_eq!(c, band * SECTORS + sector, "{band} {sector}");
                assert_eq!(cell(u.map(|v| v * 1e3)), Some(c));
                seen[c] = true;
            }
        }
        assert!(seen.iter().all(|&s| s));
        assert_eq!(cell([0.0, 0.0, 1.0]).unwrap() / SECTORS, BANDS - 1);
        assert_eq!(cell([0.0, 0.0, -1.0]).unwrap() / SECTORS, 0);
        assert_eq!(cell([f32::NAN; 3]), None);
        assert_eq!(cell([0.0; 3]), None);
        assert_eq!(cell([f32::MAX; 3]), None);
        assert_eq!(cell([d, -d, 0.0]).unwrap() % SECTORS, 7);
    }
}
