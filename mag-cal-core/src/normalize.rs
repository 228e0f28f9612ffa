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
    let mut origin: Option<[T; 3]> = None;
    let mut sum = [zero; 3];
    let mut sum_sq = zero;
    let mut any_different = false;
    let mut used = 0usize;
    for sample in samples {
        let Some(y) = finite::<T, S>(sample) else {
            continue;
        };
        let o = *origin.get_or_insert(y);
        let d = [y[0] - o[0], y[1] - o[1], y[2] - o[2]];
        any_different |= d != [zero; 3];
        sum[0] += d[0];
        sum[1] += d[1];
        sum[2] += d[2];
        sum_sq += d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        used += 1;
    }
    let dropped = samples.len() - used;
    let Some(o) = origin.filter(|_| used >= MIN_SAMPLES) else {
        return Err(Error::TooFewSamples {
            found: used,
            required: MIN_SAMPLES,
        });
    };
    if !any_different {
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

/// The per-sample map of the passes that follow a fit: a raw sample to its
/// centred vector `d = (y - c)/s - b'` and calibrated vector `u = W' d`, on
/// scalars (generic small-matrix operations in a per-sample loop cost about
/// ten times as much on a Cortex-M4F).
#[derive(Clone, Copy)]
pub(crate) struct Projector<T: Real> {
    c: [T; 3],
    inv_scale: T,
    b: [T; 3],
    /// `W'` row-major.
    w: [T; 9],
}

impl<T: Real> Projector<T> {
    /// For the fit `(b', W')` in the coordinates of `norm`.
    pub(crate) fn new(
        norm: &Normalization<T>,
        centre: &Vector3<T>,
        w: &nalgebra::Matrix3<T>,
    ) -> Self {
        Self {
            c: [norm.centre.x, norm.centre.y, norm.centre.z],
            inv_scale: norm.inv_scale,
            b: [centre.x, centre.y, centre.z],
            w: [
                w[(0, 0)],
                w[(0, 1)],
                w[(0, 2)],
                w[(1, 0)],
                w[(1, 1)],
                w[(1, 2)],
                w[(2, 0)],
                w[(2, 1)],
                w[(2, 2)],
            ],
        }
    }

    /// `(d, u)` for a finite raw sample `y`.
    #[inline(always)]
    pub(crate) fn project(&self, y: [T; 3]) -> ([T; 3], [T; 3]) {
        let [c0, c1, c2] = self.c;
        let [b0, b1, b2] = self.b;
        let [w00, w01, w02, w10, w11, w12, w20, w21, w22] = self.w;
        let is = self.inv_scale;
        let d = [
            (y[0] - c0) * is - b0,
            (y[1] - c1) * is - b1,
            (y[2] - c2) * is - b2,
        ];
        let u = [
            w00 * d[0] + w01 * d[1] + w02 * d[2],
            w10 * d[0] + w11 * d[1] + w12 * d[2],
            w20 * d[0] + w21 * d[1] + w22 * d[2],
        ];
        (d, u)
    }
}
