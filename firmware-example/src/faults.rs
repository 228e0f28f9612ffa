//! Sensor faults: detection, exclusion, and the log of what was seen and
//! handled.
//!
//! Four classes, each counted in episodes (`seen`: detected; `handled`: the
//! firmware came out of it with every affected sample kept out of the
//! calibration and the headings):
//!
//! | class | detected by | handled when |
//! |---|---|---|
//! | `nack` | an I2C transfer fails with a NACK | the operation succeeds on a retry ([`Retry`], at most [`I2C_ATTEMPTS`] attempts) |
//! | `stuck` | [`STUCK_REPEATS`] exact repeats of the raw triple in a row | a fresh triple arrives (every repeat excluded) |
//! | `saturated` | an axis at the rail, +-[`RAIL`] | readings are off the rails for [`GUARD`] readings |
//! | `disturbance` | the field's norm off its reference by more than [`RAW_THRESHOLD`] or [`CAL_THRESHOLD`] | the norm is back for [`GUARD`] readings |
//!
//! Besides, isolated *wild* readings (a bus glitch: one triple thousands of
//! counts off, inside the range) are dropped one by one, without an
//! episode or a guard (counted in [`Excluded::wild`]): on its way out of the
//! quarantine, a reading farther than [`WILD_DISTANCE`] both from the
//! median of the readings held after it and from the last reading released
//! before it is not used. That test needs no reference, so it also works
//! at the start of a collection, before the disturbance test arms (it arms
//! once the collector holds [`ARM_SAMPLES`] samples, its reference being
//! the collector's running centre and their mean distance from it).
//!
//! What none of this can tell from a clean reading, e.g. a reading
//! displaced by a fraction of the field (the fault run's displaced
//! glitches: 0.3 of the field, below the 0.5 of [`RAW_THRESHOLD`] on top
//! of the soft iron's spread), reaches the collector; the core's outlier
//! handling leaves it out of the fit (and the firmware's [`GlitchLog`]
//! counts, on the simulator, what became of each).
//!
//! # Exclusion: the quarantine
//!
//! A magnet does not appear at full strength: its field rises and falls,
//! and the first and last readings of a passage are disturbed by less than
//! any threshold can tell from a distorted sensor's normal spread. So a
//! clean reading is not used at once: [`Monitor::push`] holds it back for
//! [`GUARD`] readings and releases it only if no saturation or disturbance
//! was detected in that time; a detection drops everything held (the
//! readings just before it) and the [`GUARD`] readings after the episode.
//! The readings that reach the collector (or the heading smoother) have
//! thus been clean themselves and had clean neighbours `GUARD` readings on
//! either side. Exact repeats are dropped without a guard: they are stale
//! copies of a reading already seen, and carry no new information (the
//! collector would refuse them as too close anyway).
//!
//! # Thresholds
//!
//! - [`STUCK_REPEATS`] = 4: a still sensor repeats its previous triple
//!   exactly with probability `p^3`, `p ~ 1 / (2 sqrt(pi) sigma)` per axis
//!   (the difference of two independent roundings of a noise `sigma` counts
//!   hitting 0): 0.11 per axis at the simulator's 2.5 counts (1.4e-3 per
//!   triple), 0.28 at 1 count (0.022 per triple; the LSM303AGR's datasheet
//!   noise is 1-2 counts). Four repeats in a row then happen at most once
//!   in `1 / 0.022^4 = 4e6` readings (55 h at 20 Hz, on a sensor lying
//!   still; a moving one practically never), while a frozen output shows
//!   them within 0.2 s. A false alarm costs nothing but a log line:
//!   repeats are excluded anyway.
//! - [`RAIL`] = 32767: the LSM303AGR's output is a 16-bit two's complement
//!   count clipped at its range (+-49.152 G); a reading at the rail is a
//!   lower bound, not a measurement. The Earth's field is 150-450 counts,
//!   so no hard iron short of a magnet stuck to the sensor gets near it.
//! - [`RAW_THRESHOLD`] = 0.5, during collection (no calibration yet): the
//!   statistic is `| |y - c| / r - 1 |` with `c` the collector's running
//!   centre and `r` the mean of `|y - c|` over the samples collected. On a
//!   clean sensor it is bounded by the soft iron's spread of radii: the
//!   simulator's `T` has singular values 0.8..1.25, and the largest value
//!   over 200 simulated collections (600 readings each, armed from
//!   [`ARM_SAMPLES`] = 30 samples on) is 0.30; noise adds 2.5 / 320 =
//!   0.008. 0.5 is 0.2 above that worst case (64 counts, 25 noise
//!   standard deviations) and flags a magnet adding half the Earth's field
//!   (24 uT) along the field; a small magnet (0.1 A m^2) does so within
//!   about 8 cm.
//! - [`CAL_THRESHOLD`] = 0.15, with a calibration: the statistic is
//!   `| |W (y - b)| - 1 |`, whose clean spread is the noise alone (RMS
//!   0.008 in the simulator; the worst over 200 simulated runs, each a
//!   collection of 600 readings and three swings, is 0.040; real sensors
//!   fit with radial RMS 0.003-0.027). 0.15 (48 counts, 7 uT) is almost 4
//!   times the simulator's worst and 5 RMS of the noisiest real sensor,
//!   while
//!   a disturbance of that size would already turn a level heading by up
//!   to 0.15 / cos(dip) rad, 17 deg at 60 deg dip.
//! - [`GUARD`] = 10 readings (0.5 s at 20 Hz): a dipole's field grows as
//!   `1 / d^3`, so from 5 % of the Earth's field to the 50 % of
//!   [`RAW_THRESHOLD`] the distance shrinks by `10^(1/3)` = 2.15 times, from
//!   10.8 to 5 cm for the magnet above: 0.3 s at a hand's 0.2 m/s. The
//!   guard covers that rise, and the fall, for anything moving faster than
//!   about 0.12 m/s. The simulated passage (`sin^2`, peak 1500 counts) is
//!   flagged for its middle 26 of 40 readings in a collection (raw
//!   threshold) and 25 of 30 in a compass swing (calibrated threshold);
//!   the guard covers the rest, and the fault run checks that no reading of
//!   the passage is used.
//! - [`LONG_DISTURBANCE`] = 200 readings (10 s): a "disturbance" that does
//!   not end is a changed environment (or a reference taken from disturbed
//!   samples): the collection restarts from scratch.
//! - [`WILD_DISTANCE`] = 1800 counts, twice [`crate::storage::RHO_MAX`]
//!   (900 counts, the largest field strength the firmware takes as
//!   plausible; the Earth's field is 150-450 counts): no two clean readings
//!   of a sensor are farther apart than the diameter of its sphere, so a
//!   reading that far from its neighbours on both sides cannot be a
//!   measurement. A lasting jump of that size (a magnet stuck on) is no
//!   isolated reading: the readings after it agree with each other, and
//!   the disturbance test is the one to judge it. Why such readings must
//!   not reach the collector at all: its running centre is Kasa's
//!   algebraic sphere fit over every sample it holds, and three readings
//!   2000-3000 counts off among its first 20 samples put that centre
//!   thousands of counts off. The collector then takes every clean reading
//!   for one direction and refuses it as too close, so the collection
//!   stalls, the disturbance test (which arms on the collector's count)
//!   stays unarmed while a magnet passes, and once it arms its reference
//!   is off and flags clean readings. Measured on the fault run without
//!   this test: 1780 readings to fill the collector instead of 616, never
//!   ready (26/48 cells), 45 disturbances seen for 5 injected, 8 samples
//!   of the magnet in the calibration; on the host (collector and core
//!   only, 200 seeds) ready after 1007 readings instead of 413. The
//!   core's screening then left all of them out of the fit, but the
//!   collection was ruined before. (Those figures predate the collector's
//!   own recovery: it now starts over when its first 20 samples hold such
//!   a reading, [`mag_cal_core::collector::Offer::Restarted`], so it no
//!   longer stalls, but it discards those samples and the test here still
//!   saves that.)

