//! Quality figures of a calibration.

use nalgebra::{Matrix3, Vector3};

use crate::moments::BLOCK;
use crate::normalize::Normalization;
use crate::sample::{finite, Sample};
use crate::Real;

/// RMS of `|W (y - b)| - 1` over the finite samples, computed in the
/// normalised coordinates of the fit (`W (y - b) = W' (x - b')`).
pub(crate) fn radial_rms<T: Real, S: Sample>(
    samples: &[S],
    norm: &Normalization<T>,
    centre: &Vector3<T>,
    w: &Matrix3<T>,
) -> T {
    let one = T::one();
    let mut total = T::zero();
    let mut count = 0usize;
    for block in samples.chunks(BLOCK) {
        let mut acc = T::zero();
        for y in block.iter().filter_map(finite::<T, S>) {
            let u = w * (norm.forward(y) - centre);
            // |u| - 1 = (|u|^2 - 1) / (|u| + 1): no extra cancellation.
            let u2 = u.norm_squared();
            let r = (u2 - one) / (u2.sqrt() + one);
            acc += r * r;
            count += 1;
        }
        total += acc;
    }
    if count == 0 {
        return T::zero();
    }
    (total / T::from_count(count)).sqrt()
}
