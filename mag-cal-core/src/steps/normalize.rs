//! Centring and scaling (design document, section 2).
//!
//! Every fit runs on `x = (y - c) / s` with `c` the mean and `s` the RMS
//! distance from it, and maps its result back (`b = c + s b'`,
//! `W = W' / s`). `c` and `s` need not be exact: they define a change of
//! variables that is undone exactly, so a fast one-pass estimate is enough.

use nalgebra::Vector3;

use crate::sample::Sample;
use crate::steps::dwell::{self, Dwell};
use crate::steps::rules::{count_drops, Drops, Gate, Rules};
use crate::tuning::{DWELL_SCALE, DWELL_SHARE};
use crate::{Error, Real};

/// Minimum number of finite samples for any fit: the LS ellipsoid has nine
/// free coefficients, and one more sample makes the system overdetermined.
pub const MIN_SAMPLES: usize = 10;

/// The affine map between sensor units and normalised coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Normalization<T: Real> {
    /// Centre `c` (mean of the finite samples), sensor units.
    pub centre: Vector3<T>,
    /// Scale `s` (RMS distance from the centre), sensor units.
    pub scale: T,
    /// `1 / s`.
    pub inv_scale: T,
}

impl<T: Real> Normalization<T> {
    /// Maps a sensor-unit vector into normalised coordinates.
    #[cfg(any(test, feature = "submle"))]
    #[inline]
    pub fn forward(&self, y: [T; 3]) -> Vector3<T> {
        Vector3::new(
            (y[0] - self.centre.x) * self.inv_scale,
            (y[1] - self.centre.y) * self.inv_scale,
            (y[2] - self.centre.z) * self.inv_scale,
        )
    }

    /// Maps a point in normalised coordinates back to sensor units.
    #[inline]
    pub fn point_back(&self, x: &Vector3<T>) -> Vector3<T> {
        // Written out: nalgebra's operators on vectors are loops at
        // opt-level "s" (112 bytes of flash more, LS9 + ADC2 without
        // `robust`; 28 with it).
        let (c, s) = (&self.centre, self.scale);
        Vector3::new(c.x + x.x * s, c.y + x.y * s, c.z + x.z * s)
    }
}

/// What the normalisation pass learned about the input.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Scan<'d, T: Real> {
    pub norm: Normalization<T>,
    /// Rows the rules kept.
    pub used: usize,
    /// Rows the rules dropped, by rule.
    pub drops: Drops,
    /// The rules the later passes apply: the glitch rules only when they
    /// dropped a row here, and no clip levels (screening finds those).
    pub rules: Rules<T>,
    /// The still periods set aside ([`crate::Dwell`]): `used` and
    /// the normalisation leave them out. By reference, in the caller's
    /// frame: a `Scan` returned whole held it twice on the fit's deepest
    /// stack (the result and its value).
    pub dwell: &'d Dwell<T>,
}

/// One pass over the samples: applies the drop rules (the glitch rules
/// when `glitches` is set, see [`crate::steps::rules`]), counts, validates and
/// normalises the rows kept.
///
/// Sums are taken on `y - y0`, with `y0` the first kept sample, so the
/// variance `mean|y - y0|^2 - |mean(y - y0)|^2` cancels only when `y0` is
/// far outside the cloud; that case is detected and the spread recomputed
/// in a second pass around the now-known mean.
pub(crate) fn scan<T: Real, S: Sample>(
    samples: &[S],
    glitches: bool,
) -> Result<Scan<'static, T>, Error> {
    scan_still(samples, glitches, None)
}

