//! Raw samples: the element types the fit accepts, and a fixed-capacity store.

use crate::Real;

/// One raw three-axis reading, in whatever unit the sensor gives.
///
/// Implemented for `[f32; 3]`, `[f64; 3]`, `[i16; 3]` (the native output of
/// most magnetometers: 6 bytes a sample) and `[i32; 3]`, and for the tuples
/// of the same types (`(i16, i16, i16)`, ...). Conversion to the
/// working precision happens per sample inside each pass, so a store of `i16`
/// never needs a floating-point copy. `PartialEq` compares raw rows: the
/// repetition rule ([`crate::Rule::Repeated`]) drops a row equal to the one
/// before.
pub trait Sample: Copy + PartialEq {
    /// The three components in the working precision. A value that does not
    /// fit the working precision (an `f64` of `1e300` read as `f32`) becomes
    /// non-finite and the sample is then skipped and counted as dropped.
    fn xyz<T: Real>(&self) -> [T; 3];

    /// Whether [`Sample::xyz`] is finite for every value of the type, in
    /// both working precisions (true of the integer types). The passes then
    /// skip the per-sample finiteness check. Defaults to `false`: a type that
    /// claims `true` wrongly feeds non-finite values into the sums, and the fit
    /// then ends in [`crate::Error::OutOfRange`] instead of skipping them.
    const ALWAYS_FINITE: bool = false;

    /// Whether a component sits on a rail of the integer type (`i16`:
    /// `32767`, `-32767` or `-32768`): the reading saturated, or a bus
    /// error filled the register. Such rows are dropped before any fit
    /// (when outlier handling is on, [`crate::Config::robust`]). Defaults to
    /// `false`: floating-point samples have no rails.
    #[inline(always)]
    fn on_rails(&self) -> bool {
        false
    }

    /// Whether the row is exactly `(0, 0, 0)` (a failed bus read). The
    /// default converts to `f32`; the provided types compare their own
    /// values (integer compares on a Cortex-M4F).
    #[inline(always)]
    fn is_zero(&self) -> bool {
        self.xyz::<f32>() == [0.0; 3]
    }
}

// The conversions are written out per component: `<[_; 3]>::map` compiles
// to a loop through the stack at opt-level "s", in every per-sample pass.

/// `[f32; 3]` and `[f64; 3]` (generic, so code generic over [`Real`] can
/// pass its own arrays).
impl<R: Real> Sample for [R; 3] {
    #[inline]
    fn xyz<T: Real>(&self) -> [T; 3] {
        let [x, y, z] = *self;
        [x.cast(), y.cast(), z.cast()]
    }
    #[inline(always)]
    fn is_zero(&self) -> bool {
        let zero = R::zero();
        self[0] == zero && self[1] == zero && self[2] == zero
    }
}

impl Sample for [i16; 3] {
    #[inline]
    fn xyz<T: Real>(&self) -> [T; 3] {
        let f = |v: i16| T::from_single(f32::from(v));
        [f(self[0]), f(self[1]), f(self[2])]
    }
    const ALWAYS_FINITE: bool = true;
    #[inline(always)]
    fn on_rails(&self) -> bool {
        // v >= 32767 or v <= -32767, in one unsigned compare a component.
        let rail = |v: i16| (i32::from(v) + 32766) as u32 >= 65533;
        rail(self[0]) | rail(self[1]) | rail(self[2])
    }
    #[inline(always)]
    fn is_zero(&self) -> bool {
        self[0] | self[1] | self[2] == 0
    }
}

impl Sample for [i32; 3] {
    /// Exact up to `2^24` in `f32`; larger counts round to nearest.
    #[inline]
    fn xyz<T: Real>(&self) -> [T; 3] {
        let f = |v: i32| T::lit(f64::from(v));
        [f(self[0]), f(self[1]), f(self[2])]
    }
    /// `|v| < 2^31`, far inside the `f32` range.
    const ALWAYS_FINITE: bool = true;
    /// `i32::MAX`, `-i32::MAX` or `i32::MIN`.
    #[inline(always)]
    fn on_rails(&self) -> bool {
        // v >= MAX or v <= -MAX, in one unsigned compare a component.
        let rail =
            |v: i32| (i64::from(v) + i64::from(i32::MAX - 1)) as u64 >= 2 * i32::MAX as u64 - 1;
        rail(self[0]) | rail(self[1]) | rail(self[2])
    }
    #[inline(always)]
    fn is_zero(&self) -> bool {
        self[0] | self[1] | self[2] == 0
    }
}

