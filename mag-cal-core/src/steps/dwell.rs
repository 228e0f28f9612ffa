//! Still periods (issue 36): the rows of a device lying still, beyond the
//! first few, are set aside before any fit.
//!
//! A log usually starts and ends with the device lying still. Every
//! equal-weight least-squares step lets such a dense cluster outweigh the
//! rotation, and the screening's median centre sits inside it; so the rows
//! of a still period beyond its first `K` are left out of every pass, as
//! the drop rules' rows are.
//!
//! One pass over the rows the drop rules keep ([`detect`], in the scan):
//!
//! - the local noise `sigma` is an exponential moving average (weight
//!   [`DWELL_EMA`]) of the mean over the axes of `|x[i] - 2 x[i-1] +
//!   x[i-2]|`, divided by [`DWELL_NOISE`] (the mean absolute second
//!   difference of white noise of sigma 1);
//! - a time run is a stretch of consecutive kept rows each within
//!   [`DWELL_RADIUS`]` sigma` (Euclidean) of the mean of the run so far;
//!   a row farther starts a new run;
//! - the [`DWELL_SPANS`] longest runs are kept.
//!
//! After the scan's sums ([`Detection::decide`]), a run of at least
//! [`DWELL_MIN_RUN`] rows and [`DWELL_LONG`]` K` whose radius is at most [`DWELL_SCALE`] times
//! the rows' spread is a still period: its first `K` rows are kept and the
//! rest set aside, `K = max(DWELL_KEEP, n_motion / DWELL_SHARE)` with
//! `n_motion` the rows left (a fixed point, iterated). The spread guards
//! rows that are not in time order (a shuffled or interleaved recording):
//! their second differences are as large as their spread, and every row
//! would lie in one run.
//!
//! No row is copied and nothing is stored per row: the set-aside rows are
//! a few spans ([`Dwell`]), which every later pass skips as it skips the
//! spans beside runs of outliers ([`crate::robust::runs`]). Too few rows
//! left beside the still periods are refused as
//! [`crate::Error::HardlyMoved`]. A recording that is one run from end to
//! end (a device that never moved, a noise ball) is not set aside (its
//! radius is its spread) and keeps its refusal (no sphere): it cannot be
//! told from rows out of time order, which are one run too.

use crate::sample::Sample;
use crate::steps::rules::{check, every, Gate, Rules};
use crate::tuning::{
    DWELL_CLIP, DWELL_EMA, DWELL_KEEP, DWELL_LONG, DWELL_MIN_RUN, DWELL_NOISE, DWELL_RADIUS,
    DWELL_SCALE, DWELL_SHARE, DWELL_STRIDE,
};
use crate::Real;

/// At most this many still periods are set aside: the longest runs.
pub const DWELL_SPANS: usize = 4;

/// The rows set aside as still periods: half-open spans `start..end` of
/// row indices, disjoint (not in order), and the rows in them that the
/// drop rules keep.
///
/// ```
/// use mag_cal_core::Dwell;
/// assert!(Dwell::NONE.is_empty() && !Dwell::NONE.contains(3));
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Dwell {
    spans: [(usize, usize); DWELL_SPANS],
    len: usize,
    rows: usize,
}

impl Default for Dwell {
    fn default() -> Self {
        Self::NONE
    }
}

impl Dwell {
    /// No row set aside.
    pub const NONE: Self = Self {
        spans: [(0, 0); DWELL_SPANS],
        len: 0,
        rows: 0,
    };

    /// The spans (disjoint, not in order).
    pub fn spans(&self) -> &[(usize, usize)] {
        self.spans.get(..self.len).unwrap_or(&[])
    }

    /// Rows set aside (those in the spans that the drop rules keep).
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Whether no row is set aside.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Whether row `i` lies in a span.
    pub fn contains(&self, i: usize) -> bool {
        self.spans().iter().any(|&(s, e)| s <= i && i < e)
    }
}

/// Whether one time run holds all but `1 / DWELL_SHARE` of the `kept`
/// rows the rules keep, `longest` those of the longest: then the device
/// never moved, and the rows outside that run and those in it.
#[cfg(test)]
pub(crate) fn never_moved(longest: usize, kept: usize) -> Option<(usize, usize)> {
    (kept > 0 && longest + kept / DWELL_SHARE >= kept).then_some((kept - longest, longest))
}

/// A time run: its first row, one past its last, the rows kept in it,
/// and its radius at its end (sensor units).
#[derive(Clone, Copy, Debug)]
struct Run<T> {
    start: usize,
    end: usize,
    kept: usize,
    radius: T,
}