use core::fmt::Debug;

use defmt::{error, info, warn};
use embedded_hal::delay::DelayNs;
use embedded_hal::i2c::{self, ErrorKind};
use heapless::Deque;
use mag_cal_core::Calibration;

/// Attempts of one I2C operation before it is given up: the first and 7
/// retries, 1 ms apart. The simulated bursts NACK 1-4 transfers; a bus
/// that stays silent for 8 ms is not glitching, it is gone.
pub const I2C_ATTEMPTS: u32 = 8;

/// Exact repeats of the raw triple in a row that make a stuck output (see
/// the module documentation).
pub const STUCK_REPEATS: u32 = 4;

/// The output rail, counts: a reading with an axis at `+-RAIL` (or at
/// `i16::MIN`) is saturated.
pub const RAIL: i16 = i16::MAX;

/// Readings dropped on either side of a saturation or a disturbance (and
/// the delay of the quarantine).
pub const GUARD: u32 = 10;

/// Disturbance threshold on `| |y - c| / r - 1 |` while collecting.
pub const RAW_THRESHOLD: f32 = 0.5;

/// Disturbance threshold on `| |W (y - b)| - 1 |` with a calibration.
pub const CAL_THRESHOLD: f32 = 0.15;

/// Samples in the collector before its centre is trusted as a reference.
pub const ARM_SAMPLES: usize = 30;

