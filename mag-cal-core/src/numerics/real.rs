//! The scalar type: `f32` or `f64`, through one generic code path.

use nalgebra::RealField;

mod sealed {
    /// The linear algebra the core computes with internally: not part of
    /// the public API (a release of that library is not a release of this
    /// one).
    pub trait Sealed: super::RealField + Copy {}
    impl Sealed for f32 {}
    impl Sealed for f64 {}
}

/// A floating-point scalar the calibration can run in: `f32` or `f64`.
///
/// Sealed: the numerics (tolerances, range checks) are tuned for these two.
pub trait Real:
    Copy
    + PartialOrd
    + core::fmt::Debug
    + core::fmt::Display
    + core::ops::Add<Output = Self>
    + core::ops::Sub<Output = Self>
    + core::ops::Mul<Output = Self>
    + core::ops::Div<Output = Self>
    + core::ops::Neg<Output = Self>
    + sealed::Sealed
{
    /// Machine epsilon of the type.
    const EPSILON: Self;
    /// Smallest positive normal number of the type.
    const MIN_POSITIVE: Self;
    /// Largest finite number of the type.
    const MAX: Self;
    /// Zero, as a constant (for [`crate::Dwell::NONE`]).
    #[doc(hidden)]
    const ZERO: Self;
    /// No still period ([`crate::Dwell::NONE`]), for the gates that
    /// reference one: a constant per type, as a generic one cannot be
    /// borrowed for `'static`.
    #[doc(hidden)]
    const NO_DWELL: &'static crate::Dwell<Self>;
    /// Converts a constant, rounding to the nearest representable value.
    fn lit(x: f64) -> Self;
    /// Converts a value computed at run time (a [`crate::Config`] field),
    /// rounding to the nearest representable value as `lit` does, without
    /// the soft-float conversion routine on targets without a
    /// double-precision FPU (`__aeabi_d2f`, 310 bytes on a Cortex-M4F).
    #[doc(hidden)]
    fn from_double(x: f64) -> Self;
    /// Widens (or keeps) the value as `f64`, for reporting.
    fn to_f64(self) -> f64;
    /// Converts a count, exactly up to `2^24` (`f32`) or `2^53` (`f64`).
    fn from_count(n: usize) -> Self;
    /// A count back from the type (truncated; negative values and NaN give
    /// 0, values beyond `usize::MAX` saturate), without an `f64` detour
    /// (soft-float on a Cortex-M4F).
    fn to_count(self) -> usize;
    /// Converts an `f32` (exact for both types).
    fn from_single(x: f32) -> Self;
    /// Rounds to `f32` (the identity for `f32`; out-of-range `f64` values
    /// become infinite), for histogram bins.
    fn to_single(self) -> f32;
    /// The value in the other (or the same) precision: exact from `f32`,
    /// rounded to nearest from `f64` to `f32` (out-of-range values become
    /// infinite). From `f32` to `f32` it is the identity, with no `f64`
    /// detour (soft-float on a Cortex-M4F).
    fn cast<U: Real>(self) -> U;
    /// `1 / sqrt(x)` for a positive normal `x`, to the type's precision.
    ///
    /// `f32` on a hard-float ARM target (Cortex-M4F and up): the FPU's
    /// `VSQRT` and a division (correctly rounded twice). Other `f32`
    /// targets: the classic bit-level initial guess (`to_bits`, safe)
    /// refined by three Newton steps (relative error below 3e-7, 2.5 ulp),
    /// because `no_std` has only a software square root (`libm::sqrtf`,
    /// about 90 instructions on a Cortex-M4F, plus a division). `f64`:
    /// `1 / libm::sqrt(x)`. The result for zero, negative, subnormal or
    /// non-finite `x` is unspecified (but never a panic): callers check.
    fn rsqrt(self) -> Self;
    /// The square root, correctly rounded (IEEE 754): nalgebra's
    /// `ComplexField::sqrt`, except for `f32` on a hard-float ARM target
    /// (Cortex-M4F and up), which takes the FPU's `VSQRT`. Both round
    /// correctly, so the results are the same; in `no_std` the former is
    /// libm's software `sqrtf` (about 90 instructions a call on a
    /// Cortex-M4F, and 480 bytes of flash with its table).
    fn square_root(self) -> Self;
    /// The cube root of a positive normal `x` (`f32`: relative error below
    /// 2.5e-7, 2 ulp).
    ///
    /// `f32`: a bit-level initial guess refined by Newton steps in `f32`
    /// (libm's `cbrtf` computes in `f64`, which on a Cortex-M4F pulls in
    /// about 3 KB of soft-float routines). `f64`: `libm::cbrt`. The result
    /// for zero, negative, subnormal or non-finite `x` is unspecified (but
    /// never a panic): callers check.
    fn positive_cbrt(self) -> Self;
}