/// [`scan`] that, given `still`, also sets the still periods aside
/// ([`crate::Dwell`], written there): when the sums' pass found one, one
/// pass more without their rows (two when the guard leaves a ball out).
pub(crate) fn scan_still<'d, T: Real, S: Sample>(
    samples: &[S],
    glitches: bool,
    still: Option<&'d mut Dwell<T>>,
) -> Result<Scan<'d, T>, Error> {
    let zero = T::zero();
    // The rules first, in a loop of their own (integer compares for integer
    // samples).
    let rules = if glitches {
        Rules::GLITCHES
    } else {
        Rules::PLAIN
    };
    let mut drops = if glitches {
        count_drops::<T, S>(samples, &rules, T::NO_DWELL)
    } else {
        Drops::default()
    };
    let gate = Gate {
        rules: if drops.total() == 0 {
            Rules::PLAIN
        } else {
            rules
        },
        screen: None,
        dwell: T::NO_DWELL,
    };
    // The first kept sample is the origin; the loop runs over the rest.
    let mut prev = None;
    let mut origin = None;
    let mut rest: &[S] = &[];
    for (i, s) in samples.iter().enumerate() {
        if let Some(y) = gate.pass(s, prev) {
            origin = Some(y);
            rest = samples.get(i + 1..).unwrap_or(&[]);
            break;
        }
        prev = Some(s);
    }
    let before_rest = samples
        .len()
        .checked_sub(rest.len() + 1)
        .and_then(|i| samples.get(i));
    let mut sums = Sums {
        used: 0,
        sum: [zero; 3],
        sum_sq: zero,
    };
    let mut dwell = Dwell::NONE;
    // The sums outside the still periods, when the guard's pass made them.
    let mut outside = None;
    if let Some(o) = origin {
        // Still periods hold at least a tenth of the rows.
        let mut runs = dwell::Tracker::new(samples.len() / DWELL_SHARE);
        sums = sums_about(rest, before_rest, o, &gate, Some(&mut runs));
        sums.used += 1;
        if still.is_some() {
            dwell = runs.finish();
        }
        if !dwell.is_empty() {
            // The guard: a ball's radius is below `DWELL_SCALE` times the
            // spread of every row kept (rows out of time order are one
            // run as wide as they are), or of the rows outside every ball
            // (at least `MIN_SAMPLES`) when that is larger: a long still
            // period on one side shrinks the spread of all rows towards
            // its own noise (10x the motion at 3 % noise brought it below
            // its ball's radius: `icm20948_mag_300.csv` refused NoSphere).
            // Not the spread of all rows scaled by the share outside the
            // runs, which needs no pass: rows out of time order with 5
            // wild rows (`host-tests --test robust`, scenario A) then lay
            // in one ball, refused as HardlyMoved.
            let beside = sums_about(
                samples,
                None,
                o,
                &Gate {
                    dwell: &dwell,
                    ..gate
                },
                None,
            );
            let mut var = sums.variance();
            if beside.used >= MIN_SAMPLES && beside.variance() > var {
                var = beside.variance();
            }
            if !dwell.keep_within(var * T::lit(DWELL_SCALE * DWELL_SCALE)) {
                outside = Some(beside);
            }
        }
    }
    // The still periods' rows leave the sums: the guard's pass, or one
    // more when the guard left a ball out.
    let kept = sums.used;
    let gate = Gate {
        dwell: &dwell,
        ..gate
    };
    if let Some(o) = origin.filter(|_| !dwell.is_empty()) {
        sums = match outside {
            Some(beside) => beside,
            None => sums_about(samples, None, o, &gate, None),
        };
    }
    let aside = kept.saturating_sub(sums.used);
    let Sums { used, sum, sum_sq } = sums;
    if used + aside + drops.total() != samples.len() {
        // Non-finite rows in the plain pipeline (which counts after the
        // sums); with the glitch rules this cannot happen, as both loops
        // apply the same rules.
        drops = count_drops::<T, S>(samples, &gate.rules, &dwell);
    }
    let Some(o) = origin.filter(|_| used >= MIN_SAMPLES) else {
        if aside > 0 {
            // Too few rows left beside the still periods.
            return Err(Error::HardlyMoved {
                moving: used,
                still: aside,
                required: MIN_SAMPLES,
            });
        }
        if drops.overflow * 2 > drops.total() {
            // Most rows are too large to compute with.
            return Err(Error::OutOfRange);
        }
        if glitches && drops.glitches() > 0 {
            // Say what the rows are without the glitch rules when that is
            // a refusal too (all equal rather than "repeated"), else how
            // few the rules left.
            scan::<T, S>(samples, false)?;
        }
        return Err(Error::TooFewSamples {
            found: used,
            required: MIN_SAMPLES,
        });
    };
    // Every difference is zero, or so small that its square underflows
    // (then the spread is refused below): tell the two apart.
    if !(sum_sq > zero) && gate.rows(rest, before_rest).all(|y| y == o) {
        return Err(Error::AllSamplesEqual);
    }
    let n = T::from_count(sums.used);
    // Per component, as `point_back`.
    let mean = [sum[0] / n, sum[1] / n, sum[2] / n];
    let centre = Vector3::new(o[0] + mean[0], o[1] + mean[1], o[2] + mean[2]);
    let mut var = sums.variance();
    // Catastrophic cancellation: y0 lies far outside the cloud (a wild first
    // sample). Recompute the spread around the mean; this path is rare.
    if !(var > sum_sq / n * T::lit(1e-2)) {
        var = spread_about(samples, &centre, &gate) / n;
    }
    // Refuse spreads whose squares overflow, or that are so small that their
    // squares approach the subnormal range and lose significant bits.
    if !centre.as_slice().iter().all(|c| c.is_finite())
        || !var.is_finite()
        || var < T::MIN_POSITIVE / T::EPSILON
    {
        return Err(Error::OutOfRange);
    }
    let scale = var.square_root();
    dwell.set_rows(aside);
    let dwell = match still {
        Some(out) => {
            *out = dwell;
            &*out
        }
        None => T::NO_DWELL,
    };
    Ok(Scan {
        norm: Normalization {
            centre,
            scale,
            inv_scale: T::one() / scale,
        },
        used,
        drops,
        // Every pass reads the same rows: rules that dropped none here drop
        // none later, and need not be applied again.
        rules: Rules {
            glitches: rules.glitches && drops.glitches() > 0,
            ..rules
        },
        dwell,
    })
}

