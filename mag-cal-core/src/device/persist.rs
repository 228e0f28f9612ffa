//! Storing a calibration as bytes: magic, version, parameters, CRC.
//!
//! A calibration is [`ENCODED_LEN`] = 92 bytes, for flash or EEPROM:
//!
//! | offset | bytes | field |
//! |---|---|---|
//! | 0 | 4 | [`MAGIC`], `"MCAL"` |
//! | 4 | 1 | [`VERSION`], 1 |
//! | 5 | 1 | precision of the writer: [`PRECISION_F32`] (4) or [`PRECISION_F64`] (8) |
//! | 6 | 2 | reserved, 0 |
//! | 8 | 24 | hard iron `b`: 3 x `f64` |
//! | 32 | 48 | soft iron `W` (symmetric): `W11 W12 W13 W22 W23 W33`, 6 x `f64` |
//! | 80 | 8 | field strength `rho`: `f64` (redundant, checked on load) |
//! | 88 | 4 | CRC-32 of bytes 0..88: `u32` |
//!
//! All numbers are little-endian. The values are always stored as `f64`,
//! whatever the precision `T` of the calibration: an `f32` value widens to
//! `f64` exactly, so an `f32` calibration survives a round trip bit for bit
//! in its values, and calibrations move between `f32` and `f64` builds (a
//! host tool in `f64`, firmware in `f32`) in both directions. Twelve extra
//! bytes per calibration buy that. The precision byte records what the
//! writer computed in, which bounds the rounding error of the stored field
//! strength (below); it does not change the encoding.
//!
//! The CRC is CRC-32/ISO-HDLC (the one of Ethernet, zip and PNG: polynomial
//! `0x04C11DB7` reflected, `0xEDB88320`; initial value and final XOR
//! `0xFFFFFFFF`), see [`crc32`]. It detects every error of up to 32
//! consecutive bits, hence every single-bit flip, and all but one in `2^32`
//! of the others.
//!
//! [`from_bytes`] checks, in order: the length, the magic, the version, the
//! CRC, the precision and reserved bytes, the consistency of the stored
//! field strength with the stored `W` (and that `W` is positive definite),
//! and finally rebuilds the calibration from the stored canonical `W` as it
//! is, validating finiteness and non-singularity in the reader's precision
//! (an `f64` round trip is exact). It fails with this module's own
//! [`Error`], four ways for the bytes and two for the values.
//!
//! ```
//! use mag_cal_core::Calibration;
//! use mag_cal_core::persist::{from_bytes, to_bytes, ENCODED_LEN};
//!
//! let w = [[1.0 / 320.0, 0.0, 0.0], [0.0, 1.0 / 320.0, 0.0], [0.0, 0.0, 1.0 / 320.0]];
//! let cal = Calibration::<f32>::new([180.0, -95.0, 240.0], w)?;
//! let bytes: [u8; ENCODED_LEN] = to_bytes(&cal);
//! // ... written to flash, read back after a reset, maybe by an f64 tool:
//! let back = from_bytes::<f64>(&bytes)?;
//! assert_eq!(back.hard_iron(), cal.hard_iron().map(f64::from));
//! assert!((back.field_strength() - 320.0).abs() < 1e-3);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use core::fmt;

use nalgebra::{Matrix3, Vector3};

use crate::{Calibration, Real};

