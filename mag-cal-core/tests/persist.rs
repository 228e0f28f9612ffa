//! Stored calibrations: round trips, corruption, truncation, hostile bytes.

use mag_cal_core::persist::{
    self, crc32, from_bytes, to_bytes, ENCODED_LEN, MAGIC, PRECISION_F32, PRECISION_F64, VERSION,
};
use mag_cal_core::{calibrate, Calibration, Config, Error};
use nalgebra::{Matrix3, Rotation3, Vector3};

/// A tiny LCG (Knuth's MMIX constants); the high bits are used.
struct Lcg(u64);

impl Lcg {
    fn next_u32(&mut self) -> u32 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 32) as u32
    }

    fn byte(&mut self) -> u8 {
        (self.next_u32() >> 24) as u8
    }

    fn below(&mut self, n: u32) -> usize {
        ((u64::from(self.next_u32()) * u64::from(n)) >> 32) as usize
    }

    fn unit(&mut self) -> f64 {
        f64::from(self.next_u32()) / 4_294_967_296.0
    }
}

/// A calibration with a tilted, anisotropic soft iron.
fn sample_calibration<T: mag_cal_core::Real>() -> Calibration<T> {
    let r = Rotation3::from_euler_angles(0.3, -0.2, 0.5);
    let t = r.matrix() * Matrix3::from_diagonal(&Vector3::new(1.25, 0.85, 1.05)) * 320.0;
    let w = t.try_inverse().unwrap().map(T::lit);
    let b = Vector3::new(180.25, -95.5, 240.125).map(T::lit);
    cal_new(b, w).unwrap()
}

/// `Calibration::new` from nalgebra types (`W` by rows).
fn cal_new<T: mag_cal_core::Real>(b: Vector3<T>, w: Matrix3<T>) -> Result<Calibration<T>, Error> {
    Calibration::new(b.into(), w.transpose().into())
}

/// Recomputes the CRC of a (modified) record.
fn reseal(bytes: &mut [u8; ENCODED_LEN]) {
    let crc = crc32(&bytes[..ENCODED_LEN - 4]);
    bytes[ENCODED_LEN - 4..].copy_from_slice(&crc.to_le_bytes());
}

fn put_f64(bytes: &mut [u8; ENCODED_LEN], index: usize, v: f64) {
    let at = 8 + 8 * index;
    bytes[at..at + 8].copy_from_slice(&v.to_le_bytes());
}

fn get_f64(bytes: &[u8; ENCODED_LEN], index: usize) -> f64 {
    let at = 8 + 8 * index;
    f64::from_le_bytes(bytes[at..at + 8].try_into().unwrap())
}

fn max_rel(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    (a - b).amax() / b.amax()
}

#[test]
fn crc32_standard_check_value() {
    assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    assert_eq!(crc32(b""), 0);
    assert_eq!(crc32(&[0xFF; 4]), 0xFFFF_FFFF);
}

#[test]
fn layout() {
    let cal = sample_calibration::<f64>();
    let bytes = to_bytes(&cal);
    assert_eq!(ENCODED_LEN, 92);
    assert_eq!(bytes[..4], MAGIC);
    assert_eq!(bytes[4], VERSION);
    assert_eq!(bytes[5], PRECISION_F64);
    assert_eq!(bytes[6..8], [0, 0]);
    assert_eq!(get_f64(&bytes, 0), Vector3::from(cal.hard_iron()).x);
    assert_eq!(get_f64(&bytes, 4), Matrix3::from(cal.soft_iron())[(0, 1)]);
    assert_eq!(get_f64(&bytes, 8), Matrix3::from(cal.soft_iron())[(2, 2)]);
    assert_eq!(get_f64(&bytes, 9), cal.field_strength());
    assert_eq!(to_bytes(&sample_calibration::<f32>())[5], PRECISION_F32);
}

#[test]
fn round_trip_f64() {
    let cal = sample_calibration::<f64>();
    let bytes = to_bytes(&cal);
    let back = from_bytes::<f64>(&bytes).unwrap();
    // The stored W is the canonical form itself and is kept as stored, and
    // the field strength is recomputed from it by the same formula: the
    // round trip is exact, and storing again gives the same bytes.
    assert_eq!(back, cal);
    assert_eq!(to_bytes(&back), bytes);
}