impl Real for f32 {
    const EPSILON: Self = f32::EPSILON;
    const MIN_POSITIVE: Self = f32::MIN_POSITIVE;
    const MAX: Self = f32::MAX;
    const ZERO: Self = 0.0;
    const NO_DWELL: &'static crate::Dwell<Self> = &crate::Dwell::NONE;
    #[inline]
    fn lit(x: f64) -> Self {
        x as f32
    }
    #[inline]
    fn from_double(x: f64) -> Self {
        narrow(x)
    }
    #[inline]
    fn to_f64(self) -> f64 {
        self as f64
    }
    #[inline]
    fn from_count(n: usize) -> Self {
        n as f32
    }
    #[inline]
    fn to_count(self) -> usize {
        self as usize
    }
    #[inline]
    fn from_single(x: f32) -> Self {
        x
    }
    #[inline(always)]
    fn cast<U: Real>(self) -> U {
        U::from_single(self)
    }
    #[inline]
    fn to_single(self) -> f32 {
        self
    }
    #[inline]
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    fn rsqrt(self) -> Self {
        1.0 / vsqrt(self)
    }
    #[inline]
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
    fn rsqrt(self) -> Self {
        let half = 0.5 * self;
        let mut y = f32::from_bits(0x5f37_59df_u32.wrapping_sub(self.to_bits() >> 1));
        // Newton: y <- y (3/2 - x/2 y^2). Relative errors 3.4e-2 -> 1.8e-3
        // -> 4.7e-6 -> rounding.
        y *= 1.5 - half * y * y;
        y *= 1.5 - half * y * y;
        y *= 1.5 - half * y * y;
        y
    }
    #[inline]
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    fn square_root(self) -> Self {
        vsqrt(self)
    }
    #[inline]
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
    fn square_root(self) -> Self {
        nalgebra::ComplexField::sqrt(self)
    }
    #[inline]
    fn positive_cbrt(self) -> Self {
        // Exponent divided by 3 in the bits (relative error below 4 %),
        // then Newton on y^3 = x: 4e-2 -> 2e-3 -> 4e-6 -> rounding.
        let mut y = f32::from_bits(0x2a51_4067_u32.wrapping_add(self.to_bits() / 3));
        for _ in 0..4 {
            y -= (y - self / (y * y)) * (1.0 / 3.0);
        }
        y
    }
}

impl Real for f64 {
    const EPSILON: Self = f64::EPSILON;
    const MIN_POSITIVE: Self = f64::MIN_POSITIVE;
    const MAX: Self = f64::MAX;
    const ZERO: Self = 0.0;
    const NO_DWELL: &'static crate::Dwell<Self> = &crate::Dwell::NONE;
    #[inline]
    fn lit(x: f64) -> Self {
        x
    }
    #[inline]
    fn from_double(x: f64) -> Self {
        x
    }
    #[inline]
    fn to_f64(self) -> f64 {
        self
    }
    #[inline]
    fn from_count(n: usize) -> Self {
        n as f64
    }
    #[inline]
    fn to_count(self) -> usize {
        self as usize
    }
    #[inline]
    fn from_single(x: f32) -> Self {
        x as f64
    }
    #[inline(always)]
    fn cast<U: Real>(self) -> U {
        U::lit(self)
    }
    #[inline]
    fn to_single(self) -> f32 {
        self as f32
    }
    #[inline]
    fn rsqrt(self) -> Self {
        1.0 / libm::sqrt(self)
    }
    #[inline]
    fn square_root(self) -> Self {
        nalgebra::ComplexField::sqrt(self)
    }
    #[inline]
    fn positive_cbrt(self) -> Self {
        libm::cbrt(self)
    }
}