/// Why stored bytes do not read back as a calibration ([`from_bytes`]).
///
/// Small and `Copy`, as the fit's [`crate::Error`], of which it shares
/// none of the refusals: a record is damaged or foreign, or its values do
/// not make a calibration in the reader's precision.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Error {
    /// Fewer than [`ENCODED_LEN`] bytes.
    Truncated,
    /// The bytes do not start with [`MAGIC`] (erased flash, another
    /// record).
    BadMagic,
    /// A format version this build cannot read.
    UnsupportedVersion {
        /// Version found.
        found: u8,
    },
    /// The bytes fail their checksum, or pass it but are not what
    /// [`to_bytes`] writes.
    ChecksumMismatch,
    /// A stored value is not finite in the reader's precision (an `f64`
    /// beyond `f32`'s range read as `f32`).
    OutOfRange,
    /// The stored soft iron `W` is singular in the reader's precision.
    Singular,
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Error::Truncated => f.write_str("stored calibration is truncated"),
            Error::BadMagic => f.write_str("stored bytes are not a calibration (bad magic)"),
            Error::UnsupportedVersion { found } => {
                write!(
                    f,
                    "stored calibration has unsupported format version {found}"
                )
            }
            Error::ChecksumMismatch => f.write_str("stored calibration fails its checksum"),
            Error::OutOfRange => f.write_str(
                "stored calibration has a value beyond the range of the reader's precision",
            ),
            Error::Singular => {
                f.write_str("stored calibration's soft iron is singular in the reader's precision")
            }
        }
    }
}

impl core::error::Error for Error {}

/// The first four bytes of a stored calibration.
pub const MAGIC: [u8; 4] = *b"MCAL";

/// The format version this build writes and reads.
pub const VERSION: u8 = 1;

/// Precision byte of a calibration computed in `f32`.
pub const PRECISION_F32: u8 = 4;

/// Precision byte of a calibration computed in `f64`.
pub const PRECISION_F64: u8 = 8;

/// Length of a stored calibration, bytes: a 8-byte header, 10 `f64` and the
/// CRC.
pub const ENCODED_LEN: usize = HEADER_LEN + VALUES * 8 + 4;

/// Magic, version, precision, reserved.
const HEADER_LEN: usize = 8;

/// `b` (3), `W` (6), `rho` (1).
const VALUES: usize = 10;

/// Relative tolerance of the stored field strength against
/// `det(W)^(-1/3)`, on top of the writer's rounding error.
const RHO_TOLERANCE: f64 = 1e-6;

/// The reflected CRC-32 polynomial.
const POLY: u32 = 0xEDB8_8320;

/// CRC-32/ISO-HDLC (reflected polynomial `0xEDB88320`, initial value and
/// final XOR `0xFFFFFFFF`): the CRC of zip, PNG and Ethernet.
///
/// Bitwise, table-free: eight shift-and-conditional-XOR steps per byte (the
/// `92` bytes of a calibration take about 750 steps), no 1 kB table in
/// flash.
///
/// ```
/// use mag_cal_core::persist::crc32;
/// assert_eq!(crc32(b"123456789"), 0xCBF4_3926); // the standard check value
/// assert_eq!(crc32(b""), 0);
/// ```
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = u32::MAX;
    for &byte in bytes {
        crc ^= u32::from(byte);
        for _ in 0..8 {
            // All ones when the low bit is set, else zero: no branch.
            let mask = (crc & 1).wrapping_neg();
            crc = (crc >> 1) ^ (POLY & mask);
        }
    }
    !crc
}

/// The precision byte of `T`.
fn precision_of<T: Real>() -> u8 {
    if T::EPSILON.to_f64() > f64::from(f32::EPSILON) / 2.0 {
        PRECISION_F32
    } else {
        PRECISION_F64
    }
}

/// Encodes a calibration: see the [module documentation](self) for the
/// layout.
///
/// ```
/// use mag_cal_core::Calibration;
/// use mag_cal_core::persist::{crc32, to_bytes, ENCODED_LEN, MAGIC};
///
/// let half = [[0.5, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 0.5]];
/// let cal = Calibration::<f64>::new([1.0, 2.0, 3.0], half)?;
/// let bytes = to_bytes(&cal);
/// assert_eq!(bytes[..4], MAGIC);
/// assert_eq!(bytes[4], 1);
/// let crc = u32::from_le_bytes([bytes[88], bytes[89], bytes[90], bytes[91]]);
/// assert_eq!(crc, crc32(&bytes[..ENCODED_LEN - 4]));
/// # Ok::<(), mag_cal_core::Error>(())
/// ```
pub fn to_bytes<T: Real>(cal: &Calibration<T>) -> [u8; ENCODED_LEN] {
    let b = cal.b();
    let w = cal.w();
    let values: [T; VALUES] = [
        b.x,
        b.y,
        b.z,
        w.m11,
        w.m12,
        w.m13,
        w.m22,
        w.m23,
        w.m33,
        cal.field_strength(),
    ];
    let header = [
        MAGIC[0],
        MAGIC[1],
        MAGIC[2],
        MAGIC[3],
        VERSION,
        precision_of::<T>(),
        0,
        0,
    ];
    let body = header
        .into_iter()
        .chain(values.into_iter().flat_map(|v| v.to_f64().to_le_bytes()));
    let mut out = [0u8; ENCODED_LEN];
    for (o, byte) in out.iter_mut().zip(body) {
        *o = byte;
    }
    let crc = out
        .split_last_chunk::<4>()
        .map_or(0, |(covered, _)| crc32(covered));
    if let Some((_, tail)) = out.split_last_chunk_mut::<4>() {
        *tail = crc.to_le_bytes();
    }
    out
}

