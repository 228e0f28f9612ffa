//! Headings from a calibration, smoothed on the circle.
//!
//! A simulated level sensor with a hard-iron offset and a stretched axis
//! turns slowly through north (the raw headings would wrap from 359 to 0
//! degrees): the calibrated heading follows the true one, and the circular
//! moving average smooths the noise without breaking at the wrap. (Here
//! the soft iron is a stretch along the body axes, so the calibrated frame
//! is the body frame; in general it is turned, and `align::procrustes`
//! finds the rotation from reference directions.)
//!
//! ```sh
//! cargo run -p mag-cal-core --example heading
//! ```

use mag_cal_core::heading::{heading_deg, wrap_deg, HeadingSmoother, DEFAULT_WINDOW};
use mag_cal_core::{calibrate, Config};

/// The simulated sensor: field of 45 counts horizontal and 30 vertical,
/// x stretched by 20 %, offset (120, -60, 35) counts.
fn reading(heading: f64, tilt: f64, noise: f64) -> [f64; 3] {
    let (h, v) = (45.0, 30.0);
    // The field in the body frame at this heading and a small pitch.
    let (s, c) = heading.to_radians().sin_cos();
    let (st, ct) = tilt.to_radians().sin_cos();
    let (x, y, z) = (h * c, -h * s, v);
    let (x, z) = (ct * x - st * z, st * x + ct * z);
    [120.0 + 1.2 * x + noise, -60.0 + y - noise, 35.0 + z]
}

fn main() -> Result<(), mag_cal_core::Error> {
    // Calibrate first from readings in many orientations.
    let mut samples = Vec::new();
    for k in 0..400 {
        let heading = k as f64 * 137.5;
        let tilt = -80.0 + 160.0 * (k as f64 + 0.5) / 400.0;
        samples.push(reading(heading, tilt, 0.0));
    }
    let cal = calibrate::<f64, _>(&samples, &Config::default())?.calibration;

    // Then turn level through north, with noise on the readings.
    let mut smoother: HeadingSmoother<f64, DEFAULT_WINDOW> = HeadingSmoother::new();
    for k in 0..40 {
        let truth = wrap_deg(340.0 + 1.0 * k as f64);
        let noise = if k % 2 == 0 { 0.8 } else { -0.8 };
        let raw = reading(truth, 0.0, noise);
        let uncalibrated = heading_deg(raw);
        let calibrated = heading_deg(cal.apply(raw));
        let smoothed = smoother.push(calibrated);
        if k % 5 == 0 {
            println!(
                "true {truth:7.2}  raw {uncalibrated:8.2}  calibrated {calibrated:7.2}  smoothed {}",
                smoothed.map_or("(filling)".to_string(), |s| format!("{s:7.2}"))
            );
        }
    }
    Ok(())
}
