//! Centring and scaling (design document, section 2).
//!
//! Every fit runs on `x = (y - c) / s` with `c` the mean and `s` the RMS
//! distance from it, and maps its result back (`b = c + s b'`,
//! `W = W' / s`). `c` and `s` need not be exact: they define a change of
//! variables that is undone exactly, so a fast one-pass estimate is enough.

use nalgebra::Vector3;

use crate::sample::{finite, Sample};
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
        self.centre + x * self.scale
    }
}

/// What the normalisation pass learned about the input.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Scan<T: Real> {
    pub norm: Normalization<T>,
    /// Finite samples.
    pub used: usize,
    /// Non-finite samples, skipped.
    pub dropped: usize,
}

/// One pass over the samples: counts, validates and normalises.
///
/// Sums are taken on `y - y0`, with `y0` the first finite sample, so the
/// variance `mean|y - y0|^2 - |mean(y - y0)|^2` cancels only when `y0` is
/// far outside the cloud; that case is detected and the spread recomputed
/// in a second pass around the now-known mean.
pub(crate) fn scan<T: Real, S: Sample>(samples: &[S]) -> Result<Scan<T>, Error> {
    let zero = T::zero();
    // The first finite sample is the origin; the loop runs over the rest.
    let mut rest = samples.iter();
    let origin = rest.by_ref().find_map(finite::<T, S>);
    let mut sums = Sums {
        used: 0,
        sum: [zero; 3],
        sum_sq: zero,
    };
    if let Some(o) = origin {
        sums = sums_about(rest.as_slice(), o);
        sums.used += 1;
    }
    let Sums { used, sum, sum_sq } = sums;
    let dropped = samples.len() - used;
    let Some(o) = origin.filter(|_| used >= MIN_SAMPLES) else {
        return Err(Error::TooFewSamples {
            found: used,
            required: MIN_SAMPLES,
        });
    };
    // Every difference is zero, or so small that its square underflows
    // (then the spread is refused below): tell the two apart, rarely.
    if !(sum_sq > zero) && rest.filter_map(finite::<T, S>).all(|y| y == o) {
        return Err(Error::AllSamplesEqual);
    }
    let n = T::from_count(used);
    let mean = Vector3::new(sum[0] / n, sum[1] / n, sum[2] / n);
    let centre = Vector3::new(o[0], o[1], o[2]) + mean;
    let mean_sq = sum_sq / n;
    let mut var = mean_sq - mean.norm_squared();
    // Catastrophic cancellation: y0 lies far outside the cloud (a wild first
    // sample). Recompute the spread around the mean; this path is rare.
    if !(var > mean_sq * T::lit(1e-2)) {
        var = spread_about(samples, &centre) / n;
    }
    // Refuse spreads whose squares overflow, or that are so small that their
    // squares approach the subnormal range and lose significant bits.
    if !centre.iter().all(|c| c.is_finite())
        || !var.is_finite()
        || var < T::MIN_POSITIVE / T::EPSILON
    {
        return Err(Error::OutOfRange);
    }
    let scale = var.sqrt();
    Ok(Scan {
        norm: Normalization {
            centre,
            scale,
            inv_scale: T::one() / scale,
        },
        used,
        dropped,
    })
}

/// Count, `sum (y - o)` and `sum |y - o|^2` over finite samples.
struct Sums<T> {
    used: usize,
    sum: [T; 3],
    sum_sq: T,
}

/// [`Sums`] of the finite samples about the origin `o`: the loop of
/// [`scan`], on scalars and on its own (not inlined), so that nothing of
/// the caller competes for its registers.
#[inline(never)]
fn sums_about<T: Real, S: Sample>(samples: &[S], o: [T; 3]) -> Sums<T> {
    let [o0, o1, o2] = o;
    let (mut s0, mut s1, mut s2, mut sq) = (T::zero(), T::zero(), T::zero(), T::zero());
    let mut used = 0;
    for [y0, y1, y2] in samples.iter().filter_map(finite::<T, S>) {
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

/// `sum |y - c|^2` over the finite samples.
fn spread_about<T: Real, S: Sample>(samples: &[S], c: &Vector3<T>) -> T {
    samples
        .iter()
        .filter_map(finite::<T, S>)
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
        let scan = scan::<f64, _>(&samples).unwrap();
        assert_eq!((scan.used, scan.dropped), (24, 4));
        assert!((scan.norm.centre - Vector3::new(100.0, -50.0, 7.0)).amax() < 1e-12);
        assert!((scan.norm.scale - 1.0).abs() < 1e-12);
    }

    #[test]
    fn equal_samples_and_underflowing_spreads_are_told_apart() {
        let equal = [[3.0f32, -2.0, 1.0]; 20];
        assert_eq!(scan::<f32, _>(&equal).unwrap_err(), Error::AllSamplesEqual);
        // Differences whose squares underflow to zero: not equal, but out
        // of range.
        let mut tiny = [[0.0f32; 3]; 20];
        tiny[7][1] = 1e-40;
        assert_eq!(scan::<f32, _>(&tiny).unwrap_err(), Error::OutOfRange);
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