/// Reads fixed-size fields off the front of a byte slice.
struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    fn take<const K: usize>(&mut self) -> Result<[u8; K], Error> {
        let (head, rest) = self.0.split_first_chunk::<K>().ok_or(Error::Truncated)?;
        self.0 = rest;
        Ok(*head)
    }

    fn f64(&mut self) -> Result<f64, Error> {
        self.take::<8>().map(f64::from_le_bytes)
    }
}

/// Decodes a calibration written by [`to_bytes`], in precision `T` (either
/// precision reads what either wrote).
///
/// Only the first [`ENCODED_LEN`] bytes are read: a longer slice (a whole
/// flash page, say) is accepted and the rest ignored.
///
/// # Errors
/// In the order checked:
/// - [`Error::Truncated`]: fewer than [`ENCODED_LEN`] bytes;
/// - [`Error::BadMagic`]: the first four bytes are not [`MAGIC`] (erased
///   flash, another record);
/// - [`Error::UnsupportedVersion`]: the version byte is not [`VERSION`];
/// - [`Error::ChecksumMismatch`]: the CRC does not match; or the bytes pass
///   the CRC but are not what [`to_bytes`] writes: an unknown precision
///   byte, non-zero reserved bytes, or a stored field strength that differs
///   from `det(W)^(-1/3)` (computed in `f64` from the stored `W`) by more
///   than `1e-6` relative plus the rounding error of the writer's
///   precision, or a `W` that is not positive definite;
/// - in the reader's precision: [`Error::OutOfRange`] when a value is not
///   finite in `T` (an `f64` beyond `f32`'s range read as `f32` becomes
///   infinite, never a panic), [`Error::Singular`] when `W` is singular in
///   `T`.
///
/// ```
/// use mag_cal_core::Calibration;
/// use mag_cal_core::persist::{from_bytes, to_bytes, Error};
///
/// let half = [[0.5, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 0.5]];
/// let cal = Calibration::<f32>::new([1.0, 2.0, 3.0], half)?;
/// let mut bytes = to_bytes(&cal);
/// assert_eq!(from_bytes::<f32>(&bytes)?, cal);
/// assert_eq!(from_bytes::<f32>(&bytes[..50]), Err(Error::Truncated));
/// bytes[40] ^= 0x10;
/// assert_eq!(from_bytes::<f32>(&bytes), Err(Error::ChecksumMismatch));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn from_bytes<T: Real>(bytes: &[u8]) -> Result<Calibration<T>, Error> {
    let record = bytes.first_chunk::<ENCODED_LEN>().ok_or(Error::Truncated)?;
    let mut r = Reader(record);
    if r.take::<4>()? != MAGIC {
        return Err(Error::BadMagic);
    }
    let [version, precision, reserved_0, reserved_1] = r.take::<4>()?;
    if version != VERSION {
        return Err(Error::UnsupportedVersion { found: version });
    }
    let (covered, stored_crc) = record.split_last_chunk::<4>().ok_or(Error::Truncated)?;
    if crc32(covered) != u32::from_le_bytes(*stored_crc) {
        return Err(Error::ChecksumMismatch);
    }
    // The CRC holds, so these are what the writer wrote; values version 1
    // does not define mean the bytes were not written by `to_bytes`.
    let writer_epsilon = match precision {
        PRECISION_F32 => f64::from(f32::EPSILON),
        PRECISION_F64 => f64::EPSILON,
        _ => return Err(Error::ChecksumMismatch),
    };
    if (reserved_0, reserved_1) != (0, 0) {
        return Err(Error::ChecksumMismatch);
    }
    let mut v = [0.0f64; VALUES];
    for slot in &mut v {
        *slot = r.f64()?;
    }
    let [bx, by, bz, w11, w12, w13, w22, w23, w33, rho] = v;
    check_field_strength([w11, w12, w13, w22, w23, w33], rho, writer_epsilon)?;
    let b = Vector3::new(T::lit(bx), T::lit(by), T::lit(bz));
    let w = Matrix3::new(w11, w12, w13, w12, w22, w23, w13, w23, w33).map(T::lit);
    // W was checked symmetric positive definite above, in f64: it is the
    // canonical form itself, so it is kept as stored (an exact round trip in
    // f64) rather than re-derived from W^T W.
    Calibration::from_canonical(b, w).map_err(|e| match e {
        // The two failures of its checks: a value not finite in `T`, a
        // singular `W`.
        crate::Error::OutOfRange => Error::OutOfRange,
        _ => Error::Singular,
    })
}