/// `x as f32` in integer operations: round to nearest, ties to even;
/// beyond the range infinity, below it a subnormal or zero; NaN stays NaN.
/// The `as` conversion is a call to the soft-float routine on a
/// Cortex-M4F (single-precision FPU, `__aeabi_d2f`, 310 bytes of flash);
/// this is 170 (LS9 + ADC2 flash 41 808 -> 41 648 bytes, `bench.sh
/// footprint`). Called only with [`crate::Config`] fields, once a fit.
#[inline(never)]
fn narrow(x: f64) -> f32 {
    // In 32-bit halves: 64-bit shifts cost several instructions each on
    // a Cortex-M.
    let b = x.to_bits();
    let (hi, lo) = ((b >> 32) as u32, b as u32);
    let sign = hi & 0x8000_0000;
    let exp = (hi >> 20) & 0x7ff;
    let top = hi & 0x000f_ffff;
    let magnitude = if exp == 0x7ff {
        // Infinity, or a quiet NaN with the top of the payload.
        let payload = top << 3 | lo >> 29;
        0x7f80_0000
            | if top | lo == 0 {
                0
            } else {
                0x0040_0000 | payload
            }
    } else if exp >= 1023 + 128 {
        // 2^128 and beyond.
        0x7f80_0000
    } else if exp < 1023 - 150 {
        // Below 2^-150, half the least subnormal: zero.
        0
    } else {
        // The leading bit and 23 more, and the 29 bits below them
        // (left-aligned: their top bit is the half).
        let sig = 1 << 23 | top << 3 | lo >> 29;
        let rest = lo << 3;
        // The f32 biased exponent, when normal.
        let e = exp as i32 - (1023 - 127);
        let (kept, rest, base) = if e > 0 {
            // The exponent field below the leading bit, which adds one.
            (sig, rest, ((e - 1) as u32) << 23)
        } else {
            // Subnormal: `1 - e` (1 to 24) more bits dropped; below them
            // only whether any bit is set matters.
            let shift = (1 - e) as u32;
            (sig >> shift, sig << (32 - shift) | u32::from(rest != 0), 0)
        };
        let up = rest > 0x8000_0000 || (rest == 0x8000_0000 && kept & 1 == 1);
        // A carry out of the significand moves to the next binade, and
        // from the largest finite value to infinity.
        base + kept + u32::from(up)
    };
    f32::from_bits(sign | magnitude)
}

