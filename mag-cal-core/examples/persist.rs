//! Saves a calibration and loads it back, as firmware does with a flash
//! page: 92 bytes with a magic number, a version, the values and a CRC-32.
//! A corrupted record is refused, never half-read.
//!
//! ```sh
//! cargo run -p mag-cal-core --example persist
//! ```

use mag_cal_core::persist::{from_bytes, to_bytes, ENCODED_LEN};
use mag_cal_core::{calibrate, Config};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // A calibration from samples on an offset, stretched sphere.
    let samples: Vec<[i16; 3]> = (0..300)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / 300.0;
            let (r, phi) = ((1.0 - z * z).sqrt(), i as f32 * 2.399_963);
            let h = [r * phi.cos(), r * phi.sin(), z];
            [
                -400.0 + 310.0 * h[0],
                250.0 + 290.0 * h[1],
                90.0 + 335.0 * h[2],
            ]
            .map(|v| v.round() as i16)
        })
        .collect();
    let cal = calibrate::<f32, _>(&samples, &Config::default())?.calibration;

    // Save: on a device, these bytes go to flash (or EEPROM, or a file).
    let bytes: [u8; ENCODED_LEN] = to_bytes(&cal);
    let path = std::env::temp_dir().join("mag-cal-example.bin");
    std::fs::write(&path, bytes).expect("temporary file");
    println!("saved {} bytes to {}", bytes.len(), path.display());

    // Load after a reset: the same calibration, bit for bit.
    let stored = std::fs::read(&path).expect("temporary file");
    let loaded = from_bytes::<f32>(&stored)?;
    assert_eq!(loaded, cal);
    println!(
        "loaded: b = {:?}, field strength {}",
        loaded.hard_iron(),
        loaded.field_strength()
    );

    // A flipped bit is caught by the checksum.
    let mut damaged = stored.clone();
    damaged[20] ^= 0x04;
    match from_bytes::<f32>(&damaged) {
        Err(e) => println!("a damaged record is refused: {e}"),
        Ok(_) => unreachable!("the CRC catches every single-bit flip"),
    }
    let _ = std::fs::remove_file(&path);
    Ok(())
}