/// Checks, in `f64` on the stored values, that the symmetric `W` is
/// positive definite and that `rho = det(W)^(-1/3)`.
///
/// The writer computed `rho` in its own precision (machine epsilon `eps`)
/// from the same `W`; the 3x3 determinant by cofactors has a relative
/// rounding error of at most about `5 eps P / |det|` (`P` the sum of the
/// absolute values of its six products), the cube root and the division
/// add about `2 eps`, and the cube root divides the determinant's error by
/// three. Twice that bound is allowed on top of [`RHO_TOLERANCE`], so no
/// record written by [`to_bytes`] is refused, however ill-conditioned its
/// `W`, and for well-conditioned ones the check is at `1e-6`.
fn check_field_strength(w: [f64; 6], rho: f64, writer_epsilon: f64) -> Result<(), Error> {
    let [w11, w12, w13, w22, w23, w33] = w;
    // Leading principal minors (Sylvester's criterion).
    let minor2 = w11 * w22 - w12 * w12;
    let products = [
        w11 * w22 * w33,
        2.0 * w12 * w23 * w13,
        -w11 * w23 * w23,
        -w22 * w13 * w13,
        -w33 * w12 * w12,
    ];
    let det: f64 = products.iter().sum();
    let p = libm::fabs(w11 * w22 * w33)
        + 2.0 * libm::fabs(w12 * w23 * w13)
        + libm::fabs(w11 * w23 * w23)
        + libm::fabs(w22 * w13 * w13)
        + libm::fabs(w33 * w12 * w12);
    if !(w11 > 0.0) || !(minor2 > 0.0) || !(det > 0.0) || !(rho > 0.0) || !rho.is_finite() {
        return Err(Error::ChecksumMismatch);
    }
    let expected = 1.0 / libm::cbrt(det);
    let rounding = 2.0 * writer_epsilon * (5.0 * p / det / 3.0 + 2.0);
    let tolerance = RHO_TOLERANCE + rounding;
    // `!(x <= y)` also refuses NaN and infinities.
    if !(libm::fabs(expected - rho) <= tolerance * rho) {
        return Err(Error::ChecksumMismatch);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_constants() {
        assert_eq!(ENCODED_LEN, 92);
        assert_eq!(precision_of::<f32>(), PRECISION_F32);
        assert_eq!(precision_of::<f64>(), PRECISION_F64);
    }

    #[test]
    fn crc_check_values() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(&[0]), 0xD202_EF8D);
        assert_eq!(
            crc32(b"The quick brown fox jumps over the lazy dog"),
            0x414F_A339
        );
    }
}