#[test]
fn round_trip_f32() {
    let cal = sample_calibration::<f32>();
    let back = from_bytes::<f32>(&to_bytes(&cal)).unwrap();
    assert_eq!(
        Vector3::from(back.hard_iron()),
        Vector3::from(cal.hard_iron())
    );
    let e_w = max_rel(
        &Matrix3::from(back.soft_iron()).cast::<f64>(),
        &Matrix3::from(cal.soft_iron()).cast::<f64>(),
    );
    let e_rho = (f64::from(back.field_strength()) / f64::from(cal.field_strength()) - 1.0).abs();
    println!("f32 round trip: W {e_w:.1e}, rho {e_rho:.1e}");
    assert!(e_w < 1e-6 && e_rho < 1e-6, "{e_w} {e_rho}");
}

#[test]
fn cross_precision() {
    // Written by an f64 host tool, read by f32 firmware.
    let cal64 = sample_calibration::<f64>();
    let cal32 = from_bytes::<f32>(&to_bytes(&cal64)).unwrap();
    assert_eq!(
        Vector3::from(cal32.hard_iron()),
        Vector3::from(cal64.hard_iron()).map(|v| v as f32)
    );
    let e_w = max_rel(
        &Matrix3::from(cal32.soft_iron()).cast::<f64>(),
        &Matrix3::from(cal64.soft_iron()),
    );
    let e_rho = (f64::from(cal32.field_strength()) / cal64.field_strength() - 1.0).abs();
    println!("f64 -> f32: W {e_w:.1e}, rho {e_rho:.1e}");
    assert!(e_w < 1e-6 && e_rho < 1e-6, "{e_w} {e_rho}");
    // And the other way: f32 values widen exactly.
    let cal32 = sample_calibration::<f32>();
    let cal64 = from_bytes::<f64>(&to_bytes(&cal32)).unwrap();
    assert_eq!(
        Vector3::from(cal64.hard_iron()),
        Vector3::from(cal32.hard_iron()).cast::<f64>()
    );
    let e_w = max_rel(
        &Matrix3::from(cal64.soft_iron()),
        &Matrix3::from(cal32.soft_iron()).cast::<f64>(),
    );
    assert!(e_w < 1e-14, "{e_w}");
    // A fitted calibration, as firmware would store it.
    let samples: Vec<[f32; 3]> = (0..300)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / 300.0;
            let r = (1.0 - z * z).sqrt();
            let phi = i as f32 * 2.399_963;
            [
                180.0 + 260.0 * r * phi.cos(),
                -95.0 + 330.0 * r * phi.sin() + 20.0 * z,
                240.0 + 300.0 * z,
            ]
        })
        .collect();
    let fit = calibrate::<f32, _>(&samples, &Config::default()).unwrap();
    let bytes = to_bytes(&fit.calibration);
    let back32 = from_bytes::<f32>(&bytes).unwrap();
    let back64 = from_bytes::<f64>(&bytes).unwrap();
    let u = Vector3::from(fit.calibration.apply(samples[7]));
    assert!((Vector3::from(back32.apply(samples[7])) - u).norm() < 1e-6);
    assert!(
        (Vector3::from(back64.apply(samples[7].map(f64::from))).cast::<f32>() - u).norm() < 1e-6
    );
}

#[test]
fn ill_conditioned_calibrations_round_trip() {
    // No record that to_bytes writes is refused by from_bytes, whatever
    // the conditioning of W: the field strength check allows for the
    // writer's rounding.
    let mut rng = Lcg(42);
    for k in 0..2000 {
        let r = Rotation3::from_euler_angles(rng.unit() * 6.3, rng.unit() * 6.3, rng.unit() * 6.3);
        let log_cond = rng.unit() * if k % 2 == 0 { 3.0 } else { 6.0 };
        let s = Vector3::new(1.0, 10f64.powf(log_cond * rng.unit()), 10f64.powf(log_cond));
        let scale = 10f64.powf(rng.unit() * 8.0 - 4.0);
        let w = r.matrix() * Matrix3::from_diagonal(&s) * r.matrix().transpose() * scale;
        let b = Vector3::new(rng.unit(), rng.unit(), rng.unit()) * 1000.0;
        if k % 2 == 0 {
            let cal = cal_new::<f32>(b.cast(), w.cast()).unwrap();
            let bytes = to_bytes(&cal);
            assert!(from_bytes::<f32>(&bytes).is_ok(), "{k}: {w}");
            assert!(from_bytes::<f64>(&bytes).is_ok(), "{k}: {w}");
        } else {
            let cal = cal_new::<f64>(b, w).unwrap();
            let bytes = to_bytes(&cal);
            assert!(from_bytes::<f64>(&bytes).is_ok(), "{k}: {w}");
        }
    }
}

