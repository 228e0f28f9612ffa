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
//!   calibration is off;
//! - `faults` (with `qemu`): the simulated sensor misbehaves on a schedule
//!   (`sim::Faults::RUN`: NACK bursts, stuck output, saturation, a passing
//!   magnet, and isolated glitches: wild readings and displaced ones, the
//!   latter left to the core's outlier handling) and the run ends with
//!   summary lines of the glitches and of the faults seen and handled. The
//!   application's fault handling is the same in every build.
//!
//! The flow at each boot: initialise the sensor through the unmodified
//! `lsm303agr` driver (retrying I2C failures, [`faults`]); load the stored
//! calibration ([`storage`]), or, when there is none valid, collect samples
//! with the core's `Collector` while the device is turned in all
//! directions, calibrate on the chip (ADC2, `f32`) and store the result;
//! then stream a smoothed, calibrated level heading. Every reading passes
//! the fault monitor ([`faults::Monitor`]) first.

#![no_std]

#[cfg(all(feature = "board", feature = "qemu-base"))]
compile_error!(
    "choose one of the features `board` and `qemu` (use --no-default-features for qemu)"
);
#[cfg(not(any(feature = "board", feature = "qemu-base")))]
compile_error!("choose one of the features `board` (default) and `qemu`");

pub mod faults;
pub mod heading;
pub mod storage;

#[cfg(feature = "board")]
pub mod board;
#[cfg(feature = "board")]
pub use board as platform;

#[cfg(feature = "qemu-base")]
pub mod sim;
#[cfg(feature = "qemu-base")]
pub mod sim_sensor;
#[cfg(feature = "qemu-base")]
use defmt_semihosting as _;
#[cfg(feature = "qemu-base")]
pub use sim_sensor as platform;

use nalgebra::{Matrix3, Vector3};

/// The length of a calibrated reading (the core's API gives plain arrays).
pub fn norm(v: [f32; 3]) -> f32 {
    libm::sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
}

/// The true calibration of a simulated sensor: `y = T h + b` in counts.
pub struct Truth {
    /// `b`, counts.
    pub hard_iron: Vector3<f32>,
    /// `T`, counts.
    pub soft_iron: Matrix3<f32>,
    /// `rho = |det T|^(1/3)`, counts.
    pub field_strength: f32,
}

/// A glitch the simulator injected into a reading (its truth about it, for
/// the fault run's self-check; never known on the board): isolated
/// readings the fault monitor's episode tests cannot see
/// (`sim::Glitches`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum GlitchKind {
    /// Thousands of counts off, before the disturbance test has a
    /// reference.
    Wild,
    /// Displaced by a share of the field below the monitor's threshold.
    Displaced,
}

/// What the application did about the calibration at one boot.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum BootOutcome {
    /// A valid stored calibration was loaded; no calibration ran.
    Loaded,
    /// Nothing valid was stored (why: the load's error); the device was
    /// calibrated and the result stored.
    Calibrated(storage::LoadError),
}
