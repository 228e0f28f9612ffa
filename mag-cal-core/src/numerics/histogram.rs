//! Fixed histograms: medians and other quantiles without sorting, in
//! bounded memory, one cheap pass each (design document, section 14).
//!
//! The samples are a read-only slice and no per-sample value is stored, so
//! robust scales come from histograms filled during the passes the fit
//! makes anyway:
//!
//! - [`LogHistogram`]: magnitudes on a logarithmic scale, 8 bins per octave
//!   taken straight from the `f32` exponent and the top three mantissa bits,
//!   256 bins covering 32 octaves. A quantile is interpolated inside its
//!   bin (bins are 9 % wide: the interpolated median of a smooth
//!   distribution is good to about 1 %).
//! - [`AxisHistograms`]: three linear histograms, one per axis, over a
//!   window that the caller narrows pass by pass (nested histograms) to find
//!   a coordinate-wise median.
//!
//! Counters are `u16`: when one would overflow, every counter is halved,
//! which keeps the quantiles (to the rounding of the halving) for inputs of
//! any length.

use crate::Real;

/// Bins of a [`LogHistogram`].
const LOG_BINS: usize = 256;
/// `f32` bit pattern shift that leaves the exponent and three mantissa bits:
/// 8 bins per octave.
const LOG_SHIFT: u32 = 20;
/// The bin index of `2^-24` (the lowest bin edge, relative to the reference
/// scale): exponent field `127 - 24`, 8 bins per octave.
const LOG_BASE: u32 = (127 - 24) << 3;

/// A histogram of magnitudes `|x| / scale` on a logarithmic scale, from
/// `2^-24` to `2^8`; smaller values count in the first bin, larger ones
/// (and non-finite ones) in the last.
#[derive(Clone, Debug)]
pub(crate) struct LogHistogram {
    bins: [u16; LOG_BINS],
}

impl LogHistogram {
    /// An empty histogram.
    pub(crate) const fn new() -> Self {
        Self {
            bins: [0; LOG_BINS],
        }
    }

    /// Counts the magnitude `|x|` (already divided by the reference scale).
    #[inline(always)]
    pub(crate) fn add<T: Real>(&mut self, x: T) {
        let bits = x.to_single().abs().to_bits();
        // NaN and infinity have the largest exponent: the last bin.
        let k = (bits >> LOG_SHIFT).saturating_sub(LOG_BASE) as usize;
        let k = if k < LOG_BINS { k } else { LOG_BINS - 1 };
        self.bump(k);
    }

    #[inline(always)]
    fn bump(&mut self, k: usize) {
        if let Some(c) = self.bins.get_mut(k) {
            *c += 1;
            if *c == u16::MAX {
                self.halve();
            }
        }
    }

    /// Halves every counter (rare: once per 65 535 counts in one bin).
    #[inline(never)]
    fn halve(&mut self) {
        for c in self.bins.iter_mut() {
            *c /= 2;
        }
    }

    /// Number of counts (of the halved counters, after a halving).
    pub(crate) fn total(&self) -> u32 {
        self.bins.iter().map(|&c| u32::from(c)).sum()
    }

    /// Counts in the bins wholly below `x` (the bin holding `x` is left
    /// out: at most a bin's width, 9 %, short).
    pub(crate) fn count_below<T: Real>(&self, x: T) -> u32 {
        let bits = x.to_single().abs().to_bits();
        let k = (bits >> LOG_SHIFT).saturating_sub(LOG_BASE) as usize;
        self.bins.iter().take(k).map(|&c| u32::from(c)).sum()
    }

