//! Still periods (issue 36): the rows of a device lying still are set
//! aside before any fit.
//!
//! A log usually starts and ends with the device lying still. Every
//! equal-weight least-squares step lets such a dense cluster outweigh the
//! rotation, and the screening's median centre sits inside it; so the rows
//! a still period holds are left out of every pass, as the drop rules'
//! rows are.
//!
//! Row by row in the scan's sums loop ([`Tracker`]), over the rows the
//! drop rules keep:
//!
//! - the local noise `sigma` is an exponential moving average (weight
//!   [`DWELL_EMA`]) of the mean over the axes of `|x[i] - 2 x[i-1] +
//!   x[i-2]|`, divided by [`DWELL_NOISE`] (the mean absolute second
//!   difference of white noise of sigma 1); a second difference beyond
//!   [`DWELL_CLIP`] averages (a spike, the start of motion) leaves it;
//! - a time run is a stretch of consecutive kept rows each within
//!   [`DWELL_RADIUS`]` sigma` (Euclidean) of the moving average (weight
//!   [`DWELL_EMA`]) of the run's rows; a row farther starts a new run;
//! - a run of at least a [`DWELL_SHARE`](crate::tuning::DWELL_SHARE)-th of the rows (and
//!   [`DWELL_MIN_RUN`]) leaves a ball: about the run's moving average at
//!   its end, of [`DWELL_RADIUS`] times its rows' mean sigma; a run whose
//!   centre lies in the last ball (or whose ball holds it) widens that
//!   ball to hold both instead. At most [`DWELL_SPANS`] balls, the first.
//!
//! After the scan's sums ([`Tracker::finish`], [`Dwell::keep_within`]), a
//! ball whose radius is below [`DWELL_SCALE`](crate::tuning::DWELL_SCALE)
//! times the rows' spread (or the spread of the rows outside the balls,
//! when larger: a long still period on one side shrinks the spread of all
//! rows) is a still period. The spread guards rows that are not in time
//! order (a shuffled or interleaved recording): their second differences
//! are as large as their spread, and every row would lie in one run.
//!
//! The rule is then a pure function of the row: a row inside a still
//! period's ball is set aside ([`Dwell::holds`]), in every pass, as the
//! screening ball screens. No row is copied and nothing is stored per row.
//! A moving device that passes through a still orientation loses the rows
//! it has there, a cap of the sphere as wide as a few noise sigmas. Too
//! few rows left beside the still periods are refused as
//! [`crate::Error::HardlyMoved`]. A recording that is one run from end to
//! end (a device that never moved, a noise ball) is not set aside (its
//! radius is its spread) and keeps its refusal (no sphere): it cannot be
//! told from rows out of time order, which are one run too.

use crate::steps::rules::Ball;
use crate::tuning::{DWELL_CLIP, DWELL_EMA, DWELL_MIN_RUN, DWELL_NOISE, DWELL_RADIUS};
use crate::Real;

/// The noise's average starts at the smallest of this many second
/// differences above zero (a spike spoils three). Evidence: `cargo test
/// --release -p host-tests --test still_planar
/// a_spike_among_the_first_rows_sets_nothing_aside` (with the first alone,
/// `icm20948_mag_300.csv` with a spike at row 1 was refused PoorCoverage).
const DWELL_SEED: u8 = 4;

/// At most this many still periods are set aside: the first. Three: still
/// before, between and after the motion (`cargo test --release -p
/// host-tests --test still_periods
/// one_still_period_before_after_or_between_leaves_the_fit`); each ball is
/// 16 bytes of `f32` in every frame that holds a `Dwell` (two on the
/// fit's deepest stack).
pub const DWELL_SPANS: usize = 3;

/// The still periods set aside: a ball (sensor units) about each, and the
/// rows kept by the drop rules that lie in one.
///
/// ```
/// use mag_cal_core::Dwell;
/// let none = Dwell::<f32>::NONE;
/// assert!(none.is_empty() && !none.holds([1.0, 2.0, 3.0]) && none.rows() == 0);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dwell<T: Real> {
    /// The first `len` are the still periods'. Not options: the tag took
    /// 4 bytes a ball, and a `Dwell` is in the report, whose copies are
    /// on the robust path's deepest stack.
    balls: [Ball<T>; DWELL_SPANS],
    len: u8,
    rows: usize,
}

