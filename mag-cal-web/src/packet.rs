//! MotionCal's calibration packet, which "send to board" writes to the
//! serial port.
//!
//! PJRC's MotionCal sends 68 bytes, and the sketches built on Adafruit's
//! `Adafruit_Sensor_Calibration` (and PJRC's own) check and store them
//! unchanged:
//!
//! | bytes | content |
//! |---|---|
//! | 0, 1 | `117`, `84` |
//! | 2..66 | 16 little-endian `f32`: accelerometer offsets (3, sent as 0), gyroscope offsets (3, sent as 0), hard iron `V` (3, uT), field strength `B` (uT), soft iron `invW` as `[0][0]`, `[1][1]`, `[2][2]`, `[0][1]`, `[0][2]`, `[1][2]` |
//! | 66, 67 | CRC-16 of bytes 0..66 (reflected polynomial `0xA001`, initial value `0xFFFF`), low byte first |
//!
//! The receiver computes the CRC over all 68 bytes and accepts the packet
//! when it is 0. The board then calibrates `invW (raw - V)` in uT, with `raw`
//! in uT.
//!
//! Our calibration maps `W (y - b)` onto the unit sphere, with `y` in the
//! units of the samples. MotionCal's `Raw:` lines carry the magnetometer at
//! 10 counts per uT, so for samples in those units `V = b / 10`,
//! `B = rho / 10` with `rho = det(W)^(-1/3)` the field strength in counts,
//! and `invW = rho W` (then `|invW (raw - V)| = B`).

use mag_cal_cli::fit::Outcome;

/// Length of the packet.
pub const LEN: usize = 68;

/// The two bytes that start a packet.
pub const SIGNATURE: [u8; 2] = [117, 84];

/// Counts per uT of the magnetometer in MotionCal's `Raw:` lines.
pub const COUNTS_PER_UT: f64 = 10.0;

/// MotionCal's CRC-16 (the reflected form of `x^16 + x^15 + x^2 + 1`,
/// initial value `0xFFFF`, no final inversion) of `bytes`.
pub fn crc16(bytes: &[u8]) -> u16 {
    bytes.iter().fold(0xFFFF_u16, |crc, &byte| {
        (0..8).fold(crc ^ u16::from(byte), |c, _| {
            if c & 1 == 1 {
                (c >> 1) ^ 0xA001
            } else {
                c >> 1
            }
        })
    })
}

/// The packet for a fit of samples in MotionCal's units (0.1 uT).
pub fn from_outcome(o: &Outcome) -> [u8; LEN] {
    let rho = o.field_strength;
    let w = o.soft_iron;
    let floats: [f64; 16] = [
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        0.0,
        o.hard_iron[0] / COUNTS_PER_UT,
        o.hard_iron[1] / COUNTS_PER_UT,
        o.hard_iron[2] / COUNTS_PER_UT,
        rho / COUNTS_PER_UT,
        rho * w[0][0],
        rho * w[1][1],
        rho * w[2][2],
        rho * w[0][1],
        rho * w[0][2],
        rho * w[1][2],
    ];
    let mut packet = [0u8; LEN];
    packet[..2].copy_from_slice(&SIGNATURE);
    for (chunk, value) in packet[2..LEN - 2].chunks_exact_mut(4).zip(floats) {
        chunk.copy_from_slice(&(value as f32).to_le_bytes());
    }
    let crc = crc16(&packet[..LEN - 2]);
    packet[LEN - 2..].copy_from_slice(&crc.to_le_bytes());
    packet
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_of_the_check_string() {
        // The catalogued check value of CRC-16/MODBUS (this polynomial,
        // initial value and reflection) for "123456789".
        assert_eq!(crc16(b"123456789"), 0x4B37);
    }

    /// What a board does with the packet (Adafruit_Sensor_Calibration:
    /// `invW (raw_uT - V)`, whose length should be `B`), on the samples of
    /// a fit in MotionCal's units.
    #[test]
    fn the_board_gets_the_field_strength_back() {
        let rows: Vec<[f64; 3]> = (0..400)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / 400.0;
                let r = (1.0 - z * z).sqrt();
                let phi = i as f64 * 2.399_963;
                let h = [r * phi.cos(), r * phi.sin(), z];
                [
                    -120.0 + 410.0 * h[0] + 30.0 * h[1],
                    250.0 + 380.0 * h[1],
                    75.0 + 450.0 * h[2] - 20.0 * h[0],
                ]
            })
            .collect();
        let o = mag_cal_cli::fit::fit(
            &rows,
            &mag_cal_core::Config::default(),
            mag_cal_cli::cli::Precision::F64,
        )
        .expect("fits");
        let packet = from_outcome(&o);
        assert_eq!(packet[..2], SIGNATURE);
        assert_eq!(crc16(&packet), 0);
        let f = |i: usize| {
            let at = 2 + 4 * i;
            f64::from(f32::from_le_bytes([
                packet[at],
                packet[at + 1],
                packet[at + 2],
                packet[at + 3],
            ]))
        };
        assert!((0..6).all(|i| f(i) == 0.0));
        let (v, b) = ([f(6), f(7), f(8)], f(9));
        let s = [
            [f(10), f(13), f(14)],
            [f(13), f(11), f(15)],
            [f(14), f(15), f(12)],
        ];
        assert!((b - o.field_strength / COUNTS_PER_UT).abs() < 1e-4 * b);
        for y in &rows {
            let d: Vec<f64> = (0..3).map(|k| y[k] / COUNTS_PER_UT - v[k]).collect();
            let m: Vec<f64> = s
                .iter()
                .map(|row| row[0] * d[0] + row[1] * d[1] + row[2] * d[2])
                .collect();
            let norm = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
            assert!((norm / b - 1.0).abs() < 1e-5, "{norm} against {b}");
        }
    }

    #[test]
    fn a_whole_packet_checks_to_zero() {
        let mut packet = [0u8; LEN];
        packet[..2].copy_from_slice(&SIGNATURE);
        packet[30..34].copy_from_slice(&48.5f32.to_le_bytes());
        let crc = crc16(&packet[..LEN - 2]);
        packet[LEN - 2..].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(crc16(&packet), 0);
    }
}