/// Readings after which an unending disturbance restarts the collection.
pub const LONG_DISTURBANCE: u32 = 200;

/// A reading farther than this (counts) from the per-axis median of the
/// readings held after it is an isolated wild reading: twice
/// [`crate::storage::RHO_MAX`], the largest field strength the firmware
/// takes as plausible (see the module documentation).
pub const WILD_DISTANCE: f32 = 2.0 * crate::storage::RHO_MAX;

/// Readings held after a reading that the wild test needs (fewer, e.g.
/// after a stretch of repeats: no test).
pub const WILD_NEIGHBOURS: usize = 3;

/// Readings held back in the quarantine (at most `GUARD`, plus room).
const HELD: usize = 16;
const _: () = assert!(GUARD as usize <= HELD);

/// Episodes of one fault class.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, defmt::Format)]
pub struct Count {
    /// Detected.
    pub seen: u32,
    /// Came out of with every affected sample excluded.
    pub handled: u32,
}

/// Readings kept out of the calibration and the headings, by reason.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, defmt::Format)]
pub struct Excluded {
    /// Exact repeats of the previous triple.
    pub repeats: u32,
    /// Saturated.
    pub saturated: u32,
    /// Disturbed.
    pub disturbed: u32,
    /// Clean, but within [`GUARD`] readings of a saturation or disturbance.
    pub guard: u32,
    /// Isolated wild readings, dropped on their way out of the quarantine
    /// ([`WILD_DISTANCE`]).
    pub wild: u32,
}

/// Everything seen and done about faults in a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FaultLog {
    /// I2C NACK bursts.
    pub nack: Count,
    /// Stuck output.
    pub stuck: Count,
    /// Saturated output.
    pub saturated: Count,
    /// Field disturbances.
    pub disturbance: Count,
    /// NACKed transfers (each one retried, or the last of a burst given up).
    pub nacked_transfers: u32,
    /// Episodes of I2C errors other than NACKs (retried the same way).
    pub bus_errors: Count,
    /// Readings excluded.
    pub excluded: Excluded,
    /// Collections restarted because a disturbance did not end, or
    /// because the collector started over ([`mag_cal_core::collector::Offer::Restarted`]).
    pub restarts: u32,
    /// Samples the simulator had marked faulty that were nevertheless
    /// offered to the collector or to the heading smoother (the simulator's
    /// truth; always 0 on the board, where nobody knows).
    pub leaked: u32,
    /// What became of the glitches the simulator injected (its truth;
    /// always 0 on the board).
    pub glitches: GlitchLog,
}

/// The glitches of the simulator's fault run (isolated readings its
/// schedule adds for the core's outlier handling, `sim::Glitches`), per
/// kind `[wild, displaced]`: what the monitor made of them, how many the
/// collector accepted, and what the fits did with those. The simulator's
/// truth; all 0 on the board.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GlitchLog {
    /// Dropped by the monitor's wild test ([`WILD_DISTANCE`]).
    pub wild_dropped: [u32; 2],
    /// Readings without a glitch that the wild test dropped (must be 0).
    pub wild_false: u32,
    /// Disturbance episodes a glitch opened (its statistic beyond the
    /// threshold: counted apart from the injected disturbances).
    pub disturbances: [u32; 2],
    /// Accepted by the collector, in collections that were calibrated.
    pub collected: [u32; 2],
    /// Used by the fit.
    pub used: [u32; 2],
    /// Rejected by their residual.
    pub rejected: [u32; 2],
    /// Screened out (too far from the others).
    pub screened: [u32; 2],
    /// Dropped by a drop rule of the core.
    pub dropped: [u32; 2],
    /// Set aside as a still period's (the core's still rule).
    pub dwell: [u32; 2],
    /// In collections whose calibration the core refused.
    pub refused: [u32; 2],
}