impl<T: Real> Default for Dwell<T> {
    fn default() -> Self {
        Self::NONE
    }
}

impl<T: Real> Dwell<T> {
    /// No row set aside. Zeros (a `memclr`, not a copy of constants).
    pub const NONE: Self = Self {
        balls: [Ball {
            centre: [T::ZERO; 3],
            radius_sq: T::ZERO,
        }; DWELL_SPANS],
        len: 0,
        rows: 0,
    };

    fn used(&self) -> &[Ball<T>] {
        self.balls.get(..usize::from(self.len)).unwrap_or(&[])
    }

    /// The still periods: the centre and the radius of each ball, sensor
    /// units.
    pub fn balls(&self) -> impl Iterator<Item = ([T; 3], T)> + '_ {
        self.used()
            .iter()
            .map(|b| (b.centre, b.radius_sq.square_root()))
    }

    /// Rows set aside (those in a ball that the drop rules keep).
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Whether no still period is set aside.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Whether the row `y` (sensor units) lies in a still period's ball.
    #[inline(always)]
    pub fn holds(&self, y: [T; 3]) -> bool {
        self.used().iter().any(|b| b.contains(y))
    }

    /// Adds a ball, when a slot is free (and says whether one was).
    fn push(&mut self, centre: [T; 3], radius_sq: T) -> bool {
        let Some(slot) = self.balls.get_mut(usize::from(self.len)) else {
            return false;
        };
        // Component by component: the tracker's centre, written whole
        // into its own `found`, linked `memmove` (1.5 kB).
        let [c0, c1, c2] = centre;
        slot.centre[0] = c0;
        slot.centre[1] = c1;
        slot.centre[2] = c2;
        slot.radius_sq = radius_sq;
        self.len += 1;
        true
    }

    /// Counts `rows` set aside (the scan's count).
    pub(crate) fn set_rows(&mut self, rows: usize) {
        self.rows = rows;
    }
}

/// The pass of the rule, row by row in the scan's sums loop
/// ([`Tracker::push`]): the balls of the first [`DWELL_SPANS`] runs long
/// enough.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Tracker<T: Real> {
    /// The two rows before (`seen` of them, up to 2).
    a: [T; 3],
    b: [T; 3],
    seen: u8,
    /// The noise's average (zero before the first second difference above
    /// zero).
    noise: T,
    /// The open run: the moving average of its rows, their count, and
    /// the sum of their noise (the second differences as averaged).
    mean: [T; 3],
    kept: usize,
    noise_sum: T,
    /// The rows of a run long enough to be a still period.
    long: usize,
    /// The balls of the runs that were long enough, in time order.
    found: Dwell<T>,
}

impl<T: Real> Tracker<T> {
    /// A tracker of runs at least `long` rows long (and
    /// [`DWELL_MIN_RUN`]).
    pub(crate) fn new(long: usize) -> Self {
        let zero = [T::zero(); 3];
        Self {
            a: zero,
            b: zero,
            seen: 0,
            noise: T::zero(),
            mean: zero,
            kept: 0,
            noise_sum: T::zero(),
            long: long.max(DWELL_MIN_RUN),
            found: Dwell::NONE,
        }
    }