    /// The value below which the share `p` (in `[0, 1]`) of the counts lie,
    /// interpolated inside its bin; `None` when the histogram is empty.
    pub(crate) fn quantile<T: Real>(&self, p: T) -> Option<T> {
        let total = self.total();
        if total == 0 {
            return None;
        }
        let target = p * T::from_count(total as usize);
        // The bin by integer counts: the first whose running count reaches
        // `ceil(target)` (the same bin as float sums, which are exact for
        // these counts), without a conversion per bin.
        let floor = target.to_count();
        let need = if T::from_count(floor) < target {
            floor + 1
        } else {
            floor
        };
        let mut below = 0usize;
        for (k, &c) in self.bins.iter().enumerate() {
            let c = usize::from(c);
            if c > 0 && below + c >= need {
                let (lo, hi) = edges::<T>(k);
                let frac = (target - T::from_count(below)) / T::from_count(c);
                return Some(lo + (hi - lo) * frac);
            }
            below += c;
        }
        Some(edges::<T>(LOG_BINS - 1).1)
    }
}

/// Lower and upper edge of bin `k` of a [`LogHistogram`] (the first bin's
/// lower edge is 0, the last's upper edge `2^8`).
fn edges<T: Real>(k: usize) -> (T, T) {
    let edge = |k: usize| {
        let bits = ((k as u32).saturating_add(LOG_BASE)) << LOG_SHIFT;
        T::from_single(f32::from_bits(bits))
    };
    let lo = if k == 0 { T::zero() } else { edge(k) };
    (lo, edge(k + 1))
}

/// Bins per axis of [`AxisHistograms`].
pub(crate) const AXIS_BINS: usize = 64;

/// Counters per axis of [`AxisHistograms`]: the count below the window,
/// the [`AXIS_BINS`] bins, the count above it.
const AXIS_COUNTERS: usize = AXIS_BINS + 2;

/// Three linear histograms over a window `[lo, lo + AXIS_BINS * width)` per
/// axis, with the counts below and above the window.
#[derive(Clone, Debug)]
pub(crate) struct AxisHistograms<T: Real> {
    lo: [T; 3],
    inv_width: [T; 3],
    width: [T; 3],
    /// Per axis: below the window, the bins, above it.
    counts: [[u16; AXIS_COUNTERS]; 3],
}

/// Where a quantile of one axis lies in its window.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Place<T> {
    /// Inside bin `k` (interpolated value).
    In(usize, T),
    /// Below or above the window: the window is wrong.
    Outside,
}

impl<T: Real> AxisHistograms<T> {
    /// Empty histograms over `[lo[a], hi[a]]` per axis (`hi > lo`).
    pub(crate) fn new(lo: [T; 3], hi: [T; 3]) -> Self {
        let n = T::from_count(AXIS_BINS);
        let width = [
            (hi[0] - lo[0]) / n,
            (hi[1] - lo[1]) / n,
            (hi[2] - lo[2]) / n,
        ];
        let inv = |w: T| {
            if w > T::zero() {
                T::one() / w
            } else {
                T::zero()
            }
        };
        Self {
            lo,
            inv_width: [inv(width[0]), inv(width[1]), inv(width[2])],
            width,
            counts: [[0; AXIS_COUNTERS]; 3],
        }
    }

    /// Counts one point.
    #[inline(always)]
    pub(crate) fn add(&mut self, y: [T; 3]) {
        // One axis at a time, written out: a loop over the axes stays a
        // loop at opt-level "s", twice the instructions a sample.
        let full = self.add_axis(0, y[0]) | self.add_axis(1, y[1]) | self.add_axis(2, y[2]);
        if full {
            self.halve();
        }
    }

    /// The counter of `v` on axis `a`: 0 below the window (and NaN),
    /// `1..=AXIS_BINS` the bins, `AXIS_BINS + 1` above it.
    #[inline(always)]
    fn counter_of(&self, a: usize, v: T) -> usize {
        let (Some(&lo), Some(&iw)) = (self.lo.get(a), self.inv_width.get(a)) else {
            return 0;
        };
        let t = (v - lo) * iw;
        // The cast saturates.
        if t >= T::zero() {
            (t.to_single() as u32).min(AXIS_BINS as u32) as usize + 1
        } else {
            0
        }
    }