/// Count, `sum (y - o)` and `sum |y - o|^2` over the kept samples.
struct Sums<T> {
    used: usize,
    sum: [T; 3],
    sum_sq: T,
}

impl<T: Real> Sums<T> {
    /// The mean squared distance of the rows from their mean (the guard's
    /// spreads and the scale). Out of line: three callers.
    #[inline(never)]
    fn variance(&self) -> T {
        let n = T::from_count(self.used);
        let mean = [self.sum[0] / n, self.sum[1] / n, self.sum[2] / n];
        self.sum_sq / n - (mean[0] * mean[0] + mean[1] * mean[1] + mean[2] * mean[2])
    }
}

/// [`Sums`] of the rows `gate` keeps about the origin `o` (`prev`: the
/// row before `samples`), and their time runs when `runs` is given
/// ([`dwell::Tracker`]: the still periods' pass in the same loop): the
/// loop of [`scan`], on scalars and on its own (not inlined), so that
/// nothing of the caller competes for its registers. Every row goes
/// through [`Gate::pass`], a plain gate's too: the inline conversion of
/// a plain gate's rows took 64 bytes of flash more (LS9 + ADC2 at
/// `aa811ae`, `bash bench.sh flash`) for about 39 instructions a row less.
#[inline(never)]
fn sums_about<T: Real, S: Sample>(
    samples: &[S],
    prev: Option<&S>,
    o: [T; 3],
    gate: &Gate<T>,
    mut runs: Option<&mut dwell::Tracker<T>>,
) -> Sums<T> {
    let [o0, o1, o2] = o;
    let (mut s0, mut s1, mut s2, mut sq) = (T::zero(), T::zero(), T::zero(), T::zero());
    let mut used = 0;
    let mut last = prev;
    for s in samples {
        let row = gate.pass(s, last);
        last = Some(s);
        let Some(y) = row else {
            continue;
        };
        if let Some(runs) = runs.as_deref_mut() {
            runs.push(y);
        }
        let [y0, y1, y2] = y;
        let (d0, d1, d2) = (y0 - o0, y1 - o1, y2 - o2);
        s0 += d0;
        s1 += d1;
        s2 += d2;
        sq += d0 * d0;
        sq += d1 * d1;
        sq += d2 * d2;
        used += 1;
    }
    Sums {
        used,
        sum: [s0, s1, s2],
        sum_sq: sq,
    }
}

/// `sum |y - c|^2` over the kept samples.
fn spread_about<T: Real, S: Sample>(samples: &[S], c: &Vector3<T>, gate: &Gate<T>) -> T {
    gate.rows(samples, None)
        .map(|y| {
            let d = [y[0] - c.x, y[1] - c.y, y[2] - c.z];
            d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        })
        .fold(T::zero(), |a, b| a + b)
}