    /// The next row the rules keep.
    #[inline(always)]
    pub(crate) fn push(&mut self, y: [T; 3]) {
        let [y0, y1, y2] = y;
        let ([a0, a1, a2], [b0, b1, b2]) = (self.a, self.b);
        let w = T::lit(DWELL_EMA);
        let mut d = T::zero();
        if self.seen >= 2 {
            // The sum over the axes of `|y - 2 b + a|` (three times their
            // mean, which the radius divides out).
            d = (y0 - b0 - b0 + a0).abs() + (y1 - b1 - b1 + a1).abs() + (y2 - b2 - b2 + a2).abs();
            // A second difference beyond `DWELL_CLIP` averages is a
            // glitch's (a spike's three rows) or the start of motion: it
            // leaves the noise as it is (capped at that much instead, 10 %
            // of spikes raised the noise without bound, and one run of
            // motion was set aside as still). The first one above zero
            // starts the average.
            if self.seen < 2 + DWELL_SEED {
                // The average starts at the smallest of the first
                // `DWELL_SEED` above zero: a spike among the first rows
                // (its three second differences) started it thousands of
                // times too large, and the first run of motion took a
                // ball a quarter of the field wide.
                self.seen += 1;
                if d > T::zero() && (!(self.noise > T::zero()) || d < self.noise) {
                    self.noise = d;
                }
            }
            if !(self.noise > T::zero()) {
                self.noise = d;
            } else if d < self.noise * T::lit(DWELL_CLIP) {
                self.noise = self.noise + (d - self.noise) * w;
            } else {
                d = self.noise;
            }
        } else {
            self.seen += 1;
        }
        (self.a, self.b) = (self.b, y);
        // [`DWELL_RADIUS`] local sigmas (unbounded before the first second
        // difference above zero: rows equal till then join the first run).
        let r = if self.noise > T::zero() {
            self.noise * T::lit(DWELL_RADIUS / DWELL_NOISE / 3.0)
        } else {
            T::MAX
        };
        let m = self.mean;
        let (d0, d1, d2) = (y0 - m[0], y1 - m[1], y2 - m[2]);
        // The first row of a run is its own mean.
        if self.kept == 0 || d0 * d0 + d1 * d1 + d2 * d2 > r * r {
            self.close();
            self.mean = y;
            self.kept = 0;
            self.noise_sum = T::zero();
        } else {
            self.mean = [m[0] + d0 * w, m[1] + d1 * w, m[2] + d2 * w];
        }
        self.kept += 1;
        self.noise_sum += d;
    }

    /// Keeps the open run's ball if the run is long enough: the moving
    /// average of its rows, and [`DWELL_RADIUS`] sigmas of their mean
    /// noise (the noise at its end is a still period's last rows alone: a
    /// quiet end of a noisy period left most of it outside).
    ///
    /// A ball whose centre lies in the one kept last (or that holds it)
    /// merges with it instead (one still period split into runs, by a
    /// glitch or a quantised reading, takes one slot): that ball becomes
    /// the smallest that holds both. A new period found when every slot is
    /// taken is left in the fit.
    #[inline(never)]
    fn close(&mut self) {
        if self.kept < self.long {
            return;
        }
        let r =
            self.noise_sum / T::from_count(self.kept) * T::lit(DWELL_RADIUS / DWELL_NOISE / 3.0);
        let c = self.mean;
        let found = &mut self.found;
        let merged = match found.balls.get_mut(usize::from(found.len).wrapping_sub(1)) {
            Some(last) => {
                // The new centre in the earlier ball, or the new ball
                // holding it: that ball becomes the smallest that holds
                // both (a ball about the earlier centre, as wide as needed,
                // took too many moving rows: `planar_243.txt` with still
                // ends of 2x at 3 % noise, K'K 1.03 %, `cargo test
                // --release -p host-tests --test still_planar`).
                let d = [
                    c[0] - last.centre[0],
                    c[1] - last.centre[1],
                    c[2] - last.centre[2],
                ];
                let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).square_root();
                let r0 = last.radius_sq.square_root();
                let holds_last = dist + r0 <= r;
                let meets = dist < r0 || holds_last;
                if holds_last {
                    // The new ball holds the earlier: it takes its place.
                    last.centre = c;
                    last.radius_sq = r * r;
                } else if meets {
                    // Neither holds the other (`wide > r0`, then `dist >
                    // 0`), or the earlier holds the new (unchanged).
                    let wide = (dist + r0 + r) * T::lit(0.5);
                    if wide > r0 {
                        let t = (wide - r0) / dist;
                        for (a, da) in last.centre.iter_mut().zip(d) {
                            *a += da * t;
                        }
                        last.radius_sq = wide * wide;
                    }
                }
                meets
            }
            None => false,
        };
        if !merged {
            found.push(c, r * r);
        }
    }

    /// The balls of the runs long enough, the open one closed.
    pub(crate) fn finish(&mut self) -> Dwell<T> {
        self.close();
        self.found
    }
}