impl GlitchLog {
    /// Logs the one-line summary: `glitches: injected W wild + D
    /// displaced, dropped as wild .. + .., seen as disturbances .. + ..,
    /// collected w + d, used by the fit uw/w wild + ud/d displaced (...)`.
    pub fn log_summary(&self, injected: [u32; 2]) {
        let (c, u) = (self.collected, self.used);
        info!(
            "glitches: injected {=u32} wild + {=u32} displaced, dropped as wild {=u32} + {=u32}, seen as disturbances {=u32} + {=u32}, collected {=u32} + {=u32}, used by the fit {=u32}/{=u32} wild + {=u32}/{=u32} displaced (rejected {=u32} + {=u32}, screened {=u32} + {=u32}, dropped {=u32} + {=u32}, still {=u32} + {=u32}, in refused fits {=u32} + {=u32})",
            injected[0],
            injected[1],
            self.wild_dropped[0],
            self.wild_dropped[1],
            self.disturbances[0],
            self.disturbances[1],
            c[0],
            c[1],
            u[0],
            c[0],
            u[1],
            c[1],
            self.rejected[0],
            self.rejected[1],
            self.screened[0],
            self.screened[1],
            self.dropped[0],
            self.dropped[1],
            self.dwell[0],
            self.dwell[1],
            self.refused[0],
            self.refused[1]
        );
    }
}

impl FaultLog {
    /// Whether any fault was seen.
    pub fn any_seen(&self) -> bool {
        [
            self.nack,
            self.stuck,
            self.saturated,
            self.disturbance,
            self.bus_errors,
        ]
        .iter()
        .any(|c| c.seen > 0)
            || self.excluded.wild > 0
    }

    /// Logs the one-line summary:
    /// `faults: nack=<seen>/<handled> stuck=.. saturated=.. disturbance=..`.
    pub fn log_summary(&self) {
        info!(
            "faults: nack={=u32}/{=u32} stuck={=u32}/{=u32} saturated={=u32}/{=u32} disturbance={=u32}/{=u32}",
            self.nack.seen,
            self.nack.handled,
            self.stuck.seen,
            self.stuck.handled,
            self.saturated.seen,
            self.saturated.handled,
            self.disturbance.seen,
            self.disturbance.handled
        );
    }

    /// Logs the details behind the summary.
    pub fn log_details(&self) {
        let x = &self.excluded;
        info!(
            "fault details: {=u32} NACKed transfers, {=u32} other I2C error episodes ({=u32} recovered); readings excluded: {=u32} repeats, {=u32} saturated, {=u32} disturbed, {=u32} guard, {=u32} wild; {=u32} collections restarted",
            self.nacked_transfers,
            self.bus_errors.seen,
            self.bus_errors.handled,
            x.repeats,
            x.saturated,
            x.disturbed,
            x.guard,
            x.wild,
            self.restarts
        );
    }
}

/// Whether a driver error is an I2C NACK (address or data).
fn is_nack<E: i2c::Error>(e: &lsm303agr::Error<E>) -> bool {
    matches!(e, lsm303agr::Error::Comm(c) if matches!(c.kind(), ErrorKind::NoAcknowledge(_)))
}

/// The bookkeeping of one I2C operation tried up to [`I2C_ATTEMPTS`] times.
pub struct Retry<'a> {
    log: &'a mut FaultLog,
    what: &'static str,
    failures: u32,
    nack: bool,
    other: bool,
}

impl<'a> Retry<'a> {
    /// A new operation, described by `what` for the log.
    pub fn new(log: &'a mut FaultLog, what: &'static str) -> Self {
        Self {
            log,
            what,
            failures: 0,
            nack: false,
            other: false,
        }
    }

    /// Records a failed attempt; `true` when it may be tried again.
    pub fn failed<E: i2c::Error + Debug>(&mut self, e: &lsm303agr::Error<E>) -> bool {
        self.failures += 1;
        if is_nack(e) {
            self.log.nacked_transfers += 1;
            if !self.nack {
                self.nack = true;
                self.log.nack.seen += 1;
                warn!("fault: I2C NACK while {=str}; retrying", self.what);
            }
        } else if !self.other {
            self.other = true;
            self.log.bus_errors.seen += 1;
            warn!(
                "fault: I2C error while {=str}: {}; retrying",
                self.what,
                defmt::Debug2Format(e)
            );
        }
        if self.failures < I2C_ATTEMPTS {
            true
        } else {
            error!(
                "I2C: {=str} still failing after {=u32} attempts; giving up on it",
                self.what, self.failures
            );
            false
        }
    }

