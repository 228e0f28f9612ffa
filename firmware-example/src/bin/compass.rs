//! The example to copy: a calibrated compass on a BBC micro:bit v2.
//!
//! Reads the LSM303AGR through the `lsm303agr` driver, loads the stored
//! calibration or collects samples (with progress) and calibrates on the
//! chip, stores the result in flash, then prints smoothed headings. The
//! same code runs under QEMU against a simulated sensor (`--features
//! qemu`), where the "bench" turns the simulated device; on the board it
//! asks you to. (`src/main.rs` is the self-checking version with fault
//! handling that CI runs.)
#![no_std]
#![no_main]

use defmt::{error, info};
use embedded_hal::{delay::DelayNs, i2c::I2c};
use lsm303agr::{interface::I2cInterface, mode::MagContinuous, Lsm303agr};
use lsm303agr::{MagMode, MagOutputDataRate};
use mag_cal_core::collector::{Collector, Offer};
use mag_cal_core::heading::{heading_deg, HeadingSmoother, DEFAULT_WINDOW};
use mag_cal_core::{calibrate, Config};

use firmware_example::{platform, storage};

type Sensor<I> = Lsm303agr<I2cInterface<I>, MagContinuous>;

/// The next magnetometer reading in raw counts, as the driver gives it.
fn read<I: I2c>(sensor: &mut Sensor<I>) -> (i16, i16, i16) {
    loop {
        if sensor.mag_status().is_ok_and(|s| s.xyz_new_data()) {
            if let Ok(field) = sensor.magnetic_field() {
                return field.xyz_unscaled();
            }
        }
    }
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let mut hardware = platform::Hardware::take();
    let (i2c, delay, mut bench, flash) = hardware.split();

    let mut sensor = Lsm303agr::new_with_i2c(i2c);
    let started = sensor.init().is_ok()
        && sensor
            .set_mag_mode_and_odr(delay, MagMode::HighResolution, MagOutputDataRate::Hz20)
            .is_ok();
    let Some(mut sensor) = started.then(|| sensor.into_mag_continuous().ok()).flatten() else {
        error!("the LSM303AGR does not answer");
        platform::exit(false)
    };

    let cal = match storage::load(flash) {
        Ok(cal) => cal,
        Err(_) => {
            // Collect while the device turns; the collector keeps readings
            // at least 4 deg apart and tracks 48 direction cells.
            let mut collector: Collector<(i16, i16, i16), 600> = Collector::new(4.0);
            bench.begin_sweep();
            let mut last: u8 = 0;
            while !collector.is_ready() {
                if collector.offer(read(&mut sensor)) == Offer::Full {
                    break;
                }
                let p = collector.progress();
                if p.percent >= last + 10 {
                    info!("collected {} samples, {} %", p.samples, p.percent);
                    last = p.percent;
                }
            }
            // A little more, to close the sphere.
            for _ in 0..200 {
                let _ = collector.offer(read(&mut sensor));
            }
            match calibrate::<f32, _>(collector.samples(), &Config::default()) {
                Ok(fit) => {
                    let r = &fit.report;
                    info!(
                        "calibrated: {} samples used, {} left out, {} set aside lying still, radial RMS {=f32}",
                        r.samples_used,
                        r.samples_dropped + r.screened + r.rejected,
                        r.dwell,
                        r.radial_rms
                    );
                    if storage::store(flash, &fit.calibration).is_err() {
                        error!("the calibration could not be stored");
                    }
                    fit.calibration
                }
                Err(e) => {
                    // The refusal says why, e.g. "turn the sensor".
                    error!("not calibrated: {}", e);
                    platform::exit(false)
                }
            }
        }
    };
    info!("{}", cal);

    // Headings of the calibrated readings, averaged on the circle.
    let mut smoother: HeadingSmoother<f32, DEFAULT_WINDOW> = HeadingSmoother::new();
    bench.begin_level_turn(12, DEFAULT_WINDOW as u32);
    for k in 0..12 * DEFAULT_WINDOW {
        let heading = smoother.push(heading_deg(cal.apply(read(&mut sensor))));
        if let (Some(h), true) = (heading, (k + 1) % DEFAULT_WINDOW == 0) {
            info!("heading {=f32} deg", h);
        }
        delay.delay_ms(50);
    }
    platform::exit(true)
}