/// The FPU's square root (`VSQRT.F32`, one instruction, 14 cycles on a
/// Cortex-M4F), which stable `no_std` Rust cannot name otherwise
/// (`f32::sqrt` needs `std`; `libm::sqrtf` is the software routine).
///
/// The one `unsafe` block of the crate, allowed here for a measured
/// reason: the Newton `rsqrt` it replaces costs 20 instructions a call,
/// and the per-sample passes call it once a row (LS9 + ADC2 on 1000 clean
/// samples: 425 080 -> 399 160 instructions under `cargo xtask bench`;
/// in cycles, by the Cortex-M4 manual's figures, 14 for `VSQRT` against
/// about 30 for the dependent Newton steps: an estimate, not measured).
/// [`Real::square_root`] takes it too: with it, libm's `sqrtf` is not
/// linked (LS9 + ADC2 flash 42 616 -> 42 200 bytes, `bench.sh
/// footprint`).
#[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
#[allow(unsafe_code)]
#[inline(always)]
fn vsqrt(x: f32) -> f32 {
    let r: u32;
    // SAFETY: FPU instructions on registers only (no memory, no stack, no
    // flags); every hard-float ARM FPU (VFPv2 and later) has VSQRT. The
    // value passes through core registers because stable Rust accepts the
    // FPU register classes in `asm!` only with the `vfp2` target feature
    // named, which the thumbv7em targets do not do; s15 is declared
    // clobbered.
    unsafe {
        core::arch::asm!(
            "vmov s15, {x}",
            "vsqrt.f32 s15, s15",
            "vmov {r}, s15",
            x = in(reg) x.to_bits(),
            r = lateout(reg) r,
            out("s15") _,
            options(pure, nomem, nostack, preserves_flags)
        );
    }
    f32::from_bits(r)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rsqrt_f32_is_accurate_over_the_normal_range() {
        let mut worst = 0.0f64;
        let mut x = f32::MIN_POSITIVE;
        while x < 1e30 {
            let got = f64::from(x.rsqrt());
            let want = 1.0 / f64::from(x).sqrt();
            worst = worst.max((got / want - 1.0).abs());
            x *= 1.37;
        }
        assert!(worst < 3e-7, "{worst}");
    }

    /// Bit for bit `as f32`, on the edges of every range and on random
    /// bit patterns (NaN only as NaN).
    #[test]
    fn narrow_is_as_f32() {
        let check = |x: f64| {
            let (got, want) = (narrow(x), x as f32);
            if want.is_nan() {
                assert!(got.is_nan(), "{x:e}");
            } else {
                assert_eq!(got.to_bits(), want.to_bits(), "{x:e} ({:#x})", x.to_bits());
            }
        };
        let least = f64::from(f32::from_bits(1));
        let edges = [
            0.0,
            1.0,
            1.5,
            f64::from(f32::MAX),
            f64::from(f32::MAX) * (1.0 + f64::EPSILON),
            f64::from(f32::MIN_POSITIVE),
            least,
            least / 2.0,
            least / 2.0 * (1.0 + f64::EPSILON),
            least / 2.0 * (1.0 - f64::EPSILON / 2.0),
            least * 1.5,
            least * 2.5,
            f64::MIN_POSITIVE,
            f64::from_bits(1),
            f64::MAX,
            f64::INFINITY,
            f64::NAN,
            2f64.powi(128),
            2f64.powi(128) * (1.0 - f64::EPSILON / 2.0),
            2f64.powi(-126) * (1.0 - f64::EPSILON / 2.0),
        ];
        for x in edges {
            for y in [x, -x] {
                check(y);
                // Neighbours: ties, and one ulp either side.
                for d in [1u64, 2, 1 << 28, (1 << 29) - 1, 1 << 29, (1 << 29) + 1] {
                    check(f64::from_bits(y.to_bits().wrapping_add(d)));
                    check(f64::from_bits(y.to_bits().wrapping_sub(d)));
                }
            }
        }
        // Every f32 exactly, and the midpoints between neighbours (ties).
        let mut bits = 0u32;
        while bits < 0x7f80_0000 {
            let a = f64::from(f32::from_bits(bits));
            let b = f64::from(f32::from_bits(bits + 1));
            check(a);
            check(-a);
            check((a + b) / 2.0);
            check(-(a + b) / 2.0);
            bits += 4099;
        }
        // Random bit patterns, and random significands with an exponent
        // in or near the f32 range (xorshift64*).
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..1_000_000 {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            let r = state.wrapping_mul(0x2545_f491_4f6c_dd1d);
            check(f64::from_bits(r));
            let exp = 1023 - 160 + (r >> 52) % 300;
            check(f64::from_bits((r & 0x800f_ffff_ffff_ffff) | exp << 52));
        }
    }

    #[test]
    fn positive_cbrt_f32_is_accurate_over_the_normal_range() {
        let mut worst = 0.0f64;
        let mut x = f32::MIN_POSITIVE;
        while x < f32::MAX / 1.37 {
            let got = f64::from(x.positive_cbrt());
            let want = f64::from(x).cbrt();
            worst = worst.max((got / want - 1.0).abs());
            x *= 1.37;
        }
        assert!(worst < 2.5e-7, "{worst}");
        assert_eq!(8.0f32.positive_cbrt(), 2.0);
        assert_eq!(8.0f64.positive_cbrt(), 2.0);
    }
}