    /// Records the success that ends the operation.
    pub fn succeeded(self) {
        if self.failures == 0 {
            return;
        }
        if self.nack {
            self.log.nack.handled += 1;
        }
        if self.other {
            self.log.bus_errors.handled += 1;
        }
        info!(
            "I2C: {=str} succeeded after {=u32} failed attempts",
            self.what, self.failures
        );
    }
}

/// Runs `op` (a driver call, given the delay) until it succeeds or
/// [`I2C_ATTEMPTS`] attempts failed, 1 ms apart.
pub fn retry<T, E, D>(
    log: &mut FaultLog,
    delay: &mut D,
    what: &'static str,
    mut op: impl FnMut(&mut D) -> Result<T, lsm303agr::Error<E>>,
) -> Result<T, lsm303agr::Error<E>>
where
    E: i2c::Error + Debug,
    D: DelayNs,
{
    let mut attempt = Retry::new(log, what);
    loop {
        match op(delay) {
            Ok(v) => {
                attempt.succeeded();
                return Ok(v);
            }
            Err(e) => {
                if !attempt.failed(&e) {
                    return Err(e);
                }
                delay.delay_ms(1);
            }
        }
    }
}

/// What a disturbance is judged against.
#[derive(Clone, Copy, Debug)]
pub enum Reference<'a> {
    /// Nothing yet (too few samples collected): no disturbance detection.
    Unarmed,
    /// While collecting: the running centre `c` and the mean radius `r`,
    /// counts; statistic `| |y - c| / r - 1 |` against [`RAW_THRESHOLD`].
    Raw {
        /// Centre, counts.
        centre: [f32; 3],
        /// Mean radius, counts.
        radius: f32,
    },
    /// With a calibration: statistic `| |W (y - b)| - 1 |` against
    /// [`CAL_THRESHOLD`].
    Calibrated(&'a Calibration<f32>),
}

impl Reference<'_> {
    /// The statistic of `raw` and its threshold, or `None` when unarmed.
    pub fn statistic(&self, raw: [i16; 3]) -> Option<(f32, f32)> {
        let y = raw.map(f32::from);
        match self {
            Reference::Unarmed => None,
            Reference::Raw { centre, radius } => {
                let d = [y[0] - centre[0], y[1] - centre[1], y[2] - centre[2]];
                let r = libm::sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                Some((libm::fabsf(r / radius - 1.0), RAW_THRESHOLD))
            }
            Reference::Calibrated(cal) => {
                Some((libm::fabsf(crate::norm(cal.apply(y)) - 1.0), CAL_THRESHOLD))
            }
        }
    }
}

/// The reference of a collection: the collector's centre and the mean
/// distance of its samples from it, once it holds [`ARM_SAMPLES`].
pub fn raw_reference(samples: &[[i16; 3]], centre: Option<[f32; 3]>) -> Reference<'static> {
    let Some(c) = centre.filter(|_| samples.len() >= ARM_SAMPLES) else {
        return Reference::Unarmed;
    };
    let mut sum = 0.0f32;
    for s in samples {
        let d = [
            f32::from(s[0]) - c[0],
            f32::from(s[1]) - c[1],
            f32::from(s[2]) - c[2],
        ];
        sum += libm::sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    }
    let radius = sum / samples.len() as f32;
    if radius > 0.0 && radius.is_finite() {
        Reference::Raw { centre: c, radius }
    } else {
        Reference::Unarmed
    }
}

/// What [`Monitor::push`] made of a reading.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum Verdict {
    /// Clean (held back in the quarantine, or dropped as guard).
    Clean,
    /// An exact repeat of the previous triple: excluded.
    Repeat,
    /// An axis at the rail: excluded.
    Saturated,
    /// The norm is off its reference: excluded.
    Disturbed,
}

/// A reading that comes out of the quarantine ([`Monitor::push`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Release<T> {
    /// Clean, with clean neighbours: use it.
    Clean([i16; 3], T),
    /// An isolated wild reading ([`WILD_DISTANCE`] off the readings after
    /// it): excluded.
    Wild([i16; 3], T),
}