#[test]
fn every_single_bit_flip_is_detected() {
    for bytes in [
        to_bytes(&sample_calibration::<f64>()),
        to_bytes(&sample_calibration::<f32>()),
    ] {
        let mut counts = [0usize; 3];
        for bit in 0..8 * ENCODED_LEN {
            let mut b = bytes;
            b[bit / 8] ^= 1 << (bit % 8);
            let r32 = from_bytes::<f32>(&b);
            let r64 = from_bytes::<f64>(&b);
            assert_eq!(r32.err(), r64.err(), "bit {bit}");
            match r64 {
                Err(persist::Error::BadMagic) => {
                    assert!(bit < 32);
                    counts[0] += 1;
                }
                Err(persist::Error::UnsupportedVersion { found }) => {
                    assert!((32..40).contains(&bit) && found == VERSION ^ (1 << (bit % 8)));
                    counts[1] += 1;
                }
                Err(persist::Error::ChecksumMismatch) => {
                    assert!(bit >= 40);
                    counts[2] += 1;
                }
                other => panic!("bit {bit}: {other:?}"),
            }
        }
        assert_eq!(counts, [32, 8, 8 * ENCODED_LEN - 40]);
    }
}

#[test]
fn every_truncation_is_detected() {
    let bytes = to_bytes(&sample_calibration::<f32>());
    for len in 0..ENCODED_LEN {
        assert_eq!(
            from_bytes::<f32>(&bytes[..len]),
            Err(persist::Error::Truncated),
            "{len}"
        );
        assert_eq!(
            from_bytes::<f64>(&bytes[..len]),
            Err(persist::Error::Truncated),
            "{len}"
        );
    }
    assert!(from_bytes::<f32>(&bytes).is_ok());
}

#[test]
fn longer_input_reads_the_first_record() {
    let cal = sample_calibration::<f32>();
    let mut page = [0xFFu8; 256]; // an erased flash page around the record
    page[..ENCODED_LEN].copy_from_slice(&to_bytes(&cal));
    assert_eq!(from_bytes::<f32>(&page), from_bytes::<f32>(&to_bytes(&cal)));
    assert!(from_bytes::<f32>(&page).is_ok());
    // Erased flash alone.
    assert_eq!(
        from_bytes::<f32>(&[0xFF; 256]),
        Err(persist::Error::BadMagic)
    );
    assert_eq!(
        from_bytes::<f32>(&[0; ENCODED_LEN]),
        Err(persist::Error::BadMagic)
    );
}

#[test]
fn other_versions_are_refused_even_with_a_valid_crc() {
    let mut bytes = to_bytes(&sample_calibration::<f64>());
    for version in [0u8, 2, 255] {
        bytes[4] = version;
        reseal(&mut bytes);
        assert_eq!(
            from_bytes::<f64>(&bytes),
            Err(persist::Error::UnsupportedVersion { found: version })
        );
    }
}

#[test]
fn inconsistent_records_with_a_valid_crc_are_refused() {
    let good = to_bytes(&sample_calibration::<f64>());
    let check = |edit: &dyn Fn(&mut [u8; ENCODED_LEN]), what: &str| {
        let mut b = good;
        edit(&mut b);
        reseal(&mut b);
        assert_eq!(
            from_bytes::<f64>(&b),
            Err(persist::Error::ChecksumMismatch),
            "{what}"
        );
        assert_eq!(
            from_bytes::<f32>(&b),
            Err(persist::Error::ChecksumMismatch),
            "{what}"
        );
    };
    check(&|b| b[5] = 5, "unknown precision");
    check(&|b| b[6] = 1, "reserved byte");
    check(&|b| b[7] = 0x80, "reserved byte");
    let rho = get_f64(&good, 9);
    check(&|b| put_f64(b, 9, rho * (1.0 + 3e-6)), "rho off by 3e-6");
    check(&|b| put_f64(b, 9, -rho), "negative rho");
    check(&|b| put_f64(b, 9, f64::NAN), "NaN rho");
    check(&|b| put_f64(b, 9, f64::INFINITY), "infinite rho");
    // W = -W_good: |det| and rho unchanged, but not positive definite.
    check(
        &|b| {
            for i in 3..9 {
                let v = get_f64(&good, i);
                put_f64(b, i, -v);
            }
        },
        "negative definite W",
    );
    check(&|b| put_f64(b, 3, f64::NAN), "NaN in W");
    // Within tolerance: rho off by 1e-7 relative is accepted.
    let mut b = good;
    put_f64(&mut b, 9, rho * (1.0 + 1e-7));
    reseal(&mut b);
    assert!(from_bytes::<f64>(&b).is_ok());
}