/// What [`detect`] found: the longest runs and the rows kept.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Detection<T> {
    runs: [Run<T>; DWELL_SPANS],
    len: usize,
    kept: usize,
}

/// The pass of the rule: the [`DWELL_SPANS`] longest time runs of the rows
/// `gate` passes (its out-of-line check: no copy of the rules here).
#[inline(never)]
pub(crate) fn detect<T: Real, S: Sample>(samples: &[S], gate: &Gate<T>) -> Detection<T> {
    let zero = T::zero();
    let mut found = Detection {
        runs: [Run {
            start: 0,
            end: 0,
            kept: 0,
            radius: zero,
        }; DWELL_SPANS],
        len: 0,
        kept: 0,
    };
    let gain = T::lit(DWELL_RADIUS / DWELL_NOISE);
    let weight = T::lit(DWELL_EMA);
    let third = T::lit(1.0 / 3.0);
    let clip = T::lit(DWELL_CLIP);
    // Scalars written out per axis: arrays kept the rows in memory at
    // opt-level "s" (about 30 instructions a row more).
    // The two rows kept before (`seen` of them, up to 2) and the noise's
    // average; before the first second difference the radius is
    // unbounded: the first rows join the first run.
    let (mut a0, mut a1, mut a2) = (zero, zero, zero);
    let (mut b0, mut b1, mut b2) = (zero, zero, zero);
    let mut seen = 0u8;
    let mut ema = T::MAX;
    // The open run: its first row (the origin of its sums), the sums of
    // `y - first` and their count, and the run itself.
    let (mut f0, mut f1, mut f2) = (zero, zero, zero);
    let (mut s0, mut s1, mut s2) = (zero, zero, zero);
    let mut count = zero;
    let mut run = Run {
        start: 0,
        end: 0,
        kept: 0,
        radius: T::MAX,
    };
    // A plain gate: the conversion alone, inline (the out-of-line check
    // cost about 40 instructions a row).
    let plain = gate.is_plain();
    for (i, s, prev) in every(samples, None, DWELL_STRIDE) {
        let row = if plain {
            check::<T, S>(s, None, &Rules::PLAIN).ok()
        } else {
            gate.admit(s, prev).ok()
        };
        let Some([y0, y1, y2]) = row else {
            continue;
        };
        found.kept += DWELL_STRIDE;
        if seen >= 2 {
            let d =
                ((y0 - b0 - b0 + a0).abs() + (y1 - b1 - b1 + a1).abs() + (y2 - b2 - b2 + a2).abs())
                    * third;
            // A second difference beyond `DWELL_CLIP` averages counts
            // as that much: a spike does not inflate the noise of the rows
            // after it (which then formed one long run of motion).
            ema = if ema < T::MAX {
                ema + (d.min(ema * clip) - ema) * weight
            } else {
                d
            };
        } else {
            seen += 1;
        }
        (a0, a1, a2) = (b0, b1, b2);
        (b0, b1, b2) = (y0, y1, y2);
        let radius = if ema < T::MAX { ema * gain } else { T::MAX };
        // `|y - mean| > radius`, times the count (no division).
        let (d0, d1, d2) = (
            (y0 - f0) * count - s0,
            (y1 - f1) * count - s1,
            (y2 - f2) * count - s2,
        );
        let far = radius * count;
        // The first row of a run is its own reference.
        if run.kept == 0 || d0 * d0 + d1 * d1 + d2 * d2 > far * far {
            // Runs too short to be still periods are not kept (on moving
            // data nearly every run: a call a row or two).
            if run.kept >= DWELL_MIN_RUN {
                found.close(run);
            }
            run.start = i;
            run.kept = 0;
            (f0, f1, f2) = (y0, y1, y2);
            (s0, s1, s2) = (zero, zero, zero);
            count = zero;
        }
        s0 += y0 - f0;
        s1 += y1 - f1;
        s2 += y2 - f2;
        count += T::one();
        run.kept += DWELL_STRIDE;
        run.end = i + 1;
        run.radius = radius;
    }
    if run.kept >= DWELL_MIN_RUN {
        found.close(run);
    }
    found
}

impl<T: Real> Detection<T> {
    /// [`never_moved`] of the runs found.
    #[cfg(test)]
    pub(crate) fn never_moved(&self) -> Option<(usize, usize)> {
        let runs = self.runs.get(..self.len).unwrap_or(&[]);
        never_moved(runs.iter().map(|r| r.kept).max().unwrap_or(0), self.kept)
    }