impl<T> Release<T> {
    /// The reading, if it is clean.
    pub fn clean(self) -> Option<([i16; 3], T)> {
        match self {
            Release::Clean(raw, meta) => Some((raw, meta)),
            Release::Wild(..) => None,
        }
    }
}

/// A clean reading held back.
#[derive(Clone, Copy, Debug)]
struct Held<T> {
    index: u32,
    raw: [i16; 3],
    meta: T,
}

/// Classifies readings, tracks fault episodes, and holds clean readings
/// back in the quarantine (module documentation). `T` is whatever travels
/// with a reading (the simulator's truth, for the self-check).
pub struct Monitor<T> {
    /// Index of the next reading.
    now: u32,
    prev: Option<[i16; 3]>,
    repeats: u32,
    stuck_open: bool,
    /// Index of the last saturated reading while the episode is open.
    saturated: Option<u32>,
    /// Index of the last disturbed reading, and of the first, while the
    /// episode is open.
    disturbed: Option<(u32, u32)>,
    /// The current disturbance was reported as long.
    long_reported: bool,
    held: Deque<Held<T>, HELD>,
    /// The last reading released clean in this phase (the wild test's
    /// neighbour before).
    last_out: Option<[i16; 3]>,
}

impl<T: Copy> Default for Monitor<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Copy> Monitor<T> {
    /// No reading yet.
    pub const fn new() -> Self {
        Self {
            now: 0,
            prev: None,
            repeats: 0,
            stuck_open: false,
            saturated: None,
            disturbed: None,
            long_reported: false,
            held: Deque::new(),
            last_out: None,
        }
    }

    /// Takes one reading: classifies it against `reference`, updates the
    /// episodes in `log`, and returns the verdict and the reading that
    /// leaves the quarantine, if any ([`GUARD`] readings old: clean, or
    /// wild against the readings held after it).
    pub fn push(
        &mut self,
        raw: [i16; 3],
        meta: T,
        reference: &Reference<'_>,
        log: &mut FaultLog,
    ) -> (Verdict, Option<Release<T>>) {
        let index = self.now;
        self.now = self.now.wrapping_add(1);
        self.close_episodes(index, log);

        let verdict = self.classify(raw, reference, log);
        match verdict {
            Verdict::Repeat => log.excluded.repeats += 1,
            Verdict::Saturated | Verdict::Disturbed => {
                if verdict == Verdict::Saturated {
                    log.excluded.saturated += 1;
                } else {
                    log.excluded.disturbed += 1;
                }
                log.excluded.guard += self.held.len() as u32;
                self.held.clear();
            }
            Verdict::Clean => {
                if self.saturated.is_some() || self.disturbed.is_some() {
                    log.excluded.guard += 1;
                } else if let Err(h) = self.held.push_back(Held { index, raw, meta }) {
                    // Cannot happen (at most GUARD + 1 are held): release
                    // the oldest rather than lose the newest.
                    let old = self.held.pop_front();
                    let _ = self.held.push_back(h);
                    return (verdict, old.map(|o| self.release(o, log)));
                }
            }
        }
        let due = self
            .held
            .front()
            .is_some_and(|h| index.wrapping_sub(h.index) >= GUARD);
        let released = if due { self.held.pop_front() } else { None };
        (verdict, released.map(|h| self.release(h, log)))
    }

    /// A reading leaving the quarantine: wild when it lies more than
    /// [`WILD_DISTANCE`] from the per-axis median of the readings held
    /// after it (at least [`WILD_NEIGHBOURS`] of them) and from the last
    /// reading released before it (if any), else clean.
    fn release(&mut self, h: Held<T>, log: &mut FaultLog) -> Release<T> {
        let distance = |a: [i16; 3], b: [f32; 3]| {
            let d = [0, 1, 2].map(|i| f32::from(a[i]) - b[i]);
            libm::sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        };
        let n = self.held.len();
        let mut after = f32::NAN;
        if n >= WILD_NEIGHBOURS {
            let mut median = [0.0f32; 3];
            for (axis, m) in median.iter_mut().enumerate() {
                let mut v = [0i16; HELD];
                for (x, held) in v.iter_mut().zip(self.held.iter()) {
                    *x = held.raw[axis];
                }
                let v = &mut v[..n];
                v.sort_unstable();
                // The mean of the middle two for an even count.
                *m = (f32::from(v[(n - 1) / 2]) + f32::from(v[n / 2])) * 0.5;
            }
            after = distance(h.raw, median);
        }
        let before = self
            .last_out
            .map_or(f32::INFINITY, |p| distance(h.raw, p.map(f32::from)));
        // NaN (too few readings after it) is no evidence: clean.
        if after > WILD_DISTANCE && before > WILD_DISTANCE {
            log.excluded.wild += 1;
            warn!(
                "fault: isolated wild reading {}, {=f32} counts off the {=usize} readings after it (limit {=f32}); excluding it",
                h.raw, after, n, WILD_DISTANCE
            );
            Release::Wild(h.raw, h.meta)
        } else {
            self.last_out = Some(h.raw);
            Release::Clean(h.raw, h.meta)
        }
    }