#[test]
fn values_beyond_f32_range_are_refused_in_f32_only() {
    let cal = cal_new::<f64>(Vector3::new(1e300, 0.0, 0.0), Matrix3::identity() * 1e-3).unwrap();
    let bytes = to_bytes(&cal);
    assert_eq!(from_bytes::<f64>(&bytes), Ok(cal));
    assert_eq!(from_bytes::<f32>(&bytes), Err(persist::Error::OutOfRange));
    // A W so small that it vanishes in f32.
    let cal = cal_new::<f64>(Vector3::zeros(), Matrix3::identity() * 1e-60).unwrap();
    let bytes = to_bytes(&cal);
    assert!(from_bytes::<f64>(&bytes).is_ok());
    assert_eq!(from_bytes::<f32>(&bytes), Err(persist::Error::Singular));
}

/// Every way a record fails has a sentence of its own, on one line.
#[test]
fn every_persist_error_has_its_sentence() {
    use persist::Error as E;
    let all = [
        E::Truncated,
        E::BadMagic,
        E::UnsupportedVersion { found: 7 },
        E::ChecksumMismatch,
        E::OutOfRange,
        E::Singular,
    ];
    let texts: Vec<String> = all.iter().map(ToString::to_string).collect();
    for t in &texts {
        assert!(t.starts_with("stored "), "{t}");
        assert!(t.is_ascii() && !t.contains('\n'), "{t}");
        assert_eq!(texts.iter().filter(|u| *u == t).count(), 1, "{t}");
    }
    assert!(texts[2].ends_with("version 7"), "{}", texts[2]);
}

#[test]
fn fuzz_never_panics() {
    let mut rng = Lcg(0x5eed);
    let good = to_bytes(&sample_calibration::<f32>());
    let mut accepted = 0;
    for k in 0..6000 {
        let mut buf = [0u8; 2 * ENCODED_LEN];
        let len = rng.below(2 * ENCODED_LEN as u32 + 1);
        match k % 3 {
            // Random bytes.
            0 => buf.iter_mut().for_each(|b| *b = rng.byte()),
            // A valid record with a few random bytes changed: always caught.
            1 => {
                buf[..ENCODED_LEN].copy_from_slice(&good);
                for _ in 0..1 + rng.below(8) {
                    let i = rng.below(ENCODED_LEN as u32);
                    buf[i] ^= 1 + rng.byte() % 255;
                }
            }
            // Random content behind a valid header and CRC: exercises the
            // checks after the CRC.
            _ => {
                buf.iter_mut().for_each(|b| *b = rng.byte());
                let mut rec: [u8; ENCODED_LEN] = buf[..ENCODED_LEN].try_into().unwrap();
                rec[..4].copy_from_slice(&MAGIC);
                rec[4] = VERSION;
                if rng.below(2) == 0 {
                    rec[5] = PRECISION_F32;
                    rec[6] = 0;
                    rec[7] = 0;
                }
                reseal(&mut rec);
                buf[..ENCODED_LEN].copy_from_slice(&rec);
            }
        }
        let input = if k % 3 == 1 {
            &buf[..ENCODED_LEN]
        } else {
            &buf[..len]
        };
        let r32 = from_bytes::<f32>(input);
        let r64 = from_bytes::<f64>(input);
        if k % 3 == 1 {
            assert!(r32.is_err() && r64.is_err(), "{k}");
        }
        if r32.is_ok() || r64.is_ok() {
            accepted += 1;
        }
    }
    // Random W and rho are consistent with probability ~0.
    assert_eq!(accepted, 0);
}

/// Found by fuzzing: a field strength beyond about 4e12 units made det(W)
/// subnormal in f32 and the field strength wrong by up to 20 %, and the
/// record then failed its own consistency check on reading.
#[test]
fn huge_field_strength_in_f32_is_exact_and_round_trips() {
    let w = Matrix3::from_diagonal(&Vector3::new(7.349879e-15f32, 3.8492129e-16, 2.1973967e-13));
    let cal = cal_new::<f32>(Vector3::new(75.27761, 522.31775, -862.0255), w).unwrap();
    let want = 1.0 / (7.349879e-15f64 * 3.8492129e-16 * 2.1973967e-13).cbrt();
    let rho = f64::from(cal.field_strength());
    assert!((rho / want - 1.0).abs() < 1e-6, "{rho} vs {want}");
    assert!(from_bytes::<f32>(&to_bytes(&cal)).is_ok());
}
