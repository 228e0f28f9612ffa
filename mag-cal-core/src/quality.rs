//! Quality figures of a calibration, and the warnings a report carries.

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

/// One thing a caller should know about a calibration that was not refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
#[repr(u16)]
pub enum Warning {
    /// Iterated ADC2 stopped at its pass cap before its tolerance: the
    /// geometry is weak (partial coverage); the estimate is the last pass.
    PassCap = 1 << 0,
}

impl Warning {
    /// Every warning.
    pub const ALL: [Warning; 1] = [Warning::PassCap];

    /// Short snake-case name, as used in the CLI's JSON.
    pub const fn name(self) -> &'static str {
        match self {
            Warning::PassCap => "pass_cap",
        }
    }
}

/// A set of [`Warning`]s (a bit set: `Copy`, no allocation).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Warnings(u16);

impl Warnings {
    /// No warning.
    pub const NONE: Warnings = Warnings(0);

    /// Adds `w`.
    pub fn insert(&mut self, w: Warning) {
        self.0 |= w as u16;
    }

    /// Whether `w` is present.
    pub const fn contains(self, w: Warning) -> bool {
        self.0 & (w as u16) != 0
    }

    /// Whether there is none.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// The warnings present, in [`Warning::ALL`] order.
    pub fn iter(self) -> impl Iterator<Item = Warning> {
        Warning::ALL.into_iter().filter(move |w| self.contains(*w))
    }
}