/// Tuples, as drivers return readings (e.g. the `lsm303agr` crate's
/// `MagneticField::xyz_unscaled()`, `(i16, i16, i16)`): the same as the
/// array of the three components.
macro_rules! tuple_sample {
    ($(<$($g:ident: $b:ident)?> $t:ty),*) => {$(
        impl<$($g: $b)?> Sample for ($t, $t, $t) {
            #[inline]
            fn xyz<T: Real>(&self) -> [T; 3] {
                [self.0, self.1, self.2].xyz()
            }
            const ALWAYS_FINITE: bool = <[$t; 3] as Sample>::ALWAYS_FINITE;
            #[inline(always)]
            fn on_rails(&self) -> bool {
                [self.0, self.1, self.2].on_rails()
            }
            #[inline(always)]
            fn is_zero(&self) -> bool {
                [self.0, self.1, self.2].is_zero()
            }
        }
    )*};
}

tuple_sample!(<R: Real> R, <> i16, <> i32);

/// `nalgebra` vectors of the same types (feature `nalgebra`).
#[cfg(feature = "nalgebra")]
macro_rules! vector_sample {
    ($(<$($g:ident: $b:ident)?> $t:ty),*) => {$(
        impl<$($g: $b)?> Sample for nalgebra::Vector3<$t> {
            #[inline]
            fn xyz<T: Real>(&self) -> [T; 3] {
                [self.x, self.y, self.z].xyz()
            }
            const ALWAYS_FINITE: bool = <[$t; 3] as Sample>::ALWAYS_FINITE;
            #[inline(always)]
            fn on_rails(&self) -> bool {
                [self.x, self.y, self.z].on_rails()
            }
            #[inline(always)]
            fn is_zero(&self) -> bool {
                [self.x, self.y, self.z].is_zero()
            }
        }
    )*};
}

#[cfg(feature = "nalgebra")]
vector_sample!(<R: Real> R, <> i16, <> i32);

/// A fixed-capacity store for firmware that collects samples one at a time.
///
/// Capacity is the const generic `N`; the memory is `N * size_of::<S>()`
/// bytes inline, no heap. A full store hands a further sample back
/// instead of panicking.
///
/// ```
/// use mag_cal_core::SampleStore;
/// let mut store: SampleStore<[i16; 3], 2> = SampleStore::new();
/// store.push([1, 2, 3]).unwrap();
/// store.push([4, 5, 6]).unwrap();
/// assert!(store.is_full());
/// assert_eq!(store.push([7, 8, 9]), Err([7, 8, 9]));
/// assert_eq!(store.as_slice().len(), 2);
/// ```
#[derive(Clone, Debug, Default)]
pub struct SampleStore<S, const N: usize> {
    samples: heapless::Vec<S, N>,
}

impl<S: Sample, const N: usize> SampleStore<S, N> {
    /// An empty store.
    pub const fn new() -> Self {
        Self {
            samples: heapless::Vec::new(),
        }
    }

    /// Appends one sample; a full store hands it back (`Err(sample)`, as
    /// `heapless::Vec::push` does).
    pub fn push(&mut self, sample: S) -> Result<(), S> {
        self.samples.push(sample)
    }

    /// The stored samples, oldest first: what [`crate::calibrate`] takes.
    pub fn as_slice(&self) -> &[S] {
        &self.samples
    }

    /// Number of stored samples.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether the store holds no sample.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Whether the store is at capacity.
    pub fn is_full(&self) -> bool {
        self.samples.is_full()
    }

    /// The capacity `N`.
    pub const fn capacity(&self) -> usize {
        N
    }

    /// Removes every sample.
    pub fn clear(&mut self) {
        self.samples.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The integer types' claim: every value converts to finite components.
    #[test]
    fn integer_samples_are_always_finite() {
        for v in [i16::MIN, i16::MAX] {
            assert!([v; 3].xyz::<f32>().iter().all(|c| c.is_finite()));
        }
        for v in [i32::MIN, i32::MAX] {
            assert!([v; 3].xyz::<f32>().iter().all(|c| c.is_finite()));
        }
        const { assert!(<[i16; 3]>::ALWAYS_FINITE && <[i32; 3]>::ALWAYS_FINITE) };
        const { assert!(!<[f32; 3]>::ALWAYS_FINITE && !<[f64; 3]>::ALWAYS_FINITE) };
    }
}