    /// Counts `v` on axis `a`; true when its counter is full.
    #[inline(always)]
    fn add_axis(&mut self, a: usize, v: T) -> bool {
        let k = self.counter_of(a, v);
        let Some(counts) = self.counts.get_mut(a) else {
            return false;
        };
        match counts.get_mut(k) {
            Some(c) => {
                *c += 1;
                *c == u16::MAX
            }
            None => false,
        }
    }

    #[inline(never)]
    fn halve(&mut self) {
        for c in self.counts.as_flattened_mut() {
            *c /= 2;
        }
    }

    /// The value of axis `a` below which the share `p` of the counts lie.
    pub(crate) fn quantile(&self, a: usize, p: T) -> Place<T> {
        let (Some(counts), Some(&lo), Some(&w)) =
            (self.counts.get(a), self.lo.get(a), self.width.get(a))
        else {
            return Place::Outside;
        };
        let below = counts.first().copied().unwrap_or(0);
        let bins = counts.get(1..=AXIS_BINS).unwrap_or(&[]);
        let total: u32 = counts.iter().map(|&c| u32::from(c)).sum();
        let target = p * T::from_count(total as usize);
        let mut acc = T::from_count(usize::from(below));
        if !(acc < target) && below > 0 {
            return Place::Outside;
        }
        for (k, &c) in bins.iter().enumerate() {
            let c = T::from_count(usize::from(c));
            if acc + c >= target && c > T::zero() {
                let frac = (target - acc) / c;
                return Place::In(k, lo + w * (T::from_count(k) + frac));
            }
            acc += c;
        }
        Place::Outside
    }

    /// The window of bins `first..=last` of axis `a`, as `(lo, hi)`.
    pub(crate) fn window(&self, a: usize, first: usize, last: usize) -> (T, T) {
        let lo = self.lo.get(a).copied().unwrap_or(T::zero());
        let w = self.width.get(a).copied().unwrap_or(T::zero());
        (
            lo + w * T::from_count(first),
            lo + w * T::from_count(last + 1),
        )
    }

    /// Bin width of axis `a`.
    pub(crate) fn width(&self, a: usize) -> T {
        self.width.get(a).copied().unwrap_or(T::zero())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Number of points counted (of the halved counters, after a
    /// halving), as axis 0 holds them.
    fn axis_total(h: &AxisHistograms<f64>) -> u32 {
        h.counts[0].iter().map(|&c| u32::from(c)).sum()
    }

    #[test]
    fn log_median_of_a_geometric_sequence() {
        let mut h = LogHistogram::new();
        // 1001 values, geometric from 1e-3 to 1e1: median 0.1.
        for i in 0..=1000 {
            let x = 1e-3f64 * libm::pow(1e4, f64::from(i) / 1000.0);
            h.add(-x);
        }
        let m: f64 = h.quantile(0.5).unwrap();
        assert!((m / 0.1 - 1.0).abs() < 0.01, "{m}");
        assert_eq!(h.total(), 1001);
    }

    #[test]
    fn log_histogram_survives_long_inputs_and_extremes() {
        let mut h = LogHistogram::new();
        for _ in 0..200_000 {
            h.add(0.5f32);
        }
        h.add(f32::NAN);
        h.add(f32::INFINITY);
        h.add(0.0f32);
        let m: f32 = h.quantile(0.5).unwrap();
        assert!((m / 0.5 - 1.0).abs() < 0.1, "{m}");
        assert!(h.total() < 70_000);
        assert_eq!(LogHistogram::new().quantile::<f32>(0.5), None);
    }

    #[test]
    fn axis_median_and_outside() {
        let mut h = AxisHistograms::new([0.0f64; 3], [64.0; 3]);
        for i in 0..100 {
            let v = f64::from(i) * 0.5;
            h.add([v, v + 10.0, 100.0]);
        }
        match h.quantile(0, 0.5) {
            Place::In(k, v) => {
                assert_eq!(k, 24);
                assert!((v - 25.0).abs() < 0.6, "{v}");
            }
            Place::Outside => panic!("inside"),
        }
        assert_eq!(h.quantile(2, 0.5), Place::Outside);
        assert_eq!(axis_total(&h), 100);
    }
}