impl<T: Real> Dwell<T> {
    /// Keeps the balls whose squared radius is below `limit_sq` (in
    /// place: each read before written, the slots left zeros), and says
    /// whether any was left out.
    pub(crate) fn keep_within(&mut self, limit_sq: T) -> bool {
        let found = usize::from(self.len);
        let all = core::mem::replace(self, Self::NONE);
        for b in all.balls.iter().take(found) {
            if b.radius_sq < limit_sq {
                self.push(b.centre, b.radius_sq);
            }
        }
        usize::from(self.len) < found
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::string::ToString;
    use std::vec::Vec;

    /// A sphere of radius 100 about (20, -10, 5), traced along a slow
    /// spiral: `n` rows, with Gaussian-like noise `noise`.
    pub(crate) fn spiral(n: usize, noise: f64, seed: u64) -> Vec<[f64; 3]> {
        let mut rng = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
        let mut gauss = || {
            let mut s = 0.0;
            for _ in 0..12 {
                rng = rng
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                s += (rng >> 11) as f64 / (1u64 << 53) as f64;
            }
            s - 6.0
        };
        (0..n)
            .map(|i| {
                let t = (i as f64 + 0.5) / n as f64;
                let z = 1.0 - 2.0 * t;
                let r = (1.0 - z * z).sqrt();
                let phi = t * 40.0;
                [
                    20.0 + 100.0 * r * phi.cos() + noise * gauss(),
                    -10.0 + 100.0 * r * phi.sin() + noise * gauss(),
                    5.0 + 100.0 * z + noise * gauss(),
                ]
            })
            .collect()
    }

    fn with_still_ends(rows: &[[f64; 3]], k: usize, noise: f64) -> Vec<[f64; 3]> {
        let still = spiral(2 * k, 0.0, 0);
        let mut jitter = spiral(2 * k, noise, 9)
            .into_iter()
            .zip(still)
            .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]]);
        let (f, l) = (rows[0], rows[rows.len() - 1]);
        let mut out = Vec::new();
        for _ in 0..k {
            let j = jitter.next().unwrap();
            out.push([f[0] + j[0], f[1] + j[1], f[2] + j[2]]);
        }
        out.extend_from_slice(rows);
        for _ in 0..k {
            let j = jitter.next().unwrap();
            out.push([l[0] + j[0], l[1] + j[1], l[2] + j[2]]);
        }
        out
    }

    fn dwell_of(rows: &[[f64; 3]]) -> Dwell<f64> {
        let mut runs = Tracker::new(rows.len() / crate::tuning::DWELL_SHARE);
        for r in rows {
            runs.push(*r);
        }
        // The spread of the rows about their mean.
        let n = rows.len() as f64;
        let mean: Vec<f64> = (0..3)
            .map(|a| rows.iter().map(|r| r[a]).sum::<f64>() / n)
            .collect();
        let var = rows
            .iter()
            .map(|r| (0..3).map(|a| (r[a] - mean[a]).powi(2)).sum::<f64>())
            .sum::<f64>()
            / n;
        // The guard on all rows' spread (the scan also tries the spread
        // of the rows outside the balls).
        let mut d = runs.finish();
        d.keep_within(var * crate::tuning::DWELL_SCALE * crate::tuning::DWELL_SCALE);
        d
    }

    #[test]
    fn still_ends_are_set_aside() {
        let motion = spiral(600, 0.5, 1);
        let rows = with_still_ends(&motion, 1200, 0.5);
        let d = dwell_of(&rows);
        // Two balls, one about each still end, of about 6 sigmas (noise
        // 0.5 a row and axis).
        let balls: Vec<([f64; 3], f64)> = d.balls().collect();
        assert_eq!(balls.len(), 2, "{d:?}");
        for (&(c, r), end) in balls.iter().zip([rows[0], rows[rows.len() - 1]]) {
            let off = (0..3).map(|a| (c[a] - end[a]).powi(2)).sum::<f64>().sqrt();
            assert!(off < 1.0 && (2.0..4.5).contains(&r), "{c:?} {r} {end:?}");
        }
        // Every still row in a ball, and few of the motion's.
        let held =
            |range: core::ops::Range<usize>| rows[range].iter().filter(|y| d.holds(**y)).count();
        assert!(held(0..1200) > 1195 && held(1800..3000) > 1195);
        assert!(held(1200..1800) < 12, "{}", held(1200..1800));
    }

    /// One still period split into runs (a glitch row in it) takes one
    /// slot, so that the periods after it are set aside too.
    #[test]
    fn a_still_period_split_into_runs_takes_one_slot() {
        let still = |at: [f64; 3], k: usize, seed: u64| -> Vec<[f64; 3]> {
            spiral(k, 0.5, seed)
                .iter()
                .zip(spiral(k, 0.0, 0))
                .map(|(a, b)| {
                    [
                        at[0] + a[0] - b[0],
                        at[1] + a[1] - b[1],
                        at[2] + a[2] - b[2],
                    ]
                })
                .collect()
        };
        let motion = spiral(1800, 0.5, 7);
        let (a, b, c) = (motion[0], motion[600], motion[1200]);
        let mut rows = Vec::new();
        for part in 0..3 {
            rows.extend(still(a, 400, 10 + part));
            if part < 2 {
                // A glitch: one row far off, which ends the run.
                rows.push([a[0] + 60.0, a[1], a[2]]);
            }
        }
        rows.extend_from_slice(&motion[..600]);
        rows.extend(still(b, 400, 20));
        rows.extend_from_slice(&motion[600..1200]);
        rows.extend(still(c, 400, 21));
        rows.extend_from_slice(&motion[1200..]);
        let d = dwell_of(&rows);
        assert_eq!(d.balls().count(), 3, "{d:?}");
        for at in [a, b, c] {
            assert!(d.holds(at), "{at:?} {d:?}");
        }
    }

    #[test]
    fn a_slowly_moving_device_is_not_still() {
        // 3 000 rows of one turn: the device moves by about 0.2 % of the
        // field between rows, four times the noise.
        let rows = spiral(3000, 0.05, 2);
        let d = dwell_of(&rows);
        assert!(d.is_empty(), "{d:?}");
        assert!(dwell_of(&spiral(600, 1.0, 3)).is_empty());
    }

    #[test]
    fn rows_out_of_time_order_are_not_still() {
        // The same sphere, its rows interleaved: every row lies far from
        // the one before.
        let rows = spiral(1000, 0.5, 4);
        let shuffled: Vec<[f64; 3]> = (0..1000).map(|i| rows[(i * 383) % 1000]).collect();
        let d = dwell_of(&shuffled);
        assert!(d.is_empty(), "{d:?}");
    }

    #[test]
    fn a_device_that_never_moved_is_not_set_aside() {
        // One run from end to end: its radius (6 sigmas) is beyond its
        // spread (about 1.7 sigmas), as rows out of time order.
        let rows = with_still_ends(&[[50.0, 20.0, -30.0]], 500, 1.0);
        assert!(dwell_of(&rows).is_empty());
    }

    /// The batch fit: still ends of 5x the motion leave the result, and
    /// their rows are a class of their own.
    #[test]
    fn a_log_with_still_ends_calibrates_like_its_motion() {
        use crate::{calibrate, Config, SampleClass};
        let motion = spiral(400, 0.5, 5);
        let rows = with_still_ends(&motion, 1000, 0.5);
        let base = calibrate::<f64, _>(&motion, &Config::default()).unwrap();
        let fit = calibrate::<f64, _>(&rows, &Config::default()).unwrap();
        let (b0, b) = (base.calibration.hard_iron(), fit.calibration.hard_iron());
        let rho = base.calibration.field_strength();
        let db = ((b[0] - b0[0]).powi(2) + (b[1] - b0[1]).powi(2) + (b[2] - b0[2]).powi(2)).sqrt();
        assert!(db < 0.01 * rho, "{db}");
        assert!((fit.calibration.field_strength() - rho).abs() < 0.01 * rho);
        let r = &fit.report;
        assert!(r.dwell > 1950, "{r:?}");
        assert_eq!(
            r.samples_used + r.samples_dropped + r.dwell + r.screened + r.rejected,
            rows.len()
        );
        let dwell = fit
            .report
            .selection
            .classify(&fit.calibration, &rows)
            .filter(|c| *c == SampleClass::Dwell)
            .count();
        assert_eq!(dwell, r.dwell);
    }

    /// A still period on a clip level: its rows are still rows, counted
    /// once, as `classify` names them (the scan counts still rows before
    /// screening finds the clip levels).
    #[test]
    fn still_rows_on_a_clip_level_are_counted_once() {
        use crate::{calibrate, Config, Rule, SampleClass};
        let clip = |r: [f64; 3]| [r[0].min(100.0), r[1], r[2]];
        let motion: Vec<[f64; 3]> = spiral(600, 0.5, 6).into_iter().map(clip).collect();
        // The device lies still where the field's x is beyond the sensor's
        // range: x reads the clip level, y and z the noise.
        let still = with_still_ends(&[[115.0, -10.0, 60.0]], 600, 0.5);
        let mut rows = motion.clone();
        rows.extend(still.iter().map(|&r| clip(r)));
        let fit = calibrate::<f64, _>(&rows, &Config::default()).unwrap();
        let r = &fit.report;
        assert!(r.drops.clipped > 0 && r.dwell > 1150, "{r:?}");
        assert_eq!(
            r.samples_used + r.samples_dropped + r.dwell + r.screened + r.rejected,
            rows.len(),
            "{r:?}"
        );
        let classes: Vec<SampleClass> = r.selection.classify(&fit.calibration, &rows).collect();
        let count = |c: SampleClass| classes.iter().filter(|k| **k == c).count();
        assert_eq!(count(SampleClass::Dwell), r.dwell);
        assert_eq!(count(SampleClass::Dropped(Rule::Clipped)), r.drops.clipped);
    }

    /// A device that moved for one row between two still periods is
    /// refused as hardly moved, in `f32` and `f64`, with and without
    /// outlier handling. (One that never moved keeps its refusal: a noise
    /// ball is as wide as its noise, and is refused as no sphere.)
    #[test]
    fn a_device_that_hardly_moved_is_refused_as_such() {
        use crate::{calibrate, Config, Error};
        for robust in [true, false] {
            let config = Config {
                robust,
                ..Config::default()
            };
            let still = with_still_ends(&[[50.0, 20.0, -30.0]], 500, 1.0);
            let e = calibrate::<f64, _>(&still, &config).unwrap_err();
            assert!(matches!(e, Error::NoSphere { .. }), "{robust}: {e:?}");
            let small: Vec<[f32; 3]> = still.iter().map(|r| r.map(|v| v as f32)).collect();
            let e = calibrate::<f32, _>(&small, &config).unwrap_err();
            assert!(matches!(e, Error::NoSphere { .. }), "{robust}: {e:?}");
            // Two still periods one row apart: too few rows left.
            let rows = with_still_ends(&[[50.0, 20.0, -30.0], [20.0, 60.0, 10.0]], 700, 0.2);
            let e = calibrate::<f64, _>(&rows, &config).unwrap_err();
            assert!(
                matches!(e, Error::HardlyMoved { required: 10, .. }),
                "{robust}: {e:?}"
            );
            assert!(e.to_string().starts_with("the device hardly moved"), "{e}");
        }
    }
}
