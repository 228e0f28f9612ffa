//! On-device magnetometer calibration with `mag-cal-core`: the pieces
//! shared by the application (`src/main.rs`) and the on-target tests
//! (`src/bin/ontarget.rs`).
//!
//! One application, two wirings (chosen by feature, nothing else is gated):
//!
//! - `board` (default): BBC micro:bit v2, its LSM303AGR on the internal I2C
//!   bus ([`board`]);
//! - `qemu`: QEMU's mps2-an386 with a register-level simulated LSM303AGR on
//!   a simulated I2C bus ([`sim_sensor`], physics in [`sim`]), which also
//!   knows the truth, so the run checks itself and exits non-zero when the
//!   calibration is off.
//!
//! The flow: initialise the sensor through the unmodified `lsm303agr`
//! driver; collect 600 raw samples while the device is turned in all
//! directions; calibrate on the chip (ADC2, `f32`); log the calibration;
//! then stream a smoothed, calibrated level heading.

#![no_std]

#[cfg(all(feature = "board", feature = "qemu"))]
compile_error!(
    "choose one of the features `board` and `qemu` (use --no-default-features for qemu)"
);
#[cfg(not(any(feature = "board", feature = "qemu")))]
compile_error!("choose one of the features `board` (default) and `qemu`");

pub mod coverage;
pub mod heading;

#[cfg(feature = "board")]
pub mod board;
#[cfg(feature = "board")]
pub use board as platform;

#[cfg(feature = "qemu")]
pub mod sim;
#[cfg(feature = "qemu")]
pub mod sim_sensor;
#[cfg(feature = "qemu")]
use defmt_semihosting as _;
#[cfg(feature = "qemu")]
pub use sim_sensor as platform;

use mag_cal_core::nalgebra::{Matrix3, Vector3};

/// The true calibration of a simulated sensor: `y = T h + b` in counts.
pub struct Truth {
    /// `b`, counts.
    pub hard_iron: Vector3<f32>,
    /// `T`, counts.
    pub soft_iron: Matrix3<f32>,
    /// `rho = |det T|^(1/3)`, counts.
    pub field_strength: f32,
}