/// The per-sample map of the passes that follow a fit: a raw sample `y` to
/// its calibrated vector `u = W' ((y - c)/s - b') = A (y - e)`, with the
/// fit's centre in sensor units `e = c + s b'` and `A = W' / s`.
///
/// Folding the normalisation into the fit leaves 12 constants and 12
/// operations a sample (the subtraction first, so that a hard iron far
/// larger than the field costs no accuracy). Generic small-matrix
/// operations in a per-sample loop cost about ten times as much on a
/// Cortex-M4F, hence the scalars.
#[derive(Clone, Copy)]
pub(crate) struct Projector<T: Real> {
    /// `e`, sensor units.
    e: [T; 3],
    /// `A = W' / s`, row-major.
    a: [T; 9],
}

impl<T: Real> Projector<T> {
    /// For the fit `(b', W')` in the coordinates of `norm`.
    pub(crate) fn new(
        norm: &Normalization<T>,
        centre: &Vector3<T>,
        w: &nalgebra::Matrix3<T>,
    ) -> Self {
        let e = norm.point_back(centre);
        let is = norm.inv_scale;
        let a = |i, j| w[(i, j)] * is;
        Self {
            e: [e.x, e.y, e.z],
            a: [
                a(0, 0),
                a(0, 1),
                a(0, 2),
                a(1, 0),
                a(1, 1),
                a(1, 2),
                a(2, 0),
                a(2, 1),
                a(2, 2),
            ],
        }
    }

    /// `u` for a finite raw sample `y`.
    #[inline(always)]
    pub(crate) fn project(&self, y: [T; 3]) -> [T; 3] {
        let [e0, e1, e2] = self.e;
        let [a00, a01, a02, a10, a11, a12, a20, a21, a22] = self.a;
        let d = [y[0] - e0, y[1] - e1, y[2] - e2];
        [
            a00 * d[0] + a01 * d[1] + a02 * d[2],
            a10 * d[0] + a11 * d[1] + a12 * d[2],
            a20 * d[0] + a21 * d[1] + a22 * d[2],
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_and_scale_of_a_cloud_with_a_leading_non_finite_sample() {
        // A non-finite sample first, then +-1 along each axis about
        // (100, -50, 7): mean that point, RMS distance 1.
        let pattern = [
            [f32::NAN, 0.0, 0.0],
            [101.0, -50.0, 7.0],
            [99.0, -50.0, 7.0],
            [100.0, -49.0, 7.0],
            [100.0, -51.0, 7.0],
            [100.0, -50.0, 8.0],
            [100.0, -50.0, 6.0],
        ];
        let mut samples = [[0.0f32; 3]; 28];
        for (s, p) in samples.iter_mut().zip(pattern.iter().cycle()) {
            *s = *p;
        }
        let scan = scan::<f64, _>(&samples, true).unwrap();
        assert_eq!((scan.used, scan.drops.non_finite), (24, 4));
        assert!((scan.norm.centre - Vector3::new(100.0, -50.0, 7.0)).amax() < 1e-12);
        assert!((scan.norm.scale - 1.0).abs() < 1e-12);
    }

    #[test]
    fn equal_samples_and_underflowing_spreads_are_told_apart() {
        let equal = [[3.0f32, -2.0, 1.0]; 20];
        assert_eq!(
            scan::<f32, _>(&equal, false).unwrap_err(),
            Error::AllSamplesEqual
        );
        // Differences whose squares underflow to zero: not equal, but out
        // of range.
        let mut tiny = [[0.0f32; 3]; 20];
        tiny[7][1] = 1e-40;
        assert_eq!(scan::<f32, _>(&tiny, false).unwrap_err(), Error::OutOfRange);
    }

    /// The folded map is `W' ((y - c)/s - b')`.
    #[test]
    fn projector_is_the_calibrated_vector() {
        let norm = Normalization {
            centre: Vector3::new(300.0, -120.0, 75.0),
            scale: 45.0,
            inv_scale: 1.0 / 45.0,
        };
        let b = Vector3::new(0.1, -0.05, 0.02);
        let w = nalgebra::Matrix3::new(1.1, 0.02, 0.0, 0.02, 0.95, -0.01, 0.0, -0.01, 1.05);
        let y = [333.0, -101.0, 40.0];
        let want = w * (norm.forward(y) - b);
        let got = Projector::new(&norm, &b, &w).project(y);
        assert!((Vector3::from(got) - want).amax() < 1e-13);
    }
}