    /// Drops the readings held back (end of a phase: they are not used).
    pub fn end_phase(&mut self) {
        self.held.clear();
        self.last_out = None;
    }

    /// Whether the open disturbance has lasted more than `readings`
    /// readings: `true` once per episode.
    pub fn long_disturbance(&mut self, readings: u32) -> bool {
        let long = self
            .disturbed
            .is_some_and(|(_, first)| self.now.wrapping_sub(first) > readings);
        let report = long && !self.long_reported;
        self.long_reported |= long;
        report
    }

    /// Whether a saturation or disturbance episode is open.
    pub fn in_episode(&self) -> bool {
        self.saturated.is_some() || self.disturbed.is_some()
    }

    /// Closes the saturation and disturbance episodes whose last bad
    /// reading is more than [`GUARD`] readings before `index`.
    fn close_episodes(&mut self, index: u32, log: &mut FaultLog) {
        if let Some(last) = self.saturated {
            if index.wrapping_sub(last) > GUARD {
                self.saturated = None;
                log.saturated.handled += 1;
                info!(
                    "saturation over; {=u32} guard readings after it dropped",
                    GUARD
                );
            }
        }
        if let Some((last, first)) = self.disturbed {
            if index.wrapping_sub(last) > GUARD {
                self.disturbed = None;
                log.disturbance.handled += 1;
                info!(
                    "disturbance over after {=u32} readings; {=u32} guard readings after it dropped",
                    last.wrapping_sub(first) + 1,
                    GUARD
                );
            }
        }
    }

    fn classify(
        &mut self,
        raw: [i16; 3],
        reference: &Reference<'_>,
        log: &mut FaultLog,
    ) -> Verdict {
        let index = self.now.wrapping_sub(1);
        // Stuck output: the same triple again.
        if self.prev == Some(raw) {
            self.repeats += 1;
            if self.repeats == STUCK_REPEATS {
                self.stuck_open = true;
                log.stuck.seen += 1;
                warn!(
                    "fault: stuck output, {=u32} repeats of {}; excluding repeats",
                    self.repeats, raw
                );
            }
            return Verdict::Repeat;
        }
        if self.stuck_open {
            log.stuck.handled += 1;
            info!(
                "stuck output over: fresh data after {=u32} repeats, all excluded",
                self.repeats
            );
        }
        self.stuck_open = false;
        self.repeats = 0;
        self.prev = Some(raw);

        // Saturation: an axis at the rail.
        if raw.iter().any(|&v| v.unsigned_abs() >= RAIL.unsigned_abs()) {
            if self.saturated.is_none() {
                log.saturated.seen += 1;
                warn!(
                    "fault: saturated output {}; excluding it, {=usize} readings before and {=u32} after",
                    raw,
                    self.held.len(),
                    GUARD
                );
            }
            self.saturated = Some(index);
            return Verdict::Saturated;
        }

        // Disturbance: the norm off its reference.
        if let Some((stat, limit)) = reference.statistic(raw) {
            // NaN (a reference gone bad) counts as disturbed.
            if stat.is_nan() || stat > limit {
                match self.disturbed {
                    Some((_, first)) => self.disturbed = Some((index, first)),
                    None => {
                        log.disturbance.seen += 1;
                        warn!(
                            "fault: field disturbance, norm off by {=f32} (limit {=f32}); excluding it, {=usize} readings before and {=u32} after",
                            stat,
                            limit,
                            self.held.len(),
                            GUARD
                        );
                        self.disturbed = Some((index, index));
                        self.long_reported = false;
                    }
                }
                return Verdict::Disturbed;
            }
        }
        Verdict::Clean
    }
}