    /// Keeps `run` if it is among the longest (in the place of the
    /// shortest kept: the runs are not in time order).
    fn close(&mut self, run: Run<T>) {
        let at = if self.len < DWELL_SPANS {
            self.len += 1;
            self.len - 1
        } else {
            let (k, shortest) = self
                .runs
                .iter()
                .enumerate()
                .min_by_key(|(_, r)| r.kept)
                .map_or((0, usize::MAX), |(k, r)| (k, r.kept));
            if shortest >= run.kept {
                return;
            }
            k
        };
        if let Some(slot) = self.runs.get_mut(at) {
            *slot = run;
        }
    }

    /// The spans set aside, given the spread of the rows (`scale`, the RMS
    /// distance from their mean, sensor units): of each run of at least
    /// [`DWELL_MIN_RUN`] rows and [`DWELL_LONG`]` K` within
    /// [`DWELL_SCALE`]` scale`, the rows after its first `K` (the rows set
    /// aside are counted by the caller: those of the spans the rules keep).
    pub(crate) fn decide(&self, scale: T) -> Dwell {
        let mut dwell = Dwell::NONE;
        let runs = self.runs.get(..self.len).unwrap_or(&[]);
        if !(scale > T::zero()) {
            // No spread (every row equal): nothing to set aside.
            return dwell;
        }
        let limit = scale * T::lit(DWELL_SCALE);
        let still = |r: &Run<T>, keep: usize| {
            r.kept >= DWELL_MIN_RUN.max(keep * DWELL_LONG) && r.radius <= limit
        };
        // K = max(DWELL_KEEP, n_motion / DWELL_SHARE): a fixed point,
        // reached in a few steps (K grows with n_motion, which shrinks as
        // K grows).
        let mut keep = DWELL_KEEP;
        for _ in 0..8 {
            let aside: usize = runs
                .iter()
                .filter(|r| still(r, keep))
                .map(|r| r.kept.saturating_sub(keep))
                .sum();
            keep = DWELL_KEEP.max(self.kept.saturating_sub(aside) / DWELL_SHARE);
        }
        // In the order of the runs kept (not time order: the passes'
        // pieces do not need it).
        for r in runs.iter().filter(|r| still(r, keep)) {
            let start = r.start.saturating_add(keep);
            if start < r.end {
                if let Some(slot) = dwell.spans.get_mut(dwell.len) {
                    *slot = (start, r.end);
                    dwell.len += 1;
                }
            }
        }
        dwell
    }
}

/// Counts `rows` set aside (the caller's count of the rows of the spans
/// that the rules keep).
impl Dwell {
    pub(crate) fn set_rows(&mut self, rows: usize) {
        self.rows = rows;
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

    fn dwell_of(rows: &[[f64; 3]]) -> Dwell {
        use crate::steps::rules::Rules;
        let gate = Gate::of(Rules::<f64>::GLITCHES, &Dwell::NONE);
        let found = detect(rows, &gate);
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
        let mut d = found.decide(var.sqrt());
        let rows = d.spans().iter().map(|&(s, e)| e - s).sum();
        d.set_rows(rows);
        d
    }

    #[test]
    fn still_ends_are_set_aside_but_their_first_rows() {
        let motion = spiral(600, 0.5, 1);
        let rows = with_still_ends(&motion, 1200, 0.5);
        let d = dwell_of(&rows);
        // Two spans, each the still end but its first K rows (K =
        // max(4, 600 / 48) = 12, give or take the rows the runs take
        // from the motion).
        assert_eq!(d.spans().len(), 2, "{d:?}");
        let mut spans = d.spans().to_vec();
        spans.sort();
        let [(s0, e0), (s1, e1)] = [spans[0], spans[1]];
        assert!(s0 <= 20 && (1190..=1210).contains(&e0), "{d:?}");
        assert!((1800..=1830).contains(&s1) && e1 == rows.len(), "{d:?}");
        assert!(d.rows() > 2300);
        assert!(d.contains(s0) && !d.contains(e0));
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
    fn a_device_that_never_moved_is_one_run() {
        let rows = with_still_ends(&[[50.0, 20.0, -30.0]], 500, 1.0);
        use crate::steps::rules::Rules;
        let gate = Gate::of(Rules::<f64>::GLITCHES, &Dwell::NONE);
        assert!(detect(&rows, &gate).never_moved().is_some());
        assert!(detect(&spiral(600, 1.0, 3), &gate).never_moved().is_none());
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
